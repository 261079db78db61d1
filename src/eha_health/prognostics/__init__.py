"""Prognostics: from a history of diagnoses to a remaining useful life with an interval.

Nothing here imports ROS. Modules (docs/prognostics.md has the method and the figures):

* :mod:`.store`       -- SQLite health history (schema v2), HISTORY.csv import
* :mod:`.thresholds`  -- failure thresholds from the reference model and data/prognostics.yaml
* :mod:`.degradation` -- linear / exponential / power / Wiener models on one Kalman filter
* :mod:`.online`      -- the same filter updated one test at a time
* :mod:`.scatter`     -- a history's own checks: failed diagnoses, unrecorded repairs, its noise
* :mod:`.clock`       -- the usage clock: wear against usage, hours from the usage rate
* :mod:`.rul`         -- RUL distributions per fault and overall, ``prognose``, ``plot_prognosis``
* :mod:`.prior_cache` -- the fleet prior kept up to date one actuator at a time (the monitor)
* :mod:`.metrics`     -- PHM metrics (alpha-lambda, prognostic horizon, RA, CRA, convergence, ...)
* :mod:`.config`      -- settings and :class:`PrognosticsError` (bad input: CLI exit code 2)

CLI (:mod:`eha_health.cli.prognostics`): ``history add|list|import|repair`` -> :class:`HistoryStore` methods,
``prognose`` -> :func:`prognose` / :func:`plot_prognosis`, ``thresholds`` ->
:func:`failure_thresholds`; the run-to-failure validation harness (``bench rul``) is
:mod:`eha_health.bench.rul`.
"""
from .config import PrognosticsError, Settings, load_settings
from .rul import plot_prognosis, prognose
from .store import HealthRecord, History, HistoryStore, default_history_path, read_history_csv
from .thresholds import failure_thresholds, threshold_values


__all__ = ["HealthRecord", "History", "HistoryStore", "PrognosticsError", "Settings",
           "default_history_path", "failure_thresholds", "load_settings", "plot_prognosis", "prognose",
           "read_history_csv", "threshold_values"]
