"""Fuzzing every reader: damaged scans, meshes, sample and query files, shape codes, models,
training states and fit results end in a sane result or one clean error (``fuzz_cases``).

A few examples per format keep this under a minute; ``benchmarks/bench_fuzz.py`` runs many and
prints the outcomes per format.
"""

import pytest
from hypothesis import HealthCheck, given, settings

from fuzz_cases import READERS, TEXT_FORMATS, mutate, mutations, original_bytes, run_case
from jsrte.errors import JsrteError

EXAMPLES = 12


@pytest.mark.parametrize("fmt", sorted(READERS))
def test_the_original_file_reads(fmt):
    assert run_case(fmt, original_bytes(fmt)) == "result"


@pytest.mark.parametrize("fmt", sorted(READERS))
def test_a_damaged_file_is_a_result_or_one_clean_error(fmt):
    original = original_bytes(fmt)

    @settings(max_examples=EXAMPLES, deadline=None, database=None,
              suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])
    @given(mutations(fmt))
    def case(edits):
        run_case(fmt, mutate(original, edits))

    case()


@pytest.mark.parametrize("fmt", sorted(READERS))
def test_an_empty_or_cut_file_is_one_clean_error(fmt):
    original = original_bytes(fmt)
    sizes = [0, 1, 4, len(original) // 2] + ([] if fmt in TEXT_FORMATS else [len(original) - 1])
    for size in sizes:
        if fmt in ("xyz", "obj", "off") and size > 4:
            continue  # text rows: a shorter file is a smaller valid file
        assert run_case(fmt, original[:size]) == "error", (fmt, size)


@pytest.mark.parametrize("fmt,old,new", [
    ("pcd-binary", b" normal_y ", b" l_y "),  # Open3D crashed (segmentation fault) on this one
    ("pcd-ascii", b" normal_y ", b" l_y "),
    ("ply-binary", b"property double z\n", b""),  # Open3D returned the points with z missing
    ("pcd-ascii", b"COUNT 1 1 1 1 1 1", b"COUNT 1 1 1 1 99999999999999999999 1"),  # Open3D crashed
    ("pcd-binary", b"WIDTH 60", b"WIDTH 99999999999"),
])
def test_a_header_with_a_missing_or_absurd_field_is_one_clean_error(fmt, old, new):
    original = original_bytes(fmt)
    if old not in original:  # the writer's header differs from the one this case was found with
        old = old.replace(b"double", b"float")
    assert old in original
    assert run_case(fmt, original.replace(old, new, 1)) == "error"


# Each header below reads differently in Open3D than as written; Open3D then sized its arrays
# from a number it never read (a stack value, up to 2^31 points: tens of GB) or misread the data.
# The header check must refuse them before Open3D sees the file.
PCD_HEADER = (b"# .PCD v0.7 - Point Cloud Data file format\nVERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\n"
              b"COUNT 1 1 1\nWIDTH 2\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS 2\nDATA ascii\n")
PCD_ROWS = b"0.1 0.2 0.3\n0.4 0.5 0.6\n"


@pytest.mark.parametrize("old,new,why", [
    # cut inside the header (the fuzz case that grew to 22 GB): HEIGHT unread, no DATA line
    (b"HEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS 2\nDATA ascii\n" + PCD_ROWS, b"HEIGHT", "no DATA line"),
    (b"DATA ascii\n" + PCD_ROWS, b"", "no DATA line"),
    (b"HEIGHT 1\n", b"HEIGHT\x1c1\n", "byte"),  # not a space to Open3D: HEIGHT unread
    (b"HEIGHT 1\n", b"HEIGHT\x001\n", "byte"),  # Open3D's line ends at the zero byte
    (b"WIDTH 2\nHEIGHT 1\n", b"HEIGHT 1\nWIDTH 2\n", "WIDTH after HEIGHT"),  # HEIGHT multiplies an unset WIDTH
    (b"POINTS 2\n", b"POINTS 2\nPOINTS 2\n", "POINTS after POINTS"),
    (b"WIDTH 2\n", b"width 2\nWIDTH 2\n", "'width 2'"),  # Open3D matches keywords by case and prefix
    (b"HEIGHT 1\n", b"HEIGHTS 7\nHEIGHT 1\n", "'HEIGHTS 7'"),
    (b"DATA ascii", b"DATA ASCII", "DATA"),
    (b"WIDTH 2", b"WIDTH 2_0", "WIDTH"),  # Python reads 20, Open3D 2
], ids=["cut-after-HEIGHT", "no-DATA", "control-byte", "zero-byte", "order", "repeated", "lower-case",
        "prefix", "DATA-case", "digits"])
def test_a_pcd_header_open3d_would_misread_is_refused_before_reading(tmp_path, old, new, why):
    from jsrte.formats import check_pcd_complete

    path = tmp_path / "cloud.pcd"
    path.write_bytes(PCD_HEADER + PCD_ROWS)
    check_pcd_complete(path)  # the undamaged file passes
    assert old in PCD_HEADER + PCD_ROWS
    path.write_bytes((PCD_HEADER + PCD_ROWS).replace(old, new, 1))
    with pytest.raises(JsrteError, match="malformed PCD header") as error:
        check_pcd_complete(path)
    assert why in str(error.value) and str(path) in str(error.value)


def test_an_ascii_pcd_row_with_a_value_missing_is_refused(tmp_path):
    from jsrte.formats import check_pcd_complete

    path = tmp_path / "cloud.pcd"
    path.write_bytes(PCD_HEADER + PCD_ROWS.replace(b" 0.5", b""))  # Open3D skipped the row and returned
    with pytest.raises(JsrteError, match="2 points of 3 values, the file has 1 lines"):  # a point it never set
        check_pcd_complete(path)


def _compressed_pcd(path):
    import numpy as np
    import open3d as o3d

    points = np.random.default_rng(0).uniform(-0.5, 0.5, (50, 3))
    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points))
    assert o3d.io.write_point_cloud(str(path), cloud, compressed=True)
    return points


