"""Speed benchmark: wall time and real-time factor of both models, batch throughput.

Figures, not assertions: run ``eha-health bench speed [--json]``.
"""
from __future__ import annotations

import json
import multiprocessing as mp
import os
import subprocess
import sys
import tempfile
import time
from concurrent.futures import ProcessPoolExecutor

import numba
import numpy as np

from ..physics.faults import Faults
from ..physics.model import Plant, simulate_batch
from ..physics.params import load
from ..physics.sequence import FDISequence

_COMPILE_SNIPPET = """
import time, json
t0 = time.perf_counter()
from eha_health import simulate
simulate("reference"); t1 = time.perf_counter()
simulate("monitor"); t2 = time.perf_counter()
from eha_health.physics.model import simulate_batch
from eha_health import load, Faults, FDISequence
seq = FDISequence(); t = seq.times(1000)
simulate_batch(load("monitor"), [Faults()] * 2, seq.command(t)); t3 = time.perf_counter()
print(json.dumps({"first_call_reference_s": t1 - t0, "first_call_monitor_s": t2 - t1,
                  "first_call_batch_s": t3 - t2}))
"""


def compile_times() -> dict:
    """First-call times in a fresh process with an empty numba cache (true compile time)."""
    with tempfile.TemporaryDirectory() as d:
        env = dict(os.environ, NUMBA_CACHE_DIR=d)
        out = subprocess.run([sys.executable, "-c", _COMPILE_SNIPPET], env=env, capture_output=True,
                             text=True, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def _best(fn, repeat: int) -> float:
    ts = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        ts.append(time.perf_counter() - t0)
    return min(ts)


def _pool_worker_init() -> None:
    numba.set_num_threads(1)     # one process per core: no threads inside


def _pool_run(args) -> np.ndarray:
    """One monitor run in a worker process (the process-pool alternative to the batch)."""
    params, faults, cmd = args
    return simulate_batch(params, [faults], cmd)[0]


def ga_generation(pop: int = 20, repeat: int = 5) -> dict:
    """One GA generation's evaluation, both ways the issue names: the compiled batch
    simulator (numba ``prange`` over the population, all cores) against a process pool
    (one single-threaded run per individual, one worker per core). Pool start-up and
    compilation are excluded (warmed up first); each map still ships the command and
    returns the outputs, as a GA would."""
    seq = FDISequence()
    cmd = seq.command(seq.times(1000.0))
    mon = load("monitor")
    rng = np.random.default_rng(1)
    faults = [Faults(*rng.uniform(0, 1, 3)) for _ in range(pop)]
    simulate_batch(mon, faults[:2], cmd)
    batch = _best(lambda: simulate_batch(mon, faults, cmd), repeat)
    workers = os.cpu_count() or 1
    with ProcessPoolExecutor(workers, mp_context=mp.get_context("spawn"), initializer=_pool_worker_init) as ex:
        list(ex.map(_pool_run, [(mon, f, cmd) for f in faults]))        # warm-up: import, numba cache
        pool = _best(lambda: list(ex.map(_pool_run, [(mon, f, cmd) for f in faults])), repeat)
    return {"ga_population": pop, "ga_batch_s": batch, "ga_pool_s": pool, "ga_pool_workers": workers,
            "ga_pool_over_batch": pool / batch}


def speed(repeat: int = 7, batch: int = 40, with_compile: bool = True) -> dict:
    """Measure; returns a dict of figures (seconds, ratios)."""
    seq = FDISequence()
    t = seq.times(1000.0)
    cmd = seq.command(t)
    res: dict = {"sequence_duration_s": seq.duration, "cores": os.cpu_count()}
    if with_compile:
        res.update(compile_times())
    for kind in ("reference", "monitor"):
        plant = Plant(kind=kind, faults=Faults(0.4, 0.6, 0.4))
        plant.step(cmd)  # compiled / loaded from cache

        def one():
            plant.reset()
            plant.step(cmd)
        wall = _best(one, repeat)
        res[f"{kind}_wall_s"] = wall
        res[f"{kind}_realtime_factor"] = seq.duration / wall
        res[f"{kind}_fine_step_s"] = plant.params.integration.dt
    mon = load("monitor")
    rng = np.random.default_rng(0)
    faults = [Faults(*rng.uniform(0, 1, 3)) for _ in range(batch)]
    simulate_batch(mon, faults[:2], cmd)
    n_threads = numba.get_num_threads()
    numba.set_num_threads(1)
    one_core = _best(lambda: simulate_batch(mon, faults, cmd), 3)
    numba.set_num_threads(n_threads)
    all_cores = _best(lambda: simulate_batch(mon, faults, cmd), 3)
    res.update({
        "batch_size": batch,
        "batch_threads": n_threads,
        "batch_one_core_s": one_core,
        "batch_all_cores_s": all_cores,
        "batch_one_core_sims_per_s": batch / one_core,
        "batch_all_cores_sims_per_s": batch / all_cores,
        "batch_speedup": one_core / all_cores,
    })
    res.update(ga_generation())
    return res


def format_speed(r: dict) -> str:
    lines = [f"FDI sequence {r['sequence_duration_s']:.2f} s simulated, best of repeated runs, {r['cores']} cores"]
    if "first_call_reference_s" in r:
        lines.append(f"  first call (compile, empty cache): reference {r['first_call_reference_s']:.1f} s, "
                     f"monitor {r['first_call_monitor_s']:.1f} s, batch {r['first_call_batch_s']:.1f} s")
    for kind, target in (("reference", 100), ("monitor", 500)):
        lines.append(f"  {kind:9s}: {r[kind + '_wall_s'] * 1e3:7.2f} ms per test  "
                     f"real-time factor {r[kind + '_realtime_factor']:6.0f}x  (target >= {target}x, "
                     f"dt = {r[kind + '_fine_step_s']:.0e} s)")
    lines.append(f"  batch of {r['batch_size']} monitor runs: 1 core {r['batch_one_core_sims_per_s']:.0f}/s, "
                 f"{r['batch_threads']} threads {r['batch_all_cores_sims_per_s']:.0f}/s, "
                 f"speed-up {r['batch_speedup']:.2f}x (target >= 1.6x)")
    if "ga_batch_s" in r:
        lines.append(f"  one GA generation ({r['ga_population']} individuals): compiled batch "
                     f"{r['ga_batch_s'] * 1e3:.1f} ms, process pool of {r['ga_pool_workers']} "
                     f"{r['ga_pool_s'] * 1e3:.1f} ms: pool/batch {r['ga_pool_over_batch']:.2f}x")
    return "\n".join(lines)


