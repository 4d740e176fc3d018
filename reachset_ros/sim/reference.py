"""Random point-to-point reference trajectories (pure core, no ROS).

Like the paper's test trajectories (Sec. IV: "closed-loop trapezoidal and polynomial
trajectories with random target positions, velocities, and accelerations up to
qdd_d in U_ref = [-2, 2] rad/s^2"): a sequence of segments, each from the previous target
to a random target drawn uniformly in the position box, all joints synchronised to start
and stop together, followed by a random dwell. Each segment is, at random,

* **trapezoidal**: constant acceleration, cruise, constant deceleration per joint;
* **quintic**: ``q = q_0 + (q_1 - q_0) s(t/T)``, ``s = 10 r^3 - 15 r^4 + 6 r^5`` (rest to rest,
  zero boundary acceleration);

with a random velocity limit in ``[min_fraction, 1] * qd_max`` and acceleration limit in
``[min_fraction, 1] * qdd_max``. Limits hold exactly: ``q_min <= q_d <= q_max``,
``|qd_d| <= qd_max``, ``|qdd_d| <= qdd_max`` (trapezoids have acceleration steps, which
the paper's double-integrator plant accepts). Reproducible: the segments depend only on
the seed, the configuration and ``q0``, not on how the trajectory is sampled.

**Led segments** (``lead > 0``): the synchronised moves rarely take a joint with a short
range to its velocity limit, because a longer move of another joint sets the segment's
duration. A data set recorded to identify a model of the whole class must reach the class'
limits on every joint, so a share ``lead`` of the segments is *led* by one joint (in turn):
it moves to the far half of its range at its full ``qd_max`` and ``qdd_max``, and every
other joint's move is shortened, if needed, to finish within the leader's duration.
"""
from __future__ import annotations

import bisect
from dataclasses import dataclass, field

import numpy as np

from ..errors import ReachsetError
from ..robot.dynamics import TABLE1_Q_MAX, U_REF, load_model

QUINTIC_VEL = 1.875                 # max s'(r)
QUINTIC_ACC = 10.0 / np.sqrt(3.0)   # max |s''(r)|


def _arr(x, n, name):
    a = np.array(x, dtype=np.float64).reshape(-1)
    if a.size == 1:
        a = np.full(n, float(a[0]))
    if a.size != n:
        raise ReachsetError(f"reference: {name} needs {n} values, got {a.size}")
    a.setflags(write=False)
    return a


_BOX = []


def _default_box():
    """Table I box intersected with the shipped URDF's position limits."""
    if not _BOX:
        m = load_model()
        _BOX.append((np.maximum(-TABLE1_Q_MAX, m.lower), np.minimum(TABLE1_Q_MAX, m.upper)))
    return tuple(a.copy() for a in _BOX[0])


