"""The monitor's side of row G19: the running pair is certified under the monitor's model.

The observer and controller nodes certify every gain change under the running monitor's model
too (:func:`~reachset_ros.nodes.pair_gate.check_running_pair`), but only once their process has
discovered the monitor. A monitor that has just started, or that loads a new ``model_file``,
checks the pair that runs now itself (:func:`~reachset_ros.nodes.pair_gate.running_pair_certificate`,
the synthesis node's check, one code path):

* a ``model_file`` change is refused (on_set) when the running pair is not certified under the
  new model, or cannot be read, with the gate's reason naming G19;
* at start-up (and on the managed variant's configure), when a controller or observer is in
  the graph, the check runs on a thread of its own (the client node of
  :func:`~reachset_ros.nodes.pair_gate._client`, never on the tick path); until it has
  certified the pair the start-up stop (``kind: not_ready``) is not released. A refused or
  unreadable pair holds it (fail closed), the reason in the stop and the log, and the check is
  repeated every ``monitor.pair.recheck`` s, so once the gains are changed through the gate the
  normal release path resumes;
* with no controller or observer in the graph (training, a monitor run alone, or a pair not
  discovered yet) nothing is held; the graph is looked at every 0.5 s, and a pair that appears
  is checked then: held while the start-up stop holds, and refused, the monitor stops (the
  start-up stop again, naming G19). A reset is refused while the pair is not certified;
* a change of a gate input on either node (``/parameter_events``: gains, model, limits) is
  checked the same way at the next look: their own gate consults the monitor only once their
  process has discovered it, so a change accepted before that is caught here.

A controller run with ``allow_uncertified`` and no ``model_file`` certifies no gains by the
operator's choice: the monitor says so (WARN) and does not hold for it.
"""
from __future__ import annotations

import threading
import time

from .. import defaults, guarantees
from .common import get_remote_parameters
from .pair_gate import _client, _running, running_pair_certificate

defaults.register("monitor.pair", {
    "recheck": (2.0, "seconds between the monitor's checks of a running pair not certified under its model "
                     "(the start-up stop is held meanwhile, row G19)"),
    "timeout": (10.0, "seconds the monitor waits for the controller's and observer's parameters when it certifies "
                      "the running pair under its model (no answer: held or refused, fail closed)"),
}, owner=__name__)

#: the nodes whose running pair the monitor certifies (the defaults of their own names)
PAIR = ("controller_node", "observer_node")
#: the hold's reason while the first check has not concluded
PENDING = "the running controller/observer pair is not checked yet under this model (row G19)"


def _in_graph(client):
    """The :data:`PAIR` nodes in the graph ``client`` sees now."""
    return frozenset(n for n in PAIR if _running(client, n))


def pair_refusal(node, model):
    """``""`` when no pair runs or the running pair is certified under ``model``; else one
    line naming G19, the pair and the gate's reason (or the node that could not be read)."""
    client = _client(node)
    running = sorted(_in_graph(client), key=PAIR.index)
    if not running:
        return ""
    timeout = float(defaults.get("monitor.pair.timeout"))
    ctl, obs, why = _pair_names(client, running[0], timeout)
    pc, why = (None, why) if ctl is None else running_pair_certificate(client, model, controller=ctl, observer=obs,
                                                                        timeout=timeout)
    if pc is not None:
        return ""
    if ctl is not None and _uncertified_run(client, ctl, timeout):
        node.get_logger().warning(f"row G19 void by choice: {ctl} runs with allow_uncertified and no model_file "
                                  f"(it certifies no gains); its pair under this monitor's model: {why}")
        return ""
    return str(guarantees.refused("G19", f"the running pair ({ctl or PAIR[0]}, {obs or PAIR[1]}) is not certified "
                                         f"under this monitor's model: {' '.join(why.split())}"))


def _uncertified_run(client, ctl, timeout):
    """Whether ``ctl`` runs uncertified gains by the operator's choice (``allow_uncertified``
    and no ``model_file``: its own gate certifies nothing, only stability), so the monitor does
    not hold for its pair (it says so in a WARN)."""
    got, _ = get_remote_parameters(client, ctl, ["allow_uncertified", "model_file"], timeout=timeout)
    return got is not None and bool(got["allow_uncertified"]) and not got["model_file"]


def _pair_names(client, found, timeout):
    """``(controller, observer, "")`` of the pair ``found`` (a node of :data:`PAIR`) runs in, by
    its ``pair_node``; a node run alone (``pair_node: ''``, or one not in the graph: the
    estimates or commands come from elsewhere, as the node's own start-up gate assumes) is
    both halves (its own copy of the other half); ``(None, None, why)`` when it cannot be read."""
    got, why = get_remote_parameters(client, found, ["pair_node"], timeout=timeout)
    if got is None:
        return None, None, why
    other = str(got["pair_node"] or "")
    # its partner not in the graph (looked for as the gate does: in a fresh clone the observer was
    # discovered before its controller, and the pair was named (observer_node, observer_node))
    other = other if other and _running(client, other, wait=float(defaults.get("nodes.pair.discover"))) else found
    return (found, other, "") if found == PAIR[0] else (other, found, "")


