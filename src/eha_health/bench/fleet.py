"""Simulated fleets of recordings (``eha-health fleet simulate``) and the fleet throughput bench
(``eha-health bench fleet``).

Simulation. The degrading actuators are those of the run-to-failure bench
(:func:`.rul.make_fleet`: primary and second faults, degradation laws, gamma-process wear,
test schedule, noise seeds; one source). Each of ``n_actuators`` units gets ``n_tests`` tests
spread evenly over its schedule (healthy to near the end of life); each test is the
reference EHA with sensor noise at the true K, recorded as an MCAP bag to the topic contract
(truth in ``truth/test_1``, the actuator id in ``eha_health``, test time and usage in
``history/test_1``) or as a CSV.
Usage is flight cycles: the test time over the unit's mean flight time (drawn per unit,
1.5-3 h). Same seed, same bytes.

Bench. The same recordings diagnosed (default method) in-process one after another (numba
on one thread, the per-core work unit of a worker), then by a fresh ``LocalCluster`` of 1
and of 2 worker processes into fresh stores. Per configuration: diagnoses per hour over the
batch (first submit to last store write; cluster start and warm-up reported apart), and the
Dask overhead per task, 1 - (work on the worker per task) / (wall time per task per worker),
where wall time per task per worker = batch time x workers / tasks.
"""
from __future__ import annotations

import contextlib
import math
import os
import tempfile
import time
from pathlib import Path
from typing import Callable

import numpy as np

from ..fleet.recordings import HISTORY_META, META_RECORD, MANIFEST_NAME, FleetError, read_manifest, write_manifest
from ..physics.faults import FAULT_NAMES, Faults
from ..physics.model import simulate
from ..physics.params import load
from ..prognostics.config import load_settings
from .rul import make_fleet

FORMATS = ("mcap", "csv")


def _test_indices(n_schedule: int, n_tests: int) -> np.ndarray:
    """``n_tests`` schedule indices spread evenly from the first test to the last before end of life."""
    return np.unique(np.round(np.linspace(0, n_schedule - 1, min(n_tests, n_schedule))).astype(int))


def simulate_fleet(n_actuators: int, n_tests: int, seed: int, out: str | Path, fmt: str = "mcap",
                   progress: Callable[[str], None] | None = None) -> dict:
    """Write the recordings and ``manifest.csv`` of a simulated fleet into ``out``; returns a summary."""
    if not isinstance(n_actuators, int) or n_actuators < 1:
        raise FleetError(f"--actuators must be a positive integer, got {n_actuators!r}")
    if not isinstance(n_tests, int) or n_tests < 1:
        raise FleetError(f"--tests must be a positive integer, got {n_tests!r}")
    if not isinstance(seed, int) or seed < 0:
        raise FleetError(f"--seed must be a non-negative integer, got {seed!r}")
    if fmt not in FORMATS:
        raise FleetError(f"unknown recording format {fmt!r}; choose {' or '.join(FORMATS)}")
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    bench = load_settings(overrides={"bench": {"n_units": n_actuators, "seed": seed}}).bench
    units = make_fleet(bench)
    params = load("reference").with_effect_names(["sensor_noise"])
    total = sum(len(_test_indices(len(u.test_h), n_tests)) for u in units)
    rows, t0, n = [], time.perf_counter(), 0
    for u in units:
        flight_h = float(np.random.default_rng([seed, u.index, 1]).uniform(1.5, 3.0))
        folder = out / u.actuator_id
        folder.mkdir(exist_ok=True)
        for i in _test_indices(len(u.test_h), n_tests):
            k = np.clip(u.true_k[i], 0.0, 1.5)
            t_h, noise_seed = float(u.test_h[i]), int(u.seeds[i])
            usage = float(math.floor(t_h / flight_h))
            truth = dict(zip(FAULT_NAMES, map(float, k)))
            r = simulate(kind="reference", faults=Faults(*truth.values()), params=params, seed=noise_seed)
            path = folder / f"{u.actuator_id}_t{int(i):04d}.{fmt}"
            if fmt == "mcap":
                _write_bag(path, r, truth, u.actuator_id, {"time_h": repr(t_h), "usage": repr(usage),
                                                           "usage_unit": "cycles"})
            else:
                r.to_csv(path)
            rows.append({"actuator_id": u.actuator_id, "time_h": repr(t_h), "usage": repr(usage),
                         "usage_unit": "cycles", "path": path.relative_to(out).as_posix(),
                         **{f"truth_{name}": repr(v) for name, v in truth.items()}, "noise_seed": noise_seed})
            n += 1
            if progress:
                progress(f"recording {n}/{total}: {path.relative_to(out)}  true K "
                         f"{np.round(k, 3).tolist()}  {time.perf_counter() - t0:.0f} s")
    manifest = write_manifest(out / MANIFEST_NAME, rows)
    return {"actuators": len(units), "recordings": len(rows), "manifest": str(manifest), "format": fmt,
            "seed": seed, "end_of_life_h": {u.actuator_id: round(u.eol_h, 1) for u in units},
            "eol_fault": {u.actuator_id: u.eol_fault for u in units}, "wall_time_s": time.perf_counter() - t0}


