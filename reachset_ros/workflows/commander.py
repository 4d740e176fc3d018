"""The suite commander: a client that drives the node suite from one process.

In the way navigation2's ``nav2_simple_commander.BasicNavigator`` drives Nav2, a
:class:`SuiteCommander` (an rclpy node of its own) offers the verbs a workflow over the suite
needs: start and stop the nodes' processes (:mod:`reachset_ros.processes`), record a bag, apply
a model to the monitor, apply gains, reset the monitor, inject a fault (the simulator's, a
link's through the relay, a killed or frozen process), wait for a stop, and spin for a time
of the simulation's clock (``/clock`` from sim_node; the commander runs with
``use_sim_time``). Every node is a separate process talking over DDS; the commander only
starts and stops them, calls their services and parameters, and listens to ``/safe_stop``
and ``/sim/fault_onset``. :mod:`.demo` (``reachset demo``) and :mod:`.campaign` (the fault
campaign) are its users.

Use it with :func:`open_commander`, which initialises rclpy when nobody has (signals stay
the caller's) and, on the way out, stops every process the commander started.
"""
from __future__ import annotations

import os
import signal
import time
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.signals import SignalHandlerOptions
from reachset_msgs.msg import SafeStop
from reachset_msgs.srv import Synthesize
from std_msgs.msg import Header
from std_srvs.srv import Trigger

from .. import processes
from ..nodes.common import MONITOR_STARTED, SAFE_STOP_QOS, get_remote_parameters, set_remote_parameters
from ..nodes.pair_gate import set_pair
from ..robot.dynamics import JOINT_NAMES

JOINTS = list(JOINT_NAMES)
CORE_TOPICS = ["/joint_states", "/plant_input", "/reference", "/observer/estimate", "/effort_commands"]
#: the simulated arm waits this long (s) for a late command before holding the previous one:
#: a held command is a disturbance the training data would then contain (a 250 ms stall of
#: the loaded 2-core machine once gave 6 such steps and sets 40x larger); below the monitor's
#: watchdog limit (125 ticks = 0.5 s) so that a stall is not taken for missing data
LOCKSTEP_TIMEOUT = 0.3
MONITOR_TOPICS = CORE_TOPICS + ["/conformance/status", "/safe_stop", "/diagnostics", "/sim/fault_onset",
                                 "/brake_command"]
#: the commander's node name (the demo's conductor since the first demo)
NODE_NAME = "demo_driver"


#: a held phase (:meth:`SuiteCommander.run_steps`) may take this many times :func:`wall_limit`
HELD_WALL_FACTOR = 4


def wall_limit(seconds):
    """Wall time (s) after which a phase of ``seconds`` simulated seconds fails: the
    simulation then runs at less than about a fifth of real time (a stalled or dead node)."""
    return 30.0 + 5.0 * seconds


@dataclass(frozen=True, kw_only=True)
class Reset:
    """A monitor reset the monitor accepted: ``refused`` times refused before, accepted at
    ``at_ns`` of the simulation's clock."""

    refused: int
    at_ns: int


