"""Property-based fuzzing (hypothesis) of everything that reads untrusted input (``eha-health bench fuzz``).

Each target generates inputs nobody wrote on purpose and feeds them to the real reader:

* ``mcap``: a small valid monitor log, cut at any byte, with bits flipped inside its chunks,
  with a length field overwritten by an absurd value; plus logs with wrong schemas.
* ``importer``: channel maps (columns, units, scales, keys) and the delimited text they read.
* ``csv``: the Response CSV format, damaged (cut, characters replaced, headers shuffled).
* ``history``: HISTORY.csv rows (values, columns, order; and trends as diagnoses make them, with
  noise, failed diagnoses and unrecorded repairs; and MAINTENANCE.csv rows beside valid ones) read and imported into a real SQLite
  store, and what was taken in prognosed (ordered RUL quantiles, p_fail_next in [0, 1], or a
  reason); a damaged store file opened.
* ``messages``: node inputs (NaN / inf, wrong array sizes, stamps out of order, bad marks)
  through the real monitor and plant node callbacks (CDR bytes, as DDS delivers them).

Property: every input is handled or refused with the reader's documented error (``BagError``,
``ImportError_``, ``ValueError``, ``PrognosticsError``; one line); never another exception, a
case slower than :data:`DEADLINE_MS`, or one case raising peak memory by more than
:data:`MAX_CASE_RSS_MB` (the run's whole peak growth, hypothesis's own bookkeeping included,
is printed too). A
failing case prints the seed and the target to replay it
(``eha-health bench fuzz --target T --seed S``). hypothesis is the test extra's.
"""
from __future__ import annotations

import math
import resource
import struct
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

#: A case taking longer than this is a hang [ms].
DEADLINE_MS = 5000
#: Largest rise of the process's peak resident memory one case may cause [MB] (a blow-up).
MAX_CASE_RSS_MB = 200.0


@dataclass
class Tally:
    """What one target's cases came to."""
    cases: int = 0
    handled: int = 0            # read / taken in
    refused: int = 0            # the documented error
    slowest_s: float = 0.0
    case_rss_mb: float = 0.0    # largest rise of peak RSS in one case
    reasons: dict = field(default_factory=dict)   # first words of refusals -> count

    def refuse(self, e: Exception, allowed: tuple) -> None:
        if not isinstance(e, allowed):
            raise AssertionError(f"undocumented {type(e).__name__}: {e}") from e
        msg = str(e)
        if not msg.strip() or "\n" in msg.strip() or "Traceback" in msg:
            raise AssertionError(f"refusal is not one line: {msg!r}") from e
        self.refused += 1
        key = " ".join(msg.split(": ")[-1].split()[:3])
        self.reasons[key] = self.reasons.get(key, 0) + 1


def _one_line(text: str) -> bool:
    return bool(text.strip()) and "\n" not in text.strip()


