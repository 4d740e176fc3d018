"""Solving eq. 10 for one joint: the inner linear programme in alpha and the outer search over theta.

* For fixed ``theta`` the closed loop is fixed; the interval-hull radii of the sound outer
  invariant sets are linear in ``alpha`` (:func:`reachset_ros.systems.closedloop.radius_coefficients`):
  ``||R_e|| = c_e . alpha`` and ``radius(R_u) = c_u . alpha`` (both times ``1 + inflation``
  when the monitor checks inflated sets: the guarantee is for those). The inner problem is the
  linear programme ``min c_e . alpha  s.t.  G alpha >= h,  c_u . alpha <= u_max - u_ff - ref``
  (HiGHS; :meth:`reachset_ros.synthesis.problem.AlphaPolytope.minimize`), evaluated and cached
  per ``theta`` by :class:`Evaluator` (:class:`Evaluation`).
* Only ``theta`` (2-5 numbers) needs a non-convex search: a scrambled Sobol sequence over the
  box of ``config/synthesis.yaml`` plus seeds (start values, the separate approach's optimum,
  previous gains), then bounded Nelder-Mead refinements from the best distinct points
  (:func:`_search`). Reproducible for a given seed. Unstable ``theta`` are infeasible points.
* With references (Appendix B, method 3) the search runs on short reference windows and the
  result is verified on every tick (:func:`optimise`).
"""
from __future__ import annotations

import warnings
from dataclasses import dataclass, replace

import numpy as np

from ..sets.reachability import NotStableError, spectral_radius_reachable
from ..systems.closedloop import close_loop, radius_coefficients, stability
from .config import DEFAULT_CONFIG, PENALTY, U_MARGIN
from .reference_error import ReferenceErrorSets, ReferenceMethod, reference_error


# ====================================================================== evaluation of one theta
@dataclass
class Evaluation:
    """The inner problem at one parameter vector.

    ``merit``: ``||R*_e||`` if feasible, ``PENALTY + normalised violation`` if R_u cannot be
    kept inside U_p, ``2 PENALTY + spectral radius`` if unstable.
    """

    values: dict
    stable: bool
    feasible: bool
    merit: float
    re_norm: float = None
    alpha: np.ndarray = None
    ru_radius: float = None
    ru_room: float = None
    min_ru_radius: float = None
    reason: str = ""
    Kw: np.ndarray = None
    Kv: np.ndarray = None
    ref: ReferenceErrorSets = None


class LoopData:
    """Everything about one parameter vector that does not depend on alpha (shared by evaluators)."""

    __slots__ = ("ok", "merit", "reason", "Kw", "Kv", "ne", "ref")

    def __init__(self, ok, merit=0.0, reason="", Kw=None, Kv=None, ne=2, ref=None):
        self.ok, self.merit, self.reason = ok, merit, reason
        self.Kw, self.Kv, self.ne, self.ref = Kw, Kv, ne, ref


def _key(values):
    return tuple((n, round(float(values[n]), 12)) for n in sorted(values))


