"""Commands on recorded tests: ``diagnose``, ``discrepancy``, ``import``."""
from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np

from ..discrepancy.settings import DEFAULT_MAX_EFFECTS
from ..physics.faults import FAULT_NAMES
from .common import (UsageError, fitness_option, json_flag, load_run, load_test, method_option, progress, quiet_flag, seed_option,
                     test_option)


def cmd_diagnose(args) -> int:
    from ..identification.diagnose import diagnose
    path = Path(args.run)
    r, truth, notes = load_test(path, args.test)
    for n in notes:
        print(f"note: {n}", file=sys.stderr)
    prog = progress(args)
    d = diagnose(r, method=args.method, fitness=args.fitness, seed=args.seed, progress=prog, clean=not args.no_clean)
    if args.plot:
        from ..plotting import plot_diagnosis
        plot_diagnosis(r, d, args.plot)
    if args.json:
        out = d.as_dict()
        if truth is not None:
            out["truth"] = truth
        print(json.dumps(out, default=float))
        return 0
    k = d.faults
    print(f"diagnosis of {path} ({d.method}, fitness {d.fitness}, seed {d.seed}):")
    for key, val in zip(FAULT_NAMES, k.as_tuple()):
        tr = f"   truth {truth[key]:.4f}" if truth else ""
        print(f"  {key.upper():5s} = {val:.4f} +/- {d.std[key]:.4f}  (0 healthy, 1 limit){tr}")
    scales = {"position": (1e6, "um"), "velocity": (1e3, "mm/s"), "pressure": (1e-3, "kPa"), "current": (1e6, "uA")}
    print("  fit RMS: " + ", ".join(f"{c} {v * scales[c][0]:.1f} {scales[c][1]}" for c, v in d.rms.items())
          + f";  fitness {d.cost:.4g}")
    print(f"  {d.evaluations} monitor simulations in {d.wall_time_s:.2f} s")
    for w in d.warnings:
        print(f"  warning: {w}")
    if args.plot:
        print(f"  plot: {args.plot}")
    return 0


def check_fdi_test(r):
    """The record of ``r`` as a whole FDI test (``ValueError`` naming why it is not): from t = 0 over
    the whole sequence, with the measured channels it holds (position at least: the CLI requires it)."""
    from ..identification.record import fdi_record
    from ..physics.sequence import FDISequence
    return fdi_record(r, FDISequence())


def discrepancy_mode(r) -> tuple[str, str]:
    """("fdi", "") when ``r`` is a whole FDI test -- from t = 0 over the whole sequence, its command
    the FDI sequence's (:data:`~eha_health.identification.record.FDI_COMMAND_MATCH`), whichever
    measured channels it holds -- ("rig", why it is not) when its command is another; ``ValueError``
    (the check's) for an FDI command in a record that is not a whole test (too short, some NaN)."""
    from ..identification.record import FDI_COMMAND_MATCH, LaterStart, command_mismatch
    from ..physics.sequence import FDISequence
    try:
        check_fdi_test(r)
        problem = None
    except LaterStart:
        raise           # an FDI test in the wrong place is not a rig record: the message says where it starts
    except ValueError as e:
        problem = e
    off = command_mismatch(np.asarray(r.t, float), r.command, FDISequence())
    if off > FDI_COMMAND_MATCH:
        return "rig", (f"its command is not the FDI sequence (RMS difference from it {100 * off:.0f} % of the "
                       f"sequence's RMS; an FDI test is within {100 * FDI_COMMAND_MATCH:.0f} %)")
    if problem is not None:
        # the FDI sequence's command: an FDI test that cannot be analysed as it is, not a rig record
        raise problem
    return "fdi", ""