# ----------------------------------------------------------------------------- mcap
class McapTarget:
    """Mutations of a small valid log written by the monitor's own writer."""
    name = "mcap"

    def __init__(self, tmp: Path):
        from msg_bridge import contract as C
        from msg_bridge import convert as cv

        from ..io.mcaplog import BagWriter, read_bag
        self.tmp, self.read_bag = tmp, read_bag
        path = tmp / "base.mcap"
        with BagWriter(path, chunk_size=4096) as w:
            w.add_metadata("eha_health", {"actuator_id": "eha"})
            for i in range(300):
                ns = 1_000_000 * i
                w.write("/eha/command", C.COMMAND.type, cv.command_msg(ns, 1e-3 * math.sin(i / 20), "eha"), ns)
                w.write("/eha/pressure", C.PRESSURE.type, cv.pressure_msg(ns, 1e5 * math.cos(i / 30), "eha"), ns + 1)
                if i % 100 == 0:
                    w.flush()
        self.base = path.read_bytes()
        ok = read_bag(path, raw=True)
        assert ok.truncated is None, ok.truncated
        self.raw = ok.messages
        self.records = self._record_offsets()

    def _record_offsets(self) -> list[int]:
        """Byte offsets of the record length fields of the data section (for absurd lengths)."""
        out, i = [], 8
        while i + 9 <= len(self.base):
            op, length = struct.unpack_from("<BQ", self.base, i)
            out.append(i + 1)
            if op == 0x0F or length > len(self.base):    # data end
                break
            if op == 0x06:                                 # chunk: its uncompressed size and records length
                out += [i + 9 + 16, i + 9 + 16 + 8 + 4]
            i += 9 + length
        return out

    def strategy(self):
        from hypothesis import strategies as st
        n = len(self.base)
        cut = st.tuples(st.just("cut"), st.integers(0, n - 1))
        flips = st.tuples(st.just("flip"), st.lists(st.tuples(st.integers(8, n - 1), st.integers(0, 7)),
                                                    min_size=1, max_size=8))
        absurd = st.tuples(st.just("length"), st.tuples(
            st.sampled_from(self.records),
            st.one_of(st.sampled_from([0, 1, 2**31, 2**32 - 1, 2**62, 2**63 - 1, 2**64 - 1]),
                      st.integers(0, 2**64 - 1))))
        schema = st.tuples(st.just("schema"), st.tuples(
            st.sampled_from(["ros2msg", "ros2idl", "jsonschema", "protobuf", ""]),
            st.sampled_from(["sensor_msgs/msg/JointState", "std_msgs/msg/Header", "no/such/Type", "", "x" * 300]),
            st.one_of(st.binary(max_size=200), st.sampled_from([
                b"float64 x", b"int32[] data\n", b"string s\n" + b"=" * 80 + b"\nMSG: a/b\nint8 y",
                b"builtin_interfaces/Time stamp", b"uint8[999999999999] big"])),
            st.sampled_from(["cdr", "json", "", "ros1"]),
            st.lists(st.binary(max_size=64), min_size=1, max_size=5),
            st.booleans()))
        return st.one_of(cut, flips, absurd, schema)

    def check(self, case, tally: Tally) -> None:
        from ..io.mcaplog import BagError
        kind, arg = case
        path = self.tmp / "case.mcap"
        if kind == "schema":
            self._write_schema_case(path, *arg)
        else:
            data = bytearray(self.base)
            if kind == "cut":
                data = data[:arg]
            elif kind == "flip":
                for pos, bit in arg:
                    data[pos] ^= 1 << bit
            else:
                pos, value = arg
                data[pos:pos + 8] = struct.pack("<Q", value)
            path.write_bytes(bytes(data))
        try:
            bag = self.read_bag(path, raw=(kind == "cut"))
        except BagError as e:
            return tally.refuse(e, (BagError,))
        if bag.truncated is not None and not _one_line(bag.truncated):
            raise AssertionError(f"truncation reason is not one line: {bag.truncated!r}")
        if kind == "cut":   # a cut file keeps a prefix of the recording, never a message with holes
            for topic, msgs in bag.messages.items():
                if msgs != self.raw[topic][:len(msgs)]:
                    raise AssertionError(f"{topic}: the messages read are not a prefix of those written")
        tally.handled += 1

    def _write_schema_case(self, path, encoding, name, text, msg_encoding, payloads, chunked) -> None:
        from mcap.writer import CompressionType, Writer
        with open(path, "wb") as f:
            w = Writer(f, compression=CompressionType.ZSTD if chunked else CompressionType.NONE,
                       use_chunking=chunked)
            w.start(profile="ros2", library="fuzz")
            sid = w.register_schema(name=name, encoding=encoding, data=text)
            cid = w.register_channel(topic="/eha/command", message_encoding=msg_encoding, schema_id=sid)
            for i, p in enumerate(payloads):
                w.add_message(channel_id=cid, log_time=i, data=p, publish_time=i)
            w.finish()


