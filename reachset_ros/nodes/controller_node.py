"""controller_node: the feedback-linearizing controller (paper eqs. 5-7).

u_p = q̈_d + ω²(q_d − q̂) + 2ζω(q̇_d − q̂̇) [− d̂]  from ``/observer/estimate`` and
``/reference`` (paired by stamp), computed by the certified law itself
(:class:`~reachset_ros.systems.closedloop.FeedbackLaw` of the joint's
:class:`~reachset_ros.systems.gains.Gains`, which also solves the algebraic loop of an ESO
fed u_p[k]), then τ = M(q̂) u_p + ψ(q̂, q̂̇) with the nominal Pinocchio
model; publishes ``/effort_commands`` and ``/plant_input`` stamped with the measurement's
stamp. Gains change only through the parameter services, atomically between ticks; a
change is refused with its reason when the closed loop would be unstable or its reachable
input would leave U_p under the current model (``model_file``).

Assumptions of the guarantee it checks and reports on ``/diagnostics``: a reference with
|q̈_d| > ``u_ff_bound`` (outside the class R_u is certified for) is flagged, not altered:
counted ``reference_out_of_class`` with the last stamp and joint, the status turns WARN
(published at once) and a warning is logged the first time; the tick is still controlled by
the same law. R_e holds from zero initial error: after the start, a gain change or the end
of braking, the transient (``settling_ticks`` of each joint's closed loop,
:func:`~reachset_ros.systems.closedloop.settling_ticks`) is reported with the stamps it
spans (``transient_start_ns``, ``transient_end_ns``), during which the tracking error is not
claimed to lie in R*_e. On an active
``/safe_stop`` it carries out the stop of :mod:`reachset_ros.systems.stopping` (the one stop
law, :func:`~reachset_ros.systems.stopping.stop_tick`): a controlled stop within U_p and, in
category 1 (``stop_category``, the default), each joint's holding brake engaged on
``/brake_command`` when the joint is at rest or the controlled stop cannot decelerate it
(``stop_max_time``, ``stop_max_travel``); only a cleared stop releases the brakes and gives
control back. An estimate it cannot use (non-finite, a joint missing) engages every brake
at once and latches a stop of its own (``no usable estimate``, logged, on ``/diagnostics``)
until the monitor's audited reset; the effort command of such a tick holds the last usable
position (u_p = 0), so the drives always get a command. With ``wait_for_monitor`` it also
holds until the first ``/safe_stop`` message, so that a restarted controller cannot move
the arm in the moment before the latched stop reaches it; the monitor's start-up stop
(``kind: not_ready``, issue 34.1) is held the same way (category 2, the drives hold, no
brakes), since the ticks that release it must check the modelled plant, not a braked arm. An estimate it cannot use (a joint
missing, short arrays, non-finite values) is skipped; a reference it cannot use is
treated as a late one (below); both are counted on ``/diagnostics``.

A reference that has not come within ``reference_timeout`` (wall) of its estimate is late:
the tick is controlled with the newest earlier reference received, carried forward to the
tick's stamp at constant acceleration
(:func:`~reachset_ros.systems.late_reference.extrapolate`, ``qdd_d`` stays in the class),
counted ``late_reference`` with the largest age used (``reference_age_max_ns``). A newest
reference older than ``reference_max_age`` (0.2 s of stamp time) is a stop of the
controller's own ("reference lost": brakes, latched until the monitor's reset), since
neither holding an old reference nor carrying it further keeps the input in ``U_p``.
Late ticks, a re-entry out of the certified class when references return, and the hold
without any reference are reported, never as tracking; beyond ``U_p`` they are a stop of
the controller's own (:mod:`~reachset_ros.nodes.reference_events`, issue 34.3).

The monitor is watched (:mod:`.monitor_health`): a ``/safe_stop`` publisher whose liveliness
is lost (``monitor lost``) and, once the monitor has sent verdicts, none on
``/conformance/status`` within ``monitor_verdict_ticks`` ticks of a tick tracked (its
executor blocked: ``monitor stalled``) are stops of the controller's own. Every stop of its
own is cleared only by the monitor's audited reset (``~/reset``, ``~/reset_stop``: the
clean-tick rule, a ``PRIVILEGED`` line), never by a monitor's start state or a lifecycle
transition of either node.
"""
import time

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rcl_interfaces.msg import SetParametersResult
from rclpy.clock import Clock, ClockType
from rclpy.node import Node
from reachset_msgs.msg import BrakeCommand, JointEstimate, JointReference, PlantInput
from std_msgs.msg import Float64MultiArray

