"""Rows of a small user-written CSV table (a fleet manifest, a HISTORY.csv), checked as they are read.

Header names and cell values are stripped of surrounding blanks; a missing required column, or a
row with more values than the header, raises the caller's error class with a message that names
the file and, for a row, its line (``NAME line N``, the header being line 1), so a user can find
the cell. Checking the values is the caller's business: it gets ``(where, row)`` pairs.

The text must be UTF-8 (a byte-order mark allowed): read with replacement characters, two ids
that differ only in a Latin-1 letter (``Ne1`` / ``Nu1`` with accents) became one actuator.
"""
from __future__ import annotations

import csv
import io
from collections.abc import Iterator
from pathlib import Path


def csv_rows(path: str | Path, required: tuple[str, ...], error: type[Exception],
             need: str = "", notes: list[str] | None = None) -> Iterator[tuple[str, dict[str, str | None]]]:
    """``(where, row)`` for each data row of ``path``; ``where`` is ``"NAME line N"``.

    ``error`` is raised for a missing required column (``need``, when given, is added to the
    message in brackets: what the file is for), a name twice in the header, a row with more
    values than columns, a row cut short before a required column (a short row's optional
    cells are None), a short last line without an end of line (a truncated file), or text that
    is not UTF-8. Rows of empty cells are skipped, as blank lines are. The file must exist (the
    callers say what it should have been). ``notes``, when given, gets a line when the last line
    is whole but has no end of line: a file cut inside its last value reads 0.4567 as 0.4, and no
    check can tell that from a complete file.
    """
    path = Path(path)
    data = path.read_bytes()
    try:
        # utf-8-sig: a spreadsheet's "CSV UTF-8" starts with a byte-order mark, which would otherwise
        # become part of the first column's name
        text = data.decode("utf-8-sig")
    except UnicodeDecodeError as e:
        line = data[:e.start].count(b"\n") + 1
        raise error(f"{path} line {line}: not UTF-8 text (byte 0x{data[e.start]:02x}): save it as "
                    f"CSV UTF-8 (names with accents would be misread)") from None
    if not text.strip():
        raise error(f"{path}: the file is empty (no header, no rows)" + (f" ({need})" if need else ""))
    last_line = text.count("\n") + (0 if text.endswith(("\n", "\r")) else 1)
    cut = not text.endswith(("\n", "\r"))      # no end of line after the last row: maybe a truncated file
    with io.StringIO(text, newline="") as f:
        reader = csv.DictReader(f)
        cols = [c.strip() for c in reader.fieldnames or []]
        twice = sorted({c for c in cols if cols.count(c) > 1 and c})
        if twice:
            # DictReader keeps the last of two equal names: one column would be read, silently
            raise error(f"{path}: column(s) {', '.join(twice)} appear more than once in the header")
        missing = [c for c in required if c not in cols]
        if missing:
            raise error(f"{path}: missing column(s) {', '.join(missing)}" + (f" ({need})" if need else "")
                        + f"; the header reads {','.join(cols)[:200]!r} (names are case-sensitive, comma-separated)")
        reader.fieldnames = cols
        for row in reader:
            # line_num, not a row count: blank lines are skipped but still lines of the file
            where = f"{path.name} line {reader.line_num}"
            if None in row:
                raise error(f"{where}: more values than columns")
            if all(v is None or not v.strip() for v in row.values()):
                continue        # a spreadsheet's empty row (,,,,): a blank line
            n = sum(v is not None for v in row.values())
            short = [c for c in required if row.get(c) is None]
            if short:   # a row cut short (a truncated file): its required cells are missing, not empty
                raise error(f"{where}: {n} value(s) for {len(cols)} columns: no {', '.join(short)}")
            if n < len(cols) and cut and reader.line_num == last_line:
                # a short row elsewhere is a hand-written one; the last, with no end of line, was cut
                raise error(f"{where}: {n} value(s) for {len(cols)} columns on the last line, which has no "
                            f"end of line: the file looks cut short (write empty cells as ,, where a value is "
                            f"not stated)")
            if cut and reader.line_num == last_line and notes is not None:
                notes.append(f"{where}: the last line has no end of line: if the file was still being written, "
                             f"its last value may be cut short")
            yield where, {k: (v.strip() if isinstance(v, str) else v) for k, v in row.items()}
