"""sim_node: the simulated LWA-4P (reachset_ros.sim.simulator) as a ROS node.

Publishes ``/joint_states`` at 250 Hz from its own clock (stamp = the simulator's tick
time, anchored to the wall clock at start); applies the latest ``/effort_commands``
(joint order of the ``joints`` parameter) with the paper's one-sample input delay. In
lockstep mode (``lockstep_timeout`` > 0, the default) a tick waits, up to that timeout,
for the command computed from the previous measurement, so that DDS latency on a loaded
machine does not add delays the model does not have; the stamps stay on the simulation
clock. With 0 it runs free like a real drive and holds the last command. ``/brake_command``
(reachset_msgs/BrakeCommand, by joint name) engages and releases the simulated holding
brakes; the simulated arm also has hard stops at the URDF's position limits and clamps
torques to its effort limits (:mod:`reachset_ros.sim.simulator`): each such event, an
invalid command and each brake engagement is logged. Faults are
injected through the ``fault`` parameters (``none`` clears them all); the stamp of the
first measurement a fault can change is published, latched, on ``/sim/fault_onset``
(std_msgs/Header, frame_id = the fault's description). With ``publish_clock`` (the
default) it also publishes ``/clock`` (rosgraph_msgs/Clock, the stamp of each
measurement), as Gazebo does, so that nodes run with ``use_sim_time: true`` (the demo's
recorder and conductor) follow the simulation's time whatever the machine's load.

A step on a stale command (the lockstep timeout passed without the command of the last
measurement: the drive held the previous one, an input the recorded ``/plant_input`` does
not show) is never silent: each is logged (throttled to one line a second, with the count)
and counted on ``/diagnostics`` (``reachset_ros: simulator``, about 1 Hz, WARN while such
steps occur, with ``stale_effort``, ``last_stale_stamp_ns`` and the longest run of
consecutive stale steps).

In lockstep the monitor's verdicts are waited for too (``monitor_lockstep_ticks``, 5 by
default): a step that would publish a measurement more than that many ticks after the newest
one ``/conformance/status`` has reported checked waits, within the same ``lockstep_timeout``,
for the monitor to catch up. A real arm does not wait for its monitor; the real-time monitor
keeps up with it (docs/performance.md). A simulation that runs slower than real time on a
loaded machine, with the monitor a process among many, would otherwise let the monitor fall
behind the simulated arm by hundreds of ticks (up to 1.3 s of stamp time in a
``make test`` on a slow machine, 2026-11-26), and a stop would reach the controller that much
later in the arm's time: a delay of the simulation, not of the monitor. There is no wait
before the first status is heard (no monitor, or a monitor without a model) or while the
monitor has been silent for ``lockstep_timeout`` (frozen, dead, deactivated): the simulation
then steps ahead of it, and each such step is logged (throttled) and counted on
``/diagnostics`` (``ahead_of_monitor``, ``last_ahead_stamp_ns``), like a stale command.
"""
import time

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rcl_interfaces.msg import SetParametersResult
from rclpy.node import Node
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState
from reachset_msgs.msg import BrakeCommand, ConformanceStatus
from std_msgs.msg import Float64MultiArray, Header

from ..sim import simulator as sim
from ..errors import ReachsetError
from ..sim.reference import ReferenceConfig
from .common import (CLOCK_QOS, SAFE_STOP_QOS, TICK_QOS, declare_realtime_priority, desc, spin_node, stamp_ns,
                     to_stamp)
from .param_callbacks import StagedRequest, add_parameter_callbacks

#: how far (s) the simulation may fall behind its wall-clock schedule and still catch up
CATCH_UP = 1.0

FAULTS = ("none", "payload", "torque", "acceleration", "bias", "frozen", "nan")


def make_fault(kind, joint, magnitude, start_s):
    if kind == "payload":
        return sim.Payload(start_s=start_s, mass=magnitude)
    if kind == "torque":
        return sim.TorqueDisturbance(start_s=start_s, joint=joint, torque=magnitude)
    if kind == "acceleration":
        return sim.AccelerationDisturbance(start_s=start_s, joint=joint, acceleration=magnitude)
    if kind == "bias":
        return sim.SensorBias(start_s=start_s, joint=joint, bias=magnitude)
    if kind == "frozen":
        return sim.FrozenSensor(start_s=start_s, joint=joint)
    if kind == "nan":
        return sim.NaNSamples(start_s=start_s, joint=joint, count=max(1, int(magnitude)))
    raise ReachsetError(f"unknown fault {kind!r}; known: {', '.join(FAULTS)}")


