"""A simulated torque-controlled arm with the paper's timing (pure core, no ROS).

Physics: Pinocchio forward dynamics (articulated-body algorithm) of a "true" robot,
``qdd = M_true(q)^-1 (tau - psi_true(q, qd)) + a_fault``, integrated with classical
Runge-Kutta 4 at ``dt / substeps`` (default 1 kHz; raised automatically if the friction's
stiffness needs it, see :meth:`SimulatedArm.reset`). The torque is held constant over each
4 ms interval (zero-order hold), as a real drive does.

Timing (paper Appendix A, ``x_p[k] = [q[k-1], q[k], qd[k], d[k], u_p[k-1]]``,
``y_p[k] = q[k-1]``). Tick k has stamp ``t_k = start_ns + k dt``:

* the measurement stamped ``t_k`` reports the position (and velocity) of ``t_{k-1}``:
  one sample of **output delay**, ``y[k] = q[k-1]``;
* the torque computed from the measurement of tick k (passed to the ``step`` call that
  follows it) acts during ``[t_{k+1}, t_{k+2})``: one sample of **input delay**, the
  ``u_p[k-1]`` entry of the state; during ``[t_k, t_{k+1})`` the previous command acts.

So with ``m_k = step(tau_{k-1})``: ``reset`` returns ``m_0`` (``q(t_{-1}) = q0``, the arm
having rested there) with physics at ``t_0``; ``step(tau_k)`` integrates ``[t_k, t_{k+1})``
under the pending ``tau_{k-1}``, stores ``tau_k`` as pending and returns ``m_{k+1}``
(stamp ``t_{k+1}``, reporting ``q(t_k)``). After the call the physics is at ``t_{k+1}``.
``Measurement.tau_applied`` is the motor torque that acted during ``[t_{k-1}, t_k)`` for
``m_k``, i.e. the torque acting from the reported state on.

Hardware of a real arm the controller must respect (:class:`SimConfig`): joint position
limits as hard stops (the URDF's limits; a joint reaching one stops there, its velocity
into the stop is lost), the drives' torque limits (the URDF's effort limits; a larger or a
non-finite command is clamped or refused and counted, never integrated), and per-joint
holding brakes (:meth:`SimulatedArm.set_brakes`): an engaged brake acts on a moving joint
as a Coulomb torque of ``brake_torque`` against its velocity and holds a joint at rest
(a locked joint keeps its position and zero velocity; the holding torque is assumed to
exceed the load, and the brake's reaction on the other joints within a substep is not
modelled). A non-finite torque command is a drive fault: every brake engages. Counts are
in :attr:`SimulatedArm.counters`.

Effects the nominal model lacks, each configurable (:class:`SimConfig`) and seeded: true
inertial parameters different from the controller's (:class:`~reachset_ros.robot.ModelError`),
viscous and Coulomb friction, encoder quantization, bounded measurement noise. Faults
(:meth:`SimulatedArm.inject`) from a given time: :class:`Payload`,
:class:`TorqueDisturbance`, :class:`AccelerationDisturbance`, :class:`SensorBias`,
:class:`FrozenSensor`, :class:`NaNSamples`.
"""
from __future__ import annotations

import copy
import math
from dataclasses import dataclass, field

import numpy as np
import pinocchio as pin

from ..errors import ReachsetError
from ..robot.dynamics import Friction, RobotModel, create_data, load_model, mass_matrix, psi
from ..robot.model_error import ModelError, add_payload, perturb

DT = 0.004
RK4_STABILITY = 2.5  # |h * lambda| kept below this (RK4's real-axis limit is 2.785)


# --------------------------------------------------------------------------- config

