"""MCAP logs: round trips checked with rosbags' independent reader, truncation and damage.

Real files in tmp_path; rclpy is used only to build messages and to capture real
wire bytes (the module itself must not import it).
"""
import array
import dataclasses
import re
import struct
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap.records import Chunk, Message
from mcap.stream_reader import StreamReader, breakup_chunk
from rosbags.highlevel import AnyReader
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

from eha_health.io.mcaplog import BagError, BagWriter, read_bag, schema_text

JS, FP, DA = "sensor_msgs/msg/JointState", "sensor_msgs/msg/FluidPressure", "diagnostic_msgs/msg/DiagnosticArray"
FMA, HDR = "std_msgs/msg/Float64MultiArray", "std_msgs/msg/Header"
MAGIC = b"\x89MCAP0\r\n"


@pytest.fixture(scope="module")
def store():
    return get_typestore(Stores.ROS2_JAZZY)


def py(v):
    """Plain Python value of a message from rclpy, mcap_ros2 or rosbags, for comparison."""
    if hasattr(v, "get_fields_and_field_types"):  # rclpy
        out = {}
        for name, typ in v.get_fields_and_field_types().items():
            x = getattr(v, name)
            out[name] = x[0] if typ == "octet" else py(x)
        return out
    if dataclasses.is_dataclass(v):  # rosbags
        return {f.name: py(getattr(v, f.name)) for f in dataclasses.fields(v)
                if not f.name.startswith("__") and not f.name.isupper()}  # not constants
    if hasattr(v, "__slots__") and hasattr(v, "_type"):  # mcap_ros2
        return {s: py(getattr(v, s)) for s in v.__slots__}
    if isinstance(v, dict):
        return {k: py(x) for k, x in v.items()}
    if isinstance(v, (list, tuple, np.ndarray, array.array, bytes)):
        return [py(x) for x in v]
    if isinstance(v, np.generic):
        return v.item()
    return v


def rosbags_read(path, store):
    """topic -> (type, [(log_time, plain message)]) with rosbags' reader."""
    out = {}
    with AnyReader([Path(path)], default_typestore=store) as r:
        for c in r.connections:
            out.setdefault(c.topic, (c.msgtype, []))
        for c, t, raw in r.messages():
            out[c.topic][1].append((t, py(r.deserialize(raw, c.msgtype))))
    return out


def sample_messages():
    """topic -> (type, [rclpy messages]) covering nested messages, arrays and strings."""
    from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
    from sensor_msgs.msg import FluidPressure, JointState
    from std_msgs.msg import Float64MultiArray, Header, MultiArrayDimension

    out = {}
    js = []
    for i in range(3):
        m = JointState(name=["hinge", "rod"], position=[0.1 * i, -2.5e-3], velocity=[1e-9 * i, 3.0],
                       effort=[])
        m.header.stamp.sec, m.header.stamp.nanosec, m.header.frame_id = 100 + i, 999_999_999 - i, "eha"
        js.append(m)
    js[2].header.stamp.sec = -1  # int32 in ROS 2, not uint32
    out["/eha/joint_states"] = (JS, js)
    out["/eha/pressure"] = (FP, [FluidPressure(fluid_pressure=2.1e7 + i, variance=0.5 * i) for i in range(4)])
    da = DiagnosticArray(status=[
        DiagnosticStatus(level=DiagnosticStatus.WARN, name="eha/jack", message="friction high",
                         hardware_id="sn-17",
                         values=[KeyValue(key="k_fsj", value="0.42"), KeyValue(key="unit", value="-")]),
        DiagnosticStatus(level=DiagnosticStatus.OK, name="eha/servovalve", values=[])])
    da.header.frame_id = "diag"
    out["/diagnostics"] = (DA, [da, DiagnosticArray()])
    fa = Float64MultiArray(data=[1.0, 2.0, 3.0, 4.0, 5.0, 6.0])
    fa.layout.dim = [MultiArrayDimension(label="rows", size=2, stride=6),
                     MultiArrayDimension(label="cols", size=3, stride=3)]
    fa.layout.data_offset = 0
    out["/eha/matrix"] = (FMA, [fa])
    out["/eha/header"] = (HDR, [Header(frame_id="only a header")])
    return out


