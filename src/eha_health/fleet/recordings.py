"""Which recordings a fleet batch diagnoses, and whose they are.

A recording is an MCAP bag to the topic contract (docs/interfaces.md) or a CSV in the
``simulate`` format. Its actuator id and test time [h] come from the bag's metadata record
``eha_health`` (``actuator_id``, the record the live monitor writes) and ``history/test_<id>``
(``time_h``, ``usage``: the history CLI's record), or from a manifest CSV (:data:`MANIFEST_COLUMNS`).

Manifest paths are relative to the manifest's folder and must stay inside it (no ``..`` or
absolute path escaping it): a manifest names files of one fleet folder, nothing else.
"""
from __future__ import annotations

import csv
import math
from dataclasses import dataclass
from pathlib import Path

from ..io.bagrun import DROPPED_META, HISTORY_META, dropped_tests, read_run, window_ids
from ..io.mcaplog import bag_metadata
from ..physics.faults import FAULT_NAMES
from ..signals.response import Response
from ..signals.table import csv_rows

#: Columns of a fleet manifest (``truth_*`` and ``noise_seed`` only for simulated fleets).
MANIFEST_COLUMNS = ("actuator_id", "time_h", "usage", "usage_unit", "path",
                    "truth_k_gm", "truth_k_fsj", "truth_k_bkl", "noise_seed", "test")
#: Columns a manifest must have.
MANIFEST_REQUIRED = ("actuator_id", "time_h", "path")
MANIFEST_NAME = "manifest.csv"
#: Bag metadata record with the actuator id (the live monitor writes it; so does ``fleet simulate``).
META_RECORD = "eha_health"
#: HISTORY_META (io.bagrun): the record with the operating time [h] and usage of test window <id>,
#: the history CLI's and the monitor's.
SUFFIXES = (".mcap", ".csv")


class FleetError(ValueError):
    """Bad input to a fleet batch (one line naming the problem; the CLI exits 2)."""


@dataclass
class Recording:
    """One recorded test to diagnose: its file and whose test it is (None: not known yet)."""
    path: Path
    actuator_id: str | None = None
    time_h: float | None = None
    usage: float | None = None
    usage_unit: str | None = None
    truth: dict | None = None
    origin: str = ""          # where the id and time come from (manifest line, bag metadata)
    window: int | None = None  # the test window of a bag of several (None: the file's only or first test)
    sim_time_s: float | None = None  # the window's start stamp [s] where the bag's metadata has it

    def where(self) -> str:
        return f"{self.path}" + (f" test {self.window}" if self.window is not None else "") + (
            f" ({self.origin})" if self.origin else "")


def _number(text, where: str, name: str, optional: bool = False) -> float | None:
    if optional and (text is None or str(text).strip() == ""):
        return None
    try:
        v = float(text)
    except (TypeError, ValueError):
        raise FleetError(f"{where}: {name} {text!r} is not a number") from None
    if not math.isfinite(v) or v < 0:
        raise FleetError(f"{where}: {name} must be a finite number >= 0, got {text!r}")
    return v


def read_manifest(path: str | Path) -> list[Recording]:
    """The recordings a manifest lists, paths resolved relative to it and checked to stay inside its folder."""
    path = Path(path)
    if not path.is_file():
        raise FleetError(f"{path}: no such manifest")
    root = path.parent.resolve()
    out, listed = [], {}
    for where, row in csv_rows(path, MANIFEST_REQUIRED, FleetError,
                               need=f"a manifest needs {', '.join(MANIFEST_REQUIRED)}"):
        if not row["actuator_id"]:
            raise FleetError(f"{where}: empty actuator_id")
        if not row["path"]:
            raise FleetError(f"{where}: empty path")
        rel = Path(row["path"])
        full = (root / rel).resolve()
        if rel.is_absolute() or not full.is_relative_to(root):
            raise FleetError(f"{where}: path {row['path']!r} leaves the manifest's folder {root}")
        truth = None
        if all(row.get(f"truth_k_{n[2:]}") not in (None, "") for n in FAULT_NAMES):
            truth = {n: _number(row[f"truth_k_{n[2:]}"], where, f"truth_k_{n[2:]}") for n in FAULT_NAMES}
        test = None
        if row.get("test") not in (None, ""):     # a bag of several tests: which window
            if not str(row["test"]).isdigit():
                raise FleetError(f"{where}: test {row['test']!r} is not a test window id (an integer >= 0)")
            test = int(row["test"])
        if (full, test) in listed:
            raise FleetError(f"{where}: {row['path']}{'' if test is None else f' test {test}'} is listed "
                             f"already ({listed[(full, test)]}): one row per recorded test")
        listed[(full, test)] = where
        out.append(Recording(full, row["actuator_id"], _number(row["time_h"], where, "time_h"),
                             _number(row.get("usage"), where, "usage", optional=True),
                             row.get("usage_unit") or None, truth, where, window=test))
    if not out:
        raise FleetError(f"{path}: the manifest lists no recordings")
    return out


