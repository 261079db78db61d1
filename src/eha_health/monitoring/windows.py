"""Test windows from a stream of stamped samples: buffer, queue, readiness, assembly.

Samples arrive per channel with an integer-nanosecond stamp; test-window marks ('start',
'end' with a test id) open and close windows. A window with both marks is queued; it is
ready once every channel has reached its end stamp, or when no sample has arrived for
``timeout_s`` since its end mark (the deadline moves on while samples still arrive: a busy
plant). A ready window is assembled and checked by :func:`eha_health.io.window.assemble`.
"""
from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field

from ..io.window import Samples, assemble
from ..signals.channels import MEASURED
from ..signals.response import Response

#: Samples kept per channel (60 s at 1 kHz): older ones can no longer be in a window.
BUFFER = 60_000
#: Windows kept open (a mark seen, not yet taken): a stream of stray or hostile marks must not
#: grow the monitor without bound; the oldest open window is dropped past this.
MAX_OPEN = 100
CHANNELS = ("command",) + MEASURED


@dataclass
class Window:
    """One test window: its id, mark stamps [ns] and what is known of it."""
    id: int
    start: int | None = None
    end: int | None = None
    deadline: float = 0.0                 # monotonic time [s] after which it is taken as it is
    progress: tuple = ()                  # the channels' last stamps when the deadline was set
    truth: dict | None = None             # simulated runs: the plant's fault parameters
    response: Response | None = None      # once assembled
    queued: bool = False
    extra: dict = field(default_factory=dict)


class WindowTracker:
    """Per-channel sample buffers and the queue of windows waiting for their samples."""

    def __init__(self, buffer: int = BUFFER, max_open: int = MAX_OPEN):
        self.max_open = max_open
        self.dropped: list[int] = []          # ids of open windows dropped for max_open
        self.buffers = {c: deque(maxlen=buffer) for c in CHANNELS}
        self.last = {c: -1 for c in CHANNELS}
        self.windows: dict[int, Window] = {}
        self.queue: deque[Window] = deque()

    def put(self, channel: str, ns: int, value: float) -> None:
        """One sample [SI] of ``channel`` at stamp ``ns``."""
        self.buffers[channel].append((ns, value))
        self.last[channel] = max(self.last[channel], ns)

    def window(self, test_id: int) -> Window:
        if test_id not in self.windows and len(self.windows) >= self.max_open:
            old = next((k for k, w in self.windows.items() if not w.queued), None)
            if old is not None:
                self.windows.pop(old)
                self.dropped.append(old)
                del self.dropped[:-self.max_open]
        return self.windows.setdefault(test_id, Window(test_id))

    def mark(self, ns: int, event: str, test_id: int, now: float, timeout_s: float) -> Window:
        """A 'start' or 'end' mark; a window with both is queued with a deadline ``timeout_s`` from ``now``."""
        w = self.window(test_id)
        setattr(w, event, ns)
        if w.start is not None and w.end is not None and not w.queued:
            w.queued, w.deadline = True, now + timeout_s
            self.queue.append(w)
        return w

    def ready(self, now: float, timeout_s: float) -> list[Window]:
        """Windows to take now, in order: every channel has reached the end, or the deadline passed."""
        out = []
        while self.queue:
            w = self.queue[0]
            done = all(self.last[c] >= w.end for c in CHANNELS)
            progress = tuple(self.last.values())
            if progress != w.progress:   # samples still arriving (a busy plant): wait on
                w.progress, w.deadline = progress, now + timeout_s
            if not done and now < w.deadline:
                break
            out.append(self.queue.popleft())
        return out

    def assemble(self, w: Window, max_fill: int = 0) -> Response:
        """The window's response (lost samples filled up to runs of ``max_fill``); ``WindowError``
        (a ``ValueError``; ``IncompleteWindow`` when a channel stopped) names what is wrong with it."""
        chans = {c: Samples.of(list(b)) for c, b in self.buffers.items()}
        w.response = assemble(chans, w.start, w.end, meta={"test_id": w.id}, max_fill=max_fill)
        return w.response

    def forget(self, test_id: int) -> None:
        """Done with the window: drop it and the samples no open window can still need.

        Samples are kept only from the earliest start mark of the windows still open (or past this
        window's end): ``BUFFER`` alone would hold 60 s of every channel (~38 MB) in a monitor that
        needs at most the window in progress."""
        w = self.windows.pop(test_id, None)
        if w is None or w.end is None:
            return
        keep_from = min([w.end + 1] + [o.start for o in self.windows.values() if o.start is not None])
        for b in self.buffers.values():
            while b and b[0][0] < keep_from:
                b.popleft()

    @property
    def waiting(self) -> bool:
        return bool(self.queue)
