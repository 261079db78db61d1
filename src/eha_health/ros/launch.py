"""Run plant, command and monitor as three OS processes talking over DDS (``eha-health launch``).

>>> res = launch(Faults(0.4, 0.6, 0.4), tests=1)     # until the monitor has diagnosed one test
"""
from __future__ import annotations

import math
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

from ..identification.diagnose import DEFAULT_METHOD
from ..io.bagrun import logged_history_outcomes, recorded_results
from ..monitoring.health import results_summary
from ..monitoring.prognosis import history_summary
from ..physics.faults import Faults


def _ros_args(params: dict) -> list[str]:
    out = ["--ros-args"]
    for k, v in params.items():
        if isinstance(v, bool):
            v = "true" if v else "false"
        elif isinstance(v, float):
            v = repr(v)
        elif isinstance(v, (list, tuple)):
            v = "[" + ",".join(f"'{x}'" for x in v) + "]"
        out += ["-p", f"{k}:={v}"]
    return out


def _stop(procs: list[subprocess.Popen], grace_s: float = 10.0) -> None:
    """SIGINT (a clean rclpy shutdown), then SIGKILL whatever is left."""
    for p in procs:
        if p.poll() is None:
            p.send_signal(signal.SIGINT)
    end = time.monotonic() + grace_s
    for p in procs:
        try:
            p.wait(timeout=max(0.1, end - time.monotonic()))
        except subprocess.TimeoutExpired:
            p.kill()
            p.wait()


def launch(faults: Faults = Faults(), effects=(), seed: int = 0, tests: int = 1, rate: float = 1.0,
           method: str = DEFAULT_METHOD, log_path: str | Path = "out/launch.mcap", domain_id: int | None = None,
           timeout_s: float = 300.0, namespace: str = "", history: str | Path | None = None,
           actuator_id: str = "eha", prognostics_settings: str | Path | None = None,
           operating_hours: float | None = None) -> dict:
    """Run plant, command and monitor as three OS processes over DDS until ``tests`` are diagnosed.

    The children inherit the environment (the ROS wheels need it); ``domain_id``
    isolates them from other graphs on the machine. ``history``: the monitor appends each
    diagnosis of ``actuator_id`` to this SQLite health history at ``operating_hours`` (one test:
    :func:`check_operating_hours`), else at the test's simulated stamp in hours, and publishes its
    RUL (``prognostics_settings``: a YAML merged over data/prognostics.yaml for it); the result's
    ``history`` says what went in (:func:`~eha_health.monitoring.prognosis.history_summary`).
    """
    if tests < 1:
        raise ValueError(f"tests must be >= 1, got {tests}")
    check_operating_hours(operating_hours, history, tests)
    if domain_id is not None and not 0 <= domain_id <= 232:
        raise ValueError(f"domain id must be in 0..232, got {domain_id}")
    log_path = Path(log_path)
    log_path.parent.mkdir(parents=True, exist_ok=True)
    log_path.unlink(missing_ok=True)
    env = dict(os.environ)
    env.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    if domain_id is not None:
        env["ROS_DOMAIN_ID"] = str(domain_id)
    ns = ["-r", f"__ns:={namespace}"] if namespace else []
    plant_fqn = (namespace.rstrip("/") + "/eha_plant") if namespace else "/eha_plant"
    # the monitor asks for each test once the plant's answers reach it (matched, not only
    # discovered) and the previous verdict is in: no test starts into a half-connected graph
    cmds = {
        "monitor": {"exit_after": tests, "log_path": str(log_path), "plant_node": plant_fqn, "method": method,
                    "request_tests": tests, "actuator_id": str(actuator_id),
                    **({"history": str(Path(history).resolve())} if history else {}),
                    **({"operating_hours": float(operating_hours)} if operating_hours is not None else {}),
                    **({"prognostics_settings": str(Path(prognostics_settings).resolve())}
                       if prognostics_settings else {})},
        "plant": {"k_gm": float(faults.k_gm), "k_fsj": float(faults.k_fsj), "k_bkl": float(faults.k_bkl),
                  "seed": int(seed), **({"effects": list(effects)} if effects else {})},
        "command": {"max_tests": tests, "rate": float(rate)},
    }
    procs = {name: subprocess.Popen([sys.executable, "-m", f"eha_health.ros.{name}", *_ros_args(p), *ns], env=env)
             for name, p in cmds.items()}
    end = time.monotonic() + timeout_s
    try:
        # the monitor exits after `tests` verdicts (the command node, done playing, may exit
        # before it); a child that fails (e.g. a plant refusing its parameters) ends the run at once
        while procs["monitor"].poll() is None and time.monotonic() < end:
            if any(p.poll() not in (None, 0) for p in procs.values()):
                break
            time.sleep(0.1)
        ok = procs["monitor"].returncode == 0
    finally:
        _stop(list(procs.values()))
    results = recorded_results(log_path) if log_path.exists() else []
    ok = ok and len(results) == tests
    hist = None
    if history and log_path.exists():   # the monitor's statuses are in its log
        hist = history_summary(history, actuator_id, logged_history_outcomes(log_path),
                               HOURS_HINT if operating_hours is None else None)
    summary = (results_summary(results) + (f"\n{hist['line']}" if hist else "") + f"\nlog: {log_path}"
               + ("" if ok else f"\nlaunch: FAILED ({len(results)}/{tests} tests diagnosed)"))
    return {"ok": ok, "results": results, "log": str(log_path), "summary": summary, "history": hist,
            "returncodes": {k: p.returncode for k, p in procs.items()}}


#: Said with a refused append of a run without ``operating_hours``.
HOURS_HINT = ("each test's time was its simulated stamp in hours; --operating-hours H gives a run of one test "
               "its operating time")


def check_operating_hours(hours: float | None, history, tests: int) -> None:
    """``operating_hours`` is one time for every test the monitor appends: it needs a history, and
    more than one test would give the second one the first's time (a duplicate, refused)."""
    if hours is None:
        return
    if not history:
        raise ValueError("--operating-hours is the time of the test in the history: it needs --history")
    if not (math.isfinite(hours) and hours >= 0):
        raise ValueError(f"--operating-hours must be a number of hours >= 0, got {hours:g}")
    if tests != 1:
        raise ValueError(f"--operating-hours is one test's time, and there are {tests} tests: run one test per "
                         f"operating time, or append a log's tests afterwards, each at its own time (eha-health "
                         f"history add LOG.mcap --test N --time-h T)")


