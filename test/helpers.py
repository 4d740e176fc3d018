"""Helpers shared by the node tests (test/nodes/, the monitor core tests): models, data, DDS harness.

A plain module, imported by the tests that use it (``from helpers import Bus, write_model``),
rather than conftest.py fixtures: what is shared here are a class and functions that take
arguments (a model's sets, a stream's seed, the topics to listen to), not set-up with a
scope. conftest.py keeps the fixtures (``ros``, ``lwa4p_dir``). This module imports rclpy and
the message packages at the top, so only the node tests import it; the pure-core tests do
not need ROS.

* :func:`write_model` - a conformance model file with the given sets for two joints;
* :func:`plant_stream`, :func:`stream` - data that follow the per-joint plant (two joints);
* :class:`Bus` - the test's side of DDS for the node fault tests (publishers, service
  calls, subscriptions spun by their own thread);
* :class:`Recorder` - subscriptions to given topics spun by their own thread;
* :func:`wait_until` - poll a condition until a timeout;
* :func:`suite_processes` - the node processes naming a work directory (:func:`cmdline`,
  :func:`running`);
* :func:`run_or_explain` - run a command that starts nodes; on a hang, fail with every
  process' stacks and the logs' tails.
"""
import os
import signal
import subprocess
import threading
import time
from pathlib import Path

import numpy as np
import rclpy
from diagnostic_msgs.msg import DiagnosticArray
from rcl_interfaces.srv import GetParameters
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy
from reachset_msgs.msg import ConformanceStatus, JointEstimate, JointReference, PlantInput, SafeStop
from sensor_msgs.msg import JointState
from std_srvs.srv import Trigger

from reachset_ros.conformance import model as mdl
from reachset_ros.conformance.estimators import Estimator
from reachset_ros.nodes.common import SAFE_STOP_QOS, set_remote_parameters, stamp_ns, to_stamp
from reachset_ros.systems.plant import lwa4p_joint_plant

JOINTS = ["arm_1_joint", "arm_2_joint"]
HORIZON = 25
#: sets about 4x those identified on :func:`stream` (0.035 / 1.4e-4): no false alarm on it
#: (15,000 ticks, 5 seeds, smallest margin 2.5e-4 rad), a 0.01 rad jump is caught at once
ALPHA_W, ALPHA_V = (0.15, 0.0), (4e-4,)
#: a controller's deadline on the monitor's verdicts (issue 34.2), off in effect: for tests whose
#: /safe_stop comes from the test or from a monitor that checks no loop of the controller's (the
#: test drives /observer/estimate, not /joint_states), so no verdict ever covers a tick commanded
NO_VERDICTS = {"monitor_verdict_ticks": 10**9}
#: a loop that rides out a loaded machine (CI twice as slow; two test workers): the controller waits
#: for its reference (``reference_timeout``, default 20 ms) within the simulator's wait for its
#: command (``lockstep_timeout``), so a starved reference node slows the simulated arm instead of
#: stopping it. Under ``make test``'s two workers the 20 ms default let the reference fall 204 ms of
#: stamp time behind (``reference_max_age`` 200 ms: every brake engaged) in a test about braking.
#: For tests without a monitor; with one, :data:`PATIENT_REFERENCE` beside the demo's 0.3 s lockstep.
#: And the controller on the simulation's clock (``use_sim_time``, as ``reachset up --sim``, the
#: demo and the campaign run it): its stop without estimates (nodes/estimate_watch.py, 100 ms) is
#: timed in the arm's time. On the wall clock, a loaded machine's 100 ms pause of the observer
#: while the monitor held the arm at start engaged every brake, and the monitor latched a
#: violation at step 1 (2 of 5 runs of test_stop_hold_reset_... under two DDS workers).
PATIENT_LOOP = {"sim_node": {"lockstep_timeout": 1.0},
                "controller_node": {"reference_timeout": 0.5, "use_sim_time": True}}
#: with a monitor (whose missing-data watch is on the wall clock): within the demo's 0.3 s lockstep
PATIENT_REFERENCE = {"reference_timeout": 0.2, "use_sim_time": True}
#: deep publishers, so that the test itself never drops what it sends
PUB_QOS = QoSProfile(depth=5000, reliability=ReliabilityPolicy.RELIABLE)


