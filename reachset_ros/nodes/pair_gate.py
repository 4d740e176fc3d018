"""The gate of the pair that will run: this node's half with the other node's current half.

The observer node runs the observer (``observer``, ``eso_input`` and the observer gains), the
controller node the feedback law (``controller``, ``omega``, ``zeta``); each holds a copy of
the other half in its parameters, and :func:`~reachset_ros.nodes.gain_params.validate_pair`
certifies that copy. A change sent to one node alone (``omega = 26`` to the controller, then
``h1 = h2 = 8`` to the observer) passed each node's gate with the other half's stale copy while
the pair that ran together was refused by the same gate (issue 34.6: R*_u ±32 > U_p 26).

:func:`check_running_pair` (both nodes, on every parameter request, after their own gate)
reads the other node's current parameters (``pair_node``: ``get_parameters`` on a client node
of its own, as the synthesis node does) and certifies the pair that will actually run, this
node's proposed half with the other node's running half, by both gates: this node's (its
proposed model, U_p, U_ff bound and ``allow_uncertified``) and the other node's (its model
and limits). So at every moment the running pair is one that both nodes' gates, and so both
nodes' models, certify; a change of both halves goes through the synthesis node, which sets
one node after the other (every intermediate pair is checked here) and rolls back when one
refuses. A node that cannot read the other is refused (fail closed) unless its ``pair_node``
is empty (a node run alone, its estimates or commands coming from elsewhere).

The monitor checks the plant against its own model's sets, and the R*_e and R*_u of the gains
that run hold for the sets they were certified on (row G19). So when a monitor runs
(``monitor_node``, discovered in the graph), the pair that will run is also certified under the
monitor's running model (its ``model_file``, read as the other node's), with this node's
U_p and U_ff bound; a monitor that runs but cannot be read refuses the change (fail closed).
With no monitor running (training, a node run alone) only the two nodes' models certify it.
A change of model and gains for all three (the synthesis node: controller, observer, then
monitor) is thus applied only when the new gains are certified under the monitor's current
model too, so no moment runs gains the monitored sets do not certify. A monitor that starts, or
loads a new ``model_file``, before this node has discovered it certifies the running pair under
its model itself (:mod:`.monitor_pair`, with :func:`running_pair_certificate`).

Start-up is not checked here (the other node may not be discovered yet): both nodes start from
one parameter file (``reachset up``, the synthesis node's ``applied_gains.params.yaml``) and
their start-up gate certifies it.
"""
import time

import numpy as np
import rclpy

from .. import defaults, guarantees
from ..conformance import model as mdl
from ..errors import ReachsetError, first_line
from ..synthesis.reference_error import u_e_ff_for_gains
from ..systems.gains import GAIN_KEYS, TYPE_KEYS, certify_pair
from .common import desc, get_remote_parameters, set_remote_parameters

defaults.register("nodes.pair", {
    "timeout": (10.0, "seconds the observer and controller nodes wait for the other node's parameters when they "
                      "certify the pair that will run (pair_node); no answer: the change is refused (the synthesis "
                      "node's per-call timeout: 2 s timed out on the loaded 2-core machine during the demo)"),
    "discover": (2.0, "seconds the observer and controller nodes look for the other node (pair_node) in the "
                      "graph before refusing a change because it is not running: one snapshot of the graph "
                      "missed a live partner just after another participant left (a fresh clone's test run, "
                      "2026-11-27); a partner that is there answers at once"),
}, owner=__name__)

#: the parameters each node's half of the loop consists of (the rest is its copy of the other half)
OWN_KEYS = {"controller": ("controller", "omega", "zeta"),
            "observer": ("observer", "eso_input", *[k for k in GAIN_KEYS if k not in ("omega", "zeta")])}
#: the other node of each role (the default of ``pair_node``)
PARTNER = {"controller": "observer_node", "observer": "controller_node"}
#: what is read from the other node: its half, its joints and its gate's inputs
READ = ("joints", *TYPE_KEYS, *GAIN_KEYS, "model_file", "u_max", "u_ff_bound", "allow_uncertified", "dt")


def role(node):
    """``"observer"`` for the observer node (``GAIN_ROLE``), ``"controller"`` otherwise."""
    return getattr(node, "GAIN_ROLE", "controller")


