"""The fleet batch (client side): recordings -> Dask tasks -> the health history store.

A few recordings per task (:func:`.worker.diagnose_recordings`, :data:`RECORDINGS_PER_TASK`: Dask's
and the client's costs per task are then paid once for them) on a Dask distributed cluster: a
``LocalCluster`` of worker processes on the loopback interface by default, or an existing
scheduler (``scheduler="tcp://host:8786"``). Only this client writes the store.

Idempotent and resumable. Each recording is identified by the sha256 of its bytes (the
store's UNIQUE ``source_hash``); recordings whose hash the store already holds are skipped
before any task is submitted. Each result is written in its own ``BEGIN IMMEDIATE``
transaction as soon as it can be, so a client killed at any moment leaves only whole rows,
and the next run diagnoses exactly the recordings not stored yet.

Time order. The store accepts an actuator's tests only in increasing time (it refuses a test
earlier than the latest stored one, unless ``backfill``), while Dask returns results in any order. Tasks are
submitted earliest-test-first across actuators and a result waits in memory until every
earlier test of its actuator in this batch is written or has failed (a killed client loses
only such waiting results, which the next run redoes).

Failures. A recording that cannot be read, identified, diagnosed or stored is appended to
the failures file (CSV next to the store, ``<store>.failures.csv``: ``wall_time_utc, path,
source_hash, actuator_id, time_h, reason``) and never stops the batch; it is retried by the
next run (a log of attempts: nothing in it is ever rewritten).
"""
from __future__ import annotations

import contextlib
import csv
import datetime as _dt
import logging
import os
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

from ..identification.diagnose import DEFAULT_METHOD, METHODS
from ..physics.params import load
from ..prognostics.config import PrognosticsError
from ..prognostics.records import HealthRecord
from ..prognostics.store import HistoryStore, backfill_note, recording_hash, sha256_file
from .recordings import FleetError, Recording, bag_windows, complete_identity
from .worker import FleetWorkerSetup, diagnose_recordings, worker_info

#: The environment a LocalCluster worker process starts with (Dask's ``pre-spawn-environ``): the
#: BLAS and OpenMP pools at one thread as Dask sets them, numba's too (read when numba is imported),
#: and not Dask's ``MALLOC_TRIM_THRESHOLD_=65536``. Setting any malloc threshold turns glibc's
#: adaptive mmap threshold off, so every array over 128 kB became a fresh mmap whose pages fault in
#: again: 6,300 page faults and 8-10 ms of system time per diagnosis on a worker against 1,400 and
#: 0-4 ms in-process (docs/fleet.md). A task returns a few kB; memory is not what a worker runs short of.
#: (None removes a variable Dask's defaults would set: ``dask.config.set`` replaces the whole dict, a
#: YAML config file on a remote worker merges into it.)
WORKER_ENVIRON = {"OMP_NUM_THREADS": 1, "MKL_NUM_THREADS": 1, "OPENBLAS_NUM_THREADS": 1, "NUMBA_NUM_THREADS": 1,
                  "MALLOC_TRIM_THRESHOLD_": None}

#: Dask settings of the LocalCluster (its worker processes inherit them). A task is seconds of one
#: CPU-bound thread: the worker's statistical profiler (a stack sample every 10 ms) would only take
#: CPU from it, and sub-second memory and system polling buy nothing at that time scale. Tasks wait
#: in the scheduler's queue until a worker is free (worker-saturation), so work stealing (a scheduler
#: pass every 100 ms) has nothing to balance. The event-loop health tick (Dask's 20 ms) cost 9 % of a
#: core on an idle 2-worker cluster, 2 % at 1 s (docs/fleet.md); a task runs in its own thread, so a
#: long tick only delays the "event loop unresponsive" warning, whose limit goes to 30 s.
CLUSTER_CONFIG = {"distributed.worker.profile.enabled": False,
                  "distributed.scheduler.work-stealing": False,
                  "distributed.admin.tick.interval": "1s", "distributed.admin.tick.limit": "30s",
                  "distributed.worker.memory.monitor-interval": "1s",
                  "distributed.admin.system-monitor.interval": "2s",
                  "distributed.nanny.pre-spawn-environ": WORKER_ENVIRON}