def _write_bag(path: Path, response, truth: dict, actuator_id: str, when: dict) -> None:
    from ..io.bagrun import write_run
    from ..io.mcaplog import BagWriter
    tmp = path.with_name(path.name + ".part")
    with BagWriter(tmp) as w:
        w.add_metadata(META_RECORD, {"actuator_id": actuator_id})
        w.add_metadata(HISTORY_META.format(1), when)
        write_run(w, response, test_id=1, truth=truth, actuator_id=actuator_id)
    tmp.replace(path)   # a killed simulation leaves no half-written recording under the final name


# ----------------------------------------------------------------------------- bench
def _load() -> float:
    return round(os.getloadavg()[0], 2)


def _cpu(pids: list[int]) -> float:
    """CPU seconds (user + system, threads included) used so far by the processes ``pids``."""
    import psutil
    total = 0.0
    for p in pids:
        t = psutil.Process(p).cpu_times()
        total += t.user + t.system
    return total


def serial(recordings, method: str, progress=None, threads: int = 1) -> dict:
    """In-process, one diagnosis after another, numba on ``threads`` threads (1: the work unit of a
    worker; all cores: what a plain loop over ``diagnose`` gets); warm-up done first, timed apart."""
    import numba

    from ..fleet.worker import diagnose_recording, warm_up
    numba.set_num_threads(threads)
    params = load("monitor")
    warm = warm_up(params)
    t0, cpu0 = time.perf_counter(), _cpu([os.getpid()])
    results = []
    for i, rec in enumerate(recordings, 1):
        results.append(diagnose_recording(str(rec.path), params, method, threads=threads))
        if progress:
            progress(f"serial ({threads} numba thread(s)) {i}/{len(recordings)}  {time.perf_counter() - t0:.0f} s")
    wall, cpu = time.perf_counter() - t0, _cpu([os.getpid()]) - cpu0
    numba.set_num_threads(numba.config.NUMBA_NUM_THREADS)
    bad = [r for r in results if "error" in r]
    if bad:
        raise RuntimeError(f"serial diagnosis failed: {bad[0]['path']}: {bad[0]['error']}")
    return {"tasks": len(results), "numba_threads": threads, "batch_time_s": wall, "per_hour": 3600 * len(results) / wall, "warm_up_s": warm,
            "mean_read_s": float(np.mean([r["read_s"] for r in results])),
            "mean_diagnosis_s": float(np.mean([r["diagnosis_s"] for r in results])),
            "mean_task_s": float(np.mean([r["task_s"] for r in results])),
            "cpu_per_task_s": cpu / len(results), "k": {r["path"]: r["k"] for r in results}}


