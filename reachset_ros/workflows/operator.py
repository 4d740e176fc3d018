"""The operator's client of a running suite (issue 36.2): ``reachset status|watch|reset|stop|gains``.

In the way navigation2's ``nav2_simple_commander`` gives a script the verbs of a running Nav2,
an :class:`Operator` gives the operator's commands the verbs of a running ``reachset up``:
:meth:`~Operator.status` (nodes, stop state, rates, model, gains, set use),
:meth:`~Operator.reset` (the monitor's audited reset), :meth:`~Operator.stop` (an audited manual
stop, kind ``manual``), :meth:`~Operator.get_gains` and :meth:`~Operator.set_gains` (the
controller/observer pair, all or none, through the pair's gate), and :meth:`~Operator.sample`
for a live view. It drives a :class:`~reachset_ros.workflows.commander.SuiteCommander` (its node,
its service calls and spinning; it starts no process here) and
:func:`reachset_ros.nodes.pair_gate.set_pair`; it never runs on the simulation's clock (the
suite may drive a real arm). Open one with :func:`open_operator`.

Rates are messages received per second of wall time over the sampling window (best-effort
subscriptions: the operator never slows the loop down). The set use of a joint is the
status message's ``set_use`` where the monitor publishes one (issue 36.3), else
``deviation / (deviation + margin)`` of the tightest check (``margin = bound - |y_a|``): 1.0 on
the boundary of the reachable set, above 1 a violation.
"""
from __future__ import annotations

import collections
import math
import os
import time
from contextlib import contextmanager
from dataclasses import dataclass, field

from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from reachset_msgs.msg import ConformanceStatus
from reachset_msgs.srv import ResetStop
from sensor_msgs.msg import JointState

from ..errors import ReachsetError
from ..nodes.bringup import SIM_NODES, SUITE
from ..nodes.common import get_remote_parameters, stamp_ns
from ..nodes.pair_gate import OWN_KEYS, READ, running_envelope, set_pair
from ..systems.gains import ESO_INPUTS, GAIN_KEYS, TYPE_KEYS
from .commander import open_commander

#: the topics whose rates are measured
RATE_TOPICS = ("/joint_states", "/conformance/status")
#: the pair's nodes, in the order :func:`~reachset_ros.nodes.pair_gate.set_pair` tries first
PAIR = ("observer_node", "controller_node")
MONITOR = "monitor_node"
#: the words each loop-structure parameter takes
TYPE_WORDS = {"observer": ("hg", "eso"), "controller": ("static", "compensated"), "eso_input": ESO_INPUTS}
#: the operator's subscriptions: best effort, a few messages deep (never a burden on the loop)
LISTEN_QOS = QoSProfile(depth=50, reliability=ReliabilityPolicy.BEST_EFFORT, history=HistoryPolicy.KEEP_LAST)


def set_use_of(msg) -> dict:
    """``{joint: use}`` of a ``/conformance/status`` message (module docstring); a joint
    nothing was checked for has ``None``."""
    given = list(getattr(msg, "set_use", []) or [])
    out = {}
    for i, name in enumerate(msg.name):
        if len(given) == len(msg.name):
            use = float(given[i])
        else:
            dev, margin = float(msg.deviation[i]), float(msg.margin[i])
            bound = dev + margin
            use = dev / bound if abs(margin) < 1e299 and bound > 0 else None
        out[name] = use if use is not None and math.isfinite(use) else None
    return out


def stop_of(msg) -> dict | None:
    """A ``/safe_stop`` message as a dict (None: none received)."""
    if msg is None:
        return None
    return {"active": bool(msg.active), "kind": msg.kind, "reason": msg.reason, "joint": msg.joint,
            "stamp_ns": stamp_ns(msg.header.stamp), "window_bag": msg.window_bag}


@dataclass(frozen=True, kw_only=True)
class Status:
    """What :meth:`Operator.status` saw (``to_dict`` is ``reachset status --json``)."""

    ros_domain_id: int
    nodes: dict            # suite node -> in the ROS graph
    other_nodes: list      # other nodes in the graph (the operator's own left out)
    stop: dict | None      # the newest /safe_stop (stop_of), None: none received
    rates: dict            # topic -> Hz over the window
    window_s: float
    model: dict            # model_file (the monitor's parameter), model_id, horizon (newest status)
    gains: dict            # Operator.get_gains(), {} when the pair could not be read
    gains_error: str
    set_use: dict          # joint -> use (newest status); {} without one
    conformant: bool | None

    def to_dict(self) -> dict:
        return {k: getattr(self, k) for k in self.__dataclass_fields__}


@dataclass
class _Seen:
    """What the subscriptions have received: newest status, arrival times, peak use."""

    status: object = None
    arrivals: dict = field(default_factory=lambda: {t: collections.deque(maxlen=5000) for t in RATE_TOPICS})
    peak: dict = field(default_factory=dict)      # joint -> largest use since the last take_peak()