@dataclass(frozen=True)
class SimConfig:
    """Configuration of :class:`SimulatedArm` (immutable).

    Parameters
    ----------
    robot : RobotModel
        The controller's nominal model; the true robot is ``perturb(robot, model_error)``.
    model_error : ModelError or None
        How the truth differs from ``robot`` (None: identical).
    friction : Friction or None
        If given, the true robot's friction (replacing the one of ``robot``).
    dt : float
        I/O period [s] (0.004: 250 Hz).
    substeps : int
        RK4 steps per period (4: 1 kHz physics); more if stability requires.
    quantization : float
        Encoder resolution [rad] (0: off).
    position_noise, velocity_noise : float or tuple of n floats
        Standard deviation of Gaussian measurement noise (one for all joints, or one per
        joint), clipped at +-3 sigma so that it is bounded [rad], [rad/s] (0: off).
    start_ns : int
        Stamp of tick 0.
    hard_stops : bool
        Joint position limits (the robot's URDF limits) act as hard stops.
    torque_limits : bool
        Commands are clamped to the URDF's effort limits (counted ``torque_clamped``).
    brake_torque : tuple or None
        Holding-brake torque per joint [N m] (None: the URDF's effort limits).
    """

    robot: RobotModel = field(default_factory=load_model)
    model_error: ModelError | None = None
    friction: Friction | None = None
    dt: float = DT
    substeps: int = 4
    quantization: float = 3.5e-5
    position_noise: object = 0.0
    velocity_noise: object = 0.0
    start_ns: int = 1_000_000_000_000_000_000
    hard_stops: bool = True
    torque_limits: bool = True
    brake_torque: tuple | None = None

    def __post_init__(self):
        if not self.dt > 0 or self.substeps < 1:
            raise ReachsetError("simulator: dt must be > 0 and substeps >= 1")
        for f in ("quantization", "position_noise", "velocity_noise"):
            v = np.asarray(getattr(self, f), dtype=np.float64)
            if not np.all(np.isfinite(v)) or np.any(v < 0):
                raise ReachsetError(f"simulator: {f} must be finite and >= 0")
            if f != "quantization" and v.ndim and v.shape != (self.robot.nv,):
                raise ReachsetError(f"simulator: {f} needs one value or {self.robot.nv} (one per joint)")
        if self.brake_torque is not None:
            b = np.asarray(self.brake_torque, dtype=np.float64)
            if b.shape != (self.robot.nv,) or not np.all(np.isfinite(b)) or np.any(b <= 0):
                raise ReachsetError(f"simulator: brake_torque needs {self.robot.nv} finite values > 0")

    @classmethod
    def ideal(cls, robot: RobotModel | None = None, **kw) -> "SimConfig":
        """Truth = model, no quantization, no noise (unless given in ``kw``)."""
        for f in ("quantization", "position_noise", "velocity_noise"):
            kw.setdefault(f, 0.0)
        return cls(robot=robot or load_model(), **kw)

    @classmethod
    def realistic(cls, robot: RobotModel | None = None, seed: int = 0, **kw) -> "SimConfig":
        """Typical mismatch (:meth:`ModelError.typical`), 3.5e-5 rad encoder, noise
        1e-5 rad / 2e-3 rad/s."""
        kw.setdefault("model_error", ModelError.typical(seed))
        kw.setdefault("position_noise", 1e-5)
        kw.setdefault("velocity_noise", 2e-3)
        return cls(robot=robot or load_model(), **kw)

    #: Calibrated to the real LWA-4P (benchmarks/calibrate_sim.py --runs train --iterate 5;
    #: docs/robot.md): per joint the truth's friction is (1 + f_j) times the nominal model's
    #: (viscous and Coulomb), position noise sigma_j (velocity noise 20 sigma_j), 3.5e-5 rad encoder.
    CALIBRATED_FRICTION_ERROR = (0.171, 0.314, 0.171, 0.204, 0.095, 0.114)
    CALIBRATED_POSITION_NOISE = (2.0e-5, 1.6e-5, 3.2e-5, 2.8e-5, 3.1e-5, 2.8e-5)

    @classmethod
    def calibrated(cls, **kw) -> "SimConfig":
        """The simulated LWA-4P calibrated to the real one (issue 16.2): the nominal model is
        the identified ``config/lwa4p_nominal.yaml``; the truth differs from it by a friction
        error per joint, and measurement noise per joint, chosen so that the sets identified
        from simulated runs of the real recordings' own trajectories are within a factor 1.5
        of those identified from the real runs (Theorem 1, k* = 125, estimator fd): measured
        1.11 on the 75 training runs it was fitted on, 1.37 on the 25 held-out runs
        (docs/robot.md)."""
        from ..robot.lwa4p import load_nominal      # the shipped identified model
        f = np.asarray(cls.CALIBRATED_FRICTION_ERROR)
        kw.setdefault("robot", load_nominal())
        kw.setdefault("model_error", ModelError(viscous_scale=1 + f, coulomb_scale=1 + f, seed=0))
        kw.setdefault("position_noise", cls.CALIBRATED_POSITION_NOISE)
        kw.setdefault("velocity_noise", tuple(20 * x for x in cls.CALIBRATED_POSITION_NOISE))
        kw.setdefault("quantization", 3.5e-5)
        return cls(**kw)

    def true_robot(self) -> RobotModel:
        """The simulated ("true") robot."""
        truth = perturb(self.robot, self.model_error)
        if self.friction is not None:
            truth = truth.replace(friction=self.friction)
        return truth


