"""Commands on the models: ``simulate``, ``calibrate``, ``signatures``."""
from __future__ import annotations

import csv
import json
import sys
from pathlib import Path

from ..physics.faults import Faults
from .common import effects_option, faults_option, json_flag, params_from, progress_line, quiet_flag, seed_option


def cmd_simulate(args) -> int:
    from ..physics.model import simulate
    from ..plotting import plot_response
    faults = Faults.parse(args.faults or "")
    params = params_from(args, args.model)
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
    from ..identification.calibrate import calibrate, write_monitor_yaml
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
    from ..identification.signatures import Detector
    from ..plotting import plot_signature_families, trend_table
    out = Path(args.out)
    files = plot_signature_families(out, progress=None if args.quiet else progress_line)
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


def register(sub) -> None:
    s = sub.add_parser("simulate", help="simulate the FDI test and write a CSV",
                       parents=[faults_option(""), effects_option("comma list of effects to enable: "),
                                seed_option(None, "seed of the noise (default 0 when noise is on)")])
    s.add_argument("--model", choices=("reference", "monitor"), default="reference")
    s.add_argument("--noise", action="store_true", help="enable the default sensor (acquisition) noise")
    s.add_argument("--params", help="YAML file overriding parameters (same structure as data/params.yaml)")
    s.add_argument("--out", required=True, help="output CSV")
    s.add_argument("--plot", help="optional PNG of all channels")
    s.set_defaults(func=cmd_simulate)

    c = sub.add_parser("calibrate", help="fit the monitor first stage on the healthy reference", parents=[json_flag()])
    c.add_argument("--out", help="write the calibrated monitor overrides to this YAML")
    c.set_defaults(func=cmd_calibrate)

    g = sub.add_parser("signatures", help="paper-style signature plots (Figs. 4-7) and trend table",
                       parents=[quiet_flag()])
    g.add_argument("--out", required=True, help="output directory")
    g.set_defaults(func=cmd_signatures)
