"""A simulated or measured test response: SI channels on a common time base, CSV I/O.

CSV format (``eha-health simulate``): header ``t,command,position,velocity,pressure,
current,spool`` then one row per sample. t [s]; command, position [m]; velocity [m/s];
pressure = jack differential pressure P12 [Pa]; current = servovalve current [A];
spool = spool position [m]. Position and velocity are what the position transducer
sees: the surface (user) side of the backlash. An imported rig record (``eha-health
import``) may also carry ``load`` = measured external force on the actuator [N]
(opposing +x), and holds only the channels the rig measured: the others are empty
in the CSV and NaN in memory.
"""
from __future__ import annotations

from dataclasses import dataclass, field, fields, replace
from pathlib import Path

import numpy as np

from .channels import MEASURED

#: Columns of the CSV format, in order.
CSV_COLUMNS = ("t", "command") + MEASURED + ("spool",)


@dataclass
class Response:
    """Channels as 1-D float arrays of equal length; ``meta`` says where they came from."""
    t: np.ndarray
    command: np.ndarray
    position: np.ndarray
    velocity: np.ndarray
    pressure: np.ndarray
    current: np.ndarray
    spool: np.ndarray
    jack_position: np.ndarray | None = None
    meta: dict = field(default_factory=dict)
    load: np.ndarray | None = None

    @property
    def sample_rate(self) -> float:
        return 1.0 / float(np.median(np.diff(self.t)))

    def __len__(self) -> int:
        return len(self.t)

    def sliced(self, index: slice) -> "Response":
        """The response with every per-sample array (``t`` included, as it is) indexed by ``index``."""
        n = len(self.t)
        return replace(self, **{f.name: v[index] for f in fields(self)
                                if isinstance(v := getattr(self, f.name), np.ndarray) and v.shape == (n,)})

    def to_csv(self, path: str | Path) -> None:
        cols = CSV_COLUMNS + (("load",) if self.load is not None else ())
        data = np.column_stack([getattr(self, c) for c in cols])
        np.savetxt(path, data, delimiter=",", header=",".join(cols), comments="", fmt="%.10g")

    @classmethod
    def from_csv(cls, path: str | Path, required: tuple[str, ...] = CSV_COLUMNS) -> "Response":
        """Read a CSV in the format above; ``ValueError`` names what is wrong.

        Columns not in ``required`` may be absent or all NaN (not measured).
        """
        path = Path(path)
        if not path.is_file():
            raise ValueError(f"{path}: no such file")
        with path.open(encoding="utf-8-sig", errors="replace") as f:     # a spreadsheet's byte-order mark
            header = f.readline().strip()
        cols = [c.strip() for c in header.split(",")]
        missing = [c for c in required if c not in cols]
        if missing:
            raise ValueError(f"{path}: missing column(s) {', '.join(missing)} (header: {header!r})")
        try:
            data = np.loadtxt(path, delimiter=",", skiprows=1, ndmin=2)
        except ValueError as e:
            raise ValueError(f"{path}: unreadable numeric data ({e})") from None
        if data.shape[0] < 2:
            raise ValueError(f"{path}: fewer than 2 samples")
        if data.shape[1] != len(cols):
            raise ValueError(f"{path}: {data.shape[1]} values per row but {len(cols)} columns in the header")
        nan = np.full(data.shape[0], np.nan)
        ch = {c: data[:, cols.index(c)] if c in cols else nan.copy() for c in CSV_COLUMNS}
        load = data[:, cols.index("load")] if "load" in cols else None
        for c, v in list(ch.items()) + ([("load", load)] if load is not None else []):
            bad = ~np.isfinite(v)
            if c not in required and bad.all():
                continue
            if bad.any():
                raise ValueError(f"{path}: column {c} has {bad.sum()} NaN/inf value(s), first at row {np.argmax(bad) + 2}")
        dt = np.diff(ch["t"])
        if (dt <= 0).any():
            i = int(np.argmax(dt <= 0))
            raise ValueError(f"{path}: time axis not strictly increasing at row {i + 3} (t={ch['t'][i + 1]})")
        return cls(**ch, meta={"source": str(path)}, load=load)
