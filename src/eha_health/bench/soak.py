"""``eha-health bench soak``: many consecutive FDI tests through the in-process node graph.

Figures, not assertions: windows lost (a test without a diagnosis), resident memory growth
after the warm-up [%], thread count, and whether diagnosis time drifts (median of the last
tenth over the first tenth after the warm-up). Every test prints one progress line (so a run
stopped early still says what it measured); ``--plot`` draws memory and diagnosis time per test.
"""
from __future__ import annotations

import ctypes
import ctypes.util
import gc
import os
import signal
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from ..physics.faults import Faults
from ..ros.graph import Graph


def _proc_status() -> tuple[float, int]:
    """(resident memory [MB], OS threads) of this process, from /proc/self/status."""
    rss, threads = float("nan"), 0
    with open(f"/proc/{os.getpid()}/status") as f:
        for line in f:
            if line.startswith("VmRSS:"):
                rss = int(line.split()[1]) / 1024.0
            elif line.startswith("Threads:"):
                threads = int(line.split()[1])
    return rss, threads


class _Mallinfo2(ctypes.Structure):
    _fields_ = [(n, ctypes.c_size_t) for n in ("arena", "ordblks", "smblks", "hblks", "hblkhd", "usmblks",
                                               "fsmblks", "uordblks", "fordblks", "keepcost")]


def _heap_mb() -> float:
    """Bytes the C heap has handed out and not had back [MB] (glibc ``mallinfo2``: in-use arena
    blocks + mmapped blocks; NaN elsewhere): numpy arrays, message buffers, native libraries.
    Unlike RSS it excludes memory malloc keeps after a ``free`` (fragmented arenas it does not
    return to the OS): growth here is held data, growth of RSS alone is the allocator. Python's
    small objects (<= 512 B) live in pymalloc's own arenas, outside it: see ``py_blocks``."""
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c"))
        libc.mallinfo2.restype = _Mallinfo2
    except (OSError, AttributeError, TypeError):
        return float("nan")
    m = libc.mallinfo2()
    return (m.uordblks + m.hblkhd) / 2**20


def soak(tests: int = 300, warmup: int = 20, faults: Faults = Faults(0.4, 0.6, 0.4), seed: int = 0,
         progress=None) -> dict:
    """Run ``tests`` consecutive tests (the first ``warmup`` not counted in the drift figures)."""
    if tests <= warmup:
        raise ValueError(f"tests ({tests}) must exceed the warm-up ({warmup})")
    rows = []

    def stop(signum, frame):   # SIGTERM as Ctrl-C: a run stopped from outside still summarises
        raise KeyboardInterrupt
    previous = signal.signal(signal.SIGTERM, stop)
    try:
        return _soak(tests, warmup, faults, seed, progress, rows)
    finally:
        signal.signal(signal.SIGTERM, previous)


def _soak(tests, warmup, faults, seed, progress, rows) -> dict:
    with tempfile.TemporaryDirectory(prefix="eha-soak-") as tmp, \
            Graph(faults=faults, seed=seed, log_path=Path(tmp) / "soak.mcap") as g:
        try:
            for i in range(tests):
                t0, c0 = time.perf_counter(), time.process_time()
                r = g.run_test()
                wall, cpu = time.perf_counter() - t0, time.process_time() - c0
                gc.collect()   # memory held, not garbage waiting for the collector
                rss, threads = _proc_status()
                heap, blocks = _heap_mb(), sys.getallocatedblocks()
                d = r["diagnosis"]
                rows.append({"test": i + 1, "ok": d is not None, "level": r["level"], "rss_mb": rss, "heap_mb": heap, "py_blocks": blocks,
                             "threads": threads,
                             "diagnosis_s": d.wall_time_s if d else float("nan"), "wall_s": wall, "cpu_s": cpu,
                             "k": list(d.faults.as_tuple()) if d else None})
                if progress:
                    progress(f"soak test {i + 1}/{tests}: {r['level']}, RSS {rss:.1f} MB, heap {heap:.1f} MB, "
                             f"{blocks} Python blocks, {threads} threads, "
                             f"diagnosis {rows[-1]['diagnosis_s']:.2f} s, test {wall:.2f} s ({cpu:.2f} s CPU), "
                             f"load {os.getloadavg()[0]:.1f}")
        except KeyboardInterrupt:   # Ctrl-C or SIGTERM: summarise the tests run so far
            if len(rows) <= warmup:
                raise
            if progress:
                progress(f"soak stopped after {len(rows)} tests")
        log_mb = (Path(tmp) / "soak.mcap").stat().st_size / 1e6
        results = g.monitor.verdicts
    return summarise(rows, warmup, results, log_mb, planned=tests)


