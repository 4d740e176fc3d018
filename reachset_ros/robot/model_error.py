"""How a "true" robot differs from a model: :class:`ModelError`, :func:`perturb`, :func:`add_payload`.

For simulation studies (:mod:`reachset_ros.sim.simulator`): the simulated arm runs on a
perturbed copy of the controller's nominal :class:`~reachset_ros.robot.dynamics.RobotModel`,
so that the feedback linearization (paper eq. 6) is inexact as on a real robot and the
reachset-conformant disturbance sets have something to absorb (paper Sec. II-B: "the
inertial parameters used in the feedback linearization are usually not accurate").
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pinocchio as pin

from .dynamics import Friction, RobotModel

__all__ = ["ModelError", "perturb", "add_payload"]


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
