"""monitor_node: the online conformance monitor (Theorem 1 each 4 ms tick) with safe stop.

Pairs ``/joint_states`` (y = position) and ``/plant_input`` (u_p) by header stamp and joint
name, feeds :class:`reachset_ros.conformance.monitor.Monitor` one tick at a time, publishes
``/conformance/status`` every tick and ``/diagnostics`` at about 1 Hz. On the first
violation, or on a fault (missing data for more than ``max_missing_ticks`` ticks, an
invalid sample, a joint-name mismatch, a stamp going backwards, a stream on which the test
cases the model needs cannot be formed: ``coverage``, a position reading stuck while the
joint's ``/reference`` moves: ``invalid_sample``), it publishes a latched
``/safe_stop`` (reliable, transient local) and writes the offending window (the last
k* + history ticks) to a bag. Only a reset clears the stop: ``~/reset`` (std_srvs/Trigger)
or ``~/reset_stop`` (reachset_msgs/ResetStop, naming the caller and the reason); refused
while the stop's condition persists, logged either way (``PRIVILEGED``). An operator latches
a stop of kind ``manual`` through ``~/stop`` (reachset_msgs/ResetStop as the request: caller and
reason; ``reachset stop``), logged the same way and cleared only by that reset. The model (sets,
horizon, estimator) comes from ``model_file`` and can be swapped through the parameter
service; a refused change leaves the running model as it was.
Skipped input (repeated or stale stamps, incomplete ticks, gaps) is counted on
``/diagnostics``; see :class:`MonitorCore` for what each kind of bad input becomes. A tick
at which nothing was checked is published with ``conformant`` false (a violation is a
margin < 0, and latches the stop).

Start-up (issue 34.1): a ``model_file`` that is empty, missing, unreadable or refused (or an
``input_source: effort`` whose robot cannot be loaded) ends the node at once: a one-line error,
exit status 2, nothing published. Otherwise the node starts with an active, latched stop,
``kind: not_ready`` (reason ``not ready: ...``), and releases it itself (``active: false``,
reason :data:`~reachset_ros.nodes.common.MONITOR_STARTED`) only after k* + 1 consecutive ticks
checked to the horizon, all conformant, on every input (a tick needs both ``/joint_states``
and ``/plant_input``; ``/joint_states`` alone with ``input_source: effort``): an input that
never arrives (a remap error) keeps the arm stopped, and ``/diagnostics`` names it. The
controller holds the arm meanwhile with the braking law and the drives, no brakes (category
2): the held arm is the modelled plant, and its ticks are the checked ticks that release the
stop. A reset never clears the start-up stop; a
fault or violation while not ready replaces it with a latched stop of its own (with its
window bag; the start-up stop writes none: nothing offended). The start-up stop is also held
while the running controller/observer pair is not certified under the model (row G19,
:mod:`.monitor_pair`), and a ``model_file`` change under which it is not is refused.
"""
from __future__ import annotations

import collections
import threading
import time
from pathlib import Path

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rcl_interfaces.msg import SetParametersResult
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from reachset_msgs.msg import ConformanceStatus, JointReference, PlantInput, SafeStop
from sensor_msgs.msg import JointState
from reachset_msgs.srv import ResetStop
from std_srvs.srv import Trigger

from .. import defaults, guarantees
from ..conformance import envelope as ev_envelope
from ..conformance import model as mdl
from ..bags import BagWriter, joint_state, plant_input
from ..conformance.monitor_core import TOPIC, MonitorCore
from ..conformance.watches import FaultEvent, TickEvent
from ..errors import ReachsetError
from ..robot.effort import load_effort_input
from .audit import log_privileged
from .monitor_pair import PairHold
from .monitor_status import StatusMessage, TickTimes
from .param_callbacks import StagedRequest, add_parameter_callbacks
from .common import MONITOR_NOT_READY, MONITOR_STARTED, SAFE_STOP_QOS, STATUS_QOS, declare_realtime_priority, desc, spin_node, stamp_ns, to_stamp

#: /joint_states and /plant_input into the monitor: reliable, and deep (2 s at 250 Hz), so a
#: burst or a stalled executor costs latency, not ticks (samples wait in the DDS reader).
INPUT_QOS = QoSProfile(depth=500, reliability=ReliabilityPolicy.RELIABLE,
                       durability=DurabilityPolicy.VOLATILE, history=HistoryPolicy.KEEP_LAST)


