"""A safe stop on the simulated arm, without ROS: the nodes' code path in one loop.

Per tick, as the nodes do it: the measurement goes through each joint's observer and
certified control law (:func:`reachset_ros.systems.closedloop.closed_loop_tick`, the
controller node's :class:`~reachset_ros.systems.closedloop.FeedbackLaw`); from the stop on,
the controller's stop law :func:`reachset_ros.systems.stopping.stop_tick` on the estimate
replaces tracking and commands the holding brakes; a non-finite measurement is skipped by
the observer (no estimate, no command: the simulator steps with the previous command, as
``sim_node`` does after its lockstep timeout); the torque is the nominal feedback linearization and
the simulated arm (hard stops, torque limits, holding brakes) applies it with one sample of
input delay. Used by the tests to check that a stop holds the arm for every fault kind of
the simulator; the monitor is not in this loop (the stop comes ``stop_delay`` after the
fault's onset: the node tests and the demo cover detection).
"""
from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from .. import robot as rb
from ..systems.closedloop import closed_loop_tick
from ..systems.gains import Gains
from ..systems.reference_loop import reference_state
from ..systems.stopping import StopPolicy, StopState, rest_after_stop, stop_tick
from . import reference as refm
from . import simulator as simm
from .recordings import DEFAULT_GAINS

__all__ = ["StopRun", "simulate_safe_stop", "REST_WITHIN_S", "TRAVEL_WITHIN_RAD"]

#: What a category-1 stop (default :class:`StopPolicy`) of the simulated LWA-4P is stated to
#: achieve, from the stop's stamp: every joint at rest (|qd| < 0.01 rad/s from then on) within
#: this time, having moved at most this far. Checked for every fault kind of the simulator by
#: test/systems/test_stopping.py and, from the recorded bag, by ``reachset demo``. The brake engages
#: at the latest ``max_time`` (0.3 s) or ``max_travel`` (0.2 rad) into the stop; the rest is
#: the brake's deceleration (``brake_torque``: the URDF's effort limits) and the rest test.
REST_WITHIN_S = 0.5
TRAVEL_WITHIN_RAD = 0.3


@dataclass(frozen=True)
class StopRun:
    """What :func:`simulate_safe_stop` recorded (measured and true states per tick)."""

    names: tuple
    stamps: np.ndarray          # (T,) ns
    q: np.ndarray               # measured positions (T, n)
    qd: np.ndarray              # measured velocities (T, n)
    q_true: np.ndarray          # true positions at each stamp (T, n)
    qd_true: np.ndarray
    brakes: np.ndarray          # (T, n) brakes commanded at each tick
    fault_ns: int               # onset stamp of the fault
    stop_ns: int                # stamp of the first stop tick
    counters: dict              # the simulator's counters at the end
    reasons: tuple              # (stamp, joint, reason) of each brake engagement

    def rest(self, rest_velocity=0.01, true_state=False):
        """:func:`~reachset_ros.systems.stopping.rest_after_stop` of the measured (or true) states."""
        q, qd = (self.q_true, self.qd_true) if true_state else (self.q, self.qd)
        return rest_after_stop(self.names, self.stamps, q, qd, self.stop_ns, rest_velocity)


