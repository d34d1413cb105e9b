"""``jsrte scan``: a simulated depth scan of a mesh standing on a floor."""

from __future__ import annotations

from pathlib import Path

import typer

from jsrte.cli import app
from jsrte.cli.common import check_out_file
from jsrte.errors import JsrteError


def _range(text: str, name: str) -> tuple[float, float]:
    try:
        lo, hi = (float(v) for v in text.split(","))
    except ValueError:
        raise JsrteError(f"--{name} must be two numbers 'LO,HI', got {text!r}") from None
    if not 0 < lo <= hi:
        raise JsrteError(f"--{name} must satisfy 0 < LO <= HI, got {text!r}")
    return lo, hi


@app.command("scan")
def scan(
    mesh: Path = typer.Argument(..., help="Mesh in canonical orientation (+y up, front -z)."),
    out: Path = typer.Option(..., "--out", help="Output point cloud SCAN.ply (SCAN.json beside)."),
    seed: int = typer.Option(0, help="Random seed (pose, cameras, noise)."),
    views: int = typer.Option(3, help="Number of depth images."),
    arc: float = typer.Option(120.0, help="Azimuth span of the cameras (degrees)."),
    noise: float = typer.Option(1.0, help="Multiplier of the Kinect-like depth noise."),
    width: int = typer.Option(160, help="Image width (pixels)."),
    height: int = typer.Option(120, help="Image height (pixels)."),
    no_floor: bool = typer.Option(False, "--no-floor", help="Scan the object without a floor."),
    world_up_y: bool = typer.Option(
        False, "--world-up-y", help="Keep +y up with the floor at y = 0 (no random world frame)."),
    height_range: str = typer.Option("0.6,1.2", help="Object height range in metres 'LO,HI'."),
    overwrite: bool = typer.Option(False, "--overwrite", help="Replace an existing scan."),
) -> None:
    """Scan MESH with a virtual depth camera: the object stands on a floor in a random pose."""
    import numpy as np

    from jsrte.geometry.mesh import load_mesh
    from jsrte.scans.scanner import ScannerSettings, scan_mesh, write_scan

    if out.suffix.lower() != ".ply":
        raise JsrteError("the scan is written as PLY: give --out a .ply name", out)
    check_out_file(out, overwrite=overwrite)
    settings = ScannerSettings(
        target_height_m=_range(height_range, "height-range"), views=views, arc_deg=arc,
        noise_scale=noise, width=width, height=height, floor=not no_floor,
        random_world_frame=not world_up_y,
    )
    result = scan_mesh(load_mesh(mesh), rng=np.random.default_rng(seed), settings=settings)
    write_scan(result, out, seed=seed, mesh=mesh)
    typer.echo(f"wrote {out} ({len(result.points)} points, {int(result.is_object.sum())} on the "
               f"object) and {out.with_suffix('.json')}")
