"""The recorded closed loop as conformance data: the tracking error under the gains that are kept.

In the paper's iterative procedure (Sec. III-D, step 3) the sets are re-identified with the
controller fixed, from data recorded *with that controller*. Such data hold more than the
open-loop test cases of Theorem 1: the loop's own tracking error ``e = x_hat - x_ref`` (the
observer's estimate against the reference in its coordinates), which ``R*_e`` (Sec. III-A,
with the reference error of Appendix B) must contain once the loop's transient has passed if
the model with its sets describes the robot. The open-loop test cases do not imply it: over
their horizon (up to ``k*`` ticks) an i.i.d. disturbance averages out, while the closed loop
answers it within a few ticks (docs/synthesis.md, "Where the room in ||R*_e|| is": with the
initial-state set the recorded error reached 1.015 of ``R*_e`` on one joint).

* :func:`loop_extremes`: first checks that the bag *was* recorded with these gains: the
  observer (:class:`~reachset_ros.systems.observers.LinearObserver`) replayed on the recorded
  ``y`` and ``u_p`` reproduces the recorded estimate, and the control law
  ``u = qdd_d + K (x_ref - x_hat)`` (:class:`~reachset_ros.systems.controllers.LinearController`)
  the recorded ``u_p``, after the observer's start-up (:data:`VERIFY_TOL`); then returns the
  per-coordinate extremes of ``e`` after the closed loop's settling window
  (:func:`~reachset_ros.systems.closedloop.settling_ticks`) from each segment's start.
  Extremes merge exactly (:func:`merge`), so a fleet run gets the same numbers.
* :func:`loop_rows`: ``|e - c| <= r_ref + s (Kw alpha_W + Kv alpha_V)`` per coordinate, as
  rows ``G alpha >= h`` for :class:`~reachset_ros.synthesis.problem.AlphaPolytope`
  (``Kw``, ``Kv``: :func:`~reachset_ros.systems.closedloop.radius_coefficients` at the kept
  gains; ``c``, ``r_ref``: the reference error's box; ``s = 1 + inflation``).

Assumptions, stated: the segments' first ticks are not claimed (a segment may start at the loop's
start or after a gain change), so only ticks after the settling window (transient decayed to
``1e-3`` of its start) are constraints; ``R*_e`` is the invariant outer bound, so the rows are a
necessary condition for the model, not an approximation of it.
"""
from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from .. import guarantees
from ..errors import InfeasibleError, ReachsetError


class RecordedLoopError(guarantees.GuaranteeRefused):
    """A re-identification's own recorded loop leaves the ``R*_e`` it would certify (issue
    34.5): the sets do not describe the robot the loop ran on, so nothing may apply them."""
from ..systems.closedloop import close_loop, settling_ticks, stability
from ..systems.reference_loop import lti_simulate, reference_state
from .config import SearchSpace
from .reference_error import ReferenceMethod
from .search import Evaluator

#: relative size (of the signals' magnitude, at least 1) within which a replayed estimate and
#: law must reproduce the recorded ones for the bag to count as recorded with the gains
VERIFY_TOL = 1e-7
#: the observer's start-up transient (from a zero state) must have decayed to this before the
#: replay is compared (relative to the recorded estimate's magnitude)
STARTUP_TOL = 1e-12
#: estimate coordinates a bag records (``/observer/estimate``: position, velocity, disturbance)
RECORDED = ("q", "qd", "d")


@dataclass(frozen=True)
class LoopExtremes:
    """Per-coordinate extremes of one joint's recorded tracking error (an immutable value).

    Attributes
    ----------
    e_lo, e_hi : ndarray, (ne,)
        Smallest and largest ``x_hat - x_ref`` per error coordinate over the judged ticks
        (``+inf`` / ``-inf`` when none).
    ticks : int
        Judged ticks (after each segment's settling window).
    checked : int
        Ticks on which the replayed observer and law were compared with the recording.
    residual : float
        Largest relative difference found there (0 when nothing was compared).
    """

    e_lo: np.ndarray
    e_hi: np.ndarray
    ticks: int
    checked: int
    residual: float

    def reach(self, center):
        """Largest ``|e - center|`` per coordinate (``-inf`` where nothing was judged)."""
        c = np.asarray(center, float).ravel()[:len(self.e_lo)]
        return np.maximum(self.e_hi - c, c - self.e_lo)

    @property
    def verified(self):
        """True when the replay was compared on some ticks and agreed within :data:`VERIFY_TOL`."""
        return self.checked > 0 and self.residual <= VERIFY_TOL

    def as_dict(self):
        return {"ticks": int(self.ticks), "checked_ticks": int(self.checked), "residual": float(self.residual),
                "verified": bool(self.verified), "e_lo": [float(x) for x in self.e_lo],
                "e_hi": [float(x) for x in self.e_hi]}


