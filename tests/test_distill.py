"""Distilled decoders: a student learns its teacher's SDF over the latent space, keeps its codes,
and the ``express`` preset searches with it while the model itself finishes the fit."""

from dataclasses import replace

import numpy as np
import pytest
import torch

from analytic import WideningLShapeDecoder, make_query, tilted_truth
from jsrte.errors import JsrteError
from jsrte.fit.solve import fit_query
from jsrte.geometry.sim3 import rotation_angle_deg
from jsrte.model.checkpoint import DeepSdfModel, load_model
from jsrte.model.config import ARCHITECTURES
from jsrte.model.decoder import Decoder
from jsrte.model.distill import DistillSettings, distill, draw_codes, project_to_surface, student_error
from jsrte.model.meshing import decode_mesh
from jsrte.model.registry import DISTILLED_DIR, distilled_decoder, resolve_model, shipped_models
from jsrte.presets import get_preset

SMALL = DistillSettings(steps=200, codes_per_step=4, points_per_code=512, candidates_per_code=1024, lr=3e-3)
TRUE_CODE = np.array([0.3, 0.0, 0.0])


class _Sphere(torch.nn.Module):
    """|x| − 0.5, whatever the code."""

    def forward(self, points: torch.Tensor, codes: torch.Tensor) -> torch.Tensor:
        return points.norm(dim=-1) - 0.5


class _Offset(torch.nn.Module):
    """Another decoder's SDF plus a constant: a surface ``offset`` inside the true one."""

    def __init__(self, decoder: torch.nn.Module, offset: float) -> None:
        super().__init__()
        self.decoder, self.offset, self.config = decoder, offset, decoder.config

    def forward(self, points: torch.Tensor, codes: torch.Tensor) -> torch.Tensor:
        return self.decoder(points, codes) + self.offset


def test_drawn_codes_are_training_codes_their_mixes_and_gaussian_draws():
    codes = torch.randn(1000, 4)
    drawn = draw_codes(codes, 9, torch.Generator().manual_seed(0))
    assert drawn.shape == (9, 4)
    exact = [(codes - row).abs().sum(1).min() < 1e-6 for row in drawn]
    assert all(exact[:3]) and not any(exact[3:])


def test_points_are_moved_onto_the_zero_level_set():
    """Points within two steps (0.1 each at most) of a sphere land on it, along its normals."""
    points = torch.tensor([[[0.7, 0.0, 0.0], [0.0, 0.3, 0.2], [-0.3, 0.3, 0.45]]])
    moved = project_to_surface(_Sphere(), points, torch.zeros(1, 2))
    np.testing.assert_allclose(moved.norm(dim=-1).numpy(), 0.5, atol=1e-5)
    np.testing.assert_allclose((moved / moved.norm(dim=-1, keepdim=True)).numpy(),
                               (points / points.norm(dim=-1, keepdim=True)).numpy(), atol=1e-5)


def test_a_student_learns_its_teachers_sdf_and_keeps_its_codes():
    """A shipped distilled chair decoder as the teacher (cheap to run), a fresh ``tiny`` network as
    the student: 200 small steps cut its error near the teacher's surface by more than 3x."""
    teacher = load_model(DISTILLED_DIR / "chair.safetensors")
    torch.manual_seed(0)
    fresh = DeepSdfModel(Decoder(ARCHITECTURES["tiny"]).eval(), teacher.codes, {})
    before = student_error(fresh, teacher, SMALL, n_codes=8)
    student = distill(teacher, ARCHITECTURES["tiny"], SMALL, progress=False, name="pupil")
    after = student_error(student, teacher, SMALL, n_codes=8)
    assert after["near_surface_mean_abs"] < before["near_surface_mean_abs"] / 3
    assert after["mean_abs"] < before["mean_abs"] / 2
    assert torch.equal(student.codes, teacher.codes)
    assert student.meta["name"] == "pupil" and student.meta["arch"] == "tiny"
    assert student.meta["distilled_from"] == {"name": teacher.name, "sha256": teacher.meta["sha256"]}
    assert student.meta["distillation"]["steps_done"] == 200 and "path" not in student.meta


