"""The validated envelope: where the data a model was identified on lie (issue 37).

A conformance model covers the behaviours it was tested on (paper, Def. 4): Theorem 1 makes
the sets enclose the deviations of *these* test cases, and the calibration (``--calibrate``)
grows them for data of the same kind. Motion of another kind (a new pose, a new speed) may
leave the reachable sets although nothing is broken. The envelope records, per joint, the
region of the identification data in a few features, so that every tick can be classified
*inside* (the model was validated on such data) or *outside* (it never saw them): an
**empirical record of where the data were, not a guarantee** (docs/theory.md, row G21).

Features of a tick t of one joint (:func:`features`), computed from the samples up to t of the
same segment only (causal: the monitor computes them online with the same function):

* ``q``: the measured position y[t];
* ``qd``: a backward difference ``(y[t] - y[t-L_v]) / (L_v dt)``, ``L_v`` = :data:`VELOCITY_LAG`;
* ``qdd``: a backward second difference ``(y[t] - 2 y[t-L_a] + y[t-2 L_a]) / (L_a dt)^2``,
  ``L_a`` = :data:`ACCELERATION_LAG`;
* ``u``: the plant input u_p[t] (rad/s^2; from the effort when the model's ``input_source`` is).

A feature whose samples are not there yet (the first ticks of a segment) is NaN: not known, not
checked. The representation (:class:`JointEnvelope`): each feature's axis (its training range
cut into ``bins`` cells and widened by ``dilation`` cells on both sides; outside it a tick is
outside) and occupancy grids over pairs of features (a cell is occupied when a training tick,
or one within ``dilation`` cells of it, lies there). With no grids the envelope is a per-joint
box. A tick is inside when every known feature is on its axis and every grid whose two features
are known has its cell occupied (:func:`inside`). ``hold``: a tick is classified outside when
some tick of the last ``hold`` ticks of its segment was (:func:`held_outside`,
:class:`EnvelopeTracker`): a test case started up to k* ticks ago reports at this tick.

The choice of features, grids, bins and hold was measured on the real LWA-4P data
(``benchmarks/envelope.py``, docs/real-data.md, "Validated envelope").
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ..errors import ReachsetError

__all__ = ["ACCELERATION_LAG", "FEATURES", "FORMAT", "HISTORY", "VELOCITY_LAG", "Envelope", "EnvelopeTracker",
           "JointEnvelope", "OUTSIDE_ENVELOPE", "Packed", "classify_series", "features", "fit", "from_dict", "held_outside", "inside", "inside_packed", "pack",
           "outside_reason", "series_features", "summary", "tick_counts", "to_dict", "track", "violation_note",
           "ClassBounds", "unvalidated"]

FORMAT = "reachset_ros/envelope/1"
#: the features of a tick, in this order (module docstring)
FEATURES = ("q", "qd", "qdd", "u")
#: ticks of the velocity's backward difference (16 ms at 4 ms: the coverage's +-2 central difference)
VELOCITY_LAG = 4
#: ticks of the acceleration's backward second difference (the coverage's +-10)
ACCELERATION_LAG = 10
#: samples before a tick that its features need
HISTORY = 2 * ACCELERATION_LAG


def features(q0, q_v, q_a1, q_a2, u, dt):
    """The features (:data:`FEATURES`) of ticks: positions ``q0`` = y[t], ``q_v`` = y[t-L_v],
    ``q_a1`` = y[t-L_a], ``q_a2`` = y[t-2 L_a] (NaN where not in the segment), plant input
    ``u``; arrays of one shape, or scalars. Returns the features stacked on a last axis.

    The one formula of both the batch classification (:func:`series_features`) and the
    online one (:class:`EnvelopeTracker`): the same floating-point operations, so the two
    classify every tick alike.
    """
    q0 = np.asarray(q0, dtype=np.float64)
    out = np.empty(q0.shape + (len(FEATURES),))
    out[..., 0] = q0
    out[..., 1] = (q0 - q_v) / (VELOCITY_LAG * dt)
    out[..., 2] = (q0 - 2.0 * np.asarray(q_a1, dtype=np.float64) + q_a2) / (ACCELERATION_LAG * dt) ** 2
    out[..., 3] = u
    return out


def _lagged(y, segments, lag):
    """y[t - lag] where t - lag is in t's segment, else NaN (an array of y's length)."""
    out = np.full(len(y), np.nan)
    for a, b in segments:
        if b - a > lag:
            out[a + lag:b] = y[a:b - lag]
    return out


def series_features(y, u, segments, dt):
    """The features of every tick of one joint's series (positions ``y``, plant input ``u``)
    inside ``segments`` (:class:`~reachset_ros.bags.series.JointSeries`): shape (T, 4), rows
    of ticks outside every segment all NaN."""
    y = np.asarray(y, dtype=np.float64)
    inseg = np.zeros(len(y), dtype=bool)
    for a, b in segments:
        inseg[a:b] = True
    q0 = np.where(inseg, y, np.nan)
    F = features(q0, _lagged(y, segments, VELOCITY_LAG), _lagged(y, segments, ACCELERATION_LAG),
                 _lagged(y, segments, 2 * ACCELERATION_LAG), np.where(inseg, np.asarray(u, float), np.nan), dt)
    F[~inseg] = np.nan
    return F


@dataclass(frozen=True, kw_only=True)
class Axis:
    """One feature's cells: cell i is ``[origin + i cell, origin + (i+1) cell)``, i in [0, cells)."""

    origin: float
    cell: float
    cells: int

    def index(self, x):
        """Cell indices of values ``x`` (-1 where outside the axis or NaN)."""
        with np.errstate(invalid="ignore"):
            i = np.floor((np.asarray(x, dtype=np.float64) - self.origin) / self.cell)
        ok = np.isfinite(i) & (i >= 0) & (i < self.cells)
        return np.where(ok, i, -1).astype(np.int64)