def encode(type_name, msg):
    """CDR bytes from mcap_ros2's encoder, independently of BagWriter."""
    from mcap_ros2._dynamic import serialize_dynamic
    return serialize_dynamic(type_name, schema_text(type_name))[type_name](msg)


# ------------------------------------------------------------------ schemas

@pytest.mark.parametrize("t", [JS, FP, DA, FMA, HDR, "builtin_interfaces/msg/Time",
                               "sensor_msgs/msg/NavSatStatus", "rcl_interfaces/msg/ParameterDescriptor",
                               "type_description_interfaces/msg/FieldType", "std_msgs/msg/Empty"])
def test_schema_text_is_rosbags_msgdef(t, store):
    text = schema_text(t)
    assert text == store.generate_msgdef(t, ros_version=2)[0]
    types = get_types_from_msg(text, t)
    assert t in types
    assert schema_text(t.replace("/msg/", "/")) == text


def test_schema_text_matches_rosbags_for_every_installed_msg(store):
    share = Path(sys.prefix) / "share"
    found = [f"{f.parent.parent.name}/msg/{f.stem}" for f in share.glob("*/msg/*.msg")]
    known = [t for t in found if t in store.fielddefs]
    assert len(known) > 100
    bad = [t for t in known if schema_text(t) != store.generate_msgdef(t, ros_version=2)[0]]
    assert bad == []


def test_schema_text_details():
    js = schema_text(JS)
    assert js.startswith("std_msgs/Header header\nstring[] name\nfloat64[] position\n")
    assert f"{'=' * 80}\nMSG: std_msgs/Header\nbuiltin_interfaces/Time stamp\nstring frame_id\n" in js
    assert f"{'=' * 80}\nMSG: builtin_interfaces/Time\nint32 sec\nuint32 nanosec\n" in js
    assert "#" not in js
    assert "byte WARN=1\n" in schema_text(DA)
    assert "string<=255 nested_type_name" in schema_text("type_description_interfaces/msg/FieldType")
    assert "FloatingPointRange[<=1] floating_point_range" in schema_text("rcl_interfaces/msg/ParameterDescriptor")


def test_schema_text_from_ament_prefix_path(tmp_path, monkeypatch, store):
    """Comments, constants of every kind, defaults, bounds and same-package types, checked with rosbags."""
    share = tmp_path / "share" / "eha_test_msgs" / "msg"
    share.mkdir(parents=True)
    (share / "Reading.msg").write_text(
        "# a reading\n"
        "string QUOTED=\"a # not a comment\"  # a comment\n"
        "string BARE=rest of # line\n"
        "float64 GAIN = 2.50 # gain\n"
        "bool ON=true\n"
        "int8 LOW=-3\n"
        "\n"
        "std_msgs/Header header   # stamp\n"
        "Sample[<=4] samples\n"
        "Sample last\n"
        "string<=8 tag \"default\"\n"
        "float64[3] xyz [1.0, 2.0, 3.0]\n"
        "uint8 count 7  # with a default\n")
    (share / "Sample.msg").write_text("builtin_interfaces/Time stamp\nfloat32\tvalue\nstring<=5[] notes\n")
    monkeypatch.setenv("AMENT_PREFIX_PATH", str(tmp_path))
    t = "eha_test_msgs/msg/Reading"
    text = schema_text(t)
    ts = get_typestore(Stores.EMPTY)
    # dependencies from the Jazzy store, ours parsed by rosbags from the raw .msg files
    ts.register({k: store.fielddefs[k] for k in ("std_msgs/msg/Header", "builtin_interfaces/msg/Time")})
    ts.register(get_types_from_msg((share / "Sample.msg").read_text(), "eha_test_msgs/msg/Sample"))
    ts.register(get_types_from_msg((share / "Reading.msg").read_text(), t))
    assert text == ts.generate_msgdef(t, ros_version=2)[0]
    assert 'string QUOTED=a # not a comment\nstring BARE=rest of # line\nfloat64 GAIN=2.5\nbool ON=True\n' in text

    # and a message of that type goes through BagWriter, read_bag and rosbags
    msg = {"header": {"stamp": {"sec": 3, "nanosec": 4}, "frame_id": "f"},
           "samples": [{"stamp": {"sec": 1, "nanosec": 2}, "value": 0.5, "notes": ["ab", "c"]}],
           "last": {"value": -1.5, "notes": []}, "tag": "t", "xyz": np.array([1.0, 2.0, 3.0]), "count": 7}
    path = tmp_path / "custom.mcap"
    with BagWriter(path) as w:
        w.write("/r", t, msg, 10)
    got = py(read_bag(path).messages["/r"][0])
    assert got["samples"][0]["notes"] == ["ab", "c"] and got["xyz"] == [1.0, 2.0, 3.0]
    assert got["last"]["stamp"] == {"sec": 0, "nanosec": 0}
    (rtype, [(_, rb)]) = rosbags_read(path, get_typestore(Stores.ROS2_JAZZY))["/r"]
    assert rtype == t and rb == got