def summarise(rows: list[dict], warmup: int, results: int, log_mb: float, planned: int | None = None) -> dict:
    after = rows[warmup:]
    rss = np.array([r["rss_mb"] for r in after])
    heap = np.array([r.get("heap_mb", np.nan) for r in after])
    blocks = np.array([r.get("py_blocks", np.nan) for r in after], float)
    thr = np.array([r["threads"] for r in after])
    diag = np.array([r["diagnosis_s"] for r in after])
    cpu = np.array([r.get("cpu_s", np.nan) for r in after])
    tenth = max(1, len(after) // 10)
    first, last = np.nanmedian(diag[:tenth]), np.nanmedian(diag[-tenth:])
    cpu_first, cpu_last = np.nanmedian(cpu[:tenth]), np.nanmedian(cpu[-tenth:])
    return {"tests": len(rows), "planned": planned or len(rows), "warmup": warmup, "verdicts": results,
            "windows_lost": sum(not r["ok"] for r in rows),
            "rss_after_warmup_mb": float(rss[0]), "rss_end_mb": float(rss[-1]), "rss_max_mb": float(rss.max()),
            "rss_growth_pct": float(100 * (rss[-1] - rss[0]) / rss[0]),
            "heap_after_warmup_mb": float(heap[0]), "heap_end_mb": float(heap[-1]),
            "rss_slope_last_half_mb": _slope(rss), "heap_slope_last_half_mb": _slope(heap),
            "py_blocks_after_warmup": float(blocks[0]), "py_blocks_end": float(blocks[-1]),
            "threads_min": int(thr.min()), "threads_max": int(thr.max()),
            "diagnosis_first_tenth_s": float(first), "diagnosis_last_tenth_s": float(last),
            "diagnosis_drift_ratio": float(last / first),
            "cpu_first_tenth_s": float(cpu_first), "cpu_last_tenth_s": float(cpu_last),
            "cpu_drift_ratio": float(cpu_last / cpu_first), "log_mb": log_mb, "rows": rows}


def _slope(y: np.ndarray) -> float:
    """Least-squares trend of the last half of ``y`` [MB per test] (NaN with < 4 points)."""
    y = y[len(y) // 2:]
    if len(y) < 4 or not np.isfinite(y).all():
        return float("nan")
    return float(np.polyfit(np.arange(len(y)), y, 1)[0])


def format_soak(res: dict) -> str:
    return "\n".join([
        f"soak: {res['tests']} consecutive tests through the in-process graph (warm-up {res['warmup']})"
        + (f", stopped early (of {res['planned']})" if res.get("planned", res["tests"]) > res["tests"] else ""),
        f"  windows lost:      {res['windows_lost']} ({res['verdicts']} verdicts)",
        f"  resident memory:   {res['rss_after_warmup_mb']:.1f} MB after warm-up -> {res['rss_end_mb']:.1f} MB "
        f"at the end ({res['rss_growth_pct']:+.2f} %; max {res['rss_max_mb']:.1f} MB)",
        f"  trend, last half:  RSS {res['rss_slope_last_half_mb']:+.3f} MB/test, heap in use "
        f"{res['heap_slope_last_half_mb']:+.3f} MB/test (heap {res['heap_after_warmup_mb']:.1f} -> "
        f"{res['heap_end_mb']:.1f} MB: what malloc has handed out, not what it keeps)",
        f"  Python objects:    {res.get('py_blocks_after_warmup', float('nan')):.0f} -> "
        f"{res.get('py_blocks_end', float('nan')):.0f} pymalloc blocks in use (sys.getallocatedblocks)",
        f"  threads:           {res['threads_min']} .. {res['threads_max']}",
        f"  diagnosis time:    median {res['diagnosis_first_tenth_s']:.2f} s (first tenth) -> "
        f"{res['diagnosis_last_tenth_s']:.2f} s (last tenth), ratio {res['diagnosis_drift_ratio']:.2f} (wall clock)",
        f"  CPU per test:      median {res.get('cpu_first_tenth_s', float('nan')):.2f} s (first tenth) -> "
        f"{res.get('cpu_last_tenth_s', float('nan')):.2f} s (last tenth), ratio "
        f"{res.get('cpu_drift_ratio', float('nan')):.2f} (the process's CPU time: drift of the work, not of the load)",
        f"  MCAP log:          {res['log_mb']:.1f} MB"])


def plot_soak(res: dict, path: str | Path) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    rows = res["rows"]
    n = [r["test"] for r in rows]
    fig, ax = plt.subplots(3, 1, figsize=(8, 7), sharex=True)
    ax[0].plot(n, [r["rss_mb"] for r in rows], label="resident (RSS)")
    ax[0].plot(n, [r.get("heap_mb", np.nan) for r in rows], label="C heap in use (mallinfo2)")
    ax[0].set_ylabel("memory [MB]")
    ax[0].legend(fontsize=8)
    ax[1].plot(n, [r["threads"] for r in rows])
    ax[1].set_ylabel("threads")
    ax[2].plot(n, [r["diagnosis_s"] for r in rows], ".", label="diagnosis (wall)")
    ax[2].plot(n, [r.get("cpu_s", np.nan) for r in rows], ".", label="whole test (process CPU)")
    ax[2].set_ylabel("time [s]")
    ax[2].legend(fontsize=8)
    ax[2].set_xlabel("test")
    for a in ax:
        a.axvline(res["warmup"] + 0.5, color="grey", lw=0.8, ls="--")
    ax[0].set_title(f"soak: {res['tests']} tests, RSS {res['rss_growth_pct']:+.2f} % after warm-up, "
                    f"{res['windows_lost']} windows lost")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
