"""The Schunk LWA-4P rigid-body model: M(q), psi(q, qdot), feedback linearization, identification.

Pure core (no ROS). Pinocchio style: an immutable model value (:class:`RobotModel`) and
plain functions taking ``(model, data, ...)``, where ``data`` is a Pinocchio ``pin.Data``
made by :func:`create_data` and owned by the caller (one per thread / per node).

The dynamics are the paper's eq. (5),

    M(q) qdd + psi(q, qd) = tau,

with ``psi`` = Coriolis + centripetal + gravity (Pinocchio's non-linear effects) + joint
friction (viscous + smooth Coulomb + constant offset, :class:`Friction`). The reflected rotor
inertia (Pinocchio's ``model.armature``) is part of ``M``. Feedback linearization, eq. (6),

    tau = M(q) u_p + psi(q, qd)      gives   qdd = u_p      (eq. 7)

for the exact model; :func:`inverse_fl` is its inverse ``u_p = M^-1 (tau - psi)``, used to
compute the plant input of recorded data.

Identification: the joint torque is linear in the extended standard parameters
``theta = [pi_1..pi_n (10 per link, Pinocchio order m, mc_x, mc_y, mc_z, I_xx, I_xy, I_yy,
I_xz, I_yz, I_zz at the joint frame), armature, viscous, coulomb, offset]``, with the
regressor from ``pin.computeJointTorqueRegressor`` plus one column per joint for each of
the four joint terms (:func:`regressor`). :class:`BaseParameters` reduces it to identifiable
base parameters (QR with column pivoting on random samples); :func:`torque_gram` reduces a
data set to per-joint normal equations and :func:`identify` solves the least-squares
problem -- plain base-parameter least squares or, by default, the physically consistent
variant (pseudo-inertia LMIs, so that M(q) stays positive definite) -- including a
per-joint torque scale for logged torques whose units are unknown.

Inertial values of the shipped URDF are plausible placeholders, not identified (see
``data/lwa4p.urdf`` and docs/robot.md).
"""
from __future__ import annotations

import dataclasses
import warnings
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pinocchio as pin

from ..errors import ReachsetError

#: Joint names of the LWA-4P, in kinematic order.
JOINT_NAMES = tuple(f"arm_{i}_joint" for i in range(1, 7))
#: The shipped URDF (kinematics of SPEC.md; plausible, non-identified inertial values).
DEFAULT_URDF = Path(__file__).resolve().parents[1] / "data" / "lwa4p.urdf"
#: Paper Table I: torque limit used for deriving U_p [N m].
TABLE1_TAU_MAX = np.array([160.0, 160.0, 160.0, 160.0, 40.0, 40.0])
#: Paper Table I: the box Q = [-q_max, q_max] [rad] (140/45/100/140/80/140 deg).
TABLE1_Q_MAX = np.deg2rad([140.0, 45.0, 100.0, 140.0, 80.0, 140.0])
#: Paper Table I: velocity box dQ [rad/s].
TABLE1_QD_MAX = np.full(6, 0.7)
#: Paper Sec. IV: reference accelerations qdd_d in U_ref = [-2, 2] rad/s^2.
U_REF = 2.0
#: Default smoothing velocity of the Coulomb term tanh(qd / v_c) [rad/s].
COULOMB_VELOCITY = 0.02
_ARMATURE_TAG = "{https://github.com/reachset_ros/reachset_ros}armature"
PARAMS_PER_LINK = 10
LINK_PARAM_NAMES = ("m", "mc_x", "mc_y", "mc_z", "I_xx", "I_xy", "I_yy", "I_xz", "I_yz", "I_zz")
JOINT_PARAM_NAMES = ("armature", "viscous", "coulomb", "offset")


def _frozen(a, n=None, name="array"):
    a = np.array(a, dtype=np.float64).reshape(-1)
    if n is not None:
        if a.size == 1:
            a = np.full(n, float(a[0]))
        if a.size != n:
            raise ReachsetError(f"{name}: expected {n} values, got {a.size}")
    a.setflags(write=False)
    return a


@dataclass(frozen=True)
class Friction:
    """Joint friction ``tau_f = viscous*qd + coulomb*tanh(qd/coulomb_velocity) + offset``.

    Parameters
    ----------
    viscous : array_like, shape (n,)
        Viscous coefficients [N m s/rad].
    coulomb : array_like, shape (n,)
        Coulomb levels [N m]; smoothed with ``tanh`` so that psi is differentiable.
    offset : array_like, shape (n,)
        Constant torque offset [N m] (sensor / motor-current offset of a real drive).
    coulomb_velocity : float
        Smoothing velocity [rad/s] of the Coulomb term.
    """

    viscous: np.ndarray
    coulomb: np.ndarray
    offset: np.ndarray
    coulomb_velocity: float = COULOMB_VELOCITY

    def __post_init__(self):
        n = np.size(self.viscous)
        for f in ("viscous", "coulomb", "offset"):
            object.__setattr__(self, f, _frozen(getattr(self, f), n, f))
        if not self.coulomb_velocity > 0:
            raise ReachsetError("friction coulomb_velocity must be > 0")

    @classmethod
    def zero(cls, n=6):
        return cls(np.zeros(n), np.zeros(n), np.zeros(n))

    def torque(self, qd):
        """Friction torque at joint velocity ``qd`` (any leading batch shape)."""
        qd = np.asarray(qd, dtype=np.float64)
        return (self.viscous * qd + self.coulomb * np.tanh(qd / self.coulomb_velocity)
                + self.offset)


