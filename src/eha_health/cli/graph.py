"""Commands that run the node graph: ``demo``, ``record``, ``launch``, ``replay``."""
from __future__ import annotations

import json
import sys
from pathlib import Path

from ..physics.faults import FAULT_NAMES, Faults
from .common import (UsageError, domain_option, effects_option, faults_option, json_flag, method_option,
                     monitor_history_option, quiet_flag, seed_option)


def truth_table(truth, d) -> list[str]:
    rows = [f"  {'':6s} {'truth':>7s} {'estimate':>9s} {'std':>7s} {'error':>8s}"]
    for n in FAULT_NAMES:
        est = getattr(d.faults, n)
        rows.append(f"  {n.upper():6s} {truth[n]:7.3f} {est:9.4f} {d.std[n]:7.4f} {est - truth[n]:+8.4f}")
    return rows


def cmd_demo(args) -> int:
    from ..plotting import plot_diagnosis
    from ..identification.diagnose import DEFAULT_METHOD
    from ..ros.graph import Graph
    faults = Faults.parse(args.faults)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    log, png = out / "demo.mcap", out / "demo.png"
    log.unlink(missing_ok=True)
    print(f"Running the graph in one process: plant (reference EHA, K_GM={faults.k_gm:g}, K_FSJ={faults.k_fsj:g}, "
          f"K_BKL={faults.k_bkl:g}), command (FDI test, 1 kHz, as fast as possible), monitor ({DEFAULT_METHOD}) ...",
          flush=True)
    with Graph(faults=faults, log_path=log, rate=0.0) as g:
        r = g.run_test()
    if r["diagnosis"] is None:
        raise UsageError(r["message"])
    d = r["diagnosis"]
    truth = {k: float(v) for k, v in (r["truth"] or faults.as_dict()).items()
             if k.startswith("k_")}
    print(f"/diagnostics: {r['level']}: {r['message']}")
    print("\n".join(truth_table(truth, d)))
    print(f"  fit RMS position {d.rms['position'] * 1e6:.1f} um; {d.evaluations} monitor runs in {d.wall_time_s:.2f} s")
    plot_diagnosis(r["response"], d, png)
    print(f"wrote {log} (MCAP, ros2 profile) and {png}")
    print(f"next: eha-health diagnose {log}   |   eha-health replay {log}")
    return 0


def cmd_record(args) -> int:
    from ..ros.graph import Graph
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


def _prognostics_settings(args):
    """--settings of a monitor with a --history, checked here (the monitor would refuse it later)."""
    if not args.settings:
        return None
    if not args.history:
        raise UsageError("--settings is for the prognosis: it needs --history")
    from ..prognostics.config import load_settings
    from ..prognostics.thresholds import failure_thresholds
    # a PrognosticsError (ValueError) names what is wrong; the thresholds too (a requirement the
    # healthy actuator breaks), which the monitor would otherwise meet at its first test (about 1 s)
    failure_thresholds(load_settings(args.settings))
    return args.settings


def cmd_launch(args) -> int:
    from ..ros.launch import launch
    faults = Faults.parse(args.faults)
    res = launch(faults, effects=[e for e in args.effects.split(",") if e], seed=args.seed, tests=args.tests,
                 rate=args.rate, method=args.method, log_path=args.log, domain_id=args.domain_id,
                 timeout_s=args.timeout, history=args.history, actuator_id=args.actuator,
                 prognostics_settings=_prognostics_settings(args), operating_hours=args.operating_hours)
    print(json.dumps(res, indent=2, default=float) if args.json else res["summary"])
    return 0 if res["ok"] and not _none_appended(res) else 1


def _none_appended(res) -> bool:
    """Tests were diagnosed for a history, and every one that was not in it already was refused."""
    h = res.get("history")
    return bool(h and h["refused"] and not h["appended"])


def cmd_replay(args) -> int:
    from ..ros.replay import replay
    if args.history and args.no_monitor:
        raise UsageError("--history needs the replay's monitor (drop --no-monitor)")
    res = replay(args.bag, rate=args.rate, with_monitor=not args.no_monitor, log_path=args.log,
                 domain_id=args.domain_id, history=args.history, actuator_id=args.actuator,
                 prognostics_settings=_prognostics_settings(args), operating_hours=args.operating_hours)
    print(json.dumps(res, indent=2, default=float) if args.json else res["summary"])
    return 1 if _none_appended(res) else 0


def register(sub) -> None:
    d = sub.add_parser("demo", help="the whole node graph in one process: simulate, record, diagnose, plot",
                       parents=[faults_option("gm=0.4,fsj=0.6,bkl=0.4", None)])
    d.add_argument("--out", default="out/demo")
    d.set_defaults(func=cmd_demo)

    rc = sub.add_parser("record", help="run the graph in one process and keep the monitor's MCAP log",
                        parents=[faults_option("", "e.g. gm=0.4,fsj=0.6,bkl=0.4"), effects_option(),
                                 seed_option(0, "plant noise seed"), quiet_flag()])
    rc.add_argument("--noise", action="store_true", help="the default sensor noise (effect sensor_noise)")
    rc.add_argument("--tests", type=int, default=1)
    rc.add_argument("--no-truth", action="store_true", help="do not write the plant's truth into the metadata")
    rc.add_argument("--params", help="YAML overriding the plant's parameters (e.g. an undeclared supply sag)")
    rc.add_argument("--out", required=True, help="MCAP file")
    rc.set_defaults(func=cmd_record)

    la = sub.add_parser("launch", help="run plant, command and monitor as three processes over DDS",
                        parents=[faults_option("gm=0.4,fsj=0.6,bkl=0.4", None), effects_option(),
                                 seed_option(0, "plant noise seed"), method_option(),
                                 domain_option("ROS_DOMAIN_ID for the three processes"), json_flag(),
                                 monitor_history_option("the monitor")])
    la.add_argument("--tests", type=int, default=1, help="number of FDI tests to play")
    la.add_argument("--rate", type=float, default=1.0, help="playback speed (1 real time, 0 as fast as possible)")
    la.add_argument("--log", default="out/launch.mcap", help="MCAP log of the monitor")
    la.add_argument("--timeout", type=float, default=300.0, help="give up after this long [s]")
    la.set_defaults(func=cmd_launch)

    rp = sub.add_parser("replay", help="republish a bag's input topics into a live graph (with a monitor)",
                        parents=[domain_option("ROS_DOMAIN_ID to publish on"), json_flag(),
                                 monitor_history_option("the replay's monitor")])
    rp.add_argument("bag")
    rp.add_argument("--rate", type=float, default=1.0, help="speed vs the recording (0 as fast as possible)")
    rp.add_argument("--no-monitor", action="store_true", help="only publish (a monitor runs elsewhere)")
    rp.add_argument("--log", default="", help="MCAP log of the replay's monitor")
    rp.set_defaults(func=cmd_replay)
