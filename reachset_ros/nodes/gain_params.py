"""Per-joint gain parameters shared by the observer and controller nodes.

Both nodes turn their parameters into one :class:`~reachset_ros.systems.gains.Gains` per
joint (:func:`gains_from`), the type the synthesis certifies and writes into the model
file: ``observer``, ``controller`` and ``eso_input`` (which plant input the ESO is fed) are
one string per node, the numbers one value per joint or one for all.
"""
from array import array

import numpy as np

from .. import defaults
from ..errors import ReachsetError
from ..robot.dynamics import JOINT_NAMES
from ..synthesis.reference_error import u_e_ff_for_gains
from ..systems.gains import DEFAULTS, ESO_INPUTS, GAIN_KEYS, TYPE_KEYS, Gains, certify_pair
from .common import desc
from .pair_gate import check_running_pair, declare_pair_parameters  # noqa: F401 (check_running_pair: for the nodes)

#: description and range of each gain parameter (the keys and defaults: defaults ``gains.keys``,
#: ``gains.startup``, registered by :mod:`reachset_ros.systems.gains`)
_GAIN_TEXT = {
    "omega": ("natural frequency of the feedback law, rad/s", 0.1, 500.0),
    "zeta": ("damping ratio of the feedback law", 0.05, 10.0),
    "h1": ("high-gain observer gain h1", 1e-3, 1e4),
    "h2": ("high-gain observer gain h2", 1e-3, 1e6),
    "l1": ("ESO gain l1", 1e-3, 1e4),
    "l2": ("ESO gain l2", 1e-3, 1e6),
    "l3": ("ESO gain l3", 1e-3, 1e6),
    "eps": ("observer gain scaling epsilon, s", 1e-5, 1.0),
}
GAIN_DOCS = {k: _GAIN_TEXT[k] for k in GAIN_KEYS}
#: the string parameters: the loop structure (one per node)
TYPE_PARAMS = TYPE_KEYS


def default_u_max():
    """The ``u_max`` parameter's default: U_p of the LWA-4P (defaults ``lwa4p.u_max``, paper
    Table I) in the order of the nodes' default ``joints``."""
    u_max = defaults.get("lwa4p.u_max")
    return [float(u_max[j]) for j in JOINT_NAMES]
#: what the pair's certificate needs besides the gains (declared by both nodes)
CERTIFICATE_PARAMS = ("model_file", "u_max", "u_ff_bound", "allow_uncertified")


def declare_gain_parameters(node):
    node.declare_parameter("observer", DEFAULTS["observer"], desc("hg | eso"))
    node.declare_parameter("controller", DEFAULTS["controller"], desc("static | compensated"))
    node.declare_parameter("eso_input", DEFAULTS["eso_input"],
                           desc(f"{' | '.join(ESO_INPUTS)}: plant input the ESO is fed at tick k, u_p[k-1] or "
                                "u_p[k] (an algebraic loop the controller solves); as in the model file's gains"))
    for k, (d, lo, hi) in GAIN_DOCS.items():
        node.declare_parameter(k, [float(DEFAULTS[k])], desc(d + "; one value per joint, or one for all"))
    node.declare_parameter("change_reason", "",
                           desc("why the gains or the model change: set in the same request as them, logged with "
                                "the change (a PRIVILEGED line, granted or refused)"))


#: parameters whose change moves the arm differently (a privileged operation, issue 17.4)
GAIN_CHANGE_PARAMS = ("observer", "controller", "eso_input", *GAIN_DOCS, "model_file", "u_max", "u_ff_bound",
                      "allow_uncertified")


def log_gain_change(node, params, result, cfg=None):
    """A ``PRIVILEGED`` log line for a parameter request that changes the gains or the model
    (:func:`reachset_ros.nodes.audit.log_privileged`), granted or refused; with the
    ``change_reason`` set in the same request. Parameter requests name no caller: the line
    lists the nodes with a client of this node's parameter services. With the granted
    configuration ``cfg``: the envelope's line too (:func:`log_envelope`)."""
    from .audit import log_privileged
    changed = [p for p in params if p.name in GAIN_CHANGE_PARAMS]
    if not changed:
        return
    reason = next((str(p.value) for p in params if p.name == "change_reason"), "")
    what = ", ".join(f"{p.name}={list(p.value) if isinstance(p.value, (list, tuple, array)) else p.value!r}"
                     for p in changed)
    if len(what) > 300:
        what = what[:300] + "..."
    outcome = "granted" if result.successful else f"refused: {result.reason}"
    services = [node.resolve_service_name("~/set_parameters"), node.resolve_service_name("~/set_parameters_atomically")]
    log_privileged(node, f"gain change ({what})", "", reason, outcome, services)
    if cfg is not None and result.successful:
        log_envelope(node, cfg, "gain change")


