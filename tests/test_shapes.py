"""Procedural furniture (jsrte.shapes), the ShapeNet / mesh-folder readers, ``jsrte shapes``."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import trimesh
from manifold3d import Manifold, Mesh

from cli_runner import run_cli
from jsrte.errors import JsrteError
from jsrte.geometry.mesh import load_mesh, normalized
from jsrte.shapes import (
    CATEGORIES,
    EVAL_SET_SEED,
    TRAIN_SET_SEED,
    GeneratedShape,
    category_styles,
    generate_set,
    generate_shape,
    shape_seed,
    write_set,
)
from jsrte.shapes.shapenet import SHAPENET_SYNSETS, iter_mesh_folder, iter_shapenet

N_SEEDS = 60
HEIGHT_RANGE_M = {"chair": (0.70, 1.20), "table": (0.35, 0.80), "sofa": (0.60, 1.05),
                  "bed": (0.45, 2.30)}


@pytest.fixture(scope="module", params=CATEGORIES)
def shape_set(request) -> list[GeneratedShape]:
    """The first ``N_SEEDS`` shapes of the training set of one category."""
    return generate_set(request.param, N_SEEDS, TRAIN_SET_SEED)


def _manifold(mesh: trimesh.Trimesh) -> Manifold:
    return Manifold(Mesh(vert_properties=np.asarray(mesh.vertices, np.float32),
                         tri_verts=np.asarray(mesh.faces, np.uint32)))


# --- geometry of every generated shape --------------------------------------------------------


def test_every_shape_is_one_watertight_body(shape_set):
    for shape in shape_set:
        mesh = shape.mesh
        assert mesh.is_watertight and mesh.is_winding_consistent, shape.params
        assert mesh.volume > 0
        assert len(mesh.split(only_watertight=False)) == 1, shape.params


def test_every_shape_stands_on_the_floor_centred(shape_set):
    for shape in shape_set:
        lo, hi = shape.mesh.bounds
        assert lo[1] == pytest.approx(0.0, abs=1e-9)
        assert lo[0] == pytest.approx(-hi[0], abs=1e-9)
        assert lo[2] == pytest.approx(-hi[2], abs=1e-9)
        low, high = HEIGHT_RANGE_M[shape.category]
        assert low <= hi[1] <= high, (shape.style, hi[1])


def test_every_shape_is_mirror_symmetric_in_x(shape_set):
    for shape in shape_set[:15]:
        solid = _manifold(shape.mesh)
        difference = solid - solid.mirror((1.0, 0.0, 0.0))
        assert difference.volume() < 1e-4 * solid.volume(), shape.style


def test_every_shape_fits_the_unit_sphere_after_normalization(shape_set):
    for shape in shape_set:
        radius = np.linalg.norm(normalized(shape.mesh).vertices, axis=1).max()
        assert 0.9 < radius < 1.0


def test_front_faces_minus_z(shape_set):
    """Backs (chairs, sofas) and headboards (beds) stand at +z, the open front at -z."""
    category = shape_set[0].category
    for shape in shape_set:
        v = shape.mesh.vertices
        top = v[v[:, 1] > v[:, 1].max() - 0.02]
        if category in ("chair", "sofa"):
            assert top[:, 2].mean() > 0.05, shape.style
        if category == "sofa":
            assert shape.mesh.center_mass[2] > 0, shape.style
        if category == "bed":
            back, front = v[v[:, 2] > 0, 1].max(), v[v[:, 2] < 0, 1].max()
            assert back >= front - 1e-9, shape.style
            if shape.style != "four_poster":
                assert back > front + 0.1, shape.style


def test_all_styles_are_reachable_and_recorded(shape_set):
    category = shape_set[0].category
    styles = category_styles(category)
    assert len(styles) >= 5
    assert {s.style for s in shape_set} == set(styles)
    for shape in shape_set:
        assert shape.params["style"] == shape.style
        info = shape.to_json()
        assert set(info) == {"category", "style", "params", "seed", "height_m", "watertight"}
        assert info["watertight"] is True
        assert info["height_m"] == pytest.approx(shape.mesh.bounds[1, 1])
        json.dumps(info)  # JSON-ready


def test_legs_and_tubes_are_at_least_three_centimetres(shape_set):
    for shape in shape_set:
        for key, value in shape.params.items():
            if key in ("leg_size_m", "post_size_m", "back_post_size_m"):
                assert value >= 0.03, (shape.style, key, value)
            if key == "tube_radius_m":
                assert value >= 0.015


# --- seeds and sets ---------------------------------------------------------------------------


def test_same_seed_same_shape_and_different_seeds_differ():
    for category in CATEGORIES:
        a, b = generate_shape(category, 7), generate_shape(category, 7)
        assert np.array_equal(a.mesh.vertices, b.mesh.vertices)
        assert np.array_equal(a.mesh.faces, b.mesh.faces)
        assert a.params == b.params and a.seed == 7
        c = generate_shape(category, 8)
        assert c.params != a.params


def test_shape_seeds_are_deterministic_and_train_eval_never_overlap():
    assert shape_seed(0, 5) == shape_seed(0, 5)
    train = {shape_seed(TRAIN_SET_SEED, i) for i in range(10_000)}
    evaluation = {shape_seed(EVAL_SET_SEED, i) for i in range(10_000)}
    assert len(train) == len(evaluation) == 10_000
    assert not train & evaluation
    shapes = generate_set("table", 2, EVAL_SET_SEED)
    assert [s.seed for s in shapes] == [shape_seed(EVAL_SET_SEED, i) for i in range(2)]


def test_unknown_category_names_the_known_ones():
    with pytest.raises(JsrteError, match="chair, table, sofa, bed"):
        generate_shape("stool", 0)
    with pytest.raises(JsrteError, match="unknown category"):
        generate_set("lamp", 1, 0)


def test_write_set_writes_meshes_and_json(tmp_path):
    paths = write_set("sofa", 2, TRAIN_SET_SEED, tmp_path)
    assert [p.name for p in paths] == ["sofa_0000.ply", "sofa_0001.ply"]
    assert sorted(p.name for p in tmp_path.iterdir()) == [
        "sofa_0000.json", "sofa_0000.ply", "sofa_0001.json", "sofa_0001.ply"]
    expected = generate_shape("sofa", shape_seed(TRAIN_SET_SEED, 1))
    mesh = load_mesh(paths[1])
    assert mesh.is_watertight
    assert np.allclose(np.sort(mesh.vertices, axis=0), np.sort(expected.mesh.vertices, axis=0),
                       atol=1e-6)
    info = json.loads((tmp_path / "sofa_0001.json").read_text())
    assert info["seed"] == expected.seed and info["style"] == expected.style


# --- ShapeNet and mesh folders ----------------------------------------------------------------


def _fake_shapenet(root: Path) -> Path:
    synset = root / SHAPENET_SYNSETS["chair"]
    for model_id in ("bbb", "aaa"):
        (synset / model_id / "models").mkdir(parents=True)
        trimesh.creation.box((0.5, 1.0, 0.5)).export(synset / model_id / "models"
                                                      / "model_normalized.obj")
    (synset / "ccc" / "models").mkdir(parents=True)  # a model without its mesh: skipped
    (root / SHAPENET_SYNSETS["table"]).mkdir()
    return synset


def test_iter_shapenet_reads_root_or_synset_folder(tmp_path):
    synset = _fake_shapenet(tmp_path)
    found = list(iter_shapenet(tmp_path, "chair"))
    assert [model_id for model_id, _ in found] == ["aaa", "bbb"]
    assert found[0][1] == synset / "aaa" / "models" / "model_normalized.obj"
    assert load_mesh(found[0][1]).is_watertight
    assert list(iter_shapenet(synset, "chair")) == found
    renamed = synset.rename(tmp_path / "my_chairs")
    assert [model_id for model_id, _ in iter_shapenet(renamed, "chair")] == ["aaa", "bbb"]


def test_iter_shapenet_errors(tmp_path):
    _fake_shapenet(tmp_path)
    with pytest.raises(JsrteError, match="holds no models"):
        list(iter_shapenet(tmp_path, "table"))
    with pytest.raises(JsrteError, match="no ShapeNet synset folder 04256520"):
        list(iter_shapenet(tmp_path, "sofa"))
    with pytest.raises(JsrteError, match="no such folder"):
        list(iter_shapenet(tmp_path / "missing", "chair"))
    with pytest.raises(JsrteError, match="unknown category"):
        list(iter_shapenet(tmp_path, "lamp"))


def test_iter_mesh_folder(tmp_path):
    box = trimesh.creation.box()
    for name in ("b.obj", "a.ply", "c.OFF"):
        box.export(tmp_path / name, file_type=name.rsplit(".", 1)[1].lower())
    (tmp_path / "notes.json").write_text("{}")
    (tmp_path / "sub").mkdir()
    assert [p.name for p in iter_mesh_folder(tmp_path)] == ["a.ply", "b.obj", "c.OFF"]
    with pytest.raises(JsrteError, match="holds no mesh files"):
        list(iter_mesh_folder(tmp_path / "sub"))
    with pytest.raises(JsrteError, match="no such folder"):
        list(iter_mesh_folder(tmp_path / "missing"))


# --- jsrte shapes -----------------------------------------------------------------------------


def test_shapes_command_end_to_end(tmp_path, monkeypatch, capsys):
    out_dir = tmp_path / "chairs"
    code, out, err = run_cli(monkeypatch, capsys, "shapes", "--category", "chair", "--n", "3",
                             "--seed", "0", "--out", str(out_dir), "--sheet")
    assert code == 0, err
    assert "wrote 3 chair meshes" in out
    names = sorted(p.name for p in out_dir.iterdir())
    assert names == ["chair_0000.json", "chair_0000.ply", "chair_0001.json", "chair_0001.ply",
                     "chair_0002.json", "chair_0002.ply", "sheet.png"]
    from PIL import Image

    with Image.open(out_dir / "sheet.png") as image:
        pixels = np.asarray(image.convert("L"), dtype=np.float64)
    assert pixels.shape[0] > 200 and pixels.shape[1] > 600
    assert pixels.std() > 5  # something was drawn
    info = json.loads((out_dir / "chair_0002.json").read_text())
    assert info["seed"] == shape_seed(0, 2)

    # refuses to overwrite meshes; --overwrite replaces them and removes stale ones
    code, out, err = run_cli(monkeypatch, capsys, "shapes", "--category", "chair", "--n", "2",
                             "--out", str(out_dir))
    assert code == 2 and out == "" and "--overwrite" in err
    assert len(err.strip().splitlines()) == 1
    code, _, err = run_cli(monkeypatch, capsys, "shapes", "--category", "chair", "--n", "2",
                           "--out", str(out_dir), "--overwrite")
    assert code == 0, err
    assert not (out_dir / "chair_0002.ply").exists() and not (out_dir / "chair_0002.json").exists()


def test_shapes_command_unknown_category_is_one_line_exit_2(tmp_path, monkeypatch, capsys):
    out_dir = tmp_path / "out"
    code, out, err = run_cli(monkeypatch, capsys, "shapes", "--category", "lamp", "--n", "3",
                             "--out", str(out_dir))
    assert code == 2 and out == ""
    assert len(err.strip().splitlines()) == 1
    assert "lamp" in err and "chair, table, sofa, bed" in err
    assert not out_dir.exists()