def dask_config_yaml() -> str:
    """:data:`CLUSTER_CONFIG` as a Dask YAML config file, for workers started by hand on a real
    cluster (``eha-health fleet dask-config > ~/.config/dask/eha-health.yaml`` on each machine)."""
    import yaml
    nested: dict = {}
    for key, value in CLUSTER_CONFIG.items():
        *parents, leaf = key.split(".")
        node = nested
        for p in parents:
            node = node.setdefault(p, {})
        node[leaf] = value
    return ("# eha-health fleet workers (eha_health.fleet.batch.CLUSTER_CONFIG); Dask reads it from\n"
            "# ~/.config/dask/ or the folder named by $DASK_CONFIG\n" + yaml.safe_dump(nested, sort_keys=True))


FAILURE_COLUMNS = ("wall_time_utc", "path", "source_hash", "actuator_id", "time_h", "reason")


#: Recordings per Dask task (fewer when the batch is small: at least two tasks per worker).
RECORDINGS_PER_TASK = 4


def failures_path(history: str | Path) -> Path:
    """The failures file of a history store: ``<store>.failures.csv``."""
    p = Path(history)
    return p.with_name(p.name + ".failures.csv")


class FailureLog:
    """Append-only CSV of failed recordings (flushed per line: a killed client keeps what it logged)."""

    def __init__(self, path: str | Path):
        self.path = Path(path)
        self.count = 0
        self.items: list[dict] = []

    def add(self, rec: Recording, reason: str, source_hash: str | None = None) -> None:
        row = {"wall_time_utc": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
               "path": str(rec.path), "source_hash": source_hash or "", "actuator_id": rec.actuator_id or "",
               "time_h": "" if rec.time_h is None else f"{rec.time_h:g}",
               "reason": (f"test {rec.window}: " if rec.window is not None else "") + " ".join(str(reason).split())}
        new = not self.path.is_file() or self.path.stat().st_size == 0
        self.path.parent.mkdir(parents=True, exist_ok=True)
        with self.path.open("a", newline="") as f:
            w = csv.DictWriter(f, FAILURE_COLUMNS)
            if new:
                w.writeheader()
            w.writerow(row)
        self.count += 1
        self.items.append({"path": row["path"], "reason": row["reason"]})


def _environ_restorer(keys) -> Callable[[], None]:
    """A function that puts the variables ``keys`` of this process's environment back as they are now."""
    saved = {k: os.environ.get(k) for k in keys}

    def restore() -> None:
        for k, v in saved.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v
    return restore


@contextlib.contextmanager
def dask_client(scheduler: str | None = None, workers: int = 2, setup: bool = True):
    """A connected ``distributed.Client``: to ``scheduler`` if given, else to a new ``LocalCluster``
    of ``workers`` single-threaded worker processes on 127.0.0.1 (no dashboard); with ``setup``
    the :class:`FleetWorkerSetup` plugin is registered (once per worker, later workers included)."""
    import dask
    from distributed import Client, LocalCluster
    if scheduler is None and (not isinstance(workers, int) or workers < 1):
        raise FleetError(f"--workers must be a positive integer, got {workers!r}")
    with contextlib.ExitStack() as stack:
        # Dask's nanny puts pre-spawn-environ into *this* process's environment before it spawns a
        # worker, and leaves it there: NUMBA_NUM_THREADS=1 here then made the next numba compile in
        # this process raise ("Cannot set NUMBA_NUM_THREADS to a different value once the threads
        # have been launched"; seen with prognose after a fleet batch). Restored after the workers
        # start and again when the cluster is gone (a nanny restarting a worker sets it again).
        restore = _environ_restorer(WORKER_ENVIRON)
        stack.callback(restore)
        stack.enter_context(dask.config.set(CLUSTER_CONFIG))
        if scheduler is None:
            cluster = stack.enter_context(LocalCluster(
                n_workers=workers, threads_per_worker=1, processes=True, host="127.0.0.1",
                dashboard_address=None, silence_logs=logging.ERROR))
            restore()
            client = stack.enter_context(Client(cluster))
        else:
            try:
                client = stack.enter_context(Client(scheduler, timeout="30s"))
            except (OSError, TimeoutError) as e:
                raise FleetError(f"cannot reach the Dask scheduler at {scheduler}: {e}") from None
        if setup:
            client.register_plugin(FleetWorkerSetup())
        yield client


