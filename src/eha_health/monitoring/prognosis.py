"""The monitor's prognosis step, without ROS: append a diagnosis to the health history, then the
actuator's remaining useful life.

After each diagnosed test window the monitor calls :meth:`PrognosisStep.after_diagnosis`: the
diagnosis is appended to the SQLite history (:class:`~eha_health.prognostics.store.HistoryStore`,
one transaction; the same recording twice adds no row) with its operating time ``time_h``, the
ROS / simulated stamp of the window [s] and the wall clock; then
:func:`~eha_health.prognostics.rul.prognose` for this actuator. The fleet prior (every other
actuator of the history fitted) is fitted only when a fault of this actuator takes it (few points
since its onset), and is cached until the rest of the fleet gains a test. :meth:`PrognosisStep.stop`
(the node shutting down) lets a running step end early: the test is still appended -- unless
the append waits for another writer's lock: it stops waiting, the test is not appended -- the
prognosis is skipped or its fleet-prior fit cut short, and the outcome says so. At the node's start
:meth:`PrognosisStep.stored` gives the RUL of the stored history (nothing appended), stopped the same way;
it may run in another thread than the diagnoses: a test's append does not wait for it, the test's
prognosis does (one prognosis at a time: the fleet prior it fits is cached, the test's reuses it). An append that
waits for the lock says so at once (``on_wait``). A bad
append (times out of order, K out of range, a read-only or unreadable file) never raises: the outcome says
what went wrong and the RUL is that of the stored history.

:func:`rul_values` turns the outcome into the ``/diagnostics`` key values (docs/interfaces.md):
``rul_median_h``, ``rul_p05_h``, ``rul_p95_h``, ``p_fail_next`` overall and with a ``_gm`` /
``_fsj`` / ``_bkl`` suffix per fault, ``dominant_fault``, ``rul_time_h`` (the time they count from: the
actuator's latest stored test, not a refused test's), and per fault where the history's checks
acted ``unrecorded_repair_h_<f>``, ``outliers_h_<f>``, ``last_test_off_trend_<f>``; :meth:`PrognosisStep.level` the level
that P(failure before the next check) calls for.
"""
from __future__ import annotations

import logging
import math
import sqlite3
import threading
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

from ..physics.faults import FAULT_KEYS
from ..prognostics.config import PrognosticsError, Settings, load_settings
from ..prognostics.prior_cache import Cancelled, FleetPriorCache

#: How an append's refusal starts (:attr:`Outcome.error`).
NOT_APPENDED = "not appended to the history: "

#: What a live test refused as a duplicate row says to do: its time is the monitor's to set (probe 11
#: gave no hint; a new simulated session restarts its window stamps at 0, so its first test's time
#: and stamp are those of the previous session's first test).
DUPLICATE_HINT = ("the monitor's operating time is its operating_hours parameter (else the window's stamp in "
                  "hours, which a new simulated session restarts at 0): set operating_hours to this test's "
                  "operating hours")

#: The F fields of ``prognose --json`` the status carries, and the key they become.
RUL_FIELDS = ("rul_median_h", "rul_p05_h", "rul_p95_h", "p_fail_next")
#: Key values of :func:`rul_values` about the test itself; the others are the actuator's RUL.
TEST_KEYS = ("history_appended", "operating_time_h", "history_error")


@dataclass
class Outcome:
    """What one prognosis step did: whether the test was appended, and the actuator's prognosis."""
    appended: bool
    prognosis: dict | None = None     # {"faults": {gm: F, ...}, "overall": F} of prognose --json
    error: str | None = None          # why the append or the prognosis failed (one line)
    time_h: float | None = None       # the test's operating time [h]
    rul_time_h: float | None = None   # the time the RUL counts from: the actuator's latest stored test [h]