def write_manifest(path: str | Path, rows: list[dict]) -> Path:
    """Write ``rows`` (dicts with :data:`MANIFEST_COLUMNS`, ``path`` relative to the manifest)."""
    path = Path(path)
    with path.open("w", newline="") as f:
        w = csv.DictWriter(f, MANIFEST_COLUMNS, extrasaction="raise")
        w.writeheader()
        w.writerows(rows)
    return path


def bag_identity(path: Path) -> dict:
    """``{actuator_id, time_h, usage, usage_unit, sim_time_s}`` of a bag, where its metadata has them: the actuator
    from :data:`META_RECORD`, the time and usage from its one :data:`HISTORY_META` record (else from
    :data:`META_RECORD`)."""
    md = bag_metadata(path)
    rec = dict(md.get(META_RECORD, {}))
    tests = [name for name in md if name.startswith(HISTORY_META.format(""))]
    if len(tests) == 1:
        rec.update({k: v for k, v in md[tests[0]].items() if k in ("time_h", "usage", "usage_unit", "sim_time_s")})
    return _identity_fields(rec, f"{path}: metadata")


def _identity_fields(raw: dict, where: str) -> dict:
    """The identity fields a metadata record holds, numbers checked (:func:`_number`)."""
    out: dict = {}
    if raw.get("actuator_id"):
        out["actuator_id"] = raw["actuator_id"]
    for key in ("time_h", "usage", "sim_time_s"):
        if raw.get(key) not in (None, ""):
            out[key] = _number(raw[key], where, key)
    if raw.get("usage_unit"):
        out["usage_unit"] = raw["usage_unit"]
    return out


def bag_windows(rec: Recording) -> list[Recording]:
    """A bag of several tests as one recording per test: a monitor log holds a
    :data:`HISTORY_META` record (time, usage) per test it appended to a history. A CSV, a bag
    of one test, or a recording a manifest identified stays as it is (a
    manifest row's ``test`` names the window, checked here; without it the row is the file's
    first window)."""
    if rec.window is not None:
        if rec.path.suffix.lower() != ".mcap":
            raise FleetError("a test window applies to MCAP bags only")
        try:
            ids = window_ids(rec.path)
        except (OSError, ValueError):      # an unreadable bag fails in the batch, saying why
            return [rec]
        if rec.window not in ids:
            raise FleetError(f"no complete test window {rec.window} (complete: {ids or 'none'})")
        _refuse_cut_off(rec.path, rec.window)
        if len(ids) == 1:
            rec.window = None               # the bag's only test: the file is the recording
        return [rec]
    if rec.path.suffix.lower() != ".mcap":
        return [rec]
    if rec.actuator_id is not None:    # a manifest row without `test`: the bag's first window
        try:
            first = window_ids(rec.path)[:1]
        except (OSError, ValueError):      # an unreadable bag fails in the batch, saying why
            return [rec]
        if first:
            _refuse_cut_off(rec.path, first[0])
        return [rec]
    try:
        md = bag_metadata(rec.path)
    except Exception:      # an unreadable bag fails in the batch, saying why
        return [rec]
    prefix = HISTORY_META.format("")
    ids = sorted(int(n[len(prefix):]) for n in md if n.startswith(prefix) and n[len(prefix):].isdigit())
    if not ids:
        return [rec]
    if len(ids) == 1:
        # one record: the file is the recording only if the bag holds one test; else the record's
        # window is (a monitor that appended only its third test: the first window is not it)
        try:
            if len(window_ids(rec.path)) <= 1:
                return [rec]
        except (OSError, ValueError):      # an unreadable bag fails in the batch, saying why
            return [rec]
    actuator = dict(md.get(META_RECORD, {})).get("actuator_id")
    out = []
    for i in ids:       # each test's time and usage from its record, the actuator from the bag's
        name = HISTORY_META.format(i)
        ident = _identity_fields({**md[name], "actuator_id": actuator}, f"{rec.path}: metadata {name}")
        out.append(Recording(rec.path, ident.get("actuator_id"), ident.get("time_h"), ident.get("usage"),
                             ident.get("usage_unit"), None, "bag metadata", window=i,
                             sim_time_s=ident.get("sim_time_s")))
    return out