def test_schema_text_unknown_type():
    with pytest.raises(BagError, match=r"no_such_pkg/msg/Thing: message definition not found"):
        schema_text("no_such_pkg/msg/Thing")
    with pytest.raises(BagError, match="not a ROS 2 message type"):
        schema_text("JointState")


# ------------------------------------------------------------------ round trips

def check_against_rosbags(path, expected, store):
    """Every topic, type, count, log time and value, with read_bag and with rosbags."""
    bag = read_bag(path)
    assert bag.truncated is None
    rb = rosbags_read(path, store)
    assert set(bag.messages) == set(rb) == set(expected)
    for topic, (typ, items) in expected.items():
        want_t = [t for t, _ in items]
        want = [py(m) for _, m in items]
        assert bag.types[topic] == rb[topic][0] == typ
        assert bag.log_times[topic].dtype == np.int64
        assert bag.log_times[topic].tolist() == want_t == [t for t, _ in rb[topic][1]]
        assert [py(m) for m in bag.messages[topic]] == want, topic
        assert [m for _, m in rb[topic][1]] == want, topic
    return bag


def test_round_trip_write_and_write_raw(tmp_path, store):
    path = tmp_path / "rt.mcap"
    expected = {}
    t = 1_700_000_000_000_000_000
    with BagWriter(path) as w:
        for topic, (typ, msgs) in sample_messages().items():
            for i, m in enumerate(msgs):
                w.write(topic, typ, m, t + i, publish_time_ns=t + i - 5)
                # the same message as raw CDR, from mcap_ros2's encoder fed a dict
                w.write_raw(topic + "/raw", typ, encode(typ, py(m)), t + 1000 + i)
            expected[topic] = (typ, [(t + i, m) for i, m in enumerate(msgs)])
            expected[topic + "/raw"] = (typ, [(t + 1000 + i, m) for i, m in enumerate(msgs)])
    bag = check_against_rosbags(path, expected, store)
    js = bag.messages["/eha/joint_states"][0]
    assert (js.header.stamp.sec, js.header.frame_id, js.position) == (100, "eha", [0.0, -2.5e-3])
    assert bag.messages["/diagnostics"][0].status[0].values[1].key == "unit"
    assert bag.messages["/eha/matrix"][0].layout.dim[1].label == "cols"
    # publish times and file structure, with mcap's own reader
    with open(path, "rb") as f:
        reader = make_reader(f)
        header = reader.get_header()
        summary = reader.get_summary()
        pubs = [(m.log_time, m.publish_time) for _, ch, m in reader.iter_messages(topics=["/eha/pressure"])]
    assert header.profile == "ros2"
    assert pubs[0] == (t, t - 5)
    assert {s.encoding for s in summary.schemas.values()} == {"ros2msg"}
    assert {c.message_encoding for c in summary.channels.values()} == {"cdr"}
    assert {s.name: s.data.decode() for s in summary.schemas.values()} == {
        typ: schema_text(typ) for typ, _ in sample_messages().values()}
    assert len(summary.schemas) == 5  # one schema per type, shared by the topics
    assert {ci.compression for ci in summary.chunk_indexes} == {"zstd"}