@dataclass(frozen=True)
class ReferenceConfig:
    """Limits and randomisation of :class:`ReferenceGenerator`.

    Defaults: the paper's Table I box ``|q| <= q_max`` (140/45/100/140/80/140 deg)
    intersected with the shipped URDF's position limits (which are tighter on joints 4 and
    6: +-2.07 rad), ``qd_max = 0.7`` rad/s and ``U_ref``: ``qdd_max = 2`` rad/s^2.

    Parameters
    ----------
    q_min, q_max : array_like (n,)
        Position box [rad].
    qd_max, qdd_max : float or array_like (n,)
        Velocity [rad/s] and acceleration [rad/s^2] limits.
    kinds : tuple of str
        Segment kinds drawn from (``"trapezoidal"``, ``"quintic"``).
    dwell : (float, float)
        Range of the random pause after each segment [s].
    min_fraction : float
        Per-segment limits are drawn uniformly in ``[min_fraction, 1]`` times the limits.
    min_distance : float
        Targets closer than this to the start (max over joints) are redrawn [rad].
    lead : float
        Share of the segments led by one joint at its full limits (round-robin over the
        joints; see the module docstring). 0 (default): none, and the draws of every seed
        are those of the plain generator.
    """

    q_min: np.ndarray = field(default_factory=lambda: _default_box()[0])
    q_max: np.ndarray = field(default_factory=lambda: _default_box()[1])
    qd_max: object = 0.7
    qdd_max: object = U_REF
    kinds: tuple = ("trapezoidal", "quintic")
    dwell: tuple = (0.0, 0.5)
    min_fraction: float = 0.2
    min_distance: float = 0.05
    lead: float = 0.0

    def __post_init__(self):
        n = np.size(self.q_min)
        object.__setattr__(self, "q_min", _arr(self.q_min, n, "q_min"))
        object.__setattr__(self, "q_max", _arr(self.q_max, n, "q_max"))
        object.__setattr__(self, "qd_max", _arr(self.qd_max, n, "qd_max"))
        object.__setattr__(self, "qdd_max", _arr(self.qdd_max, n, "qdd_max"))
        if np.any(self.q_max <= self.q_min):
            raise ReachsetError("reference: q_max must exceed q_min on every joint")
        if np.any(self.qd_max <= 0) or np.any(self.qdd_max <= 0):
            raise ReachsetError("reference: qd_max and qdd_max must be > 0")
        if not self.kinds or set(self.kinds) - {"trapezoidal", "quintic"}:
            raise ReachsetError(f"reference: kinds must be trapezoidal and/or quintic, "
                                f"got {self.kinds}")
        if not (0 < self.min_fraction <= 1) or not (0 <= self.dwell[0] <= self.dwell[1]):
            raise ReachsetError("reference: need 0 < min_fraction <= 1 and 0 <= dwell[0] <= dwell[1]")
        if not (0.0 <= self.lead <= 1.0):
            raise ReachsetError(f"reference: lead must be in [0, 1], got {self.lead}")

    @property
    def n(self) -> int:
        return self.q_min.size

    @classmethod
    def for_robot(cls, model, margin: float = 0.1, qd_max: float = 0.7, qdd_max: float = U_REF, **kw):
        """Limits of any arm from its model (URDF): the position box is each joint's URDF range
        shrunk by ``margin`` of its width at both ends; velocities are capped at ``qd_max``
        and half the URDF velocity limit, accelerations at ``qdd_max`` (the paper's class
        U_ref, Sec. IV). The shipped LWA-4P's default box (Table I) is :class:`ReferenceConfig`'s."""
        lo, hi = np.asarray(model.lower, float), np.asarray(model.upper, float)
        if not (np.all(np.isfinite(lo)) and np.all(np.isfinite(hi)) and np.all(hi > lo)):
            raise ReachsetError("reference: the robot model needs finite position limits on every joint")
        w = hi - lo
        vl = np.asarray(model.velocity_limit, float)
        vmax = np.where(np.isfinite(vl) & (vl > 0), np.minimum(qd_max, 0.5 * vl), qd_max)
        return cls(q_min=lo + margin * w, q_max=hi - margin * w, qd_max=vmax, qdd_max=qdd_max, **kw)


@dataclass(frozen=True)
class Segment:
    """One synchronised move from ``q0`` to ``q1`` starting at ``t0``, lasting ``T``,
    then resting until ``t0 + T + dwell``. ``a``, ``v``: per-joint signed acceleration and
    cruise velocity of a trapezoid (unused for quintic)."""

    t0: float
    T: float
    dwell: float
    q0: np.ndarray
    q1: np.ndarray
    kind: str
    a: np.ndarray
    v: np.ndarray

    @property
    def t_end(self) -> float:
        return self.t0 + self.T + self.dwell

    def evaluate(self, t: float):
        """``(q, qd, qdd)`` at absolute time ``t`` in ``[t0, t_end]``."""
        tau = min(max(t - self.t0, 0.0), self.T)
        d = self.q1 - self.q0
        if t - self.t0 >= self.T or self.T == 0.0:
            z = np.zeros_like(d)
            return self.q1.copy(), z, z.copy()
        if self.kind == "quintic":
            r = tau / self.T
            s = r ** 3 * (10 - 15 * r + 6 * r * r)
            ds = 30 * r * r * (1 - r) ** 2 / self.T
            dds = 60 * r * (1 - r) * (1 - 2 * r) / self.T ** 2
            return self.q0 + d * s, d * ds, d * dds
        # trapezoid (v = 0 joints do not move); t_a = |v / a|
        q, qd, qdd = self.q0.copy(), np.zeros_like(d), np.zeros_like(d)
        mv = self.v != 0
        a, v = self.a[mv], self.v[mv]
        ta = v / a
        T = self.T
        acc = tau < ta
        dec = tau > T - ta
        cru = ~(acc | dec)
        qm = np.empty_like(v)
        vm = np.empty_like(v)
        am = np.empty_like(v)
        qm[acc] = 0.5 * a[acc] * tau ** 2
        vm[acc] = a[acc] * tau
        am[acc] = a[acc]
        qm[cru] = 0.5 * v[cru] * ta[cru] + v[cru] * (tau - ta[cru])
        vm[cru] = v[cru]
        am[cru] = 0.0
        rem = T - tau
        qm[dec] = d[mv][dec] - 0.5 * a[dec] * rem ** 2
        vm[dec] = a[dec] * rem
        am[dec] = -a[dec]
        q[mv] += qm
        qd[mv] = vm
        qdd[mv] = am
        return q, qd, qdd


