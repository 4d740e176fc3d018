"""Combined controller synthesis and reachset-conformant identification (paper eq. 10).

Per joint the paper solves

    min_p ||R_e(p)||   s.t.  Theorem-1 conformance on the recorded test cases,   R_u(p) in U_p,

over ``p = [theta, c_W, c_V, alpha_W, alpha_V]`` where ``theta`` are the controller/observer
parameters (HG + static feedback: omega, zeta, h1, h2; ESO + compensated feedback: omega,
zeta, l1, l2, l3). This module uses the problem's structure:

* The Theorem-1 constraints depend only on the data (test cases replay the *recorded*
  plant input ``u_p``), not on ``theta``: the deviation extremes are computed once per joint
  (:func:`reachset_ros.conformance.deviation_extremes`) and reduced to a handful of
  non-redundant rows ``G alpha >= h`` (:class:`AlphaPolytope`; centres fixed at 0 as in the
  paper's Appendix A).
* For fixed ``theta`` the closed loop is fixed; the interval-hull radii of the sound outer
  invariant sets are linear in ``alpha`` (:func:`reachset_ros.systems.closedloop.radius_coefficients`):
  ``||R_e|| = c_e . alpha`` and ``radius(R_u) = c_u . alpha``. The inner problem is the
  linear programme ``min c_e . alpha  s.t.  G alpha >= h,  c_u . alpha <= u_max - u_ff - ref``
  (HiGHS).
* Only ``theta`` (2-5 numbers) needs a non-convex search: a scrambled Sobol sequence over the
  box of ``config/synthesis.yaml`` plus seeds (start values, the separate approach's optimum,
  previous gains), then bounded Nelder-Mead refinements from the best distinct points.
  Reproducible for a given seed. Unstable ``theta`` are infeasible points.

Baselines: :func:`separate` (identify by min ||W|| + ||V||, then search ``theta`` with the
sets fixed), :func:`lqg_baseline` (paper Table IV) and :func:`reidentify` (controller fixed,
sets re-identified by the inner LP). :func:`iterate` is the paper's iterative procedure
(Sec. III-D) around a user-given ``record(gains) -> bags`` callable.

Reference error (paper Appendix B), :class:`ReferenceErrorSets`: method 3 (default) encloses
``y_e,ref`` and ``u_e,ff`` of the nominal closed loop driven by every reference found in the
bags (``/reference``) in boxes and adds them to ``R_e`` and ``R_u`` inside the optimisation;
method 2 optimises ``R_e``/``R_u`` alone and checks ``R_u (+) u_e,ff`` for the recorded
references afterwards; method 1 assumes the controller tracks ``y_cl,ref`` (no ``u_e,ff``).
Without a ``/reference`` topic the reference error is taken as zero: the feedforward
``u_ff = qdd_d`` through the double integrator reproduces the reference exactly (App. B).

Pure numpy/scipy (plus rosbags to read the optional reference/estimate topics); no ROS import.
"""
from __future__ import annotations

import copy
import math
import time
import warnings
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
from scipy.optimize import linprog, minimize

from .. import conformance as cf
from ..systems.closedloop import close_loop, radius_coefficients
from ..bags.references import ESTIMATE_TOPIC, REFERENCE_TOPIC, Reference, read_estimates, read_references
from ..errors import InfeasibleError, ReachsetError
from ..sets.reachability import NotStableError, spectral_radius_reachable

__all__ = ["DEFAULT_CONFIG", "load_config", "config_path", "u_max_for", "SearchSpace", "PARAMS",
           "components_from_gains", "Reference", "read_references", "read_estimates", "LoopIO", "loop_io",
           "LTIPlan", "lti_simulate", "simulate_closed_loop", "steady_state", "reference_windows",
           "ReferenceErrorSets", "reference_error", "AlphaPolytope", "JointProblem", "problems_from_series",
           "Evaluation", "Evaluator", "JointResult", "combined", "separate", "reidentify", "lqg_baseline",
           "synthesize", "iterate", "BagSynthesis", "synthesize_bags", "Scenario", "Recording",
           "DEFAULT_GAINS", "simulate_recordings", "simulate_arm_recordings", "recordings_series",
           "write_recordings"]

#: Parameters of each observer family (the controller adds omega, zeta).
PARAMS = {"hg": ("omega", "zeta", "h1", "h2"), "eso": ("omega", "zeta", "l1", "l2", "l3")}
#: Penalty added to the merit of infeasible (2x: unstable) parameter vectors.
PENALTY = 1e6
#: Relative margin kept from U_p in the LP so that the floating-point clean-up of alpha
#: (:func:`reachset_ros.conformance.make_sound`) cannot push R_u outside U_p.
U_MARGIN = 1e-4  # relative slack of R_u inside U_p: absorbs the final outer-bound and soundness inflation