@dataclass(frozen=True, kw_only=True)
class Grid:
    """An occupancy grid over two features: ``occupied[i, j]`` for cells of their axes."""

    features: tuple
    occupied: np.ndarray = field(compare=False)


@dataclass(frozen=True, kw_only=True)
class JointEnvelope:
    """One joint's envelope: an axis per feature and the occupancy grids (module docstring)."""

    axes: dict
    grids: tuple = ()
    ticks: int = 0          # training ticks it was fitted on


@dataclass(frozen=True, kw_only=True)
class Envelope:
    """The region of data a model was validated on, per joint (an immutable value).

    Attributes
    ----------
    joints : dict
        ``{name: JointEnvelope}``.
    dt : float
        The sampling period the features were computed with.
    bins, dilation : int
        Cells per feature across the training range; cells added around every occupied one.
    hold : int
        Ticks a tick outside keeps the classification outside (:func:`held_outside`).
    grids : tuple of (str, str)
        The feature pairs with occupancy grids (empty: per-joint boxes).
    """

    joints: dict
    dt: float
    bins: int
    dilation: int
    hold: int
    grids: tuple = ()


def _axis(x, bins, dilation):
    x = x[np.isfinite(x)]
    if x.size == 0:
        raise ReachsetError("envelope: a feature has no finite value in the data")
    lo, hi = float(x.min()), float(x.max())
    cell = max(hi - lo, 1e-9 * max(1.0, abs(lo), abs(hi))) / bins
    # one more cell than the span so that the largest value (at lo + bins cell) is on the axis
    return Axis(origin=lo - dilation * cell, cell=cell, cells=bins + 1 + 2 * dilation)


def _dilate(occ, d):
    """Cells within ``d`` cells (Chebyshev) of an occupied one."""
    out = occ.copy()
    n, m = occ.shape
    for di in range(-d, d + 1):
        for dj in range(-d, d + 1):
            src = occ[max(0, -di):n - max(0, di), max(0, -dj):m - max(0, dj)]
            out[max(0, di):n - max(0, -di), max(0, dj):m - max(0, -dj)] |= src
    return out


def fit_joint(F, *, bins, dilation, grids):
    """A :class:`JointEnvelope` of one joint's training features ``F`` (T, 4)."""
    axes = {f: _axis(F[:, i], bins, dilation) for i, f in enumerate(FEATURES)}
    out = []
    for a, b in grids:
        ia, ib = axes[a].index(F[:, FEATURES.index(a)]), axes[b].index(F[:, FEATURES.index(b)])
        ok = (ia >= 0) & (ib >= 0)
        occ = np.zeros((axes[a].cells, axes[b].cells), dtype=bool)
        occ[ia[ok], ib[ok]] = True
        out.append(Grid(features=(a, b), occupied=_dilate(occ, dilation)))
    known = np.isfinite(F).all(axis=1)
    return JointEnvelope(axes=axes, grids=tuple(out), ticks=int(known.sum()))


