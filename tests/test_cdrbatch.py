"""Batch CDR decoding (io/cdrbatch.py) against mcap_ros2's message-by-message decoder.

On every committed bag, and on generated JointState / FluidPressure messages (odd names and
array lengths, NaN, big endian from rosbags' serializer), the batch path gives the same numbers
bit for bit as the decoder, or declines (None) and read_run decodes message by message.
"""
import functools
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from mcap.records import Schema
from mcap_ros2._dynamic import serialize_dynamic
from mcap_ros2.decoder import DecoderFactory
from rosbags.typesys import Stores, get_typestore

from eha_health.io import cdrbatch
from eha_health.io.bagrun import SIGNALS, _batch_samples, _channels, read_run, resolve_topics
from eha_health.io.mcaplog import BagError, BagWriter, read_bag, scan_bag, schema_text
from msg_bridge import contract as C

BAGS = sorted((Path(__file__).parent.parent / "bags").glob("*.mcap"))
JS, FP = "sensor_msgs/msg/JointState", "sensor_msgs/msg/FluidPressure"
STORE = get_typestore(Stores.ROS2_JAZZY)


def same(a, b):
    a, b = np.asarray(a), np.asarray(b)
    return a.dtype == b.dtype and a.shape == b.shape and a.tobytes() == b.tobytes()


@pytest.mark.parametrize("path", BAGS, ids=lambda p: p.stem)
def test_batch_path_equals_message_by_message_on_every_bag(path):
    scan = scan_bag(path)
    names = resolve_topics(scan.bag.types, path)
    decoded = read_bag(path, topics=list(names.values()))
    for record in (False, True):
        want = _channels(decoded, names, record)          # mcap_ros2, one message at a time
        done = {}
        for t in SIGNALS:
            batch = _batch_samples(scan, names[t.name], t.name, record)
            assert batch is not None, f"{path.name}: {t.name} not decoded in a batch"
            done[t.name] = batch
        got = _channels(scan.decode([]), names, record, done)
        assert list(got) == list(want)
        for ch in want:
            assert same(got[ch].stamps, want[ch].stamps) and same(got[ch].values, want[ch].values), (path, ch)


@functools.lru_cache(maxsize=None)
def _decoder(typ):
    return DecoderFactory().decoder_for("cdr", Schema(id=1, name=typ, encoding="ros2msg",
                                                      data=schema_text(typ).encode()))


def _rosbags_msg(typ, sec, nanosec, frame, names, arrays, scalars):
    T = STORE.types
    header = T["std_msgs/msg/Header"](stamp=T["builtin_interfaces/msg/Time"](sec=sec, nanosec=nanosec),
                                      frame_id=frame)
    if typ == JS:
        return T[JS](header=header, name=names, **{k: np.asarray(v, float) for k, v in arrays.items()})
    return T[FP](header=header, fluid_pressure=scalars[0], variance=scalars[1])


floats = st.floats(allow_nan=True, allow_infinity=True, width=64)
text = st.text(st.characters(blacklist_categories=("Cs",), blacklist_characters="\x00"), max_size=9)


@st.composite
def topics(draw):
    """Messages of one topic: one layout (names, frame, array lengths) with other numbers per
    message, sometimes with one message of another layout; little or big endian."""
    typ = draw(st.sampled_from([JS, FP]))
    n = draw(st.integers(1, 12))
    frame, names = draw(text), draw(st.lists(text, max_size=3))
    lengths = {k: draw(st.integers(0, 3)) for k in ("position", "velocity", "effort")}
    odd = draw(st.none() | st.integers(0, n - 1))
    big = draw(st.booleans())
    out = []
    for i in range(n):
        f, nm, ln = frame, names, lengths
        if i == odd:
            f = draw(text)
            nm = draw(st.lists(text, max_size=3))
            ln = {k: draw(st.integers(0, 3)) for k in lengths}
        sec = draw(st.integers(-2**31, 2**31 - 1))
        nanosec = draw(st.integers(0, 2**32 - 1))
        arrays = {k: draw(st.lists(floats, min_size=m, max_size=m)) for k, m in ln.items()}
        scalars = (draw(floats), draw(floats))
        msg = _rosbags_msg(typ, sec, nanosec, f, nm, arrays, scalars)
        if big:
            out.append(bytes(STORE.serialize_cdr(msg, typ, little_endian=False)))
        else:  # mcap_ros2's encoder, as BagWriter.write uses it
            enc = serialize_dynamic(typ, schema_text(typ))[typ]
            out.append(enc({"header": {"stamp": {"sec": sec, "nanosec": nanosec}, "frame_id": f},
                            "name": nm, **arrays, "fluid_pressure": scalars[0], "variance": scalars[1]}))
    return typ, out, odd


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(topics())
def test_batch_columns_equal_the_decoder_on_generated_messages(case):
    typ, msgs, odd = case
    cols = cdrbatch.columns(typ, msgs)
    decoded = [_decoder(typ)(m) for m in msgs]
    def layout(m, d):
        return (len(m), d.header.frame_id, *(tuple(getattr(d, f, [])) if f == "name" else len(getattr(d, f, []))
                                             for f in ("name", "position", "velocity", "effort")))
    one_layout = len({layout(m, d) for m, d in zip(msgs, decoded)}) == 1
    assert (cols is not None) == one_layout     # declined exactly when a message has another layout
    if cols is None:
        assert odd is not None
        return
    stamps = [int(d.header.stamp.sec) * 1_000_000_000 + int(d.header.stamp.nanosec) for d in decoded]
    assert same(cols.stamp_ns, np.asarray(stamps, np.int64))
    for name, v in cols.values.items():
        want = [np.asarray(getattr(d, name), float).reshape(-1) for d in decoded]
        assert v.shape == (len(msgs), len(want[0]))
        assert same(v, np.asarray(want, float).reshape(v.shape)), name


