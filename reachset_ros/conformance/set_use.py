"""Set use: how much of the reachable set each measurement tick uses (issue 36.3/36.4).

At a measurement tick t every test case that started in the last k* ticks is checked at its
step k (Theorem 1, ``N_k y_a <= D_k xi``: the ticks :func:`~reachset_ros.conformance.kernels.sweep`
visits with ``t = m + k``, the checks the online monitor makes at tick t). The *set use* of
tick t is the largest ratio of a deviation to its bound over those checks and half-spaces,
``max (N_k y_a) / d+_k`` and ``max (-N_k y_a) / d-_k``: 0 at the nominal prediction, 1.0 on
the boundary of R_a[k], above 1 a violation. It is computed from the same sweep, normals and
offsets as :func:`~reachset_ros.conformance.theorem1.check`, and marks the same violating ticks
(``use > 1`` exactly where ``check`` counts a violation, NaN deviations included: their use is
infinite, fail closed). Ticks at which nothing is checked have use NaN.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .kernels import as_2d, matvec, sweep

__all__ = ["SetUse", "check_use", "set_use"]

#: the smallest use reported for a violated check (a ratio of exactly 1.0 can still be a
#: violation after rounding; a violation is always reported above 1)
_ABOVE_ONE = float(np.nextafter(1.0, 2.0))


@dataclass(frozen=True)
class SetUse:
    """Set use of one joint's recording, per measurement tick.

    Attributes
    ----------
    use : ndarray (T,)
        Largest ``|deviation| / bound`` over the checks of the tick (NaN: nothing checked).
    violating : ndarray of bool (T,)
        The ticks :func:`~reachset_ros.conformance.theorem1.check` counts as violations.
    test_cases : int
    """

    use: np.ndarray
    violating: np.ndarray
    test_cases: int


def _ratio(dev, bound, violated):
    """Per half-space, ``dev / bound`` where the bound is positive; a non-positive bound counts
    1 when respected and infinity when violated; a NaN deviation counts infinity (fail closed)."""
    pos = bound > 0
    with np.errstate(divide="ignore", invalid="ignore"):
        r = np.where(pos, dev / np.where(pos, bound, 1.0), np.where(violated, np.inf, 1.0))
    return np.where(np.isnan(r), np.inf, r)


def check_use(Ny, dp, dm):
    """The use of the reachable set by each check: the one formula of the batch side
    (:func:`set_use`) and the online monitor (:meth:`~reachset_ros.conformance.monitor.Monitor._tick_numpy`;
    the compiled tick ``_tick.c`` performs the same operations, bit for bit).

    Parameters
    ----------
    Ny : ndarray (q, M)
        ``N_k y_a`` of M checks (columns) with q half-space pairs each (Theorem 1).
    dp, dm : ndarray broadcastable to (q, M)
        Their offsets ``d+_k`` and ``d-_k`` (``-d-_k <= N_k y_a <= d+_k``).

    Returns
    -------
    use : ndarray (M,)
        ``max(N y_a / d+, -N y_a / d-)`` over the rows: at most 1.0 where every row holds,
        above 1 (at least ``nextafter(1, 2)``) where one is violated; a NaN deviation counts
        infinity (fail closed).
    violated : ndarray of bool (M,)
        Some row violated (``not (d+ - N y_a >= 0)`` or ``not (d- + N y_a >= 0)``, the
        monitor's and :func:`~reachset_ros.conformance.theorem1.check`'s test).
    """
    mp = dp - Ny
    mm = dm + Ny
    vp, vm = ~(mp >= 0), ~(mm >= 0)                    # a NaN margin is a violation (as check)
    viol = vp.any(axis=0) | vm.any(axis=0)
    r = np.maximum(_ratio(Ny, dp, vp).max(axis=0), _ratio(-Ny, dm, vm).max(axis=0))
    # a violation is above 1, a respected bound at most 1 (x <= d > 0 gives x / d <= 1 exactly);
    # + 0.0 makes a use of -0.0 (a deviation of exactly 0 at k = 0) +0.0, so that the largest of
    # several uses has one bit pattern whatever the order they are compared in (online = batch)
    return np.where(viol, np.maximum(r, _ABOVE_ONE), np.minimum(r, 1.0)) + 0.0, viol


def set_use(plant, thm, estimator, xi, y, u, segments, horizon):
    """The set use of every tick of a recording (Theorem 1's checks, as
    :func:`~reachset_ros.conformance.theorem1.check` makes them).

    Parameters
    ----------
    plant, thm, estimator, xi, y, u, segments, horizon
        As :func:`~reachset_ros.conformance.theorem1.check` (``xi``: the checked sets,
        :meth:`~reachset_ros.conformance.model.ConformanceModel.checked_xi`).

    Returns
    -------
    SetUse
    """
    offs = thm.offsets(xi)
    T = len(as_2d(y))
    use = np.full(T, np.nan)
    bad = np.zeros(T, dtype=bool)

    def visit(k, m, t, ya):
        dp, dm = offs[k]
        r, viol = check_use(matvec(thm.normals[k], ya), dp[:, None], dm[:, None])
        bad[t[viol]] = True
        np.fmax.at(use, t, r)

    M = sweep(plant, estimator, y, u, segments, horizon, visit)
    return SetUse(use, bad, M)