def fit(series, *, bins, dilation, hold, grids=(("q", "qd"), ("qd", "u"))):
    """The :class:`Envelope` of training data ``series`` ({name: JointSeries}, all with one dt).

    Only the identification's own data enter (the held-out rule: runs held out never fit it).
    """
    if not series:
        raise ReachsetError("envelope: no data")
    if bins < 1 or dilation < 0 or hold < 0:
        raise ReachsetError(f"envelope: bins >= 1, dilation >= 0 and hold >= 0 needed, got {bins}, {dilation}, {hold}")
    for a, b in grids:
        if a not in FEATURES or b not in FEATURES or a == b:
            raise ReachsetError(f"envelope: bad grid ({a}, {b}); features are {', '.join(FEATURES)}")
    dt = float(next(iter(series.values())).dt)
    joints = {n: fit_joint(series_features(s.y, s.u, s.segments, dt), bins=bins, dilation=dilation, grids=grids)
              for n, s in series.items()}
    return Envelope(joints=joints, dt=dt, bins=int(bins), dilation=int(dilation), hold=int(hold),
                    grids=tuple(tuple(g) for g in grids))


@dataclass(frozen=True, kw_only=True)
class Packed:
    """Joints' envelopes as arrays (:func:`pack`), so that :func:`inside_packed` classifies one
    tick of every joint in a few vector operations (the monitor's budget is a tick of 4 ms)."""

    origin: np.ndarray = field(compare=False)     # (J, 4)
    cell: np.ndarray = field(compare=False)       # (J, 4)
    cells: np.ndarray = field(compare=False)      # (J, 4)
    grids: tuple = field(compare=False)           # ((a, b, occupied (J, A, B) padded with False), ...)
    joint: np.ndarray = field(compare=False)      # arange(J)


def pack(joint_envelopes):
    """The :class:`Packed` form of a list of :class:`JointEnvelope` (all with the same grids)."""
    js = list(joint_envelopes)
    origin = np.array([[j.axes[f].origin for f in FEATURES] for j in js], dtype=np.float64)
    cell = np.array([[j.axes[f].cell for f in FEATURES] for j in js], dtype=np.float64)
    cells = np.array([[j.axes[f].cells for f in FEATURES] for j in js], dtype=np.int64)
    grids = []
    for g, feats in enumerate(js[0].grids if js else ()):
        a, b = (FEATURES.index(f) for f in feats.features)
        occ = np.zeros((len(js), int(cells[:, a].max()), int(cells[:, b].max())), dtype=bool)
        for k, j in enumerate(js):
            o = j.grids[g].occupied
            occ[k, :o.shape[0], :o.shape[1]] = o
        grids.append((a, b, occ))
    return Packed(origin=origin, cell=cell, cells=cells, grids=tuple(grids), joint=np.arange(len(js)))


def inside_packed(p: Packed, F):
    """Whether ticks with features ``F`` (..., J, 4) of the packed joints lie inside their
    envelopes: every known (finite) feature on its axis (cell ``floor((x - origin) / cell)`` in
    ``[0, cells)``), and every grid of two known features occupied there. The one law ``check``,
    ``replay`` and the monitor classify with (:func:`inside` is its one-joint form)."""
    F = np.asarray(F, dtype=np.float64)
    known = np.isfinite(F)
    i = np.floor((F - p.origin) / p.cell)       # NaN and inf propagate without a warning
    on = known & (i >= 0) & (i < p.cells)
    ok = (~known | on).all(axis=-1)
    idx = np.where(on, i, 0).astype(np.int64)
    joint = p.joint if F.ndim == 2 else np.broadcast_to(p.joint, F.shape[:-1])
    for a, b, occ in p.grids:
        both = on[..., a] & on[..., b]
        ok &= ~both | occ[joint, idx[..., a], idx[..., b]]
    return ok