@dataclass(frozen=True)
class RobotModel:
    """Immutable robot model value: Pinocchio model + friction + torque scale.

    Never mutate ``pin_model`` in place: every function here that changes parameters
    returns a new :class:`RobotModel` built on a copy. Dynamic quantities are computed by
    the module functions with a separate ``pin.Data`` (:func:`create_data`).

    Attributes
    ----------
    pin_model : pin.Model
        Kinematics, link inertias and ``armature`` (reflected rotor inertia, part of M).
    friction : Friction
        Joint friction, part of psi.
    torque_scale : np.ndarray, shape (n,)
        Joint torque [N m] per unit of logged torque: ``tau = torque_scale * logged``.
        Ones for a simulated robot; identified for the real recordings.
    source : str
        Where the parameters come from (URDF path, identification command, ...).
    """

    pin_model: pin.Model
    friction: Friction
    torque_scale: np.ndarray = None
    source: str = ""

    def __post_init__(self):
        n = self.pin_model.nv
        if self.pin_model.nq != n:
            raise ReachsetError("only revolute/prismatic joints (nq == nv) are supported")
        ts = np.ones(n) if self.torque_scale is None else self.torque_scale
        object.__setattr__(self, "torque_scale", _frozen(ts, n, "torque_scale"))
        if np.size(self.friction.viscous) != n:
            raise ReachsetError(f"friction has {np.size(self.friction.viscous)} joints, model {n}")

    @property
    def nv(self) -> int:
        return self.pin_model.nv

    @property
    def joint_names(self) -> tuple:
        return tuple(self.pin_model.names[1:])

    @property
    def armature(self) -> np.ndarray:
        return _frozen(self.pin_model.armature)

    @property
    def lower(self) -> np.ndarray:
        return _frozen(self.pin_model.lowerPositionLimit)

    @property
    def upper(self) -> np.ndarray:
        return _frozen(self.pin_model.upperPositionLimit)

    @property
    def velocity_limit(self) -> np.ndarray:
        return _frozen(self.pin_model.velocityLimit)

    @property
    def effort_limit(self) -> np.ndarray:
        return _frozen(self.pin_model.effortLimit)

    def replace(self, **changes) -> "RobotModel":
        """A copy with fields replaced (``dataclasses.replace``)."""
        return dataclasses.replace(self, **changes)

    def __repr__(self):
        return (f"RobotModel(joints={list(self.joint_names)}, source={self.source!r}, "
                f"torque_scale={np.round(self.torque_scale, 4).tolist()})")


def create_data(model: RobotModel) -> pin.Data:
    """A fresh Pinocchio ``Data`` for ``model`` (the mutable workspace of all functions)."""
    return model.pin_model.createData()


# --------------------------------------------------------------------------- loading

def _read_armature(urdf: Path, names) -> np.ndarray:
    arm = np.zeros(len(names))
    try:
        root = ET.parse(urdf).getroot()
    except ET.ParseError as e:
        raise ReachsetError(f"{urdf}: malformed URDF ({e})") from e
    for el in root.iter(_ARMATURE_TAG):
        j = el.get("joint")
        if j not in names:
            raise ReachsetError(f"{urdf}: armature for unknown joint {j!r}")
        arm[names.index(j)] = float(el.get("value"))
    return arm


def load_model(urdf=None, params=None) -> RobotModel:
    """Load the robot model.

    Parameters
    ----------
    urdf : str or Path, optional
        URDF file; default the shipped LWA-4P (:data:`DEFAULT_URDF`). ``<dynamics damping
        friction>`` become viscous / Coulomb friction, ``<reachset:armature>`` the armature.
    params : str, Path or dict, optional
        Identified parameters (the YAML written by ``reachset fit-lwa4p``, e.g.
        ``config/lwa4p_nominal.yaml``, or its dict) applied over the URDF's values.

    Returns
    -------
    RobotModel
    """
    urdf = Path(urdf) if urdf is not None else DEFAULT_URDF
    if not urdf.is_file():
        raise ReachsetError(f"{urdf}: URDF not found")
    try:
        pm = pin.buildModelFromUrdf(str(urdf))
    except Exception as e:  # noqa: BLE001  (Pinocchio raises plain exceptions)
        raise ReachsetError(f"{urdf}: cannot load URDF ({str(e).splitlines()[0]})") from e
    names = list(pm.names[1:])
    pm.armature[:] = _read_armature(urdf, names)
    fr = Friction(viscous=np.array(pm.damping), coulomb=np.array(pm.friction),
                  offset=np.zeros(pm.nv))
    model = RobotModel(pm, fr, None, source=str(urdf))
    if params is not None:
        model = apply_params(model, params)
    return model


