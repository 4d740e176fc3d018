"""``reachset identify``: reachset-conformant identification (Theorem 1, HiGHS LP).

Options beyond the paper's separate approach:

- ``--cost quadratic``: minimise ||G'_W diag a_W||_F^2 + ||G'_V diag a_V||_F^2 under the same
  Theorem-1 constraints (OSQP through cvxpy, then made sound in floating point).
- ``--cost detection``: minimise the radii of the reachable output sets R_a[k] summed over
  the steps k within ``--detection-window`` (default 0.1 s: the 100 ms in which a fault must
  stop; 0: k = 0..k*; the sets the monitor checks) under the same constraints (HiGHS), rather
  than ||W|| + ||V||, which may put all of W on the generator whose output set grows fastest
  (issue 35.2; measured in docs/performance.md).
- ``--method corollary1``: the conservative state-based variant (paper Corollary 1); it
  needs an estimator consistent with the model and fails with a message naming the test
  case and state direction otherwise (always on noisy LWA-4P data with ``fd``).
- ``--validate BAG...``: inflation calibration on held-out bags. Each joint's identified sets
  are checked on the validation bags (``reachset check``'s arithmetic) with the sets scaled
  by 1 + inflation for inflation 0 and each ``--inflation-grid`` value; per joint the
  smallest grid value with no held-out violation is chosen (the largest grid value,
  flagged, if none) and stored as that joint's ``inflation`` in the model (the model-level
  ``inflation`` is the largest, for readers of one value). At that inflation a test fault is
  injected into the validation data, a constant acceleration of ``--fault-accel`` rad/s^2
  (the measured position gets accel/2 * t^2 from the onset, the middle of the longest
  validation segment), and the detection delay (ticks from onset to first violation) is
  reported.
- ``--workers N`` / ``--scheduler ADDRESS``: the sweep runs one task per bag on Dask
  (:mod:`reachset_ros.fleet`); the model is the single-process one to the bit (provenance
  aside). ``--validate`` bags are then read in this process; ``--calibrate`` and
  ``--method corollary1`` need the whole series and are refused with the options.

The horizon k* is refused (exit 2) below the plant's minimum
(:func:`~reachset_ros.conformance.kernels.minimum_horizon`: the first k* at which Theorem 1
constrains every alpha_W and alpha_V; 2 for the LWA-4P joint plant) unless
``--allow-weak-horizon`` is given; the model file and ``--json`` then record
``horizon_below_minimum: true``. Per joint, ``stable_horizon`` is Remark 3's threshold on
the data (on a grid up to k*) and ``horizon_settled`` says whether the sets stopped changing
before k* (false: a longer horizon may still change them).
"""
import sys
from dataclasses import replace

from .. import defaults

from ..conformance.estimators import ESTIMATORS
from ..workflows.coverage import warning_lines
from ..workflows.identify import DEFAULT_GRID, IdentifyOptions, check_options, identify
from . import emit, help_of
from ._bagargs import (add_bag_arguments, add_fleet_arguments, check_out_path, fleet_of, parse_joints, read_spec,
                       reader_options, topics_of)
from ._progress import bag_count, progress

NAME = "identify"
HELP = help_of(NAME)


