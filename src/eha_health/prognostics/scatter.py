"""Scatter of one fault's history about its trend: the noise level, tests far off it, falls.

Wear is monotone and persists; a diagnosis is noisy and can fail (a disturbed test, a fit in
the wrong basin) and then lies far off its neighbours for one test only; a repair nobody
recorded makes K fall and stay down. The estimates below are robust to failed tests and blind
to the trend:

* :func:`noise_estimate`: 1.4826 MAD of the second differences / sqrt(6) (a second difference
  of white noise of sd s has variance 6 s^2; a smooth trend's is nearly zero).
* :func:`isolated_outliers`: the Hampel identifier (Hampel 1974; Pearson 2002, "Outliers in
  process modeling and identification"): a test is off when |K_i - median(K_{i-2..i+2})| (near
  the ends: also its distance from a robust line through the 4 nearest other tests) exceeds
  ``sigma`` scatter sd (the larger of :func:`noise_estimate` and the test's stated standard
  error) and ``min_jump``. A level shift -- wear that jumped and stays -- moves the running
  median with it and is not flagged; near the end, where the window is cut short, neither is a
  test that every later test agrees with, or one on the line through the tests before it. The last test has no later neighbour to
  confirm it: it is never called an outlier, only reported as off the trend when it lies
  ``sigma`` times further from the line through the tests before it than the earlier tests did
  from theirs, and that far from the test before it.
* :func:`last_persistent_fall`: where K fell and stayed down (medians of 3 tests on each side,
  along the wear rate).
* :func:`first_above_the_rest`: a first test above each of the 3 after it by a repair's fall
  (the test that found the wear, recorded at the repair's time).
"""
from __future__ import annotations

import functools
import math
import statistics

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view

#: Tests needed before any is called an outlier: the scale needs >= 4 second differences
#: of which one outlier spoils at most 3.
MIN_TESTS = 8


def _median(x: np.ndarray, axis: int | None = None):
    """``np.median(x)`` of a 1-D float array, or ``np.median(x, axis=1)`` of a 2-D one, the same
    value to the bit: np.median's own steps (the partition at the same kth, NaN last; the mean of
    the one or two middle values by ``np.add.reduce`` and a division by their count; the NaN
    partitioned last where there is one) without its general path (dispatch, axis and keepdims
    handling, np.mean's checks): ~6-9 us a call instead of ~20-25 us on the short series of a
    fault's tests, of which a 1000-actuator prognosis makes ~39000."""
    n = x.shape[-1]
    if n == 0 or x.ndim != (1 if axis is None else 2):
        return np.median(x, axis=axis)
    h = n // 2
    part = np.partition(x, [h - 1, h, -1] if n % 2 == 0 else [h, -1], axis=-1)
    mid = part[..., h - 1:h + 1] if n % 2 == 0 else part[..., h:h + 1]
    m = np.add.reduce(mid, axis=-1) / mid.shape[-1]
    if part.ndim == 1:
        return part[-1] if np.isnan(part[-1]) else m
    return np.where(np.isnan(part[:, -1]), part[:, -1], m)


@functools.lru_cache(maxsize=None)
def _pairs(n: int) -> tuple[np.ndarray, np.ndarray]:
    """``np.triu_indices(n, 1)``, made once per n (read-only)."""
    a, b = np.triu_indices(n, 1)
    a.flags.writeable = b.flags.writeable = False
    return a, b


def noise_estimate(k: np.ndarray, starts=()) -> float:
    """1-sd of the scatter of a series about a smooth trend [units of k]: 1.4826 MAD(second
    differences) / sqrt(6); NaN with fewer than 3 second differences (5 points). ``starts``:
    indices where a new trend begins (a repair): no difference spans one, so a repair's fall is
    not read as scatter."""
    k = np.asarray(k, float)
    cuts = sorted({int(i) for i in starts if 0 < int(i) < len(k)})
    d2 = np.concatenate([np.diff(seg, 2) for seg in np.split(k, cuts) if len(seg) >= 3] or [np.empty(0)])
    if len(d2) < 3:
        return float("nan")
    return float(_noise_rows(d2[None, :])[0])