@dataclass
class _Pending:
    """Per actuator: the batch's tests in time order, and the results waiting for earlier ones."""
    order: list[str] = field(default_factory=list)      # source hashes, earliest first
    ready: dict[str, dict | None] = field(default_factory=dict)   # hash -> result (None: failed)


def _fmt_rate(n: int, seconds: float) -> str:
    return f"{3600.0 * n / seconds:,.0f}/h" if seconds > 0 and n else "-"


def plan(recordings: list[Recording], store: HistoryStore, failures: FailureLog,
         backfill: bool = False) -> tuple[list, int]:
    """(to do: [(recording, hash)], skipped): hash every file (a bag of several tests: every test
    window), drop those the store has (and repeats, and tests a monitor appended live: the same
    actuator, time and window stamp), fill ids and times from bag metadata; unreadable or
    unidentified files fail here, and so do a recording held for another actuator and a test
    the store would refuse (earlier than its actuator's latest, unless ``backfill``)."""
    known = dict(store.conn.execute("SELECT source_hash, actuator_id FROM tests"))
    latest = store.latest_times()
    todo, seen, skipped = [], {}, 0
    file_hashes: dict[Path, str] = {}
    windows = []
    for rec in recordings:
        try:
            windows += bag_windows(rec)        # a bag of several tests: one recording each
        except FleetError as e:
            failures.add(rec, str(e))
    for rec in windows:
        try:
            if rec.path not in file_hashes:
                file_hashes[rec.path] = sha256_file(rec.path)
            h = recording_hash(rec.path, rec.window, file_hashes[rec.path])
        except OSError as e:
            failures.add(rec, f"cannot read: {e.strerror or e}")
            continue
        owner = known.get(h, seen.get(h))
        if owner is not None:
            # the same recording again: nothing to do -- unless it is said to be another actuator's
            # (as `history add` refuses it)
            if rec.actuator_id is None:
                try:
                    complete_identity(rec)
                except ValueError:
                    pass
            if rec.actuator_id not in (None, owner):
                failures.add(rec, f"the same recording is {'in the history' if h in known else 'in this batch'} "
                                  f"for actuator {owner}, not {rec.actuator_id}", h)
            else:
                skipped += 1
            continue
        try:
            complete_identity(rec)
        except ValueError as e:
            failures.add(rec, str(e), h)
            continue
        seen[h] = rec.actuator_id
        if store.holds_test(rec.actuator_id, rec.time_h, rec.sim_time_s):    # appended live by a monitor
            skipped += 1
            continue
        try:   # a test the store would refuse (earlier than its actuator's latest) fails before its diagnosis
            store.check_next_time(rec.actuator_id, rec.time_h, rec.sim_time_s, rec.where(), latest, backfill)
        except PrognosticsError as e:
            failures.add(rec, f"not stored: {e}", h)
            continue
        todo.append((rec, h))
    # earliest tests of every actuator first, so results mostly arrive in the order they are written
    rank: dict[str, int] = {}
    keyed = []
    for rec, h in sorted(todo, key=lambda x: (x[0].actuator_id, x[0].time_h)):
        rank[rec.actuator_id] = rank.get(rec.actuator_id, -1) + 1
        keyed.append((rank[rec.actuator_id], rec.actuator_id, rec, h))
    return [(rec, h) for _, _, rec, h in sorted(keyed, key=lambda x: (x[0], x[1]))], skipped


def record_of(rec: Recording, h: str, res: dict) -> HealthRecord:
    """The store row of one successful task result."""
    return HealthRecord(rec.actuator_id, float(rec.time_h), tuple(res["k"]), tuple(res["std"]), usage=rec.usage,
                        usage_unit=rec.usage_unit, sim_time_s=rec.sim_time_s, method=res["method"], cost=res["cost"], fit_rms=res["rms"],
                        discrepancy=res.get("discrepancy"), warnings=res["warnings"], source_path=str(rec.path),
                        source_hash=h)


