"""Decision settings of the discrepancy loop, and where they come from (``data/discrepancy.yaml``)."""
from __future__ import annotations

import functools
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path

from ..physics.yamlfile import safe_load

#: Most effects one analysis adds, by default (``eha-health discrepancy --max-effects``).
DEFAULT_MAX_EFFECTS = 2


@dataclass(frozen=True)
class Settings:
    """Decision thresholds of the loop (``data/discrepancy.yaml`` says how they were set)."""
    fit_fraction: float = 0.7          # share of the samples fitted; the rest is held out
    held_out_ratio: float = 0.5        # selected only if the held-out residual power above noise and
                                       # floor, with / without the effect, is <= this
    fit_ratio: float = 0.8             # ... and RSS_fit(aug)/RSS_fit(base) <= this
    grid: int = 48                     # grid points of a candidate's knob before the local fit
    starts: int = 2                    # local fits per candidate, from the best distinct grid points
    max_nfev: int = 30                 # iterations of each local fit
    scan: int = 12                     # grid points of an in-loop candidate's screening scan
    refits: int = 2                    # candidates refitted in full after screening: the best screened,
    sparse_refits: int = 1             # ... and the first of the sparse regression
    pruned_retries: int = 4            # in-loop candidates pruned at screening retried from the base
                                       # re-identified with them, when nothing passes (evidence.retry_pruned)
    floor: dict = field(default_factory=dict)   # per-channel residual floor of the model [SI]
    effect_floor: dict = field(default_factory=dict)  # {candidate: per-channel floor} once it is added
    fault_error: dict = field(default_factory=dict)   # {fault coefficient: 1 sd} its error once an effect
                                                      # is in the model, beyond the whole-test fit's terms
    rest_noise: bool = False           # noise also measured where the command rests (a rig's coloured
                                       # interference; residuals.rest_noise_level)
    frequency_evidence: bool = False   # a broadband record (a rig's chirp): the held-out position/command
                                       # response error is evidence too (signals.frequency.response_error)

    def floor_with(self, effects) -> dict[str, float]:
        """Per-channel floor [SI] of the model holding ``effects``: its largest known model-form error."""
        out = dict(self.floor)
        for e in effects:
            for c, v in self.effect_floor.get(e, {}).items():
                out[c] = max(out.get(c, 0.0), v)
        return out


@functools.lru_cache(maxsize=None)
def _packaged_settings() -> dict:
    return safe_load(resources.files("eha_health").joinpath("data/discrepancy.yaml").read_text()) or {}


def fdi_settings(path: str | Path | None = None) -> Settings:
    """Settings for FDI tests of the shipped monitor: thresholds and the model's residual floor."""
    data = safe_load(Path(path).read_text()) if path else _packaged_settings()
    fl = {k: float(v) for k, v in (data.get("floor") or {}).items()}
    ef = {e: {k: float(v) for k, v in (chans or {}).items()} for e, chans in (data.get("effect_floor") or {}).items()}
    th = data.get("thresholds") or {}
    fe = {k: float(v) for k, v in (data.get("fault_error_sd") or {}).items()}
    return Settings(**{k: float(v) for k, v in th.items() if k in ("held_out_ratio", "fit_ratio")}, floor=fl,
                    effect_floor=ef, fault_error=fe)
