"""observer_node: HG or ESO per joint on /joint_states (+ /plant_input), publishes /observer/estimate.

The observer of each joint is the one its :class:`~reachset_ros.systems.gains.Gains` say
(``observer``, the gains, and for the ESO ``eso_input``: fed u_p[k-1] or u_p[k]), built by
the same code the synthesis certified. At a measurement stamped t the estimate
``x0 = Co xo + Do_y y[t]`` (with the feedthrough of y[t], without that of u_p[t]: with
``eso_input: current`` the controller solves that algebraic loop,
:class:`~reachset_ros.systems.closedloop.FeedbackLaw`) is published stamped t; the observer
state advances once the plant input stamped t arrives (the ESO needs it; the HG observer
ignores it). It starts (and restarts after a gain change) at the first measurement from
``LinearObserver.start_state``. A sample it cannot use (a joint missing, a non-finite
position) leaves the observer state as it was and is published as an estimate of NaN with the
sample's stamp, so the controller brakes on that tick (its "no usable estimate" stop). Gains
change only through the parameter service, atomically between ticks, and pass the same gate as the controller's
(:func:`~reachset_ros.nodes.gain_params.validate_pair`: the pair's closed loop stable and,
with a ``model_file``, R*_u inside U_p for the monitored sets; without one only with
``allow_uncertified``), and the pair that will run with the controller's current gains passes
both nodes' gates (:func:`~reachset_ros.nodes.pair_gate.check_running_pair`, ``pair_node``);
refused gains are refused with the reason.
"""
import numpy as np
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rcl_interfaces.msg import SetParametersResult
from rclpy.node import Node
from reachset_msgs.msg import JointEstimate, PlantInput
from sensor_msgs.msg import JointState

from ..conformance import model as mdl
from ..errors import ReachsetError
from ..robot.dynamics import JOINT_NAMES
from .common import TICK_QOS, declare_realtime_priority, desc, spin_node, stamp_ns
from .gain_params import (check_running_pair, current_values, declare_certificate_parameters, declare_gain_parameters,
                          log_envelope, log_gain_change, proposed_values, validate_pair)
from .param_callbacks import StagedRequest, add_parameter_callbacks


