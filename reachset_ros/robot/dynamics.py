"""The rigid-body arm behind the feedback-linearised joint plant: M(q), psi(q, qd), eqs. (5)-(7).

Pure core (no ROS). Pinocchio style: an immutable model value (:class:`RobotModel`) and
plain functions taking ``(model, data, ...)``, where ``data`` is a Pinocchio ``pin.Data``
made by :func:`create_data` and owned by the caller (one per thread / per node).

The dynamics are the paper's eq. (5) (``eq:problem:robotDynamics``),

    M(q) qdd + psi(q, qd) = tau,

with ``psi`` = Coriolis + centripetal + gravity (Pinocchio's non-linear effects) + joint
friction (viscous + smooth Coulomb + constant offset, :class:`Friction`). The reflected rotor
inertia (Pinocchio's ``model.armature``) is part of ``M``. Feedback linearization, eq. (6)
(``eq:problem:feedbackLinearizationTorque``),

    tau = M(q) u_p + psi(q, qd)      gives   qdd = u_p      (eq. 7, ``eq:problem:feedbackLinearization``)

for the exact model (:func:`feedback_linearization`); :func:`inverse_fl` is its inverse
``u_p = M^-1 (tau - psi)``, used to compute the plant input of recorded data.

Also here: the constants of the LWA-4P and of the paper's Table I, and loading a model from
a URDF plus an identified-parameter document (:func:`load_model`, :func:`apply_params`,
:func:`model_params_dict`). Inertial values of the shipped URDF are plausible placeholders,
not identified (see ``data/lwa4p.urdf`` and docs/robot.md).
"""
from __future__ import annotations

import dataclasses
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pinocchio as pin
import yaml

from ..errors import ReachsetError

__all__ = ["JOINT_NAMES", "DEFAULT_URDF", "TABLE1_TAU_MAX", "TABLE1_Q_MAX", "TABLE1_QD_MAX", "U_REF",
           "COULOMB_VELOCITY", "Friction", "RobotModel", "create_data", "load_model", "apply_params",
           "model_params_dict", "mass_matrix", "friction_torque", "psi", "feedback_linearization",
           "inverse_fl", "forward_dynamics", "logged_to_torque", "min_mass_eigenvalue"]

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

def _read_armature(urdf: Path, names, locked=()) -> np.ndarray:
    arm = np.zeros(len(names))
    try:
        root = ET.parse(urdf).getroot()
    except ET.ParseError as e:
        raise ReachsetError(f"{urdf}: malformed URDF ({e})") from e
    for el in root.iter(_ARMATURE_TAG):
        j = el.get("joint")
        if j in locked:
            continue
        if j not in names:
            raise ReachsetError(f"{urdf}: armature for unknown joint {j!r}")
        arm[names.index(j)] = float(el.get("value"))
    return arm


def load_model(urdf=None, params=None, joints=None) -> RobotModel:
    """Load the robot model.

    Parameters
    ----------
    urdf : str or Path, optional
        URDF file; default the shipped LWA-4P (:data:`DEFAULT_URDF`). ``<dynamics damping
        friction>`` become viscous / Coulomb friction, ``<reachset:armature>`` the armature.
    params : str, Path or dict, optional
        Identified parameters (the YAML written by ``reachset fit-lwa4p``, e.g.
        ``config/lwa4p_nominal.yaml``, or its dict) applied over the URDF's values.
    joints : sequence of str, optional
        Keep only these joints (any order; the model keeps the URDF's kinematic order); the
        others (e.g. a gripper's fingers) are locked at their neutral configuration
        (``pin.buildReducedModel``), so M(q), psi(q, qd) are those of the arm with the
        locked joints rigid. Default: every movable joint of the URDF.

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
    locked = ()
    if joints is not None:
        joints = list(joints)
        every = list(pm.names[1:])
        unknown = [j for j in joints if j not in every]
        if unknown:
            raise ReachsetError(f"{urdf}: no joint {unknown[0]} (its joints: {', '.join(every)})")
        if len(set(joints)) != len(joints) or not joints:
            raise ReachsetError(f"{urdf}: joints {joints} must be distinct and not empty")
        locked = tuple(n for n in every if n not in joints)
        if locked:
            pm = pin.buildReducedModel(pm, [pm.getJointId(n) for n in locked], pin.neutral(pm))
    names = list(pm.names[1:])
    pm.armature[:] = _read_armature(urdf, names, locked)
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