def _refuse_cut_off(path: Path, window: int) -> None:
    """A window the monitor recorded as cut off by its stop (:data:`~eha_health.io.bagrun.DROPPED_META`)
    may lack samples it was still waiting for, even with both its marks in the log: not a whole
    test (as ``history add`` refuses it)."""
    why = dropped_tests(path).get(window)
    if why is not None:
        raise FleetError(f"test window {window} was cut off by the monitor's stop ({why}; metadata "
                         f"{DROPPED_META.format(window)}): not a whole test")


def find_recordings(paths: list[str | Path]) -> list[Recording]:
    """Recordings under ``paths`` (files, or folders searched recursively for .mcap and .csv).

    A ``manifest.csv`` is not a recording: it gives the actuator id and test time of the files
    it lists (CSVs need it; bags carry their own metadata). A file's manifest is the nearest
    one listing it, from the file's folder up to the folder given (a file given alone: its own
    folder). Without either, the recording is still returned (it fails in the batch, saying why).
    """
    found: list[tuple[Path, Path]] = []   # (file, the top folder its manifest may be in)
    for p in map(Path, paths):
        if p.is_dir():
            top = p.resolve()
            found += [(q.resolve(), top) for q in sorted(p.rglob("*")) if q.is_file() and q.suffix.lower() in SUFFIXES]
        elif p.is_file():
            found.append((p.resolve(), p.resolve().parent))
        else:
            raise FleetError(f"{p}: no such file or folder")
    manifests: dict[Path, dict[Path, Recording]] = {}

    def listed(folder: Path) -> dict[Path, Recording]:
        if folder not in manifests:
            m = folder / MANIFEST_NAME
            manifests[folder] = {r.path: r for r in read_manifest(m)} if m.is_file() else {}
        return manifests[folder]

    seen, out = set(), []
    for full, top in found:
        if full.name == MANIFEST_NAME or full in seen:
            continue
        seen.add(full)
        rec = None
        for folder in [full.parent, *full.parent.parents]:
            rec = listed(folder).get(full)
            if rec is not None or folder == top or not folder.is_relative_to(top):
                break
        out.append(rec or Recording(full))
    if not out:
        raise FleetError(f"no .mcap or .csv recordings in {', '.join(map(str, paths))}")
    return out


def complete_identity(rec: Recording) -> None:
    """Fill a bag's actuator id and test time from its metadata where the manifest gave none;
    raises FleetError (a per-recording failure) when they stay unknown."""
    if rec.actuator_id is None and rec.path.suffix.lower() == ".mcap":
        ident = bag_identity(rec.path)
        if "actuator_id" in ident and "time_h" in ident:
            rec.actuator_id, rec.time_h = ident["actuator_id"], ident["time_h"]
            rec.usage, rec.usage_unit = ident.get("usage"), ident.get("usage_unit")
            rec.sim_time_s = ident.get("sim_time_s")
            rec.origin = "bag metadata"
    if rec.actuator_id is None or rec.time_h is None:
        where = (f"no metadata '{META_RECORD}' with actuator_id and '{HISTORY_META.format('<id>')}' with time_h"
                 if rec.path.suffix.lower() == ".mcap"
                 else "a CSV recording has no metadata")
        raise FleetError(f"unknown actuator id / test time: {where}, and no manifest lists the file")


def read_recording(path: str | Path, window: int | None = None) -> tuple[Response, dict | None]:
    """(response, truth or None) of one recording (``window``: a bag's test window, default its first);
    ValueError names what is wrong with the file."""
    path = Path(path)
    if path.suffix.lower() == ".mcap":
        run = read_run(path, window, partial=True)      # a bag without a measured channel's topic: the others
        truth = {k: float(run.truth[k]) for k in FAULT_NAMES} if run.truth else None
        return run.response, truth
    if path.suffix.lower() == ".csv":
        return Response.from_csv(path, ("t", "command")), None     # measured columns it lacks: diagnose says
    raise FleetError(f"{path}: not a recording (.mcap or .csv)")
