"""``reachset identify``: reachset-conformant identification (Theorem 1, HiGHS LP).

Options beyond the paper's separate approach:

- ``--cost quadratic``: minimise ||G'_W diag a_W||_F^2 + ||G'_V diag a_V||_F^2 under the same
  Theorem-1 constraints (OSQP through cvxpy, then made sound in floating point).
- ``--method corollary1``: the conservative state-based variant (paper Corollary 1); it
  needs an estimator consistent with the model and fails with a message naming the test
  case and state direction otherwise (always on noisy LWA-4P data with ``fd``).
- ``--validate BAG...``: inflation calibration on held-out bags. Each joint's identified sets
  are checked on the validation bags (``reachset check``'s arithmetic) with the sets scaled
  by 1 + inflation for inflation 0 and each ``--inflation-grid`` value; per joint the
  smallest grid value with no held-out violation is chosen (the largest grid value,
  flagged, if none). The model's ``inflation`` field (one value for all joints, as the
  monitor uses it) is the largest per-joint choice. For that inflation a test fault is
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

import numpy as np

from ..conformance import model as mdl
from ..conformance.calibration import cross_validate
from ..conformance.corollary1 import identify_corollary1
from ..conformance.estimators import ESTIMATORS, Estimator
from ..conformance.identify import identify_quadratic, identify_sets, stable_horizon
from ..conformance.kernels import require_minimum_horizon
from ..conformance.theorem1 import Theorem1, deviation_extremes_many
from ..conformance.validation import detection_delay, validation_grid
from ..errors import ReachsetError
from ..systems.plant import lwa4p_joint_plant
from . import emit
from ._bagargs import (add_bag_arguments, add_fleet_arguments, check_out_path, fleet_of, load_series, read_spec,
                       reader_options, require_horizon, topics_of)

NAME = "identify"
HELP = "identify a reachset-conformant model (min ||W||+||V||, Theorem 1) from bags"

DEFAULT_GRID = (0.01, 0.02, 0.05, 0.1, 0.2, 0.5, 1.0, 2.0, 5.0)


def add_arguments(p):
    add_bag_arguments(p)
    add_fleet_arguments(p)
    p.add_argument("--horizon", type=int, default=125, help="k*, ticks (default 125, the paper's; at least "
                                                             "the plant's minimum, 2 for the LWA-4P joint)")
    p.add_argument("--allow-weak-horizon", action="store_true",
                   help="accept a horizon below the plant's minimum (a weaker guarantee: some alpha is not "
                        "constrained by the data); recorded in the model file")
    p.add_argument("--out", help="write the model YAML here")
    p.add_argument("--estimator", default="fd", choices=sorted(ESTIMATORS),
                   help="initial-state estimator of the test cases (stored in the model)")
    p.add_argument("--initial-state-set", action="store_true",
                   help="Theorem 1 with the estimator's initial-state error as a set made of the same noise and "
                        "disturbances (not charged to the test case's W and V; much smaller sets; docs/theory.md); "
                        "stored in the model, which the monitor then checks the same way")
    p.add_argument("--centers", default="zero", choices=["zero", "free"],
                   help="set centers fixed at 0 (paper) or identified")
    p.add_argument("--alpha-lower", type=float, nargs="+", metavar="F",
                   help="lower bounds on [alpha_W..., alpha_V...] (e.g. encoder resolution)")
    p.add_argument("--dt", type=float, default=0.004, help="sampling time, s")
    p.add_argument("--cost", default="linear", choices=["linear", "quadratic"],
                   help="linear: ||W||+||V|| (paper, HiGHS); quadratic: squared Frobenius norm of the "
                        "scaled generators (OSQP)")
    p.add_argument("--method", default="theorem1", choices=["theorem1", "corollary1"],
                   help="Theorem 1 (output-based, default) or Corollary 1 (state-based, conservative)")
    p.add_argument("--validate", nargs="+", metavar="VBAG",
                   help="held-out bags: report violation rates and calibrate the model's inflation")
    p.add_argument("--inflation-grid", type=float, nargs="+", metavar="F",
                   help=f"inflations tried on the validation bags (default {' '.join(map(str, DEFAULT_GRID))})")
    p.add_argument("--inflation", type=float, default=None, metavar="F",
                   help="the model's inflation: the monitor checks the sets scaled by 1 + F (default 0; "
                        "with --validate it is calibrated instead, so the two exclude each other)")
    p.add_argument("--calibrate", type=int, default=None, metavar="K",
                   help="calibrate the inflation by K-fold cross-validation inside the given bags (folds of whole "
                        "runs: stretches of consecutive stamps); per joint the largest over the folds of the "
                        "smallest --inflation-grid value at which the fold is conformant with sets identified on "
                        "the other folds; the model stores the largest over the joints")
    p.add_argument("--calibrate-margin", type=int, default=0, metavar="N",
                   help="with --calibrate: store the --inflation-grid value N steps above the cross-validated "
                        "one (default 0). The folds calibrate for data as long as a fold; a run many folds long "
                        "sees more (docs/reliability.md, run-length margin)")
    p.add_argument("--fault-accel", type=float, default=5.0, metavar="A",
                   help="test fault for the detection delay: constant acceleration, rad/s^2 (default 5)")


def calibrate_margin(calibrated, grid, steps):
    """The inflation ``steps`` grid values above the cross-validated one (``--calibrate-margin``).

    Cross-validation (:func:`reachset_ros.conformance.calibration.cross_validate`) finds the
    inflation that the worst of K held-out folds needed. A monitored run M folds long is M
    more draws of the same kind: under exchangeability the chance that all of them stay within
    the worst of the K folds is K / (K + M) (for the fault campaign's 6 folds of 40 s and a
    48-min run, 8 %), so a long run needs a margin that the folds cannot measure. This is a
    chosen margin, not a calibrated one: above the grid's largest value the largest is kept
    and the caller is told so by the returned value equalling it.
    """
    values = sorted({0.0, *map(float, grid)})
    above = [v for v in values if v > calibrated]
    return above[min(steps, len(above)) - 1] if above else values[-1]


def identify_series(plant, est, series, horizon, centers="zero", alpha_lower=None, thm=None,
                    cost="linear", method="theorem1", settle=True, devs=None):
    """Identify each joint of ``series``; returns {name: (IdentifiedSets, Deviations, settled_k)}.

    ``settled_k`` (Remark 3) is computed with the linear cost; it is None for Corollary 1,
    which needs no horizon, and when ``settle`` is false (the folds of ``--calibrate``).
    ``devs``: the joints' deviation extremes when already reduced (a fleet run,
    :mod:`reachset_ros.fleet`; ``series`` is then not read by Theorem 1).
    """
    thm = thm or Theorem1.build(plant, horizon)
    out = {}
    if devs is None:
        devs = deviation_extremes_many(plant, est, series, horizon, thm)
    for name, dev in devs.items():
        try:
            if method == "corollary1":
                s = series[name]
                sets = identify_corollary1(plant, est, s.y, s.u, s.segments, centers=centers,
                                           alpha_lower=alpha_lower, horizon=horizon, thm=thm)
                settled = None
            else:
                if cost == "quadratic":
                    sets = identify_quadratic(plant, thm, dev, centers=centers, alpha_lower=alpha_lower)
                else:
                    sets = identify_sets(plant, thm, dev, centers=centers, alpha_lower=alpha_lower)
                settled = (stable_horizon(plant, thm, dev, centers=centers, alpha_lower=alpha_lower)[0]
                           if settle else None)
        except ReachsetError as e:
            raise ReachsetError(f"joint {name}: {e}") from None
        out[name] = (sets, dev, settled)
    return out, thm


def _joint_sets(sets, dev, horizon):
    """The model-file value of one joint's identified sets."""
    return mdl.JointSets(tuple(sets.alpha_w.tolist()), tuple(sets.alpha_v.tolist()), tuple(sets.c_w.tolist()),
                         tuple(sets.c_v.tolist()), dev.test_cases, horizon)