def on_cluster(recordings, workers: int, method: str, progress=None) -> dict:
    """A fresh LocalCluster of ``workers`` processes into a fresh store: the real ``fleet diagnose`` path."""
    from ..fleet.batch import dask_client, diagnose_fleet
    from ..prognostics.store import HistoryStore
    with tempfile.TemporaryDirectory(prefix="eha-bench-fleet-") as d, contextlib.ExitStack() as stack:
        db = Path(d) / "history.sqlite"
        t0 = time.perf_counter()
        client = stack.enter_context(dask_client(workers=workers))
        start = time.perf_counter() - t0
        # every process of the cluster: this one (client, scheduler, nannies) and the workers
        pids = [os.getpid()] + list(client.run(os.getpid).values())
        cpu0 = _cpu(pids)
        s = diagnose_fleet(recordings, db, method=method, progress=progress, client=client)
        cpu = _cpu(pids) - cpu0
        with HistoryStore(db) as st:
            k = {r["source_path"]: [r["k_gm"], r["k_fsj"], r["k_bkl"]] for r in st.list_tests()}
    if s["failed"] or s["diagnosed"] != len(recordings):
        raise RuntimeError(f"{workers} worker(s): {s['diagnosed']} of {len(recordings)} stored, {s['failed']} failed "
                           f"({s['failures'][:1]})")
    per_task = s["batch_time_s"] * s["workers"] / s["diagnosed"]
    return {"tasks": s["diagnosed"], "workers": s["workers"], "batch_time_s": s["batch_time_s"],
            "wall_time_s": s["wall_time_s"], "per_hour": s["per_hour"], "mean_read_s": s["mean_read_s"],
            "mean_diagnosis_s": s["mean_diagnosis_s"], "mean_task_s": s["mean_task_s"],
            "wall_per_task_s": per_task, "overhead": 1.0 - s["mean_task_s"] / per_task,
            "non_diagnosis": 1.0 - s["mean_diagnosis_s"] / per_task,
            "cpu_per_task_s": cpu / s["diagnosed"], "task_cpu_s": s["mean_task_cpu_s"],
            "cpu_overhead": 1.0 - s["mean_task_cpu_s"] * s["diagnosed"] / cpu,
            "cluster_start_and_setup_s": start + s["wall_time_s"] - s["batch_time_s"],
            "worker_setup": s["worker_setup"], "k": k}


def _pool(runs: list[dict]) -> dict:
    """One configuration over rounds: throughput from the summed tasks and batch times, the other
    figures averaged; the per-round throughputs kept; K and the worker setup of the first round."""
    out = dict(runs[0])
    tasks, batch = sum(r["tasks"] for r in runs), sum(r["batch_time_s"] for r in runs)
    for k, v in runs[0].items():
        if isinstance(v, float) and k not in ("batch_time_s", "per_hour"):
            out[k] = float(np.mean([r[k] for r in runs]))
    out.update(tasks=tasks, batch_time_s=batch, per_hour=3600.0 * tasks / batch,
               per_hour_rounds=[r["per_hour"] for r in runs])
    return out


