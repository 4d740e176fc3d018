"""``reachset analyze``: reachable tracking error R_e and reachable input R_u of one joint.

Builds the paper's per-joint plant (Appendix A), an observer (high-gain or extended-state)
and a controller (static or disturbance-compensated feedback), closes the loop and prints
the sound outer bounds of R_e and R_u (paper Sec. III-A), plus the truncated inner numbers.

Defaults are the paper's axis-1 values of the experiment that uses the chosen observer:

* ``--observer hg`` (Sec. IV-A, Table II axis 1): h1 = 15, h2 = 30, eps = 0.01, static
  feedback with omega = 24.40, zeta = 0.96, alpha_W = [0.0348, 3.59], alpha_V = 3.49e-5;
* ``--observer eso`` (Sec. IV-C, Table III axis 1): l1 = 57.1, l2 = 103.3, l3 = 18.1,
  eps = 0.01, compensated feedback with omega = 20, zeta = 1,
  alpha_W = [0.0234, 3.587], alpha_V = 3.49e-5.

``--u-ff`` is the half-width of U_ff (paper: |qdd_d| <= 2 rad/s^2). An unstable loop is not
bad input but has no reachable sets: the result is printed (``stable`` false, the set keys
null), a one-line reason goes to stderr and the exit status is 1.
"""
import math
import sys

from .. import defaults
from ..errors import ReachsetError, first_line
from ..systems.closedloop import analyze, close_loop
from ..systems.controllers import compensated_feedback, static_feedback
from ..systems.gains import family_controller
from ..systems.observers import extended_state_observer, high_gain_observer
from ..systems.plant import lwa4p_joint_plant
from . import emit, help_of

NAME = "analyze"
HELP = help_of(NAME)

defaults.register("analyze.hg", {
    "alpha_w": ([0.0348, 3.59], "scalings of the two process-disturbance generators identified for axis 1 "
                                "(paper Sec. IV-A, Table II)"),
    "alpha_v": (3.49e-5, "scaling of the measurement-noise generator identified for axis 1 (paper Table II)"),
}, owner=__name__)
defaults.register("analyze.eso", {
    "alpha_w": ([0.0234, 3.587], "scalings of the two process-disturbance generators identified for axis 1 "
                                 "(paper Sec. IV-C, Table III)"),
    "alpha_v": (3.49e-5, "scaling of the measurement-noise generator identified for axis 1 (paper Table III)"),
}, owner=__name__)

#: per observer: the loop of the paper's experiment with that observer (module docstring):
#: its family's feedback law (defaults ``gains.hg.controller`` / ``gains.eso.controller``) at
#: Table II's omega, zeta (hg, defaults ``gains.feedback.table_ii``) or the paper's fixed ones
#: (eso, ``gains.feedback.paper``), and axis 1's identified sets (``analyze.hg``, ``analyze.eso``)
_DEFAULTS = {
    "hg": dict(controller=family_controller("hg"), **defaults.get("gains.feedback.table_ii"),
               **defaults.table("analyze.hg")),
    "eso": dict(controller=family_controller("eso"), **defaults.get("gains.feedback.paper"),
                **defaults.table("analyze.eso")),
}
_HG, _ESO = defaults.table("gains.hg"), defaults.table("gains.eso")


def _num(v):
    """A default as the help writes it: ``3.49e-5``, ``20``, ``0.01``."""
    return f"{v:g}".replace("e-0", "e-").replace("e+0", "e+")


def _pair(key, hg_fmt=_num):
    return f"{hg_fmt(_DEFAULTS['hg'][key])} hg / {_num(_DEFAULTS['eso'][key])} eso"


