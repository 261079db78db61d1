"""Commands on the health history and the remaining useful life: ``history add|list|import|export|repair``,
``prognose``, ``thresholds`` (the harness is ``bench rul`` in :mod:`.bench`).

Every history command takes ``--history DB``; without it the file is
:func:`eha_health.prognostics.store.default_history_path` (``$EHA_HEALTH_HISTORY``, else
``history.default_path`` of data/prognostics.yaml). Bad input: one line, exit code 2, and the
store unchanged (each append is one SQLite transaction, validated before it is written).
"""
from __future__ import annotations

import json
import math
import os
import sys
from pathlib import Path

from ..physics.faults import FAULT_KEYS
from .common import (UsageError, fitness_option, history_option, json_flag, load_test, method_option,
                     prognostics_settings_option, progress, quiet_flag, seed_option, test_option)

#: --backfill of the commands that append tests
BACKFILL_HELP = "accept tests older than the actuator's latest stored one (a recording that failed once and is fixed, an older log found later); without it they are refused as out of order"


def _db(args, must_exist: bool, settings) -> Path:
    from ..prognostics.store import default_history_path
    path = Path(args.history).expanduser() if args.history else default_history_path(settings)
    if path.is_dir():
        raise UsageError(f"{path}: a directory, not a history file")
    if must_exist and not path.is_file():
        raise UsageError(f"{path}: no such history (add tests first: eha-health history add | import)")
    if path.suffix.lower() == ".csv":
        raise UsageError(f"{path}: --history of this command is a SQLite history, not a HISTORY.csv "
                         "(import it with: eha-health history import FILE.csv)")
    return path


def _settings(args):
    """The prognostics settings of ``--settings`` (merged over data/prognostics.yaml; ``--clock``
    over both)."""
    from ..prognostics.config import load_settings
    path = getattr(args, "settings", None)
    if path and not Path(path).expanduser().is_file():
        raise UsageError(f"{path}: no such settings file")
    clock = getattr(args, "clock", None)
    return load_settings(Path(path).expanduser() if path else None,
                         {"prognosis": {"clock": clock}} if clock else None)


def _finite(v: float | None, name: str, minimum: float = 0.0) -> None:
    if v is not None and not (math.isfinite(v) and v >= minimum):
        raise UsageError(f"{name} must be a finite number >= {minimum:g}, got {v}")


