"""Inflation by K-fold cross-validation inside the identification data (``identify --calibrate K``).

A reachset-conformant model is conformant on the test cases it was identified from
(Definition 4, Theorem 1), not on behaviour it has not seen. The inflation s (the monitor
checks the sets scaled by 1 + s) buys margin for unseen data; :func:`cross_validate` chooses
it from the training data alone, so that held-out data stay held out:

1. The recording is cut into *runs*: maximal stretches of consecutive stamps (a pause
   between recordings, a lost tick, ends one; :func:`reachset_ros.bags.series.segments_of`
   with every sample valid). In a bag from ``reachset import-lwa4p`` each run is one
   recording. With fewer runs than folds, the longest is halved until there are K blocks
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

This is an empirical calibration, not a guarantee: it says how much the sets had to grow
for data of the same kind that the identification did not see. The final sets are
identified on all folds, and ``reachset check`` on held-out data is the test of it
(docs/real-data.md).
"""
from __future__ import annotations

import numpy as np

from ..errors import ReachsetError
from .validation import validation_grid

__all__ = ["run_ranges", "blocks", "segment_folds", "cross_validate"]


def run_ranges(stamps, dt):
    """Index ranges ``(start, stop)`` of the runs of sorted stamps: consecutive stamps within
    ``[0.5, 1.5] dt`` of each other (every sample counted, valid or not)."""
    from ..bags import segments_of     # the one definition of "consecutive"
    return segments_of(stamps, np.ones(len(stamps), dtype=bool), dt)


def blocks(stamps, k, dt):
    """The folds' blocks of sorted stamps: the runs (:func:`run_ranges`), and while there are
    fewer than ``k`` the longest block halved (a single long recording becomes ``k``
    contiguous blocks). Index ranges ``(start, stop)`` in stamp order."""
    out = list(run_ranges(stamps, dt))
    while 0 < len(out) < k:
        i = max(range(len(out)), key=lambda j: out[j][1] - out[j][0])
        a, b = out[i]
        if b - a < 2:
            break
        m = (a + b) // 2
        out[i:i + 1] = [(a, m), (m, b)]
    return out


def segment_folds(series, k, dt):
    """The segments of a :class:`~reachset_ros.bags.series.JointSeries` cut at its block
    boundaries (:func:`blocks`), each with its fold (block index mod ``k``).

    Returns (segments, folds, n_blocks, n_runs). A segment is only cut where two blocks of
    one run meet (a long recording split for lack of runs); the test cases that would
    cross that boundary are dropped, never split between folds.
    """
    runs = run_ranges(series.stamps, dt)
    bl = blocks(series.stamps, k, dt)
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


class _Sub:
    """A series restricted to some of its segments (same arrays)."""

    def __init__(self, s, segments):
        self.name, self.stamps, self.y, self.u, self.dt = s.name, s.stamps, s.y, s.u, s.dt
        self.segments = tuple(segments)


def cross_validate(plant, estimator, series, horizon, k, grid, identify, thm):
    """Per-joint inflation by ``k``-fold cross-validation (module docstring).

    Parameters
    ----------
    plant, estimator, horizon, thm
        As for :func:`reachset_ros.conformance.validation.validation_grid`.
    series : dict name -> JointSeries
        The identification data.
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
        segs, folds, n_blocks, n_runs = segment_folds(s, k, s.dt)
        if n_blocks < k:
            raise ReachsetError(f"--calibrate {k}: joint {name} has {n_blocks} stretches of consecutive stamps "
                                f"long enough to split; K folds need at least K")
        assign[name] = (segs, folds)
        out[name] = {"inflation": 0.0, "flagged": False, "folds": [], "runs": n_runs, "blocks": n_blocks}
    for f in range(k):
        train = {n: _Sub(s, [seg for seg, g in zip(*assign[n]) if g != f]) for n, s in series.items()}
        held = {n: [seg for seg, g in zip(*assign[n]) if g == f] for n, s in series.items()}
        sets = identify(train)
        for n, s in series.items():
            rows, chosen, flagged = validation_grid(plant, thm, estimator, sets[n], s.y, s.u, held[n], horizon, grid)
            out[n]["folds"].append({"fold": f, "segments": len(held[n]), "test_cases": rows[0]["test_cases"],
                                    "chosen_inflation": chosen, "violating_ticks_at_zero": rows[0]["violating_ticks"],
                                    "flagged": flagged})
            out[n]["inflation"] = max(out[n]["inflation"], chosen)
            out[n]["flagged"] = out[n]["flagged"] or flagged
    return out