# ----------------------------------------------------------------------------- importer
class ImporterTarget:
    """Channel maps and the text they read, well-formed or not."""
    name = "importer"

    def __init__(self, tmp: Path):
        self.tmp = tmp

    def strategy(self):
        from hypothesis import strategies as st

        from ..io.importer import CHANNELS, UNITS
        units = sorted({u for _, tab in UNITS.values() for u in tab}) + ["", "furlong", "MM"]
        number = st.one_of(st.floats(allow_nan=True, allow_infinity=True), st.integers(-5, 5),
                           st.sampled_from([True, "3", None]))
        column = st.one_of(st.integers(-2, 6), st.sampled_from(["a", "pos", "cmd", "", True]))
        spec = st.fixed_dictionaries({"column": column}, optional={
            "unit": st.sampled_from(units), "scale": number, "offset": number})
        chans = st.dictionaries(st.sampled_from(list(CHANNELS) + ["torque"]), spec, max_size=5)
        top = st.fixed_dictionaries({"channels": st.one_of(chans, st.just("x"))}, optional={
            "delimiter": st.sampled_from([",", ";", "\t", "", "ab"]), "skip_rows": st.one_of(st.integers(-1, 3), number),
            "header_row": st.one_of(st.integers(-1, 2), number), "sample_rate": number,
            "time": spec, "extra": st.just(1)})
        cell = st.one_of(st.floats(allow_nan=True, allow_infinity=True).map(repr), st.integers(-9, 9).map(str),
                         st.sampled_from(["", "abc", "1e999", "-0", " 2 "]))
        rows = st.lists(st.lists(cell, min_size=0, max_size=7), min_size=0, max_size=130)
        good_rows = st.integers(100, 130).flatmap(
            lambda n: st.lists(st.lists(st.floats(-1e3, 1e3).map(repr), min_size=5, max_size=5), min_size=n, max_size=n))
        header = st.sampled_from(["", "t,cmd,pos,a,b", "cmd;pos"])
        text = st.one_of(st.text(max_size=300), st.binary(max_size=300).map(lambda b: b.decode("latin-1")))
        good_spec = st.fixed_dictionaries({"column": st.integers(0, 4), "unit": st.sampled_from(["m", "mm", "in"])},
                                          optional={"scale": st.floats(-1e3, 1e3), "offset": st.floats(-1e3, 1e3)})
        good = st.fixed_dictionaries({"sample_rate": st.floats(1.0, 1e5),
                                      "channels": st.fixed_dictionaries({"command": good_spec, "position": good_spec})},
                                     optional={"skip_rows": st.integers(0, 2), "description": st.text(max_size=20)})
        return st.one_of(st.tuples(st.one_of(top, good, text.map(lambda t: ("raw", t))), header, st.one_of(rows, good_rows)),
                         st.tuples(good, st.just(""), good_rows))

    def check(self, case, tally: Tally) -> None:
        import yaml

        from ..io.importer import ImportError_, import_text
        m, header, rows = case
        mp, dp = self.tmp / "map.yaml", self.tmp / "data.csv"
        mp.write_text(m[1] if isinstance(m, tuple) else yaml.safe_dump(m))
        dp.write_text(header + "\n" + "\n".join(",".join(r) for r in rows))
        try:
            r = import_text(dp, mp)
        except ImportError_ as e:
            return tally.refuse(e, (ImportError_,))
        n = len(r.t)
        if not (n >= 100 and np.isfinite(r.command).all() and np.isfinite(r.position).all() and len(r.position) == n):
            raise AssertionError(f"imported record not as documented: {n} samples, non-finite required channel")
        tally.handled += 1