def apply_params(model: RobotModel, params) -> RobotModel:
    """Apply an identified-parameter document (dict or YAML path) to ``model``.

    The document has ``joints`` (names, must match), ``links`` (per joint: ``mass``,
    ``com`` [3], ``inertia`` [Ixx, Ixy, Iyy, Ixz, Iyz, Izz] about the COM), ``armature``,
    ``friction`` (``viscous``, ``coulomb``, ``offset``, ``coulomb_velocity``) and
    ``torque_scale``; missing entries keep the model's values.
    """
    src = "params"
    if not isinstance(params, dict):
        import yaml
        path = Path(params)
        if not path.is_file():
            raise ReachsetError(f"{path}: parameter file not found")
        try:
            params = yaml.safe_load(path.read_text())
        except yaml.YAMLError as e:
            raise ReachsetError(f"{path}: malformed YAML ({str(e).splitlines()[0]})") from e
        if not isinstance(params, dict):
            raise ReachsetError(f"{path}: expected a mapping")
        src = str(path)
    names = model.joint_names
    if "joints" in params and tuple(params["joints"]) != names:
        raise ReachsetError(f"{src}: joints {params['joints']} do not match the model {list(names)}")
    pm = model.pin_model.copy()
    try:
        for i, link in enumerate(params.get("links", []) or []):
            I = np.array(link["inertia"], dtype=float)
            Ic = np.array([[I[0], I[1], I[3]], [I[1], I[2], I[4]], [I[3], I[4], I[5]]])
            pm.inertias[i + 1] = pin.Inertia(float(link["mass"]), np.array(link["com"], float), Ic)
        if "armature" in params:
            pm.armature[:] = np.array(params["armature"], dtype=float)
        f = params.get("friction", {}) or {}
        fr = Friction(viscous=f.get("viscous", model.friction.viscous),
                      coulomb=f.get("coulomb", model.friction.coulomb),
                      offset=f.get("offset", model.friction.offset),
                      coulomb_velocity=float(f.get("coulomb_velocity",
                                                   model.friction.coulomb_velocity)))
        scale = params.get("torque_scale", model.torque_scale)
        return RobotModel(pm, fr, _frozen(scale, model.nv, "torque_scale"),
                          source=params.get("source", src) if src == "params" else src)
    except (KeyError, TypeError, ValueError, IndexError) as e:
        raise ReachsetError(f"{src}: malformed parameters ({e!r})") from e


def model_params_dict(model: RobotModel) -> dict:
    """The parameter document of ``model`` (inverse of :func:`apply_params`), YAML-ready."""
    links = []
    for i in range(1, model.nv + 1):
        I = model.pin_model.inertias[i]
        Ic = I.inertia
        links.append({"mass": float(I.mass), "com": [float(x) for x in I.lever],
                      "inertia": [float(Ic[0, 0]), float(Ic[0, 1]), float(Ic[1, 1]),
                                  float(Ic[0, 2]), float(Ic[1, 2]), float(Ic[2, 2])]})
    fr = model.friction
    return {
        "joints": list(model.joint_names),
        "links": links,
        "armature": [float(x) for x in model.armature],
        "friction": {"viscous": fr.viscous.tolist(), "coulomb": fr.coulomb.tolist(),
                     "offset": fr.offset.tolist(), "coulomb_velocity": float(fr.coulomb_velocity)},
        "torque_scale": model.torque_scale.tolist(),
    }


# --------------------------------------------------------------------------- dynamics

def mass_matrix(model: RobotModel, data: pin.Data, q) -> np.ndarray:
    """Joint-space inertia matrix M(q) of eq. (5), armature included (symmetric, n x n)."""
    M = pin.crba(model.pin_model, data, np.asarray(q, dtype=np.float64))
    return np.triu(M) + np.triu(M, 1).T


def friction_torque(model: RobotModel, qd) -> np.ndarray:
    """Friction part of psi (see :class:`Friction`)."""
    return model.friction.torque(qd)


def psi(model: RobotModel, data: pin.Data, q, qd) -> np.ndarray:
    """psi(q, qd) of eq. (5): Coriolis + centripetal + gravity + friction [N m]."""
    qd = np.asarray(qd, dtype=np.float64)
    return (pin.nonLinearEffects(model.pin_model, data, np.asarray(q, dtype=np.float64), qd)
            + model.friction.torque(qd))


def feedback_linearization(model: RobotModel, data: pin.Data, q, qd, u_p) -> np.ndarray:
    """Feedback-linearizing torque of eq. (6): ``tau = M(q) u_p + psi(q, qd)`` [N m].

    Computed with the recursive Newton-Euler algorithm (``rnea(q, qd, u_p)`` equals
    ``M(q) u_p + nle(q, qd)``, armature included) plus friction. With the exact model the
    robot then obeys ``qdd = u_p`` (eq. 7).
    """
    qd = np.asarray(qd, dtype=np.float64)
    return (pin.rnea(model.pin_model, data, np.asarray(q, dtype=np.float64), qd,
                     np.asarray(u_p, dtype=np.float64)) + model.friction.torque(qd))


def inverse_fl(model: RobotModel, data: pin.Data, q, qd, tau) -> np.ndarray:
    """Plant input of a torque: ``u_p = M(q)^-1 (tau - psi(q, qd))`` (inverse of eq. 6).

    Computed with the articulated-body algorithm (forward dynamics of ``tau`` minus
    friction), which equals the linear solve with :func:`mass_matrix`.
    """
    qd = np.asarray(qd, dtype=np.float64)
    return pin.aba(model.pin_model, data, np.asarray(q, dtype=np.float64), qd,
                   np.asarray(tau, dtype=np.float64) - model.friction.torque(qd))


def forward_dynamics(model: RobotModel, data: pin.Data, q, qd, tau) -> np.ndarray:
    """Joint accelerations of eq. (5) under ``tau`` (same as :func:`inverse_fl`)."""
    return inverse_fl(model, data, q, qd, tau)


def logged_to_torque(model: RobotModel, logged) -> np.ndarray:
    """Joint torque [N m] of logged torque values: ``torque_scale * logged``."""
    return model.torque_scale * np.asarray(logged, dtype=np.float64)


def min_mass_eigenvalue(model: RobotModel, data: pin.Data, qs) -> float:
    """Smallest eigenvalue of M(q) over configurations ``qs`` (shape (N, n))."""
    return float(min(np.linalg.eigvalsh(mass_matrix(model, data, q))[0]
                     for q in np.atleast_2d(qs)))


# --------------------------------------------------------------------------- model error

