"""Systems: the linear closed loop of one joint - plant, observer, controller - and its analysis.

The paper's per-joint models and feedback laws (Sec. II-C, III-A, IV; Appendix A), pure
numpy/scipy:

* :mod:`~reachset_ros.systems.plant` - :class:`LinearPlant` (paper eq. ``discreteSystem``)
  and the LWA-4P's per-joint plant (Appendix A) and 4-state robot model;
* :mod:`~reachset_ros.systems.observers` - high-gain, extended-state and Kalman observers
  as discrete linear systems (:class:`LinearObserver`, :class:`ObserverState`);
* :mod:`~reachset_ros.systems.controllers` - static and disturbance-compensated feedback
  (paper eqs. ``staticfeedback``, ``feedbackLaw``), LQR and the LQG baseline;
* :mod:`~reachset_ros.systems.closedloop` - the composed error system
  (:func:`close_loop`), its stability, and the reachable tracking error ``R_e`` and input
  ``R_u`` (:func:`analyze`, paper Sec. III-A); the control law as deployed
  (:class:`FeedbackLaw`), tick-by-tick simulation, the settling time of a transient;
* :mod:`~reachset_ros.systems.gains` - :class:`Gains`, the one type for a joint's observer
  and controller parameters (synthesis, model file, ROS parameters), and :func:`check_gains`;
* :mod:`~reachset_ros.systems.late_reference` - the reference of a tick whose own has not
  come: the newest earlier one carried forward at constant acceleration, its age bounded;
* :mod:`~reachset_ros.systems.stopping` - the safe stop's law (categories 1 and 2);
* :mod:`~reachset_ros.systems.reference_loop` - the closed loop driven by references
  (:class:`LoopIO`, its exact simulation :class:`LTIPlan`, :func:`simulate_closed_loop`,
  :func:`steady_state`): what the reference error of Appendix B and the simulated recordings
  run.

May import: :mod:`reachset_ros._lazy` (the package's lazy attributes), :mod:`reachset_ros.sets`, :mod:`reachset_ros.defaults` (registers the gains' defaults),
:mod:`reachset_ros.guarantees` (a refusal names the row it protects) and :mod:`reachset_ros.errors` only.
"""
from .._lazy import attach

# each public name is imported from its submodule on first use (reachset_ros._lazy, issue 38.1)
__getattr__, __dir__, _EXPORTED = attach(__name__, {
    ".closedloop": [
        "SETTLING_TOLERANCE", "Analysis", "ClosedLoop", "FeedbackLaw", "Stability", "analyze",
        "center_coefficients", "close_loop", "closed_loop_tick", "radius_coefficients", "settling_ticks",
        "settling_time", "simulate", "simulate_ticks", "stability",
    ],
    ".controllers": [
        "LinearController", "compensated_feedback", "control_input", "lqg", "lqr", "lqr_gain",
        "static_feedback",
    ],
    ".gains": [
        "DEFAULTS", "Gains", "check_gains",
    ],
    ".observers": [
        "LinearObserver", "ObserverState", "bilinear", "extended_state_observer", "high_gain_observer",
        "kalman_filter", "observer_output", "observer_update", "paper_lqg_covariances",
    ],
    ".plant": [
        "LinearPlant", "lwa4p_joint_plant", "lwa4p_robot_model",
    ],
    ".reference_loop": [
        "LoopIO", "LTIPlan", "lti_simulate", "loop_io", "reference_inputs", "reference_state",
        "simulate_closed_loop", "steady_state", "steady_state_solver",
    ],
})

__all__ = ["LinearPlant", "lwa4p_joint_plant", "lwa4p_robot_model",
           "LinearObserver", "ObserverState", "bilinear", "high_gain_observer",
           "extended_state_observer", "kalman_filter", "paper_lqg_covariances",
           "observer_output", "observer_update",
           "LinearController", "static_feedback", "compensated_feedback", "lqr_gain", "lqr",
           "lqg", "control_input",
           "ClosedLoop", "close_loop", "Stability", "stability", "Analysis", "analyze",
           "radius_coefficients", "center_coefficients", "FeedbackLaw", "closed_loop_tick", "simulate",
           "simulate_ticks", "SETTLING_TOLERANCE", "settling_ticks", "settling_time",
           "Gains", "check_gains", "DEFAULTS",
           "LoopIO", "loop_io", "LTIPlan", "lti_simulate", "reference_inputs", "reference_state",
           "simulate_closed_loop", "steady_state", "steady_state_solver"]
