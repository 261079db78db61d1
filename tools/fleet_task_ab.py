"""Where a fleet worker's extra cost per diagnosis comes from: the same recordings diagnosed
in-process and on a 1-worker LocalCluster, interleaved in blocks (this virtual machine's speed
drifts over tens of seconds, so blocks alternate): ``worker`` = all of a block in one Dask task,
``pertask`` = one task per recording, waited for one by one, ``pertask_async`` = one task per
recording, all submitted at once (as ``fleet diagnose`` does). Prints median CPU ms (the thread's)
of reading and of the diagnosis.

    python tools/fleet_task_ab.py [--rounds 6] [--tests 10]

Needs ``eha-health bench fleet --tests 50`` to have written out/bench_fleet/mcap_50_seed17.
"""
import argparse

import numpy as np


def block(paths, params):
    """CPU s (the task thread's) of reading and of diagnosing each recording, by the fleet's own task."""
    from eha_health.fleet.worker import diagnose_recording
    rs, ds = [], []
    for p in paths:
        res = diagnose_recording(p, params)
        rs.append(res["task_cpu_s"] - res["diagnosis_cpu_s"])
        ds.append(res["diagnosis_cpu_s"])
    return rs, ds


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rounds", type=int, default=6)
    ap.add_argument("--tests", type=int, default=10)
    args = ap.parse_args()
    from eha_health.fleet.batch import dask_client
    from eha_health.fleet.recordings import read_manifest
    from eha_health.fleet.worker import warm_up
    from eha_health.physics.params import load
    paths = [str(r.path) for r in read_manifest("out/bench_fleet/mcap_50_seed17/manifest.csv")[:args.tests]]
    params = load("monitor")
    warm_up(params)
    modes = ("local", "worker", "pertask", "pertask_async")
    out = {m: ([], []) for m in modes}

    def add(m, rd):
        out[m][0].extend(rd[0])
        out[m][1].extend(rd[1])

    with dask_client(workers=1) as c:
        for _ in range(args.rounds):
            add("local", block(paths, params))
            add("worker", c.submit(block, paths, params, pure=False).result())
            for p in paths:
                add("pertask", c.submit(block, [p], params, pure=False).result())
            for f in [c.submit(block, [p], params, pure=False) for p in paths]:
                add("pertask_async", f.result())
    for m in modes:
        r, d = out[m]
        print(f"{m:14s} read median {np.median(r) * 1e3:6.1f} ms   diagnosis median {np.median(d) * 1e3:6.1f} ms, "
              f"mean {np.mean(d) * 1e3:6.1f} ms")


if __name__ == "__main__":
    main()
