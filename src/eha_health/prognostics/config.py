"""Prognostics settings: ``data/prognostics.yaml`` read into typed frozen dataclasses.

One source of truth: every default lives in the YAML shipped with the package (read with
``physics.yamlfile.safe_load``: safe, and a key written twice is refused); the dataclasses carry
the unit and a one-line doc of each field in its metadata. :func:`load_settings` reads the shipped
file, optionally merged with a user YAML of the same structure (partial allowed) and a nested
``overrides`` dict.
"""
from __future__ import annotations

import copy
import dataclasses
import functools
import math
import typing
from dataclasses import dataclass, field, fields, is_dataclass
from importlib import resources
from pathlib import Path
from typing import Any

import yaml

from ..physics.faults import FAULT_KEYS, FAULT_UPPER
from ..physics.yamlfile import safe_load


class PrognosticsError(ValueError):
    """Bad input to the prognostics (history, settings, arguments): a one-line message naming it.

    The CLI prints the message and exits with code 2.
    """


def _f(unit: str, doc: str):
    return field(metadata={"unit": unit, "doc": doc})


# ----------------------------------------------------------------------------- blocks
@dataclass(frozen=True)
class Requirement:
    """A requirement on the reference EHA's FDI response: ``metric <= limit``."""
    name: str = _f("-", "requirement name")
    metric: str = _f("-", "metric of eha_health.prognostics.thresholds.METRICS")
    limit: float = _f("metric's unit", "largest admissible value of the metric (SI)")


@dataclass(frozen=True)
class ThresholdSettings:
    default: float = _f("-", "K where no requirement is set or none breaks")
    search_max: float = _f("-", "upper end of the K search")
    scan_points: int = _f("-", "K values scanned before the root is refined")
    tolerance: float = _f("-", "bisection tolerance on K")


@dataclass(frozen=True)
class HistorySettings:
    default_path: str = _f("path", "history database used when none is given")
    default_std: float = _f("-", "floor of the 1-sd of K estimated for a test without one "
                               "(a HISTORY.csv row without std columns)")


@dataclass(frozen=True)
class PrognosisSettings:
    min_tests: int = _f("-", "tests since the last repair below which no RUL is given")
    next_check_h: float = _f("h", "default interval to the next check")
    clock: str = _f("-", "what wear is fitted against: time (time_h, operating hours) or usage (the tests' "
                         "usage: flight hours, cycles); the RUL is in hours either way (prognostics/clock.py)")
    warn_p_fail: float = _f("-", "p_fail_next at or above which the monitor reports WARN")
    error_p_fail: float = _f("-", "p_fail_next at or above which the monitor reports ERROR")
    onset_sigma: float = _f("-", "onset: rise over the first post-repair K in standard errors")
    onset_delta: float = _f("-", "onset: smallest rise of K")
    onset_candidates: int = _f("-", "onset times weighed by the evidence, from the first post-repair test to the anchor")
    onset_chi2: float = _f("-", "onset where no single test clears the first: the tests' rise as a whole (hinge over level), gain in chi^2 (0: off)")
    outlier_sigma: float = _f("-", "a test this many scatter sd off its neighbours' median is set aside (0: never, and no unrecorded repair)")
    outlier_min_jump: float = _f("-", "smallest K distance from the neighbours' median for a test to be set aside")
    repair_fall: float = _f("-", "a fall of K that persists by at least this (and outlier_sigma sd) is an unrecorded repair")
    shared_wear_alpha: float = _f("-", "faults whose test-to-test increments move together at this one-sided significance: the overall p95 holds for any positive dependence between them (0: faults independent)")
    samples: int = _f("-", "Monte Carlo samples per RUL distribution")
    horizon_factor: float = _f("-", "RUL horizon in data spans")
    seed: int = _f("-", "seed of the Monte Carlo sampling")
    min_std: float = _f("-", "smallest 1-sd of K the models take a test to have (a smaller stated one, or 0, is raised to it)")


