"""Calibrate a model's inflation on the sets it holds (issue 34.11).

``identify --calibrate K`` calibrates the inflation of identify's sets (min ||W||+||V||). A
synthesis keeps the Theorem-1 constraints of the same data but picks other sets (the ones
that minimise its ||R*_e||, paper eq. 10); the monitor then checks the synthesis' sets, and an
inflation calibrated on identify's says nothing about them. :func:`calibrate_model` calibrates
the inflation of any model on the sets it holds, with the rule that made them:

* cross-validation (``folds``, :func:`reachset_ros.conformance.calibration.cross_validate`):
  per fold, the sets are made from the other folds by the model's own rule
  (:func:`fold_rule`: identify's min ||W||+||V|| for a model without gains; for a synthesis,
  min ||R*_e|| of the model's fixed gains over the fold's Theorem-1 polytope, the synthesis'
  inner linear programme without its R*_u constraint) and checked on the fold with ``reachset
  check``'s arithmetic;
* held-out bags (``validate``): the model's sets themselves are checked on bags they were not
  made from (:func:`reachset_ros.workflows.identify.validate`).

The result records the calibration with the digest of exactly these sets
(:func:`reachset_ros.conformance.model.with_calibration`); every reader refuses the record on
other sets.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .. import defaults
from ..bags import read_joint_series
from ..bags.messages import JOINT_STATES, PLANT_INPUT
from ..conformance import model as mdl
from ..conformance.calibration import cross_validate
from ..conformance.identify import identify_sets, set_norm_cost
from ..conformance.kernels import require_horizon
from ..conformance.theorem1 import deviation_extremes_many
from ..errors import ReachsetError
from ..systems.closedloop import close_loop, radius_coefficients
from ..systems.gains import Gains
from .identify import applied_inflations, calibrate_margin, inflation_grid, model_joint_sets, run_ranges, validate

__all__ = ["CalibratedModel", "calibrate_model", "fold_rule"]


@dataclass(frozen=True, kw_only=True)
class CalibratedModel:
    """What :func:`calibrate_model` computed: the ``model`` with its calibrated inflation and
    record, the inflation the folds or bags needed (``calibrated``, before any margin) and the
    per-joint details (``joints``)."""

    model: mdl.ConformanceModel
    calibrated: float               # the largest over the joints
    joints: dict
    rule: dict
    calibrated_per_joint: dict = None   # {joint: inflation the folds or bags needed}, before margin and floor


def _re_weights(model, name):
    """Per-alpha weights turning identify's cost ||W||+||V|| into the synthesis' ||R*_e|| of
    ``name``'s gains (paper eq. 10's objective at fixed gains; linear in alpha,
    :func:`reachset_ros.systems.closedloop.radius_coefficients`)."""
    obs, ctrl = Gains.from_model(model.joints[name].gains).build(model.plant.dt)
    cl = close_loop(model.plant, obs, ctrl)
    Kw, Kv = radius_coefficients(cl)
    ne = cl.n_error
    ce = 2.0 * np.concatenate([Kw[:ne].sum(axis=0), Kv[:ne].sum(axis=0)])
    cn = set_norm_cost(model.plant)
    return np.where(cn > 0, ce / np.where(cn > 0, cn, 1.0), 0.0)


def fold_rule(model):
    """The rule that made ``model``'s sets, applied to one fold's training data.

    Returns ``(fit, rule)``: ``fit({name: series}) -> {name: JointSets}`` (for
    :func:`~reachset_ros.conformance.calibration.cross_validate`) and a description recorded
    in the calibration record. A joint with gains (a synthesis) gets min ||R*_e|| of its gains
    over the Theorem-1 polytope; a joint without, identify's min ||W||+||V||; centres free when
    the model's are not zero.
    """
    thm = model.theorem1()
    centers = "free" if any(any(j.c_w) or any(j.c_v) for j in model.joints.values()) else "zero"
    weights = {n: _re_weights(model, n) if j.gains else None for n, j in model.joints.items()}
    rule = {"sets": "synthesis_min_re_norm" if any(w is not None for w in weights.values()) else "identify",
            "centers": centers, "note": "synthesis: the inner programme of eq. 10 at the model's gains, "
                                        "without the R*_u constraint"}

    def fit(train):
        devs = deviation_extremes_many(model.plant, model.estimator, train, model.horizon, thm)
        out = {}
        for n, dev in devs.items():
            try:
                sets = identify_sets(model.plant, thm, dev, centers=centers, weights=weights[n])
            except ReachsetError as e:
                raise ReachsetError(f"joint {n}: calibration fold: {e}") from None
            out[n] = model_joint_sets(sets, dev, model.horizon)
        return out
    return fit, rule


def _series(model, bags, topics, reader):
    series, _ = read_joint_series([Path(b) for b in bags], list(model.joints), model.plant.dt, topics,
                                  **(reader or {}))
    missing = [n for n in model.joints if n not in series]
    if missing:
        raise ReachsetError(f"joint {missing[0]} of the model not found in the bags")
    require_horizon(series, model.estimator.history, model.horizon, bags)
    return series


def calibrate_model(model, *, bags=(), folds=None, validate_bags=None, grid=None, margin=0, floor=0.0,
                    topics=(JOINT_STATES, PLANT_INPUT), reader=None, fault_accel=5.0, inflation_rule=None):
    """The model's inflation calibrated on its own sets (module docstring).

    Parameters
    ----------
    model : ConformanceModel
        Its sets are kept; its inflation is replaced.
    bags : sequence of path
        The data the sets were made from (cross-validation: ``folds`` >= 2 folds of whole runs).
    validate_bags : sequence of path, optional
        Held-out bags instead: the model's sets are checked on them.
    grid : sequence of float, optional
        Inflations tried (default :data:`~reachset_ros.workflows.identify.DEFAULT_GRID`).
    margin : int
        Grid steps above each joint's cross-validated inflation (``--calibrate-margin``).
    floor : float or dict
        Each joint's inflation is at least this (a number for every joint or ``{joint:
        number}``; e.g. the inflation the gains were synthesised for): a larger inflation only
        grows the sets, so the folds that held at the calibrated value still hold; the record
        keeps both (``calibrated_inflation``, ``per_joint``, ``floor``).
    topics, reader
        How the bags are read; u_p must be computed as the model's was
        (:func:`~reachset_ros.conformance.model.require_input_source`).
    inflation_rule : str, optional
        ``"largest"`` (every joint gets the largest of the joints' values, floors and margin
        included) or ``"per-joint"`` (:func:`~reachset_ros.workflows.identify.applied_inflations`);
        default ``identify.inflation_rule``, as ``identify`` applies it.

    Returns
    -------
    CalibratedModel
        Each joint carries its own calibrated inflation (issue 35.1).
    """
    if (folds is None) == (validate_bags is None):
        raise ReachsetError("calibrate_model: give folds (cross-validation) or validate_bags (held-out), not both")
    mdl.require_input_source(model, (reader or {}).get("effort"), source="calibration")
    g = inflation_grid(grid)
    if validate_bags is not None:
        vseries = _series(model, validate_bags, topics, reader)
        chosen, per = validate(model.plant, model.estimator, horizon=model.horizon, thm=model.theorem1(),
                               joints=model.joints, vseries=vseries, grid=g, fault_accel=fault_accel,
                               rule=inflation_rule or defaults.get("identify.inflation_rule"))
        rule = {"sets": "the model's own sets"}
        out = mdl.with_calibration(model.with_inflation(chosen), method="held_out_bags", inflation_grid=list(g),
                                   rule=rule, bags=[str(b) for b in validate_bags])
        return CalibratedModel(model=out, calibrated=max(chosen.values()), joints=per, rule=rule,
                               calibrated_per_joint=dict(chosen))
    series = _series(model, bags, topics, reader)
    fit, rule = fold_rule(model)
    runs = {n: run_ranges(s.stamps, s.dt) for n, s in series.items()}
    calib = cross_validate(model.plant, model.estimator, series, horizon=model.horizon, k=folds, grid=g,
                           identify=fit, thm=model.theorem1(), runs=runs)
    per = {n: float(c["inflation"]) for n, c in calib.items()}
    floors = dict(floor) if isinstance(floor, dict) else {n: float(floor) for n in per}
    # applied as identify applies it (identify.inflation_rule: the largest over the joints, or each its own)
    inflations = applied_inflations({n: max(calibrate_margin(x, g, margin) if margin else x, float(floors.get(n, 0.0)))
                                     for n, x in per.items()}, inflation_rule or defaults.get("identify.inflation_rule"))
    out = mdl.with_calibration(model.with_inflation(inflations), method="cross_validation",
                               folds=int(folds), inflation_grid=list(g), calibrated_inflation=max(per.values()),
                               margin_steps=int(margin), floor={n: float(x) for n, x in floors.items()},
                               rule=rule, per_joint=per)
    return CalibratedModel(model=out, calibrated=max(per.values()), joints=calib, rule=rule, calibrated_per_joint=per)