def cmd_history_add(args) -> int:
    from ..identification.diagnose import diagnose
    from ..prognostics.records import DuplicateRow, HealthRecord, check_actuator_id
    from ..prognostics.store import HistoryStore, recording_hash
    path = Path(args.run)
    if not path.is_file():
        raise UsageError(f"{path}: no such recording")
    check_actuator_id(args.actuator, "--actuator")
    _finite(args.time_h, "--time-h")
    _finite(args.usage, "--usage")
    settings = _settings(args)
    db = _db(args, False, settings)
    mcap = path.suffix.lower() == ".mcap"
    if mcap:
        from ..io.mcaplog import bag_metadata
        md = bag_metadata(path)     # read once: the cut-off windows, the test's history record, the actuator
    test = _test_to_add(path, args.test, md) if mcap else args.test
    r, _, notes = load_test(path, test)
    for n in notes:
        print(f"note: {n}", file=sys.stderr)
    time_h, usage, sim_s, meta, live, logged = args.time_h, args.usage, None, {}, None, None
    if mcap:
        from ..io.bagrun import history_record, history_times
        record = history_record(path, r.meta.get("test_id"), md)
        meta = history_times(path, r.meta.get("test_id"), record)
        logged = record.get("history") or None     # the file the monitor appended the test to
        time_h = meta.get("time_h") if time_h is None else time_h
        usage = meta.get("usage") if usage is None else usage
        sim_s = meta.get("sim_time_s")
        live = md.get("eha_health", {}).get("actuator_id") if "time_h" in meta else None
    if time_h is None:
        raise UsageError(f"{path}: no --time-h and the recording carries no operating time "
                         f"(MCAP metadata history/test_<id>)")
    # each test window of a bag of several is a recording of its own
    tid, ids = r.meta.get("test_id"), r.meta.get("test_ids") or []
    window = tid if tid is not None and len(ids) > 1 else None
    digest = recording_hash(path, window)
    with HistoryStore(db, settings) as st:
        t = st.find_recording(digest)
        if t is not None:   # before the diagnosis: the same recording twice adds nothing
            if t["actuator_id"] != args.actuator:
                raise UsageError(f"{path} is already in the history for actuator {t['actuator_id']}, "
                                 f"not {args.actuator}")
            return _already(args, db, t["actuator_id"], t["time_h"],
                            f"{path}{'' if tid is None else f' test {tid}'} is already in {db} (actuator "
                            f"{t['actuator_id']}, time_h {t['time_h']:g}): nothing added")
        if "time_h" in meta and st.holds_test(live or args.actuator, meta["time_h"], sim_s):
            # the monitor appended this test live (its row hashed by the channels, not by this file)
            if (live or args.actuator, meta["time_h"]) != (args.actuator, time_h):   # it would be stored twice
                raise UsageError(f"{path}{'' if tid is None else f' test {tid}'} is already in the history: the "
                                 f"monitor appended it live for actuator {live or args.actuator} at time_h "
                                 f"{meta['time_h']:g} (metadata history/test_{tid}), not {args.actuator} at {time_h:g}")
            return _already(args, db, args.actuator, time_h,
                            f"{path} test {tid} is already in {db} (actuator {args.actuator}, time_h {time_h:g}, "
                            f"window stamp {sim_s:g} s: metadata history/test_{tid}, appended by the monitor"
                            f"{'' if logged is None or _same_file(logged, db) else f' to {logged}'}): nothing added")
        try:                                                                     # before the diagnosis
            st.check_next_time(args.actuator, time_h, sim_s, str(path), backfill=args.backfill)
        except DuplicateRow as e:   # another recording at a stored time: the time is the user's to give
            raise UsageError(f"{e}; each test of an actuator has its own operating time: give this one its "
                             f"--time-h") from None
        d = diagnose(r, method=args.method, fitness=args.fitness, seed=args.seed, progress=progress(args))
        rec = HealthRecord(args.actuator, float(time_h), (0.0,) * 3, (0.0,) * 3, usage=usage)
        notes = st.usage_notes([rec]) + (st.backfill_notes([rec]) if args.backfill else [])
        added = st.add_diagnosis(d, args.actuator, time_h, usage=usage, usage_unit=args.usage_unit,
                                 source_path=path, sim_time_s=sim_s, source_window=window, backfill=args.backfill)
        # where the monitor appended it, said after the append (a refusal stays one line), never left unsaid
        where = [] if logged is None else [
            f"{path} test {tid}: the log's metadata history/test_{tid} says the monitor appended it to {db}, "
            f"which held no test of actuator {live or args.actuator} at time_h {meta.get('time_h', time_h):g} "
            f"with its window stamp (a row removed, or the file replaced)" if _same_file(logged, db) else
            f"{path} test {tid}: the monitor appended it to {logged} (metadata history/test_{tid}), not to {db}"
            + (f"; added to {db} as well" if added else "")]
    for n in where + (notes if added else []):
        print(f"note: {n}", file=sys.stderr)
    ks = ", ".join(f"{n.upper()}={v:.4f}+-{d.std['k_' + n]:.4f}" for n, v in zip(FAULT_KEYS, d.faults.as_tuple()))
    if args.json:
        print(json.dumps({"added": added, "actuator_id": args.actuator, "time_h": time_h, "usage": usage,
                          "diagnosis": d.as_dict(), "history": str(db)}, default=float))
    else:
        print(f"{'added' if added else 'already present'}: {args.actuator} at {time_h:g} h: {ks} ({d.method}) "
              f"-> {db}")
    return 0


def _already(args, db: Path, actuator: str, time_h: float, said: str) -> int:
    """A recording the history holds already: nothing added, no diagnosis run; with ``--json`` the
    same object as an append, ``added`` false, ``diagnosis`` null and ``reason`` the line."""
    if args.json:
        print(json.dumps({"added": False, "actuator_id": actuator, "time_h": float(time_h), "usage": None,
                          "diagnosis": None, "history": str(db), "reason": said}))
    else:
        print(said)
    return 0


