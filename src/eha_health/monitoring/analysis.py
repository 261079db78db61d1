"""What the monitor runs on one test window: the diagnosis, then (optionally) the discrepancy loop."""
from __future__ import annotations

from ..discrepancy.loop import analyse_fdi_test
from ..discrepancy.settings import DEFAULT_MAX_EFFECTS
from ..identification.diagnose import diagnose
from ..signals.response import Response


def analyse_window(response: Response, discrepancy: bool = False, max_effects: int = DEFAULT_MAX_EFFECTS, **diagnose_args):
    """``(diagnosis, report or None)``: :func:`~eha_health.identification.diagnose.diagnose` with
    ``diagnose_args`` (method, fitness, seed), then the discrepancy loop started from it."""
    d = diagnose(response, **diagnose_args)
    if not discrepancy:
        return d, None
    return d, analyse_fdi_test(response, max_effects=max_effects, diagnosis=d)
