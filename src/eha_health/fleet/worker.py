"""What runs on a Dask worker: the once-per-worker setup and the one-recording task.

Each worker process runs one task at a time (one thread) and is one core's worth of work,
so numba must not start threads of its own inside it: ``NUMBA_NUM_THREADS=1`` is put in the
worker's environment before it starts (LocalCluster) and the task also sets
``numba.set_num_threads(1)``, which is per thread and therefore must be called in the
executor thread that runs the task (it also covers workers started by hand with ``dask worker``).

A task returns a plain dict (the diagnosis, where the time went, which worker): only the
client writes the history store.
"""
from __future__ import annotations

import os
import time

from distributed.diagnostics.plugin import WorkerPlugin

from ..identification.diagnose import DEFAULT_METHOD, diagnose

PLUGIN_NAME = "eha-health-fleet-setup"


def warm_up(params) -> float:
    """Load the numba kernels (from the on-disk cache, compiling if it is empty) with one short
    simulation of each kind a diagnosis uses, and build the start's signature tables; returns the wall
    time [s]."""
    import numpy as np

    from ..identification import diagnose as _diag
    from ..physics.faults import Faults
    from ..physics.model import simulate_batch
    from ..physics.sequence import FDISequence
    t0 = time.perf_counter()
    seq = FDISequence()
    command = seq.command(seq.times(1000.0))[:50]
    simulate_batch(params, [Faults(), Faults(0.1, 0.1, 0.1)], np.asarray(command, float))
    # the start's signature tables are built on first use and cached per parameter set; building
    # them here keeps that one-off cost out of the first task's time
    _diag.prepare(params, seq)
    return time.perf_counter() - t0


class FleetWorkerSetup(WorkerPlugin):
    """Once per worker: numba single-threaded, kernels warmed, the setup recorded on the worker."""
    name = PLUGIN_NAME

    def __init__(self):
        self.info: dict = {}

    def setup(self, worker):
        os.environ.setdefault("NUMBA_NUM_THREADS", "1")   # effective if numba is not loaded yet
        import numba
        numba.set_num_threads(1)
        from ..physics.params import load
        warm_s = warm_up(load("monitor"))
        self.info = {"pid": os.getpid(), "warm_up_s": warm_s, "numba_threads": numba.config.NUMBA_NUM_THREADS,
                     "setups": self.info.get("setups", 0) + 1, "tasks": 0}

    def teardown(self, worker):
        pass


def worker_info(dask_worker) -> dict:
    """The setup record of this worker (for ``client.run``): pid, warm-up time, numba threads, tasks run."""
    plugin = dask_worker.plugins.get(PLUGIN_NAME)
    return dict(plugin.info) if plugin is not None else {}


def diagnose_recording(path: str, params, method: str = DEFAULT_METHOD, seed: int = 0,
                       discrepancy: bool = False, threads: int = 1, window: int | None = None) -> dict:
    """Diagnose one recording (``window``: a bag's test window, default its first); a dict with the
    estimate, or with ``error`` (one line) if it failed.

    ``params`` is the calibrated monitor model, scattered to every worker once by the client.
    Times [s]: ``read_s`` (reading the file), ``diagnosis_s`` (``diagnose``), ``discrepancy_s``,
    ``task_s`` (all of it, on the worker); CPU times of the task's thread ``diagnosis_cpu_s``, ``task_cpu_s``. ``threads``: numba threads (1 on a worker: one core each).
    """
    import numba
    t0, c0 = time.perf_counter(), time.thread_time()
    numba.set_num_threads(threads)
    out: dict = {"path": path, "pid": os.getpid(), "numba_threads": numba.get_num_threads()}
    try:
        from ..identification.record import from_test_start
        from .recordings import read_recording
        response, truth = read_recording(path, window)
        # a logger started before the test: cut where the command starts the sequence, and say so
        response, cut = from_test_start(response)
        t1, c1 = time.perf_counter(), time.thread_time()
        d = diagnose(response, method=method, seed=seed, params=params)
        t2, c2 = time.perf_counter(), time.thread_time()
        verdict = None
        if discrepancy:
            from ..discrepancy.loop import analyse_fdi_test
            verdict = analyse_fdi_test(response, seed=seed, params=params, diagnosis=d).verdict
        t3 = time.perf_counter()
        out.update(k=list(d.faults.as_tuple()), std=[d.std[n] for n in ("k_gm", "k_fsj", "k_bkl")],
                   method=d.method, cost=float(d.cost), rms=dict(d.rms), warnings=[cut] * bool(cut) + list(d.warnings),
                   evaluations=int(d.evaluations), discrepancy=verdict, truth=truth,
                   read_s=t1 - t0, diagnosis_s=t2 - t1, discrepancy_s=t3 - t2, diagnosis_cpu_s=c2 - c1)
    except Exception as e:   # one bad file must not stop the batch: its reason goes back to the client
        out["error"] = f"{type(e).__name__}: {e}" if not isinstance(e, ValueError) else str(e)
    out["task_s"] = time.perf_counter() - t0
    # CPU time of this thread (numba on one thread runs in it): the work, whatever else loads the machine
    out["task_cpu_s"] = time.thread_time() - c0
    try:
        from distributed import get_worker
        plugin = get_worker().plugins.get(PLUGIN_NAME)
        if plugin is not None:
            plugin.info["tasks"] = plugin.info.get("tasks", 0) + 1
    except ValueError:   # not on a worker (in-process serial run)
        pass
    return out


def diagnose_recordings(items: list[tuple[str, int | None]], params, method: str = DEFAULT_METHOD, seed: int = 0,
                        discrepancy: bool = False) -> list[dict]:
    """:func:`diagnose_recording` of each (path, test window) in turn, in one task: Dask's and the
    client's costs per task are paid once for them (a diagnosis takes 0.07 s; those costs were 7 % of
    all CPU with one recording per task, measured by `eha-health bench fleet`)."""
    return [diagnose_recording(p, params, method, seed, discrepancy, window=w) for p, w in items]
