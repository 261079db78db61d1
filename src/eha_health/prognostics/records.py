"""Health records: the tests and maintenance actions of a history, their checks, and the
in-memory history the prognostics read (one actuator's tests as arrays, in time order).

Shared by the SQLite store (:mod:`.store`) and the CSV files (:mod:`.history_csv`): one source
of truth for what a valid record is. A test's K are the fault coefficients (0 healthy, 1 the
default limit, at most ``physics.faults.FAULT_UPPER``), its std their standard errors, its time
operating hours [h], its usage flight hours or cycles counted from new.
"""
from __future__ import annotations

import datetime as _dt
import hashlib
import json
import math
from dataclasses import dataclass, field

import numpy as np

from ..physics.faults import FAULT_KEYS, FAULT_UPPER
from .config import PrognosticsError
from .scatter import noise_estimate

MAINT_FAULTS = FAULT_KEYS + ("all",)
ACTIONS = ("repair", "replace")
K_COLUMNS = tuple(f"k_{f}" for f in FAULT_KEYS)
STD_COLUMNS = tuple(f"std_{f}" for f in FAULT_KEYS)


def now_utc() -> str:
    return _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds")


def package_version() -> str:
    import eha_health
    return str(getattr(eha_health, "__version__", "unknown"))


def sha256_json(obj) -> str:
    return hashlib.sha256(json.dumps(obj, sort_keys=True, separators=(",", ":")).encode()).hexdigest()


@dataclass
class HealthRecord:
    """One diagnosis to append (K and std in the order gm, fsj, bkl; a std None: not stated,
    estimated when the history is read, :func:`fill_missing_std`)."""
    actuator_id: str
    time_h: float
    k: tuple
    std: tuple
    usage: float | None = None
    usage_unit: str | None = None
    sim_time_s: float | None = None
    method: str | None = None
    cost: float | None = None
    fit_rms: dict | None = None
    discrepancy: str | None = None
    warnings: list | None = None
    source_path: str | None = None
    source_hash: str | None = None
    wall_time_utc: str | None = None
    software_version: str | None = None
    where: str | None = field(default=None, compare=False, repr=False)   # its place in a file (messages only)
    #: appended as it was diagnosed (the monitor): ``source_path``, if any, names a log still being
    #: written, not the recording its hash is of
    live: bool = field(default=False, compare=False, repr=False)

    def content_hash(self) -> str:
        """Hash of the diagnosis inputs when there is no recording file."""
        return sha256_json({"actuator_id": self.actuator_id, "time_h": self.time_h,
                            "k": [float(v) for v in self.k],
                            "std": [None if v is None else float(v) for v in self.std],
                            "usage": self.usage, "method": self.method})

    def row(self) -> tuple:
        return (self.actuator_id, float(self.time_h), self.wall_time_utc or now_utc(), self.sim_time_s,
                self.usage, self.usage_unit, *map(float, self.k),
                *(None if v is None else float(v) for v in self.std), self.method,
                self.cost, json.dumps(self.fit_rms) if self.fit_rms is not None else None, self.discrepancy,
                json.dumps(self.warnings) if self.warnings is not None else None, self.source_path,
                self.source_hash or self.content_hash(), self.software_version or package_version())


def check_actuator_id(actuator_id, where: str) -> None:
    """An actuator id must be a non-empty string without leading or trailing spaces ('A1 ' would
    be an actuator of its own beside 'A1')."""
    if not isinstance(actuator_id, str) or not actuator_id.strip():
        raise PrognosticsError(f"{where}: empty actuator id")
    if actuator_id != actuator_id.strip():
        raise PrognosticsError(f"{where}: actuator id {actuator_id!r} has leading or trailing spaces")


#: Largest operating time [h] and usage a record may hold: about 114,000 years of operation. Far
#: beyond any machine; times near the float limit (1e290 h) overflowed the prognosis.
MAX_TIME_H = 1.0e9
MAX_USAGE = 1.0e12


