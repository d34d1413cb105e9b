"""jsrte view / jsrte report without a browser: loading fit folders, batches and scenes, bad input,
distance colouring, the report's contents and size, the viewer's server and its port checks."""

import base64
import gzip
import json
import re
import shutil
import signal
import socket
import subprocess
import sys
import threading
import urllib.request
from pathlib import Path

import numpy as np
import pytest
import trimesh

from jsrte.errors import JsrteError
from jsrte.view.display import colour_by_distance, coloured_scan, decimated, distance_to_surface
from jsrte.view.loading import find_fits, load_item, load_items
from view_fixtures import RADIUS, make_batch, make_fit, make_scan, sphere_points

SRC = Path(__file__).resolve().parents[1] / "src"


@pytest.fixture
def fit_folder(tmp_path):
    scan = make_scan(tmp_path / "scans", "chair")
    return make_fit(tmp_path / "fit", scan)


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


# -- loading ------------------------------------------------------------------------------------

def test_fit_folder_loads_mesh_scan_truth_floor_poses_and_numbers(fit_folder):
    collection = find_fits(fit_folder)
    assert collection.kind == "fit" and [e.name for e in collection.entries] == ["fit"]
    item = load_item(collection.entries[0])
    assert item.problems == []
    assert item.scan.shape == (2300, 3)
    assert np.allclose(item.mesh.bounds.mean(axis=0), [0, RADIUS, 0], atol=1e-6)
    assert np.allclose(item.truth.bounds, item.mesh.bounds, atol=1e-6)  # true pose applied to the unit sphere
    assert np.allclose(item.floor.normal, [0, 1, 0]) and item.floor.offset == 0.0
    assert [p.winner for p in item.poses] == [True, False]  # hypothesis 0 is the winner, 2 has no pose
    assert item.poses[1].scale == 0.4
    assert item.numbers["scale"] == "0.5000" and item.numbers["yaw"] == "90.0°" and item.numbers["loss"] == "0.0123"
    assert item.numbers["class"] == "chair" and item.numbers["winner"] == "hypothesis 0 of 3"
    assert float(item.numbers["F@5%"]) > 0.7  # the fitted sphere is the true one


def test_fscore_against_the_truth_drops_for_a_displaced_mesh(tmp_path):
    scan = make_scan(tmp_path / "scans", "chair")
    item = load_item(find_fits(make_fit(tmp_path / "fit", scan, offset=4 * RADIUS)).entries[0])
    assert float(item.numbers["F@5%"]) == 0.0


def test_relative_scan_path_is_found_beside_the_fit_folders(tmp_path, monkeypatch):
    make_scan(tmp_path / "scans", "chair")
    folder = make_fit(tmp_path / "out" / "chair", None, input_text="scans/chair.ply")
    monkeypatch.chdir(tmp_path / "out")  # not where fit-many ran: found from the folders above the fit
    item = load_item(find_fits(folder).entries[0])
    assert item.scan is not None and item.truth is not None and item.problems == []


def test_batch_and_scene_layouts(tmp_path):
    out = make_batch(tmp_path, 3)
    batch = find_fits(out)
    assert batch.kind == "batch" and [e.name for e in batch.entries] == ["s0", "s1", "s2"]
    scene = tmp_path / "scene"
    (scene / "objects").mkdir(parents=True)
    (scene / "scene.json").write_text("{}")
    for i in (1, 0):
        shutil.copytree(out / f"s{i}", scene / "objects" / f"{i:02d}")
    found = find_fits(scene)
    assert found.kind == "scene" and [e.name for e in found.entries] == ["00", "01"]