def bench_fleet(n_tests: int = 60, method: str | None = None, fleet_dir: str | Path = "out/bench_fleet",
                fmt: str = "mcap", seed: int = 17, workers: tuple = (1, 2), plot: str | None = "out/bench_fleet.png",
                all_cores_serial: bool = False, rounds: int = 3,
                progress: Callable[[str], None] | None = None) -> dict:
    """Throughput of serial vs LocalCluster(1, 2 workers) on the same ``n_tests`` simulated recordings.

    The configurations run ``rounds`` times, in forward then reverse order (serial, 1, 2 workers;
    2, 1, serial; ...): this 2-core virtual machine's speed drifts by +-15 % over tens of seconds
    (the same in-process work measured 0.20-0.29 CPU s per diagnosis in back-to-back runs), which a
    single pass in a fixed order turns into a bias against whichever configuration runs later.
    Each configuration's throughput is its tasks over its batch time summed over the rounds; the
    speedup is the ratio of those, and ``speedup_rounds`` the ratio within each round."""
    from ..identification.diagnose import DEFAULT_METHOD
    method = method or DEFAULT_METHOD
    if not isinstance(rounds, int) or rounds < 1:
        raise FleetError(f"--rounds must be a positive integer, got {rounds!r}")
    fleet_dir = Path(fleet_dir) / f"{fmt}_{n_tests}_seed{seed}"
    n_act = max(1, math.ceil(n_tests / 10))
    if not (fleet_dir / MANIFEST_NAME).is_file():
        simulate_fleet(n_act, math.ceil(n_tests / n_act), seed, fleet_dir, fmt, progress)
    recordings = read_manifest(fleet_dir / MANIFEST_NAME)[:n_tests]
    res: dict = {"tests": len(recordings), "method": method, "format": fmt, "fleet": str(fleet_dir),
                 "cpu_count": os.cpu_count(), "rounds": rounds, "load": {"start": _load()}}
    import numba
    configs = ["serial"] + (["serial_all_cores"] if all_cores_serial else []) + [f"workers_{n}" for n in workers]
    runs: dict[str, list] = {c: [] for c in configs}
    for r in range(rounds):
        for c in (configs if r % 2 == 0 else configs[::-1]):
            if progress:
                progress(f"round {r + 1}/{rounds}: {c}")
            if c == "serial":
                runs[c].append(serial(recordings, method, progress))
            elif c == "serial_all_cores":
                runs[c].append(serial(recordings, method, progress, threads=numba.config.NUMBA_NUM_THREADS))
            else:
                runs[c].append(on_cluster(recordings, int(c.split("_")[1]), method, progress))
            res["load"][f"after_{c}" + (f"_round{r + 1}" if rounds > 1 else "")] = _load()
    for c in configs:
        res[c] = _pool(runs[c])
    res["speedup_rounds"] = {c: [w["per_hour"] / s["per_hour"] for w, s in zip(runs[c], runs["serial"])]
                             for c in configs if c != "serial"}
    base = res["serial"]["per_hour"]
    res["speedup"] = {f"workers_{n}": res[f"workers_{n}"]["per_hour"] / base for n in workers}
    if all_cores_serial:
        res["speedup"]["serial_all_cores"] = res["serial_all_cores"]["per_hour"] / base
        res["speedup_vs_serial_all_cores"] = {f"workers_{n}": res[f"workers_{n}"]["per_hour"]
                                              / res["serial_all_cores"]["per_hour"] for n in workers}
        res["serial_all_cores"].pop("k")
    ref = res["serial"].pop("k")
    res["max_k_difference_vs_serial"] = {
        f"workers_{n}": max(float(np.max(np.abs(np.subtract(res[f"workers_{n}"]["k"][p], ref[p])))) for p in ref)
        for n in workers}
    for n in workers:
        res[f"workers_{n}"].pop("k")
    top = f"workers_{max(workers)}"
    cores = os.cpu_count() or 1
    res["capacity"] = {"cores": cores, "from": top, "cpu_per_task_s": res[top]["cpu_per_task_s"],
                       "per_hour": cores * 3600.0 / res[top]["cpu_per_task_s"]}
    res["targets"] = {"2 workers vs serial >= 1.8x": res["speedup"].get("workers_2", 0.0) >= 1.8,
                      "Dask overhead <= 5 % of task time": all(res[f"workers_{n}"]["overhead"] <= 0.05 for n in workers),
                      ">= 6000 diagnoses per hour": res[top]["per_hour"] >= 6000}
    if plot:
        plot_bench(res, plot)
        res["plot"] = plot
    return res