def write_model(path, alpha_w=ALPHA_W, alpha_v=ALPHA_V, joints=JOINTS, horizon=HORIZON):
    """A conformance model for the per-joint plant with the sets ``alpha_w``, ``alpha_v``
    (zero centres, estimator ``fd``, u_p from the plant-input topic) for each of ``joints``,
    saved to ``path``; returns ``Path(path)``."""
    p = lwa4p_joint_plant()
    js = {j: mdl.JointSets(tuple(alpha_w), tuple(alpha_v), (0.0,) * 5, (0.0,), 0, horizon) for j in joints}
    mdl.save(mdl.ConformanceModel(p, {"kind": "lwa4p_joint", "dt": 0.004}, Estimator("fd"), horizon, js,
                                  input_source=mdl.PLANT_INPUT), path)
    return Path(path)


def write_envelope_model(path, alpha_w=ALPHA_W, seeds=(11, 12, 13), n=3000):
    """:func:`write_model` with a validated envelope (issue 37) fitted on :func:`stream` of
    ``seeds`` (each ``n`` ticks, one recording each; hold k*); returns ``Path(path)``."""
    from dataclasses import replace

    from reachset_ros.bags.series import JointSeries, segments_of
    from reachset_ros.conformance import envelope
    write_model(path, alpha_w=alpha_w)
    m = mdl.load(path)
    parts = [stream(n, s) for s in seeds]
    gap = np.full((1, 2), np.nan)
    Y = np.concatenate([p for Y, _ in parts for p in (Y, gap)])
    U = np.concatenate([p for _, U in parts for p in (U, gap)])
    st = np.arange(len(Y), dtype=np.int64) * DT_NS
    seg = segments_of(st, np.isfinite(Y).all(axis=1), 0.004)
    series = {j: JointSeries(name=j, stamps=st, y=Y[:, k], u=U[:, k], segments=seg, dt=0.004)
              for k, j in enumerate(JOINTS)}
    mdl.save(replace(m, envelope=envelope.fit(series, bins=16, dilation=1, hold=m.horizon)), path)
    return Path(path)


def plant_stream(n, seed=0, fault_from=None):
    """Data that follow the per-joint plant (small bounded disturbances), two joints: yields
    ``(k, y, u)`` per tick; from tick ``fault_from`` on a constant acceleration of 20 rad/s^2
    acts on both joints."""
    p = lwa4p_joint_plant()
    rng = np.random.default_rng(seed)
    X = np.zeros((2, 5))
    for k in range(n):
        y = X[:, 0] + 2e-5 * rng.uniform(-1, 1, 2)
        u = np.sin(0.01 * k + np.arange(2)) - 50 * X[:, 1] - 10 * X[:, 2]
        yield k, y, u
        a = 0.0 if fault_from is None or k < fault_from else 20.0
        for j in range(2):
            X[j] = p.A @ X[j] + p.B[:, 0] * u[j] + p.Gw @ (np.array([0.01, 1.0]) * rng.uniform(-1, 1, 2))
            X[j, 2] += 0.004 * a
            X[j, 1] += 0.5 * 0.004 ** 2 * a


def stream(n, seed=0):
    """(Y, U) of shape (n, 2): two joints following the per-joint plant in closed loop,
    bounded disturbances (0.01, 1.0) and 2e-5 rad noise (:func:`plant_stream` without a fault)."""
    Y, U = np.empty((n, 2)), np.empty((n, 2))
    for k, y, u in plant_stream(n, seed):
        Y[k], U[k] = y, u
    return Y, U


def wait_until(cond, timeout=15.0, poll=0.01):
    """Poll ``cond()`` every ``poll`` s until it is true or ``timeout`` s have passed; its
    last value as a bool."""
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if cond():
            return True
        time.sleep(poll)
    return bool(cond())



def cmdline(pid):
    try:
        return Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")
    except OSError:
        return None


