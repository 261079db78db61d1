"""A history as CSV files: HISTORY.csv (tests) and MAINTENANCE.csv (repairs and replacements).

* HISTORY.csv: ``actuator_id, time_h, k_gm, k_fsj, k_bkl`` [+ ``std_gm, std_fsj, std_bkl,
  usage, usage_unit, sim_time_s``]; time [h], K dimensionless in [0, FAULT_UPPER], std their
  standard errors (an empty or absent std: not stated, estimated when the history is read), usage
  flight hours or cycles from new, usage_unit its unit (text, e.g. FH), sim_time_s the test
  window's ROS / simulated stamp [s] (the store's columns of the same names; empty or absent: none).
  Other columns are the user's own and are not read.
* MAINTENANCE.csv: ``actuator_id, time_h, fault`` [+ ``action, note``]; fault gm, fsj, bkl or
  all; action repair (default) or replace. A fault's trend restarts at its latest maintenance,
  and a usage count may fall at a replacement (a new unit counts from zero).

``history export`` writes both from a store and ``history import HISTORY.csv --maintenance
MAINTENANCE.csv`` (or ``prognose --history HISTORY.csv --maintenance MAINTENANCE.csv``) reads
them back: the same prognosis (`test_an_export_imports_to_the_same_prognosis`). Without the
maintenance a restarted trend would read as one long series across the repair. Numbers are
written with ``repr`` (the shortest text that reads back to the same float).
"""
from __future__ import annotations

import csv
import os
import tempfile
from pathlib import Path

from ..physics.faults import FAULT_KEYS
from ..signals.table import csv_rows
from .config import PrognosticsError
from .records import (K_COLUMNS, STD_COLUMNS, HealthRecord, MaintenanceRecord, check_maintenance,
                      check_maintenance_time, check_order, check_record)

HISTORY_COLUMNS = ("actuator_id", "time_h", *K_COLUMNS, *STD_COLUMNS, "usage", "usage_unit", "sim_time_s")
MAINTENANCE_COLUMNS = ("actuator_id", "time_h", "fault", "action", "note")


def _float(text: str, where: str, name: str) -> float:
    try:
        # float() reads "0.0_5" as 0.005 and Arabic-Indic or full-width digits as numbers: typing
        # errors or another locale's text, not the numbers of a CSV
        if "_" in text or not text.isascii():
            raise ValueError(text)
        v = float(text)
    except (TypeError, ValueError):
        raise PrognosticsError(f"{where}: {name} {text!r} is not a number") from None
    return v


def maintenance_beside(history_csv: str | Path) -> Path:
    """Where ``history export`` writes the MAINTENANCE.csv of a HISTORY.csv by default: beside it,
    ``NAME_maintenance.csv``."""
    history_csv = Path(history_csv)
    return history_csv.with_name(history_csv.stem + "_maintenance.csv")


def _check_case(path: Path, row: dict, known: tuple[str, ...]) -> None:
    """A column named as one of ours in other letter case (``Usage``) would be read as absent."""
    odd = [c for c in row if c and c not in known and c.lower() in known]
    if odd:
        raise PrognosticsError(f"{path}: column(s) {', '.join(odd)}: names are case-sensitive; the columns "
                               f"are {', '.join(known)}")


def _existing(path: str | Path, what: str) -> Path:
    path = Path(path)
    if path.is_dir():
        raise PrognosticsError(f"{path}: a directory, not a {what}")
    if not path.is_file():
        raise PrognosticsError(f"{path}: no such file")
    return path


def read_maintenance_csv(path: str | Path) -> list[MaintenanceRecord]:
    """Rows of a MAINTENANCE.csv, validated row by row (a header alone: no actions). The same
    actuator, fault and time twice is refused, naming both lines."""
    path = _existing(path, "MAINTENANCE.csv")
    out, seen = [], {}
    for where, row in csv_rows(path, ("actuator_id", "time_h", "fault"), PrognosticsError,
                               need="a MAINTENANCE.csv"):
        if not seen:
            _check_case(path, row, MAINTENANCE_COLUMNS)
        m = MaintenanceRecord(row["actuator_id"] or "", _float(row["time_h"], where, "time_h"),
                              (row["fault"] or "").lower().removeprefix("k_"),
                              row.get("action") or "repair", row.get("note") or None)
        check_maintenance(m, where)
        key = (m.actuator_id, m.time_h, m.fault)
        if key in seen:
            raise PrognosticsError(f"{where}: duplicate maintenance: {m.actuator_id} {m.fault} at "
                                   f"time_h={m.time_h:g} is also on {seen[key]}")
        seen[key] = where
        out.append(m)
    return out