def declare_pair_parameters(node):
    """``pair_node``: the node running the other half of the loop ('' = none: a node run alone)."""
    node.declare_parameter("pair_node", PARTNER[role(node)],
                           desc("the node running the other half of the loop (the observer for the controller, "
                                "the controller for the observer); every gain or model change is certified for the "
                                "pair that will run with that node's current gains, by both nodes' gates; '' for a "
                                "node run alone (only its own copy of the pair is certified)", read_only=True))
    node.declare_parameter("monitor_node", "monitor_node",
                           desc("the monitor whose running model (model_file) must also certify the pair that will "
                                "run, when it runs (row G19); '' for none", read_only=True))
    if node.get_parameter("pair_node").value or node.get_parameter("monitor_node").value:
        _client(node)           # made now: discovered by the time a change needs it


def _per_joint(value, joints, own_joints, name, partner):
    """The other node's per-joint array ``value`` (1 value, or one per its ``joints``) for ``own_joints``."""
    vals = [float(x) for x in value] if isinstance(value, (list, tuple)) else [float(value)]
    if len(vals) == 1:
        return vals * len(own_joints)
    if len(vals) < len(joints):
        raise ReachsetError(f"{partner}: parameter {name} has {len(vals)} values for {len(joints)} joints")
    return [vals[joints.index(j)] for j in own_joints]


def running_values(node, values, other):
    """The parameter values of the pair that will run, in this node's joint order: this node's
    half from ``values`` (its proposed parameters), the other half from ``other`` (the other
    node's current ones, :data:`READ`)."""
    partner = node.get_parameter("pair_node").value
    joints = [j for j in other["joints"] if j]
    missing = [j for j in node.joints if j not in joints]
    if missing:
        raise ReachsetError(f"{partner} does not run joint {missing[0]}: the pair that will run cannot be certified")
    mine = OWN_KEYS[role(node)]
    run = {}
    for k in (*TYPE_KEYS, *GAIN_KEYS):
        if k in mine:
            run[k] = values[k]
        elif k in TYPE_KEYS:
            run[k] = str(other[k])
        else:
            run[k] = _per_joint(other[k], joints, node.joints, k, partner)
    return run, joints


def _client(node):
    """The client node this node reads the other node's parameters with (its own executor
    cannot be spun from inside its parameter callback); made on first use."""
    if getattr(node, "_pair_client", None) is None:
        node._pair_client = rclpy.create_node(f"{node.get_name()}_pair_client", namespace=node.get_namespace(),
                                              context=node.context, start_parameter_services=False)
    return node._pair_client


def _running(client, name, wait=0.0):
    """Whether a node named ``name`` is in the graph ``client`` sees; with ``wait`` > 0 the graph
    is looked at again every 50 ms for up to ``wait`` seconds before answering no (a partner
    the gate needs: a single snapshot can miss a live node while the graph churns)."""
    end = time.monotonic() + wait
    while True:
        if name.lstrip("/") in [n for n, _ in client.get_node_names_and_namespaces()]:
            return True
        if time.monotonic() >= end:
            return False
        time.sleep(0.05)


def check_running_pair(node, params, values, model, *, u_e_ff_for=u_e_ff_for_gains):
    """Refuse a request whose pair that will run is refused by this node's or the other node's gate.

    Parameters
    ----------
    node : the observer or controller node (``joints``, ``dt``, parameter ``pair_node``)
    params : sequence of rclpy.parameter.Parameter
        The request; one that changes none of the gate's inputs
        (:data:`~reachset_ros.nodes.gain_params.GAIN_CHANGE_PARAMS`) is not checked here.
    values : dict
        The request's proposed parameter values (:func:`~reachset_ros.nodes.gain_params.proposed_values`).
    model : ConformanceModel or None
        This node's proposed model.
    u_e_ff_for : callable, optional
        As :func:`~reachset_ros.systems.gains.certify_pair` (default: the nodes' gate's,
        :func:`~reachset_ros.synthesis.reference_error.u_e_ff_for_gains`).

    Raises
    ------
    ReachsetError
        One line naming the other node and the gate that refused (the reason names the joint
        and the row: unstable, R*_u outside U_p, no certificate), or that the other node could
        not be read.
    """
    from .gain_params import GAIN_CHANGE_PARAMS, gains_from, u_max_array
    if not any(p.name in GAIN_CHANGE_PARAMS for p in params):
        return
    partner = node.get_parameter("pair_node").value
    own = ("this node's", model, u_max_array(values["u_max"], len(node.joints)), float(values["u_ff_bound"]),
           bool(values["allow_uncertified"]))
    gates, gains = [], gains_from(values, node.joints)
    if partner:
        gains, theirs, other_model = _partner_gate(node, partner, values, model)
        # a certificate costs seconds (U_e,ff over the reference class): none is computed twice.
        # The node's own gate (validate_pair) certified its copy already; the other node's gate
        # with the same model and limits is the same gate
        same_pair = gains == gains_from(values, node.joints)
        same_gate = (other_model is model and theirs[3:] == own[3:] and np.array_equal(theirs[2], own[2]))
        gates = ([] if same_pair else [own]) + ([] if same_gate else [theirs])
    monitored = _monitor_gate(node, values, own)
    if monitored is not None:
        gates.append(monitored)
    half = "observer" if role(node) == "controller" else "controller"
    for who, m, u_max, u_ff, allow in gates:
        try:
            certify_pair(gains, m, u_max, u_ff, node.dt, allow, u_e_ff_for=u_e_ff_for)
        except ReachsetError as e:
            pair = f"with {partner}'s current {half} gains " if partner else ""
            why = f"the pair that would run {pair}is refused by {who} gate: {first_line(e)}"
            if who.startswith("the monitor"):       # G19, beside the row the gate protects
                raise guarantees.refused("G19", why) from None
            # the gate's refusal names the row it protects (G4, G7, G11); any other is G16's
            raise (ReachsetError(why) if "[guarantee " in why else guarantees.refused("G16", why)) from None