class Operator:
    """The operator's verbs over a running suite (module docstring).

    Parameters
    ----------
    commander : reachset_ros.workflows.commander.SuiteCommander
        Its node subscribes, calls and is spun here.
    domain_id : int
        The suite's ``ROS_DOMAIN_ID`` (reported; the commander's context is in it).
    expected : sequence of str, optional
        The suite's nodes (``reachset up``'s, from its ``up.json``); default: the suite
        without the simulated arm, which is listed when it runs.
    """

    def __init__(self, commander, *, domain_id, expected=None):
        self.commander = commander
        self.domain_id = int(domain_id)
        self.expected = list(expected) if expected else [n for n in SUITE if n not in SIM_NODES]
        self.seen = _Seen()
        self.subs = [commander.create_subscription(JointState, "/joint_states",
                                                   lambda m: self._arrived("/joint_states"), LISTEN_QOS),
                     commander.create_subscription(ConformanceStatus, "/conformance/status", self._on_status,
                                                   LISTEN_QOS)]

    # ------------------------------------------------------------------ listening
    def _arrived(self, topic):
        self.seen.arrivals[topic].append(time.monotonic())

    def _on_status(self, msg):
        self._arrived("/conformance/status")
        self.seen.status = msg
        for j, u in set_use_of(msg).items():
            if u is not None and u > self.seen.peak.get(j, -math.inf):
                self.seen.peak[j] = u

    def spin(self, seconds, until=None):
        """Spin ``seconds`` of wall time, or until ``until()``; whether it was met. Only the
        newest ``/safe_stop`` is kept (an active stop is repeated every tick)."""
        end = time.monotonic() + seconds
        while True:
            self.commander.spin_once(min(0.05, max(0.0, end - time.monotonic())))
            del self.commander.stops[:-1]
            if until is not None and until():
                return True
            if time.monotonic() >= end:
                return False

    def node_names(self) -> set:
        return {n for n, _ in self.commander.get_node_names_and_namespaces()}

    def wait_for_suite(self, timeout):
        """Spin until every expected node is in the graph (discovery can take seconds on a loaded
        machine: a node not seen yet is not a missing node), its latched ``/safe_stop`` has
        arrived and the subscriptions of :data:`RATE_TOPICS` have matched a publisher each (so
        that a rate window counts from its start), or ``timeout`` s; whether the monitor and its
        state came."""
        self.spin(timeout, until=lambda: (set(self.expected) <= self.node_names() and MONITOR in self.node_names()
                                          and bool(self.commander.stops)
                                          and all(s.get_publisher_count() for s in self.subs)))
        return MONITOR in self.node_names() and bool(self.commander.stops)

    def latest_stop(self):
        """The newest ``/safe_stop`` message, or None."""
        return self.commander.stops[-1] if self.commander.stops else None

    def rates(self, window_s) -> dict:
        """Messages per second of each of :data:`RATE_TOPICS` received in the last ``window_s``."""
        now = time.monotonic()
        return {t: round(sum(1 for a in q if now - a <= window_s) / window_s, 1) for t, q in self.seen.arrivals.items()}

    def take_peak(self) -> dict:
        """The largest set use of each joint since the last call (then forgotten)."""
        peak, self.seen.peak = self.seen.peak, {}
        return peak

    # ------------------------------------------------------------------ the verbs
    def status(self, *, window_s=1.0, timeout=10.0) -> Status:
        """Nodes, stop state, rates over ``window_s``, the monitor's model, the pair's gains
        and the set use, after waiting up to ``timeout`` s for the monitor (:meth:`wait_for_suite`)."""
        self.wait_for_suite(timeout)
        self.spin(window_s)
        names = self.node_names()
        nodes = {n: n in names for n in self.expected}
        nodes.update({n: True for n in SIM_NODES if n in names})
        model = {"model_file": None, "model_id": None, "horizon": None}
        if MONITOR in names:
            got, _ = get_remote_parameters(self.commander, MONITOR, ["model_file"], timeout=timeout)
            model["model_file"] = (got or {}).get("model_file")
        st = self.seen.status
        if st is not None:
            model["model_id"], model["horizon"] = st.model_id, int(st.horizon)
        try:
            gains, gains_error = self.get_gains(timeout=timeout), ""
        except ReachsetError as e:
            gains, gains_error = {}, str(e)
        return Status(ros_domain_id=self.domain_id, nodes=nodes,
                      other_nodes=sorted(names - set(nodes) - {self.commander.get_name()}),
                      stop=stop_of(self.latest_stop()), rates=self.rates(window_s), window_s=window_s, model=model,
                      gains=gains, gains_error=gains_error, set_use=set_use_of(st) if st is not None else {},
                      conformant=bool(st.conformant) if st is not None else None)

    def reset(self, *, reason="", patience_s=0.0, retry_s=0.25, timeout=10.0):
        """The monitor's audited reset (``~/reset_stop``, naming this node and ``reason``), tried
        again every ``retry_s`` while refused for up to ``patience_s`` s (the arm coming to
        rest); returns ``(granted, message)`` of the last answer. ``timeout``: seconds to wait
        for the monitor to appear."""
        end = time.monotonic() + patience_s
        while True:
            r = self._call_monitor("reset_stop", reason, timeout)
            if r.success or time.monotonic() >= end:
                return bool(r.success), r.message
            self.spin(retry_s)

    def stop(self, reason="", *, timeout=10.0):
        """An audited manual stop (the monitor's ``~/stop``: kind ``manual``); ``(latched, message)``."""
        r = self._call_monitor("stop", reason, timeout)
        return bool(r.success), r.message

    def _call_monitor(self, service, reason, timeout):
        if MONITOR not in self.node_names() and not self.spin(timeout, until=lambda: MONITOR in self.node_names()):
            raise ReachsetError(f"no {MONITOR} in ROS_DOMAIN_ID={self.domain_id}: is the suite running there?")
        req = ResetStop.Request(caller=self.commander.get_name(), reason=reason)
        try:
            return self.commander.call(ResetStop, f"/{MONITOR}/{service}", req, timeout=30.0)
        except RuntimeError as e:
            raise ReachsetError(f"{MONITOR}: {e}") from None

    def get_gains(self, *, timeout=10.0) -> dict:
        """The pair's gains: ``{"joints", "pair": the half each node runs, "nodes": {node:
        every gain parameter it holds (its copy of the other half too)}}``; raises
        :class:`~reachset_ros.errors.ReachsetError` when a node cannot be read."""
        keys = [k for k in READ if k in ("joints", *TYPE_KEYS, *GAIN_KEYS, "model_file", "allow_uncertified")]
        nodes = {}
        for n in PAIR:
            got, why = get_remote_parameters(self.commander, n, keys, timeout=timeout)
            if got is None:
                raise ReachsetError(f"the gains cannot be read: {why}")
            nodes[n] = got
        own = {"observer_node": OWN_KEYS["observer"], "controller_node": OWN_KEYS["controller"]}
        pair = {k: nodes[n][k] for n in PAIR for k in own[n]}
        return {"joints": [j for j in nodes["controller_node"]["joints"] if j], "pair": pair, "nodes": nodes}

    def set_gains(self, gains, *, reason="", timeout=10.0):
        """Set ``gains`` (``{name: value}``, :func:`check_gains`) on the observer and the
        controller, all or none (:func:`~reachset_ros.nodes.pair_gate.set_pair`: each node's
        gate certifies the pair that will run; accepted targets are set back on a refusal);
        ``reason`` is logged with the change (``change_reason``). Returns ``(ok, reason)``."""
        values = {**check_gains(gains), **({"change_reason": reason} if reason else {})}
        return set_pair(self.commander, {t: dict(values) for t in PAIR}, timeout=timeout)

    def envelope(self, *, timeout=10.0) -> dict:
        """The envelope's answer for the pair running now (issue 37.3): the parts of the class
        the gate certifies that the controller's model was never validated on, or ``envelope:
        none recorded`` (:func:`~reachset_ros.nodes.pair_gate.running_envelope`; the nodes'
        parameter service cannot carry it, rclpy answers a granted request with no reason)."""
        return running_envelope(self.commander, timeout=timeout)