def _same_file(logged: str, db: Path) -> bool:
    """Whether the history a monitor log names (an absolute path, as the monitor wrote it) is ``db``."""
    try:
        return os.path.samefile(logged, db)
    except OSError:     # one of them is gone (moved, not created yet): only the names can tell
        return Path(logged).expanduser().resolve() == db.expanduser().resolve()


def _test_to_add(path: Path, test: int | None, metadata: dict) -> int | None:
    """The window of a bag to add: ``test``, or the first complete one, passing over the windows its
    monitor recorded as cut off by its stop (:data:`~eha_health.io.bagrun.DROPPED_META`): such a window
    may have both marks in the log and still lack samples the monitor was waiting for, so it is not
    taken as a whole test. Each one passed over is said on stderr; none left is a usage error.
    ``metadata``: the bag's :func:`~eha_health.io.mcaplog.bag_metadata`."""
    from ..io.bagrun import DROPPED_META, dropped_tests, window_ids
    dropped = dropped_tests(path, metadata)
    if not dropped or (test is not None and test not in dropped):
        return test
    cut = "cut off by the monitor's stop"
    if test is not None:
        raise UsageError(f"{path} test {test}: not added: {cut} ({dropped[test]}; metadata "
                         f"{DROPPED_META.format(test)})")
    wins = window_ids(path)
    if wins and wins[0] not in dropped:
        return None          # the default window is whole (read_run says which it took of several)
    left = [t for t in wins if t not in dropped]
    if not left:
        said = "; ".join(f"test {t}: {why}" for t, why in dropped.items() if t in wins or not wins)
        raise UsageError(f"{path}: nothing to add: every test window of the log was {cut} ({said})")
    for t in wins[:wins.index(left[0])]:
        print(f"note: {path} test {t}: skipped, {cut} ({dropped[t]}; metadata {DROPPED_META.format(t)})",
              file=sys.stderr)
    print(f"note: {path}: diagnosing test {left[0]}, the first one not cut off (choose with --test)",
          file=sys.stderr)
    return left[0]


def cmd_history_list(args) -> int:
    from ..prognostics.store import HistoryStore
    settings = _settings(args)
    db = _db(args, True, settings)
    with HistoryStore(db, settings, readonly=True) as st:
        rows = st.list_tests(args.actuator)
        maint = st.list_maintenance(args.actuator)
    if args.json:
        print(json.dumps({"history": str(db), "tests": rows, "maintenance": maint}, default=float))
        return 0
    print(f"{db}: {len(rows)} test(s), {len(maint)} maintenance action(s)")
    print(f"{'actuator':12s} {'time_h':>9s} " + " ".join(f"{'K_' + n.upper():>15s}" for n in FAULT_KEYS)
          + f" {'usage':>8s}  method         source")
    for t in rows:
        # a std not stated (an import without std columns) is estimated when prognose reads it
        ks = " ".join(f"{t['k_' + n]:7.4f}+-" + ("  est " if t["std_" + n] is None else f"{t['std_' + n]:.4f}")
                      for n in FAULT_KEYS)
        use = "" if t["usage"] is None else f"{t['usage']:g}"
        print(f"{t['actuator_id']:12s} {_fmt_time(t['time_h'])} {ks} {use:>8s}  {t['method'] or '':14s} "
              f"{Path(t['source_path']).name if t['source_path'] else ''}"
              + ("  (back-filled: stored after later tests)" if t["backfilled"] else ""))
    for m in maint:
        print(f"{m['actuator_id']:12s} {_fmt_time(m['time_h'])} {m['action']} {m['fault']}" +
              (f" ({m['note']})" if m["note"] else ""))
    return 0