def inside(je: JointEnvelope, F):
    """Whether ticks with features ``F`` (..., 4) lie inside one joint's envelope
    (:func:`inside_packed` of that joint)."""
    F = np.asarray(F, dtype=np.float64)
    return inside_packed(pack([je]), F[..., None, :])[..., 0]


def held_outside(outside, segments, hold):
    """Ticks outside, or within ``hold`` ticks after one outside in the same segment (the
    batch form of :class:`EnvelopeTracker`'s counter)."""
    out = np.zeros(len(outside), dtype=bool)
    for a, b in segments:
        o = np.asarray(outside[a:b], dtype=bool)
        idx = np.arange(b - a)
        last = np.maximum.accumulate(np.where(o, idx, -(hold + 1) - 1))
        out[a:b] = idx - last <= hold
    return out


def classify_series(env: Envelope, name, s):
    """Per tick of joint ``name``'s series ``s``, whether it is classified outside (bool array;
    False outside every segment: such ticks are not classified) and how many ticks were
    classified (those inside a segment)."""
    if name not in env.joints:
        raise ReachsetError(f"envelope: joint {name} has no envelope recorded")
    F = series_features(s.y, s.u, s.segments, env.dt)
    out = ~inside(env.joints[name], F)
    inseg = np.zeros(len(s.y), dtype=bool)
    for a, b in s.segments:
        inseg[a:b] = True
    out &= inseg
    return held_outside(out, s.segments, env.hold), int(inseg.sum())


def tick_counts(env, name, s, violating):
    """Per joint the ``check``/``replay`` JSON of the envelope: ``outside_envelope_ticks`` (ticks
    of ``s`` classified outside, :func:`classify_series`), ``violations_inside_envelope`` (ticks of
    the bool array ``violating``, some test case outside its reachable set, that are classified
    inside) and ``classified_ticks``. Without an envelope (``env`` None, or none for ``name``)
    the counts are None: the model records none, nothing is guessed."""
    if env is None or name not in env.joints:
        return {"outside_envelope_ticks": None, "violations_inside_envelope": None, "classified_ticks": None}
    out, n = classify_series(env, name, s)
    return {"outside_envelope_ticks": int(out.sum()),
            "violations_inside_envelope": int((np.asarray(violating, dtype=bool) & ~out).sum()),
            "classified_ticks": n}


def summary(env):
    """The ``envelope`` object of ``check``'s and ``replay``'s JSON: whether the model records
    one, and with what (module docstring)."""
    if env is None:
        return {"recorded": False, "note": "the model records no validated envelope (identified before issue 37): "
                                           "ticks are not classified; re-identify to record one"}
    return {"recorded": True, "bins": env.bins, "dilation": env.dilation, "hold": env.hold,
            "grids": [list(g) for g in env.grids], "joints": sorted(env.joints)}


#: the monitor node's ``outside_envelope`` values: what it does at a tick outside the envelope
OUTSIDE_ENVELOPE = ("warn", "stop")


def violation_note(outside):
    """The words a violation's stop reason ends with (issue 37): whether the violating joint's
    data were inside the validated envelope (``outside`` False), outside it (True) or whether
    the model records none (None)."""
    if outside is None:
        return "; the model records no validated envelope"
    if outside:
        return "; the data were OUTSIDE the validated envelope (motion the model was never validated on)"
    return "; the data were inside the validated envelope (motion of the kind the model was validated on)"


def outside_reason(joints, stamp):
    """The stop reason (``outside_envelope: stop``) or the warning for ``joints`` outside at ``stamp``."""
    return (f"joint {joints[0]}" + (f" (and {len(joints) - 1} more)" if len(joints) > 1 else "")
            + f" outside the validated envelope at stamp {stamp} ns: the model was never validated on such motion")


