"""Held-out validation, inflation calibration and fault injection (beyond the paper).

A conformance model is reachset conformant on the test cases it was identified from
(Def. 4); these functions measure how it does on held-out recordings. :func:`check_many`
is Theorem 1's batch check (:func:`~reachset_ros.conformance.theorem1.check`) for several
parameter vectors in one sweep, counting violated test cases too; :func:`validation_grid`
picks the smallest set inflation with no held-out violation (``reachset identify
--validate``); :func:`inject_acceleration_fault` and :func:`detection_delay` measure how
fast a test fault is detected at that inflation.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .. import defaults
from ..errors import ReachsetError
from .kernels import as_2d, matvec, sweep

defaults.register("detection", {
    "within_s": (0.1, "seconds: a fault counts as stopped in time when the monitor stops within this time of "
                      "the first measurement it can change (issue 35.5). The one window of the minimum detectable "
                      "fault (sim.detectability, benchmarks/min_detectable.py), of identify's detection cost "
                      "(identify.detection_window) and of the demo's promise on a fault's detection latency (50 ms "
                      "before 2026-12-01, issue 16.3's, set for its default fault; issue 35 judges the demo's "
                      "hidden fault cases within 100 ms)"),
}, owner=__name__)


@dataclass(frozen=True)
class CaseCheck:
    """A batch check (as :class:`~.theorem1.CheckResult`) that also counts violated test cases."""

    violations: int               # measurement ticks at which some test case is outside
    first_violation_tick: int
    violated_test_cases: int      # test cases (start ticks) with a violation at some k
    test_cases: int               # = checked measurement ticks (each valid tick starts one)
    checks: int
    worst_margin: float
    bad: np.ndarray               # bool (T,): violating measurement ticks


def check_many(plant, thm, estimator, xis, y, u, segments, horizon):
    """:func:`~.theorem1.check` for several parameter vectors in one sweep (same arithmetic, same verdicts).

    Every measurement tick after a segment's estimator history starts a test case and is
    checked at k = 0, so ``test_cases`` is also the number of checked ticks.
    """
    offs = [thm.offsets(np.asarray(x, float)) for x in xis]
    T = len(as_2d(y))
    bad = [np.zeros(T, dtype=bool) for _ in xis]
    badm = [np.zeros(T, dtype=bool) for _ in xis]
    margin = [np.inf] * len(xis)
    checks = [0]

    def visit(k, m, t, ya):
        Ny = matvec(thm.normals[k], ya)
        checks[0] += ya.shape[1]
        for i, o in enumerate(offs):
            dp, dm = o[k]
            mp = dp[:, None] - Ny
            mm = dm[:, None] + Ny
            viol = (mp < 0).any(axis=0) | (mm < 0).any(axis=0)
            bad[i][t[viol]] = True
            badm[i][m[viol]] = True
            margin[i] = min(margin[i], float(mp.min()), float(mm.min()))

    M = sweep(plant, estimator, y, u, segments, horizon, visit)
    out = []
    for i in range(len(xis)):
        idx = np.flatnonzero(bad[i])
        out.append(CaseCheck(int(bad[i].sum()), int(idx[0]) if len(idx) else -1,
                             int(badm[i].sum()), M, checks[0], margin[i], bad[i]))
    return out


def inject_acceleration_fault(y, segments, onset, accel, dt):
    """Test fault: a constant acceleration ``accel`` (rad/s^2) from tick ``onset`` on.

    The measured position gets the double integrator of the disturbance,
    ``y[t] += accel/2 * ((t - onset) dt)^2`` for ``onset <= t < end`` of the segment that
    contains ``onset`` (the recorded inputs are unchanged). Returns a new array.
    """
    y = np.array(as_2d(y), float, copy=True)
    for s, e in segments:
        if s <= onset < e:
            tt = (np.arange(onset, e) - onset) * dt
            y[onset:e] += 0.5 * accel * tt[:, None] ** 2
            return y
    raise ReachsetError(f"fault onset tick {onset} is not in a valid segment")


def fault_onset_tick(segments, history):
    """Default onset: the middle of the longest segment's checked ticks."""
    s, e = max(segments, key=lambda se: se[1] - se[0])
    if e - s - history < 2:
        raise ReachsetError("validation data too short to inject a test fault")
    return s + history + (e - s - history) // 2


def detection_delay(plant, thm, estimator, xi, y, u, segments, horizon, accel, dt, onset=None):
    """Ticks from a test fault's onset to the first violation (see :func:`inject_acceleration_fault`).

    Returns a dict: ``onset_tick``, ``accel``, ``detected``, ``delay_ticks`` and ``delay_s``
    (None if not detected before the segment ends), ``alarms_before_onset`` (violating
    ticks before the onset; the fault changes nothing there).
    """
    y = as_2d(y)
    onset = fault_onset_tick(segments, estimator.history) if onset is None else int(onset)
    yf = inject_acceleration_fault(y, segments, onset, accel, dt)
    r = check_many(plant, thm, estimator, [xi], yf, u, segments, horizon)[0]
    after = np.flatnonzero(r.bad[onset:])
    d = int(after[0]) if len(after) else None
    return {"onset_tick": int(onset), "accel": float(accel), "detected": d is not None,
            "delay_ticks": d, "delay_s": None if d is None else d * float(dt),
            "alarms_before_onset": int(r.bad[:onset].sum())}


def validation_grid(plant, thm, estimator, joint_sets, y, u, segments, horizon, grid):
    """Held-out violation rates of one joint for inflations 0 and ``grid`` (one sweep).

    ``joint_sets`` is a :class:`~reachset_ros.conformance.model.JointSets`; inflation s checks with
    ``joint_sets.xi(s)`` exactly as ``reachset check`` would with the model's inflation s.
    Returns (rows, chosen, flagged): a row per inflation, the smallest grid inflation with no
    held-out violation (or the largest grid value, ``flagged=True``).
    """
    infl = sorted({0.0, *map(float, grid)})
    res = check_many(plant, thm, estimator, [joint_sets.xi(s) for s in infl], y, u, segments, horizon)
    rows = []
    for s, r in zip(infl, res):
        rows.append({"inflation": s, "violating_ticks": r.violations, "checked_ticks": r.test_cases,
                     "violation_rate": r.violations / r.test_cases if r.test_cases else 0.0,
                     "violated_test_cases": r.violated_test_cases, "test_cases": r.test_cases,
                     "first_violation_tick": r.first_violation_tick,
                     "worst_margin": r.worst_margin if r.checks else None})
    ok = [row["inflation"] for row in rows if row["violating_ticks"] == 0]
    if ok:
        return rows, ok[0], False
    return rows, infl[-1], True
