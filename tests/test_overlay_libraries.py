"""A whole ``jsrte fit`` draws its overlay without OpenGL, pyrender or matplotlib.

The fit runs in a fresh interpreter (this test process may have imported anything) and reports
which of those libraries it loaded.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import trimesh
from PIL import Image

import jsrte

GL_AND_PLOTTING = ("pyrender", "OpenGL", "pyglet", "matplotlib")
SRC = str(Path(jsrte.__file__).resolve().parents[1])

# argv[1]: the command's arguments (JSON); argv[2]: the module names to look for (JSON).
PROBE = """
import json, sys
args, watched = json.loads(sys.argv[1]), json.loads(sys.argv[2])
sys.argv = ["jsrte", *args]
from jsrte.cli import main
code = 0
try:
    main()
except SystemExit as exc:
    code = exc.code or 0
print(json.dumps({"code": code, "loaded": [m for m in watched if m in sys.modules]}))
"""


def test_a_fit_writes_its_overlay_without_gl_or_matplotlib(tmp_path) -> None:
    from jsrte.scans.scanner import ScannerSettings, scan_mesh, write_scan

    box = trimesh.creation.box(extents=(0.6, 0.9, 0.5))
    scan = scan_mesh(box, rng=np.random.default_rng(0), settings=ScannerSettings(outlier_fraction=0.0))
    ply = write_scan(scan, tmp_path / "scan.ply", seed=0)
    out = tmp_path / "fit"
    args = ["fit", str(ply), "--preset", "smoke", "--hypotheses", "2", "--threads", "1", "--no-progress",
            "--out", str(out)]
    proc = subprocess.run([sys.executable, "-c", PROBE, json.dumps(args), json.dumps(GL_AND_PLOTTING)],
                          capture_output=True, text=True, env={"PYTHONPATH": SRC, "PATH": "/usr/bin:/bin"},
                          timeout=600, check=True)
    outcome = json.loads(proc.stdout.strip().splitlines()[-1])
    assert outcome == {"code": 0, "loaded": []}, proc.stderr[-2000:]
    with Image.open(out / "overlay.png") as image:
        rgb = np.asarray(image.convert("RGB"), dtype=np.int64)
    red = (rgb[..., 0] > 150) & (rgb[..., 1] < 80) & (rgb[..., 2] < 80)
    gray = (np.ptp(rgb, axis=2) < 10) & (rgb[..., 0] > 50) & (rgb[..., 0] < 230)
    assert red.sum() > 100 and gray.sum() > 1000  # the scan's points over the fitted mesh
