"""Monitor node: record each test window, diagnose it, publish health, log everything.

Subscribes to the input topics of :mod:`msg_bridge.contract` (command, joint state,
pressure, current, test-window marks). When a window's 'end' mark has arrived and
every channel has reached that stamp (or ``window_timeout_s`` has passed), the
window is assembled and checked (:mod:`eha_health.io.window`): gaps, NaN, order,
duplicates, dropped samples, length. A good window is diagnosed in a worker thread
(:func:`eha_health.identification.diagnose`) so the executor keeps serving messages; a bad
one is reported at once as ERROR with the reason. Either way the node keeps running.

With a ``history`` file, each diagnosis is appended to that SQLite health history at the test's
operating time (``operating_hours``, else the window's ROS / simulated start stamp in hours)
and the actuator's remaining useful life follows (:mod:`eha_health.monitoring.prognosis`, in
the same worker thread): its key values join the status, P(failure before the next check)
raises it to WARN / ERROR at ``warn_p_fail`` / ``error_p_fail``, and ``eha/rul`` carries it. A history
already holding tests of ``actuator_id`` gives its RUL at start, before the first test (in a thread of its
own: the first test is diagnosed and appended meanwhile; its RUL waits for the fleet-prior fit, which it reuses).

Outputs (each also written to the log as published): ``/diagnostics`` (one status per actuator, re-published every
``diagnostics_period_s``; levels from ``warn_level`` / ``error_level`` on the
largest coefficient, and from the prognosis), ``eha/health`` (latched 2x3 array), ``eha/rul``
(latched JSON prognosis, with a history), and an MCAP log of every
input topic (raw wire bytes, ros2 profile) and every output, flushed after every window so
a crash loses at most the samples of the window in progress.
"""
from __future__ import annotations

import json
import time
from collections import Counter, deque
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

from rcl_interfaces.srv import GetParameters
from rclpy._rclpy_pybind11 import RCLError
from rclpy.node import Node
from rclpy.parameter import parameter_value_to_python
from rclpy.serialization import deserialize_message
from std_srvs.srv import Trigger

from msg_bridge import contract as C
from msg_bridge import convert as cv

from ..discrepancy.settings import DEFAULT_MAX_EFFECTS
from ..identification.diagnose import DEFAULT_METHOD, METHODS
from ..identification.fitness import FITNESSES
from ..io.bagrun import DROPPED_META, HISTORY_META, HISTORY_REFUSED_META
from ..io.mcaplog import BagWriter
from ..io.window import IncompleteWindow, NoSamples
from ..monitoring.analysis import analyse_window
from ..monitoring.health import HealthPolicy, Verdict, escalate
from ..monitoring.prognosis import PrognosisStep, actuator_rul_values, rul_values
from ..monitoring.windows import WindowTracker
from ..physics.faults import FAULT_NAMES, FAULT_UPPER
from ..prognostics.config import load_settings
from . import msg_class, qos, run_node
from .params import INT_MAX, Param, declare

#: How long a window waits for late samples once none arrives [s].
WINDOW_TIMEOUT_S = 2.0

#: Verdicts that keep their window's samples and fitted response in ``results`` (older ones drop them).
KEEP_RESPONSES = 10
#: Verdicts kept in ``results`` by default (each ~2-4 kB without its response; every verdict is in the
#: MCAP log, and with a ``history`` in the health history, so a monitor that runs on must not hold all).
KEEP_VERDICTS = 1000
#: A test this node asked for that reached it without one sample of a channel is asked for again,
#: this many times in a row at most (then it is reported, refused: the source does not reach us).
LOST_RETRIES = 3

