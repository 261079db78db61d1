#!/usr/bin/env python3
"""Golden outputs: the same inputs must give the same numbers across a refactor.

    python tools/golden.py record [--only NAME ...]   # run every command, save tests/golden/NAME.json
    python tools/golden.py check  [--only NAME ...]   # run again, compare with the saved outputs
    python tools/golden.py speed --baseline REV [--rounds N]
                                                      # speed of REV and this tree, side by side

Every case is a command of the ``eha-health`` console script (the public face, so the
comparison does not care where a module lives), run in the venv of the interpreter
that runs this script. ``check`` compares every number of the saved JSON to 1e-9
(relative, absolute below 1) except wall times and the bench speed figures; it prints
each difference with its path and exits 1 if there is any. ``speed`` exports REV into a
temporary folder and times it and this tree alternately in fresh processes (same venv,
``PYTHONPATH`` picking the tree): monitor and reference real-time factors and the
diagnosis time, each the median over ``--rounds`` rounds, with the ratio this/REV.

Run from the repository root (``make golden-check`` runs ``check``).
"""
from __future__ import annotations

import argparse
import hashlib
import json
import math
import os
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
GOLDEN = ROOT / "tests" / "golden"
RIG = ROOT.parent / "shared" / "data" / "mts_servohydraulic_chirp" / "0A.txt"
BAGS = sorted(p.name for p in (ROOT / "bags").glob("*.mcap"))
#: Keys whose values are wall-clock measurements (not outputs of the algorithm) or file locations.
IGNORED = re.compile(r"wall|^source$|^log$|^first_call")
RTOL = 1e-9


def eha(*args: str) -> str:
    exe = Path(sys.executable).parent / "eha-health"
    out = subprocess.run([str(exe), *args], cwd=ROOT, capture_output=True, text=True)
    if out.returncode != 0:
        raise RuntimeError(f"eha-health {' '.join(args)} failed ({out.returncode}):\n{out.stderr[-2000:]}")
    return out.stdout


def _json(*args: str):
    return json.loads(eha(*args))


def _csv_digest(*args: str) -> dict:
    with tempfile.TemporaryDirectory() as d:
        out = Path(d) / "run.csv"
        eha(*args, "--out", str(out))
        text = out.read_text()
    return {"sha256": hashlib.sha256(text.encode()).hexdigest(), "rows": text.count("\n") - 1}


def _rig() -> dict | None:
    if not RIG.is_file():
        return None
    with tempfile.TemporaryDirectory() as d:
        csv = Path(d) / "mts.csv"
        eha("import", str(RIG), "--map", "maps/mts_servohydraulic.yaml", "--out", str(csv))
        return _json("discrepancy", str(csv), "--json", "--quiet")


def cases() -> dict:
    """name -> callable returning the JSON-able output (None: not available here, skipped)."""
    c = {
        "simulate_reference": lambda: _csv_digest("simulate", "--faults", "gm=0.4,fsj=0.6,bkl=0.4"),
        "simulate_monitor": lambda: _csv_digest("simulate", "--model", "monitor", "--faults", "gm=0.3,fsj=0.2,bkl=0.5"),
        "simulate_effects": lambda: _csv_digest("simulate", "--faults", "gm=0.2,bkl=0.3", "--noise", "--seed", "3",
                                                "--effects", "compressibility,sensor_delay,stribeck,command_noise"),
        "calibrate": lambda: _json("calibrate", "--json"),
        "paper": lambda: _json("bench", "paper", "--method", "all", "--json"),
    }
    for b in BAGS:
        stem = b.removesuffix(".mcap")
        c[f"diagnose_{stem}"] = (lambda b=b: _json("diagnose", f"bags/{b}", "--json"))
        c[f"discrepancy_{stem}"] = (lambda b=b: _json("discrepancy", f"bags/{b}", "--json", "--quiet"))
    c["discrepancy_rig"] = _rig
    c["speed"] = lambda: _json("bench", "speed", "--json", "--no-compile")
    return c


def compare(a, b, path: str = "") -> list[str]:
    """Differences between saved ``a`` and new ``b`` (numbers to RTOL; ignored keys skipped)."""
    if isinstance(a, dict) and isinstance(b, dict):
        out = []
        for k in sorted(set(a) | set(b)):
            if IGNORED.search(str(k)):
                continue
            if k not in a or k not in b:
                out.append(f"{path}/{k}: {'added' if k in b else 'missing'}")
                continue
            out += compare(a[k], b[k], f"{path}/{k}")
        return out
    if isinstance(a, list) and isinstance(b, list):
        if len(a) != len(b):
            return [f"{path}: length {len(a)} -> {len(b)}"]
        return [d for i, (x, y) in enumerate(zip(a, b)) for d in compare(x, y, f"{path}[{i}]")]
    if isinstance(a, (int, float)) and isinstance(b, (int, float)) and not isinstance(a, bool):
        if math.isnan(a) and math.isnan(b):
            return []
        if a == b or abs(a - b) <= RTOL * max(1.0, abs(a), abs(b)):
            return []
        return [f"{path}: {a!r} -> {b!r}"]
    return [] if a == b else [f"{path}: {a!r} -> {b!r}"]