def loop_extremes(plant, observer, controller, y, u, x_hat, q_d, qd_d, qdd_d, segments):
    """The recorded loop's error extremes after settling, and whether these gains recorded it.

    Parameters
    ----------
    plant : JointPlant
    observer, controller : the kept gains' components
        (:func:`reachset_ros.synthesis.config.components_from_gains`).
    y, u : array_like, (T,)
        Recorded measurement and plant input (``JointSeries.y``, ``.u``).
    x_hat : array_like, (T, 3)
        Recorded ``/observer/estimate`` (position, velocity, disturbance) at the same stamps.
    q_d, qd_d, qdd_d : array_like, (T,)
        Recorded ``/reference`` at the same stamps.
    segments : sequence of (start, stop)
        Consecutive valid ticks (``JointSeries.segments``); every stamp above must be valid
        there.

    Returns
    -------
    LoopExtremes

    Notes
    -----
    The error coordinates are the closed loop's (``ClosedLoop.n_error`` first estimates:
    position and velocity), those ``R*_e`` bounds. A segment shorter than the observer's
    start-up is not compared; shorter than the loop's settling window, not judged.
    """
    y, u = (np.asarray(a, float).ravel() for a in (y, u))
    x_hat = np.asarray(x_hat, float).reshape(len(y), -1)
    q_d, qd_d, qdd_d = (np.asarray(a, float).ravel() for a in (q_d, qd_d, qdd_d))
    names = tuple(observer.estimate_names)
    cl = close_loop(plant, observer, controller)
    ne = cl.n_error
    if tuple(names[:ne]) != ("q", "qd")[:ne]:
        raise ReachsetError(f"the tracking error's coordinates {names[:ne]} are not (q, qd)")
    rho = stability(cl).spectral_radius
    if not rho < 1.0:
        raise ReachsetError(f"the kept gains' closed loop is not stable (spectral radius {rho:.6g})")
    settle = settling_ticks(rho)
    rho_o = float(np.max(np.abs(np.linalg.eigvals(observer.Ao)))) if observer.Ao.size else 0.0
    startup = settling_ticks(rho_o, STARTUP_TOL) if rho_o < 1.0 else None
    cols = [names.index(n) for n in RECORDED if n in names]
    rec_cols = [RECORDED.index(names[c]) for c in cols]
    kcols = [names.index(n) for n in controller.estimate_names]
    B, D = np.hstack([observer.Bo_y, observer.Bo_u]), np.hstack([observer.Do_y, observer.Do_u])
    lo, hi, ticks, checked, resid = np.full(ne, np.inf), np.full(ne, -np.inf), 0, 0, 0.0
    for a, b in segments:
        a, b = int(a), int(b)
        xr = reference_state(names, q_d[a:b], qd_d[a:b], qdd_d[a:b])
        if startup is not None and b - a > startup:
            xh = lti_simulate(observer.Ao, B, observer.Co, D, np.column_stack([y[a:b], u[a:b]]))
            law = qdd_d[a:b] + (xr[:, kcols] - xh[:, kcols]) @ controller.K[0]
            s = slice(startup, None)
            est_rec = x_hat[a:b][s][:, rec_cols]
            d_est = np.abs(xh[s][:, cols] - est_rec).max(initial=0.0) / max(1.0, np.abs(est_rec).max(initial=0.0))
            d_law = np.abs(law[s] - u[a:b][s]).max(initial=0.0) / max(1.0, np.abs(u[a:b][s]).max(initial=0.0))
            resid = max(resid, float(d_est), float(d_law))
            checked += b - a - startup
        if b - a > settle:
            e = x_hat[a:b][settle:, :ne] - xr[settle:, :ne]
            lo, hi = np.minimum(lo, e.min(axis=0)), np.maximum(hi, e.max(axis=0))
            ticks += b - a - settle
    return LoopExtremes(lo, hi, ticks, checked, resid)