@pytest.mark.parametrize("compressed,uncompressed,why", [
    (10**9, None, "truncated"),  # Open3D allocated the compressed size before reading it
    (None, 2**32 - 1, "malformed PCD data"),  # and the uncompressed size, then decompressed into it
    (None, 12, "malformed PCD data"),  # fewer bytes than 50 points: Open3D read past them
])
def test_binary_compressed_pcd_sizes_are_checked(tmp_path, compressed, uncompressed, why):
    import struct

    from jsrte.formats import check_pcd_complete
    from jsrte.scans.io import load_scan

    path = tmp_path / "cloud.pcd"
    points = _compressed_pcd(path)
    assert load_scan(path).points == pytest.approx(points, abs=1e-6)  # the undamaged file reads
    data = path.read_bytes()
    at = data.index(b"DATA binary_compressed\n") + len(b"DATA binary_compressed\n")
    sizes = struct.unpack("<II", data[at:at + 8])
    sizes = (compressed or sizes[0], uncompressed or sizes[1])
    path.write_bytes(data[:at] + struct.pack("<II", *sizes) + data[at + 8:])
    with pytest.raises(JsrteError, match=why):
        check_pcd_complete(path)


def test_binary_pcd_with_double_coordinates_is_refused(tmp_path):
    import numpy as np

    from jsrte.scans.io import load_scan

    header = PCD_HEADER.replace(b"SIZE 4 4 4", b"SIZE 8 8 8").replace(b"DATA ascii", b"DATA binary")
    path = tmp_path / "cloud.pcd"
    path.write_bytes(header + bytes(range(48)))  # Open3D returned every point as (0, 0, 0)
    with pytest.raises(JsrteError, match="4-byte floats"):
        load_scan(path)
    path.write_bytes(PCD_HEADER.replace(b"SIZE 4 4 4", b"SIZE 8 8 8") + PCD_ROWS)  # text: read as written
    assert load_scan(path).points == pytest.approx(np.array([[0.1, 0.2, 0.3], [0.4, 0.5, 0.6]]))


def _cli_args(fmt, path, tmp_path):
    """The command that reads a file of ``fmt`` first, with ``path`` as that file."""
    from fuzz_cases import originals

    if fmt == "jsrte":
        return ["decode", path, "--out", tmp_path / "m.ply"]
    if fmt == "model":
        return ["fit", originals()["ply-binary"], "--model", path, "--out", tmp_path / "out"]
    if fmt == "fit-json":
        return ["encode", path.parent, "--out", tmp_path / "c.jsrte"]
    return ["fit", path, "--out", tmp_path / "out", "--preset", "smoke", "--no-progress", "--threads", "1"]


@pytest.mark.parametrize("fmt", sorted(set(READERS) - {"train-state"}))
def test_cli_on_a_damaged_file_is_one_line(fmt, tmp_path, run_cli):
    from fuzz_cases import originals

    original = original_bytes(fmt)
    for i, data in enumerate((original[: len(original) // 2], original[:7])):
        folder = tmp_path / f"case{i}"
        folder.mkdir()
        path = folder / originals()[fmt].name
        path.write_bytes(data)
        code, _, err = run_cli(_cli_args(fmt, path, folder))
        assert code == 2 and err.count("\n") == 1 and "Traceback" not in err, (fmt, err)
        assert not (folder / "out").exists() and not (folder / "c.jsrte").exists()