def test_write_accepts_dicts_numpy_and_decoded_messages(tmp_path, store):
    path = tmp_path / "d.mcap"
    d = {"header": {"stamp": {"sec": np.int32(5), "nanosec": 6}, "frame_id": "x"},
         "name": ("a", "b"), "position": np.array([1.5, 2.5]), "velocity": np.arange(2.0), "effort": []}
    with BagWriter(path, compression="lz4") as w:
        w.write("/js", JS, d, 1)
    first = read_bag(path).messages["/js"][0]
    with BagWriter(tmp_path / "again.mcap", compression="none") as w:
        w.write("/js", JS, first, 1)  # a message read back is written again unchanged
    again = read_bag(tmp_path / "again.mcap").messages["/js"][0]
    want = {"header": {"stamp": {"sec": 5, "nanosec": 6}, "frame_id": "x"},
            "name": ["a", "b"], "position": [1.5, 2.5], "velocity": [0.0, 1.0], "effort": []}
    assert py(first) == py(again) == want
    assert rosbags_read(tmp_path / "again.mcap", store)["/js"][1][0][1] == want


@pytest.fixture
def ros(monkeypatch):
    """An isolated rclpy context with one node and a single-threaded executor."""
    from rosnode import node_on_executor

    # nodes in one context still talk with discovery off; nothing leaves the process
    monkeypatch.setenv("ROS_AUTOMATIC_DISCOVERY_RANGE", "OFF")
    with node_on_executor("mcaplog_test") as node_ex:
        yield node_ex


def test_write_raw_with_real_wire_bytes(tmp_path, ros, store):
    """Bytes from an rclpy subscription with raw=True are written as they are; rosbags decodes them."""
    from rclpy.serialization import deserialize_message
    from sensor_msgs.msg import JointState

    node, ex = ros
    got = []
    pub = node.create_publisher(JointState, "/eha/joint_states", 10)
    node.create_subscription(JointState, "/eha/joint_states", lambda b: got.append((time.time_ns(), b)),
                             10, raw=True)
    deadline = time.monotonic() + 5
    while pub.get_subscription_count() < 1 and time.monotonic() < deadline:
        ex.spin_once(timeout_sec=0.01)
    sent = sample_messages()["/eha/joint_states"][1]
    for m in sent:
        pub.publish(m)
    while len(got) < len(sent) and time.monotonic() < deadline:
        ex.spin_once(timeout_sec=0.05)
    assert len(got) == len(sent)
    assert all(isinstance(b, bytes) for _, b in got)
    assert [py(deserialize_message(b, JointState)) for _, b in got] == [py(m) for m in sent]

    path = tmp_path / "wire.mcap"
    with BagWriter(path) as w:
        for t, b in got:
            w.write_raw("/eha/joint_states", JS, b, t)
        for i, m in enumerate(sent):  # the same messages from the rclpy objects
            w.write("/eha/joint_states/encoded", JS, m, got[-1][0] + 1 + i)
    check_against_rosbags(path, {
        "/eha/joint_states": (JS, [(t, m) for (t, _), m in zip(got, sent)]),
        "/eha/joint_states/encoded": (JS, [(got[-1][0] + 1 + i, m) for i, m in enumerate(sent)]),
    }, store)
    raw = read_bag(path, topics=["/eha/joint_states"], raw=True)
    assert raw.messages == {"/eha/joint_states": [b for _, b in got]}  # byte for byte
    assert raw.log_times["/eha/joint_states"].tolist() == [t for t, _ in got]


def test_metadata_round_trip(tmp_path):
    path = tmp_path / "meta.mcap"
    meta = {"run": {"rig": "eha-2", "operator": "Zoë", "params": '{"k_gm": 0.3}'},
            "calibration": {"p_offset_pa": "1250.0"}, "empty": {}}
    with BagWriter(path) as w:
        w.add_metadata("run", meta["run"])
        w.write("/eha/pressure", FP, {"fluid_pressure": 1.0}, 1)
        w.add_metadata("calibration", meta["calibration"])
        w.add_metadata("empty", {})
        with pytest.raises(BagError, match="must be a str name"):
            w.add_metadata("bad", {"x": 1.0})
    assert read_bag(path).metadata == meta
    with open(path, "rb") as f:  # and with mcap's own reader
        assert {m.name: m.metadata for m in make_reader(f).iter_metadata()} == meta