@dataclass(frozen=True)
class ModelError:
    """How a "true" robot differs from a model (for simulation studies).

    Applied by :func:`perturb`. Scalars apply to every link/joint, arrays per link/joint.

    Parameters
    ----------
    mass_scale : float or array_like (n,)
        Factor on each link mass; the first moment scales with it (COM kept).
    inertia_scale : float or array_like (n,)
        Factor on each link's rotational inertia about its COM.
    com_shift : float or array_like (n, 3)
        COM displacement [m] in the link frame (scalar: along every axis).
    armature_scale, viscous_scale, coulomb_scale : float or array_like (n,)
        Factors on the joint terms.
    offset : float or array_like (n,)
        Added constant torque [N m].
    relative_std : float
        Extra random relative perturbation (Gaussian, clipped to +-3 sigma) of every
        mass, inertia, armature and friction value, drawn with ``seed``.
    seed : int
        Seed of the random perturbation.
    payload_mass : float
        Point mass [kg] added to the last link at ``payload_com`` (link frame).
    payload_com : tuple of 3 floats
    """

    mass_scale: object = 1.0
    inertia_scale: object = 1.0
    com_shift: object = 0.0
    armature_scale: object = 1.0
    viscous_scale: object = 1.0
    coulomb_scale: object = 1.0
    offset: object = 0.0
    relative_std: float = 0.0
    seed: int = 0
    payload_mass: float = 0.0
    payload_com: tuple = (0.0, 0.0, 0.05)

    @classmethod
    def typical(cls, seed: int = 0) -> "ModelError":
        """A realistic mismatch: +10 % masses and inertias, 1 cm COM shift, friction
        +30 % Coulomb / -20 % viscous, armature +15 %, plus 5 % random spread."""
        return cls(mass_scale=1.10, inertia_scale=1.10, com_shift=0.01, armature_scale=1.15,
                   viscous_scale=0.8, coulomb_scale=1.3, relative_std=0.05, seed=seed)


def perturb(model: RobotModel, error: ModelError | None) -> RobotModel:
    """A new :class:`RobotModel`: ``model`` changed as ``error`` describes."""
    if error is None:
        return model
    n = model.nv
    rng = np.random.default_rng(error.seed)

    def rnd(shape):
        if error.relative_std <= 0:
            return np.ones(shape)
        return 1.0 + np.clip(rng.standard_normal(shape), -3, 3) * error.relative_std

    ms = np.broadcast_to(np.asarray(error.mass_scale, float), (n,)) * rnd(n)
    is_ = np.broadcast_to(np.asarray(error.inertia_scale, float), (n,)) * rnd(n)
    cs = np.broadcast_to(np.asarray(error.com_shift, float).reshape(-1, 3)
                         if np.ndim(error.com_shift) else np.full(3, float(error.com_shift)),
                         (n, 3))
    pm = model.pin_model.copy()
    for i in range(n):
        I = pm.inertias[i + 1]
        pm.inertias[i + 1] = pin.Inertia(I.mass * ms[i], I.lever + cs[i], I.inertia * is_[i])
    if error.payload_mass:
        pm.inertias[n] = pm.inertias[n] + pin.Inertia(
            float(error.payload_mass), np.asarray(error.payload_com, float), np.zeros((3, 3)))
    pm.armature[:] = np.asarray(pm.armature) * error.armature_scale * rnd(n)
    fr = model.friction
    fr = Friction(viscous=fr.viscous * error.viscous_scale * rnd(n),
                  coulomb=fr.coulomb * error.coulomb_scale * rnd(n),
                  offset=fr.offset + error.offset, coulomb_velocity=fr.coulomb_velocity)
    return RobotModel(pm, fr, model.torque_scale, source=f"{model.source} perturbed by {error}")


def add_payload(model: RobotModel, mass: float, com=(0.0, 0.0, 0.05)) -> RobotModel:
    """``model`` with a point mass [kg] rigidly attached to the last link at ``com``."""
    return perturb(model, ModelError(payload_mass=float(mass), payload_com=tuple(com)))


# --------------------------------------------------------------------------- identification

def parameter_names(model: RobotModel) -> list:
    """Names of the extended standard parameters (see :func:`parameter_vector`)."""
    names = [f"{j}.{p}" for j in model.joint_names for p in LINK_PARAM_NAMES]
    names += [f"{j}.{p}" for p in JOINT_PARAM_NAMES for j in model.joint_names]
    return names


def parameter_vector(model: RobotModel) -> np.ndarray:
    """Extended standard parameters theta (length 14 n).

    ``[pi_1, ..., pi_n, armature, viscous, coulomb, offset]`` with ``pi_i`` the 10 dynamic
    parameters of link i in Pinocchio's order (inertia about the joint frame origin).
    """
    pm = model.pin_model
    pis = [pm.inertias[i].toDynamicParameters() for i in range(1, model.nv + 1)]
    fr = model.friction
    return np.concatenate(pis + [np.asarray(pm.armature), fr.viscous, fr.coulomb, fr.offset])


def with_parameters(model: RobotModel, theta, torque_scale=None, source=None) -> RobotModel:
    """A new :class:`RobotModel` with extended standard parameters ``theta``.

    Link parameters need not be physically consistent (Pinocchio accepts any inertia);
    check :func:`min_mass_eigenvalue` on the configurations of interest.
    """
    n = model.nv
    theta = np.asarray(theta, dtype=np.float64)
    if theta.size != 14 * n:
        raise ReachsetError(f"expected {14 * n} parameters, got {theta.size}")
    pm = model.pin_model.copy()
    for i in range(n):
        pm.inertias[i + 1] = pin.Inertia.FromDynamicParameters(theta[10 * i:10 * i + 10].copy())
    j = theta[10 * n:]
    pm.armature[:] = j[:n]
    fr = Friction(j[n:2 * n], j[2 * n:3 * n], j[3 * n:4 * n], model.friction.coulomb_velocity)
    return RobotModel(pm, fr, model.torque_scale if torque_scale is None else torque_scale,
                      source=model.source if source is None else source)