@dataclass(frozen=True)
class ModelSettings:
    names: tuple = _f("-", "degradation models fitted (linear, exponential, power, hyperbolic, wiener)")
    criterion: str = _f("-", "model weights: aicc (Akaike weights) or evidence (Bayesian evidence on the grid)")
    aic_delta_max: float = _f("-", "criterion difference beyond which a model gets no weight")
    stochastic_prior: float = _f("-", "prior probability of the Wiener model (the path models share the rest)")
    exponential_rate: tuple = _f("1/span", "grid of the exponential model's rate b")
    power_exponent: tuple = _f("-", "grid of the power model's exponent b")
    hyperbolic_blowup: tuple = _f("span", "grid of the hyperbolic model's blow-up time c (> 1, in data spans from onset)")
    wiener_exponential_rate: tuple = _f("1/span", "grid of the Wiener model's exponential time-scale rate b")
    wiener_exponent: tuple = _f("-", "grid of the Wiener model's power time-scale exponent b")
    wiener_hyperbolic_blowup: tuple = _f("span", "grid of the Wiener model's hyperbolic time-scale blow-up c (> 1; [] none)")
    scatter: tuple = _f("-", "grid of the path models' extra iid scatter eta (K)")
    wiener_scatter: tuple = _f("-", "grid of the Wiener model's extra iid scatter eta (K)")
    diffusion: tuple = _f("-", "grid of the Wiener diffusion sigma (K sd over one data span)")
    rate_diffusion: tuple = _f("1/span", "grid of the wear-rate random walk (sd of the rate change over one span, K/span)")


@dataclass(frozen=True)
class FleetSettings:
    min_points: int = _f("-", "points since onset for an actuator to inform the fleet prior")
    min_members: int = _f("-", "fleet members needed for a prior")
    use_below_points: int = _f("-", "actuators with fewer points since onset receive the prior")


@dataclass(frozen=True)
class BenchSettings:
    n_units: int = _f("-", "actuators in the simulated fleet")
    seed: int = _f("-", "seed of the fleet (laws, rates, onsets, noise)")
    laws: tuple = _f("-", "degradation laws drawn in turn (linear, exponential, power, two_phase)")
    life_median_h: float = _f("h", "median time from onset to the threshold (mean path)")
    life_spread: float = _f("-", "sd of log life, unit to unit")
    healthy_fraction: tuple = _f("-", "healthy period before onset, fraction of the life (min, max)")
    volatility: tuple = _f("-", "gamma-process scale nu (K), Var K = nu E K (min, max, log-uniform)")
    second_fault_probability: float = _f("-", "chance that a unit has a slower second fault")
    second_fault_slowdown: tuple = _f("-", "second fault's life relative to the first (min, max)")
    test_interval_h: float = _f("h", "nominal test interval")
    test_jitter: float = _f("-", "test time jitter, fraction of the interval (uniform +-)")
    first_prediction_test: int = _f("-", "first scored prediction (1-based test number)")
    method: str = _f("-", "diagnose() method of every simulated test")
    naive_window: int = _f("-", "points of the naive straight-line baseline")
    alpha: float = _f("-", "accuracy modifier of alpha-lambda and prognostic horizon")
    lambdas: tuple = _f("-", "lambda points of the alpha-lambda metric")


@dataclass(frozen=True)
class Settings:
    """All prognostics settings (data/prognostics.yaml)."""
    requirements: tuple = _f("-", "requirements of the reference EHA (tuple of Requirement)")
    thresholds: ThresholdSettings = _f("-", "threshold search")
    history: HistorySettings = _f("-", "history store")
    prognosis: PrognosisSettings = _f("-", "RUL prediction")
    models: ModelSettings = _f("-", "degradation models")
    fault_models: tuple = _f("-", "per fault, where set: (fault, ModelSettings) pairs, models: with the "
                                  "fault's entries of fault_models: over them (models_for)")
    fleet: FleetSettings = _f("-", "fleet prior")
    bench: BenchSettings = _f("-", "validation harness")

    def models_for(self, fault: str) -> ModelSettings:
        """The degradation models of ``fault`` (gm, fsj, bkl): ``fault_models.<fault>`` over ``models``."""
        return next((m for f, m in self.fault_models if f == fault), self.models)