def _grid(values):
    g = DEFAULT_GRID if values is None else tuple(values)
    if not all(np.isfinite(v) and v >= 0 for v in g):
        raise ReachsetError("--inflation-grid: values must be finite and >= 0")
    return sorted(set(float(v) for v in g) | {0.0})


def validate(plant, est, horizon, thm, joints, vseries, grid, fault_accel):
    """Held-out validation of identified joints; returns (inflation, {name: validation dict})."""
    per = {}
    for name, js in joints.items():
        s = vseries[name]
        try:
            rows, chosen, flagged = validation_grid(plant, thm, est, js, s.y, s.u, s.segments,
                                                    horizon, grid)
        except ReachsetError as e:
            raise ReachsetError(f"joint {name}: validation: {e}") from None
        per[name] = (rows, chosen, flagged)
    inflation = max(c for _, c, _ in per.values())
    out = {}
    for name, (rows, chosen, flagged) in per.items():
        s = vseries[name]
        for r in rows:
            t = r.pop("first_violation_tick")
            r["first_violation_ns"] = int(s.stamps[t]) if t >= 0 else None
        model_row = next(r for r in rows if r["inflation"] == inflation)   # same grid for all joints
        try:
            fault = detection_delay(plant, thm, est, joints[name].xi(inflation), s.y, s.u, s.segments,
                                    horizon, fault_accel, plant.dt)
        except ReachsetError as e:
            raise ReachsetError(f"joint {name}: validation: {e}") from None
        fault["onset_ns"] = int(s.stamps[fault["onset_tick"]])
        fault["kind"] = "constant acceleration added to the measured position: y += accel/2 * t^2"
        out[name] = {"checked_ticks": rows[0]["checked_ticks"],
                     "test_cases": rows[0]["test_cases"],
                     "at_zero": rows[0],
                     "grid": rows,
                     "chosen_inflation": chosen,
                     "flagged": flagged,
                     "model_inflation": inflation,
                     "at_model_inflation": {k: model_row[k] for k in
                                            ("violating_ticks", "violation_rate", "violated_test_cases")},
                     "fault": fault}
    return inflation, out