def check_record(r: HealthRecord, where: str) -> None:
    check_actuator_id(r.actuator_id, where)
    if not isinstance(r.time_h, (int, float)) or not math.isfinite(r.time_h) or not 0 <= r.time_h <= MAX_TIME_H:
        raise PrognosticsError(f"{where}: time_h must be a number of hours in [0, {MAX_TIME_H:g}], got {r.time_h!r}")
    for name, v in zip(FAULT_KEYS, r.k):
        if not isinstance(v, (int, float)) or not math.isfinite(v) or not 0.0 <= v <= FAULT_UPPER:
            raise PrognosticsError(f"{where}: k_{name}={v!r} outside [0, {FAULT_UPPER}]")
    for name, v in zip(FAULT_KEYS, r.std):
        if v is None:       # not stated: estimated when read
            continue
        if not isinstance(v, (int, float)) or not math.isfinite(v):
            raise PrognosticsError(f"{where}: std_{name} is {v!r} (standard errors must be finite)")
        if v < 0:
            raise PrognosticsError(f"{where}: std_{name}={v!r} is negative")
    if r.usage is not None and (not math.isfinite(r.usage) or not 0 <= r.usage <= MAX_USAGE):
        raise PrognosticsError(f"{where}: usage must be a number in [0, {MAX_USAGE:g}], got {r.usage!r}")
    # the stamp tells a monitor's live test from another at the same time_h (store.holds_test)
    if r.sim_time_s is not None and not (isinstance(r.sim_time_s, (int, float)) and math.isfinite(r.sim_time_s)
                                         and r.sim_time_s >= 0):
        raise PrognosticsError(f"{where}: sim_time_s must be a time stamp [s] >= 0, got {r.sim_time_s!r}")


# ----------------------------------------------------------------------------- in-memory history
@dataclass
class ActuatorHistory:
    """Tests of one actuator in time order, and its maintenance actions."""
    actuator_id: str
    time_h: np.ndarray
    k: np.ndarray          # [n, 3]
    std: np.ndarray        # [n, 3]
    usage: np.ndarray      # [n], NaN where not given
    repairs: list = field(default_factory=list)   # (time_h, fault in gm/fsj/bkl/all, action)

    def since_repair(self, fault: str) -> np.ndarray:
        """Mask of the tests at or after the fault's last maintenance (its current trend)."""
        start = trend_start_h(self.repairs, fault)
        return self.time_h >= start if start is not None else np.ones(len(self.time_h), bool)

    def usage_window(self) -> np.ndarray:
        """Mask of the tests of the current unit: since the last replacement, and since the last
        fall of the usage count (a replacement not, or not yet, recorded)."""
        ok = np.ones(len(self.time_h), bool)
        replaced = [t for t, _f, act in self.repairs if act == "replace"]
        if replaced:              # a new unit counts its usage from its own zero
            ok &= self.time_h >= max(replaced)
        idx = np.nonzero(ok & np.isfinite(self.usage))[0]
        fell = idx[1:][np.diff(self.usage[idx]) < 0]
        if len(fell):
            ok[:fell[-1]] = False
        return ok

    def usage_per_hour(self) -> float | None:
        """Usage rate [usage unit / h] from a straight line through the tests with usage of the
        current unit (:meth:`usage_window`); None where fewer than 2 tests have one or the usage
        does not grow (no usage RUL to give)."""
        ok = self.usage_window() & np.isfinite(self.usage)
        if ok.sum() < 2 or np.ptp(self.time_h[ok]) <= 0 or np.ptp(self.usage[ok]) <= 0:
            return None
        rate = float(np.polyfit(self.time_h[ok], self.usage[ok], 1)[0])
        return rate if rate > 0 else None


def trend_start_h(repairs, fault: str) -> float | None:
    """Where a fault's trend restarts [h]: its latest maintenance, of it or of ``all``, from
    ``repairs`` of (time_h, fault, ...); None if it has none."""
    times = [t for t, f, *_ in repairs if f in (fault, "all")]
    return max(times) if times else None


def superseded_notes(stored: list[tuple], new: list, shown: int = 5) -> list[str]:
    """One note for the actions of ``new`` (MaintenanceRecord) older than a maintenance of the same
    fault already in ``stored`` (actuator, time_h, fault): they are kept in the log, and the
    trend restarts at the stored one instead (what ``history repair`` says of one action)."""
    logs: dict[str, list] = {}
    for a, t, f in stored:
        logs.setdefault(a, []).append((t, f))
    said = []
    for m in new:
        log = logs.get(m.actuator_id, [])
        if (m.time_h, m.fault) in log:
            continue                                  # already stored: not imported again
        faults = FAULT_KEYS if m.fault == "all" else (m.fault,)
        later = {f: trend_start_h(log, f) for f in faults}
        later = {f: t for f, t in later.items() if t is not None and t > m.time_h}
        if later:
            said.append(f"{m.actuator_id} {m.fault} at {m.time_h:g} h (restarts at "
                        + ", ".join(f"{f} {t:g} h" for f, t in later.items()) + ")")
    if not said:
        return []
    more = f" and {len(said) - shown} more" if len(said) > shown else ""
    return [f"{len(said)} maintenance action(s) are older than a maintenance already recorded for the same "
            f"fault, where the trend restarts instead; they are kept in the log only: "
            + "; ".join(said[:shown]) + more]