# ----------------------------------------------------------------------------- YAML I/O
def _convert(tp, v, where: str):
    if isinstance(tp, type) and is_dataclass(tp):
        return _build(tp, v, where)
    if tp is int:
        if isinstance(v, bool) or not isinstance(v, int):
            raise PrognosticsError(f"{where}: expected an integer, got {v!r}")
        return v
    if tp is float:
        if isinstance(v, str):  # YAML 1.1 reads 1.0e6 without a sign as text
            try:
                v = float(v)
            except ValueError:
                pass
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
            raise PrognosticsError(f"{where}: expected a finite number, got {v!r}")
        return float(v)
    if tp is str:
        if not isinstance(v, str):
            raise PrognosticsError(f"{where}: expected text, got {v!r}")
        return v
    if tp is tuple:
        if not isinstance(v, list):
            raise PrognosticsError(f"{where}: expected a list, got {v!r}")
        return tuple(v)
    return v


def _build(cls, data: Any, where: str):
    if not isinstance(data, dict):
        raise PrognosticsError(f"{where}: expected a mapping, got {type(data).__name__}")
    hints = typing.get_type_hints(cls)
    known = {f.name for f in fields(cls)}
    unknown = sorted(set(data) - known)
    if unknown:
        raise PrognosticsError(f"{where}: unknown setting(s) {unknown}")
    kwargs = {}
    for f in fields(cls):
        if f.name not in data:
            raise PrognosticsError(f"{where}.{f.name}: missing")
        kwargs[f.name] = _convert(hints[f.name], data[f.name], f"{where}.{f.name}")
    return cls(**kwargs)


def _merge(base: dict, over: dict) -> dict:
    out = dict(base)
    for k, v in over.items():
        out[k] = _merge(base[k], v) if isinstance(v, dict) and isinstance(base.get(k), dict) else v
    return out


def _read(path) -> dict:
    try:
        data = safe_load(path.read_text(encoding="utf-8"))
    except (OSError, yaml.YAMLError, UnicodeDecodeError) as e:
        raise PrognosticsError(f"{path}: cannot read settings ({e.__class__.__name__}: {str(e).splitlines()[0]})") \
            from None
    if data is not None and not isinstance(data, dict):
        raise PrognosticsError(f"{path}: settings must be a mapping of sections (thresholds:, prognosis:, ...), "
                               f"got {type(data).__name__}")
    return data or {}


@functools.lru_cache(maxsize=None)
def _packaged() -> dict:
    return _read(resources.files("eha_health") / "data" / "prognostics.yaml")


def load_settings(path: str | Path | None = None, overrides: dict | None = None) -> Settings:
    """Read ``data/prognostics.yaml``, merged with ``path`` (a user YAML) and ``overrides``."""
    data = copy.deepcopy(_packaged())
    if path is not None:
        data = _merge(data, _read(Path(path)))
    if overrides:
        data = _merge(data, overrides)
    reqs = data.get("requirements")
    if not isinstance(reqs, list):
        raise PrognosticsError("requirements: expected a list of {name, metric, limit}")
    data["requirements"] = [_build(Requirement, r, f"requirements[{i}]") for i, r in enumerate(reqs)]
    fm = data.get("fault_models")
    data["fault_models"] = []                # built below, from the models block once that is read
    s = _build(Settings, data, "prognostics")
    s = dataclasses.replace(s, fault_models=_fault_models(data["models"], fm))
    _validate(s)
    return s