def add_arguments(p):
    add_bag_arguments(p)
    add_fleet_arguments(p)
    p.add_argument("--horizon", type=int, default=125, help="k*, ticks (default 125, the paper's; at least "
                                                             "the plant's minimum, 2 for the LWA-4P joint)")
    p.add_argument("--allow-weak-horizon", action="store_true",
                   help="accept a horizon below the plant's minimum (a weaker guarantee: some alpha is not "
                        "constrained by the data); recorded in the model file")
    p.add_argument("--out", help="write the model YAML here")
    p.add_argument("--estimator", default=defaults.get("identify.estimator"), choices=sorted(ESTIMATORS),
                   help="initial-state estimator of the test cases (stored in the model): fd, finite differences of "
                        "two samples; lsq, a least-squares fit over --estimator-window + 1 samples (reads a step "
                        "as less motion; docs/theory.md); observer, a Kalman predictor; output, pinv(C) y")
    p.add_argument("--estimator-window", type=int, metavar="N",
                   help=f"lsq: samples - 1 (default {defaults.get('estimator.lsq_window')}); observer: ticks "
                        f"(default 20)")
    p.add_argument("--initial-state-set", action="store_true",
                   help="Theorem 1 with the estimator's initial-state error as a set made of the same noise and "
                        "disturbances (not charged to the test case's W and V; much smaller sets; docs/theory.md); "
                        "stored in the model, which the monitor then checks the same way")
    p.add_argument("--centers", default="zero", choices=["zero", "free"],
                   help="set centers fixed at 0 (paper) or identified")
    p.add_argument("--alpha-lower", type=float, nargs="+", metavar="F",
                   help="lower bounds on [alpha_W..., alpha_V...] (e.g. encoder resolution)")
    p.add_argument("--dt", type=float, default=0.004, help="sampling time, s")
    p.add_argument("--cost", default=defaults.get("identify.cost"), choices=["linear", "quadratic", "detection"],
                   help="linear: ||W||+||V|| (paper, HiGHS); quadratic: squared Frobenius norm of the "
                        "scaled generators (OSQP); detection: the radii of the reachable output sets summed "
                        "over --detection-window (HiGHS; the monitor's detection power, docs/performance.md); default "
                        "%(default)s")
    p.add_argument("--detection-window", type=float, default=defaults.get("identify.detection_window"), metavar="S",
                   help="with --cost detection: sum the radii over the steps within S seconds of a test case's start "
                        "(default %(default)g: the 100 ms in which a fault must stop; 0: the whole horizon)")
    p.add_argument("--method", default="theorem1", choices=["theorem1", "corollary1"],
                   help="Theorem 1 (output-based, default) or Corollary 1 (state-based, conservative)")
    p.add_argument("--validate", nargs="+", metavar="VBAG",
                   help="held-out bags: report violation rates and calibrate the model's inflation")
    p.add_argument("--inflation-grid", type=float, nargs="+", metavar="F",
                   help=f"inflations tried on the validation bags (default {' '.join(map(str, DEFAULT_GRID))})")
    p.add_argument("--inflation", type=float, default=None, metavar="F",
                   help="the model's inflation, every joint's: the monitor checks the sets scaled by 1 + F (default 0; "
                        "with --validate it is calibrated instead, so the two exclude each other)")
    p.add_argument("--calibrate", type=int, default=None, metavar="K",
                   help="calibrate the inflation by K-fold cross-validation inside the given bags (folds of whole "
                        "runs: stretches of consecutive stamps); per joint the largest over the folds of the "
                        "smallest --inflation-grid value at which the fold is conformant with sets identified on "
                        "the other folds; each joint's value is stored as that joint's inflation")
    p.add_argument("--calibrate-margin", type=int, default=0, metavar="N",
                   help="with --calibrate: store per joint the --inflation-grid value N steps above its cross-validated "
                        "one (default 0). The folds calibrate for data as long as a fold; a run many folds long "
                        "sees more (docs/reliability.md, run-length margin)")
    p.add_argument("--inflation-rule", default=defaults.get("identify.inflation_rule"),
                   choices=["largest", "per-joint"],
                   help="with --calibrate/--validate: apply to every joint the largest of the joints' calibrated "
                        "values, or each joint its own (issue 35.1: more detection power, but on the real LWA-4P the "
                        "folds under-estimated arm_5's held-out need, docs/performance.md); default %(default)s")
    p.add_argument("--fault-accel", type=float, default=5.0, metavar="A",
                   help="test fault for the detection delay: constant acceleration, rad/s^2 (default 5)")
    cov = defaults.table("identify.coverage")
    p.add_argument("--class-qd-max", type=float, default=cov["qd_max"], metavar="V",
                   help=f"the reference class' velocity limit the data's coverage is reported against, rad/s "
                        f"(default {cov['qd_max']:g}, reference_node's qd_max)")
    p.add_argument("--class-qdd-max", type=float, default=cov["qdd_max"], metavar="A",
                   help=f"the reference class' acceleration limit u_ff, rad/s^2 (default {cov['qdd_max']:g})")
    p.add_argument("--coverage-threshold", type=float, default=cov["threshold"], metavar="F",
                   help=f"warn (stderr) for a joint whose data reach less than this share of the class' velocity "
                        f"or acceleration (default {cov['threshold']:g}; record more with reachset excite)")


def options_of(args):
    """The :class:`~reachset_ros.workflows.identify.IdentifyOptions` of the command line (without
    the reader options and the output path, which :func:`run` adds after checking them)."""
    return IdentifyOptions(
        bags=tuple(args.bags), joints=parse_joints(args.joints), dt=args.dt, topics=topics_of(args),
        horizon=args.horizon, allow_weak_horizon=args.allow_weak_horizon,
        estimator=args.estimator, estimator_window=args.estimator_window,
        initial_state_set=bool(args.initial_state_set), centers=args.centers,
        alpha_lower=args.alpha_lower, cost=args.cost, detection_window=args.detection_window, method=args.method,
        inflation_rule=args.inflation_rule,
        validate=None if args.validate is None else tuple(args.validate),
        inflation_grid=None if args.inflation_grid is None else tuple(args.inflation_grid),
        inflation=args.inflation, calibrate=args.calibrate, calibrate_margin=args.calibrate_margin,
        fault_accel=args.fault_accel, class_qd_max=args.class_qd_max, class_qdd_max=args.class_qdd_max,
        coverage_threshold=args.coverage_threshold, command="reachset " + " ".join(sys.argv[1:]))


def run(args):
    opts = options_of(args)
    check_options(opts)
    out = check_out_path(args.out)
    fleet = fleet_of(args, refused=((args.method == "corollary1", "--method corollary1"),
                                    (args.calibrate is not None, "--calibrate")))
    opts = replace(opts, out=out, reader=reader_options(args))
    read = None if fleet is None else read_spec(args, args.joints, args.dt)
    with progress(args) as p:
        p.phase(f"reading {bag_count(args.bags)} and identifying the sets")
        res = identify(opts, fleet=fleet, fleet_read=read)
    for line in warning_lines(res.coverage or {}):
        print(f"reachset identify: {line}", file=sys.stderr)
    emit(args, res.to_json(), res.human())