class SuiteCommander(Node):
    """The suite's commander node.

    Parameters
    ----------
    workdir : str or Path
        Where the processes it starts write their parameter files and logs.
    stop : reachset_ros.processes.StopRequest, optional
        Looked at after every spin, where :class:`reachset_ros.processes.Interrupted` ends the
        workflow.
    node_name : str
    use_sim_time : bool
        Run on the simulation's ``/clock`` (the demo, the campaign); False for a client of a
        suite that may run a real arm (:mod:`.operator`).
    """

    def __init__(self, *, workdir, stop=None, node_name=NODE_NAME, use_sim_time=True):
        super().__init__(node_name, parameter_overrides=[Parameter("use_sim_time", value=use_sim_time)])
        self.workdir = Path(workdir)
        self.stop = stop
        self.stops = []          # every /safe_stop message
        self.onsets = []         # every /sim/fault_onset message
        self.group = []          # every process started (close() stops them)
        self.procs = {}          # the newest process of each node name
        self._sim_steps = None   # a held simulation's clock: start stamp, period, measurement limit
        self.create_subscription(SafeStop, "safe_stop", self.stops.append, SAFE_STOP_QOS)
        self.create_subscription(Header, "sim/fault_onset", self.onsets.append, SAFE_STOP_QOS)
        # its own executor: /clock wakes it every tick, and rclpy.spin_once would add the node
        # to the global executor and remove it again at each wake-up. Not the nodes'
        # EventsExecutor: with it, this process once hung in rclpy's shutdown (in
        # Context._logging_fini) after the demo had finished.
        self.own_executor = SingleThreadedExecutor()   # Node.executor holds only a weak reference
        self.own_executor.add_node(self)

    # ------------------------------------------------------------------ spinning and time
    def spin_once(self, timeout_sec):
        self.own_executor.spin_once(timeout_sec=timeout_sec)
        if self.stop is not None:
            self.stop.check()

    def spin_for(self, seconds, until=None):
        """Spin ``seconds`` of wall time, or until ``until()``; returns whether it was met."""
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            self.spin_once(0.05)
            if until is not None and until():
                return True
        return False

    def sim_now(self):
        """The simulation's time, ns (0 before the first ``/clock``)."""
        return self.get_clock().now().nanoseconds

    def spin_sim(self, seconds, until=None, since=None):
        """Spin for ``seconds`` of simulated time (from ``since``, ns, default now), or until
        ``until()``; returns ``(until_met, real_time_factor)``. Raises when the simulation
        does not advance that far within ``wall_limit(seconds)`` of wall time."""
        wall0 = time.monotonic()
        wall_end = wall0 + wall_limit(seconds)
        while self.sim_now() == 0:
            if time.monotonic() > wall_end:
                raise RuntimeError("no /clock from sim_node: the simulation is not running")
            self.spin_once(0.05)
        start = since if since is not None else self.sim_now()
        sim0, end = self.sim_now(), start + int(seconds * 1e9)
        met = False
        while self.sim_now() < end:
            if time.monotonic() > wall_end:
                raise RuntimeError(f"the simulation advanced {(self.sim_now() - sim0) * 1e-9:.1f} s in "
                                   f"{time.monotonic() - wall0:.0f} s of wall time: a node is stalled or dead")
            self.spin_once(0.05)
            if until is not None and until():
                met = True
                break
        wall = time.monotonic() - wall0
        return met, ((self.sim_now() - sim0) * 1e-9 / wall if wall > 0 else float("nan"))

    def run_steps(self, seconds):
        """Let a held simulation (sim_node started with ``measurement_limit`` 0) publish
        ``round(seconds / dt)`` more measurements, then hold again; returns once the last of them
        is on ``/clock``, with its real-time factor. A phase is then a fixed count of simulation
        steps, the same on a quick or a loaded machine (issue 35.4): nothing moves while the
        workflow starts a recorder, synthesises or applies gains."""
        if self._sim_steps is None:
            values, why = get_remote_parameters(self, "sim_node", ("start_stamp_ns", "dt", "measurement_limit"))
            if values is None:
                raise RuntimeError(f"cannot read the simulation's clock parameters: {why}")
            if int(values["measurement_limit"]) < 0:
                raise RuntimeError("the simulation is not held (sim_node measurement_limit -1): no fixed steps")
            self._sim_steps = {"start": int(values["start_stamp_ns"]), "dt_ns": int(round(values["dt"] * 1e9)),
                               "limit": int(values["measurement_limit"])}
        st = self._sim_steps
        n = int(round(seconds * 1e9 / st["dt_ns"]))
        wall0 = time.monotonic()
        st["limit"] += n
        self.set_parameters("sim_node", {"measurement_limit": st["limit"]}, refused="the simulation refused to step")
        last = st["start"] + (st["limit"] - 1) * st["dt_ns"]
        # held steps wait for every command (up to the lockstep timeout each): an overloaded
        # machine makes them slower, not different, so the limit only bounds a dead loop
        # (bench_demo once exceeded wall_limit(3 s) = 45 s at load average 17)
        limit = HELD_WALL_FACTOR * wall_limit(seconds)
        if not self.spin_for(limit, until=lambda: self.sim_now() >= last):
            raise RuntimeError(f"the simulation did not publish {n} steps within {limit:.0f} s of "
                               "wall time: a node is stalled or dead")
        wall = time.monotonic() - wall0
        return True, (n * st["dt_ns"] * 1e-9 / wall if wall > 0 else float("nan"))

    def release_sim(self):
        """A held simulation runs on without a limit again (``measurement_limit`` -1)."""
        self.set_parameters("sim_node", {"measurement_limit": -1}, refused="the simulation refused to run on")
        self._sim_steps = None

    def wait_for_loop(self, timeout=120.0):
        """Wait until the loop's nodes have joined the graph (the observer and the reference
        subscribed to ``/joint_states``, the controller to ``/observer/estimate`` and
        ``/reference`` and publishing ``/effort_commands``), then 1 s for their matching: a held
        simulation's first measurement then reaches every node."""
        def subscribed(topic, node):
            return any(i.node_name == node for i in self.get_subscriptions_info_by_topic(topic))

        def ready():
            return (subscribed("/joint_states", "observer_node") and subscribed("/joint_states", "reference_node")
                    and subscribed("/observer/estimate", "controller_node")
                    and subscribed("/reference", "controller_node")
                    and any(i.node_name == "controller_node"
                            for i in self.get_publishers_info_by_topic("/effort_commands")))
        if not self.spin_for(timeout, until=ready):
            raise RuntimeError(f"the loop's nodes did not come up within {timeout:.0f} s")
        self.spin_for(1.0)

    def sim_wait(self, seconds, until=None):
        """:meth:`spin_sim` without the real-time factor: whether ``until()`` was met."""
        return self.spin_sim(seconds, until=until)[0]

    def call(self, srv_type, name, request, timeout=600.0):
        """Call service ``name`` and spin until its answer (raises when none comes)."""
        client = self.create_client(srv_type, name)
        try:
            if not client.wait_for_service(timeout_sec=30.0):
                raise RuntimeError(f"service {name} not available")
            fut = client.call_async(request)
            end = time.monotonic() + timeout
            while not fut.done() and time.monotonic() < end:
                self.spin_once(0.1)
            if not fut.done():
                raise RuntimeError(f"service {name} timed out after {timeout:.0f} s")
            return fut.result()
        finally:
            self.destroy_client(client)

    # ------------------------------------------------------------------ processes
    def start(self, node, params, *, node_name=None, remap=None):
        """Start ``reachset_ros.nodes.<node>`` (:func:`reachset_ros.processes.start`); stopped by
        :meth:`close` if not before."""
        proc = processes.start(node, params, self.workdir, node_name=node_name, group=self.group, remap=remap)
        self.procs[node_name or node] = proc
        return proc

    def stop_processes(self, procs, *, timeout=10.0):
        """Stop ``procs`` gracefully (:func:`reachset_ros.processes.stop`)."""
        processes.stop(list(procs), timeout=timeout)

    def stop_all(self):
        """Stop every process the commander started."""
        processes.stop(self.group)

    def kill(self, name):
        """SIGKILL the process of node ``name`` (a crash)."""
        os.kill(self.procs[name].proc.pid, signal.SIGKILL)

    def freeze(self, name, seconds):
        """SIGSTOP the process of node ``name`` for ``seconds`` of wall time, then SIGCONT."""
        pid = self.procs[name].proc.pid
        os.kill(pid, signal.SIGSTOP)
        try:
            self.spin_for(seconds)
        finally:
            os.kill(pid, signal.SIGCONT)

    def record(self, path, topics, *, node_name, wait_s=60.0):
        """Start a recorder of ``topics`` to bag ``path``; returns once it has subscribed to
        every topic (a loaded machine can take many seconds to start a process, so not after
        a fixed pause) and had 0.5 s to match the publishers. Stop it with
        :meth:`stop_processes`."""
        rec = self.start("recorder_node", {"output": str(path), "topics": topics, "use_sim_time": True},
                         node_name=node_name)
        if not self.spin_for(wait_s, until=lambda: all(
                any(i.node_name == node_name for i in self.get_subscriptions_info_by_topic(t)) for t in topics)):
            raise RuntimeError(f"{node_name} did not subscribe to {topics} within {wait_s:.0f} s")
        self.spin_for(0.5)  # matching with the publishers
        return rec

    # ------------------------------------------------------------------ parameters
    def set_parameters(self, target, values, *, refused):
        """Set parameters of node ``target`` atomically; raises ``RuntimeError("{refused}:
        {reason}")`` when it refuses or does not answer."""
        ok, why = set_remote_parameters(self, target, values)
        if not ok:
            raise RuntimeError(f"{refused}: {why}")

    def apply_model(self, model_file):
        """Give the monitor the model ``model_file`` (its ``model_file`` parameter)."""
        self.set_parameters("monitor_node", {"model_file": str(model_file)}, refused="monitor refused the model")

    def apply_gains(self, gains, *, targets=("observer_node", "controller_node")):
        """Set the gain parameters ``gains`` (``{name: value}``) on each of ``targets``, all or
        none (:func:`reachset_ros.nodes.pair_gate.set_pair`: each node certifies the pair that
        will run with the other's running half; the other order is tried, accepted targets
        are set back on a refusal); raises ``RuntimeError`` naming the node that refused."""
        ok, why = set_pair(self, {t: dict(gains) for t in targets})
        if not ok:
            raise RuntimeError(f"the gains were refused: {why}")

    def inject_fault(self, kind, *, joint, magnitude):
        """The simulator's fault ``kind`` on ``joint`` (its ``fault*`` parameters)."""
        self.set_parameters("sim_node", {"fault_joint": joint, "fault_magnitude": float(magnitude), "fault": kind},
                            refused="fault injection refused")

    def clear_fault(self):
        """The simulator without a fault again."""
        self.set_parameters("sim_node", {"fault": "none"}, refused="clearing the fault")

    def set_link(self, *, drop_share=0.0, drop_every=0, delay_s=0.0):
        """The relay's link fault (all zero: none)."""
        self.set_parameters("relay_node", {"drop_share": float(drop_share), "drop_every": int(drop_every),
                                           "delay_s": float(delay_s)}, refused="the relay refused the link fault")

    # ------------------------------------------------------------------ the monitor and stops
    def reset_monitor(self, *, patience_s=None, retry_s=0.25):
        """The monitor's ``~/reset``; returns a :class:`Reset`.

        ``patience_s`` None: a refusal raises at once. Else the reset is tried again every
        ``retry_s`` of simulated time while it is refused because the stop's condition has not
        cleared (the arm still coming to rest), for up to ``patience_s`` simulated seconds."""
        t0 = self.sim_now()
        refused = 0
        while True:
            r = self.call(Trigger, "/monitor_node/reset", Trigger.Request(), timeout=30.0)
            if r.success:
                return Reset(refused=refused, at_ns=self.sim_now())
            if patience_s is None:
                raise RuntimeError(f"monitor reset failed: {r.message}")
            refused += 1
            if self.sim_now() - t0 > patience_s * 1e9:
                raise RuntimeError(f"monitor reset refused for {patience_s:g} s: {r.message}")
            self.sim_wait(retry_s)

    def wait_for_monitor(self, timeout=120.0):
        """Spin until the monitor's first ``/safe_stop`` state (it has started)."""
        if not self.spin_for(timeout, until=lambda: bool(self.stops)):
            raise RuntimeError(f"no /safe_stop state from the monitor within {timeout:.0f} s")

    def start_monitor(self, params, *, remap=None, timeout=120.0):
        """Start ``monitor_node`` (``params`` name its ``model_file``) and spin until it has
        released its start-up stop (issue 34.1): the controller holds the arm at rest under
        that stop, and k* + 1 ticks of the held arm checked conformant release it. A stop the
        monitor latches meanwhile (a violation, a fault), or no release within ``timeout`` s
        of wall time, raises. Returns the process."""
        n = len(self.stops)

        def done():
            return any(s.active and s.kind != "not_ready" or not s.active and s.reason == MONITOR_STARTED
                       for s in self.stops[n:])
        proc = self.start("monitor_node", params, remap=remap)
        met = self.spin_for(timeout, until=done)
        stopped = [s for s in self.stops[n:] if s.active and s.kind != "not_ready"]
        if stopped or not met:
            why = f"{stopped[0].kind}: {stopped[0].reason}" if stopped else f"no release within {timeout:.0f} s"
            raise RuntimeError(f"the monitor did not release its start-up stop ({why}; log {proc.log})")
        return proc

    def active_stops(self):
        """The active ``/safe_stop`` messages received."""
        return [s for s in self.stops if s.active]

    def wait_for_stop(self, seconds, *, since=None):
        """:meth:`spin_sim` until an active stop: ``(stopped, real_time_factor)``."""
        return self.spin_sim(seconds, until=lambda: bool(self.active_stops()), since=since)

    def wait_for_onset(self, timeout):
        """Spin (wall time) until a ``/sim/fault_onset``; whether one came."""
        return self.spin_for(timeout, until=lambda: bool(self.onsets))

    # ------------------------------------------------------------------ synthesis
    def synthesize(self, bags, *, joints, mode="combined", apply=True, timeout=600.0):
        """The synthesis node's ``~/synthesize`` on ``bags``; returns its response."""
        req = Synthesize.Request(bags=[str(b) for b in bags], joints=list(joints), mode=mode, apply=apply)
        return self.call(Synthesize, "/synthesis_node/synthesize", req, timeout=timeout)

    def close(self):
        """Stop every process started, then the commander's executor and node."""
        try:
            self.stop_all()
        finally:
            self.own_executor.shutdown(timeout_sec=1.0)
            self.destroy_node()


@contextmanager
def open_commander(*, workdir, stop=None, node_name=NODE_NAME, use_sim_time=True):
    """A :class:`SuiteCommander`, closed on the way out (every process it started stopped).

    rclpy is initialised here when it is not yet (with the signals left to the caller, e.g.
    a :class:`reachset_ros.processes.StopRequest`, not to rclpy, which would shut the context
    down) and then shut down here too. The nodes run in this process' ``ROS_DOMAIN_ID``."""
    own = not rclpy.ok()
    if own:
        processes.use_dds_profiles()
        rclpy.init(signal_handler_options=SignalHandlerOptions.NO)
    try:
        commander = SuiteCommander(workdir=workdir, stop=stop, node_name=node_name, use_sim_time=use_sim_time)
        try:
            yield commander
        finally:
            commander.close()
    finally:
        if own:
            rclpy.try_shutdown()
