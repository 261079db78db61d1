"""Test runs from an MCAP bag recorded to the topic contract (docs/interfaces.md).

:func:`read_run` reads the measured channels and the test-window marks, picks one
window and returns its :class:`~eha_health.signals.response.Response` (checked by
:func:`eha_health.io.window.assemble`) together with the truth the bag declares in its
metadata, if any (simulated runs only). No ROS install is needed.
"""
from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from msg_bridge import contract as C
from msg_bridge import convert as cv

from ..physics.faults import FAULT_NAMES
from ..physics.sequence import FDISequence
from ..signals.response import Response
from . import cdrbatch
from .mcaplog import Bag, BagError, Scan, bag_metadata, read_bag, scan_bag, schema_text
from .window import NS, Samples, WindowError, assemble

SIGNALS = (C.COMMAND, C.JOINT_STATE, C.PRESSURE, C.CURRENT)


@dataclass
class Run:
    response: Response
    test_id: int | None              # None: the bag has no window marks (whole record used)
    windows: list[int]               # complete windows in the bag
    truth: dict[str, str] | None     # metadata 'truth/test_<id>' (simulated runs)
    recorded: dict[str, str] | None  # metadata 'diagnosis/test_<id>' (what the live monitor said)
    notes: list[str] = field(default_factory=list)


#: Metadata record of a test the monitor appended to its health history: ``actuator_id``, ``time_h``
#: (operating hours), ``sim_time_s`` (window start stamp), ``usage`` (if given), ``history`` (the file).
HISTORY_META = "history/test_{}"
#: Metadata record of a diagnosed test the history refused (``actuator_id``, ``time_h``, ``sim_time_s``,
#: ``history``, ``error``: why; e.g. another diagnosis stored at that time): not read back as appended.
HISTORY_REFUSED_META = "history_refused/test_{}"
#: a window the monitor stopped before it could diagnose it (its samples still arriving), and why
DROPPED_META = "dropped/test_{}"


def history_record(path: str | Path, test_id: int | None, metadata: dict | None = None) -> dict[str, str]:
    """Test ``test_id``'s :data:`HISTORY_META` record of an MCAP log as written ({} without one);
    ``metadata``: the log's :func:`~eha_health.io.mcaplog.bag_metadata`, already read."""
    if test_id is None:
        return {}
    md = bag_metadata(path) if metadata is None else metadata
    return dict(md.get(HISTORY_META.format(test_id)) or {})


def history_times(path: str | Path, test_id: int | None, record: dict[str, str] | None = None) -> dict[str, float]:
    """``time_h``, ``usage``, ``sim_time_s`` of test ``test_id`` from an MCAP log's :data:`HISTORY_META`
    record (the keys it has; {} without one); ``record``: that record, already read."""
    rec = history_record(path, test_id) if record is None else record
    return {k: float(rec[k]) for k in ("time_h", "usage", "sim_time_s") if rec.get(k) not in (None, "", "None")}


def dropped_tests(path: str | Path, metadata: dict | None = None) -> dict[int, str]:
    """Test id -> reason of each window an MCAP log's :data:`DROPPED_META` records as cut off by the
    monitor's stop ({} for a bag without any); ``metadata``: the log's
    :func:`~eha_health.io.mcaplog.bag_metadata`, already read."""
    prefix = DROPPED_META.format("")
    out = {}
    for name, rec in (bag_metadata(path) if metadata is None else metadata).items():
        if name.startswith(prefix) and name[len(prefix):].isdigit():
            out[int(name[len(prefix):])] = (rec or {}).get("reason") or "no reason recorded"
    return dict(sorted(out.items()))


def truth_values(record: dict[str, str] | None) -> dict[str, float] | None:
    """The fault coefficients of a ``truth/test_<id>`` metadata record (strings) as numbers."""
    if not record:
        return None
    return {k: float(record[k]) for k in FAULT_NAMES}


def recorded_results(log_path: str | Path) -> list[dict]:
    """The monitor's verdicts recorded in an MCAP log (metadata 'diagnosis/test_<id>', 'truth/test_<id>')."""
    meta = read_bag(log_path, topics=[]).metadata
    out = []
    for name, rec in sorted(meta.items()):
        if name.startswith("diagnosis/test_"):
            tid = int(name.rsplit("_", 1)[1])
            d = {k: json.loads(v) for k, v in rec.items()}
            out.append({"test_id": tid, "diagnosis": d, "truth": truth_values(meta.get(f"truth/test_{tid}"))})
    return sorted(out, key=lambda r: r["test_id"])