def cmd_history_import(args) -> int:
    from ..prognostics.history_csv import read_history_csv, read_maintenance_csv
    from ..prognostics.records import DuplicateRow, superseded_notes
    from ..prognostics.store import HistoryStore
    settings = _settings(args)
    db = _db(args, False, settings)
    # both files read before the store is opened: a bad file creates no store
    maint = read_maintenance_csv(args.maintenance) if args.maintenance else None
    try:   # a row at a time its actuator has a test at already, in the file or in the store
        read = []
        recs = read_history_csv(args.file, read)
        _maintenance_beside(args.file, args.maintenance)
        with HistoryStore(db, settings) as st:
            notes = st.usage_notes(recs, maint) + (st.backfill_notes(recs) if args.backfill else [])
            older = superseded_notes([(x["actuator_id"], x["time_h"], x["fault"]) for x in st.list_maintenance()],
                                     maint or [])
            n, m = st.import_files(args.file, args.maintenance, recs, maint, backfill=args.backfill)
            total = st.count_tests()
    except DuplicateRow as e:
        raise UsageError(f"{e}; {_csv_duplicate_hint(e)}") from None
    for note in read + (notes if n else []) + (older if m else []):
        print(f"note: {note}", file=sys.stderr)
    extra = f" and {m} maintenance action(s) from {args.maintenance}" if args.maintenance else ""
    print(f"imported {n} new test(s) from {args.file}{extra} into {db} ({total} tests in all)")
    return 0


def _csv_duplicate_hint(e) -> str:
    """What to do about a HISTORY.csv row at a time its actuator has a test at already
    (:class:`~eha_health.prognostics.records.DuplicateRow`): in the history (with other values: the
    same test adds nothing), or in a row of the file before it -- the same test twice, or two."""
    if e.held is None:
        return ("the history holds another test there (the same one, with the same K, would add nothing); each "
                "test of an actuator has its own operating time: correct this row's time_h, or remove the row")
    if e.record is not None and e.record == e.held:
        return f"it repeats the test of {e.held.where} (the same values): remove one of the two rows"
    return ("each test of an actuator has its own operating time: correct the time_h of one of the two rows, "
            "or remove one")


def _maintenance_beside(history_csv, maintenance) -> None:
    """Say so when ``history export``'s maintenance file lies beside a HISTORY.csv read without it."""
    from ..prognostics.history_csv import maintenance_beside
    beside = maintenance_beside(history_csv)
    if maintenance is None and beside.is_file():
        print(f"note: {beside} beside it is not read: its repairs and replacements count only with "
              f"--maintenance {beside}", file=sys.stderr)


def _csv_out(path: str, what: str, db: Path) -> Path:
    p = Path(path).expanduser()
    if p.suffix.lower() != ".csv":
        raise UsageError(f"{p}: the {what} is written as CSV: give a name ending in .csv")
    if p.is_dir():
        raise UsageError(f"{p}: a directory, not a {what}")
    if not p.parent.is_dir():
        raise UsageError(f"{p.parent}: no such directory for the {what}")
    if p.resolve() == db.resolve():
        raise UsageError(f"{p}: that is the history itself")
    return p


def cmd_history_export(args) -> int:
    from ..prognostics.history_csv import maintenance_beside, write_history_csv, write_maintenance_csv
    from ..prognostics.store import HistoryStore
    settings = _settings(args)
    db = _db(args, True, settings)
    out = _csv_out(args.file, "HISTORY.csv", db)
    mout = _csv_out(args.maintenance or str(maintenance_beside(out)), "MAINTENANCE.csv", db)
    if mout.resolve() == out.resolve():
        raise UsageError(f"{mout}: the tests and the maintenance need two files")
    with HistoryStore(db, settings, readonly=True) as st, st.snapshot():
        rows = st.list_tests(args.actuator)
        maint = st.list_maintenance(args.actuator)
    if not rows:
        raise UsageError(f"{db}: the history is empty: nothing to export")
    write_history_csv(out, rows)
    write_maintenance_csv(mout, maint)
    print(f"exported {len(rows)} test(s) to {out} and {len(maint)} maintenance action(s) to {mout} from {db} "
          f"(import both: eha-health history import {out} --maintenance {mout})")
    return 0


