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
an error: ``stable`` is false and the set keys are null.
"""
import math

from ..errors import ReachsetError
from ..systems.closedloop import analyze, close_loop
from ..systems.controllers import compensated_feedback, static_feedback
from ..systems.observers import extended_state_observer, high_gain_observer
from ..systems.plant import lwa4p_joint_plant
from . import emit

NAME = "analyze"
HELP = "reachable tracking error R_e and reachable input R_u of one joint's closed loop"

_DEFAULTS = {
    "hg": dict(controller="static", omega=24.40, zeta=0.96, alpha_w=[0.0348, 3.59], alpha_v=3.49e-5),
    "eso": dict(controller="compensated", omega=20.0, zeta=1.0, alpha_w=[0.0234, 3.587], alpha_v=3.49e-5),
}


def add_arguments(p):
    p.add_argument("--observer", choices=["hg", "eso"], default="hg",
                   help="high-gain (hg, default) or extended-state observer (eso)")
    p.add_argument("--h1", type=float, default=15.0, help="HG gain h1 (default 15, paper Sec. IV-A)")
    p.add_argument("--h2", type=float, default=30.0, help="HG gain h2 (default 30)")
    p.add_argument("--l1", type=float, default=57.1, help="ESO gain l1 (default 57.1, Table III axis 1)")
    p.add_argument("--l2", type=float, default=103.3, help="ESO gain l2 (default 103.3)")
    p.add_argument("--l3", type=float, default=18.1, help="ESO gain l3 (default 18.1)")
    p.add_argument("--eps", type=float, default=0.01, help="observer gain scaling epsilon (default 0.01)")
    p.add_argument("--eso-input", choices=["previous", "current"], default="previous",
                   help="plant input fed to the ESO at tick k: u_p[k-1] (default, reproduces the paper) "
                        "or u_p[k] (algebraic loop, solved exactly)")
    p.add_argument("--controller", choices=["static", "compensated"], default=None,
                   help="static or disturbance-compensated feedback (default: static with hg, "
                        "compensated with eso)")
    p.add_argument("--omega", type=float, default=None, help="natural frequency (default 24.40 hg / 20 eso)")
    p.add_argument("--zeta", type=float, default=None, help="damping ratio (default 0.96 hg / 1 eso)")
    p.add_argument("--alpha-w", type=float, nargs=2, default=None, metavar="F",
                   help="scalings of the two process-disturbance generators (default 0.0348 3.59 hg / "
                        "0.0234 3.587 eso)")
    p.add_argument("--alpha-v", type=float, default=None, metavar="F",
                   help="scaling of the measurement-noise generator (default 3.49e-5)")
    p.add_argument("--dt", type=float, default=0.004, help="sampling time in s (default 0.004)")
    p.add_argument("--u-ff", type=float, default=2.0, help="half-width of U_ff in rad/s^2 (default 2)")
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