def regressor(model: RobotModel, data: pin.Data, q, qd, qdd) -> np.ndarray:
    """Extended joint-torque regressor Y with ``tau = Y(q, qd, qdd) theta`` (n x 14 n).

    Columns: ``pin.computeJointTorqueRegressor`` (rigid bodies, 10 per link), then per
    joint ``qdd_j`` (armature), ``qd_j`` (viscous), ``tanh(qd_j / v_c)`` (Coulomb), ``1``
    (offset), each only in row j.
    """
    q, qd, qdd = (np.asarray(x, dtype=np.float64) for x in (q, qd, qdd))
    n = model.nv
    Y = np.zeros((n, 14 * n))
    Y[:, :10 * n] = pin.computeJointTorqueRegressor(model.pin_model, data, q, qd, qdd)
    d = np.arange(n)
    Y[d, 10 * n + d] = qdd
    Y[d, 11 * n + d] = qd
    Y[d, 12 * n + d] = np.tanh(qd / model.friction.coulomb_velocity)
    Y[d, 13 * n + d] = 1.0
    return Y


def regressor_batch(model: RobotModel, data: pin.Data, Q, QD, QDD) -> np.ndarray:
    """:func:`regressor` for N samples (arrays (N, n)); returns (N, n, 14 n)."""
    Q, QD, QDD = (np.atleast_2d(np.asarray(x, dtype=np.float64)) for x in (Q, QD, QDD))
    return np.stack([regressor(model, data, Q[k], QD[k], QDD[k]) for k in range(len(Q))])


def random_states(model: RobotModel, n_samples: int, rng, qd_max=2.0, qdd_max=10.0):
    """Random (q, qd, qdd) samples, q uniform within the model's position limits."""
    lo = np.maximum(model.lower, -np.pi)
    hi = np.minimum(model.upper, np.pi)
    Q = rng.uniform(lo, hi, (n_samples, model.nv))
    QD = rng.uniform(-qd_max, qd_max, (n_samples, model.nv))
    QDD = rng.uniform(-qdd_max, qdd_max, (n_samples, model.nv))
    return Q, QD, QDD


@dataclass(frozen=True)
class BaseParameters:
    """Base (identifiable) parameters ``beta = K theta`` of the extended regressor.

    ``Y theta = Y[:, independent] beta`` for every motion. Found by QR with column pivoting
    of the regressor stacked over random samples; ``beta_k = theta_{independent[k]} +
    sum_l K_d[k, l] theta_{dependent[l]}``.

    Attributes
    ----------
    independent : np.ndarray of int
        Columns of the extended regressor kept (the base regressor).
    dependent : np.ndarray of int
        Columns that are zero or linear combinations of the independent ones.
    K : np.ndarray, shape (r, 14 n)
        Projection from standard to base parameters.
    names : tuple of str
        Name of each base parameter (the standard parameter it is built on).
    """

    independent: np.ndarray
    dependent: np.ndarray
    K: np.ndarray
    names: tuple

    @property
    def rank(self) -> int:
        return len(self.independent)

    @classmethod
    def from_model(cls, model: RobotModel, n_samples: int = 300, seed: int = 0,
                   tol: float = 1e-9) -> "BaseParameters":
        """Compute the base parameters of ``model``'s kinematics (inertias irrelevant)."""
        import scipy.linalg
        data = create_data(model)
        rng = np.random.default_rng(seed)
        Y = regressor_batch(model, data, *random_states(model, n_samples, rng))
        Y = Y.reshape(-1, Y.shape[-1])
        _, R, P = scipy.linalg.qr(Y, mode="economic", pivoting=True)
        diag = np.abs(np.diag(R))
        r = int(np.sum(diag > tol * diag[0]))
        ind, dep = P[:r], P[r:]
        Kd = scipy.linalg.solve_triangular(R[:r, :r], R[:r, r:])
        Kd[np.abs(Kd) < 1e-10] = 0.0
        order = np.argsort(ind)
        ind, Kd = ind[order], Kd[order]
        K = np.zeros((r, Y.shape[1]))
        K[np.arange(r), ind] = 1.0
        K[:, dep] = Kd
        names = parameter_names(model)
        for a in (ind, dep, K):
            a.setflags(write=False)
        return cls(ind, dep, K, tuple(names[i] for i in ind))

    def base(self, theta) -> np.ndarray:
        """Base parameters of standard parameters ``theta``."""
        return self.K @ np.asarray(theta, dtype=np.float64)

    def standard(self, beta, theta_prior) -> np.ndarray:
        """Standard parameters with base parameters ``beta``, closest to ``theta_prior``.

        Minimum-norm correction ``theta = prior + K^+ (beta - K prior)`` in parameter units
        scaled by ``max(|prior|, 1e-3)`` so that small and large parameters move alike.
        """
        prior = np.asarray(theta_prior, dtype=np.float64)
        w = np.maximum(np.abs(prior), 1e-3)
        Kw = self.K * w
        corr = np.linalg.lstsq(Kw, np.asarray(beta) - self.K @ prior, rcond=None)[0]
        return prior + w * corr