def cmd_history_repair(args) -> int:
    from ..prognostics.records import trend_start_h
    from ..prognostics.store import HistoryStore
    _finite(args.time_h, "--time-h")
    settings = _settings(args)
    db = _db(args, True, settings)
    with HistoryStore(db, settings) as st:
        st.record_repair(args.actuator, args.fault, args.time_h, action=args.action, note=args.note)
        log = [(m["time_h"], m["fault"]) for m in st.list_maintenance(args.actuator)]
        at_test = st.has_test_at(args.actuator, args.time_h)
    # a back-filled log: where a later maintenance covers the fault, its trend restarts there
    later = {f: trend_start_h(log, f) for f in (FAULT_KEYS if args.fault == "all" else (args.fault,))}
    here = [f for f, t in later.items() if t <= args.time_h]
    later = {f: t for f, t in later.items() if t > args.time_h}
    said = ("its trend restarts there" if not later else
            f"the trend of {', '.join(here)} restarts there" if here else "kept in the log only")
    print(f"recorded: {args.action} of {args.fault} on {args.actuator} at {args.time_h:g} h ({said}) -> {db}")
    if at_test and not later:
        # the usual slip: the time of the test that found the wear; a return-to-service test is as likely
        print(f"note: the test at {args.time_h:g} h counts as after the {args.action} (the trend restarts at or "
              f"after it); if it is the test that found the wear, a K above the tests after it is set aside "
              f"when prognosed, and named", file=sys.stderr)
    if later:
        print("note: a later maintenance is recorded, where the trend restarts instead: "
              + ", ".join(f"{f} at {t:g} h" for f, t in later.items()), file=sys.stderr)
    return 0


def _fmt_time(t: float) -> str:
    """A test time [h] for `history list`: 2 decimals from 1 h (epoch-scale hours keep theirs), 4
    significant digits below (a rig's tests minutes apart)."""
    return f"{t:9.2f}" if t == 0 or abs(t) >= 1.0 else f"{t:9.4g}"


def _fmt_h(v) -> str:
    from ..prognostics.rul import format_hours
    return format_hours(v)


def _fmt_usage(v) -> str:
    return "beyond the horizon" if v is None else f"{v:g}"


def format_prognosis(obj: dict, next_check_h: float) -> str:
    """The ``prognose`` object as a table: one line per fault and the overall, per actuator."""
    lines = []
    for a, r in obj["actuators"].items():
        lines.append(f"{a}:" + ("  (wear fitted against usage; hours at the unit's usage rate)"
                                if r["overall"].get("clock") == "usage" else ""))
        lines.append(f"  {'fault':8s} {'model':18s} {'RUL median [5 %, 95 %] h':>28s} "
                     f"{'P(fail < ' + format(next_check_h, 'g') + ' h)':>16s} {'threshold':>9s} {'tests':>5s}")
        for name, f in [*r["faults"].items(), ("overall", r["overall"])]:
            sampled = f["p_fail_next"] is not None or f.get("p_fail_next_min") is not None
            rul = (f"{_fmt_h(f['rul_median_h'])} [{_fmt_h(f['rul_p05_h'])}, {_fmt_h(f['rul_p95_h'])}]"
                   if sampled else "-")
            pf = (f"{f['p_fail_next']:.3f}" if f["p_fail_next"] is not None else
                  f">= {f['p_fail_next_min']:.3f}" if f.get("p_fail_next_min") is not None else "-")
            thr = "-" if f["threshold"] is None else f"{f['threshold']:.3f}"
            model = (f["model"] or "-") + (" +fleet" if f.get("fleet_prior") else "")
            lines.append(f"  {name:8s} {model:18s} {rul:>28s} {pf:>16s} {thr:>9s} {f['n_tests']:5d}")
            if r["overall"].get("clock") == "usage" and f.get("rul_median_usage") is not None:
                lines.append(f"  {'':8s} in usage: {f['rul_median_usage']:g} [{f['rul_p05_usage']:g}, "
                             f"{_fmt_usage(f['rul_p95_usage'])}] (the fit's clock)")
            if name == "overall" and f.get("dominant_fault"):
                lines.append(f"  {'':8s} dominant fault: {f['dominant_fault']}")
            for g in f.get("shared_wear") or []:
                lines.append(f"  {'':8s} {' and '.join(g)} wear together (their increments move together): the 95 % "
                             "end holds for any dependence between them")
            if f.get("unrecorded_repair_h") is not None:
                lines.append(f"  {'':8s} K fell at {f['unrecorded_repair_h']:g} h and stayed down: an unrecorded repair, "
                             "the trend restarts there (record it: history repair)")
            if f.get("outliers_h"):
                lines.append(f"  {'':8s} set aside as failed diagnoses (far off their neighbours): tests at "
                             + ", ".join(f"{t:g}" for t in f["outliers_h"]) + " h")
            if f.get("last_test_off_trend"):
                lines.append(f"  {'':8s} the last test is off the trend: the RUL mixes the futures with and without it "
                             "(the next test will tell)")
            if f.get("reason"):
                lines.append(f"  {'':8s} {f['reason']}")
    return "\n".join(lines)