DEFAULT_CONFIG = {
    "format": "reachset_ros/synthesis-config/1",
    "search": {"sobol_log2": 6, "local_starts": 3, "local_maxfev": 120, "seed": 0,
               "max_spectral_radius": 0.999},
    "u_ff": 2.0,
    "u_max": {"default": 26.0, "arm_1_joint": 26.0, "arm_2_joint": 26.0, "arm_3_joint": 26.0,
              "arm_4_joint": 26.0, "arm_5_joint": 100.0, "arm_6_joint": 100.0},
    "structures": {
        "hg": {"controller": "static", "free": ["omega", "zeta"],
               "values": {"omega": 20.0, "zeta": 1.0, "h1": 15.0, "h2": 30.0, "eps": 0.01},
               "bounds": {"omega": [1.0, 100.0], "zeta": [0.3, 3.0], "h1": [1.0, 1000.0],
                          "h2": [1.0, 5000.0]},
               "log": ["omega", "h1", "h2"]},
        "eso": {"controller": "compensated", "free": ["l1", "l2", "l3"],
                "values": {"omega": 20.0, "zeta": 1.0, "l1": 57.1, "l2": 103.3, "l3": 18.1, "eps": 0.01},
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
    import yaml
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
    return float(um.get(joint, um.get("default", 26.0)))


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

    def build(self, values):
        """Observer and controller of the parameter values."""
        from ..systems.controllers import compensated_feedback, static_feedback
        from ..systems.observers import extended_state_observer, high_gain_observer
        v = values
        if self.observer == "hg":
            obs = high_gain_observer(v["h1"], v["h2"], v["eps"], self.dt)
        else:
            obs = extended_state_observer(v["l1"], v["l2"], v["l3"], v["eps"], self.dt, self.eso_input)
        ctrl = (static_feedback if self.controller == "static" else compensated_feedback)(v["omega"], v["zeta"])
        return obs, ctrl

    def gains(self, values):
        """The gains entry of a model file (the controller and observer nodes read it)."""
        g = {"observer": self.observer, "controller": self.controller}
        for n in PARAMS[self.observer]:
            g[n] = float(values[n])
        g["eps"] = float(values["eps"])
        if self.observer == "eso":
            g["eso_input"] = self.eso_input
        return g

    @classmethod
    def from_gains(cls, gains, dt=0.004):
        """A space with every parameter fixed at the values of a model file's ``gains``."""
        if not isinstance(gains, dict) or "observer" not in gains:
            raise ReachsetError("gains must name the observer (hg or eso)")
        obs = gains["observer"]
        if obs not in PARAMS:
            raise ReachsetError(f"gains: unknown observer {obs!r}")
        try:
            values = {n: float(gains[n]) for n in PARAMS[obs]}
        except KeyError as e:
            raise ReachsetError(f"gains: missing {e.args[0]} for the {obs} loop") from None
        except (TypeError, ValueError):
            raise ReachsetError("gains: parameter values must be numbers") from None
        values["eps"] = float(gains.get("eps", 0.01))
        return cls(obs, gains.get("controller", "static" if obs == "hg" else "compensated"), (), values, {},
                   frozenset(), gains.get("eso_input", "previous"), dt)


def components_from_gains(gains, dt=0.004):
    """``(observer, controller)`` of a model file's ``gains`` dict (for the nodes)."""
    sp = SearchSpace.from_gains(gains, dt)
    return sp.build(sp.values)


# ====================================================================== closed loop with references
@dataclass(frozen=True, eq=False)
class LoopIO:
    """The closed loop driven by references and disturbances (superposition's other half).

    ``z[k+1] = A z + B r``, ``out = C z + D r`` with ``z = [x_p; x_o]``, inputs
    ``r = [u_ff (m), x_ref (ne), w (n_p), v (p)]`` and outputs ``[y (p), u (m), x_hat (ne)]``;
    ``x_ref`` in the observer's estimate coordinates (``estimate_names``). The control law is
    ``u = u_ff + K (x_ref - x_hat)`` with the algebraic loop solved exactly.
    """

    A: np.ndarray
    B: np.ndarray
    C: np.ndarray
    D: np.ndarray
    m: int
    ne: int
    n_p: int
    p: int
    estimate_names: tuple

    def inputs(self, *parts):
        """Column slice of ``B``/``D`` for the named input groups ("u_ff", "x_ref", "w", "v")."""
        offs = {"u_ff": (0, self.m), "x_ref": (self.m, self.m + self.ne),
                "w": (self.m + self.ne, self.m + self.ne + self.n_p),
                "v": (self.m + self.ne + self.n_p, self.m + self.ne + self.n_p + self.p)}
        idx = np.concatenate([np.arange(*offs[k]) for k in parts])
        return idx


def loop_io(plant, observer, controller):
    """:class:`LoopIO` of plant + observer + controller (same algebra as :func:`close_loop`)."""
    Ap, Bp, Cp, Dp = plant.A, plant.B, plant.C, plant.D
    npl, m, p = plant.n_states, plant.n_inputs, plant.n_outputs
    K = controller.gain_for(observer.estimate_names)
    ne = len(observer.estimate_names)
    Ao, Boy, Bou, Co, Doy, Dou = (observer.Ao, observer.Bo_y, observer.Bo_u, observer.Co,
                                  observer.Do_y, observer.Do_u)
    no = observer.n_states
    Xz = np.hstack([Doy @ Cp, Co])
    Dxu = Doy @ Dp + Dou
    L = np.eye(m) + K @ Dxu
    Li = np.linalg.inv(L)
    Fz = -Li @ K @ Xz
    nr = m + ne + npl + p
    Ur = np.zeros((m, nr))                    # u = Fz z + Ur r
    Ur[:, :m] = Li
    Ur[:, m:m + ne] = Li @ K
    Ur[:, m + ne + npl:] = -Li @ K @ Doy
    Ev = np.zeros((p, nr))
    Ev[:, m + ne + npl:] = np.eye(p)
    Yz = np.hstack([Cp, np.zeros((p, no))]) + Dp @ Fz   # y = Yz z + Yr r
    Yr = Dp @ Ur + Ev
    Hz = Xz + Dxu @ Fz                                   # x_hat = Hz z + Hr r
    Hr = Dxu @ Ur + Doy @ Ev
    Bu = np.vstack([Bp, Bou])
    By = np.vstack([np.zeros((npl, p)), Boy])
    Ew = np.zeros((npl + no, nr))
    Ew[:npl, m + ne:m + ne + npl] = np.eye(npl)
    A = np.block([[Ap, np.zeros((npl, no))], [np.zeros((no, npl)), Ao]]) + Bu @ Fz + By @ Yz
    B = Bu @ Ur + By @ Yr + Ew
    C = np.vstack([Yz, Fz, Hz])
    D = np.vstack([Yr, Ur, Hr])
    return LoopIO(A, B, C, D, m, ne, npl, p, tuple(observer.estimate_names))


class LTIPlan:
    """Blocked exact simulation of ``z[k+1] = A z + B r[k]``, ``y[k] = C z + D r[k]``.

    Within a block of ``block`` ticks the response is a block-Toeplitz matrix product (one
    BLAS call for all blocks of a sequence); only the block-boundary states are propagated
    sequentially. The plan (Toeplitz and observability matrices) is built once and reused for
    many input sequences. Same result as the tick loop up to floating-point re-association.
    """

    def __init__(self, A, B, C, D, block=32):
        A, B, C, D = (np.atleast_2d(np.asarray(x, float)) for x in (A, B, C, D))
        n, m, p = A.shape[0], B.shape[1], C.shape[0]
        b = int(max(1, block))
        powers = [np.eye(n)]
        for _ in range(b):
            powers.append(A @ powers[-1])
        P = np.stack(powers[:b])                                   # (b, n, n)
        mk = np.concatenate([D[None], np.einsum("pn,knq,qm->kpm", C, P[:b - 1], B)])  # (b, p, m)
        i, j = np.meshgrid(np.arange(b), np.arange(b), indexing="ij")
        blocks = np.where((i >= j)[:, :, None, None], mk[np.clip(i - j, 0, b - 1)], 0.0)  # (b, b, p, m)
        self.ToeT = blocks.transpose(0, 2, 1, 3).reshape(b * p, b * m).T.copy()
        self.ObsT = np.vstack([C @ powers[i] for i in range(b)]).T
        self.CtrT = np.hstack([powers[b - 1 - j] @ B for j in range(b)]).T
        self.Ab = powers[b]
        self.n, self.m, self.p, self.b = n, m, p, b

    def run(self, r, z0=None):
        """Outputs ``(T, p)`` for inputs ``r`` ``(T, m)`` from the state ``z0`` (zero by default)."""
        r = np.asarray(r, float).reshape(len(r), -1)
        T = r.shape[0]
        n, m, p, b = self.n, self.m, self.p, self.b
        if T == 0:
            return np.zeros((0, p))
        nb = -(-T // b)
        R = np.zeros((nb * b, m))
        R[:T] = r
        R = R.reshape(nb, b * m)
        CR = R @ self.CtrT
        Z = np.empty((nb, n))
        z = np.zeros(n) if z0 is None else np.asarray(z0, float).copy()
        Ab = self.Ab
        for i in range(nb):
            Z[i] = z
            z = Ab @ z + CR[i]
        Y = Z @ self.ObsT + R @ self.ToeT
        return Y.reshape(nb * b, p)[:T]


def lti_simulate(A, B, C, D, r, z0=None, block=32):
    """Outputs of ``z[k+1] = A z + B r[k]``, ``y[k] = C z + D r[k]`` for ``k = 0..T-1`` (exact).

    See :class:`LTIPlan` (blocked; equal to the tick loop up to re-association).

    Parameters
    ----------
    A, B, C, D : array_like
    r : array_like, (T, m)
    z0 : array_like, (n,), optional

    Returns
    -------
    ndarray, (T, p)
    """
    r = np.asarray(r, float).reshape(len(r), -1)
    return LTIPlan(A, B, C, D, min(block, max(len(r), 1))).run(r, z0)


def _x_ref(names, q, qd, qdd):
    """Reference in the observer's estimate coordinates (q, qd, d, q_prev, u_prev)."""
    T = len(q)
    out = np.zeros((T, len(names)))
    prev = lambda a: np.concatenate([a[:1], a[:-1]])  # noqa: E731
    for i, nm in enumerate(names):
        if nm == "q":
            out[:, i] = q
        elif nm == "qd":
            out[:, i] = qd
        elif nm == "q_prev":
            out[:, i] = prev(q)
        elif nm == "u_prev":
            out[:, i] = prev(qdd)
        elif nm == "d":
            pass
        else:
            raise ReachsetError(f"no reference for the estimate {nm!r}")
    return out


def simulate_closed_loop(plant, observer, controller, q_d, qd_d, qdd_d, w=None, v=None, x0=None,
                         xo0=None):
    """Simulate plant + observer + controller with a reference and disturbances (a recording).

    ``u[k] = qdd_d[k] + K (x_ref[k] - x_hat[k])``; the measurement ``y[k] = C x_p[k] + v[k]``
    is what ``/joint_states`` carries and ``u[k]`` what ``/plant_input`` carries.

    Parameters
    ----------
    plant, observer, controller
    q_d, qd_d, qdd_d : array_like, (T,)
        Reference (a single-input plant).
    w : array_like, (T, n_p), optional
        Raw process disturbances (plant-state vectors); zero by default.
    v : array_like, (T, p), optional
    x0 : array_like, optional
        Initial plant state (default: the loop's forced response to the quadratic
        extrapolation of the first reference sample, :func:`steady_state`).
    xo0 : array_like, optional
        Initial observer state (default: as ``x0``).

    Returns
    -------
    dict with ``y`` (T, p), ``u`` (T, m), ``x_hat`` (T, ne), ``x_ref`` (T, ne)
    """
    io = loop_io(plant, observer, controller)
    q_d, qd_d, qdd_d = (np.asarray(a, float).ravel() for a in (q_d, qd_d, qdd_d))
    T = len(q_d)
    xr = _x_ref(io.estimate_names, q_d, qd_d, qdd_d)
    r = np.zeros((T, io.B.shape[1]))
    r[:, :io.m] = qdd_d[:, None]
    r[:, io.m:io.m + io.ne] = xr
    if w is not None:
        r[:, io.m + io.ne:io.m + io.ne + io.n_p] = np.asarray(w, float).reshape(T, io.n_p)
    if v is not None:
        r[:, io.m + io.ne + io.n_p:] = np.asarray(v, float).reshape(T, io.p)
    z0 = steady_state(io, plant, q_d[0], qd_d[0], qdd_d[0], io.inputs("u_ff", "x_ref"))
    if x0 is not None:
        z0[:plant.n_states] = np.asarray(x0, float)
    if xo0 is not None:
        z0[plant.n_states:] = np.asarray(xo0, float)
    out = lti_simulate(io.A, io.B, io.C, io.D, r, z0)
    p, m = io.p, io.m
    return {"y": out[:, :p], "u": out[:, p:p + m], "x_hat": out[:, p + m:], "x_ref": xr}


@dataclass(frozen=True)
class ReferenceErrorSets:
    """Enclosures of the reference error (paper Appendix B) over a set of references.

    ``e_lo``/``e_hi``: box of ``y_e,ref = x_hat_sel - x_ref_sel`` of the disturbance-free
    closed loop (``Y_e,ref``); ``u_lo``/``u_hi``: interval of ``u_e,ff = u_p - u_ff``
    (``U_e,ff``); ``qdd_max``: largest ``|qdd_d|`` of the references; ``ticks``, ``stretches``;
    ``argext``: for each of ``e_lo..., e_hi..., u_lo, u_hi`` the (stretch, tick) where it is
    attained; ``exact``: computed on every reference tick (False: on the search windows).
    """

    e_lo: np.ndarray
    e_hi: np.ndarray
    u_lo: float
    u_hi: float
    qdd_max: float
    ticks: int
    stretches: int
    argext: tuple = ()
    exact: bool = True

    @property
    def norm(self):
        """Sum of the edge lengths of the box ``Y_e,ref``."""
        return float(np.sum(self.e_hi - self.e_lo))

    @property
    def u_bound(self):
        """Largest ``|u|`` that ``U_e,ff`` adds on either side of ``R_u (+) U_ff``."""
        return float(max(self.u_hi, -self.u_lo))

    def as_dict(self):
        return {"y_e_ref": [[float(a), float(b)] for a, b in zip(self.e_lo, self.e_hi)],
                "u_e_ff": [float(self.u_lo), float(self.u_hi)], "norm": self.norm,
                "qdd_max": float(self.qdd_max), "ticks": int(self.ticks), "stretches": int(self.stretches)}


def zero_reference_error(n=2):
    return ReferenceErrorSets(np.zeros(n), np.zeros(n), 0.0, 0.0, 0.0, 0, 0)


def _reference_inputs(names, q, qd, qdd):
    return np.hstack([np.asarray(qdd, float)[:, None], _x_ref(names, q, qd, qdd)])


def steady_state(io, plant, q0, qd0, qdd0, cols, solver=None):
    """Loop state on the forced response to the quadratic extrapolation of a reference sample.

    For ``q_d[k] = q0 + qd0 dt k + qdd0 (dt k)^2 / 2`` (and the matching ``qd_d``, ``qdd_d``,
    shifted components) the loop has a quadratic particular solution
    ``z[k] = z0 + z1 k + z2 k^2``; ``z0`` is returned (min-norm, so the unreachable
    constant-disturbance state stays 0). A reference stretch that starts mid-motion then starts
    without an artificial transient.
    """
    dt = plant.dt
    ks = np.array([0.0, 1.0, 2.0])
    q = q0 + qd0 * dt * ks + 0.5 * qdd0 * (dt * ks) ** 2
    qd = qd0 + qdd0 * dt * ks
    qdd = np.full(3, float(qdd0))
    names = io.estimate_names
    r = _reference_inputs(names, q, qd, qdd)
    # q_prev / u_prev at k = 0 must be the extrapolated k = -1 values
    for i, nm in enumerate(names):
        if nm == "q_prev":
            r[:, 1 + i] = q - qd0 * dt + 0.5 * qdd0 * dt * dt * (1 - 2 * ks)
        elif nm == "u_prev":
            r[:, 1 + i] = qdd0
    r2 = 0.5 * (r[2] - 2 * r[1] + r[0])
    r1 = r[1] - r[0] - r2
    r0 = r[0]
    B = io.B[:, cols]
    solve = solver or steady_state_solver(io, cols)
    z2 = solve(B @ r2)
    z1 = solve(B @ r1 - 2 * z2)
    return solve(B @ r0 - z1 - z2)


def steady_state_solver(io, cols):
    """``rhs -> z`` solving ``(I - A) z = rhs`` on the reachable subspace of the reference inputs."""
    from ..sets.reachability import reachable_subspace
    V = reachable_subspace(io.A, io.B[:, cols])    # excludes e.g. the constant-disturbance state
    Mp = np.linalg.pinv((np.eye(io.A.shape[0]) - io.A) @ V)
    VM = V @ Mp
    return lambda rhs: VM @ rhs


def reference_windows(references, before=300, after=100, warmup=150, per_stretch=8, max_windows=24):
    """Short slices of the references where the reference error peaks (for the search).

    Around the extremes of ``qd_d``, ``qdd_d`` and their first two differences (jerk and snap)
    of every stretch, ranked over all stretches by the size of those features; overlapping
    slices are merged. The reference error on these slices (each started on its quadratic
    steady state, :func:`steady_state`, with ``warmup`` uncounted ticks so that the start
    transient has decayed) approximates the exact one closely; the final result is always
    computed on every tick.
    """
    cands = []
    for si, r in enumerate(references):
        n = len(r)
        if n == 0:
            continue
        feats = [r.qd, r.qdd]
        if n > 2:
            j = np.diff(r.qdd, prepend=r.qdd[0])
            feats += [j, np.diff(j, prepend=j[0])]
        for f in feats:
            scale = float(np.abs(f).max()) or 1.0
            for t in (int(np.argmax(f)), int(np.argmin(f))):
                cands.append((abs(float(f[t])) / scale, si, t))
    cands.sort(key=lambda c: -c[0])
    spans = {}
    for _, si, t in cands:
        n = len(references[si])
        lo, hi = max(0, t - before - warmup), min(n, t + after + 1)
        spans.setdefault(si, []).append((lo, hi))
    out = []
    for si, lst in spans.items():
        lst.sort()
        merged = []
        for lo, hi in lst[:per_stretch * 2]:
            if merged and lo <= merged[-1][1]:
                merged[-1] = (merged[-1][0], max(hi, merged[-1][1]))
            else:
                merged.append((lo, hi))
        r = references[si]
        for lo, hi in merged:
            out.append(r.slice(lo, hi, warmup if lo > 0 else 0))
    return tuple(out[:max_windows])


def reference_error(plant, observer, controller, references, errors=("q", "qd"), exact=True):
    """Appendix B, method 3: boxes enclosing ``y_e,ref`` and ``u_e,ff`` over ``references``.

    Each :class:`Reference` stretch drives the disturbance-free closed loop with
    ``u_ff = qdd_d``, starting on the forced response to the quadratic extrapolation of its
    first sample (:func:`steady_state`).

    Returns
    -------
    ReferenceErrorSets
    """
    if not references:
        return zero_reference_error(len(errors))
    io = loop_io(plant, observer, controller)
    sel = [io.estimate_names.index(nm) for nm in errors]
    cols = io.inputs("u_ff", "x_ref")
    p, m = io.p, io.m
    rows = [p] + [p + m + i for i in sel]
    plan = LTIPlan(io.A, io.B[:, cols], io.C[rows], io.D[np.ix_(rows, cols)])
    ne = len(sel)
    lo = np.full(ne + 1, np.inf)
    hi = np.full(ne + 1, -np.inf)
    arg_lo = [(0, 0)] * (ne + 1)
    arg_hi = [(0, 0)] * (ne + 1)
    qmax, ticks = 0.0, 0
    solver = steady_state_solver(io, cols)
    for si, ref in enumerate(references):
        w = min(int(ref.warmup), len(ref) - 1)
        if len(ref) == 0:
            continue
        r = _reference_inputs(io.estimate_names, ref.q, ref.qd, ref.qdd)
        z0 = steady_state(io, plant, ref.q[0], ref.qd[0], ref.qdd[0], cols, solver)
        out = plan.run(r, z0)[w:]
        err = np.column_stack([out[:, 0] - ref.qdd[w:], out[:, 1:] - r[w:, 1:][:, sel]])
        il, ih = err.argmin(axis=0), err.argmax(axis=0)
        for c in range(ne + 1):
            if err[il[c], c] < lo[c]:
                lo[c], arg_lo[c] = err[il[c], c], (si, int(il[c]) + w)
            if err[ih[c], c] > hi[c]:
                hi[c], arg_hi[c] = err[ih[c], c], (si, int(ih[c]) + w)
        qmax = max(qmax, float(np.abs(ref.qdd).max()))
        ticks += len(ref)
    if ticks == 0:
        return zero_reference_error(ne)
    return ReferenceErrorSets(lo[1:], hi[1:], float(lo[0]), float(hi[0]), qmax, ticks, len(references),
                          tuple(arg_lo[1:] + arg_hi[1:] + [arg_lo[0], arg_hi[0]]), exact)


# ====================================================================== Theorem-1 constraints on alpha
@dataclass(frozen=True, eq=False)
class AlphaPolytope:
    """Theorem 1 with zero centres as ``G alpha >= h``, ``alpha >= lower`` (non-redundant rows).

    ``alpha = [alpha_W, alpha_V]``. Built from :func:`reachset_ros.conformance.identification_constraints`;
    rows with ``h <= 0`` (implied by ``alpha >= 0``, since ``G >= 0``) and rows implied by a
    single other row (``G_i / h_i >= G_j / h_j`` element-wise) are dropped, which leaves a
    few dozen of the ``2 (k* + 1)`` rows.
    """

    G: np.ndarray
    h: np.ndarray
    lower: np.ndarray
    rows_total: int
    pw: int
    pv: int

    @classmethod
    def build(cls, plant, thm, devs, horizon=None, alpha_lower=None):
        A_ub, b_ub, _, _ = cf.identification_constraints(plant, thm, devs, horizon, "zero")
        pw, pv, ny = plant.Gw.shape[1], plant.Gv.shape[1], plant.C.shape[0]
        off = pw + ny
        G, h = -A_ub[:, off:], -b_ub
        total = len(h)
        na = pw + pv
        lower = np.zeros(na) if alpha_lower is None else np.array(
            np.broadcast_to(np.asarray(alpha_lower, float), (na,)))
        if np.any(lower < 0) or not np.all(np.isfinite(lower)):
            raise ReachsetError("alpha lower bounds must be finite and non-negative")
        if np.any(G < -1e-15):
            raise ReachsetError("internal: Theorem-1 rows with negative alpha coefficients")
        G = np.maximum(G, 0.0)
        keep = h > 0
        G, h = G[keep], h[keep]
        dead = ~np.any(G > 0, axis=1)
        if np.any(dead):
            raise InfeasibleError(f"conformance is infeasible: a measured deviation of {float(h[dead].max()):.3g} "
                                  "lies in a direction no disturbance generator reaches")
        if len(h):
            Gn = G / h[:, None]
            order = np.lexsort(Gn.T[::-1])
            Gn, G, h = Gn[order], G[order], h[order]
            keep = np.ones(len(h), bool)
            for i in range(len(h)):
                if not keep[i]:
                    continue
                dom = np.all(Gn >= Gn[i], axis=1)   # rows implied by row i
                dom[i] = False
                keep &= ~dom
            G, h = G[keep], h[keep]
        return cls(G, h, lower, total, pw, pv)

    def minimize(self, c, extra=None, rhs=None):
        """``min c . alpha`` over the polytope, optionally with ``extra . alpha <= rhs``.

        Returns ``(alpha, value)`` or ``(None, None)`` when infeasible. The problem is scaled
        (rows by ``h``, variables by their largest coefficient) before HiGHS sees it.
        """
        c = np.asarray(c, float)
        na = self.G.shape[1]
        if len(self.h):
            s = 1.0 / np.maximum((self.G / self.h[:, None]).max(axis=0), 1e-300)
        else:
            s = np.ones(na)
        s = np.where(np.isfinite(s) & (s > 0), s, 1.0)
        A = [-(self.G / self.h[:, None]) * s] if len(self.h) else []
        b = [-np.ones(len(self.h))] if len(self.h) else []
        if extra is not None:
            if rhs <= 0:
                if rhs < 0 or np.any(np.asarray(extra) * np.maximum(self.lower, 0) > 0):
                    return None, None
            else:
                A.append((np.asarray(extra, float) * s / rhs)[None, :])
                b.append(np.ones(1))
        cs = c * s
        scale = float(np.abs(cs).max()) or 1.0
        bounds = [(float(lo / sj), None) for lo, sj in zip(self.lower, s)]
        A_ub = np.vstack(A) if A else None
        b_ub = np.concatenate(b) if b else None
        res = linprog(cs / scale, A_ub=A_ub, b_ub=b_ub, bounds=bounds, method="highs")
        if res.status == 2:
            return None, None
        if res.status != 0:
            raise InfeasibleError(f"inner linear programme failed: {res.message}")
        alpha = np.maximum(res.x * s, self.lower)
        return alpha, float(c @ alpha)


# ====================================================================== per-joint problem
@dataclass(frozen=True, eq=False)
class JointProblem:
    """Everything about one joint that does not depend on the controller parameters.

    Build with :meth:`prepare`.
    """

    name: str
    plant: object
    estimator: object
    thm: object
    devs: object
    horizon: int
    polytope: AlphaPolytope
    u_max: float
    u_ff: float
    y: np.ndarray
    u: np.ndarray
    segments: tuple
    references: tuple = ()
    reference_method: int = 3
    alpha_lower: np.ndarray = None
    stamps: np.ndarray = None
    ref_windows: tuple = ()

    @classmethod
    def prepare(cls, name, plant, estimator, y, u, segments, horizon=125, u_max=26.0, u_ff=2.0,
                thm=None, references=(), reference_method=3, alpha_lower=None, stamps=None):
        """Deviation extremes (one sweep over all test cases) and the reduced Theorem-1 rows.

        Raises
        ------
        ReachsetError
            On bad limits, too little data, or references faster than ``U_ff``.
        """
        if not (math.isfinite(u_max) and u_max > 0):
            raise ReachsetError(f"joint {name}: u_max must be positive, got {u_max}")
        if not (math.isfinite(u_ff) and u_ff >= 0):
            raise ReachsetError(f"joint {name}: u_ff must be >= 0, got {u_ff}")
        if reference_method not in (1, 2, 3):
            raise ReachsetError(f"reference method must be 1, 2 or 3, got {reference_method}")
        refs = tuple(references or ())
        qmax = max((float(np.abs(r.qdd).max()) for r in refs if len(r)), default=0.0)
        if qmax > u_ff * (1 + 1e-12):
            raise ReachsetError(f"joint {name}: the references in the bags reach |qdd_d| = {qmax:.4g} rad/s^2, "
                                f"outside U_ff = [-{u_ff:g}, {u_ff:g}] (raise --u-ff)")
        thm = thm or cf.Theorem1.build(plant, horizon)
        try:
            devs = cf.deviation_extremes(plant, estimator, y, u, segments, horizon, thm)
            poly = AlphaPolytope.build(plant, thm, devs, horizon, alpha_lower)
        except ReachsetError as e:
            raise type(e)(f"joint {name}: {e}") from None
        windows = reference_windows(refs) if (refs and reference_method == 3) else ()
        return cls(name, plant, estimator, thm, devs, horizon, poly, float(u_max), float(u_ff),
                   cf.as_2d(y), cf.as_2d(u), tuple(segments), refs, int(reference_method),
                   poly.lower, stamps, windows)

    @property
    def test_cases(self):
        return self.devs.test_cases


# ====================================================================== evaluation of one theta
@dataclass
class Evaluation:
    """The inner problem at one parameter vector.

    ``merit``: ``||R*_e||`` if feasible, ``PENALTY + normalised violation`` if R_u cannot be
    kept inside U_p, ``2 PENALTY + spectral radius`` if unstable.
    """

    values: dict
    stable: bool
    feasible: bool
    merit: float
    re_norm: float = None
    alpha: np.ndarray = None
    ru_radius: float = None
    ru_room: float = None
    min_ru_radius: float = None
    reason: str = ""
    Kw: np.ndarray = None
    Kv: np.ndarray = None
    ref: ReferenceErrorSets = None


class LoopData:
    """Everything about one parameter vector that does not depend on alpha (shared by evaluators)."""

    __slots__ = ("ok", "merit", "reason", "Kw", "Kv", "ne", "ref")

    def __init__(self, ok, merit=0.0, reason="", Kw=None, Kv=None, ne=2, ref=None):
        self.ok, self.merit, self.reason = ok, merit, reason
        self.Kw, self.Kv, self.ne, self.ref = Kw, Kv, ne, ref


def _key(values):
    return tuple((n, round(float(values[n]), 12)) for n in sorted(values))


class Evaluator:
    """Evaluates (and caches) the inner problem of a :class:`JointProblem` for a :class:`SearchSpace`.

    ``alpha_fixed``: the separate approach - the sets are given, only R_u is checked.
    ``loops``: a dict shared between evaluators of the same problem and space (the closed
    loop's radius coefficients and reference error do not depend on alpha).
    """

    def __init__(self, problem, space, alpha_fixed=None, max_spectral_radius=1.0, loops=None,
                 references=None, ref_offset=None):
        self.problem = problem
        self.space = space
        self.references = problem.references if references is None else tuple(references)
        self.ref_offset = ref_offset      # added to windowed reference errors: (de_lo, de_hi, du_lo, du_hi)
        self.alpha_fixed = None if alpha_fixed is None else np.asarray(alpha_fixed, float)
        self.max_rho = float(max_spectral_radius)
        self.cache = {}
        self.loops = {} if loops is None else loops
        self.count = 0

    def __call__(self, values):
        key = _key(values)
        ev = self.cache.get(key)
        if ev is None:
            ev = self._evaluate(values, key)
            self.cache[key] = ev
            self.count += 1
        return ev

    def loop_data(self, values, key=None):
        key = key or _key(values)
        ld = self.loops.get(key)
        if ld is None:
            ld = self._loop_data(values)
            self.loops[key] = ld
        return ld

    def _loop_data(self, values):
        pb = self.problem
        try:
            obs, ctrl = self.space.build(values)
            cl = close_loop(pb.plant, obs, ctrl)
        except (ValueError, np.linalg.LinAlgError) as e:
            return LoopData(False, 3 * PENALTY, str(e).splitlines()[0])
        if self.max_rho < 1.0:
            rho, _ = spectral_radius_reachable(cl.A, np.hstack([cl.Ew, cl.Ev]))
            if rho >= self.max_rho:
                return LoopData(False, 2 * PENALTY + min(rho, 1e3), f"spectral radius {rho:.6g} >= {self.max_rho:g}")
        try:
            Kw, Kv = radius_coefficients(cl)
        except (NotStableError, ValueError, np.linalg.LinAlgError) as e:
            from ..systems.closedloop import stability
            rho = stability(cl).spectral_radius
            return LoopData(False, 2 * PENALTY + min(rho, 1e3), str(e).splitlines()[0])
        ref = None
        if pb.reference_method == 3 and self.references:
            ref = reference_error(pb.plant, obs, ctrl, self.references,
                                  exact=self.references is pb.references)
            if self.ref_offset is not None and not ref.exact:
                de_lo, de_hi, du_lo, du_hi = self.ref_offset
                ref = replace(ref, e_lo=ref.e_lo + de_lo, e_hi=np.maximum(ref.e_hi + de_hi, ref.e_lo + de_lo),
                              u_lo=ref.u_lo + du_lo, u_hi=max(ref.u_hi + du_hi, ref.u_lo + du_lo))
        return LoopData(True, 0.0, "", Kw, Kv, cl.n_error, ref)

    def _evaluate(self, values, key):
        pb = self.problem
        ld = self.loop_data(values, key)
        if not ld.ok:
            return Evaluation(values, False, False, ld.merit, reason=ld.reason)
        Kw, Kv, ne, ref = ld.Kw, ld.Kv, ld.ne, ld.ref
        ref_norm = ref.norm if ref is not None else 0.0
        ref_u = ref.u_bound if ref is not None else 0.0
        ce = 2.0 * np.concatenate([Kw[:ne].sum(axis=0), Kv[:ne].sum(axis=0)])
        cu = np.concatenate([Kw[ne], Kv[ne]])
        room = pb.u_max - pb.u_ff - ref_u
        rhs = room - U_MARGIN * pb.u_max
        if self.alpha_fixed is not None:
            alpha = self.alpha_fixed
            ru = float(cu @ alpha)
            if ru <= rhs:
                re = float(ce @ alpha) + ref_norm
                return Evaluation(values, True, True, re, re, alpha, ru, room, None, "", Kw, Kv, ref)
            viol = (ru - rhs) / max(pb.u_max, 1.0)
            return Evaluation(values, True, False, PENALTY + viol, None, alpha, ru, room, ru,
                              "R_u outside U_p", Kw, Kv, ref)
        alpha, val = pb.polytope.minimize(ce, cu, rhs) if rhs > 0 else (None, None)
        if alpha is not None:
            re = val + ref_norm
            return Evaluation(values, True, True, re, re, alpha, float(cu @ alpha), room, None, "", Kw, Kv, ref)
        amin, umin = pb.polytope.minimize(cu)
        viol = (umin - rhs) / max(pb.u_max, 1.0)
        return Evaluation(values, True, False, PENALTY + viol, None, None, None, room, umin,
                          "R_u outside U_p", Kw, Kv, ref)


# ====================================================================== outer search
def _search(evaluator, space, seeds, search_cfg, rng_seed, global_stage=True):
    """Sobol multistart + bounded Nelder-Mead over the unit box; returns the best Evaluation.

    Without ``global_stage`` only the seeds are refined (used when re-searching after the
    reference windows were extended).
    """
    d = space.dim
    if d == 0:
        ev = evaluator(space.full())
        return ev
    cfg = {**DEFAULT_CONFIG["search"], **(search_cfg or {})}
    pts = [space.to_unit(s) for s in seeds]
    if global_stage or not pts:
        from scipy.stats import qmc
        sob = qmc.Sobol(d, scramble=True, seed=int(rng_seed))
        pts += list(sob.random_base2(int(cfg["sobol_log2"])))
    evals = []
    for u in pts:
        ev = evaluator(space.from_unit(u))
        evals.append((ev.merit, tuple(np.round(u, 12)), ev))
    evals.sort(key=lambda t: t[0])
    starts = []
    for merit, u, ev in evals:
        if all(np.max(np.abs(np.asarray(u) - np.asarray(s))) > 0.05 for s in starts):
            starts.append(u)
        if len(starts) >= int(cfg["local_starts"]):
            break
    best = evals[0][2]

    def f(u):
        ev = evaluator(space.from_unit(u))
        return ev.merit

    maxfev = int(cfg["local_maxfev"]) * max(d, 1)
    for s in starts:
        x0 = np.asarray(s, float)
        step = 0.05
        simplex = [x0]
        for i in range(d):
            x = x0.copy()
            x[i] = x[i] + step if x[i] + step <= 1.0 else x[i] - step
            simplex.append(x)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            res = minimize(f, x0, method="Nelder-Mead", bounds=[(0.0, 1.0)] * d,
                           options={"initial_simplex": np.array(simplex), "maxfev": maxfev,
                                    "xatol": 1e-4, "fatol": 1e-7})
        ev = evaluator(space.from_unit(res.x))
        if ev.merit < best.merit:
            best = ev
    # the best point ever evaluated (Nelder-Mead's final point need not be it)
    for ev in evaluator.cache.values():
        if ev.merit < best.merit:
            best = ev
    return best


# ====================================================================== results
@dataclass
class JointResult:
    """Synthesis / re-identification result of one joint (JSON: :meth:`as_dict`)."""

    name: str
    mode: str
    observer: str
    controller: str
    params: dict
    free: tuple
    alpha_w: np.ndarray
    alpha_v: np.ndarray
    c_w: np.ndarray
    c_v: np.ndarray
    re_norm: float
    re_radius: np.ndarray
    re_center: np.ndarray
    re_norm_disturbance: float
    ru: tuple
    ru_radius: float
    u_max: float
    u_ff: float
    reference: dict
    test_cases: int
    horizon: int
    conformant: bool
    violations: int
    worst_margin: float
    soundness_inflation: float
    spectral_radius: float
    evaluations: int = 0
    seconds: float = 0.0
    eso_input: str = "previous"
    notes: list = field(default_factory=list)
    extra: dict = field(default_factory=dict)
    separate: object = None

    @property
    def ru_inside(self):
        return bool(-self.u_max <= self.ru[0] and self.ru[1] <= self.u_max)

    def gains(self):
        """The model file's ``gains`` entry (also what the controller/observer nodes read)."""
        g = {"observer": self.observer, "controller": self.controller}
        for n in PARAMS[self.observer]:
            g[n] = float(self.params[n])
        g["eps"] = float(self.params["eps"])
        if self.observer == "eso":
            g["eso_input"] = self.eso_input
        g.update(re_norm=float(self.re_norm), re_radius=[float(x) for x in self.re_radius],
                 ru=[float(self.ru[0]), float(self.ru[1])], u_max=float(self.u_max), u_ff=float(self.u_ff),
                 mode=self.mode, reference_method=int(self.reference.get("method", 3)))
        return g

    def as_dict(self):
        d = {"re_norm": float(self.re_norm), "re_radius": [float(x) for x in self.re_radius],
             "re_center": [float(x) for x in self.re_center],
             "re_norm_disturbance": float(self.re_norm_disturbance),
             "ru": [float(self.ru[0]), float(self.ru[1])], "ru_radius": float(self.ru_radius),
             "u_max": float(self.u_max), "u_ff": float(self.u_ff), "ru_inside_up": self.ru_inside,
             "gains": self.gains(), "mode": self.mode, "free": list(self.free),
             "alpha_w": [float(x) for x in self.alpha_w], "alpha_v": [float(x) for x in self.alpha_v],
             "c_w": [float(x) for x in self.c_w], "c_v": [float(x) for x in self.c_v],
             "test_cases": int(self.test_cases), "horizon": int(self.horizon),
             "conformant": bool(self.conformant), "violations": int(self.violations),
             "worst_margin": float(self.worst_margin),
             "soundness_inflation": float(self.soundness_inflation),
             "spectral_radius": float(self.spectral_radius), "reference_error": self.reference,
             "evaluations": int(self.evaluations), "seconds": round(float(self.seconds), 4)}
        if self.notes:
            d["notes"] = list(self.notes)
        d.update(self.extra)
        return d


def _finalize(problem, space, values, alpha, mode, evaluations=0, t0=None, notes=(), check=True):
    """Make the sets sound in floating point, compute the final R_e, R_u, check conformance."""
    from ..systems.closedloop import analyze
    pb = problem
    pw = pb.plant.Gw.shape[1]
    n, ny = pb.plant.A.shape[0], pb.plant.C.shape[0]
    c_w, c_v = np.zeros(n), np.zeros(ny)
    aw, av = np.array(alpha[:pw], float), np.array(alpha[pw:], float)
    aw, av, bump = cf.make_sound(pb.plant, pb.thm, pb.devs, c_w, c_v, aw, av)
    obs, ctrl = space.build(values)
    cl = close_loop(pb.plant, obs, ctrl)
    an = analyze(cl, aw, av, u_ff=0.0)
    if not an.stable:
        raise InfeasibleError(f"joint {pb.name}: the chosen closed loop is not stable ({an.stability.message})")
    ref_obj = None
    refd = {"method": pb.reference_method}
    if pb.references:
        ref_obj = reference_error(pb.plant, obs, ctrl, pb.references)
        refd.update(ref_obj.as_dict())
        refd["source"] = f"{REFERENCE_TOPIC} ({ref_obj.ticks} ticks in {ref_obj.stretches} stretches)"
    else:
        refd.update(zero_reference_error().as_dict())
        refd["source"] = (f"none: no {REFERENCE_TOPIC} in the bags; taken as zero (Appendix B: the "
                          "feedforward qdd_d through the double integrator reproduces the reference)")
    r_u = float(an.ru[1])
    re_rad = np.asarray(an.re_radius, float)
    center = np.zeros_like(re_rad)
    lo_u, hi_u = -r_u - pb.u_ff, r_u + pb.u_ff
    if pb.reference_method == 3 and ref_obj is not None:
        re_rad = re_rad + 0.5 * (ref_obj.e_hi - ref_obj.e_lo)
        center = 0.5 * (ref_obj.e_hi + ref_obj.e_lo)
        lo_u, hi_u = lo_u + ref_obj.u_lo, hi_u + ref_obj.u_hi
    elif pb.reference_method == 2 and ref_obj is not None:
        star = (lo_u + ref_obj.u_lo, hi_u + ref_obj.u_hi)
        refd["ru_star"] = [float(star[0]), float(star[1])]
        refd["ru_star_inside_up"] = bool(-pb.u_max <= star[0] and star[1] <= pb.u_max)
        refd["re_star_norm"] = float(an.re_norm + ref_obj.norm)
    elif pb.reference_method == 1:
        refd["note"] = ("the controller must track y_cl,ref = y_ref + y_e,ref (Appendix B, method 1); "
                        "R_e is relative to y_cl,ref")
    re_norm = float(2.0 * re_rad.sum())
    res_check = None
    if check:
        xi = cf.xi_of(c_w, c_v, aw, av)
        res_check = cf.check(pb.plant, pb.thm, pb.estimator, xi, pb.y, pb.u, pb.segments, pb.horizon)
    return JointResult(
        pb.name, mode, space.observer, space.controller, dict(values), space.free, aw, av, c_w, c_v,
        re_norm, re_rad, center, float(an.re_norm), (float(lo_u), float(hi_u)), r_u, pb.u_max, pb.u_ff,
        refd, pb.test_cases, pb.horizon,
        bool(res_check.violations == 0) if res_check else True,
        int(res_check.violations) if res_check else 0,
        float(res_check.worst_margin) if res_check else float("nan"), float(bump),
        float(an.stability.spectral_radius), evaluations,
        0.0 if t0 is None else time.perf_counter() - t0, space.eso_input, list(notes))


def _optimise(pb, space, alpha, seeds, search, seed, loops=None, rounds=3, tol=0.01):
    """Search ``theta``; with references (method 3) on windows first, verified on every tick.

    During the search the reference error is computed on :attr:`JointProblem.ref_windows`
    (fast); the best point is then re-evaluated with the exact reference error (inner LP
    included). If that is infeasible or its ``||R*_e||`` exceeds the windowed value by more
    than ``tol`` (relative), windows around the ticks where the exact extremes occur are
    added, the windowed bounds are shifted by the remaining difference at the best point, and
    the local search is repeated from there (at most ``rounds`` times, then on every tick).
    A search that finds nothing feasible on the windows is repeated on every tick before
    infeasibility is reported. Returns (exact Evaluation, evaluator).
    """
    loops = {} if loops is None else loops
    rho = _max_rho(search)
    exact_refs = pb.reference_method == 3 and bool(pb.references)
    windows = pb.ref_windows if exact_refs else None
    first_seeds = list(seeds)
    seeds = list(seeds)
    offset = None
    total = 0
    rnd = 0
    while True:
        use = windows if (exact_refs and rnd < rounds) else None
        key = ("w", id(use), rnd) if use is not None else "exact"
        ev = Evaluator(pb, space, alpha, rho, loops.setdefault(key, {}), references=use, ref_offset=offset)
        cfg = search if (use is not None or not exact_refs) else {**(search or {}), "local_starts": 1}
        best = _search(ev, space, seeds, cfg, seed, global_stage=(rnd == 0))
        total += ev.count
        if use is None:
            ev.count = total
            return best, ev
        exact = Evaluator(pb, space, alpha, 1.0, loops.setdefault("exact", {}))
        if not best.feasible:
            # windows can over-estimate (start transients of slow loops): check the best
            # candidates on every tick before searching there
            cands = sorted((e for e in ev.cache.values() if e.stable), key=lambda e: e.merit)[:8]
            exs = [exact(e.values) for e in cands]
            total += len(exs)
            ok = [e for e in exs if e.feasible]
            if not ok:                       # search on every tick, from the best candidates
                rnd = rounds
                seeds = [e.values for e in cands[:3]] + first_seeds
                continue
            best = ex = min(ok, key=lambda e: e.merit)
            refine = True                    # the windows were wrong here: refine with corrections
        else:
            ex = exact(best.values)
            total += 1
            refine = False
        if not refine and ex.feasible and ex.merit <= best.merit + tol * max(best.merit, 1e-12):
            ev.count = total
            return ex, ev
        ref = exact.loop_data(best.values).ref
        new = []
        for si, t in (ref.argext if ref is not None else ()):
            r = pb.references[si]
            lo, hi = max(0, t - 450), min(len(r), t + 101)
            new.append(r.slice(lo, hi, 150 if lo > 0 else 0))
        windows = tuple(windows) + tuple(new)
        if ref is not None:
            obs, ctrl = space.build(best.values)
            approx = reference_error(pb.plant, obs, ctrl, windows, exact=False)
            offset = (ref.e_lo - approx.e_lo, ref.e_hi - approx.e_hi, ref.u_lo - approx.u_lo, ref.u_hi - approx.u_hi)
        seeds = [best.values]
        rnd += 1


def _max_rho(search):
    return float({**DEFAULT_CONFIG["search"], **(search or {})}["max_spectral_radius"])


def _infeasible(problem, space, best, evaluator, what):
    pb = problem
    if best is None or not best.stable:
        lim = (f" with spectral radius below {evaluator.max_rho:g}" if evaluator.max_rho < 1.0 else "")
        raise InfeasibleError(f"joint {pb.name}: {what}: no stable closed loop{lim} in the search box "
                              f"({evaluator.count} parameter vectors tried)")
    ref = best.ref.u_bound if best.ref is not None else 0.0
    room = pb.u_max - pb.u_ff - ref
    if room <= 0:
        raise InfeasibleError(f"joint {pb.name}: {what}: U_ff (+-{pb.u_ff:g}) and the reference error "
                              f"({ref:.4g}) alone exceed U_p = [-{pb.u_max:g}, {pb.u_max:g}]")
    if space.dim == 0:
        raise InfeasibleError(
            f"joint {pb.name}: {what}: the controller cannot keep R_u inside U_p with sets conformant to "
            f"these data: smallest achievable R_u radius {best.min_ru_radius:.4g} > u_max {pb.u_max:g} - u_ff "
            f"{pb.u_ff:g}" + (f" - reference error {ref:.4g}" if ref else "") + f" = {room:.4g} "
            f"({_fmt(space, best.values)}); synthesise again with these data")
    raise InfeasibleError(
        f"joint {pb.name}: {what}: no gains keep R_u inside U_p: smallest achievable R_u radius "
        f"{best.min_ru_radius:.4g} > u_max {pb.u_max:g} - u_ff {pb.u_ff:g}"
        + (f" - reference error {ref:.4g}" if ref else "") + f" = {room:.4g} "
        f"(best of {evaluator.count} parameter vectors, at {_fmt(space, best.values)})")


def _fmt(space, values):
    return ", ".join(f"{n}={values[n]:.4g}" for n in (space.free or PARAMS[space.observer]))


def separate(problem, space, search=None, seeds=(), seed=0, sets=None, loops=None):
    """The paper's separate approach: identify (min ||W|| + ||V||), then search ``theta``.

    Returns
    -------
    JointResult
        ``mode="separate"``; ``extra["identified"]`` has the identification's cost.

    Raises
    ------
    InfeasibleError
        If no ``theta`` keeps R_u inside U_p with the identified sets.
    """
    t0 = time.perf_counter()
    pb = problem
    if sets is None:
        sets = cf.identify(pb.plant, pb.thm, pb.devs, centers="zero", alpha_lower=pb.alpha_lower,
                           horizon=pb.horizon)
    alpha = np.concatenate([sets.alpha_w, sets.alpha_v])
    best, ev = _optimise(pb, space, alpha, [space.values, *seeds], search, seed, loops)
    if not best.feasible:
        # report the binding constraint with the identified sets
        if best.stable:
            best.min_ru_radius = best.ru_radius
        _infeasible(pb, space, best, ev, "separate approach")
    res = _finalize(pb, space, best.values, alpha, "separate", ev.count, t0)
    res.extra["identification_cost"] = float(sets.cost)
    return res


def combined(problem, space, search=None, seeds=(), seed=0, separate_result=None, loops=None):
    """Combined synthesis and identification (paper eq. 10) for one joint.

    The search is seeded with the start values, ``seeds`` (dicts of parameter values) and the
    separate approach's optimum (``separate_result``), so ``||R_e||`` of the result is never
    larger than the separate approach's: if the combined search ends above it (possible only
    through the floating-point clean-up), the separate optimum is returned as the combined one.

    Raises
    ------
    InfeasibleError
        Naming the binding constraint (R_u inside U_p, or stability).
    """
    t0 = time.perf_counter()
    pb = problem
    seeds = [space.values, *seeds]
    if separate_result is not None:
        seeds.append({**space.values, **{n: separate_result.params[n] for n in space.free}})
    best, ev = _optimise(pb, space, None, seeds, search, seed, loops)
    if not best.feasible:
        _infeasible(pb, space, best, ev, "combined synthesis")
    res = _finalize(pb, space, best.values, best.alpha, "combined", ev.count, t0)
    if separate_result is not None and separate_result.re_norm < res.re_norm:
        notes = [f"the combined search ended at ||R_e|| = {res.re_norm:.6g}, above the separate optimum; "
                 "the separate optimum (feasible for eq. 10) is returned"]
        sep_alpha = np.concatenate([separate_result.alpha_w, separate_result.alpha_v])
        res = _finalize(pb, space, separate_result.params, sep_alpha, "combined", ev.count, t0, notes)
    return res


def reidentify(problem, gains, dt=None):
    """Controller fixed (``gains`` of a model file): only the sets are re-identified.

    Solves the inner problem of eq. 10 at the fixed parameters: min ||R_e|| over conformant
    ``alpha`` with R_u inside U_p (paper Sec. III-D step 3).
    """
    t0 = time.perf_counter()
    pb = problem
    space = SearchSpace.from_gains(gains, dt if dt is not None else pb.plant.dt)
    ev = Evaluator(pb, space)
    best = ev(space.values)
    if not best.feasible:
        _infeasible(pb, space, best, ev, "re-identification with the fixed controller")
    return _finalize(pb, space, best.values, best.alpha, "reidentify", ev.count, t0)


def lqg_baseline(problem, alpha_w, alpha_v, r_values, Q=None, form="predictor"):
    """Paper Table IV: LQG (Kalman filter + LQR on the 4-state robot model) for each ``r``.

    The closed loops are evaluated with the given (conformant) sets, as the paper does with
    the sets of its Table II. Per ``r``: ``re_norm`` (including the reference error of method
    3 when the bags have references), ``ru`` (R_u (+) U_ff (+) U_e,ff), ``ru_inside_up``, and
    ``re_norm_best_sets``: ||R_e|| with the sets re-chosen for this controller (the inner LP
    without the input constraint).
    """
    from ..systems.closedloop import analyze
    from ..systems.controllers import lqg
    from ..systems.plant import lwa4p_robot_model
    pb = problem
    model = lwa4p_robot_model(dt=pb.plant.dt)
    rows = []
    for r in r_values:
        row = {"r": float(r)}
        try:
            obs, ctrl = lqg(model, float(r), alpha_w, alpha_v, Q=Q, form=form)
            cl = close_loop(pb.plant, obs, ctrl)
            an = analyze(cl, alpha_w, alpha_v, u_ff=0.0)
        except (ValueError, np.linalg.LinAlgError) as e:
            row.update(error=str(e).splitlines()[0])
            rows.append(row)
            continue
        if not an.stable:
            row.update(stable=False, error=an.stability.message)
            rows.append(row)
            continue
        ref = reference_error(pb.plant, obs, ctrl, pb.references) if pb.references else zero_reference_error()
        re = float(an.re_norm + (ref.norm if pb.reference_method == 3 else 0.0))
        lo = -an.ru[1] - pb.u_ff + (ref.u_lo if pb.reference_method == 3 else 0.0)
        hi = an.ru[1] + pb.u_ff + (ref.u_hi if pb.reference_method == 3 else 0.0)
        Kw, Kv = radius_coefficients(cl)
        ce = 2.0 * np.concatenate([Kw[:2].sum(axis=0), Kv[:2].sum(axis=0)])
        _, best = pb.polytope.minimize(ce)
        row.update(stable=True, re_norm=re, re_radius=[float(x) for x in an.re_radius],
                   ru=[float(lo), float(hi)], ru_inside_up=bool(-pb.u_max <= lo and hi <= pb.u_max),
                   re_norm_best_sets=float(best + (ref.norm if pb.reference_method == 3 else 0.0)),
                   spectral_radius=float(an.stability.spectral_radius))
        rows.append(row)
    return rows


# ====================================================================== several joints
def synthesize(problems, space, mode="combined", search=None, seed=0, seeds=None, gains=None,
               lqg_r=(), with_separate=True):
    """Run ``mode`` for every :class:`JointProblem`; returns ``{joint: JointResult}``.

    ``mode="combined"`` also runs the separate approach (the paper's baseline, and a seed)
    unless ``with_separate`` is false; its result is in ``result.extra["separate"]``.
    ``seeds``: ``{joint: [values dict, ...]}``; ``gains``: ``{joint: gains}`` for ``reidentify``.
    ``lqg_r``: LQG baseline with the result's sets, in ``result.extra["lqg"]``.
    """
    out = {}
    for pb in problems:
        js = (seeds or {}).get(pb.name, [])
        if mode == "reidentify":
            g = (gains or {}).get(pb.name)
            if not g:
                raise ReachsetError(f"joint {pb.name}: the model has no gains to keep fixed")
            res = reidentify(pb, g)
        elif mode == "separate":
            res = separate(pb, space, search, js, seed)
        elif mode == "combined":
            sep, sep_err, loops = None, None, {}
            if with_separate:
                try:
                    sep = separate(pb, space, search, js, seed, loops=loops)
                except InfeasibleError as e:
                    sep_err = str(e)
            res = combined(pb, space, search, js, seed, sep, loops=loops)
            if with_separate:
                res.extra["separate"] = sep.as_dict() if sep is not None else {"error": sep_err}
                res.separate = sep
        else:
            raise ReachsetError(f"unknown mode {mode!r} (combined, separate or reidentify)")
        if lqg_r:
            res.extra["lqg"] = lqg_baseline(pb, res.alpha_w, res.alpha_v, lqg_r)
        out[pb.name] = res
    return out


def problems_from_series(series, plant, estimator, horizon, u_max, u_ff, references=None,
                         reference_method=3, alpha_lower=None, thm=None):
    """:class:`JointProblem` per joint of ``{name: JointSeries}``; ``u_max``: float or dict."""
    thm = thm or cf.Theorem1.build(plant, horizon)
    out = []
    for name, s in series.items():
        um = u_max[name] if isinstance(u_max, dict) else u_max
        refs = (references or {}).get(name, ())
        out.append(JointProblem.prepare(name, plant, estimator, s.y, s.u, s.segments, horizon, um, u_ff,
                                        thm, refs, reference_method, alpha_lower, s.stamps))
    return out


def iterate(record, series, space, iterations=2, final_reidentify=True, plant=None, estimator=None,
            horizon=125, u_max=26.0, u_ff=2.0, search=None, seed=0, reference_method=3, dt=0.004):
    """The paper's iterative procedure (Sec. III-D, Fig. 4).

    1. synthesise (combined) on the initial data ``series``;
    2. ``record(gains)`` with the new gains (``{joint: gains}``) returns new data: a list of bag
       paths, ``{joint: JointSeries}`` or ``({joint: JointSeries}, {joint: [Reference]})`` (e.g.
       :func:`recordings_series` of :func:`simulate_arm_recordings`; the simulator or the node
       suite drives the robot);
    3. repeat 1-2 ``iterations`` times in total, each synthesis seeded with the previous gains;
       then, if ``final_reidentify``, record once more and re-identify the sets with the
       controller fixed.

    Returns
    -------
    list of dict
        One ``{"step": ..., "results": {joint: JointResult}}`` per synthesis/re-identification.
    """
    from ..conformance.estimators import Estimator
    from ..systems.plant import lwa4p_joint_plant
    plant = plant or lwa4p_joint_plant(dt=dt)
    estimator = estimator or Estimator("fd")
    thm = cf.Theorem1.build(plant, horizon)
    history = []
    data, refs = _as_series(series, dt)
    prev = None
    if not isinstance(series, (dict, tuple)) and not data:
        raise ReachsetError("iterate: no data")
    for it in range(int(iterations)):
        probs = problems_from_series(data, plant, estimator, horizon, u_max, u_ff, refs, reference_method,
                                     thm=thm)
        seeds = {n: [r.params] for n, r in prev.items()} if prev else None
        res = synthesize(probs, space, "combined", search, seed, seeds, with_separate=(it == 0))
        history.append({"step": f"synthesis {it + 1}", "results": res})
        prev = res
        if it + 1 < iterations or final_reidentify:
            data, refs = _as_series(record({n: r.gains() for n, r in res.items()}), dt)
    if final_reidentify and prev:
        probs = problems_from_series(data, plant, estimator, horizon, u_max, u_ff, refs, reference_method,
                                     thm=thm)
        res = synthesize(probs, space, "reidentify", gains={n: r.gains() for n, r in prev.items()})
        history.append({"step": "re-identification", "results": res})
    return history


def _as_series(data, dt):
    """``(series, references)`` of bag paths, ``{joint: JointSeries}`` or ``(series, references)``."""
    if isinstance(data, dict):
        return data, {}
    if isinstance(data, tuple) and len(data) == 2 and isinstance(data[0], dict):
        return data[0], dict(data[1] or {})
    from ..bags import read_joint_series
    paths = [Path(p) for p in data]
    series, _ = read_joint_series(paths, None, dt)
    return series, read_references(paths, list(series), dt)


# ====================================================================== simulated recordings
@dataclass(frozen=True)
class Scenario:
    """A simulated joint for tests, benchmarks and the docs' tables (deterministic per seed).

    Reference: a sum of three sines scaled to ``|qd_d| <= qd_max``, ``|qdd_d| <= qdd_max``,
    ``|q_d| <= q_max``. Process disturbance ``w = G'_W [w1, w2]``: ``w1`` i.i.d. uniform in
    ``[-a1, a1]`` (rad/s); ``w2`` (rad/s^2) an i.i.d. uniform part in ``[-a2, a2]`` plus a
    smooth model error along the reference (viscous ``c_visc qd_d``, Coulomb
    ``c_coul tanh(qd_d / 0.05)``, gravity ``c_grav cos(q_d)``), the kind of error a feedback
    linearization leaves. Measurement noise uniform in ``[-av, av]`` rad.
    """

    a1: float = 0.002
    a2: float = 0.5
    c_visc: float = 0.5
    c_coul: float = 0.3
    c_grav: float = 0.5
    av: float = 3.5e-5
    qd_max: float = 0.7
    qdd_max: float = 1.8
    q_max: float = 1.2

    @classmethod
    def for_joint(cls, index):
        """Joint-dependent magnitudes (wrist joints 5-6 worse, as in the paper's data)."""
        i = int(index)
        scale = 1.0 + 0.25 * i + (1.5 if i >= 4 else 0.0)
        return cls(a1=0.002, a2=0.5 * scale, c_visc=0.4 * scale, c_coul=0.3 * scale, c_grav=0.4 * scale)


@dataclass(frozen=True)
class Recording:
    """A simulated recording of one joint (all arrays of length T)."""

    stamps: np.ndarray
    y: np.ndarray
    u: np.ndarray
    x_hat: np.ndarray
    estimate_names: tuple
    q_d: np.ndarray
    qd_d: np.ndarray
    qdd_d: np.ndarray


def _reference(T, dt, rng, sc):
    t = np.arange(T) * dt
    f = rng.uniform(0.05, 0.35, 3) * 2 * np.pi
    ph = rng.uniform(0, 2 * np.pi, 3)
    a = rng.uniform(0.5, 1.0, 3)
    q = (a[None, :] * np.sin(f[None, :] * t[:, None] + ph[None, :])).sum(axis=1)
    qd = (a * f)[None, :] * np.cos(f[None, :] * t[:, None] + ph[None, :])
    qdd = -(a * f * f)[None, :] * np.sin(f[None, :] * t[:, None] + ph[None, :])
    qd, qdd = qd.sum(axis=1), qdd.sum(axis=1)
    s = min(sc.q_max / max(np.abs(q).max(), 1e-9), sc.qd_max / max(np.abs(qd).max(), 1e-9),
            sc.qdd_max / max(np.abs(qdd).max(), 1e-9))
    return s * q, s * qd, s * qdd


DEFAULT_GAINS = {"observer": "hg", "controller": "static", "omega": 20.0, "zeta": 1.0, "h1": 15.0,
                 "h2": 30.0, "eps": 0.01}


def simulate_recordings(joints, ticks, seed=0, gains=None, scenarios=None, plant=None, t0=1_700_000_000_000_000_000):
    """Simulated closed-loop recordings of independent joints (the per-joint plant of App. A).

    Parameters
    ----------
    joints : sequence of str
    ticks : int
    seed : int
        Everything (references, disturbances) is a deterministic function of the seed and the
        joint's position in ``joints``.
    gains : dict, optional
        ``{joint: gains}`` (model-file gains, :func:`components_from_gains`) or one gains dict
        for all joints; default HG (15, 30, eps 0.01) + static feedback (omega 20, zeta 1).
    scenarios : dict, optional
        ``{joint: Scenario}``; default :meth:`Scenario.for_joint`.

    Returns
    -------
    dict name -> Recording
    """
    from ..systems.plant import lwa4p_joint_plant
    plant = plant or lwa4p_joint_plant()
    dt = plant.dt
    out = {}
    for i, name in enumerate(joints):
        g = gains.get(name, DEFAULT_GAINS) if isinstance(gains, dict) and "observer" not in gains else (
            gains or DEFAULT_GAINS)
        obs, ctrl = components_from_gains(g, dt)
        sc = (scenarios or {}).get(name) or Scenario.for_joint(i)
        rng = np.random.default_rng([int(seed), i])
        q_d, qd_d, qdd_d = _reference(ticks, dt, rng, sc)
        w1 = rng.uniform(-sc.a1, sc.a1, ticks)
        w2 = (rng.uniform(-sc.a2, sc.a2, ticks) + sc.c_visc * qd_d + sc.c_coul * np.tanh(qd_d / 0.05)
              + sc.c_grav * np.cos(q_d))
        w = np.column_stack([w1, w2]) @ plant.Gw.T
        v = rng.uniform(-sc.av, sc.av, (ticks, 1)) @ plant.Gv.T
        sim = simulate_closed_loop(plant, obs, ctrl, q_d, qd_d, qdd_d, w, v)
        stamps = t0 + np.arange(ticks, dtype=np.int64) * int(round(dt * 1e9))
        out[name] = Recording(stamps, sim["y"][:, 0], sim["u"][:, 0], sim["x_hat"], obs.estimate_names,
                              q_d, qd_d, qdd_d)
    return out


def recordings_series(recs, dt=0.004):
    """``({joint: JointSeries}, {joint: [Reference]})`` of :func:`simulate_recordings` output."""
    from ..bags import JointSeries
    series, refs = {}, {}
    for name, r in recs.items():
        n = len(r.stamps)
        series[name] = JointSeries(name, r.stamps, r.y, r.u, ((0, n),), dt)
        refs[name] = [Reference(r.stamps, r.q_d, r.qd_d, r.qdd_d)]
    return series, refs


def write_recordings(path, recs, reference=True, estimate=True, storage="mcap"):
    """Write :func:`simulate_recordings` output as a rosbag2 with the topics of INTERFACES.md.

    ``/joint_states`` (position = y), ``/plant_input`` (u_p), and optionally ``/reference``
    (q_d, qd_d, qdd_d) and ``/observer/estimate`` (q_hat, qd_hat, d_hat).
    """
    from .. import bags
    ts = bags.typestore()
    JR = ts.types["reachset_msgs/msg/JointReference"]
    JE = ts.types["reachset_msgs/msg/JointEstimate"]
    names = list(recs)
    first = recs[names[0]]
    T = len(first.stamps)
    Y = np.column_stack([recs[n].y for n in names])
    U = np.column_stack([recs[n].u for n in names])

    def est(n, k, nm):
        r = recs[n]
        return float(r.x_hat[k, r.estimate_names.index(nm)]) if nm in r.estimate_names else 0.0

    with bags.BagWriter(path, storage=storage) as w:
        for k in range(T):
            st = int(first.stamps[k])
            w.write(bags.JOINT_STATES, bags.joint_state(st, names, Y[k]), st + 200_000)
            w.write(bags.PLANT_INPUT, bags.plant_input(st, names, U[k]), st + 500_000)
            if reference:
                w.write(REFERENCE_TOPIC, JR(header=bags.header(st), name=names,
                                            position=np.array([recs[n].q_d[k] for n in names]),
                                            velocity=np.array([recs[n].qd_d[k] for n in names]),
                                            acceleration=np.array([recs[n].qdd_d[k] for n in names])),
                        st + 100_000, "reachset_msgs/msg/JointReference")
            if estimate:
                w.write(ESTIMATE_TOPIC, JE(header=bags.header(st), name=names,
                                           position=np.array([est(n, k, "q") for n in names]),
                                           velocity=np.array([est(n, k, "qd") for n in names]),
                                           disturbance=np.array([est(n, k, "d") for n in names])),
                        st + 400_000, "reachset_msgs/msg/JointEstimate")
    return Path(path)


def simulate_arm_recordings(seconds, gains=None, seed=0, sim_config=None, reference_config=None):
    """Recordings of the project's simulated LWA-4P (:mod:`reachset_ros.sim.simulator`) in closed loop.

    The nodes' code path without ROS: per tick the measurement ``y[k] = q[k-1]`` (one sample
    of output delay) goes through each joint's observer and control law
    (:func:`reachset_ros.systems.closedloop.closed_loop_tick`, ``u_ff = qdd_d``), the torque is the
    feedback linearization ``tau = M(q_hat) u_p + psi(q_hat, qd_hat)`` of the *nominal* model
    (the controller node's law) and the simulated arm (the "true" robot with model error,
    friction, quantization and noise; :meth:`SimConfig.realistic`) applies it with one sample
    of input delay. The references are the project's random point-to-point trajectories
    (:class:`reachset_ros.sim.reference.ReferenceGenerator`, |qdd_d| <= 2).

    Parameters
    ----------
    seconds : float
    gains : dict, optional
        ``{joint: gains}`` or one gains dict for all joints (default :data:`DEFAULT_GAINS`).
    seed : int
        Seeds the reference, the measurement noise and the model error.

    Returns
    -------
    dict name -> Recording (every joint of the arm)
    """
    from ..sim import reference as refm
    from .. import robot as rb
    from ..sim import simulator as simm
    from ..systems.closedloop import closed_loop_tick
    cfg = sim_config or simm.SimConfig.realistic(seed=seed)
    arm = simm.SimulatedArm(cfg, seed=seed)
    names = tuple(arm.joint_names)
    n = len(names)
    dt = cfg.dt
    gen = refm.ReferenceGenerator(reference_config, seed=seed)
    _, Qd, QDd, QDDd = gen.trajectory(seconds, dt)
    T = len(Qd)
    model = cfg.robot
    data = rb.create_data(model)
    comps, states, xnames = [], [], []
    m = arm.reset(Qd[0])
    for j, nm in enumerate(names):
        g = gains.get(nm, DEFAULT_GAINS) if isinstance(gains, dict) and "observer" not in gains else (
            gains or DEFAULT_GAINS)
        obs, ctrl = components_from_gains(g, dt)
        xr0 = _x_ref(obs.estimate_names, Qd[:1, j], QDd[:1, j], QDDd[:1, j])[0]
        comps.append((obs, ctrl))
        states.append(obs.initial_state(xr0, [m.q_measured[j]], [QDDd[0, j]]))
        xnames.append(obs.estimate_names)
    Y, U = np.empty((T, n)), np.empty((T, n))
    XH = [np.empty((T, len(xn))) for xn in xnames]
    stamps = np.empty(T, np.int64)
    qh, qdh, u = np.zeros(n), np.zeros(n), np.zeros(n)
    for k in range(T):
        stamps[k] = m.stamp_ns
        y = m.q_measured
        for j in range(n):
            obs, ctrl = comps[j]
            xr = np.empty(len(xnames[j]))
            for i, nm in enumerate(xnames[j]):
                xr[i] = {"q": Qd[k, j], "qd": QDd[k, j], "d": 0.0,
                         "q_prev": Qd[max(k - 1, 0), j], "u_prev": QDDd[max(k - 1, 0), j]}[nm]
            uj, xh, states[j] = closed_loop_tick(states[j], ctrl, [y[j]], xr, QDDd[k, j])
            u[j] = uj[0]
            XH[j][k] = xh
            qh[j] = xh[xnames[j].index("q")] if "q" in xnames[j] else y[j]
            qdh[j] = xh[xnames[j].index("qd")] if "qd" in xnames[j] else 0.0
        Y[k], U[k] = y, u
        tau = rb.feedback_linearization(model, data, qh, qdh, u)
        m = arm.step(tau)
    out = {}
    for j, nm in enumerate(names):
        out[nm] = Recording(stamps.copy(), Y[:, j].copy(), U[:, j].copy(), XH[j], xnames[j],
                            Qd[:, j].copy(), QDd[:, j].copy(), QDDd[:, j].copy())
    return out


# ====================================================================== bags in, model out
@dataclass
class BagSynthesis:
    """Everything :func:`synthesize_bags` computed (the CLI and the synthesis node use it)."""

    results: dict            # joint -> JointResult
    problems: list           # JointProblem per joint
    report: object           # bags.ReadReport
    plant: object
    plant_spec: dict
    estimator: object
    horizon: int
    space: object            # SearchSpace (None for reidentify)
    mode: str
    seed: int
    reference_method: int
    bags: tuple

    def as_dict(self):
        d = {"mode": self.mode, "joints": {n: r.as_dict() for n, r in self.results.items()},
             "data": self.report.as_dict(), "reference_method": self.reference_method, "seed": self.seed}
        if self.space is not None:
            d.update(observer=self.space.observer, controller=self.space.controller, free=list(self.space.free),
                     search_box={n: list(self.space.bounds[n]) for n in self.space.free})
        return d

    def model(self, command=""):
        """The :class:`reachset_ros.conformance.model.ConformanceModel` of the results (gains per joint)."""
        from ..conformance import model as mdl
        joints = {}
        for n, r in self.results.items():
            joints[n] = mdl.JointSets(tuple(r.alpha_w.tolist()), tuple(r.alpha_v.tolist()), tuple(r.c_w.tolist()),
                                      tuple(r.c_v.tolist()), r.test_cases, self.horizon, r.gains(),
                                      {"reference_error": r.reference, "conformant": r.conformant})
        return mdl.ConformanceModel(self.plant, self.plant_spec, self.estimator, self.horizon, joints, 0.0,
                                    mdl.provenance(self.bags, command))


def synthesize_bags(bags, joints=None, mode="combined", observer="hg", controller=None, free=None, fix=None,
                    bounds=None, u_max=None, u_ff=None, horizon=None, estimator=None, alpha_lower=None,
                    reference_method=3, eso_input="previous", seed=None, lqg_r=(), config=None, model=None,
                    dt=0.004):
    """Read bags, build the per-joint problems and run ``mode`` (what ``reachset synthesize`` does).

    Parameters
    ----------
    bags : sequence of path
    joints : list of str or None (all joints on both topics; reidentify: the model's joints)
    mode : {"combined", "separate", "reidentify"}
    observer, controller, free, fix, bounds, eso_input : the search space (:meth:`SearchSpace.from_config`)
    u_max : float, list (one per joint) or dict, optional
        Default: the gains' ``u_max`` (reidentify), else the config's per-joint value.
    u_ff, horizon, estimator, alpha_lower, reference_method, seed, lqg_r : see the CLI
    config : path of a synthesis config (default ``config/synthesis.yaml``)
    model : path of a model file (mode reidentify: its gains are kept; its plant, estimator
        and horizon are used unless given)

    Returns
    -------
    BagSynthesis
    """
    from ..conformance import model as mdl
    from ..bags import read_joint_series
    from ..conformance.estimators import Estimator
    from ..systems.plant import lwa4p_joint_plant
    cfg = load_config(config)
    bags = tuple(Path(b) for b in bags)
    if mode not in ("combined", "separate", "reidentify"):
        raise ReachsetError(f"unknown mode {mode!r} (combined, separate or reidentify)")
    if mode == "reidentify":
        if not model:
            raise ReachsetError("mode reidentify needs a model file whose gains are kept")
        base = mdl.load(model)
        plant, plant_spec = base.plant, base.plant_spec
        horizon = base.horizon if horizon is None else int(horizon)
        est = base.estimator if estimator is None else Estimator.named(estimator, base.plant)
        gains = {n: j.gains for n, j in base.joints.items()}
        names = list(base.joints) if not joints else list(joints)
        for n in names:
            if n not in base.joints:
                raise ReachsetError(f"joint {n} is not in the model {model}")
        space = None
    else:
        if model:
            raise ReachsetError("a model file is only used with mode reidentify")
        plant, plant_spec = lwa4p_joint_plant(dt=dt), {"kind": "lwa4p_joint", "dt": dt}
        horizon = 125 if horizon is None else int(horizon)
        est = Estimator.named(estimator or "fd", lwa4p_joint_plant(dt=dt))
        gains, names = None, (list(joints) if joints else None)
        space = SearchSpace.from_config(cfg, observer, controller, free, fix, bounds, eso_input, dt)
    if horizon < 0:
        raise ReachsetError("horizon must be >= 0")
    series, report = read_joint_series(list(bags), names, plant.dt)
    names = list(series)
    cf.require_horizon(series, est.history, horizon, bags)
    if mode == "reidentify":
        missing = [n for n in names if not gains.get(n)]
        if missing:
            raise ReachsetError(f"joint {missing[0]}: the model {model} has no gains to keep fixed")
    # U_p per joint
    if u_max is None:
        um = {n: float(gains[n]["u_max"]) if gains and "u_max" in gains.get(n, {}) else u_max_for(cfg, n)
              for n in names}
    elif isinstance(u_max, dict):
        um = {n: float(u_max[n]) if n in u_max else u_max_for(cfg, n) for n in names}
    else:
        vals = list(np.atleast_1d(np.asarray(u_max, float)))
        if len(vals) == 1:
            um = {n: vals[0] for n in names}
        elif len(vals) == len(names):
            um = dict(zip(names, vals))
        else:
            raise ReachsetError(f"u_max: {len(vals)} values for {len(names)} joints ({', '.join(names)})")
    for n, v in um.items():
        if not (math.isfinite(v) and v > 0):
            raise ReachsetError(f"joint {n}: u_max must be positive, got {v}")
    uff = float(cfg.get("u_ff", 2.0) if u_ff is None else u_ff)
    search = dict(cfg.get("search", {}))
    seed = int(search.get("seed", 0) if seed is None else seed)
    if seed < 0:
        raise ReachsetError(f"seed must be >= 0, got {seed}")
    refs = read_references(list(bags), names, plant.dt)
    problems = problems_from_series(series, plant, est, horizon, um, uff, refs, reference_method, alpha_lower)
    results = synthesize(problems, space, mode, search, seed, gains=gains, lqg_r=tuple(lqg_r or ()))
    return BagSynthesis(results, problems, report, plant, plant_spec, est, horizon, space, mode, seed,
                        int(reference_method), bags)