# ------------------------------------------------------------------ truncation

def write_chunked(path, n=120, flush_at=60, **kw):
    """/eha/pressure and /eha/joint_states at log times 0..n-1 in small chunks, flush() at ``flush_at``.

    Returns a copy of the file taken right after flush().
    """
    w = BagWriter(path, chunk_size=kw.pop("chunk_size", 400), **kw)
    w.add_metadata("run", {"n": str(n)})
    copy = None
    for i in range(n):
        w.write("/eha/pressure", FP, {"header": {"frame_id": "p"}, "fluid_pressure": float(i)}, i)
        w.write("/eha/joint_states", JS, {"name": ["h"], "position": [i * 1e-3]}, i)
        if i == flush_at - 1:
            w.flush()
            copy = path.read_bytes()
    w.close()
    w.close()  # idempotent
    return copy


def chunk_table(path):
    """Per chunk, from mcap's reader: (start, end) of its record and the message log times
    per topic in this and all earlier chunks."""
    with open(path, "rb") as f:
        summary = make_reader(f).get_summary()
    index = sorted(summary.chunk_indexes, key=lambda c: c.chunk_start_offset)
    chunks = [r for r in StreamReader(str(path), emit_chunks=True).records if isinstance(r, Chunk)]
    assert len(chunks) == len(index)
    out, seen = [], {}
    for ci, chunk in zip(index, chunks):
        for r in breakup_chunk(chunk, validate_crc=True):
            if isinstance(r, Message):
                seen.setdefault(summary.channels[r.channel_id].topic, []).append(r.log_time)
        out.append((ci.chunk_start_offset, ci.chunk_start_offset + ci.chunk_length,
                    {t: list(v) for t, v in seen.items()}))
    return out


def expected_after_cut(table, cut):
    """Log times per topic of the chunks that end before ``cut``."""
    done = [times for _, end, times in table if end <= cut]
    return done[-1] if done else {}


def test_flush_makes_a_crash_readable(tmp_path):
    path = tmp_path / "f.mcap"
    copy = write_chunked(path, n=120, flush_at=60, chunk_size=10**6)  # one chunk unless flushed
    (tmp_path / "crash.mcap").write_bytes(copy)  # the file as a crash right after flush() leaves it
    bag = read_bag(tmp_path / "crash.mcap")
    assert bag.truncated and bag.truncated.startswith("cut off after 120 messages")
    assert bag.log_times["/eha/pressure"].tolist() == list(range(60))
    assert [m.fluid_pressure for m in bag.messages["/eha/pressure"]] == [float(i) for i in range(60)]
    assert [m.position for m in bag.messages["/eha/joint_states"]] == [[i * 1e-3] for i in range(60)]
    assert bag.metadata == {"run": {"n": "120"}}
    full = read_bag(path)
    assert full.truncated is None and len(full.messages["/eha/joint_states"]) == 120
    assert len(chunk_table(path)) == 2  # the flush closed the first chunk


def test_flush_survives_a_killed_writer(tmp_path):
    """A writer process killed (no close, no atexit) after flush(): everything flushed is there.

    The child also checks that the module did not import rclpy.
    """
    path = tmp_path / "killed.mcap"
    code = (
        "import os, sys\n"
        "from eha_health.io.mcaplog import BagWriter\n"
        f"w = BagWriter({str(path)!r})\n"
        "for i in range(80):\n"
        f"    w.write('/eha/pressure', {FP!r}, {{'fluid_pressure': float(i)}}, i)\n"
        "    if i == 49:\n"
        "        w.flush()\n"
        "os._exit(4 if any(m.split('.')[0] == 'rclpy' for m in sys.modules) else 3)\n")
    assert subprocess.run([sys.executable, "-c", code], timeout=60).returncode == 3
    bag = read_bag(path)
    assert bag.truncated is not None
    assert bag.log_times["/eha/pressure"].tolist() == list(range(50))


