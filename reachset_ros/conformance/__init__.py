"""Reachset conformance: test cases, deviations y_a, Theorem 1, identification, checking, monitoring.

Paper Sec. II-B (Defs. 2-4) and III-B. For sequential test cases (Def. 3) starting at
every valid tick m of a recording, the deviation y_a^(m)[k] of the measurement from the
nominal prediction (eq. 12; x_*^(m)[0] from an :class:`Estimator`, see :mod:`.kernels`)
must lie in R_a[k] = (+)_{i<k} C A^i W (+) V (eq. 13). Theorem 1 writes this as
``max_m N_k y_a^(m)[k] <= D_k xi`` with xi = [c_W, c_V, alpha_W, alpha_V], linear in xi,
where the normals N_k come from the H-representation of R_a[k] built from the *unscaled*
generators (they do not depend on alpha > 0).

Submodules
----------
kernels
    The deterministic element-wise kernels (:func:`matvec`, :func:`predict_output`,
    :func:`advance`), the test cases (:func:`test_case_starts`) and the batch
    :func:`sweep` over them; the one loader of the compiled kernels (``_tick.c``: the
    sweep block and the monitor tick, bitwise equal to their numpy code paths).
estimators
    Initial states x0(m) of the test cases (:class:`Estimator`).
theorem1
    Theorem 1 (:class:`Theorem1`), the reduction of all test cases to its left-hand sides
    (:func:`deviation_extremes`) and the batch check of Def. 4 (:func:`check`).
identify
    Identification of W and V under Theorem 1 (:func:`identify_sets`, LP;
    :func:`identify_quadratic`, QP), :func:`make_sound`, Remark 3 (:func:`stable_horizon`).
corollary1
    The conservative state-based identification of Corollary 1 (:func:`identify_corollary1`).
validation
    Held-out validation, inflation calibration, fault injection (beyond the paper).
calibration
    Inflation by K-fold cross-validation inside the identification data (``identify --calibrate K``).
coverage
    The motion the identification data contain (velocity, acceleration, position range), reduced to
    extremes that merge exactly: how much of the reference class ``identify`` saw (row G20).
model
    The conformance model file (plant, estimator, horizon, per-joint sets, inflation).
monitor
    The online monitor: Theorem 1 checked tick by tick (:class:`Monitor`,
    :class:`JointMonitor`), with the same arithmetic as :func:`sweep`, so
    ``reachset replay`` and the monitor node give exactly ``reachset check``'s verdicts.
watches
    The monitor's events (:class:`TickEvent`, :class:`FaultEvent`) and the fault watches of
    its input (:class:`CoverageWatch`, :class:`StuckSensorWatch`).
monitor_core
    The monitor node without ROS (:class:`MonitorCore`): pairing of ``/joint_states`` and
    ``/plant_input`` by stamp and joint name, fault detection, the monitor.

All arithmetic on the nominal trajectories uses the element-wise :func:`matvec`, so the
batch sweep and the online monitor, which advances one tick at a time, produce bitwise
identical deviations and hence identical verdicts.

May import: :mod:`reachset_ros._lazy` (the package's lazy attributes), :mod:`reachset_ros.sets`, :mod:`reachset_ros.systems`,
:mod:`reachset_ros.errors`, :mod:`reachset_ros.guarantees`, :mod:`reachset_ros.defaults` (registers the estimators'
defaults) and :mod:`reachset_ros.atomic`; not synthesis, bags, robot, sim or
nodes. Code inside reachset_ros imports from the submodules; ``from reachset_ros import conformance as cf; cf.sweep(...)`` is for users,
tests and tools.
"""
from .._lazy import attach

# each public name is imported from its submodule on first use (reachset_ros._lazy, issue 38.1)
__getattr__, __dir__, _EXPORTED = attach(__name__, {
    ".corollary1": [
        "StateDeviations", "corollary1_constraints", "identify_corollary1", "state_deviations",
    ],
    ".estimators": [
        "ESTIMATORS", "Estimator",
    ],
    ".identify": [
        "IdentifiedSets", "frobenius_weights", "identification_constraints", "identify_quadratic",
        "identify_sets", "make_sound", "set_norm_cost", "stable_horizon", "z_bounds", "z_to_xi",
    ],
    ".kernels": [
        "advance", "as_2d", "matvec", "matvec_into", "matvec_plan", "minimum_horizon", "predict_output",
        "require_horizon", "require_minimum_horizon", "require_runs", "sweep", "test_case_starts",
    ],
    ".model": [
        "ConformanceModel", "JointSets",
    ],
    ".monitor": [
        "JointMonitor", "Monitor", "MonitorModel", "TickResult",
    ],
    ".monitor_core": [
        "MonitorCore",
    ],
    ".theorem1": [
        "CheckResult", "Deviations", "Theorem1", "check", "check_extremes", "combine", "deviation_extremes",
        "deviation_extremes_many", "initial_error_maps", "output_normals", "xi_of",
    ],
    ".watches": [
        "CoverageWatch", "FaultEvent", "StuckSensorWatch", "TickEvent",
    ],
    ".validation": [
        "CaseCheck", "check_many", "detection_delay", "fault_onset_tick", "inject_acceleration_fault",
        "validation_grid",
    ],
})

__all__ = [
    # kernels
    "matvec", "matvec_into", "matvec_plan", "predict_output", "advance", "as_2d",
    "test_case_starts", "require_horizon", "require_runs", "minimum_horizon", "require_minimum_horizon", "sweep",
    # estimators
    "Estimator", "ESTIMATORS",
    # theorem1
    "output_normals", "initial_error_maps", "Theorem1", "xi_of", "Deviations", "deviation_extremes",
    "deviation_extremes_many", "combine", "CheckResult", "check", "check_extremes",
    # identify
    "IdentifiedSets", "z_to_xi", "z_bounds", "identification_constraints", "set_norm_cost", "make_sound",
    "identify_sets", "stable_horizon", "frobenius_weights", "identify_quadratic",
    # corollary1
    "StateDeviations", "state_deviations", "corollary1_constraints", "identify_corollary1",
    # validation
    "CaseCheck", "check_many", "inject_acceleration_fault", "fault_onset_tick",
    "detection_delay", "validation_grid",
    # model
    "ConformanceModel", "JointSets",
    # monitor
    "MonitorModel", "TickResult", "JointMonitor", "Monitor",
    # watches, monitor_core
    "TickEvent", "FaultEvent", "CoverageWatch", "StuckSensorWatch", "MonitorCore",
]
