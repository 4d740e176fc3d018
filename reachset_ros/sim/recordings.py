"""Simulated closed-loop recordings for tests, benchmarks and the docs' synthesis tables.

Two sources: independent joints of the per-joint plant of the paper's Appendix A with bounded
disturbances and a smooth model error along a sum-of-sines reference (:class:`Scenario`,
:func:`simulate_recordings`, through :func:`reachset_ros.systems.reference_loop.simulate_closed_loop`),
and the project's simulated arm (the LWA-4P, or any URDF's) driven by the nodes' control law
(:func:`simulate_arm_recordings`). Either becomes synthesis input directly
(:func:`recordings_series`) or a rosbag2 with the topics of INTERFACES.md (:func:`write_recordings`).

Imports :mod:`reachset_ros.systems` for the loop, never :mod:`reachset_ros.synthesis`; the
synthesis never imports this module.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .. import bags
from .. import defaults
from .. import robot as rb
from ..bags import JointSeries
from ..bags.messages import ESTIMATE_TOPIC, REFERENCE_TOPIC
from ..bags.references import Reference
from ..errors import ReachsetError
from ..systems.closedloop import closed_loop_tick
from ..systems.gains import Gains, family_controller
from ..systems.plant import lwa4p_joint_plant
from ..systems.reference_loop import reference_state, simulate_closed_loop
from . import reference as refm
from . import simulator as simm

__all__ = ["Scenario", "Recording", "DEFAULT_GAINS", "simulate_recordings", "recordings_series",
           "write_recordings", "simulate_arm_recordings"]


@dataclass(frozen=True)
class Scenario:
    """A simulated joint for tests, benchmarks and the docs' tables (deterministic per seed).

    Reference: a sum of three sines scaled to ``|qd_d| <= qd_max``, ``|qdd_d| <= qdd_max``,
    ``|q_d| <= q_max``. Process disturbance ``w = G'_W [w1, w2]``: ``w1`` i.i.d. uniform in
    ``[-a1, a1]`` (rad/s); ``w2`` (rad/s^2) an i.i.d. uniform part in ``[-a2, a2]`` plus a
    smooth model error along the reference (viscous ``c_visc qd_d``, Coulomb
    ``c_coul tanh(qd_d / 0.05)``, gravity ``c_grav cos(q_d)``), the kind of error a feedback
    linearization leaves. Measurement noise uniform in ``[-av, av]`` rad.
    """

    a1: float = 0.002
    a2: float = 0.5
    c_visc: float = 0.5
    c_coul: float = 0.3
    c_grav: float = 0.5
    av: float = 3.5e-5
    qd_max: float = 0.7
    qdd_max: float = 1.8
    q_max: float = 1.2

    @classmethod
    def for_joint(cls, index):
        """Joint-dependent magnitudes (wrist joints 5-6 worse, as in the paper's data)."""
        i = int(index)
        scale = 1.0 + 0.25 * i + (1.5 if i >= 4 else 0.0)
        return cls(a1=0.002, a2=0.5 * scale, c_visc=0.4 * scale, c_coul=0.3 * scale, c_grav=0.4 * scale)


@dataclass(frozen=True)
class Recording:
    """A simulated recording of one joint (all arrays of length T)."""

    stamps: np.ndarray
    y: np.ndarray
    u: np.ndarray
    x_hat: np.ndarray
    estimate_names: tuple
    q_d: np.ndarray
    qd_d: np.ndarray
    qdd_d: np.ndarray


def _reference(T, dt, rng, sc):
    t = np.arange(T) * dt
    f = rng.uniform(0.05, 0.35, 3) * 2 * np.pi
    ph = rng.uniform(0, 2 * np.pi, 3)
    a = rng.uniform(0.5, 1.0, 3)
    q = (a[None, :] * np.sin(f[None, :] * t[:, None] + ph[None, :])).sum(axis=1)
    qd = (a * f)[None, :] * np.cos(f[None, :] * t[:, None] + ph[None, :])
    qdd = -(a * f * f)[None, :] * np.sin(f[None, :] * t[:, None] + ph[None, :])
    qd, qdd = qd.sum(axis=1), qdd.sum(axis=1)
    s = min(sc.q_max / max(np.abs(q).max(), 1e-9), sc.qd_max / max(np.abs(qd).max(), 1e-9),
            sc.qdd_max / max(np.abs(qdd).max(), 1e-9))
    return s * q, s * qd, s * qdd


defaults.register("sim", {
    "recording_gains": ({"observer": "hg", "controller": family_controller("hg"),
                         **defaults.get("gains.feedback.paper"),
                         **{n: defaults.get(f"gains.hg.{n}") for n in ("h1", "h2", "eps")}},
                        "the gains the simulator's recordings are made with when none are given (model-file "
                        "gains): the HG observer of Sec. IV-A with the paper's fixed feedback law (Sec. IV-C, "
                        "omega 20, zeta 1); not the nodes' start-up gains (gains.startup)"),
}, owner=__name__)
#: the simulator's recording gains (defaults ``sim.recording_gains``)
DEFAULT_GAINS = defaults.get("sim.recording_gains")


def simulate_recordings(joints, ticks, seed=0, gains=None, scenarios=None, plant=None, t0=1_700_000_000_000_000_000):
    """Simulated closed-loop recordings of independent joints (the per-joint plant of App. A).

    Parameters
    ----------
    joints : sequence of str
    ticks : int
    seed : int
        Everything (references, disturbances) is a deterministic function of the seed and the
        joint's position in ``joints``.
    gains : dict, optional
        ``{joint: gains}`` (model-file gains, :meth:`reachset_ros.systems.gains.Gains.from_model`)
        or one gains dict for all joints; default HG (15, 30, eps 0.01) + static feedback (omega 20,
        zeta 1).
    scenarios : dict, optional
        ``{joint: Scenario}``; default :meth:`Scenario.for_joint`.

    Returns
    -------
    dict name -> Recording
    """
    plant = plant or lwa4p_joint_plant()
    dt = plant.dt
    out = {}
    for i, name in enumerate(joints):
        g = gains.get(name, DEFAULT_GAINS) if isinstance(gains, dict) and "observer" not in gains else (
            gains or DEFAULT_GAINS)
        obs, ctrl = Gains.from_model(g).build(dt)
        sc = (scenarios or {}).get(name) or Scenario.for_joint(i)
        rng = np.random.default_rng([int(seed), i])
        q_d, qd_d, qdd_d = _reference(ticks, dt, rng, sc)
        w1 = rng.uniform(-sc.a1, sc.a1, ticks)
        w2 = (rng.uniform(-sc.a2, sc.a2, ticks) + sc.c_visc * qd_d + sc.c_coul * np.tanh(qd_d / 0.05)
              + sc.c_grav * np.cos(q_d))
        w = np.column_stack([w1, w2]) @ plant.Gw.T
        v = rng.uniform(-sc.av, sc.av, (ticks, 1)) @ plant.Gv.T
        sim = simulate_closed_loop(plant, obs, ctrl, q_d, qd_d, qdd_d, w, v)
        stamps = t0 + np.arange(ticks, dtype=np.int64) * int(round(dt * 1e9))
        out[name] = Recording(stamps, sim["y"][:, 0], sim["u"][:, 0], sim["x_hat"], obs.estimate_names,
                              q_d, qd_d, qdd_d)
    return out


def recordings_series(recs, dt=0.004):
    """``({joint: JointSeries}, {joint: [Reference]})`` of :func:`simulate_recordings` output."""
    series, refs = {}, {}
    for name, r in recs.items():
        n = len(r.stamps)
        series[name] = JointSeries(name, r.stamps, r.y, r.u, ((0, n),), dt)
        refs[name] = [Reference(r.stamps, r.q_d, r.qd_d, r.qdd_d)]
    return series, refs


def write_recordings(path, recs, reference=True, estimate=True, storage="mcap"):
    """Write :func:`simulate_recordings` output as a rosbag2 with the topics of INTERFACES.md.

    ``/joint_states`` (position = y), ``/plant_input`` (u_p), and optionally ``/reference``
    (q_d, qd_d, qdd_d) and ``/observer/estimate`` (q_hat, qd_hat, d_hat).
    """
    ts = bags.typestore()
    JR = ts.types["reachset_msgs/msg/JointReference"]
    JE = ts.types["reachset_msgs/msg/JointEstimate"]
    names = list(recs)
    first = recs[names[0]]
    T = len(first.stamps)
    Y = np.column_stack([recs[n].y for n in names])
    U = np.column_stack([recs[n].u for n in names])

    def est(n, k, nm):
        r = recs[n]
        return float(r.x_hat[k, r.estimate_names.index(nm)]) if nm in r.estimate_names else 0.0

    with bags.BagWriter(path, storage=storage) as w:
        for k in range(T):
            st = int(first.stamps[k])
            w.write(bags.JOINT_STATES, bags.joint_state(st, names, Y[k]), st + 200_000)
            w.write(bags.PLANT_INPUT, bags.plant_input(st, names, U[k]), st + 500_000)
            if reference:
                w.write(REFERENCE_TOPIC, JR(header=bags.header(st), name=names,
                                            position=np.array([recs[n].q_d[k] for n in names]),
                                            velocity=np.array([recs[n].qd_d[k] for n in names]),
                                            acceleration=np.array([recs[n].qdd_d[k] for n in names])),
                        st + 100_000, "reachset_msgs/msg/JointReference")
            if estimate:
                w.write(ESTIMATE_TOPIC, JE(header=bags.header(st), name=names,
                                           position=np.array([est(n, k, "q") for n in names]),
                                           velocity=np.array([est(n, k, "qd") for n in names]),
                                           disturbance=np.array([est(n, k, "d") for n in names])),
                        st + 400_000, "reachset_msgs/msg/JointEstimate")
    return Path(path)


def _arm_reference(cfg, names, *, seconds, seed, reference_config, reference):
    """``(Qd, QDd, QDDd)`` (T, n) of :func:`simulate_arm_recordings`: the explicit ``reference``,
    or the project's random point-to-point trajectories of ``seconds`` (Table I for the LWA-4P,
    the URDF's limits for any other arm)."""
    n = len(names)
    if reference_config is None and names != tuple(rb.JOINT_NAMES):
        reference_config = refm.ReferenceConfig.for_robot(cfg.robot)
    if reference is None:
        gen = refm.ReferenceGenerator(reference_config, seed=seed)
        _, Qd, QDd, QDDd = gen.trajectory(seconds, cfg.dt)
        return Qd, QDd, QDDd
    Qd, QDd, QDDd = (np.asarray(a, dtype=np.float64).reshape(-1, n) for a in reference)
    if not (len(Qd) == len(QDd) == len(QDDd) > 1):
        raise ReachsetError("simulate_arm_recordings: reference arrays of different lengths")
    return Qd, QDd, QDDd


def _joint_loops(names, gains, *, dt, q0, ref0):
    """Each joint's ``(observer, controller)``, initial observer state and estimate names, from
    ``gains`` (``{joint: gains}`` or one gains dict, default :data:`DEFAULT_GAINS`), the first
    measurement ``q0`` and the first reference sample ``ref0 = (Qd[:1], QDd[:1], QDDd[:1])``."""
    Qd0, QDd0, QDDd0 = ref0
    comps, states, xnames = [], [], []
    for j, nm in enumerate(names):
        g = gains.get(nm, DEFAULT_GAINS) if isinstance(gains, dict) and "observer" not in gains else (
            gains or DEFAULT_GAINS)
        obs, ctrl = Gains.from_model(g).build(dt)
        xr0 = reference_state(obs.estimate_names, Qd0[:, j], QDd0[:, j], QDDd0[:, j])[0]
        comps.append((obs, ctrl))
        states.append(obs.initial_state(xr0, [q0[j]], [QDDd0[0, j]]))
        xnames.append(obs.estimate_names)
    return comps, states, xnames


def _reference_row(names, q_d, qd_d, qdd_d, k):
    """The reference of tick ``k`` in the estimate coordinates ``names`` (q, qd, d, q_prev, u_prev)."""
    xr = np.empty(len(names))
    for i, nm in enumerate(names):
        xr[i] = {"q": q_d[k], "qd": qd_d[k], "d": 0.0,
                 "q_prev": q_d[max(k - 1, 0)], "u_prev": qdd_d[max(k - 1, 0)]}[nm]
    return xr


def simulate_arm_recordings(seconds, gains=None, seed=0, sim_config=None, reference_config=None, faults=(),
                            log=None, reference=None):
    """Recordings of the project's simulated arm (:mod:`reachset_ros.sim.simulator`) in closed loop.

    Any serial arm: the simulated LWA-4P by default, any URDF's model through ``sim_config``.
    The nodes' code path without ROS: per tick the measurement ``y[k] = q[k-1]`` (one sample
    of output delay) goes through each joint's observer and control law
    (:func:`reachset_ros.systems.closedloop.closed_loop_tick`, ``u_ff = qdd_d``), the torque is the
    feedback linearization ``tau = M(q_hat) u_p + psi(q_hat, qd_hat)`` (paper eq. 6) of the
    *nominal* model (the controller node's law; with the exact model the joints would obey
    ``qdd = u_p``, eq. 7) and the simulated arm (the "true" robot of eq. 5 with model error,
    friction, quantization and noise; :meth:`SimConfig.realistic`) applies it with one sample
    of input delay. The references are the project's random point-to-point trajectories
    (:class:`reachset_ros.sim.reference.ReferenceGenerator`, |qdd_d| <= 2). A non-finite
    measurement of a joint (a :class:`~reachset_ros.sim.simulator.NaNSamples` fault) is skipped
    as ``observer_node`` skips it: that joint's observer does not advance and its previous
    u_p holds for the tick (counted in ``log["skipped_samples"]``).

    Parameters
    ----------
    seconds : float
    gains : dict, optional
        ``{joint: gains}`` or one gains dict for all joints (default :data:`DEFAULT_GAINS`).
    seed : int
        Seeds the reference, the measurement noise and the model error.
    sim_config : SimConfig, optional
        The simulated arm (default :meth:`SimConfig.realistic` of the LWA-4P); any arm's
        model works (``SimConfig.realistic(robot=rb.load_model(urdf, joints=...))``).
    reference_config : ReferenceConfig, optional
        Default: :class:`ReferenceConfig`'s (Table I) for the shipped LWA-4P,
        :meth:`ReferenceConfig.for_robot` (the URDF's limits) for any other arm.
    faults : sequence of Fault
        Injected after the reset (:meth:`SimulatedArm.inject`); their onset stamps go to
        ``log["fault_onsets"]``.
    reference : (Qd, QDd, QDDd), optional
        An explicit reference, arrays (T, n) at dt (e.g. a real recording's trajectory);
        ``seconds`` and ``reference_config`` are then not used.
    log : dict, optional
        Filled with arrays of every tick: ``stamps`` (T,), ``q``, ``qd`` (T, n) measured,
        ``effort`` (T, n) the torque command issued at the tick [N m] (clamped to the
        URDF's effort limits when the arm clamps, i.e. what the drive executes),
        ``fault_onsets``, ``counters`` (the arm's :attr:`SimulatedArm.counters` at the end:
        ``hard_stop``, ``torque_clamped``, ``invalid_command``, ``brake_engaged``) and
        ``skipped_samples`` (n,) (non-finite samples skipped, per joint), ``q_true``, ``qd_true`` (T, n) true states.

    Returns
    -------
    dict name -> Recording (every joint of the arm)
    """
    cfg = sim_config or simm.SimConfig.realistic(seed=seed)
    arm = simm.SimulatedArm(cfg, seed=seed)
    names = tuple(arm.joint_names)
    n = len(names)
    dt = cfg.dt
    Qd, QDd, QDDd = _arm_reference(cfg, names, seconds=seconds, seed=seed, reference_config=reference_config,
                                   reference=reference)
    T = len(Qd)
    model = cfg.robot
    data = rb.create_data(model)
    # an explicit reference (a real run) may start moving: the arm starts on it, not at rest
    m = arm.reset(Qd[0]) if reference is None else arm.reset(Qd[0], QDd[0])
    onsets = [int(arm.inject(f)) for f in faults]
    comps, states, xnames = _joint_loops(names, gains, dt=dt, q0=m.q_measured, ref0=(Qd[:1], QDd[:1], QDDd[:1]))
    Y, U = np.empty((T, n)), np.empty((T, n))
    XH = [np.empty((T, len(xn))) for xn in xnames]
    stamps = np.empty(T, np.int64)
    qh, qdh, u = Qd[0].copy(), QDd[0].copy(), np.zeros(n)    # (held by a joint whose sample is skipped)
    QDm, EFF, QT, QDT = (np.empty((T, n)) for _ in range(4))      # QT, QDT: the true state at each stamp
    skipped = np.zeros(n, np.int64)
    lim = arm.tau_limit                 # the drives' clamp (inf where there is none)
    for k in range(T):
        stamps[k], QDm[k] = m.stamp_ns, m.qd_measured
        _, QT[k], QDT[k] = arm.true_state
        y = m.q_measured
        for j in range(n):
            obs, ctrl = comps[j]
            if not np.isfinite(y[j]):
                # an invalid sample is skipped, as observer_node does (a non-finite input would
                # poison the observer state for good): no estimate, the previous command holds
                skipped[j] += 1
                XH[j][k] = XH[j][k - 1] if k else np.nan
                continue
            xr = _reference_row(xnames[j], Qd[:, j], QDd[:, j], QDDd[:, j], k)
            uj, xh, states[j] = closed_loop_tick(states[j], ctrl, [y[j]], xr, QDDd[k, j])
            u[j] = uj[0]
            XH[j][k] = xh
            qh[j] = xh[xnames[j].index("q")] if "q" in xnames[j] else y[j]
            qdh[j] = xh[xnames[j].index("qd")] if "qd" in xnames[j] else 0.0
        Y[k], U[k] = y, u
        tau = rb.feedback_linearization(model, data, qh, qdh, u)
        EFF[k] = np.clip(tau, -lim, lim)
        m = arm.step(tau)
    if log is not None:
        log.update(stamps=stamps.copy(), q=Y.copy(), qd=QDm, effort=EFF, fault_onsets=onsets, names=names,
                   counters=dict(arm.counters), skipped_samples=skipped, q_true=QT, qd_true=QDT)
    out = {}
    for j, nm in enumerate(names):
        out[nm] = Recording(stamps.copy(), Y[:, j].copy(), U[:, j].copy(), XH[j], xnames[j],
                            Qd[:, j].copy(), QDd[:, j].copy(), QDDd[:, j].copy())
    return out
