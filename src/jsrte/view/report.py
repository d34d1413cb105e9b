"""``jsrte report``: one self-contained HTML file, offline, with an interactive 3D view per fit.

The page holds everything: plotly.js (from the ``plotly`` package, gzip-compressed and
base64-inlined, unpacked by the browser's own ``DecompressionStream``: 1.5 MB instead of 4.8),
each fit's drawing data (decimated meshes, subsampled scan points coloured by distance to the
fitted surface, floor) and, for a batch, a summary table with each fit's overlay thumbnail
(downscaled PNG, base64). One 3D view shows the selected fit; the table's rows, the
previous/next buttons and the arrow keys select. Nothing is fetched from the network.

Display detail shrinks with the number of fits so that 30 fits stay under 5 MB.
"""

from __future__ import annotations

import base64
import gzip
import html
import io
import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from jsrte.errors import JsrteError
from jsrte.view.display import coloured_scan, decimated
from jsrte.view.loading import FitItem

REPORT_NAME = "report.html"
THUMBNAIL_WIDTH = 280
"""Pixels across a summary-table thumbnail."""
DATA_BUDGET = 2_400_000
"""Bytes of drawing data (meshes and points) for the whole report, shared among the fits."""
MESH_COLOUR = "rgb(240,140,60)"
TRUTH_COLOUR = "rgb(60,190,90)"


