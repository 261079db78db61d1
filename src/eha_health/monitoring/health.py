"""The health verdict of one test: level (OK / WARN / ERROR), message and key values.

Levels follow the largest fault coefficient against ``warn_level`` and ``error_level``; a
discrepancy report that names a missing effect, or a structured residual no candidate
explains, raises an OK to WARN (the coefficients may be biased) and is said in the message.
The key values are what ``/diagnostics`` carries (docs/interfaces.md); :func:`escalate` adds the
prognosis (:mod:`.prognosis`): P(failure before the next check) may raise the level further.
"""
from __future__ import annotations

from dataclasses import dataclass, field

from ..discrepancy.report import UNEXPLAINED
from ..io.window import NS
from ..physics.faults import FAULT_NAMES


@dataclass(frozen=True)
class Verdict:
    level: str                  # 'OK', 'WARN', 'ERROR' (or 'STALE' before any test)
    message: str
    values: dict = field(default_factory=dict)   # the status key values


@dataclass(frozen=True)
class HealthPolicy:
    """Thresholds on the largest coefficient (dimensionless, 0 healthy, 1 limit)."""
    warn_level: float = 0.3
    error_level: float = 0.7

    def level(self, k) -> tuple[str, str]:
        """Level and reason of the coefficients ``k`` (K_GM, K_FSJ, K_BKL)."""
        worst = max(zip(k, FAULT_NAMES))
        if worst[0] >= self.error_level:
            return "ERROR", f"{worst[1].upper()} = {worst[0]:.3f} >= {self.error_level:g}: near the fault limit"
        if worst[0] >= self.warn_level:
            return "WARN", f"{worst[1].upper()} = {worst[0]:.3f} >= {self.warn_level:g}: degraded"
        return "OK", "healthy"

    def refused(self, test_id: int, error: str) -> Verdict:
        """A window that could not be diagnosed (bad data, or the identification failed)."""
        return Verdict("ERROR", f"test {test_id} not diagnosed: {error}", {"test_id": test_id, "error": error})

    def incomplete(self, test_id: int, why: str) -> Verdict:
        """A window whose samples stopped before its end (a source killed or gone): WARN, not diagnosed."""
        return Verdict("WARN", f"test {test_id} incomplete, not diagnosed: {why}",
                       {"test_id": test_id, "incomplete": why})

    def verdict(self, test_id: int, window_start_ns: int, diagnosis, report=None, filled: dict | None = None) -> Verdict:
        """The verdict of a diagnosed window (``report``: the discrepancy loop's, if it ran; ``filled``:
        samples filled per channel, said in the message)."""
        k = diagnosis.faults.as_tuple()
        level, msg = self.level(k)
        values = {"test_id": test_id}
        if filled:
            n = sum(filled.values())
            msg += f"; {n} lost sample(s) filled (" + ", ".join(f"{c} {k_}" for c, k_ in filled.items()) + ")"
            values["filled_samples"] = n
        if report is not None:
            values["discrepancy"] = report.verdict
            lacks = discrepancy_text(report)
            if lacks:
                msg = lacks + "; " + msg if level == "OK" else msg + "; " + lacks
                level = "WARN" if level == "OK" else level
        for n, v in zip(FAULT_NAMES, k):
            values[n] = v
            values[n + "_std"] = diagnosis.std[n]
        values.update({"fitness": diagnosis.cost, "rms_position_m": diagnosis.rms["position"],
                       "rms_pressure_pa": diagnosis.rms["pressure"], "method": diagnosis.method,
                       "fitness_function": diagnosis.fitness, "evaluations": diagnosis.evaluations,
                       "wall_time_s": diagnosis.wall_time_s, "window_start_s": window_start_ns / NS,
                       "guard": diagnosis.guard or "none",
                       "warnings": "; ".join(diagnosis.warnings) or "none"})
        return Verdict(level, msg, values)


_RANK = {"OK": 0, "WARN": 1, "ERROR": 2}


def escalate(v: Verdict, level: str, why: str | None, values: dict) -> Verdict:
    """``v`` with more key values (the prognosis), raised to ``level`` if that is worse, ``why`` in the message."""
    # after a raised level, a bare "healthy" read as a verdict on the whole: it is the coefficients'
    tail = "coefficients healthy" if v.message == "healthy" else v.message
    msg = v.message if not why else (why + "; " + tail if _RANK[level] > _RANK.get(v.level, 0)
                                     else v.message + "; " + why)
    worst = level if _RANK[level] > _RANK.get(v.level, 0) else v.level
    return Verdict(worst, msg, {**v.values, **values})


def discrepancy_text(report) -> str | None:
    """What a discrepancy report adds to the message, if anything."""
    if report.selected:
        return (f"{report.verdict} (position residual RMS {report.before.rms['position'] * 1e6:.1f} -> "
                f"{report.after.rms['position'] * 1e6:.1f} um; coefficients re-identified with it: " +
                ", ".join(f"{n.upper()}={report.after.values[n]:.3f}" for n in FAULT_NAMES) + ")")
    if report.verdict == UNEXPLAINED:
        # the diagnosis was fitted by a model that misses something: say so, with the evidence
        return f"{report.verdict}; the coefficients may be biased ({report.residual_before.evidence[0]})"
    return None


def results_summary(results: list[dict]) -> str:
    """One line per diagnosed test: the coefficients (and the truth where known) and the time."""
    lines = []
    for r in results:
        d, t = r["diagnosis"], r["truth"]
        est = "  ".join(f"{k.upper()}={d[k]:.3f}" + (f" (truth {t[k]:.3f})" if t else "") for k in FAULT_NAMES)
        lines.append(f"test {r['test_id']}: {est}; {d['wall_time_s']:.2f} s")
    return "\n".join(lines) or "no diagnosis recorded"
