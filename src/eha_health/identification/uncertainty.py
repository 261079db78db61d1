"""Uncertainty of a fitted estimate: the one Gauss-Newton covariance, and what it cannot see.

* :func:`covariance` -- ``s^2 (J'J)^-1`` with ``s^2 = |r|^2 / (m - k)`` (m residuals, k free
  knobs), times an inflation for correlated residuals (:func:`autocorr_inflation`, the
  effective sample size of a coloured residual).
* :func:`model_error` -- the monitor model's measured model-form error
  (``data/model_error.yaml``: the RMS identification error on clean reference runs, which no
  fit residual can reveal), growing with the estimated damage; measured per identification method
  (the whole-test methods stop anywhere in a saw-tooth of the cost in K_BKL, the fast one does not).
* :func:`noise_error` -- what the sensor noise adds beyond the Gauss-Newton term through the
  loop's stick-slip and backlash events, scaled by the position noise measured in the data.
* :func:`twin_warnings` -- "twin cases": correlations above 0.95, or a distinct fault
  combination in a final GA population that fits almost as well.
"""
from __future__ import annotations

import functools
from importlib import resources
from pathlib import Path

import numpy as np

from ..physics.faults import FAULT_NAMES
from ..physics.yamlfile import safe_load

#: The error bars' Jacobian steps this many optimiser steps (0.005 for a coefficient): the
#: slope over the error bars' own scale, not over the finer stick-slip roughness the
#: optimiser's step must resolve.
COVARIANCE_STEP_SCALE = 2.5


