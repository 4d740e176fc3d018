"""Reachset-conformant identification from bags (Theorem 1, HiGHS LP): the workflow of
``reachset identify`` (see :mod:`reachset_ros.commands.identify` for the options).

:func:`identify` reads the bags (or sweeps them on a fleet, :mod:`reachset_ros.fleet`),
identifies every joint (:func:`identify_series`), optionally calibrates the inflation by
K-fold cross-validation (:func:`reachset_ros.conformance.calibration.cross_validate`,
:func:`calibrate_margin`) or on held-out bags (:func:`validate`), writes the model file and
returns an :class:`IdentifyResult` whose :meth:`~IdentifyResult.to_json` is the command's
``--json`` object.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .. import defaults
from ..bags import read_joint_series, segments_of
from ..bags.messages import JOINT_STATES, PLANT_INPUT
from ..conformance import envelope
from ..conformance import model as mdl
from ..conformance.calibration import cross_validate
from ..conformance.corollary1 import identify_corollary1
from ..conformance.estimators import Estimator
from ..conformance.identify import detection_cost, identify_quadratic, identify_sets, prefetch_solver, stable_horizon
from ..conformance.kernels import require_horizon, require_minimum_horizon
from ..conformance.theorem1 import Theorem1, deviation_extremes_many
from ..conformance.validation import detection_delay, validation_grid
from ..errors import ReachsetError
from ..systems.plant import lwa4p_joint_plant
from .coverage import class_coverage, series_motion

__all__ = ["DEFAULT_GRID", "IdentifyOptions", "IdentifyResult", "calibrate_margin", "check_options", "fit_envelope",
           "identify",
           "identify_series", "inflation_grid", "model_joint_sets", "run_ranges", "validate"]

defaults.register("identify", {
    "estimator": ("lsq", "the test cases' initial-state estimator (--estimator): 'lsq', a least-squares fit over "
                         "estimator.lsq_window + 1 samples, reads a step of the samples as less motion than 'fd' "
                         "(two samples). On the campaign's simulated training it lowered the minimum detectable "
                         "constant acceleration 1.3-1.8 times and bias 1.2-1.7 times with no stop in fault-free "
                         "running; on hidden simulated runs and on the real LWA-4P, 0 held-out violations and a "
                         "+6 rad/s^2 fault caught as soon or sooner on every joint (12-20 ms sooner in simulation; "
                         "docs/performance.md, 'The lsq estimator')"),
    "inflation_rule": ("largest", "how a calibrated inflation is applied (--inflation-rule): 'largest', each joint's "
                                  "value (cross-validated or validated, with the margin) replaced by the largest over "
                                  "the joints, or 'per-joint', each its own. On the real LWA-4P the per-joint values "
                                  "left held-out violations (arm_5: 145 ticks with --cost detection, 31 with one step "
                                  "of margin; arm_2 and arm_5: 1 and 6 with --cost linear) where the largest left none "
                                  "(docs/performance.md, 'Per-joint inflation'): folds do not see what no fold "
                                  "contains"),
    "cost": ("detection", "identify's objective (--cost): 'detection', the radii of the reachable output sets "
                          "summed over the horizon (conformance.identify.detection_cost), caught a +6 rad/s^2 "
                          "fault 2-5x sooner than the paper's 'linear' ||W||+||V|| at the same held-out "
                          "violations (0) on the real LWA-4P and the simulated arm (docs/performance.md, "
                          "benchmarks/detection_objective.py)"),
    "detection_window": (defaults.get("detection.within_s"),
                         "seconds (--detection-window): the 'detection' cost sums the radii over the steps "
                         "within this time of a test case's start, the time in which a fault must stop "
                         "(detection.within_s, issue 35.5); 0: the whole horizon (before 2026-11-28). On the "
                         "campaign's simulated training, 0.1 lowered the minimum detectable bias 1.2-1.8 times and "
                         "acceleration 1.1-1.35 times, with no stop in fault-free running; on the real LWA-4P, 0 "
                         "held-out violations both ways (docs/performance.md, 'Identification for detection')"),
}, owner=__name__)

defaults.register("identify.envelope", {
    "bins": (16, "cells per feature across the training data's range of the validated envelope "
                 "(conformance.envelope): on the real LWA-4P 16 left 0 % of the unseen family's violating ticks "
                 "inside and 0 % of the held-out ticks outside, 32 called 2.5 % of the held-out ticks outside "
                 "(docs/real-data.md, 'Validated envelope', benchmarks/envelope.py)"),
    "dilation": (1, "cells added around every occupied cell of the envelope's grids and at both ends of each "
                    "feature's axis (without: 8.9 % of the held-out ticks outside on the real LWA-4P)"),
    "grids": ([["q", "qd"], ["qd", "u"]], "the feature pairs with an occupancy grid in the envelope (position and "
                                          "velocity; velocity and plant input u_p); the hold is k*"),
}, owner=__name__)

#: inflations tried on validation bags or folds (``--inflation-grid``'s default)
DEFAULT_GRID = (0.01, 0.02, 0.05, 0.1, 0.2, 0.5, 1.0, 2.0, 5.0)


@dataclass(frozen=True, kw_only=True)
class IdentifyOptions:
    """What to identify and how (``reachset identify``'s options, as values).

    Attributes
    ----------
    bags : tuple of path
    joints : list of str or None
        None: every joint on both topics.
    dt : float
    topics : (str, str)
        Measurement and plant-input topic.
    reader : dict
        More :func:`reachset_ros.bags.read_joint_series` options (``effort``, ``joint_names``).
    horizon, allow_weak_horizon, estimator, estimator_window, initial_state_set, centers, alpha_lower,
    cost, method
        As the command's options.
    validate : tuple of path or None
        Held-out bags (``--validate``).
    inflation_grid : tuple of float or None
        ``--inflation-grid`` (None: :data:`DEFAULT_GRID`).
    inflation : float or None
    calibrate : int or None
        K of ``--calibrate K``.
    calibrate_margin : int
    fault_accel : float
    class_qd_max, class_qdd_max, coverage_threshold : float
        The reference class the data's coverage is measured against and the share below which a
        joint's data are thin (:mod:`reachset_ros.workflows.coverage`).
    out : path or None
        Where the model file is written.
    command : str
        The command line recorded in the model's provenance.
    """

    bags: tuple
    joints: list | None = None
    dt: float = 0.004
    topics: tuple = (JOINT_STATES, PLANT_INPUT)
    reader: dict = field(default_factory=dict)
    horizon: int = 125
    allow_weak_horizon: bool = False
    estimator: str = defaults.get("identify.estimator")
    estimator_window: int | None = None
    initial_state_set: bool = False
    centers: str = "zero"
    alpha_lower: tuple | None = None
    cost: str = defaults.get("identify.cost")
    detection_window: float = field(default_factory=lambda: defaults.get("identify.detection_window"))
    inflation_rule: str = defaults.get("identify.inflation_rule")
    method: str = "theorem1"
    validate: tuple | None = None
    inflation_grid: tuple | None = None
    inflation: float | None = None
    calibrate: int | None = None
    calibrate_margin: int = 0
    fault_accel: float = 5.0
    class_qd_max: float = field(default_factory=lambda: defaults.get("identify.coverage.qd_max"))
    class_qdd_max: float = field(default_factory=lambda: defaults.get("identify.coverage.qdd_max"))
    coverage_threshold: float = field(default_factory=lambda: defaults.get("identify.coverage.threshold"))
    out: Path | None = None
    command: str = ""
    envelope: bool = True       # record the validated envelope (issue 37; needs the series: not on a fleet)


@dataclass(frozen=True, kw_only=True)
class IdentifyResult:
    """What :func:`identify` computed.

    ``joints`` holds per joint the ``--json`` values (sets, checks, Remark 3's threshold and,
    when computed, ``inflation``/``calibration`` or ``validation``); ``model_sets`` the model
    file's :class:`~reachset_ros.conformance.model.JointSets`.
    """

    inflation: float                # the largest joint inflation (the model file's model-level value)
    joints: dict
    model_sets: dict
    data: dict
    cost: str
    method: str
    horizon: int
    minimum_horizon: int
    horizon_below_minimum: bool
    initial_state_set: bool
    calibrate: int | None = None
    calibrated_inflation: float | None = None
    calibration: dict | None = None
    validation_data: dict | None = None
    model: str | None = None
    inflations: dict = field(default_factory=dict)   # per joint, the inflation the model applies
    coverage: dict | None = None
    envelope: dict | None = None     # {"recorded": bool, ...}: the envelope the model records (issue 37)

    def to_json(self):
        """The ``reachset identify --json`` object."""
        out = {"inflation": self.inflation, "joints": self.joints, "data": self.data, "cost": self.cost,
               "method": self.method, "horizon": self.horizon, "minimum_horizon": self.minimum_horizon,
               "horizon_below_minimum": self.horizon_below_minimum, "initial_state_set": self.initial_state_set}
        if self.calibration is not None:
            out["calibrated_inflation"] = self.calibrated_inflation
        if self.validation_data is not None:
            out["validation_data"] = self.validation_data
        if self.model is not None:
            out["model"] = self.model
        if self.coverage is not None:
            out["coverage"] = self.coverage
            out["thin_coverage"] = sorted(n for n, c in self.coverage.items() if c["thin"])
        if self.envelope is not None:
            out["envelope"] = self.envelope
        return out

    def human(self):
        """The command's text output (one line per joint, then validation and calibration)."""
        js, horizon = self.joints, self.horizon
        lines = [f"{n}: alpha_w={v['alpha_w']} alpha_v={v['alpha_v']} test_cases={v['test_cases']} "
                 + (f"(sets stop changing at k={v['stable_horizon']})" if v["horizon_settled"] else
                    f"(sets still changing at k*={horizon}: Remark 3's threshold not reached)"
                    if v["horizon_settled"] is False else "") for n, v in js.items()]
        if self.horizon_below_minimum:
            lines.append(f"WEAK GUARANTEE: horizon {horizon} is below the plant's minimum {self.minimum_horizon} "
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
        if self.calibration is not None:
            for n, c in self.calibration.items():
                lines.append(f"{n}: cross-validated inflation {c['inflation']} ({self.calibrate} folds from "
                             f"{c['runs']} runs; per fold " + ", ".join(str(f["chosen_inflation"]) for f in c["folds"])
                             + ("; FLAGGED: some fold is violated at every grid value" if c["flagged"] else "") + ")")
        if self.validation_data is not None or self.calibration is not None:
            lines.append("model inflation per joint: " + ", ".join(f"{n} {x:g}" for n, x in self.inflations.items()))
        if self.envelope is not None and self.envelope.get("recorded"):
            e = self.envelope
            lines.append(f"validated envelope recorded: grids {', '.join('/'.join(g) for g in e['grids'])}, "
                         f"{e['bins']} cells per range, dilation {e['dilation']}, hold {e['hold']} ticks")
        return "\n".join(lines) + (f"\nmodel written to {self.model}" if self.model else "")


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


def run_ranges(stamps, dt):
    """Index ranges ``(start, stop)`` of the runs of sorted stamps: consecutive stamps within
    ``[0.5, 1.5] dt`` of each other (every sample counted, valid or not;
    :func:`reachset_ros.bags.segments_of`, the one definition of "consecutive"). The runs
    :func:`~reachset_ros.conformance.calibration.cross_validate` cuts into folds."""
    return segments_of(stamps, np.ones(len(stamps), dtype=bool), dt)


def identify_series(plant, est, series, horizon, *, centers="zero", alpha_lower=None, thm=None,
                    cost=None, method="theorem1", settle=True, devs=None, detection_window=None):
    """Identify each joint of ``series``; returns {name: (IdentifiedSets, Deviations, settled_k)}.

    ``cost``: ``"linear"``, ``"quadratic"`` or ``"detection"`` (None: the default
    ``identify.cost``); ``detection_window``: seconds of steps the detection cost sums (None:
    ``identify.detection_window``; 0: the whole horizon). ``settled_k`` (Remark 3) is computed with the linear cost; it is None for Corollary 1,
    which needs no horizon, and when ``settle`` is false (the folds of ``--calibrate``).
    ``devs``: the joints' deviation extremes when already reduced (a fleet run,
    :mod:`reachset_ros.fleet`; ``series`` is then not read by Theorem 1).
    """
    thm = thm or Theorem1.build(plant, horizon)
    cost = defaults.get("identify.cost") if cost is None else cost
    out = {}
    if devs is None:
        if method != "corollary1" and cost != "quadratic":
            prefetch_solver()                 # the LP solver's import overlaps the (GIL-free) sweep
        devs = deviation_extremes_many(plant, est, series, horizon, thm)
    # the detection cost depends on the plant, the rows and the window only: one vector for every joint
    cvec = detection_cost(plant, thm, window=detection_steps(plant.dt, detection_window)) \
        if cost == "detection" and method != "corollary1" else None
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
                    sets = identify_sets(plant, thm, dev, centers=centers, alpha_lower=alpha_lower, cost_vector=cvec)
                settled = (stable_horizon(plant, thm, dev, centers=centers, alpha_lower=alpha_lower)[0]
                           if settle else None)
        except ReachsetError as e:
            raise ReachsetError(f"joint {name}: {e}") from None
        out[name] = (sets, dev, settled)
    return out, thm


def detection_steps(dt, seconds=None):
    """The steps of ``dt`` seconds the detection cost sums
    (:func:`~reachset_ros.conformance.identify.detection_cost`'s ``window``) for ``seconds``
    (None: ``identify.detection_window``); None for 0: the horizon."""
    seconds = defaults.get("identify.detection_window") if seconds is None else float(seconds)
    if not (np.isfinite(seconds) and seconds >= 0):
        raise ReachsetError(f"--detection-window must be a finite number of seconds >= 0, got {seconds!r}")
    return None if seconds == 0 else max(1, int(round(seconds / dt)))


def model_joint_sets(sets, dev, horizon):
    """The model-file value (:class:`~reachset_ros.conformance.model.JointSets`) of one joint's
    identified sets ``sets`` with its deviations ``dev``."""
    return mdl.JointSets(alpha_w=tuple(sets.alpha_w.tolist()), alpha_v=tuple(sets.alpha_v.tolist()),
                         c_w=tuple(sets.c_w.tolist()), c_v=tuple(sets.c_v.tolist()), test_cases=dev.test_cases,
                         horizon=horizon)


def inflation_grid(values):
    """The inflations tried: ``values`` (None: :data:`DEFAULT_GRID`) and 0, sorted."""
    g = DEFAULT_GRID if values is None else tuple(values)
    if not all(np.isfinite(v) and v >= 0 for v in g):
        raise ReachsetError("--inflation-grid: values must be finite and >= 0")
    return sorted(set(float(v) for v in g) | {0.0})


def applied_inflations(values, rule):
    """The inflation each joint's sets are checked with, from each joint's calibrated
    ``values`` ({joint: float}): its own (``rule`` ``"per-joint"``, issue 35.1) or the largest
    over the joints (``"largest"``)."""
    if rule == "per-joint":
        return {n: float(v) for n, v in values.items()}
    if rule != "largest":
        raise ReachsetError(f"--inflation-rule must be 'largest' or 'per-joint', not {rule!r}")
    top = max(values.values(), default=0.0)
    return {n: float(top) for n in values}


def validate(plant, est, *, horizon, thm, joints, vseries, grid, fault_accel, rule="per-joint"):
    """Held-out validation of identified joints; returns ({name: inflation}, {name: validation
    dict}): each joint's inflation is its own smallest conformant grid value (issue 35.1), or
    the largest of them (``rule``, :func:`applied_inflations`), at which its test fault is
    injected."""
    per = {}
    for name, js in joints.items():
        s = vseries[name]
        try:
            rows, chosen, flagged = validation_grid(plant, thm, est, js, s.y, s.u, segments=s.segments,
                                                    horizon=horizon, grid=grid)
        except ReachsetError as e:
            raise ReachsetError(f"joint {name}: validation: {e}") from None
        per[name] = (rows, chosen, flagged)
    out = {}
    applied = applied_inflations({n: c for n, (_, c, _) in per.items()}, rule)
    for name, (rows, chosen, flagged) in per.items():
        s = vseries[name]
        for r in rows:
            t = r.pop("first_violation_tick")
            r["first_violation_ns"] = int(s.stamps[t]) if t >= 0 else None
        inflation = applied[name]                       # its own, or the largest (same grid for all joints)
        model_row = next(r for r in rows if r["inflation"] == inflation)
        try:
            fault = detection_delay(plant, thm, est, joints[name].xi(inflation), s.y, s.u, segments=s.segments,
                                    horizon=horizon, accel=fault_accel, dt=plant.dt)
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
    return {n: v["model_inflation"] for n, v in out.items()}, out


def check_options(o: IdentifyOptions):
    """Refuse options that exclude each other or are out of range (:class:`ReachsetError`,
    naming the command-line option), before any bag is read."""
    if o.horizon < 0:
        raise ReachsetError("--horizon must be >= 0")
    if o.dt <= 0:
        raise ReachsetError("--dt must be positive")
    require_minimum_horizon(lwa4p_joint_plant(dt=o.dt), o.horizon, o.allow_weak_horizon)
    Estimator.named(o.estimator, lwa4p_joint_plant(dt=o.dt), o.estimator_window)   # --estimator-window
    if not np.isfinite(o.fault_accel):
        raise ReachsetError("--fault-accel must be finite")
    detection_steps(o.dt, o.detection_window)      # --detection-window in range
    if o.inflation_grid is not None and o.validate is None and o.calibrate is None:
        raise ReachsetError("--inflation-grid needs --validate or --calibrate")
    if o.calibrate is not None:
        if o.validate is not None:
            raise ReachsetError("--calibrate and --validate exclude each other (each calibrates the inflation)")
        if o.inflation is not None:
            raise ReachsetError("--calibrate and --inflation exclude each other (--calibrate calibrates the inflation)")
        if o.calibrate < 2:
            raise ReachsetError(f"--calibrate needs K >= 2 folds, got {o.calibrate}")
        if o.method == "corollary1":
            raise ReachsetError("--calibrate works with --method theorem1 only")
    if o.calibrate_margin != 0:
        if o.calibrate is None:
            raise ReachsetError("--calibrate-margin needs --calibrate")
        if o.calibrate_margin < 0:
            raise ReachsetError(f"--calibrate-margin must be >= 0 grid steps, got {o.calibrate_margin}")
    if o.inflation is not None:
        if o.validate is not None:
            raise ReachsetError("--inflation and --validate exclude each other (--validate calibrates the inflation)")
        if not (np.isfinite(o.inflation) and o.inflation >= 0):
            raise ReachsetError(f"--inflation must be finite and >= 0, got {o.inflation}")
    inflation_grid(o.inflation_grid)
    for opt, v in (("--class-qd-max", o.class_qd_max), ("--class-qdd-max", o.class_qdd_max)):
        if not (np.isfinite(v) and v > 0):
            raise ReachsetError(f"{opt} must be finite and > 0, got {v}")
    if not (np.isfinite(o.coverage_threshold) and 0 <= o.coverage_threshold <= 1):
        raise ReachsetError(f"--coverage-threshold must be in [0, 1], got {o.coverage_threshold}")


@dataclass(frozen=True, kw_only=True)
class _Data:
    """The identification data: the series (single process) or the swept extremes (fleet)."""

    series: dict | None
    devs: dict | None
    report: object
    sha256: tuple | None = None
    motion: dict | None = None      # a fleet's merged motion extremes (coverage of the class)


def _read(o: IdentifyOptions, *, plant, est, thm, fleet, fleet_read):
    """The bags' series, or their sweep on ``fleet`` (merged exactly: the same devs, to the bit)."""
    if fleet is None:
        series, report = read_joint_series([Path(b) for b in o.bags], o.joints, o.dt, o.topics, **(o.reader or {}))
        require_horizon(series, est.history, o.horizon, o.bags)
        return _Data(series=series, devs=None, report=report)
    from .. import fleet as fl        # lazy: the fleet's modules (and the synthesis') cost 0.1 s of start-up
    with fleet:
        swept = fl.extremes(fleet, o.bags, fleet_read, fl.SweepSpec(plant, est, o.horizon, thm))
    return _Data(series=None, devs=swept.devs, report=swept.report, sha256=swept.sha256, motion=swept.motion)


def _joint_json(sets, dev, settled, horizon):
    return {"alpha_w": sets.alpha_w.tolist(), "alpha_v": sets.alpha_v.tolist(),
            "c_w": sets.c_w.tolist(), "c_v": sets.c_v.tolist(),
            "test_cases": dev.test_cases, "horizon": horizon,
            "checks": dev.checks, "stable_horizon": settled,
            "horizon_settled": None if settled is None else bool(settled < horizon),
            "soundness_inflation": float(sets.soundness_bump),
            "objective": float(sets.cost)}


def _calibrate(o: IdentifyOptions, *, plant, est, thm, series, grid):
    """``--calibrate K``: per joint the cross-validated inflation (Remark: folds of whole runs)."""
    def fit(sub):
        res, _ = identify_series(plant, est, sub, o.horizon, centers=o.centers, alpha_lower=o.alpha_lower, thm=thm,
                                 cost=o.cost, method=o.method, settle=False, detection_window=o.detection_window)
        return {n: model_joint_sets(st, dv, o.horizon) for n, (st, dv, _) in res.items()}
    runs = {n: run_ranges(s.stamps, s.dt) for n, s in series.items()}
    return cross_validate(plant, est, series, horizon=o.horizon, k=o.calibrate, grid=grid, identify=fit, thm=thm,
                          runs=runs)


def _provenance(o: IdentifyOptions, *, data, grid, calib, inflation):
    prov = mdl.provenance(o.bags, o.command, data.sha256)
    prov["input"] = data.report.input
    if o.validate:
        prov["validation"] = {"bags": mdl.provenance(o.validate, "")["bags"],
                              "inflation_grid": grid, "fault_accel": o.fault_accel}
    if calib is not None:
        prov["calibration"] = {"folds": o.calibrate, "inflation_grid": grid,
                               "inflation": {n: c["inflation"] for n, c in calib.items()},
                               "margin_steps": o.calibrate_margin, "model_inflation": max(inflation.values()),
                               "model_inflations": dict(inflation),
                               "flagged": [n for n, c in calib.items() if c["flagged"]]}
    return prov


def _with_calibration(m, o: IdentifyOptions, *, grid, calib, calibrated):
    """``m`` with the record of the sets its inflation was calibrated on (issue 34.11,
    :func:`reachset_ros.conformance.model.with_calibration`): ``--calibrate`` (the fold sets
    identified as these were, by ``rule``) or ``--validate`` (these very sets checked on
    held-out bags); unchanged when the inflation was given."""
    rule = {"sets": "identify", "cost": o.cost, "centers": o.centers}
    if o.cost == "detection":
        rule["detection_window_s"] = float(o.detection_window)
    if calib is not None:
        return mdl.with_calibration(m, method="cross_validation", folds=int(o.calibrate), inflation_grid=list(grid),
                                    calibrated_inflation=float(calibrated), margin_steps=int(o.calibrate_margin),
                                    per_joint={n: float(c["inflation"]) for n, c in calib.items()}, rule=rule)
    if o.validate:
        return mdl.with_calibration(m, method="held_out_bags", inflation_grid=list(grid),
                                    bags=[str(b) for b in o.validate], rule=rule)
    return m


def _envelope(o: IdentifyOptions, data):
    """The validated envelope of the identification data (:func:`reachset_ros.conformance.envelope.fit`,
    hold k*) and its ``--json`` summary (None and ``recorded: false`` when not asked). On a fleet the
    bags are read here once more (the fleet reduced them to extremes): the same envelope as one process."""
    if not o.envelope:
        return None, {"recorded": False, "reason": "not asked for"}
    series = data.series
    if series is None:
        series, _ = read_joint_series([Path(b) for b in o.bags], o.joints, o.dt, o.topics, **(o.reader or {}))
    return fit_envelope(series, horizon=o.horizon)


def fit_envelope(series, *, horizon):
    """The validated envelope a model records of its identification data ``series`` ({joint:
    JointSeries}): :func:`reachset_ros.conformance.envelope.fit` with the defaults
    ``identify.envelope`` and hold ``horizon`` (k*), and its ``--json`` summary. The one fit of
    every command that identifies sets from data (``identify``; ``synthesize``, all modes)."""
    env = envelope.fit(series, bins=defaults.get("identify.envelope.bins"),
                       dilation=defaults.get("identify.envelope.dilation"), hold=horizon,
                       grids=[tuple(g) for g in defaults.get("identify.envelope.grids")])
    return env, {"recorded": True, "bins": env.bins, "dilation": env.dilation, "hold": env.hold,
                 "grids": [list(g) for g in env.grids], "ticks": {n: j.ticks for n, j in env.joints.items()}}


class _Outcome:
    """The value of ``fn()`` computed now, or the exception it raised, handed over by :meth:`get`."""

    def __init__(self, fn):
        try:
            self.value, self.error = fn(), None
        except Exception as e:  # noqa: BLE001 (re-raised unchanged by get)
            self.value, self.error = None, e

    def get(self):
        if self.error is not None:
            raise self.error
        return self.value


def _sweep_started(o: IdentifyOptions, *, plant, est, thm, series):
    """The joints' Theorem-1 sweep (:func:`deviation_extremes_many`) started in a thread, or None
    (a fleet swept already). Its compiled kernel releases the GIL: the caller computes the
    coverage and the envelope meanwhile, and the LP solver is imported (:func:`prefetch_solver`)."""
    if series is None:
        return None
    from concurrent.futures import ThreadPoolExecutor
    if o.method != "corollary1" and o.cost != "quadratic":
        prefetch_solver()
    pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="sweep")
    future = pool.submit(deviation_extremes_many, plant, est, series, o.horizon, thm)
    pool.shutdown(wait=False)       # the thread ends with its one task
    return future


def identify(options: IdentifyOptions, *, fleet=None, fleet_read=None):
    """Identify a reachset-conformant model from bags (``reachset identify``).

    Parameters
    ----------
    options : IdentifyOptions
    fleet : reachset_ros.fleet.cluster.Fleet, optional
        A fleet (not yet entered): the Theorem-1 sweep runs one task per bag on it, read as
        ``fleet_read`` (:class:`~reachset_ros.fleet.ReadSpec`) says; the model is the
        single-process one to the bit (provenance aside). ``--calibrate`` and Corollary 1 need
        the whole series: the caller refuses them with a fleet.

    Returns
    -------
    IdentifyResult
        The model file is written to ``options.out`` (when given) once everything is computed.
    """
    o = options
    check_options(o)
    plant = lwa4p_joint_plant(dt=o.dt)
    k_min, weak = require_minimum_horizon(plant, o.horizon, o.allow_weak_horizon)
    grid = inflation_grid(o.inflation_grid)
    est = Estimator.named(o.estimator, lwa4p_joint_plant(dt=o.dt), o.estimator_window)
    if o.initial_state_set and o.method == "corollary1":
        raise ReachsetError("--initial-state-set works with --method theorem1 only")
    thm = Theorem1.build(plant, o.horizon, est if o.initial_state_set else None)
    data = _read(o, plant=plant, est=est, thm=thm, fleet=fleet, fleet_read=fleet_read)
    vseries = vreport = None
    if o.validate:
        vseries, vreport = read_joint_series([Path(b) for b in o.validate], list(data.series or data.devs), o.dt,
                                             o.topics, **(o.reader or {}))
        require_horizon(vseries, est.history, o.horizon, o.validate)
    sweep = _sweep_started(o, plant=plant, est=est, thm=thm, series=data.series)
    # while the sweep runs (its kernel without the GIL): the coverage and the envelope, whose
    # errors are raised where they were computed before (after the sweep's and the LPs')
    motion = _Outcome(lambda: data.motion if data.series is None else series_motion(data.series, o.bags))
    envelope_ = _Outcome(lambda: _envelope(o, data))
    results, thm = identify_series(plant, est, data.series, o.horizon, centers=o.centers, alpha_lower=o.alpha_lower,
                                   thm=thm, cost=o.cost, method=o.method,
                                   devs=data.devs if sweep is None else sweep.result(),
                                   detection_window=o.detection_window)
    joints = {n: model_joint_sets(sets, dev, o.horizon) for n, (sets, dev, _) in results.items()}
    js = {n: _joint_json(sets, dev, settled, o.horizon) for n, (sets, dev, settled) in results.items()}
    motion = motion.get()
    cov = class_coverage(motion, qd_max=o.class_qd_max, qdd_max=o.class_qdd_max, threshold=o.coverage_threshold)
    inflations = {n: 0.0 if o.inflation is None else float(o.inflation) for n in joints}   # --inflation F: all
    calib = calibrated = None
    if o.calibrate is not None:
        calib = _calibrate(o, plant=plant, est=est, thm=thm, series=data.series, grid=grid)
        # per joint (issue 35.1): its own cross-validated value, --calibrate-margin steps above it
        inflations = applied_inflations({n: calibrate_margin(c["inflation"], grid, o.calibrate_margin)
                                         if o.calibrate_margin else float(c["inflation"]) for n, c in calib.items()},
                                        o.inflation_rule)
        for name, c in calib.items():
            js[name]["inflation"] = inflations[name]          # the value the model applies to this joint
            js[name]["calibration"] = c                       # c["inflation"]: cross-validated, before any margin
        calibrated = max(c["inflation"] for c in calib.values())
    if vseries is not None:
        inflations, val = validate(plant, est, horizon=o.horizon, thm=thm, joints=joints, vseries=vseries, grid=grid,
                                   fault_accel=o.fault_accel, rule=o.inflation_rule)
        for name, v in val.items():
            js[name]["validation"] = v
            js[name]["inflation"] = inflations[name]
    env, env_json = envelope_.get()
    model = None
    if o.out is not None:
        prov = _provenance(o, data=data, grid=grid, calib=calib, inflation=inflations)
        m = mdl.ConformanceModel(plant=plant, plant_spec={"kind": "lwa4p_joint", "dt": o.dt}, estimator=est,
                                 horizon=o.horizon, joints=joints, provenance=prov,
                                 minimum_horizon=k_min, horizon_below_minimum=weak,
                                 initial_state_set=bool(o.initial_state_set),
                                 input_source=mdl.input_source_of((o.reader or {}).get("effort")),
                                 envelope=env).with_inflation(inflations)
        mdl.save(_with_calibration(m, o, grid=grid, calib=calib, calibrated=calibrated), o.out)
        model = str(o.out)
    return IdentifyResult(inflation=max(inflations.values()), inflations=inflations, joints=js, model_sets=joints, data=data.report.as_dict(), cost=o.cost,
                          method=o.method, horizon=o.horizon, minimum_horizon=k_min, horizon_below_minimum=weak,
                          initial_state_set=bool(o.initial_state_set), calibrate=o.calibrate,
                          calibrated_inflation=calibrated, calibration=calib,
                          validation_data=None if vseries is None else vreport.as_dict(), model=model,
                          coverage=cov, envelope=env_json)
