"""The synthesis configuration and the search space of ``theta`` (paper eq. 10).

``theta`` are the controller/observer parameters of one loop structure (HG + static feedback:
omega, zeta, h1, h2; ESO + compensated feedback: omega, zeta, l1, l2, l3; paper Sec. IV).
:data:`DEFAULT_CONFIG` / :func:`load_config` (``config/synthesis.yaml``): search settings,
``U_ff`` and ``U_p`` per joint (:func:`u_max_for`) and, per observer family, the free
parameters, start values, box and log-scaled parameters; :class:`SearchSpace` is that box
(with command-line overrides); a parameter vector becomes a
:class:`~reachset_ros.systems.gains.Gains` (:meth:`SearchSpace.to_gains`), the one gains type,
which builds the observer and controller that are certified and writes the model file's
``gains`` entry that the nodes run; :func:`components_from_gains` builds the loop of a model
file's ``gains``.
"""
from __future__ import annotations

import copy
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import yaml

from .. import defaults
from ..errors import ReachsetError
from ..systems.gains import ESO_INPUTS, FAMILY_PARAMS, Gains, family_controller

#: Parameters of each observer family (the controller adds omega, zeta).
PARAMS = FAMILY_PARAMS
#: Penalty added to the merit of infeasible (2x: unstable) parameter vectors.
PENALTY = 1e6
#: Relative margin kept from U_p in the LP so that the floating-point clean-up of alpha
#: (:func:`reachset_ros.conformance.make_sound`) cannot push R_u outside U_p.
U_MARGIN = 1e-4  # relative slack of R_u inside U_p: absorbs the final outer-bound and soundness inflation

defaults.register("synthesis", {
    "estimator": ("fd", "the test cases' initial-state estimator of a synthesis from bags (synthesize "
                        "--estimator; reidentify: the model's), and so of the demo's calibration of its rows: "
                        "causal finite differences corrected with the model's input response. identify's "
                        "default is 'lsq' (identify.estimator); the synthesis was not measured with it"),
    "u_max_unlisted": (26.0, "U_p half-width, rad/s^2, of a joint the synthesis configuration does not list "
                             "(its u_max.default; the LWA-4P's axes 1-4 value of paper Table I)"),
}, owner=__name__)


def _start_values(observer):
    """Start values of a family's search (fixed values of the non-free parameters): the paper's
    fixed feedback law (Sec. IV-C, defaults ``gains.feedback.paper``) with the family's observer
    gains (defaults ``gains.hg`` / ``gains.eso``)."""
    return {**defaults.get("gains.feedback.paper"),
            **{n: defaults.get(f"gains.{observer}.{n}") for n in FAMILY_PARAMS[observer] + ("eps",)
               if n not in ("omega", "zeta")}}


#: The built-in configuration (config/synthesis.yaml is the same, test/test_defaults.py checks it).
DEFAULT_CONFIG = {
    "format": "reachset_ros/synthesis-config/1",
    "search": {"sobol_log2": 6, "local_starts": 3, "local_maxfev": 120, "seed": 0,
               "max_spectral_radius": 0.999},
    "u_ff": defaults.get("gains.u_ff"),
    "u_max": {"default": defaults.get("synthesis.u_max_unlisted"), **defaults.get("lwa4p.u_max")},
    "structures": {
        "hg": {"controller": family_controller("hg"), "free": ["omega", "zeta"],
               "values": _start_values("hg"),
               "bounds": {"omega": [1.0, 100.0], "zeta": [0.3, 3.0], "h1": [1.0, 1000.0],
                          "h2": [1.0, 5000.0]},
               "log": ["omega", "h1", "h2"]},
        "eso": {"controller": family_controller("eso"), "free": ["l1", "l2", "l3"],
                "values": _start_values("eso"),
                "bounds": {"omega": [1.0, 100.0], "zeta": [0.3, 3.0], "l1": [1.0, 1000.0],
                           "l2": [1.0, 5000.0], "l3": [0.1, 5000.0]},
                "log": ["omega", "l1", "l2", "l3"]},
    },
}


# ====================================================================== configuration
def _merge(base, over):
    out = copy.deepcopy(base)
    for k, v in (over or {}).items():
        if isinstance(v, dict) and isinstance(out.get(k), dict):
            out[k] = _merge(out[k], v)
        else:
            out[k] = copy.deepcopy(v)
    return out


