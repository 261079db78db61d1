"""Rows of a small user-written CSV table (a fleet manifest, a HISTORY.csv), checked as they are read.

Header names and cell values are stripped of surrounding blanks; a missing required column, or a
row with more values than the header, raises the caller's error class with a message that names
the file and, for a row, its line (``NAME line N``, the header being line 1), so a user can find
the cell. Checking the values is the caller's business: it gets ``(where, row)`` pairs.
"""
from __future__ import annotations

import csv
from collections.abc import Iterator
from pathlib import Path


def csv_rows(path: str | Path, required: tuple[str, ...], error: type[Exception],
             need: str = "") -> Iterator[tuple[str, dict[str, str | None]]]:
    """``(where, row)`` for each data row of ``path``; ``where`` is ``"NAME line N"``.

    ``error`` is raised for a missing required column (``need``, when given, is added to the
    message in brackets: what the file is for), a name twice in the header, a row with more
    values than columns, or a row cut short before a required column (a short row's optional
    cells are None). The file must exist (the callers say what it should have been).
    """
    path = Path(path)
    # utf-8-sig: a spreadsheet's "CSV UTF-8" starts with a byte-order mark, which would otherwise
    # become part of the first column's name
    with path.open(newline="", encoding="utf-8-sig", errors="replace") as f:
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
            short = [c for c in required if row.get(c) is None]
            if short:   # a row cut short (a truncated file): its required cells are missing, not empty
                n = sum(v is not None for v in row.values())
                raise error(f"{where}: {n} value(s) for {len(cols)} columns: no {', '.join(short)}")
            yield where, {k: (v.strip() if isinstance(v, str) else v) for k, v in row.items()}
