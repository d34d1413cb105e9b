"""``jsrte fit``, ``jsrte reconstruct`` and ``jsrte models``."""

from __future__ import annotations

import json
import os
from pathlib import Path

import typer

from jsrte.cli import app
from jsrte.cli import fit_options as opt
from jsrte.cli.common import check_out_file, check_out_folder, check_threads, set_threads
from jsrte.errors import JsrteError


@app.command("fit")
def fit_command(
    scan: Path = typer.Argument(..., help="Scan (PLY/PCD/XYZ, metres), complete mesh (OBJ/OFF/STL/GLB) "
                                          "or SDF samples (.npz)."),
    out: Path = typer.Option(..., "--out", help="Output folder (fit.json, shape.ply, overlay.png; with --scene: "
                                                "scene.json, scene.ply, overlay.png, objects/NN/)."),
    model: str = typer.Option(None, help=opt.MODEL.help + " Default: chair; auto with --scene."),
    scene: bool = typer.Option(False, "--scene", help="Fit every object standing on the floor, each with its "
                                                      "class (docs/clutter.md)."),
    preset: str = opt.SCENE_OR_FIT_PRESET, up: str = opt.UP, viewpoint: list[str] = opt.VIEWPOINT,
    line_of_sight: bool = opt.LINE_OF_SIGHT, free_axis: bool = opt.FREE_AXIS, at: str = opt.AT,
    hypotheses: int = opt.HYPOTHESES, seed: int = opt.SEED, device: str = opt.DEVICE,
    units_check: bool = opt.UNITS_CHECK, dtype: str = opt.DTYPE,
    float32_retry: bool = opt.FLOAT32_RETRY, floor_contact: float = opt.FLOOR_CONTACT,
    leftovers: bool = opt.LEFTOVERS,
    threads: int = typer.Option(0, help="CPU threads (0: all cores); with --scene, objects fitted at once."),
    overwrite: bool = typer.Option(False, help="Replace results already in --out."),
    progress: bool = typer.Option(True, help="Show a progress bar."),
) -> None:
    """Fit the model to a scan: latent code + similarity transform (the paper's JSRTE)."""
    from jsrte.atomic import output_dir
    from jsrte.fit import fit
    from jsrte.fit.outputs import RESULT_NAME, write_fit_outputs
    from jsrte.presets import default_preset, names_several_models

    preset = preset or default_preset(scene=scene, class_unknown=names_several_models(model))
    options = opt.fit_options(preset=preset, up=up, viewpoint=viewpoint, line_of_sight=line_of_sight,
                              free_axis=free_axis, at=at, hypotheses=hypotheses, seed=seed, device=device,
                              units_check=units_check, dtype=dtype, float32_retry=float32_retry,
                              floor_contact=floor_contact)
    check_threads(threads)
    if not scan.exists():
        raise JsrteError("no such file", scan)
    if leftovers and not scene:
        raise JsrteError("--leftovers is for --scene (a single fit keeps one object)")
    if scene:
        _fit_scene(scan, out, model=model or "auto", options=options, overwrite=overwrite, progress=progress,
                   threads=threads, leftovers=leftovers)
        return
    check_out_folder(out, marker=RESULT_NAME, overwrite=overwrite)
    set_threads(threads)
    result = fit(scan, model=model or "chair", options=options, progress=progress)
    with output_dir(out, overwrite=overwrite, marker=RESULT_NAME) as folder:
        write_fit_outputs(result, folder, query_points=result.query_points, up=result.info.get("up"),
                          extra={"input": str(scan)})
    _report(result, out)


@app.command("prepare")
def prepare_command(
    scan: Path = typer.Argument(..., help="Scan (PLY/PCD/XYZ, metres) or complete mesh (OBJ/OFF/STL/GLB)."),
    out: Path = typer.Option(..., "--out", help="Query file to write (.npz), for `jsrte fit QUERY.npz`."),
    preset: str = opt.QUERY_PRESET, up: str = opt.UP, viewpoint: list[str] = opt.VIEWPOINT,
    line_of_sight: bool = opt.LINE_OF_SIGHT, at: str = opt.AT, seed: int = opt.SEED,
    units_check: bool = opt.UNITS_CHECK,
    overwrite: bool = typer.Option(False, help="Replace an existing query file."),
) -> None:
    """Preprocess a scan once into the fit's SDF query (floor, outliers, normals, samples): fit it
    later or on another machine (a GPU box without Open3D) with `jsrte fit QUERY.npz`.

    The fit-time options (--hypotheses, --free-axis, --device) are given to that `jsrte fit`."""
    import numpy as np

    from jsrte.fit import fit_query_of
    from jsrte.fit.query import save_query

    options = opt.fit_options(preset=preset, up=up, viewpoint=viewpoint, line_of_sight=line_of_sight, at=at,
                              seed=seed, units_check=units_check)
    check_out_file(out, overwrite=overwrite, suffixes=(".npz",))
    query = fit_query_of(scan, options)
    query.info["source"] = scan.name
    save_query(query, out)
    typer.echo(f"wrote {out}: {len(query.sdf)} SDF samples, {len(query.surface)} surface points"
               + ("" if query.up is None else f", up {np.round(query.up, 3).tolist()}"))


