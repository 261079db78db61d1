"""``eha-health bench WHAT``: figures, not assertions (speed, paper, graph, floor, discrepancy, guard, rul,
fleet, fuzz, soak, loss)."""
from __future__ import annotations

import json
from pathlib import Path

from .common import UsageError, fitness_option, json_flag, progress, progress_line, quiet_flag


def bench_speed(args) -> int:
    from ..bench.speed import format_speed, speed
    res = speed(with_compile=not args.no_compile)
    print(json.dumps(res, indent=2) if args.json else format_speed(res))
    return 0


def bench_graph(args) -> int:
    from ..bench.graph import format_graph, graph
    res = graph(rate=args.rate, progress=progress(args))
    print(json.dumps(res, indent=2) if args.json else format_graph(res))
    return 0


def bench_floor(args) -> int:
    from ..bench.discrepancy import with_fault_error_block
    from ..bench.floor import effect_floor, floor_yaml, residual_floor
    from ..discrepancy.settings import Settings
    prog = progress(args)
    res = residual_floor(n=args.random or 12, seed=args.seed or 2024, progress=prog)
    eff = effect_floor(seed=(args.seed or 2024) + 1, progress=prog)
    if args.write:
        st = Settings()
        text = floor_yaml(res, "eha-health " + " ".join(args.raw),
                          {"held_out_ratio": st.held_out_ratio, "fit_ratio": st.fit_ratio}, eff)
        old = Path(args.write).read_text() if Path(args.write).exists() else ""
        Path(args.write).write_text(with_fault_error_block(text, old))
    print(json.dumps({**res, "effects": eff}, indent=2))
    return 0


def bench_discrepancy(args) -> int:
    from ..bench.discrepancy import FAULT_SETS, format_synthetic, synthetic
    from ..discrepancy.candidates import BY_NAME
    effects = [e for e in args.effects.split(",") if e] if args.effects else None
    bad = [e for e in effects or () if e not in BY_NAME]
    if bad:
        raise UsageError(f"unknown effect {bad[0]!r}; known: {', '.join(BY_NAME)}")
    if not 1 <= args.fault_sets <= len(FAULT_SETS):
        raise UsageError(f"--fault-sets must be within 1..{len(FAULT_SETS)}")
    res = synthetic(seed=args.seed or 0, n_noise=args.random or 6, progress=progress(args), effects=effects,
                    fault_sets=FAULT_SETS[:args.fault_sets], two_effects=not args.no_two,
                    without=tuple(c for c in args.without.split(",") if c))
    if args.write_fault_error:
        from ..bench.discrepancy import all_found, fault_error_sd, fault_error_yaml
        from ..discrepancy.settings import fdi_settings
        target = Path(args.write_fault_error)
        res["fault_error_sd"] = fault_error_sd(res, fdi_settings(target if target.exists() else None).fault_error)
        target.write_text(fault_error_yaml(target.read_text() if target.exists() else "", res["fault_error_sd"],
                                           "eha-health " + " ".join(args.raw), len(all_found(res["cases"]))))
    print(json.dumps(res, indent=2, default=float) if args.json else "\n" + format_synthetic(res))
    return 0


def bench_guard(args) -> int:
    from ..bench.guard import format_guard, guard_bench
    res = guard_bench(n=args.random or 12, seed=args.seed or 3, progress=progress(args))
    print(json.dumps(res, indent=2, default=float) if args.json else format_guard(res))
    return 0


def bench_paper(args) -> int:
    from ..bench.paper import format_markdown, format_text, model_error_yaml, run_bench
    from ..identification.diagnose import DEFAULT_METHOD, METHODS
    methods = METHODS if args.method == "all" else (args.method,)
    if args.method != "all" and args.method not in METHODS:
        raise UsageError(f"unknown method {args.method!r}; choose from {', '.join(METHODS)} or all")
    if args.random < 0:
        raise UsageError("--random must be >= 0")
    res = run_bench(methods, fitness=args.fitness, noise=args.noise, n_random=args.random, seed=args.seed or 0,
                    de=not args.no_de, progress=progress(args))
    cmd = "eha-health " + " ".join(args.raw)
    if args.markdown:
        Path(args.markdown).write_text(format_markdown(res, cmd))
    if args.write_model_error:
        import yaml
        target = Path(args.write_model_error)
        previous = yaml.safe_load(target.read_text()) if target.is_file() else None
        try:
            # the default method first: a clean bench's top level is its block
            for method in sorted(methods, key=lambda m: m != DEFAULT_METHOD):
                text = model_error_yaml(res, method, cmd, previous)
                previous = yaml.safe_load(text)
        except ValueError as e:
            raise UsageError(str(e)) from None
        target.write_text(text)
    print(json.dumps(res, indent=2, default=float) if args.json else format_text(res))
    return 0


def _plot(args, default: str) -> str | None:
    """The --plot file of a bench: its default when not given, none when given as ''."""
    return default if args.plot is None else (args.plot or None)


