"""Identification references that cover the reference class on every joint (``reachset excite``).

A model identified from recordings is conformant on what the recordings contain (Definition 4,
Theorem 1); cross-validation (``identify --calibrate``) measures how much the sets must grow
for data *of the same kind*, never for motions that no fold contains. The fault campaign's
false stops came from training that never moved arm_2 faster than 0.18 rad/s of the class'
0.7 (docs/reliability.md). :func:`excitation` builds a reference that reaches the class'
limits on every joint, so the training data do:

* the class (docs/theory.md, row G5; the paper's ``U_ref``, Sec. IV): ``|qdd_d| <= u_ff``
  (``qdd_max``), ``|qd_d| <= qd_max`` (the reference node's velocity limit), ``q_d`` inside the
  position box (Table I and the URDF's limits for the LWA-4P,
  :class:`~reachset_ros.sim.reference.ReferenceConfig`; the URDF's range for any other arm,
  :meth:`~reachset_ros.sim.reference.ReferenceConfig.for_robot`), shrunk by ``margin`` of its
  width at both ends;
* for each level ``f`` of ``fractions`` (ascending; the last should be 1): every joint
  **alone** (the others at rest) moves from the start to the top of its range, to the bottom
  and back, accelerating at ``f qdd_max`` to ``f qd_max``, cruising and braking at
  ``f qdd_max``; then all joints **together**, in the same direction (up, down, back) and in
  alternating directions (even joints up while odd joints go down, then the reverse, back);
* each move is rest to rest and followed by ``rest`` s at rest; the reference starts and ends at
  rest at the start position (default: the box centre, where the simulated arm starts).

The acceleration is piecewise constant on the sampling grid ``k dt`` (each acceleration phase
is ``n`` ticks of the full acceleration and one tick of the remainder, so the velocity limit is
reached exactly), and positions and velocities are its exact integrals: the samples *are* the
reference, and :class:`TrajectoryPlayer` evaluates it exactly between samples.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .. import bags
from .. import defaults
from ..errors import ReachsetError

__all__ = ["ExciteConfig", "Trajectory", "TrajectoryPlayer", "excitation", "load_trajectory", "summary",
           "write_trajectory"]

defaults.register("excite", {
    "qd_max": (0.7, "the reference class' velocity limit, rad/s: reference_node's qd_max, the class the "
                    "excitation reaches (reachset excite --qd-max; ReferenceConfig.qd_max)"),
    "qdd_max": (2.0, "the reference class' acceleration limit u_ff = U_ref, rad/s^2 (paper Sec. IV; "
                     "gains.u_ff): what the excitation reaches (reachset excite --qdd-max)"),
    "fractions": ([0.5, 1.0], "levels of the class' limits the excitation moves at, ascending: each joint alone "
                              "and all together at f qd_max and f qdd_max for each f (reachset excite --fractions)"),
    "margin": (0.1, "share of the position box's width kept free at both ends by the excitation "
                    "(reachset excite --margin)"),
    "rest": (0.5, "seconds at rest after each move of the excitation (reachset excite --rest)"),
}, owner=__name__)

#: a sample with |qd_d| and |qdd_d| below this is at rest
REST_TOL = 1e-9


@dataclass(frozen=True, kw_only=True)
class ExciteConfig:
    """What :func:`excitation` covers.

    Attributes
    ----------
    names : tuple of str
        Joint names.
    q_min, q_max : ndarray (n,)
        The position box [rad] (before ``margin``).
    qd_max, qdd_max : ndarray (n,)
        The class' velocity [rad/s] and acceleration [rad/s^2] limits.
    fractions : tuple of float
        Levels in (0, 1], ascending.
    margin : float
        Share of the box's width kept free at both ends, in [0, 0.5).
    rest : float
        Seconds at rest after each move (and at the start).
    dt : float
        Sampling period [s].
    start : ndarray (n,) or None
        Start and end position; None: the box centre.
    excited : tuple of str or None
        The joints that move (the others rest at the start); None: all.
    """

    names: tuple
    q_min: np.ndarray
    q_max: np.ndarray
    qd_max: np.ndarray
    qdd_max: np.ndarray
    fractions: tuple = field(default_factory=lambda: tuple(defaults.get("excite.fractions")))
    margin: float = field(default_factory=lambda: defaults.get("excite.margin"))
    rest: float = field(default_factory=lambda: defaults.get("excite.rest"))
    dt: float = 0.004
    start: np.ndarray | None = None
    excited: tuple | None = None

    def __post_init__(self):
        n = len(self.names)
        if self.excited is not None:
            bad = [j for j in self.excited if j not in self.names]
            if not self.excited or bad:
                raise ReachsetError(f"excite: no joint {', '.join(bad) or '(none given)'} to excite "
                                    f"(the arm's: {', '.join(self.names)})")
            object.__setattr__(self, "excited", tuple(self.excited))
        for nm in ("q_min", "q_max", "qd_max", "qdd_max"):
            a = np.array(getattr(self, nm), dtype=np.float64).reshape(-1)
            a = np.full(n, float(a[0])) if a.size == 1 else a
            if a.size != n or not np.all(np.isfinite(a)):
                raise ReachsetError(f"excite: {nm} needs {n} finite values, got {np.size(getattr(self, nm))}")
            object.__setattr__(self, nm, a)
        if n == 0:
            raise ReachsetError("excite: no joints")
        if np.any(self.q_max <= self.q_min):
            raise ReachsetError("excite: the position box is empty on some joint (q_max <= q_min)")
        if np.any(self.qd_max <= 0) or np.any(self.qdd_max <= 0):
            raise ReachsetError("excite: --qd-max and --qdd-max must be > 0")
        fr = tuple(float(f) for f in self.fractions)
        if not fr or any(not (0 < f <= 1) for f in fr) or list(fr) != sorted(fr):
            raise ReachsetError(f"excite: --fractions must be ascending values in (0, 1], got {list(fr)}")
        object.__setattr__(self, "fractions", fr)
        if not (0 <= self.margin < 0.5):
            raise ReachsetError(f"excite: --margin must be in [0, 0.5), got {self.margin}")
        if not (np.isfinite(self.rest) and self.rest >= 0) or not (np.isfinite(self.dt) and self.dt > 0):
            raise ReachsetError(f"excite: --rest must be >= 0 and dt > 0, got {self.rest}, {self.dt}")
        lo, hi = self.box
        if self.start is not None:
            s = np.array(self.start, dtype=np.float64).reshape(-1)
            if s.size != n or np.any(s < lo) or np.any(s > hi):
                raise ReachsetError(f"excite: the start {np.round(s, 4).tolist()} is not inside the box "
                                    f"[{np.round(lo, 4).tolist()}, {np.round(hi, 4).tolist()}] (after the margin)")
            object.__setattr__(self, "start", s)

    @property
    def box(self):
        """The box the reference stays in: ``[q_min, q_max]`` shrunk by ``margin`` of its width."""
        w = self.q_max - self.q_min
        return self.q_min + self.margin * w, self.q_max - self.margin * w

    @property
    def q0(self) -> np.ndarray:
        lo, hi = self.box
        return 0.5 * (lo + hi) if self.start is None else self.start.copy()


@dataclass(frozen=True, kw_only=True)
class Trajectory:
    """A sampled reference: ``t`` (s, from 0), ``q``, ``qd``, ``qdd`` (T, n), joint ``names``."""

    names: tuple
    t: np.ndarray
    q: np.ndarray
    qd: np.ndarray
    qdd: np.ndarray

    def __len__(self):
        return len(self.t)


def _profile(dist, v, a, dt):
    """The acceleration ticks of a rest-to-rest move over ``dist`` >= 0 [rad] at most ``v``, ``a``:
    ``n`` ticks of ``a`` and one of the remainder up to ``v`` (or less when ``dist`` is too short
    to reach ``v``), cruise, then the mirror image. Returns (accelerations, distance covered)."""
    def ramp(vel):
        n = int(np.floor(vel / (a * dt) + 1e-9))
        r = vel / dt - n * a
        return [a] * n + ([r] if r > 1e-12 else [])

    def covered(acc):
        vel = np.concatenate([[0.0], np.cumsum(acc) * dt])
        return float(np.sum(vel[:-1] * dt + np.asarray(acc) * dt * dt / 2))

    up = ramp(v)
    d_ramp = covered(up)
    if 2 * d_ramp > dist:          # too short to reach v: the largest v that fits (bisection on the grid)
        lo, hi = 0.0, v
        for _ in range(60):
            mid = 0.5 * (lo + hi)
            lo, hi = (mid, hi) if 2 * covered(ramp(mid)) <= dist else (lo, mid)
        v = lo
        up = ramp(v)
        d_ramp = covered(up)
    cruise = int(np.floor((dist - 2 * d_ramp) / (v * dt) + 1e-9)) if v > 0 else 0
    acc = up + [0.0] * cruise + [-x for x in reversed(up)]
    return np.asarray(acc, dtype=np.float64), 2 * d_ramp + cruise * v * dt


def _move(cfg, q_from, q_to, f):
    """One synchronised start of per-joint rest-to-rest moves from ``q_from`` towards ``q_to`` at
    level ``f``, then ``rest`` s at rest: acceleration ticks (T, n). Each joint's own profile
    (:func:`_profile`), so each reaches ``f`` of its limits; they finish at their own times."""
    n = len(cfg.names)
    cols = []
    for j in range(n):
        d = q_to[j] - q_from[j]
        acc, _ = _profile(abs(d), f * cfg.qd_max[j], f * cfg.qdd_max[j], cfg.dt)
        cols.append(np.sign(d) * acc if d != 0 else np.zeros(0))
    T = max(len(c) for c in cols) + int(round(cfg.rest / cfg.dt))
    A = np.zeros((T, n))
    for j, c in enumerate(cols):
        A[:len(c), j] = c
    return A


def _targets(cfg):
    """The ordered moves (module docstring): ``(level, moving, target)``; the joints not in the
    boolean mask ``moving`` stay where they are."""
    lo, hi = cfg.box
    q0 = cfg.q0
    n = len(cfg.names)
    alle = np.array([cfg.excited is None or nm in cfg.excited for nm in cfg.names])
    even = np.cumsum(alle) % 2 == 1            # every other excited joint
    moves = []
    for f in cfg.fractions:
        for j in np.flatnonzero(alle):
            one = np.arange(n) == j
            moves += [(f, one, hi), (f, one, lo), (f, one, q0)]
        moves += [(f, alle, hi), (f, alle, lo), (f, alle, q0)]
        moves += [(f, alle, np.where(even, hi, lo)), (f, alle, np.where(even, lo, hi)), (f, alle, q0)]
    return moves


def _integrate(q0, A, dt):
    """Exact positions and velocities of piecewise-constant accelerations ``A`` (T, n) from rest at ``q0``."""
    qd = np.vstack([np.zeros((1, A.shape[1])), np.cumsum(A, axis=0) * dt])
    q = q0[None, :] + np.vstack([np.zeros((1, A.shape[1])), np.cumsum(qd[:-1] * dt + A * dt * dt / 2, axis=0)])
    return q, qd


def excitation(cfg: ExciteConfig) -> Trajectory:
    """The excitation reference of ``cfg`` (module docstring), sampled at ``k dt``.

    Moves are planned from where the previous one actually ended (the grid rounds each cruise
    down by less than one tick), so the reference never leaves the box; the last move returns
    to the start, within one tick's travel, and the last sample is at rest.
    """
    A_parts = [np.zeros((int(round(cfg.rest / cfg.dt)), len(cfg.names)))]
    q = cfg.q0
    for f, moving, target in _targets(cfg):
        A = _move(cfg, q, np.where(moving, target, q), f)
        A_parts.append(A)
        qs, _ = _integrate(q, A, cfg.dt)
        q = qs[-1]
    A = np.vstack(A_parts + [np.zeros((1, len(cfg.names)))])
    Q, QD = _integrate(cfg.q0, A[:-1], cfg.dt)
    QD[np.abs(QD) < 1e-12] = 0.0
    t = np.arange(len(A)) * cfg.dt
    return Trajectory(names=tuple(cfg.names), t=t, q=Q, qd=QD, qdd=A)


def summary(traj: Trajectory, cfg: ExciteConfig) -> dict:
    """Per joint what the reference reaches against the class: ``{name: {max_abs_velocity,
    velocity_fraction, max_abs_acceleration, acceleration_fraction, position_range,
    position_box}}`` (fractions of ``qd_max`` and ``qdd_max``)."""
    lo, hi = cfg.box
    out = {}
    for j, n in enumerate(traj.names):
        v, a = float(np.max(np.abs(traj.qd[:, j]))), float(np.max(np.abs(traj.qdd[:, j])))
        out[n] = {"excited": cfg.excited is None or n in cfg.excited, "max_abs_velocity": v, "velocity_limit": float(cfg.qd_max[j]),
                  "velocity_fraction": v / float(cfg.qd_max[j]),
                  "max_abs_acceleration": a, "acceleration_limit": float(cfg.qdd_max[j]),
                  "acceleration_fraction": a / float(cfg.qdd_max[j]),
                  "position_range": [float(traj.q[:, j].min()), float(traj.q[:, j].max())],
                  "position_box": [float(lo[j]), float(hi[j])]}
    return out


def write_trajectory(path, traj: Trajectory, *, t0_ns: int = 0, storage: str = "mcap"):
    """Write ``traj`` as ``/reference`` (``reachset_msgs/msg/JointReference``) with the project's
    bag writer (atomic: nothing is left at ``path`` on an error), stamped ``t0_ns + t``."""
    JR = bags.typestore().types[bags.REFERENCE_TYPE]
    names = list(traj.names)
    with bags.BagWriter(path, storage=storage) as w:
        for k in range(len(traj)):
            st = int(t0_ns) + int(round(traj.t[k] * 1e9))
            w.write(bags.REFERENCE_TOPIC, JR(header=bags.header(st), name=names, position=traj.q[k].copy(),
                                             velocity=traj.qd[k].copy(), acceleration=traj.qdd[k].copy()),
                    st, bags.REFERENCE_TYPE)


def load_trajectory(path, *, qd_max=None, qdd_max=None) -> Trajectory:
    """A ``/reference`` recorded in the bag at ``path`` (:func:`write_trajectory`'s, or any
    recorded one) as a :class:`Trajectory`, checked: one sample per stamp with every joint, finite,
    starting and ending at rest, and (when given) inside the class ``|qd_d| <= qd_max``,
    ``|qdd_d| <= qdd_max``. Raises :class:`ReachsetError` naming what is wrong."""
    try:
        rows = bags.read_topic_rows([path], bags.REFERENCE_TOPIC, ("position", "velocity", "acceleration"))
    except ReachsetError as e:
        raise ReachsetError(f"trajectory file {path}: {e}") from None
    if not rows:
        raise ReachsetError(f"trajectory file {path}: no {bags.REFERENCE_TOPIC} samples")
    names = tuple(rows)
    st = rows[names[0]][0]
    if len(st) < 2 or any(len(rows[n][0]) != len(st) or np.any(rows[n][0] != st) for n in names):
        raise ReachsetError(f"trajectory file {path}: every {bags.REFERENCE_TOPIC} sample must hold every joint "
                            f"({', '.join(names)}), at least two samples")
    V = np.stack([rows[n][1] for n in names], axis=1)          # (T, n, 3)
    if not np.all(np.isfinite(V)):
        raise ReachsetError(f"trajectory file {path}: non-finite values")
    q, qd, qdd = V[:, :, 0], V[:, :, 1], V[:, :, 2]
    for k, where in ((0, "start"), (-1, "end")):
        if np.any(np.abs(qd[k]) > REST_TOL) or np.any(np.abs(qdd[k]) > REST_TOL):
            raise ReachsetError(f"trajectory file {path}: the reference must {where} at rest (qd_d = qdd_d = 0)")
    for lim, arr, what in ((qd_max, qd, "|qd_d|"), (qdd_max, qdd, "|qdd_d|")):
        if lim is not None and np.max(np.abs(arr)) > lim * (1 + 1e-9):
            j = int(np.argmax(np.max(np.abs(arr), axis=0)))
            raise ReachsetError(f"trajectory file {path}: {what} of {names[j]} reaches {np.max(np.abs(arr)):.6g}, "
                                f"outside the class ({lim:g})")
    t = (st - st[0]) * 1e-9
    return Trajectory(names=names, t=t, q=q.copy(), qd=qd.copy(), qdd=qdd.copy())


class TrajectoryPlayer:
    """A :class:`Trajectory` played as ``reference_node`` streams (the interface of
    :class:`~reachset_ros.sim.reference.ReferenceStream`): the first stamp seen is its time 0;
    between samples ``q = q_k + qd_k tau + qdd_k tau^2 / 2``, ``qd = qd_k + qdd_k tau`` (exact for
    :func:`excitation`'s piecewise-constant acceleration); after the last sample it rests there.

    ``hold``: the reference runs on to the next sample at rest and stays there; when cleared it
    continues from there (its time stands still while holding). :meth:`restart` (a cleared safe
    stop): the file is not resumed (it would jump from where the arm is held); the reference
    rests at the arm's position until the node is restarted.
    """

    def __init__(self, traj: Trajectory):
        self.traj = traj
        self.t0_ns = None
        self.paused = 0.0
        self.hold_index = None
        self.parked = None
        self.restarts = 0
        self._last_tau = -1.0
        rest = np.all((np.abs(traj.qd) <= REST_TOL) & (np.abs(traj.qdd) <= REST_TOL), axis=1)
        self._rest = np.flatnonzero(rest)

    @property
    def done(self) -> bool:
        """Whether the last stamp seen was at or after the file's end (or the file was abandoned)."""
        return self.parked is not None or self._last_tau >= self.traj.t[-1]

    def restart(self, stamp_ns: int, q, rest_s: float = 1.0):
        self.restarts += 1
        self.parked = np.array(q, dtype=np.float64)

    def _sample(self, k, tau=0.0):
        tr = self.traj
        return (tr.q[k] + tr.qd[k] * tau + tr.qdd[k] * tau * tau / 2, tr.qd[k] + tr.qdd[k] * tau, tr.qdd[k].copy())

    def at(self, stamp_ns: int, hold: bool = False):
        """``(q_d, qd_d, qdd_d)`` for the measurement stamped ``stamp_ns``."""
        if self.parked is not None:
            z = np.zeros(len(self.parked))
            return self.parked.copy(), z, z.copy()
        if self.t0_ns is None:
            self.t0_ns = int(stamp_ns)
        tr = self.traj
        tau = max(0.0, (int(stamp_ns) - self.t0_ns) * 1e-9 - self.paused)
        if hold:
            if self.hold_index is None:
                k = int(np.searchsorted(tr.t, tau, side="left"))
                i = int(np.searchsorted(self._rest, k, side="left"))
                self.hold_index = int(self._rest[min(i, len(self._rest) - 1)])
            if tau >= tr.t[self.hold_index]:
                return self._sample(self.hold_index)
        elif self.hold_index is not None:
            delta = max(0.0, tau - tr.t[self.hold_index])
            self.paused += delta
            tau -= delta
            self.hold_index = None
        self._last_tau = tau
        if tau >= tr.t[-1]:
            return self._sample(len(tr) - 1)
        k = int(np.searchsorted(tr.t, tau, side="right")) - 1
        return self._sample(k, tau - tr.t[k])