def _partner_gate(node, partner, values, model):
    """``(gains of the pair that will run, the other node's gate, its model)``; refuses (G16)
    when the other node is not running or cannot be read."""
    from .gain_params import gains_from
    timeout = float(defaults.get("nodes.pair.timeout"))
    client = _client(node)
    if not _running(client, partner, wait=float(defaults.get("nodes.pair.discover"))):
        raise guarantees.refused("G16", f"the pair that will run cannot be certified: {partner} is not running "
                                        f"(pair_node {partner!r}; '' for a node run alone)")
    other, why = get_remote_parameters(client, partner, READ, timeout=timeout)
    if other is None:
        raise guarantees.refused("G16", f"the pair that will run cannot be certified: {why} (pair_node "
                                        f"{partner!r}; '' for a node run alone)")
    run, joints = running_values(node, values, other)
    path = str(other["model_file"] or "")
    own_path = str(values.get("model_file") or "")
    try:
        other_model = model if path == own_path else (mdl.load(path) if path else None)
    except ReachsetError as e:
        raise ReachsetError(f"{partner}'s model_file {path}: {e}") from None
    theirs = (f"{partner}'s", other_model, np.asarray(_per_joint(other["u_max"], joints, node.joints, "u_max", partner)),
              float(other["u_ff_bound"]), bool(other["allow_uncertified"]))
    return gains_from(run, node.joints), theirs, other_model


def _monitor_gate(node, values, own):
    """The gate of the monitor's running model (row G19): ``(who, model, u_max, u_ff, allow)``
    with this node's limits, or ``None`` when no monitor runs or it runs this node's proposed
    model (certified by this node's gate already). A running monitor that cannot be read, or
    whose model cannot be loaded, refuses the change (fail closed)."""
    monitor = node.get_parameter("monitor_node").value
    if not monitor:
        return None
    client = _client(node)
    if not _running(client, monitor):
        return None
    got, why = get_remote_parameters(client, monitor, ["model_file"], timeout=float(defaults.get("nodes.pair.timeout")))
    if got is None:
        raise guarantees.refused("G19", f"the monitored sets cannot be read: {why} (monitor_node {monitor!r}; '' "
                                        "for none)")
    path = str(got["model_file"] or "")
    if not path or path == str(values.get("model_file") or ""):
        return None
    try:
        return (f"the monitor {monitor}'s model", mdl.load(path), own[2], own[3], own[4])
    except ReachsetError as e:
        raise guarantees.refused("G19", f"{monitor}'s model_file {path}: {first_line(e)}") from None


def running_pair_certificate(client, model, *, controller="controller_node", observer="observer_node",
                             timeout=10.0, u_e_ff_for=u_e_ff_for_gains):
    """The certificate of the pair running now under ``model``: ``(PairCertificate, "")``, or
    ``(None, why)`` when the gate refuses it or a node cannot be read (one line).

    The controller's half is read from ``controller``, the observer's from ``observer``
    (their current parameters, :data:`READ`), and certified with the controller's U_p, U_ff
    bound and ``allow_uncertified`` (:func:`~reachset_ros.systems.gains.certify_pair`).
    """
    from .gain_params import gains_from, u_max_array
    ctl, why = get_remote_parameters(client, controller, READ, timeout=timeout)
    obs, why2 = (None, "") if ctl is None else get_remote_parameters(client, observer, READ, timeout=timeout)
    if ctl is None or obs is None:
        return None, why or why2
    joints = [j for j in ctl["joints"] if j]
    try:
        run = {k: (ctl[k] if k in OWN_KEYS["controller"] else str(obs[k]) if k in TYPE_KEYS
                   else _per_joint(obs[k], [j for j in obs["joints"] if j], joints, k, observer))
               for k in (*TYPE_KEYS, *GAIN_KEYS)}
        # the controller's own tick period, as its gate certifies with (gain_params: node.dt)
        return certify_pair(gains_from(run, joints), model, u_max_array(ctl["u_max"], len(joints)),
                            float(ctl["u_ff_bound"]), float(ctl["dt"]), bool(ctl["allow_uncertified"]),
                            u_e_ff_for=u_e_ff_for), ""
    except (ReachsetError, ValueError, IndexError) as e:
        return None, first_line(e)


