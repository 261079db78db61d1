"""MCAP logs in the ROS 2 profile, written and read without rclpy.

Files follow what rosbag2 and Foxglove expect: profile ``ros2``, schema encoding
``ros2msg`` (the .msg text, see :func:`schema_text`), message encoding ``cdr``,
zstd-compressed chunks. Only ``mcap`` and ``mcap_ros2`` are used, so batch jobs
read and write logs on machines without ROS; the .msg files needed to write come
from the installed interface packages (``share/<pkg>/msg``).

Crash safety. :meth:`BagWriter.flush` closes the open chunk and flushes the
file; a file cut off later (killed recorder, full disk) still reads up to there.
:func:`read_bag` reads such files: it keeps every complete record before the cut
and says where the file ends in :attr:`Bag.truncated`.

Damage. A chunk whose CRC or compression is broken, or a record that makes no
sense, stops the reading there: the messages before it are kept and the reason
goes to :attr:`Bag.truncated` (so the messages are always a prefix of the
recording, never a recording with holes). With nothing readable before it, the
damage raises :class:`BagError`. A complete file whose data-section or summary
checksum fails, or whose summary counts other messages than were read, is kept
and reported the same way. Problems that are not damage to the file (a message
that does not decode against its own schema, an unknown type) raise.
"""
from __future__ import annotations

import array
import functools
import io
import operator
import os
import re
import struct
import sys
import zlib
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Iterable

import numpy as np
from mcap.data_stream import ReadDataStream
from mcap.exceptions import McapError
from mcap.opcode import Opcode
from mcap.records import Channel, Chunk, DataEnd, Footer, Header, Message, Metadata, Schema, Statistics
from mcap.well_known import MessageEncoding, SchemaEncoding
from mcap.writer import LIBRARY_IDENTIFIER, CompressionType
from mcap.writer import Writer as _McapWriter
from mcap_ros2 import __version__ as _MCAP_ROS2_VERSION
from mcap_ros2.decoder import DecoderFactory
# private module, but the only encoder mcap_ros2 has outside its own Writer (which hides the
# mcap.Writer options we need); written against mcap-ros2-support 0.6.0, covered by the tests
from mcap_ros2._dynamic import serialize_dynamic

__all__ = ["Bag", "BagError", "BagWriter", "Scan", "bag_metadata", "read_bag", "scan_bag", "schema_text"]

_MAGIC = b"\x89MCAP0\r\n"
_RECORD = struct.Struct("<BQ")  # opcode, body length
_MESSAGE = struct.Struct("<HIQQ")  # message record: channel id, sequence, log time, publish time; then data
_FOOTER_LEN = _RECORD.size + 20  # footer record: opcode, length, two u64 and the summary CRC
_SEPARATOR = "=" * 80
_INNER = {Opcode.SCHEMA: Schema, Opcode.CHANNEL: Channel, Opcode.MESSAGE: Message}  # records read from chunks
_BASE_TYPES = frozenset({"bool", "byte", "char", "float32", "float64", "int8", "uint8", "int16",
                         "uint16", "int32", "uint32", "int64", "uint64", "string", "wstring"})


_LIBRARY = f"eha_health.mcaplog {LIBRARY_IDENTIFIER} mcap-ros2-support/{_MCAP_ROS2_VERSION}"


class BagError(ValueError):
    """A log that cannot be written or read; the message names the file and the problem."""


# --------------------------------------------------------------------------- schemas

def _split_type(type_name: str) -> tuple[str, str]:
    """('sensor_msgs', 'JointState') from 'sensor_msgs/msg/JointState' or 'sensor_msgs/JointState'."""
    parts = type_name.split("/") if isinstance(type_name, str) else []
    if len(parts) == 3 and parts[1] == "msg" and all(parts):
        return parts[0], parts[2]
    if len(parts) == 2 and all(parts):
        return parts[0], parts[1]
    raise BagError(f"{type_name!r}: not a ROS 2 message type (expected 'pkg/msg/Type')")


def _full_type(type_name: str) -> str:
    pkg, name = _split_type(type_name)
    return f"{pkg}/msg/{name}"


def _share_dirs(pkg: str) -> list[Path]:
    """Candidate share/<pkg> directories, ament index first."""
    dirs = []
    try:
        from ament_index_python.packages import get_package_share_directory
        dirs.append(Path(get_package_share_directory(pkg)))
    except (ImportError, LookupError, OSError, ValueError):
        pass  # no ament index (e.g. AMENT_PREFIX_PATH unset in a plain venv): search by hand
    roots = [sys.prefix, *filter(None, os.environ.get("AMENT_PREFIX_PATH", "").split(os.pathsep))]
    dirs.extend(Path(r) / "share" / pkg for r in roots)
    return list(dict.fromkeys(dirs))


