"""The command line starts without the heavy libraries: they load only in the commands that run.

Each check runs in a fresh interpreter (this test process has long imported everything).
"""

import json
import subprocess
import sys
from pathlib import Path

import pytest

import jsrte

HEAVY = ("torch", "open3d", "matplotlib", "pyrender", "ray", "trimesh", "scipy", "skimage")
SRC = str(Path(jsrte.__file__).resolve().parents[1])

ENV = {"PYTHONPATH": SRC, "PATH": "/usr/bin:/bin"}

# argv[1]: the command's arguments (JSON); argv[2]: the module names to look for (JSON).
PROBE = """
import json, sys
args, heavy = json.loads(sys.argv[1]), json.loads(sys.argv[2])
sys.argv = ["jsrte", *args]
from jsrte.cli import main
code = 0
try:
    main()
except SystemExit as exc:
    code = exc.code or 0
print(json.dumps({"code": code, "heavy": [m for m in heavy if m in sys.modules]}))
"""


def _loaded_after(args: list[str], watched: tuple[str, ...] = HEAVY) -> dict:
    """Run ``jsrte ARGS`` in a new interpreter: {"code": exit status, "heavy": the ``watched``
    modules it imported}."""
    proc = subprocess.run([sys.executable, "-c", PROBE, json.dumps(args), json.dumps(watched)], capture_output=True,
                          text=True, env=ENV, timeout=120, check=True)
    return json.loads(proc.stdout.strip().splitlines()[-1])


@pytest.mark.parametrize("args", [["--help"], ["fit", "--help"], ["train", "--help"], ["sample", "--help"],
                                  ["experiment", "scans", "--help"], ["version"]])
def test_help_imports_no_heavy_library(args) -> None:
    outcome = _loaded_after(args)
    assert outcome["code"] == 0
    assert outcome["heavy"] == []


EVERY_HELP = """
import json, sys
import typer
from jsrte.cli import _register, app
_register()

def paths(command, prefix):
    if hasattr(command, "commands"):  # a group
        for name, sub in command.commands.items():
            yield from paths(sub, prefix + [name])
    else:
        yield prefix

group = typer.main.get_command(app)
shown = []
for path in paths(group, []):
    try:
        group.main(path + ["--help"], prog_name="jsrte", standalone_mode=False)
    except SystemExit:
        pass
    shown.append(" ".join(path))
print(json.dumps({"commands": shown, "heavy": [m for m in json.loads(sys.argv[1]) if m in sys.modules]}))
"""


def test_every_command_help_imports_no_heavy_library() -> None:
    """Whatever commands the app has (new ones included), their --help stays light."""
    proc = subprocess.run([sys.executable, "-c", EVERY_HELP, json.dumps(HEAVY)], capture_output=True, text=True,
                          env=ENV, timeout=120, check=True)
    outcome = json.loads(proc.stdout.strip().splitlines()[-1])
    assert {"fit", "train", "demo", "experiment scans"} <= set(outcome["commands"])
    assert outcome["heavy"] == []


def test_import_jsrte_is_light() -> None:
    probe = f"import sys, jsrte; print([m for m in {HEAVY!r} if m in sys.modules])"
    proc = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True,
                          env=ENV, timeout=120, check=True)
    assert proc.stdout.strip() == "[]"


def test_a_running_command_does_load_torch() -> None:
    """The probe sees imports: a command that needs PyTorch (set_threads) does import it."""
    probe = ("import sys; from jsrte.cli.common import set_threads; set_threads(1); "
             "print('torch' in sys.modules)")
    proc = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True,
                          env=ENV, timeout=120, check=True)
    assert proc.stdout.strip() == "True"


@pytest.fixture(scope="module")
def bare_scan(tmp_path_factory) -> Path:
    """A small virtual scan of a stand-in chair as bare points in a PLY file (no normals, no
    cameras: the fit estimates normals and orients them by hidden point removal)."""
    import numpy as np
    from plyfile import PlyData, PlyElement

    from jsrte.scans.scanner import ScannerSettings, scan_mesh
    from test_scans import stand_in_chair

    folder = tmp_path_factory.mktemp("scans")
    settings = ScannerSettings(width=80, height=60)
    scan = scan_mesh(stand_in_chair(), rng=np.random.default_rng(0), settings=settings)
    vertex = np.zeros(len(scan.points), dtype=[("x", "f4"), ("y", "f4"), ("z", "f4")])
    for i, axis in enumerate("xyz"):
        vertex[axis] = scan.points[:, i]
    bare = folder / "bare.ply"
    PlyData([PlyElement.describe(vertex, "vertex")]).write(str(bare))
    return bare


def test_fitting_a_ply_scan_imports_neither_open3d_nor_gl(bare_scan, tmp_path) -> None:
    """Reading the PLY, the floor, segmentation (DBSCAN), outlier and hidden point removal and
    normals run without Open3D (its import is about half a second of a fit's start-up), and the
    overlay is drawn without pyrender, OpenGL or matplotlib: the scan's red points over the
    gray fitted mesh."""
    import numpy as np
    from PIL import Image

    out = tmp_path / "fit"
    outcome = _loaded_after(["fit", str(bare_scan), "--preset", "smoke", "--hypotheses", "1",
                             "--threads", "1", "--no-progress", "--out", str(out)],
                            watched=(*HEAVY, "OpenGL", "pyglet"))
    assert outcome["code"] == 0
    assert (out / "fit.json").is_file()
    assert "torch" in outcome["heavy"]
    assert not {"open3d", "pyrender", "OpenGL", "pyglet", "matplotlib"} & set(outcome["heavy"])
    with Image.open(out / "overlay.png") as image:
        rgb = np.asarray(image.convert("RGB"), dtype=np.int64)
    red = (rgb[..., 0] > 150) & (rgb[..., 1] < 80) & (rgb[..., 2] < 80)
    gray = (np.ptp(rgb, axis=2) < 10) & (rgb[..., 0] > 50) & (rgb[..., 0] < 230)
    assert red.sum() > 100 and gray.sum() > 1000