@dataclass
class History:
    actuators: dict = field(default_factory=dict)   # id -> ActuatorHistory
    #: the usage-clock view, computed at its first use (:func:`clock.on_usage_clock`)
    _usage_clock: tuple | None = field(default=None, repr=False, compare=False)


def history_from_records(recs: list[HealthRecord], repairs: list[tuple], floor: float) -> History:
    """Arrays per actuator; a std not stated is :func:`fill_missing_std`'s (at least ``floor``)."""
    by: dict[str, list[HealthRecord]] = {}
    for r in recs:
        by.setdefault(r.actuator_id, []).append(r)
    h = History()
    for a, rs in by.items():
        rs = sorted(rs, key=lambda r: r.time_h)
        fill_missing_std(rs, floor, [(t, f) for (aa, t, f, _act) in repairs if aa == a])
        h.actuators[a] = ActuatorHistory(
            a, np.array([r.time_h for r in rs], float), np.array([r.k for r in rs], float),
            np.array([r.std for r in rs], float),
            np.array([np.nan if r.usage is None else r.usage for r in rs], float),
            [(t, f, act) for (aa, t, f, act) in repairs if aa == a])
    return h


def fill_missing_std(recs: list[HealthRecord], floor: float, repairs=()) -> None:
    """Standard errors not stated, in place: the scatter of the actuator's whole series about a
    smooth trend (:func:`noise_estimate`, 1.4826 MAD of second differences / sqrt(6)), at least
    ``floor`` (``history.default_std``). ``recs``: one actuator's tests in time order. Estimated
    when read, from every test held -- a test imported alone has no scatter of its own.
    ``repairs``: (time_h, fault) of its maintenance; no difference spans one of the fault (5 tests
    before and 5 after a repair read 0.0204 for a true 0.005: an independent probe, 2026-11-29)."""
    times = np.array([r.time_h for r in recs], float)
    for i in range(3):
        if all(r.std[i] is not None for r in recs):
            continue
        starts = np.searchsorted(times, [t for t, f in repairs if f in (FAULT_KEYS[i], "all")], "left")
        est = noise_estimate(np.array([r.k[i] for r in recs], float), starts)
        fill = max(floor, est) if math.isfinite(est) else floor
        for r in recs:
            if r.std[i] is None:
                r.std = tuple(fill if j == i else v for j, v in enumerate(r.std))


#: What an out-of-order refusal says to do, on the command line (the monitor says its own knobs).
BACKFILL_HINT = "a test older than the latest stored one goes in with --backfill"


class DuplicateRow(PrognosticsError):
    """A test at an actuator's time that is taken already (a caller may say how to give it another):
    ``record`` the refused test, ``held`` the one of the same batch before it at that time (None: the
    history's, or not known)."""

    def __init__(self, message: str, record: "HealthRecord | None" = None, held: "HealthRecord | None" = None):
        super().__init__(message)
        self.record, self.held = record, held


def check_order(items: list[tuple[str, HealthRecord]], latest: dict | None = None) -> None:
    """Times must increase strictly per actuator within a batch (and after ``latest``). A usage
    that falls is not refused: :func:`usage_fall_notes` says it (a replaced unit's first tests
    may come before its replacement is known)."""
    last: dict[str, tuple[float, str, HealthRecord | None]] = {}
    for where, r in items:
        prev = last.get(r.actuator_id)
        if prev is None and latest and r.actuator_id in latest:
            prev = (latest[r.actuator_id], "the history", None)
        if prev is not None:
            t0, w0, r0 = prev
            if r.time_h == t0:
                raise DuplicateRow(f"{where}: duplicate row: actuator {r.actuator_id} already has a test at "
                                   f"time_h={r.time_h:g} ({w0})", r, r0)
            if r.time_h < t0:
                hint = f"; {BACKFILL_HINT}" if w0 == "the history" else ""
                raise PrognosticsError(f"{where}: times out of order: actuator {r.actuator_id} test at "
                                       f"time_h={r.time_h:g} comes after one at {t0:g} ({w0}){hint}")
        last[r.actuator_id] = (r.time_h, where, r)