def _fault_models(models: dict, per_fault) -> tuple:
    """``fault_models:`` -- per fault, models settings that differ from ``models:`` -- as
    (fault, full ModelSettings) pairs in fault order."""
    if per_fault is None:                    # "fault_models:" with nothing under it
        return ()
    if not isinstance(per_fault, dict):
        raise PrognosticsError(f"fault_models: expected a mapping of fault ({', '.join(FAULT_KEYS)}) to "
                               f"models settings, got {type(per_fault).__name__}")
    unknown = sorted(map(str, set(per_fault) - set(FAULT_KEYS)))
    if unknown:
        raise PrognosticsError(f"fault_models: unknown fault(s) {unknown}; faults: {', '.join(FAULT_KEYS)}")
    out = []
    for f in FAULT_KEYS:
        if f in per_fault:
            over = per_fault[f] if per_fault[f] is not None else {}
            if not isinstance(over, dict):
                raise PrognosticsError(f"fault_models.{f}: expected a mapping of models settings "
                                       f"(names:, grids), got {type(over).__name__}")
            out.append((f, _build(ModelSettings, _merge(models, over), f"fault_models.{f}")))
    return tuple(out)


def _validate(s: Settings) -> None:
    from .thresholds import METRICS   # the metric table lives beside the code that computes it
    for r in s.requirements:
        if r.metric not in METRICS:
            raise PrognosticsError(f"requirement {r.name}: unknown metric {r.metric!r}; known: {', '.join(METRICS)}")
        if not r.limit > 0:
            raise PrognosticsError(f"requirement {r.name}: limit must be > 0 {METRICS[r.metric][0]}")
    p = s.prognosis
    if p.clock not in ("time", "usage"):
        raise PrognosticsError(f"prognosis.clock must be time or usage, got {p.clock!r}")
    if p.min_tests < 3:
        raise PrognosticsError(f"prognosis.min_tests must be >= 3 (a trend needs three points), got {p.min_tests}")
    if not 0 < p.warn_p_fail <= p.error_p_fail <= 1:
        raise PrognosticsError("prognosis: need 0 < warn_p_fail <= error_p_fail <= 1")
    if not p.onset_chi2 >= 0:
        raise PrognosticsError(f"prognosis.onset_chi2 must be >= 0 (0: off), got {p.onset_chi2}")
    if p.onset_candidates < 1:
        raise PrognosticsError(f"prognosis.onset_candidates must be >= 1, got {p.onset_candidates}")
    if not (p.outlier_sigma >= 0 and p.outlier_min_jump >= 0 and p.repair_fall >= 0):
        raise PrognosticsError("prognosis: outlier_sigma, outlier_min_jump and repair_fall must be >= 0 "
                               "(outlier_sigma 0: none set aside, no unrecorded repair)")
    if not 0 <= p.shared_wear_alpha < 1:
        raise PrognosticsError(f"prognosis.shared_wear_alpha must be within [0, 1) (0: off), got {p.shared_wear_alpha}")
    _check(p.next_check_h > 0, "prognosis.next_check_h", p.next_check_h, "> 0 h")
    if not 0 < s.thresholds.default <= s.thresholds.search_max <= FAULT_UPPER:
        raise PrognosticsError(f"thresholds: need 0 < default <= search_max <= {FAULT_UPPER} (the identification bound)")
    t = s.thresholds
    # a tolerance of 0 never ends the bisection; a coarse one moves the threshold (5: K_GM 0.816 -> 0.844)
    _check(0 < t.tolerance <= 0.01, "thresholds.tolerance", t.tolerance, "within (0, 0.01]")
    _check(2 <= t.scan_points <= 1000, "thresholds.scan_points", t.scan_points, "within [2, 1000]")
    _check(s.history.default_std > 0, "history.default_std", s.history.default_std, "> 0")
    _check(p.horizon_factor > 0, "prognosis.horizon_factor", p.horizon_factor, "> 0 (data spans)")
    _check(p.min_std > 0, "prognosis.min_std", p.min_std, "> 0 (a zero variance makes the likelihood singular)")
    _check(p.onset_sigma > 0, "prognosis.onset_sigma", p.onset_sigma, "> 0")
    _check(p.onset_delta >= 0, "prognosis.onset_delta", p.onset_delta, ">= 0")
    _check(p.seed >= 0, "prognosis.seed", p.seed, ">= 0")
    # memory: a batch of 256 series holds samples x 30 floats each
    _check(100 <= p.samples <= 100_000, "prognosis.samples", p.samples, "within [100, 100000]")
    _validate_models(s.models, "models")
    for fault, m in s.fault_models:
        _validate_models(m, f"fault_models.{fault}")
    f = s.fleet
    _check(f.min_points >= 2, "fleet.min_points", f.min_points, ">= 2")
    _check(f.min_members >= 1, "fleet.min_members", f.min_members, ">= 1")
    _check(f.use_below_points >= 0, "fleet.use_below_points", f.use_below_points, ">= 0")
    _check(s.bench.n_units >= 1, "bench.n_units", s.bench.n_units, ">= 1")


