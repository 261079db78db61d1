"""``eha-health fleet simulate | diagnose | dask-config``: many recorded tests on a Dask cluster, into the history."""
from __future__ import annotations

import json

from .common import UsageError, json_flag, method_option, progress, quiet_flag, seed_option


def cmd_fleet_simulate(args) -> int:
    from ..bench.fleet import simulate_fleet
    res = simulate_fleet(args.actuators, args.tests, args.seed, args.out, args.format, progress(args))
    if args.json:
        print(json.dumps(res, default=float))
    else:
        print(f"wrote {res['recordings']} recordings of {res['actuators']} actuators ({res['format']}) and "
              f"{res['manifest']} in {res['wall_time_s']:.1f} s")
    return 0


def cmd_fleet_diagnose(args) -> int:
    from ..fleet import diagnose_fleet, find_recordings, format_summary, read_manifest
    from ..prognostics.store import default_history_path
    if bool(args.paths) == bool(args.manifest):
        raise UsageError("give recordings (files or folders) or --manifest FILE.csv, not both and not neither")
    if args.scheduler and args.workers is not None:
        raise UsageError("--scheduler and --workers exclude each other (the cluster's workers are its own)")
    workers = 2 if args.workers is None else args.workers
    if workers < 1:
        raise UsageError(f"--workers must be >= 1, got {workers}")
    recs = read_manifest(args.manifest) if args.manifest else find_recordings(args.paths)
    history = args.history or default_history_path()
    s = diagnose_fleet(recs, history, scheduler=args.scheduler, workers=workers, method=args.method,
                       seed=args.seed, discrepancy=args.discrepancy, progress=progress(args), backfill=args.backfill)
    print(json.dumps(s, default=float) if args.json else format_summary(s))
    return 1 if s["failed"] else 0   # the batch ran to its end; 1 tells a script that some files failed


def cmd_fleet_dask_config(args) -> int:
    from ..fleet.batch import dask_config_yaml
    print(dask_config_yaml(), end="")
    return 0


def register(sub) -> None:
    from .prognostics import BACKFILL_HELP
    f = sub.add_parser("fleet", help="fleet scale: simulate a fleet of recordings, diagnose many on Dask")
    fs = f.add_subparsers(dest="fleet_command", required=True)
    s = fs.add_parser("simulate", help="a reproducible fleet of degrading actuators' FDI tests, with a manifest",
                      parents=[seed_option(0, "fleet seed (same seed, same recordings)"), json_flag(), quiet_flag()])
    s.add_argument("--actuators", type=int, required=True, help="actuators in the fleet")
    s.add_argument("--tests", type=int, required=True, help="tests per actuator, spread over its life")
    s.add_argument("--out", required=True, help="folder for the recordings and manifest.csv")
    s.add_argument("--format", choices=("mcap", "csv"), default="mcap", help="recording format (default mcap)")
    s.set_defaults(func=cmd_fleet_simulate)
    d = fs.add_parser("diagnose", help="diagnose recordings on a Dask cluster into the health history",
                      parents=[method_option(), seed_option(0, "seed of every diagnosis (GA)"),
                               json_flag("print the summary as one JSON object"), quiet_flag()])
    d.add_argument("paths", nargs="*", help="recordings (.mcap, .csv) or folders (searched recursively)")
    d.add_argument("--manifest", help="FILE.csv: actuator_id, time_h, path (relative to it) [, usage, usage_unit]")
    d.add_argument("--history", help="SQLite health history (default: $EHA_HEALTH_HISTORY or the settings' path)")
    d.add_argument("--scheduler", help="address of a running Dask scheduler, e.g. tcp://10.0.0.5:8786")
    d.add_argument("--workers", type=int, help="worker processes of the LocalCluster (default 2)")
    d.add_argument("--discrepancy", action="store_true",
                   help="also run the discrepancy loop on each test and store its verdict")
    d.add_argument("--backfill", action="store_true", help=BACKFILL_HELP)
    d.set_defaults(func=cmd_fleet_diagnose)
    c = fs.add_parser("dask-config", help="print the Dask settings of fleet workers as a YAML config file "
                      "(for ~/.config/dask/ on the machines of a real cluster)")
    c.set_defaults(func=cmd_fleet_dask_config)