def usage_fall_notes(tests: dict[str, list[tuple[float, float, bool]]], replaced: dict[str, list[float]]) -> list[str]:
    """One note per actuator whose usage count falls between two consecutive tests that carry
    one (in time order), where no replacement in ``replaced`` (:func:`replacements`) lies after
    the higher count and at or before the lower, and one of the two is new.

    ``tests``: actuator -> (time_h [h], usage, new: whether the test is being added; the others
    are stored). A usage counts up from new (flight hours or cycles); it falls at a
    replacement, whose first tests may be appended before it is recorded, or by a typing error.
    Such a test is kept either way, and the usage rate counts from the fall
    (:meth:`ActuatorHistory.usage_per_hour`); the note says which and what to do."""
    notes = []
    for a, seq in tests.items():
        seq = sorted(seq, key=lambda x: x[0])
        for (t0, u0, new0), (t1, u1, new1) in zip(seq, seq[1:]):
            if u1 >= u0 or not (new0 or new1) or replaced_between(replaced, a, t0, t1):
                continue
            if new1:
                notes.append(f"usage falls for actuator {a}: {u1:g} at time_h={t1:g} after {u0:g} at time_h={t0:g}"
                             f"{'' if new0 else ' in the history'}; kept, and the usage rate counts from it. A "
                             f"replaced unit: record it (eha-health history repair --actuator {a} --fault all "
                             f"--action replace --time-h T) or give it in a MAINTENANCE.csv; else correct the usage")
            else:
                notes.append(f"usage falls for actuator {a}: the stored test at time_h={t1:g} has {u1:g}, below the "
                             f"{u0:g} of the test back-filled at time_h={t0:g}; kept: correct the usage if it is "
                             f"a typing error")
            break
    return notes


def batch_usage_notes(records: list[HealthRecord], maintenance: list | None = None) -> list[str]:
    """:func:`usage_fall_notes` of a batch read alone (a HISTORY.csv with its MAINTENANCE.csv)."""
    tests: dict[str, list] = {}
    for r in records:
        if r.usage is not None:
            tests.setdefault(r.actuator_id, []).append((r.time_h, r.usage, True))
    return usage_fall_notes(tests, replacements(maintenance))


@dataclass
class MaintenanceRecord:
    """One maintenance action: ``fault`` gm, fsj, bkl or all; ``action`` repair or replace (a
    new part or unit: a usage count restarts from zero); ``time_h`` operating hours [h]. The
    fault's trend restarts there (:func:`trend_start_h`)."""
    actuator_id: str
    time_h: float
    fault: str
    action: str = "repair"
    note: str | None = None
    wall_time_utc: str | None = None


def check_maintenance(m: MaintenanceRecord, where: str) -> None:
    """A valid action: a known fault and action, a finite time >= 0 [h], a good actuator id."""
    check_actuator_id(m.actuator_id, where)
    if m.fault not in MAINT_FAULTS:
        raise PrognosticsError(f"{where}: unknown fault {m.fault!r}: choose gm, fsj, bkl or all")
    if m.action not in ACTIONS:
        raise PrognosticsError(f"{where}: unknown maintenance action {m.action!r}: choose repair or replace")
    if not isinstance(m.time_h, (int, float)) or not math.isfinite(m.time_h) or not 0 <= m.time_h <= MAX_TIME_H:
        raise PrognosticsError(f"{where}: repair time_h must be a number of hours in [0, {MAX_TIME_H:g}], "
                               f"got {m.time_h!r}")


def check_maintenance_time(m: MaintenanceRecord, latest: dict[str, float], where: str, source) -> None:
    """An action of an actuator with tests, not after its latest one (a repair "in the future"):
    ``latest``, each actuator's latest test time [h] in ``source`` (a store, a HISTORY.csv)."""
    at = f"{where}: " if where else ""
    if m.actuator_id not in latest:
        raise PrognosticsError(f"{at}unknown actuator {m.actuator_id!r}: it has no tests in {source}")
    if m.time_h > latest[m.actuator_id]:
        raise PrognosticsError(f"{at}repair at time_h={m.time_h:g} is in the future: the latest test of "
                               f"{m.actuator_id} is at {latest[m.actuator_id]:g} h (append the post-repair "
                               f"test first)")


def replacements(maintenance: list[MaintenanceRecord] | None) -> dict[str, list[float]]:
    """Actuator -> the times [h] of its replacements (where a usage count restarts)."""
    out: dict[str, list[float]] = {}
    for m in maintenance or ():
        if m.action == "replace":
            out.setdefault(m.actuator_id, []).append(m.time_h)
    return out


def replaced_between(replaced: dict[str, list[float]], actuator_id: str, after_h: float, upto_h: float) -> bool:
    """Whether ``replaced`` (:func:`replacements`) holds a replacement of the actuator in
    (after_h, upto_h]: a usage count may fall there (the new unit counts from zero)."""
    return any(after_h < t <= upto_h for t in replaced.get(actuator_id, ()))