# --------------------------------------------------------------------------- faults

@dataclass(frozen=True)
class Fault:
    """Base of all faults: active from ``start_s`` seconds after :meth:`SimulatedArm.reset`."""

    start_s: float = 0.0

    #: Physical faults change the arm's motion; sensor faults only its measurements.
    physical = False


@dataclass(frozen=True)
class Payload(Fault):
    """A point mass [kg] rigidly attached to the last link at ``com`` (link frame)."""

    mass: float = 1.0
    com: tuple = (0.0, 0.0, 0.05)
    physical = True


@dataclass(frozen=True)
class TorqueDisturbance(Fault):
    """A constant torque [N m] added on ``joint`` (index or name)."""

    joint: object = 0
    torque: float = 1.0
    physical = True


@dataclass(frozen=True)
class AccelerationDisturbance(Fault):
    """A constant acceleration [rad/s^2] added to ``joint`` (the ``d`` of Appendix A)."""

    joint: object = 0
    acceleration: float = 1.0
    physical = True


@dataclass(frozen=True)
class SensorBias(Fault):
    """A constant offset [rad] on the measured position of ``joint``."""

    joint: object = 0
    bias: float = 1e-3


@dataclass(frozen=True)
class FrozenSensor(Fault):
    """The measured position and velocity of ``joint`` stop updating (last value held)."""

    joint: object = 0


@dataclass(frozen=True)
class NaNSamples(Fault):
    """``count`` measurements of ``joint`` (None: all joints) are NaN."""

    joint: object = None
    count: int = 1


# --------------------------------------------------------------------------- state

@dataclass(frozen=True)
class Measurement:
    """One 250 Hz sample (see the module docstring for the timing).

    Attributes
    ----------
    stamp_ns : int
        Stamp of tick k.
    q_measured, qd_measured : np.ndarray
        Measured position [rad] / velocity [rad/s] of ``t_{k-1}``.
    tau_applied : np.ndarray
        Motor torque [N m] acting during ``[t_{k-1}, t_k)`` (without fault torques).
    """

    stamp_ns: int
    q_measured: np.ndarray
    qd_measured: np.ndarray
    tau_applied: np.ndarray

    @property
    def valid(self) -> bool:
        return bool(np.all(np.isfinite(self.q_measured)))


@dataclass
class SimState:
    """Mutable state of :class:`SimulatedArm` (true physics, pending command, faults)."""

    k: int
    q: np.ndarray              # true position at t_k
    qd: np.ndarray             # true velocity at t_k
    q_prev: np.ndarray         # true position at t_{k-1} (reported by measurement k)
    qd_prev: np.ndarray
    tau_prev: np.ndarray       # torque applied during [t_{k-1}, t_k)
    tau_pending: np.ndarray    # torque applied during [t_k, t_{k+1})
    substeps: int
    faults: list
    truth: RobotModel
    data: pin.Data
    payload_models: dict       # fault id -> truth with that payload (and the earlier ones)
    frozen: dict               # joint -> (q, qd) held
    nan_left: dict             # fault id -> samples left
    rng: np.random.Generator
    last_q: np.ndarray = None
    last_qd: np.ndarray = None
    brakes: np.ndarray = None      # holding brake engaged, per joint
    locked: np.ndarray = None      # braked joint at rest (held), per joint
    q_lock: np.ndarray = None      # where a locked joint is held