def _validate_models(m: ModelSettings, where: str) -> None:
    """Checks of a models block (``models`` or ``fault_models.<fault>``)."""
    known = {"linear", "exponential", "power", "hyperbolic", "wiener"}
    if not m.names:
        raise PrognosticsError(f"{where}.names is empty: name at least one model of {sorted(known)}")
    unknown = [n for n in m.names if not isinstance(n, str) or n not in known]
    if unknown:
        raise PrognosticsError(f"{where}.names: choose from {sorted(known)}, got {unknown!r}")
    if not 0 < m.stochastic_prior < 1:
        raise PrognosticsError(f"{where}.stochastic_prior must be within (0, 1), got {m.stochastic_prior}")
    _check(m.criterion in ("evidence", "aicc"), f"{where}.criterion", m.criterion, "evidence or aicc")
    _check(m.aic_delta_max > 0, f"{where}.aic_delta_max", m.aic_delta_max, "> 0")
    _check(len(set(m.names)) == len(m.names), f"{where}.names", list(m.names), "without a model named twice")
    for name, ok, what in (("exponential_rate", lambda v: v != 0, "finite and not 0"),
                           ("power_exponent", lambda v: v > 0, "> 0"),
                           ("hyperbolic_blowup", lambda v: v > 1, "> 1 (data spans)"),
                           ("wiener_exponential_rate", lambda v: v != 0, "finite and not 0"),
                           ("wiener_exponent", lambda v: v > 0, "> 0"),
                           ("scatter", lambda v: v >= 0, ">= 0"),
                           ("wiener_scatter", lambda v: v >= 0, ">= 0"),
                           ("diffusion", lambda v: v > 0, "> 0"),
                           ("rate_diffusion", lambda v: v >= 0, ">= 0"),
                           ("wiener_hyperbolic_blowup", lambda v: v > 1, "> 1 (data spans)")):
        grid = getattr(m, name)
        # the Wiener model's time scales other than the linear one may be left out ([]: none)
        may_be_empty = name in ("wiener_exponential_rate", "wiener_exponent", "wiener_hyperbolic_blowup")
        _check((may_be_empty or len(grid) > 0) and all(
            isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) and ok(v) for v in grid),
            f"{where}.{name}", list(grid),
            f"a {'list (may be empty)' if may_be_empty else 'non-empty list'} of numbers each {what}")


def _check(ok: bool, name: str, value, need: str) -> None:
    if not ok:
        raise PrognosticsError(f"{name} must be {need}, got {value!r}")


def settings_table(obj: Any, prefix: str = "") -> list[tuple[str, Any, str, str]]:
    """Rows ``(name, value, unit, doc)`` of every setting (for docs)."""
    rows = []
    for f in fields(obj):
        v = getattr(obj, f.name)
        if is_dataclass(v):
            rows += settings_table(v, f"{prefix}{f.name}.")
        elif f.name != "requirements":
            rows.append((prefix + f.name, v, f.metadata.get("unit", ""), f.metadata.get("doc", "")))
    return rows