def _duration(D, vmax, amax, kind):
    """Per joint, the shortest rest-to-rest move over distances ``D`` within the limits [s]."""
    if kind == "quintic":
        return np.maximum(QUINTIC_VEL * D / vmax, np.sqrt(QUINTIC_ACC * D / amax))
    return np.where(D < vmax ** 2 / amax, 2 * np.sqrt(D / amax), D / vmax + vmax / amax)


class ReferenceGenerator:
    """Random point-to-point reference ``(q_d, qd_d, qdd_d)`` (see the module docstring).

    Parameters
    ----------
    config : ReferenceConfig
    q0 : array_like (n,), optional
        Start position (inside the box); default the box centre.
    seed : int

    Examples
    --------
    >>> gen = ReferenceGenerator(ReferenceConfig(), seed=3)
    >>> q_d, qd_d, qdd_d = gen.sample(1.234)
    >>> t, Q, QD, QDD = gen.trajectory(10.0)         # 250 Hz batch
    """

    def __init__(self, config: ReferenceConfig | None = None, q0=None, seed: int = 0, q0_outside_box=False):
        self.config = config or ReferenceConfig()
        c = self.config
        q0 = 0.5 * (c.q_min + c.q_max) if q0 is None else _arr(q0, c.n, "q0")
        # q0_outside_box: a restart from where the arm is (after a safe stop it may be outside
        # the box): the first move then goes back into the box
        if not q0_outside_box and (np.any(q0 < c.q_min - 1e-12) or np.any(q0 > c.q_max + 1e-12)):
            raise ReachsetError(f"reference: q0 {np.round(q0, 4).tolist()} outside the position box")
        self.q0 = np.array(q0, dtype=np.float64)
        self.seed = int(seed)
        self._rng = np.random.default_rng(self.seed)
        self._segments: list = []
        self._starts: list = []
        self._led = 0                       # led segments so far (the next leader is _led % n)

    @property
    def segments(self) -> tuple:
        """Segments generated so far."""
        return tuple(self._segments)

    def _new_segment(self) -> Segment:
        c, rng = self.config, self._rng
        if self._segments:
            last = self._segments[-1]
            t0, qs = last.t_end, last.q1
        else:
            t0, qs = 0.0, self.q0
        for _ in range(100):
            q1 = rng.uniform(c.q_min, c.q_max)
            if np.max(np.abs(q1 - qs)) >= c.min_distance:
                break
        kind = c.kinds[int(rng.integers(len(c.kinds)))]
        vmax = c.qd_max * rng.uniform(c.min_fraction, 1.0)
        amax = c.qdd_max * rng.uniform(c.min_fraction, 1.0)
        dwell = float(rng.uniform(*c.dwell))
        if c.lead > 0.0 and rng.uniform() < c.lead:
            q1, vmax, amax = self._led_move(qs, q1, vmax, amax, kind)
        d = q1 - qs
        D = np.abs(d)
        T = float(np.max(_duration(D, vmax, amax, kind)))
        if kind == "quintic":
            a = v = np.zeros(c.n)
        else:
            # each joint keeps its acceleration limit and cruises slower to finish at T
            disc = np.maximum(amax ** 2 * T ** 2 - 4 * amax * D, 0.0)
            vabs = (amax * T - np.sqrt(disc)) / 2
            vabs = np.minimum(vabs, vmax)
            v = np.sign(d) * vabs
            # exact arrival: acceleration from v and T (a = v^2 / (v T - D)), <= amax
            with np.errstate(divide="ignore", invalid="ignore"):
                aabs = np.where(vabs > 0, vabs ** 2 / np.maximum(vabs * T - D, 1e-300), 0.0)
            aabs = np.minimum(aabs, amax)
            a = np.sign(d) * aabs
            v = np.where(D > 0, v, 0.0)
        seg = Segment(t0, T, dwell, np.array(qs), q1, kind, a, v)
        return seg

    def _led_move(self, qs, q1, vmax, amax, kind):
        """A led segment's target and limits: joint ``j`` (in turn) goes to the far half of
        its range at its full limits; the others' moves are shortened to end within its
        duration (each joint's duration grows with its distance, so a cap on the distance
        is a cap on the duration)."""
        c, rng = self.config, self._rng
        j = self._led % c.n
        self._led += 1
        vmax, amax, q1 = vmax.copy(), amax.copy(), q1.copy()
        vmax[j], amax[j] = c.qd_max[j], c.qdd_max[j]
        mid = 0.5 * (c.q_min[j] + c.q_max[j])
        q1[j] = rng.uniform(mid, c.q_max[j]) if qs[j] < mid else rng.uniform(c.q_min[j], mid)
        T = _duration(np.abs(q1[j:j + 1] - qs[j:j + 1]), vmax[j:j + 1], amax[j:j + 1], kind)[0]
        if kind == "quintic":
            dmax = np.minimum(T * vmax / QUINTIC_VEL, amax * T * T / QUINTIC_ACC)
        else:
            dmax = np.where(T >= 2 * vmax / amax, vmax * (T - vmax / amax), amax * T * T / 4)
        d = q1 - qs
        dmax[j] = np.inf
        d = np.sign(d) * np.minimum(np.abs(d), dmax * (1 - 1e-9))
        return qs + d, vmax, amax

    def _segment_at(self, t: float) -> Segment:
        if t < 0:
            raise ReachsetError(f"reference: time {t} before the start")
        while not self._segments or self._segments[-1].t_end <= t:
            seg = self._new_segment()
            self._segments.append(seg)
            self._starts.append(seg.t0)
        i = bisect.bisect_right(self._starts, t) - 1
        return self._segments[i]

    def sample(self, t: float):
        """``(q_d, qd_d, qdd_d)`` at time ``t`` [s] since the start (any order of calls)."""
        return self._segment_at(float(t)).evaluate(float(t))

    def current_move(self, t: float) -> Segment:
        """The move (with its rest) under way at time ``t`` [s]: ``t0 <= t < t_end``.

        ``evaluate(t_end)`` of it is its end point at rest: where a reference that stops
        taking new moves (``reference_node``'s ``hold``) stays.
        """
        return self._segment_at(float(t))

    def batch(self, ts):
        """:meth:`sample` at each time of ``ts``; arrays (len(ts), n)."""
        out = [self.sample(t) for t in np.asarray(ts, dtype=np.float64)]
        return tuple(np.array([o[i] for o in out]) for i in range(3))

    def trajectory(self, duration: float, dt: float = 0.004):
        """Sampled at ``k dt`` for ``k dt < duration``: ``(t, Q, QD, QDD)``."""
        t = np.arange(int(np.ceil(duration / dt - 1e-9))) * dt
        return (t,) + self.batch(t)