class EnvelopeTracker:
    """The online classification of one tick of several joints (the monitor's and replay's).

    Keeps the last :data:`HISTORY` positions of each joint and the ticks since the last one
    outside. :meth:`reset` starts a new segment (the monitor's reset; a stamp gap or an
    invalid sample resets it too, as they end the monitor's test cases). :meth:`tick`
    computes the features with :func:`features` and classifies them with :func:`inside`, the
    functions :func:`classify_series` uses: the same verdict tick for tick.
    """

    def __init__(self, env: Envelope, names):
        missing = [n for n in names if n not in env.joints]
        if missing:
            raise ReachsetError(f"envelope: joint {missing[0]} has no envelope recorded")
        self.env, self.names = env, list(names)
        self._packed = pack([env.joints[n] for n in self.names])
        self._hist = np.full((HISTORY + 1, len(self.names)), np.nan)   # row 0: the newest
        self._since = np.full(len(self.names), env.hold + 1, dtype=np.int64)
        self._last_stamp = None

    def reset(self):
        """Forget the history (a new segment)."""
        self._hist[:] = np.nan
        self._since[:] = self.env.hold + 1
        self._last_stamp = None

    def tick(self, stamp_ns, y, u):
        """Classify one tick (positions ``y`` and plant inputs ``u`` of the joints).

        Returns
        -------
        ndarray of bool
            Per joint, whether the tick is classified outside (held, :func:`held_outside`);
            False at an invalid sample (not classified).
        """
        y, u = np.asarray(y, dtype=np.float64), np.asarray(u, dtype=np.float64)
        dt = self.env.dt
        if self._last_stamp is not None and not 0.5 * dt <= (stamp_ns - self._last_stamp) * 1e-9 <= 1.5 * dt:
            self.reset()
        if not (np.isfinite(y).all() and np.isfinite(u).all()):
            self.reset()
            return np.zeros(len(self.names), dtype=bool)
        self._last_stamp = stamp_ns
        self._hist[1:] = self._hist[:-1]
        self._hist[0] = y
        F = features(y, self._hist[VELOCITY_LAG], self._hist[ACCELERATION_LAG], self._hist[2 * ACCELERATION_LAG], u,
                     dt)
        out = ~inside_packed(self._packed, F)
        self._since = np.where(out, 0, np.minimum(self._since + 1, self.env.hold + 1))
        return self._since <= self.env.hold


def track(env: Envelope, names, stamps, Y, U):
    """What a new :class:`EnvelopeTracker` of ``names`` returns tick by tick for these ticks, in
    array operations (``reachset replay``; the tracker's own :meth:`~EnvelopeTracker.tick` is the
    monitor node's).

    The tracker's rules: a stamp step outside [0.5, 1.5] dt from the previous valid tick resets
    it, a tick with a non-finite sample of any joint resets it and is not classified (False); the
    features of a tick are :func:`features` of the positions of its run (the ticks since the last
    reset), classified by :func:`inside_packed`; a tick is held outside while one of the last
    ``hold`` ticks of its run was outside. The same floating-point operations on the same values,
    so the same verdicts (``test/conformance/test_envelope_track.py``).

    Returns
    -------
    ndarray of bool, (T, J)
    """
    stamps = np.asarray(stamps, dtype=np.int64)
    T, J = len(stamps), len(names)
    Y = np.asarray(Y, dtype=np.float64).reshape(T, J)
    U = np.asarray(U, dtype=np.float64).reshape(T, J)
    if T == 0:
        return np.zeros((0, J), dtype=bool)
    dt, hold = env.dt, env.hold
    valid = np.isfinite(Y).all(axis=1) & np.isfinite(U).all(axis=1)
    step = np.diff(stamps) * 1e-9                  # as (stamp_ns - last_stamp) * 1e-9, int to float
    gap = ~((0.5 * dt <= step) & (step <= 1.5 * dt))
    start = np.concatenate([[True], (gap & valid[:-1]) | ~valid[:-1]])      # a reset before the tick
    t = np.arange(T)
    run = np.maximum.accumulate(np.where(start, t, 0))                       # first tick of t's run

    def lagged(lag):
        src = t - lag
        ok = src >= run
        return np.where(ok[:, None], Y[np.maximum(src, 0)], np.nan)

    F = features(Y, lagged(VELOCITY_LAG), lagged(ACCELERATION_LAG), lagged(2 * ACCELERATION_LAG), U, dt)
    out = ~inside_packed(pack([env.joints[n] for n in names]), F) & valid[:, None]   # (T, J)
    last = np.maximum.accumulate(np.where(out, t[:, None], -1), axis=0)      # the last tick outside so far
    held = (last >= run[:, None]) & (t[:, None] - last <= hold)
    return held & valid[:, None]


# ------------------------------------------------------------------ the model file's ``envelope`` block
def _rows(occ):
    return ["".join("1" if v else "0" for v in row) for row in occ]


