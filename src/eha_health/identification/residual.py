"""The weighted residual every fit minimises: model output against a record.

Per sample k and channel c on a sample mask of n samples,

    r[k, c] = w_c f_c[k] (y_model[k, c] - y[k, c]) / sqrt(n),    w_c = weight_c / scale_c

so a difference of one scale (:data:`CHANNEL_SCALES`) weighs one unit and the squared
norm is a mean square, comparable between masks of different length. ``f`` is an
optional per-sample factor of a channel (e.g. a segment that weighs less). With
``block_s`` > 0 the residual is averaged over blocks of that length before squaring
(mean x sqrt(count): a smooth residual keeps its sum of squares, sub-block spikes drop).
"""
from __future__ import annotations

import numpy as np

from ..physics.layout import O_CUR, O_P12, O_POS, O_VEL, O_XS
from .record import Record

#: Residual scale per channel [SI]: a difference of one scale weighs one unit.
CHANNEL_SCALES = {"position": 1e-4, "velocity": 5e-3, "pressure": 5e5, "current": 5e-4, "spool": 2e-5}
#: Kernel output column of each channel.
CHANNEL_COLUMNS = {"position": O_POS, "velocity": O_VEL, "pressure": O_P12, "current": O_CUR, "spool": O_XS}
#: Velocity weighs little: it repeats the position's information, and at backlash impacts
#: its spikes depend on contact details no monitor model gets right (measured: with
#: weight 1 the sine-segment velocity mismatch biased K_FSJ by 0.04 at K_GM = K_BKL = 1;
#: with 0.05 every coefficient of the single and combined cases is within 0.003).
CHANNEL_WEIGHTS = {"position": 1.0, "velocity": 0.05, "pressure": 1.0, "current": 1.0, "spool": 1.0}


class Residual:
    """Weighted residual of kernel outputs ``[n, N_OUT]`` against ``record`` on ``mask``.

    ``weights``: per-channel ``w_c`` replacing ``CHANNEL_WEIGHTS / CHANNEL_SCALES``;
    ``sample_factors``: channel -> per-sample factor over the whole record; ``block_s`` [s].
    """

    def __init__(self, record: Record, mask: np.ndarray | None = None, weights: dict | None = None,
                 sample_factors: dict[str, np.ndarray] | None = None, block_s: float = 0.0):
        self.record = record
        self.mask = np.ones(len(record), bool) if mask is None else np.asarray(mask, bool)
        self._whole = bool(self.mask.all())
        self.n = int(self.mask.sum())
        if self.n < 10:
            raise ValueError(f"residual mask holds {self.n} samples (need >= 10)")
        self.channels = tuple(record.channels)
        self.cols = [CHANNEL_COLUMNS[c] for c in self.channels]
        wt = weights or {}
        self.w = np.array([wt.get(c, CHANNEL_WEIGHTS[c] / CHANNEL_SCALES[c]) for c in self.channels]) / np.sqrt(self.n)
        self.y = np.column_stack([record.channels[c][self.mask] for c in self.channels])
        self._W = self.w
        # samples the record marks as carrying no information weigh nothing, whatever the fitness
        excluded = {c: m for c, m in record.excluded.items() if c in self.channels and np.any(m)}
        if excluded:
            sample_factors = dict(sample_factors or {})
            for c, m in excluded.items():
                sample_factors[c] = np.asarray(sample_factors.get(c, 1.0), float) * ~np.asarray(m, bool)
        if sample_factors:
            self._W = np.tile(self.w, (self.n, 1))     # [n, channels]
            for c, f in sample_factors.items():
                if c in self.channels:
                    i = self.channels.index(c)
                    self._W[:, i] = self._W[:, i] * np.asarray(f, float)[self.mask]
        self._starts = self._block = None
        if block_s > 0:
            m = max(1, int(round(block_s * record.sample_rate)))
            self._starts = np.arange(0, self.n, m)
            counts = np.diff(np.append(self._starts, self.n))
            self._block = (1.0 / np.sqrt(counts))[:, None]

    @property
    def horizon(self) -> int:
        """Samples of the record up to the last one this residual reads (a model simulated that far,
        :meth:`~.problem.KnobModel.until`, gives the same residual)."""
        return int(np.flatnonzero(self.mask)[-1]) + 1

    def __call__(self, out: np.ndarray) -> np.ndarray:
        """The residual vector of one output ``[n, N_OUT]`` (sample-major, channels inner)."""
        return self._batch(out[None]).ravel()

    def cost(self, out: np.ndarray) -> float:
        """Squared norm of the residual of one output."""
        r = self(out)
        return float(r @ r)

    def _batch(self, outs: np.ndarray) -> np.ndarray:
        """Weighted (block-summed) differences ``[B, n', channels]`` of a batch of outputs: the one
        place the residual's arithmetic lives (one output is a batch of one)."""
        # (the channels' columns first: a masked copy of every output column was most of the time)
        o = outs[:, :, self.cols]
        if not self._whole:
            o = o[:, self.mask]
        d = (o - self.y[None]) * self._W
        if self._starts is not None:
            d = np.add.reduceat(d, self._starts, axis=1) * self._block[None]
        return d

    def costs(self, outs: np.ndarray) -> np.ndarray:
        """Squared norms for a batch of outputs ``[B, n, N_OUT]``."""
        return self.costs_and_residuals(outs)[0]

    def costs_and_residuals(self, outs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`costs` and the residual vectors ``[B, m]`` of one batch, from one pass over it."""
        d = self._batch(outs)
        return np.einsum("bnc,bnc->b", d, d), d.reshape(len(d), -1)

    def expected_noise_cost(self, sigma: dict[str, float]) -> float:
        """Expected cost of white measurement noise of standard deviation ``sigma[c]`` [SI] per channel:
        sum over samples of (w_c f_c sigma_c)^2, divided by the block length when blocks average it."""
        W2 = np.broadcast_to(self._W, (self.n, len(self.channels))) ** 2
        s2 = np.array([sigma.get(c, 0.0) ** 2 for c in self.channels])
        m = 1.0 if self._starts is None else self.n / len(self._starts)
        return float(np.sum(W2 * s2) / m)

    def rms(self, out: np.ndarray) -> dict[str, float]:
        """Unweighted RMS of each channel [SI] on the mask."""
        o = out if self._whole else out[self.mask]
        d = o[:, self.cols] - self.y
        return {c: float(np.sqrt(np.mean(d[:, i] ** 2))) for i, c in enumerate(self.channels)}