def _at(stamps, src_stamps, values):
    """``values`` (rows by ``src_stamps``) at ``stamps``; NaN rows where a stamp is missing."""
    values = np.asarray(values, float).reshape(len(src_stamps), -1)
    order = np.argsort(src_stamps, kind="stable")
    ss, vv = np.asarray(src_stamps)[order], values[order]
    idx = np.clip(np.searchsorted(ss, stamps), 0, max(len(ss) - 1, 0))
    out = np.full((len(stamps), values.shape[1]), np.nan)
    if len(ss):
        hit = ss[idx] == stamps
        out[hit] = vv[idx[hit]]
    return out


def _runs(mask, segments):
    """The segments split into runs where ``mask`` holds."""
    out = []
    for a, b in segments:
        m = np.concatenate([[False], mask[a:b], [False]])
        d = np.flatnonzero(np.diff(m.astype(np.int8)))
        out += [(a + int(lo), a + int(hi)) for lo, hi in zip(d[::2], d[1::2])]
    return tuple(out)


def series_loop_extremes(plant, observer, controller, series, estimates, references):
    """:func:`loop_extremes` of one joint's bag data, paired by stamp.

    Parameters
    ----------
    series : JointSeries
    estimates : (stamps, ndarray (T, 3)) or None
        The joint's ``/observer/estimate`` (:func:`reachset_ros.bags.read_estimates`).
    references : sequence of Reference
        The joint's ``/reference`` stretches (:func:`reachset_ros.bags.read_references`).

    Returns
    -------
    LoopExtremes or None
        None when the bags recorded no estimate or no reference of the joint (or never both
        at one stamp).
    """
    refs = [r for r in (references or ()) if len(r)]
    if estimates is None or not len(estimates[0]) or not refs:
        return None
    st = np.asarray(series.stamps)
    xh = _at(st, np.asarray(estimates[0]), estimates[1])
    rs = np.concatenate([r.stamps for r in refs])
    rv = _at(st, rs, np.column_stack([np.concatenate([getattr(r, k) for r in refs]) for k in ("q", "qd", "qdd")]))
    have = np.all(np.isfinite(xh[:, :2]), axis=1) & np.all(np.isfinite(rv), axis=1)
    xh = np.where(np.isfinite(xh), xh, 0.0)      # an ESO's disturbance may be absent (NaN) in the bag
    ext = loop_extremes(plant, observer, controller, y=series.y, u=series.u, x_hat=xh, q_d=rv[:, 0], qd_d=rv[:, 1],
                        qdd_d=rv[:, 2], segments=_runs(have, series.segments))
    return ext if ext.ticks or ext.checked else None


def merge(parts):
    """Exact merge of :class:`LoopExtremes` of disjoint data (min, max, sums, max); None parts
    (bags without the loop's topics) are skipped, and all None give None."""
    parts = [p for p in parts if p is not None]
    if not parts:
        return None
    lo = np.min([p.e_lo for p in parts], axis=0)
    hi = np.max([p.e_hi for p in parts], axis=0)
    return LoopExtremes(lo, hi, sum(p.ticks for p in parts), sum(p.checked for p in parts),
                        max(p.residual for p in parts))


def loop_rows(Kw, Kv, ne, ref_center, ref_radius, ext, scale=1.0):
    """``G alpha >= h``: the recorded error inside ``R*_e`` (per coordinate, module docstring).

    Parameters
    ----------
    Kw, Kv : ndarray
        Radius coefficients of the kept loop (:func:`~reachset_ros.systems.closedloop.radius_coefficients`).
    ne : int
        Error coordinates (``ClosedLoop.n_error``).
    ref_center, ref_radius : array_like, (ne,)
        Box of the reference error (Appendix B) of the kept loop; zeros without one.
    ext : LoopExtremes
    scale : float
        ``1 + inflation``: the sets the monitor checks.

    Returns
    -------
    G : ndarray, (ne, gw + gv)
    h : ndarray, (ne,)
        Coordinates without judged ticks give ``h = -inf`` (no constraint).
    """
    r = np.asarray(ref_radius, float).ravel()[:ne]
    G = float(scale) * np.hstack([np.asarray(Kw, float)[:ne], np.asarray(Kv, float)[:ne]])
    reach = ext.reach(ref_center)
    h = np.where(np.isfinite(reach), reach - r, -np.inf)
    return G, h


