"""Waiting in a test on what another process brings about (a row in a store, a mark in a log).

No fixed sleep: between checks of the condition the test blocks on a watched process, whose exit
is itself an event it must react to (a producer that died fails the wait at once, with its return
code, instead of running the deadline out). The deadline is generous: a busy machine only
makes the wait longer.
"""
from __future__ import annotations

import subprocess
import time

#: Longest block on a watched process between two checks of the condition [s].
CHECK_EVERY_S = 0.2


def wait_until(condition, deadline_s: float, what: str, procs: dict[str, subprocess.Popen], may_exit=()):
    """``condition()``'s first true value, checked whenever a watched process exits or
    :data:`CHECK_EVERY_S` has passed. A process of ``procs`` not in ``may_exit`` that exits first
    fails the wait (after one last check of the condition); so does the deadline."""
    end = time.monotonic() + deadline_s
    while True:
        value = condition()
        if value:
            return value
        for name, p in procs.items():
            if name not in may_exit and p.poll() is not None:
                value = condition()
                assert value, f"{name} exited ({p.returncode}) while waiting for {what}"
                return value
        assert time.monotonic() < end, f"{what} not reached within {deadline_s:g} s"
        running = [p for p in procs.values() if p.poll() is None]
        assert running, f"every watched process exited while waiting for {what}"
        try:
            running[0].wait(timeout=CHECK_EVERY_S)
        except subprocess.TimeoutExpired:
            pass