@functools.lru_cache(maxsize=None)
def _msg_source(pkg: str, name: str) -> str:
    dirs = _share_dirs(pkg)
    for d in dirs:
        f = d / "msg" / f"{name}.msg"
        if f.is_file():
            return f.read_text(encoding="utf-8")
    raise BagError(f"{pkg}/msg/{name}: message definition not found "
                   f"(no msg/{name}.msg in {', '.join(map(str, dirs))})")


def _unquote(text: str) -> str:
    """Value of a string constant: a quoted literal, else the rest of the line (as ROS reads it)."""
    if text[:1] in "\"'":
        m = re.match(r"""(["'])((?:\\.|(?!\1).)*)\1""", text)
        if m:
            return re.sub(r"\\(.)", r"\1", m.group(2))
    return text


def _constant_value(typ: str, text: str) -> str:
    if typ.startswith("string"):
        return _unquote(text.strip())
    text = text.split("#", 1)[0].strip()
    if typ == "bool":
        return str(text.lower() in ("true", "1"))
    if typ.startswith("float"):
        return str(float(text))
    return str(int(text, 0))


@functools.lru_cache(maxsize=None)
def _definition(pkg: str, name: str) -> tuple[str, tuple[tuple[str, str], ...]]:
    """(normalized body, message types it uses) of one .msg file.

    Normalized the way rosbags' ``generate_msgdef`` prints it: no comments or
    default values, constants first, nested types as ``pkg/Type``.
    """
    constants, fields, deps = [], [], []
    for raw in _msg_source(pkg, name).splitlines():
        line = raw.strip()
        if not line or line.startswith(("#", "@")):
            continue
        typ, rest = (re.split(r"\s+", line, maxsplit=1) + [""])[:2]
        const = re.match(r"([A-Za-z][A-Za-z0-9_]*)\s*=(.*)$", rest)
        if const and typ.split("<")[0] in _BASE_TYPES:
            try:
                value = _constant_value(typ, const.group(2))
            except ValueError:
                raise BagError(f"{pkg}/msg/{name}: bad constant line {line!r}") from None
            constants.append(f"{typ} {const.group(1)}={value}")
            continue
        fname = rest.split("#", 1)[0].split()  # [name, default...]: the default is not on the wire
        m = re.fullmatch(r"([A-Za-z0-9_/]+)(<=\d+)?(\[(?:<=)?\d*\])?", typ)
        if not fname or not m:
            raise BagError(f"{pkg}/msg/{name}: cannot parse line {line!r}")
        base, bound, dims = m.group(1), m.group(2) or "", m.group(3) or ""
        if base not in _BASE_TYPES:
            if base in ("time", "duration"):  # ROS 1 spellings
                base = f"builtin_interfaces/{base.capitalize()}"
            elif base == "Header":
                base = "std_msgs/Header"
            elif "/" not in base:
                base = f"{pkg}/{base}"  # same package
            dep = _split_type(base)
            base = "/".join(dep)
            deps.append(dep)
        fields.append(f"{base}{bound}{dims} {fname[0]}")
    return "\n".join([*constants, *fields, ""]), tuple(deps)


@functools.lru_cache(maxsize=None)
def schema_text(type_name: str) -> str:
    """ros2msg schema text for a message type, e.g. ``'sensor_msgs/msg/JointState'``.

    The normalized .msg body, then for each (transitive) dependency a line of 80
    ``=``, ``MSG: pkg/Type`` and its body: the same text as rosbags'
    ``generate_msgdef(type, ros_version=2)``. Read from the installed interface
    packages (ament index, ``sys.prefix/share``, ``AMENT_PREFIX_PATH``).
    """
    root = _split_type(type_name)
    body, deps = _definition(*root)
    order: list[tuple[str, str]] = []

    def visit(deps):
        # depth first, each type once at its first use: rosbags' order
        for dep in deps:
            if dep != root and dep not in order:
                order.append(dep)
                visit(_definition(*dep)[1])

    visit(deps)
    return body + "".join(f"{_SEPARATOR}\nMSG: {p}/{n}\n{_definition(p, n)[0]}" for p, n in order)


# --------------------------------------------------------------------------- writing

