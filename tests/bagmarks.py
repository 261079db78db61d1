"""Bags whose test-window marks are incomplete, as a recording stopped mid-test leaves them."""
from __future__ import annotations

from msg_bridge import contract as C
from msg_bridge import convert as cv


class WithoutEnd:
    """A :class:`~eha_health.io.mcaplog.BagWriter` to give ``write_run``: every message but the
    window's end mark is written (the recording stopped once the test's samples were in)."""

    def __init__(self, w):
        self.w = w

    def write(self, topic, typ, msg, ns):
        if not (topic.endswith(C.TEST_WINDOW.name) and cv.window_from_msg(msg)[1] == "end"):
            self.w.write(topic, typ, msg, ns)