def declare_certificate_parameters(node):
    """What the gate of the pair needs: the model, U_p, U_ff, the explicit opt-out and the
    node running the other half (``pair_node``, :mod:`~reachset_ros.nodes.pair_gate`)."""
    node.declare_parameter("model_file", "", desc("conformance model the gains are certified against (R*_u inside "
                                                  "U_p with its sets and inflation)"))
    node.declare_parameter("u_max", default_u_max(),
                           desc("U_p half-width per joint, rad/s^2"))
    node.declare_parameter("u_ff_bound", defaults.get("gains.u_ff"),
                           desc("bound of the feedforward |qdd_d|, rad/s^2, that R_u is certified for; references "
                                "beyond it are flagged reference_out_of_class", 0.0, 1000.0))
    declare_pair_parameters(node)
    node.declare_parameter("allow_uncertified", False,
                           desc("run gains that no model certifies (no model_file, or a joint not in it) on closed-"
                                "loop stability alone; without it they are refused"))


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


def validate_pair(node, values, model):
    """The gate of both nodes: :func:`~reachset_ros.systems.gains.certify_pair` of the gains
    a proposed set of parameters gives (``values``: gain parameters, optionally u_max,
    u_ff_bound, allow_uncertified; the node's current values otherwise), with U_e,ff of gains
    other than the model's over its reference class
    (:func:`~reachset_ros.synthesis.reference_error.u_e_ff_for_gains`). Returns a dict:
    ``gains``, ``laws``, ``settling``, ``uncertified``, ``envelope_note`` and ``unvalidated``
    (from the certificate: the parts of the certified class the model was never validated on,
    issue 37.3, :meth:`~reachset_ros.systems.gains.PairCertificate.envelope_note`), ``u_max``,
    ``u_ff``, ``model``; raises ReachsetError with the reason."""
    def value(name):
        return values[name] if name in values else node.get_parameter(name).value
    gains = gains_from(values, node.joints)
    u_max = u_max_array(value("u_max"), len(node.joints))
    u_ff = float(value("u_ff_bound"))
    pc = certify_pair(gains, model, u_max, u_ff, node.dt, bool(value("allow_uncertified")),
                      u_e_ff_for=u_e_ff_for_gains)
    return dict(gains=pc.gains, laws=pc.laws, settling=pc.settling, uncertified=pc.uncertified,
                envelope_note=pc.envelope_note(), unvalidated=pc.unvalidated_lines(), u_max=u_max, u_ff=u_ff,
                model=model)


def log_envelope(node, cfg, cause):
    """One line per applied change of the gate's inputs (start-up, a gain or model change; issue
    37.3): a WARN naming the parts of the certified class the model was never validated on
    (:func:`validate_pair`'s ``envelope_note``), else an INFO saying the class lies inside the
    envelope or that the model records none. Naming, not refusing (docs/theory.md, row G21):
    the certificate holds for the model; the envelope says where the model was tested. The
    parameter service cannot carry it: rclpy answers a granted request with an empty reason."""
    text = f"{cause}: {cfg['envelope_note']}"
    if cfg["unvalidated"]:          # two call sites: rclpy refuses one site logging at two severities
        node.get_logger().warning(text)
    else:
        node.get_logger().info(text)


def gains_from(values: dict, joints):
    """Per-joint :class:`Gains` from parameter values (arrays of length 1 or len(joints))."""
    out = {}
    for i, j in enumerate(joints):
        kw = {t: values[t] for t in TYPE_PARAMS if t in values}
        for k in GAIN_DOCS:
            arr = list(values[k])
            if len(arr) not in (1, len(joints)):
                raise ReachsetError(f"parameter {k} needs 1 or {len(joints)} values, got {len(arr)}")
            kw[k] = float(arr[i] if len(arr) > 1 else arr[0])
        out[j] = Gains.from_dict(kw)
    return out


def current_values(node):
    names = list(TYPE_PARAMS) + list(GAIN_DOCS)
    return {n: node.get_parameter(n).value for n in names}


def proposed_values(node, params):
    vals = current_values(node)
    vals.update({n: node.get_parameter(n).value for n in CERTIFICATE_PARAMS})
    for p in params:
        if p.name in vals:
            vals[p.name] = p.value
    return vals