def constrain(problem, gains, ext):
    """``problem`` with the recorded loop's rows (:func:`loop_rows` at ``gains``) in its polytope.

    The rows are added only when the bags were recorded with ``gains`` (``ext.verified``) and
    the reference error is part of ``R*_e`` (Appendix B method 3, the default); otherwise the
    problem is returned with ``recorded_loop`` set (reported) and its rows unchanged. ``ext``
    None (no estimate or reference in the bags) returns ``problem`` itself.

    Raises
    ------
    InfeasibleError
        If the recorded error lies in a coordinate that no disturbance set reaches.
    """
    if ext is None:
        return problem
    if not ext.verified or problem.reference_method != ReferenceMethod.REFERENCE_SET:
        return replace(problem, recorded_loop=ext)
    space = SearchSpace.from_gains(gains, problem.plant.dt)
    ld = Evaluator(problem, space).loop_data(space.values)
    if not ld.ok:
        raise InfeasibleError(f"joint {problem.name}: the kept gains' loop: {ld.reason}")
    ne = ld.ne
    c = 0.5 * (ld.ref.e_hi + ld.ref.e_lo) if ld.ref is not None else np.zeros(ne)
    r = 0.5 * (ld.ref.e_hi - ld.ref.e_lo) if ld.ref is not None else np.zeros(ne)
    G, h = loop_rows(ld.Kw, ld.Kv, ne, c, r, ext, problem.set_scale)
    keep = h > 0
    G, h = np.maximum(G[keep], 0.0), h[keep] * (1.0 + 1e-9)   # a relative margin for the LP's tolerance
    if np.any(~np.any(G > 0, axis=1)):
        raise InfeasibleError(f"joint {problem.name}: the recorded tracking error lies in a direction no "
                              "disturbance set reaches")
    P = problem.polytope
    poly = replace(P, G=np.vstack([P.G, G]), h=np.concatenate([P.h, h]))
    return replace(problem, polytope=poly, recorded_loop=ext, loop_rows=len(h))


def report(problem, result):
    """``extra["recorded_loop"]`` of a re-identification: the extremes, whether they were rows,
    and how far the recorded error reaches into the result's ``R*_e`` (above 1: outside)."""
    ext = problem.recorded_loop
    d = ext.as_dict()
    with np.errstate(invalid="ignore", divide="ignore"):
        reach = ext.reach(result.re_center) / np.asarray(result.re_radius, float)[:len(ext.e_lo)]
    d.update(constrained=bool(problem.loop_rows is not None), rows=int(problem.loop_rows or 0),
             reach=[float(x) if np.isfinite(x) else None for x in reach],
             inside=bool(ext.ticks > 0 and np.all(reach <= 1.0)))
    return d


def require_inside(results):
    """Refuse re-identification results whose own recorded loop leaves ``R*_e``.

    Every path that applies re-identified sets (``reachset synthesize --mode reidentify``,
    the synthesis node through its worker, :func:`reachset_ros.synthesis.pipeline.iterate`)
    calls this on ``{joint: JointResult}``: a joint whose ``extra["recorded_loop"]``
    (:func:`report`) was recorded with the kept gains (``verified``) and judged on some ticks
    must lie inside the result's ``R*_e`` (``inside``). A loop recorded with other gains says
    nothing about these gains' ``R*_e`` and is only reported.

    Raises
    ------
    RecordedLoopError
        One line naming the joint, the coordinate and how far the recorded error reaches
        (above 1: outside), and whether the loop's rows were in the problem.
    """
    coords = ("q", "qd", "d")
    for name, res in results.items():
        d = (getattr(res, "extra", None) or {}).get("recorded_loop")
        if not d or not d.get("verified") or not d.get("ticks") or d.get("inside"):
            continue
        reach = [(-np.inf if r is None else float(r)) for r in d.get("reach", [])]
        worst = int(np.nanargmax(reach)) if reach else 0
        why = ("with its rows in the problem (the LP's tolerance)" if d.get("constrained") else
               "its rows were not in the problem (reference method other than 3)")
        raise RecordedLoopError(
            f"joint {name}: the loop recorded with these gains leaves R*_e: its tracking error reaches "
            f"{reach[worst] if reach else float('nan'):.4g} of R*_e's radius in {coords[worst]} over "
            f"{int(d['ticks'])} judged ticks ({why}); the sets do not describe this loop: refused "
            f"{guarantees.tag('G15')}", row="G15")
