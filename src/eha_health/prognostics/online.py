"""Online update of one fault's degradation models, one test at a time (monitor node wiring).

The state of every grid cell of every model is the Kalman filter posterior of
(l0, a, u, v) -- level at onset, rise per span, Wiener deviation and wear-rate deviation --
plus its accumulated log-likelihood (:mod:`degradation`). A new test (tau, K, s) is one
predict + update of every cell: the Bayesian update of the degradation parameters and of
the wear-rate state, O(cells) work, no refit. Cell and model weights follow from the
updated likelihoods.

Time is normalised by a span T_s fixed when the tracker starts (default: the span of the
points it starts with); when the data reach ``regrid_factor`` T_s the tracker refits its
stored points with the new span (the grids are defined per span), so long runs keep a
well-placed grid. Between regrids, :meth:`OnlineFault.fit` equals the batch fit of the
same points with the same span (tested).

Use: a caller that follows one fault test by test keeps one :class:`OnlineFault` after the onset
and calls :meth:`OnlineFault.update` after each diagnosis. The monitor does not: it appends each
diagnosis to the history and runs ``prognose`` for its actuator (``monitoring/prognosis.py``),
which is the reference and what the CLI runs.
"""
from __future__ import annotations

import numpy as np

from .config import Settings, load_settings
from .degradation import ModelFit, Series, grid_g, increment_temper, model_grids, model_weights, run_filters, summarise


class OnlineFault:
    """Degradation models of one fault since its onset anchor, updated test by test."""

    def __init__(self, tau_h, k, std, span_h: float | None = None, settings: Settings | None = None,
                 regrid_factor: float = 2.0, fault: str | None = None):
        self.settings = settings or load_settings()
        # the fault's own model set where fault_models: gives one (None: models:)
        self.models = self.settings.models if fault is None else self.settings.models_for(fault)
        self.grids = model_grids(self.models)
        self.regrid_factor = float(regrid_factor)
        self.tau = list(np.atleast_1d(np.asarray(tau_h, float)))
        self.y = list(np.atleast_1d(np.asarray(k, float)))
        self.s = list(np.maximum(np.atleast_1d(np.asarray(std, float)), self.settings.prognosis.min_std))
        if not self.tau or self.tau[0] != 0.0:
            raise ValueError("the first point of an online fault is its onset anchor, at tau = 0 h")
        self.regrids = 0
        self._refit(span_h)

    def _refit(self, span_h: float | None = None) -> None:
        """Filter the stored points from scratch with span ``span_h`` (default: their span)."""
        self.span_h = float(span_h if span_h is not None else (self.tau[-1] if self.tau[-1] > 0 else 1.0))
        t = np.asarray(self.tau)[None, :] / self.span_h
        y, r = np.asarray(self.y)[None, :], np.asarray(self.s)[None, :] ** 2
        self.state, self.g_last = {}, {}
        for m, grid in self.grids.items():
            g = grid_g(grid, t)
            self.state[m] = run_filters(grid, g, y, r, np.ones(y.shape, bool))
            self.g_last[m] = g[:, :, -1]

    def update(self, tau_h: float, k: float, std: float) -> None:
        """Add one test (hours since the anchor, K, its 1-sd); times must increase."""
        if not tau_h > self.tau[-1]:
            raise ValueError(f"test at tau={tau_h:g} h is not after the previous one ({self.tau[-1]:g} h)")
        self.tau.append(float(tau_h))
        self.y.append(float(k))
        std = max(float(std), self.settings.prognosis.min_std)     # as prognose: no diagnosis is exact
        self.s.append(std)
        if tau_h > self.regrid_factor * self.span_h:
            self.regrids += 1
            self._refit()
            return
        t = np.array([[tau_h / self.span_h]])
        y, r = np.array([[0.0, float(k)]]), np.array([[0.0, float(std) ** 2]])   # column 0: the state's point
        for m, grid in self.grids.items():
            g = np.concatenate([self.g_last[m][:, :, None], grid_g(grid, t)], -1)
            run_filters(grid, g, y, r, np.ones(y.shape, bool), st=self.state[m], start=1)
            self.g_last[m] = g[:, :, -1]

    def fit(self) -> tuple[list[ModelFit], np.ndarray]:
        """Model fits and model weights (:func:`degradation.model_weights`)."""
        n = np.array([len(self.tau)])
        t = np.asarray(self.tau)[None, :] / self.span_h
        temper = increment_temper(t, np.asarray(self.y)[None, :], np.ones(t.shape, bool))
        fits = [summarise(self.grids[m], self.state[m], self.g_last[m], n, temper if m == "wiener" else None)
                for m in self.grids]
        return fits, model_weights(fits, self.models)

    def series(self) -> Series:
        return Series(np.asarray(self.tau), np.asarray(self.y), np.asarray(self.s), self.span_h)