# ----------------------------------------------------------------------------- response csv
class CsvTarget:
    """The Response CSV format, damaged."""
    name = "csv"

    def __init__(self, tmp: Path):
        from ..signals.response import CSV_COLUMNS, Response
        self.tmp = tmp
        t = np.arange(40) / 1000.0
        r = Response(t=t, command=np.sin(t), position=np.sin(t), velocity=np.cos(t), pressure=1e5 * t,
                     current=1e-3 * t, spool=0 * t)
        r.to_csv(tmp / "base.csv")
        self.base = (tmp / "base.csv").read_text()
        self.columns = CSV_COLUMNS

    def strategy(self):
        from hypothesis import strategies as st
        n = len(self.base)
        cut = st.tuples(st.just("cut"), st.integers(0, n))
        edit = st.tuples(st.just("edit"), st.lists(st.tuples(st.integers(0, n - 1), st.sampled_from(
            list(",\n-.e0x ") + ["nan", "inf", "\x00", "\xff", ",,", "1e999"])), min_size=1, max_size=10))
        header = st.tuples(st.just("header"), st.permutations(list(self.columns) + ["load"]).map(lambda c: c[:7]))
        garbage = st.tuples(st.just("bytes"), st.binary(max_size=400))
        digits = [i for i, c in enumerate(self.base) if c.isdigit() and i > self.base.index("\n")]
        digit = st.tuples(st.just("edit"), st.lists(st.tuples(st.sampled_from(digits), st.sampled_from("0123456789")),
                                                     min_size=1, max_size=10))
        return st.one_of(cut, edit, header, garbage, digit)

    def check(self, case, tally: Tally) -> None:
        from ..signals.response import Response
        kind, arg = case
        path = self.tmp / "case.csv"
        if kind == "bytes":
            path.write_bytes(arg)
        else:
            text = self.base
            if kind == "cut":
                text = text[:arg]
            elif kind == "edit":
                for pos, s in arg:
                    text = text[:pos] + s + text[pos + 1:]
            else:
                text = ",".join(arg) + "\n" + text.split("\n", 1)[1]
            path.write_text(text, errors="surrogateescape")
        try:
            r = Response.from_csv(path)
        except ValueError as e:
            return tally.refuse(e, (ValueError,))
        if not (len(r.t) >= 2 and (np.diff(r.t) > 0).all() and np.isfinite(r.command).all()):
            raise AssertionError("a CSV was read into a Response that breaks its documented form")
        tally.handled += 1


