"""Inflation by K-fold cross-validation inside the identification data (``identify --calibrate K``).

A reachset-conformant model is conformant on the test cases it was identified from
(Definition 4, Theorem 1), not on behaviour it has not seen. The inflation s (the monitor
checks the sets scaled by 1 + s) buys margin for unseen data; :func:`cross_validate` chooses
it from the training data alone, so that held-out data stay held out:

1. The recording is cut into *runs*: maximal stretches of consecutive stamps (a pause
   between recordings, a lost tick, ends one; given by the caller, who reads the bags:
   :func:`reachset_ros.workflows.identify.run_ranges`). In a bag from ``reachset
   import-lwa4p`` each run is one recording. With fewer runs than folds, the longest is halved until there are K blocks
   (one long recording becomes K contiguous blocks; the test cases that would cross such
   a cut are dropped, about k* per cut).
2. Block r (in stamp order) goes to fold ``r mod K``; every segment (test cases never span
   two) belongs to the block it lies in, so a test case is never split between folds.
3. For each fold, the sets are identified on the other K-1 folds and checked on the fold
   with exactly ``reachset check``'s arithmetic
   (:func:`reachset_ros.conformance.validation.validation_grid`) for inflation 0 and each grid
   value; the fold's inflation is the smallest grid value with no violation.
4. A joint's inflation is the largest over its folds (``flagged`` if some fold is violated
   at every grid value).

A fold too small to mean anything is refused before anything is identified: every fold
must hold at least :data:`MIN_FOLD_HORIZONS` horizons of samples, ``MIN_FOLD_HORIZONS (k* + 1)``
on every joint (that many test cases that share no sample; 1260 samples, 5.04 s, at the
paper's k* = 125). Before, one short recording halved into K blocks gave "5 folds of 1 runs"
whose verdicts rested on a handful of independent test cases each.

This is an empirical calibration, not a guarantee: it says how much the sets had to grow
for data of the same kind that the identification did not see. The final sets are
identified on all folds, and ``reachset check`` on held-out data is the test of it
(docs/real-data.md).
"""
from __future__ import annotations

import numpy as np

from .. import guarantees
from ..errors import ReachsetError
from .validation import validation_grid

__all__ = ["MIN_FOLD_HORIZONS", "blocks", "segment_folds", "cross_validate"]

#: the least data a fold may hold: this many horizons of k* + 1 samples (module docstring)
MIN_FOLD_HORIZONS = 10


def blocks(runs, k):
    """The folds' blocks: the ``runs`` (index ranges ``(start, stop)`` of the stretches of
    consecutive stamps, :func:`reachset_ros.workflows.identify.run_ranges`), and while there
    are fewer than ``k`` the longest block halved (a single long recording becomes ``k``
    contiguous blocks). Index ranges ``(start, stop)`` in stamp order."""
    out = list(runs)
    while 0 < len(out) < k:
        i = max(range(len(out)), key=lambda j: out[j][1] - out[j][0])
        a, b = out[i]
        if b - a < 2:
            break
        m = (a + b) // 2
        out[i:i + 1] = [(a, m), (m, b)]
    return out


def segment_folds(series, k, runs):
    """The segments of a :class:`~reachset_ros.bags.series.JointSeries` cut at its block
    boundaries (:func:`blocks` of its ``runs``), each with its fold (block index mod ``k``).

    Returns (segments, folds, n_blocks, n_runs). A segment is only cut where two blocks of
    one run meet (a long recording split for lack of runs); the test cases that would
    cross that boundary are dropped, never split between folds.
    """
    bl = blocks(runs, k)
    starts = np.array([a for a, _ in bl], dtype=np.int64)
    segs, folds = [], []
    for a, b in series.segments:
        i = int(np.searchsorted(starts, a, side="right")) - 1
        while a < b:
            stop = min(b, bl[i][1])
            segs.append((a, stop))
            folds.append(i % k)
            a, i = stop, i + 1
    return segs, folds, len(bl), len(runs)