def cmd_prognose(args) -> int:
    from ..prognostics.rul import plot_prognosis, prognose
    from ..prognostics.store import as_history, default_history_path
    s = _settings(args)
    src = Path(args.history).expanduser() if args.history else default_history_path(s)   # as_history checks it
    _finite(args.next_check_h, "--next-check-h", minimum=1e-12)
    notes: list[str] = []
    hist = as_history(src, s, args.maintenance, notes)
    if src.suffix.lower() == ".csv":
        _maintenance_beside(src, args.maintenance)
    for note in notes:
        print(f"note: {note}", file=sys.stderr)
    plotted = None
    if args.plot:                   # said before the work, not after it
        out = Path(args.plot).expanduser()
        if out.is_dir():
            raise UsageError(f"{args.plot}: is a directory; --plot takes a file name, e.g. {out / 'prognosis.png'}")
        if not out.parent.is_dir():
            raise UsageError(f"{args.plot}: cannot write the plot (no such directory {out.parent})")
    if args.plot and not Path(args.plot).suffix:
        args.plot += ".png"         # what matplotlib writes; the path said is the path written
    if args.plot:
        try:
            obj = plot_prognosis(hist, args.plot, args.actuator, args.next_check_h, settings=s)
        except (PermissionError, IsADirectoryError, NotADirectoryError) as e:
            raise UsageError(f"{args.plot}: cannot write the plot ({e.strerror or type(e).__name__})") from None
        plotted = next(iter(obj["actuators"]))
        if args.actuator is None:   # the plot shows one actuator; the answer is about all of them
            obj = prognose(hist, None, args.next_check_h, settings=s)
    else:
        obj = prognose(hist, args.actuator, args.next_check_h, settings=s)
    if args.json:
        print(json.dumps(obj, default=float))
        return 0
    nc = args.next_check_h if args.next_check_h is not None else s.prognosis.next_check_h
    print(format_prognosis(obj, nc))
    if args.plot:
        n = len(obj["actuators"])
        print(f"  plot: {args.plot} (actuator {plotted}" + (f", the first of {n}; --actuator picks another)" if n > 1 else ")"))
    return 0


def cmd_thresholds(args) -> int:
    from ..prognostics.thresholds import failure_thresholds
    th = failure_thresholds(_settings(args))
    if args.json:
        print(json.dumps({f: t.as_dict() for f, t in th.items()}))
        return 0
    print(f"failure thresholds of the reference EHA ({args.settings or 'data/prognostics.yaml'} requirements, "
          "noise-free FDI sequence):")
    for f, t in th.items():
        if t.requirement is None:
            print(f"  K_{f.upper():4s} {t.k:.4f}  (default: no requirement breaks below the search bound)")
        else:
            print(f"  K_{f.upper():4s} {t.k:.4f}  breaks {t.requirement}: {t.metric} > {t.limit:g} {t.unit} "
                  f"(healthy {t.healthy_value:.4g} {t.unit})")
    return 0