def _mad(x: np.ndarray) -> np.ndarray:
    """1.4826 MAD of each row of ``x`` [rows, m] (_median's of a row are np.median's of it)."""
    return 1.4826 * _median(np.abs(x - _median(x, axis=1)[:, None]), axis=1)


def _noise_rows(d2: np.ndarray) -> np.ndarray:
    """:func:`noise_estimate` from the second differences ``d2`` [rows, m] of each row."""
    return _mad(d2) / math.sqrt(6.0)


def _theil_sen_at(t: np.ndarray, k: np.ndarray, t_at: np.ndarray) -> np.ndarray:
    """K at ``t_at`` of the Theil-Sen lines (median of the pairwise slopes; Sen 1968) through
    each row of ``t``, ``k`` [rows, points]."""
    a, b = _pairs(t.shape[1])
    slope = _median((k[:, b] - k[:, a]) / (t[:, b] - t[:, a]), axis=1)
    return _median(k - slope[:, None] * t, axis=1) + slope * t_at


def _distance(t: np.ndarray, k: np.ndarray, half_window: int) -> np.ndarray:
    """How far each test of each row of ``t, k`` [rows, n] lies from what its neighbours say it
    should read [K].

    Inside: from the median of the 2 hw + 1 tests around it. Near the ends that window lags a
    trend, and a line lags a kink (the onset): there the smaller distance from the median of the
    (truncated) window and from the Theil-Sen line through the 2 hw nearest other tests, at its time.
    """
    (rows, n), hw, w = k.shape, half_window, 2 * half_window
    d = np.empty((rows, n))
    inner = _median(sliding_window_view(k, w + 1, axis=-1).reshape(-1, w + 1), axis=1).reshape(rows, -1)
    d[:, hw:n - hw] = np.abs(k[:, hw:n - hw] - inner)
    ends = np.r_[np.arange(hw), np.arange(n - hw, n)]
    j = np.array([[m for m in range(lo, lo + w + 1) if m != i]
                  for i, lo in ((i, min(max(i - hw, 0), n - w - 1)) for i in ends)])
    line = np.abs(k[:, ends] - _theil_sen_at(t[:, j].reshape(-1, w), k[:, j].reshape(-1, w),
                                             t[:, ends].reshape(-1)).reshape(rows, -1))
    med = np.array([[statistics.median(kr[max(i - hw, 0):i + hw + 1].tolist()) for i in ends] for kr in k])
    d[:, ends] = np.minimum(np.abs(k[:, ends] - med), line)
    return d


def isolated_outliers(t: np.ndarray, k: np.ndarray, std: np.ndarray, sigma: float, min_jump: float,
                      half_window: int = 2) -> tuple[np.ndarray, bool]:
    """(mask of the tests to set aside, whether the last test is off the trend).

    ``t`` [h] strictly increasing, ``k``, ``std``: the fault's coefficients and their standard
    errors; ``sigma`` (<= 0: no test is set aside) and ``min_jump`` [K] as in the module docstring.
    The last test is judged by how far it lies from the line through the 2 hw tests before it,
    against how far the earlier tests lay from theirs: wear that varies from test to test (a
    gamma or Wiener process, an accelerating law) is not called off the trend.
    """
    return isolated_outliers_of([(t, k, std)], sigma, min_jump, half_window)[0]


def isolated_outliers_of(series: list[tuple[np.ndarray, np.ndarray, np.ndarray]], sigma: float,
                         min_jump: float, half_window: int = 2) -> list[tuple[np.ndarray, bool]]:
    """:func:`isolated_outliers` of each (t, k, std) of ``series``, those of equal length judged
    together (:func:`by_length`)."""
    series = [tuple(np.asarray(v, float) for v in x) for x in series]
    found = by_length(series, MIN_TESTS if sigma > 0 else math.inf,
                      lambda t, k, std: _outliers(t, k, std, sigma, min_jump, half_window))
    return [(np.zeros(len(x[1]), bool), False) if f is None else f for x, f in zip(series, found)]


