"""The clock wear is fitted against: operating hours (``time_h``), or usage (flight hours, cycles).

``prognosis.clock: usage`` (``prognose --clock usage``): where wear follows the usage -- flight
cycles, say -- and the usage does not grow evenly with the operating clock (a fleet that flies in
seasons, tests at the checks between them), a trend in hours bends where the flying did and its
extrapolation is off. On the usage clock the degradation models of :mod:`degradation` see the
wear against what drives it; the RUL comes out in usage units, and in hours as the time the
usage takes to grow by it. The usage is taken to go on as it went: U(t) = u' t + W(v t), u' the
actuator's usage rate [usage/h] (:meth:`records.ActuatorHistory.usage_per_hour`: a straight line
through its tests' usage) and v [usage^2/h] the long-run variance of its growth about that line
(:func:`usage_variance`: its own, or the fleet's pooled where larger); so the hours to use up a usage RUL R are inverse Gaussian, IG(R / u',
R^2 / v) (the first passage of a Wiener process with drift), with u' itself drawn about its
estimate with sd sqrt(v / span) (the rate measured over the history's span), per Monte Carlo
sample with common random numbers (``SeedSequence([prognosis.seed, 3])``). v = 0 (usage as even as the
hours) gives R / u'. Times of past tests (onset, tests set aside, an unrecorded repair) are given
back in hours.

Per actuator, the tests that count are those of the current unit (since its last replacement,
or the last fall of its usage count: :meth:`records.ActuatorHistory.usage_window`); each must
carry a usage. Tests at the same usage (no flying between two checks) are one test on this
clock: their K are merged, weighted by 1/std^2 (std of the mean 1/sqrt(sum 1/std^2)) -- never
across a repair (one on the ground between two checks): there the later test is put just past
the earlier on the clock. A repair restarts a trend at the usage of the first test at or after it.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .config import PrognosticsError
from .records import ActuatorHistory, History


@dataclass(frozen=True)
class UsageClock:
    """One actuator's tests on both clocks, and its usage rate and variance."""
    usage: np.ndarray        # usage of the tests fitted (merged: strictly increasing)
    time_h: np.ndarray       # the operating hours of the same tests (the last of a merged group)
    rate: float              # u': usage per operating hour
    variance: float          # v: long-run variance of the usage growth [usage^2 / h]
    span_h: float            # hours the rate was measured over

    def to_hours(self, usage: float) -> float:
        """Operating hours [h] of a past test at ``usage`` (the clocks' tests interpolated)."""
        return float(np.interp(usage, self.usage, self.time_h))

    def hours(self, rul_usage: np.ndarray, z_rate: np.ndarray, z: np.ndarray, u: np.ndarray) -> np.ndarray:
        """Hours [h] to use up usage RUL samples R (inf stays inf): the rate to come drawn about
        u' with the sd of its estimate, sqrt(v / span) (``z_rate``; at least u' / 10), then
        IG(R / rate, R^2 / v) from the standard normals ``z`` and uniforms ``u``
        (:func:`rul.inverse_gaussian`)."""
        from .rul import inverse_gaussian
        r = np.asarray(rul_usage, float)
        fin = np.isfinite(r) & (r > 0)
        out = np.where(np.isfinite(r), 0.0, np.inf)
        if self.variance <= 0:
            out[fin] = r[fin] / self.rate
            return out
        rate = np.maximum(self.rate + np.sqrt(self.variance / self.span_h) * z_rate[fin], 0.1 * self.rate)
        out[fin] = inverse_gaussian(r[fin] / rate, r[fin] ** 2 / self.variance, z[fin], u[fin])
        return out


