"""read_run of this tree against an older revision, side by side in one process.

    python tools/bagread_compare.py [--rev REV] [--reps N] [--mutations N] [--seed S] [BAG ...]

The older revision's ``eha_health`` is exported (``git archive``) into a temporary folder as
the package ``eha_health_old``. For each bag (default every bag in bags/), plain and as a rig
record, both read_run must give the same Run bit for bit (every channel, stamps, windows, notes,
truth) or the same error; then the bags are timed, old and new interleaved (medians). With
``--mutations N``, N cut / bit-flipped / overwritten copies of a small contract bag are compared
the same way. Exit code 1 if anything differs.
"""
from __future__ import annotations

import argparse
import dataclasses
import importlib
import io
import random
import statistics
import struct
import subprocess
import sys
import tarfile
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent


def _old_package(rev: str, into: Path):
    """The revision's eha_health, importable as eha_health_old (its imports are relative)."""
    tar = subprocess.run(["git", "-C", str(ROOT), "archive", rev, "src/eha_health"],
                         check=True, capture_output=True).stdout
    with tarfile.open(fileobj=io.BytesIO(tar)) as t:
        t.extractall(into, filter="data")
    (into / "src" / "eha_health").rename(into / "eha_health_old")
    sys.path.insert(0, str(into))
    return importlib.import_module("eha_health_old.io.bagrun")


def _plain(run) -> dict:
    r = run.response
    arrays = {f.name: (lambda v: (v.dtype.str, v.shape, v.tobytes()) if isinstance(v, np.ndarray) else v)(
        getattr(r, f.name)) for f in dataclasses.fields(r)}
    return {"response": arrays, **{k: getattr(run, k) for k in ("test_id", "windows", "truth", "recorded", "notes")}}


def _outcome(read_run, path, **kw):
    try:
        return ("ok", _plain(read_run(path, **kw)))
    except Exception as e:  # the error itself is compared
        return ("error", type(e).__name__, str(e))


def _compare(old, new, path) -> list[str]:
    out = []
    for kw in ({}, {"record": True}):
        a, b = _outcome(old, path, **kw), _outcome(new, path, **kw)
        if a != b:
            out.append(f"{path} {kw}: old {a if a[0] == 'error' else 'ok'}, new {b if b[0] == 'error' else 'ok'}")
    return out


class _Mangle:
    """A BagWriter that changes a few of the messages written through it: a flipped bit after the
    encapsulation header, bytes cut off or appended (each message with probability 1/``every``)."""

    def __init__(self, writer, rng: random.Random, every: int):
        from mcap_ros2._dynamic import serialize_dynamic

        from eha_health.io.mcaplog import schema_text
        self.w, self.rng, self.every = writer, rng, every
        self.encode = lambda typ: serialize_dynamic(typ, schema_text(typ))[typ]

    def add_metadata(self, *a):
        self.w.add_metadata(*a)

    def write(self, topic, typ, msg, ns):
        from eha_health.io.mcaplog import _plain
        data = bytearray(self.encode(typ)(_plain(msg)))
        if self.rng.randrange(self.every) == 0:
            how = self.rng.choice(["flip", "cut", "extend"])
            if how == "flip":
                data[self.rng.randrange(2, len(data))] ^= 1 << self.rng.randrange(8)
            elif how == "cut":
                del data[self.rng.randrange(4, len(data)):]
            else:
                data += bytes(self.rng.randrange(256) for _ in range(self.rng.randint(1, 9)))
        self.w.write_raw(topic, typ, bytes(data), ns)