@dataclass
class PrognosisStep:
    """Append + prognose for one actuator of a history file (one SQLite connection per call, so any
    thread may call it)."""
    history: str | Path
    actuator_id: str
    next_check_h: float | None = None   # h (default prognosis.next_check_h of data/prognostics.yaml)
    warn_p_fail: float | None = None    # P(fail before the next check) for WARN (default prognosis.warn_p_fail)
    error_p_fail: float | None = None   # ... for ERROR (default prognosis.error_p_fail)
    settings: Settings = field(default_factory=load_settings)
    #: hears that an append waits for another writer's lock (default: a warning on stderr)
    on_wait: Callable[[str], None] = field(default=lambda m: logging.getLogger(__name__).warning(m), repr=False)

    def __post_init__(self):
        from ..prognostics.records import check_actuator_id
        from ..prognostics.store import check_writable
        # refused here, at the node's start, rather than at every test (probe 11)
        check_writable(Path(self.history))
        check_actuator_id(self.actuator_id, f"actuator_id for the history {self.history}")
        p = self.settings.prognosis
        self.next_check_h = p.next_check_h if self.next_check_h is None else float(self.next_check_h)
        self.warn_p_fail = p.warn_p_fail if self.warn_p_fail is None else float(self.warn_p_fail)
        self.error_p_fail = p.error_p_fail if self.error_p_fail is None else float(self.error_p_fail)
        if not (math.isfinite(self.next_check_h) and self.next_check_h > 0):
            raise PrognosticsError(f"next_check_h must be a positive number of hours, got {self.next_check_h}")
        if not 0 < self.warn_p_fail <= self.error_p_fail <= 1:
            raise PrognosticsError(f"need 0 < warn_p_fail ({self.warn_p_fail}) <= error_p_fail "
                                   f"({self.error_p_fail}) <= 1")
        self._stopping = threading.Event()
        self._priors = FleetPriorCache(self.settings, cancelled=self._stopping.is_set)
        # one prognosis at a time on the cache, whichever thread (the monitor's start prognosis has one
        # of its own): a second would fit the same prior again, and the cache is not thread-safe
        self._lock = threading.Lock()

    def stop(self) -> None:
        """From any thread: the running and later steps append their test but skip the prognosis
        (a fleet-prior fit of ~10 s on 1000 actuators would hold up the node's shutdown); an append
        waiting for another writer's lock (up to 60 s) gives up, its test not appended."""
        self._stopping.set()

    def after_diagnosis(self, diagnosis, time_h: float, sim_time_s: float | None = None, response=None,
                        discrepancy: str | None = None, usage: float | None = None,
                        log_path: str | Path | None = None) -> Outcome:
        """Append ``diagnosis`` at operating time ``time_h`` [h] (window stamp ``sim_time_s`` [s]; ``log_path``:
        the MCAP log the test is being recorded into, its row's ``source_path``), then prognose."""
        from ..prognostics.records import DuplicateRow
        from ..prognostics.store import HistoryStore, ReadOnlyHistory
        out = Outcome(False, time_h=time_h)

        def run():
            try:
                st = HistoryStore(self.history, self.settings, cancelled=self._stopping.is_set,
                                  on_wait=self.on_wait)
            except ReadOnlyHistory as e:   # a read-only medium: no append, the stored history's RUL
                out.error = f"{NOT_APPENDED}{e}"
                if not Path(self.history).is_file():   # no stored history: the read would hide why
                    return
                st = HistoryStore(self.history, self.settings, readonly=True)
            with st:
                try:
                    if not st.readonly:
                        out.appended = st.add_diagnosis(diagnosis, self.actuator_id, time_h, usage=usage,
                                                        response=response, sim_time_s=sim_time_s,
                                                        discrepancy=discrepancy, log_path=log_path)
                except PrognosticsError as e:   # e.g. times out of order: the stored history stays
                    out.error = f"{NOT_APPENDED}{e}" + (f"; {DUPLICATE_HINT}" if isinstance(e, DuplicateRow) else "")
                # the append did not wait for the start's stored prognosis (its own connection); the
                # prognosis does: it needs the fleet prior that one may be fitting, and reuses it
                with self._lock:
                    self._prognose(st, out)
        return self._guarded(out, run)

    def stored(self) -> Outcome | None:
        """The RUL of the stored history, nothing appended (the monitor's start, before its first
        test: probe 11); None when the history holds no test of this actuator."""
        from ..prognostics.store import HistoryStore
        if not Path(self.history).is_file():
            return None
        with self._lock:
            out = Outcome(False)

            def run():
                with HistoryStore(self.history, self.settings, readonly=True) as st:
                    self._prognose(st, out)
            self._guarded(out, run)
            return None if out.prognosis is None and out.error is None else out

    def _prognose(self, st, out: Outcome) -> None:
        from ..prognostics.rul import prognose
        if self._stopping.is_set():
            raise Cancelled("prognosis skipped")
        hist = st.history()
        if self.actuator_id in hist.actuators:
            obj = prognose(hist, self.actuator_id, self.next_check_h, self.settings, priors=self._priors)
            out.prognosis = obj["actuators"][self.actuator_id]
            # not this test's time when it was refused: the RUL is the stored history's (probe 11)
            out.rul_time_h = float(max(hist.actuators[self.actuator_id].time_h))

    def _guarded(self, out: Outcome, run: Callable[[], None]) -> Outcome:
        """``run()``, whatever goes wrong said in ``out.error`` (never raised)."""
        try:
            run()
        except Cancelled as e:
            out.error = "; ".join(filter(None, [out.error, f"{e}: the monitor is stopping (`eha-health "
                                                             f"prognose` gives the stored history's RUL)"]))
        except (PrognosticsError, sqlite3.Error, OSError) as e:   # an unreadable, locked or full history file
            out.error = str(e) if isinstance(e, PrognosticsError) else f"history {self.history}: {e}"
        except Exception as e:    # noqa: BLE001 -- the test was diagnosed: a failed prognosis must not
            # read as a failed diagnosis (the node's poll would report the window "not diagnosed")
            out.error = f"prognosis failed: {type(e).__name__}: {' '.join(str(e).split())[:300]}"
        out.error = out.error and in_monitor_terms(out.error)
        return out

    def level(self, outcome: Outcome) -> tuple[str, str | None]:
        """OK / WARN / ERROR from P(failure before the next check) overall, and why."""
        ov = (outcome.prognosis or {}).get("overall") or {}
        p, rel = ov.get("p_fail_next"), "="
        if p is None and ov.get("p_fail_next_min") is not None:
            p, rel = ov["p_fail_next_min"], ">="     # the next check lies beyond the prediction horizon
        if p is None:
            return "OK", None
        if p >= self.error_p_fail:
            level, at = "ERROR", self.error_p_fail
        elif p >= self.warn_p_fail:
            level, at = "WARN", self.warn_p_fail
        else:
            return "OK", None
        # the level's threshold in words, right after the number it judges: "(...) >= 0.2; ... test again
        # >= 0.2" and ">= 0.503 ... >= 0.2" misread (probe 11)
        why = (f"P(failure before the next check in {self.next_check_h:g} h) {rel} {p:.3f}"
               f" (dominant {ov.get('dominant_fault')}, RUL median {_h(ov.get('rul_median_h'))}),"
               f" at or above the {level} level {at:g}")
        off = [f for f, F in (outcome.prognosis or {}).get("faults", {}).items() if F.get("last_test_off_trend")]
        if off:   # half of that probability is a single test: what to do next is to test again
            why += (f"; the last {'/'.join(off)} test is off its trend (a failed diagnosis, or wear that "
                    f"jumped): test again")
        return level, why


