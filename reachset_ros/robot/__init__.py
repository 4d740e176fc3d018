"""The rigid-body arm behind the feedback-linearised joint plant (Schunk LWA-4P).

The paper's joint plant (Sec. II-B, Appendix A) is the robot after feedback linearization:
the dynamics ``M(q) qdd + psi(q, qd) = tau`` (eq. 5) under ``tau = M(q) u_p + psi(q, qd)``
(eq. 6) become ``qdd = u_p`` (eq. 7) for the exact model. This subpackage holds that
rigid-body model and what is computed from it. Pure cores, no ROS.

Submodules
----------
:mod:`~reachset_ros.robot.dynamics`
    :class:`RobotModel`, :class:`Friction`, the LWA-4P and Table-I constants, loading a
    model (URDF + identified parameters), M(q), psi(q, qd), feedback linearization (eq. 6)
    and its inverse.
:mod:`~reachset_ros.robot.model_error`
    :class:`ModelError`, :func:`perturb`, :func:`add_payload`: the "true" robot of a
    simulation study.
:mod:`~reachset_ros.robot.inertial_id`
    Inertial-parameter identification from joint torques (regressor, base parameters,
    :func:`identify_inertial`), for the nominal model of the feedback linearization.
:mod:`~reachset_ros.robot.interval`
    Interval arithmetic with outward rounding and the interval Newton-Euler algorithm.
:mod:`~reachset_ros.robot.input_limits`
    U_p from torque limits (paper eq. ``deriveInputConstraint``, Table I), sound.
:mod:`~reachset_ros.robot.lwa4p`
    The real LWA-4P recordings: reading, nominal-model fit, import to a bag.
:mod:`~reachset_ros.robot.effort`
    u_p of a measured effort (inverse of eq. 6), for bags with only ``/joint_states``.
:mod:`~reachset_ros.robot.descriptions`
    Where a URDF is: a path, or ``example-robot-data:<path>`` (the Franka Panda, UR arms, ...).
    :func:`load_model` loads any serial arm's URDF; ``joints=`` keeps some joints and locks
    the others (a gripper's fingers) at their neutral configuration.

The names of ``dynamics``, ``model_error`` and ``inertial_id`` are re-exported here
(``from reachset_ros import robot as rb; rb.load_model()``); ``input_limits``, ``interval``
and ``lwa4p`` are used as modules.

May import: :mod:`reachset_ros._lazy` (the package's lazy attributes), :mod:`reachset_ros.errors`, :mod:`reachset_ros.atomic` and :mod:`reachset_ros.bags`
(which ``lwa4p`` writes the imported recordings with); otherwise Pinocchio, numpy, scipy,
PyYAML, and cvxpy (lazily, for the LMI identification only).
"""
from .._lazy import attach

# each public name is imported from its submodule on first use (reachset_ros._lazy, issue 38.1)
__getattr__, __dir__, _EXPORTED = attach(__name__, {
    ".dynamics": [
        "COULOMB_VELOCITY", "DEFAULT_URDF", "JOINT_NAMES", "TABLE1_QD_MAX", "TABLE1_Q_MAX", "TABLE1_TAU_MAX",
        "U_REF", "Friction", "RobotModel", "apply_params", "create_data", "feedback_linearization",
        "forward_dynamics", "friction_torque", "inverse_fl", "load_model", "logged_to_torque", "mass_matrix",
        "min_mass_eigenvalue", "model_params_dict", "psi",
    ],
    ".inertial_id": [
        "JOINT_PARAM_NAMES", "LINK_PARAM_NAMES", "PARAMS_PER_LINK", "BaseParameters", "Identification",
        "TorqueGram", "identify_inertial", "parameter_names", "parameter_vector", "predict_logged",
        "random_states", "regressor", "regressor_batch", "torque_gram", "with_parameters",
    ],
    ".model_error": [
        "ModelError", "add_payload", "perturb",
    ],
})

__all__ = [
    # dynamics
    "JOINT_NAMES", "DEFAULT_URDF", "TABLE1_TAU_MAX", "TABLE1_Q_MAX", "TABLE1_QD_MAX", "U_REF",
    "COULOMB_VELOCITY", "Friction", "RobotModel", "create_data", "load_model", "apply_params",
    "model_params_dict", "mass_matrix", "friction_torque", "psi", "feedback_linearization",
    "inverse_fl", "forward_dynamics", "logged_to_torque", "min_mass_eigenvalue",
    # model_error
    "ModelError", "perturb", "add_payload",
    # inertial_id
    "PARAMS_PER_LINK", "LINK_PARAM_NAMES", "JOINT_PARAM_NAMES", "parameter_names",
    "parameter_vector", "with_parameters", "regressor", "regressor_batch", "random_states",
    "BaseParameters", "TorqueGram", "torque_gram", "Identification", "identify_inertial",
    "predict_logged",
]