def diagnose_fleet(recordings: list[Recording], history: str | Path, scheduler: str | None = None,
                   workers: int = 2, method: str = DEFAULT_METHOD, seed: int = 0, discrepancy: bool = False,
                   progress: Callable[[str], None] | None = None, client=None, per_task: int | None = None,
                   backfill: bool = False) -> dict:
    """Diagnose every recording not yet in the store at ``history`` and append the results.

    ``per_task``: recordings per Dask task (default :data:`RECORDINGS_PER_TASK`, fewer when the
    batch is small: at least two tasks per worker). ``backfill``: tests older than their
    actuator's latest stored one are stored too (:meth:`HistoryStore.add_tests`).

    Returns the summary: ``recordings, diagnosed, skipped, failed, failures`` (first 20:
    path, reason), ``wall_time_s`` (all of it, cluster start included), ``batch_time_s``
    (first submit to last write), ``per_hour`` (diagnosed / batch time), mean ``read_s``,
    ``diagnosis_s`` and ``task_s`` on the workers, ``workers``, ``scheduler``, ``method``,
    ``history``, ``failures_file``, ``worker_setup`` (per worker: pid, warm-up time, numba threads,
    setups run, tasks run), ``task_numba_threads`` (numba's thread count seen inside the tasks).
    """
    if method not in METHODS:
        raise FleetError(f"unknown method {method!r}; choose from {', '.join(METHODS)}")
    t_start = time.perf_counter()
    failures = FailureLog(failures_path(history))
    try:
        store = HistoryStore(history)
    except PrognosticsError as e:
        raise FleetError(str(e)) from None
    with store:
        todo, skipped = plan(recordings, store, failures, backfill)
        # a bag of several tests is several recordings: count what the plan saw
        summary = {"recordings": len(todo) + skipped + failures.count, "files": len({r.path for r in recordings}),
                   "diagnosed": 0, "skipped": skipped, "failed": failures.count, "backfilled": [],
                   "method": method, "history": str(history), "failures_file": str(failures.path),
                   "scheduler": scheduler or "LocalCluster", "workers": None, "worker_setup": [],
                   "batch_time_s": 0.0}
        if progress:
            progress(f"{summary['recordings']} recordings: {len(todo)} to diagnose, {skipped} already in the history, "
                     f"{failures.count} failed before diagnosis")
        if todo:
            with contextlib.ExitStack() as stack:
                if client is None:
                    client = stack.enter_context(dask_client(scheduler, workers))
                summary.update(_run(client, todo, store, failures, method, seed, discrepancy, progress, summary,
                                    per_task, backfill))
        summary["failed"] = failures.count
        summary["failures"] = failures.items[:20]
        summary["wall_time_s"] = time.perf_counter() - t_start
        summary["per_hour"] = (3600.0 * summary["diagnosed"] / summary["batch_time_s"]
                               if summary["batch_time_s"] > 0 else None)
    return summary