@dataclass(frozen=True)
class Detail:
    """How much of each fit is drawn: triangles of the retrieved and true meshes, scan points."""

    mesh_faces: int
    truth_faces: int
    points: int

    @staticmethod
    def for_fits(n: int) -> Detail:
        """Within :data:`DATA_BUDGET` for ``n`` fits (~26 bytes a triangle, ~22 a point in base64)."""
        per_fit = DATA_BUDGET / max(n, 1)
        mesh = int(np.clip(per_fit * 0.4 / 26, 400, 20_000))
        return Detail(mesh_faces=mesh, truth_faces=mesh // 2, points=int(np.clip(per_fit * 0.35 / 22, 500, 8_000)))


def write_report(items: list[FitItem], out: str | Path, *, title: str, overwrite: bool = False,
                 thumbnails: dict[str, bytes] | None = None) -> int:
    """Write the report of ``items`` to ``out`` (atomically); returns its size in bytes.

    ``thumbnails`` maps an item's name to PNG bytes, for items without an overlay.png (the
    experiments' in-memory results). Refuses an existing ``out`` unless ``overwrite``.
    """
    from jsrte.atomic import write_bytes_atomic

    out = Path(out)
    if out.is_dir():
        raise JsrteError("is a folder; give a file name such as report.html", out)
    if out.exists() and not overwrite:
        raise JsrteError("already exists; pass --overwrite to replace it", out)
    data = render_report(items, title=title, thumbnails=thumbnails).encode()
    write_bytes_atomic(out, data)
    return len(data)


def write_batch_report(folder: str | Path, *, say: Any = print) -> Path | None:
    """``folder/report.html`` for the fits of a ``fit-many`` output (replacing that command's own
    earlier report); None, and nothing written, when no fit there can be read."""
    from jsrte.view.loading import find_fits, load_items

    folder = Path(folder)
    try:
        items = load_items(find_fits(folder))
    except JsrteError:
        return None
    out = folder / REPORT_NAME
    size = write_report(items, out, title=f"jsrte fit-many: {folder.resolve().name}", overwrite=True)
    say(f"wrote {out} ({size / 1e6:.2f} MB)")
    return out


def overlay_png(mesh: Any, points: np.ndarray, up: np.ndarray | None) -> bytes:
    """A small two-view overlay (PNG bytes) of ``mesh`` and ``points`` (n, 3), for a thumbnail."""
    import tempfile

    from jsrte.viz import render_overlay

    with tempfile.TemporaryDirectory(prefix="jsrte-thumbnail-") as tmp:
        path = Path(tmp) / "overlay.png"
        render_overlay(mesh, points, path, up=(0.0, 1.0, 0.0) if up is None else tuple(np.asarray(up, float)),
                       views=2, size=(320, 240))
        return path.read_bytes()


def render_report(items: list[FitItem], *, title: str, thumbnails: dict[str, bytes] | None = None) -> str:
    """The report page of ``items`` as one HTML string."""
    detail = Detail.for_fits(len(items))
    fits = [_fit_data(item, detail) for item in items]
    thumbs = {item.name: _thumbnail(item, (thumbnails or {}).get(item.name)) for item in items}
    rows = "\n".join(_table_row(i, item, thumbs[item.name]) for i, item in enumerate(items))
    problems = sum(bool(item.problems) for item in items)
    summary = (f"{len(items)} fit{'s' * (len(items) != 1)}" + (f", {problems} with something missing"
                                                                if problems else ""))
    page = _PAGE.format(
        title=html.escape(title), summary=html.escape(summary), rows=rows,
        data=json.dumps({"fits": fits}).replace("</", "<\\/"),
        plotly=_plotly_gzip_base64(), script=_SCRIPT, style=_STYLE,
        table_class="" if len(items) > 1 else "single")
    return page


# -- drawing data -------------------------------------------------------------------------------

def _fit_data(item: FitItem, detail: Detail) -> dict[str, Any]:
    """One fit's plotly.js traces (arrays as base64 typed arrays), camera and numbers."""
    traces = []
    if item.mesh is not None:
        traces.append(_mesh_trace(decimated(item.mesh, detail.mesh_faces), "retrieved mesh", MESH_COLOUR, 1.0))
    if item.truth is not None:
        traces.append(_mesh_trace(decimated(item.truth, detail.truth_faces), "true mesh", TRUTH_COLOUR, 0.35))
    if item.scan is not None:
        traces.append(_points_trace(item, detail.points))
    centre, radius = _extent(item)
    if item.floor is not None:
        traces.append(_floor_trace(item, centre, radius))
    up = item.up if item.up is not None else np.array([0.0, 1.0, 0.0])
    return {"name": item.name, "traces": traces, "up": [float(x) for x in up],
            "eye": [float(x) for x in _eye_direction(up)], "numbers": item.numbers, "problems": item.problems}


def _typed(array: np.ndarray) -> dict[str, str]:
    """An array as plotly.js's base64 typed-array form (float32, or the smallest unsigned integer)."""
    array = np.asarray(array)
    if array.dtype.kind == "f":
        array, dtype = array.astype("<f4"), "f4"
    else:
        array, dtype = (array.astype("<u2"), "u2") if array.max(initial=0) < 65_536 else (array.astype("<u4"), "u4")
    return {"dtype": dtype, "bdata": base64.b64encode(np.ascontiguousarray(array).tobytes()).decode()}


def _mesh_trace(mesh: Any, name: str, colour: str, opacity: float) -> dict[str, Any]:
    v, f = np.asarray(mesh.vertices), np.asarray(mesh.faces)
    return {"type": "mesh3d", "name": name, "x": _typed(v[:, 0]), "y": _typed(v[:, 1]), "z": _typed(v[:, 2]),
            "i": _typed(f[:, 0]), "j": _typed(f[:, 1]), "k": _typed(f[:, 2]), "color": colour, "opacity": opacity,
            "flatshading": False, "showlegend": True, "hoverinfo": "skip",
            "lighting": {"ambient": 0.5, "diffuse": 0.9, "specular": 0.15, "roughness": 0.6},
            "lightposition": {"x": 1000, "y": 2000, "z": 3000}}


def _points_trace(item: FitItem, max_points: int) -> dict[str, Any]:
    points = coloured_scan(item.scan, item.mesh, max_points)
    p = points.points
    if item.mesh is None:
        marker: dict[str, Any] = {"size": 1.6, "color": "rgb(150,150,150)"}
    else:
        marker = {"size": 1.6, "color": _typed(points.distances * 100), "cmin": 0.0, "cmax": float(points.far * 100),
                  "colorscale": [[0, "rgb(40,90,220)"], [0.5, "rgb(250,200,40)"], [1, "rgb(220,40,40)"]],
                  "colorbar": {"title": {"text": "cm to surface"}, "thickness": 12, "len": 0.5}}
    return {"type": "scatter3d", "mode": "markers", "name": "scan points", "x": _typed(p[:, 0]),
            "y": _typed(p[:, 1]), "z": _typed(p[:, 2]), "marker": marker, "hoverinfo": "skip"}


def _floor_trace(item: FitItem, centre: np.ndarray, radius: float) -> dict[str, Any]:
    """The floor as a square of side 4 radii under the object."""
    normal = item.floor.normal
    a = np.cross(normal, [1.0, 0.0, 0.0] if abs(normal[0]) < 0.9 else [0.0, 0.0, 1.0])
    a /= np.linalg.norm(a)
    b = np.cross(normal, a)
    on_floor = centre - (centre @ normal - item.floor.offset) * normal
    corners = np.array([on_floor + 2 * radius * (sa * a + sb * b) for sa, sb in ((-1, -1), (1, -1), (1, 1), (-1, 1))])
    return {"type": "mesh3d", "name": "floor", "x": corners[:, 0].tolist(), "y": corners[:, 1].tolist(),
            "z": corners[:, 2].tolist(), "i": [0, 0], "j": [1, 2], "k": [2, 3], "color": "rgb(200,200,200)",
            "opacity": 0.35, "showlegend": True, "hoverinfo": "skip"}


def _extent(item: FitItem) -> tuple[np.ndarray, float]:
    from jsrte.view.server import _extent as extent

    return extent(item)


def _eye_direction(up: np.ndarray) -> np.ndarray:
    """Unit direction from the object to the camera: 30° above the floor."""
    side = np.cross(up, [1.0, 0.0, 0.0] if abs(up[0]) < 0.9 else [0.0, 0.0, 1.0])
    side /= np.linalg.norm(side)
    return np.cos(np.radians(30)) * side + np.sin(np.radians(30)) * up


# -- page parts -------------------------------------------------------------------------------------

def _thumbnail(item: FitItem, png: bytes | None) -> str | None:
    """A data: URL of the fit's overlay (or ``png``), downscaled to :data:`THUMBNAIL_WIDTH`; None if none."""
    from PIL import Image, UnidentifiedImageError

    if png is None and item.overlay is None:
        return None
    try:
        with Image.open(io.BytesIO(png) if png is not None else item.overlay) as image:
            image = image.convert("RGB")
            image.thumbnail((THUMBNAIL_WIDTH, THUMBNAIL_WIDTH))
            buffer = io.BytesIO()
            image.quantize(colors=128).save(buffer, format="PNG", optimize=True)
    except (OSError, UnidentifiedImageError, ValueError):
        item.problems.append(f"{item.overlay}: not a readable PNG; no thumbnail")
        return None
    return "data:image/png;base64," + base64.b64encode(buffer.getvalue()).decode()


def _table_row(index: int, item: FitItem, thumbnail: str | None) -> str:
    image = (f'<img src="{thumbnail}" alt="overlay of {html.escape(item.name)}">' if thumbnail
             else '<span class="none">no overlay</span>')
    problems = "".join(f"<div class=\"problem\">missing: {html.escape(p)}</div>" for p in item.problems)
    numbers = "".join(f"<tr><th>{html.escape(k)}</th><td>{html.escape(v)}</td></tr>" for k, v in item.numbers.items())
    return (f'<tr data-index="{index}"><td>{image}</td><td class="name">{html.escape(item.name)}{problems}</td>'
            f'<td class="numbers"><table>{numbers}</table></td></tr>')


_PLOTLY_CACHE: dict[str, str] = {}


def _plotly_gzip_base64() -> str:
    """plotly.js of the installed ``plotly`` package, gzip-compressed, base64 (cached per process)."""
    if "js" not in _PLOTLY_CACHE:
        from plotly.offline import get_plotlyjs

        _PLOTLY_CACHE["js"] = base64.b64encode(gzip.compress(get_plotlyjs().encode(), 6, mtime=0)).decode()
    return _PLOTLY_CACHE["js"]


_STYLE = """
body { font-family: system-ui, sans-serif; margin: 16px; color: #222; }
h1 { font-size: 20px; margin: 0 0 4px 0; }
#top { display: flex; gap: 16px; align-items: stretch; }
#plot { flex: 1 1 auto; height: 560px; min-width: 400px; border: 1px solid #ddd; }
#side { flex: 0 0 260px; font-size: 14px; }
#side table { border-collapse: collapse; } #side th { text-align: left; padding-right: 12px; font-weight: 600; }
button { margin: 4px 4px 8px 0; padding: 4px 10px; }
#fits { border-collapse: collapse; margin-top: 16px; font-size: 13px; }
#fits > tbody > tr { border-top: 1px solid #ddd; cursor: pointer; }
#fits > tbody > tr:hover { background: #f4f4f4; } #fits > tbody > tr.selected { background: #e6efff; }
#fits td { padding: 4px 10px; vertical-align: top; } #fits img { width: 280px; display: block; }
#fits td.numbers th { text-align: left; font-weight: 600; padding-right: 10px; }
#fits.single { display: none; }
.problem { color: #a00; font-size: 12px; max-width: 360px; } .none { color: #888; }
"""

_SCRIPT = """
(function () {
  const data = JSON.parse(document.getElementById('jsrte-data').textContent);
  let current = -1;
  async function loadPlotly() {
    const text = document.getElementById('plotly-gz').textContent;
    const bytes = Uint8Array.from(atob(text), function (c) { return c.charCodeAt(0); });
    const stream = new Blob([bytes]).stream().pipeThrough(new DecompressionStream('gzip'));
    const code = await new Response(stream).text();
    const script = document.createElement('script');
    script.textContent = code;
    document.head.appendChild(script);
  }
  function escapeHtml(s) {
    return String(s).replace(/[&<>"]/g, function (c) {
      return {'&': '&amp;', '<': '&lt;', '>': '&gt;', '"': '&quot;'}[c];
    });
  }
  function show(index) {
    const n = data.fits.length;
    index = ((index % n) + n) % n;
    const fit = data.fits[index];
    const eye = fit.eye.map(function (x) { return 1.7 * x; });
    const layout = {
      margin: {l: 0, r: 0, t: 0, b: 0}, showlegend: true, legend: {x: 0, y: 1},
      uirevision: String(index),
      scene: {aspectmode: 'data',
              xaxis: {visible: false}, yaxis: {visible: false}, zaxis: {visible: false},
              camera: {up: {x: fit.up[0], y: fit.up[1], z: fit.up[2]},
                       eye: {x: eye[0], y: eye[1], z: eye[2]}}}
    };
    Plotly.react('plot', fit.traces, layout, {displaylogo: false, responsive: true});
    let rows = '';
    for (const key in fit.numbers) {
      rows += '<tr><th>' + escapeHtml(key) + '</th><td>' + escapeHtml(fit.numbers[key]) + '</td></tr>';
    }
    let problems = fit.problems.map(function (p) {
      return '<div class="problem">missing: ' + escapeHtml(p) + '</div>';
    }).join('');
    document.getElementById('fit-name').textContent = fit.name + ' (' + (index + 1) + ' of ' + n + ')';
    document.getElementById('fit-numbers').innerHTML = '<table>' + rows + '</table>' + problems;
    document.querySelectorAll('#fits > tbody > tr').forEach(function (tr) {
      tr.classList.toggle('selected', Number(tr.dataset.index) === index);
    });
    current = index;
  }
  document.getElementById('previous').onclick = function () { show(current - 1); };
  document.getElementById('next').onclick = function () { show(current + 1); };
  document.addEventListener('keydown', function (e) {
    if (e.key === 'ArrowLeft') show(current - 1);
    if (e.key === 'ArrowRight') show(current + 1);
  });
  document.querySelectorAll('#fits > tbody > tr').forEach(function (tr) {
    tr.onclick = function () { show(Number(tr.dataset.index)); window.scrollTo({top: 0}); };
  });
  loadPlotly().then(function () {
    show(0);
    document.body.dataset.ready = '1';
  });
})();
"""

_PAGE = """<!doctype html>
<html lang="en">
<head>
<meta charset="utf-8">
<meta name="generator" content="jsrte report">
<title>{title}</title>
<style>{style}</style>
</head>
<body>
<h1>{title}</h1>
<p>{summary}. Drag to turn, scroll to zoom; click a legend entry to hide a layer. Scan points are coloured by
their distance to the retrieved surface.</p>
<div id="top">
<div id="plot"></div>
<div id="side">
<button id="previous">&larr; previous</button><button id="next">next &rarr;</button>
<h2 id="fit-name" style="font-size:16px"></h2>
<div id="fit-numbers"></div>
</div>
</div>
<table id="fits" class="{table_class}">
<thead><tr><th>overlay</th><th>fit</th><th>numbers</th></tr></thead>
<tbody>
{rows}
</tbody>
</table>
<script id="jsrte-data" type="application/json">{data}</script>
<script id="plotly-gz" type="application/octet-stream">{plotly}</script>
<script>{script}</script>
</body>
</html>
"""