def usage_draws(seed: int, m: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Common random numbers of the usage to come (two normals, a uniform) for ``m`` samples."""
    rng = np.random.default_rng([seed, 3])        # faults are 0-2 (rul.Draws)
    return rng.standard_normal(m), rng.standard_normal(m), rng.random(m)


def usage_variance(units: list[tuple[np.ndarray, np.ndarray, float]]) -> float:
    """Long-run variance v [usage^2/h] of the usage about each unit's line, pooled over ``units``
    of (test hours, usage, rate u').

    For blocks of L consecutive test intervals (L = 1, 2, 4, ... while at least 3 blocks fit in
    all), sum (Delta U - u' Delta t)^2 / sum Delta t over every unit's blocks; the largest over
    L. Usage that comes in seasons is correlated from one interval to the next, and its variance
    per hour shows only over intervals as long as a season (the long-run variance of a time
    series, Newey & West 1987); the largest is the safe side. One unit's history holds a season
    or two: its own v reads a tenth of the truth (usage_seasons of tools/prognose_processes.py,
    300-1200 h of 200-h seasons), so the clock takes the fleet's where larger."""
    best, L = 0.0, 1
    while sum((len(t) - 1) // L for t, _u, _r in units) >= 3:
        ss = hours = 0.0
        for t, u, rate in units:
            n = (len(t) - 1) // L
            if n:
                idx = np.arange(0, n * L + 1, L)
                dt, du = np.diff(t[idx]), np.diff(u[idx])
                ss, hours = ss + float(np.sum((du - rate * dt) ** 2)), hours + float(np.sum(dt))
        best = max(best, ss / hours)
        L *= 2
    return best


def _merge_equal(u: np.ndarray, t: np.ndarray, k: np.ndarray, std: np.ndarray, repairs_h):
    """Tests at the same usage as one: K weighted by 1/std^2 per fault -- but never across a
    maintenance (a repair on the ground between two checks): there the later test's clock is
    nudged past the earlier's (by 1e-9 of the usage range), so the trend restarts after it."""
    cut = np.array([np.any((t[j - 1] < np.asarray(repairs_h)) & (np.asarray(repairs_h) <= t[j]))
                    for j in range(1, len(t))], bool) if len(repairs_h) else np.zeros(len(t) - 1, bool)
    starts = np.r_[0, np.nonzero((np.diff(u) > 0) | cut)[0] + 1]
    w = 1.0 / np.square(np.maximum(std, 1e-12))
    ends = np.r_[starts[1:], len(u)]
    km = np.array([np.sum(w[a:b] * k[a:b], 0) / np.sum(w[a:b], 0) for a, b in zip(starts, ends)])
    sm = np.array([1.0 / np.sqrt(np.sum(w[a:b], 0)) for a, b in zip(starts, ends)])
    um = u[starts].astype(float)
    eps = 1e-9 * max(float(np.ptp(u)), 1.0)
    for j in range(1, len(um)):
        um[j] = max(um[j], um[j - 1] + eps)
    return um, t[ends - 1], km, sm


def on_usage_clock(hist: History, required=None) -> tuple[History, dict[str, UsageClock], dict[str, str]]:
    """``hist`` with each actuator's clock the usage of its current unit (module docstring), the
    clocks, and why the actuators left out could not be put on it.

    Raises :class:`PrognosticsError` naming the actuator where a test of its current unit has no
    usage, or where the usage does not grow (no rate to give hours by) -- for the actuators in
    ``required`` (default: all); others that cannot be put on the clock are left out (they
    inform no fleet prior on it) with that reason. Computed once per History (a History is not
    changed once built): the monitor's step asks twice, for the fleet prior and the prognosis."""
    if hist._usage_clock is None:
        hist._usage_clock = _usage_clock(hist)
    out, clocks, refused = hist._usage_clock
    bad = [why for a, why in refused.items() if required is None or a in required]
    if bad:
        raise PrognosticsError(bad[0])
    return out, clocks, dict(refused)


#: Where a usage comes from, on the command line (the monitor says its own knobs).
USAGE_HINT = "(history add --usage, or a usage column); or use --clock time"


def _usage_clock(hist: History) -> tuple[History, dict[str, UsageClock], dict[str, str]]:
    """:func:`on_usage_clock` with every actuator that cannot be put on the clock refused."""
    out, clocks, usage, refused = History(), {}, {}, {}
    for a, h in hist.actuators.items():
        rate, keep = h.usage_per_hour(), h.usage_window()
        missing = keep & ~np.isfinite(h.usage)
        if rate is None or missing.any():
            refused[a] = (f"actuator {a}: the usage clock needs a usage that grows over at least 2 tests "
                          f"{USAGE_HINT}" if rate is None else
                          f"actuator {a}: the usage clock needs a usage at every test of the current unit; the "
                          f"test at time_h={h.time_h[missing][0]:g} has none")
            continue
        u, t, k, std = _merge_equal(h.usage[keep], h.time_h[keep], h.k[keep], h.std[keep],
                                    [tr for tr, _f, _a in h.repairs])
        # a repair restarts the trend at the first test at or after it, on this clock too
        repairs = []
        for tr, f, act in h.repairs:
            after = np.nonzero(t >= tr)[0]
            repairs.append((float(u[after[0]]) if len(after) else float(u[-1]) + 1.0, f, act))
        out.actuators[a] = ActuatorHistory(a, u, k, std, u.copy(), repairs)
        usage[a] = (u, t, rate, (h.time_h[keep], h.usage[keep], rate))
    fleet = usage_variance([x[3] for x in usage.values()])
    for a, (u, t, rate, own) in usage.items():
        clocks[a] = UsageClock(u, t, rate, max(usage_variance([own]), fleet), float(own[0][-1] - own[0][0]))
    return out, clocks, refused