def test_every_shipped_model_has_its_distilled_decoder():
    """Each shipped model finds the shipped student made from it (by its SHA-256), a cheaper
    network with the same codes: re-shipping a model without distilling it again fails here."""
    for name in shipped_models():
        model = resolve_model(name)
        student = distilled_decoder(model)
        assert student.meta["distilled_from"]["sha256"] == model.meta["sha256"]
        assert torch.equal(student.codes, model.codes)
        assert sum(p.numel() for p in student.decoder.parameters()) * 5 < \
            sum(p.numel() for p in model.decoder.parameters())


def test_a_models_own_distilled_decoder_beside_it_comes_before_the_shipped_one(tmp_path):
    import shutil

    from jsrte.model.checkpoint import save_model

    copy = tmp_path / "mine.safetensors"
    shutil.copy(shipped_models()["chair"], copy)
    own = load_model(DISTILLED_DIR / "chair.safetensors")
    own.meta.pop("sha256")
    own.meta.pop("path")
    own.meta["name"] = "mine-tiny"
    save_model(own, tmp_path / "mine.distilled.safetensors")
    assert distilled_decoder(load_model(copy)).name == "mine-tiny"
    assert distilled_decoder(resolve_model("chair")).name == "chair-tiny"


def test_a_model_without_a_distilled_decoder_is_named_with_the_command_that_makes_one(tmp_path):
    import shutil

    copy = tmp_path / "mine.safetensors"
    shutil.copy(shipped_models()["chair"], copy)
    model = load_model(copy)
    model.meta["sha256"] = "another"
    with pytest.raises(JsrteError, match="no distilled decoder.*jsrte distill --teacher .*mine.safetensors "
                                         ".*mine.distilled.safetensors"):
        distilled_decoder(model)


def _widening_case() -> tuple[DeepSdfModel, object, object]:
    """A widening L-shape model whose student's surface lies 0.03 inside its own, the true
    similarity and the query of its shape at the true code so placed."""
    teacher = DeepSdfModel(WideningLShapeDecoder(), torch.zeros(1, 3),
                           {"name": "widening", "canonical_height": 1.5, "canonical_radius": 0.95})
    teacher.distilled = DeepSdfModel(_Offset(teacher.decoder, 0.03), teacher.codes, {"name": "widening-student"})
    mesh = decode_mesh(teacher.decoder, torch.tensor(TRUE_CODE, dtype=torch.float32), resolution=64).mesh
    truth, up = tilted_truth(theta=-2.0)
    query = make_query(mesh, truth, up, np.random.default_rng(6))
    return teacher, truth, query


def test_express_searches_with_the_distilled_decoder_and_finishes_with_the_model():
    """The student's surface lies 0.03 inside the model's, so a fit by the student alone ends
    more than 3% too large; the model's own Levenberg–Marquardt iterations and final losses bring
    the scale back, and the mesh is the model's at the fitted code."""
    teacher, truth, query = _widening_case()
    settings = replace(get_preset("express").fit, extract_resolution=32)
    result = fit_query(teacher, query, settings, seed=0)
    assert result.info["search_decoder"] == "widening-student"
    assert result.transform.s == pytest.approx(truth.s, rel=0.02)
    assert rotation_angle_deg(result.transform.R, truth.R) < 3.0
    expected = decode_mesh(teacher.decoder, result.latent, resolution=32).mesh
    np.testing.assert_allclose(result.mesh_canonical.bounds, expected.bounds, atol=1e-6)
    alone = fit_query(DeepSdfModel(teacher.distilled.decoder, teacher.codes, dict(teacher.meta)), query,
                      replace(settings, distilled_search=False), seed=0)
    assert alone.transform.s > truth.s * 1.03


