"""``reachset synthesize``: combined controller synthesis and reachset-conformant identification.

Per joint, paper eq. 10: min ||R_e|| over the controller/observer parameters and the
disturbance sets, subject to Theorem-1 conformance on the bags' test cases and
R_u (+) U_ff inside U_p = [-u_max, u_max]. See docs/synthesis.md and
:mod:`reachset_ros.synthesis`.

Modes:

- ``combined`` (default): eq. 10; also runs the separate approach (reported under
  ``separate``; it seeds the combined search, so combined ||R_e|| <= separate ||R_e||).
- ``separate``: identify min ||W|| + ||V||, then search the parameters with the sets fixed.
- ``reidentify``: the controller of ``--model`` is kept, only the sets are re-identified
  (the inner linear programme of eq. 10; paper Sec. III-D, step 3).

Theorem 1 holds the initial-state estimate's error as a set (``--initial-state-set``, the
default since issue 16.1; ``--no-initial-state-set``: the paper's eq. 13).

``--lqg-r R...`` adds the LQG baseline of the paper's Table IV (with the result's sets).
``--out`` writes a model file (``reachset check`` accepts it) whose joints carry the gains.
``--workers N`` / ``--scheduler ADDRESS``: the sweep runs one task per bag on Dask
(:mod:`reachset_ros.fleet`); the result is the single-process one to the bit (provenance and
timings aside); ``--plot`` needs the series in this process and is refused with them.
"""
import argparse
import math
import sys
import time

from .. import defaults
from ..conformance.estimators import ESTIMATORS
from ..errors import ReachsetError
from ..synthesis.config import PARAMS
from ..synthesis.reference_error import ReferenceClass, ReferenceMethod
from ..workflows.synthesize import SynthesisOptions, synthesize
from . import emit, help_of
from ._bagargs import (add_bag_arguments, add_fleet_arguments, check_out_path, fleet_of, parse_joints, read_spec,
                       reader_options, topics_of)
from ._progress import bag_count, progress

NAME = "synthesize"
HELP = help_of(NAME)


def add_arguments(p):
    add_bag_arguments(p)
    add_fleet_arguments(p)
    p.add_argument("--mode", choices=["combined", "separate", "reidentify"], default="combined",
                   help="combined (eq. 10, default), separate (identify then synthesise) or reidentify "
                        "(controller of --model fixed, sets updated)")
    p.add_argument("--model", help="model file whose gains reidentify keeps (mode reidentify)")
    p.add_argument("--observer", choices=["hg", "eso"], default="hg",
                   help="high-gain (hg, default) or extended-state observer (eso)")
    p.add_argument("--controller", choices=["static", "compensated"], default=None,
                   help="static (default with hg) or disturbance-compensated feedback (default with eso)")
    p.add_argument("--free", help="comma-separated parameters to search (default from the config: "
                                  "hg: omega,zeta; eso: l1,l2,l3)")
    p.add_argument("--fix", action="append", default=[], metavar="NAME=VALUE",
                   help="fix a parameter (repeatable), e.g. --fix omega=20")
    p.add_argument("--bound", action="append", default=[], metavar="NAME=LO,HI",
                   help="search box of a parameter (repeatable)")
    p.add_argument("--config", help="synthesis config YAML (default config/synthesis.yaml)")
    p.add_argument("--u-max", type=float, nargs="+", metavar="F",
                   help="U_p = [-F, F] in rad/s^2: one value for all joints or one per joint "
                        "(default: config u_max per joint, the paper's Table I)")
    p.add_argument("--u-ff", type=float, default=None,
                   help="U_ff = [-F, F], bound of the feedforward qdd_d (default 2, paper Sec. IV)")
    p.add_argument("--horizon", type=int, default=None, help="k*, ticks (default 125; reidentify: the model's; "
                                                              "at least the plant's minimum, 2 for the LWA-4P joint)")
    p.add_argument("--allow-weak-horizon", action="store_true",
                   help="accept a horizon below the plant's minimum (a weaker guarantee: some alpha is not "
                        "constrained by the data); recorded in the model file")
    p.add_argument("--estimator", default=None, choices=sorted(ESTIMATORS),
                   help=f"initial-state estimator of the test cases (default {defaults.get('synthesis.estimator')}; "
                        "reidentify: the model's)")
    p.add_argument("--initial-state-set", action=argparse.BooleanOptionalAction, default=None,
                   help="Theorem 1 with the estimator's initial-state error as a set (default; as identify "
                        "--initial-state-set: much smaller sets, docs/synthesis.md); --no-initial-state-set: "
                        "the paper's eq. 13; reidentify: the model's choice")
    p.add_argument("--alpha-lower", type=float, nargs="+", metavar="F",
                   help="lower bounds on [alpha_W..., alpha_V...]")
    p.add_argument("--reference-method", type=int, choices=[int(m) for m in ReferenceMethod],
                   default=int(ReferenceMethod.REFERENCE_SET),
                   help="Appendix B: 3 (default) sets over the bags' references inside the optimisation; "
                        "2 optimise without, check R_u + u_e,ff for the recorded references; "
                        "1 the controller tracks y_cl,ref (no u_e,ff)")
    p.add_argument("--reference-class", metavar="qdd_max=F[,step_max=F]", default=None,
                   help="bound the reference error (Appendix B) over every reference with |qdd_d| <= qdd_max "
                        "varying by <= step_max (default 2 qdd_max) within a tick, instead of the bags' "
                        "/reference (which must then lie in it); required when the bags have no /reference")
    p.add_argument("--eso-input", choices=["previous", "current"], default="previous",
                   help="plant input fed to the ESO: u_p[k-1] (default) or u_p[k]")
    p.add_argument("--seed", type=int, default=None, help="seed of the global search (default: config, 0)")
    p.add_argument("--lqg-r", type=float, nargs="+", metavar="R",
                   help="LQG baseline (paper Table IV) for these input weights r")
    p.add_argument("--out", help="write the model (sets + gains) YAML here")
    p.add_argument("--plot", metavar="DIR", help="write PNG figures (R_e, R_u, conformance) into DIR")
    p.add_argument("--dt", type=float, default=0.004, help="sampling time, s")
    p.add_argument("--inflation", type=float, default=None, metavar="F",
                   help="the monitor will check the sets scaled by 1 + F: R*_u inside U_p is enforced and R*_e "
                        "reported for those sets, and the model records F (default 0; reidentify: the model's)")
    p.add_argument("--calibrate", type=int, default=None, metavar="K",
                   help="calibrate the model's inflation on the synthesised sets (the ones the monitor checks) by "
                        "K-fold cross-validation of the bags, with the rule that made them (min ||R*_e|| of the "
                        "gains per fold), and record it; an inflation calibrated by identify is for identify's "
                        "sets (docs/theory.md). Synthesise with --inflation at least the result for R*_u to cover it")