#: The monitor's parameters (docs/interfaces.md): defaults, units, ranges. ``start_only``: read when the node
#: starts (the log, the subscriptions, the health history and its prognosis), so a change is refused.
PARAMS = (
    Param("actuator_id", "eha", "hardware_id of the diagnostic status", start_only=True),
    Param("method", DEFAULT_METHOD, "identification method", choices=tuple(METHODS)),
    Param("fitness", "lsq", "fitness function", choices=tuple(FITNESSES)),
    Param("seed", 0, "seed of the identification (GA)", 0, INT_MAX),
    Param("warn_level", 0.3, "WARN when a coefficient reaches this [-]", 0.0, FAULT_UPPER),
    Param("error_level", 0.7, "ERROR when a coefficient reaches this [-]", 0.0, FAULT_UPPER),
    Param("log_path", "auto", "MCAP log file; 'auto' = eha_monitor_<date>.mcap in log_dir; '' = no log",
          start_only=True),
    Param("log_dir", ".", "directory of the 'auto' log", start_only=True),
    Param("plant_node", "", "simulated runs: node whose k_* parameters are the truth (into MCAP metadata)",
          start_only=True),
    Param("window_timeout_s", WINDOW_TIMEOUT_S,
          "after the end mark, wait for late samples until none has come for this long [s]", 0.05, 600.0),
    Param("diagnostics_period_s", 1.0, "re-publish the status this often [s]", 0.01, 3600.0, start_only=True),
    Param("exit_after", 0, "stop after this many windows (0: run on)", 0, INT_MAX),
    Param("discrepancy", False, "after each diagnosis run the discrepancy loop; a structured residual -> WARN "
          "'model lacks: ...' (or, when no candidate explains it, WARN that the coefficients may be biased)"),
    Param("discrepancy_max_effects", DEFAULT_MAX_EFFECTS, "most effects the loop may add (as `eha-health discrepancy`)", 0, 8),
    Param("max_fill_samples", 0, "fill lost samples of a measured channel by linear interpolation when no gap is "
          "longer than this many samples (and at most 10 % are lost); 0: refuse any gap", 0, 100),
    Param("best_effort", False, "subscribe to the inputs BEST_EFFORT (a lossy link; matches both kinds of "
          "publisher) instead of RELIABLE", start_only=True),
    Param("history", "", "SQLite health history: each diagnosis is appended and the RUL published ('' = none)",
          start_only=True),
    Param("prognostics_settings", "", "YAML merged over data/prognostics.yaml for the prognosis (requirement "
          "limits, models, fleet prior; '' = the packaged settings)", start_only=True),
    Param("operating_hours", -1.0, "operating hours of the next test in the history [h]; < 0: the window's start "
          "stamp (ROS / simulated time) in hours", -1.0, 1e7),
    Param("usage", -1.0, "usage at the next test (flight hours or cycles; < 0: none)", -1.0, 1e9),
    # the declared ranges hold the "< 0: default" sentinel; 0 is refused at start (probe 11), which the text says
    Param("next_check_h", -1.0, "hours to the next check, for p_fail_next [h]: > 0 (< 0: prognosis.next_check_h "
          "of prognostics.yaml; 0 is refused)", -1.0, 1e6, start_only=True),
    Param("warn_p_fail", -1.0, "WARN when P(failure before the next check) reaches this: 0 < value <= error_p_fail "
          "(< 0: prognosis.warn_p_fail; 0 is refused)", -1.0, 1.0, start_only=True),
    Param("error_p_fail", -1.0, "ERROR when P(failure before the next check) reaches this: warn_p_fail <= value "
          "<= 1 (< 0: prognosis.error_p_fail; 0 is refused)", -1.0, 1.0, start_only=True),
    Param("request_timeout_s", 30.0, "a test asked for whose start mark has not arrived this long after the command "
          "node accepted the request is asked for again [s, wall clock]", 1.0, 3600.0),
    Param("request_tests", 0, "ask the command node (eha/start_test) for this many tests, one after each verdict, "
          "each once every input topic has a matched publisher; one that arrives without any sample of a channel "
          "is asked for again (0: never ask)", 0, INT_MAX),
    Param("keep_verdicts", KEEP_VERDICTS, "latest verdicts kept in memory (each is also in the MCAP log, when there "
          "is one); 0: all", 0, INT_MAX, start_only=True),
)