def test_fast_distilled_moves_the_starts_by_the_distilled_decoder_and_the_model_settles_the_survivors():
    """Adam: the student (its surface 0.03 inside the model's; alone, the fit ends more than 3%
    too large) moves the 12 starts through 130 steps, each pruning keeping those the model
    explains best, and the model takes the two survivors' last 30 steps and the final losses:
    the scale comes back, and the evaluations split so."""
    teacher, truth, query = _widening_case()
    settings = replace(get_preset("fast-distilled").fit, extract_resolution=32, decoder_dtype="float32")
    assert settings == replace(get_preset("fast").fit, distilled_search=True, distilled_iterations=130,
                               decoder_dtype="float32", extract_resolution=32)
    result = fit_query(teacher, query, settings, seed=0)
    assert result.info["search_decoder"] == "widening-student"
    assert result.transform.s == pytest.approx(truth.s, rel=0.02)
    assert rotation_angle_deg(result.transform.R, truth.R) < 3.0
    n, judged = settings.samples_per_iteration, (12 + 4) * settings.judge_samples
    parts = result.info["decoder_evaluations_by_part"]
    assert parts["distilled"] == (12 * 20 + 4 * 40 + 2 * 70) * n
    assert parts["model"] == result.info["decoder_evaluations"] - parts["distilled"] > 2 * 30 * n + judged
    alone = fit_query(DeepSdfModel(teacher.distilled.decoder, teacher.codes, dict(teacher.meta)), query,
                      replace(settings, distilled_search=False), seed=0)
    assert alone.transform.s > truth.s * 1.03


def test_only_express_screens_candidates_with_the_distilled_decoder():
    """The quick fits follow the full fit's distilled search only where ``distilled_screen`` says so."""
    from jsrte.fit.screen import ScreenSettings

    assert ScreenSettings().searched_as(get_preset("express-scales").fit).fit.distilled_search
    assert not ScreenSettings().searched_as(get_preset("fast-scales-distilled").fit).fit.distilled_search
    assert not ScreenSettings().searched_as(get_preset("fast").fit).class_fit.distilled_search


def test_distill_refuses_an_architecture_it_does_not_know_and_a_file_it_would_overwrite(tmp_path, run_cli):
    out = tmp_path / "student.safetensors"
    code, _, stderr = run_cli(["distill", "--teacher", "chair", "--arch", "huge", "--out", str(out)])
    assert code == 2 and "unknown architecture 'huge'" in stderr and not out.exists()
    out.write_bytes(b"mine")
    code, _, stderr = run_cli(["distill", "--teacher", "chair", "--out", str(out), "--steps", "1"])
    assert code == 2 and "already exists" in stderr and out.read_bytes() == b"mine"


def test_express_scales_recovers_an_object_whose_height_misleads_its_start():
    """An object 2.5 times taller than its class's mean shape (analytic; the distilled decoder a
    copy of the model): ``express`` starts at 1/2.5 of its scale by its height and ends far off;
    ``express-scales`` also starts at its points' scale and recovers it."""
    from analytic import LShapeDecoder, tall_class_case

    mesh = decode_mesh(LShapeDecoder(), torch.zeros(4), resolution=48).mesh
    query, truth, model, _, _ = tall_class_case(mesh, factor=2.5)
    model.distilled = DeepSdfModel(_Offset(model.decoder, 0.0), model.codes, {"name": "lshape-student"})
    express, scales = (replace(get_preset(name).fit, extract_resolution=32, latent_space="raw",
                               below_floor_samples=0) for name in ("express", "express-scales"))
    assert scales == replace(express, init_scale="both")
    assert abs(fit_query(model, query, express, seed=0).transform.s / truth.s - 1.0) > 0.1
    result = fit_query(model, query, scales, seed=0)
    assert result.transform.s == pytest.approx(truth.s, rel=0.03)
    assert rotation_angle_deg(result.transform.R, truth.R) < 3.0