def test_truncation_at_every_offset(tmp_path):
    path = tmp_path / "t.mcap"
    write_chunked(path, n=40, flush_at=20, chunk_size=300)
    data = path.read_bytes()
    table = chunk_table(path)
    assert len(table) >= 8
    header_end = 8 + 9 + struct.unpack_from("<Q", data, 9)[0]
    meta_end = header_end + 9 + struct.unpack_from("<Q", data, header_end + 1)[0]
    assert data[header_end] == 0x0C  # the metadata record comes before the first chunk
    data_end = data.rindex(bytes([0x0F]) + struct.pack("<Q", 4), 0, len(data) - 8)  # the data end record
    special = {"a few bytes after the header": header_end + 3,
               "mid-chunk": (table[3][0] + table[3][1]) // 2,
               "right after a chunk": table[4][1],
               "after the last chunk, before the summary": data_end,
               "inside the summary": data_end + 20,
               "one byte short": len(data) - 1}
    cuts = sorted(set(range(header_end, len(data), 13)) | set(special.values()))
    for cut in cuts:
        (tmp_path / "cut.mcap").write_bytes(data[:cut])
        bag = read_bag(tmp_path / "cut.mcap")  # never raises
        want = expected_after_cut(table, cut)
        assert bag.truncated and "\n" not in bag.truncated, cut
        n = sum(map(len, want.values()))
        assert bag.truncated.startswith(f"cut off after {n} messages: "), (cut, bag.truncated)
        for topic in ("/eha/pressure", "/eha/joint_states"):
            assert bag.log_times.get(topic, np.zeros(0)).tolist() == want.get(topic, []), cut
        assert [m.fluid_pressure for m in bag.messages.get("/eha/pressure", [])] == \
            [float(t) for t in want.get("/eha/pressure", [])]
        assert bag.metadata == ({"run": {"n": "40"}} if cut >= meta_end else {})
    assert set(expected_after_cut(table, special["mid-chunk"])) == {"/eha/pressure", "/eha/joint_states"}
    assert expected_after_cut(table, special["after the last chunk, before the summary"]) == \
        {"/eha/pressure": list(range(40)), "/eha/joint_states": list(range(40))}
    assert read_bag(path).truncated is None
    (tmp_path / "cut.mcap").write_bytes(data[:special["a few bytes after the header"]])
    bag = read_bag(tmp_path / "cut.mcap")
    assert (bag.messages, bag.types) == ({}, {})
    with pytest.raises(BagError, match=r"missing topic /eha/pressure \(topics present: none\); cut off after 0"):
        bag.require("/eha/pressure")
    (tmp_path / "cut.mcap").write_bytes(data[:special["inside the summary"]])
    assert "in the summary section (the data section is complete)" in read_bag(tmp_path / "cut.mcap").truncated


# ------------------------------------------------------------------ damage

@pytest.mark.parametrize("content, match", [
    (b"", "empty file"),
    (np.random.default_rng(1).bytes(3000), r"not an MCAP file \(bad magic\)"),
    (b"time,pressure\n0,1\n", r"not an MCAP file \(bad magic\)"),
    (MAGIC[:5], "cut off inside the MCAP magic"),
    (MAGIC + b"\x01\x05", "cut off before the first record ended"),
    (MAGIC + bytes([0x05]) + struct.pack("<Q", 0), r"not a valid MCAP file \(first record is message, not a header\)"),
])
def test_not_a_bag(tmp_path, content, match):
    path = tmp_path / "x.mcap"
    path.write_bytes(content)
    with pytest.raises(BagError, match=f"^{re.escape(str(path))}: {match}"):
        read_bag(path)


def test_missing_file_and_directory(tmp_path):
    with pytest.raises(BagError, match=f"^{re.escape(str(tmp_path / 'nope.mcap'))}: no such file$"):
        read_bag(tmp_path / "nope.mcap")
    with pytest.raises(BagError, match="is a directory"):
        read_bag(tmp_path)


