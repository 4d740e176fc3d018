"""reference_node: streams ``/reference`` from the reference generator.

For every ``/joint_states`` sample it publishes the reference at that stamp (time since
the first sample), stamped with the measurement's stamp, so the controller pairs the two
by stamp, and named with the generator's joints (the LWA-4P's, in its order), so the
controller pairs them by name whatever the order of names on ``/joint_states``. Random
trapezoidal / quintic point-to-point moves inside the position box with |qd_d| <= qd_max
and |qdd_d| <= qdd_max (the paper's U_ref), reproducible from ``seed``; ``lead``: the share
of moves led by one joint at its full limits (:class:`reachset_ros.sim.reference.ReferenceConfig`).

``hold`` (settable at run time): the move under way is finished and the reference then
rests at its end point (velocity and acceleration 0) until ``hold`` is cleared; the moves
then continue where they stopped (:class:`reachset_ros.sim.reference.ReferenceStream`).

A safe stop (``/safe_stop`` active) is followed: while it lasts the reference is the arm's
measured position at rest (q_d = q, qd_d = qdd_d = 0), so it does not run away from the held
arm; when the stop is cleared (the monitor's reset) the stream is re-synchronised to the
arm: it rests at the measured position for ``resume_rest`` s, then new moves start from
there (:meth:`ReferenceStream.restart`), so tracking resumes with no jump.

``trajectory_file`` (a bag with ``/reference``, e.g. written by ``reachset excite``): the node
plays that reference instead of random moves (:class:`reachset_ros.sim.excite.TrajectoryPlayer`:
time 0 at the first ``/joint_states`` sample, exact between the file's samples, at rest at its
last sample once it ends); the file must start and end at rest and stay inside the class
(``qd_max``, ``qdd_max``), else the node exits 2 naming the problem. ``hold`` runs on to the
file's next rest and waits there; after a cleared safe stop the file is not resumed (it would
jump from where the arm is held): the reference rests at the arm's position.

``envelope_model`` (a model file whose identification recorded its validated envelope, issue
37.3): the random moves are kept inside the envelope's position, velocity and acceleration axes
(:func:`reachset_ros.conformance.envelope.reference_limits`: the box, ``qd_max`` and ``qdd_max``
cut per joint; each cut is logged, naming the part of the class the model was never validated
on; a joint the envelope does not record keeps its limits, logged). The axes only: a combination
of features the envelope's grids never saw can still occur. A model without an envelope, or
``trajectory_file`` beside it: exit 2.
"""
import dataclasses

import numpy as np
from rclpy.node import Node
from reachset_msgs.msg import JointReference, SafeStop
from sensor_msgs.msg import JointState

from ..errors import ReachsetError
from ..sim.excite import TrajectoryPlayer, load_trajectory
from ..sim.reference import ReferenceConfig, ReferenceGenerator, ReferenceStream
from ..robot.dynamics import JOINT_NAMES
from .common import SAFE_STOP_QOS, TICK_QOS, declare_realtime_priority, desc, spin_node, stamp_ns