def test_a_scenes_boxes_are_shown_as_their_cuboids(tmp_path):
    """A scene's boxes (scene.json objects of status box) are items beside its fits: the cuboid
    as the mesh, the scene's scan and floor; a box whose cuboid is unreadable is named."""
    scan = make_scan(tmp_path / "scans", "chair")
    scene = tmp_path / "scene"
    scene.mkdir()
    turn = trimesh.transformations.rotation_matrix(0.4, [0, 1, 0])[:3, :3]
    box = {"index": 1, "status": "box", "class": "box", "points": 900, "box_evidence": {"seen_through": 0.02},
           "cuboid": {"centre": [2.0, 0.25, 1.0], "axes": turn.T.tolist(), "extents": [0.6, 0.4, 0.5]}}
    broken = {"index": 2, "status": "box", "cuboid": {"centre": [0, 0, 0], "axes": turn.T.tolist(),
                                                      "extents": [0.6, -1, 0.5]}}
    record = {"input": str(scan), "floor": {"up": [0, 1, 0], "offset": 0.0},
              "objects": [{"index": 0, "status": "unexplained"}, box, broken]}
    unseen_floor = dict(box, index=3, box_evidence={"seen_through": None, "floor_seen_under": 0.04})
    record["objects"].append(unseen_floor)  # told without cameras: by the floor hidden under it
    (scene / "scene.json").write_text(json.dumps(record))
    found = find_fits(scene)  # no fitted object: the boxes alone make it a scene
    assert found.kind == "scene" and [e.name for e in found.entries] == ["01", "02", "03"]
    item = load_item(found.entries[0])
    assert item.fit_read and item.problems == [] and item.scan is not None
    assert item.mesh.volume == pytest.approx(0.6 * 0.4 * 0.5)
    assert np.allclose(item.mesh.bounds.mean(axis=0), [2.0, 0.25, 1.0])
    assert np.allclose(item.floor.normal, [0, 1, 0]) and item.numbers["class"] == "box"
    assert item.numbers["size (m)"] == "0.60 × 0.40 × 0.50" and item.numbers["seen through"] == "0.020 per point"
    told_by_floor = load_item(found.entries[2]).numbers
    assert "seen through" not in told_by_floor and told_by_floor["floor seen under"] == "0.04 of its footprint"
    bad = load_item(found.entries[1])
    assert not bad.fit_read and "box 02 is not readable" in bad.problems[0]


def test_folder_without_a_fit_is_a_one_line_error(tmp_path):
    (tmp_path / "empty" / "sub").mkdir(parents=True)
    with pytest.raises(JsrteError, match="empty: holds no fit"):
        find_fits(tmp_path / "empty")
    (tmp_path / "scene").mkdir()
    (tmp_path / "scene" / "scene.json").write_text("{}")  # a scene without objects is no fit either
    with pytest.raises(JsrteError, match="holds no fit"):
        find_fits(tmp_path / "scene")
    with pytest.raises(JsrteError, match="no such file or folder"):
        find_fits(tmp_path / "nothing")


def test_corrupt_and_missing_meshes_are_named_and_the_rest_still_loads(tmp_path):
    out = make_batch(tmp_path, 3)
    (out / "s0" / "shape.ply").write_bytes(b"ply\nformat nonsense\n")
    (out / "s1" / "shape.ply").unlink()
    items = load_items(find_fits(out))
    assert items[0].mesh is None and "s0/shape.ply" in items[0].problems[0]
    assert items[1].mesh is None and "s1/shape.ply: missing" in items[1].problems[0]
    assert items[2].mesh is not None and items[2].problems == []
    assert all(i.scan is not None for i in items)  # the scans are still shown
    assert all("\n" not in p for i in items for p in i.problems)


def test_unreadable_fit_json_in_a_batch_is_one_missing_item(tmp_path):
    out = make_batch(tmp_path, 2)
    (out / "s1" / "fit.json").write_text("{not json")
    items = load_items(find_fits(out))
    assert items[0].fit_read and not items[1].fit_read and "s1/fit.json: not a readable fit" in items[1].problems[0]
    (out / "s0" / "fit.json").write_text("[]")
    with pytest.raises(JsrteError, match="no fit could be read"):
        load_items(find_fits(out))


# -- display -------------------------------------------------------------------------------------

def test_distance_to_surface_of_a_sphere():
    sphere = trimesh.creation.icosphere(subdivisions=4, radius=1.0)
    points = np.vstack([sphere_points(200, np.zeros(3), 1.0), sphere_points(200, np.zeros(3), 1.3)])
    d = distance_to_surface(points, sphere)
    exact = trimesh.proximity.closest_point(sphere, points)[1]
    assert np.all(d >= exact - 1e-9) and np.all(d - exact < 1.5 * np.sqrt(sphere.area / 30_000))
    assert np.mean(d - exact < 1e-6) > 0.95 and np.allclose(exact[200:], 0.3, atol=0.003)


