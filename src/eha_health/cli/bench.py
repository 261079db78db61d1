"""``eha-health bench WHAT``: figures, not assertions (speed, paper, graph, floor, discrepancy, fleet)."""
from __future__ import annotations

import json
from pathlib import Path

from .common import UsageError, fitness_option, json_flag, progress, quiet_flag


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
    from ..bench.floor import effect_floor, floor_yaml, residual_floor
    from ..discrepancy.settings import Settings
    prog = progress(args)
    res = residual_floor(n=args.random or 12, seed=args.seed or 2024, progress=prog)
    eff = effect_floor(seed=(args.seed or 2024) + 1, progress=prog)
    if args.write:
        st = Settings()
        Path(args.write).write_text(floor_yaml(res, "eha-health " + " ".join(args.raw),
                                               {"held_out_ratio": st.held_out_ratio, "fit_ratio": st.fit_ratio}, eff))
    print(json.dumps({**res, "effects": eff}, indent=2))
    return 0


def bench_discrepancy(args) -> int:
    from ..bench.discrepancy import format_synthetic, synthetic
    res = synthetic(seed=args.seed, n_noise=args.random or 6, progress=progress(args))
    print(json.dumps(res, indent=2, default=float) if args.json else "\n" + format_synthetic(res))
    return 0


def bench_paper(args) -> int:
    from ..bench.paper import format_markdown, format_text, model_error_yaml, run_bench
    from ..identification.diagnose import DEFAULT_METHOD, METHODS
    methods = METHODS if args.method == "all" else (args.method,)
    if args.method != "all" and args.method not in METHODS:
        raise UsageError(f"unknown method {args.method!r}; choose from {', '.join(METHODS)} or all")
    if args.random < 0:
        raise UsageError("--random must be >= 0")
    res = run_bench(methods, fitness=args.fitness, noise=args.noise, n_random=args.random, seed=args.seed,
                    de=not args.no_de, progress=progress(args))
    cmd = "eha-health " + " ".join(args.raw)
    if args.markdown:
        Path(args.markdown).write_text(format_markdown(res, cmd))
    if args.write_model_error:
        import yaml
        method = DEFAULT_METHOD if DEFAULT_METHOD in methods else methods[0]
        target = Path(args.write_model_error)
        previous = yaml.safe_load(target.read_text()) if target.is_file() else None
        try:
            text = model_error_yaml(res, method, cmd, previous)
        except ValueError as e:
            raise UsageError(str(e)) from None
        target.write_text(text)
    print(json.dumps(res, indent=2, default=float) if args.json else format_text(res))
    return 0


def bench_fleet(args) -> int:
    from ..bench.fleet import bench_fleet as run, format_bench
    from ..identification.diagnose import DEFAULT_METHOD, METHODS
    method = DEFAULT_METHOD if args.method == "all" else args.method
    if method not in METHODS:
        raise UsageError(f"unknown method {method!r}; choose from {', '.join(METHODS)}")
    if args.tests < 2:
        raise UsageError(f"--tests must be >= 2, got {args.tests}")
    res = run(n_tests=args.tests, method=method, fmt=args.format, seed=args.seed or 17,
              plot=args.plot or None, all_cores_serial=args.serial_all_cores, progress=progress(args))
    print(json.dumps(res, indent=2, default=float) if args.json else format_bench(res))
    return 0


BENCHES = {"speed": bench_speed, "paper": bench_paper, "graph": bench_graph, "floor": bench_floor,
           "discrepancy": bench_discrepancy, "fleet": bench_fleet}


def cmd_bench(args) -> int:
    if args.what not in BENCHES:
        raise UsageError(f"unknown benchmark {args.what!r}; available: {', '.join(BENCHES)}")
    return BENCHES[args.what](args)


def register(sub) -> None:
    b = sub.add_parser("bench", help="benchmarks: " + " | ".join(BENCHES),
                       parents=[fitness_option("paper: fitness function"), json_flag(), quiet_flag()])
    b.add_argument("what", help="speed, paper, graph, floor (the monitor's residual floor), discrepancy "
                                "(the loop on synthetic undeclared effects) or fleet (Dask throughput)")
    b.add_argument("--write", metavar="YAML", help="floor: write the settings file, e.g. src/eha_health/data/discrepancy.yaml")
    b.add_argument("--rate", type=float, default=0.0, help="graph: command playback speed (0 as fast as possible)")
    b.add_argument("--no-compile", action="store_true", help="speed: skip the fresh-process compile-time measurement")
    b.add_argument("--method", default="all", help="paper: deterministic, ga, hybrid or all; fleet: the "
                                                   "diagnosis method (all: the default method)")
    b.add_argument("--noise", action="store_true", help="paper: default sensor noise on the reference runs")
    b.add_argument("--random", type=int, default=0, metavar="N",
                   help="paper: add N random K triples in [0,1]^3; floor: runs (12); discrepancy: noise-only runs (6)")
    b.add_argument("--seed", type=int, default=0, help="paper: seed of random cases, noise and GA; fleet: "
                                                       "seed of the simulated fleet (0: 17)")
    b.add_argument("--tests", type=int, default=60, help="fleet: recordings diagnosed by each configuration (60)")
    b.add_argument("--format", choices=("mcap", "csv"), default="mcap", help="fleet: recording format (mcap)")
    b.add_argument("--serial-all-cores", action="store_true",
                   help="fleet: also time the serial loop with numba on all cores")
    b.add_argument("--plot", default="out/bench_fleet.png", help="fleet: PNG of the figures ('' for none)")
    b.add_argument("--no-de", action="store_true", help="paper: skip the scipy differential_evolution peer")
    b.add_argument("--markdown", help="paper: write the tables to this Markdown file")
    b.add_argument("--write-model-error", metavar="YAML",
                   help="paper (clean runs): write the measured model-form error, e.g. src/eha_health/data/model_error.yaml")
    b.set_defaults(func=cmd_bench)