class MonitorNode(Node):
    def __init__(self, name: str = "eha_monitor", **kw):
        super().__init__(name, **kw)
        declare(self, PARAMS)
        self.prognosis = self._prognosis_step()   # a bad history or setting is refused before a log is made
        self.log = self._open_log()
        self.windows = WindowTracker()
        self._futures: deque = deque()        # diagnoses running in the worker
        self._closing = False
        self._worker = ThreadPoolExecutor(max_workers=1, thread_name_prefix="eha-diagnose")
        # the stored history's RUL, published before the first test (a restarted monitor gave none: probe 11),
        # in a thread of its own: in the diagnosis worker its fleet-prior fit (~10 s on 1000 actuators) held
        # up the first test's diagnosis. Started by the first poll, so a node whose __init__ fails after
        # this line leaves no fit running that nothing would stop.
        self._start_worker = ThreadPoolExecutor(max_workers=1, thread_name_prefix="eha-stored")
        self._stored = None
        self._stored_due = self.prognosis is not None
        keep = int(self.get_parameter("keep_verdicts").value)
        self.results: deque[dict] = deque(maxlen=keep or None)   # the latest verdicts, oldest first
        self.verdicts = 0                                        # verdicts given since the start
        self.bad_messages = 0
        self.received: Counter = Counter()   # messages per input topic
        self._status = Verdict("STALE", "no test window diagnosed yet")
        self._last_rul = None    # (level, why, key values) of the latest RUL: a window not diagnosed keeps it

        self.pub_diag = self.create_publisher(msg_class(C.DIAGNOSTICS), C.DIAGNOSTICS.name, qos(C.DIAGNOSTICS))
        self.pub_health = self.create_publisher(msg_class(C.HEALTH), C.HEALTH.name, qos(C.HEALTH))
        self.pub_rul = self.create_publisher(msg_class(C.RUL), C.RUL.name, qos(C.RUL)) if self.prognosis else None
        handlers = {C.COMMAND.name: self._on_command, C.JOINT_STATE.name: self._on_joint_state,
                    C.PRESSURE.name: self._on_pressure, C.CURRENT.name: self._on_current,
                    C.TEST_WINDOW.name: self._on_window}
        lossy = bool(self.get_parameter("best_effort").value)
        self._subs = [self.create_subscription(msg_class(topic), topic.name, self._recorder(
            topic, handlers.get(topic.name)), qos(topic, best_effort=lossy), raw=True)
                      for topic in C.INPUTS]
        self.tests_requested = 0
        self.tests_lost = 0                   # tests asked for again: no window, or a channel without a sample
        self._lost_in_row = 0
        self._request = None                  # the start_test call in flight
        self._asked_at: float | None = None   # when the command node accepted our last request [s, monotonic]
        self._next_request = 0.0
        # made when request_tests is first > 0: a monitor started with 0 and set to N at run time asks too
        self._start_client = None
        self._truth_client = None
        if self.get_parameter("plant_node").value:
            self._truth_client = self.create_client(
                GetParameters, f"{self.get_parameter('plant_node').value.rstrip('/')}/get_parameters")
        self.create_timer(0.05, self._poll)
        self.create_timer(float(self.get_parameter("diagnostics_period_s").value), self._publish_status)

    def _prognosis_step(self) -> PrognosisStep | None:
        path = self.get_parameter("history").value
        if not path:
            return None

        def opt(name):
            v = float(self.get_parameter(name).value)
            return None if v < 0 else v
        extra = self.get_parameter("prognostics_settings").value
        settings = load_settings(extra) if extra else load_settings()
        step = PrognosisStep(path, self.get_parameter("actuator_id").value, opt("next_check_h"), opt("warn_p_fail"),
                             opt("error_p_fail"), settings)   # PrognosticsError (ValueError) names a bad parameter
        self.get_logger().info(f"health history {path}: diagnoses appended, RUL on {C.RUL.name}")
        return step

    # ---------------------------------------------------------------- log
    def _open_log(self):
        path = self.get_parameter("log_path").value
        if not path:
            return None
        if path == "auto":
            path = Path(self.get_parameter("log_dir").value) / time.strftime("eha_monitor_%Y%m%d-%H%M%S.mcap")
        Path(path).parent.mkdir(parents=True, exist_ok=True)
        self.log_path = Path(path)
        w = BagWriter(path)
        w.add_metadata("eha_health", {"actuator_id": self.get_parameter("actuator_id").value,
                                      "method": self.get_parameter("method").value,
                                      "fitness": self.get_parameter("fitness").value,
                                      "created": time.strftime("%Y-%m-%dT%H:%M:%S%z")})
        self.get_logger().info(f"logging to {path}")
        return w

    def _recorder(self, topic, handler):
        cls = msg_class(topic)
        logged_as = self.resolve_topic_name(topic.name)   # fully qualified, as ros2 bag records

        def cb(data: bytes) -> None:
            self.received[topic.name] += 1
            if self.log is not None:
                self.log.write_raw(logged_as, topic.type, data, time.time_ns())
            if handler is None:
                return
            try:
                msg = deserialize_message(data, cls)
            except Exception as e:   # not CDR of this type (rclpy raises RMWError): logged as received, ignored
                msg, why = None, f"undecodable: {str(e).split(', at ')[0]}"
            try:
                if msg is None:
                    raise ValueError(why)
                handler(msg)
            except (ValueError, AttributeError, TypeError) as e:   # one bad message never stops the node
                self.bad_messages += 1
                self.get_logger().warning(f"{topic.name}: message ignored ({e})", throttle_duration_sec=1.0)
        return cb

    # ---------------------------------------------------------------- inputs
    def _put(self, name: str, ns: int, v: float) -> None:
        self.windows.put(name, ns, v)

    def _on_command(self, msg):
        ns, u = cv.command_from_msg(msg)
        self._put("command", ns, u)

    def _on_joint_state(self, msg):
        ns, x, v = cv.joint_state_from_msg(msg)
        self._put("position", ns, x)
        self._put("velocity", ns, v)

    def _on_pressure(self, msg):
        self._put("pressure", *cv.pressure_from_msg(msg))

    def _on_current(self, msg):
        self._put("current", *cv.current_from_msg(msg))

    def _on_window(self, msg):
        ns, event, tid = cv.window_from_msg(msg)
        self.windows.mark(ns, event, tid, time.monotonic(), float(self.get_parameter("window_timeout_s").value))
        if event == "start":
            self._asked_at = None
            self._fetch_truth(tid)

    def _fetch_truth(self, tid: int) -> None:
        if self._truth_client is None or not self._truth_client.service_is_ready():
            return
        names = [*FAULT_NAMES, "effects", "seed"]
        fut = self._truth_client.call_async(GetParameters.Request(names=names))

        def done(f):
            try:
                vals = f.result().values
            except Exception:   # the plant went away: no truth, no harm
                return
            truth = {n: parameter_value_to_python(v) for n, v in zip(names, vals)}
            truth["effects"] = ",".join(e for e in (truth["effects"] or []) if e)
            w = self.windows.windows.get(tid)
            if w is not None:   # a late answer must not re-open a window already reported
                w.truth = truth
            if self.log is not None:
                self.log.add_metadata(f"truth/test_{tid}", {k: str(v) for k, v in truth.items()})
        fut.add_done_callback(done)

    # ---------------------------------------------------------------- windows
    def _poll(self) -> None:
        self._check_request()
        self._maybe_request_test()
        for w in self.windows.ready(time.monotonic(), float(self.get_parameter("window_timeout_s").value)):
            self._start_diagnosis(w)
        self._collect_stored()
        self._collect()

    def _collect_stored(self) -> None:
        """Start the stored history's prognosis (first call), publish its RUL once it is done."""
        if self._stored_due:
            self._stored_due = False
            self._stored = self._start_worker.submit(self.prognosis.stored)
        f = self._stored
        if f is None or not f.done():
            return
        self._stored = None
        out = None if f.cancelled() else f.result()   # stored() never raises
        if out is None or self.verdicts:   # no test of this actuator stored; or a test's RUL came first
            return
        if out.prognosis is None:
            self.get_logger().warning(f"the stored history gives no RUL: {out.error}")
            return
        level, why = self.prognosis.level(out)
        values = actuator_rul_values(out)
        self._last_rul = (level, why, values)
        self._publish_rul(out, "stored history")
        said = f"no test window diagnosed yet: RUL of the stored history (latest test at {out.rul_time_h:g} h)"
        self._status = Verdict(level, f"{why}; {said}" if why else said, values)
        self._publish_status()
        if self.log is not None:
            self.log.flush()

    def _collect(self) -> None:
        """Report the diagnoses the worker has finished, in test order."""
        while self._futures and self._futures[0][1].done():
            w, fut = self._futures.popleft()
            if fut.cancelled():     # the node stopped before it started
                self.get_logger().warning(f"test {w.id}: not diagnosed, the monitor stopped first "
                                          f"(its samples are in the log: `eha-health history add` takes it)")
                self.windows.forget(w.id)
                continue
            try:
                d, rep, prog = fut.result()
                self._report(w, d, None, rep, prog)
            except Exception as e:   # identification refused the data (ValueError) or failed
                self._report(w, None, f"{type(e).__name__}: {e}" if not isinstance(e, ValueError) else str(e))

    def _maybe_request_test(self) -> None:
        """Ask for the next test once the previous one has its verdict and every input is matched.

        Discovery says a node exists; only a matched publisher delivers. Starting a test
        before the plant's answers reach this node would lose its first samples.
        """
        if self._request is not None or time.monotonic() < self._next_request:
            return
        if self.tests_requested >= int(self.get_parameter("request_tests").value):
            return
        if self._start_client is None:
            self._start_client = self.create_client(Trigger, "eha/start_test")
        if self.verdicts < self.tests_requested or self.busy:
            return
        if not all(s.get_publisher_count() >= 1 for s in self._subs) or not self._start_client.service_is_ready():
            return
        self._request = self._start_client.call_async(Trigger.Request())

        def done(f):
            self._request = None
            try:
                ok, why = f.result().success, f.result().message
            except Exception as e:   # the command node went away: try again later
                ok, why = False, str(e)
            if ok:
                self.tests_requested += 1
                self._asked_at = time.monotonic()
            else:
                self._next_request = time.monotonic() + 0.5
                self.get_logger().info(f"start_test refused: {why}; asking again", throttle_duration_sec=5.0)
        self._request.add_done_callback(done)

    def _start_diagnosis(self, w) -> None:
        if self.log is not None:
            self.log.flush()
        try:
            r = self.windows.assemble(w, int(self.get_parameter("max_fill_samples").value))
        except IncompleteWindow as e:   # a source stopped mid-test: say so, do not diagnose a part
            return self._report(w, None, str(e), incomplete=True)
        except NoSamples as e:
            if self._asked_again(w, e):
                return
            return self._report(w, None, str(e))
        except ValueError as e:     # WindowError: the window names what is wrong with it
            return self._report(w, None, str(e))
        args = dict(method=self.get_parameter("method").value, fitness=self.get_parameter("fitness").value,
                    seed=int(self.get_parameter("seed").value))
        self.get_logger().info(f"test {w.id}: {len(r)} samples, diagnosing ({args['method']}) ...")
        disc, max_eff = bool(self.get_parameter("discrepancy").value), int(self.get_parameter("discrepancy_max_effects").value)
        step, start_s = self.prognosis, w.start / 1e9
        hours = float(self.get_parameter("operating_hours").value)
        time_h = hours if hours >= 0 else start_s / 3600.0
        usage = float(self.get_parameter("usage").value)
        # absolute: a reader of the history may run from another folder (as for the log's history metadata)
        log = self.log_path.absolute() if self.log is not None else None

        def work():
            d, rep = analyse_window(r, disc, max_eff, **args)
            out = None
            if step is not None:   # in the worker too: the executor keeps serving messages
                out = step.after_diagnosis(d, time_h, sim_time_s=start_s, response=r, usage=usage if usage >= 0 else None,
                                           discrepancy=rep.verdict if rep is not None else None, log_path=log)
            return d, rep, out
        self._futures.append((w, self._worker.submit(work)))

    def _check_request(self) -> None:
        """A test asked for whose start mark never came (its marks, too, can go to a publisher that
        has not matched this node yet: measured, a restarted monitor waited for ever) is asked for
        again after ``request_timeout_s``, at most :data:`LOST_RETRIES` times in a row."""
        if self._asked_at is None or time.monotonic() - self._asked_at < float(self.get_parameter("request_timeout_s").value):
            return
        self._asked_at = None
        if self.verdicts >= self.tests_requested or self.busy or self.windows.windows:
            return          # answered, or a window is in hand (its start mark came before the answer)
        if self._lost_in_row >= LOST_RETRIES:
            self.get_logger().error(f"no test window reached this monitor after {LOST_RETRIES + 1} requests in a row: "
                                    "are the command node's eha/test_window marks remapped or filtered?")
            return
        self._ask_again(f"the test asked for has not started here after "
                        f"{self.get_parameter('request_timeout_s').value:g} s")

    def _asked_again(self, w, e: NoSamples) -> bool:
        """A test this node asked for, of which not one sample of a channel reached it, is asked
        for again (at most :data:`LOST_RETRIES` times in a row) rather than reported.

        Discovery is not symmetric: this node's subscription can see the publisher (and ask for a
        test) before the publisher has matched it. Measured over DDS: a monitor restarted after a
        kill -9 got the test's marks and no command sample in 3 of 14 runs -- the publisher's
        side matched it seconds later, while the test streamed.
        """
        if self.verdicts >= self.tests_requested or self._lost_in_row >= LOST_RETRIES:
            return False    # not a test of ours, or the source does not reach us at all: say so
        self._ask_again(f"test {w.id}: {e} -- none reached this monitor, which asked for the test")
        self.windows.forget(w.id)
        return True

    def _ask_again(self, why: str) -> None:
        """A test asked for did not reach this node: the request is made again (counted, said)."""
        self._lost_in_row += 1
        self.tests_lost += 1
        self.tests_requested -= 1
        self.get_logger().warning(f"{why}; asking for another ({self._lost_in_row} of {LOST_RETRIES})")

    def _policy(self) -> HealthPolicy:
        return HealthPolicy(float(self.get_parameter("warn_level").value), float(self.get_parameter("error_level").value))

    def _report(self, w, d, error: str | None, rep=None, prog=None, incomplete: bool = False) -> None:
        entry = {"test_id": w.id, "start_ns": w.start, "truth": w.truth, "response": w.response, "diagnosis": d}
        if d is None:
            if incomplete:
                v = self._policy().incomplete(w.id, error)
                self.get_logger().warning(v.message)
            else:
                v = self._policy().refused(w.id, error)
                self.get_logger().error(v.message)
            if self._last_rul is not None:   # the actuator's RUL stands, as on the latched eha/rul (probe 11)
                v = escalate(v, *self._last_rul)
        else:
            v = self._policy().verdict(w.id, w.start, d, rep, (w.response.meta or {}).get("filled"))
            if rep is not None:
                entry["discrepancy"] = rep
            if prog is not None:
                v = self._with_prognosis(w, v, prog)
                entry["prognosis"] = prog
            k = d.faults.as_tuple()
            self._publish(self.pub_health, C.HEALTH, cv.health_msg(k, [d.std[n] for n in FAULT_NAMES]))
            self.get_logger().info(f"test {w.id}: " + ", ".join(f"{n.upper()}={x:.3f}" for n, x in zip(FAULT_NAMES, k))
                                   + f" ({d.wall_time_s:.2f} s) -> {v.level}")
            if self.log is not None:
                self.log.add_metadata(f"diagnosis/test_{w.id}", {
                    k_: json.dumps(x, default=float) for k_, x in d.as_dict().items()})
                if rep is not None:
                    self.log.add_metadata(f"discrepancy/test_{w.id}", {
                        k_: json.dumps(x, default=float) for k_, x in rep.as_dict().items()})
        entry.update(level=v.level, message=v.message)
        self.results.append(entry)
        self.verdicts += 1
        self._lost_in_row = 0
        # only the last windows' samples and fitted responses stay (~0.4 MB a test: 300 tests would hold 120 MB)
        if len(self.results) > KEEP_RESPONSES:
            old = self.results[-KEEP_RESPONSES - 1]
            old["response"] = None
            if old["diagnosis"] is not None:
                old["diagnosis"].fitted = None
        self._status = v
        self._publish_status()
        if self.log is not None:
            self.log.flush()
        self.windows.forget(w.id)

    def _with_prognosis(self, w, v: Verdict, prog) -> Verdict:
        """The verdict with the RUL key values and level; publish the RUL and log where the test went."""
        level, why = self.prognosis.level(prog)
        if prog.prognosis is not None:
            self._last_rul = (level, why, actuator_rul_values(prog))
        if prog.error:
            self.get_logger().warning(f"test {w.id}: {prog.error}")
            why = "; ".join(filter(None, [why, prog.error]))
            level = "WARN" if level == "OK" else level
        aid = self.get_parameter("actuator_id").value
        if prog.prognosis is not None:
            self._publish_rul(prog, "test")
        if self.log is not None and (prog.appended or prog.error):
            usage = float(self.get_parameter("usage").value)
            where = {"actuator_id": aid, "time_h": repr(prog.time_h), "sim_time_s": repr(w.start / 1e9),
                     # absolute: `history add` of the log may run from another folder (probe 11)
                     "history": str(Path(self.get_parameter("history").value).absolute()),
                     **({"usage": repr(usage)} if usage >= 0 else {})}
            if prog.appended:
                self.log.add_metadata(HISTORY_META.format(w.id), where)
            else:   # the refused test is in the log too, with why (history add of the log may store it)
                self.log.add_metadata(HISTORY_REFUSED_META.format(w.id), {**where, "error": prog.error})
        return escalate(v, level, why, rul_values(prog))

    def _publish_rul(self, prog, source: str) -> None:
        self._publish(self.pub_rul, C.RUL, cv.rul_msg({
            "actuator_id": self.get_parameter("actuator_id").value, "source": source, "time_h": prog.rul_time_h,
            "test_time_h": prog.time_h, "next_check_h": self.prognosis.next_check_h, **prog.prognosis}))

    def _publish_status(self) -> None:
        v = self._status
        aid = self.get_parameter("actuator_id").value
        self._publish(self.pub_diag, C.DIAGNOSTICS, cv.diagnostic_array(
            self.get_clock().now().nanoseconds, f"{self.get_name()}: {aid}", aid, v.level, v.message, v.values))

    def _publish(self, pub, topic, msg) -> None:
        """Publish, and log what was published (every estimate is in the log)."""
        try:
            pub.publish(msg)
        except RCLError:
            if not self._closing:
                raise
            # Ctrl-C shut the context down before close(): the log still gets what would have gone out
        if self.log is not None:
            self.log.write(self.resolve_topic_name(topic.name), topic.type, msg, time.time_ns())

    # ---------------------------------------------------------------- life cycle
    @property
    def busy(self) -> bool:
        return bool(self.windows.waiting or self._futures)

    @property
    def done(self) -> bool:
        n = int(self.get_parameter("exit_after").value)
        return n > 0 and self.verdicts >= n

    def close(self) -> None:
        """Stop the worker, report what it finished and close the log (writes its summary).

        A running prognosis (of a test, or the stored history's at start) ends early (its test is appended; the fleet-prior fit, ~20 s on
        a 1000-actuator history, is cut short); the running diagnosis finishes and goes into the
        log; windows not yet started are dropped with a warning (their samples are in the log), so is
        a window cut off by the stop (its samples still arriving)."""
        if self.prognosis is not None:
            self.prognosis.stop()
        self._start_worker.shutdown(wait=True, cancel_futures=True)
        self._worker.shutdown(wait=True, cancel_futures=True)
        self._closing = True
        self._collect()
        for w in list(self.windows.windows.values()):   # never queued for a diagnosis: cut off (probe 11)
            why = ("its samples were still arriving (no end mark)" if w.end is None else
                   "it waited for its last samples" if w.start is not None else "it had an end mark only")
            self.get_logger().warning(f"test {w.id}: not diagnosed, the monitor stopped while {why}; the samples "
                                      f"that came are in the log")
            if self.log is not None:   # said in the log too: a reader of it later sees why the test has no verdict
                self.log.add_metadata(DROPPED_META.format(w.id), {"reason": f"the monitor stopped while {why}"})
            self.windows.forget(w.id)
        if self.log is not None:
            self.log.close()
            self.log = None


def main(args=None) -> int:
    return run_node(MonitorNode, args)


if __name__ == "__main__":
    import sys
    sys.exit(main())

