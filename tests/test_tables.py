import pytest

from athermal.atomic import write_text
from athermal.errors import FileFormatError, InputError
from athermal.studies.tables import read_table, write_table


def test_table_round_trip_is_exact_and_keeps_text(tmp_path):
    rows = [{"phase": "start", "phi": 0.1 + 0.2, "n": 3}, {"phase": "final", "phi": 1e-300, "n": 4}]
    write_table(tmp_path / "t.csv", rows)
    back = read_table(tmp_path / "t.csv")
    assert back == [
        {"phase": "start", "phi": 0.1 + 0.2, "n": 3.0},
        {"phase": "final", "phi": 1e-300, "n": 4.0},
    ]


def test_failed_writes_leave_the_old_file_and_no_temporary(tmp_path):
    target = tmp_path / "t.csv"
    write_text(target, "old\n")
    with pytest.raises(InputError, match="same columns"):
        write_table(target, [{"a": 1}, {"b": 2}])
    with pytest.raises(FileFormatError, match="cannot write"):
        write_text(tmp_path / "missing" / "t.csv", "x")
    assert target.read_text() == "old\n" and sorted(p.name for p in tmp_path.iterdir()) == ["t.csv"]
