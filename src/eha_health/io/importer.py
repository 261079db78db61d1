"""Import measured rig data from delimited text (CSV, logger exports) with a channel map.

The map (YAML) says where each channel is and how to make it SI::

    delimiter: ","            # field separator (default ",")
    skip_rows: 8              # lines before the first data row
    sample_rate: 1000.0       # Hz, when there is no time column
    # time: {column: 0, unit: s}            # or a time column
    channels:                 # command and position required; velocity, pressure,
      command:  {column: 4, scale: 10, unit: mm}   # current and load (external force
      position: {column: 2, scale: 10, unit: mm}   # on the actuator, opposing +x) optional
      load:     {column: 3, scale: 9806.65, unit: N, offset: 0.0}
      pressure: {column: 5, minus: 6, unit: bar}   # two chamber transducers: P12 = P1 - P2

``column`` (and ``minus``) is a 0-based index or a header name (then ``header_row`` gives the
0-based line of the names). Value in SI = ((raw - raw[minus]) * scale - offset) * unit factor.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import yaml

from ..physics.yamlfile import safe_load
from ..signals.response import Response

#: SI target of each importable channel and the units accepted for it (factor to SI).
UNITS = {
    "length": ("m", {"m": 1.0, "mm": 1e-3, "um": 1e-6, "cm": 1e-2, "in": 0.0254}),
    "velocity": ("m/s", {"m/s": 1.0, "mm/s": 1e-3, "in/s": 0.0254}),
    "force": ("N", {"N": 1.0, "kN": 1e3, "lbf": 4.4482216152605}),
    "pressure": ("Pa", {"Pa": 1.0, "kPa": 1e3, "MPa": 1e6, "bar": 1e5, "psi": 6894.757293168}),
    "current": ("A", {"A": 1.0, "mA": 1e-3}),
    "time": ("s", {"s": 1.0, "ms": 1e-3}),
}
CHANNELS = {"command": "length", "position": "length", "velocity": "velocity", "pressure": "pressure",
            "current": "current", "load": "force"}
REQUIRED = ("command", "position")


class ImportError_(ValueError):
    """The data or its map cannot be imported; the message says why."""


def _unit_factor(channel: str, kind: str, unit) -> float:
    si, table = UNITS[kind]
    if unit is None:
        raise ImportError_(f"map: channel {channel}: 'unit' missing (one of {', '.join(table)})")
    if unit not in table:
        raise ImportError_(f"map: channel {channel}: unit {unit!r} is not a {kind} unit "
                           f"(accepted: {', '.join(table)}; SI is {si})")
    return table[unit]


def load_map(path: str | Path) -> dict:
    """Read and check a channel map; ``ImportError_`` names the first problem."""
    path = Path(path)
    if not path.is_file():
        raise ImportError_(f"{path}: no such map file")
    try:
        m = safe_load(path.read_text())
    except yaml.YAMLError as e:
        raise ImportError_(f"{path}: not valid YAML ({str(e).splitlines()[0]})") from None
    if not isinstance(m, dict) or not isinstance(m.get("channels"), dict):
        raise ImportError_(f"{path}: the map needs a 'channels' mapping")
    unknown = set(m) - {"delimiter", "skip_rows", "header_row", "sample_rate", "time", "channels", "description"}
    if unknown:
        raise ImportError_(f"{path}: unknown key(s) {sorted(unknown)}")
    for c in m["channels"]:
        if c not in CHANNELS:
            raise ImportError_(f"map: unknown channel {c!r} (known: {', '.join(CHANNELS)})")
    for c in REQUIRED:
        if c not in m["channels"]:
            raise ImportError_(f"map: channel {c} is required")
    if ("time" in m) == ("sample_rate" in m):
        raise ImportError_("map: give either a 'time' column or a 'sample_rate' [Hz]")
    if "sample_rate" in m:
        sr = m["sample_rate"]
        if isinstance(sr, bool) or not isinstance(sr, (int, float)) or not np.isfinite(sr) or sr <= 0:
            raise ImportError_(f"map: sample_rate must be a positive number in Hz, got {sr!r}")
    return m


def _column(spec, name: str, header: list[str] | None) -> int:
    if not isinstance(spec, dict) or "column" not in spec:
        raise ImportError_(f"map: channel {name} needs a 'column'")
    col = spec["column"]
    if isinstance(col, bool):
        raise ImportError_(f"map: channel {name}: column must be an index or a header name")
    if isinstance(col, int):
        if col < 0:
            raise ImportError_(f"map: channel {name}: column index must be >= 0")
        return col
    if header is None:
        raise ImportError_(f"map: channel {name}: column {col!r} is a name but no header_row is given")
    if str(col) not in header:
        raise ImportError_(f"map: channel {name}: no column named {col!r} in the header ({', '.join(header)})")
    return header.index(str(col))


def _values(rows: list[list[str]], c: int, name: str, data_path: Path, skip: int) -> np.ndarray:
    vals = np.empty(len(rows))
    for i, r in enumerate(rows):
        if c >= len(r):
            raise ImportError_(f"{data_path}: data row {skip + i + 1} has {len(r)} fields; "
                               f"channel {name} is column {c}")
        try:
            vals[i] = float(r[c])
        except ValueError:
            raise ImportError_(f"{data_path}: data row {skip + i + 1}, column {c} ({name}): "
                               f"{r[c].strip()!r} is not a number") from None
    return vals


def import_text(data_path: str | Path, map_path: str | Path) -> Response:
    """Read measured data into a :class:`Response` (unmeasured channels are NaN)."""
    m = load_map(map_path)
    data_path = Path(data_path)
    if not data_path.is_file():
        raise ImportError_(f"{data_path}: no such data file")
    delim = m.get("delimiter", ",")
    lines = data_path.read_text(encoding="utf-8-sig", errors="replace").splitlines()   # a byte-order mark is not data
    header = None
    if "header_row" in m:
        h = m["header_row"]
        if not isinstance(h, int) or not 0 <= h < len(lines):
            raise ImportError_(f"map: header_row {h!r} is not a line of {data_path}")
        header = [s.strip() for s in lines[h].split(delim)]
    skip = m.get("skip_rows", 0)
    if not isinstance(skip, int) or skip < 0:
        raise ImportError_(f"map: skip_rows must be an integer >= 0, got {skip!r}")
    specs = dict(m["channels"])
    if "time" in m:
        specs["t"] = m["time"]
    cols = {name: _column(spec, name, header) for name, spec in specs.items()}
    minus = {name: _column({"column": spec["minus"]}, f"{name} (minus)", header)
             for name, spec in specs.items() if isinstance(spec, dict) and "minus" in spec}
    rows = [ln.split(delim) for ln in lines[skip:] if ln.strip()]
    if len(rows) < 100:
        raise ImportError_(f"{data_path}: {len(rows)} data rows after skipping {skip} (need >= 100)")
    out = {}
    for name, c in cols.items():
        kind = "time" if name == "t" else CHANNELS[name]
        spec = specs[name]
        factor = _unit_factor(name, kind, spec.get("unit"))
        scale, offset = spec.get("scale", 1.0), spec.get("offset", 0.0)
        for key, v in (("scale", scale), ("offset", offset)):
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not np.isfinite(v):
                raise ImportError_(f"map: channel {name}: {key} must be a finite number, got {v!r}")
        vals = _values(rows, c, name, data_path, skip)
        if name in minus:
            vals = vals - _values(rows, minus[name], f"{name} (minus)", data_path, skip)
        bad = ~np.isfinite(vals)
        if bad.any():
            raise ImportError_(f"{data_path}: channel {name} has {int(bad.sum())} NaN/inf value(s), "
                               f"first at data row {skip + int(np.argmax(bad)) + 1}")
        out[name] = (vals * scale - offset) * factor
    n = len(rows)
    if "t" in out:
        t = out.pop("t")
        t = t - t[0]
        if (np.diff(t) <= 0).any():
            raise ImportError_(f"{data_path}: time column is not strictly increasing")
    else:
        t = np.arange(n) / float(m["sample_rate"])
    nan = np.full(n, np.nan)
    r = Response(t=t, command=out["command"], position=out["position"],
                 velocity=out.get("velocity", nan.copy()), pressure=out.get("pressure", nan.copy()),
                 current=out.get("current", nan.copy()), spool=nan.copy(),
                 meta={"source": str(data_path), "map": str(map_path),
                       "measured": [c for c in ("position", "velocity", "pressure", "current") if c in out]})
    r.load = out.get("load")
    return r