class ReferenceNode(Node):
    def __init__(self):
        super().__init__("reference_node")
        declare_realtime_priority(self)
        self.declare_parameter("seed", 0, desc("seed of the random moves", 0, 2 ** 31 - 1, integer=True,
                                               read_only=True))
        self.declare_parameter("qd_max", 0.7, desc("velocity limit, rad/s", 0.01, 2.0, read_only=True))
        self.declare_parameter("qdd_max", 2.0, desc("acceleration limit (U_ref), rad/s^2", 0.01, 20.0,
                                                    read_only=True))
        self.declare_parameter("lead", 0.0, desc("share of the moves led by one joint (in turn) at its full "
                                                 "qd_max and qdd_max, the others finishing with it: data that "
                                                 "reaches the class' limits on every joint", 0.0, 1.0,
                                                 read_only=True))
        self.declare_parameter("hold", False, desc("finish the move under way, then rest at its end point "
                                                   "until cleared (no new moves)"))
        self.declare_parameter("trajectory_file", "", desc("a bag whose /reference this node plays instead of random "
                                                           "moves (reachset excite writes one); '' for random moves",
                                                           read_only=True))
        self.declare_parameter("envelope_model", "", desc("a model file with a validated envelope: the random moves "
                                                          "stay inside its position, velocity and acceleration axes "
                                                          "('' : the class' own limits)", read_only=True))
        qd_max, qdd_max = float(self.get_parameter("qd_max").value), float(self.get_parameter("qdd_max").value)
        cfg = ReferenceConfig(qd_max=qd_max, qdd_max=qdd_max, lead=float(self.get_parameter("lead").value))
        path = str(self.get_parameter("trajectory_file").value)
        cfg = self.inside_envelope(cfg, str(self.get_parameter("envelope_model").value), path)
        if path:
            traj = load_trajectory(path, qd_max=qd_max, qdd_max=qdd_max)
            self.stream, self.names = TrajectoryPlayer(traj), list(traj.names)
            self.get_logger().info(f"playing {path}: {len(traj)} samples, {traj.t[-1]:.1f} s")
        else:
            self.stream = ReferenceStream(ReferenceGenerator(cfg, seed=int(self.get_parameter("seed").value)))
            self.names = list(JOINT_NAMES)
        self.pub = self.create_publisher(JointReference, "reference", TICK_QOS)
        self.declare_parameter("resume_rest", 1.0, desc("after a cleared safe stop: rest this long (s) at the arm's "
                                                        "position before new moves", 0.0, 60.0))
        self.create_subscription(JointState, "joint_states", self.on_joint_states, TICK_QOS)
        self.create_subscription(SafeStop, "safe_stop", self.on_safe_stop, SAFE_STOP_QOS)
        self.stopped = False         # a safe stop is active: the reference is the measured position
        self.resync = False          # the stop was cleared: restart from the next measurement

    def inside_envelope(self, cfg, model_file, trajectory_file):
        """``cfg`` with its limits cut to the envelope of ``model_file`` (unchanged for '')."""
        if not model_file:
            return cfg
        if trajectory_file:
            raise ReachsetError("envelope_model and trajectory_file: give one (a played file is not cut)")
        from ..conformance import model as mdl
        from ..conformance.envelope import reference_limits
        env = mdl.load(model_file).envelope
        if env is None:
            raise ReachsetError(f"{model_file}: the model records no validated envelope (identify records one)")
        limits, cut = reference_limits(env, list(JOINT_NAMES), q_min=cfg.q_min, q_max=cfg.q_max,
                                       qd_max=cfg.qd_max, qdd_max=cfg.qdd_max)
        for line in cut:
            self.get_logger().warning(f"reference class cut to the validated envelope: {line}")
        if not cut:
            self.get_logger().info("the reference class lies inside the validated envelope's axes")
        return dataclasses.replace(cfg, **limits)

    def on_safe_stop(self, msg):
        if msg.active and not self.stopped:
            self.get_logger().warning(f"safe stop active ({msg.kind}): the reference holds the measured position")
        if not msg.active and self.stopped:
            self.resync = True
        self.stopped = bool(msg.active)

    def measured(self, msg):
        """The measured positions in the generator's joint order, or None if unusable."""
        idx = {n: i for i, n in enumerate(msg.name)}
        if len(msg.position) < len(msg.name) or any(j not in idx for j in self.names):
            return None
        q = np.array([msg.position[idx[j]] for j in self.names], dtype=np.float64)
        return q if np.all(np.isfinite(q)) else None

    def on_joint_states(self, msg):
        stamp = stamp_ns(msg.header.stamp)
        q_meas = self.measured(msg) if (self.stopped or self.resync) else None
        if self.stopped and q_meas is not None:
            z = np.zeros(len(q_meas))
            self.publish(msg, q_meas, z, z)
            return
        if self.resync and q_meas is not None:
            rest = float(self.get_parameter("resume_rest").value)
            self.stream.restart(stamp, q_meas, rest)
            self.resync = False
            self.get_logger().info(f"safe stop cleared: the reference restarts from the arm's position at stamp "
                                   f"{stamp} (resting {rest:g} s, then new moves)")
        q, qd, qdd = self.stream.at(stamp, bool(self.get_parameter("hold").value))
        self.publish(msg, q, qd, qdd)
        if getattr(self.stream, "done", False) and not getattr(self, "_told_done", False):
            self._told_done = True
            self.get_logger().info("trajectory file played to its end: the reference rests at its last sample")

    def publish(self, msg, q, qd, qdd):
        out = JointReference()
        out.header.stamp = msg.header.stamp
        out.name = self.names[:len(q)]
        out.position = [float(x) for x in q]
        out.velocity = [float(x) for x in qd]
        out.acceleration = [float(x) for x in qdd]
        self.pub.publish(out)


def main(args=None):
    spin_node(ReferenceNode, args)


if __name__ == "__main__":
    main()
