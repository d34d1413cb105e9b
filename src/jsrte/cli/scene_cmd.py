"""``jsrte scene``: a simulated depth scan of an object in a room (walls, other objects)."""

from __future__ import annotations

from pathlib import Path

import typer

from jsrte.cli import app
from jsrte.errors import JsrteError


@app.command("scene")
def scene(
    mesh: Path = typer.Argument(None, help="The object, canonical orientation (+y up, front -z); default: a "
                                           "held-out procedural shape of --category."),
    out: Path = typer.Option(..., "--out", help="Output folder (scan.ply, scan.json, scene.json, labels.npy, "
                                                "meshes/)."),
    category: str = typer.Option("chair", help="The object's class (recorded in scene.json; the shape drawn "
                                               "when no MESH is given)."),
    index: int = typer.Option(0, help="Evaluation-set index of the shape drawn when no MESH is given."),
    seed: int = typer.Option(0, help="Random seed (room, cameras, noise)."),
    walls: str = typer.Option("1,3", help="Number of walls 'LO,HI' (0 to 3)."),
    others: str = typer.Option("1,3", help="Number of other objects 'LO,HI'."),
    kinds: str = typer.Option("table,sofa,box", help="What the other objects may be: table, sofa, bed, "
                                                     "chair, box."),
    views: int = typer.Option(4, help="Number of depth images, on a level arc."),
    arc: float = typer.Option(90.0, help="Azimuth span of the cameras (degrees)."),
    noise: float = typer.Option(1.0, help="Multiplier of the Kinect-like depth noise."),
    overwrite: bool = typer.Option(False, "--overwrite", help="Replace an existing scene."),
) -> None:
    """Scan an object in a room: walls behind and beside it, other objects around it (one touching
    it), a short arc of views, depth noise, dropouts and flying pixels; writes the truth of
    every object."""
    from dataclasses import replace

    import numpy as np

    from jsrte.atomic import output_dir
    from jsrte.geometry.mesh import load_mesh
    from jsrte.scans.scene import SceneSettings, scan_room, write_room
    from jsrte.shapes import CATEGORIES, EVAL_SET_SEED, check_category, generate_shape, shape_seed

    check_category(category)
    known = CATEGORIES + ("box",)
    chosen = tuple(k.strip() for k in kinds.split(",") if k.strip())
    if not chosen or any(k not in known for k in chosen):
        raise JsrteError(f"--kinds must name some of {', '.join(known)}, got {kinds!r}")
    settings = SceneSettings()
    settings = replace(settings, walls=_count_range(walls, "walls", 3), others=_count_range(others, "others", 8),
                       other_kinds=chosen,
                       scanner=replace(settings.scanner, views=views, arc_deg=arc, noise_scale=noise))
    target = load_mesh(mesh) if mesh is not None else generate_shape(category, shape_seed(EVAL_SET_SEED, index)).mesh
    room = scan_room(target, rng=np.random.default_rng(seed), settings=settings, target_kind=category)
    with output_dir(out, overwrite=overwrite, marker="scene.json") as folder:
        write_room(room, folder, seed=seed)
    kinds_seen = ", ".join(o.kind for o in room.objects[1:]) or "nothing"
    typer.echo(f"wrote {out}/scan.ply ({len(room.scan.points)} points, {int(room.scan.is_object.sum())} on the "
               f"{category}; {len(room.walls)} wall(s); beside it: {kinds_seen}), scan.json, scene.json, labels.npy")


def _count_range(text: str, name: str, most: int) -> tuple[int, int]:
    try:
        lo, hi = (int(v) for v in text.split(","))
    except ValueError:
        raise JsrteError(f"--{name} must be two whole numbers 'LO,HI', got {text!r}") from None
    if not 0 <= lo <= hi <= most:
        raise JsrteError(f"--{name} must satisfy 0 <= LO <= HI <= {most}, got {text!r}")
    return lo, hi