from ..conformance import model as mdl
from ..robot import dynamics as robot
from ..errors import ReachsetError
from ..systems import late_reference
from ..systems.stopping import StopPolicy, StopState, stop_tick
from . import reference_events
from .common import MONITOR_STARTED, TICK_QOS, declare_realtime_priority, desc, spin_node, stamp_ns
from .gain_params import (current_values, declare_certificate_parameters, declare_gain_parameters, log_gain_change,
                          log_envelope, proposed_values,
                          validate_pair)
from . import estimate_watch, monitor_health
from .pair_gate import check_running_pair
from .param_callbacks import StagedRequest, add_parameter_callbacks

DEFAULT_JOINTS = list(robot.JOINT_NAMES)


#: :meth:`ControllerNode.reference_at`: the newest earlier reference is older than ``reference_max_age``
LOST = object()
#: references kept for estimates still to come (2 s at 250 Hz): after a stall, a backlog of
#: estimates finds its own references (50, before the sixth long campaign, dropped those of a
#: backlog longer than 200 ms: late ticks, and a "reference lost" stop after a 422 ms freeze)
REFERENCE_BUFFER = 500


class ControllerNode(monitor_health.MonitorWatch, Node):
    def __init__(self, **node_kwargs):
        super().__init__("controller_node", **node_kwargs)
        declare_realtime_priority(self)
        self.declare_parameter("joints", DEFAULT_JOINTS, desc("joints; /effort_commands uses this order", read_only=True))
        self.declare_parameter("robot_params", "", desc("identified robot parameters YAML ('' = URDF values)",
                                                        read_only=True))
        declare_certificate_parameters(self)
        self.declare_parameter("dt", 0.004, desc("tick period, s (the observer's; a model must have the same)",
                                                 1e-4, 1.0, read_only=True))
        self.declare_parameter("reference_timeout", 0.02,
                               desc("wait up to this long (s, wall) for the reference of an estimate's stamp; "
                                    "then the newest earlier reference, carried forward to the tick (counted "
                                    "late_reference; reference_max_age)",
                                    0.0, 1.0))
        self.declare_parameter("reference_max_age", late_reference.MAX_AGE_S,
                               desc("a late reference is the newest earlier one carried forward to the tick at "
                                    "constant acceleration, up to this age (s of stamp time); an older one is no "
                                    "reference: a stop of the controller's own (reference lost)", 0.0, 10.0))
        self.declare_parameter("wait_for_monitor", False,
                               desc("hold the joints (braking law) until the first /safe_stop message; the monitor "
                                    "publishes its state, latched, when it starts, so a (re)started controller "
                                    "never moves the arm before it knows whether a safe stop is latched",
                                    read_only=True))
        self.declare_parameter("stop_category", 1, desc("safe-stop category (IEC 60204-1): 1 = controlled stop, then "
                                                        "the holding brakes; 2 = controlled stop, held by the "
                                                        "braking law", 1, 2, integer=True))
        self.declare_parameter("stop_max_time", StopPolicy.max_time,
                               desc("category 1: a joint still moving this long (s) after the stop began is braked",
                                    1e-3, 60.0))
        self.declare_parameter("stop_max_travel", StopPolicy.max_travel,
                               desc("category 1: a joint farther than this (rad) from where the stop began is braked",
                                    1e-4, 10.0))
        self.declare_parameter("rest_velocity", StopPolicy.rest_velocity,
                               desc("|qd| below which a joint is at rest, rad/s (category 1: its brake engages)",
                                    1e-5, 1.0))
        declare_gain_parameters(self)
        monitor_health.declare_parameters(self)
        self.joints = list(self.get_parameter("joints").value)
        self.dt = float(self.get_parameter("dt").value)
        self.robot = None            # set by configure()
        #: why the controller holds although no safe stop is active (the managed variant's
        #: inactive state, controller_lifecycle_node); None: it tracks
        self.hold_reason = None
        self.model = None
        if not self.MANAGED:
            self.configure()
        self.refs = {}
        self.stop_active = False
        self.monitor_not_ready = False   # the active stop is the monitor's start-up stop (kind not_ready)
        self.stop_known = not self.get_parameter("wait_for_monitor").value
        self.stop = None             # StopState of the stop in progress (None while tracking)
        self.last_estimate_stamp = 0  # stamp of the newest estimate received (ns)
        self.last_estimate_time = None  # the arm's time it arrived (s, estimate_watch.arm_time)
        self.stop_received = 0       # last_estimate_stamp when the active /safe_stop arrived (BrakeCommand)
        self.own_stop = None         # reason of a stop latched by this node (no usable estimate)
        self.last_q = None           # the last usable estimated position
        self.counters = {"no_reference": 0, "late_reference": 0, "bad_reference": 0, "bad_estimate": 0,
                         "braking_ticks": 0, "reference_out_of_class": 0, "brakes_engaged": 0, "bad_command": 0,
                         "torque_beyond_limits": 0, "stale_estimate": 0, "reference_age_max_ns": 0,
                         **reference_events.COUNTERS}
        reference_events.init(self)      # re-entries after late references, the hold (issue 34.3)
        self.last_command_stamp = None   # stamp of the last command sent (commands never go back in stamp)
        self.out_of_class_last = None    # (stamp, joint, qdd_d) of the last flagged reference
        self.out_of_class_reported = 0   # the count at the last /diagnostics
        self.flagged = False             # the previous tick's reference was out of class
        self.waiting = None          # (stamp, msg, wall time) of an estimate whose reference is not here yet
        self.last_ref = None         # the newest usable reference (stamp, (q_d, qd_d, qdd_d))
        self.effort_pub = self.create_publisher(Float64MultiArray, "effort_commands", TICK_QOS)
        self.input_pub = self.create_publisher(PlantInput, "plant_input", TICK_QOS)
        self.brake_pub = self.create_publisher(BrakeCommand, "brake_command", TICK_QOS)
        self.create_subscription(JointEstimate, "observer/estimate", self.on_estimate, TICK_QOS)
        self.create_subscription(JointReference, "reference", self.on_reference, TICK_QOS)
        self.watch_monitor()         # /safe_stop, its liveliness, the deadline on the verdicts
        self.diag_pub = self.create_publisher(DiagnosticArray, "diagnostics", 10)
        wall = Clock(clock_type=ClockType.STEADY_TIME)   # the timers run on the wall, also under use_sim_time
        self.create_timer(1.0, self.publish_diagnostics, clock=wall)
        self.create_timer(0.002, self.on_wait_timer, clock=wall)
        self.param_request = StagedRequest()
        add_parameter_callbacks(self, on_set=self.on_set_parameters, post_set=self.post_set_parameters,
                                take_repeats=True)   # a resent request runs no gate again

    #: True in the managed (lifecycle) variant: configure() runs on the configure transition
    MANAGED = False

    def configure(self):
        """Load the robot model and the conformance model and certify the gain pair: the
        start-up configuration passes the same gate as a later change (the pair's
        certificate, gain_params.validate_pair), else the node does not start (plain node)
        or the configure transition fails (managed node). Raises ReachsetError."""
        params = self.get_parameter("robot_params").value or None
        rob = robot.load_model(params=params)
        missing = [j for j in self.joints if j not in rob.joint_names]
        if missing:
            raise ReachsetError(f"joint {missing[0]} is not a joint of the robot model")
        model = None
        path = self.get_parameter("model_file").value
        if path:
            model = mdl.load(path)
        try:
            cfg = self.validate(current_values(self), model)
        except ReachsetError as e:
            raise ReachsetError(f"start-up parameters refused: {e}") from None
        self.robot, self.data = rob, robot.create_data(rob)
        self.idx = np.array([rob.joint_names.index(j) for j in self.joints])
        self.model = model
        self.apply(cfg, "start-up")
        log_envelope(self, cfg, "start-up")
        # the drives' torque limits (the URDF's effort limits) of the controlled joints
        eff = np.array(rob.pin_model.effortLimit, dtype=np.float64)[self.idx]
        self.tau_limit = np.where(np.isfinite(eff) & (eff > 0), eff, np.inf)

    def publish_diagnostics(self):
        """About 1 Hz (and at once when a reference leaves the class or a transient starts):
        braking or not, the counts of skipped and flagged inputs, and the transient window."""
        arr = DiagnosticArray()
        arr.header.stamp = self.get_clock().now().to_msg()
        st = DiagnosticStatus(name="reachset_ros: controller", hardware_id="")
        n_flagged = self.counters["reference_out_of_class"]
        new_flags = n_flagged - self.out_of_class_reported
        self.out_of_class_reported = n_flagged
        tr = self.transient
        late_seen, self.late_reported = self.late_reported, self.counters["late_reference"]
        if self.own_stop is not None:
            st.level, st.message = DiagnosticStatus.ERROR, f"stopped by the controller: {self.own_stop}; brakes engaged"
        elif self.stop_active:
            engaged = int(self.stop.engaged.sum()) if self.stop is not None else 0
            st.level = DiagnosticStatus.ERROR
            st.message = (f"safe stop (category {self.policy().category}): braking; "
                          f"{engaged} of {len(self.joints)} holding brakes engaged")
        elif not self.stop_known:
            st.level, st.message = DiagnosticStatus.WARN, "holding: no /safe_stop state from the monitor yet"
        elif new_flags:
            stamp, joint, acc = self.out_of_class_last
            st.level = DiagnosticStatus.WARN
            st.message = (f"reference out of class at {new_flags} tick(s) (last: stamp {stamp}, {joint} |qdd_d| = "
                          f"{abs(acc):.4g} > u_ff_bound {self.u_ff:g} rad/s^2): R_u is not certified there")
        elif (ref_msg := reference_events.status(self, self.counters["late_reference"] - late_seen)) is not None:
            st.level, st.message = DiagnosticStatus.WARN, ref_msg
        elif tr is not None and tr["active"]:
            st.level = DiagnosticStatus.OK
            st.message = (f"tracking; transient after the {tr['cause']} until stamp {tr['end_ns']}: the tracking "
                          "error is not claimed to be inside R*_e before it")
        else:
            st.level, st.message = DiagnosticStatus.OK, "tracking"
        counts = dict(self.counters, callback_errors=getattr(self, "callback_errors", 0))
        values = {k: str(v) for k, v in counts.items()}
        values["uncertified_joints"] = ",".join(self.uncertified)     # gains run on stability alone
        if self.out_of_class_last is not None:
            stamp, joint, acc = self.out_of_class_last
            values.update(reference_out_of_class_last_ns=str(stamp), reference_out_of_class_joint=joint,
                          reference_out_of_class_qdd_d=repr(float(acc)))
        values["u_ff_bound"] = repr(self.u_ff)
        values["monitor_verdict_lag_max_ns"] = str(self.verdicts.lag_max_ns)
        for j, k in self.settling.items():
            values[f"settling_ticks/{j}"] = str(k)
        values["transient_ticks"] = str(max(self.settling.values(), default=0))
        if tr is not None:
            values.update(transient_cause=tr["cause"], transient_start_ns=str(tr["start_ns"]),
                          transient_end_ns=str(tr["end_ns"]), in_transient=str(tr["active"]).lower())
            for j, e in tr["end_ns_joint"].items():
                values[f"transient_end_ns/{j}"] = str(e)
        st.values = [KeyValue(key=k, value=v) for k, v in sorted(values.items())]
        arr.status = [st]
        self.diag_pub.publish(arr)

    # -- gains ---------------------------------------------------------------------------
    def validate(self, values, model):
        """The configuration a proposed set of parameters gives (:func:`validate_pair`, the
        one gate of the observer + controller pair, :func:`~reachset_ros.systems.gains.certify_pair`),
        or ReachsetError with the reason."""
        return validate_pair(self, values, model)

    def apply(self, cfg, cause):
        """Take a validated configuration; a change of the loop (any joint's gains) starts
        a transient at the next tick (``cause`` names it in the diagnostics)."""
        changed = getattr(self, "gains", None) != cfg["gains"]
        if cfg["uncertified"] and cfg["uncertified"] != getattr(self, "uncertified", None):
            self.get_logger().warning(f"gains of {', '.join(cfg['uncertified'])} run without a certificate "
                                      "(allow_uncertified): closed-loop stability only")
        self.uncertified = cfg["uncertified"]
        self.gains, self.laws, self.settling = cfg["gains"], cfg["laws"], cfg["settling"]
        self.u_max, self.u_ff, self.model = cfg["u_max"], cfg["u_ff"], cfg["model"]
        # per joint: where x0 and x_ref take the estimate components the law acts on
        self.slots = {j: tuple(law.estimate_names) for j, law in self.laws.items()}
        if changed:
            self.begin_transient(cause)

    def begin_transient(self, cause):
        """The next tracking tick starts a transient (``cause``: start-up, gain change, end of braking)."""
        self.transient_cause = cause
        if not hasattr(self, "transient"):
            self.transient = None

    def on_set_parameters(self, params):
        """Validate a request (on_set): the pair's gate with the proposed values and model; a
        refused request is logged (PRIVILEGED) and leaves the running configuration as it was
        (a repeat of the running values never comes here: ``take_repeats``)."""
        result, cfg = self.check_request(params)
        if result.successful:
            self.param_request.hold(params, cfg)
        else:
            log_gain_change(self, params, result)
        return result

    def post_set_parameters(self, params):
        """Apply the configuration :meth:`on_set_parameters` validated for this request (post_set)."""
        cfg = self.param_request.take(params)
        self.apply(cfg, "gain change")
        log_gain_change(self, params, SetParametersResult(successful=True), cfg)

    def check_request(self, params):
        """``(SetParametersResult, configuration or None)`` of a proposed request (nothing applied)."""
        values = proposed_values(self, params)
        model = self.model
        for p in params:
            if p.name == "model_file":
                try:
                    model = mdl.load(p.value) if p.value else None
                except ReachsetError as e:
                    return SetParametersResult(successful=False, reason=str(e)), None
        try:
            cfg = self.validate(values, model)
            check_running_pair(self, params, values, model)      # with the observer's running half (issue 34.6)
        except ReachsetError as e:
            return SetParametersResult(successful=False, reason=str(e)), None
        return SetParametersResult(successful=True), cfg

    # -- data ----------------------------------------------------------------------------
    def on_reference(self, msg):
        stamp = stamp_ns(msg.header.stamp)
        self.refs[stamp] = msg
        while len(self.refs) > REFERENCE_BUFFER:
            self.refs.pop(next(iter(self.refs)))
        if self.waiting is not None and self.waiting[0] == stamp:
            _, est, _ = self.waiting
            self.waiting = None
            self.on_estimate(est)

    def on_wait_timer(self):
        """An estimate waited ``reference_timeout`` for its reference: control with the newest
        earlier one. And a safe stop without estimates brakes at once
        (:func:`~reachset_ros.nodes.estimate_watch.brake_without_estimates`)."""
        estimate_watch.brake_without_estimates(self)
        if self.waiting is None:
            return
        if time.monotonic() - self.waiting[2] >= float(self.get_parameter("reference_timeout").value):
            _, est, _ = self.waiting
            self.waiting = None
            self.on_estimate(est, late=True)

    def on_safe_stop(self, msg):
        active = bool(msg.active)
        if not active and self.own_stop is not None and not monitor_health.is_audited_reset(msg):
            # a (new) monitor's start state, a managed monitor's activation: no reset of a stop
            # of this node's own, which only the audited ~/reset clears (issue 34.9)
            self.stop_known = True
            what = "a monitor started" if msg.reason == MONITOR_STARTED else f"the monitor released ({msg.reason})"
            self.get_logger().warning(f"{what}; the controller's own stop ({self.own_stop}) stays until "
                                      "the monitor's ~/reset")
            return
        if not active and (self.stop_active or not self.stop_known):
            # tracking resumes from wherever braking/holding left the joints: a transient
            self.begin_transient(self.transient_cause or "end of braking")
        if active != self.stop_active or not self.stop_known:
            what = f"({msg.kind}: {msg.reason}; stamp {stamp_ns(msg.header.stamp)})"
            if active:
                self.stop_received = self.last_estimate_stamp
                self.get_logger().warning(f"safe stop active: braking {what}")
            else:
                self.get_logger().info(f"safe stop inactive: tracking {what}")
        self.stop_known = True
        self.stop_active = active
        # the monitor's start-up stop (issue 34.1): held by the drives (category 2), so the
        # ticks that release it check the modelled plant, not a braked arm
        self.monitor_not_ready = active and msg.kind == "not_ready"
        if not self.stop_active:
            self.stop = None            # the brakes are released with the next command
            self.stop_received = 0
            self.last_ref = None        # tracking resumes on new references, none carried over the stop
            if self.own_stop is not None:
                self.get_logger().info(f"the controller's own stop ({self.own_stop}) is cleared with the reset")
            self.own_stop = None

    def policy(self):
        """The :class:`StopPolicy` of the current parameters."""
        return StopPolicy(category=int(self.get_parameter("stop_category").value),
                          rest_velocity=float(self.get_parameter("rest_velocity").value),
                          max_time=float(self.get_parameter("stop_max_time").value),
                          max_travel=float(self.get_parameter("stop_max_travel").value))

    def publish_brakes(self, header_stamp):
        """``/brake_command`` with every effort command: engaged brakes of the stop in progress."""
        b = BrakeCommand()
        b.header.stamp = header_stamp
        b.name = list(self.joints)
        engaged = self.stop.engaged if self.stop is not None else np.zeros(len(self.joints), bool)
        b.engage = [bool(x) for x in engaged]
        # when braking began and when the stop reached this node (stamps): what the fault
        # campaign measures as braking onset after the stop's arrival
        since = 0
        if self.stop is not None:   # an own stop engages every brake at once (no braking law tick)
            since = self.stop.start_ns or (self.stop.reasons[0][0] if self.stop.reasons else 0)
        b.braking_since_ns = int(since)
        b.stop_received_ns = int(self.stop_received)
        if self.stop is not None and self.stop.reasons:
            _, j, why = self.stop.reasons[-1]
            b.reason = f"{self.joints[j]}: {why}"
        self.brake_pub.publish(b)

    def latch_own_stop(self, stamp, why, detail):
        """A stop of the controller's own (no usable estimate, a non-finite command): every
        brake engages at once; latched, logged and on /diagnostics until the safe stop is reset."""
        if self.stop is None:
            self.stop = StopState(len(self.joints))
        before = int(self.stop.engaged.sum())
        self.stop.engage_all(stamp, why)
        self.counters["brakes_engaged"] += len(self.joints) - before
        if self.own_stop is None:
            self.own_stop = f"{why} at stamp {stamp} ({detail})"
            self.get_logger().error(f"stop: {self.own_stop}; all holding brakes engaged until the safe stop is reset")
            self.publish_diagnostics()

    def unusable_estimate(self, msg, what):
        """An estimate the controller cannot use: every brake engages, a stop of its own latches."""
        self.counters["bad_estimate"] += 1
        self.latch_own_stop(stamp_ns(msg.header.stamp), "no usable estimate", what)
        if self.last_q is not None:     # hold where the arm was last seen (u_p = 0, at rest)
            self.publish_command(msg.header.stamp, self.last_q, np.zeros(len(self.joints)),
                                 np.zeros(len(self.joints)))
        else:
            self.publish_brakes(msg.header.stamp)

    def parse_reference(self, ref):
        """(q_d, qd_d, qdd_d) of a JointReference in this node's joint order, or None when it
        lacks a joint, has short arrays or non-finite values (counted ``bad_reference``)."""
        ridx = {n: i for i, n in enumerate(ref.name)}
        n = len(ref.name)
        if (any(j not in ridx for j in self.joints) or len(ref.position) < n or len(ref.velocity) < n
                or len(ref.acceleration) < n):
            self.counters["bad_reference"] += 1
            return None
        sel = [ridx[j] for j in self.joints]
        out = tuple(np.array([arr[i] for i in sel], dtype=np.float64)
                    for arr in (ref.position, ref.velocity, ref.acceleration))
        if not all(np.all(np.isfinite(a)) for a in out):
            self.counters["bad_reference"] += 1
            return None
        return out

    def pop_refs_before(self, stamp):
        """Remove the received references stamped before ``stamp``; returns them as
        ``(stamp, msg)``, newest first."""
        older = sorted(((s, m) for s, m in self.refs.items() if s < stamp), key=lambda x: x[0], reverse=True)
        for s, _ in older:
            del self.refs[s]
        return older

    def reference_at(self, stamp, late=False):
        """(q_d, qd_d, qdd_d) of the reference stamped ``stamp``; None when there is no usable
        one to carry forward (``no_reference``: none received since the start or the last stop).

        When it has not arrived and ``late``, or it is unusable (lacks a joint, short arrays,
        non-finite values: ``bad_reference``; issue 34.3, holding ``qd_d = 0`` at speed left
        ``U_p``): the newest usable reference received with an earlier stamp (arrived on time
        or not), carried forward to ``stamp`` at constant acceleration
        (:func:`~reachset_ros.systems.late_reference.extrapolate`; counted ``late_reference``,
        its age in ``reference_age_max_ns``; ``ref_late`` set); :data:`LOST` when that
        reference is older than ``reference_max_age`` (the caller stops). References older
        than the one used are dropped (commands never go back in stamp)."""
        ref = self.refs.pop(stamp, None)
        self.ref_late = False
        if ref is not None:
            out = self.parse_reference(ref)
            if out is not None:
                self.last_ref = (stamp, out)
                self.pop_refs_before(stamp)     # older than a usable one: never needed again
                return out
            late = True     # unusable: carried forward as a late one (holding q̇_d = 0 at speed leaves U_p)
        if not late:
            self.counters["no_reference"] += 1
            return None
        for s, older in self.pop_refs_before(stamp):
            out = self.parse_reference(older)
            if out is not None:
                if self.last_ref is None or s > self.last_ref[0]:
                    self.last_ref = (s, out)
                break
        if self.last_ref is None or self.last_ref[0] >= stamp:
            self.counters["no_reference"] += 1
            return None
        age = stamp - self.last_ref[0]
        if not late_reference.usable(self.last_ref[0], stamp, float(self.get_parameter("reference_max_age").value)):
            return LOST
        self.counters["late_reference"] += 1
        self.counters["reference_age_max_ns"] = max(self.counters["reference_age_max_ns"], age)
        self.ref_late = True
        return late_reference.extrapolate(*self.last_ref[1], age * 1e-9)

    def on_estimate(self, msg, late=False):
        """Control from the estimate and the reference of the same stamp (paired by stamp: the
        two come from different nodes, in either order). An estimate whose reference has not
        arrived waits for it up to ``reference_timeout``; a newer estimate ends the wait."""
        stamp = stamp_ns(msg.header.stamp)
        if not late:
            self.last_estimate_time = estimate_watch.arm_time(self) or self.last_estimate_time   # None: no /clock yet
            # the newest stamp (a sample whose stamp jumped back is not newer; a jump back by
            # more than 1 s is a new clock, as for the commands below)
            if stamp > self.last_estimate_stamp or stamp < self.last_estimate_stamp - 1_000_000_000:
                self.last_estimate_stamp = stamp
        if not late and self.waiting is not None and self.waiting[0] < stamp:
            # an older estimate still waits for its reference: it is controlled first, whether
            # this one tracks or brakes, so commands never go back in stamp (the monitor's
            # stamp_backwards fault; seen when a stop began while an estimate waited)
            _, old, _ = self.waiting
            self.waiting = None
            self.on_estimate(old, late=True)
        if self.last_command_stamp is not None and self.last_command_stamp - 1_000_000_000 < stamp <= self.last_command_stamp:
            # a command for a later tick is out: never go back (a jump back by more than 1 s is
            # a new clock, e.g. a restarted simulation, and is followed)
            self.counters["stale_estimate"] += 1
            return
        braking = self.braking()
        if not late and not braking and stamp not in self.refs:
            if float(self.get_parameter("reference_timeout").value) > 0:
                self.waiting = (stamp, msg, time.monotonic())
                return
            late = True
        idx = {n: i for i, n in enumerate(msg.name)}
        n = len(msg.name)
        if any(j not in idx for j in self.joints) or len(msg.position) < n or len(msg.velocity) < n:
            self.unusable_estimate(msg, "a joint missing or short arrays")
            return
        sel = [idx[j] for j in self.joints]
        q = np.array([msg.position[i] for i in sel], dtype=np.float64)
        qd = np.array([msg.velocity[i] for i in sel], dtype=np.float64)
        d = np.array([msg.disturbance[i] if i < len(msg.disturbance) else 0.0 for i in sel], dtype=np.float64)
        if not (np.all(np.isfinite(q)) and np.all(np.isfinite(qd)) and np.all(np.isfinite(d))):
            self.unusable_estimate(msg, "non-finite values")
            return
        braking = self.check_monitor_verdicts(stamp, braking)
        self.last_q = q
        ref = None if braking else self.reference_at(stamp, late)
        if ref is LOST:
            age_ms = (stamp - self.last_ref[0]) * 1e-6
            self.latch_own_stop(stamp, "reference lost",
                                f"the newest reference is {age_ms:.0f} ms older than the tick; reference_max_age "
                                f"{float(self.get_parameter('reference_max_age').value) * 1e3:g} ms")
            braking = True
        if braking:
            self.reentry.reset()
            u = self.braking_tick(stamp, q, qd)
        else:
            if ref is None:
                q_d, qd_d, qdd_d = q.copy(), np.zeros_like(q), np.zeros_like(q)
            else:
                q_d, qd_d, qdd_d = ref
                self.check_reference_class(stamp, qdd_d)
            reference_events.on_reference_tick(self, stamp, ref, self.ref_late)
            self.track_transient(stamp)
            u = np.empty(len(self.joints))
            for i, j in enumerate(self.joints):
                u[i] = self.law_input(j, q[i], qd[i], d[i], q_d[i], qd_d[i], qdd_d[i])
            if reference_events.beyond_u_p(self, stamp, u):     # out of class: never sent (issue 34.3)
                self.reentry.reset()
                u = self.braking_tick(stamp, q, qd)
        self.publish_command(msg.header.stamp, q, qd, u)

    def braking(self):
        """True while the controller does not track: a safe stop, no stop state yet
        (``wait_for_monitor``), a stop of its own, or the managed variant's hold."""
        return self.stop_active or not self.stop_known or self.own_stop is not None or self.hold_reason is not None

    def braking_tick(self, stamp, q, qd):
        """u_p of a tick while braking (:func:`~reachset_ros.systems.stopping.stop_tick`, the one
        stop law); brakes it engages are counted and logged."""
        self.counters["braking_ticks"] += 1
        if self.stop is None:
            self.stop = StopState(len(self.joints))
        before = int(self.stop.engaged.sum())
        if (self.stop_known and self.stop_active and not self.monitor_not_ready
                or self.own_stop is not None or self.hold_reason is not None):
            u, _ = stop_tick(self.policy(), self.stop, stamp, q, qd, self.u_max)
        else:   # waiting for the monitor's state or its release: hold with the braking law, no brakes
            u, _ = stop_tick(StopPolicy(category=2), self.stop, stamp, q, qd, self.u_max)
        now = int(self.stop.engaged.sum())
        if now > before:
            self.counters["brakes_engaged"] += now - before
            for s, j, why in self.stop.reasons[before:]:
                self.get_logger().warning(f"holding brake of {self.joints[j]} engaged at stamp {s}: {why}")
        return u

    def publish_command(self, header_stamp, q, qd, u):
        """``/plant_input`` u_p, ``/brake_command`` and ``/effort_commands`` tau = M(q) u_p + psi(q, qd)."""
        self.last_command_stamp = stamp_ns(header_stamp)
        # full-robot feedback linearization: joints not controlled here get u_p = 0
        qf = np.zeros(self.robot.nv)
        qdf = np.zeros(self.robot.nv)
        uf = np.zeros(self.robot.nv)
        qf[self.idx], qdf[self.idx], uf[self.idx] = q, qd, u
        tau = robot.feedback_linearization(self.robot, self.data, qf, qdf, uf)[self.idx]
        if not (np.all(np.isfinite(u)) and np.all(np.isfinite(tau))):
            # an absurd command is never sent: a stop of the controller's own, all brakes, and
            # the torque that holds the last usable position at rest (if that is finite)
            self.counters["bad_command"] += 1
            self.latch_own_stop(stamp_ns(header_stamp), "non-finite command", f"u_p {np.round(u, 4).tolist()}")
            u = np.zeros(len(self.joints))
            qf[self.idx] = self.last_q if self.last_q is not None else 0.0
            tau = robot.feedback_linearization(self.robot, self.data, qf, np.zeros_like(qdf),
                                               np.zeros_like(uf))[self.idx]
        over = np.abs(tau) > self.tau_limit
        if np.any(over):
            # sent as computed (the drives clamp at their limits), but the certified loop assumed
            # no saturation: counted and on /diagnostics
            self.counters["torque_beyond_limits"] += 1
        pi = PlantInput()
        pi.header.stamp = header_stamp
        pi.name = list(self.joints)
        pi.acceleration = [float(x) for x in u]
        self.input_pub.publish(pi)
        self.publish_brakes(header_stamp)       # before the effort: the simulator steps on the effort
        self.effort_pub.publish(Float64MultiArray(data=[float(x) for x in tau]))


    def law_input(self, joint, q, qd, d, q_d, qd_d, qdd_d):
        """u_p of one joint: the certified law (:class:`FeedbackLaw`) on the published estimate
        ``x0`` (position, velocity, disturbance, in the observer's estimate order), the
        reference in the same coordinates (zero for the disturbance) and ``u_ff = qdd_d``."""
        est = {"q": q, "qd": qd, "d": d}
        ref = {"q": q_d, "qd": qd_d}
        names = self.slots[joint]
        x0 = np.array([est[n] for n in names], dtype=np.float64)
        x_ref = np.array([ref.get(n, 0.0) for n in names], dtype=np.float64)
        u, _ = self.laws[joint](x0, x_ref, qdd_d)
        return u[0]

    def check_reference_class(self, stamp, qdd_d):
        """Flag a reference with |qdd_d| > u_ff_bound (the class R_u is certified for, U_ff):
        counted, the last one kept for the diagnostics, a warning logged the first time and
        /diagnostics published at once when a run of flagged ticks begins. Nothing is clamped:
        the tick is controlled by the same law; that R_u covers it is no longer claimed."""
        over = np.abs(qdd_d) > self.u_ff
        if not np.any(over):
            self.flagged = False
            return
        i = int(np.argmax(np.abs(qdd_d)))
        self.counters["reference_out_of_class"] += 1
        self.out_of_class_last = (stamp, self.joints[i], float(qdd_d[i]))
        if self.counters["reference_out_of_class"] == 1:
            self.get_logger().warning(
                f"reference out of class at stamp {stamp}: {self.joints[i]} |qdd_d| = {abs(qdd_d[i]):.4g} > "
                f"u_ff_bound {self.u_ff:g} rad/s^2; R_u is not certified for it (counted reference_out_of_class "
                "on /diagnostics; logged once)")
        if not self.flagged:
            self.flagged = True
            self.publish_diagnostics()

    def track_transient(self, stamp):
        """Start the pending transient at this tracking tick (its end per joint from the
        settling ticks of the joint's closed loop and ``dt``), and keep ``active`` current."""
        if self.transient_cause is not None:
            dt_ns = int(round(self.dt * 1e9))
            ends = {j: stamp + k * dt_ns for j, k in self.settling.items()}
            self.transient = {"cause": self.transient_cause, "start_ns": stamp, "end_ns": max(ends.values()),
                              "end_ns_joint": ends, "active": True}
            self.transient_cause = None
            self.get_logger().info(
                f"transient after the {self.transient['cause']} from stamp {stamp}: settles in "
                f"{max(self.settling.values())} ticks (until stamp {self.transient['end_ns']}); the tracking error "
                "is not claimed to be inside R*_e before it")
            self.publish_diagnostics()
        elif self.transient is not None:
            self.transient["active"] = stamp < self.transient["end_ns"]


def main(args=None):
    spin_node(ControllerNode, args)


if __name__ == "__main__":
    main()