def _write_contract(path, js_msgs, *, big_endian_pressure=False, bad_pressure=None):
    """A bag to the topic contract with the given joint-state messages (bytes), written raw."""
    n = len(js_msgs)
    enc = {t: serialize_dynamic(t, schema_text(t))[t] for t in (JS, FP)}
    with BagWriter(path, chunk_size=2048) as w:
        hdr = "std_msgs/msg/Header"
        for i in range(n):
            ns = 1_000_000 * (i + 1)
            stamp = {"sec": 0, "nanosec": ns}
            if i == 0:
                w.write("/eha/test_window", hdr, {"stamp": stamp, "frame_id": "start:1"}, ns)
            w.write_raw("/eha/command", JS, enc[JS]({"header": {"stamp": stamp}, "name": ["j"],
                                                     "position": [1e-3 * i]}), ns)
            w.write_raw("/eha/joint_state", JS, js_msgs[i], ns)
            if i == bad_pressure:
                w.write_raw("/eha/pressure", FP, b"\x00\x01\x00\x00\x01", ns)
            elif big_endian_pressure:
                msg = _rosbags_msg(FP, 0, ns, "eha", [], {}, (1e5 * i, 0.0))
                w.write_raw("/eha/pressure", FP, bytes(STORE.serialize_cdr(msg, FP, little_endian=False)), ns)
            else:
                w.write("/eha/pressure", FP, {"header": {"stamp": stamp}, "fluid_pressure": 1e5 * i}, ns)
            w.write("/eha/current", JS, {"header": {"stamp": stamp}, "name": ["j/tm"], "effort": [0.01 * i]}, ns)
            if i == n - 1:
                w.write("/eha/test_window", hdr, {"stamp": stamp, "frame_id": "end:1"}, ns)


def _js(i, names=("j",), velocity=True):
    return serialize_dynamic(JS, schema_text(JS))[JS](
        {"header": {"stamp": {"sec": 0, "nanosec": 1_000_000 * (i + 1)}}, "name": list(names),
         "position": [2e-3 * i], "velocity": [0.5 * i] if velocity else []})


def _per_message(path, record=False):
    """read_run's samples the message-by-message way (read_bag + _channels)."""
    names = resolve_topics(read_bag(path, topics=[]).types, path)
    return _channels(read_bag(path, topics=list(names.values())), names, record)


@pytest.mark.parametrize("variant", ["uniform", "names_change", "big_endian", "no_velocity"])
def test_read_run_takes_either_path_to_the_same_samples(tmp_path, variant):
    n = 120
    js = [_js(i, ("j", "rod") if variant == "names_change" and i >= 30 else ("j",),
              velocity=variant != "no_velocity") for i in range(n)]
    path = tmp_path / "run.mcap"
    _write_contract(path, js, big_endian_pressure=variant == "big_endian")
    scan = scan_bag(path)
    names = resolve_topics(scan.bag.types, path)
    batch = _batch_samples(scan, names[C.JOINT_STATE.name], C.JOINT_STATE.name, False)
    assert (batch is None) == (variant in ("names_change", "no_velocity"))
    assert _batch_samples(scan, names[C.PRESSURE.name], C.PRESSURE.name, False) is not None
    record = variant == "no_velocity"  # a rig record without velocity still reads in a batch
    assert (_batch_samples(scan, names[C.JOINT_STATE.name], C.JOINT_STATE.name, True) is None) == (
        variant == "names_change")
    want = _per_message(path, record)
    done = {t.name: b for t in SIGNALS for b in [_batch_samples(scan, names[t.name], t.name, record)] if b}
    got = _channels(scan.decode(names.values()), names, record, done)
    assert list(got) == list(want)
    for ch in want:
        assert same(got[ch].stamps, want[ch].stamps) and same(got[ch].values, want[ch].values), ch
    run = read_run(path, record=True)  # a 0.12 s window: too short for the FDI sequence, fine for a record
    assert run.test_id == 1 and same(run.response.position, _per_message(path, True)["position"].values)


def test_a_message_that_does_not_decode_raises_as_before(tmp_path):
    path = tmp_path / "bad.mcap"
    _write_contract(path, [_js(i) for i in range(20)], bad_pressure=7)
    names = resolve_topics(read_bag(path, topics=[]).types, path)
    with pytest.raises(BagError) as before:
        read_bag(path, topics=list(names.values()))
    with pytest.raises(BagError) as now:
        read_run(path)
    assert str(now.value) == str(before.value)
    assert "/eha/pressure: message 7 does not decode as sensor_msgs/msg/FluidPressure" in str(now.value)