def _plain(value: Any) -> Any:
    """Message value as dicts/lists the mcap_ros2 encoder takes (rclpy messages, numpy arrays)."""
    if value is None or isinstance(value, (str, bytes, bool, int, float)):
        return value
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, dict):
        return {k: _plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]  # the encoder wants lists for message arrays
    if isinstance(value, array.array):  # the encoder takes these as they are
        return value
    fields = getattr(value, "get_fields_and_field_types", None)
    if callable(fields):  # rclpy message
        out = {}
        for name, typ in fields().items():
            v = getattr(value, name)
            # rclpy gives byte (octet) fields as 1-byte bytes and byte arrays as lists of them
            if typ == "octet" and isinstance(v, bytes):
                v = v[0]
            elif typ.startswith(("sequence<octet", "octet[")) and isinstance(v, list):
                v = b"".join(v)
            out[name] = _plain(v)
        return out
    slots = getattr(type(value), "__slots__", None)
    if slots and not isinstance(slots, str):  # e.g. a message decoded by mcap_ros2
        return {s: _plain(getattr(value, s)) for s in slots if hasattr(value, s)}
    if hasattr(value, "__dict__"):
        return {k: _plain(v) for k, v in vars(value).items() if not k.startswith("_")}
    return value


def _time(path: Path, what: str, t: Any) -> int:
    try:
        t = operator.index(t)
    except TypeError:
        raise BagError(f"{path}: {what} must be an integer in ns, got {type(t).__name__}") from None
    if not 0 <= t < 2**64:
        raise BagError(f"{path}: {what} {t} ns is out of range (0 .. 2**64-1)")
    return t


