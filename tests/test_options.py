"""FitOptions: one object of fit options, checked in one place, applied to the preset."""

import numpy as np
import pytest

import jsrte
from analytic import octahedron_model, octahedron_query
from jsrte.errors import JsrteError
from jsrte.options import FitOptions
from jsrte.presets import LINE_OF_SIGHT_SAMPLES, get_preset


def test_vectors_of_any_kind_become_checked_tuples():
    options = FitOptions(up=np.array([0, 0, 2]), at=[1, 2, 3], viewpoints=np.zeros((2, 3)), device=None)
    assert options.up == (0.0, 0.0, 2.0) and options.at == (1.0, 2.0, 3.0)
    assert options.viewpoints == ((0.0, 0.0, 0.0), (0.0, 0.0, 0.0))
    assert FitOptions(hypotheses=np.int64(4)).hypotheses == 4
    assert hash(options)  # frozen and hashable: it travels to fit-many's workers as it is
    for bad, message in [({"up": (0, 0, 0)}, "non-zero"), ({"at": (1, 2)}, "three finite"),
                         ({"viewpoints": [(0, 0, np.nan)]}, "three finite"), ({"hypotheses": 0}, "positive"),
                         ({"preset": "quick"}, "unknown preset 'quick'; known: paper, fast"),
                         ({"dtype": "half"}, "unknown dtype 'half'; known: float32, bfloat16, auto")]:
        with pytest.raises(JsrteError, match=message):
            FitOptions(**bad)
    with pytest.raises(JsrteError, match="unknown fit option hypothesis; known: preset, up"):
        FitOptions().changed(hypothesis=3)


def test_settings_apply_line_of_sight_and_free_axis_to_the_preset():
    fast = get_preset("fast")
    assert FitOptions().settings() == fast
    assert FitOptions(line_of_sight=False).settings().scan_sdf.n_ray_freespace == 0
    assert FitOptions(preset="paper", line_of_sight=True).settings().scan_sdf.n_ray_freespace == LINE_OF_SIGHT_SAMPLES
    assert fast.fit.hold_axis and not FitOptions(free_axis=True).settings().fit.hold_axis
    assert fast.fit.decoder_dtype == "auto" and get_preset("paper").fit.decoder_dtype == "float32"
    assert FitOptions(dtype="float32").settings().fit.decoder_dtype == "float32"
    assert FitOptions(preset="paper", dtype="bfloat16").settings().fit.decoder_dtype == "bfloat16"
    assert fast.fit.float32_retry and not get_preset("paper").fit.float32_retry
    assert not FitOptions(float32_retry=False).settings().fit.float32_retry
    assert FitOptions(preset="paper", float32_retry=True).settings().fit.float32_retry
    assert fast.fit.floor_contact == 0.0 and get_preset("fast-scales-floor").fit.floor_contact_classes == ("table",)
    held = FitOptions(floor_contact=0.3).settings().fit
    assert held.floor_contact == 0.3 and held.floor_contact_classes is None  # every class
    assert FitOptions(preset="fast-gn", floor_contact=0.0).settings().fit.floor_contact == 0.0


def test_a_floor_contact_is_a_weight_of_0_or_more_for_adam_fits_only(run_cli, tmp_path):
    for bad, message in [({"floor_contact": -0.1}, "floor_contact must be a finite number 0 or more, got -0.1"),
                         ({"floor_contact": float("nan")}, "finite number"),
                         ({"floor_contact": 0.3, "preset": "fast-gn"},
                          "floor_contact holds Adam's fits only; preset fast-gn fits by gauss-newton")]:
        with pytest.raises(JsrteError, match=message):
            FitOptions(**bad)
    for flags, message in [(["--floor-contact", "-1"], "--floor-contact must be a finite number 0 or more"),
                           (["--floor-contact", "0.3", "--preset", "fast-gn"],
                            "--floor-contact holds Adam's fits only; preset fast-gn fits by gauss-newton")]:
        code, _, err = run_cli(["fit", str(tmp_path / "scan.ply"), "--out", str(tmp_path / "out"), *flags])
        assert code == 2 and message in err and err.count("\n") == 1
        assert not (tmp_path / "out").exists()


def test_the_dtype_flag_is_checked_and_recorded(run_cli, tmp_path):
    """``jsrte fit --dtype``: a bad value is a one-line error; fit.json records the arithmetic used."""
    from jsrte.fit.query import save_query

    query_file = tmp_path / "q.npz"
    save_query(octahedron_query(), query_file)
    code, _, err = run_cli(["fit", str(query_file), "--dtype", "half", "--out", str(tmp_path / "bad")])
    assert code == 2 and "--dtype must be one of float32, bfloat16, auto, got 'half'" in err
    assert not (tmp_path / "bad").exists()
    result = jsrte.fit(octahedron_query(), model=octahedron_model(), preset="smoke", hypotheses=1, dtype="bfloat16")
    assert result.info["decoder_dtype"] == "bfloat16" and result.info["options"]["dtype"] == "bfloat16"


def test_options_by_object_or_by_name_fit_alike():
    model, query = octahedron_model(), octahedron_query()
    by_name = jsrte.fit(query, model=model, preset="smoke", hypotheses=2, seed=4)
    by_object = jsrte.fit(query, model=model, options=FitOptions(preset="smoke", hypotheses=2, seed=4))
    over = jsrte.fit(query, model=model, options=FitOptions(preset="smoke", hypotheses=2, seed=9), seed=4)
    assert by_name.transform.s == by_object.transform.s == over.transform.s
    assert len(by_name.hypotheses) == 2


def test_every_fit_option_is_a_flag_of_fit_and_fit_many_and_the_query_ones_of_prepare():
    from dataclasses import fields

    import typer.main

    from jsrte.cli import _register, app

    _register()
    commands = typer.main.get_command(app).commands  # type: ignore[attr-defined]
    flag = {"viewpoints": "viewpoint"}  # repeatable: one flag per viewpoint
    every = {flag.get(f.name, f.name) for f in fields(FitOptions)}
    # prepare leaves them to jsrte fit
    fit_time = {"hypotheses", "free_axis", "device", "dtype", "float32_retry", "floor_contact"}
    query_only = every - fit_time
    for name, wanted in (("fit", every), ("fit-many", every), ("prepare", query_only)):
        params = {p.name for p in commands[name].params}
        assert wanted <= params, (name, wanted - params)


def test_a_mode_typo_in_fit_settings_is_refused():
    from jsrte.presets import FitSettings

    with pytest.raises(ValueError, match="FitSettings.selection must be one of fscore, loss, got 'los'"):
        FitSettings(selection="los")
    assert FitSettings(solver="gauss-newton", latent_space="whitened", init_scale="height").solver == "gauss-newton"


def test_the_default_preset_follows_what_the_fit_must_find():
    from jsrte.presets import default_preset, names_several_models

    assert [names_several_models(m) for m in ("auto", "chair,table", "chair", None, ["a", "b"], ["a"])] == \
        [True, True, False, False, True, False]
    assert default_preset() == "fast" and default_preset(class_unknown=True) == "fast-scales"
    assert default_preset(scene=True, class_unknown=True) == "fast-scales"