def cmd_discrepancy(args) -> int:
    from ..discrepancy.loop import analyse_fdi_test
    from ..discrepancy.report import format_report
    path = Path(args.run)
    if args.max_effects < 0:
        raise UsageError(f"--max-effects must be >= 0, got {args.max_effects}")
    r, truth, notes = load_run(path, args.test, required=("t", "command", "position"))
    for n in notes:
        print(f"note: {n}", file=sys.stderr)
    mode, why = discrepancy_mode(r) if args.mode == "auto" else (args.mode, "")
    if args.mode == "fdi":
        check_fdi_test(r)
    if why:
        # say it: a user who meant an FDI test should not have to guess why the faults are missing
        print(f"note: analysed as a rig record, not an FDI test: {why}", file=sys.stderr)
    from ..identification.record import recorded
    from ..signals.channels import MEASURED
    held = recorded(r)
    missing = [c for c in MEASURED if c not in held] if mode == "fdi" else []
    if missing:
        print(f"note: {', '.join(missing)} not in the record: the loop compares the channels it holds "
              f"and leaves out the candidates that act on {'it' if len(missing) == 1 else 'them'} only",
              file=sys.stderr)
    prog = progress(args)
    if mode == "fdi":
        rep = analyse_fdi_test(r, max_effects=args.max_effects, seed=args.seed, truth=truth, progress=prog)
    else:
        from ..discrepancy.rig import analyse_rig
        rep = analyse_rig(r, max_effects=args.max_effects, fit_fraction=args.fit_fraction, progress=prog)
    if args.plot:
        from ..plotting import plot_discrepancy
        plot_discrepancy(rep, args.plot)
    if args.json:
        out = rep.as_dict()
        out["mode"] = mode
        if why:
            out["mode_reason"] = why
        if missing:
            out["not_recorded"] = missing
        out["source"] = str(path)
        if truth is not None:
            out["truth"] = truth
        print(json.dumps(out, default=float))
        return 0
    if prog:
        print(file=sys.stderr)
    print(format_report(rep, f"{path} ({mode})"))
    if args.plot:
        print(f"  plot: {args.plot}")
    return 0


def cmd_import(args) -> int:
    from ..io.importer import import_text
    r = import_text(args.file, args.map)
    out = Path(args.out)
    measured = r.meta["measured"]
    if out.suffix.lower() == ".csv":
        out.parent.mkdir(parents=True, exist_ok=True)
        r.to_csv(out)
    elif out.suffix.lower() == ".mcap":
        from ..io.bagrun import write_run
        from ..io.mcaplog import BagWriter
        out.parent.mkdir(parents=True, exist_ok=True)
        with BagWriter(out) as w:
            write_run(w, r)
    else:
        raise UsageError(f"--out must end in .csv or .mcap, got {out.name}")
    load = f", load {np.ptp(r.load):.4g} N peak-to-peak" if r.load is not None else ""
    print(f"wrote {out}: {len(r.t)} samples at {r.sample_rate:.6g} Hz over {r.t[-1]:.3f} s; measured "
          f"{', '.join(measured)}{load}; command {np.ptp(r.command) * 1e3:.4g} mm peak-to-peak")
    return 0


def register(sub) -> None:
    q = sub.add_parser("diagnose", help="identify the fault coefficients of a recorded test (CSV or MCAP)",
                       parents=[test_option("MCAP: test window id (default: the first complete one)"), method_option(),
                                fitness_option(), seed_option(0, "seed of the identification (GA)"),
                                json_flag("print one JSON object"), quiet_flag()])
    q.add_argument("run", help="CSV in the simulate format, or an MCAP bag to the docs/interfaces.md contract")
    q.add_argument("--plot", help="PNG: measured vs fitted per channel, and the convergence")
    q.add_argument("--no-clean", action="store_true",
                   help="keep the raw fit: do not set aside spikes, clipped or frozen samples and interference "
                        "found against it (lsq fitness)")
    q.set_defaults(func=cmd_diagnose)

    im = sub.add_parser("import", help="measured rig data (delimited text) into the project's format")
    im.add_argument("file", help="text/CSV data file")
    im.add_argument("--map", required=True, help="YAML channel map (columns, scales, units; see docs/discrepancy.md)")
    im.add_argument("--out", required=True, help="RUN.csv or RUN.mcap (the topic contract; channels a rig lacks are left out)")
    im.set_defaults(func=cmd_import)

    dc = sub.add_parser("discrepancy", help="residual -> missing effect -> augmented model, before and after",
                        parents=[test_option("MCAP: test window id"), seed_option(0, "fdi: seed of the diagnosis"),
                                 json_flag("one JSON object: before, after, candidates, selected"), quiet_flag()])
    dc.add_argument("run", help="CSV (simulate or import format) or MCAP bag")
    dc.add_argument("--max-effects", type=int, default=DEFAULT_MAX_EFFECTS,
                    help=f"most effects to add (default {DEFAULT_MAX_EFFECTS})")
    dc.add_argument("--mode", choices=("auto", "fdi", "rig"), default="auto",
                    help="fdi: an FDI test of the shipped EHA (faults re-identified); rig: calibrate the "
                         "nominal loop to a measured rig first (auto: fdi when the record is a whole FDI "
                         "test -- t from 0, the FDI sequence's command -- whichever channels it holds)")
    dc.add_argument("--fit-fraction", type=float, default=0.7, help="rig: share of the record fitted (rest held out)")
    dc.add_argument("--plot", help="PNG: residuals before and after, and the candidate ranking")
    dc.set_defaults(func=cmd_discrepancy)
