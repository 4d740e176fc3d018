"""controller_node: the feedback-linearizing controller (paper eqs. 5-7).

u_p = q̈_d + ω²(q_d − q̂) + 2ζω(q̇_d − q̂̇) [− d̂]  from ``/observer/estimate`` and
``/reference`` (paired by stamp), then τ = M(q̂) u_p + ψ(q̂, q̂̇) with the nominal Pinocchio
model; publishes ``/effort_commands`` and ``/plant_input`` stamped with the measurement's
stamp. Gains change only through the parameter services, atomically between ticks; a
change is refused with its reason when the closed loop would be unstable or its reachable
input would leave U_p under the current model (``model_file``). On an active
``/safe_stop`` it switches to a braking law that brings the joints to rest within U_p and
holds them; only a cleared stop gives control back. With ``wait_for_monitor`` it also
holds until the first ``/safe_stop`` message, so that a restarted controller cannot move
the arm in the moment before the latched stop reaches it. An estimate it cannot use (a joint
missing, short arrays, non-finite values) is skipped; a reference it cannot use is
treated as none (hold the measured position); both are counted on ``/diagnostics``.
"""
import time

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rcl_interfaces.msg import SetParametersResult
from rclpy.node import Node
from reachset_msgs.msg import JointEstimate, JointReference, PlantInput, SafeStop
from std_msgs.msg import Float64MultiArray

from ..conformance import model as mdl
from ..robot import dynamics as robot
from ..errors import ReachsetError
from ..systems import closedloop
from ..systems.gains import check_gains
from ..systems.plant import lwa4p_joint_plant
from .common import SAFE_STOP_QOS, TICK_QOS, desc, spin_node, stamp_ns
from .gain_params import current_values, declare_gain_parameters, gains_from, proposed_values

DEFAULT_JOINTS = list(robot.JOINT_NAMES)


def braking_input(q, qd, q_hold, u_max, omega=8.0, zeta=1.0):
    """Braking law: a PD on the hold position, saturated to U_p (rad/s^2)."""
    u = omega ** 2 * (q_hold - q) - 2 * zeta * omega * qd
    return np.clip(u, -u_max, u_max)


def hold_position(q, qd, u_max):
    """Where the braking law holds the joints: the stopping point at half the admissible
    deceleration, q + qd |qd| / u_max."""
    return q + qd * np.abs(qd) / (2 * 0.5 * u_max)


def u_max_array(value, n):
    """U_p half-widths for ``n`` joints from the ``u_max`` parameter (one value for all, or
    at least ``n``: the first ``n`` are used); each finite and > 0, else ReachsetError."""
    try:
        a = np.array([float(x) for x in value], dtype=np.float64)
    except (TypeError, ValueError):
        raise ReachsetError(f"u_max must be numbers, got {value!r}") from None
    if a.size == 1:
        a = np.full(n, a[0])
    if a.size < n:
        raise ReachsetError(f"u_max needs 1 or {n} values, got {a.size}")
    a = a[:n]
    if not np.all(np.isfinite(a)) or np.any(a <= 0):
        raise ReachsetError(f"u_max must be finite and > 0 rad/s^2, got {a.tolist()}")
    return a