def test_complete_file_without_messages(tmp_path):
    with BagWriter(tmp_path / "e.mcap") as w:
        w.add_metadata("run", {})
    with pytest.raises(BagError, match="e.mcap: no messages in the file"):
        read_bag(tmp_path / "e.mcap")


def chunk_data_offsets(path):
    """(start, end) of the (compressed) records inside each chunk record."""
    data = path.read_bytes()
    out = []
    for start, _, _ in chunk_table(path):
        p = start + 9 + 8 + 8 + 8 + 4  # record header, start/end time, uncompressed size and CRC
        p += 4 + struct.unpack_from("<I", data, p)[0]  # compression name
        n = struct.unpack_from("<Q", data, p)[0]
        out.append((p + 8, p + 8 + n))
    return out


@pytest.mark.parametrize("compression, match", [("none", r"CRC mismatch"),
                                                ("zstd", r"CRC mismatch|does not decompress")])
def test_flipped_byte_in_a_chunk(tmp_path, compression, match):
    path = tmp_path / "c.mcap"
    write_chunked(path, compression=compression)
    data = path.read_bytes()
    table = chunk_table(path)
    chunks = chunk_data_offsets(path)
    # in the third chunk: the first two are kept, the damage is reported
    a, b = chunks[2]
    bad = bytearray(data)
    bad[(a + b) // 2] ^= 0x55
    (tmp_path / "bad.mcap").write_bytes(bad)
    bag = read_bag(tmp_path / "bad.mcap")
    want = table[1][2]
    assert bag.log_times["/eha/pressure"].tolist() == want["/eha/pressure"]
    assert bag.log_times["/eha/joint_states"].tolist() == want["/eha/joint_states"]
    n = sum(map(len, want.values()))
    assert bag.truncated.startswith(f"damaged after {n} messages: chunk ending at byte {table[2][1]} ")
    assert re.search(match, bag.truncated) and bag.truncated.endswith("stopped reading there")
    # in the first chunk: nothing readable, so it raises
    a, b = chunks[0]
    bad = bytearray(data)
    bad[(a + b) // 2] ^= 0x55
    (tmp_path / "bad.mcap").write_bytes(bad)
    with pytest.raises(BagError, match=f"bad.mcap: chunk ending at byte {table[0][1]} .*({match})"):
        read_bag(tmp_path / "bad.mcap")


def test_flipped_byte_outside_the_chunks_is_reported(tmp_path):
    """A message index is not covered by a chunk CRC: the data-section CRC catches it."""
    path = tmp_path / "c.mcap"
    write_chunked(path)
    data = bytearray(path.read_bytes())
    i = chunk_table(path)[0][1]  # the message indexes follow the chunk
    assert data[i] == 0x07
    data[i + 9 + 2 + 4 + 3] ^= 0x01  # inside its first timestamp
    (tmp_path / "bad.mcap").write_bytes(bytes(data))
    bag = read_bag(tmp_path / "bad.mcap")
    assert len(bag.messages["/eha/pressure"]) == 120
    assert bag.truncated.startswith("data section CRC mismatch")


def test_damaged_record_length_is_not_a_cut(tmp_path):
    """A chunk length pointing past the end of a file that has its footer: damage, not truncation."""
    path = tmp_path / "c.mcap"
    write_chunked(path)
    table = chunk_table(path)
    data = bytearray(path.read_bytes())
    data[table[2][0] + 1 + 6] ^= 0x10  # a high byte of the third chunk's record length
    (tmp_path / "bad.mcap").write_bytes(bytes(data))
    bag = read_bag(tmp_path / "bad.mcap")
    n = sum(map(len, table[1][2].values()))
    assert re.fullmatch(rf"damaged after {n} messages: chunk record at byte {table[2][0]} \(\d+ bytes\) runs "
                        rf"past the end of the file \({len(data)} bytes\), yet the file ends with a footer; "
                        "stopped reading there", bag.truncated)
    assert bag.log_times["/eha/pressure"].tolist() == table[1][2]["/eha/pressure"]


def test_summary_count_mismatch_is_reported(tmp_path):
    """A chunk whose opcode byte is damaged is skipped as unknown: the summary count catches it."""
    path = tmp_path / "c.mcap"
    with BagWriter(path, chunk_size=400) as w:
        for i in range(60):
            w.write("/eha/pressure", FP, {"fluid_pressure": float(i)}, i)
    data = bytearray(path.read_bytes())
    second = chunk_table(path)[1][0]
    assert data[second] == 0x06
    data[second] = 0x99  # a private-range opcode, which readers skip
    # no data-section CRC, to see the summary check alone (rosbag2 writes none)
    end = data.rindex(bytes([0x0F]) + struct.pack("<Q", 4), 0, len(data) - 8)
    data[end + 9:end + 13] = bytes(4)
    (tmp_path / "bad.mcap").write_bytes(bytes(data))
    bag = read_bag(tmp_path / "bad.mcap")
    assert re.fullmatch(r"summary counts 60 messages, \d+ were readable", bag.truncated)
    assert 0 < len(bag.messages["/eha/pressure"]) < 60


def test_message_that_does_not_decode(tmp_path):
    path = tmp_path / "m.mcap"
    with BagWriter(path) as w:
        w.write("/eha/joint_states", JS, {"name": ["a"]}, 1)
        w.write_raw("/eha/joint_states", JS, b"\x00\x01\x00\x00\x07", 2)  # a valid header, then junk
    with pytest.raises(BagError, match=r"m.mcap: /eha/joint_states: message 1 does not decode as "
                                       r"sensor_msgs/msg/JointState"):
        read_bag(path)
    assert len(read_bag(path, topics=["/other"]).messages) == 0  # not decoded when not asked for


# ------------------------------------------------------------------ writer errors and require

def test_writer_errors(tmp_path):
    path = tmp_path / "w.mcap"
    with BagWriter(path) as w:
        w.write("/p", FP, {"fluid_pressure": 1.0}, 1)
        with pytest.raises(BagError, match=r"w.mcap: topic /p has type sensor_msgs/msg/FluidPressure, "
                                           r"cannot write a sensor_msgs/msg/JointState"):
            w.write("/p", JS, {}, 2)
        with pytest.raises(BagError, match="cannot encode dict as sensor_msgs/msg/FluidPressure"):
            w.write("/q", FP, {"fluid_pressure": "high"}, 2)
        with pytest.raises(BagError, match="does not start with a CDR encapsulation header"):
            w.write_raw("/r", FP, b"\x01", 3)
        with pytest.raises(BagError, match="log time -1 ns is out of range"):
            w.write("/p", FP, {}, -1)
        with pytest.raises(BagError, match="message definition not found"):
            w.write("/x", "eha_msgs/msg/Nope", {}, 1)
    with pytest.raises(BagError, match="w.mcap: writer is closed"):
        w.write("/p", FP, {}, 5)
    with pytest.raises(BagError, match="unknown compression 'gzip'"):
        BagWriter(tmp_path / "z.mcap", compression="gzip")
    with pytest.raises(BagError, match="cannot create"):
        BagWriter(tmp_path / "no" / "dir" / "a.mcap")
    bag = read_bag(path)
    assert bag.truncated is None and bag.types == {"/p": FP}  # failed writes left nothing behind


def test_require(tmp_path):
    path = tmp_path / "r.mcap"
    with BagWriter(path) as w:
        w.write("/eha/pressure", FP, {"fluid_pressure": 1.0}, 1)
        w.write("/eha/joint_states", JS, {}, 1)
    bag = read_bag(path)
    bag.require("/eha/pressure", "/eha/joint_states")
    with pytest.raises(BagError, match=rf"^{re.escape(str(path))}: missing topic /eha/command "
                                       r"\(topics present: /eha/joint_states, /eha/pressure\)$"):
        bag.require("/eha/pressure", "/eha/command", "/eha/other")
    part = read_bag(path, topics=["/eha/pressure"])
    assert set(part.messages) == {"/eha/pressure"} and set(part.types) == {"/eha/pressure", "/eha/joint_states"}
    part.require("/eha/pressure")
    with pytest.raises(BagError, match="topic /eha/joint_states was not read"):
        part.require("/eha/joint_states")