def certify_running_pair_under(client, model, *, controller="controller_node", observer="observer_node",
                               timeout=10.0, u_e_ff_for=u_e_ff_for_gains):
    """Whether the pair running now is certified under ``model`` (row G19 for a monitor about
    to check ``model``'s sets while these gains still run; :func:`running_pair_certificate`).

    Returns
    -------
    str
        Empty when certified; else one line: the gate's refusal or the node that could not be read.
    """
    return running_pair_certificate(client, model, controller=controller, observer=observer, timeout=timeout,
                                    u_e_ff_for=u_e_ff_for)[1]


def running_envelope(client, *, controller="controller_node", observer="observer_node", timeout=10.0):
    """The envelope's answer for the pair running now under the controller's model (issue
    37.3; ``reachset gains set``): ``{"note": str, "unvalidated": {joint: [line]} or None}``,
    :meth:`~reachset_ros.systems.gains.PairCertificate.envelope_note`. A model without an
    envelope (or no model) is ``envelope: none recorded`` without a certificate; a pair the
    gate refuses or a node that cannot be read gives the reason in ``note``."""
    got, why = get_remote_parameters(client, controller, ["model_file"], timeout=timeout)
    if got is None:
        return {"note": f"envelope: not checked ({why})", "unvalidated": None}
    path = str(got["model_file"] or "")
    try:
        model = mdl.load(path) if path else None
    except ReachsetError as e:
        return {"note": f"envelope: not checked ({first_line(e)})", "unvalidated": None}
    if model is None or model.envelope is None:
        return {"note": "envelope: none recorded", "unvalidated": None}
    pc, why = running_pair_certificate(client, model, controller=controller, observer=observer, timeout=timeout)
    if pc is None:
        return {"note": f"envelope: not checked ({why})", "unvalidated": None}
    return {"note": pc.envelope_note(),
            "unvalidated": None if pc.unvalidated is None else {j: list(v) for j, v in pc.unvalidated.items()}}


def set_pair(node, changes, *, timeout=10.0):
    """Set the parameters ``changes`` (``{target: {name: value}}``, e.g. the same gains for
    ``observer_node`` and ``controller_node``) on the nodes of a pair, all or none.

    Each target certifies the pair that will run after its change with the other's running
    half (:func:`check_running_pair`), so the targets are set one after the other: in the
    given order and, when the first refuses, in the reverse order (of the two intermediate
    pairs one may be certified when the other is not). A target that refuses after another
    accepted has the accepted ones set back to their previous values of the same parameters.

    Parameters
    ----------
    node : rclpy.node.Node
        The client node (spun here until each answer arrives).
    changes : dict
    timeout : float
        Seconds per parameter call.

    Returns
    -------
    ok : bool
    reason : str
        Empty when every target accepted; else one line per order tried: which node refused
        and why, and whether the others were set back.
    """
    targets = list(changes)
    previous = {}
    for t in targets:
        cur, why = get_remote_parameters(node, t, list(changes[t]), timeout=timeout)
        if cur is None:
            return False, why
        previous[t] = cur
    reasons = []
    for order in ([targets, targets[::-1]] if len(targets) == 2 else [targets]):
        done = []
        for t in order:
            ok, why = set_remote_parameters(node, t, changes[t], timeout=timeout)
            if not ok:
                reasons.append(f"{t} refused: {' '.join(why.split())}")
                break
            done.append(t)
        else:
            return True, ""
        failed = [t for t in reversed(done) if not set_remote_parameters(node, t, previous[t], timeout=timeout)[0]]
        if failed:
            return False, f"{reasons[-1]}; ROLLBACK FAILED for {', '.join(failed)}, which keeps the new values"
        if done:
            reasons[-1] += f"; {', '.join(done)} set back"
            break            # something was applied and set back: no second order from there
    return False, "; in the reverse order: ".join(reasons)