def running(pid):
    """True while ``pid`` exists and is not a zombie."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return False
    return stat.rsplit(")", 1)[1].split()[0] != "Z"


def suite_processes(marker, domain=None):
    """Processes of this user whose command line mentions reachset_ros and ``marker`` (a
    working directory), or whose environment has ``ROS_DOMAIN_ID=domain``."""
    found = []
    for d in Path("/proc").iterdir():
        if not d.name.isdigit() or int(d.name) == os.getpid():
            continue
        cmd = cmdline(d.name)
        if cmd is None or not running(d.name):
            continue
        try:
            env = (d / "environ").read_bytes().split(b"\0")
        except OSError:
            env = []
        in_domain = domain is not None and f"ROS_DOMAIN_ID={domain}".encode() in env
        if ("reachset_ros" in cmd or "reachset" in cmd) and (marker in cmd or in_domain):
            found.append((int(d.name), cmd))
    return found


def run_or_explain(cmd, *, timeout, workdir=None, env=None, log_lines=40):
    """Run ``cmd`` (its output captured) and return its :class:`subprocess.CompletedProcess`.

    When it is still running after ``timeout`` s (a hang), SIGUSR1 goes to it and to every
    node naming ``workdir`` on its command line (:func:`suite_processes`) (each prints every thread's stack:
    :mod:`reachset_ros.stacks`), then all of them are killed, and the test fails with the
    command's output tails and the last ``log_lines`` lines of each ``*.log`` in ``workdir``
    (a node's stacks end its log). A hang then names the line it hangs on, in the CI log."""
    with subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env) as proc:
        try:
            out, err = proc.communicate(timeout=timeout)
        except subprocess.TimeoutExpired:
            import pytest
            others = [pid for pid, _ in suite_processes(str(workdir))] if workdir else []
            for pid in (proc.pid, *others):
                try:
                    os.kill(pid, signal.SIGUSR1)
                except ProcessLookupError:
                    pass
            time.sleep(3.0)
            for pid in (proc.pid, *others):
                try:
                    os.kill(pid, signal.SIGKILL)
                except ProcessLookupError:
                    pass
            out, err = proc.communicate()
            tails = "".join(f"\n--- {log}\n" + "\n".join(log.read_text(errors="replace").splitlines()[-log_lines:])
                            for log in sorted(Path(workdir).rglob("*.log"))) if workdir else ""
            pytest.fail(f"{' '.join(map(str, cmd))} still running after {timeout} s\nstdout (tail): {out[-4000:]}\n"
                        f"stderr (tail): {err[-12000:]}{tails}", pytrace=False)
    return subprocess.CompletedProcess(cmd, proc.returncode, out, err)


def spin_until(node, cond, timeout):
    """Spin ``node`` (20 ms at a time) until ``cond()`` is true or ``timeout`` s have passed;
    whether it became true."""
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        rclpy.spin_once(node, timeout_sec=0.02)
        if cond():
            return True
    return False

class Recorder:
    """Subscriptions spun by their own executor thread (nothing missed while the test waits)."""

    def __init__(self, name, topics):
        self.node = Node(name)
        self.msgs = {t: [] for t in topics}
        self.subs = {}
        for topic, cls in topics.items():
            qos = SAFE_STOP_QOS if cls is SafeStop else QoSProfile(depth=5000)
            self.subs[topic] = self.node.create_subscription(
                cls, topic, lambda m, t=topic: self.msgs[t].append((time.monotonic(), m)), qos)
        self.ex = SingleThreadedExecutor()
        self.ex.add_node(self.node)
        threading.Thread(target=self.ex.spin, daemon=True).start()

    def wait(self, cond, timeout):
        return wait_until(cond, timeout, poll=0.02)

    def matched(self, topic):
        """Whether ``topic``'s subscription has matched a publisher (as :meth:`Bus.status_matched`:
        the graph shows a publisher before the endpoints match, and a volatile topic's messages
        sent before the match are lost)."""
        return self.subs[topic].get_publisher_count() > 0

    def close(self):
        self.ex.shutdown()
        self.node.destroy_node()