def test_colours_run_blue_yellow_red_and_points_are_coloured_by_their_distance():
    c = colour_by_distance(np.array([0.0, 0.5, 1.0, 3.0]), far=1.0)
    assert c[0].tolist() == [40, 90, 220] and c[1].tolist() == [250, 200, 40]
    assert c[2].tolist() == c[3].tolist() == [220, 40, 40]
    sphere = trimesh.creation.icosphere(subdivisions=3, radius=1.0)
    scan = np.vstack([sphere_points(100, np.zeros(3), 1.0), sphere_points(100, np.zeros(3), 2.0)])
    coloured = coloured_scan(scan, sphere, max_points=1000)
    assert np.all(coloured.colours[:100, 2] > 150) and np.all(coloured.colours[100:, 0] == 220)


def test_decimation_keeps_the_shape_with_fewer_faces():
    sphere = trimesh.creation.icosphere(subdivisions=5, radius=1.0)
    small = decimated(sphere, 2000)
    assert len(small.faces) <= 2100 and len(sphere.faces) == 20480
    assert np.allclose(np.linalg.norm(small.vertices, axis=1), 1.0, atol=0.03)


# -- report ---------------------------------------------------------------------------------------

def _report_data(text: str) -> dict:
    return json.loads(re.search(r'<script id="jsrte-data" type="application/json">(.*?)</script>', text, re.S)[1])


def test_report_is_self_contained_and_holds_every_fit(tmp_path, run_cli):
    out = make_batch(tmp_path, 3)
    (out / "s1" / "shape.ply").unlink()
    code, stdout, stderr = run_cli(["report", out, "--out", tmp_path / "report.html"])
    assert code == 0, stderr
    assert "wrote" in stdout and "s1/shape.ply: missing" in stderr
    text = (tmp_path / "report.html").read_text()
    assert not re.search(r"<script[^>]+src=|<link[^>]+href=|https?://(?!www\.w3\.org)", text.split("plotly-gz")[0])
    plotly_js = gzip.decompress(base64.b64decode(re.search(r'id="plotly-gz"[^>]*>(.*?)</script>', text, re.S)[1]))
    assert b"plotly.js" in plotly_js[:300] and len(plotly_js) > 3_000_000  # the whole library, inlined
    fits = _report_data(text)["fits"]
    assert [f["name"] for f in fits] == ["s0", "s1", "s2"]
    assert [t["name"] for t in fits[0]["traces"]] == ["retrieved mesh", "true mesh", "scan points", "floor"]
    assert [t["name"] for t in fits[1]["traces"]] == ["true mesh", "scan points", "floor"]  # its mesh: missing
    assert "missing: " in text and text.count('src="data:image/png;base64,') == 3  # thumbnails


def test_report_of_twenty_fits_stays_under_5_mb(tmp_path):
    from jsrte.view.report import write_report

    items = load_items(find_fits(make_fit(tmp_path / "fit", make_scan(tmp_path / "scans", "c"))))
    big = trimesh.creation.icosphere(subdivisions=5, radius=RADIUS)  # 20k faces, decimated for display
    big.apply_translation([0, RADIUS, 0])
    many = []
    for i in range(20):
        item = load_item(find_fits(tmp_path / "fit").entries[0])
        item.name, item.mesh, item.truth = f"fit{i}", big, big
        item.scan = np.vstack([item.scan] * 40)  # 92k points, subsampled for display
        many.append(item)
    size = write_report(many, tmp_path / "r.html", title="twenty")
    assert size == (tmp_path / "r.html").stat().st_size < 5_000_000
    assert len(items) == 1


def test_fit_many_output_gets_its_report_beside_summary_csv(tmp_path):
    from jsrte.view.report import write_batch_report

    out = make_batch(tmp_path, 2)
    lines = []
    assert write_batch_report(out, say=lines.append) == out / "report.html"
    assert [f["name"] for f in _report_data((out / "report.html").read_text())["fits"]] == ["s0", "s1"]
    assert lines == [f"wrote {out / 'report.html'} ({(out / 'report.html').stat().st_size / 1e6:.2f} MB)"]
    assert write_batch_report(tmp_path / "scans") is None  # no fit there: nothing written
    assert not (tmp_path / "scans" / "report.html").exists()


def test_report_refuses_to_overwrite_and_writes_nothing_without_a_fit(tmp_path, run_cli, fit_folder):
    target = tmp_path / "r.html"
    target.write_text("mine")
    code, _, stderr = run_cli(["report", fit_folder, "--out", target])
    assert code == 2 and "already exists; pass --overwrite" in stderr and target.read_text() == "mine"
    (tmp_path / "nofit").mkdir()
    code, _, stderr = run_cli(["report", tmp_path / "nofit", "--out", tmp_path / "n.html"])
    assert code == 2 and len(stderr.strip().splitlines()) == 1 and "holds no fit" in stderr
    assert not (tmp_path / "n.html").exists() and list(tmp_path.glob(".n.*")) == []


