"""CSV tables written atomically read back with their cells typed as written."""

import pytest

from jsrte.atomic import csv_cell, read_csv_rows, write_csv_atomic
from jsrte.errors import JsrteError


def test_rows_read_back_as_written(tmp_path):
    rows = [{"room": 3, "fscore": 0.8125, "flag": "ok", "matched": True, "margin": None},
            {"room": 4, "fscore": 1e-07, "flag": "doubtful", "matched": False, "margin": -2.5}]
    write_csv_atomic(tmp_path / "t.csv", rows)
    back = read_csv_rows(tmp_path / "t.csv")
    assert back == rows
    assert [type(r["room"]) for r in back] == [int, int] and back[0]["matched"] is True


def test_cells():
    assert csv_cell("") is None and csv_cell("7") == 7 and csv_cell("-0.5") == -0.5
    assert csv_cell("nan") != csv_cell("nan") and csv_cell("chair_001") == "chair_001"


def test_an_unreadable_table_is_an_error_naming_it(tmp_path):
    path = tmp_path / "t.csv"
    path.write_bytes(b"a,b\n\xff\xfe,1\n")
    with pytest.raises(JsrteError, match="t.csv"):
        read_csv_rows(path)