def logged_history_outcomes(log_path: str | Path) -> list[dict]:
    """Per diagnosed test of a monitor's MCAP log, where its append to the health history went:
    ``test_id``, ``appended`` (bool), ``error`` (the status's ``history_error``, or None), from the
    last ``/diagnostics`` status logged for it (the monitor logs what it publishes)."""
    types = read_bag(log_path, topics=[]).types
    topics = [t for t in types if t.rsplit("/", 1)[-1] == C.DIAGNOSTICS.name.rsplit("/", 1)[-1]]
    last: dict[int, dict] = {}
    for m in (read_bag(log_path, topics=topics).messages.get(topics[0], []) if topics else []):
        for st in m.status:
            v = {kv.key: kv.value for kv in st.values}
            if "history_appended" in v and "test_id" in v:
                last[int(v["test_id"])] = {"test_id": int(v["test_id"]), "appended": v["history_appended"] == "True",
                                           "error": v.get("history_error")}
    return [last[k] for k in sorted(last)]


def resolve_topics(types: dict[str, str], path, namespace: str | None = None) -> dict[str, str]:
    """Contract name ('eha/command') -> the bag's topic ('/eha/command', '/left/eha/command', ...).

    A bag may hold one actuator under any namespace; with several, ``namespace`` picks one.
    """
    out = {}
    for topic in SIGNALS + (C.TEST_WINDOW,):
        if namespace is not None:
            want = "/" + "/".join(p for p in (namespace.strip("/"), topic.name) if p)
            found = [t for t in types if t == want]
        else:
            found = [t for t in types if t in (topic.name, "/" + topic.name) or t.endswith("/" + topic.name)]
        if len(found) > 1:
            raise BagError(f"{path}: several actuators publish {topic.name} ({', '.join(sorted(found))}); "
                           f"choose one with --namespace")
        if found:
            if types[found[0]] != topic.type:
                raise BagError(f"{path}: topic {found[0]} has type {types[found[0]]}, the contract says {topic.type}")
            out[topic.name] = found[0]
    return out


#: Contract topic -> (channel, message field, required) as the readers of msg_bridge.convert take them
#: (field[0]); a rig record's joint state has velocity and the load force (effort) optional.
_FIELDS = {C.COMMAND.name: (("command", "position", True),),
           C.JOINT_STATE.name: (("position", "position", True), ("velocity", "velocity", True)),
           C.PRESSURE.name: (("pressure", "fluid_pressure", True),),
           C.CURRENT.name: (("current", "effort", True),)}
_RECORD_JOINT_STATE = (("position", "position", True), ("velocity", "velocity", False), ("load", "effort", False))


def _same_bits(a, b) -> bool:
    a, b = np.asarray(a, float).reshape(-1), np.asarray(b, float).reshape(-1)
    return a.shape == b.shape and bool((a.view(np.int64) == b.view(np.int64)).all())


def _batch_samples(scan: Scan, topic: str, contract: str, record: bool) -> dict[str, Samples] | None:
    """The samples of a topic decoded at once (:func:`cdrbatch.columns`), exactly what
    :func:`_channels` makes of the decoded messages; None where that path is needed (other
    schema, mixed layouts, a message that does not decode or a field it needs empty)."""
    found = scan.channel(topic)
    typ = scan.bag.types[topic]
    if found is None or found[1] is None:
        return None
    ch, schema = found
    try:
        if (ch.message_encoding != "cdr" or schema.encoding != "ros2msg" or schema.name != typ
                or schema.data != schema_text(typ).encode()):
            return None
    except BagError:  # no definition installed for the type: decode message by message
        return None
    msgs = scan.bag.messages[topic]
    cols = cdrbatch.columns(typ, msgs)
    if cols is None:
        return None
    fields = _RECORD_JOINT_STATE if record and contract == C.JOINT_STATE.name else _FIELDS[contract]
    try:  # the first and last message through mcap_ros2: they decode, to the same numbers
        decoder = scan.decoder(topic)
        for i in (0, len(msgs) - 1):
            msg = decoder(msgs[i])
            if cv.stamp_ns(msg.header.stamp) != cols.stamp_ns[i] or not all(
                    _same_bits(getattr(msg, f), cols.values[f][i]) for _, f, _ in fields):
                return None
    except Exception:  # the message-by-message path raises the documented error
        return None
    out = {}
    for chan, f, required in fields:
        v = cols.values[f]
        if v.shape[1] == 0 and required:
            return None
        out[chan] = Samples(cols.stamp_ns.copy(), v[:, 0].copy() if v.shape[1] else np.full(len(v), np.nan))
    return out