def check_gains(gains) -> dict:
    """``gains`` with each value checked: a name of :data:`~reachset_ros.systems.gains.GAIN_KEYS`
    (a positive finite number, or a list of them: one per joint) or of ``TYPE_KEYS`` (one of
    :data:`TYPE_WORDS`); raises :class:`~reachset_ros.errors.ReachsetError` naming the first
    that is not."""
    if not gains:
        raise ReachsetError("no gains given (NAME=VALUE, e.g. omega=12 or omega=10,12,12,12,12,12)")
    out = {}
    for name, value in gains.items():
        if name in TYPE_KEYS:
            if value not in TYPE_WORDS[name]:
                raise ReachsetError(f"{name}={value!r}: must be one of {', '.join(TYPE_WORDS[name])}")
            out[name] = str(value)
        elif name in GAIN_KEYS:
            vals = list(value) if isinstance(value, (list, tuple)) else [value]
            try:
                vals = [float(v) for v in vals]
            except (TypeError, ValueError):
                raise ReachsetError(f"{name}={value!r}: not a number (one value, or one per joint)") from None
            if not vals or not all(math.isfinite(v) and v > 0 for v in vals):
                raise ReachsetError(f"{name}={value!r}: every value must be a positive finite number")
            out[name] = vals
        else:
            raise ReachsetError(f"{name!r} is not a gain (one of {', '.join((*TYPE_KEYS, *GAIN_KEYS))})")
    return out


@contextmanager
def open_operator(*, domain_id, expected=None, node_name=None):
    """An :class:`Operator` in DDS domain ``domain_id``, closed on the way out.

    rclpy is initialised here in that domain when nobody has (a command's process); in a
    process that runs rclpy already the operator joins that context's domain. The node is
    named ``reachset_operator_<pid>`` (two operators at once do not share a name): the
    audit lines of the reset and the stop name it as the caller."""
    os.environ["ROS_DOMAIN_ID"] = str(int(domain_id))
    with open_commander(workdir=".", node_name=node_name or f"reachset_operator_{os.getpid()}",
                        use_sim_time=False) as commander:
        yield Operator(commander, domain_id=domain_id, expected=expected)