# -- viewer server ----------------------------------------------------------------------------------

def _serve_in_thread(collection, port):
    from jsrte.view.server import serve

    lines, stop = [], threading.Event()
    ready = threading.Event()

    def say(line):
        lines.append(line)
        ready.set()

    thread = threading.Thread(target=serve, args=(collection,), daemon=True,
                              kwargs={"host": "127.0.0.1", "port": port, "say": say, "warn": lines.append,
                                      "stop": stop})
    thread.start()
    return thread, stop, ready, lines


def test_viewer_draws_every_layer_steps_through_the_fits_and_names_what_is_missing(tmp_path):
    import viser

    from jsrte.view.server import Viewer

    out = make_batch(tmp_path, 2)
    (out / "s1" / "shape.ply").unlink()
    server = viser.ViserServer(host="127.0.0.1", port=0, verbose=False)
    try:
        warnings = []
        viewer = Viewer(server, find_fits(out), warn=warnings.append)
        viewer.show(0)
        drawn = {name: len(nodes) for name, nodes in viewer.layers.items()}
        assert drawn == {"scan points": 1, "retrieved mesh": 1, "true mesh": 1, "floor": 1, "winning pose": 1,
                         "other hypotheses": 1, "other objects": 0}
        assert viewer.layers["winning pose"][0].visible and not viewer.layers["other hypotheses"][0].visible
        assert "| scale | 0.5000 |" in viewer.numbers.content and warnings == []
        viewer.toggles["scan points"].value = False
        viewer._set_visible("scan points")
        assert not viewer.layers["scan points"][0].visible
        viewer.show(1)
        assert viewer.layers["retrieved mesh"] == [] and len(viewer.layers["true mesh"]) == 1
        assert not viewer.layers["scan points"][0].visible  # the toggle holds across fits
        assert "missing:" in viewer.numbers.content and "s1/shape.ply: missing" in warnings[0]
    finally:
        server.stop()


def test_viewer_serves_its_page(tmp_path):
    out = make_batch(tmp_path, 2)
    (out / "s1" / "shape.ply").write_text("broken")
    port = free_port()
    thread, stop, ready, lines = _serve_in_thread(find_fits(out), port)
    try:
        assert ready.wait(60), lines
        assert f"http://127.0.0.1:{port}" in lines[-1]
        with urllib.request.urlopen(f"http://127.0.0.1:{port}/", timeout=10) as response:
            assert response.status == 200 and b"<html" in response.read().lower()
    finally:
        stop.set()
        thread.join(20)
    assert not thread.is_alive()


def test_port_in_use_is_a_one_line_error_naming_it(tmp_path, run_cli, fit_folder):
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen(1)
        port = taken.getsockname()[1]
        code, stdout, stderr = run_cli(["view", fit_folder, "--port", port])
    assert code == 2 and stdout == ""
    assert stderr.strip() == (f"jsrte: error: port {port} on 127.0.0.1 is already in use (Address already in use); "
                              f"pass --port with a free port, e.g. --port {port + 1}")


def test_view_of_a_folder_without_a_fit_is_a_one_line_error(tmp_path, run_cli):
    code, _, stderr = run_cli(["view", tmp_path, "--port", free_port()])
    assert code == 2 and len(stderr.strip().splitlines()) == 1 and "holds no fit" in stderr


def test_ctrl_c_stops_the_viewer_cleanly(fit_folder):
    port = free_port()
    process = subprocess.Popen([sys.executable, "-m", "jsrte.cli", "view", str(fit_folder), "--port", str(port)],
                               stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                               env={"PYTHONPATH": str(SRC), "PATH": "/usr/bin:/bin"})
    try:
        line = process.stdout.readline()
        assert f"http://127.0.0.1:{port}" in line, process.stderr.read()
        process.send_signal(signal.SIGINT)
        stdout, stderr = process.communicate(timeout=30)
    finally:
        if process.poll() is None:
            process.kill()
    assert process.returncode == 0, stderr
    assert "stopped" in stdout and "Traceback" not in stderr