class BagWriter:
    """Write a ros2-profile MCAP: schema encoding 'ros2msg', message encoding 'cdr', zstd chunks.

    Channels and schemas are registered on the first message of a topic. Use as a
    context manager, or call :meth:`close`; :meth:`flush` makes everything so far
    durable against a crash of the writer.

    Parameters
    ----------
    path : str or Path
        File to create (overwritten).
    chunk_size : int
        Uncompressed bytes per chunk before it is closed and written.
    compression : {'zstd', 'lz4', 'none'}
    profile : str
        MCAP profile in the header.
    """

    def __init__(self, path, *, chunk_size: int = 256 * 1024, compression: str = "zstd",
                 profile: str = "ros2"):
        self.path = Path(path)
        codecs = {"zstd": CompressionType.ZSTD, "lz4": CompressionType.LZ4,
                  "none": CompressionType.NONE, "": CompressionType.NONE}
        if compression not in codecs:
            raise BagError(f"{self.path}: unknown compression {compression!r} (use 'zstd', 'lz4' or 'none')")
        if not isinstance(chunk_size, int) or chunk_size <= 0:
            raise BagError(f"{self.path}: chunk_size must be a positive int, got {chunk_size!r}")
        try:
            self._file = open(self.path, "wb")
        except OSError as e:
            raise BagError(f"{self.path}: cannot create ({e.strerror})") from None
        try:
            # no summary offsets: mcap indexes empty metadata/attachment groups otherwise, which
            # `mcap doctor` flags; data CRC on so read_bag can check a complete file end to end
            self._w: _McapWriter | None = _McapWriter(
                self._file, chunk_size=chunk_size, compression=codecs[compression],
                use_summary_offsets=False, enable_data_crcs=True)
        except McapError as e:
            self._file.close()
            raise BagError(f"{self.path}: {e}") from None
        self._w.start(profile=profile, library=_LIBRARY)
        self._file.flush()  # the header is on disk: a file killed from now on is readable
        self._schemas: dict[str, int] = {}
        self._channels: dict[str, tuple[int, str]] = {}
        self._encoders: dict[str, Callable[[Any], bytes]] = {}

    def _writer(self) -> _McapWriter:
        if self._w is None:
            raise BagError(f"{self.path}: writer is closed")
        return self._w

    def _type(self, type_name: str) -> str:
        """'pkg/msg/Type', checked to have a definition (errors name this file)."""
        try:
            type_name = _full_type(type_name)
            schema_text(type_name)
        except BagError as e:
            raise BagError(f"{self.path}: {e}") from None
        return type_name

    def _channel(self, topic: str, type_name: str) -> int:
        known = self._channels.get(topic)
        if known is not None:
            if known[1] != type_name:
                raise BagError(f"{self.path}: topic {topic} has type {known[1]}, cannot write a {type_name} to it")
            return known[0]
        if not isinstance(topic, str) or not topic:
            raise BagError(f"{self.path}: topic must be a non-empty string, got {topic!r}")
        w = self._writer()
        if type_name not in self._schemas:
            self._schemas[type_name] = w.register_schema(
                type_name, SchemaEncoding.ROS2, schema_text(type_name).encode())
        cid = w.register_channel(topic, MessageEncoding.CDR, self._schemas[type_name])
        self._channels[topic] = (cid, type_name)
        return cid

    def _add(self, topic, type_name, data, log_time_ns, publish_time_ns) -> None:
        log_time = _time(self.path, "log time", log_time_ns)
        pub_time = log_time if publish_time_ns is None else _time(self.path, "publish time", publish_time_ns)
        cid = self._channel(topic, type_name)
        self._writer().add_message(cid, log_time=log_time, data=data, publish_time=pub_time)

    def add_metadata(self, name: str, data: dict[str, str]) -> None:
        """Write an MCAP metadata record (string keys and values)."""
        if not isinstance(name, str) or not all(isinstance(k, str) and isinstance(v, str)
                                                for k, v in dict(data).items()):
            raise BagError(f"{self.path}: metadata {name!r} must be a str name and str -> str items")
        self._writer().add_metadata(name, dict(data))

    def write_raw(self, topic: str, type_name: str, data: bytes, log_time_ns: int,
                  publish_time_ns: int | None = None) -> None:
        """Write one message given as CDR bytes exactly as on the wire.

        E.g. from an rclpy subscription created with ``raw=True``. Bytes from
        ``rclpy.serialization.serialize_message`` carry padding that rosbags rejects.
        """
        self._writer()
        type_name = self._type(type_name)
        try:
            data = bytes(data)
        except TypeError:
            raise BagError(f"{self.path}: {topic}: raw data must be bytes, got {type(data).__name__}") from None
        # encapsulation header 00 00 (CDR big endian) or 00 01 (little endian), then options
        if len(data) < 4 or data[0] != 0 or data[1] not in (0, 1):
            raise BagError(f"{self.path}: {topic}: raw data ({len(data)} bytes) does not start "
                           "with a CDR encapsulation header")
        self._add(topic, type_name, data, log_time_ns, publish_time_ns)

    def write(self, topic: str, type_name: str, msg: Any, log_time_ns: int,
              publish_time_ns: int | None = None) -> None:
        """Encode ``msg`` with mcap_ros2's CDR encoder and write it.

        ``msg`` is an rclpy message, a dict, or any object with the field
        attributes; numpy arrays are accepted. In dicts, give ``byte`` fields as
        ints. Missing fields are written as zero/empty.
        """
        self._writer()
        type_name = self._type(type_name)
        encoder = self._encoders.get(type_name)
        if encoder is None:
            encoder = serialize_dynamic(type_name, schema_text(type_name))[type_name]
            self._encoders[type_name] = encoder
        try:
            data = encoder(_plain(msg))
        except Exception as e:  # the encoder raises ValueError, TypeError, struct.error, ...
            raise BagError(f"{self.path}: {topic}: cannot encode {type(msg).__name__} as {type_name} "
                           f"({type(e).__name__}: {e})") from e
        self._add(topic, type_name, data, log_time_ns, publish_time_ns)

    def flush(self, *, fsync: bool = False) -> None:
        """Close the open chunk and flush the file.

        Everything written so far survives a crash of this process: a file cut off
        after this point reads up to here. Uses the public ``mcap.writer.Writer.flush``
        (no private API). ``fsync=True`` also survives a crash of the machine.
        """
        w = self._writer()
        if not hasattr(w, "flush"):
            raise BagError(f"{self.path}: flush() needs mcap.writer.Writer.flush (mcap 1.6.0 has it)")
        w.flush()
        if fsync:
            os.fsync(self._file.fileno())

    def close(self) -> None:
        """Write the summary and close the file; idempotent."""
        if self._w is None:
            return
        w, self._w = self._w, None
        try:
            w.finish()
        finally:
            self._file.close()

    def __enter__(self) -> BagWriter:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


# --------------------------------------------------------------------------- reading

@dataclass
class Bag:
    """The messages of one MCAP log, decoded.

    Attributes
    ----------
    path : Path
    messages : dict
        Topic -> decoded messages (attribute access: ``msg.header.stamp.sec``,
        ``msg.position``; arrays are lists; ``bytes`` for uint8/byte arrays), in
        file order; CDR bytes if read with ``raw=True``. Only the topics read.
    log_times : dict
        Topic -> int64 log times [ns], same order as ``messages``.
    types : dict
        Topic -> type (``'sensor_msgs/msg/JointState'``), for every topic in the file.
    metadata : dict
        Metadata record name -> key/value strings (a later record of the same name wins).
    truncated : str or None
        None if the file is complete and intact, else a one-line reason: where it
        was cut off, or the damage that stopped the reading.
    """

    path: Path
    messages: dict[str, list]
    log_times: dict[str, np.ndarray]
    types: dict[str, str]
    metadata: dict[str, dict[str, str]]
    truncated: str | None = None

    def require(self, *topics: str) -> None:
        """Raise BagError for the first topic that has no messages here."""
        for t in topics:
            why = f"; {self.truncated}" if self.truncated else ""
            if t not in self.types:
                present = ", ".join(sorted(self.types)) or "none"
                raise BagError(f"{self.path}: missing topic {t} (topics present: {present}){why}")
            if t not in self.messages:
                raise BagError(f"{self.path}: topic {t} was not read (not in read_bag's topics)")
            if not self.messages[t]:
                raise BagError(f"{self.path}: topic {t} has no messages{why}")