def read_history_csv(path: str | Path, notes: list[str] | None = None) -> list[HealthRecord]:
    """Rows of a HISTORY.csv, validated row by row, in time order per actuator
    (:func:`records.check_order`; a usage that falls is the caller's note,
    :func:`records.batch_usage_notes`). A missing std stays None: the history fills it when read
    (:func:`records.fill_missing_std`), and the store keeps it NULL. ``notes`` gets what the
    reading says of the file (a last line with no end of line, :func:`signals.table.csv_rows`)."""
    path = _existing(path, "HISTORY.csv")
    recs = []
    for where, row in csv_rows(path, ("actuator_id", "time_h", *K_COLUMNS), PrognosticsError, notes=notes):
        if not recs:
            # a column named k_* or std_* that is none of ours is a misspelling: read as absent, a
            # std_fjs left K_FSJ's errors to the estimate; other extra columns are the user's own
            odd = [c for c in row if c and c.lower().startswith(("k_", "std_")) and c not in K_COLUMNS + STD_COLUMNS]
            if odd:
                raise PrognosticsError(f"{path}: unknown column(s) {', '.join(odd)}: the K and std columns are "
                                       f"{', '.join(K_COLUMNS + STD_COLUMNS)} (case-sensitive)")
            _check_case(path, row, HISTORY_COLUMNS)
        k = tuple(_float(row[f"k_{n}"], where, f"k_{n}") for n in FAULT_KEYS)
        std = tuple(_float(row[f"std_{n}"], where, f"std_{n}") if row.get(f"std_{n}") not in (None, "")
                    else None for n in FAULT_KEYS)
        usage = _float(row["usage"], where, "usage") if row.get("usage") not in (None, "") else None
        stamp = _float(row["sim_time_s"], where, "sim_time_s") if row.get("sim_time_s") not in (None, "") else None
        r = HealthRecord(row["actuator_id"] or "", _float(row["time_h"], where, "time_h"), k, std,
                         usage=usage, usage_unit=row.get("usage_unit") or None, sim_time_s=stamp, method="import")
        check_record(r, where)
        r.source_path, r.where = str(path), where
        recs.append((where, r))
    if not recs:
        raise PrognosticsError(f"{path}: the history is empty (no rows)")
    check_order(recs)
    return [r for _, r in recs]


def check_maintenance_times(tests: list[HealthRecord], maintenance: list[MaintenanceRecord], path: str | Path,
                            maintenance_path: str | Path) -> None:
    """What the store refuses of a maintenance action (:func:`records.check_maintenance_time`),
    for a HISTORY.csv read with its MAINTENANCE.csv."""
    latest: dict[str, float] = {}
    for r in tests:
        latest[r.actuator_id] = max(latest.get(r.actuator_id, r.time_h), r.time_h)
    for i, m in enumerate(maintenance):
        check_maintenance_time(m, latest, f"{Path(maintenance_path).name} row {i + 1}", path)


def _cell(v) -> str:
    return "" if v is None else repr(float(v))


def _write_atomic(path: Path, header: tuple, rows) -> None:
    """Write a CSV through a temporary file beside it and a rename: an export cut short leaves
    the file as it was, never half of it."""
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "w", newline="", encoding="utf-8") as f:
            w = csv.writer(f)
            w.writerow(header)
            w.writerows(rows)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def write_history_csv(path: str | Path, tests: list[dict]) -> None:
    """A HISTORY.csv of stored tests (dicts of :meth:`store.HistoryStore.list_tests`)."""
    _write_atomic(Path(path), HISTORY_COLUMNS,
                  ([t["actuator_id"], _cell(t["time_h"]), *(_cell(t[c]) for c in K_COLUMNS + STD_COLUMNS),
                    _cell(t["usage"]), t["usage_unit"] or "", _cell(t["sim_time_s"])] for t in tests))


def write_maintenance_csv(path: str | Path, maintenance: list[dict]) -> None:
    """A MAINTENANCE.csv of stored actions (dicts of :meth:`store.HistoryStore.list_maintenance`)."""
    _write_atomic(Path(path), MAINTENANCE_COLUMNS,
                  ([m["actuator_id"], _cell(m["time_h"]), m["fault"], m["action"], m["note"] or ""]
                   for m in maintenance))