def _kv(items, what):
    out = {}
    for it in items:
        if "=" not in it:
            raise ReachsetError(f"--{what}: expected NAME=VALUE, got {it!r}")
        k, v = it.split("=", 1)
        out[k.strip()] = v.strip()
    return out


def _finite(name, v, positive=False):
    if v is None:
        return
    if not math.isfinite(v) or (positive and v <= 0) or (not positive and v < 0):
        raise ReachsetError(f"--{name} must be a {'positive' if positive else 'non-negative'} finite number, got {v}")


def _human(res):
    lines = []
    for n, r in res.items():
        g = r.gains()
        pars = ", ".join(f"{k}={g[k]:.4g}" for k in PARAMS[r.observer])
        lines.append(f"{n}: {r.mode} {r.observer}+{r.controller}: ||R_e|| = {r.re_norm:.4g}, "
                     f"R_u = [{r.ru[0]:.4g}, {r.ru[1]:.4g}] in U_p = [-{r.u_max:g}, {r.u_max:g}]; {pars}; "
                     f"alpha_w = [{', '.join(f'{a:.4g}' for a in r.alpha_w)}], "
                     f"alpha_v = [{', '.join(f'{a:.4g}' for a in r.alpha_v)}]; "
                     f"{'conformant' if r.conformant else 'NOT conformant'} on {r.test_cases} test cases")
        if r.separate is not None:
            s = r.separate
            lines.append(f"  separate: ||R_e|| = {s.re_norm:.4g}, R_u = [{s.ru[0]:.4g}, {s.ru[1]:.4g}], "
                         + ", ".join(f"{k}={s.params[k]:.4g}" for k in (s.free or PARAMS[s.observer]))
                         + f", alpha_w = [{', '.join(f'{a:.4g}' for a in s.alpha_w)}]")
        for row in r.extra.get("lqg", []):
            if "re_norm" in row:
                lines.append(f"  LQG r={row['r']:g}: ||R_e|| = {row['re_norm']:.4g}, "
                             f"R_u = [{row['ru'][0]:.4g}, {row['ru'][1]:.4g}]"
                             + ("" if row["ru_inside_up"] else "  (outside U_p)"))
            else:
                lines.append(f"  LQG r={row['r']:g}: {row.get('error', 'failed')}")
    return "\n".join(lines)


def _fix(items):
    fix = {}
    for k, v in _kv(items, "fix").items():
        try:
            fix[k] = float(v)
        except ValueError:
            raise ReachsetError(f"--fix {k}: {v!r} is not a number") from None
    return fix


def _bounds(items):
    bounds = {}
    for k, v in _kv(items, "bound").items():
        try:
            lo, hi = (float(x) for x in v.split(","))
        except ValueError:
            raise ReachsetError(f"--bound {k}: expected LO,HI, got {v!r}") from None
        bounds[k] = (lo, hi)
    return bounds


