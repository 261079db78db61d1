"""Command node: plays the FDI test sequence on request and optionally every N seconds.

A test is started by the ``eha/start_test`` service (``std_srvs/Trigger``), by
``period_s`` > 0 (every N s of simulated time, measured from one test's start to
the next) or at start-up with ``autostart``. Each test publishes
``eha/test_window`` 'start:<id>', one ``eha/command`` sample per 1/``sample_rate_hz``
(stamped in simulated time), then 'end:<id>'.

Pacing (``rate``): 1.0 plays in real time, R plays R times faster, 0 as fast as the
graph allows. At 0 the node keeps at most ``max_in_flight`` samples ahead of the
plant's answers (``eha/joint_state``), so no queue overflows and no sample is lost.
"""
from __future__ import annotations

import time

import numpy as np
from rclpy.duration import Duration
from rclpy.node import Node
from std_srvs.srv import Trigger

from msg_bridge import contract as C
from msg_bridge import convert as cv
from msg_bridge.convert import NS

from ..physics.sequence import FDISequence
from . import msg_class, qos, run_node
from .params import INT_MAX, Param, declare


#: The command node's parameters (docs/interfaces.md): defaults, units, ranges.
PARAMS = (
    Param("rate", 1.0, "playback speed: 1 real time, 0 as fast as possible", 0.0, 1000.0),
    Param("sample_rate_hz", 1000.0, "command sample rate [Hz]", 10.0, 100_000.0),
    Param("period_s", 0.0, "start a test every N s of simulated time (0: off) [s]", 0.0, 1e6),
    Param("autostart", False, "start one test as soon as the graph is up"),
    Param("max_tests", 0, "stop after this many tests (0: no limit)", 0, INT_MAX),
    Param("wait_for_graph_s", 10.0, "autostart/period: wait up to this long for plant and monitor subscribers [s]",
          0.0, 3600.0),
    Param("graph_grace_s", 2.0, "after plant and monitor are discovered, wait this long before autostart [s]",
          0.0, 600.0),
    Param("settle_s", FDISequence().settle, "between two tests [s of simulated time]: the actuator is brought back to the "
          "test's first command over the first half (raised cosine) and rests there", 0.0, 60.0),
    Param("max_in_flight", 200, "rate 0: samples ahead of the plant", 1, C.SAMPLE_DEPTH),
    Param("actuator_id", "eha", "joint name in the command messages"),
)