class SimNode(Node):
    def __init__(self):
        super().__init__("sim_node")
        declare_realtime_priority(self)
        self.declare_parameter("seed", 0, desc("seed of noise and model error", 0, 2 ** 31 - 1, integer=True,
                                               read_only=True))
        self.declare_parameter("realistic", True, desc("model error, friction, quantization, noise", read_only=True))
        self.declare_parameter("calibrated", False,
                               desc("the simulated LWA-4P calibrated to the real one (SimConfig.calibrated: the "
                                    "identified nominal model with per-joint friction error and noise; the "
                                    "controller's robot_params must then be config/lwa4p_nominal.yaml); "
                                    "takes precedence over realistic", read_only=True))
        self.declare_parameter("dt", 0.004, desc("tick period, s", 1e-4, 1.0, read_only=True))
        self.declare_parameter("lockstep_timeout", 0.05,
                               desc("wait up to this long (s) for the command of the last measurement "
                                    "before stepping with the previous one (0: free-running)", 0.0, 1.0))
        self.declare_parameter("monitor_lockstep_ticks", 5,
                               desc("in lockstep, a step also waits (within lockstep_timeout) until the monitor's "
                                    "/conformance/status has checked the measurement this many ticks before the one "
                                    "it would publish (0: never wait for the monitor; no wait before the first "
                                    "status, nor while the monitor has been silent for lockstep_timeout)",
                                    0, 100000, integer=True))
        self.declare_parameter("drive_watchdog_steps", 3,
                               desc("the drives engage every holding brake after this many consecutive steps on a "
                                    "stale command (a controller that died or stalled), as a drive's communication "
                                    "watchdog does; the next brake command releases them (0: off)", 0, 100000,
                                    integer=True))
        self.declare_parameter("publish_clock", True,
                               desc("publish /clock (the simulation's time) every tick", read_only=True))
        self.declare_parameter("measurement_limit", -1,
                               desc("publish at most this many measurements (the initial state is the first), then "
                                    "hold: no step, no /clock, until the limit is raised (-1: no limit). With 0 at "
                                    "start nothing is published until it is raised, so that every node is up before "
                                    "the first measurement: a phase of n steps is the same n steps however loaded "
                                    "the machine is (lockstep; the demo's training, issue 35.4)",
                                    -1, 2 ** 62, integer=True))
        self.declare_parameter("fault", "none",
                               desc("inject now: " + " | ".join(FAULTS[1:]) + "; none: clear all faults"))
        self.declare_parameter("fault_joint", "arm_1_joint", desc("joint of the fault"))
        self.declare_parameter("fault_magnitude", 5.0,
                               desc("kg (payload), N m (torque), rad/s^2 (acceleration), rad (bias), samples (nan)"))
        seed = int(self.get_parameter("seed").value)
        dt = float(self.get_parameter("dt").value)
        start_ns = time.time_ns() // 1_000_000 * 1_000_000
        if self.get_parameter("calibrated").value:
            cfg = sim.SimConfig.calibrated(dt=dt, start_ns=start_ns)
        elif self.get_parameter("realistic").value:
            cfg = sim.SimConfig.realistic(seed=seed, dt=dt, start_ns=start_ns)
        else:
            cfg = sim.SimConfig.ideal(dt=dt, start_ns=start_ns)
        self.arm = sim.SimulatedArm(cfg, seed=seed)
        self.declare_parameter("start_stamp_ns", int(start_ns),
                               desc("stamp of the initial measurement, ns (measurement n has start_stamp_ns + n dt)",
                                    read_only=True))
        rc = ReferenceConfig()
        q0 = 0.5 * (rc.q_min + rc.q_max)
        self.m = self.arm.reset(q0)
        self.tau = np.array(self.arm.state.tau_pending)
        self.t_start = time.monotonic()
        self.names = list(self.arm.joint_names)
        self.counters = {"ticks": 0, "stale_effort": 0, "bad_effort": 0, "stale_run_max": 0, "ahead_of_monitor": 0}
        self.dt_ns = int(round(dt * 1e9))
        self.checked_stamp = None    # newest stamp the monitor reported checked (/conformance/status)
        self.checked_wall = 0.0      # wall time of that report
        self.last_ahead_stamp = 0    # stamp of the last measurement published ahead of the monitor
        self.ahead_reported = 0      # ahead_of_monitor at the last /diagnostics
        self.stale_run = 0           # consecutive steps on a stale command now
        self.last_stale_stamp = 0    # stamp of the last measurement stepped on a stale command
        self.stale_reported = 0      # stale_effort at the last /diagnostics
        self.fresh = False
        self.pub = self.create_publisher(JointState, "joint_states", TICK_QOS)
        self.clock_pub = (self.create_publisher(Clock, "/clock", CLOCK_QOS)
                          if self.get_parameter("publish_clock").value else None)
        self.onset_pub = self.create_publisher(Header, "sim/fault_onset", SAFE_STOP_QOS)
        self.create_subscription(Float64MultiArray, "effort_commands", self.on_effort, TICK_QOS)
        self.create_subscription(BrakeCommand, "brake_command", self.on_brakes, TICK_QOS)
        self.create_subscription(ConformanceStatus, "conformance/status", self.on_status, TICK_QOS)
        self.reported = dict(self.arm.counters)
        self.diag_pub = self.create_publisher(DiagnosticArray, "diagnostics", 10)
        self.create_timer(1.0, self.publish_diagnostics)
        self.param_request = StagedRequest()
        add_parameter_callbacks(self, on_set=self.on_set_parameters, post_set=self.post_set_parameters)
        self.dt = dt
        self.next_wall = time.monotonic() + dt
        self.published_wall = time.monotonic()
        self.published = 0           # measurements published (the initial state is the first)
        if self.get_parameter("measurement_limit").value != 0:
            self.publish(self.m)
        self.create_timer(min(dt, 0.001), self.tick)

    def on_effort(self, msg):
        tau = np.asarray(msg.data, dtype=np.float64)
        if tau.shape != (len(self.names),):
            self.counters["bad_effort"] += 1
            return
        # a non-finite command goes to the simulated drives, which refuse it and engage every
        # brake (a drive fault), as a real drive would; it is not silently replaced here
        self.tau = tau
        self.fresh = True
        self.tick()  # the awaited command is here: step now if the period is due

    def on_status(self, msg):
        """The monitor's verdict of a tick: how far it has checked the measurements."""
        stamp = stamp_ns(msg.header.stamp)
        if self.checked_stamp is None or stamp > self.checked_stamp:
            self.checked_stamp = stamp
        self.checked_wall = time.monotonic()
        self.tick()  # an awaited verdict: step now if the period is due

    def held(self):
        """True while ``measurement_limit`` measurements have been published (hold: no step)."""
        limit = int(self.get_parameter("measurement_limit").value)
        return 0 <= limit <= self.published

    def ahead_of_monitor(self):
        """True when the next measurement would be more than ``monitor_lockstep_ticks`` ticks
        after the newest one the monitor has reported checked (False before any report)."""
        ticks = int(self.get_parameter("monitor_lockstep_ticks").value)
        if ticks <= 0 or self.checked_stamp is None:
            return False
        return self.m.stamp_ns + self.dt_ns - self.checked_stamp > ticks * self.dt_ns

    def on_brakes(self, msg):
        """Engage/release the holding brakes of the named joints (others unchanged)."""
        if len(msg.engage) != len(msg.name):
            self.counters["bad_brake_command"] = self.counters.get("bad_brake_command", 0) + 1
            return
        want = self.arm.brakes
        for n, e in zip(msg.name, msg.engage):
            if n in self.names:
                want[self.names.index(n)] = bool(e)
        if np.any(want != self.arm.brakes):
            on = [self.names[i] for i in np.flatnonzero(want & ~self.arm.brakes)]
            off = [self.names[i] for i in np.flatnonzero(~want & self.arm.brakes)]
            self.get_logger().warning(f"holding brakes at stamp {self.arm.stamp(self.arm.state.k)}: "
                                      + (f"engaged {', '.join(on)}" if on else "")
                                      + ("; " if on and off else "") + (f"released {', '.join(off)}" if off else "")
                                      + (f" ({msg.reason})" if msg.reason and on else ""))
            self.arm.set_brakes(want)

    def fault_request(self, params):
        """``(kind, joint, magnitude)`` of a request's ``fault`` (None without one): the joint and
        magnitude given with it, else the current parameters."""
        kind = next((p.value for p in params if p.name == "fault"), None)
        if kind is None:
            return None
        joint = self.get_parameter("fault_joint").value
        mag = float(self.get_parameter("fault_magnitude").value)
        for q in params:
            if q.name == "fault_joint":
                joint = q.value
            if q.name == "fault_magnitude":
                mag = float(q.value)
        return kind, joint, mag

    def on_set_parameters(self, params):
        """Validate a fault to inject (on_set): a known kind, on a joint of the simulated arm."""
        request = self.fault_request(params)
        if request is not None and request[0] != "none":
            kind, joint, mag = request
            try:
                fault = make_fault(kind, joint, mag, 0.0)
                if getattr(fault, "joint", None) is not None:
                    self.arm._joint(fault.joint)      # the simulator's own check of the joint (inject's)
            except ReachsetError as e:
                return SetParametersResult(successful=False, reason=str(e))
        self.param_request.hold(params)
        return SetParametersResult(successful=True)

    def post_set_parameters(self, params):
        """Clear the faults, or inject the validated one from the next step (post_set)."""
        self.param_request.take(params)
        request = self.fault_request(params)
        if request is None:
            return
        kind, joint, mag = request
        if kind == "none":
            n = self.arm.clear_faults()
            next_stamp = self.arm.stamp(self.arm.state.k + 1)
            self.get_logger().warning(f"faults cleared ({n} removed) from stamp {next_stamp} ns")
            return
        start_s = (self.arm.state.k + 1) * self.arm.config.dt
        onset = self.arm.inject(make_fault(kind, joint, mag, start_s))
        h = Header(frame_id=f"{kind} on {joint}, magnitude {mag:g}")
        to_stamp(h.stamp, onset)
        self.onset_pub.publish(h)
        self.get_logger().warning(f"fault injected: {h.frame_id}, first affected stamp {onset} ns")

    def tick(self):
        """Step when the period is due and the command of the last measurement has arrived
        and the monitor has checked up to ``monitor_lockstep_ticks`` ticks before the next
        measurement (lockstep, as a simulator may: the stamps stay on the simulation clock), or
        when ``lockstep_timeout`` has passed (then the previous command is held, as a real drive
        does, or the step goes ahead of the monitor; both counted)."""
        now = time.monotonic()
        if now < self.next_wall or self.held():
            return
        if self.published == 0:
            # held from the start: the initial state is the first measurement released
            self.next_wall = now + self.dt
            self.publish(self.m)
            self.published_wall = time.monotonic()
            return
        timeout = float(self.get_parameter("lockstep_timeout").value)
        stale = not self.fresh
        ahead = timeout > 0 and self.ahead_of_monitor()
        if timeout > 0 and now - self.published_wall < timeout and (
                stale or (ahead and now - self.checked_wall < timeout)):
            return   # the command of the last measurement, or the monitor's verdicts, are awaited
        if ahead:
            self.counters["ahead_of_monitor"] += 1
            self.last_ahead_stamp = self.m.stamp_ns + self.dt_ns
            self.get_logger().warning(
                f"stepped ahead of the monitor at stamp {self.last_ahead_stamp} (newest stamp it reported checked: "
                f"{self.checked_stamp}; {self.counters['ahead_of_monitor']} such steps so far)",
                throttle_duration_sec=1.0)
        if stale:
            self.counters["stale_effort"] += 1
            self.stale_run += 1
            self.counters["stale_run_max"] = max(self.counters["stale_run_max"], self.stale_run)
        else:
            self.stale_run = 0
        self.fresh = False
        # keep the 4 ms schedule: a tick that was late is made up by the next ones (each still
        # waits for its command); after a stall of more than CATCH_UP the schedule restarts
        self.next_wall = self.next_wall + self.dt if now - self.next_wall < CATCH_UP else now + self.dt
        wd = int(self.get_parameter("drive_watchdog_steps").value)
        if stale and wd > 0 and self.stale_run >= wd and not bool(np.all(self.arm.brakes)):
            self.counters["drive_watchdog"] = self.counters.get("drive_watchdog", 0) + 1
            self.get_logger().error(f"drive watchdog: {self.stale_run} consecutive steps without a fresh command "
                                    f"at stamp {self.arm.stamp(self.arm.state.k + 1)}: every holding brake engaged")
            self.arm.set_brakes(np.ones(len(self.names), dtype=bool))
        self.m = self.arm.step(self.tau)
        if stale:
            self.last_stale_stamp = self.m.stamp_ns
            self.get_logger().warning(
                f"stepped on a stale command at stamp {self.m.stamp_ns} (no command for the last measurement "
                f"within {timeout:g} s; {self.counters['stale_effort']} such steps so far, {self.stale_run} in a row)",
                throttle_duration_sec=1.0)
        self.published_wall = time.monotonic()
        self.counters["ticks"] += 1
        if self.arm.counters != self.reported:
            for k, v in self.arm.counters.items():
                if v > self.reported.get(k, 0) and k != "brake_engaged":
                    self.get_logger().warning(f"simulated arm at stamp {self.m.stamp_ns}: {k} "
                                              f"(now {v}; hard_stop: a joint reached a position limit, "
                                              "torque_clamped: a command beyond the effort limits was clamped, "
                                              "invalid_command: a non-finite command engaged every brake)")
            self.reported = dict(self.arm.counters)
        self.publish(self.m)

    def publish_diagnostics(self):
        """About 1 Hz: ticks, stale-command steps (WARN when some occurred since the last
        report), bad effort messages and the simulated arm's event counters."""
        arr = DiagnosticArray()
        arr.header.stamp = self.get_clock().now().to_msg()
        st = DiagnosticStatus(name="reachset_ros: simulator", hardware_id="")
        new = self.counters["stale_effort"] - self.stale_reported
        self.stale_reported = self.counters["stale_effort"]
        ahead = self.counters["ahead_of_monitor"] - self.ahead_reported
        self.ahead_reported = self.counters["ahead_of_monitor"]
        parts = []
        if new:
            parts.append(f"{new} step(s) on a stale command since the last report (last at stamp "
                         f"{self.last_stale_stamp}): the applied input is not the recorded /plant_input")
        if ahead:
            parts.append(f"{ahead} step(s) ahead of the monitor's verdicts since the last report (last at stamp "
                         f"{self.last_ahead_stamp})")
        st.level = DiagnosticStatus.WARN if parts else DiagnosticStatus.OK
        st.message = "; ".join(parts) or "stepping"
        values = dict(self.counters, last_stale_stamp_ns=self.last_stale_stamp,
                      last_ahead_stamp_ns=self.last_ahead_stamp, **self.arm.counters)
        st.values = [KeyValue(key=k, value=str(v)) for k, v in sorted(values.items())]
        arr.status = [st]
        self.diag_pub.publish(arr)

    def close(self):
        """At shutdown: say how many steps held a stale command or went ahead of the monitor."""
        c = self.counters
        self.get_logger().info(f"ticks {c['ticks']}, steps with a stale command {c['stale_effort']} "
                               f"(longest run {c['stale_run_max']}), "
                               f"steps ahead of the monitor {c['ahead_of_monitor']}, "
                               f"bad effort messages {c['bad_effort']}; simulated arm: "
                               + ", ".join(f"{k} {v}" for k, v in self.arm.counters.items()))

    def publish(self, m):
        self.published += 1
        if self.clock_pub is not None:
            c = Clock()
            to_stamp(c.clock, m.stamp_ns)
            self.clock_pub.publish(c)
        js = JointState()
        to_stamp(js.header.stamp, m.stamp_ns)
        js.name = self.names
        js.position = [float(x) for x in m.q_measured]
        js.velocity = [float(x) for x in m.qd_measured]
        js.effort = [float(x) for x in m.tau_applied]
        self.pub.publish(js)


def main(args=None):
    spin_node(SimNode, args)


if __name__ == "__main__":
    main()