class Bus:
    """The test's side of DDS: publishers and service clients on ``caller`` (main thread),
    subscriptions on ``listener``, spun by its own executor thread so nothing is missed."""

    def __init__(self):
        self.caller = Node("faults_caller")
        self.listener = Node("faults_listener")
        self.status, self.stops, self.inputs = [], [], []
        self.diags = {}
        deep = QoSProfile(depth=5000, reliability=ReliabilityPolicy.RELIABLE)
        L = self.listener
        self.status_sub = L.create_subscription(ConformanceStatus, "conformance/status", self.status.append, deep)
        L.create_subscription(SafeStop, "safe_stop", self.stops.append, SAFE_STOP_QOS)
        self.inputs_sub = L.create_subscription(PlantInput, "plant_input", self.inputs.append, deep)
        L.create_subscription(DiagnosticArray, "diagnostics", self._on_diag, deep)
        self.executor = SingleThreadedExecutor()
        self.executor.add_node(L)
        self.thread = threading.Thread(target=self.executor.spin, daemon=True)
        self.thread.start()
        C = self.caller
        self.js = C.create_publisher(JointState, "joint_states", PUB_QOS)
        self.pi = C.create_publisher(PlantInput, "plant_input", PUB_QOS)
        self.est = C.create_publisher(JointEstimate, "observer/estimate", PUB_QOS)
        self.ref = C.create_publisher(JointReference, "reference", PUB_QOS)

    def _on_diag(self, arr):
        for st in arr.status:
            self.diags[st.name] = (st.level, st.message, {kv.key: kv.value for kv in st.values}, time.monotonic())

    def close(self):
        self.executor.shutdown()
        self.listener.destroy_node()
        self.caller.destroy_node()

    def clear(self):
        del self.status[:], self.stops[:], self.inputs[:]

    wait = staticmethod(wait_until)

    def ref_subscribers(self):
        """Subscriptions to /reference other than a monitor's (the monitor reads it for its
        stuck-sensor rule): the controllers, the count the tests wait for."""
        return sum(1 for i in self.caller.get_subscriptions_info_by_topic("/reference")
                   if not i.node_name.startswith("monitor"))

    def active_stops(self):
        """The active stops a check or fault latched: the monitor's start-up stop (``kind:
        not_ready``, issue 34.1, which it releases itself) is left out."""
        return [s for s in list(self.stops) if s.active and s.kind != "not_ready"]

    def distinct_active_stops(self):
        """The active stops without the monitor's repeats (same stamp, kind, joint, reason)."""
        seen = {}
        for s in self.active_stops():
            seen.setdefault((stamp_ns(s.header.stamp), s.kind, s.joint, s.reason), s)
        return list(seen.values())

    def status_matched(self):
        """Whether this bus' ``/conformance/status`` subscription has matched a publisher: a
        monitor's statuses published before that are lost (the topic is volatile). The graph
        (``count_publishers``) shows a publisher before the endpoints match: a fresh clone's run
        that waited for that lost the statuses of the first 41 of 93 ticks."""
        return self.status_sub.get_publisher_count() > 0

    def inputs_matched(self):
        """Whether this bus' ``/plant_input`` subscription has matched a publisher (a
        controller's commands before that are lost, as for :meth:`status_matched`)."""
        return self.inputs_sub.get_publisher_count() > 0

    def statuses(self, ts):
        lo, hi = ts[0], ts[-1]
        return [s for s in list(self.status) if lo <= stamp_ns(s.header.stamp) <= hi]

    def call_trigger(self, name, timeout=15.0):
        cli = self.caller.create_client(Trigger, name)
        try:
            assert cli.wait_for_service(timeout_sec=timeout), f"{name} not available"
            fut = cli.call_async(Trigger.Request())
            rclpy.spin_until_future_complete(self.caller, fut, timeout_sec=timeout)
            assert fut.done(), f"{name} did not answer"
            return fut.result()
        finally:
            self.caller.destroy_client(cli)

    def set_params(self, target, values, atomically=True):
        return set_remote_parameters(self.caller, target, values, atomically=atomically)

    def get_param(self, target, name):
        cli = self.caller.create_client(GetParameters, f"/{target}/get_parameters")
        try:
            assert cli.wait_for_service(timeout_sec=15.0)
            fut = cli.call_async(GetParameters.Request(names=[name]))
            rclpy.spin_until_future_complete(self.caller, fut, timeout_sec=15.0)
            v = fut.result().values[0]
            return {1: v.bool_value, 2: v.integer_value, 3: v.double_value, 4: v.string_value,
                    8: list(v.double_array_value), 9: list(v.string_array_value)}.get(v.type)
        finally:
            self.caller.destroy_client(cli)

    def counters(self, name="reachset_ros: conformance monitor", newer_than=None, timeout=15.0):
        """Counters of the next /diagnostics of ``name`` received after ``newer_than`` (monotonic)."""
        t = time.monotonic() if newer_than is None else newer_than
        assert self.wait(lambda: name in self.diags and self.diags[name][3] > t, timeout), f"no diagnostics of {name}"
        return {k: int(v) if v.lstrip("-").isdigit() else v for k, v in self.diags[name][2].items()}

    def send_y(self, t, names, values):
        m = JointState(name=list(names), position=[float(v) for v in values])
        to_stamp(m.header.stamp, t)
        self.js.publish(m)

    def send_u(self, t, names, values):
        m = PlantInput(name=list(names), acceleration=[float(v) for v in values])
        to_stamp(m.header.stamp, t)
        self.pi.publish(m)

    def send_ticks(self, ts, Y, U, drop_y=(), drop_u=(), pace=0.002):
        for k, t in enumerate(ts):
            if k not in drop_y:
                self.send_y(t, JOINTS, Y[k])
            if k not in drop_u:
                self.send_u(t, JOINTS[::-1], U[k][::-1])
            if pace:
                time.sleep(pace)

    def make_ready(self, timeout=60.0):
        """Stream clean ticks (:func:`stream`) to a monitor that has just started until it
        releases its start-up stop (issue 34.1: k* + 1 consecutive ticks checked to the
        horizon, all conformant); returns the releasing message.

        The stream goes on in chunks of 2 (history + k* + 1) contiguous ticks, each followed by
        up to ``CHUNK_WAIT_S`` s of waiting for the release, until ``timeout``: a writer that has
        matched the monitor's subscription can still publish before the monitor's reader has
        matched it, and those samples are lost (volatile durability). Sent once, one chunk left
        a monitor in a loaded fresh clone (2026-12-01) with no tick checked after 60 s."""
        from reachset_ros.nodes.common import MONITOR_STARTED
        assert self.wait(lambda: self.js.get_subscription_count() and self.pi.get_subscription_count(), timeout)
        assert self.wait(lambda: any(s.kind == "not_ready" for s in list(self.stops)), timeout), \
            "no start-up stop (kind not_ready) from the monitor"
        n = 2 * (HISTORY + HORIZON + 1)
        released = lambda: [s for s in list(self.stops) if not s.active and s.reason == MONITOR_STARTED]
        end = time.monotonic() + timeout
        chunks = int(timeout / self.CHUNK_WAIT_S) + 1
        Y, U = stream(chunks * n, seed=11)
        ts = stamps(chunks * n)
        for c in range(chunks):
            part = slice(c * n, (c + 1) * n)
            self.send_ticks(ts[part], Y[part], U[part])
            if self.wait(released, max(0.0, min(self.CHUNK_WAIT_S, end - time.monotonic()))):
                return released()[-1]
            if time.monotonic() >= end:
                break
        raise AssertionError([s.reason for s in self.stops][-3:])

    #: seconds :meth:`make_ready` waits for the release after each chunk of its stream
    CHUNK_WAIT_S = 5.0


HISTORY = 3     # the fd estimator's history: ticks of a segment before its first test case
#: the sample period of the node tests' streams, ns
DT_NS = 4_000_000
_next_stamp = [10**18]


def stamps(n):
    """Stamps for ``n`` ticks, later than any used before in this test session: a node hearing
    an older test's late message must never see a stamp going backwards by accident."""
    t0 = _next_stamp[0]
    _next_stamp[0] += (n + 10_000) * DT_NS
    return [t0 + k * DT_NS for k in range(n)]
