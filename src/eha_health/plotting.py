"""Plots (matplotlib, headless): responses and the paper-style signature families."""
from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from .identification.signatures import signatures  # noqa: E402
from .physics.faults import FAULT_NAMES, Faults  # noqa: E402
from .physics.model import simulate  # noqa: E402
from .physics.params import ModelParams  # noqa: E402
from .signals.channels import DISPLAY_UNITS  # noqa: E402
from .signals.response import Response  # noqa: E402

_CH = (("position", 1e3, "position [mm]"), ("velocity", 1e3, "velocity [mm/s]"),
       ("pressure", 1e-6, "P12 [MPa]"), ("current", 1e3, "current [mA]"), ("spool", 1e3, "spool [mm]"))


def plot_response(r: Response, path: str | Path, title: str = "", others: dict[str, Response] | None = None):
    """Every channel against time; ``others`` overlays further responses by label."""
    fig, axes = plt.subplots(len(_CH), 1, figsize=(10, 11), sharex=True)
    for ax, (name, scale, label) in zip(axes, _CH):
        if name == "position":
            ax.plot(r.t, r.command * scale, color="0.6", lw=0.8, label="command")
        ax.plot(r.t, getattr(r, name) * scale, lw=1.0, label=r.meta.get("label", "response"))
        for lab, o in (others or {}).items():
            ax.plot(o.t, getattr(o, name) * scale, "--", lw=0.9, label=lab)
        ax.set_ylabel(label)
        ax.grid(alpha=0.3)
    axes[0].legend(loc="upper right", fontsize=8)
    axes[-1].set_xlabel("t [s]")
    fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


# (fault, channel, time window [s], scale, y label, figure title) -- paper Figs. 4-7
FAMILIES = (
    ("k_gm", "position", (0.98, 1.12), 1e3, "position [mm]", "Fig. 4 - step response vs torque-motor gain loss K_GM"),
    ("k_fsj", "pressure", (0.0, 1.0), 1e-6, "P12 [MPa]", "Fig. 5 - ramp differential pressure vs static friction K_FSJ"),
    ("k_bkl", "position", (0.0, 0.12), 1e3, "position [mm]", "Fig. 6 - ramp position vs backlash K_BKL"),
    ("k_bkl", "current", (0.0, 0.12), 1e3, "current [mA]", "Fig. 7 - breakaway current vs backlash K_BKL"),
)