# ----------------------------------------------------------------------------- history
class HistoryTarget:
    """HISTORY.csv rows into a real SQLite store; damaged store files."""
    name = "history"

    def __init__(self, tmp: Path):
        from ..prognostics.store import HistoryStore
        self.tmp = tmp
        self.db = tmp / "history.sqlite"
        with HistoryStore(self.db):
            pass
        self.db_bytes = self.db.read_bytes()

    def strategy(self):
        from hypothesis import strategies as st
        num = st.one_of(st.floats(-0.5, 2.0), st.floats(allow_nan=True, allow_infinity=True),
                        st.sampled_from(["", "x", "1e999", "-0"]))
        cols = ["actuator_id", "time_h", "k_gm", "k_fsj", "k_bkl", "std_gm", "std_fsj", "std_bkl", "usage"]
        header = st.one_of(st.just(cols), st.lists(st.sampled_from(cols + ["bogus"]), min_size=0, max_size=9))
        row = st.lists(st.one_of(num.map(str), st.sampled_from(["A1", "", "B2", "a,b", '"q"'])), min_size=0, max_size=10)
        rows = st.lists(row, max_size=20)
        valid = st.lists(st.tuples(st.sampled_from(["A1", "B2"]), st.floats(0, 1e4), st.floats(0, 1.5),
                                   st.floats(0, 1.5), st.floats(0, 1.5)), max_size=20)
        flips = st.lists(st.tuples(st.integers(0, len(self.db_bytes) - 1), st.integers(0, 7)), min_size=1, max_size=6)
        # histories as diagnoses make them: per fault a level, a rise of some shape, noise, failed
        # diagnoses and a repair nobody recorded (random K rows almost never hold a trend)
        fault = st.tuples(st.floats(0, 1.5), st.floats(-0.5, 1.5), st.sampled_from([0.5, 1.0, 2.0, 3.0]),
                          st.sampled_from([0.0, 0.001, 0.01, 0.05]), st.floats(0, 0.3),
                          st.one_of(st.none(), st.floats(0.2, 0.9)))
        # the same history in other time units (a rig's hours, an aircraft's) and with its errors
        # not stated, stated, or stated as 0 (an exact synthetic K)
        trend = st.tuples(st.integers(3, 40), st.integers(0, 2 ** 32 - 1), st.tuples(fault, fault, fault),
                          st.sampled_from([1e-3, 0.1, 1.0, 1e3]), st.sampled_from(["none", "stated", "zero"]))
        # a MAINTENANCE.csv beside a valid HISTORY.csv: fault, action and time cells of any kind
        mcols = ["actuator_id", "time_h", "fault", "action", "note"]
        mheader = st.one_of(st.just(mcols), st.lists(st.sampled_from(mcols + ["bogus"]), min_size=0, max_size=6))
        mcell = st.one_of(num.map(str), st.sampled_from(["A1", "B2", "", "gm", "fsj", "bkl", "all", "K_GM", "repair",
                                                         "replace", "swap", "a,b"]))
        maint = st.tuples(valid, mheader, st.lists(st.lists(mcell, min_size=0, max_size=6), max_size=8))
        return st.one_of(st.tuples(st.just("csv"), st.tuples(header, rows)),
                         st.tuples(st.just("valid"), valid),
                         st.tuples(st.just("maint"), maint),
                         st.tuples(st.just("trend"), trend),
                         st.tuples(st.just("db"), flips))

    @staticmethod
    def trend_rows(n: int, seed: int, faults, scale: float = 1.0, std: str = "none") -> list[tuple]:
        """One actuator's HISTORY.csv rows from (level, rise, exponent, noise sd, share of failed
        diagnoses, unrecorded repair at this fraction or None) per fault; times [h] 1-100 h apart
        times ``scale``; ``std``: no std columns, the noise sd, or 0."""
        rng = np.random.default_rng(seed)
        t = np.cumsum(rng.uniform(1.0, 100.0, n)) * scale
        x = (t - t[0]) / max(t[-1] - t[0], 1e-9)
        cols = []
        for level, rise, p, sd, bad, repair in faults:
            k = level + rise * x ** p + rng.normal(0.0, sd + 1e-12, n)
            failed = rng.random(n) < bad
            k[failed] += rng.uniform(-0.5, 0.5, failed.sum())
            if repair is not None:
                k[x >= repair] -= level + rise * repair ** p
            cols.append(np.clip(k, 0.0, 1.5))
        sd = [] if std == "none" else [float(f[3]) if std == "stated" else 0.0 for f in faults]
        return [("A1", float(t[i]), *(float(c[i]) for c in cols), *sd) for i in range(n)]

    @staticmethod
    def header(with_std: bool) -> list[str]:
        """HISTORY.csv columns of a ``valid`` or ``trend`` case."""
        return ["actuator_id", "time_h", "k_gm", "k_fsj", "k_bkl"] + (["std_gm", "std_fsj", "std_bkl"] if with_std else [])

    def check(self, case, tally: Tally) -> None:
        import csv
        import sqlite3

        from ..prognostics.config import PrognosticsError
        from ..prognostics.store import HistoryStore
        kind, arg = case
        db = self.tmp / "case.sqlite"
        for suffix in ("", "-wal", "-shm"):
            Path(str(db) + suffix).unlink(missing_ok=True)
        if kind == "db":
            data = bytearray(self.db_bytes)
            for pos, bit in arg:
                data[pos] ^= 1 << bit
            db.write_bytes(bytes(data))
            try:
                with HistoryStore(db) as s:
                    s.list_tests()
            except PrognosticsError as e:
                return tally.refuse(e, (PrognosticsError,))
            except sqlite3.DatabaseError as e:   # reported below as undocumented
                return tally.refuse(e, (PrognosticsError,))
            tally.handled += 1
            return
        path = self.tmp / "history.csv"
        if kind == "maint":
            return self._check_maintenance(arg, path, db, tally)
        with path.open("w", newline="") as f:
            w = csv.writer(f)
            if kind == "csv":
                header, rows = arg
                w.writerow(header)
                w.writerows(rows)
            else:
                w.writerow(self.header(kind == "trend" and arg[4] != "none"))
                w.writerows(self.trend_rows(*arg) if kind == "trend" else arg)
        db.write_bytes(self.db_bytes)
        with HistoryStore(db) as s:
            before = s.list_tests()
            try:
                added = s.import_csv(path)
            except PrognosticsError as e:
                if s.list_tests() != before:
                    raise AssertionError("a refused import changed the store") from e
                return tally.refuse(e, (PrognosticsError,))
            if len(s.list_tests()) != len(before) + added:
                raise AssertionError("the store does not hold what the import reported")
        if added:
            obj = self._prognose(db)
            if kind == "trend" and arg[3] != 1.0:
                self._same_in_other_units(obj, arg, path)
        tally.handled += 1

    def _check_maintenance(self, arg, path: Path, db: Path, tally: Tally) -> None:
        """A HISTORY.csv and a MAINTENANCE.csv imported together: both go in, or neither."""
        import csv

        from ..prognostics.config import PrognosticsError
        from ..prognostics.store import HistoryStore
        tests, mheader, mrows = arg
        mpath = self.tmp / "maintenance.csv"
        for p, header, rows in ((path, self.header(False), tests), (mpath, mheader, mrows)):
            with p.open("w", newline="") as f:
                w = csv.writer(f)
                w.writerow(header)
                w.writerows(rows)
        db.write_bytes(self.db_bytes)
        with HistoryStore(db) as s:
            before = (s.list_tests(), s.list_maintenance())
            try:
                added, actions = s.import_files(path, mpath)
            except PrognosticsError as e:
                if (s.list_tests(), s.list_maintenance()) != before:
                    raise AssertionError("a refused import changed the store") from e
                return tally.refuse(e, (PrognosticsError,))
            if (len(s.list_tests()), len(s.list_maintenance())) != (len(before[0]) + added, len(before[1]) + actions):
                raise AssertionError("the store does not hold what the import reported")
        if added:
            self._prognose(db)
        tally.handled += 1

    THRESHOLDS = {"gm": 0.816, "fsj": 0.915, "bkl": 0.838}     # fixed: no reference runs

    @classmethod
    def _prognose(cls, history: Path, next_check_h: float = 50.0) -> dict:
        """What was taken in is prognosed: every fault and the overall answer a RUL with ordered
        quantiles and p_fail_next in [0, 1], or a reason; model weights sum to 1."""
        from ..prognostics.rul import prognose
        obj = prognose(history, thresholds=cls.THRESHOLDS, next_check_h=next_check_h)
        for a, res in obj["actuators"].items():
            for f, F in [*res["faults"].items(), ("overall", res["overall"])]:
                q = [F["rul_p05_h"], F["rul_median_h"], F["rul_p95_h"]]
                if F["rul_median_h"] is None and not F.get("reason"):
                    raise AssertionError(f"{a} {f}: a null RUL without a reason")
                got = [v for v in q if v is not None]
                if got != sorted(got) or any(v < 0 for v in got):
                    raise AssertionError(f"{a} {f}: RUL quantiles out of order or negative: {q}")
                if F["p_fail_next"] is not None and not 0.0 <= F["p_fail_next"] <= 1.0:
                    raise AssertionError(f"{a} {f}: p_fail_next {F['p_fail_next']} outside [0, 1]")
                if "model_weights" in F and abs(sum(F["model_weights"].values()) - 1.0) > 0.01:
                    raise AssertionError(f"{a} {f}: model weights {F['model_weights']} do not sum to 1")
        return obj

    def _same_in_other_units(self, obj: dict, arg: tuple, path: Path) -> None:
        """A history in hours x c is the history in hours: every RUL and time x c, the same
        probabilities (nothing in the models fixes a time scale)."""
        import csv
        n, seed, faults, scale, std = arg
        with path.open("w", newline="") as f:
            w = csv.writer(f)
            w.writerow(self.header(std != "none"))
            w.writerows(self.trend_rows(n, seed, faults, 1.0, std))
        one = self._prognose(path, 50.0 / scale)["actuators"]
        for a, res in obj["actuators"].items():
            for f, F in [*res["faults"].items(), ("overall", res["overall"])]:
                G = one[a]["faults"][f] if f != "overall" else one[a]["overall"]
                for k in ("rul_p05_h", "rul_median_h", "rul_p95_h", "onset_h"):
                    x, y = F.get(k), G.get(k)
                    if (x is None) != (y is None) or (x is not None and abs(x / scale - y) > 2e-3 * max(abs(y), 1e-9)):
                        raise AssertionError(f"{a} {f}: {k} {x} in hours x {scale:g} but {y} in hours")
                if F["p_fail_next"] != G["p_fail_next"]:
                    raise AssertionError(f"{a} {f}: p_fail_next {F['p_fail_next']} in hours x {scale:g} but "
                                         f"{G['p_fail_next']} in hours")


