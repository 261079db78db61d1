"""Where a fleet worker's extra cost per diagnosis comes from: the same recordings diagnosed
in-process and on a 1-worker LocalCluster, interleaved in blocks (this virtual machine's speed
drifts over tens of seconds, so blocks alternate): ``worker`` = all of a block in one Dask task,
``pertask`` = one task per recording, waited for one by one, ``pertask_async`` = one task per
recording, all submitted at once (as ``fleet diagnose`` does). Prints median CPU ms (the thread's)
of reading and of the diagnosis, and the task thread's minor page faults and system CPU ms.

    python tools/fleet_task_ab.py [--rounds 6] [--tests 10] [--dask-malloc-trim]

``--dask-malloc-trim`` starts the worker with Dask's own ``MALLOC_TRIM_THRESHOLD_=65536`` (the
fleet's LocalCluster leaves it out: ``fleet.batch.WORKER_ENVIRON``), to see what it costs.
Needs ``eha-health bench fleet --tests 50`` to have written out/bench_fleet/mcap_50_seed17.
"""
import argparse
import resource

import numpy as np


def block(paths, params):
    """Per recording, by the fleet's own task: CPU s of reading and of diagnosing (the task
    thread's), minor page faults and system CPU s of the task thread."""
    from eha_health.fleet.worker import diagnose_recording
    rows = []
    for p in paths:
        r0 = resource.getrusage(resource.RUSAGE_THREAD)
        res = diagnose_recording(p, params)
        r1 = resource.getrusage(resource.RUSAGE_THREAD)
        rows.append((res["task_cpu_s"] - res["diagnosis_cpu_s"], res["diagnosis_cpu_s"],
                     r1.ru_minflt - r0.ru_minflt, r1.ru_stime - r0.ru_stime))
    return rows


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rounds", type=int, default=6)
    ap.add_argument("--tests", type=int, default=10)
    ap.add_argument("--dask-malloc-trim", action="store_true",
                    help="worker environment with Dask's MALLOC_TRIM_THRESHOLD_=65536")
    args = ap.parse_args()
    from eha_health.fleet.batch import CLUSTER_CONFIG, WORKER_ENVIRON, dask_client
    from eha_health.fleet.recordings import read_manifest
    from eha_health.fleet.worker import warm_up
    from eha_health.physics.params import load
    paths = [str(r.path) for r in read_manifest("out/bench_fleet/mcap_50_seed17/manifest.csv")[:args.tests]]
    params = load("monitor")
    warm_up(params)
    modes = ("local", "worker", "pertask", "pertask_async")
    out = {m: [] for m in modes}
    environ = dict(WORKER_ENVIRON, MALLOC_TRIM_THRESHOLD_=65536) if args.dask_malloc_trim else WORKER_ENVIRON
    # dask_client applies CLUSTER_CONFIG over any outer dask.config.set: change it for this run
    CLUSTER_CONFIG["distributed.nanny.pre-spawn-environ"] = environ
    with dask_client(workers=1) as c:
        for _ in range(args.rounds):
            out["local"] += block(paths, params)
            out["worker"] += c.submit(block, paths, params, pure=False).result()
            for p in paths:
                out["pertask"] += c.submit(block, [p], params, pure=False).result()
            for f in [c.submit(block, [p], params, pure=False) for p in paths]:
                out["pertask_async"] += f.result()
    print("worker environment:", {k: v for k, v in environ.items() if v is not None})
    for m in modes:
        a = np.array(out[m])
        print(f"{m:14s} read median {np.median(a[:, 0]) * 1e3:6.1f} ms   diagnosis median {np.median(a[:, 1]) * 1e3:6.1f} ms, "
              f"mean {np.mean(a[:, 1]) * 1e3:6.1f} ms   page faults median {np.median(a[:, 2]):6.0f}   "
              f"system CPU mean {np.mean(a[:, 3]) * 1e3:5.1f} ms")


if __name__ == "__main__":
    main()