class _Strict(io.BytesIO):
    """A record body: reading past its end raises instead of returning short data."""

    def read(self, n: int | None = -1) -> bytes:
        data = super().read(n)
        if n is not None and n >= 0 and len(data) != n:
            raise EOFError(f"record ends {n - len(data)} bytes early")
        return data


def _parse(record_type, body: bytes, *args):
    stream = ReadDataStream(_Strict(body))
    record = record_type.read(stream, *args)
    if stream.count != len(body) and record_type is not Chunk:
        raise EOFError(f"{len(body) - stream.count} stray bytes at the end")
    return record


class _Damage(Exception):
    """Bytes that are all there but make no sense: reading stops before them."""


class _Cut(Exception):
    """The file ends inside the record that starts here."""


def _opname(op: int) -> str:
    try:
        return Opcode(op).name.lower().replace("_", " ")
    except ValueError:
        return f"opcode 0x{op:02x}"


class _Reader:
    def __init__(self, path: Path, f, size: int, topics: set[str] | None, raw: bool, keep: bool = False):
        self.path, self.f, self.size, self.topics, self.raw = path, f, size, topics, raw
        # keep: also note each kept message's channel and place in the file, so that
        # Scan.decode can decode later exactly as a decoding read would have
        self.keep = keep
        self.chans: dict[str, list[int]] = {}
        self.order: dict[str, list[int]] = {}
        self.pos = 0
        self.crc = 0
        self.schemas: dict[int, Schema] = {}
        self.channels: dict[int, Channel] = {}
        self.decoders: dict[int, Callable[[bytes], Any]] = {}
        self.factory = DecoderFactory()
        self.n = 0  # message records read, all topics
        self.messages: dict[str, list] = {}
        self.times: dict[str, list[int]] = {}
        self.types: dict[str, str] = {}
        self.metadata: dict[str, dict[str, str]] = {}

    def next_record(self) -> tuple[int, bytes]:
        """(opcode, body) of the record at self.pos; _Cut if the file ends inside it."""
        head = self.f.read(_RECORD.size)
        if len(head) < _RECORD.size:
            if not head:
                raise _Cut(f"file ends at byte {self.pos} before the end of the data section")
            raise _Cut(f"file ends at byte {self.size} inside a record header at byte {self.pos}")
        op, length = _RECORD.unpack(head)
        if self.pos + _RECORD.size + length > self.size:
            raise _Cut(f"{_opname(op)} record at byte {self.pos} ({length} bytes) runs past the "
                       f"end of the file ({self.size} bytes)")
        body = self.f.read(length)
        self.crc = zlib.crc32(body, zlib.crc32(head, self.crc))
        self.pos += _RECORD.size + length
        return op, body

    def run(self) -> Bag:
        magic = self.f.read(len(_MAGIC))
        if magic != _MAGIC:
            if len(magic) < len(_MAGIC) and _MAGIC.startswith(magic):
                raise BagError(f"{self.path}: cut off inside the MCAP magic ({self.size} bytes)")
            raise BagError(f"{self.path}: not an MCAP file (bad magic)")
        self.pos, self.crc = len(_MAGIC), zlib.crc32(magic)
        try:
            op, body = self.next_record()
        except _Cut as e:
            raise BagError(f"{self.path}: cut off before the first record ended ({e})") from None
        if op != Opcode.HEADER:
            raise BagError(f"{self.path}: not a valid MCAP file (first record is {_opname(op)}, not a header)")
        try:
            _parse(Header, body)
        except Exception as e:
            raise BagError(f"{self.path}: unreadable MCAP header ({e})") from None

        try:
            problem = self.data_section()
        except _Cut as e:
            if self.footer_at() is None:
                problem = f"cut off after {self.n} messages: {e}"
            else:  # the end of the file is there: a record length is wrong
                problem = self.damaged(f"{e}, yet the file ends with a footer")
        except _Damage as e:
            problem = self.damaged(str(e))
        if self.n == 0 and problem is None:
            raise BagError(f"{self.path}: no messages in the file")
        return Bag(self.path, self.messages,
                   {t: np.asarray(v, dtype=np.int64) for t, v in self.times.items()},
                   self.types, self.metadata, problem)

    def damaged(self, reason: str) -> str:
        """The reason to report for damage, which raises if nothing before it was readable."""
        if self.n == 0:
            raise BagError(f"{self.path}: {reason}")
        return f"damaged after {self.n} messages: {reason}; stopped reading there"

    def data_section(self) -> str | None:
        """Read up to the data end record, then check the summary; a problem, or None."""
        while True:
            start, crc = self.pos, self.crc
            op, body = self.next_record()
            if op == Opcode.FOOTER:
                raise _Damage(f"footer at byte {start} without a data end record")
            try:
                if op == Opcode.DATA_END:
                    end = _parse(DataEnd, body)
                    break
                self.record(op, body)
            except (_Damage, BagError):
                raise
            except Exception as e:  # struct/EOF/unicode errors from a malformed record body
                raise _Damage(f"{_opname(op)} record at byte {start} is unreadable "
                              f"({type(e).__name__}: {e})") from None
        if end.data_section_crc not in (0, crc):
            return f"data section CRC mismatch (all {self.n} messages kept, some may be wrong)"
        try:
            return self.summary()
        except Exception as e:
            return f"unreadable summary section ({type(e).__name__}: {e}; all {self.n} messages read)"

    def footer_at(self) -> int | None:
        """Offset of the footer record if the file ends with one and the magic, else None."""
        at = self.size - len(_MAGIC) - _FOOTER_LEN
        if at < len(_MAGIC):
            return None
        self.f.seek(at)
        tail = self.f.read()
        op, length = _RECORD.unpack_from(tail)
        ok = tail[-len(_MAGIC):] == _MAGIC and op == Opcode.FOOTER and length == _FOOTER_LEN - _RECORD.size
        return at if ok else None

    def summary(self) -> str | None:
        """Check the footer, the summary CRC and the message count in the statistics."""
        footer_at = self.footer_at()
        if footer_at is None or footer_at < self.pos:
            return (f"cut off after {self.n} messages: file ends at byte {self.size} in the summary "
                    "section (the data section is complete)")
        self.f.seek(footer_at + _RECORD.size)
        footer = _parse(Footer, self.f.read(_FOOTER_LEN - _RECORD.size))
        start = footer.summary_start or footer_at
        if not self.pos <= start <= footer_at:
            return f"footer points outside the summary section (all {self.n} messages read)"
        self.f.seek(start)
        summary = self.f.read(footer_at + _FOOTER_LEN - 4 - start)
        if footer.summary_crc not in (0, zlib.crc32(summary)):
            return f"summary section CRC mismatch (all {self.n} messages of the data section read)"
        i, body_end = 0, footer_at - start
        while i + _RECORD.size <= body_end:
            op, length = _RECORD.unpack_from(summary, i)
            if op == Opcode.STATISTICS:
                stats = _parse(Statistics, summary[i + _RECORD.size:i + _RECORD.size + length])
                if stats.message_count != self.n:
                    return f"summary counts {stats.message_count} messages, {self.n} were readable"
            i += _RECORD.size + length
        return None

    def record(self, op: int, body: bytes) -> None:
        if op == Opcode.CHUNK:
            for rec in self.chunk(_parse(Chunk, body)):
                self.apply(rec)
        elif op in _INNER:
            self.apply(self.inner([(op, body)])[0])
        elif op == Opcode.METADATA:
            meta = _parse(Metadata, body)
            self.metadata[meta.name] = dict(meta.metadata)
        elif op == 0:
            raise _Damage(f"invalid opcode 0x00 at byte {self.pos - len(body) - _RECORD.size}")
        # anything else (indexes, attachments, private records) is not needed here

    def chunk(self, chunk: Chunk) -> list[Schema | Channel | Message]:
        """The schema, channel and message records of a chunk, checked before any is used."""
        where = f"chunk ending at byte {self.pos}"
        try:
            if chunk.compression == "zstd":
                import zstandard
                data = zstandard.ZstdDecompressor().decompress(chunk.data, max_output_size=chunk.uncompressed_size)
            elif chunk.compression == "lz4":
                import lz4.frame
                data = lz4.frame.decompress(chunk.data)
            elif chunk.compression == "":
                data = chunk.data
            else:
                raise _Damage(f"{where}: unknown compression {chunk.compression!r}")
        except _Damage:
            raise
        except ImportError as e:
            raise BagError(f"{self.path}: {where}: {chunk.compression} needs {e.name}") from None
        except Exception as e:
            raise _Damage(f"{where} does not decompress ({type(e).__name__}: {e})") from None
        if len(data) != chunk.uncompressed_size:
            raise _Damage(f"{where} decompresses to {len(data)} bytes, not {chunk.uncompressed_size}")
        if chunk.uncompressed_crc not in (0, zlib.crc32(data)):
            raise _Damage(f"{where} is corrupt (CRC mismatch)")
        raw, i = [], 0
        while i < len(data):
            if i + _RECORD.size > len(data):
                raise _Damage(f"{where}: record header cut at byte {i} of {len(data)}")
            op, length = _RECORD.unpack_from(data, i)
            i += _RECORD.size
            if i + length > len(data):
                raise _Damage(f"{where}: {_opname(op)} record runs past the chunk end")
            if op in _INNER:
                raw.append((op, data[i:i + length]))
            i += length
        try:
            return self.inner(raw)
        except _Damage as e:
            raise _Damage(f"{where}: {e}") from None

    def inner(self, raw: list[tuple[int, bytes]]) -> list[Schema | Channel | Message]:
        """Parse schema, channel and message records and check what they refer to, before
        any is taken in: a chunk is kept whole or not at all."""
        schemas, channels, out = set(self.schemas), set(self.channels), []
        for op, body in raw:
            try:
                if op == Opcode.MESSAGE and len(body) >= _MESSAGE.size:
                    # what Message.read makes of it, without a stream per record (the reader's
                    # hot loop); shorter bodies go through _parse for its error message
                    cid, seq, log_time, pub_time = _MESSAGE.unpack_from(body)
                    rec = Message(channel_id=cid, log_time=log_time, data=body[_MESSAGE.size:],
                                  publish_time=pub_time, sequence=seq)
                else:
                    rec = _parse(_INNER[op], body, *([len(body)] if op == Opcode.MESSAGE else []))
            except Exception as e:
                raise _Damage(f"unreadable {_opname(op)} record ({type(e).__name__}: {e})") from None
            if isinstance(rec, Schema):
                schemas.add(rec.id)
            elif isinstance(rec, Channel):
                if rec.schema_id and rec.schema_id not in schemas:
                    raise _Damage(f"channel {rec.topic} refers to unknown schema {rec.schema_id}")
                channels.add(rec.id)
            elif rec.channel_id not in channels:
                raise _Damage(f"message on unknown channel {rec.channel_id}")
            out.append(rec)
        return out

    def apply(self, rec: Schema | Channel | Message) -> None:
        """Take in a checked schema, channel or message record."""
        if isinstance(rec, Schema):
            self.schemas[rec.id] = rec
        elif isinstance(rec, Channel):
            schema = self.schemas.get(rec.schema_id)
            typ = schema.name if schema else ""
            if self.types.get(rec.topic, typ) != typ:
                raise BagError(f"{self.path}: topic {rec.topic} has two types, {self.types[rec.topic]} and {typ}")
            self.channels[rec.id] = rec
            self.types[rec.topic] = typ
            if self.topics is None or rec.topic in self.topics:
                self.messages.setdefault(rec.topic, [])
                self.times.setdefault(rec.topic, [])
                if self.keep:
                    self.chans.setdefault(rec.topic, [])
                    self.order.setdefault(rec.topic, [])
        else:
            self.n += 1
            ch = self.channels[rec.channel_id]
            if ch.topic not in self.messages:
                return
            if self.raw:
                self.messages[ch.topic].append(rec.data)
                self.times[ch.topic].append(rec.log_time)
                if self.keep:
                    self.chans[ch.topic].append(ch.id)
                    self.order[ch.topic].append(self.n)
            else:
                self.decode(ch, rec.data, rec.log_time, self.messages[ch.topic], self.times[ch.topic])

    def decoder(self, ch: Channel) -> Callable[[bytes], Any]:
        """mcap_ros2's decoder of a channel's messages (BagError if its schema is unusable)."""
        decoder = self.decoders.get(ch.id)
        typ = self.types[ch.topic]
        if decoder is None:
            schema = self.schemas.get(ch.schema_id)
            try:
                decoder = self.factory.decoder_for(ch.message_encoding, schema)
            except Exception as e:
                raise BagError(f"{self.path}: {ch.topic}: cannot use the schema of {typ} "
                               f"({type(e).__name__}: {e})") from None
            if decoder is None:
                enc = schema.encoding if schema else "no schema"
                raise BagError(f"{self.path}: {ch.topic}: cannot decode {ch.message_encoding!r} "
                               f"messages with {enc!r} (need 'cdr' and 'ros2msg')")
            self.decoders[ch.id] = decoder
        return decoder

    def decode(self, ch: Channel, data: bytes, log_time: int, out: list, times: list) -> None:
        """Decode one message of ``ch`` onto ``out`` (its log time onto ``times``)."""
        decoder = self.decoder(ch)
        try:
            out.append(decoder(data))
        except Exception as e:
            raise BagError(f"{self.path}: {ch.topic}: message {len(out)} does not decode as "
                           f"{self.types[ch.topic]} ({type(e).__name__}: {e})") from None
        times.append(log_time)