class PairHold:
    """The checks of :func:`pair_refusal` on a thread, applied in the node's executor by
    :meth:`poll` (a timer every 0.5 s): ``reason`` is empty while the running pair is certified
    under the model (or none runs); the node's release path and its reset wait for that.

    * A model loaded with a pair in the graph: the start-up stop is held (``PENDING``) until the
      check concludes.
    * No pair in the graph then: nothing to hold for. The graph is watched: a controller or
      observer that appears later (or leaves and comes back) is checked under the model then;
      held (``PENDING``) while the start-up stop still holds, and if refused the monitor stops
      (the start-up stop again, with the refusal: fail closed).
    * A change of a gate input on either node (:meth:`on_parameter_event`) is checked the same
      way at the next poll.
    """

    def __init__(self, node):
        self.node = node
        self.lock = threading.Lock()      # one user of the client node at a time
        self.model, self.reason, self.result, self.thread, self.next = None, "", None, None, 0.0
        self.seen = frozenset()           # the PAIR nodes in the graph at the last look
        self.changed = set()              # PAIR nodes whose gate inputs changed since the last look
        node.create_timer(0.5, self.poll)
        from rcl_interfaces.msg import ParameterEvent
        from rclpy.qos import QoSProfile, ReliabilityPolicy
        node.create_subscription(ParameterEvent, "/parameter_events", self.on_parameter_event,
                                 QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE))

    def on_parameter_event(self, msg):
        """A controller or observer changed a gate input (gains, model, limits): its pair is
        checked again under this model at the next poll. Their own gate certifies a change under
        the monitor's model only once their process has discovered the monitor (a fresh
        controller accepted omega 26 the wide model refuses, in a test run); this is the
        monitor's own check of what then runs."""
        from .gain_params import GAIN_CHANGE_PARAMS
        name = msg.node.rsplit("/", 1)[-1]
        if name in PAIR and any(p.name in GAIN_CHANGE_PARAMS for p in (*msg.new_parameters, *msg.changed_parameters)):
            self.changed.add(name)

    def start(self, model, reason=PENDING):
        """A model loaded: held until the check concludes when a pair runs (``reason=""``:
        checked already)."""
        self.model, self.next = model, 0.0
        present = self._present()         # None: a check holds the client; look again at the next poll
        self.seen = present or frozenset()
        self.reason = reason if reason and (present is None or present) else ""
        if self.reason:
            self.kick()

    def _present(self):
        """The :data:`PAIR` nodes in the graph now, or None while a check uses the client."""
        if not self.lock.acquire(blocking=False):
            return None
        try:
            return _in_graph(_client(self.node))
        finally:
            self.lock.release()

    def explain(self, why):
        """The start-up stop's reason ``why`` with the refusal that holds it, if any (row G19)."""
        held = self.reason if self.reason != PENDING else ""
        return f"{why}; {held}" if held and held not in why else why

    def check_now(self, model):
        """The on_set check: :func:`pair_refusal` under ``model`` (no wait: the graph is known)."""
        with self.lock:
            return pair_refusal(self.node, model)

    def kick(self):
        if self.thread is not None and self.thread.is_alive():
            return
        model = self.model

        def run():
            with self.lock:
                try:
                    why = pair_refusal(self.node, model)
                except Exception as e:     # noqa: BLE001 - fail closed with the reason
                    why = str(guarantees.refused("G19", f"the running pair cannot be checked: {e}"))
            self.result = (model, why)

        self.thread = threading.Thread(target=run, daemon=True)
        self.thread.start()

    def poll(self):
        """Timer: apply a finished check (hold with the reason, or release), start the next;
        with nothing held, check a pair that has appeared in the graph."""
        result, self.result = self.result, None
        if result is not None and result[0] is self.model:
            self.apply(result[1])
        if self.model is None or (self.thread is not None and self.thread.is_alive()):
            return
        if self.reason:                   # held or refused: ask again (at once after a new model)
            if time.monotonic() >= self.next:
                self.kick()
            return
        present = self._present()
        if present is None:
            return
        appeared, self.seen = present - self.seen, present
        changed, self.changed = self.changed & present, set()
        if appeared or changed:
            what = ([f"{', '.join(sorted(appeared))} appeared"] if appeared else []) + (
                [f"{', '.join(sorted(changed))} changed its gate's inputs"] if changed else [])
            self.node.get_logger().info(f"{'; '.join(what)}: checking the running pair under this model (row G19)")
            if self.node.not_ready:
                self.reason = PENDING
            self.kick()

    def apply(self, why):
        """A check's answer ``why`` ('' certified): hold, stop or release."""
        was = self.reason
        self.reason = why
        self.next = time.monotonic() + float(defaults.get("monitor.pair.recheck"))
        if why and why != was:
            self.node.get_logger().error(f"start-up stop held: {why}")
            if self.node.not_ready or not self.node.stop_active:
                self.node.enter_not_ready(why)      # a running monitor stops (fail closed)
        elif not why and was:
            self.node.get_logger().info("the running pair is certified under this model (row G19)")
            if was != PENDING and self.node.not_ready:      # the stop no longer says G19
                self.node.enter_not_ready("the running pair is certified under this model now")
            self.node.release_when_ready()      # the ticks counted meanwhile may suffice
