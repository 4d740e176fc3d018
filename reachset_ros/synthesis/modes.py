"""The synthesis modes for one joint and for several: combined (eq. 10), separate, re-identify, LQG.

:func:`combined` is the paper's combined synthesis and identification (eq. 10). Baselines:
:func:`separate` (identify by min ||W|| + ||V||, then search ``theta`` with the sets fixed),
:func:`lqg_baseline` (paper Table IV) and :func:`reidentify` (controller fixed, sets
re-identified by the inner LP; Sec. III-D step 3). :func:`synthesize` runs a mode for every
joint. Infeasibility is reported naming the binding constraint (R_u inside U_p, or stability).
"""
from __future__ import annotations

import time

import numpy as np

from .. import conformance as cf
from ..errors import InfeasibleError, ReachsetError
from ..systems.closedloop import analyze, close_loop, radius_coefficients
from ..systems.controllers import lqg
from ..systems.plant import lwa4p_robot_model
from . import recorded_loop
from .config import PARAMS, SearchSpace
from .reference_error import ReferenceMethod
from .result import finalize
from .search import Evaluator, optimise


def _infeasible(problem, space, best, evaluator, what):
    pb = problem
    if best is None or not best.stable:
        lim = (f" with spectral radius below {evaluator.max_rho:g}" if evaluator.max_rho < 1.0 else "")
        raise InfeasibleError(f"joint {pb.name}: {what}: no stable closed loop{lim} in the search box "
                              f"({evaluator.count} parameter vectors tried)")
    ref = best.ref.u_bound if best.ref is not None else 0.0
    room = pb.u_max - pb.u_ff - ref
    if room <= 0:
        raise InfeasibleError(f"joint {pb.name}: {what}: U_ff (+-{pb.u_ff:g}) and the reference error "
                              f"({ref:.4g}) alone exceed U_p = [-{pb.u_max:g}, {pb.u_max:g}]")
    if space.dim == 0:
        raise InfeasibleError(
            f"joint {pb.name}: {what}: the controller cannot keep R_u inside U_p with sets conformant to "
            f"these data: smallest achievable R_u radius {best.min_ru_radius:.4g} > u_max {pb.u_max:g} - u_ff "
            f"{pb.u_ff:g}" + (f" - reference error {ref:.4g}" if ref else "") + f" = {room:.4g} "
            f"({_fmt(space, best.values)}); synthesise again with these data")
    raise InfeasibleError(
        f"joint {pb.name}: {what}: no gains keep R_u inside U_p: smallest achievable R_u radius "
        f"{best.min_ru_radius:.4g} > u_max {pb.u_max:g} - u_ff {pb.u_ff:g}"
        + (f" - reference error {ref:.4g}" if ref else "") + f" = {room:.4g} "
        f"(best of {evaluator.count} parameter vectors, at {_fmt(space, best.values)})")


def _fmt(space, values):
    return ", ".join(f"{n}={values[n]:.4g}" for n in (space.free or PARAMS[space.observer]))


def separate(problem, space, search=None, seeds=(), seed=0, sets=None, loops=None):
    """The paper's separate approach: identify (min ||W|| + ||V||), then search ``theta``.

    Returns
    -------
    JointResult
        ``mode="separate"``; ``extra["identified"]`` has the identification's cost.

    Raises
    ------
    InfeasibleError
        If no ``theta`` keeps R_u inside U_p with the identified sets.
    """
    t0 = time.perf_counter()
    pb = problem
    if sets is None:
        sets = cf.identify_sets(pb.plant, pb.thm, pb.devs, centers="zero", alpha_lower=pb.alpha_lower,
                               horizon=pb.horizon)
    alpha = np.concatenate([sets.alpha_w, sets.alpha_v])
    best, ev = optimise(pb, space, alpha, [space.values, *seeds], search, seed, loops)
    if not best.feasible:
        # report the binding constraint with the identified sets
        if best.stable:
            best.min_ru_radius = best.ru_radius
        _infeasible(pb, space, best, ev, "separate approach")
    res = finalize(pb, space, best.values, alpha, "separate", ev.count, t0)
    res.extra["identification_cost"] = float(sets.cost)
    return res


def combined(problem, space, search=None, seeds=(), seed=0, separate_result=None, loops=None):
    """Combined synthesis and identification (paper eq. 10) for one joint.

    The search is seeded with the start values, ``seeds`` (dicts of parameter values) and the
    separate approach's optimum (``separate_result``), so ``||R_e||`` of the result is never
    larger than the separate approach's: if the combined search ends above it (possible only
    through the floating-point clean-up), the separate optimum is returned as the combined one.

    Raises
    ------
    InfeasibleError
        Naming the binding constraint (R_u inside U_p, or stability).
    """
    t0 = time.perf_counter()
    pb = problem
    seeds = [space.values, *seeds]
    if separate_result is not None:
        seeds.append({**space.values, **{n: separate_result.params[n] for n in space.free}})
    best, ev = optimise(pb, space, None, seeds, search, seed, loops)
    if not best.feasible:
        _infeasible(pb, space, best, ev, "combined synthesis")
    res = finalize(pb, space, best.values, best.alpha, "combined", ev.count, t0)
    if separate_result is not None and separate_result.re_norm < res.re_norm:
        notes = [f"the combined search ended at ||R_e|| = {res.re_norm:.6g}, above the separate optimum; "
                 "the separate optimum (feasible for eq. 10) is returned"]
        sep_alpha = np.concatenate([separate_result.alpha_w, separate_result.alpha_v])
        res = finalize(pb, space, separate_result.params, sep_alpha, "combined", ev.count, t0, notes)
    return res