def to_dict(env: Envelope) -> dict:
    """The model file's ``envelope`` block (occupancy rows as strings of 0 and 1)."""
    return {"format": FORMAT, "features": list(FEATURES), "velocity_lag": VELOCITY_LAG,
            "acceleration_lag": ACCELERATION_LAG, "dt": float(env.dt), "bins": int(env.bins),
            "dilation": int(env.dilation), "hold": int(env.hold), "grids": [list(g) for g in env.grids],
            "joints": {n: {"ticks": int(j.ticks),
                           "axes": {f: {"origin": float(a.origin), "cell": float(a.cell), "cells": int(a.cells)}
                                    for f, a in j.axes.items()},
                           "grids": [{"features": list(g.features), "rows": _rows(g.occupied)} for g in j.grids]}
                       for n, j in env.joints.items()}}


def _num(v, what, source):
    try:
        x = float(v)
    except (TypeError, ValueError):
        raise ReachsetError(f"{source}: envelope {what} must be a number, got {v!r}") from None
    if not math.isfinite(x):
        raise ReachsetError(f"{source}: envelope {what} must be finite, got {v!r}")
    return x


def _count(v, what, source, low=0):
    if isinstance(v, bool) or not isinstance(v, int) or v < low:
        raise ReachsetError(f"{source}: envelope {what} must be an integer >= {low}, got {v!r}")
    return v


def _joint_from(name, j, grids, source):
    if not isinstance(j, dict) or not isinstance(j.get("axes"), dict):
        raise ReachsetError(f"{source}: envelope joint {name}: expected a mapping with axes")
    axes = {}
    for f in FEATURES:
        a = j["axes"].get(f)
        if not isinstance(a, dict):
            raise ReachsetError(f"{source}: envelope joint {name}: no axis {f}")
        cell = _num(a.get("cell"), f"joint {name} axis {f} cell", source)
        if cell <= 0:
            raise ReachsetError(f"{source}: envelope joint {name} axis {f}: cell must be > 0")
        axes[f] = Axis(origin=_num(a.get("origin"), f"joint {name} axis {f} origin", source), cell=cell,
                       cells=_count(a.get("cells"), f"joint {name} axis {f} cells", source, 1))
    gs = j.get("grids", [])
    if not isinstance(gs, list) or [tuple(g.get("features", ())) if isinstance(g, dict) else None
                                    for g in gs] != list(grids):
        raise ReachsetError(f"{source}: envelope joint {name}: grids must be the envelope's {list(grids)}")
    out = []
    for g in gs:
        a, b = g["features"]
        rows = g.get("rows")
        if (not isinstance(rows, list) or len(rows) != axes[a].cells
                or any(not isinstance(r, str) or len(r) != axes[b].cells or set(r) - {"0", "1"} for r in rows)):
            raise ReachsetError(f"{source}: envelope joint {name} grid ({a}, {b}): rows must be {axes[a].cells} "
                                f"strings of {axes[b].cells} 0/1")
        out.append(Grid(features=(a, b), occupied=np.array([[c == "1" for c in r] for r in rows], dtype=bool)))
    return JointEnvelope(axes=axes, grids=tuple(out), ticks=_count(j.get("ticks", 0), f"joint {name} ticks", source))


def from_dict(d, source="model") -> Envelope:
    """Validate and build an :class:`Envelope` from the model file's ``envelope`` block; every
    problem is one :class:`ReachsetError` line naming ``source``."""
    if not isinstance(d, dict):
        raise ReachsetError(f"{source}: envelope must be a mapping")
    if d.get("format") != FORMAT:
        raise ReachsetError(f"{source}: envelope format {d.get('format')!r} is not {FORMAT}")
    if (list(d.get("features", ())) != list(FEATURES) or d.get("velocity_lag") != VELOCITY_LAG
            or d.get("acceleration_lag") != ACCELERATION_LAG):
        raise ReachsetError(f"{source}: envelope features/lags are not this version's ({', '.join(FEATURES)}; "
                            f"lags {VELOCITY_LAG}, {ACCELERATION_LAG})")
    dt = _num(d.get("dt"), "dt", source)
    if dt <= 0:
        raise ReachsetError(f"{source}: envelope dt must be > 0")
    grids = d.get("grids", [])
    if not isinstance(grids, list) or any(not isinstance(g, list) or len(g) != 2 or g[0] not in FEATURES
                                          or g[1] not in FEATURES for g in grids):
        raise ReachsetError(f"{source}: envelope grids must be pairs of {', '.join(FEATURES)}")
    grids = tuple(tuple(g) for g in grids)
    joints = d.get("joints")
    if not isinstance(joints, dict) or not joints:
        raise ReachsetError(f"{source}: envelope has no joints")
    return Envelope(joints={str(n): _joint_from(n, j, grids, source) for n, j in joints.items()}, dt=dt,
                    bins=_count(d.get("bins"), "bins", source, 1), dilation=_count(d.get("dilation"), "dilation",
                                                                                     source),
                    hold=_count(d.get("hold"), "hold", source), grids=grids)