@dataclass(frozen=True)
class TorqueGram:
    """Sufficient statistics of a torque data set for least squares, per joint.

    For the extended regressor ``Y`` (:func:`regressor`) and logged torques ``u`` over N
    samples: ``G[j] = sum_k Y_k[j]^T Y_k[j]``, ``c[j] = sum_k Y_k[j]^T u_k[j]``,
    ``uu[j] = sum_k u_k[j]^2``. Any residual ``Y theta / s - u`` has the squared norm
    ``theta^T G theta / s^2 - 2 c^T theta / s + uu`` per joint, so data sets of any length
    reduce to a few kilobytes and add up (``+``).
    """

    G: np.ndarray
    c: np.ndarray
    uu: np.ndarray
    N: int

    def __add__(self, other):
        return TorqueGram(self.G + other.G, self.c + other.c, self.uu + other.uu,
                          self.N + other.N)

    def sse(self, theta, s):
        """Sum of squared residuals per joint (logged units) of parameters and scales."""
        theta = np.asarray(theta, dtype=np.float64)
        g = 1.0 / np.asarray(s, dtype=np.float64)
        quad = np.einsum("p,npq,q->n", theta, self.G, theta)
        return np.maximum(g ** 2 * quad - 2 * g * (self.c @ theta) + self.uu, 0.0)

    def rms(self, theta, s):
        """RMS residual per joint (logged units)."""
        return np.sqrt(self.sse(theta, s) / max(self.N, 1))


def torque_gram(model: RobotModel, data: pin.Data, Q, QD, QDD, logged,
                chunk: int = 4000) -> TorqueGram:
    """:class:`TorqueGram` of samples ``(Q, QD, QDD)`` (N, n) with logged torques (N, n)."""
    Q, QD, QDD, U = (np.atleast_2d(np.asarray(x, dtype=np.float64)) for x in (Q, QD, QDD, logged))
    if not (QD.shape == QDD.shape == U.shape == Q.shape):
        raise ReachsetError("Q, QD, QDD and logged torques must have equal shapes")
    n, p = model.nv, 14 * model.nv
    G, c, uu = np.zeros((n, p, p)), np.zeros((n, p)), np.zeros(n)
    for a in range(0, len(Q), chunk):
        sl = slice(a, a + chunk)
        Y = regressor_batch(model, data, Q[sl], QD[sl], QDD[sl])
        G += np.einsum("knp,knq->npq", Y, Y)
        c += np.einsum("knp,kn->np", Y, U[sl])
        uu += np.sum(U[sl] ** 2, axis=0)
    return TorqueGram(G, c, uu, len(Q))


@dataclass(frozen=True)
class Identification:
    """Result of :func:`identify`.

    Attributes
    ----------
    model : RobotModel
        The identified model (torque scale included).
    theta : np.ndarray
        Extended standard parameters (:func:`parameter_vector` of ``model``).
    beta : np.ndarray
        Base parameters ``base.K @ theta``.
    base : BaseParameters
    torque_scale : np.ndarray
        N m per logged unit.
    rms : np.ndarray
        RMS residual per joint on the fitting data, in logged torque units.
    samples : int
    method : str
        ``"placeholder"``, ``"ls"`` or ``"lmi"``.
    settings : dict
        Weights and solver information.
    """

    model: RobotModel
    theta: np.ndarray
    beta: np.ndarray
    base: BaseParameters
    torque_scale: np.ndarray
    rms: np.ndarray
    samples: int
    method: str
    settings: dict = field(default_factory=dict)


def _friction_cols(n, terms):
    """Columns of the extended parameters of the friction ``terms`` (all joints)."""
    off = {"viscous": 11, "coulomb": 12, "offset": 13}
    return {t: np.arange(off[t] * n, off[t] * n + n) for t in terms}


def _stage1(model, gram, theta0, fit_scale, terms):
    """Placeholder stage: rigid + armature (and friction terms not in ``terms``) fixed at
    ``theta0``; per joint least squares in ``(1/s, friction/s)``."""
    n = model.nv
    fc = _friction_cols(n, terms)
    free = np.concatenate([fc[t] for t in terms]) if terms else np.zeros(0, int)
    tf = theta0.copy()
    tf[free] = 0.0
    theta = theta0.copy()
    s = np.ones(n)
    k = len(terms)
    for j in range(n):
        cols = [fc[t][j] for t in terms]
        # columns [Y theta_fixed, F_free]; their Gram matrix and right-hand side.
        T = np.zeros((14 * n, 1 + k))
        T[:, 0] = tf
        T[cols, np.arange(1, 1 + k)] = 1.0
        H = T.T @ gram.G[j] @ T
        g = T.T @ gram.c[j]
        if fit_scale:
            x = np.linalg.lstsq(H, g, rcond=None)[0]
            if not x[0] >= 1e-6:                   # no positive scale: friction only
                x[0] = 1e-6
                x[1:] = np.linalg.lstsq(H[1:, 1:], g[1:] - H[1:, 0] * x[0], rcond=None)[0]
            s[j] = 1.0 / x[0]
            theta[cols] = x[1:] * s[j]
        else:
            x = np.linalg.lstsq(H[1:, 1:], g[1:] - H[1:, 0], rcond=None)[0]
            theta[cols] = x
    return theta, s