def config_path():
    """``config/synthesis.yaml`` of a source checkout or of the installed share directory."""
    here = Path(__file__).resolve().parents[1]   # the reachset_ros package directory
    for p in (here.parent / "config" / "synthesis.yaml",
              here.parents[3] / "share" / "reachset_ros" / "config" / "synthesis.yaml"
              if len(here.parents) > 3 else None):
        if p is not None and p.is_file():
            return p
    return None


def load_config(path=None):
    """The search configuration: :data:`DEFAULT_CONFIG` merged with the YAML file.

    Parameters
    ----------
    path : path, optional
        A YAML file with the layout of ``config/synthesis.yaml`` (any subset of keys).
        Default: the shipped ``config/synthesis.yaml`` if found, else the built-in defaults.
    """
    p = Path(path) if path is not None else config_path()
    if p is None:
        return copy.deepcopy(DEFAULT_CONFIG)
    if not p.is_file():
        raise ReachsetError(f"{p}: synthesis config not found")
    try:
        d = yaml.safe_load(p.read_text()) or {}
    except yaml.YAMLError as e:
        raise ReachsetError(f"{p}: synthesis config does not parse ({str(e).splitlines()[0]})") from None
    if not isinstance(d, dict):
        raise ReachsetError(f"{p}: synthesis config must be a mapping")
    return _merge(DEFAULT_CONFIG, d)


def u_max_for(cfg, joint):
    """U_p half-width of ``joint`` from the configuration (``u_max.default`` otherwise)."""
    um = cfg.get("u_max", {})
    if isinstance(um, (int, float)):
        return float(um)
    return float(um.get(joint, um.get("default", defaults.get("synthesis.u_max_unlisted"))))


# ====================================================================== search space
def _pos(name, v):
    v = float(v)
    if not (math.isfinite(v) and v > 0):
        raise ReachsetError(f"parameter {name} must be positive and finite, got {v}")
    return v