def simulate_safe_stop(fault, before=2.0, stop_delay=0.02, after=3.0, policy=None, gains=None, seed=0,
                       u_max=26.0, sim_config=None):
    """Track the project's reference, inject ``fault``, stop ``stop_delay`` s after its onset.

    Parameters
    ----------
    fault : reachset_ros.sim.simulator.Fault or None
        Injected at ``before`` s (its ``start_s`` is replaced); None: no fault.
    before, stop_delay, after : float
        Seconds of tracking before the fault, from the fault's onset to the stop, after the stop.
    policy : StopPolicy, optional
        Default: category 1 with the default limits.
    gains : dict, optional
        Gains of every joint (default :data:`reachset_ros.sim.recordings.DEFAULT_GAINS`).
    u_max : float
        U_p half-width of the braking law, rad/s^2.

    Returns
    -------
    StopRun
    """
    policy = policy or StopPolicy()
    cfg = sim_config or simm.SimConfig.realistic(seed=seed)
    arm = simm.SimulatedArm(cfg, seed=seed)
    names = tuple(arm.joint_names)
    n, dt = len(names), cfg.dt
    gen = refm.ReferenceGenerator(None, seed=seed)
    _, Qd, QDd, QDDd = gen.trajectory(before + stop_delay + after + 1.0, dt)
    model = cfg.robot
    data = rb.create_data(model)
    m = arm.reset(Qd[0])
    comps, states, xnames = [], [], []
    for j in range(n):
        obs, ctrl = Gains.from_model(gains or DEFAULT_GAINS).build(dt)
        xr0 = reference_state(obs.estimate_names, Qd[:1, j], QDd[:1, j], QDDd[:1, j])[0]
        comps.append((obs, ctrl))
        states.append(obs.initial_state(xr0, [m.q_measured[j]], [QDDd[0, j]]))
        xnames.append(obs.estimate_names)
    fault_ns = None
    if fault is not None:
        fault_ns = arm.inject(replace(fault, start_s=before))
    stop_from = (fault_ns if fault_ns is not None else arm.stamp(int(round(before / dt)))) + int(round(stop_delay * 1e9))
    T = int(round((before + stop_delay + after) / dt))
    u_max = np.full(n, float(u_max))
    rec = {k: np.empty((T, n)) for k in ("q", "qd", "q_true", "qd_true", "brakes")}
    stamps = np.empty(T, np.int64)
    stop = None
    tau = np.array(arm.state.tau_pending)
    for k in range(T):
        stamps[k] = m.stamp_ns
        rec["q"][k], rec["qd"][k] = m.q_measured, m.qd_measured
        rec["q_true"][k], rec["qd_true"][k] = arm.state.q_prev, arm.state.qd_prev
        y = np.asarray(m.q_measured, dtype=np.float64)
        usable = bool(np.all(np.isfinite(y)))
        qh, qdh, u = np.zeros(n), np.zeros(n), np.zeros(n)
        if stop is None and m.stamp_ns >= stop_from:
            stop = StopState(n)
        for j in range(n):
            obs, ctrl = comps[j]
            if not usable:
                continue
            if stop is None:
                xr = np.array([{"q": Qd[k, j], "qd": QDd[k, j], "d": 0.0, "q_prev": Qd[max(k - 1, 0), j],
                                "u_prev": QDDd[max(k - 1, 0), j]}[nm] for nm in xnames[j]])
                uj, xh, _ = closed_loop_tick(states[j], ctrl, [y[j]], xr, QDDd[k, j])
                u[j] = uj[0]
            else:
                xh = states[j].partial_estimate([y[j]])
            qh[j] = xh[xnames[j].index("q")] if "q" in xnames[j] else y[j]
            qdh[j] = xh[xnames[j].index("qd")] if "qd" in xnames[j] else 0.0
        if usable:
            if stop is not None:
                u, _ = stop_tick(policy, stop, m.stamp_ns, qh, qdh, u_max)
                arm.set_brakes(stop.engaged)
            for j in range(n):
                states[j] = states[j].advance([y[j]], [u[j]])
            tau = rb.feedback_linearization(model, data, qh, qdh, u)
        # else: no estimate, no command: the previous command is held (tau unchanged)
        rec["brakes"][k] = arm.brakes
        m = arm.step(tau)
    return StopRun(names=names, stamps=stamps, q=rec["q"], qd=rec["qd"], q_true=rec["q_true"], qd_true=rec["qd_true"],
                   brakes=rec["brakes"].astype(bool), fault_ns=fault_ns if fault_ns is not None else stop_from,
                   stop_ns=stop_from, counters=dict(arm.counters),
                   reasons=tuple(stop.reasons) if stop is not None else ())
