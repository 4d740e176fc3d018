"""Plant input of a measured joint effort: ``u_p = M̂(q)⁻¹ (s τ − ψ̂(q, q̇))``, eq. (6) inverted.

Pure core (no ROS). An arm that is driven by another controller (a ros2_control effort
controller, a vendor's torque loop) publishes ``/joint_states`` with position, velocity and
effort, and has a URDF. Its plant input in the sense of the paper (the acceleration the
feedback linearization of eqs. (5)-(7) would have asked for) is recovered from the
measured torque with the nominal model, ``u_p = M̂(q)⁻¹ (τ − ψ̂(q, q̇))``, exactly as
``reachset import-lwa4p`` does for the Schunk LWA-4P recordings: :func:`plant_inputs` is the
one implementation both use, and the monitor node's ``input_source: effort`` calls it too.

Choices (documented in docs/any-arm.md):

* no filter and no lag: the effort of the JointState message stamped t_k is paired with the
  position and velocity of the same message, and the result is the plant input of tick k
  (the convention of the LWA-4P recordings, where the logged torque of row k is the command
  issued at sample k; the plant's one-sample input and output delays of Appendix A are in
  the identified model, not in this map);
* ``τ = torque_scale · effort`` (1 unless an identified parameter document says otherwise:
  the LWA-4P logs torque in drive units);
* a row with a non-finite position, velocity or effort gives a NaN plant input for every
  joint (M̂⁻¹ couples the joints), so those ticks are invalid samples, never silently used.
"""
from __future__ import annotations

import hashlib
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import ReachsetError
from .descriptions import resolve_urdf
from .dynamics import RobotModel, create_data, inverse_fl, load_model

__all__ = ["EffortInput", "plant_inputs", "load_effort_input", "file_digest"]


def file_digest(path) -> str:
    """SHA-256 (hex) of a file's bytes: what the model's ``input_source`` binds a URDF and a
    parameter document by (their contents, not their paths)."""
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def plant_inputs(model: RobotModel, Q, QD, TAU, data=None) -> np.ndarray:
    """Plant inputs of measured efforts, one row per sample (eq. 6 inverted).

    Parameters
    ----------
    model : RobotModel
        The nominal model M̂, ψ̂ (and the torque scale).
    Q, QD : array_like, shape (T, n)
        Measured joint positions [rad] and velocities [rad/s], columns in the model's joint order.
    TAU : array_like, shape (T, n)
        Measured (or commanded) effort, as logged: ``torque_scale * TAU`` is N m.
    data : pin.Data, optional
        Workspace (:func:`~reachset_ros.robot.dynamics.create_data`).

    Returns
    -------
    ndarray, shape (T, n)
        ``u_p[k] = M̂(q_k)⁻¹ (s τ_k − ψ̂(q_k, q̇_k))`` [rad/s²]; NaN rows where an input is
        not finite.
    """
    Q, QD, TAU = (np.atleast_2d(np.asarray(a, dtype=np.float64)) for a in (Q, QD, TAU))
    n = model.nv
    if not (Q.shape == QD.shape == TAU.shape and Q.shape[1] == n):
        raise ReachsetError(f"plant_inputs: q, qd, effort must be (T, {n}); got {Q.shape}, {QD.shape}, {TAU.shape}")
    data = data if data is not None else create_data(model)
    tau = model.torque_scale * TAU
    out = np.full(Q.shape, np.nan)
    ok = np.isfinite(Q).all(axis=1) & np.isfinite(QD).all(axis=1) & np.isfinite(tau).all(axis=1)
    for k in np.flatnonzero(ok):
        out[k] = inverse_fl(model, data, Q[k], QD[k], tau[k])
    return out


@dataclass(frozen=True)
class EffortInput:
    """The plant-input source ``--input effort``: a nominal model and where it came from.

    Attributes
    ----------
    model : RobotModel
        Nominal model (URDF, optionally with identified parameters applied).
    urdf : str
        The URDF path.
    nominal : str or None
        The parameter document applied over the URDF (``--nominal``), if any.
    locked : tuple of str
        URDF joints locked at their neutral configuration (``--lock-joints``).
    """

    model: RobotModel
    urdf: str
    nominal: str | None = None
    locked: tuple = ()

    @property
    def joint_names(self) -> tuple:
        return self.model.joint_names

    def plant_inputs(self, Q, QD, TAU, data=None) -> np.ndarray:
        """:func:`plant_inputs` with this source's model."""
        return plant_inputs(self.model, Q, QD, TAU, data)

    def plant_input(self, q, qd, effort, data=None) -> np.ndarray:
        """One sample of :meth:`plant_inputs` (1-D arrays in the model's joint order): the same
        operations on the same values, so the same bits, without the 2-D detour (the monitor
        node's ``input_source: effort``, once per message; issue 38.4)."""
        model = self.model
        tau = model.torque_scale * effort
        if not (np.isfinite(q).all() and np.isfinite(qd).all() and np.isfinite(tau).all()):
            return np.full(model.nv, np.nan)
        return inverse_fl(model, data if data is not None else create_data(model), q, qd, tau)

    def binding(self) -> dict:
        """The model file's ``input_source`` block of this source (issue 34.10): how u_p is
        computed, as values a reader compares: ``{"kind": "effort", "urdf_sha256",
        "params_sha256" (None without ``--nominal``), "locked_joints", "joints",
        "torque_scale"}`` (the torque scale per joint, ``tau = torque_scale * effort``).
        :func:`reachset_ros.conformance.model.require_input_source` refuses a model identified
        with another binding."""
        return {"kind": "effort", "urdf_sha256": file_digest(self.urdf),
                "params_sha256": None if self.nominal is None else file_digest(self.nominal),
                "locked_joints": sorted(self.locked), "joints": list(self.joint_names),
                "torque_scale": [float(x) for x in self.model.torque_scale]}

    def describe(self) -> dict:
        """Provenance: ``{"source": "effort", "robot": urdf, "nominal": params or None, "joints": [...]}``."""
        return {"source": "effort", "robot": self.urdf, "nominal": self.nominal,
                "joints": list(self.joint_names), "locked_joints": list(self.locked)}


def load_effort_input(urdf, nominal=None, joints=None, lock=None) -> EffortInput:
    """An :class:`EffortInput` from a URDF (a path or ``example-robot-data:<path>``,
    :func:`~reachset_ros.robot.descriptions.resolve_urdf`) and an optional parameter document.

    ``joints``: keep only these joints of the URDF; ``lock``: lock these (e.g. a gripper's
    fingers that the bag does not carry) at their neutral configuration
    (:func:`~reachset_ros.robot.dynamics.load_model`); at most one of the two.
    """
    if urdf is None:
        raise ReachsetError("--input effort needs --robot URDF")
    urdf = resolve_urdf(urdf)
    if lock and joints is not None:
        raise ReachsetError("give the joints to keep or those to lock, not both")
    every = load_model(urdf).joint_names if (lock or joints is not None) else None
    if lock:
        unknown = [j for j in lock if j not in every]
        if unknown:
            raise ReachsetError(f"{urdf}: no joint {unknown[0]} to lock (its joints: {', '.join(every)})")
        joints = [j for j in every if j not in lock]
    model = load_model(urdf, nominal, joints)
    locked = () if every is None else tuple(j for j in every if j not in model.joint_names)
    return EffortInput(model, str(urdf), None if nominal is None else str(Path(nominal).resolve()), locked)
