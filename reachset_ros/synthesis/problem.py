"""The per-joint synthesis problem: data, Theorem-1 constraints on alpha, limits, references.

The Theorem-1 constraints (paper Sec. III-B) depend only on the data (test cases replay the
*recorded* plant input ``u_p``), not on ``theta``: the deviation extremes are computed once per
joint (:func:`reachset_ros.conformance.deviation_extremes`) and reduced to a handful of
non-redundant rows ``G alpha >= h`` (:class:`AlphaPolytope`; centres fixed at 0 as in the
paper's Appendix A). :class:`JointProblem` holds them with everything else about one joint that
does not depend on the controller parameters (``U_p``, ``U_ff``, the references or the reference
class and the reference-error method); :func:`problems_from_series` builds one per joint. A
problem needs recorded references or a :class:`ReferenceClass`: the reference error of
Appendix B is never taken as zero.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .. import conformance as cf
from .. import guarantees
from ..errors import InfeasibleError, ReachsetError
from .reference_error import (ReferenceClass, ReferenceMethod, class_reference_error, reference_error,
                              reference_windows)


# ====================================================================== Theorem-1 constraints on alpha
@dataclass(frozen=True, eq=False)
class AlphaPolytope:
    """Theorem 1 with zero centres as ``G alpha >= h``, ``alpha >= lower`` (non-redundant rows).

    ``alpha = [alpha_W, alpha_V]``. Built from :func:`reachset_ros.conformance.identification_constraints`;
    rows with ``h <= 0`` (implied by ``alpha >= 0``, since ``G >= 0``) and rows implied by a
    single other row (``G_i / h_i >= G_j / h_j`` element-wise) are dropped, which leaves a
    few dozen of the ``2 (k* + 1)`` rows.
    """

    G: np.ndarray
    h: np.ndarray
    lower: np.ndarray
    rows_total: int
    pw: int
    pv: int

    @classmethod
    def build(cls, plant, thm, devs, horizon=None, alpha_lower=None):
        A_ub, b_ub, _, _ = cf.identification_constraints(plant, thm, devs, horizon, "zero")
        pw, pv, ny = plant.Gw.shape[1], plant.Gv.shape[1], plant.C.shape[0]
        off = pw + ny
        G, h = -A_ub[:, off:], -b_ub
        total = len(h)
        na = pw + pv
        lower = np.zeros(na) if alpha_lower is None else np.array(
            np.broadcast_to(np.asarray(alpha_lower, float), (na,)))
        if np.any(lower < 0) or not np.all(np.isfinite(lower)):
            raise ReachsetError("alpha lower bounds must be finite and non-negative")
        if np.any(G < -1e-15):
            raise ReachsetError("internal: Theorem-1 rows with negative alpha coefficients")
        G = np.maximum(G, 0.0)
        keep = h > 0
        G, h = G[keep], h[keep]
        dead = ~np.any(G > 0, axis=1)
        if np.any(dead):
            raise InfeasibleError(f"conformance is infeasible: a measured deviation of {float(h[dead].max()):.3g} "
                                  "lies in a direction no disturbance generator reaches")
        if len(h):
            Gn = G / h[:, None]
            order = np.lexsort(Gn.T[::-1])
            Gn, G, h = Gn[order], G[order], h[order]
            keep = np.ones(len(h), bool)
            for i in range(len(h)):
                if not keep[i]:
                    continue
                dom = np.all(Gn >= Gn[i], axis=1)   # rows implied by row i
                dom[i] = False
                keep &= ~dom
            G, h = G[keep], h[keep]
        return cls(G, h, lower, total, pw, pv)

    def minimize(self, c, extra=None, rhs=None):
        """``min c . alpha`` over the polytope, optionally with ``extra . alpha <= rhs``.

        Returns ``(alpha, value)`` or ``(None, None)`` when infeasible. The problem is scaled
        (rows by ``h``, variables by their largest coefficient) before HiGHS sees it.
        """
        c = np.asarray(c, float)
        na = self.G.shape[1]
        if len(self.h):
            colmax = (self.G / self.h[:, None]).max(axis=0)
            # a column no row constrains (k* below the plant's minimum horizon) keeps scale 1
            s = np.where(colmax > 0, 1.0 / np.where(colmax > 0, colmax, 1.0), 1.0)
        else:
            s = np.ones(na)
        s = np.where(np.isfinite(s) & (s > 0), s, 1.0)
        A = [-(self.G / self.h[:, None]) * s] if len(self.h) else []
        b = [-np.ones(len(self.h))] if len(self.h) else []
        if extra is not None:
            if rhs <= 0:
                if rhs < 0 or np.any(np.asarray(extra) * np.maximum(self.lower, 0) > 0):
                    return None, None
            else:
                A.append((np.asarray(extra, float) * s / rhs)[None, :])
                b.append(np.ones(1))
        cs = c * s
        scale = float(np.abs(cs).max()) or 1.0
        bounds = [(float(lo / sj), None) for lo, sj in zip(self.lower, s)]
        A_ub = np.vstack(A) if A else None
        b_ub = np.concatenate(b) if b else None
        from scipy.optimize import linprog  # lazy: 0.3 s of start-up (issue 38.1)
        res = linprog(cs / scale, A_ub=A_ub, b_ub=b_ub, bounds=bounds, method="highs")
        if res.status == 2:
            return None, None
        if res.status != 0:
            raise InfeasibleError(f"inner linear programme failed: {res.message}")
        alpha = np.maximum(res.x * s, self.lower)
        return alpha, float(c @ alpha)


# ====================================================================== per-joint problem
@dataclass(frozen=True, eq=False, kw_only=True)
class JointProblem:
    """Everything about one joint that does not depend on the controller parameters.

    Build with :meth:`prepare`.
    """

    name: str
    plant: object
    estimator: object
    thm: object
    devs: object
    horizon: int
    polytope: AlphaPolytope
    u_max: float
    u_ff: float
    y: np.ndarray
    u: np.ndarray
    segments: tuple
    references: tuple = ()
    reference_method: ReferenceMethod = ReferenceMethod.REFERENCE_SET
    alpha_lower: np.ndarray = None
    stamps: np.ndarray = None
    ref_windows: tuple = ()
    reference_class: ReferenceClass = None
    inflation: float = 0.0      # the monitor checks W, V scaled by 1 + inflation: R_e, R_u are for those
    #: a fleet run (:mod:`reachset_ros.fleet`) holds no series here (``y``, ``u`` None) but the
    #: reduced ``devs``; ``checker(name, xi)`` then counts a non-conformant xi's violating ticks
    checker: object = None
    #: a re-identification's recorded closed loop (:class:`~reachset_ros.synthesis.recorded_loop.LoopExtremes`)
    #: and how many of its rows the polytope holds (None: not constrained), see
    #: :func:`~reachset_ros.synthesis.recorded_loop.constrain`
    recorded_loop: object = None
    loop_rows: int = None

    @property
    def set_scale(self):
        """``1 + inflation``: the factor on alpha of the sets the monitor checks (:meth:`JointSets.xi`)."""
        return 1.0 + self.inflation

    @classmethod
    def prepare(cls, name, plant, estimator, y, u, segments, horizon=125, u_max=26.0, u_ff=2.0, *,
                thm=None, references=(), reference_method=ReferenceMethod.REFERENCE_SET, alpha_lower=None,
                stamps=None, reference_class=None, inflation=0.0, devs=None, checker=None):
        """Deviation extremes (one sweep over all test cases) and the reduced Theorem-1 rows.

        ``devs``: the extremes when already reduced (a fleet run: ``y``, ``u``, ``segments``
        are then None and ``checker`` checks the data, see :meth:`check`).

        ``references`` (recorded) or ``reference_class`` is required (Appendix B). With a
        class, its sound bound (:func:`class_reference_error`) is used and the recorded
        references, if any, must lie in it.

        Raises
        ------
        ReachsetError
            On bad limits, too little data, neither references nor a reference class, references
            outside the class, or references (or a class) faster than ``U_ff``.
        """
        if not (math.isfinite(u_max) and u_max > 0):
            raise ReachsetError(f"joint {name}: u_max must be positive, got {u_max}")
        if not (math.isfinite(u_ff) and u_ff >= 0):
            raise ReachsetError(f"joint {name}: u_ff must be >= 0, got {u_ff}")
        if not (math.isfinite(inflation) and inflation >= 0):
            raise ReachsetError(f"joint {name}: inflation must be finite and >= 0, got {inflation}")
        if reference_method not in tuple(ReferenceMethod):
            raise ReachsetError(f"reference method must be 1, 2 or 3, got {reference_method}")
        reference_method = ReferenceMethod(int(reference_method))
        refs = tuple(references or ())
        qmax = max((float(np.abs(r.qdd).max()) for r in refs if len(r)), default=0.0)
        if qmax > u_ff * (1 + 1e-12):
            raise guarantees.refused("G5", f"joint {name}: the references in the bags reach |qdd_d| = {qmax:.4g} "
                                           f"rad/s^2, outside U_ff = [-{u_ff:g}, {u_ff:g}] (raise --u-ff)")
        if reference_class is not None:
            if not isinstance(reference_class, ReferenceClass):
                raise ReachsetError(f"joint {name}: reference_class must be a ReferenceClass")
            if reference_class.qdd_max > u_ff * (1 + 1e-12):
                raise guarantees.refused("G5", f"joint {name}: the reference class allows |qdd_d| <= "
                                               f"{reference_class.qdd_max:g} rad/s^2, outside U_ff = [-{u_ff:g}, "
                                               f"{u_ff:g}] (raise --u-ff)")
            for r in refs:
                why = reference_class.violation(r, plant.dt)
                if why:
                    raise guarantees.refused("G11", f"joint {name}: a recorded reference is not in the reference "
                                                    f"class {reference_class.spec}: {why}")
        elif not any(len(r) for r in refs):
            raise guarantees.refused("G11", f"joint {name}: no references and no reference class: the reference "
                                            "error (Appendix B) cannot be bounded; record the references or give a "
                                            "reference class")
        thm = thm or cf.Theorem1.build(plant, horizon)
        try:
            if devs is None:
                devs = cf.deviation_extremes(plant, estimator, y, u, segments, horizon, thm)
            poly = AlphaPolytope.build(plant, thm, devs, horizon, alpha_lower)
        except ReachsetError as e:
            raise type(e)(f"joint {name}: {e}") from None
        windows = (reference_windows(refs) if (refs and reference_class is None
                                               and reference_method == ReferenceMethod.REFERENCE_SET) else ())
        return cls(name=name, plant=plant, estimator=estimator, thm=thm, devs=devs, horizon=horizon, polytope=poly,
                   u_max=float(u_max), u_ff=float(u_ff), y=None if y is None else cf.as_2d(y),
                   u=None if u is None else cf.as_2d(u), segments=None if segments is None else tuple(segments),
                   references=refs, reference_method=reference_method, alpha_lower=poly.lower, stamps=stamps,
                   ref_windows=windows, reference_class=reference_class, inflation=float(inflation),
                   checker=checker)

    @property
    def test_cases(self):
        return self.devs.test_cases

    def check(self, xi):
        """:func:`reachset_ros.conformance.check` of the joint's data against ``xi``.

        Without the series (a fleet run) the verdict and worst margin come from the extremes,
        where they are exact (:func:`reachset_ros.conformance.check_extremes`); only a
        non-conformant ``xi`` needs the data again (``checker``) to count its violating ticks.
        The result is the same :class:`~reachset_ros.conformance.CheckResult` to the bit.
        """
        if self.y is not None:
            return cf.check(self.plant, self.thm, self.estimator, xi, self.y, self.u, self.segments, self.horizon)
        ok, margin = cf.check_extremes(self.thm, xi, self.devs)
        if ok:
            return cf.CheckResult(0, -1, self.devs.test_cases, self.devs.checks, margin)
        if self.checker is None:
            raise ReachsetError(f"joint {self.name}: the sets are not conformant and no data is at hand to count "
                                "the violating ticks")
        return self.checker(self.name, xi)

    def reference_sets(self, observer, controller, references=None):
        """``Y_e,ref`` and ``U_e,ff`` (Appendix B) of this joint's loop with ``observer``, ``controller``.

        The reference class's sound bound when the problem has one; otherwise the enclosure over
        ``references`` (default: the recorded ones, ``exact``; the search passes windows).

        Returns
        -------
        ReferenceErrorSets
        """
        if self.reference_class is not None:
            return class_reference_error(self.plant, observer, controller, self.reference_class)
        refs = self.references if references is None else tuple(references)
        return reference_error(self.plant, observer, controller, refs, exact=refs is self.references)


def problems_from_series(series, plant, estimator, horizon, u_max, u_ff, references=None,
                         reference_method=ReferenceMethod.REFERENCE_SET, alpha_lower=None, thm=None,
                         reference_class=None, inflation=0.0, devs=None, checker=None):
    """:class:`JointProblem` per joint of ``{name: JointSeries}``; ``u_max``: float or dict;
    ``reference_class``: a :class:`ReferenceClass` for all joints, a dict per joint, or None;
    ``inflation``: the monitored sets' inflation the guarantee is computed for: float (all joints)
    or dict per joint (a model's own, issue 35.1).
    ``devs``: ``{name: Deviations}`` instead of ``series`` (None then), with ``checker`` (a
    fleet run, :meth:`JointProblem.check`)."""
    thm = thm or cf.Theorem1.build(plant, horizon)
    out = []
    for name in (series if devs is None else devs):
        s = None if devs is not None else series[name]
        um = u_max[name] if isinstance(u_max, dict) else u_max
        refs = (references or {}).get(name, ())
        rc = reference_class.get(name) if isinstance(reference_class, dict) else reference_class
        y, u, segments, stamps = (s.y, s.u, s.segments, s.stamps) if s else (None,) * 4
        out.append(JointProblem.prepare(name, plant, estimator, y, u, segments, horizon=horizon, u_max=um, u_ff=u_ff,
                                        thm=thm, references=refs, reference_method=reference_method,
                                        alpha_lower=alpha_lower, stamps=stamps, reference_class=rc,
                                        inflation=float(inflation[name] if isinstance(inflation, dict) else inflation),
                                        devs=None if devs is None else devs[name],
                                        checker=checker))
    return out
