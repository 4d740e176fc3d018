"""The safe stop: what the controller does while a safe stop is active (pure core, no ROS).

Stop categories as in IEC 60204-1 (9.2.2) and ISO 10218-1 (5.5):

* **category 2**: a controlled stop, the drives stay powered: a braking law within the
  input limits ``U_p`` (:func:`braking_input`) brings each joint to rest at a hold point
  (:func:`hold_position`) and holds it there.
* **category 1** (the default): the same controlled stop, then each joint's holding brake
  engages: when the joint is at rest (``|qd| < rest_velocity`` for ``rest_ticks``
  consecutive ticks), or when the controlled stop cannot decelerate it: still moving
  ``max_time`` after the stop began, or farther than ``max_travel`` from where it was when
  the stop began. Once engaged a brake stays engaged until the stop is cleared (reset).

The braking law acts on the joints' accelerations ``u_p`` (saturated to ``U_p``), so a
disturbance larger than ``u_max`` (e.g. a 30 rad/s^2 collision on a joint with
``u_max = 26``) cannot be stopped by it: category 2 does not make such an arm safe; the
brake of category 1 does (within the brake's torque, the simulator's ``brake_torque``).

An estimate the controller cannot use (non-finite, a joint missing) during a stop leaves
no state to run a controlled stop on: every brake engages at once (:meth:`StopState.engage_all`).

:class:`StopPolicy` is the immutable configuration, :class:`StopState` the mutable state of
one stop (the model/data split); :func:`stop_tick` is the one law, used by the controller
node and by the core simulations (:func:`reachset_ros.sim.stopping.simulate_stop`).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ..errors import ReachsetError

#: Brake reasons, in the order :func:`stop_tick` checks them.
AT_REST = "at rest"
TIMEOUT = "still moving at the stop's time limit"
TRAVEL = "travel limit exceeded"
NO_STATE = "no usable estimate"


def braking_input(q, qd, q_hold, u_max, omega=8.0, zeta=1.0):
    """Braking law of the controlled stop: a PD on the hold position, saturated to ``U_p``.

    ``u = clip(omega^2 (q_hold - q) - 2 zeta omega qd, -u_max, u_max)`` (rad/s^2), per joint.
    """
    u = omega ** 2 * (np.asarray(q_hold) - q) - 2 * zeta * omega * np.asarray(qd)
    return np.clip(u, -u_max, u_max)


def hold_position(q, qd, u_max):
    """Where the braking law holds the joints: the stopping point at half the admissible
    deceleration, ``q + qd |qd| / u_max``."""
    return q + qd * np.abs(qd) / (2 * 0.5 * u_max)


@dataclass(frozen=True)
class StopPolicy:
    """How a safe stop is carried out (immutable).

    Parameters
    ----------
    category : {1, 2}
        IEC 60204-1 stop category: 1 engages the holding brakes (see the module docstring),
        2 holds with the braking law only.
    rest_velocity : float
        |qd| below which a joint counts as at rest, rad/s.
    rest_ticks : int
        Consecutive ticks at rest before the brake engages.
    max_time : float
        A joint not at rest this long (s, stamp time) after the stop began is braked.
    max_travel : float
        A joint farther than this (rad) from its position at the stop's start is braked.
    omega, zeta : float
        Gains of the braking law.
    """

    category: int = 1
    rest_velocity: float = 0.01
    rest_ticks: int = 5
    max_time: float = 0.3
    max_travel: float = 0.2
    omega: float = 8.0
    zeta: float = 1.0

    def __post_init__(self):
        if self.category not in (1, 2):
            raise ReachsetError(f"stop category must be 1 or 2, got {self.category!r}")
        for name in ("rest_velocity", "max_time", "max_travel", "omega", "zeta"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise ReachsetError(f"stop policy: {name} must be finite and > 0, got {v!r}")
        if int(self.rest_ticks) != self.rest_ticks or self.rest_ticks < 1:
            raise ReachsetError(f"stop policy: rest_ticks must be an integer >= 1, got {self.rest_ticks!r}")


@dataclass
class StopState:
    """Mutable state of one safe stop of ``n`` joints (created when the stop begins)."""

    n: int
    start_ns: int = None            # stamp of the first stop tick
    q_start: np.ndarray = None      # positions at that tick
    q_hold: np.ndarray = None       # hold point of the braking law
    rest: np.ndarray = None         # consecutive ticks at rest, per joint
    engaged: np.ndarray = None      # holding brake engaged, per joint
    reasons: list = field(default_factory=list)   # (stamp, joint index, reason) of each engagement

    def __post_init__(self):
        self.rest = np.zeros(self.n, dtype=np.int64)
        self.engaged = np.zeros(self.n, dtype=bool)

    def engage_all(self, stamp_ns, reason=NO_STATE):
        """Engage every brake not engaged yet (e.g. no usable estimate: nothing to stop on)."""
        for j in np.flatnonzero(~self.engaged):
            self.reasons.append((int(stamp_ns), int(j), reason))
        self.engaged[:] = True


def stop_tick(policy: StopPolicy, state: StopState, stamp_ns, q, qd, u_max):
    """One tick of the safe stop: the braking input and the brakes to engage.

    Parameters
    ----------
    policy : StopPolicy
    state : StopState
        Updated in place (start, hold point, rest counts, engaged brakes).
    stamp_ns : int
        The estimate's stamp.
    q, qd : array (n,)
        Estimated positions and velocities (finite).
    u_max : array (n,) or float
        ``U_p`` half-widths, rad/s^2.

    Returns
    -------
    u : ndarray (n,)
        ``u_p`` of the braking law (rad/s^2; 0 for braked joints, whose drive only holds).
    engaged : ndarray of bool (n,)
        The holding brakes that are (now) engaged; always all False for category 2.
    """
    q = np.asarray(q, dtype=np.float64)
    qd = np.asarray(qd, dtype=np.float64)
    if state.start_ns is None:
        state.start_ns = int(stamp_ns)
        state.q_start = q.copy()
        state.q_hold = hold_position(q, qd, u_max)
    u = braking_input(q, qd, state.q_hold, u_max, policy.omega, policy.zeta)
    if policy.category == 1:
        still = np.abs(qd) < policy.rest_velocity
        state.rest = np.where(still, state.rest + 1, 0)
        elapsed = (int(stamp_ns) - state.start_ns) * 1e-9
        for j in np.flatnonzero(~state.engaged):
            why = (AT_REST if state.rest[j] >= policy.rest_ticks else
                   TIMEOUT if elapsed >= policy.max_time else
                   TRAVEL if abs(q[j] - state.q_start[j]) > policy.max_travel else None)
            if why is not None:
                state.engaged[j] = True
                state.reasons.append((int(stamp_ns), int(j), why))
        u = np.where(state.engaged, 0.0, u)
    return u, state.engaged.copy()


@dataclass(frozen=True)
class RestReport:
    """How the joints came to rest after a stop, measured (:func:`rest_after_stop`).

    Per joint: ``rest_s`` the time from the stop to the first sample after which
    ``|qd| < rest_velocity`` holds to the end of the data (None: not at rest at the end),
    ``travel`` the largest ``|q - q(stop)|`` after the stop (rad); ``finite`` whether every
    sample after the stop is finite.
    """

    names: tuple
    rest_s: tuple
    travel: tuple
    finite: tuple
    seconds_after: float            # data after the stop, s

    def failures(self, max_rest_s, max_travel):
        """One line per joint that did not come to rest within ``max_rest_s`` and ``max_travel``."""
        out = []
        for n, r, t, f in zip(self.names, self.rest_s, self.travel, self.finite):
            if not f:
                out.append(f"{n}: non-finite samples after the stop")
            elif r is None:
                out.append(f"{n}: not at rest (|qd| >= rest velocity) at the end, {self.seconds_after:.3g} s after the stop")
            elif r > max_rest_s or t > max_travel:
                out.append(f"{n}: at rest {r:.3g} s after the stop with {t:.3g} rad of travel "
                           f"(stated: within {max_rest_s:g} s and {max_travel:g} rad)")
        return out

    def as_dict(self):
        return {n: {"rest_s": r, "travel_rad": t, "finite": f}
                for n, r, t, f in zip(self.names, self.rest_s, self.travel, self.finite)}


def rest_after_stop(names, stamps_ns, q, qd, stop_ns, rest_velocity=0.01):
    """Measure, from recorded ``/joint_states``, how each joint came to rest after a stop.

    Parameters
    ----------
    names : sequence of str
    stamps_ns : array (T,)
        Sample stamps (sorted).
    q, qd : array (T, n)
        Measured positions and velocities.
    stop_ns : int
        Stamp of the safe stop.
    rest_velocity : float
        |qd| below which a joint is at rest, rad/s.

    Returns
    -------
    RestReport
    """
    stamps_ns = np.asarray(stamps_ns, dtype=np.int64)
    q, qd = np.asarray(q, float), np.asarray(qd, float)
    after = stamps_ns >= stop_ns
    if not np.any(after):
        raise ReachsetError(f"no sample at or after the stop's stamp {stop_ns}")
    i0 = int(np.argmax(after))
    t, qa, qda = stamps_ns[i0:], q[i0:], qd[i0:]
    rest, travel, finite = [], [], []
    for j in range(len(names)):
        ok = bool(np.all(np.isfinite(qa[:, j])) and np.all(np.isfinite(qda[:, j])))
        finite.append(ok)
        moving = np.flatnonzero(~(np.abs(qda[:, j]) < rest_velocity))
        if not len(moving):
            rest.append(0.0)
        elif moving[-1] == len(t) - 1:
            rest.append(None)
        else:
            rest.append(float((t[moving[-1] + 1] - stop_ns) * 1e-9))
        travel.append(float(np.nanmax(np.abs(qa[:, j] - qa[0, j]))) if ok else float("inf"))
    return RestReport(tuple(names), tuple(rest), tuple(travel), tuple(finite), float((t[-1] - stop_ns) * 1e-9))
