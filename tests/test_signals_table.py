"""signals.table.csv_rows: the one reader of user-written CSV tables (manifest, HISTORY.csv)."""
import pytest

from eha_health.signals.table import csv_rows


class TableError(ValueError):
    pass


def test_rows_are_stripped_and_located_by_line(tmp_path):
    p = tmp_path / "t.csv"
    p.write_text(" a , b \n 1 , x \n\n2,  y\n")
    rows = list(csv_rows(p, ("a", "b"), TableError))
    # csv skips the blank line, but the line numbers stay those of the file
    assert rows == [("t.csv line 2", {"a": "1", "b": "x"}), ("t.csv line 4", {"a": "2", "b": "y"})]


def test_missing_column_is_named_with_what_the_file_needs(tmp_path):
    p = tmp_path / "t.csv"
    p.write_text("a,c\n1,2\n")
    with pytest.raises(TableError, match=r"t\.csv: missing column\(s\) b \(a table needs a, b\); the header reads "
                                         r"'a,c' \(names are case-sensitive, comma-separated\)$"):
        list(csv_rows(p, ("a", "b"), TableError, need="a table needs a, b"))


def test_an_empty_file_is_said_to_be_empty(tmp_path):
    # it read "missing column(s) a, b; the header reads ''" (probe 12)
    p = tmp_path / "t.csv"
    for text in ("", "\n\n", "  \r\n"):
        p.write_text(text)
        with pytest.raises(TableError, match=r"^.*t\.csv: the file is empty \(no header, no rows\) \(a table\)$"):
            list(csv_rows(p, ("a", "b"), TableError, need="a table"))


def test_extra_values_name_the_line_and_rows_before_it_were_read(tmp_path):
    p = tmp_path / "t.csv"
    p.write_text("a,b\n1,2\n3,4,5\n")
    got = []
    with pytest.raises(TableError, match=r"^t\.csv line 3: more values than columns$"):
        for where, row in csv_rows(p, ("a", "b"), TableError):
            got.append(row)
    assert got == [{"a": "1", "b": "2"}]


def test_short_row_gives_none_for_missing_optional_cells(tmp_path):
    p = tmp_path / "t.csv"
    p.write_text("a,b\n1\n")
    assert list(csv_rows(p, ("a",), TableError)) == [("t.csv line 2", {"a": "1", "b": None})]


def test_a_row_cut_short_before_a_required_column_names_the_line(tmp_path):
    # a truncated last line used to surface as "b None is not a number" in the caller
    p = tmp_path / "t.csv"
    p.write_text("a,b,c\n1,2,3\n4\n")
    with pytest.raises(TableError, match=r"^t\.csv line 3: 1 value\(s\) for 3 columns: no b$"):
        list(csv_rows(p, ("a", "b"), TableError))


def test_a_name_twice_in_the_header_is_refused(tmp_path):
    # csv.DictReader keeps the last of two equal names: the first column was dropped silently
    p = tmp_path / "t.csv"
    p.write_text("a,b,a\n1,2,3\n")
    with pytest.raises(TableError, match=r"^.*t\.csv: column\(s\) a appear more than once in the header$"):
        list(csv_rows(p, ("a", "b"), TableError))


def test_a_spreadsheets_byte_order_mark_is_not_part_of_the_first_name(tmp_path):
    """Excel's "CSV UTF-8" starts with U+FEFF; read as text it made the first column
    '\\ufeffa' and the file 'missing column a'."""
    p = tmp_path / "t.csv"
    p.write_bytes("a,b\r\n1,x\r\n".encode("utf-8-sig"))
    assert list(csv_rows(p, ("a", "b"), TableError)) == [("t.csv line 2", {"a": "1", "b": "x"})]


def test_text_that_is_not_utf8_is_refused_naming_the_line(tmp_path):
    """Read with replacement characters, 'N\\xe91' and 'N\\xfc1' (cp1252) both became 'N\\ufffd1':
    two actuators merged into one, silently (an independent probe, 2026-11-29)."""
    p = tmp_path / "t.csv"
    p.write_bytes("a,b\nN\xe91,1\nN\xfc1,2\n".encode("cp1252"))
    with pytest.raises(TableError, match=r"t\.csv line 2: not UTF-8 text \(byte 0xe9\): save it as CSV UTF-8"):
        list(csv_rows(p, ("a", "b"), TableError))
    p.write_bytes("a,b\nN\xe91,1\nN\xfc1,2\n".encode("utf-8"))
    assert [r["a"] for _, r in csv_rows(p, ("a", "b"), TableError)] == ["N\xe91", "N\xfc1"]


def test_a_spreadsheets_empty_rows_are_blank_lines(tmp_path):
    p = tmp_path / "t.csv"
    p.write_text("a,b,c\n1,2,3\n,,\n , ,\n")
    assert list(csv_rows(p, ("a", "b"), TableError)) == [("t.csv line 2", {"a": "1", "b": "2", "c": "3"})]


def test_a_short_last_line_without_an_end_of_line_is_a_cut_file(tmp_path):
    """A file cut mid-row after its required cells: the row read with its optional cells missing
    and its last value cut ('0.004' -> '0.0'), silently (an independent probe, 2026-11-29)."""
    p = tmp_path / "t.csv"
    p.write_text("a,b,c,d\n1,2,3,4\n5,6,0.0")
    with pytest.raises(TableError, match=r"^t\.csv line 3: 3 value\(s\) for 4 columns on the last line, which has "
                                         r"no end of line: the file looks cut short"):
        list(csv_rows(p, ("a", "b"), TableError))
    p.write_text("a,b,c,d\n1,2,3,4\n5,6,0.0\n")          # ended: a hand-written short row
    assert list(csv_rows(p, ("a", "b"), TableError))[-1][1] == {"a": "5", "b": "6", "c": "0.0", "d": None}
    p.write_text("a,b,c,d\n1,2,3,4\n5,6,7,8")             # whole, without the final end of line
    assert len(list(csv_rows(p, ("a", "b"), TableError))) == 2


def test_a_whole_last_line_without_an_end_of_line_is_noted_where_the_caller_asks(tmp_path):
    """Cut inside its last value ('8.25' -> '8.2'), a file reads whole: nothing can refuse it, so the
    reader says it (F6 of an independent probe, 2026-12-07) to a caller that passes ``notes``."""
    p = tmp_path / "t.csv"
    p.write_text("a,b\n1,2\n\n5,8.2")
    notes = []
    assert len(list(csv_rows(p, ("a", "b"), TableError, notes=notes))) == 2
    assert notes == ["t.csv line 4: the last line has no end of line: if the file was still being written, its "
                     "last value may be cut short"]
    for text in ("a,b\n1,2\n5,8.25\n", "a,b\n1,2\n5,8.25\r\n", "a,b\n1,2\n5,8.25\n\n"):
        p.write_text(text)
        notes = []
        assert len(list(csv_rows(p, ("a", "b"), TableError, notes=notes))) == 2 and notes == [], text