class ReferenceStream:
    """The reference as ``reference_node`` streams it: sampled at measurement stamps, with hold.

    Mutable state (the generator is the model): the first stamp seen is time 0; while
    ``hold`` is set, the move under way is finished and the reference then rests at its
    end point (velocity and acceleration 0); when ``hold`` is cleared, the moves continue
    where they stopped: the generator's time stands still while holding, so the reference
    stays continuous.

    Parameters
    ----------
    generator : ReferenceGenerator

    Examples
    --------
    >>> s = ReferenceStream(ReferenceGenerator(seed=3))
    >>> q_d, qd_d, qdd_d = s.at(1_000_000_000)             # stamp in ns; t = 0 here
    >>> q_d, qd_d, qdd_d = s.at(1_004_000_000, hold=True)
    """

    def __init__(self, generator: ReferenceGenerator):
        self.generator = generator
        self.t0_ns = None
        self.paused = 0.0        # s of generator time skipped while holding
        self.hold_move = None    # the move whose end point a hold rests at
        self.restarts = 0

    def restart(self, stamp_ns: int, q, rest_s: float = 1.0):
        """Re-synchronise to the arm: from ``stamp_ns`` the reference rests at ``q`` (the
        arm's measured, held position) for ``rest_s``, then new moves start from there
        (a generator seeded ``seed + restarts``, so a restart is reproducible). Used after a
        safe stop is cleared: tracking resumes where the arm is, with no jump."""
        g = self.generator
        self.restarts += 1
        self.generator = ReferenceGenerator(g.config, q0=np.asarray(q, dtype=np.float64), seed=g.seed + self.restarts,
                                            q0_outside_box=True)
        self.t0_ns = int(stamp_ns) + int(round(rest_s * 1e9))
        self.paused = 0.0
        self.hold_move = None

    def at(self, stamp_ns: int, hold: bool = False):
        """``(q_d, qd_d, qdd_d)`` for the measurement stamped ``stamp_ns``."""
        if self.t0_ns is not None and stamp_ns < self.t0_ns:     # resting after a restart
            z = np.zeros(self.generator.config.n)
            return self.generator.q0.copy(), z, z.copy()
        if self.t0_ns is None:
            self.t0_ns = int(stamp_ns)
        tau = (int(stamp_ns) - self.t0_ns) * 1e-9 - self.paused
        if hold:
            if self.hold_move is None:
                self.hold_move = self.generator.current_move(tau)
            if tau >= self.hold_move.t_end:
                return self.hold_move.evaluate(self.hold_move.t_end)
        elif self.hold_move is not None:
            # resume: the generator's time continues from the end of the held move
            delta = max(0.0, tau - self.hold_move.t_end)
            self.paused += delta
            tau -= delta
            self.hold_move = None
        return self.generator.sample(tau)
