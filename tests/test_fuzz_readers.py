"""Fuzzing every reader: damaged scans, meshes, sample and query files, shape codes, models,
training states and fit results end in a sane result or one clean error (``fuzz_cases``).

A few examples per format keep this under a minute; ``benchmarks/bench_fuzz.py`` runs many and
prints the outcomes per format.
"""

import pytest
from hypothesis import HealthCheck, given, settings

from fuzz_cases import READERS, TEXT_FORMATS, mutate, mutations, original_bytes, run_case

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