def add_arguments(p):
    p.add_argument("--observer", choices=["hg", "eso"], default="hg",
                   help="high-gain (hg, default) or extended-state observer (eso)")
    p.add_argument("--h1", type=float, default=_HG["h1"], help=f"HG gain h1 (default {_HG['h1']:g}, paper Sec. IV-A)")
    p.add_argument("--h2", type=float, default=_HG["h2"], help=f"HG gain h2 (default {_HG['h2']:g})")
    p.add_argument("--l1", type=float, default=_ESO["l1"],
                   help=f"ESO gain l1 (default {_ESO['l1']:g}, Table III axis 1)")
    p.add_argument("--l2", type=float, default=_ESO["l2"], help=f"ESO gain l2 (default {_ESO['l2']:g})")
    p.add_argument("--l3", type=float, default=_ESO["l3"], help=f"ESO gain l3 (default {_ESO['l3']:g})")
    p.add_argument("--eps", type=float, default=_HG["eps"],
                   help=f"observer gain scaling epsilon (default {_HG['eps']:g})")
    p.add_argument("--eso-input", choices=["previous", "current"], default=_ESO["eso_input"],
                   help="plant input fed to the ESO at tick k: u_p[k-1] (default, reproduces the paper) "
                        "or u_p[k] (algebraic loop, solved exactly)")
    p.add_argument("--controller", choices=["static", "compensated"], default=None,
                   help=f"static or disturbance-compensated feedback (default: {_DEFAULTS['hg']['controller']} with "
                        f"hg, {_DEFAULTS['eso']['controller']} with eso)")
    p.add_argument("--omega", type=float, default=None,
                   help=f"natural frequency (default {_pair('omega', '{:.2f}'.format)})")
    p.add_argument("--zeta", type=float, default=None, help=f"damping ratio (default {_pair('zeta')})")
    p.add_argument("--alpha-w", type=float, nargs=2, default=None, metavar="F",
                   help="scalings of the two process-disturbance generators (default "
                        f"{' '.join(map(str, _DEFAULTS['hg']['alpha_w']))} hg / "
                        f"{' '.join(map(str, _DEFAULTS['eso']['alpha_w']))} eso)")
    p.add_argument("--alpha-v", type=float, default=None, metavar="F",
                   help=f"scaling of the measurement-noise generator (default {_num(_DEFAULTS['hg']['alpha_v'])})")
    p.add_argument("--dt", type=float, default=0.004, help="sampling time in s (default 0.004)")
    p.add_argument("--u-ff", type=float, default=defaults.get("gains.u_ff"),
                   help=f"half-width of U_ff in rad/s^2 (default {_num(defaults.get('gains.u_ff'))})")
    p.add_argument("--json", action="store_true", help="print one JSON object")


def _finite_positive(name, v):
    if v is None or not math.isfinite(v) or v <= 0:
        raise ReachsetError(f"--{name} must be a positive finite number, got {v}")


def run(args):
    d = _DEFAULTS[args.observer]
    ctrl_kind = args.controller or d["controller"]
    omega = d["omega"] if args.omega is None else args.omega
    zeta = d["zeta"] if args.zeta is None else args.zeta
    alpha_w = list(d["alpha_w"] if args.alpha_w is None else args.alpha_w)
    alpha_v = d["alpha_v"] if args.alpha_v is None else args.alpha_v
    for nm, v in (("dt", args.dt), ("eps", args.eps), ("omega", omega), ("zeta", zeta)):
        _finite_positive(nm, v)
    for nm, v in (("h1", args.h1), ("h2", args.h2)) if args.observer == "hg" else \
            (("l1", args.l1), ("l2", args.l2), ("l3", args.l3)):
        _finite_positive(nm, v)
    for nm, vals in (("alpha-w", alpha_w), ("alpha-v", [alpha_v]), ("u-ff", [args.u_ff])):
        if any(not math.isfinite(x) or x < 0 for x in vals):
            raise ReachsetError(f"--{nm} must be finite and non-negative, got {' '.join(map(str, vals))}")
    if ctrl_kind == "compensated" and args.observer != "eso":
        raise ReachsetError("--controller compensated needs a disturbance estimate: use --observer eso")

    plant = lwa4p_joint_plant(dt=args.dt)
    try:
        if args.observer == "hg":
            obs = high_gain_observer(args.h1, args.h2, eps=args.eps, dt=args.dt)
        else:
            obs = extended_state_observer(args.l1, args.l2, args.l3, eps=args.eps, dt=args.dt, u_input=args.eso_input)
        ctrl = static_feedback(omega, zeta) if ctrl_kind == "static" else compensated_feedback(omega, zeta)
        cl = close_loop(plant, obs, ctrl)
        res = analyze(cl, alpha_w, [alpha_v], u_ff=args.u_ff)
    except ValueError as e:
        raise ReachsetError(str(e)) from e

    out = res.as_dict()
    out["params"] = dict(observer=args.observer, observer_gains=obs.params, controller=ctrl_kind,
                         omega=omega, zeta=zeta, alpha_w=alpha_w, alpha_v=[alpha_v], dt=args.dt,
                         u_ff=args.u_ff)
    if res.stable:
        human = (f"{res.stability.message}\n"
                 f"R_e (outer): norm {res.re_norm:.6g} (sum of interval-hull edge lengths), "
                 f"radius [q {res.re_radius[0]:.6g} rad, qd {res.re_radius[1]:.6g} rad/s]\n"
                 f"R_u (outer, incl. U_ff = +-{args.u_ff:g}): [{res.ru[0]:.6g}, {res.ru[1]:.6g}] rad/s^2\n"
                 f"inner (truncated after {res.s} steps): norm {res.re_norm_inner:.6g}, "
                 f"R_u [{res.ru_inner[0]:.6g}, {res.ru_inner[1]:.6g}]")
    else:
        human = res.stability.message
    emit(args, out, human)
    if not res.stable:       # no R_e, no R_u: exit 1, as check does for a non-conformant bag
        print(f"reachset analyze: {first_line(ValueError(res.stability.message))}", file=sys.stderr)
        return 1
    return 0