def _channels(bag: Bag, names: dict[str, str], record: bool = False,
              done: dict[str, dict[str, Samples]] | None = None) -> dict[str, Samples]:
    """Samples per channel; ``record``: a rig record (absent topics skipped, the joint state read
    leniently: velocity and the load force in effort optional). ``done``: contract topic -> its
    samples already decoded in a batch (:func:`_batch_samples`)."""
    pairs: dict[str, list | Samples] = {}
    for topic in SIGNALS:
        if topic.name not in names:
            continue
        if done and topic.name in done:
            pairs.update(done[topic.name])
            continue
        reader, chans = cv.READERS[topic.name], C.CHANNELS[topic.name]
        if record and topic is C.JOINT_STATE:
            reader, chans = cv.joint_state_record_from_msg, chans + ("load",)
        for ch in chans:
            pairs.setdefault(ch, [])
        for i, msg in enumerate(bag.messages[names[topic.name]]):
            try:
                vals = reader(msg)
            except (ValueError, AttributeError, TypeError) as e:
                raise WindowError(f"{names[topic.name]} message {i}: {e}") from None
            for ch, v in zip(chans, vals[1:]):
                pairs[ch].append((vals[0], v))
    return {c: p if isinstance(p, Samples) else Samples.of(p) for c, p in pairs.items()}


def window_marks(bag: Bag, topic: str | None) -> dict[int, dict]:
    """Test id -> {'start': ns, 'end': ns} (the marks it has) of every window marked on ``topic``
    (the bag's test-window topic, from :func:`resolve_topics`; None: the bag has none)."""
    marks: dict[int, dict] = {}
    for i, msg in enumerate(bag.messages.get(topic, []) if topic else []):
        try:
            ns, event, tid = cv.window_from_msg(msg)
        except (ValueError, AttributeError) as e:
            raise WindowError(f"{topic} message {i}: {e}") from None
        marks.setdefault(tid, {})[event] = ns
    return dict(sorted(marks.items()))


def complete_windows(marks: dict[int, dict]) -> dict[int, dict]:
    """The windows of :func:`window_marks` with both their marks."""
    return {tid: m for tid, m in marks.items() if "start" in m and "end" in m}


def window_ids(path: str | Path) -> list[int]:
    """Ids of the complete test windows of the bag at ``path`` (reads only its window marks)."""
    topic = resolve_topics(read_bag(path, topics=[]).types, path).get(C.TEST_WINDOW.name)
    return list(complete_windows(window_marks(read_bag(path, topics=[topic] if topic else []), topic)))


