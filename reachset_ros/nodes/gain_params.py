"""Per-joint gain parameters shared by the observer and controller nodes.

Both nodes turn their parameters into one :class:`~reachset_ros.systems.gains.Gains` per
joint (:func:`gains_from`), the type the synthesis certifies and writes into the model
file: ``observer``, ``controller`` and ``eso_input`` (which plant input the ESO is fed) are
one string per node, the numbers one value per joint or one for all.
"""
from ..errors import ReachsetError
from ..systems.gains import DEFAULTS, ESO_INPUTS, Gains
from .common import desc

GAIN_DOCS = {
    "omega": ("natural frequency of the feedback law, rad/s", 0.1, 500.0),
    "zeta": ("damping ratio of the feedback law", 0.05, 10.0),
    "h1": ("high-gain observer gain h1", 1e-3, 1e4),
    "h2": ("high-gain observer gain h2", 1e-3, 1e6),
    "l1": ("ESO gain l1", 1e-3, 1e4),
    "l2": ("ESO gain l2", 1e-3, 1e6),
    "l3": ("ESO gain l3", 1e-3, 1e6),
    "eps": ("observer gain scaling epsilon, s", 1e-5, 1.0),
}
#: the string parameters: the loop structure (one per node)
TYPE_PARAMS = ("observer", "controller", "eso_input")


def declare_gain_parameters(node):
    node.declare_parameter("observer", DEFAULTS["observer"], desc("hg | eso"))
    node.declare_parameter("controller", DEFAULTS["controller"], desc("static | compensated"))
    node.declare_parameter("eso_input", DEFAULTS["eso_input"],
                           desc(f"{' | '.join(ESO_INPUTS)}: plant input the ESO is fed at tick k, u_p[k-1] or "
                                "u_p[k] (an algebraic loop the controller solves); as in the model file's gains"))
    for k, (d, lo, hi) in GAIN_DOCS.items():
        node.declare_parameter(k, [float(DEFAULTS[k])], desc(d + "; one value per joint, or one for all"))


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
    for p in params:
        if p.name in vals:
            vals[p.name] = p.value
    return vals