def _mutations(old, new, n: int, seed: int, tmp: Path) -> tuple[int, list[str]]:
    from eha_health.io.bagrun import write_run
    from eha_health.io.mcaplog import BagWriter
    from eha_health.signals.response import Response
    rng = random.Random(seed)
    t = np.arange(701) * 5e-3  # the 3.5 s FDI test at 200 Hz: a whole window, read fast enough
    r = Response(t=t, command=1e-3 * np.sin(20 * t), position=1e-3 * np.sin(20 * t - 0.1), velocity=np.cos(t),
                 pressure=1e5 * np.cos(3 * t), current=0.01 * np.sin(t), spool=np.zeros(t.size))
    truth = {"k_gm": 0.1, "k_fsj": 0.2, "k_bkl": 0.3}
    base = tmp / "base.mcap"
    with BagWriter(base, chunk_size=4096) as w:
        write_run(w, r, test_id=3, start_ns=10**9, truth=truth)
    data0, diffs = base.read_bytes(), []
    for _ in range(n):
        d = bytearray(data0)
        kind = rng.choice(["cut", "flip", "flip", "length", "payload", "payload"])
        if kind == "payload":  # messages changed before they are written: intact file, odd CDR
            with BagWriter(tmp / "case.mcap", chunk_size=4096) as w:
                write_run(_Mangle(w, rng, 4000), r, test_id=3, start_ns=10**9, truth=truth)
            d = bytearray((tmp / "case.mcap").read_bytes())
        elif kind == "cut":
            d = d[:rng.randrange(len(d))]
        elif kind == "flip":
            for _ in range(rng.randint(1, 4)):
                d[rng.randrange(8, len(d))] ^= 1 << rng.randrange(8)
        else:
            pos = rng.randrange(8, len(d) - 8)
            d[pos:pos + 8] = struct.pack("<Q", rng.choice([0, 1, 2**32 - 1, 2**63 - 1, rng.randrange(2**64)]))
        case = tmp / "case.mcap"
        case.write_bytes(bytes(d))
        diffs += [f"{kind}: {m}" for m in _compare(old, new, case)]
    return 2 * n, diffs


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("bags", nargs="*", type=Path)
    ap.add_argument("--rev", default="b9af69c", help="older revision (default b9af69c, before scan_bag/cdrbatch)")
    ap.add_argument("--reps", type=int, default=5, help="timed reads per bag and side (5)")
    ap.add_argument("--mutations", type=int, default=0, help="mutated contract bags to compare (0)")
    ap.add_argument("--seed", type=int, default=1, help="seed of the mutations (1)")
    a = ap.parse_args(argv)
    bags = a.bags or sorted((ROOT / "bags").glob("*.mcap"))
    from eha_health.io.bagrun import read_run as new
    with tempfile.TemporaryDirectory() as tmp:
        old = _old_package(a.rev, Path(tmp)).read_run
        diffs = [m for p in bags for m in _compare(old, new, p)]
        print(f"identical: {2 * len(bags) - len(diffs)} of {2 * len(bags)} bag reads (plain and record)")
        if a.mutations:
            n, mdiffs = _mutations(old, new, a.mutations, a.seed, Path(tmp))
            print(f"identical: {n - len(mdiffs)} of {n} mutated-bag reads (seed {a.seed})")
            diffs += mdiffs
        for m in diffs:
            print("DIFFERS", m)
        ratios = []
        for p in bags:
            to, tn = [], []
            for _ in range(a.reps):
                t0 = time.perf_counter()
                old(p)
                t1 = time.perf_counter()
                new(p)
                to.append(t1 - t0)
                tn.append(time.perf_counter() - t1)
            mo, mn = statistics.median(to), statistics.median(tn)
            ratios.append(mo / mn)
            print(f"{p.name:34s} old {mo:6.3f} s  new {mn:6.3f} s  {mo / mn:5.1f}x")
        print(f"read_run speed-up, median over {len(bags)} bags: {statistics.median(ratios):.1f}x "
              f"(old = {a.rev}, interleaved, medians of {a.reps}; load {_load()})")
    return 1 if diffs else 0


def _load() -> str:
    try:
        return Path("/proc/loadavg").read_text().split()[0]
    except OSError:
        return "unknown"


if __name__ == "__main__":
    sys.exit(main())