def axis_range(je: JointEnvelope, feature):
    """``(low, high)`` of a joint's ``feature`` axis: the training range widened by the
    dilation (a value outside it is outside the envelope whatever the grids say)."""
    a = je.axes[feature]
    return float(a.origin), float(a.origin + a.cells * a.cell)


def reference_limits(env: Envelope, names, *, q_min, q_max, qd_max, qdd_max):
    """A reference class' limits cut to the envelope's axes, and what was cut (issue 37.3).

    A reference generator that keeps ``q`` in ``[q_min, q_max]``, ``|qd| <= qd_max`` and
    ``|qdd| <= qdd_max`` per joint commands motions the model was never validated on where those
    limits reach beyond the envelope's position, velocity and acceleration axes. The cut limits
    keep the references inside every axis; the occupancy grids (combinations of features) are
    not enforced, so a reference inside the cut limits can still be classified outside (the
    features are of the measured motion, which follows the reference within R_e).

    Parameters
    ----------
    env : Envelope
    names : list of str
        The joints, in the order of the limits.
    q_min, q_max, qd_max, qdd_max : array_like (n,) or float
        The class' limits (rad, rad/s, rad/s^2).

    Returns
    -------
    limits : dict
        ``{q_min, q_max, qd_max, qdd_max}``, arrays (n,): each limit cut to the envelope.
    cut : list of str
        One line per limit that reached beyond the envelope, naming the joint, the feature, the
        class' limit and the validated range: the part of the class never validated; and one
        per joint the envelope does not record (its limits unchanged). Empty when the class lies
        inside every axis of every joint.

    Raises
    ------
    ReachsetError
        A velocity or acceleration axis that does not contain 0 (no reference class with a rest
        fits inside it).
    """
    n = len(names)
    out = {k: np.broadcast_to(np.asarray(v, dtype=np.float64), (n,)).copy()
           for k, v in (("q_min", q_min), ("q_max", q_max), ("qd_max", qd_max), ("qdd_max", qdd_max))}
    cut = []
    for j, name in enumerate(names):
        je = env.joints.get(name)
        if je is None:
            cut.append(f"{name}: not recorded by the envelope (a joint the model does not cover): limits unchanged")
            continue
        lo, hi = axis_range(je, "q")
        if out["q_min"][j] < lo or out["q_max"][j] > hi:
            cut.append(f"{name}: positions [{out['q_min'][j]:.4g}, {out['q_max'][j]:.4g}] rad, validated "
                       f"[{lo:.4g}, {hi:.4g}]")
            out["q_min"][j], out["q_max"][j] = max(out["q_min"][j], lo), min(out["q_max"][j], hi)
        for key, feature, unit in (("qd_max", "qd", "rad/s"), ("qdd_max", "qdd", "rad/s^2")):
            lo, hi = axis_range(je, feature)
            if not lo < 0.0 < hi:
                raise ReachsetError(f"{name}: the envelope's {feature} axis [{lo:.4g}, {hi:.4g}] does not contain 0")
            bound = min(-lo, hi)
            if out[key][j] > bound:
                cut.append(f"{name}: |{feature}| up to {out[key][j]:.4g} {unit}, validated up to {bound:.4g}")
                out[key][j] = bound
    return out, cut