def options_of(args, joints, free, reader=None):
    """The :class:`~reachset_ros.workflows.synthesize.SynthesisOptions` of the command line."""
    return SynthesisOptions(
        joints=joints, mode=args.mode, observer=args.observer, controller=args.controller, free=free,
        fix=_fix(args.fix), bounds=_bounds(args.bound), u_max=args.u_max, u_ff=args.u_ff, horizon=args.horizon,
        estimator=args.estimator, alpha_lower=args.alpha_lower, reference_method=ReferenceMethod(args.reference_method),
        eso_input=args.eso_input, seed=args.seed, lqg_r=tuple(args.lqg_r or ()), config=args.config, model=args.model,
        dt=args.dt, allow_weak_horizon=args.allow_weak_horizon,
        reference_class=None if args.reference_class is None else ReferenceClass.parse(args.reference_class),
        inflation=args.inflation, topics=topics_of(args), reader=reader, initial_state_set=args.initial_state_set)


def check_args(args):
    """Refuse out-of-range numbers and options that exclude each other, naming the option."""
    if args.dt <= 0 or not math.isfinite(args.dt):
        raise ReachsetError("--dt must be positive")
    _finite("u-ff", args.u_ff)
    _finite("inflation", args.inflation)
    if args.horizon is not None and args.horizon < 0:
        raise ReachsetError("--horizon must be >= 0")
    for v in args.u_max or []:
        _finite("u-max", v, positive=True)
    for r in args.lqg_r or []:
        _finite("lqg-r", r, positive=True)
    if args.mode == "reidentify" and not args.model:
        raise ReachsetError("--mode reidentify needs --model (the model whose gains are kept)")
    if args.mode != "reidentify" and args.model:
        raise ReachsetError("--model is only used with --mode reidentify")
    if args.calibrate is not None and args.calibrate < 2:
        raise ReachsetError(f"--calibrate needs K >= 2 folds, got {args.calibrate}")


def compute(args, command=None):
    """Run the synthesis of the command line (:func:`~reachset_ros.workflows.synthesize.synthesize`):
    its :class:`~reachset_ros.workflows.synthesize.SynthesisResult`, and the ``--json`` object
    (with ``seconds``). ``command``: the command line for the model's provenance (default:
    this process's)."""
    t0 = time.perf_counter()
    check_args(args)
    out = check_out_path(args.out)
    free = None if args.free is None else [x.strip() for x in args.free.split(",") if x.strip()]
    joints = None if args.joints in (None, "all") else parse_joints(args.joints)
    fleet = fleet_of(args, refused=((args.plot is not None, "--plot"), (args.calibrate is not None, "--calibrate")))
    if fleet is None:
        opts, read = options_of(args, joints, free, reader=reader_options(args)), None
    else:                      # the sweep per bag on Dask, merged exactly (the same result, to the bit)
        # the reader's effort source is only recorded (the model's input_source), the workers read
        opts, read = options_of(args, joints, free, reader=reader_options(args)), read_spec(args, None, args.dt)
    command = command or "reachset " + " ".join(sys.argv[1:])
    with progress(args) as p:
        p.phase(f"reading {bag_count(args.bags)} and synthesising the gains")
        res = synthesize(args.bags, opts, out=out, plot=args.plot, command=command, fleet=fleet, fleet_read=read,
                         calibrate=args.calibrate)
    result = res.to_json()
    result["seconds"] = round(time.perf_counter() - t0, 3)
    return res, result


def run(args):
    res, result = compute(args)
    bs = res.synthesis
    weak = (f"\nWEAK GUARANTEE: horizon {bs.horizon} is below the plant's minimum {bs.minimum_horizon} "
            "(--allow-weak-horizon)") if bs.horizon_below_minimum else ""
    cal = res.calibration
    cal = "" if cal is None else (f"\ninflation calibrated on these sets ({cal['folds']} folds), per joint: "
                                  + ", ".join(f"{n} {x:g}" for n, x in cal["inflations"].items())
                                  + ("" if cal["certified"] else f"; NOT CERTIFIED: R*_u was synthesised for inflation "
                                     f"{cal['synthesised_for_inflation']:g} (synthesize again with --inflation "
                                     f"{cal['inflation']:g})"))
    emit(args, result, _human(bs.results) + weak + cal + _envelope_human(res.envelope)
         + (f"\nmodel written to {res.model}" if res.model else ""))


def _envelope_human(env):
    """The envelope's lines of the text output: the note, then one line per part of the reference
    class the model was never validated on (issue 37.3; the ``--json`` ``envelope`` object)."""
    if env is None:
        return ""
    lines = [x for v in (env.get("unvalidated") or {}).values() for x in v]
    if lines:
        return "\nenvelope: NOT VALIDATED, the model was never validated on:" + "".join(f"\n  {x}" for x in lines)
    return "\n" + env["note"] + ("" if env.get("recorded") else f" ({env.get('reason', '')})")