def run(args):
    if args.horizon < 0:
        raise ReachsetError("--horizon must be >= 0")
    if args.dt <= 0:
        raise ReachsetError("--dt must be positive")
    plant = lwa4p_joint_plant(dt=args.dt)
    k_min, weak = require_minimum_horizon(plant, args.horizon, args.allow_weak_horizon)
    if not np.isfinite(args.fault_accel):
        raise ReachsetError("--fault-accel must be finite")
    if args.inflation_grid is not None and args.validate is None and args.calibrate is None:
        raise ReachsetError("--inflation-grid needs --validate or --calibrate")
    if args.calibrate is not None:
        if args.validate is not None:
            raise ReachsetError("--calibrate and --validate exclude each other (each calibrates the inflation)")
        if args.inflation is not None:
            raise ReachsetError("--calibrate and --inflation exclude each other (--calibrate calibrates the inflation)")
        if args.calibrate < 2:
            raise ReachsetError(f"--calibrate needs K >= 2 folds, got {args.calibrate}")
        if args.method == "corollary1":
            raise ReachsetError("--calibrate works with --method theorem1 only")
    if args.calibrate_margin != 0:
        if args.calibrate is None:
            raise ReachsetError("--calibrate-margin needs --calibrate")
        if args.calibrate_margin < 0:
            raise ReachsetError(f"--calibrate-margin must be >= 0 grid steps, got {args.calibrate_margin}")
    if args.inflation is not None:
        if args.validate is not None:
            raise ReachsetError("--inflation and --validate exclude each other (--validate calibrates the inflation)")
        if not (np.isfinite(args.inflation) and args.inflation >= 0):
            raise ReachsetError(f"--inflation must be finite and >= 0, got {args.inflation}")
    grid = _grid(args.inflation_grid)
    out = check_out_path(args.out)
    est = Estimator.named(args.estimator, lwa4p_joint_plant(dt=args.dt))
    fleet = fleet_of(args, refused=((args.method == "corollary1", "--method corollary1"),
                                    (args.calibrate is not None, "--calibrate")))
    if args.initial_state_set and args.method == "corollary1":
        raise ReachsetError("--initial-state-set works with --method theorem1 only")
    thm = Theorem1.build(plant, args.horizon, est if args.initial_state_set else None)
    opts = reader_options(args)
    devs = series = None
    if fleet is None:
        series, report = load_series(args.bags, args.joints, args.dt, topics=topics_of(args), options=opts)
        require_horizon(series, est.history, args.horizon, args.bags)
    else:                      # the sweep per bag on Dask, merged exactly (the same devs, to the bit)
        from .. import fleet as fl
        with fleet:
            swept = fl.extremes(fleet, args.bags, read_spec(args, args.joints, args.dt),
                                fl.SweepSpec(plant, est, args.horizon, thm))
        devs, report = swept.devs, swept.report
    vseries = vreport = None
    if args.validate:
        vseries, vreport = load_series(args.validate, list(series or devs), args.dt, topics=topics_of(args),
                                       options=opts)
        require_horizon(vseries, est.history, args.horizon, args.validate)
    results, thm = identify_series(plant, est, series, args.horizon, args.centers, args.alpha_lower, thm=thm,
                                   cost=args.cost, method=args.method, devs=devs)
    joints, js = {}, {}
    for name, (sets, dev, settled) in results.items():
        joints[name] = _joint_sets(sets, dev, args.horizon)
        js[name] = {"alpha_w": sets.alpha_w.tolist(), "alpha_v": sets.alpha_v.tolist(),
                    "c_w": sets.c_w.tolist(), "c_v": sets.c_v.tolist(),
                    "test_cases": dev.test_cases, "horizon": args.horizon,
                    "checks": dev.checks, "stable_horizon": settled,
                    "horizon_settled": None if settled is None else bool(settled < args.horizon),
                    "soundness_inflation": float(sets.soundness_bump),
                    "objective": float(sets.cost)}
    inflation = 0.0 if args.inflation is None else float(args.inflation)
    calib = None
    if args.calibrate is not None:
        def fit(sub):
            res, _ = identify_series(plant, est, sub, args.horizon, args.centers, args.alpha_lower, thm=thm,
                                     cost=args.cost, method=args.method, settle=False)
            return {n: _joint_sets(st, dv, args.horizon) for n, (st, dv, _) in res.items()}
        calib = cross_validate(plant, est, series, args.horizon, args.calibrate, grid, fit, thm)
        for name, c in calib.items():
            js[name]["inflation"] = c["inflation"]
            js[name]["calibration"] = c
        inflation = calibrated = max(c["inflation"] for c in calib.values())
        if args.calibrate_margin:
            inflation = calibrate_margin(calibrated, grid, args.calibrate_margin)
    result = {"inflation": inflation, "joints": js, "data": report.as_dict(), "cost": args.cost, "method": args.method,
              "horizon": args.horizon, "minimum_horizon": k_min, "horizon_below_minimum": weak,
              "initial_state_set": bool(args.initial_state_set)}
    if calib is not None:
        result["calibrated_inflation"] = calibrated
    if vseries is not None:
        inflation, val = validate(plant, est, args.horizon, thm, joints, vseries, grid, args.fault_accel)
        for name, v in val.items():
            js[name]["validation"] = v
        result["inflation"] = inflation
        result["validation_data"] = vreport.as_dict()
    if out is not None:
        prov = mdl.provenance(args.bags, "reachset " + " ".join(sys.argv[1:]),
                              None if devs is None else swept.sha256)
        prov["input"] = report.input
        if args.validate:
            prov["validation"] = {"bags": mdl.provenance(args.validate, "")["bags"],
                                  "inflation_grid": grid, "fault_accel": args.fault_accel}
        if calib is not None:
            prov["calibration"] = {"folds": args.calibrate, "inflation_grid": grid,
                                   "inflation": {n: c["inflation"] for n, c in calib.items()},
                                   "margin_steps": args.calibrate_margin, "model_inflation": inflation,
                                   "flagged": [n for n, c in calib.items() if c["flagged"]]}
        m = mdl.ConformanceModel(plant, {"kind": "lwa4p_joint", "dt": args.dt}, est, args.horizon, joints,
                                 inflation, prov, k_min, weak, bool(args.initial_state_set))
        mdl.save(m, out)
        result["model"] = str(out)
    lines = [f"{n}: alpha_w={v['alpha_w']} alpha_v={v['alpha_v']} test_cases={v['test_cases']} "
             + (f"(sets stop changing at k={v['stable_horizon']})" if v["horizon_settled"] else
                f"(sets still changing at k*={args.horizon}: Remark 3's threshold not reached)"
                if v["horizon_settled"] is False else "") for n, v in js.items()]
    if weak:
        lines.append(f"WEAK GUARANTEE: horizon {args.horizon} is below the plant's minimum {k_min} "
                     "(--allow-weak-horizon)")
    for n, v in js.items():
        val = v.get("validation")
        if val:
            f = val["fault"]
            lines.append(
                f"{n}: held-out violation rate {val['at_zero']['violation_rate']:.3g} at inflation 0; "
                f"smallest conformant inflation {val['chosen_inflation']}"
                + (" (FLAGGED: no grid value is conformant)" if val["flagged"] else "")
                + f"; {f['accel']} rad/s^2 fault at inflation {val['model_inflation']} "
                + (f"detected after {f['delay_ticks']} ticks" if f["detected"] else "NOT detected"))
    if calib is not None:
        for n, c in calib.items():
            lines.append(f"{n}: cross-validated inflation {c['inflation']} ({args.calibrate} folds of {c['runs']} runs; "
                         "per fold " + ", ".join(str(f["chosen_inflation"]) for f in c["folds"])
                         + ("; FLAGGED: some fold is violated at every grid value" if c["flagged"] else "") + ")")
    if vseries is not None or calib is not None:
        lines.append(f"model inflation: {inflation}")
    emit(args, result, "\n".join(lines) + (f"\nmodel written to {out}" if out else ""))