def in_monitor_terms(line: str) -> str:
    """A line of the store or of ``prognose`` with the command-line knobs it names said as the
    monitor's (probe 11: the monitor has no --backfill, no --usage, no --clock)."""
    from ..prognostics.clock import USAGE_HINT
    from ..prognostics.records import BACKFILL_HINT
    return line.replace(BACKFILL_HINT, "the monitor's operating time is its operating_hours parameter (else the "
                        "window's stamp in hours); the refused test stays in its MCAP log, which `eha-health history "
                        "add LOG --actuator ID --time-h T --backfill` stores").replace(
        USAGE_HINT, "(the monitor's usage parameter, at each test); or prognosis: {clock: time} in its "
                    "prognostics_settings")


def _h(v) -> str:
    from ..prognostics.rul import format_hours
    return "beyond the horizon" if v is None else f"{format_hours(v)} h"


def history_summary(history, actuator_id: str, outcomes: list[dict], hint: str | None = None) -> dict:
    """What a run's monitor did with the history: ``outcomes`` per diagnosed test (``appended``,
    ``error``) -> counts ``appended``, ``refused`` (not appended, with a reason), ``held`` (the
    history has it already), ``first_refusal`` and a printable ``line`` (ending in ``hint`` where
    a test was refused)."""
    refused = [o for o in outcomes if not o["appended"] and o.get("error")]
    out = {"path": str(history), "actuator_id": actuator_id, "diagnosed": len(outcomes),
           "appended": sum(bool(o["appended"]) for o in outcomes), "refused": len(refused),
           "first_refusal": (f"test {refused[0]['test_id']}: {refused[0]['error'].removeprefix(NOT_APPENDED)}"
                             if refused else None)}
    out["held"] = out["diagnosed"] - out["appended"] - out["refused"]
    line = (f"history {history} (actuator {actuator_id}): {out['appended']} of {out['diagnosed']} diagnosed "
            f"test(s) appended")
    if out["held"]:
        line += f", {out['held']} already in it"
    if refused:
        line += f", {len(refused)} refused (first: {out['first_refusal']})" + (f"; {hint}" if hint else "")
    out["line"] = line
    return out


