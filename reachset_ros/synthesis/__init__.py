"""Combined controller synthesis and reachset-conformant identification (paper eq. 10).

Per joint the paper solves

    min_p ||R_e(p)||   s.t.  Theorem-1 conformance on the recorded test cases,   R_u(p) in U_p,

over ``p = [theta, c_W, c_V, alpha_W, alpha_V]`` where ``theta`` are the controller/observer
parameters (HG + static feedback: omega, zeta, h1, h2; ESO + compensated feedback: omega,
zeta, l1, l2, l3). The Theorem-1 constraints do not depend on ``theta`` and, for fixed
``theta``, the set sizes are linear in ``alpha``: an inner linear programme in ``alpha`` and a
small non-convex search over ``theta`` (Sobol + Nelder-Mead). Baselines: the separate
approach, LQG (Table IV) and re-identification with the controller fixed; the iterative
procedure of Sec. III-D; the reference error of Appendix B.

Submodules:

* :mod:`~reachset_ros.synthesis.config`: configuration (``config/synthesis.yaml``) and the
  search space of ``theta`` (:class:`SearchSpace`, :func:`components_from_gains`).
* :mod:`~reachset_ros.synthesis.reference_error`: the reference error of Appendix B
  (:class:`ReferenceMethod`, :func:`reference_error` over recorded references,
  :func:`class_reference_error` over a :class:`ReferenceClass`) of the closed loop driven by
  references (:mod:`reachset_ros.systems.reference_loop`, whose names are re-exported here).
* :mod:`~reachset_ros.synthesis.problem`: the per-joint problem (:class:`JointProblem`) and
  the Theorem-1 constraints on alpha (:class:`AlphaPolytope`).
* :mod:`~reachset_ros.synthesis.search`: the inner LP per ``theta`` (:class:`Evaluator`) and
  the outer search.
* :mod:`~reachset_ros.synthesis.result`: :class:`JointResult` and the final soundness and
  conformance check.
* :mod:`~reachset_ros.synthesis.recorded_loop`: a re-identification's recorded closed loop
  (the bags' tracking error under the kept gains, verified by replaying the law) as rows that
  keep it inside ``R*_e``.
* :mod:`~reachset_ros.synthesis.modes`: :func:`combined`, :func:`separate`,
  :func:`reidentify`, :func:`lqg_baseline`, :func:`synthesize` (several joints).
* :mod:`~reachset_ros.synthesis.pipeline`: bags in, model out (:func:`synthesize_bags`) and
  the iterative procedure (:func:`iterate`).

Simulated recordings for tests, benchmarks and the docs live in
:mod:`reachset_ros.sim.recordings`; the references recorded in bags in
:mod:`reachset_ros.bags.references`.

May import: :mod:`reachset_ros._lazy` (the package's lazy attributes), :mod:`reachset_ros.sets`, :mod:`reachset_ros.systems`,
:mod:`reachset_ros.conformance`, :mod:`reachset_ros.bags`, :mod:`reachset_ros.defaults`,
:mod:`reachset_ros.guarantees` and :mod:`reachset_ros.errors`; never ``fleet``, ``sim``, ``robot`` or the ROS nodes. Pure numpy/scipy (plus rosbags to read
the optional reference/estimate topics); no ROS import.
"""
from .._lazy import attach

# each public name is imported from its submodule on first use (reachset_ros._lazy, issue 38.1)
__getattr__, __dir__, _EXPORTED = attach(__name__, {
    ".config": [
        "DEFAULT_CONFIG", "PARAMS", "PENALTY", "U_MARGIN", "SearchSpace", "components_from_gains",
        "config_path", "load_config", "u_max_for",
    ],
    "..systems.reference_loop": [
        "LoopIO", "LTIPlan", "lti_simulate", "loop_io", "simulate_closed_loop", "steady_state",
        "steady_state_solver",
    ],
    ".reference_error": [
        "ReferenceClass", "ReferenceErrorSets", "ReferenceMethod", "class_reference_error", "reference_error",
        "reference_windows",
    ],
    ".problem": [
        "AlphaPolytope", "JointProblem", "problems_from_series",
    ],
    ".search": [
        "Evaluation", "Evaluator", "LoopData",
    ],
    ".result": [
        "JointResult",
    ],
    ".modes": [
        "combined", "lqg_baseline", "reidentify", "separate", "synthesize",
    ],
    ".pipeline": [
        "BagSynthesis", "iterate", "synthesize_bags",
    ],
})
# ``reference_error`` names both a submodule and its function: importing the submodule would set
# the package's attribute to the module, so the function is imported now (numpy only)
from .reference_error import reference_error  # noqa: E402

__all__ = ["DEFAULT_CONFIG", "load_config", "config_path", "u_max_for", "SearchSpace", "PARAMS", "PENALTY",
           "U_MARGIN", "components_from_gains", "LoopIO", "loop_io", "LTIPlan", "lti_simulate",
           "simulate_closed_loop", "steady_state", "steady_state_solver", "reference_windows", "ReferenceMethod",
           "ReferenceErrorSets", "ReferenceClass", "class_reference_error", "reference_error", "AlphaPolytope",
           "JointProblem", "problems_from_series", "Evaluation", "LoopData", "Evaluator", "JointResult", "combined",
           "separate", "reidentify", "lqg_baseline", "synthesize", "iterate", "BagSynthesis", "synthesize_bags"]