def bench_fuzz(args) -> int:
    try:
        from ..bench.fuzz import TARGETS, format_fuzz, fuzz
    except ImportError as e:
        raise UsageError(f"fuzz needs hypothesis (pip install -e '.[test]'): {e}") from None
    targets = args.target or list(TARGETS)
    unknown = [t for t in targets if t not in TARGETS]
    if unknown:
        raise UsageError(f"unknown fuzz target(s) {', '.join(unknown)}; available: {', '.join(TARGETS)}")
    if args.examples < 1:
        raise UsageError("--examples must be >= 1")
    res = fuzz(targets, examples=args.examples, seed=args.seed or 0, progress=progress(args))
    print(json.dumps(res, indent=2, default=float) if args.json else format_fuzz(res))
    return 0 if res["ok"] else 1


def bench_soak(args) -> int:
    from ..bench.soak import format_soak, plot_soak, soak
    tests = 300 if args.tests is None else args.tests
    if tests < 2:
        raise UsageError("--tests must be >= 2")
    warmup = min(20, tests // 5) if args.warmup is None else args.warmup
    if not 0 <= warmup < tests:
        raise UsageError(f"--warmup must be in 0..{tests - 1}")
    res = soak(tests=tests, warmup=warmup, seed=args.seed or 0, progress=progress(args))
    if args.plot:
        plot_soak(res, args.plot)
    if args.json:
        print(json.dumps(res, indent=2, default=float))
    else:
        print(format_soak(res) + (f"\n  plot: {args.plot}" if args.plot else ""))
    return 0


def bench_loss(args) -> int:
    from ..bench.loss import format_loss, loss
    res = loss(seed=7 if args.seed is None else args.seed, progress=progress(args))
    print(json.dumps(res, indent=2, default=float) if args.json else format_loss(res))
    return 0


def bench_rul(args) -> int:
    from ..bench.rul import bench_rul as run, format_result, time_prognose, write_markdown
    from ..prognostics.config import load_settings
    if args.time_prognose is not None:
        if args.time_prognose < 1:
            raise UsageError(f"--time-prognose must be >= 1 actuators, got {args.time_prognose}")
        res = time_prognose(args.time_prognose)
        print(json.dumps(res) if args.json else f"prognose on {res['actuators']} actuators ({res['series']} series): "
              f"{res['wall_time_s']:.1f} s wall, {res['cpu_time_s']:.1f} s CPU (load {res['load_1min_before']:.1f}); "
              f"the monitor's step on it as a SQLite history: first {res['monitor_first_step_s']:.2f} s; "
              f"the fleet prior fitted for a young actuator {res['fleet_prior_fit_s']:.1f} s, then its step "
              f"after another actuator's test {res['monitor_step_s']:.2f} s ({res['monitor_step_refitted']} "
              f"actuator refitted)")
        return 0
    if args.units is not None and args.units < 3:
        raise UsageError(f"--units must be >= 3 (one per fault), got {args.units}")
    over = {"bench": {k: v for k, v in (("n_units", args.units), ("seed", args.seed)) if v is not None}}
    s = load_settings(args.settings, over)
    # minutes of work: its stages on stderr, with --json too (stdout stays the JSON)
    res = run(s, args.cache, _plot(args, "out/bench_rul.png"), None if args.quiet else progress_line)
    if args.markdown:
        write_markdown(res, args.markdown, "eha-health " + " ".join(args.raw))
    print(json.dumps(res, indent=1, default=float) if args.json else format_result(res))
    return 0


def bench_fleet(args) -> int:
    from ..bench.fleet import bench_fleet as run, format_bench
    from ..identification.diagnose import DEFAULT_METHOD, METHODS
    method = DEFAULT_METHOD if args.method == "all" else args.method
    if method not in METHODS:
        raise UsageError(f"unknown method {method!r}; choose from {', '.join(METHODS)}")
    n_tests = 60 if args.tests is None else args.tests
    if n_tests < 2:
        raise UsageError(f"--tests must be >= 2, got {n_tests}")
    res = run(n_tests=n_tests, method=method, fmt=args.format, seed=args.seed or 17,
              plot=_plot(args, "out/bench_fleet.png"), all_cores_serial=args.serial_all_cores, rounds=args.rounds,
              progress=progress(args))
    print(json.dumps(res, indent=2, default=float) if args.json else format_bench(res))
    return 0


BENCHES = {"speed": bench_speed, "paper": bench_paper, "graph": bench_graph, "floor": bench_floor,
           "discrepancy": bench_discrepancy, "guard": bench_guard, "rul": bench_rul, "fleet": bench_fleet,
           "fuzz": bench_fuzz, "soak": bench_soak, "loss": bench_loss}


def cmd_bench(args) -> int:
    if args.what not in BENCHES:
        raise UsageError(f"unknown benchmark {args.what!r}; available: {', '.join(BENCHES)}")
    return BENCHES[args.what](args)


def register(sub) -> None:
    b = sub.add_parser("bench", help="benchmarks: " + " | ".join(BENCHES),
                       parents=[fitness_option("paper: fitness function"), json_flag(), quiet_flag()])
    b.add_argument("what", help="speed, paper, graph, floor (the monitor's residual floor), discrepancy "
                                "(the loop on synthetic undeclared effects), guard (the fast method's global guard "
                                "from random starts), rul (run-to-failure fleet: prognostics), fleet (Dask "
                                "throughput), fuzz (untrusted inputs), soak (many tests) or loss (lossy link)")
    b.add_argument("--write", metavar="YAML", help="floor: write the settings file, e.g. src/eha_health/data/discrepancy.yaml")
    b.add_argument("--rate", type=float, default=0.0, help="graph: command playback speed (0 as fast as possible)")
    b.add_argument("--no-compile", action="store_true", help="speed: skip the fresh-process compile-time measurement")
    b.add_argument("--method", default="all", help="paper: fast, deterministic, ga, hybrid or all; fleet: the "
                                                   "diagnosis method (all: the default method)")
    b.add_argument("--noise", action="store_true", help="paper: default sensor noise on the reference runs")
    b.add_argument("--random", type=int, default=0, metavar="N",
                   help="paper: add N random K triples in [0,1]^3; floor: runs (12); discrepancy: noise-only runs (6); "
                        "guard: cases (12)")
    b.add_argument("--seed", type=int, default=None, help="paper: seed of random cases, noise and GA (0); "
                                                          "rul: fleet seed (bench.seed of data/prognostics.yaml); "
                                                          "fleet: seed of the simulated fleet (17); guard: seed (3); "
                                                          "fuzz, soak: seed (0); loss: drop seed (7)")
    b.add_argument("--tests", type=int, default=None, metavar="N",
                   help="fleet: recordings diagnosed by each configuration (60); soak: consecutive tests (300)")
    b.add_argument("--format", choices=("mcap", "csv"), default="mcap", help="fleet: recording format (mcap)")
    b.add_argument("--rounds", type=int, default=3, metavar="N",
                   help="fleet: run the configurations N times, forward then reverse order (3)")
    b.add_argument("--serial-all-cores", action="store_true",
                   help="fleet: also time the serial loop with numba on all cores")
    b.add_argument("--effects", default="", metavar="A,B",
                   help="discrepancy: only these candidate effects (default every in-loop and recording one)")
    b.add_argument("--fault-sets", type=int, default=3, metavar="N",
                   help="discrepancy: the first N fault sets (0,0,0), (0.4,0.5,0), (0.3,0.4,0.3)")
    b.add_argument("--no-two", action="store_true", help="discrepancy: skip the two-effect cases")
    b.add_argument("--without", default="", metavar="CHANNEL[,CHANNEL]",
                   help="discrepancy: records without these measured channels (velocity, pressure, current), "
                        "as a CSV without their columns")
    b.add_argument("--write-fault-error", metavar="YAML",
                   help="discrepancy: write the fault coefficients' measured error with effects in the model "
                        "(fault_error_sd) into the settings file, e.g. src/eha_health/data/discrepancy.yaml")
    b.add_argument("--no-de", action="store_true", help="paper: skip the scipy differential_evolution peer")
    b.add_argument("--markdown", help="paper: write the tables to this Markdown file; rul: write the figures into "
                                      "this file (between its 'bench rul' markers if it has them, e.g. "
                                      "docs/prognostics.md)")
    b.add_argument("--units", type=int, help="rul: fleet size (bench.n_units of data/prognostics.yaml)")
    b.add_argument("--settings", metavar="YAML", help="rul: a YAML merged over data/prognostics.yaml")
    b.add_argument("--cache", default="out/rul_cache", help="rul: diagnosis cache directory (out/rul_cache)")
    b.add_argument("--plot", help="rul: PNG of example units and the PIT (out/bench_rul.png); fleet: PNG of the "
                                  "figures (out/bench_fleet.png); soak: memory, threads and diagnosis time per "
                                  "test (none); '' for none")
    b.add_argument("--time-prognose", type=int, metavar="N",
                   help="rul: only time prognose on a synthetic N-actuator history (every fault degrading)")
    b.add_argument("--write-model-error", metavar="YAML",
                   help="paper: write the measured error terms of each method run (clean runs: model-form error; --noise: the noise part), e.g. src/eha_health/data/model_error.yaml")
    b.add_argument("--target", action="append", metavar="T",
                   help="fuzz: mcap, importer, csv, history or messages (repeatable; default all)")
    b.add_argument("--examples", type=int, default=2000, metavar="N", help="fuzz: cases per target (2000)")
    b.add_argument("--warmup", type=int, default=None, metavar="N",
                   help="soak: tests before the memory/time baseline (20, or a fifth of --tests)")
    b.set_defaults(func=cmd_bench)