def autocorr_inflation(res: np.ndarray, n_channels: int) -> float:
    """Variance inflation 1 + 2 sum(rho_k) of the residual, averaged over channels (Bartlett)."""
    r = res.reshape(-1, n_channels)
    total, weight = 0.0, 0.0
    for c in range(n_channels):
        x = r[:, c] - r[:, c].mean()
        v = float(x @ x)
        if v <= 0:
            continue
        n = len(x)
        f = np.fft.rfft(x, 2 * n)
        ac = np.fft.irfft(f * np.conj(f))[:n] / v
        s = 0.0
        for k in range(1, min(n // 4, 400)):
            if ac[k] < 0.05:
                break
            s += ac[k] * (1 - k / n)
        total += v * (1 + 2 * s)
        weight += v
    return total / weight if weight > 0 else 1.0


def covariance(J: np.ndarray, r: np.ndarray, inflation: float = 1.0) -> np.ndarray:
    """Gauss-Newton covariance ``|r|^2 / (m - k) (J'J)^-1 inflation`` of the k fitted knobs."""
    dof = max(len(r) - J.shape[1], 1)
    try:
        return np.linalg.pinv(J.T @ J) * float(r @ r) / dof * inflation
    except np.linalg.LinAlgError:
        return np.full((J.shape[1], J.shape[1]), np.inf)


def correlation(cov: np.ndarray) -> np.ndarray:
    sd = np.sqrt(np.maximum(np.diag(cov), 0.0))
    with np.errstate(invalid="ignore", divide="ignore"):
        corr = cov / np.outer(sd, sd)
    corr = np.nan_to_num(corr)
    np.fill_diagonal(corr, 1.0)
    return corr


def _coefficients(block: dict, key: str, where: str) -> np.ndarray | None:
    """A ``*_variance`` block: for each coefficient, four values >= 0 (constant, K_GM, K_FSJ, K_BKL)."""
    var = block.get(key)
    if var is None:
        return None
    try:
        c = np.array([[float(v) for v in var[n]] for n in FAULT_NAMES])
    except (KeyError, TypeError, ValueError):
        c = None
    if c is None or c.shape != (3, 4) or not (np.isfinite(c).all() and (c >= 0).all()):
        raise ValueError(f"model error file {where}: {key} needs, for each of {', '.join(FAULT_NAMES)}, "
                         f"four coefficients >= 0 (constant, K_GM, K_FSJ, K_BKL)")
    return c


def _error_block(data: dict, where: str) -> dict:
    """The error terms of one identification method (the file's top level, or one ``methods:`` entry)."""
    def triple(key: str, required: bool) -> tuple[float, float, float]:
        sd = data.get(key)
        if sd is None and not required:
            return (0.0, 0.0, 0.0)
        try:
            vals = tuple(float(sd[n]) for n in FAULT_NAMES)
        except (KeyError, TypeError, ValueError):
            raise ValueError(f"model error file {where}: needs {key} with {', '.join(FAULT_NAMES)}") from None
        if not all(np.isfinite(v) and v >= 0 for v in vals):
            raise ValueError(f"model error file {where}: {key} values must be finite and >= 0, got {vals}")
        return vals

    out = {"model": triple("model_error_sd", True), "noise": triple("noise_error_sd", False),
           "variance": _coefficients(data, "model_error_variance", where),
           "noise_variance": _coefficients(data, "noise_error_variance", where)}
    ref = data.get("noise_reference_m")
    if (any(out["noise"]) or out["noise_variance"] is not None) and not (isinstance(ref, (int, float)) and ref > 0):
        raise ValueError(f"model error file {where}: noise_error_sd needs noise_reference_m > 0 [m]")
    out["noise_reference_m"] = float(ref) if ref else 0.0
    floor = data.get("fit_floor")
    if floor is not None and not (isinstance(floor, (int, float)) and floor > 0):
        raise ValueError(f"model error file {where}: fit_floor must be a number > 0, got {floor!r}")
    out["fit_floor"] = float(floor) if floor is not None else None
    return out


@functools.lru_cache(maxsize=None)
def _error_file(path: str | None, method: str | None = None) -> dict:
    """The error terms of ``method``: its ``methods:`` entry if the file has one, else the top level
    (the default method's, ``fast``, whose fit_floor the guard reads)."""
    where = path or "data/model_error.yaml"
    text = Path(path).read_text() if path else resources.files("eha_health").joinpath(
        "data/model_error.yaml").read_text()
    data = safe_load(text) or {}
    methods = data.get("methods") or {}
    if not isinstance(methods, dict):
        raise ValueError(f"model error file {where}: methods must map a method name to its error terms")
    if method in methods:
        if not isinstance(methods[method], dict):
            raise ValueError(f"model error file {where}: methods.{method} must be a mapping")
        return _error_block(methods[method], f"{where} (methods.{method})")
    return _error_block(data, where)


def _damage(estimate) -> np.ndarray:
    return np.concatenate([[1.0], np.clip(np.asarray(estimate, float), 0.0, None)])


def model_error(path: str | Path | None = None, estimate=None, method: str | None = None) -> np.ndarray:
    """Model-form error of the monitor model, 1 sd per coefficient (data/model_error.yaml).

    Measured on clean reference runs (no noise, so all of it is model mismatch, plus where the
    method's search stops short: the whole-test cost is a saw-tooth in K_BKL); the file records
    the command that made it, per identification ``method`` (its ``methods:`` entry; the top level
    is the default method's). Without ``estimate``: the RMS error over those runs. With the
    estimated (K_GM, K_FSJ, K_BKL) and a ``model_error_variance`` block: the error grows with the
    damage, var_k = c_k0 + c_k1 K_GM + c_k2 K_FSJ + c_k3 K_BKL (non-negative least squares of the
    squared errors on the same runs).
    """
    f = _error_file(str(path) if path else None, method)
    if estimate is None or f["variance"] is None:
        return np.array(f["model"])
    return np.sqrt(f["variance"] @ _damage(estimate))


def noise_error(position_noise_m: float, path: str | Path | None = None, estimate=None,
                method: str | None = None) -> np.ndarray:
    """Error the sensor noise adds beyond the Gauss-Newton term, 1 sd per coefficient.

    Noise inside the loop moves the stick-slip and backlash events, which a local
    linearisation cannot see. Measured as the excess error over noisy reference runs at
    position noise ``noise_reference_m`` (per ``method``, as :func:`model_error`) and scaled
    linearly with the position noise measured in the data [m]. With the estimate and a
    ``noise_error_variance`` block, the excess grows with the damage as the model-form error does.
    """
    f = _error_file(str(path) if path else None, method)
    if f["noise_reference_m"] <= 0:
        return np.zeros(3)
    scale = max(float(position_noise_m), 0.0) / f["noise_reference_m"]
    if estimate is None or f["noise_variance"] is None:
        return np.array(f["noise"]) * scale
    return np.sqrt(f["noise_variance"] @ _damage(estimate)) * scale


def measured_error(estimate, position_noise_m: float, method: str | None = None) -> np.ndarray:
    """What a fit of ``method`` errs beyond its Gauss-Newton term at ``estimate``, 1 sd per
    coefficient: :func:`model_error` and :func:`noise_error` in quadrature (added to the Gauss-Newton
    variance by every error bar of the fault coefficients)."""
    return np.hypot(model_error(estimate=estimate, method=method),
                    noise_error(position_noise_m, estimate=estimate, method=method))


def fit_floor(path: str | Path | None = None) -> float | None:
    """The model's floor of the stage cost (:func:`~.fitness.fdi_stage_residual`): the largest left
    by a diagnosis of the clean reference runs in data/model_error.yaml (None if not measured)."""
    return _error_file(str(path) if path else None)["fit_floor"]


def twin_warnings(corr: np.ndarray, x: np.ndarray, pop=None, pop_cost=None, cost=None) -> list[str]:
    out = []
    for i in range(3):
        for j in range(i + 1, 3):
            if abs(corr[i, j]) > 0.95:
                out.append(f"twin cases: {FAULT_NAMES[i]} and {FAULT_NAMES[j]} are correlated (rho={corr[i, j]:+.2f}); "
                           f"other combinations of the two explain the data almost as well")
    if pop is not None and cost is not None and cost > 0:
        for xp, cp in zip(pop, pop_cost):
            if np.max(np.abs(xp - x)) > 0.1 and cp < 1.05 * cost:
                out.append("twin cases: the GA population holds gm={:.3f} fsj={:.3f} bkl={:.3f} with fitness within "
                           "5 % of the estimate".format(*xp))
                break
    return out
