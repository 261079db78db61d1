"""Prognostics: from a history of diagnoses to a remaining useful life with an interval.

Nothing here imports ROS. Modules (docs/prognostics.md has the method and the figures):

* :mod:`.records`     -- a test and a maintenance action, their checks, the history as arrays
* :mod:`.store`       -- SQLite health history (schema v2)
* :mod:`.history_csv` -- HISTORY.csv and MAINTENANCE.csv: import, export, ``prognose`` from files
* :mod:`.thresholds`  -- failure thresholds from the reference model and data/prognostics.yaml
* :mod:`.degradation` -- linear / exponential / power / Wiener models on one Kalman filter
* :mod:`.online`      -- the same filter updated one test at a time
* :mod:`.scatter`     -- a history's own checks: failed diagnoses, unrecorded repairs, its noise
* :mod:`.dependence`  -- faults that wear together: the test, and the overall interval it widens
* :mod:`.clock`       -- the usage clock: wear against usage, hours from the usage rate
* :mod:`.rul`         -- RUL distributions per fault and overall, ``prognose``, ``plot_prognosis``
* :mod:`.prior_cache` -- the fleet prior kept up to date one actuator at a time (the monitor)
* :mod:`.metrics`     -- PHM metrics (alpha-lambda, prognostic horizon, RA, CRA, convergence, ...)
* :mod:`.config`      -- settings and :class:`PrognosticsError` (bad input: CLI exit code 2)

CLI (:mod:`eha_health.cli.prognostics`): ``history add|list|import|export|repair`` -> :class:`HistoryStore` methods,
``prognose`` -> :func:`prognose` / :func:`plot_prognosis`, ``thresholds`` ->
:func:`failure_thresholds`; the run-to-failure validation harness (``bench rul``) is
:mod:`eha_health.bench.rul`.
"""
from .config import PrognosticsError, Settings, load_settings
from .history_csv import read_history_csv, read_maintenance_csv
from .records import HealthRecord, History, MaintenanceRecord
from .rul import plot_prognosis, prognose
from .store import HistoryStore, default_history_path
from .thresholds import failure_thresholds, threshold_values


__all__ = ["HealthRecord", "History", "HistoryStore", "MaintenanceRecord", "PrognosticsError", "Settings",
           "default_history_path", "failure_thresholds", "load_settings", "plot_prognosis", "prognose",
           "read_history_csv", "read_maintenance_csv", "threshold_values"]