def _lmi_step(model, H, g, theta_ref, D2, prior_weight, min_armature, cache,
              fixed=(), nonneg=()):
    """min theta^T H theta - 2 g^T theta + w ||D (theta - theta_ref)||^2 subject to
    physical consistency (pseudo-inertia of every link PSD) and armature >= min_armature;
    columns ``fixed`` stay at ``theta_ref``, columns ``nonneg`` are >= 0. ``cache`` keeps the
    compiled cvxpy problem."""
    import cvxpy as cp
    n = model.nv
    p = 14 * n
    if "prob" not in cache:
        th = cp.Variable(p)
        R = cp.Parameter((p, p))
        gp = cp.Parameter(p)
        cons = []
        for i in range(n):
            m, hx, hy, hz, ixx, ixy, iyy, ixz, iyz, izz = (th[10 * i + k] for k in range(10))
            J = cp.Variable((4, 4), PSD=True)
            tr = (ixx + iyy + izz) / 2
            cons += [J[0, 0] == tr - ixx, J[1, 1] == tr - iyy, J[2, 2] == tr - izz,
                     J[0, 1] == -ixy, J[0, 2] == -ixz, J[1, 2] == -iyz,
                     J[0, 3] == hx, J[1, 3] == hy, J[2, 3] == hz, J[3, 3] == m]
        cons += [th[10 * n:11 * n] >= min_armature]
        if len(fixed):
            cons += [th[np.asarray(fixed)] == theta_ref[np.asarray(fixed)]]
        if len(nonneg):
            cons += [th[np.asarray(nonneg)] >= 0]
        prob = cp.Problem(cp.Minimize(cp.sum_squares(R @ th) - 2 * gp @ th), cons)
        cache.update(prob=prob, th=th, R=R, g=gp)
    Ht = H + prior_weight * np.diag(D2)
    rhs = g + prior_weight * D2 * theta_ref
    L = np.linalg.cholesky(Ht + 1e-12 * np.trace(Ht) / p * np.eye(p))
    cache["R"].value = L.T
    cache["g"].value = rhs
    try:
        with warnings.catch_warnings():       # "inaccurate" is judged by the status below
            warnings.simplefilter("ignore", UserWarning)
            cache["prob"].solve(solver="CLARABEL", tol_gap_abs=1e-10, tol_gap_rel=1e-10,
                                tol_feas=1e-10, max_iter=500)
    except Exception:  # noqa: BLE001  (solver failure: retry with SCS)
        cache["prob"].solve(solver="SCS", eps=1e-9, max_iters=200000)
    if cache["th"].value is None or cache["prob"].status not in ("optimal", "optimal_inaccurate"):
        raise ReachsetError(f"identification: the physically consistent fit failed "
                            f"({cache['prob'].status})")
    return np.array(cache["th"].value)