def plot_bench(res: dict, path: str | Path) -> None:
    """Throughput per configuration, and where the wall time per task goes."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    names = [k for k in ("serial", "serial_all_cores") if k in res] + [k for k in res if k.startswith("workers_")]
    labels = [f"serial\n(numba {res[k]['numba_threads']} thr.)" if k.startswith("serial")
              else f"LocalCluster\n{res[k]['workers']} worker(s)" for k in names]
    fig, (a, b) = plt.subplots(1, 2, figsize=(10, 4))
    a.bar(labels, [res[k]["per_hour"] for k in names], color="tab:blue")
    a.axhline(6000, color="tab:red", ls="--", label="target 6,000/h")
    a.set_ylabel(f"{res['method']} diagnoses per hour")
    a.set_title(f"{res['tests']} recordings ({res['format']}), load {res['load']['start']}")
    a.legend()
    read = [res[k]["mean_read_s"] for k in names]
    diag = [res[k]["mean_diagnosis_s"] for k in names]
    wall = [res[k].get("wall_per_task_s", res[k]["batch_time_s"] / res[k]["tasks"]) for k in names]
    other = [max(w - r - d, 0.0) for w, r, d in zip(wall, read, diag)]
    b.bar(labels, diag, label="diagnosis")
    b.bar(labels, read, bottom=diag, label="reading the recording")
    b.bar(labels, other, bottom=np.add(diag, read), label="everything else (Dask, store)")
    b.set_ylabel("wall time per task per worker [s]")
    b.legend()
    fig.tight_layout()
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=100)
    plt.close(fig)


def format_bench(res: dict) -> str:
    lines = [f"bench fleet: {res['tests']} recordings ({res['format']}), method {res['method']}, "
             f"{res['cpu_count']} cores, load average {res['load']}"]
    lines.append(f"  {'configuration':28s} {'diagnoses/h':>12s} {'vs serial':>10s} {'diagnosis s':>12s} "
                 f"{'read s':>8s} {'wall/task s':>12s} {'overhead':>9s}")
    for k in [k for k in ("serial", "serial_all_cores") if k in res] + [k for k in res if k.startswith("workers_")]:
        r = res[k]
        name = (f"serial, numba {r['numba_threads']} thread(s)" if k.startswith("serial")
                else f"LocalCluster {r['workers']} worker(s)")
        wpt = r.get("wall_per_task_s", r["batch_time_s"] / r["tasks"])
        ov = f"{r['overhead']:.1%}" if "overhead" in r else "-"
        sp = res["speedup"].get(k, 1.0)
        lines.append(f"  {name:28s} {r['per_hour']:12,.0f} {sp:9.2f}x {r['mean_diagnosis_s']:12.3f} "
                     f"{r['mean_read_s']:8.3f} {wpt:12.3f} {ov:>9s}")
    for k in [k for k in res if k.startswith("workers_")]:
        r = res[k]
        lines.append(f"  {k}: cluster start + worker setup {r['cluster_start_and_setup_s']:.1f} s (not in the "
                     f"throughput); warm-up per worker "
                     + ", ".join(f"{w['warm_up_s']:.2f} s" for w in r["worker_setup"])
                     + f"; max |K - serial K| {res['max_k_difference_vs_serial'][k]:.2g}")
    if res.get("rounds", 1) > 1:
        lines.append(f"  {res['rounds']} rounds (forward, then reverse order); vs serial within each round: " + "; ".join(
            f"{k} " + " / ".join(f"{v:.2f}x" for v in vs) for k, vs in res["speedup_rounds"].items()))
    lines.append("  CPU time (less load-dependent than wall time; all processes: client, scheduler, nannies, workers):")
    for k in [k for k in ("serial", "serial_all_cores") if k in res] + [k for k in res if k.startswith("workers_")]:
        r = res[k]
        extra = (f", task threads {r['task_cpu_s']:.3f} s, Dask/store CPU overhead {r['cpu_overhead']:.1%}"
                 if "cpu_overhead" in r else "")
        lines.append(f"    {k}: {r['cpu_per_task_s']:.3f} CPU s per diagnosis{extra}")
    c = res.get("capacity")
    if c:
        lines.append(f"    capacity at full use of {c['cores']} cores: {c['per_hour']:,.0f} diagnoses/h "
                     f"({c['cores']} x 3600 / {c['cpu_per_task_s']:.3f} CPU s of {c['from']})")
    if "speedup_vs_serial_all_cores" in res:
        lines.append("  LocalCluster vs the serial loop on all cores: " + ", ".join(
            f"{k} {v:.2f}x" for k, v in res["speedup_vs_serial_all_cores"].items()))
    lines.append("  targets: " + "; ".join(f"{k}: {'met' if v else 'NOT met'}" for k, v in res["targets"].items()))
    if res.get("plot"):
        lines.append(f"  plot: {res['plot']}")
    return "\n".join(lines)