def _outliers(t: np.ndarray, k: np.ndarray, std: np.ndarray, sigma: float, min_jump: float,
              half_window: int) -> list[tuple[np.ndarray, bool]]:
    """:func:`isolated_outliers` of each row of ``t, k, std`` [rows, n] (n >= MIN_TESTS, sigma > 0)."""
    n = k.shape[1]
    scale = np.maximum(_noise_rows(np.diff(k, 2, axis=-1))[:, None], std)
    # near the ends the distance is an extrapolation over a step, which wear that varies from
    # test to test (a gamma or Wiener process) spreads: judged against the steps' own scatter
    edge = np.r_[np.arange(half_window), np.arange(n - half_window, n)]
    scale[:, edge] = np.maximum(scale[:, edge], _mad(np.diff(k, axis=-1))[:, None])
    need = np.maximum(sigma * scale, min_jump)
    off = _distance(t, k, half_window) > need
    off[:, -1] = False
    w = 2 * half_window
    near = range(max(n - half_window, w), n - 1)
    for r in np.nonzero(off[:, near.start:near.stop].any(1))[0]:
        for i in near:
            if not off[r, i]:
                continue
            # near the end the window is cut short and holds the tests after i: a test that every
            # later one agrees with is a level that stays (wear that jumped, confirmed), and one on
            # the line through the tests before it is on the trend (a later test is what jumped)
            tr, kr = t[r], k[r]
            on_line = abs(kr[i] - _theil_sen_at(tr[None, i - w:i], kr[None, i - w:i], tr[i:i + 1])[0]) <= need[r, i]
            if on_line or np.all(np.abs(kr[i + 1:] - kr[i]) <= need[r, i]):
                off[r, i] = False
    # each test against the line through the w tests before it; the tests set aside judge nothing
    # (the rows with none set aside judged together)
    last = np.zeros(len(k), bool)
    clean = ~off.any(1)
    if n >= w + 3:
        last[clean] = _off_trend(t[clean], k[clean], scale[clean, -1], need[clean, -1], sigma, min_jump, w)
    for r in np.nonzero(~clean)[0]:
        tc, kc = t[r, ~off[r]], k[r, ~off[r]]
        if len(kc) >= w + 3:
            last[r] = _off_trend(tc[None], kc[None], scale[r:r + 1, -1], need[r:r + 1, -1], sigma, min_jump, w)[0]
    return [(o, bool(x)) for o, x in zip(off, last)]


def _off_trend(tc: np.ndarray, kc: np.ndarray, scale_last: np.ndarray, need_last: np.ndarray, sigma: float,
               min_jump: float, w: int) -> list[bool]:
    """Whether the last test of each row of ``tc, kc`` [rows, m] (m >= w + 3) is off the trend:
    as far again from the line through the w tests before it as ``sigma`` times the earlier tests'
    scatter about theirs, and that far from the test before it."""
    rows = len(kc)
    if not rows:
        return []
    ahead = kc[:, w:] - _theil_sen_at(sliding_window_view(tc[:, :-1], w, axis=-1).reshape(-1, w),
                                      sliding_window_view(kc[:, :-1], w, axis=-1).reshape(-1, w),
                                      tc[:, w:].reshape(-1)).reshape(rows, -1)
    step_scale = 1.4826 * _median(np.abs(ahead[:, :-1]), axis=1)
    # ... and away from the test before it: one that agrees with the last test confirms it
    return [bool(abs(a[-1]) > max(sigma * max(st, sl), min_jump) and abs(kr[-1] - kr[-2]) > nl)
            for a, st, sl, kr, nl in zip(ahead, step_scale, scale_last, kc, need_last)]


def _gather(x: np.ndarray, start: np.ndarray, stop: np.ndarray, width: int) -> np.ndarray:
    """Rows ``x[..., start:stop]`` [..., rows, width] of ``x`` [..., n], NaN-padded (``stop - start <= width``)."""
    idx = start[:, None] + np.arange(width)
    return np.where(idx < stop[:, None], x[..., np.minimum(idx, x.shape[-1] - 1)], np.nan)