class ObserverNode(Node):
    #: this node runs the observer half of the pair (:mod:`~reachset_ros.nodes.pair_gate`)
    GAIN_ROLE = "observer"

    def __init__(self):
        super().__init__("observer_node")
        declare_realtime_priority(self)
        self.declare_parameter("joints", list(JOINT_NAMES), desc("joints, in this order", read_only=True))
        self.declare_parameter("dt", 0.004, desc("tick period, s", 1e-4, 1.0, read_only=True))
        declare_certificate_parameters(self)
        declare_gain_parameters(self)
        self.joints = list(self.get_parameter("joints").value)
        self.dt = float(self.get_parameter("dt").value)
        self.counters = {"missing_input": 0, "bad_sample": 0, "stale": 0}
        path = self.get_parameter("model_file").value
        self.model = mdl.load(path) if path else None
        try:
            self.configure(current_values(self), self.model)
        except ReachsetError as e:
            raise ReachsetError(f"start-up parameters refused: {e}") from None
        self.pub = self.create_publisher(JointEstimate, "observer/estimate", TICK_QOS)
        self.create_subscription(JointState, "joint_states", self.on_joint_states, TICK_QOS)
        self.create_subscription(PlantInput, "plant_input", self.on_plant_input, TICK_QOS)
        self.param_request = StagedRequest()
        add_parameter_callbacks(self, on_set=self.on_set_parameters, post_set=self.post_set_parameters,
                                take_repeats=True)   # a resent request runs no gate again
        self.diag_pub = self.create_publisher(DiagnosticArray, "diagnostics", 10)
        self.reported_bad = 0
        self.create_timer(1.0, self.publish_diagnostics)

    def publish_diagnostics(self):
        """About 1 Hz: the counts of skipped inputs; WARN when samples were unusable since the
        last report (an unusable /joint_states sample is published as an estimate of NaN, on
        which the controller brakes and the monitor stops), and the joints whose gains run
        uncertified."""
        arr = DiagnosticArray()
        arr.header.stamp = self.get_clock().now().to_msg()
        st = DiagnosticStatus(name="reachset_ros: observer", hardware_id="")
        new_bad = self.counters["bad_sample"] - self.reported_bad
        self.reported_bad = self.counters["bad_sample"]
        if new_bad:
            st.level, st.message = DiagnosticStatus.WARN, f"{new_bad} unusable sample(s) skipped since the last report"
        else:
            st.level, st.message = DiagnosticStatus.OK, "estimating"
        values = {k: str(v) for k, v in self.counters.items()}
        values["uncertified_joints"] = ",".join(self.uncertified)
        st.values = [KeyValue(key=k, value=v) for k, v in values.items()]
        arr.status = [st]
        self.diag_pub.publish(arr)

    def configure(self, values, model):
        """Validate and apply a configuration (start-up); ReachsetError with the reason."""
        cfg = self.validate(values, model)
        self.apply(cfg)
        log_envelope(self, cfg, "start-up")

    def validate(self, values, model):
        """The pair's gate (as the controller's) and each observer stable; nothing applied.
        Returns the configuration :meth:`apply` takes, or raises ReachsetError."""
        cfg = validate_pair(self, values, model)      # the pair's gate, as the controller's
        gains = cfg["gains"]
        observers = {j: g.build_observer(self.dt) for j, g in gains.items()}
        for j, o in observers.items():
            rho = max(abs(np.linalg.eigvals(o.Ao))) if o.n_states else 0.0
            if rho >= 1.0:
                raise ReachsetError(f"observer of joint {j} is unstable (spectral radius {rho:.4g})")
        return dict(cfg, observers=observers, model=model)

    def apply(self, cfg):
        """Run a validated configuration: the observers restart at the next measurement."""
        if cfg["uncertified"] and cfg["uncertified"] != getattr(self, "uncertified", None):
            self.get_logger().warning(f"gains of {', '.join(cfg['uncertified'])} run without a certificate "
                                      "(allow_uncertified): closed-loop stability only")
        self.uncertified = cfg["uncertified"]
        self.model = cfg["model"]
        self.observers = cfg["observers"]
        self.states = {j: o.initial_state() for j, o in self.observers.items()}
        self.initialised = False
        self.pending = None  # (stamp, y per joint) awaiting its plant input

    def on_set_parameters(self, params):
        """Validate a request (on_set); a refused one is logged (PRIVILEGED) and changes nothing
        (a repeat of the running values never comes here: ``take_repeats``)."""
        model = self.model
        try:
            for p in params:
                if p.name == "model_file":
                    model = mdl.load(p.value) if p.value else None
            values = proposed_values(self, params)
            cfg = self.validate(values, model)
            check_running_pair(self, params, values, model)     # with the controller's running half (issue 34.6)
        except ReachsetError as e:
            result = SetParametersResult(successful=False, reason=str(e))
            log_gain_change(self, params, result)
            return result
        self.param_request.hold(params, cfg)
        return SetParametersResult(successful=True)

    def post_set_parameters(self, params):
        """Apply the configuration :meth:`on_set_parameters` validated for this request (post_set)."""
        cfg = self.param_request.take(params)
        self.apply(cfg)
        log_gain_change(self, params, SetParametersResult(successful=True), cfg)

    def on_joint_states(self, msg):
        stamp = stamp_ns(msg.header.stamp)
        idx = {n: i for i, n in enumerate(msg.name)}
        if any(j not in idx for j in self.joints) or len(msg.position) < len(msg.name):
            self.unusable_sample(msg)
            return
        y = {j: float(msg.position[idx[j]]) for j in self.joints}
        if not all(np.isfinite(v) for v in y.values()):
            self.unusable_sample(msg)
            return
        if self.pending is not None:
            # the plant input of the previous tick never came: advance with the last known one
            self.counters["missing_input"] += 1
            self.advance(self.pending[1], self.last_u if hasattr(self, "last_u") else {j: 0.0 for j in self.joints})
        if not self.initialised:
            self.states = {j: o.start_state(y[j]) for j, o in self.observers.items()}
            self.initialised = True
        out = JointEstimate()
        out.header.stamp = msg.header.stamp
        out.name = list(self.joints)
        est = {j: self.states[j].partial_estimate([y[j]]) for j in self.joints}
        names = {j: self.observers[j].estimate_names for j in self.joints}
        out.position = [float(est[j][names[j].index("q")]) for j in self.joints]
        out.velocity = [float(est[j][names[j].index("qd")]) for j in self.joints]
        out.disturbance = [float(est[j][names[j].index("d")]) if "d" in names[j] else 0.0 for j in self.joints]
        self.pub.publish(out)
        self.pending = (stamp, y)

    def unusable_sample(self, msg):
        """A /joint_states sample without a finite position of every joint: counted, the
        observer state untouched (a NaN would poison it for good), and an estimate of all NaN
        published with the sample's stamp. That is the controller's "no usable estimate": it
        engages every brake on this tick. Skipping the tick instead left the controller without
        a tick to act on, so it commanded nothing until the next finite sample (3 ticks late in
        the fault campaign's NaN events)."""
        self.counters["bad_sample"] += 1
        out = JointEstimate()
        out.header.stamp = msg.header.stamp
        out.name = list(self.joints)
        nan = [float("nan")] * len(self.joints)
        out.position, out.velocity, out.disturbance = nan, nan, nan
        self.pub.publish(out)

    def on_plant_input(self, msg):
        if self.pending is None:
            return
        stamp = stamp_ns(msg.header.stamp)
        if stamp != self.pending[0]:
            self.counters["stale"] += 1
            return
        idx = {n: i for i, n in enumerate(msg.name)}
        if any(j not in idx for j in self.joints) or len(msg.acceleration) < len(msg.name):
            self.counters["bad_sample"] += 1
            return
        u = {j: float(msg.acceleration[idx[j]]) for j in self.joints}
        if not all(np.isfinite(v) for v in u.values()):
            # a non-finite input would poison the observer state for good: skip it (counted);
            # the next measurement advances with the last valid input
            self.counters["bad_sample"] += 1
            return
        self.last_u = u
        self.advance(self.pending[1], u)

    def advance(self, y, u):
        self.states = {j: self.states[j].advance([y[j]], [u[j]]) for j in self.joints}
        self.pending = None


def main(args=None):
    spin_node(ObserverNode, args)


if __name__ == "__main__":
    main()