def _run(client, todo, store: HistoryStore, failures: FailureLog, method: str, seed: int, discrepancy: bool,
         progress, summary: dict, per_task: int | None = None, backfill: bool = False) -> dict:
    from distributed import as_completed
    # the calibrated monitor goes to every worker once; tasks carry only a reference to it
    # a key of this batch's own (hash=False): the content-hashed key was the same in every batch,
    # and a batch right after another on the same client re-scattered it while the first's release
    # was still deleting it from the workers ("lost dependencies": 7 of 12 successive batches lost
    # a task; test_successive_batches_on_one_client_lose_no_task)
    params = client.scatter(load("monitor"), broadcast=True, hash=False)
    t0 = time.perf_counter()
    by_hash = {h: rec for rec, h in todo}
    pending: dict[str, _Pending] = {}
    for rec, h in sorted(todo, key=lambda x: (x[0].actuator_id, x[0].time_h)):
        pending.setdefault(rec.actuator_id, _Pending()).order.append(h)
    # a few recordings per task (in the submission order: earliest tests first), at least two tasks per
    # worker so that none idles at the end
    n_workers = max(len(client.scheduler_info().get("workers", {})), 1)
    size = per_task if per_task is not None else max(1, min(RECORDINGS_PER_TASK, len(todo) // (2 * n_workers)))
    if size < 1:
        raise FleetError(f"recordings per task must be >= 1, got {size}")
    chunks = [todo[i:i + size] for i in range(0, len(todo), size)]
    futures = [client.submit(diagnose_recordings, [(str(rec.path), rec.window) for rec, _ in chunk], params, method, seed,
                             discrepancy, key=f"eha-diagnose-{chunk[0][1]}-{len(chunk)}", pure=False)
               for chunk in chunks]
    hashes = {f.key: [h for _, h in chunk] for f, chunk in zip(futures, chunks)}
    done = ok = late_skips = 0
    backfilled: dict[str, tuple[list[float], list[float]]] = {}   # actuator -> (its back-filled times, later ones)
    last_line = 0.0
    threads: set[int] = set()
    times = {"read_s": 0.0, "diagnosis_s": 0.0, "task_s": 0.0, "diagnosis_cpu_s": 0.0, "task_cpu_s": 0.0}

    def flush(actuator: str) -> None:
        nonlocal done, late_skips
        p = pending[actuator]
        while p.order and p.order[0] in p.ready:
            h = p.order.pop(0)
            res = p.ready.pop(h)
            if res is None:
                continue
            rec = by_hash[h]
            try:
                added = store.add_tests([record_of(rec, h, res)], [rec.where()], backfill)
            except (PrognosticsError, ValueError) as e:
                failures.add(rec, f"not stored: {e}", h)
                continue
            done += added
            later = store.later_tests(rec.actuator_id, rec.time_h) if backfill and added else []
            if later:       # earlier tests go in first (the order above): these later ones were there before
                backfilled.setdefault(rec.actuator_id, ([], later))[0].append(rec.time_h)
            # nothing added, no error: the store got the test meanwhile (another batch, a monitor) or
            # holds it from another file (a log cut at two lengths): counted as skipped, not lost
            late_skips += 1 - added

    n = 0
    for fut in as_completed(futures):
        task = hashes[fut.key]
        try:
            results = fut.result()
        except Exception as e:   # the task itself died (worker killed, ...): its files fail, the batch goes on
            results = [{"error": f"task failed: {type(e).__name__}: {e}"}] * len(task)
        fut.release()
        for h, res in zip(task, results):
            n += 1
            rec = by_hash[h]
            if "error" in res:
                failures.add(rec, res["error"], h)
                pending[rec.actuator_id].ready[h] = None
            else:
                ok += 1
                threads.add(res["numba_threads"])
                for k in times:
                    times[k] += res.get(k, 0.0)
                pending[rec.actuator_id].ready[h] = res
            flush(rec.actuator_id)
        el = time.perf_counter() - t0
        if progress and (el - last_line >= 2.0 or n == len(todo)):
            last_line = el
            progress(f"{n}/{len(todo)} done: {done} stored, {failures.count} failed, {_fmt_rate(n, el)}, "
                     f"{el:.0f} s")
    ok = max(ok, 1)
    info = client.run(worker_info)
    return {"diagnosed": done, "skipped": summary["skipped"] + late_skips, "batch_time_s": time.perf_counter() - t0,
            "backfilled": [backfill_note(a, t, later) for a, (t, later) in sorted(backfilled.items())],
            "workers": len(client.scheduler_info().get("workers", {})),
            "worker_setup": list(info.values()), "task_numba_threads": sorted(threads),
            **{f"mean_{k}": v / ok for k, v in times.items()}}


def format_summary(s: dict) -> str:
    """The end-of-batch lines: done, skipped, failed, throughput."""
    lines = [f"fleet diagnose: {s['diagnosed']} diagnosed and stored, {s['skipped']} skipped (already in the "
             f"history), {s['failed']} failed, of {s['recordings']} recordings"
             + (f" in {s['files']} files" if s.get("files") not in (None, s["recordings"]) else "")]
    if s.get("per_hour"):
        lines.append(f"  throughput {s['per_hour']:,.0f} diagnoses/h ({s['method']}) on {s['workers']} worker(s) "
                     f"of {s['scheduler']}; batch {s['batch_time_s']:.1f} s, total {s['wall_time_s']:.1f} s")
        lines.append(f"  per task on the workers: read {s['mean_read_s']:.2f} s, diagnosis {s['mean_diagnosis_s']:.2f} s, "
                     f"task {s['mean_task_s']:.2f} s")
    for note in s.get("backfilled", [])[:5]:
        lines.append(f"  {note}")
    if len(s.get("backfilled", [])) > 5:
        lines.append(f"  back-filled: {len(s['backfilled']) - 5} more actuator(s) (--json lists them)")
    for f in s.get("failures", [])[:5]:
        lines.append(f"  failed: {f['path']}: {f['reason']}")
    if s["failed"]:
        lines.append(f"  failures logged in {s['failures_file']}")
    lines.append(f"  history: {s['history']}")
    return "\n".join(lines)