defaults.register("monitor", {
    "outside_envelope": ("warn", "what the monitor does at a tick whose data lie outside the model's validated "
                                 "envelope (issue 37): 'warn' (diagnostics WARN) or 'stop'; the envelope is an "
                                 "empirical record of where the identification data were, not a guarantee "
                                 "(docs/theory.md, row G22), so outside is no fault by default"),
}, owner=__name__)


class MonitorNode(Node):
    """ROS adapter of :class:`MonitorCore`."""

    #: True in the managed (lifecycle) variant (monitor_lifecycle_node): the model is loaded
    #: on the configure transition and the initial safe-stop state is the variant's
    MANAGED = False
    #: joints outside the validated envelope at the last tick (issue 37; diagnostics)
    envelope_outside = ()

    def __init__(self):
        super().__init__("monitor_node")
        declare_realtime_priority(self)
        self.declare_parameter("model_file", "", desc("conformance model YAML (identify/synthesize output)"))
        self.declare_parameter("joints", [""], desc("joints to monitor (default: all of the model)"))
        self.declare_parameter("max_missing_ticks", 125, desc("missing-data limit: ticks without a complete sample, or "
                                                               "(after the warm-up) without the checks the model "
                                                               "needs, before a fault",
                                                               1, 10000, integer=True))
        self.declare_parameter("gap_window", MonitorCore.GAP_WINDOW,
                               desc("lossy-link limit: samples lost again within this many ticks (stamp time) of "
                                    "the previous loss is a coverage fault (0: off)", 0, 100000, integer=True))
        self.declare_parameter("stuck_ticks", MonitorCore.STUCK_TICKS,
                               desc("stuck-sensor rule: a joint's position reading repeated this many times in a "
                                    "row while its /reference moves at >= stuck_speed is an invalid_sample fault "
                                    "(0: off; no /reference: not checked)", 0, 100000, integer=True))
        self.declare_parameter("stuck_speed", MonitorCore.STUCK_SPEED,
                               desc("stuck-sensor rule: the reference speed, rad/s, at which a joint must move",
                                    1e-6, 100.0))
        self.declare_parameter("outside_envelope", defaults.get("monitor.outside_envelope"),
                               desc("what a tick whose data lie outside the model's validated envelope does "
                                    "(issue 37): 'warn' (diagnostics WARN naming the joints) or 'stop' (a safe "
                                    "stop of kind outside_envelope); a violation's stop reason says either way "
                                    "whether the data were inside; a model without an envelope: nothing classified"))
        self.outside_mode = self._outside_mode(self.get_parameter("outside_envelope").value)
        self.declare_parameter("window_dir", "bags/safe_stop", desc("where offending windows are written"))
        self.declare_parameter("dt", 0.004, desc("tick period, s (the watchdog's timer, read at start-up)", 1e-4, 1.0,
                                                 read_only=True))
        self.declare_parameter("reset_clean_ticks", -1,
                               desc("~/reset clears an active stop only after this many consecutive ticks checked "
                                    "to the horizon, all conformant, with no fault (the violating condition has "
                                    "cleared); -1: the model's k* + 1; 0: reset unconditionally", -1, 100000,
                                    integer=True))
        self.declare_parameter("input_source", "plant_input",
                               desc("where u_p comes from: 'plant_input' (the topic) or 'effort' (computed from "
                                    "/joint_states position, velocity and effort with robot_urdf: u_p = "
                                    "M^-1(q) (tau - psi(q, qd)), as `reachset check --input effort`)", read_only=True))
        self.declare_parameter("robot_urdf", "", desc("input_source effort: the robot's URDF (nominal M, psi)",
                                                      read_only=True))
        self.declare_parameter("robot_params", "", desc("input_source effort: identified parameters applied over "
                                                        "the URDF (optional)", read_only=True))
        self.declare_parameter("robot_locked_joints", [""], desc("input_source effort: URDF joints locked at their "
                                                                 "neutral configuration (e.g. gripper fingers that "
                                                                 "/joint_states does not carry)", read_only=True))
        self.clean_ticks = 0          # consecutive ticks checked to k*, conformant, no fault (since the last one that was not)
        self.last_unclean = "no tick checked yet"
        self.core = None
        self.stop_active = False
        self.stop_msg = None
        self.last_tick_wall = None
        self.last_rx_wall = {}        # topic kind ("y", "u") -> wall time of its last message
        self.first_rx_wall = {}       # topic kind -> its first message since the model was loaded / reset
        self.counters = collections.Counter()   # node-level: messages ignored without a model
        self.tick_times = TickTimes()           # the whole tick's wall time (issue 38.4, /diagnostics)
        self.publish_times = TickTimes("publish_wall")   # its part in publishing the status
        self.statuses = 0                       # /conformance/status messages published
        self.status_msg = StatusMessage()
        self.model_id = ""
        self.status_pub = self.create_publisher(ConformanceStatus, "conformance/status", STATUS_QOS)
        self.stop_pub = self.create_publisher(SafeStop, "safe_stop", SAFE_STOP_QOS)
        self.diag_pub = self.create_publisher(DiagnosticArray, "diagnostics", 10)
        self.effort, self.effort_error = None, ""
        source = self.get_parameter("input_source").value
        if source == "effort":
            try:
                lock = [j for j in self.get_parameter("robot_locked_joints").value if j]
                self.effort = load_effort_input(self.get_parameter("robot_urdf").value or None,
                                                self.get_parameter("robot_params").value or None, lock=lock or None)
            except (ReachsetError, OSError) as e:
                self.effort_error = f"input_source effort: {e}"
        elif source != "plant_input":
            self.effort_error = f"input_source must be 'plant_input' or 'effort', got {source!r}"
        self.create_subscription(JointState, "joint_states", self.on_joint_states, INPUT_QOS)
        if source != "effort":
            self.create_subscription(PlantInput, "plant_input", self.on_plant_input, INPUT_QOS)
        self.create_subscription(JointReference, "reference", self.on_reference, INPUT_QOS)
        self.create_service(Trigger, "~/reset", self.on_reset)
        self.create_service(ResetStop, "~/reset_stop", self.on_reset_stop)
        self.create_service(ResetStop, "~/stop", self.on_manual_stop)
        self.create_timer(1.0, self.publish_diagnostics)
        self.create_timer(float(self.get_parameter("dt").value), self.watchdog)
        self.create_timer(float(self.get_parameter("dt").value), self.repeat_stop)
        self.param_request = StagedRequest()
        self.pair_hold = PairHold(self)     # row G19: the running pair under this model
        add_parameter_callbacks(self, on_set=self.on_set_parameters, post_set=self.post_set_parameters)
        if self.MANAGED:                        # the managed variant loads the model on configure
            if self.effort_error:
                self.get_logger().error(self.effort_error + " (no model can be loaded until it is fixed)")
            return
        # issue 34.1: a monitor that cannot check never runs (exit 2, one line, nothing
        # published); one that can starts with an active stop that it releases itself
        path = self.get_parameter("model_file").value
        if not path:
            raise guarantees.refused("G12", "model_file is empty: without a model nothing can be checked")
        ok, why = self.load(path)
        if not ok:
            why = " ".join(f"model_file: {why}".split())
            # a refusal of the model's own (e.g. G1, G17) names its row; any other is G12's
            raise ReachsetError(why) if "[guarantee " in why else guarantees.refused("G12", why)
        self.enter_not_ready("no tick checked yet")

    def publish_stop_state(self, active, kind, reason):
        """Publish (latched) a safe-stop state stamped now, without a check's details: the
        start-up state, a reset, the managed variant's lifecycle stop."""
        self.stop_active = active
        m = SafeStop()
        m.header.stamp = self.get_clock().now().to_msg()
        m.active, m.kind, m.reason = active, kind, reason
        self.stop_msg = m
        self.stop_pub.publish(m)

    def enter_not_ready(self, why):
        """Latch the start-up stop (``kind: not_ready``, issue 34.1): nothing is released until
        :meth:`release_when_ready` has seen ``k* + 1`` consecutive ticks checked to the
        horizon, all conformant, which takes both inputs (a tick is a /joint_states and a
        /plant_input sample of the same stamp; /joint_states alone with ``input_source:
        effort``). Written without an offending window: nothing offended."""
        why = self.pair_hold.explain(why)      # a pair not certified under the model holds it (G19)
        self.clean_ticks, self.last_unclean = 0, why
        need = self.core.model.horizon + 1 if self.core is not None else "k*+1"
        self.publish_stop_state(True, "not_ready",
                                f"{MONITOR_NOT_READY} {why}; released after {need} consecutive ticks checked to "
                                "the horizon, all conformant, on every input")
        self.get_logger().warning(f"safe stop latched until the monitor is ready: {self.stop_msg.reason}")

    @property
    def not_ready(self):
        """True while the active stop is the start-up stop (``kind: not_ready``)."""
        return self.stop_active and self.stop_msg is not None and self.stop_msg.kind == "not_ready"

    def release_when_ready(self):
        """Release the start-up stop once ``k* + 1`` consecutive ticks were checked to the
        horizon and conformant (the clean-tick count of :meth:`handle_events`); a stop
        latched by a check stays (only a reset clears it)."""
        if (self.not_ready and self.core is not None and self.clean_ticks >= self.core.model.horizon + 1
                and not self.pair_hold.reason):
            self.publish_stop_state(False, "reset", MONITOR_STARTED)
            self.get_logger().info(f"ready: {self.clean_ticks} consecutive ticks checked to k*="
                                   f"{self.core.model.horizon}, all conformant; the start-up stop is released")

    def repeat_stop(self):
        """Bounded delivery (issue 17.2): an active stop is published again every tick period
        (the same message, the same stamp) until a reset, whatever the data do, so a sample
        lost on the otherwise idle topic is replaced within a tick instead of at the DDS
        heartbeat period (3 s); receivers treat a repeat as the stop they already have."""
        if self.stop_active and self.stop_msg is not None:
            self.stop_pub.publish(self.stop_msg)

    def restart_watchdog(self):
        """Forget the wall times of the last tick and messages: the missing-data watchdog
        starts again from the next messages (a new model, a reset, an activation)."""
        self.last_tick_wall = None
        self.last_rx_wall.clear()
        self.first_rx_wall.clear()

    # -- configuration ------------------------------------------------------------------
    def build(self, path, joints=None, new=None):
        """A new :class:`MonitorCore` for ``path`` (not applied); ``(core, model_id, reason)``.
        ``new``: parameter values of a request not applied yet (the others are read)."""
        if self.effort_error:
            return None, "", self.effort_error
        new = new or {}

        def param(name):
            return new[name] if name in new else self.get_parameter(name).value

        try:
            model = mdl.load(path)
            mdl.require_input_source(model, self.effort, source=path)    # u_p as the model's (issue 34.10)
            joints = joints if joints is not None else [j for j in self.get_parameter("joints").value if j]
            core = MonitorCore(model, joints or None, param("max_missing_ticks"), self.effort,
                               param("stuck_ticks"), param("stuck_speed"), param("gap_window"))
            model_id = mdl.file_sha256(path)[:12]
        except (ReachsetError, OSError) as e:
            return None, "", str(e)
        return core, model_id, ""

    def apply(self, core, model_id, path):
        self.core = core
        self.model_id = model_id
        self.clean_ticks, self.last_unclean = 0, "no tick checked yet"
        self.restart_watchdog()
        self.get_logger().info(f"monitoring joints {core.joints} with model {path} (k*={core.model.horizon})")

    def load(self, path, joints=None):
        core, model_id, why = self.build(path, joints)
        if core is None:
            return False, why
        self.apply(core, model_id, path)
        self.pair_hold.start(core.model)        # held until the running pair is certified (G19)
        return True, ""

    def _outside_mode(self, value):
        """``outside_envelope`` at start-up: a value that is neither warn nor stop stops (fail closed)."""
        if value not in ev_envelope.OUTSIDE_ENVELOPE:
            self.get_logger().error(f"outside_envelope must be 'warn' or 'stop', got {value!r}: stopping outside it")
            return "stop"
        return value

    def on_set_parameters(self, params):
        """Validate the whole request first (on_set): a new model is built, not applied, so a
        refused request leaves the running configuration as it was."""
        new = {p.name: p.value for p in params}
        if "outside_envelope" in new and new["outside_envelope"] not in ev_envelope.OUTSIDE_ENVELOPE:
            return SetParametersResult(successful=False, reason=f"outside_envelope must be 'warn' or 'stop', got "
                                                                f"{new['outside_envelope']!r}")
        if "model_file" in new and not new["model_file"]:
            return SetParametersResult(successful=False, reason="model_file must not be empty")
        staged = None
        if "model_file" in new or "joints" in new:
            path = new.get("model_file", self.get_parameter("model_file").value)
            joints = [j for j in new.get("joints", self.get_parameter("joints").value) if j]
            if path:
                core, model_id, why = self.build(path, joints, new)
                if core is None:
                    return SetParametersResult(successful=False, reason=why)
                why = self.pair_hold.check_now(core.model) if "model_file" in new else ""
                if why:                         # row G19: the running pair under the new model
                    return SetParametersResult(successful=False, reason=why)
                staged = (core, model_id, path)
        self.param_request.hold(params, staged)
        return SetParametersResult(successful=True)

    def post_set_parameters(self, params):
        """Apply what :meth:`on_set_parameters` accepted (post_set): the new model, or the
        running check's coverage and stuck-sensor rules."""
        staged = self.param_request.take(params)
        new = {p.name: p.value for p in params}
        if "outside_envelope" in new:
            self.outside_mode = new["outside_envelope"]
        if "model_file" in new or "joints" in new:
            if staged is not None:
                self.apply(*staged)
                if "model_file" in new:         # on_set certified the running pair under it
                    self.pair_hold.start(staged[0].model, "")
        elif self.core is not None:
            if "max_missing_ticks" in new:
                self.core.coverage.set_max_missing_ticks(new["max_missing_ticks"])
            if "gap_window" in new:
                self.core.coverage.set_gap_window(new["gap_window"])
            if "stuck_ticks" in new or "stuck_speed" in new:
                self.core.set_stuck_rule(new.get("stuck_ticks", self.get_parameter("stuck_ticks").value),
                                         new.get("stuck_speed", self.get_parameter("stuck_speed").value))

    # -- data ---------------------------------------------------------------------------
    def on_joint_states(self, msg):
        t0, n0 = time.perf_counter_ns(), self.statuses
        if self.effort is not None:
            if self.core is None:
                self.counters["ignored_without_model"] += 1
                return
            now = time.monotonic()
            for kind in TOPIC:          # both halves of the tick come with this message
                self.last_rx_wall[kind] = now
                self.first_rx_wall.setdefault(kind, now)
            self.handle_events(self.core.add_joint_state(stamp_ns(msg.header.stamp), list(msg.name), msg.position,
                                                         msg.velocity, msg.effort))
        else:
            self.on_data("y", msg.header.stamp, msg.name, msg.position)
        if self.statuses != n0:                 # this message completed a tick: its whole time
            self.tick_times.add(time.perf_counter_ns() - t0)

    def on_plant_input(self, msg):
        t0, n0 = time.perf_counter_ns(), self.statuses
        self.on_data("u", msg.header.stamp, msg.name, msg.acceleration)
        if self.statuses != n0:
            self.tick_times.add(time.perf_counter_ns() - t0)

    def on_reference(self, msg):
        """/reference feeds the stuck-sensor rule only (no tick, no watchdog)."""
        if self.core is not None:
            self.core.add_reference(stamp_ns(msg.header.stamp), list(msg.name), msg.velocity)

    def on_data(self, kind, stamp, names, values):
        if self.core is None:
            self.counters["ignored_without_model"] += 1
            return
        now = time.monotonic()
        self.last_rx_wall[kind] = now
        self.first_rx_wall.setdefault(kind, now)
        self.handle_events(self.core.add(kind, stamp_ns(stamp), names, values))

    def handle_events(self, events):
        for ev in events:
            if isinstance(ev, FaultEvent):
                self.clean_ticks, self.last_unclean = 0, f"{ev.kind} at stamp {ev.stamp}: {ev.reason}"
                self.trigger(ev.stamp, ev.kind, ev.reason, ev.joint)
                continue
            stamp, res = ev.stamp, ev.result
            out = ev.outside_envelope
            self.envelope_outside = () if out is None or not any(out) else \
                tuple(n for n, o in zip(self.core.joints, out) if o)
            # with outside_envelope: stop, a tick outside the envelope is not clean: a reset (and the
            # start-up release) waits until the data are back inside, or the monitor would grant a
            # reset and stop again at the next tick (issue 37.2)
            outside_stops = bool(self.envelope_outside) and self.outside_mode == "stop"
            conformant = ev.conformant
            if conformant and ev.longest >= self.core.model.horizon and not outside_stops:
                self.clean_ticks += 1
            else:
                self.clean_ticks = 0
                self.last_unclean = (f"tick {stamp} not conformant" if "violation" in res["status"] else
                                     f"tick {stamp} outside the validated envelope on "
                                     f"{', '.join(self.envelope_outside)} (outside_envelope: stop)"
                                     if conformant and ev.longest >= self.core.model.horizon else
                                     f"tick {stamp} checked only up to step {ev.longest} of k*={self.core.model.horizon}")
            self.last_tick_wall = time.monotonic()
            self.publish_status(ev, conformant)
            if self.stop_active:
                self.release_when_ready()
            if "violation" in res["status"]:
                j = res["status"].index("violation")
                self.trigger(stamp, "violation",
                             f"joint {self.core.joints[j]} left its reachable set at step k={int(res['step'][j])}: "
                             f"N y_a = {res['deviation'][j]:.6g} > bound {res['bound'][j]:.6g}"
                             + ev_envelope.violation_note(None if out is None else out[j]),
                             self.core.joints[j], int(res["step"][j]),
                             int(res["start_tick"][j]), float(res["deviation"][j]), float(res["bound"][j]))
            if self.envelope_outside and self.outside_mode == "stop":
                self.trigger(stamp, "outside_envelope", ev_envelope.outside_reason(self.envelope_outside, stamp),
                             self.envelope_outside[0])

    def publish_status(self, ev: TickEvent, conformant):
        """``/conformance/status`` of a tick (the message built once, :class:`StatusMessage`).
        ``conformant``: ``ev.conformant`` (a property, computed once by the caller): true only
        if every joint checked a test case and none was violated: a tick at which nothing was checked
        (warm-up after a start, reset or gap) is not conformant; a violation is a margin < 0
        (margin is +1e300 where nothing was checked)."""
        core = self.core
        m = self.status_msg.fill(stamp=ev.stamp, result=ev.result,
                                 conformant=conformant,
                                 stop_active=self.stop_active, tick=core.ticks_since_reset,
                                 horizon=core.model.horizon, joints=core.joints, duration=ev.duration,
                                 model_id=self.model_id)
        t0 = time.perf_counter_ns()
        self.status_pub.publish(m)
        self.publish_times.add(time.perf_counter_ns() - t0)
        self.statuses += 1

    def trigger(self, stamp, kind, reason, joint="", step=-1, start_tick=-1, deviation=0.0, bound=0.0):
        """Latch the safe stop (first cause wins; a fault or violation while not ready replaces
        the start-up stop: it is latched, only a reset clears it) and write the offending window."""
        if self.stop_active and not self.not_ready:
            return
        self.stop_active = True
        m = SafeStop()
        to_stamp(m.header.stamp, stamp)
        m.active, m.kind, m.reason, m.joint = True, kind, reason, joint
        m.step = int(step)
        m.deviation, m.bound = float(deviation), float(bound)
        if start_tick >= 0 and self.core is not None:
            m.test_case_start_ns = int(stamp - step * self.core.dt_ns)   # step k of the model's ticks
        m.window_bag = self.write_window(stamp, kind)
        self.stop_msg = m
        self.stop_pub.publish(m)
        self.get_logger().error(f"SAFE STOP ({kind}): {reason}")

    def write_window(self, stamp, kind):
        if self.core is None or not self.core.window:
            return ""
        rows = list(self.core.window)
        names = list(self.core.joints)
        out = Path(self.get_parameter("window_dir").value) / f"safe_stop_{stamp}_{kind}"

        def write():
            try:
                out.parent.mkdir(parents=True, exist_ok=True)
                with BagWriter(out) as w:
                    for s, y, u in rows:
                        w.write("/joint_states", joint_state(s, names, y), s)
                        w.write("/plant_input", plant_input(s, names, u), s)
            except Exception as e:  # never kill the node for a failed write
                self.get_logger().error(f"could not write window bag {out}: {e}")

        threading.Thread(target=write, daemon=True).start()
        return str(out)

    def watchdog(self):
        """Missing data: no complete tick for ``max_missing_ticks`` periods (wall time), once
        the loop has started, i.e. since the last tick or, before the first one, since both
        topics have delivered a message (so a topic that goes silent, or two topics whose
        stamps never pair, end in a safe stop). While a topic has never arrived the monitor
        waits and says so on /diagnostics (WARN): a controller still starting is no fault."""
        if self.core is None or self.stop_active:
            return
        since = self.last_tick_wall
        if since is None:
            if len(self.first_rx_wall) < len(TOPIC):
                return
            since = max(self.first_rx_wall.values())
        limit = self.get_parameter("max_missing_ticks").value * self.get_parameter("dt").value
        now = time.monotonic()
        silent = now - since
        if silent > limit:
            stamp = self.core.last_stamp or max(self.core.topic_last.values(), default=0) \
                or self.get_clock().now().nanoseconds
            detail = [f"{topic} silent for {(now - self.last_rx_wall[kind]) * 1000:.0f} ms"
                      for kind, topic in TOPIC.items() if now - self.last_rx_wall[kind] > limit]
            if not detail:
                detail.append("both topics arrive but their stamps do not pair")
            skipped = {k: v for k, v in self.core.counters.items()
                       if k.startswith(("stale_", "duplicate_", "dropped_", "rejected_")) and v}
            if skipped:
                detail.append("skipped so far: " + ", ".join(f"{k} {v}" for k, v in sorted(skipped.items())))
            self.trigger(stamp, "missing_data",
                         f"no complete /joint_states + /plant_input sample for {silent * 1000:.0f} ms "
                         f"(limit {limit * 1000:.0f} ms): " + "; ".join(detail))

    def clean_needed(self):
        n = int(self.get_parameter("reset_clean_ticks").value)
        return (self.core.model.horizon + 1 if self.core is not None else 0) if n < 0 else n

    def on_reset(self, request, response):
        """``~/reset`` (std_srvs/Trigger, which names no caller): :meth:`reset_stop`."""
        response.success, response.message = self.reset_stop("", "", "~/reset")
        return response

    def on_reset_stop(self, request, response):
        """``~/reset_stop`` (reachset_msgs/ResetStop: the caller and the reason): :meth:`reset_stop`."""
        response.success, response.message = self.reset_stop(request.caller, request.reason, "~/reset_stop")
        return response

    def on_manual_stop(self, request, response):
        """``~/stop`` (reachset_msgs/ResetStop as the request: the caller and the reason): :meth:`manual_stop`."""
        response.success, response.message = self.manual_stop(request.caller, request.reason)
        return response

    def manual_stop(self, caller, reason):
        """An operator's stop (issue 36.2, ``reachset stop``): latch ``/safe_stop`` with kind
        ``manual`` and the reason, as a check latches one (the controller's category-1 stop,
        the offending window written); it replaces the start-up stop, and only the audited
        reset (:meth:`reset_stop`) clears it. A stop already latched by a check stays as it is
        (the first cause wins; the arm is stopped already). Every request is a ``PRIVILEGED``
        log line. Returns ``(success, message)``: success means a stop is latched now."""
        services = [self.resolve_service_name("~/stop")]
        why = " ".join((reason or "").split())
        if self.stop_active and not self.not_ready:
            message = (f"a safe stop is latched already ({self.stop_msg.kind}: {self.stop_msg.reason}); it stays "
                       "until the reset")
        else:
            stamp = ((self.core.last_stamp if self.core is not None else 0) or self.get_clock().now().nanoseconds)
            self.trigger(stamp, "manual", "manual stop through ~/stop" + (f" by {caller}" if caller else "")
                         + (f": {why}" if why else ""))
            message = "safe stop latched (kind manual); only the reset clears it"
        log_privileged(self, "manual safe stop through ~/stop", caller, reason, f"granted ({message})", services)
        return True, message

    def reset_stop(self, caller, reason, via):
        """Clear the safe stop, only once its cause has cleared: the monitor keeps checking
        while stopped (the held arm against the model), and a reset needs ``reset_clean_ticks``
        consecutive ticks checked to k*, all conformant, no fault, the last one within the
        missing-data limit (fresh data). Refused otherwise, with the reason. Every request,
        granted or refused, is a ``PRIVILEGED`` log line (:mod:`reachset_ros.nodes.audit`).
        Returns ``(success, message)``."""
        was = self.stop_active
        need = self.clean_needed()
        services = [self.resolve_service_name("~/reset"), self.resolve_service_name("~/reset_stop")]
        if self.not_ready:
            # the start-up stop is the monitor's own to release (issue 34.1), whatever
            # reset_clean_ticks says: a reset must not release an arm nothing has checked
            why = f"reset refused: {self.not_ready_detail()}"
            log_privileged(self, f"safe-stop reset through {via}", caller, reason, why, services)
            return False, why
        if was and need > 0:
            limit = self.get_parameter("max_missing_ticks").value * self.get_parameter("dt").value
            fresh = self.last_tick_wall is not None and time.monotonic() - self.last_tick_wall <= limit
            if self.clean_ticks < need or not fresh:
                why = (f"reset refused: the stop's condition has not cleared: {self.clean_ticks} of {need} "
                       f"consecutive ticks checked to k* and conformant (last not: {self.last_unclean})"
                       if fresh else "reset refused: no checked tick within the missing-data limit (no fresh data)")
                log_privileged(self, f"safe-stop reset through {via}", caller, reason, why, services)
                return False, why
        if was and self.pair_hold.reason:
            # row G19: the running pair is not (yet) certified under this model (asked after the
            # clean ticks, whose refusal is the usual one while the arm comes to rest)
            why = f"reset refused: {self.pair_hold.reason}"
            log_privileged(self, f"safe-stop reset through {via}", caller, reason, why, services)
            return False, why
        self.clean_ticks, self.last_unclean = 0, "no tick checked since the reset"
        if self.core is not None:
            self.core.reset()
        self.restart_watchdog()
        by = f" by {caller}" if caller else ""
        self.publish_stop_state(False, "reset", f"reset through {via}{by}" + (f": {reason.strip()}" if reason else ""))
        message = "safe stop cleared" if was else "no safe stop was active"
        log_privileged(self, f"safe-stop reset through {via}", caller, reason, f"granted ({message})", services)
        return True, message

    def not_ready_detail(self):
        """Why the start-up stop still holds: an input that never arrived, or the clean ticks so far."""
        need = self.core.model.horizon + 1 if self.core is not None else "k*+1"
        kinds = ("y",) if self.effort is not None else tuple(TOPIC)
        never = [TOPIC[k] for k in kinds if k not in self.first_rx_wall]
        if self.core is None:
            what = "no model loaded"
        elif never:
            what = "waiting for " + " and ".join(never) + " (never received)"
        else:
            what = (f"{self.clean_ticks} of {need} consecutive ticks checked to k* and conformant "
                    f"(last not: {self.last_unclean})")
        return (f"{MONITOR_NOT_READY} {what}; the monitor releases the stop itself after {need} consecutive "
                "ticks checked to the horizon, all conformant, on every input")

    def publish_diagnostics(self):
        arr = DiagnosticArray()
        arr.header.stamp = self.get_clock().now().to_msg()
        st = DiagnosticStatus(name="reachset_ros: conformance monitor", hardware_id="")
        if self.core is None:
            st.level, st.message = DiagnosticStatus.WARN, "no model loaded"
        elif self.not_ready:
            st.level, st.message = DiagnosticStatus.WARN, self.not_ready_detail()
        elif self.stop_active:
            st.level, st.message = DiagnosticStatus.ERROR, f"safe stop: {self.stop_msg.reason}"
        elif self.last_tick_wall is None:
            never = [topic for kind, topic in TOPIC.items() if kind not in self.first_rx_wall]
            st.level = DiagnosticStatus.WARN
            st.message = ("waiting for " + " and ".join(never) if never
                          else "no tick yet: /joint_states and /plant_input arrive but no stamps paired")
        elif self.core.coverage.last_longest < 0:
            st.level, st.message = DiagnosticStatus.WARN, "nothing checked at the last tick (warm-up or gaps)"
        elif self.core.coverage.last_longest < self.core.model.horizon:
            st.level = DiagnosticStatus.OK
            st.message = (f"conformant, checked up to step {self.core.coverage.last_longest} of "
                          f"k*={self.core.model.horizon} (warm-up or gaps)")
        else:
            st.level, st.message = DiagnosticStatus.OK, "conformant"
        if st.level == DiagnosticStatus.OK and self.envelope_outside:
            st.level = DiagnosticStatus.WARN
            st.message += (f"; joints {', '.join(self.envelope_outside)} outside the validated envelope: the model "
                           "was never validated on such motion (outside_envelope: warn)")
        counts = collections.Counter(self.counters)
        counts["callback_errors"] = getattr(self, "callback_errors", 0)
        values = self.tick_times.summary() | self.publish_times.summary()
        if self.core is not None:
            counts.update(self.core.counters)
            cov = self.core.coverage
            values |= {"longest_step": cov.last_longest, "horizon": self.core.model.horizon,
                      "horizon_coverage": f"{cov.share:.4f}", "outside_envelope": self.outside_mode,
                      "envelope": "recorded" if self.core.envelope is not None else
                      "none recorded in the model: ticks not classified",
                      "outside_envelope_joints": ",".join(self.envelope_outside)}
            if self.core.stuck is not None:     # ticks the stuck-sensor rule had no reference for
                values["stuck_rule_unreferenced_ticks"] = self.core.stuck.unreferenced
        st.values = [KeyValue(key=k, value=str(v)) for k, v in sorted({**counts, **values}.items())]
        arr.status = [st]
        self.diag_pub.publish(arr)


def main(args=None):
    spin_node(MonitorNode, args)


if __name__ == "__main__":
    main()