def identify(model: RobotModel, gram: TorqueGram, *, method: str = "lmi",
             fit_scale: bool = True, prior_weight: float = 1e-3, scale_weight: float = 1.0,
             min_armature: float = 1e-3, friction_terms=("viscous", "coulomb", "offset"),
             nonnegative_friction: bool = False, base=None, max_iter: int = 200,
             tol: float = 1e-10) -> Identification:
    """Least-squares identification from a :class:`TorqueGram` of logged torques.

    The torque of joint j is ``s_j * logged_j = Y(q, qd, qdd)_j theta`` (eq. 5 written
    with the regressor of :func:`regressor`) with an unknown torque scale ``s_j`` [N m per
    logged unit]. Residuals are measured in logged units (where the noise is),
    ``r_j = Y_j theta / s_j - logged_j``, rows of joint j weighted by the inverse residual
    RMS of the placeholder stage. The data fix ``theta`` and ``s`` only up to a common factor
    (to which ``u_p = M^-1 (tau - psi)`` is invariant) and barely see some directions
    (joint 6 hardly moves in the LWA-4P data), so two priors close the problem: a
    scale-free ridge ``prior_weight * ||D (theta - theta_0)||^2`` towards ``model``
    (``D`` the regressor's column norms) and ``scale_weight * N * ||log s - log s_0||^2``
    towards the placeholder stage's scales ``s_0``. Absolute N m values are therefore only
    as right as the prior's overall size.

    Methods
    -------
    ``"placeholder"``
        Rigid-body and armature parameters of ``model`` kept; per joint, linear least
        squares in ``(1/s_j, friction_j/s_j)`` (viscous, Coulomb, offset). The baseline.
    ``"ls"``
        Base parameters (:class:`BaseParameters`) by ridge least squares, scales by
        variable projection (L-BFGS over ``log s``, ``beta`` eliminated in closed form).
        Fast, but nothing keeps M(q) positive definite (on the LWA-4P data it is not).
    ``"lmi"`` (default)
        Physically consistent: every link's pseudo-inertia ``[[tr(I)/2 - I, h], [h^T, m]]``
        PSD (Wensing, Kim, Slotine 2017) and armature >= ``min_armature``, so
        ``M(q) >= min_armature * I`` everywhere. Friction is left free: a logged motor
        command need not show a textbook friction curve. For fixed scales the problem is
        convex (cvxpy, Clarabel); the scales are optimised over this profile by L-BFGS-B
        with the exact gradient (envelope theorem), ``max_iter`` iterations, ``tol``. Convex (cvxpy, Clarabel) for fixed
        scales; alternated with the closed-form per-joint scale update until the cost
        changes by less than ``tol`` (relative).

    Parameters
    ----------
    model : RobotModel
        Prior / placeholder model (kinematics, prior parameters, Coulomb smoothing).
    gram : TorqueGram
        Data (:func:`torque_gram`).
    fit_scale : bool
        False: the logged torques are N m (``s = 1`` fixed).
    prior_weight, scale_weight : float
        Prior weights (see above).
    min_armature : float
        Lower bound on the armature [kg m^2] (``"lmi"``).
    friction_terms : tuple of str
        Friction terms fitted (subset of viscous, coulomb, offset); the others keep
        ``model``'s values (``"placeholder"`` and ``"lmi"`` only).
    nonnegative_friction : bool
        Constrain viscous and Coulomb coefficients to be >= 0 (``"lmi"``).
    base : BaseParameters, optional
        Precomputed base parameters of ``model``.

    Returns
    -------
    Identification
    """
    import scipy.optimize
    if method not in ("placeholder", "ls", "lmi"):
        raise ReachsetError(f"unknown identification method {method!r}")
    n = model.nv
    N = gram.N
    if N < 20 * n:
        raise ReachsetError(f"identify: {N} samples are too few")
    base = base or BaseParameters.from_model(model)
    theta0 = parameter_vector(model)
    terms = tuple(friction_terms)
    if set(terms) - {"viscous", "coulomb", "offset"}:
        raise ReachsetError(f"unknown friction terms {terms}")
    if method == "ls" and len(terms) != 3:
        raise ReachsetError("method 'ls' fits all friction terms")
    theta, s = _stage1(model, gram, theta0, fit_scale, terms)
    rms1 = gram.rms(theta, s)
    settings = {"prior_weight": prior_weight, "scale_weight": scale_weight,
                "friction_terms": list(terms), "nonnegative_friction": nonnegative_friction,
                "placeholder_rms": rms1.tolist(), "placeholder_scale": s.tolist()}
    if method != "placeholder":
        w2 = 1.0 / np.maximum(rms1, 1e-9 * rms1.max()) ** 2
        Gw, cw = gram.G * w2[:, None, None], gram.c * w2[:, None]
        uuw = gram.uu * w2
        ok = s < 1e5
        rho0 = np.log(s)
        rho0[~ok] = np.median(rho0[ok]) if ok.any() else 0.0

        def data_cost(th, rho):
            gi = np.exp(-rho)
            return float(np.sum(gi ** 2 * np.einsum("p,npq,q->n", th, Gw, th)
                                - 2 * gi * (cw @ th) + uuw))

        def scale_prior(rho):
            return scale_weight * N * float(np.sum((rho - rho0) ** 2))

        if method == "ls":
            ind = base.independent
            Gb, cb = Gw[:, ind][:, :, ind], cw[:, ind]
            beta0 = base.base(theta0)
            D2 = np.einsum("npp,n->p", Gb, np.exp(-2 * rho0))
            D2 = np.maximum(D2, 1e-9 * D2.max())

            def solve(rho):
                gi = np.exp(-rho)
                H = np.einsum("n,npq->pq", gi ** 2, Gb) + prior_weight * np.diag(D2)
                return np.linalg.solve(H, np.einsum("n,np->p", gi, cb)
                                       + prior_weight * D2 * beta0)

            def cost(rho):
                b = solve(rho)
                gi = np.exp(-rho)
                dc = np.sum(gi ** 2 * np.einsum("p,npq,q->n", b, Gb, b) - 2 * gi * (cb @ b) + uuw)
                return dc + prior_weight * np.sum(D2 * (b - beta0) ** 2) + scale_prior(rho)

            rho = rho0
            if fit_scale:
                sol = scipy.optimize.minimize(cost, rho0, method="L-BFGS-B",
                                              bounds=[(r - 5.0, r + 5.0) for r in rho0])
                rho = sol.x
                settings.update(iterations=int(sol.nit))
            theta = base.standard(solve(rho), theta0)
            s = np.exp(rho)
        else:
            D2 = np.einsum("npp,n->p", Gw, np.exp(-2 * rho0))
            D2 = np.maximum(D2, 1e-6 * D2.max())
            cache = {}
            last = {}
            fc = _friction_cols(n, ("viscous", "coulomb", "offset"))
            fixed = np.concatenate([fc[t] for t in fc if t not in terms] + [np.zeros(0, int)])
            nonneg = (np.concatenate([fc["viscous"], fc["coulomb"]]) if nonnegative_friction
                      else np.zeros(0, int))

            def profile(rho):
                """Cost with theta optimal for these scales, and its exact gradient
                (envelope theorem: the constraints do not depend on the scales)."""
                gi = np.exp(-rho)
                H = np.einsum("n,npq->pq", gi ** 2, Gw)
                g = np.einsum("n,np->p", gi, cw)
                th = _lmi_step(model, H, g, theta0, D2, prior_weight, min_armature, cache,
                               fixed, nonneg)
                last["theta"] = th
                a = np.einsum("p,npq,q->n", th, Gw, th)
                b = cw @ th
                total = (data_cost(th, rho) + scale_prior(rho)
                         + prior_weight * float(np.sum(D2 * (th - theta0) ** 2)))
                grad = (-2 * gi ** 2 * a + 2 * gi * b + 2 * scale_weight * N * (rho - rho0))
                return total / N, grad / N      # per sample: O(1) numbers for L-BFGS

            rho = rho0.copy()
            if fit_scale:
                sol = scipy.optimize.minimize(profile, rho0, jac=True, method="L-BFGS-B",
                                              bounds=[(r - 5.0, r + 5.0) for r in rho0],
                                              options={"maxiter": max_iter, "ftol": tol,
                                                       "gtol": 1e-9})
                rho = sol.x
                settings.update(iterations=int(sol.nit), evaluations=int(sol.nfev),
                                converged=bool(sol.success), message=str(sol.message))
            profile(rho)
            theta = last["theta"]
            settings.update(min_armature=min_armature)
            s = np.exp(rho)
    ident = with_parameters(model, theta, torque_scale=s, source=f"identified ({method})")
    return Identification(ident, theta, base.base(theta), base, s, gram.rms(theta, s), N,
                          method, settings)


def predict_logged(model: RobotModel, data: pin.Data, Q, QD, QDD) -> np.ndarray:
    """Logged torque predicted by ``model``: ``(M qdd + psi) / torque_scale`` (N, n)."""
    Q, QD, QDD = (np.atleast_2d(np.asarray(x, dtype=np.float64)) for x in (Q, QD, QDD))
    return np.stack([feedback_linearization(model, data, Q[k], QD[k], QDD[k])
                     for k in range(len(Q))]) / model.torque_scale