class CommandNode(Node):
    def __init__(self, name: str = "eha_command", sequence: FDISequence | None = None, **kw):
        super().__init__(name, **kw)
        declare(self, PARAMS)
        self.sequence = sequence or FDISequence()
        self.pub_cmd = self.create_publisher(msg_class(C.COMMAND), C.COMMAND.name, qos(C.COMMAND))
        self.pub_win = self.create_publisher(msg_class(C.TEST_WINDOW), C.TEST_WINDOW.name, qos(C.TEST_WINDOW))
        self._echo = self.create_subscription(msg_class(C.JOINT_STATE), C.JOINT_STATE.name, self._on_echo,
                                              qos(C.JOINT_STATE))
        self.create_service(Trigger, "eha/start_test", self._on_trigger)
        self.tests_started = 0
        self.tests_done = 0
        self.next_start_ns = 0          # simulated time of the next test's first sample
        self._test: dict | None = None  # the test being played
        self._last_u: float | None = None   # last command sent [m]
        self._last_ns = -1                  # and its stamp [ns]
        self._echo_ns = -1
        self._stall_since = None
        self._pending = bool(self.get_parameter("autostart").value)
        self._created = time.monotonic()
        self._next_wall = 0.0
        self._seen_since = None
        self.timer = self.create_timer(0.002, self._tick)

    @property
    def done(self) -> bool:
        """True once ``max_tests`` tests have been played (lets a process exit)."""
        m = self.get_parameter("max_tests").value
        return m > 0 and self.tests_done >= m and self._test is None

    # ---------------------------------------------------------------- requests
    def _on_trigger(self, request, response):
        # discovered is not matched: a plant whose answers do not reach us yet would not hear
        # the first samples either
        if self.pub_cmd.get_subscription_count() < 1 or self._echo.get_publisher_count() < 1:
            response.success, response.message = False, "no plant matched on eha/command and eha/joint_state yet"
            return response
        ok, why = self.start_test()
        response.success, response.message = ok, why
        return response

    def start_test(self) -> tuple[bool, str]:
        if self._test is not None:
            return False, f"test {self._test['id']} is still playing"
        m = self.get_parameter("max_tests").value
        if m > 0 and self.tests_started >= m:
            return False, f"max_tests={m} already played"
        fs = float(self.get_parameter("sample_rate_hz").value)
        if not fs > 0:
            return False, f"sample_rate_hz must be > 0, got {fs}"
        t = self.sequence.times(fs)
        dt_ns = round(NS / fs)
        t0 = self.next_start_ns
        self.tests_started += 1
        u = self.sequence.command(t)
        stamps = t0 + dt_ns * np.arange(len(u), dtype=np.int64)
        # The sequence ends mid-sine (-5 mm by default), but a test, and the monitor model, start
        # at rest at the first command: after an earlier test, bring the actuator back first,
        # inside the settle time before this test's start (outside its window)
        m = int(round(float(self.get_parameter("settle_s").value) / 2 * fs))
        m = min(m, max(0, (t0 - self._last_ns) // dt_ns - 1) // 2)   # settle_s raised since: fit the gap
        if self._last_u is not None and m > 0 and self._last_u != u[0]:
            back = self.sequence.return_to_start(self._last_u, m)
            lead = t0 - 2 * m * dt_ns + dt_ns * np.arange(1, m + 1, dtype=np.int64)
            u, stamps = np.concatenate([back, u]), np.concatenate([lead, stamps])
        else:
            m = 0
        self._test = {"id": self.tests_started, "u": u, "stamps": stamps, "first": m, "k": 0, "t0": t0,
                      "dt": dt_ns, "wall0": time.monotonic()}
        self._last_u, self._last_ns = float(u[-1]), int(stamps[-1])
        self.get_logger().info(f"test {self.tests_started}: {len(t)} samples at {fs:g} Hz from t={t0 / NS:.3f} s")
        return True, f"test {self.tests_started} started"

    def _graph_ready(self) -> bool:
        """Plant and monitor are discovered (or waited long enough)."""
        now = time.monotonic()
        if now - self._created > self.get_parameter("wait_for_graph_s").value:
            return True
        # a plant (publishes the answers) and a monitor (takes the marks and the answers; the
        # command node itself is the other joint_state subscriber)
        seen = (self.count_publishers(C.JOINT_STATE.name) >= 1 and self.count_subscribers(C.TEST_WINDOW.name) >= 1
                and self.count_subscribers(C.JOINT_STATE.name) >= 2 and self.count_subscribers(C.PRESSURE.name) >= 1)
        if not seen:
            self._seen_since = None
            return False
        # discovered from here; the plant-monitor matching and services may lag: give them time
        self._seen_since = self._seen_since or now
        return now - self._seen_since >= float(self.get_parameter("graph_grace_s").value)

    # ---------------------------------------------------------------- playing
    def _on_echo(self, msg) -> None:
        self._echo_ns = max(self._echo_ns, cv.stamp_ns(msg.header.stamp))

    def _tick(self) -> None:
        if self._test is None:
            self._maybe_start()
            return
        T = self._test
        n, stamps = len(T["u"]), T["stamps"]
        rate = float(self.get_parameter("rate").value)
        if rate > 0:
            due = int(np.searchsorted(stamps, stamps[0] + (time.monotonic() - T["wall0"]) * rate * NS, "right"))
        else:
            acked = int(np.searchsorted(stamps, self._echo_ns, "right"))
            due = min(n, acked + int(self.get_parameter("max_in_flight").value))
            if due <= T["k"]:   # nothing new acknowledged: is anyone answering?
                due = T["k"]    # never back: what is sent is sent
                self._stall_since = self._stall_since or time.monotonic()
                if time.monotonic() - self._stall_since > 5.0:
                    # (measured: this used to step back to the last acknowledged sample and wait
                    # 5 s again, so a test whose plant was killed took ~90 s to finish)
                    self.get_logger().warning("no plant answers for 5 s: playing on without flow control",
                                              throttle_duration_sec=5.0)
                    due = min(n, T["k"] + int(self.get_parameter("max_in_flight").value))
            else:
                self._stall_since = None
        joint = self.get_parameter("actuator_id").value
        for k in range(T["k"], due):
            if k == T["first"]:
                self.pub_win.publish(cv.window_msg(T["t0"], "start", T["id"]))
            self.pub_cmd.publish(cv.command_msg(int(stamps[k]), T["u"][k], joint))
        T["k"] = due
        if due == n:
            t_end = int(stamps[-1])
            self.pub_win.publish(cv.window_msg(t_end, "end", T["id"]))
            self.tests_done += 1
            settle = round(float(self.get_parameter("settle_s").value) * NS)
            period = round(float(self.get_parameter("period_s").value) * NS)
            self.next_start_ns = max(t_end + T["dt"] + settle, T["t0"] + period)
            # the simulated clock runs at `rate`: the next periodic test waits for it
            rate = float(self.get_parameter("rate").value)
            wait = (self.next_start_ns - t_end) / NS / rate if rate > 0 else 0.0
            self._next_wall = time.monotonic() + wait
            self._test = None

    def close(self, timeout_s: float = 5.0) -> None:
        """Before the node goes: wait (bounded) until every subscriber has acknowledged the
        samples and marks already published; a process that exits right after its last
        sample would otherwise take the end of the test with it."""
        if not self.context.ok():
            return      # shut down already (SIGINT): nothing can be delivered any more
        try:
            for pub in (self.pub_cmd, self.pub_win):
                pub.wait_for_all_acked(Duration(seconds=timeout_s))
        except KeyboardInterrupt:
            # told to stop while waiting (`launch` stops every node once the monitor is done; at
            # teardown run_node's handler raises): stop waiting, as for a SIGINT before it -- no traceback
            pass

    def _maybe_start(self) -> None:
        period = self.get_parameter("period_s").value
        if not (self._pending or period > 0) or self.done:
            return
        if not self._graph_ready():
            return
        if not self._pending and time.monotonic() < self._next_wall:
            return
        self._pending = False
        ok, why = self.start_test()
        if not ok:
            self.get_logger().warning(why)

def main(args=None) -> int:
    return run_node(CommandNode, args)


if __name__ == "__main__":
    import sys
    sys.exit(main())