def quantize(q, step):
    """An encoder's reading of ``q``: rounded to the nearest multiple of ``step`` (> 0), as
    :meth:`SimulatedArm._measure` reads the position before adding the noise."""
    return np.round(np.asarray(q, dtype=np.float64) / step) * step


class SimulatedArm:
    """A simulated arm with the paper's one-sample input and output delays.

    Syntax::

        arm = SimulatedArm(SimConfig.realistic(), seed=1)
        m = arm.reset(q0)
        for k in range(n):
            tau = controller(m)          # torque from measurement k
            m = arm.step(tau)            # applied during [t_{k+1}, t_{k+2})

    Parameters
    ----------
    config : SimConfig
    seed : int
        Seed of the measurement noise (the same seed and inputs give identical outputs).
    """

    def __init__(self, config: SimConfig | None = None, seed: int = 0):
        self.config = config or SimConfig()
        self.seed = int(seed)
        self._truth0 = self.config.true_robot()
        self.state: SimState | None = None
        pm = self.config.robot.pin_model
        cfg = self.config
        n = self.config.robot.nv
        lo, hi = np.array(pm.lowerPositionLimit[:n], float), np.array(pm.upperPositionLimit[:n], float)
        ok = np.isfinite(lo) & np.isfinite(hi) & (lo < hi)
        self.q_lower = np.where(ok & cfg.hard_stops, lo, -np.inf)
        self.q_upper = np.where(ok & cfg.hard_stops, hi, np.inf)
        eff = np.array(pm.effortLimit[:n], float)
        eff_ok = np.isfinite(eff) & (eff > 0)
        self.tau_limit = np.where(eff_ok & cfg.torque_limits, eff, np.inf)
        self.brake_torque = (np.asarray(cfg.brake_torque, float) if cfg.brake_torque is not None
                             else np.where(eff_ok, eff, 100.0))
        #: hard_stop (a joint reaching a limit), torque_clamped (commands beyond the effort
        #: limits), invalid_command (non-finite commands: the brakes engage), brake_engaged
        self.counters = {"hard_stop": 0, "torque_clamped": 0, "invalid_command": 0, "brake_engaged": 0}

    # ------------------------------------------------------------------ helpers
    @property
    def joint_names(self) -> tuple:
        return self.config.robot.joint_names

    @property
    def nv(self) -> int:
        return self.config.robot.nv

    @property
    def true_robot(self) -> RobotModel:
        """The true robot in effect now (payload faults included)."""
        return self.state.truth if self.state else self._truth0

    def stamp(self, k: int) -> int:
        """Stamp [ns] of tick ``k``."""
        return int(self.config.start_ns + round(k * self.config.dt * 1e9))

    def onset_stamp(self, fault: Fault) -> int:
        """Stamp of the first measurement a fault can change.

        Sensor faults: the first tick with ``t_k >= start_s``. Physical faults act on the
        physics from the first integration substep starting at or after ``start_s``; the
        first true state they change is the next tick's, ``t_j``, and with the output delay
        the measurement stamped ``t_{j+1}`` is the first to show it. After :meth:`reset`, a
        fault starting before the arm's present tick k (e.g. ``start_s = 0`` injected after
        ``reset``) cannot change what is already measured or integrated: its onset is then
        tick k+1 (sensor) or k+2 (physical).
        """
        dt = self.config.dt
        now = self.state.k if self.state else -1        # the last measurement already taken
        if not fault.physical:
            return self.stamp(max(math.ceil(fault.start_s / dt - 1e-9), now + 1))
        sub = self.state.substeps if self.state else self.config.substeps
        h = dt / sub
        t_eff = math.ceil(fault.start_s / h - 1e-9) * h
        j = max(math.floor(t_eff / dt + 1e-9) + 1, now + 1)
        return self.stamp(j + 1)

    def _joint(self, j) -> int:
        if isinstance(j, str):
            if j not in self.joint_names:
                raise ReachsetError(f"simulator: unknown joint {j!r}")
            return self.joint_names.index(j)
        j = int(j)
        if not 0 <= j < self.nv:
            raise ReachsetError(f"simulator: joint index {j} out of range")
        return j

    def _stable_substeps(self, truth, data, q) -> int:
        """Substeps so that RK4 stays stable under the friction's velocity stiffness:
        ``h * max eig(M^-1 D) <= RK4_STABILITY``, ``D = diag(viscous + coulomb / v_c)``."""
        fr = truth.friction
        Dm = np.abs(fr.viscous) + np.abs(fr.coulomb) / fr.coulomb_velocity
        M = mass_matrix(truth, data, q)
        lam = float(np.max(np.abs(np.linalg.eigvals(np.linalg.solve(M, np.diag(Dm))))))
        need = math.ceil(self.config.dt * lam / RK4_STABILITY)
        return max(self.config.substeps, need)

    # ------------------------------------------------------------------ API
    def reset(self, q0=None, qd0=None, tau0=None) -> Measurement:
        """Start at rest (or at ``qd0``) at ``q0``; returns measurement 0.

        ``tau0`` is the torque acting during ``[t_0, t_1)`` (before the first command takes
        effect); default the true robot's holding torque ``psi_true(q0, qd0)``. Faults
        injected earlier are cleared.
        """
        n = self.nv
        q0 = np.zeros(n) if q0 is None else np.array(q0, dtype=np.float64).reshape(n)
        qd0 = np.zeros(n) if qd0 is None else np.array(qd0, dtype=np.float64).reshape(n)
        truth = self._truth0
        data = create_data(truth)
        if tau0 is None:
            tau0 = psi(truth, data, q0, qd0)
        tau0 = np.array(tau0, dtype=np.float64).reshape(n)
        self.state = SimState(
            k=0, q=q0.copy(), qd=qd0.copy(), q_prev=q0.copy(), qd_prev=qd0.copy(),
            tau_prev=tau0.copy(), tau_pending=tau0.copy(),
            substeps=self._stable_substeps(truth, data, q0), faults=[], truth=truth,
            data=data, payload_models={}, frozen={}, nan_left={},
            rng=np.random.default_rng(self.seed), brakes=np.zeros(n, bool), locked=np.zeros(n, bool),
            q_lock=np.zeros(n))
        self.counters = dict.fromkeys(self.counters, 0)
        return self._measure()

    def set_brakes(self, engage) -> None:
        """Engage (True) or release (False) each joint's holding brake from the next substep.

        ``engage``: bool per joint (or one bool for all). A joint whose brake is released is
        free again; one whose brake engages is decelerated by ``brake_torque`` and held once
        at rest.
        """
        st = self.state
        if st is None:
            raise ReachsetError("simulator: set_brakes() before reset()")
        e = np.broadcast_to(np.asarray(engage, dtype=bool), (self.nv,))
        self.counters["brake_engaged"] += int(np.sum(e & ~st.brakes))
        st.locked &= e
        st.brakes = e.copy()

    @property
    def brakes(self):
        """Engaged holding brakes (bool per joint)."""
        return self.state.brakes.copy()

    def inject(self, fault: Fault) -> int:
        """Add a fault (active from ``fault.start_s`` after reset); returns
        :meth:`onset_stamp`. Faults persist until :meth:`clear_faults` or the next :meth:`reset`."""
        if self.state is None:
            raise ReachsetError("simulator: inject() before reset()")
        if not isinstance(fault, Fault):
            raise ReachsetError(f"simulator: not a fault: {fault!r}")
        if getattr(fault, "joint", None) is not None:
            self._joint(fault.joint)
        if isinstance(fault, NaNSamples) and fault.count < 1:
            raise ReachsetError("simulator: NaNSamples.count must be >= 1")
        st = self.state
        st.faults.append(fault)
        if isinstance(fault, Payload):
            prev = [f for f in st.faults[:-1] if isinstance(f, Payload)]
            base = st.payload_models[id(prev[-1])] if prev else self._truth0
            st.payload_models[id(fault)] = add_payload(base, fault.mass, fault.com)
        if isinstance(fault, NaNSamples):
            st.nan_left[id(fault)] = int(fault.count)
        return self.onset_stamp(fault)

    def clear_faults(self) -> int:
        """Remove every injected fault from now on; returns how many were removed.

        The next measurement and the physics from the next substep are fault-free (a payload
        is dropped, a frozen sensor thaws, a bias disappears); what a physical fault already
        did to the motion stays. Faults of the same kind can be injected again.
        """
        st = self.state
        if st is None:
            raise ReachsetError("simulator: clear_faults() before reset()")
        n = len(st.faults)
        st.faults, st.payload_models, st.frozen, st.nan_left = [], {}, {}, {}
        st.truth = self._truth0
        return n

    def step(self, tau) -> Measurement:
        """Command ``tau`` [N m] (computed from the latest measurement); advance one tick.

        Integrates ``[t_k, t_{k+1})`` under the pending command, makes ``tau`` pending for
        ``[t_{k+1}, t_{k+2})`` and returns measurement k+1 (reporting ``q(t_k)``).
        """
        st = self.state
        if st is None:
            raise ReachsetError("simulator: step() before reset()")
        tau = np.array(tau, dtype=np.float64).reshape(self.nv)
        if not np.all(np.isfinite(tau)):
            # a drive fault: the command is refused and every brake engages
            self.counters["invalid_command"] += 1
            self.set_brakes(True)
            tau = st.tau_pending.copy()
        over = np.abs(tau) > self.tau_limit
        if np.any(over):
            self.counters["torque_clamped"] += 1
            tau = np.clip(tau, -self.tau_limit, self.tau_limit)
        q_k, qd_k = st.q.copy(), st.qd.copy()
        self._integrate(st, st.tau_pending)
        st.q_prev, st.qd_prev = q_k, qd_k
        st.tau_prev = st.tau_pending
        st.tau_pending = tau
        st.k += 1
        return self._measure()

    def preview_state(self):
        """True ``(q, qd)`` at ``t_{k+1}``, where the command given to the next
        :meth:`step` starts acting (it is already determined); no side effects."""
        st = copy.copy(self.state)
        st.q, st.qd = st.q.copy(), st.qd.copy()
        st.brakes, st.locked, st.q_lock = st.brakes.copy(), st.locked.copy(), st.q_lock.copy()
        counters = dict(self.counters)
        self._integrate(st, st.tau_pending)
        self.counters = counters
        return st.q, st.qd

    @property
    def true_state(self):
        """``(stamp_ns, q, qd)``: the true state at the latest tick's stamp."""
        st = self.state
        return self.stamp(st.k), st.q.copy(), st.qd.copy()

    # ------------------------------------------------------------------ internals
    def _active(self, st, f, t) -> bool:
        return t >= f.start_s - 1e-12

    def _integrate(self, st: SimState, tau: np.ndarray) -> None:
        h = self.config.dt / st.substeps
        t0 = st.k * self.config.dt
        for i in range(st.substeps):
            t = t0 + i * h
            truth, tau_ext, acc = self._physical_faults(st, t, tau)
            data = st.data
            fr = truth.friction
            pm = truth.pin_model

            def f(q, qd):
                return pin.aba(pm, data, q, qd, tau_ext - fr.torque(qd)) + acc

            q, qd = st.q, st.qd
            sliding = st.brakes & ~st.locked
            if np.any(sliding):
                # a braked joint at exactly zero velocity is at rest: held from now on
                now = sliding & (qd == 0.0)
                st.locked |= now
                st.q_lock = np.where(now, q, st.q_lock)
                sliding &= ~now
                tau_b = np.where(sliding, -self.brake_torque * np.sign(qd), 0.0)
                tau_ext = tau_ext + tau_b

                def f(q, qd, tau_ext=tau_ext):       # noqa: F811 (with the brake torque)
                    return pin.aba(pm, data, q, qd, tau_ext - fr.torque(qd)) + acc
            k1v, k1a = qd, f(q, qd)
            k2v = qd + 0.5 * h * k1a
            k2a = f(q + 0.5 * h * k1v, k2v)
            k3v = qd + 0.5 * h * k2a
            k3a = f(q + 0.5 * h * k2v, k3v)
            k4v = qd + h * k3a
            k4a = f(q + h * k3v, k4v)
            st.q = q + h / 6.0 * (k1v + 2 * k2v + 2 * k3v + k4v)
            st.qd = qd + h / 6.0 * (k1a + 2 * k2a + 2 * k3a + k4a)
            self._constraints(st, q, qd, sliding)

    def _constraints(self, st, q_before, qd_before, sliding):
        """Brakes and hard stops after a substep: a sliding braked joint whose velocity
        reached or crossed zero is at rest and held; held joints keep their position; a
        joint beyond a position limit stops at it (its velocity into the stop is lost)."""
        if np.any(sliding):
            stopped = sliding & (st.qd * qd_before <= 0.0)
            st.locked |= stopped
            st.q_lock = np.where(stopped, st.q, st.q_lock)
        if np.any(st.locked):
            st.q = np.where(st.locked, st.q_lock, st.q)
            st.qd = np.where(st.locked, 0.0, st.qd)
        below, above = st.q < self.q_lower, st.q > self.q_upper
        if np.any(below | above):
            inside = (q_before > self.q_lower) & (q_before < self.q_upper)
            self.counters["hard_stop"] += int(np.sum((below | above) & inside))   # arrivals at a stop
            st.q = np.clip(st.q, self.q_lower, self.q_upper)
            st.qd = np.where((below & (st.qd < 0)) | (above & (st.qd > 0)), 0.0, st.qd)

    def _physical_faults(self, st, t, tau):
        truth = self._truth0
        tau = tau.copy()
        acc = np.zeros(self.nv)
        for fl in st.faults:
            if not fl.physical or not self._active(st, fl, t):
                continue
            if isinstance(fl, Payload):
                truth = st.payload_models[id(fl)]
            elif isinstance(fl, TorqueDisturbance):
                tau[self._joint(fl.joint)] += fl.torque
            elif isinstance(fl, AccelerationDisturbance):
                acc[self._joint(fl.joint)] += fl.acceleration
        st.truth = truth
        return truth, tau, acc

    def _noise(self, st, std):
        z = st.rng.standard_normal(self.nv)          # drawn every tick: same stream always
        return np.asarray(std, dtype=np.float64) * np.clip(z, -3.0, 3.0)

    def _measure(self) -> Measurement:
        st, cfg = self.state, self.config
        q = st.q_prev.copy()
        qd = st.qd_prev.copy()
        nq = self._noise(st, cfg.position_noise)
        nqd = self._noise(st, cfg.velocity_noise)
        t = st.k * cfg.dt
        for fl in st.faults:
            if isinstance(fl, SensorBias) and self._active(st, fl, t):
                q[self._joint(fl.joint)] += fl.bias
        if cfg.quantization > 0:
            q = quantize(q, cfg.quantization)
        q = q + nq
        qd = qd + nqd
        for fl in st.faults:
            if fl.physical or not self._active(st, fl, t):
                continue
            if isinstance(fl, FrozenSensor):
                j = self._joint(fl.joint)
                if j not in st.frozen:
                    st.frozen[j] = ((st.last_q[j], st.last_qd[j]) if st.last_q is not None
                                    else (q[j], qd[j]))
                q[j], qd[j] = st.frozen[j]
            elif isinstance(fl, NaNSamples) and st.nan_left.get(id(fl), 0) > 0:
                idx = slice(None) if fl.joint is None else self._joint(fl.joint)
                q[idx] = np.nan
                qd[idx] = np.nan
                st.nan_left[id(fl)] -= 1
        st.last_q, st.last_qd = q.copy(), qd.copy()
        for a in (q, qd):
            a.setflags(write=False)
        tau_applied = st.tau_prev.copy()
        tau_applied.setflags(write=False)
        return Measurement(self.stamp(st.k), q, qd, tau_applied)