def read_run(path: str | Path, test_id: int | None = None, sequence: FDISequence | None = None,
             namespace: str | None = None, record: bool = False, partial: bool = False) -> Run:
    """The response of one test window of the bag at ``path``.

    ``test_id`` picks a window by its id; default the first complete one. A bag
    without window marks is taken whole (first to last command sample); one whose marks
    complete no window (a recording stopped mid-test) is refused. ``record``:
    a measured rig record, which needs only command and joint state (position); the
    channels it lacks come out all NaN, a load force becomes ``Response.load``.
    ``partial``: a test to diagnose, read as a record when the bag lacks a measured
    channel's topic (the diagnosis takes the channels it has and checks the FDI test);
    a bag with every topic is read to the full contract.
    Raises ``BagError`` / ``WindowError`` (both ``ValueError``) naming the problem.
    """
    scan = scan_bag(path)  # one pass; topics decoded below (all at once where their layout allows)
    names = resolve_topics(scan.bag.types, path, namespace)
    if partial and not record and any(t.name not in names for t in SIGNALS):
        record = True
    needed = C.RECORD_INPUTS if record else SIGNALS
    missing = [t.name for t in needed if t.name not in names]
    if missing:
        raise BagError(f"{path}: missing topic {missing[0]} (the contract of docs/interfaces.md needs "
                       f"{', '.join(t.name for t in needed)})")
    done = {t.name: b for t in SIGNALS if t.name in names
            for b in [_batch_samples(scan, names[t.name], t.name, record)] if b is not None}
    bag = scan.decode(t for c, t in names.items() if c not in done)
    scan.bag.require(*(names[t.name] for t in needed))
    notes = [f"{path}: {bag.truncated}; using the complete part"] if bag.truncated else []
    chans = _channels(bag, names, record, done)
    topic = names.get(C.TEST_WINDOW.name)
    marks = window_marks(bag, topic)
    wins = complete_windows(marks)
    if marks and not wins:   # e.g. a recording stopped mid-test: a part of a test, not a whole record
        said = ", ".join(f"{tid} ({next(iter(m))} only)" for tid, m in marks.items())
        raise WindowError(f"{path}: no complete test window: the marks on {topic} are of test(s) {said}, none "
                          f"with both its start and end mark: a part of a test, not read as a whole record"
                          + (f" ({bag.truncated})" if bag.truncated else ""))
    if test_id is not None and test_id not in wins:
        raise WindowError(f"{path}: no complete test window {test_id} (complete: {sorted(wins) or 'none'})")
    if wins:
        tid = test_id if test_id is not None else next(iter(wins))
        start, end = wins[tid]["start"], wins[tid]["end"]
        if len(wins) > 1 and test_id is None:
            notes.append(f"{path}: {len(wins)} test windows {sorted(wins)}; diagnosing {tid} (choose with --test)")
    else:
        tid = None
        cmd = chans["command"].stamps
        if len(cmd) == 0:
            raise WindowError(f"{path}: no command samples")
        start, end = int(cmd.min()), int(cmd.max())
        notes.append(f"{path}: no test-window marks; using the whole record")
    try:
        r = assemble(chans, start, end, sequence, meta={"source": str(path), "test_id": tid, "test_ids": sorted(wins)},
                     record=record)
    except WindowError as e:
        why = f"{path}: test {tid}: {e}" if tid is not None else f"{path}: {e}"
        if bag.truncated:
            why += f" ({bag.truncated})"
        raise WindowError(why) from None
    return Run(r, tid, sorted(wins), bag.metadata.get(f"truth/test_{tid}"),
               bag.metadata.get(f"diagnosis/test_{tid}"), notes)




def write_run(writer, response: Response, test_id: int = 1, start_ns: int = 0, truth: dict | None = None,
              actuator_id: str = "eha") -> None:
    """Append ``response`` as test window ``test_id`` to an open :class:`~eha_health.io.mcaplog.BagWriter`,
    to the topic contract (stamps ``start_ns + t``; log time = stamp). Needs the rclpy message
    classes (msg_bridge builders). ``truth`` (fault coefficients of a simulated run) goes into
    the metadata record ``truth/test_<id>``, never into a topic.

    A measured record may lack channels (all NaN): no pressure or current topic then, an empty
    joint-state velocity; its ``load`` [N] goes into the joint-state effort.
    """
    stamps = start_ns + np.round(np.asarray(response.t) * NS).astype(np.int64)
    has = {c: bool(np.isfinite(getattr(response, c)).all()) for c in ("velocity", "pressure", "current")}
    for c in has:
        if not has[c] and np.isfinite(getattr(response, c)).any():
            raise ValueError(f"channel {c} is measured only in part (NaN samples): cannot be written")
    load = response.load

    def put(topic, msg, ns):
        writer.write("/" + topic.name, topic.type, msg, int(ns))
    put(C.TEST_WINDOW, cv.window_msg(int(stamps[0]), "start", test_id), stamps[0])
    for i, ns in enumerate(stamps):
        ns = int(ns)
        put(C.COMMAND, cv.command_msg(ns, response.command[i], actuator_id), ns)
        put(C.JOINT_STATE, cv.joint_state_msg(ns, response.position[i],
                                              response.velocity[i] if has["velocity"] else None, actuator_id,
                                              None if load is None else load[i]), ns)
        if has["pressure"]:
            put(C.PRESSURE, cv.pressure_msg(ns, response.pressure[i], actuator_id), ns)
        if has["current"]:
            put(C.CURRENT, cv.current_msg(ns, response.current[i], actuator_id), ns)
    put(C.TEST_WINDOW, cv.window_msg(int(stamps[-1]), "end", test_id), stamps[-1])
    if truth is not None:
        writer.add_metadata(f"truth/test_{test_id}", {k: str(v) for k, v in truth.items()})