def rul_values(outcome: Outcome | None) -> dict:
    """The ``/diagnostics`` key values of a prognosis outcome ('none' where there is no RUL)."""
    if outcome is None:
        return {}
    out: dict = {"history_appended": outcome.appended}
    if outcome.time_h is not None:
        out["operating_time_h"] = float(outcome.time_h)
    if outcome.error:
        out["history_error"] = outcome.error
    prog = outcome.prognosis
    if prog is None:
        return out
    if outcome.rul_time_h is not None:
        out["rul_time_h"] = float(outcome.rul_time_h)
    ov = prog["overall"]
    for k in RUL_FIELDS:
        out[k] = "none" if ov.get(k) is None else float(ov[k])
    if ov.get("p_fail_next_min") is not None:
        out["p_fail_next_min"] = float(ov["p_fail_next_min"])
    out["dominant_fault"] = ov.get("dominant_fault") or "none"
    if ov.get("reason"):
        out["rul_reason"] = ov["reason"]
    if ov.get("shared_wear"):    # faults seen wearing together: the overall p95 holds for any dependence
        out["shared_wear"] = "; ".join("+".join(g) for g in ov["shared_wear"])
    for f in FAULT_KEYS:
        F = prog["faults"][f]
        for k in RUL_FIELDS:
            out[f"{k}_{f}"] = "none" if F.get(k) is None else float(F[k])
        if F.get("p_fail_next_min") is not None:
            out[f"p_fail_next_min_{f}"] = float(F["p_fail_next_min"])
        if F.get("reason"):
            out[f"rul_reason_{f}"] = F["reason"]
        # what the history's own checks did (prognostics.scatter), only where they did something
        if F.get("unrecorded_repair_h") is not None:
            out[f"unrecorded_repair_h_{f}"] = float(F["unrecorded_repair_h"])
        if F.get("outliers_h"):
            out[f"outliers_h_{f}"] = ", ".join(f"{t:g}" for t in F["outliers_h"])
        if F.get("last_test_off_trend"):
            out[f"last_test_off_trend_{f}"] = True
    return out


def actuator_rul_values(outcome: Outcome) -> dict:
    """:func:`rul_values` of the actuator's RUL alone, without the keys about the test
    (:data:`TEST_KEYS`): what a status keeps when a later window is not diagnosed."""
    return {k: x for k, x in rul_values(outcome).items() if k not in TEST_KEYS}