class Evaluator:
    """Evaluates (and caches) the inner problem of a :class:`JointProblem` for a :class:`SearchSpace`.

    ``alpha_fixed``: the separate approach - the sets are given, only R_u is checked.
    ``loops``: a dict shared between evaluators of the same problem and space (the closed
    loop's radius coefficients and reference error do not depend on alpha).
    """

    def __init__(self, problem, space, alpha_fixed=None, max_spectral_radius=1.0, loops=None,
                 references=None, ref_offset=None):
        self.problem = problem
        self.space = space
        self.references = problem.references if references is None else tuple(references)
        self.ref_offset = ref_offset      # added to windowed reference errors: (de_lo, de_hi, du_lo, du_hi)
        self.alpha_fixed = None if alpha_fixed is None else np.asarray(alpha_fixed, float)
        self.max_rho = float(max_spectral_radius)
        self.cache = {}
        self.loops = {} if loops is None else loops
        self.count = 0

    def __call__(self, values):
        key = _key(values)
        ev = self.cache.get(key)
        if ev is None:
            ev = self._evaluate(values, key)
            self.cache[key] = ev
            self.count += 1
        return ev

    def loop_data(self, values, key=None):
        key = key or _key(values)
        ld = self.loops.get(key)
        if ld is None:
            ld = self._loop_data(values)
            self.loops[key] = ld
        return ld

    def _loop_data(self, values):
        pb = self.problem
        try:
            obs, ctrl = self.space.build(values)
            cl = close_loop(pb.plant, obs, ctrl)
        except (ValueError, np.linalg.LinAlgError) as e:
            return LoopData(False, 3 * PENALTY, str(e).splitlines()[0])
        if self.max_rho < 1.0:
            rho, _ = spectral_radius_reachable(cl.A, np.hstack([cl.Ew, cl.Ev]))
            if rho >= self.max_rho:
                return LoopData(False, 2 * PENALTY + min(rho, 1e3), f"spectral radius {rho:.6g} >= {self.max_rho:g}")
        try:
            Kw, Kv = radius_coefficients(cl)
        except (NotStableError, ValueError, np.linalg.LinAlgError) as e:
            rho = stability(cl).spectral_radius
            return LoopData(False, 2 * PENALTY + min(rho, 1e3), str(e).splitlines()[0])
        ref = None
        if pb.reference_method == ReferenceMethod.REFERENCE_SET:
            try:                               # a reference class takes precedence
                ref = pb.reference_sets(obs, ctrl, self.references)
            except NotStableError as e:        # its bound did not converge: not certifiable here
                return LoopData(False, 2 * PENALTY + 1.0, "reference class: " + str(e).splitlines()[0])
            if self.ref_offset is not None and not ref.exact:
                de_lo, de_hi, du_lo, du_hi = self.ref_offset
                ref = replace(ref, e_lo=ref.e_lo + de_lo, e_hi=np.maximum(ref.e_hi + de_hi, ref.e_lo + de_lo),
                              u_lo=ref.u_lo + du_lo, u_hi=max(ref.u_hi + du_hi, ref.u_lo + du_lo))
        return LoopData(True, 0.0, "", Kw, Kv, cl.n_error, ref)

    def _evaluate(self, values, key):
        pb = self.problem
        ld = self.loop_data(values, key)
        if not ld.ok:
            return Evaluation(values, False, False, ld.merit, reason=ld.reason)
        Kw, Kv, ne, ref = ld.Kw, ld.Kv, ld.ne, ld.ref
        ref_norm = ref.norm if ref is not None else 0.0
        ref_u = ref.u_bound if ref is not None else 0.0
        # the guarantee is for the sets the monitor checks: alpha scaled by 1 + inflation
        s = pb.set_scale
        ce = s * (2.0 * np.concatenate([Kw[:ne].sum(axis=0), Kv[:ne].sum(axis=0)]))
        cu = s * np.concatenate([Kw[ne], Kv[ne]])
        room = pb.u_max - pb.u_ff - ref_u
        rhs = room - U_MARGIN * pb.u_max
        common = dict(values=values, stable=True, ru_room=room, Kw=Kw, Kv=Kv, ref=ref)
        if self.alpha_fixed is not None:
            alpha = self.alpha_fixed
            ru = float(cu @ alpha)
            if ru <= rhs:
                re = float(ce @ alpha) + ref_norm
                return Evaluation(feasible=True, merit=re, re_norm=re, alpha=alpha, ru_radius=ru, **common)
            viol = (ru - rhs) / max(pb.u_max, 1.0)
            return Evaluation(feasible=False, merit=PENALTY + viol, alpha=alpha, ru_radius=ru, min_ru_radius=ru,
                              reason="R_u outside U_p", **common)
        alpha, val = pb.polytope.minimize(ce, cu, rhs) if rhs > 0 else (None, None)
        if alpha is not None:
            re = val + ref_norm
            return Evaluation(feasible=True, merit=re, re_norm=re, alpha=alpha, ru_radius=float(cu @ alpha), **common)
        amin, umin = pb.polytope.minimize(cu)
        viol = (umin - rhs) / max(pb.u_max, 1.0)
        return Evaluation(feasible=False, merit=PENALTY + viol, min_ru_radius=umin, reason="R_u outside U_p",
                          **common)


