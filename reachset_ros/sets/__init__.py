"""Sets: zonotopes and the reachable sets of discrete linear systems (paper Sec. II-A, III-A/B).

The set arithmetic everything else builds on, pure numpy/scipy:

* :mod:`~reachset_ros.sets.zonotope` - :class:`Zonotope` (paper Def. 1) and its exact
  operations (Minkowski sum, linear map, interval hull, Prop. 1-4), order reduction,
  H-representation (:func:`halfspace_normals`), containment;
* :mod:`~reachset_ros.sets.reachability` - reachable output sets over a horizon (paper eqs.
  ``reachableSet``, ``Ra``-``Gk``), the sound outer bound of the minimal robust positively
  invariant set (:func:`invariant_outer`) and its interval-hull radius as a linear function
  of the generator scalings (:func:`radius_coefficients`, used by the synthesis' LP).

May import: :mod:`reachset_ros._lazy` (the package's lazy attributes), :mod:`reachset_ros.errors` only (this is the bottom layer; systems, conformance
and synthesis import it).
"""
from .._lazy import attach

# each public name is imported from its submodule on first use (reachset_ros._lazy, issue 38.1)
__getattr__, __dir__, _EXPORTED = attach(__name__, {
    ".reachability": [
        "InvariantSet", "NotStableError", "RadiusInfo", "disturbance_output_sets", "invariant_outer",
        "markov_parameters", "nominal_outputs", "radius_coefficients", "rakovic_alpha", "reachable_outputs",
        "reachable_subspace", "spectral_radius_reachable", "truncated_sum",
    ],
    ".zonotope": [
        "MAX_FACETS", "Zonotope", "box", "halfspace_normals",
    ],
})

__all__ = ["Zonotope", "halfspace_normals", "box", "MAX_FACETS",
           "reachable_subspace", "nominal_outputs", "disturbance_output_sets", "reachable_outputs",
           "markov_parameters", "rakovic_alpha", "truncated_sum", "invariant_outer",
           "InvariantSet", "radius_coefficients", "RadiusInfo", "NotStableError",
           "spectral_radius_reachable"]