# ----------------------------------------------------------------------------- node messages
class MessagesTarget:
    """Hostile message streams into the real monitor and plant node callbacks (CDR, as DDS
    delivers; :class:`~..ros.harness.NodeHarness`)."""
    name = "messages"

    def __init__(self, tmp: Path):
        from ..ros.harness import NodeHarness
        self.nodes = NodeHarness()

    def close(self) -> None:
        self.nodes.close()

    def strategy(self):
        from hypothesis import strategies as st
        val = st.one_of(st.floats(allow_nan=True, allow_infinity=True), st.floats(-1, 1))
        arr = st.lists(val, max_size=3)
        stamp = st.one_of(st.integers(0, 10**10), st.integers(-2**31, 2**31 - 1))
        frame = st.one_of(st.sampled_from(["start:1", "end:1", "start:2", "end:2", "start:-3", "end:x", "",
                                           "start:99999999999999999999", "stop:1", "start:1:2"]), st.text(max_size=20))
        msg = st.one_of(
            st.tuples(st.just("eha/command"), stamp, arr, arr, arr),
            st.tuples(st.just("eha/joint_state"), stamp, arr, arr, arr),
            st.tuples(st.just("eha/current"), stamp, arr, arr, arr),
            st.tuples(st.just("eha/pressure"), stamp, val),
            st.tuples(st.just("eha/test_window"), stamp, frame),
            st.tuples(st.just("bytes"), st.sampled_from(["eha/command", "eha/pressure", "eha/test_window"]),
                      st.binary(max_size=64)))
        return st.lists(msg, min_size=1, max_size=60)

    def check(self, case, tally: Tally) -> None:
        from ..ros.harness import message
        nodes = self.nodes
        mon = nodes.monitor
        n_verdicts = mon.verdicts
        for m in case:
            if m[0] == "bytes":
                topic, data, msg = m[1], m[2], None
            else:
                topic, msg = m[0], message(*m)
                data = nodes.serialize(msg)
            try:
                nodes.feed(topic, data, msg)
            except Exception as e:
                raise AssertionError(f"{topic}: the node let {type(e).__name__} out: {e}") from e
        nodes.settle(DEADLINE_MS / 1000)
        new = min(mon.verdicts - n_verdicts, len(mon.results))
        for r in list(mon.results)[len(mon.results) - new:]:
            if r["diagnosis"] is None and not _one_line(r["message"]):
                raise AssertionError(f"a refused window's reason is not one line: {r['message']!r}")
        if len(mon.windows.windows) > mon.windows.max_open:
            raise AssertionError(f"{len(mon.windows.windows)} open windows kept (limit {mon.windows.max_open})")
        tally.handled += 1