def plot_signature_families(out_dir: str | Path, levels=(0.0, 0.2, 0.4, 0.6, 0.8, 1.0),
                            params: ModelParams | None = None, progress=None) -> list[Path]:
    """One figure per paper figure, a curve per fault level; returns the written files."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    cache: dict[tuple, Response] = {}
    files = []
    for i, (fault, ch, (a, b), scale, ylabel, title) in enumerate(FAMILIES, 1):
        fig, ax = plt.subplots(figsize=(8, 4.5))
        for k in levels:
            key = (fault, k)
            if key not in cache:
                cache[key] = simulate(faults=Faults(**{fault: k}), params=params)
                if progress:
                    progress(f"simulated {fault}={k:g}")
            r = cache[key]
            m = (r.t >= a) & (r.t <= b)
            ax.plot(r.t[m], getattr(r, ch)[m] * scale, label=f"{fault.upper()} = {k:g}")
        if ch == "position":
            ax.plot(r.t[m], r.command[m] * scale, color="0.5", lw=0.8, ls=":", label="command")
        ax.set_xlabel("t [s]")
        ax.set_ylabel(ylabel)
        ax.set_title(title, fontsize=10)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
        fig.tight_layout()
        path = out_dir / f"fig{i + 3}_{fault[2:]}_{ch}.png"
        fig.savefig(path, dpi=90)
        plt.close(fig)
        files.append(path)
    return files


def trend_table(levels=(0.0, 0.2, 0.4, 0.6, 0.8, 1.0), params: ModelParams | None = None) -> list[dict]:
    """Signature values per single fault and level (rows for a CSV or JSON report)."""
    rows = []
    for fault in FAULT_NAMES:
        for k in levels:
            s = signatures(simulate(faults=Faults(**{fault: k}), params=params))
            rows.append({"fault": fault, "level": k, **s.as_dict()})
    return rows


def plot_diagnosis(measured: Response, diagnosis, path: str | Path):
    """Measured vs fitted monitor response per channel, and the convergence history."""
    fitted = diagnosis.fitted
    chans = [c for c in _CH if c[0] != "spool"]
    fig, axes = plt.subplots(len(chans) + 1, 1, figsize=(10, 12))
    for ax, (name, scale, label) in zip(axes, chans):
        ax.plot(measured.t, getattr(measured, name) * scale, lw=1.0, label="measured")
        ax.plot(fitted.t, getattr(fitted, name) * scale, "--", lw=0.9, label="monitor fit")
        ax.set_ylabel(label)
        ax.grid(alpha=0.3)
    axes[0].legend(loc="upper right", fontsize=8)
    axes[len(chans) - 1].set_xlabel("t [s]")
    h = axes[-1]
    h.semilogy(diagnosis.history, lw=1.0)
    h.set_xlabel("iteration (deterministic stages, GA generations, local refinement)")
    h.set_ylabel("fitness")
    h.grid(alpha=0.3)
    k = diagnosis.faults
    fig.suptitle(f"{diagnosis.method}: K_GM={k.k_gm:.3f}  K_FSJ={k.k_fsj:.3f}  K_BKL={k.k_bkl:.3f}")
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def plot_discrepancy(rep, path: str | Path):
    """Residual (fitted - measured) per channel before and after augmentation with the measured
    noise band, for a rig the frequency response error of both models, and the ranking."""
    chans = list(rep.measured)
    fr = rep.frequency_response or []
    rows = len(chans) + 1 + bool(fr)
    fig, axes = plt.subplots(rows, 1, figsize=(10, 2.3 * rows + 0.5))
    for ax, c in zip(axes, chans):
        k, unit = DISPLAY_UNITS[c]
        # the moving mean (1 % of the record) shows slow structure (an offset) under the noise
        w = max(len(rep.t) // 100, 1)
        span = w * float(np.median(np.diff(rep.t)))
        states = (("before", "before", rep.fitted_before, rep.before, "navy"),
                  ("after", f"after ({', '.join(rep.selected) or 'unchanged'})", rep.fitted_after, rep.after,
                   "saddlebrown"))
        for key, name, fitted, state, col in states:
            r = (fitted[c] - rep.measured[c]) * k
            ax.plot(rep.t, r, lw=0.7, label=f"{name}: RMS {state.rms[c] * k:.3g} {unit}")
            ax.plot(rep.t, np.convolve(r, np.ones(w) / w, mode="same"), lw=1.2, color=col, zorder=2.5,
                    label=f"{key}: moving mean over {span:.3g} s")
        sd = rep.residual_before.channels[c].noise_sd * k if c in rep.residual_before.channels else 0.0
        if sd > 0:
            ax.axhspan(-sd, sd, color="0.3", alpha=0.25, lw=0, zorder=3, label=f"measured noise +/- {sd:.3g} {unit}")
        ax.axvline(rep.split_time_s, color="0.5", ls=":", lw=1)
        ax.set_ylabel(f"{c} residual [{unit}]")
        ax.grid(alpha=0.3)
        ax.legend(loc="upper left", fontsize=7)
    axes[len(chans) - 1].set_xlabel("t [s]  (dotted: fit | held-out split)")
    if fr:
        ax = axes[len(chans)]
        fc = [(b["f_lo"] + b["f_hi"]) / 2 for b in fr]
        for k, st in (("before", "o-"), ("after", "s--")):
            ax.plot(fc, [100 * (b["gain_ratio"][k] - 1) for b in fr], st, label=f"{k}: gain error [%]")
        ax.axhline(0.0, color="k", lw=0.8)
        ax.set_ylabel("model / measured - 1 [%]")
        ax.set_xlabel("f [Hz]  (position / command, H1 per band; phase error on the right)")
        ax.grid(alpha=0.3)
        tw = ax.twinx()
        for k, st in (("before", "o:"), ("after", "s:")):
            tw.plot(fc, [b["phase_error_deg"][k] for b in fr], st, color="0.4", ms=3)
        tw.set_ylabel("phase error [deg]")
        ax.legend(loc="lower left", fontsize=7)
    ax = axes[-1]
    first = [c for c in rep.candidates if c.round == 1]
    names = [c.name for c in first]
    ax.barh(range(len(first)), [c.held_out_ratio for c in first],
            color=["tab:green" if c.selected else "tab:gray" for c in first])
    ax.set_yticks(range(len(first)), names, fontsize=7)
    ax.invert_yaxis()
    ax.axvline(1.0, color="k", lw=0.8)
    ax.set_xlabel("round 1: held-out residual power with the candidate / without (ranked by information criterion)")
    fig.suptitle(f"discrepancy: {rep.verdict}")
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)