def _selected(names) -> dict:
    all_cases = cases()
    unknown = [n for n in names or () if n not in all_cases]
    if unknown:
        sys.exit(f"unknown case(s) {unknown}; known: {', '.join(all_cases)}")
    return {n: f for n, f in all_cases.items() if not names or n in names}


def record(names) -> int:
    GOLDEN.mkdir(parents=True, exist_ok=True)
    for name, fn in _selected(names).items():
        t0 = time.perf_counter()
        out = fn()
        if out is None:
            print(f"{name}: not available here (skipped)")
            continue
        (GOLDEN / f"{name}.json").write_text(json.dumps(out, indent=1, sort_keys=True, default=float) + "\n")
        print(f"{name}: saved ({time.perf_counter() - t0:.1f} s)", flush=True)
    return 0


def check(names) -> int:
    bad = 0
    for name, fn in _selected(names).items():
        saved = GOLDEN / f"{name}.json"
        if not saved.is_file():
            print(f"{name}: no saved output (run record first)")
            continue
        if name == "speed":
            print("speed: not compared here (wall clock); use `golden.py speed --baseline REV`")
            continue
        t0 = time.perf_counter()
        new = fn()
        if new is None:
            print(f"{name}: not available here (skipped)")
            continue
        new = json.loads(json.dumps(new, default=float))
        diffs = compare(json.loads(saved.read_text()), new)
        bad += bool(diffs)
        print(f"{name}: {'SAME' if not diffs else f'{len(diffs)} DIFFERENCE(S)'} ({time.perf_counter() - t0:.1f} s)",
              flush=True)
        for d in diffs[:40]:
            print(f"    {d}")
    print("golden: all identical" if not bad else f"golden: {bad} case(s) differ")
    return 1 if bad else 0


_SPEED = r"""
import json, time
import numpy as np
from eha_health import Faults, Plant, simulate, load
try:
    from eha_health import diagnose
except ImportError:
    from eha_health.identify import diagnose
from eha_health import FDISequence
seq = FDISequence(); cmd = seq.command(seq.times(1000.0))
out = {}
for kind in ("reference", "monitor"):
    p = Plant(kind=kind, faults=Faults(0.4, 0.6, 0.4)); p.step(cmd)
    ts = []
    for _ in range(7):
        p.reset(); t0 = time.perf_counter(); p.step(cmd); ts.append(time.perf_counter() - t0)
    out[kind + "_realtime_factor"] = seq.duration / min(ts)
r = simulate(faults=Faults(0.4, 0.6, 0.4))
diagnose(r, method="deterministic")
try:
    from eha_health.identification.diagnose import DEFAULT_METHOD
except ImportError:
    DEFAULT_METHOD = "hybrid"
diagnose(r)
for m in ("hybrid", "deterministic", "default"):
    ts = []
    for _ in range(3):
        t0 = time.perf_counter(); diagnose(r, method=DEFAULT_METHOD if m == "default" else m)
        ts.append(time.perf_counter() - t0)
    out["diagnose_" + m + "_s"] = min(ts)
print(json.dumps(out))
"""


def speed(baseline: str, rounds: int) -> int:
    import statistics
    with tempfile.TemporaryDirectory() as d:
        base = Path(d) / "baseline"
        base.mkdir()
        archive = subprocess.run(["git", "archive", baseline], cwd=ROOT, capture_output=True, check=True).stdout
        subprocess.run(["tar", "-x", "-C", str(base)], input=archive, check=True)
        trees = {"baseline": base, "this": ROOT}
        res: dict[str, list[dict]] = {k: [] for k in trees}
        for i in range(rounds):
            for name, tree in trees.items():
                env = dict(os.environ, PYTHONPATH=f"{tree / 'src'}{os.pathsep}{tree}")
                p = subprocess.run([sys.executable, "-c", _SPEED], env=env, capture_output=True, text=True)
                if p.returncode:
                    sys.exit(f"{name}: speed run failed:\n{p.stderr[-2000:]}")
                res[name].append(json.loads(p.stdout.strip().splitlines()[-1]))
            print(f"round {i + 1}/{rounds} done", file=sys.stderr, flush=True)
    keys = list(res["this"][0])
    print(f"side by side, median of {rounds} alternating rounds (baseline {baseline} vs this tree):")
    print(f"  {'figure':32s} {'baseline':>10s} {'this':>10s} {'this/baseline':>14s}")
    for k in keys:
        a = statistics.median(r[k] for r in res["baseline"])
        b = statistics.median(r[k] for r in res["this"])
        print(f"  {k:32s} {a:10.4g} {b:10.4g} {b / a:14.3f}")
    return 0


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = ap.add_subparsers(dest="cmd", required=True)
    for name in ("record", "check"):
        s = sub.add_parser(name)
        s.add_argument("--only", nargs="*", help="case names (default all)")
    s = sub.add_parser("speed")
    s.add_argument("--baseline", required=True, help="git revision to compare against")
    s.add_argument("--rounds", type=int, default=5)
    a = ap.parse_args()
    if a.cmd == "speed":
        return speed(a.baseline, a.rounds)
    return record(a.only) if a.cmd == "record" else check(a.only)


if __name__ == "__main__":
    sys.exit(main())