@dataclass(frozen=True)
class SearchSpace:
    """Controller/observer family and the box over which ``theta`` is searched.

    Attributes
    ----------
    observer : {"hg", "eso"}
    controller : {"static", "compensated"}
    free : tuple of str
        Searched parameters (order of ``theta``); the rest keep ``values``.
    values : dict
        Start value of every parameter (fixed value of the non-free ones), plus ``eps``.
    bounds : dict name -> (lo, hi)
    log : frozenset of str
        Parameters searched on a logarithmic scale.
    eso_input : {"previous", "current"}
        Plant input fed to the ESO (see :func:`reachset_ros.systems.observers.extended_state_observer`).
    dt : float
    """

    observer: str
    controller: str
    free: tuple
    values: dict
    bounds: dict
    log: frozenset = frozenset()
    eso_input: str = "previous"
    dt: float = 0.004

    def __post_init__(self):
        if self.observer not in PARAMS:
            raise ReachsetError(f"unknown observer {self.observer!r} (hg or eso)")
        if self.controller not in ("static", "compensated"):
            raise ReachsetError(f"unknown controller {self.controller!r} (static or compensated)")
        if self.controller == "compensated" and self.observer != "eso":
            raise ReachsetError("the compensated controller needs a disturbance estimate: use the eso observer")
        if self.eso_input not in ESO_INPUTS:
            raise ReachsetError(f"eso_input must be previous or current, not {self.eso_input!r}")
        names = PARAMS[self.observer]
        for n in self.free:
            if n not in names:
                raise ReachsetError(f"parameter {n!r} is not a parameter of the {self.observer} loop "
                                    f"({', '.join(names)})")
        if len(set(self.free)) != len(self.free):
            raise ReachsetError("a free parameter is listed twice")
        vals = {k: _pos(k, v) for k, v in self.values.items() if k in names or k == "eps"}
        for n in names:
            if n not in vals:
                raise ReachsetError(f"no value for parameter {n}")
        vals.setdefault("eps", 0.01)
        bnds = {}
        for n in self.free:
            if n not in self.bounds:
                raise ReachsetError(f"no search bounds for free parameter {n}")
            lo, hi = (float(x) for x in self.bounds[n])
            if not (0 < lo < hi and math.isfinite(hi)):
                raise ReachsetError(f"bounds of {n} must satisfy 0 < lo < hi, got [{lo}, {hi}]")
            bnds[n] = (lo, hi)
        object.__setattr__(self, "values", vals)
        object.__setattr__(self, "bounds", {**{k: tuple(map(float, v)) for k, v in self.bounds.items()}, **bnds})
        object.__setattr__(self, "free", tuple(self.free))
        object.__setattr__(self, "log", frozenset(self.log))

    @classmethod
    def from_config(cls, cfg, observer="hg", controller=None, free=None, fix=None, bounds=None,
                    eso_input="previous", dt=0.004):
        """Build from :func:`load_config` output with command-line style overrides.

        ``free``: list of names (replaces the configured ones; fixed ones keep their value);
        ``fix``: dict name -> value (removed from ``free``); ``bounds``: dict name -> (lo, hi).
        """
        st = cfg.get("structures", {}).get(observer)
        if st is None:
            raise ReachsetError(f"no search space for observer {observer!r} in the synthesis config")
        values = dict(st.get("values", {}))
        fr = list(st.get("free", [])) if free is None else list(free)
        known = set(PARAMS.get(observer, ())) | {"eps"}
        for k in list(fix or {}) + list(bounds or {}):
            if k not in known:
                raise ReachsetError(f"parameter {k!r} is not a parameter of the {observer} loop "
                                    f"({', '.join(sorted(known))})")
        for k, v in (fix or {}).items():
            values[k] = v
            if k in fr:
                fr.remove(k)
        bnds = dict(st.get("bounds", {}))
        bnds.update(bounds or {})
        for n in fr:   # a start value outside a user-given box: start in the box
            if n in bnds and n in values:
                lo, hi = bnds[n]
                values[n] = min(max(float(values[n]), float(lo)), float(hi))
        return cls(observer, controller or st.get("controller", "static"), tuple(fr), values, bnds,
                   frozenset(st.get("log", [])), eso_input, dt)

    @property
    def dim(self):
        return len(self.free)

    def full(self, theta=None):
        """All parameter values with ``theta`` (free parameters, in order) inserted."""
        v = dict(self.values)
        if theta is not None:
            for n, x in zip(self.free, np.atleast_1d(theta)):
                v[n] = float(x)
        return v

    def theta(self, values):
        return np.array([float(values[n]) for n in self.free])

    def to_unit(self, values):
        """Free parameters of ``values`` in the unit box (log scale where configured), clipped."""
        u = []
        for n in self.free:
            lo, hi = self.bounds[n]
            x = min(max(float(values[n]), lo), hi)
            u.append((math.log(x / lo) / math.log(hi / lo)) if n in self.log else (x - lo) / (hi - lo))
        return np.array(u)

    def from_unit(self, u):
        v = dict(self.values)
        for n, t in zip(self.free, np.clip(np.asarray(u, float), 0.0, 1.0)):
            lo, hi = self.bounds[n]
            v[n] = float(lo * (hi / lo) ** t) if n in self.log else float(lo + t * (hi - lo))
        return v

    def to_gains(self, values):
        """The :class:`~reachset_ros.systems.gains.Gains` of the parameter values (this
        space's observer, controller and ``eso_input``)."""
        return Gains(observer=self.observer, controller=self.controller, eso_input=self.eso_input,
                     eps=float(values["eps"]), **{n: float(values[n]) for n in PARAMS[self.observer]})

    def build(self, values):
        """Observer and controller of the parameter values (through :meth:`to_gains`: the
        loop the nodes build from the same gains)."""
        return self.to_gains(values).build(self.dt)

    def gains(self, values):
        """The gains entry of a model file (:meth:`Gains.model_dict`; the nodes read it)."""
        return self.to_gains(values).model_dict()

    @classmethod
    def from_gains(cls, gains, dt=0.004):
        """A space with every parameter fixed at the values of a model file's ``gains``
        (read by :meth:`Gains.from_model`)."""
        g = gains if isinstance(gains, Gains) else Gains.from_model(gains)
        values = {n: float(getattr(g, n)) for n in PARAMS[g.observer]}
        values["eps"] = float(g.eps)
        return cls(g.observer, g.controller, (), values, {}, frozenset(), g.eso_input, dt)


def components_from_gains(gains, dt=0.004):
    """``(observer, controller)`` of a model file's ``gains`` dict (:meth:`Gains.from_model`)."""
    return Gains.from_model(gains).build(dt)
