"""controller_node: the feedback-linearizing controller (paper eqs. 5-7).

u_p = q̈_d + ω²(q_d − q̂) + 2ζω(q̇_d − q̂̇) [− d̂]  from ``/observer/estimate`` and
``/reference`` (paired by stamp), then τ = M(q̂) u_p + ψ(q̂, q̂̇) with the nominal Pinocchio
model; publishes ``/effort_commands`` and ``/plant_input`` stamped with the measurement's
stamp. Gains change only through the parameter services, atomically between ticks; a
change is refused with its reason when the closed loop would be unstable or its reachable
input would leave U_p under the current model (``model_file``). On an active
``/safe_stop`` it switches to a braking law that brings the joints to rest within U_p and
holds them; only a cleared stop gives control back.
"""
import numpy as np
from rcl_interfaces.msg import SetParametersResult
from rclpy.node import Node
from reachset_msgs.msg import JointEstimate, JointReference, PlantInput, SafeStop
from std_msgs.msg import Float64MultiArray

from .. import model as mdl
from .. import robot
from ..errors import ReachsetError
from ..gains import check_gains
from .common import SAFE_STOP_QOS, TICK_QOS, desc, spin_node, stamp_ns
from .gain_params import current_values, declare_gain_parameters, gains_from, proposed_values

DEFAULT_JOINTS = list(robot.JOINT_NAMES)


def braking_input(q, qd, q_hold, u_max, omega=8.0, zeta=1.0):
    """Braking law: a PD on the hold position, saturated to U_p (rad/s^2)."""
    u = omega ** 2 * (q_hold - q) - 2 * zeta * omega * qd
    return np.clip(u, -u_max, u_max)


class ControllerNode(Node):
    def __init__(self):
        super().__init__("controller_node")
        self.declare_parameter("joints", DEFAULT_JOINTS, desc("joints; /effort_commands uses this order"))
        self.declare_parameter("robot_params", "", desc("identified robot parameters YAML ('' = URDF values)"))
        self.declare_parameter("model_file", "", desc("conformance model used to check gain changes"))
        self.declare_parameter("u_max", [26.0, 26.0, 26.0, 26.0, 100.0, 100.0],
                               desc("U_p half-width per joint, rad/s^2"))
        self.declare_parameter("u_ff_bound", 2.0, desc("bound of the feedforward |qdd_d|, rad/s^2", 0.0, 1000.0))
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
        self.gains = gains_from(current_values(self), self.joints)
        self.refs = {}
        self.stop_active = False
        self.q_hold = None
        self.counters = {"no_reference": 0, "bad_estimate": 0, "braking_ticks": 0}
        self.effort_pub = self.create_publisher(Float64MultiArray, "effort_commands", TICK_QOS)
        self.input_pub = self.create_publisher(PlantInput, "plant_input", TICK_QOS)
        self.create_subscription(JointEstimate, "observer/estimate", self.on_estimate, TICK_QOS)
        self.create_subscription(JointReference, "reference", self.on_reference, TICK_QOS)
        self.create_subscription(SafeStop, "safe_stop", self.on_safe_stop, SAFE_STOP_QOS)
        self.add_on_set_parameters_callback(self.on_set_parameters)

    # -- gains ---------------------------------------------------------------------------
    def validate(self, values, model):
        gains = gains_from(values, self.joints)
        u_max = list(values.get("u_max", self.get_parameter("u_max").value))
        for i, j in enumerate(self.joints):
            js = model.joints.get(j) if model is not None else None
            if js is None:
                continue
            ok, why, _ = check_gains(gains[j], js, float(u_max[i]), float(self.get_parameter("u_ff_bound").value),
                                     model.plant)
            if not ok:
                raise ReachsetError(f"joint {j}: {why}")
        if model is None:
            from .. import closedloop
            from ..plant import lwa4p_joint_plant
            for j, g in gains.items():
                cl = closedloop.close_loop(lwa4p_joint_plant(), g.build_observer(), g.build_controller())
                st = closedloop.stability(cl)
                if not st.stable:
                    raise ReachsetError(f"joint {j}: closed loop unstable ({st.message})")
        return gains

    def on_set_parameters(self, params):
        values = proposed_values(self, params)
        model = self.model
        for p in params:
            if p.name == "u_max":
                values["u_max"] = p.value
            if p.name == "model_file":
                try:
                    model = mdl.load(p.value) if p.value else None
                except ReachsetError as e:
                    return SetParametersResult(successful=False, reason=str(e))
            if p.name in ("joints", "robot_params"):
                return SetParametersResult(successful=False, reason=f"{p.name} is fixed at start-up")
        try:
            gains = self.validate(values, model)
        except ReachsetError as e:
            return SetParametersResult(successful=False, reason=str(e))
        self.gains, self.model = gains, model
        return SetParametersResult(successful=True)

    # -- data ----------------------------------------------------------------------------
    def on_reference(self, msg):
        self.refs[stamp_ns(msg.header.stamp)] = msg
        while len(self.refs) > 50:
            self.refs.pop(next(iter(self.refs)))

    def on_safe_stop(self, msg):
        self.stop_active = bool(msg.active)
        if not self.stop_active:
            self.q_hold = None

    def on_estimate(self, msg):
        stamp = stamp_ns(msg.header.stamp)
        idx = {n: i for i, n in enumerate(msg.name)}
        if any(j not in idx for j in self.joints):
            self.counters["bad_estimate"] += 1
            return
        sel = [idx[j] for j in self.joints]
        q = np.array([msg.position[i] for i in sel])
        qd = np.array([msg.velocity[i] for i in sel])
        d = np.array([msg.disturbance[i] if i < len(msg.disturbance) else 0.0 for i in sel])
        if not (np.all(np.isfinite(q)) and np.all(np.isfinite(qd))):
            self.counters["bad_estimate"] += 1
            return
        u_max = np.array(self.get_parameter("u_max").value, dtype=float)[:len(self.joints)]
        if self.stop_active:
            self.counters["braking_ticks"] += 1
            if self.q_hold is None:
                self.q_hold = q + qd * np.abs(qd) / (2 * 0.5 * u_max)
            u = braking_input(q, qd, self.q_hold, u_max)
        else:
            ref = self.refs.pop(stamp, None)
            if ref is None:
                self.counters["no_reference"] += 1
                qd_ref, qdot_ref, qdd_ref = q.copy(), np.zeros_like(q), np.zeros_like(q)
            else:
                ridx = {n: i for i, n in enumerate(ref.name)}
                qd_ref = np.array([ref.position[ridx[j]] for j in self.joints])
                qdot_ref = np.array([ref.velocity[ridx[j]] for j in self.joints])
                qdd_ref = np.array([ref.acceleration[ridx[j]] for j in self.joints])
            u = np.empty(len(self.joints))
            for i, j in enumerate(self.joints):
                g = self.gains[j]
                u[i] = (qdd_ref[i] + g.omega ** 2 * (qd_ref[i] - q[i])
                        + 2 * g.zeta * g.omega * (qdot_ref[i] - qd[i]))
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
