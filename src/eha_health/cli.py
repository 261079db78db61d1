"""``eha-health``: the command-line entry point.

Subcommands: simulate, calibrate, signatures, bench, diagnose, demo, record, launch, replay,
import, discrepancy. Bad input exits
with code 2 and one line that says what is wrong.
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

from .physics.params import EFFECT_NAMES, load
from .physics.faults import Faults


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
    return p.with_effect_names(effects)   # ValueError names an unknown effect


def cmd_simulate(args) -> int:
    from .physics.model import simulate
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
    from .identification.calibrate import calibrate, write_monitor_yaml
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
    from .identification.signatures import Detector
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
        from .bench.speed import format_speed, speed
        res = speed(with_compile=not args.no_compile)
        print(json.dumps(res, indent=2) if args.json else format_speed(res))
        return 0
    if args.what == "graph":
        from .bench.graph import format_graph, graph
        res = graph(rate=args.rate, progress=None if (args.json or args.quiet) else _progress_line)
        print(json.dumps(res, indent=2) if args.json else format_graph(res))
        return 0
    if args.what == "floor":
        from .bench.floor import effect_floor, floor_yaml, residual_floor
        from .discrepancy.loop import Settings
        prog = None if (args.json or args.quiet) else _progress_line
        res = residual_floor(n=args.random or 12, seed=args.seed or 2024, progress=prog)
        eff = effect_floor(seed=(args.seed or 2024) + 1, progress=prog)
        if args.write:
            st = Settings()
            Path(args.write).write_text(floor_yaml(res, "eha-health " + " ".join(args.raw),
                                                   {"held_out_ratio": st.held_out_ratio, "fit_ratio": st.fit_ratio},
                                                   eff))
        print(json.dumps({**res, "effects": eff}, indent=2))
        return 0
    if args.what == "discrepancy":
        from .bench.discrepancy import format_synthetic, synthetic
        res = synthetic(seed=args.seed, n_noise=args.random or 6,
                        progress=None if (args.json or args.quiet) else _progress_line)
        print(json.dumps(res, indent=2, default=float) if args.json else "\n" + format_synthetic(res))
        return 0
    if args.what != "paper":
        raise UsageError(f"unknown benchmark {args.what!r}; available: speed, paper, graph, floor, discrepancy")
    from .identification.diagnose import METHODS
    from .bench.paper import format_markdown, format_text, run_bench
    methods = METHODS if args.method == "all" else (args.method,)
    if args.method != "all" and args.method not in METHODS:
        raise UsageError(f"unknown method {args.method!r}; choose from {', '.join(METHODS)} or all")
    if args.random < 0:
        raise UsageError("--random must be >= 0")
    progress = None if (args.json or args.quiet) else _progress_line
    res = run_bench(methods, fitness=args.fitness, noise=args.noise, n_random=args.random, seed=args.seed,
                    de=not args.no_de, progress=progress)
    cmd = "eha-health " + " ".join(args.raw)
    if args.markdown:
        Path(args.markdown).write_text(format_markdown(res, cmd))
    if args.write_model_error:
        import yaml
        from .bench.paper import model_error_yaml
        method = "hybrid" if "hybrid" in methods else methods[0]
        target = Path(args.write_model_error)
        previous = yaml.safe_load(target.read_text()) if target.is_file() else None
        try:
            text = model_error_yaml(res, method, cmd, previous)
        except ValueError as e:
            raise UsageError(str(e)) from None
        target.write_text(text)
    print(json.dumps(res, indent=2, default=float) if args.json else format_text(res))
    return 0


def _load_run(path: Path, test_id: int | None, required: tuple[str, ...] | None = None):
    """(response, truth or None, notes) from a CSV (columns ``required``, default all) or an MCAP bag."""
    from .signals.response import Response
    if path.suffix.lower() == ".mcap":
        from .io.bagrun import read_run, truth_values
        # fewer required channels: a measured record (e.g. a rig with command and position only)
        run = read_run(path, test_id, record=required is not None)
        return run.response, truth_values(run.truth), run.notes
    if test_id is not None:
        raise UsageError("--test applies to MCAP bags only")
    return (Response.from_csv(path, required) if required else Response.from_csv(path)), None, []


def cmd_diagnose(args) -> int:
    from .identification.diagnose import NAMES, diagnose
    path = Path(args.run)
    r, truth, notes = _load_run(path, args.test)
    for n in notes:
        print(f"note: {n}", file=sys.stderr)
    progress = None if (args.json or args.quiet) else _progress_line
    d = diagnose(r, method=args.method, fitness=args.fitness, seed=args.seed, progress=progress)
    if args.plot:
        from .plotting import plot_diagnosis
        plot_diagnosis(r, d, args.plot)
    if args.json:
        out = d.as_dict()
        if truth is not None:
            out["truth"] = truth
        print(json.dumps(out, default=float))
        return 0
    k = d.faults
    print(f"diagnosis of {path} ({d.method}, fitness {d.fitness}, seed {d.seed}):")
    for key, val in zip(NAMES, k.as_tuple()):
        tr = f"   truth {truth[key]:.4f}" if truth else ""
        print(f"  {key.upper():5s} = {val:.4f} +/- {d.std[key]:.4f}  (0 healthy, 1 limit){tr}")
    print(f"  fit RMS: position {d.rms['position'] * 1e6:.1f} um, pressure {d.rms['pressure'] / 1e3:.1f} kPa, "
          f"current {d.rms['current'] * 1e6:.1f} uA;  fitness {d.cost:.4g}")
    print(f"  {d.evaluations} monitor simulations in {d.wall_time_s:.2f} s")
    for w in d.warnings:
        print(f"  warning: {w}")
    if args.plot:
        print(f"  plot: {args.plot}")
    return 0


def _truth_table(truth, d) -> list[str]:
    from .identification.diagnose import NAMES
    rows = [f"  {'':6s} {'truth':>7s} {'estimate':>9s} {'std':>7s} {'error':>8s}"]
    for n in NAMES:
        est = getattr(d.faults, n)
        rows.append(f"  {n.upper():6s} {truth[n]:7.3f} {est:9.4f} {d.std[n]:7.4f} {est - truth[n]:+8.4f}")
    return rows


def cmd_demo(args) -> int:
    from .ros.graph import Graph
    from .plotting import plot_diagnosis
    faults = Faults.parse(args.faults)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    log, png = out / "demo.mcap", out / "demo.png"
    log.unlink(missing_ok=True)
    print(f"Running the graph in one process: plant (reference EHA, K_GM={faults.k_gm:g}, K_FSJ={faults.k_fsj:g}, "
          f"K_BKL={faults.k_bkl:g}), command (FDI test, 1 kHz, as fast as possible), monitor (hybrid) ...",
          flush=True)
    with Graph(faults=faults, log_path=log, rate=0.0) as g:
        r = g.run_test()
    if r["diagnosis"] is None:
        raise UsageError(r["message"])
    d = r["diagnosis"]
    truth = {k: float(v) for k, v in (r["truth"] or dict(zip(("k_gm", "k_fsj", "k_bkl"), faults.as_tuple()))).items()
             if k.startswith("k_")}
    print(f"/diagnostics: {r['level']}: {r['message']}")
    print("\n".join(_truth_table(truth, d)))
    print(f"  fit RMS position {d.rms['position'] * 1e6:.1f} um; {d.evaluations} monitor runs in {d.wall_time_s:.2f} s")
    plot_diagnosis(r["response"], d, png)
    print(f"wrote {log} (MCAP, ros2 profile) and {png}")
    print(f"next: eha-health diagnose {log}   |   eha-health replay {log}")
    return 0


def cmd_record(args) -> int:
    from .ros.graph import Graph
    faults = Faults.parse(args.faults)
    effects = [e.strip() for e in args.effects.split(",") if e.strip()] + (["sensor_noise"] if args.noise else [])
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.unlink(missing_ok=True)
    with Graph(faults=faults, effects=tuple(effects), seed=args.seed, log_path=out, truth=not args.no_truth,
               params_file=str(Path(args.params).resolve()) if args.params else "") as g:
        for _ in range(args.tests):
            r = g.run_test()
            if not args.quiet:
                print(f"test {r['test_id']}: {r['level']}: {r['message']}", file=sys.stderr)
    print(f"wrote {out} ({args.tests} test(s), faults {args.faults or 'none'}, effects {','.join(effects) or 'none'}"
          f"{', truth not recorded' if args.no_truth else ''})")
    return 0


def cmd_launch(args) -> int:
    from .ros.launch import launch
    faults = Faults.parse(args.faults)
    res = launch(faults, effects=[e for e in args.effects.split(",") if e], seed=args.seed, tests=args.tests,
                 rate=args.rate, method=args.method, log_path=args.log, domain_id=args.domain_id,
                 timeout_s=args.timeout)
    print(json.dumps(res, indent=2, default=float) if args.json else res["summary"])
    return 0 if res["ok"] else 1


def cmd_replay(args) -> int:
    from .ros.replay import replay
    res = replay(args.bag, rate=args.rate, with_monitor=not args.no_monitor, log_path=args.log,
                 domain_id=args.domain_id)
    print(json.dumps(res, indent=2, default=float) if args.json else res["summary"])
    return 0


def cmd_import(args) -> int:
    from .io.importer import import_text
    r = import_text(args.file, args.map)
    out = Path(args.out)
    measured = r.meta["measured"]
    if out.suffix.lower() == ".csv":
        out.parent.mkdir(parents=True, exist_ok=True)
        r.to_csv(out)
    elif out.suffix.lower() == ".mcap":
        from .io.bagrun import write_run
        from .io.mcaplog import BagWriter
        out.parent.mkdir(parents=True, exist_ok=True)
        with BagWriter(out) as w:
            write_run(w, r)
    else:
        raise UsageError(f"--out must end in .csv or .mcap, got {out.name}")
    load = f", load {np.ptp(r.load):.4g} N peak-to-peak" if r.load is not None else ""
    print(f"wrote {out}: {len(r.t)} samples at {r.sample_rate:.6g} Hz over {r.t[-1]:.3f} s; measured "
          f"{', '.join(measured)}{load}; command {np.ptp(r.command) * 1e3:.4g} mm peak-to-peak")
    return 0


def _discrepancy_mode(r) -> str:
    from .identification.fitness import check_window
    from .physics.sequence import FDISequence
    if not all(np.isfinite(getattr(r, c)).all() for c in ("position", "velocity", "pressure", "current")):
        return "rig"
    try:
        check_window(r, FDISequence())
    except ValueError:
        return "rig"
    return "fdi"


def cmd_discrepancy(args) -> int:
    from .discrepancy.loop import analyse_fdi_test, format_report
    path = Path(args.run)
    if args.max_effects < 0:
        raise UsageError(f"--max-effects must be >= 0, got {args.max_effects}")
    r, truth, notes = _load_run(path, args.test, required=("t", "command", "position"))
    for n in notes:
        print(f"note: {n}", file=sys.stderr)
    mode = _discrepancy_mode(r) if args.mode == "auto" else args.mode
    progress = None if (args.json or args.quiet) else _progress_line
    if mode == "fdi":
        rep = analyse_fdi_test(r, max_effects=args.max_effects, seed=args.seed, truth=truth, progress=progress)
    else:
        from .discrepancy.rig import analyse_rig
        rep = analyse_rig(r, max_effects=args.max_effects, fit_fraction=args.fit_fraction, progress=progress)
    if args.plot:
        from .plotting import plot_discrepancy
        plot_discrepancy(rep, args.plot)
    if args.json:
        out = rep.as_dict()
        out["mode"] = mode
        out["source"] = str(path)
        if truth is not None:
            out["truth"] = truth
        print(json.dumps(out, default=float))
        return 0
    if progress:
        print(file=sys.stderr)
    print(format_report(rep, f"{path} ({mode})"))
    if args.plot:
        print(f"  plot: {args.plot}")
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

    b = sub.add_parser("bench", help="benchmarks: speed | paper | graph | floor | discrepancy")
    b.add_argument("what", help="speed, paper, graph, floor (the monitor's residual floor) or discrepancy "
                                "(the loop on synthetic undeclared effects)")
    b.add_argument("--write", metavar="YAML", help="floor: write the settings file, e.g. src/eha_health/data/discrepancy.yaml")
    b.add_argument("--rate", type=float, default=0.0, help="graph: command playback speed (0 as fast as possible)")
    b.add_argument("--json", action="store_true")
    b.add_argument("--no-compile", action="store_true", help="speed: skip the fresh-process compile-time measurement")
    b.add_argument("--method", default="all", help="paper: deterministic, ga, hybrid or all")
    b.add_argument("--fitness", choices=("lsq", "paper"), default="lsq", help="paper: fitness function")
    b.add_argument("--noise", action="store_true", help="paper: default sensor noise on the reference runs")
    b.add_argument("--random", type=int, default=0, metavar="N",
                   help="paper: add N random K triples in [0,1]^3; floor: runs (12); discrepancy: noise-only runs (6)")
    b.add_argument("--seed", type=int, default=0, help="paper: seed of random cases, noise and GA")
    b.add_argument("--no-de", action="store_true", help="paper: skip the scipy differential_evolution peer")
    b.add_argument("--markdown", help="paper: write the tables to this Markdown file")
    b.add_argument("--write-model-error", metavar="YAML",
                   help="paper (clean runs): write the measured model-form error, e.g. src/eha_health/data/model_error.yaml")
    b.add_argument("--quiet", action="store_true")
    b.set_defaults(func=cmd_bench)

    q = sub.add_parser("diagnose", help="identify the fault coefficients of a recorded test (CSV or MCAP)")
    q.add_argument("run", help="CSV in the simulate format, or an MCAP bag to the docs/interfaces.md contract")
    q.add_argument("--test", type=int, help="MCAP: test window id (default: the first complete one)")
    q.add_argument("--method", choices=("hybrid", "deterministic", "ga"), default="hybrid")
    q.add_argument("--fitness", choices=("lsq", "paper"), default="lsq")
    q.add_argument("--seed", type=int, default=0)
    q.add_argument("--json", action="store_true", help="print one JSON object")
    q.add_argument("--plot", help="PNG: measured vs fitted per channel, and the convergence")
    q.add_argument("--quiet", action="store_true")
    q.set_defaults(func=cmd_diagnose)

    d = sub.add_parser("demo", help="the whole node graph in one process: simulate, record, diagnose, plot")
    d.add_argument("--faults", default="gm=0.4,fsj=0.6,bkl=0.4")
    d.add_argument("--out", default="out/demo")
    d.set_defaults(func=cmd_demo)

    rc = sub.add_parser("record", help="run the graph in one process and keep the monitor's MCAP log")
    rc.add_argument("--faults", default="", help="e.g. gm=0.4,fsj=0.6,bkl=0.4")
    rc.add_argument("--effects", default="", help=f"plant effects: {', '.join(EFFECT_NAMES)}")
    rc.add_argument("--noise", action="store_true", help="the default sensor noise (effect sensor_noise)")
    rc.add_argument("--seed", type=int, default=0, help="plant noise seed")
    rc.add_argument("--tests", type=int, default=1)
    rc.add_argument("--no-truth", action="store_true", help="do not write the plant's truth into the metadata")
    rc.add_argument("--params", help="YAML overriding the plant's parameters (e.g. an undeclared supply sag)")
    rc.add_argument("--out", required=True, help="MCAP file")
    rc.add_argument("--quiet", action="store_true")
    rc.set_defaults(func=cmd_record)

    la = sub.add_parser("launch", help="run plant, command and monitor as three processes over DDS")
    la.add_argument("--faults", default="gm=0.4,fsj=0.6,bkl=0.4")
    la.add_argument("--effects", default="", help=f"plant effects: {', '.join(EFFECT_NAMES)}")
    la.add_argument("--seed", type=int, default=0, help="plant noise seed")
    la.add_argument("--tests", type=int, default=1, help="number of FDI tests to play")
    la.add_argument("--rate", type=float, default=1.0, help="playback speed (1 real time, 0 as fast as possible)")
    la.add_argument("--method", choices=("hybrid", "deterministic", "ga"), default="hybrid")
    la.add_argument("--log", default="out/launch.mcap", help="MCAP log of the monitor")
    la.add_argument("--domain-id", type=int, help="ROS_DOMAIN_ID for the three processes")
    la.add_argument("--timeout", type=float, default=300.0, help="give up after this long [s]")
    la.add_argument("--json", action="store_true")
    la.set_defaults(func=cmd_launch)

    rp = sub.add_parser("replay", help="republish a bag's input topics into a live graph (with a monitor)")
    rp.add_argument("bag")
    rp.add_argument("--rate", type=float, default=1.0, help="speed vs the recording (0 as fast as possible)")
    rp.add_argument("--no-monitor", action="store_true", help="only publish (a monitor runs elsewhere)")
    rp.add_argument("--log", default="", help="MCAP log of the replay's monitor")
    rp.add_argument("--domain-id", type=int, help="ROS_DOMAIN_ID to publish on")
    rp.add_argument("--json", action="store_true")
    rp.set_defaults(func=cmd_replay)

    im = sub.add_parser("import", help="measured rig data (delimited text) into the project's format")
    im.add_argument("file", help="text/CSV data file")
    im.add_argument("--map", required=True, help="YAML channel map (columns, scales, units; see docs/discrepancy.md)")
    im.add_argument("--out", required=True, help="RUN.csv or RUN.mcap (the topic contract; channels a rig lacks are left out)")
    im.set_defaults(func=cmd_import)

    dc = sub.add_parser("discrepancy", help="residual -> missing effect -> augmented model, before and after")
    dc.add_argument("run", help="CSV (simulate or import format) or MCAP bag")
    dc.add_argument("--test", type=int, help="MCAP: test window id")
    dc.add_argument("--max-effects", type=int, default=2, help="most effects to add (default 2)")
    dc.add_argument("--mode", choices=("auto", "fdi", "rig"), default="auto",
                    help="fdi: an FDI test of the shipped EHA (faults re-identified); rig: calibrate the "
                         "nominal loop to a measured rig first (auto: fdi when all channels and the FDI "
                         "sequence are there)")
    dc.add_argument("--fit-fraction", type=float, default=0.7, help="rig: share of the record fitted (rest held out)")
    dc.add_argument("--seed", type=int, default=0, help="fdi: seed of the diagnosis")
    dc.add_argument("--json", action="store_true", help="one JSON object: before, after, candidates, selected")
    dc.add_argument("--plot", help="PNG: residuals before and after, and the candidate ranking")
    dc.add_argument("--quiet", action="store_true")
    dc.set_defaults(func=cmd_discrepancy)
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