def _fit_scene(scan: Path, out: Path, *, model: str, options: object, overwrite: bool, progress: bool,
               threads: int, leftovers: bool = False) -> None:
    """``jsrte fit --scene``: every object of the scan, one line each, then the files."""
    from jsrte.atomic import output_dir
    from jsrte.fit.scene import PHASES, fit_scene
    from jsrte.fit.scene_outputs import SCENE_NAME, write_scene_outputs

    if options.at is not None:
        raise JsrteError("--scene fits every object; --at picks one (give one or the other)")
    check_out_folder(out, marker=SCENE_NAME, overwrite=overwrite)
    set_threads(threads)
    scene = fit_scene(scan, model=model, options=options, progress=progress, workers=threads or os.cpu_count() or 1,
                      leftovers=leftovers)
    with output_dir(out, overwrite=overwrite, marker=SCENE_NAME) as folder:
        write_scene_outputs(scene, folder, extra={"input": str(scan)})
    for obj in scene.objects:
        typer.echo(_scene_line(obj))
    for skip in scene.skipped:
        typer.echo(f"skipped candidate {skip['candidate']}: {skip['points']} points, {skip['reason']}")
    for cover in scene.covered:
        whole = f"; {cover['fitted_whole']}" if "fitted_whole" in cover else ""
        typer.echo(f"set aside candidate {cover['candidate']}: {cover['points']} points, {cover['reason']}{whole}")
    failed = len(scene.objects) - len(scene.fitted) - len(scene.boxes)
    typer.echo(f"{len(scene.found)} object(s) fitted, {len(scene.boxes)} box(es), "
               f"{len(scene.fitted) - len(scene.found)} unexplained, {failed} failed, "
               f"{len(scene.skipped)} candidate(s) skipped, {len(scene.covered)} set aside; "
               f"wrote {out}/scene.json, scene.ply, overlay.png, objects/NN/")
    timing = scene.timing
    phases = ", ".join(f"{phase} {timing[phase]:.1f} s" for phase in PHASES if phase in timing)
    typer.echo(f"fitted in {timing.get('total', 0.0):.1f} s ({phases})")


def _scene_line(obj) -> str:  # noqa: ANN001
    """One line for an object of a scene: class, flag, scale, centre (a box: its size)."""
    import numpy as np

    if obj.box is not None:
        size = " x ".join(f"{v:.2f}" for v in obj.box.cuboid.extents)
        return (f"object {obj.index:02d}: box, {size} (height last), at "
                f"{np.round(obj.box.cuboid.centre, 2).tolist()}, {len(obj.points)} points")
    if obj.status != "ok":
        return f"object {obj.index:02d}: {obj.status} ({obj.reason}); {len(obj.points)} points"
    margin = (obj.class_choice or {}).get("margin")
    margin_text = "" if margin is None else f" (margin {margin:.3f})"
    return (f"object {obj.index:02d}: {obj.model}{margin_text}, flag {obj.result.flag}, "
            f"scale {obj.result.transform.s:.3f}, at {np.round(obj.centre, 2).tolist()}, "
            f"{len(obj.points)} points")


def _report(result, out: Path) -> None:  # noqa: ANN001
    import numpy as np

    t = result.transform
    typer.echo(f"scale {t.s:.4f}  yaw θ {np.degrees(result.angles['theta']) % 360:.1f}°  "
               f"translation {np.round(t.t, 3).tolist()}")
    if "class" in result.info:
        choice = result.info["class"]
        margin = "" if choice["margin"] is None else f" (margin {choice['margin']:.4f} over the next)"
        final = choice.get("final")
        if final is not None and len(final["compared"]) > 1:
            margin = f" (by the final fits of {', '.join(final['compared'])}: margin {final['margin']:.4f})"
        typer.echo(f"class {choice['chosen']}{margin}")
    typer.echo(f"winner by {result.criterion['name']}: {result.criterion['value']:.4f}; "
               f"time {result.timing['total']:.1f} s")
    retry = result.info.get("float32_retry")
    if retry is not None:
        typer.echo(f"the bfloat16 fit was doubtful: fitted again in float32, kept the {retry['kept']} fit")
    if result.flag is not None:
        typer.echo(_quality_line(result.flag, result.quality))
    typer.echo(f"wrote {out}/fit.json, shape.ply, shape_canonical.ply, overlay.png")


def _quality_line(flag: str, quality: dict) -> str:
    """One line: the flag and the measures it rests on (docs/confidence.md)."""
    def number(key: str, text: str) -> str:
        value = quality.get(key)
        return f"{text} –" if value is None else f"{text} {value:.2f}"

    return (f"flag {flag}: " + number("inlier_share", "inliers") + ", "
            + number("free_space_violation", "free-space violation") + ", "
            + number("loss_margin_rel", "loss margin") + ", "
            + number("latent_mahalanobis_ratio", "code distance") + ", "
            + number("surface_coverage", "surface covered") + " (docs/confidence.md)")


@app.command("models")
def models_command(as_json: bool = typer.Option(False, "--json", help="Print JSON.")) -> None:
    """List the shipped models."""
    from jsrte.model.registry import describe_models

    rows = describe_models()
    if as_json:
        typer.echo(json.dumps(rows, indent=2))
        return
    if not rows:
        typer.echo("no shipped models")
    for r in rows:
        f = r["metrics"].get("train_fscore_mean")
        h = r["metrics"].get("heldout_fscore_mean")
        sizes = r["sizes_m"]
        sized = "" if sizes is None else f", radius {sizes['smallest']:.2f}-{sizes['largest']:.2f} m"
        student = r["distilled"]
        distilled = "" if student is None else f", distilled ({student['architecture']}, {student['size_kb']} KB)"
        typer.echo(f"{r['name']:8s} {r['category'] or '?':6s} {r['shapes']} shapes{sized}, latent {r['latent_size']}, "
                   f"{r['size_kb']} KB, F@5% train {f if f is not None else '-'} held-out "
                   f"{h if h is not None else '-'}{distilled}")