TARGETS = {t.name: t for t in (McapTarget, ImporterTarget, CsvTarget, HistoryTarget, MessagesTarget)}


def _rss_mb() -> float:
    """Peak resident memory of this process so far [MB] (Linux ru_maxrss is in KiB)."""
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def fuzz_target(name: str, examples: int, seed: int, progress=None) -> dict:
    """Run ``examples`` cases of one target from ``seed``; the figures, or ``failure`` with the seed to replay."""
    from hypothesis import HealthCheck, given, settings
    from hypothesis import seed as hseed
    with tempfile.TemporaryDirectory(prefix=f"eha-fuzz-{name}-") as d:
        target = TARGETS[name](Path(d))
        rss0 = _rss_mb()          # after the target's own set-up (imports, nodes, base files)
        tally = Tally()

        @hseed(seed)
        @settings(max_examples=examples, deadline=DEADLINE_MS, database=None, print_blob=True,
                  suppress_health_check=list(HealthCheck))
        @given(target.strategy())
        def run(case):
            t0, m0 = time.perf_counter(), _rss_mb()
            target.check(case, tally)
            tally.cases += 1
            tally.slowest_s = max(tally.slowest_s, time.perf_counter() - t0)
            tally.case_rss_mb = max(tally.case_rss_mb, _rss_mb() - m0)
            if _rss_mb() - m0 > MAX_CASE_RSS_MB:
                raise AssertionError(f"one case raised peak memory by {_rss_mb() - m0:.0f} MB")
            if progress and tally.cases % 200 == 0:
                progress(f"fuzz {name}: {tally.cases} cases")

        failure = None
        try:
            run()
        except Exception as e:  # hypothesis re-raises the shrunk failing case
            import traceback
            errs = list(getattr(e, "exceptions", None) or [e])   # hypothesis groups distinct failures
            said = []
            for x in errs:
                where = traceback.extract_tb(x.__cause__.__traceback__ if x.__cause__ else x.__traceback__)[-1]
                said.append(f"{type(x).__name__}: {x} (at {Path(where.filename).name}:{where.lineno})")
            failure = (f"{name}: " + "; ".join(said) + f"\nreplay: eha-health bench fuzz --target {name} "
                       f"--seed {seed} --examples {examples}")
        finally:
            if hasattr(target, "close"):
                target.close()
    growth = _rss_mb() - rss0
    return {"target": name, "seed": seed, "cases": tally.cases, "handled": tally.handled, "refused": tally.refused,
            "slowest_case_s": tally.slowest_s, "max_case_rss_mb": tally.case_rss_mb,
            "peak_rss_growth_mb": growth, "failure": failure,
            "top_refusals": dict(sorted(tally.reasons.items(), key=lambda kv: -kv[1])[:5])}


def fuzz(targets=None, examples: int = 2000, seed: int = 0, progress=None) -> dict:
    """``examples`` cases per target (all targets by default)."""
    rows = [fuzz_target(n, examples, seed, progress) for n in (targets or TARGETS)]
    return {"seed": seed, "examples": examples, "targets": rows, "ok": all(r["failure"] is None for r in rows)}


def format_fuzz(res: dict) -> str:
    lines = [f"fuzzing, seed {res['seed']}, up to {res['examples']} cases per target",
             f"{'target':<10} {'cases':>6} {'handled':>8} {'refused':>8} {'slowest [s]':>12} "
             f"{'case RSS +MB':>13} {'run RSS +MB':>12}"]
    for r in res["targets"]:
        lines.append(f"{r['target']:<10} {r['cases']:>6} {r['handled']:>8} {r['refused']:>8} "
                     f"{r['slowest_case_s']:>12.3f} {r['max_case_rss_mb']:>13.1f} {r['peak_rss_growth_mb']:>12.1f}")
    lines += [r["failure"] for r in res["targets"] if r["failure"]]
    lines.append("all handled or refused with the documented error" if res["ok"] else "FAILED")
    return "\n".join(lines)
