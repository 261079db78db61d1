"""What two cores give without Dask: the fleet's task (``fleet.worker.diagnose_recording``) run
by N plain ``multiprocessing`` processes on disjoint shares of the same recordings, against one
process; rounds alternate the order (this virtual machine's speed drifts over tens of seconds).
The ratio is the ceiling ``bench fleet``'s 2-worker figure is measured against.

    python tools/fleet_ceiling.py [--rounds 3] [--tests 50]

Needs ``eha-health bench fleet --tests 50`` to have written out/bench_fleet/mcap_50_seed17.
"""
import argparse
import multiprocessing as mp
import time

import numpy as np


def work(paths, barrier, queue):
    """One process: warm up, wait for the others, diagnose ``paths``; report (start, end, task CPU s)."""
    import numba
    numba.set_num_threads(1)
    from eha_health.fleet.worker import diagnose_recording, warm_up
    from eha_health.physics.params import load
    params = load("monitor")
    warm_up(params)
    barrier.wait()
    t0 = time.perf_counter()
    cpu = [diagnose_recording(p, params)["task_cpu_s"] for p in paths]
    queue.put((t0, time.perf_counter(), float(np.mean(cpu))))


def run(paths, n):
    """Diagnoses per hour of ``n`` processes (first start to last end) and their mean task CPU s."""
    ctx = mp.get_context("spawn")
    barrier, queue = ctx.Barrier(n), ctx.Queue()
    procs = [ctx.Process(target=work, args=(paths[i::n], barrier, queue)) for i in range(n)]
    for p in procs:
        p.start()
    res = [queue.get() for _ in procs]
    for p in procs:
        p.join()
    wall = max(r[1] for r in res) - min(r[0] for r in res)
    return 3600.0 * len(paths) / wall, float(np.mean([r[2] for r in res]))


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--tests", type=int, default=50)
    args = ap.parse_args()
    from eha_health.fleet.recordings import read_manifest
    paths = [str(r.path) for r in read_manifest("out/bench_fleet/mcap_50_seed17/manifest.csv")[:args.tests]]
    rates = {1: [], 2: []}
    for r in range(args.rounds):
        for n in ((1, 2) if r % 2 == 0 else (2, 1)):
            per_hour, cpu = run(paths, n)
            rates[n].append(per_hour)
            print(f"round {r + 1}: {n} process(es) {per_hour:9,.0f}/h  task CPU {cpu * 1e3:.1f} ms", flush=True)
    ratios = [b / a for a, b in zip(rates[1], rates[2])]
    print(f"2 vs 1 process per round: {', '.join(f'{x:.2f}x' for x in ratios)}; "
          f"ratio of the mean rates {np.mean(rates[2]) / np.mean(rates[1]):.2f}x")


if __name__ == "__main__":
    main()