def reidentify(problem, gains, dt=None):
    """Controller fixed (``gains`` of a model file): only the sets are re-identified.

    Solves the inner problem of eq. 10 at the fixed parameters: min ||R_e|| over conformant
    ``alpha`` with R_u inside U_p (paper Sec. III-D step 3). A problem holding the bags'
    recorded loop (:func:`reachset_ros.synthesis.recorded_loop.constrain`) also keeps the
    recorded tracking error inside R*_e; ``extra["recorded_loop"]`` reports it.
    """
    t0 = time.perf_counter()
    pb = problem
    space = SearchSpace.from_gains(gains, dt if dt is not None else pb.plant.dt)
    ev = Evaluator(pb, space)
    best = ev(space.values)
    if not best.feasible:
        _infeasible(pb, space, best, ev, "re-identification with the fixed controller")
    res = finalize(pb, space, best.values, best.alpha, "reidentify", ev.count, t0)
    if pb.recorded_loop is not None:
        res.extra["recorded_loop"] = recorded_loop.report(pb, res)
    return res


def lqg_baseline(problem, alpha_w, alpha_v, r_values, Q=None, form="predictor"):
    """Paper Table IV: LQG (Kalman filter + LQR on the 4-state robot model) for each ``r``.

    The closed loops are evaluated with the given (conformant) sets, as the paper does with
    the sets of its Table II. Per ``r``: ``re_norm`` (including the reference error of method
    3 when the bags have references), ``ru`` (R_u (+) U_ff (+) U_e,ff), ``ru_inside_up``, and
    ``re_norm_best_sets``: ||R_e|| with the sets re-chosen for this controller (the inner LP
    without the input constraint).
    """
    pb = problem
    model = lwa4p_robot_model(dt=pb.plant.dt)
    rows = []
    for r in r_values:
        row = {"r": float(r)}
        try:
            obs, ctrl = lqg(model, float(r), alpha_w, alpha_v, Q=Q, form=form)
            cl = close_loop(pb.plant, obs, ctrl)
            an = analyze(cl, alpha_w, alpha_v, u_ff=0.0)
        except (ValueError, np.linalg.LinAlgError) as e:
            row.update(error=str(e).splitlines()[0])
            rows.append(row)
            continue
        if not an.stable:
            row.update(stable=False, error=an.stability.message)
            rows.append(row)
            continue
        ref = pb.reference_sets(obs, ctrl)
        # method 3: the reference error is part of R*_e and R*_u
        in_sets = pb.reference_method == ReferenceMethod.REFERENCE_SET
        re = float(an.re_norm + (ref.norm if in_sets else 0.0))
        lo = -an.ru[1] - pb.u_ff + (ref.u_lo if in_sets else 0.0)
        hi = an.ru[1] + pb.u_ff + (ref.u_hi if in_sets else 0.0)
        Kw, Kv = radius_coefficients(cl)
        ce = 2.0 * np.concatenate([Kw[:2].sum(axis=0), Kv[:2].sum(axis=0)])
        _, best = pb.polytope.minimize(ce)
        row.update(stable=True, re_norm=re, re_radius=[float(x) for x in an.re_radius],
                   ru=[float(lo), float(hi)], ru_inside_up=bool(-pb.u_max <= lo and hi <= pb.u_max),
                   re_norm_best_sets=float(best + (ref.norm if in_sets else 0.0)),
                   spectral_radius=float(an.stability.spectral_radius))
        rows.append(row)
    return rows


# ====================================================================== several joints
def synthesize(problems, space, mode="combined", search=None, seed=0, seeds=None, gains=None,
               lqg_r=(), with_separate=True):
    """Run ``mode`` for every :class:`JointProblem`; returns ``{joint: JointResult}``.

    ``mode="combined"`` also runs the separate approach (the paper's baseline, and a seed)
    unless ``with_separate`` is false; its result is in ``result.extra["separate"]``.
    ``seeds``: ``{joint: [values dict, ...]}``; ``gains``: ``{joint: gains}`` for ``reidentify``.
    ``lqg_r``: LQG baseline with the result's sets, in ``result.extra["lqg"]``.
    """
    out = {}
    for pb in problems:
        js = (seeds or {}).get(pb.name, [])
        if mode == "reidentify":
            g = (gains or {}).get(pb.name)
            if not g:
                raise ReachsetError(f"joint {pb.name}: the model has no gains to keep fixed")
            res = reidentify(pb, g)
        elif mode == "separate":
            res = separate(pb, space, search, js, seed)
        elif mode == "combined":
            sep, sep_err, loops = None, None, {}
            if with_separate:
                try:
                    sep = separate(pb, space, search, js, seed, loops=loops)
                except InfeasibleError as e:
                    sep_err = str(e)
            res = combined(pb, space, search, js, seed, sep, loops=loops)
            if with_separate:
                res.extra["separate"] = sep.as_dict() if sep is not None else {"error": sep_err}
                res.separate = sep
        else:
            raise ReachsetError(f"unknown mode {mode!r} (combined, separate or reidentify)")
        if lqg_r:
            res.extra["lqg"] = lqg_baseline(pb, res.alpha_w, res.alpha_v, lqg_r)
        out[pb.name] = res
    return out