def bag_metadata(path) -> dict[str, dict[str, str]]:
    """The metadata records of an MCAP log (name -> key/value strings, a later record wins).

    Read through the summary's metadata index (a fraction of a millisecond) so a batch client
    can plan thousands of bags; a file without a usable summary (cut off, damaged) is read
    with :func:`read_bag` instead, which also names what is wrong with it.
    """
    from mcap.reader import make_reader
    try:
        with open(path, "rb") as f:
            reader = make_reader(f)
            if reader.get_summary() is not None:
                return {m.name: dict(m.metadata) for m in reader.iter_metadata()}
    except (McapError, OSError, ValueError, struct.error):
        pass
    return read_bag(path, topics=[]).metadata


def read_bag(path, topics: Iterable[str] | None = None, *, raw: bool = False) -> Bag:
    """Read and decode every message of an MCAP log, or only those of ``topics``.

    Decoding uses mcap_ros2 and the schemas in the file (no rclpy, no .msg files);
    with ``raw=True`` the messages are the CDR bytes as stored, not decoded.
    A file cut off after its header is read up to the last complete record and
    :attr:`Bag.truncated` says where it ends; so is a file damaged after some
    readable messages (see the module docstring).

    Raises
    ------
    BagError
        Missing, empty or non-MCAP file; damage before any readable message; a
        complete file with no messages; a message that does not decode.
    """
    if isinstance(topics, str):
        topics = [topics]
    return _read(Path(path), None if topics is None else set(topics), raw)[1]