class ControllerNode(Node):
    def __init__(self):
        super().__init__("controller_node")
        self.declare_parameter("joints", DEFAULT_JOINTS, desc("joints; /effort_commands uses this order"))
        self.declare_parameter("robot_params", "", desc("identified robot parameters YAML ('' = URDF values)"))
        self.declare_parameter("model_file", "", desc("conformance model used to check gain changes"))
        self.declare_parameter("u_max", [26.0, 26.0, 26.0, 26.0, 100.0, 100.0],
                               desc("U_p half-width per joint, rad/s^2"))
        self.declare_parameter("u_ff_bound", 2.0, desc("bound of the feedforward |qdd_d|, rad/s^2", 0.0, 1000.0))
        self.declare_parameter("reference_timeout", 0.02,
                               desc("wait up to this long (s, wall) for the reference of an estimate's stamp; "
                                    "then the newest earlier reference is used (counted late_reference)",
                                    0.0, 1.0))
        self.declare_parameter("wait_for_monitor", False,
                               desc("hold the joints (braking law) until the first /safe_stop message; the monitor "
                                    "publishes its state, latched, when it starts, so a (re)started controller "
                                    "never moves the arm before it knows whether a safe stop is latched"))
        declare_gain_parameters(self)
        self.joints = list(self.get_parameter("joints").value)
        params = self.get_parameter("robot_params").value or None
        self.robot = robot.load_model(params=params)
        self.data = robot.create_data(self.robot)
        idx = [self.robot.joint_names.index(j) for j in self.joints]
        self.idx = np.array(idx)
        self.model = None
        path = self.get_parameter("model_file").value
        if path:
            self.model = mdl.load(path)
        # the start-up configuration passes the same checks as a later change (stable closed
        # loops; R_u inside U_p where the model has the joint): else the node does not start
        values = dict(current_values(self), u_max=self.get_parameter("u_max").value,
                      u_ff_bound=self.get_parameter("u_ff_bound").value)
        try:
            self.gains, self.u_max = self.validate(values, self.model)
        except ReachsetError as e:
            raise ReachsetError(f"start-up parameters refused: {e}") from None
        self.refs = {}
        self.stop_active = False
        self.stop_known = not self.get_parameter("wait_for_monitor").value
        self.q_hold = None
        self.counters = {"no_reference": 0, "late_reference": 0, "bad_reference": 0, "bad_estimate": 0,
                         "braking_ticks": 0}
        self.waiting = None          # (stamp, msg, wall time) of an estimate whose reference is not here yet
        self.last_ref = None         # the newest usable reference (stamp, (q_d, qd_d, qdd_d))
        self.effort_pub = self.create_publisher(Float64MultiArray, "effort_commands", TICK_QOS)
        self.input_pub = self.create_publisher(PlantInput, "plant_input", TICK_QOS)
        self.create_subscription(JointEstimate, "observer/estimate", self.on_estimate, TICK_QOS)
        self.create_subscription(JointReference, "reference", self.on_reference, TICK_QOS)
        self.create_subscription(SafeStop, "safe_stop", self.on_safe_stop, SAFE_STOP_QOS)
        self.diag_pub = self.create_publisher(DiagnosticArray, "diagnostics", 10)
        self.create_timer(1.0, self.publish_diagnostics)
        self.create_timer(0.002, self.on_wait_timer)
        self.add_on_set_parameters_callback(self.on_set_parameters)

    def publish_diagnostics(self):
        """About 1 Hz: braking or not, and the counts of skipped inputs."""
        arr = DiagnosticArray()
        arr.header.stamp = self.get_clock().now().to_msg()
        st = DiagnosticStatus(name="reachset_ros: controller", hardware_id="")
        if self.stop_active:
            st.level, st.message = DiagnosticStatus.ERROR, "safe stop: braking and holding"
        elif not self.stop_known:
            st.level, st.message = DiagnosticStatus.WARN, "holding: no /safe_stop state from the monitor yet"
        else:
            st.level, st.message = DiagnosticStatus.OK, "tracking"
        counts = dict(self.counters, callback_errors=getattr(self, "callback_errors", 0))
        st.values = [KeyValue(key=k, value=str(v)) for k, v in sorted(counts.items())]
        arr.status = [st]
        self.diag_pub.publish(arr)

    # -- gains ---------------------------------------------------------------------------
    def validate(self, values, model):
        """Gains and U_p of a proposed configuration, or ReachsetError with the reason: every
        joint's closed loop must be stable, and where the model has the joint's sets its R_u
        must stay inside U_p."""
        gains = gains_from(values, self.joints)
        u_max = u_max_array(values.get("u_max", self.get_parameter("u_max").value), len(self.joints))
        u_ff = float(values.get("u_ff_bound", self.get_parameter("u_ff_bound").value))
        for i, j in enumerate(self.joints):
            js = model.joints.get(j) if model is not None else None
            if js is not None:
                ok, why, _ = check_gains(gains[j], js, u_max=float(u_max[i]), u_ff=u_ff, plant=model.plant)
                if not ok:
                    raise ReachsetError(f"joint {j}: {why}")
                continue
            g = gains[j]
            cl = closedloop.close_loop(lwa4p_joint_plant(), g.build_observer(), g.build_controller())
            st = closedloop.stability(cl)
            if not st.stable:
                raise ReachsetError(f"joint {j}: closed loop unstable ({st.message})")
        return gains, u_max

    def on_set_parameters(self, params):
        values = proposed_values(self, params)
        model = self.model
        for p in params:
            if p.name in ("u_max", "u_ff_bound"):
                values[p.name] = p.value
            if p.name == "model_file":
                try:
                    model = mdl.load(p.value) if p.value else None
                except ReachsetError as e:
                    return SetParametersResult(successful=False, reason=str(e))
            if p.name in ("joints", "robot_params", "wait_for_monitor"):
                return SetParametersResult(successful=False, reason=f"{p.name} is fixed at start-up")
        try:
            gains, u_max = self.validate(values, model)
        except ReachsetError as e:
            return SetParametersResult(successful=False, reason=str(e))
        self.gains, self.model, self.u_max = gains, model, u_max
        return SetParametersResult(successful=True)

    # -- data ----------------------------------------------------------------------------
    def on_reference(self, msg):
        stamp = stamp_ns(msg.header.stamp)
        self.refs[stamp] = msg
        while len(self.refs) > 50:
            self.refs.pop(next(iter(self.refs)))
        if self.waiting is not None and self.waiting[0] == stamp:
            _, est, _ = self.waiting
            self.waiting = None
            self.on_estimate(est)

    def on_wait_timer(self):
        """An estimate waited ``reference_timeout`` for its reference: control with the newest earlier one."""
        if self.waiting is None:
            return
        if time.monotonic() - self.waiting[2] >= float(self.get_parameter("reference_timeout").value):
            _, est, _ = self.waiting
            self.waiting = None
            self.on_estimate(est, late=True)

    def on_safe_stop(self, msg):
        active = bool(msg.active)
        if active != self.stop_active or not self.stop_known:
            what = f"({msg.kind}: {msg.reason}; stamp {stamp_ns(msg.header.stamp)})"
            if active:
                self.get_logger().warning(f"safe stop active: braking {what}")
            else:
                self.get_logger().info(f"safe stop inactive: tracking {what}")
        self.stop_known = True
        self.stop_active = active
        if not self.stop_active:
            self.q_hold = None

    def reference_at(self, stamp, late=False):
        """(q_d, qd_d, qdd_d) of the reference stamped ``stamp``; when it has not arrived and
        ``late``, the newest earlier usable reference (counted ``late_reference``); None when
        there is none (``no_reference``) or it lacks a joint, has short arrays or non-finite
        values (``bad_reference``)."""
        ref = self.refs.pop(stamp, None)
        if ref is None:
            if late and self.last_ref is not None and self.last_ref[0] < stamp:
                self.counters["late_reference"] += 1
                return self.last_ref[1]
            self.counters["no_reference"] += 1
            return None
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
        self.last_ref = (stamp, out)
        return out

    def on_estimate(self, msg, late=False):
        """Control from the estimate and the reference of the same stamp (paired by stamp: the
        two come from different nodes, in either order). An estimate whose reference has not
        arrived waits for it up to ``reference_timeout``; a newer estimate ends the wait."""
        stamp = stamp_ns(msg.header.stamp)
        braking = self.stop_active or not self.stop_known
        if not late and not braking and stamp not in self.refs:
            if self.waiting is not None and self.waiting[0] < stamp:
                _, old, _ = self.waiting
                self.waiting = None
                self.on_estimate(old, late=True)
            if float(self.get_parameter("reference_timeout").value) > 0:
                self.waiting = (stamp, msg, time.monotonic())
                return
            late = True
        idx = {n: i for i, n in enumerate(msg.name)}
        n = len(msg.name)
        if any(j not in idx for j in self.joints) or len(msg.position) < n or len(msg.velocity) < n:
            self.counters["bad_estimate"] += 1
            return
        sel = [idx[j] for j in self.joints]
        q = np.array([msg.position[i] for i in sel], dtype=np.float64)
        qd = np.array([msg.velocity[i] for i in sel], dtype=np.float64)
        d = np.array([msg.disturbance[i] if i < len(msg.disturbance) else 0.0 for i in sel], dtype=np.float64)
        if not (np.all(np.isfinite(q)) and np.all(np.isfinite(qd)) and np.all(np.isfinite(d))):
            self.counters["bad_estimate"] += 1
            return
        u_max = self.u_max
        if braking:
            self.counters["braking_ticks"] += 1
            if self.q_hold is None:
                self.q_hold = hold_position(q, qd, u_max)
            u = braking_input(q, qd, self.q_hold, u_max)
        else:
            ref = self.reference_at(stamp, late)
            if ref is None:
                q_d, qd_d, qdd_d = q.copy(), np.zeros_like(q), np.zeros_like(q)
            else:
                q_d, qd_d, qdd_d = ref
            u = np.empty(len(self.joints))
            for i, j in enumerate(self.joints):
                g = self.gains[j]
                u[i] = (qdd_d[i] + g.omega ** 2 * (q_d[i] - q[i])
                        + 2 * g.zeta * g.omega * (qd_d[i] - qd[i]))
                if g.controller == "compensated":
                    u[i] -= d[i]
        # full-robot feedback linearization: joints not controlled here get u_p = 0
        qf = np.zeros(self.robot.nv)
        qdf = np.zeros(self.robot.nv)
        uf = np.zeros(self.robot.nv)
        qf[self.idx], qdf[self.idx], uf[self.idx] = q, qd, u
        tau = robot.feedback_linearization(self.robot, self.data, qf, qdf, uf)[self.idx]
        pi = PlantInput()
        pi.header.stamp = msg.header.stamp
        pi.name = list(self.joints)
        pi.acceleration = [float(x) for x in u]
        self.input_pub.publish(pi)
        self.effort_pub.publish(Float64MultiArray(data=[float(x) for x in tau]))


def main(args=None):
    spin_node(ControllerNode, args)


if __name__ == "__main__":
    main()