def _require_fold_size(name, segs, folds, *, k, horizon, dt, n_blocks, n_runs):
    """Refuse (one line naming the numbers) a fold with fewer than ``MIN_FOLD_HORIZONS (k* + 1)`` samples."""
    need = MIN_FOLD_HORIZONS * (int(horizon) + 1)
    ticks = [sum(b - a for (a, b), g in zip(segs, folds) if g == f) for f in range(k)]
    f = int(np.argmin(ticks))
    if ticks[f] < need:
        raise guarantees.refused("G20", f"--calibrate {k}: fold {f} of joint {name} holds {ticks[f]} samples "
                            f"({ticks[f] * dt:.2f} s; {n_runs} runs cut into {n_blocks} blocks for {k} folds), a fold "
                            f"needs at least {MIN_FOLD_HORIZONS} horizons of k*+1 = {int(horizon) + 1} samples "
                            f"({need} samples, {need * dt:.2f} s): record more or use fewer folds")


class _Sub:
    """A series restricted to some of its segments (same arrays)."""

    def __init__(self, s, segments):
        self.name, self.stamps, self.y, self.u, self.dt = s.name, s.stamps, s.y, s.u, s.dt
        self.segments = tuple(segments)


def cross_validate(plant, estimator, series, *, horizon, k, grid, identify, thm, runs):
    """Per-joint inflation by ``k``-fold cross-validation (module docstring).

    Parameters
    ----------
    plant, estimator, horizon, thm
        As for :func:`reachset_ros.conformance.validation.validation_grid`.
    series : dict name -> JointSeries
        The identification data.
    runs : dict name -> sequence of (start, stop)
        Each joint's runs: index ranges of its stretches of consecutive stamps
        (:func:`reachset_ros.workflows.identify.run_ranges`).
    k : int
        Number of folds (>= 2).
    grid : sequence of float
        Inflations tried (0 is always tried first).
    identify : callable
        ``identify({name: series}) -> {name: JointSets}`` with the command's options.

    Returns
    -------
    dict name -> {"inflation", "flagged", "folds": [{"fold", "segments", "test_cases",
    "chosen_inflation", "violating_ticks_at_zero", "flagged"}, ...], "runs": int, "blocks": int}
    """
    if int(k) != k or k < 2:
        raise ReachsetError(f"--calibrate needs K >= 2 folds, got {k}")
    k = int(k)
    assign, out = {}, {}
    for name, s in series.items():
        segs, folds, n_blocks, n_runs = segment_folds(s, k, runs[name])
        if n_blocks < k:
            raise ReachsetError(f"--calibrate {k}: joint {name} has {n_blocks} stretches of consecutive stamps "
                                f"long enough to split; K folds need at least K")
        assign[name] = (segs, folds)
        _require_fold_size(name, segs, folds, k=k, horizon=horizon, dt=s.dt, n_blocks=n_blocks, n_runs=n_runs)
        out[name] = {"inflation": 0.0, "flagged": False, "folds": [], "runs": n_runs, "blocks": n_blocks}
    for f in range(k):
        train = {n: _Sub(s, [seg for seg, g in zip(*assign[n]) if g != f]) for n, s in series.items()}
        held = {n: [seg for seg, g in zip(*assign[n]) if g == f] for n, s in series.items()}
        sets = identify(train)
        for n, s in series.items():
            rows, chosen, flagged = validation_grid(plant, thm, estimator, sets[n], s.y, s.u, segments=held[n],
                                                    horizon=horizon, grid=grid)
            out[n]["folds"].append({"fold": f, "segments": len(held[n]), "test_cases": rows[0]["test_cases"],
                                    "chosen_inflation": chosen, "violating_ticks_at_zero": rows[0]["violating_ticks"],
                                    "flagged": flagged})
            out[n]["inflation"] = max(out[n]["inflation"], chosen)
            out[n]["flagged"] = out[n]["flagged"] or flagged
    return out