# ====================================================================== outer search
def _search(evaluator, space, seeds, search_cfg, rng_seed, global_stage=True):
    """Sobol multistart + bounded Nelder-Mead over the unit box; returns the best Evaluation.

    Without ``global_stage`` only the seeds are refined (used when re-searching after the
    reference windows were extended).
    """
    # lazy: scipy.optimize and scipy.stats cost 0.7 s of every start-up (issue 38.1)
    from scipy.optimize import minimize
    from scipy.stats import qmc
    d = space.dim
    if d == 0:
        ev = evaluator(space.full())
        return ev
    cfg = {**DEFAULT_CONFIG["search"], **(search_cfg or {})}
    pts = [space.to_unit(s) for s in seeds]
    if global_stage or not pts:
        sob = qmc.Sobol(d, scramble=True, seed=int(rng_seed))
        pts += list(sob.random_base2(int(cfg["sobol_log2"])))
    evals = []
    for u in pts:
        ev = evaluator(space.from_unit(u))
        evals.append((ev.merit, tuple(np.round(u, 12)), ev))
    evals.sort(key=lambda t: t[0])
    starts = []
    for merit, u, ev in evals:
        if all(np.max(np.abs(np.asarray(u) - np.asarray(s))) > 0.05 for s in starts):
            starts.append(u)
        if len(starts) >= int(cfg["local_starts"]):
            break
    best = evals[0][2]

    def f(u):
        ev = evaluator(space.from_unit(u))
        return ev.merit

    maxfev = int(cfg["local_maxfev"]) * max(d, 1)
    for s in starts:
        x0 = np.asarray(s, float)
        step = 0.05
        simplex = [x0]
        for i in range(d):
            x = x0.copy()
            x[i] = x[i] + step if x[i] + step <= 1.0 else x[i] - step
            simplex.append(x)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            res = minimize(f, x0, method="Nelder-Mead", bounds=[(0.0, 1.0)] * d,
                           options={"initial_simplex": np.array(simplex), "maxfev": maxfev,
                                    "xatol": 1e-4, "fatol": 1e-7})
        ev = evaluator(space.from_unit(res.x))
        if ev.merit < best.merit:
            best = ev
    # the best point ever evaluated (Nelder-Mead's final point need not be it)
    for ev in evaluator.cache.values():
        if ev.merit < best.merit:
            best = ev
    return best


def optimise(pb, space, alpha, seeds, search, seed, loops=None, rounds=3, tol=0.01):
    """Search ``theta``; with references (method 3) on windows first, verified on every tick.

    During the search the reference error is computed on :attr:`JointProblem.ref_windows`
    (fast); the best point is then re-evaluated with the exact reference error (inner LP
    included). If that is infeasible or its ``||R*_e||`` exceeds the windowed value by more
    than ``tol`` (relative), windows around the ticks where the exact extremes occur are
    added, the windowed bounds are shifted by the remaining difference at the best point, and
    the local search is repeated from there (at most ``rounds`` times, then on every tick).
    A search that finds nothing feasible on the windows is repeated on every tick before
    infeasibility is reported. Returns (exact Evaluation, evaluator).
    """
    loops = {} if loops is None else loops
    rho = _max_rho(search)
    exact_refs = (pb.reference_method == ReferenceMethod.REFERENCE_SET and bool(pb.references)
                  and pb.reference_class is None)
    windows = pb.ref_windows if exact_refs else None
    first_seeds = list(seeds)
    seeds = list(seeds)
    offset = None
    total = 0
    rnd = 0
    while True:
        use = windows if (exact_refs and rnd < rounds) else None
        key = ("w", id(use), rnd) if use is not None else "exact"
        ev = Evaluator(pb, space, alpha, rho, loops.setdefault(key, {}), references=use, ref_offset=offset)
        cfg = search if (use is not None or not exact_refs) else {**(search or {}), "local_starts": 1}
        best = _search(ev, space, seeds, cfg, seed, global_stage=(rnd == 0))
        total += ev.count
        if use is None:
            ev.count = total
            return best, ev
        exact = Evaluator(pb, space, alpha, 1.0, loops.setdefault("exact", {}))
        if not best.feasible:
            # windows can over-estimate (start transients of slow loops): check the best
            # candidates on every tick before searching there
            cands = sorted((e for e in ev.cache.values() if e.stable), key=lambda e: e.merit)[:8]
            exs = [exact(e.values) for e in cands]
            total += len(exs)
            ok = [e for e in exs if e.feasible]
            if not ok:                       # search on every tick, from the best candidates
                rnd = rounds
                seeds = [e.values for e in cands[:3]] + first_seeds
                continue
            best = ex = min(ok, key=lambda e: e.merit)
            refine = True                    # the windows were wrong here: refine with corrections
        else:
            ex = exact(best.values)
            total += 1
            refine = False
        if not refine and ex.feasible and ex.merit <= best.merit + tol * max(best.merit, 1e-12):
            ev.count = total
            return ex, ev
        ref = exact.loop_data(best.values).ref
        new = []
        for si, t in (ref.argext if ref is not None else ()):
            r = pb.references[si]
            lo, hi = max(0, t - 450), min(len(r), t + 101)
            new.append(r.slice(lo, hi, 150 if lo > 0 else 0))
        windows = tuple(windows) + tuple(new)
        if ref is not None:
            obs, ctrl = space.build(best.values)
            approx = reference_error(pb.plant, obs, ctrl, windows, exact=False)
            offset = (ref.e_lo - approx.e_lo, ref.e_hi - approx.e_hi, ref.u_lo - approx.u_lo, ref.u_hi - approx.u_hi)
        seeds = [best.values]
        rnd += 1


def _max_rho(search):
    return float({**DEFAULT_CONFIG["search"], **(search or {})}["max_spectral_radius"])
