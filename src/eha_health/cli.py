"""``eha-health``: the command-line entry point.

Subcommands: simulate, calibrate, signatures, bench speed, demo. Bad input exits
with code 2 and one line that says what is wrong.
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from .params import Faults, load

EFFECT_NAMES = ("compressibility", "sensor_noise", "quantization", "sensor_delay", "sensor_calibration",
                "stribeck", "command_noise")


class UsageError(Exception):
    """Bad user input: reported in one line, exit code 2."""


def _progress_line(msg: str) -> None:
    """Progress of long work, on stderr so --json output stays clean."""
    print("  " + msg, file=sys.stderr, flush=True)


def _params(args, kind: str):
    p = load(kind, path=getattr(args, "params", None))
    effects = [e.strip() for e in (getattr(args, "effects", None) or "").split(",") if e.strip()]
    if getattr(args, "noise", False):
        effects.append("sensor_noise")
    for e in effects:
        if e not in EFFECT_NAMES:
            raise UsageError(f"unknown effect {e!r}; known: {', '.join(EFFECT_NAMES)}")
        p = p.with_effects(**{e: {"enabled": True}})
    return p


def cmd_simulate(args) -> int:
    from .model import simulate
    from .plotting import plot_response
    faults = Faults.parse(args.faults or "")
    params = _params(args, args.model)
    seed = args.seed
    eff = params.effects
    if seed is None and (eff.sensor_noise.enabled or eff.command_noise.enabled):
        seed = 0
        print("note: noise enabled without --seed; using seed 0", file=sys.stderr)
    r = simulate(args.model, faults, params=params, seed=seed)
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    r.to_csv(out)
    msg = f"wrote {out} ({len(r)} samples at {params.integration.sample_rate:g} Hz, {args.model} model, " \
          f"faults gm={faults.k_gm:g} fsj={faults.k_fsj:g} bkl={faults.k_bkl:g})"
    if args.plot:
        plot_response(r, args.plot, title=f"{args.model}: gm={faults.k_gm:g} fsj={faults.k_fsj:g} bkl={faults.k_bkl:g}")
        msg += f"; plot {args.plot}"
    print(msg)
    return 0


def cmd_calibrate(args) -> int:
    from .calibrate import calibrate, write_monitor_yaml
    print("calibrating the monitor first stage on the healthy reference response ...", file=sys.stderr)
    res = calibrate(verbose=not args.json)
    if args.out:
        write_monitor_yaml(res, args.out)
    if args.json:
        print(json.dumps({"values": res.values, "rms_before": res.rms_before, "rms_after": res.rms_after,
                          "evaluations": res.evaluations, "wall_time_s": res.wall_time_s}, indent=2))
    else:
        print("fitted first stage:")
        for k, v in res.values.items():
            print(f"  {k:22s} {v:.6g}")
        print("RMS monitor - reference (healthy)   before        after")
        for c in res.rms_after:
            print(f"  {c:30s} {res.rms_before[c]:10.3g}  {res.rms_after[c]:10.3g}")
        print(f"{res.evaluations} simulations, {res.wall_time_s:.1f} s" + (f"; wrote {args.out}" if args.out else ""))
    return 0


def cmd_signatures(args) -> int:
    import csv

    from .plotting import plot_signature_families, trend_table
    from .signatures import Detector
    out = Path(args.out)
    files = plot_signature_families(out, progress=None if args.quiet else _progress_line)
    rows = trend_table()
    with (out / "signatures.csv").open("w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)
    det = Detector.build()
    (out / "thresholds.json").write_text(json.dumps(
        {"level": det.level, "margin": det.margin, "thresholds": det.thresholds(),
         "healthy": det.healthy.as_dict()}, indent=2))
    for f in files:
        print(f"wrote {f}")
    print(f"wrote {out / 'signatures.csv'} and {out / 'thresholds.json'}")
    return 0


def cmd_bench(args) -> int:
    if args.what == "speed":
        from .bench import format_speed, speed
        res = speed(with_compile=not args.no_compile)
        print(json.dumps(res, indent=2) if args.json else format_speed(res))
        return 0
    if args.what != "paper":
        raise UsageError(f"unknown benchmark {args.what!r}; available: speed, paper")
    from .identify import METHODS
    from .paperbench import format_markdown, format_text, run_bench
    methods = METHODS if args.method == "all" else (args.method,)
    if args.method != "all" and args.method not in METHODS:
        raise UsageError(f"unknown method {args.method!r}; choose from {', '.join(METHODS)} or all")
    if args.random < 0:
        raise UsageError("--random must be >= 0")
    progress = None if (args.json or args.quiet) else _progress_line
    res = run_bench(methods, fitness=args.fitness, noise=args.noise, n_random=args.random, seed=args.seed,
                    de=not args.no_de, progress=progress)
    if args.markdown:
        cmd = "eha-health " + " ".join(args.raw)
        Path(args.markdown).write_text(format_markdown(res, cmd))
    print(json.dumps(res, indent=2, default=float) if args.json else format_text(res))
    return 0


def cmd_diagnose(args) -> int:
    from .identify import NAMES, diagnose
    from .response import Response
    path = Path(args.run)
    if path.suffix.lower() == ".mcap":
        raise UsageError(f"{path}: MCAP input arrives with the node-graph issue; give a CSV from `eha-health simulate`")
    r = Response.from_csv(path)
    progress = None if (args.json or args.quiet) else _progress_line
    d = diagnose(r, method=args.method, fitness=args.fitness, seed=args.seed, progress=progress)
    if args.plot:
        from .plotting import plot_diagnosis
        plot_diagnosis(r, d, args.plot)
    if args.json:
        print(json.dumps(d.as_dict(), default=float))
        return 0
    k = d.faults
    print(f"diagnosis of {path} ({d.method}, fitness {d.fitness}, seed {d.seed}):")
    for key, val in zip(NAMES, k.as_tuple()):
        print(f"  {key.upper():5s} = {val:.4f} +/- {d.std[key]:.4f}  (0 healthy, 1 limit)")
    print(f"  fit RMS: position {d.rms['position'] * 1e6:.1f} um, pressure {d.rms['pressure'] / 1e3:.1f} kPa, "
          f"current {d.rms['current'] * 1e6:.1f} uA;  fitness {d.cost:.4g}")
    print(f"  {d.evaluations} monitor simulations in {d.wall_time_s:.2f} s")
    for w in d.warnings:
        print(f"  warning: {w}")
    if args.plot:
        print(f"  plot: {args.plot}")
    return 0


def cmd_demo(args) -> int:
    from .model import simulate
    from .plotting import plot_response
    from .signatures import Detector, signatures
    faults = Faults.parse(args.faults)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    print(f"Simulating the FDI test sequence on the reference EHA with faults "
          f"K_GM={faults.k_gm:g}, K_FSJ={faults.k_fsj:g}, K_BKL={faults.k_bkl:g} ...")
    healthy = simulate("reference", Faults())
    faulty = simulate("reference", faults)
    sh, sf = signatures(healthy), signatures(faulty)
    units = {"overshoot": (1e3, "mm"), "pressure_peak": (1e-6, "MPa"), "pressure_plateau": (1e-6, "MPa"),
             "motion_start": (1e3, "ms"), "velocity_peak": (1e3, "mm/s"), "current_peak": (1e3, "mA"),
             "current_peak_time": (1e3, "ms")}
    print(f"{'signature':20s} {'healthy':>10s} {'faulty':>10s}")
    for k, (sc, u) in units.items():
        print(f"{k:20s} {getattr(sh, k) * sc:10.3f} {getattr(sf, k) * sc:10.3f}  {u}")
    det = Detector.build()
    found = det.detect(sf)
    scores = det.scores(sf)
    print("coarse detector (thresholds from 20 % damage simulations):")
    for f in ("gm", "fsj", "bkl"):
        print(f"  {f.upper():4s} {'PRESENT' if found[f] else 'absent ':8s} score {scores[f]:5.2f} "
              f"(1.0 = signature of 20 % damage)")
    csv_path, png_path = out / "demo_faulty.csv", out / "demo.png"
    faulty.to_csv(csv_path)
    faulty.meta["label"] = "faulty"
    plot_response(faulty, png_path, title=f"Reference EHA, faults {args.faults}", others={"healthy": healthy})
    print(f"wrote {csv_path} and {png_path}")
    return 0


def build_parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog="eha-health", description="Health monitor for electrohydraulic servo actuators")
    sub = ap.add_subparsers(dest="command", required=True)

    s = sub.add_parser("simulate", help="simulate the FDI test and write a CSV")
    s.add_argument("--model", choices=("reference", "monitor"), default="reference")
    s.add_argument("--faults", default="", help="e.g. gm=0.4,fsj=0.6,bkl=0.4 (0 healthy, 1 limit)")
    s.add_argument("--noise", action="store_true", help="enable the default sensor (acquisition) noise")
    s.add_argument("--effects", default="", help=f"comma list of effects to enable: {', '.join(EFFECT_NAMES)}")
    s.add_argument("--params", help="YAML file overriding parameters (same structure as data/params.yaml)")
    s.add_argument("--seed", type=int, help="seed of the noise (default 0 when noise is on)")
    s.add_argument("--out", required=True, help="output CSV")
    s.add_argument("--plot", help="optional PNG of all channels")
    s.set_defaults(func=cmd_simulate)

    c = sub.add_parser("calibrate", help="fit the monitor first stage on the healthy reference")
    c.add_argument("--out", help="write the calibrated monitor overrides to this YAML")
    c.add_argument("--json", action="store_true")
    c.set_defaults(func=cmd_calibrate)

    g = sub.add_parser("signatures", help="paper-style signature plots (Figs. 4-7) and trend table")
    g.add_argument("--out", required=True, help="output directory")
    g.add_argument("--quiet", action="store_true")
    g.set_defaults(func=cmd_signatures)

    b = sub.add_parser("bench", help="benchmarks: speed | paper")
    b.add_argument("what", help="speed or paper")
    b.add_argument("--json", action="store_true")
    b.add_argument("--no-compile", action="store_true", help="speed: skip the fresh-process compile-time measurement")
    b.add_argument("--method", default="all", help="paper: deterministic, ga, hybrid or all")
    b.add_argument("--fitness", choices=("lsq", "paper"), default="lsq", help="paper: fitness function")
    b.add_argument("--noise", action="store_true", help="paper: default sensor noise on the reference runs")
    b.add_argument("--random", type=int, default=0, metavar="N", help="paper: add N random K triples in [0,1]^3")
    b.add_argument("--seed", type=int, default=0, help="paper: seed of random cases, noise and GA")
    b.add_argument("--no-de", action="store_true", help="paper: skip the scipy differential_evolution peer")
    b.add_argument("--markdown", help="paper: write the tables to this Markdown file")
    b.add_argument("--quiet", action="store_true")
    b.set_defaults(func=cmd_bench)

    q = sub.add_parser("diagnose", help="identify the fault coefficients of a recorded test (CSV)")
    q.add_argument("run", help="CSV in the simulate format")
    q.add_argument("--method", choices=("hybrid", "deterministic", "ga"), default="hybrid")
    q.add_argument("--fitness", choices=("lsq", "paper"), default="lsq")
    q.add_argument("--seed", type=int, default=0)
    q.add_argument("--json", action="store_true", help="print one JSON object")
    q.add_argument("--plot", help="PNG: measured vs fitted per channel, and the convergence")
    q.add_argument("--quiet", action="store_true")
    q.set_defaults(func=cmd_diagnose)

    d = sub.add_parser("demo", help="simulate a faulty actuator, print signatures, write a plot")
    d.add_argument("--faults", default="gm=0.4,fsj=0.6,bkl=0.4")
    d.add_argument("--out", default="out/demo")
    d.set_defaults(func=cmd_demo)
    return ap


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    args.raw = list(argv) if argv is not None else sys.argv[1:]
    try:
        return args.func(args)
    except (UsageError, ValueError, FileNotFoundError) as e:
        print(f"eha-health {args.command}: error: {e}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
