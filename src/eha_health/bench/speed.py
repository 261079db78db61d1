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


def plant_run_s(plant: Plant, cmd: np.ndarray, repeat: int) -> float:
    """Best wall time [s] of ``plant`` run from rest over ``cmd`` on the calling thread (the first
    run, which compiles or loads the kernel, not timed)."""
    plant.step(cmd)

    def one():
        plant.reset()
        plant.step(cmd)
    return _best(one, repeat)


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


#: Case of the diagnosis timings: the paper's combined case of the demo (K_GM, K_FSJ, K_BKL).
DIAGNOSIS_CASE = (0.4, 0.6, 0.4)


def diagnosis_times(repeat: int = 3, methods=None, de: bool = False) -> dict:
    """Wall time and monitor runs of one diagnosis per method, clean and with the default sensor
    noise, measured side by side in this process (best of ``repeat``; caches warm), and each
    method's time over the default's: the ratio holds when the machine is busy, the seconds do not.
    With ``de``, scipy's differential_evolution (the peer of ``bench paper``) runs alongside, and
    its max abs error over the default's is reported too."""
    from ..identification.diagnose import DEFAULT_METHOD, METHODS, diagnose
    from ..physics.model import simulate
    from .paper import run_de
    methods = tuple(methods or METHODS)
    ref = load("reference")
    cases = {"clean": simulate("reference", Faults(*DIAGNOSIS_CASE)),
             "noisy": simulate("reference", Faults(*DIAGNOSIS_CASE),
                               params=ref.with_effects(sensor_noise={"enabled": True}), seed=1)}
    diagnose(cases["clean"], method=DEFAULT_METHOD)      # signature tables, numba caches
    out: dict = {"diagnosis_case": list(DIAGNOSIS_CASE), "default_method": DEFAULT_METHOD}
    for label, r in cases.items():
        for _ in range(repeat):
            for m in methods:          # interleaved, so load changes hit every method alike
                t0 = time.perf_counter()
                d = diagnose(r, method=m)
                dt = time.perf_counter() - t0
                key = f"diagnose_{m}_{label}"
                out[key + "_s"] = min(out.get(key + "_s", np.inf), dt)
                out[key + "_runs"] = d.evaluations
                out[key + "_err"] = float(np.max(np.abs(np.array(d.faults.as_tuple()) - DIAGNOSIS_CASE)))
            if de:
                est, dt, runs = run_de(r, 0)
                key = f"diagnose_scipy_de_{label}"
                out[key + "_s"] = min(out.get(key + "_s", np.inf), dt)
                out[key + "_runs"] = runs
                out[key + "_err"] = float(np.max(np.abs(np.array(est) - DIAGNOSIS_CASE)))
        for m in methods + (("scipy_de",) if de else ()):
            out[f"diagnose_{m}_{label}_over_default"] = (out[f"diagnose_{m}_{label}_s"]
                                                         / out[f"diagnose_{DEFAULT_METHOD}_{label}_s"])
    return out


def step_check(substeps=(16, 15, 10), repeat: int = 3) -> dict:
    """What a larger fine step of the monitor would buy and cost: per-run time ratio to the shipped
    step, and the RMS change of each measured channel over the monitor's residual floor
    (data/discrepancy.yaml), largest over a healthy, a combined and a backlash-limit case.

    ``substeps``: fine steps per sample period to try (the shipped monitor takes 20 at 1 kHz; the
    step must divide the sample period, so 16, 15, 10 are 1.25x, 1.33x and 2x the shipped step)."""
    from ..discrepancy.settings import fdi_settings
    from ..physics.model import simulate
    floor = fdi_settings().floor
    mon = load("monitor")
    seq = FDISequence()
    cmd = seq.command(seq.times(mon.integration.sample_rate))
    cases = [(0.0, 0.0, 0.0), DIAGNOSIS_CASE, (0.0, 0.0, 1.0)]

    def per_run(p):
        return plant_run_s(Plant(params=p, faults=Faults(*DIAGNOSIS_CASE)), cmd, repeat)
    base_t = per_run(mon)
    base = [simulate("monitor", Faults(*c), params=mon) for c in cases]
    out: dict = {"shipped_dt_s": mon.integration.dt, "steps": []}
    for n in substeps:
        p = mon.updated("integration", dt=1.0 / (mon.integration.sample_rate * n))
        worst = dict.fromkeys(floor, 0.0)
        for c, b in zip(cases, base):
            r = simulate("monitor", Faults(*c), params=p)
            for ch in floor:
                d = float(np.sqrt(np.mean((getattr(r, ch) - getattr(b, ch)) ** 2))) / floor[ch]
                worst[ch] = max(worst[ch], d)
        out["steps"].append({"dt_s": p.integration.dt, "time_ratio": per_run(p) / base_t,
                             "change_over_floor": worst})
    return out


def monitor_run_s(repeat: int = 15) -> float:
    """Best wall time [s] of one monitor run of the FDI test (faults 0.4, 0.6, 0.4) on the calling
    thread: the machine's speed, by which two machines' time figures of the same command compare."""
    seq = FDISequence()
    return plant_run_s(Plant(kind="monitor", faults=Faults(0.4, 0.6, 0.4)), seq.command(seq.times(1000.0)), repeat)


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
        wall = plant_run_s(plant, cmd, repeat)
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
    res.update(diagnosis_times(de=True))
    res["step_check"] = step_check()
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
    if "default_method" in r:
        from ..identification.diagnose import METHODS
        lines.append(f"  one diagnosis of {tuple(r['diagnosis_case'])} (best of 3, side by side; over "
                     f"{r['default_method']}: the ratio holds on a busy machine):")
        for label in ("clean", "noisy"):
            lines.append(f"    {label}: " + ", ".join(
                f"{m} {r[f'diagnose_{m}_{label}_s']:.3f} s / {r[f'diagnose_{m}_{label}_runs']} runs "
                f"({r[f'diagnose_{m}_{label}_over_default']:.1f}x)" for m in METHODS + ("scipy_de",)
                if f"diagnose_{m}_{label}_s" in r))
    if "step_check" in r:
        sc = r["step_check"]
        lines.append(f"  larger monitor step (shipped dt {sc['shipped_dt_s']:.1e} s), time per run and the largest "
                     f"change of a channel over its model floor:")
        for st in sc["steps"]:
            ch = ", ".join(f"{c} {v:.2f}" for c, v in st["change_over_floor"].items())
            lines.append(f"    dt {st['dt_s']:.2e} s: time x{st['time_ratio']:.2f}; change/floor {ch}")
    return "\n".join(lines)