def _nanmedian(x: np.ndarray) -> np.ndarray:
    """Median of the numbers of each row (last axis; NaN for a row of none); np.nanmedian, 10x
    faster on short rows."""
    xs = np.sort(x, axis=-1)                                 # NaN sorts last
    c = np.sum(~np.isnan(x), axis=-1)[..., None]
    lo = np.take_along_axis(xs, np.maximum(c - 1, 0) // 2, -1)[..., 0]
    hi = np.take_along_axis(xs, np.maximum(c, 1) // 2 - (c == 0), -1)[..., 0]
    return np.where(c[..., 0] > 0, 0.5 * (lo + hi), np.nan)


def _slopes(t: np.ndarray, k: np.ndarray, start: np.ndarray, stop: np.ndarray, width: int) -> np.ndarray:
    """Theil-Sen slope [K/h] of ``t, k [..., start:stop]`` per row (NaN with fewer than 2 points)."""
    tt, kk = _gather(t, start, stop, width), _gather(k, start, stop, width)
    i, j = _pairs(width)
    with np.errstate(all="ignore"):
        return _nanmedian((kk[..., j] - kk[..., i]) / (tt[..., j] - tt[..., i]))


def _scatter(k: np.ndarray, start: np.ndarray, stop: np.ndarray, width: int) -> np.ndarray:
    """:func:`noise_estimate` of ``k[..., start:stop]`` per row (NaN with fewer than 5 points)."""
    d2 = np.diff(_gather(k, start, stop, width), 2, axis=-1)
    mad = _nanmedian(np.abs(d2 - _nanmedian(d2)[..., None]))
    return np.where(stop - start >= 5, 1.4826 * mad / math.sqrt(6.0), np.nan)


#: (series x tests) per batch of :func:`by_length` (memory ~ 70 x this floats)
_BATCH = 20_000


def first_above_the_rest(k: np.ndarray, std: np.ndarray, sigma: float, min_fall: float, after: int = 3) -> bool:
    """Whether the first test lies above each of the ``after`` tests after it by a repair's fall:
    ``min_fall`` [K] and ``sigma`` times their stated sd [K] (``sigma`` 0: never). Wear does not
    heal: this is the test that found the wear, recorded at the repair's time, or a failed diagnosis."""
    if sigma <= 0 or len(k) < after + 1:
        return False
    need = max(sigma * float(np.median(std[:after + 1])), min_fall)
    return bool(np.all(k[0] - k[1:after + 1] > need))


def last_persistent_fall(t: np.ndarray, k: np.ndarray, std: np.ndarray, sigma: float, min_fall: float,
                         window: int = 3) -> int | None:
    """Index of the first test after the latest fall of K that persists, or None.

    Wear does not heal: when test i and the median of the (up to) ``window`` tests from i on lie
    below the median of the ``window`` tests before i, and below that of the ``window`` tests
    before those, by more than ``sigma`` scatter sd and ``min_fall`` [K], with at least 2 tests
    from i on, the actuator was repaired or replaced at i (a repair the history does not hold).
    One failed diagnosis moves no median; a burst of them that ends falls back to the level
    before it, not below; nor are two low among three a fall: the median of the (up to)
    ``4 window`` tests from i on must lie as far below; with only 2 tests from i on, both must
    (their mean is one failed diagnosis' to move). Test i, as read, must also lie below the
    median of the tests before it by half as much: a plateau (no wear for a while) carried
    along the rate reads as a fall. Each median is of the levels carried to
    t_i [h] along the wear rate b = max(0, min(Theil-Sen slopes of the ``2 window`` tests before
    those windows, of those windows, of the ``4 window`` tests from i on -- 0 with fewer than
    ``window`` before or after)): a partial repair of wear that goes on falls below the rising
    trend, not always below the level of six tests earlier. The least slope does not make a fall
    of a bend (convex wear: the earlier one; concave: the later one), nor of a burst (not all of
    them hold it). The scatter sd is the whole series' or, where larger, that of the
    ``8 window`` tests about i (errors that grow with K).
    """
    return last_persistent_falls([(t, k, std)], sigma, min_fall, window)[0]


def last_persistent_falls(series: list[tuple[np.ndarray, np.ndarray, np.ndarray]], sigma: float,
                          min_fall: float, window: int = 3) -> list[int | None]:
    """:func:`last_persistent_fall` of each (t, k, std) of ``series``, those of equal length judged
    together (:func:`by_length`)."""
    series = [tuple(np.asarray(v, float) for v in x) for x in series]
    return by_length(series, window + 2 if sigma > 0 else math.inf,
                     lambda t, k, std: _falls(t, k, std, sigma, min_fall, window))


def by_length(series: list[tuple[np.ndarray, ...]], min_len: float, judge) -> list:
    """``judge(t, k, std)`` of the series of ``series`` with at least ``min_len`` tests, those of
    equal length stacked into rows [series, n] and judged at once (None for the shorter ones).

    A judge's windows depend on the length only, and every median, slope and scale is of its own
    row: each series' result is the one it has alone (the per-series numpy calls were a quarter of
    a 1000-actuator prognosis)."""
    out: list = [None] * len(series)
    same: dict[int, list[int]] = {}
    for j, x in enumerate(series):
        if len(x[1]) >= min_len:
            same.setdefault(len(x[1]), []).append(j)
    for n, js in same.items():
        step = max(1, _BATCH // n)
        for a in range(0, len(js), step):
            part = js[a:a + step]
            for j, r in zip(part, judge(*(np.stack([series[j][c] for j in part]) for c in range(3)))):
                out[j] = r
    return out


def _falls(t: np.ndarray, k: np.ndarray, std: np.ndarray, sigma: float, min_fall: float,
           window: int) -> list[int | None]:
    """:func:`last_persistent_fall` of each row of ``t, k, std`` [series, n] (n >= window + 2)."""
    n, w = k.shape[1], window
    need = np.array([max(sigma * max(noise_estimate(kr) if n >= 5 else 0.0, float(_median(sr))), min_fall)
                     for kr, sr in zip(k, std)])[:, None]
    i = np.arange(w, n - 1)
    lo = np.maximum(i - 2 * w, 0)
    first = np.maximum(lo - 2 * w, 0)
    stop = np.minimum(i + 4 * w, n)
    b = np.fmin(np.fmin(_slopes(t, k, first, lo, 2 * w), _slopes(t, k, lo, i, 2 * w)), _slopes(t, k, i, stop, 4 * w))
    # a rate from at least ``window`` tests on each side: from two, a failed diagnosis or two noisy
    # tests read any slope (a burst of failed diagnoses at the start was made a fall)
    b = np.where((b > 0) & (lo - first >= w) & (stop - i >= w), b, 0.0)
    here = np.fmax(need, sigma * _scatter(k, first, stop, 8 * w))
    ti, ki = t[:, i], k[:, i]

    def carried(start, end, width):                        # K of [start, end) carried to t_i
        return _gather(k, start, end, width) - b[..., None] * (_gather(t, start, end, width) - ti[..., None])

    def level(start, end):                                 # their median
        return _nanmedian(carried(start, end, w))

    def down(start, end, width=w):
        # K from i on carried to t_i: the median of 3 or more; of 2 (the second-to-last test), the
        # higher -- their mean is moved by one failed diagnosis, and a fall shows in both
        x = carried(start, end, width)
        return np.where(end - start >= 3, _nanmedian(x), np.nanmax(x, axis=-1))
    before, after = level(i - w, i), down(i, np.minimum(i + w, n))
    earlier = np.where(i - w > lo, level(lo, np.maximum(i - w, lo)), np.nan)
    # below the tests before the fall, and below those before them: a burst of failed
    # diagnoses that ends falls back to the earlier level only; and down for good, by the median
    # of up to 4 window tests from i on: two failed diagnoses low among three are not a fall
    hit = ((before - after > here) & (before - ki > here)
           & (np.isnan(earlier) | (earlier - after > here)) & (before - down(i, stop, 4 * w) > here))
    # and test i below the tests before it as read, by half as much: carried along the rate, a
    # plateau (no wear for a while) reads as a fall (an independent probe: 8 in 120 such histories)
    hit &= _nanmedian(_gather(k, i - w, i, w)) - ki > 0.5 * here
    return [_latest_fall(i[h].tolist(), kr) for h, kr in zip(hit, k)]


def _latest_fall(hits: list[int], k: np.ndarray) -> int | None:
    """Of the latest run of consecutive hits, the test after the largest single drop (None: no hit)."""
    if not hits:
        return None
    run = [hits[-1]]
    while len(run) < len(hits) and hits[-len(run) - 1] == run[0] - 1:
        run.insert(0, hits[-len(run) - 1])
    return max(run, key=lambda i: k[i - 1] - k[i])