def _read(path: Path, topics: set[str] | None, raw: bool, keep: bool = False) -> tuple[_Reader, Bag]:
    try:
        size = path.stat().st_size
        if path.is_dir():
            raise BagError(f"{path}: is a directory, not an MCAP file")
        f = open(path, "rb")
    except FileNotFoundError:
        raise BagError(f"{path}: no such file") from None
    except OSError as e:
        raise BagError(f"{path}: cannot open ({e.strerror})") from None
    if size == 0:
        f.close()
        raise BagError(f"{path}: empty file")
    with f:
        reader = _Reader(path, f, size, topics, raw, keep)
        return reader, reader.run()


class Scan:
    """One pass over an MCAP log: every topic's CDR bytes, decoded when asked.

    ``scan_bag(p).bag`` is ``read_bag(p, raw=True)``; ``scan.decode(topics)`` is what
    ``read_bag(p, topics)`` would have returned, raising the same error for the same first
    bad message, without a second pass over the file.
    """

    def __init__(self, reader: _Reader, bag: Bag):
        self._r, self.bag = reader, bag

    def channel(self, topic: str) -> tuple[Channel, Schema | None] | None:
        """The one channel (and its schema) all of ``topic``'s messages came on; None if several."""
        ids = self._r.chans.get(topic)
        if not ids or ids.count(ids[0]) != len(ids):
            return None
        ch = self._r.channels[ids[0]]
        return ch, self._r.schemas.get(ch.schema_id)

    def decoder(self, topic: str) -> Callable[[bytes], Any]:
        """mcap_ros2's decoder of ``topic`` (which :meth:`channel` found on one channel)."""
        found = self.channel(topic)
        if found is None:
            raise BagError(f"{self.bag.path}: {topic}: messages on several channels")
        return self._r.decoder(found[0])

    def decode(self, topics: Iterable[str]) -> Bag:
        """The bag with ``topics`` decoded, in file order across topics (so the first message that
        does not decode raises as in :func:`read_bag`); other topics are left out."""
        r, bag = self._r, self.bag
        want = [t for t in dict.fromkeys(topics) if t in bag.messages]
        messages: dict[str, list] = {t: [] for t in want}
        times: dict[str, list[int]] = {t: [] for t in want}
        for _, t, k in sorted((i, t, k) for t in want for k, i in enumerate(r.order[t])):
            r.decode(r.channels[r.chans[t][k]], bag.messages[t][k], int(bag.log_times[t][k]),
                     messages[t], times[t])
        return Bag(bag.path, messages, {t: np.asarray(v, dtype=np.int64) for t, v in times.items()},
                   bag.types, bag.metadata, bag.truncated)


def scan_bag(path) -> Scan:
    """Read an MCAP log once, keeping every message's CDR bytes (see :class:`Scan`).

    Raises the :class:`BagError` that ``read_bag(path, raw=True)`` raises.
    """
    return Scan(*_read(Path(path), None, raw=True, keep=True))
