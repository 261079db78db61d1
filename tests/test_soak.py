"""Soak (issue 18): what a monitor that runs on keeps in memory stays bounded (no spinning: the
node's own report path, on a real rclpy node). The long run itself is ``eha-health bench soak``."""
import rclpy
from rclpy.parameter import Parameter
from rclpy.signals import SignalHandlerOptions

from eha_health.ros import teardown
from eha_health.ros.monitor import MonitorNode


def test_the_monitor_keeps_the_latest_verdicts_and_counts_all():
    ctx = rclpy.Context()
    rclpy.init(context=ctx, signal_handler_options=SignalHandlerOptions.NO)
    mon = None
    try:
        mon = MonitorNode(context=ctx, parameter_overrides=[Parameter("log_path", value=""),
                                                            Parameter("keep_verdicts", value=4)])
        for tid in range(1, 13):
            w = mon.windows.window(tid)
            w.start, w.end = tid * 4_000_000_000, tid * 4_000_000_000 + 3_499_000_000
            mon._report(w, None, f"test {tid}: refused for the test")
        assert mon.verdicts == 12
        assert [r["test_id"] for r in mon.results] == [9, 10, 11, 12]
        assert mon.results[-1]["level"] == "ERROR" and "test 12" in mon.results[-1]["message"]
        assert mon.windows.windows == {}
    finally:
        teardown(None, [mon] if mon is not None else [], ctx)