@dataclass(frozen=True, kw_only=True)
class ClassBounds:
    """What a reference class and its certificate let one joint do (checked by :func:`unvalidated`).

    Attributes
    ----------
    qdd_max : float, optional
        Bound of the reference's ``|qdd_d|``, rad/s^2 (the class' ``qdd_max``, or ``u_ff``: the
        bound of U_ff the certificate covers); ``qdd_source`` names which.
    u : (float, float), optional
        The interval of the plant input u_p, rad/s^2: the certified R*_u (``u_source``).
    qd_max : float, optional
        Bound of ``|qd|``, rad/s, when the class has one.
    q : (float, float), optional
        The class' position box ``(q_min, q_max)``, rad, when known.

    A bound left None is not checked (not known to the caller: nothing is guessed).
    """

    qdd_max: float = None
    qdd_source: str = "qdd_max"
    u: tuple = None
    u_source: str = "R*_u"
    qd_max: float = None
    q: tuple = None


def _beyond(name, feature, what, lo, hi, axis):
    """The line naming ``[lo, hi]`` (the class' reach of ``feature``) beyond ``axis``, or None."""
    vlo, vhi = axis
    if lo >= vlo and hi <= vhi:
        return None
    return (f"{name}: {what} but the model was validated on {feature} in [{vlo:.4g}, {vhi:.4g}]")


def unvalidated(env: Envelope, bounds):
    """The parts of a reference class the model was never validated on, per joint (issue 37.3).

    A conformance model covers the behaviours it was tested on (paper, Def. 4): its sets hold
    for the recorded test cases, and the certificate of a reference class (R*_u inside U_p,
    R*_e) is a statement about the model, which says nothing of motion its identification data
    never contained. This compares what the class and its certificate let each joint do with
    the envelope's axes (:func:`axis_range`, the training range widened by the dilation): the
    reference's ``|qdd_d|`` with the ``qdd`` axis (the measured acceleration follows the
    reference within R_e), the certified R*_u with the ``u`` axis (u_p), and, when given,
    ``|qd|`` and the position box with the ``qd`` and ``q`` axes. The occupancy grids are not
    consulted (a class is bounds on single features, not combinations), so an empty answer
    means "inside every axis", not "every combination was seen". Naming, not refusing: the
    callers report the lines (the gain gate, ``reachset synthesize``).

    Parameters
    ----------
    env : Envelope
        The model's envelope (a model without one: the caller says "envelope: none recorded").
    bounds : dict
        ``{joint: ClassBounds}``.

    Returns
    -------
    dict
        ``{joint: tuple of str}`` for every joint of ``bounds``: one line per feature whose
        class reach leaves the validated range, naming the joint, the feature, the class' value
        and the validated range (e.g. ``"arm_2_joint: u_p reaches 24.1 rad/s^2 (R*_u = [-24.1,
        23.9]) but the model was validated on u_p in [-3.2, 3.1]"``); one line for a joint the
        envelope does not record; an empty tuple when the class lies inside every axis.
    """
    out = {}
    for name, b in bounds.items():
        je = env.joints.get(name)
        if je is None:
            out[name] = (f"{name}: not recorded by the envelope (the model was validated on no data of this joint)",)
            continue
        lines = []
        if b.q is not None:
            lo, hi = float(b.q[0]), float(b.q[1])
            lines.append(_beyond(name, "q", f"q spans [{lo:.4g}, {hi:.4g}] rad (the class' position box)", lo, hi,
                                 axis_range(je, "q")))
        if b.qd_max is not None:
            v = abs(float(b.qd_max))
            lines.append(_beyond(name, "qd", f"|qd| reaches {v:.4g} rad/s (qd_max)", -v, v, axis_range(je, "qd")))
        if b.qdd_max is not None:
            v = abs(float(b.qdd_max))
            lines.append(_beyond(name, "qdd", f"|qdd_d| reaches {v:.4g} rad/s^2 ({b.qdd_source})", -v, v,
                                 axis_range(je, "qdd")))
        if b.u is not None:
            lo, hi = float(b.u[0]), float(b.u[1])
            vlo, vhi = axis_range(je, "u")
            peak = lo if vlo - lo > hi - vhi else hi
            lines.append(_beyond(name, "u_p", f"u_p reaches {peak:.4g} rad/s^2 ({b.u_source} = [{lo:.4g}, "
                                              f"{hi:.4g}])", lo, hi, (vlo, vhi)))
        out[name] = tuple(x for x in lines if x is not None)
    return out