def register(sub) -> None:
    h = sub.add_parser("history", help="the health history: add | list | import | export | repair")
    hs = h.add_subparsers(dest="history_command", required=True)
    a = hs.add_parser("add", help="diagnose a recorded test (CSV or MCAP) and append it to the history",
                      parents=[history_option(), prognostics_settings_option(), test_option("MCAP: test window id"), method_option(),
                               fitness_option(), seed_option(0, "seed of the identification (GA)"),
                               json_flag("print one JSON object"), quiet_flag()])
    a.add_argument("run", help="RUN.csv (simulate format) or BAG.mcap (docs/interfaces.md contract)")
    a.add_argument("--actuator", required=True, help="actuator id")
    a.add_argument("--time-h", type=float, help="operating hours at the test (an MCAP log of the monitor "
                                                "carries it; required otherwise)")
    a.add_argument("--usage", type=float, help="usage at the test (flight hours or cycles)")
    a.add_argument("--usage-unit", default=None, help="unit of --usage, e.g. FH or cycles")
    a.add_argument("--backfill", action="store_true", help=BACKFILL_HELP)
    a.set_defaults(func=cmd_history_add)

    ls = hs.add_parser("list", help="the stored tests and maintenance",
                       parents=[history_option(), prognostics_settings_option(), json_flag()])
    ls.add_argument("--actuator", help="one actuator only")
    ls.set_defaults(func=cmd_history_list)

    im = hs.add_parser("import", help="append the rows of a HISTORY.csv (actuator_id, time_h, k_gm, k_fsj, "
                                      "k_bkl [, std_gm, std_fsj, std_bkl, usage, usage_unit, sim_time_s])",
                        parents=[history_option(), prognostics_settings_option()])
    im.add_argument("file", help="HISTORY.csv")
    im.add_argument("--maintenance", help="MAINTENANCE.csv (actuator_id, time_h, fault [, action, note]) "
                                          "imported with it in one transaction: repairs and replacements")
    im.add_argument("--backfill", action="store_true", help=BACKFILL_HELP)
    im.set_defaults(func=cmd_history_import)

    ex = hs.add_parser("export", help="write the history as HISTORY.csv and MAINTENANCE.csv "
                                      "(history import reads them back)",
                       parents=[history_option(), prognostics_settings_option()])
    ex.add_argument("file", help="HISTORY.csv to write (replaced if it exists)")
    ex.add_argument("--maintenance", help="MAINTENANCE.csv to write (default: FILE_maintenance.csv beside it)")
    ex.add_argument("--actuator", help="one actuator only")
    ex.set_defaults(func=cmd_history_export)

    rp = hs.add_parser("repair", help="record a repair or replacement: that fault's trend restarts",
                       parents=[history_option(), prognostics_settings_option()])
    rp.add_argument("--actuator", required=True)
    rp.add_argument("--fault", required=True, choices=(*FAULT_KEYS, "all"))
    rp.add_argument("--time-h", type=float, required=True, help="operating hours of the repair")
    rp.add_argument("--action", choices=("repair", "replace"), default="repair")
    rp.add_argument("--note", help="free text")
    rp.set_defaults(func=cmd_history_repair)

    p = sub.add_parser("prognose", help="remaining useful life per fault and overall, with its interval",
                       parents=[history_option(), prognostics_settings_option(),
                                json_flag("one object: {actuators: {ID: {faults, overall}}}")])
    p.add_argument("--actuator", help="one actuator (default: all)")
    p.add_argument("--next-check-h", type=float, help="hours to the next check (p_fail_next; default "
                                                      "prognosis.next_check_h of data/prognostics.yaml)")
    p.add_argument("--plot", help="PNG per fault: history, trend and band, threshold, RUL distribution "
                                  "(of --actuator, default the first); another suffix (.pdf, .svg, .jpg) writes "
                                  "that format, none adds .png")
    p.add_argument("--clock", choices=("time", "usage"), help="fit wear against time_h or against the tests' "
                   "usage (wear that follows flight hours or cycles; RUL in hours at each unit's usage rate); "
                   "default prognosis.clock of the settings (time)")
    p.add_argument("--maintenance", help="MAINTENANCE.csv of a --history HISTORY.csv (repairs and replacements)")
    p.set_defaults(func=cmd_prognose)
    p.epilog = "--history also takes a HISTORY.csv (with --maintenance, its MAINTENANCE.csv)"

    t = sub.add_parser("thresholds", help="failure thresholds from the physics (requirements of data/prognostics.yaml)",
                       parents=[prognostics_settings_option(), json_flag()])
    t.set_defaults(func=cmd_thresholds)
