"""Controller and observer gains of one joint as a value, and their safety check.

:class:`Gains` is the one representation of a joint's loop structure and parameters: the
synthesis searches over it (:class:`reachset_ros.synthesis.config.SearchSpace` builds its
loops through it and writes :meth:`Gains.model_dict` into the model file,
``JointSets.gains``), the model file is read back with :meth:`Gains.from_model`, and the
observer and controller nodes build their observer and control law from it
(:meth:`Gains.build`). So the loop that was certified is the loop that runs, including
which plant input the ESO is fed (``eso_input``). :func:`check_gains` checks a proposed set
of gains against the identified sets: the closed loop must be stable and its reachable
input R_u must stay inside U_p.
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass, replace

import numpy as np

from . import closedloop
from .controllers import compensated_feedback, static_feedback
from .. import defaults, guarantees
from ..errors import ReachsetError
from .observers import extended_state_observer, high_gain_observer
from .plant import lwa4p_joint_plant

__all__ = ["Gains", "check_gains", "certify", "Certificate", "max_certified_inflation", "recorded_u_e_ff", "NO_U_E_FF",
           "recorded_for_other_gains", "is_model_gains",
           "certified_inflation", "model_limits",
           "DEFAULTS", "FAMILY_PARAMS", "ESO_INPUTS", "GAIN_KEYS", "TYPE_KEYS", "family_controller"]

# ---------------------------------------------------------------- the defaults of the gains
# (reachset_ros.defaults: each default once, with what it means; test/test_defaults.py checks
# the copies users edit: config/*.yaml, docs/nodes.md)
defaults.register("gains", {
    "keys": (("omega", "zeta", "h1", "h2", "l1", "l2", "l3", "eps"),
             "the numeric gain parameters, in this order: the feedback law's omega (rad/s) and zeta, the HG "
             "observer's h1, h2, the ESO's l1, l2, l3, and the observer scaling eps (s); the nodes' per-joint "
             "gain parameters and the synthesis node's gain keys"),
    "types": (("observer", "controller", "eso_input"),
              "the loop structure, one word each (one parameter per node): observer family, feedback law and "
              "the plant input the ESO is fed"),
}, owner=__name__)
defaults.register("gains.hg", {
    "controller": ("static", "the feedback law the high-gain observer is combined with: static feedback (paper "
                             "eq. staticfeedback; the HG observer estimates no disturbance)"),
    "h1": (15.0, "high-gain observer gain h1 (paper Sec. IV-A)"),
    "h2": (30.0, "high-gain observer gain h2 (paper Sec. IV-A)"),
    "eps": (0.01, "high-gain observer scaling epsilon, s (paper Sec. IV-A)"),
}, owner=__name__)
defaults.register("gains.eso", {
    "controller": ("compensated", "the feedback law the extended-state observer is combined with: disturbance-"
                                  "compensated feedback (paper eq. feedbackLaw, Sec. IV-C); the one default of "
                                  "Gains, Gains.from_dict, Gains.from_model, the synthesis and reachset analyze"),
    "l1": (57.1, "ESO gain l1 (paper Sec. IV-C, Table III axis 1)"),
    "l2": (103.3, "ESO gain l2 (paper Sec. IV-C, Table III axis 1)"),
    "l3": (18.1, "ESO gain l3 (paper Sec. IV-C, Table III axis 1)"),
    "eps": (0.01, "ESO scaling epsilon, s (paper Sec. IV-C)"),
    "eso_input": ("previous", "the plant input the ESO is fed at tick k: u_p[k-1] (reproduces the paper; "
                              "'current' feeds u_p[k], an algebraic loop); model files without it mean this"),
}, owner=__name__)
defaults.register("gains.feedback", {
    "paper": ({"omega": 20.0, "zeta": 1.0},
              "the feedback law the paper keeps fixed while it searches the observer gains (Sec. IV-C): the "
              "synthesis' start values and the simulator's recording gains"),
    "table_ii": ({"omega": 24.40, "zeta": 0.96},
                 "the static feedback law the paper synthesised for the HG observer (Sec. IV-A, Table II axis 1)"),
    "startup": ({"omega": 10.0, "zeta": 1.0},
                "the nodes' start-up feedback law: slower than the paper's, the loop that records the "
                "identification data before any synthesis (run uncertified, allow_uncertified)"),
}, owner=__name__)
_STARTUP = {"observer": "hg", **defaults.get("gains.feedback.startup"), **defaults.table("gains.hg"),
            **{k: defaults.get(f"gains.eso.{k}") for k in ("l1", "l2", "l3", "eso_input")}}
defaults.register("gains", {
    "startup": ({k: _STARTUP[k] for k in ("observer", "controller", *defaults.get("gains.keys"), "eso_input")},
                "the nodes' start-up gains (observer and controller nodes, config/lwa4p.yaml), every key of "
                "Gains: the HG observer of Sec. IV-A with static feedback at the start-up feedback law; the ESO "
                "gains are Table III's, used when only the observer is switched to eso"),
}, owner=__name__)

defaults.register("gains", {
    "u_ff": (2.0, "U_ff = [-u_ff, u_ff], the bound of the feedforward qdd_d, rad/s^2, that R*_u is certified for "
                  "(paper Sec. IV: U_ref = [-2, 2]): the synthesis configuration's u_ff, the nodes' u_ff_bound, "
                  "reachset analyze --u-ff, check_gains and a model's gains that record no u_ff"),
}, owner=__name__)
defaults.register("lwa4p", {
    "u_max": ({"arm_1_joint": 26.0, "arm_2_joint": 26.0, "arm_3_joint": 26.0, "arm_4_joint": 26.0,
               "arm_5_joint": 100.0, "arm_6_joint": 100.0},
              "U_p = [-u_max, u_max] of each joint of the Schunk LWA-4P, rad/s^2 (paper Table I: 26 for axes 1-4, "
              "100 for axes 5-6), which certify() keeps R*_u inside: the nodes' u_max parameter (in the order of "
              "their joints), the synthesis configuration's u_max, config/lwa4p.yaml"),
}, owner=__name__)

#: the nodes' start-up gains (defaults ``gains.startup``): every key of :class:`Gains`
DEFAULTS = defaults.get("gains.startup")
#: the numeric gain parameters (defaults ``gains.keys``)
GAIN_KEYS = defaults.get("gains.keys")
#: the loop structure's words (defaults ``gains.types``)
TYPE_KEYS = defaults.get("gains.types")
#: the numeric parameters of each observer family's loop (the controller adds omega, zeta)
FAMILY_PARAMS = {"hg": ("omega", "zeta", "h1", "h2"), "eso": ("omega", "zeta", "l1", "l2", "l3")}
#: which plant input the ESO is fed at tick k (:func:`~reachset_ros.systems.observers.extended_state_observer`)
ESO_INPUTS = ("previous", "current")
_NUMBERS = GAIN_KEYS
_WORDS = TYPE_KEYS


def family_controller(observer):
    """The feedback law an observer family is combined with when none is named (defaults
    ``gains.hg.controller``, ``gains.eso.controller``: static for hg, compensated for eso)."""
    if observer not in FAMILY_PARAMS:
        raise ReachsetError(f"observer must be hg or eso, not {observer!r}")
    return defaults.get(f"gains.{observer}.controller")


@dataclass(frozen=True)
class Gains:
    """Observer and controller parameters of one joint (SI units: omega rad/s, eps s).

    ``eso_input`` is part of the loop: ``"previous"`` feeds the ESO u_p[k-1], ``"current"``
    u_p[k] (an algebraic loop, solved by :class:`~reachset_ros.systems.closedloop.FeedbackLaw`);
    the two give different closed loops and different R_e. It is ignored by the HG observer.
    Defaults: the nodes' start-up gains (:data:`DEFAULTS`, defaults ``gains.startup``), and
    the observer family's feedback law when ``controller`` is not given (static for hg,
    compensated for eso: :func:`family_controller`).
    """

    observer: str = DEFAULTS["observer"]
    controller: str = None      # None: the observer family's (:func:`family_controller`)
    omega: float = DEFAULTS["omega"]
    zeta: float = DEFAULTS["zeta"]
    h1: float = DEFAULTS["h1"]
    h2: float = DEFAULTS["h2"]
    l1: float = DEFAULTS["l1"]
    l2: float = DEFAULTS["l2"]
    l3: float = DEFAULTS["l3"]
    eps: float = DEFAULTS["eps"]
    eso_input: str = DEFAULTS["eso_input"]

    def __post_init__(self):
        if self.observer not in ("hg", "eso"):
            raise ReachsetError(f"observer must be hg or eso, not {self.observer!r}")
        if self.controller is None:
            object.__setattr__(self, "controller", family_controller(self.observer))
        if self.controller not in ("static", "compensated"):
            raise ReachsetError(f"controller must be static or compensated, not {self.controller!r}")
        if self.controller == "compensated" and self.observer != "eso":
            raise ReachsetError("the compensated controller needs the ESO's disturbance estimate")
        if self.eso_input not in ESO_INPUTS:
            raise ReachsetError(f"eso_input must be previous or current, not {self.eso_input!r}")
        for k in _NUMBERS:
            v = getattr(self, k)
            if not isinstance(v, (int, float)) or not math.isfinite(v) or v <= 0:
                raise ReachsetError(f"gain {k} must be a positive finite number, got {v!r}")

    @classmethod
    def from_dict(cls, d):
        """Gains from a mapping; missing keys take :data:`DEFAULTS` (a missing ``controller``
        the observer family's, :func:`family_controller`, as :meth:`from_model`), unknown keys
        are ignored."""
        known = {k: d[k] for k in DEFAULTS if k in d}
        for k, v in known.items():
            if k in _WORDS:
                known[k] = str(v)
            else:
                try:
                    known[k] = float(v)
                except (TypeError, ValueError):
                    raise ReachsetError(f"gain {k} must be a number, got {v!r}") from None
        return cls(**known)

    @classmethod
    def from_model(cls, d):
        """Gains from a model file's ``gains`` entry (written by :meth:`model_dict`).

        Strict: the entry must name the observer and give every parameter of its family
        (and ``eps``); ``controller`` defaults to the family's (static for hg, compensated for
        eso), ``eso_input`` to ``"previous"`` (model files written before it was recorded).
        Other keys (``re_norm``, ``ru``, ...) are ignored.
        """
        if not isinstance(d, dict) or "observer" not in d:
            raise ReachsetError("gains must name the observer (hg or eso)")
        obs = d["observer"]
        if obs not in FAMILY_PARAMS:
            raise ReachsetError(f"gains: unknown observer {obs!r}")
        for n in FAMILY_PARAMS[obs]:
            if n not in d:
                raise ReachsetError(f"gains: missing {n} for the {obs} loop")
        kw = {n: d[n] for n in FAMILY_PARAMS[obs] + ("eps",) if n in d}
        try:
            kw = {n: float(v) for n, v in kw.items()}
        except (TypeError, ValueError):
            raise ReachsetError("gains: parameter values must be numbers") from None
        return cls(observer=obs, controller=str(d.get("controller", family_controller(obs))),
                   eso_input=str(d.get("eso_input", defaults.get("gains.eso.eso_input"))), **kw)

    def model_dict(self):
        """The model file's ``gains`` entry: observer, controller, the family's parameters,
        ``eps`` and, for the ESO, ``eso_input`` (read back by :meth:`from_model`)."""
        g = {"observer": self.observer, "controller": self.controller}
        for n in FAMILY_PARAMS[self.observer]:
            g[n] = float(getattr(self, n))
        g["eps"] = float(self.eps)
        if self.observer == "eso":
            g["eso_input"] = self.eso_input
        return g

    def as_dict(self):
        return asdict(self)

    def with_(self, **kw):
        return replace(self, **kw)

    def build_observer(self, dt=0.004):
        """The observer these gains describe (HG or ESO fed the plant input ``eso_input``)."""
        if self.observer == "hg":
            return high_gain_observer(self.h1, self.h2, eps=self.eps, dt=dt)
        return extended_state_observer(self.l1, self.l2, self.l3, eps=self.eps, dt=dt, u_input=self.eso_input)

    def build_controller(self):
        """The feedback law these gains describe (paper eqs. ``staticfeedback``, ``feedbackLaw``)."""
        if self.controller == "static":
            return static_feedback(self.omega, self.zeta)
        return compensated_feedback(self.omega, self.zeta)

    def build(self, dt=0.004):
        """``(observer, controller)``: the loop the synthesis certifies and the nodes run."""
        return self.build_observer(dt), self.build_controller()


@dataclass(frozen=True)
class Certificate:
    """Outcome of :func:`certify`: ``ok``, the ``reason`` when not, the certified
    ``ru = R*_u`` interval (None when the loop is unstable), the :class:`Analysis` of the
    monitored sets, the ``inflation`` and ``u_e_ff`` it was computed with, and the ``row`` of
    :data:`reachset_ros.guarantees.ROWS` a refusal protects ('' when ok)."""

    ok: bool
    reason: str
    ru: tuple
    analysis: object
    inflation: float
    u_e_ff: tuple
    row: str = ""


#: Why :func:`certify` refuses a model joint that records no U_e,ff when the caller gives none.
NO_U_E_FF = ("U_e,ff (the reference error's input part, paper Appendix B) is unknown: the model records none "
             "(a model from `reachset identify`) and no bound was given, and it is not zero (one-tick delays, "
             "the observer's lag); the nodes bound it over every reference U_ff admits")


def recorded_u_e_ff(joint_sets):
    """``U_e,ff = [lo, hi]`` of the model's synthesis record (paper Appendix B), None if none.

    Written by the synthesis into ``JointSets.extra["reference_error"]["u_e_ff"]``; a model
    from ``reachset identify`` has none (the reference error is a property of a closed loop,
    which identification does not choose). Never taken as zero: :func:`certify` refuses
    without it, the nodes' gate bounds it over the references ``U_ff`` admits
    (:func:`reachset_ros.synthesis.reference_error.u_e_ff_for_gains`).
    """
    rec = ((getattr(joint_sets, "extra", None) or {}).get("reference_error") or {}).get("u_e_ff")
    if rec is None:
        return None
    try:
        lo, hi = (float(v) for v in rec)
    except (TypeError, ValueError):
        raise ReachsetError(f"model: reference_error.u_e_ff must be [lo, hi], got {rec!r}") from None
    if not (math.isfinite(lo) and math.isfinite(hi)) or lo > hi:
        raise ReachsetError(f"model: reference_error.u_e_ff must be a finite interval, got {rec!r}")
    return (lo, hi)


def _describe(g):
    return ", ".join(f"{k}={v:g}" if isinstance(v, float) else f"{k}={v}" for k, v in g.model_dict().items())


def is_model_gains(gains: Gains, joint_sets):
    """Whether ``gains`` are the loop a model joint records (``JointSets.gains``; False without)."""
    own = getattr(joint_sets, "gains", None)
    return bool(own) and Gains.from_model(own).model_dict() == gains.model_dict()


def recorded_for_other_gains(gains: Gains, joint_sets):
    """Why the model's recorded ``U_e,ff`` does not hold for ``gains`` ('' when it does).

    ``U_e,ff`` (paper Appendix B) is the input part of the reference error of one closed
    loop: the synthesis records it with the gains it certified (``JointSets.gains``). For
    other gains it is another number (e.g. 6.89 at omega 20, 7.62 at omega 22 for |qdd_d| <= 2),
    so a certificate with the recorded value would be wrong: the caller must compute theirs
    (:func:`reachset_ros.synthesis.reference_error.u_e_ff_for_gains` over the model's
    reference class) or the change is refused.
    """
    rec = ((getattr(joint_sets, "extra", None) or {}).get("reference_error") or {})
    if rec.get("u_e_ff") is None or not getattr(joint_sets, "gains", None) or is_model_gains(gains, joint_sets):
        return ""
    return (f"U_e,ff (the reference error's input part, Appendix B) is recorded for the model's gains "
            f"({_describe(Gains.from_model(joint_sets.gains))}), not for these ({_describe(gains)}), and no "
            "reference class to recompute it is known: synthesise or re-identify for these gains")


def certify(gains: Gains, joint_sets, inflation: float, u_max: float, u_ff: float, u_e_ff=None, plant=None):
    """Certify ``R*_u`` inside ``U_p`` for the sets the monitor actually checks.

    The monitor accepts data conformant to ``W, V`` scaled by ``1 + inflation``
    (:meth:`JointSets.xi`), so the guarantee covers those sets:
    ``R*_u = [0 I] R~_cl,e[k_inf]((1 + inflation) alpha) (+) U_ff (+) U_e,ff`` (paper
    Sec. III-A and Appendix B; ``U_ff = [-u_ff, u_ff]``; ``U_e,ff`` the reference feedforward
    error, by default the model's synthesis record, :func:`recorded_u_e_ff`, which holds only
    for the gains it was synthesised with: other gains without ``u_e_ff`` are refused,
    :func:`recorded_for_other_gains`, and a model without a record is refused, :data:`NO_U_E_FF`,
    never certified with ``U_e,ff = 0``), with the sound
    outer bound of :func:`~reachset_ros.systems.closedloop.analyze` (outward rounded). This is
    the one certification of gains against sets: ``check_gains``, the controller node's gate
    (model load, gain or ``u_max`` change), and the demo's monitored model all call it.

    Returns
    -------
    Certificate
        ``ok`` False with a reason naming R_u, its radius and U_p when ``R*_u`` leaves
        ``U_p = [-u_max, u_max]``, or when the closed loop is unstable.
    """
    inflation = float(inflation)
    if not math.isfinite(inflation) or inflation < 0:
        raise ReachsetError(f"inflation must be finite and >= 0, got {inflation!r}")
    ue = recorded_u_e_ff(joint_sets) if u_e_ff is None else tuple(float(v) for v in u_e_ff)
    if u_e_ff is None:
        other = recorded_for_other_gains(gains, joint_sets)
        if other:
            return Certificate(False, other, None, None, inflation, ue, row="G11")
        if ue is None:
            return Certificate(False, NO_U_E_FF, None, None, inflation, None, row="G11")
    plant = plant or lwa4p_joint_plant()
    cl = closedloop.close_loop(plant, gains.build_observer(plant.dt), gains.build_controller())
    st = closedloop.stability(cl)
    if not st.stable:
        return Certificate(False, f"closed loop unstable ({st.message})", None, None, inflation, ue, row="G7")
    s = 1.0 + inflation
    a = closedloop.analyze(cl, s * np.asarray(joint_sets.alpha_w, float), s * np.asarray(joint_sets.alpha_v, float),
                           u_ff=u_ff, c_w=joint_sets.c_w, c_v=joint_sets.c_v)
    if not a.stable:
        return Certificate(False, f"closed loop unstable ({a.stability.message})", None, a, inflation, ue, row="G7")
    lo, hi = a.ru[0] + min(ue[0], 0.0), a.ru[1] + max(ue[1], 0.0)
    ru = (float(lo), float(hi))
    if lo < -u_max or hi > u_max:
        why = (f"reachable input R*_u = [{lo:.4g}, {hi:.4g}] (radius {max(-lo, hi):.4g}) leaves "
               f"U_p = +-{u_max:g} rad/s^2 (sets inflated by 1 + {inflation:g}, |u_ff| <= {u_ff:g}, "
               f"U_e,ff = [{ue[0]:.3g}, {ue[1]:.3g}])")
        return Certificate(False, why, ru, a, inflation, ue, row="G7")
    return Certificate(True, "", ru, a, inflation, ue)


def max_certified_inflation(gains: Gains, joint_sets, u_max: float, u_ff: float, u_e_ff=None, plant=None):
    """Largest inflation ``i >= 0`` with :func:`certify` ok, or None when not even ``i = 0`` is.

    ``R_u`` is linear in ``alpha`` (:func:`~reachset_ros.systems.closedloop.radius_coefficients`),
    so its disturbance part scales with ``1 + i``; the returned value is rounded down and
    checked with :func:`certify`.
    """
    c0 = certify(gains, joint_sets, 0.0, u_max, u_ff, u_e_ff, plant)
    if not c0.ok:
        return None
    a, ue = c0.analysis, c0.u_e_ff
    cen = 0.5 * (a.ru[0] + a.ru[1])
    r = 0.5 * (a.ru[1] - a.ru[0]) - abs(u_ff)                # disturbance part of R_u
    if r <= 0:
        return math.inf
    room = min(u_max - (cen + abs(u_ff) + max(ue[1], 0.0)), u_max + (cen - abs(u_ff) + min(ue[0], 0.0)))
    i = max(0.0, room / r - 1.0) * (1.0 - 1e-9)
    while i > 0 and not certify(gains, joint_sets, i, u_max, u_ff, u_e_ff, plant).ok:
        i *= 1.0 - 1e-6
    return i


def check_gains(gains: Gains, joint_sets, u_max: float, u_ff: float = defaults.get("gains.u_ff"), plant=None,
                inflation: float = 0.0, u_e_ff=None):
    """Would these gains be safe under the sets the monitor checks?

    Returns ``(ok, reason, analysis)`` of :func:`certify`: ``ok`` is False when the closed
    loop is unstable or when ``R*_u`` (sound outer bound with alpha scaled by ``1 + inflation``,
    plus ``|u_ff|`` and ``U_e,ff``) leaves ``U_p = [-u_max, u_max]``.
    """
    c = certify(gains, joint_sets, inflation, u_max, u_ff, u_e_ff, plant)
    return c.ok, c.reason, c.analysis


def model_limits(joint_sets):
    """``(u_max, u_ff)`` the synthesis recorded with a joint's gains (``JointSets.gains``)."""
    g = joint_sets.gains or {}
    if "u_max" not in g:
        raise ReachsetError("model: the joint's gains do not record u_max (not written by the synthesis)")
    return float(g["u_max"]), float(g.get("u_ff", defaults.get("gains.u_ff")))


def certified_inflation(model, requested: float):
    """The largest inflation ``<= requested`` certified for every joint of a synthesised model.

    Per joint, its recorded gains (:meth:`Gains.from_model`), ``u_max`` and ``u_ff``
    (:func:`model_limits`) and its sets go through :func:`max_certified_inflation`. Returns
    ``(inflation, {joint: largest certified inflation})``; raises ReachsetError naming the
    joint when not even inflation 0 is certified.
    """
    per = {}
    for name, js in model.joints.items():
        u_max, u_ff = model_limits(js)
        best = max_certified_inflation(Gains.from_model(js.gains), js, u_max, u_ff, plant=model.plant)
        if best is None:
            c = certify(Gains.from_model(js.gains), js, 0.0, u_max, u_ff, plant=model.plant)
            raise guarantees.refused(c.row, f"joint {name}: {c.reason}")
        per[name] = float(best)
    return float(min([float(requested), *per.values()])), per


@dataclass(frozen=True)
class PairCertificate:
    """What :func:`certify_pair` established for the observer + controller of every joint.

    ``gains`` (joint -> Gains), ``laws`` (joint -> :class:`~reachset_ros.systems.closedloop.FeedbackLaw`,
    the certified law of the loop), ``settling`` (joint -> ticks of its transient,
    :func:`~reachset_ros.systems.closedloop.settling_ticks`), ``certified`` (joint -> the
    :class:`Certificate` of R*_u inside U_p, None where no model covers the joint),
    ``uncertified`` (the joints run on stability alone, allowed by ``allow_uncertified``) and
    ``unvalidated`` (issue 37.3: joint -> the lines naming the parts of the certified class,
    ``|qdd_d| <= u_ff`` and R*_u, that leave the model's validated envelope, an empty tuple
    when none does,
    :meth:`~reachset_ros.conformance.model.ConformanceModel.unvalidated`; None when no model or
    the model records no envelope: then :meth:`envelope_note` says "envelope: none recorded").
    """

    gains: dict
    laws: dict
    settling: dict
    certified: dict
    uncertified: tuple
    unvalidated: dict = None

    def unvalidated_lines(self):
        """Every line of :attr:`unvalidated`, joint by joint (empty when none, or none recorded)."""
        return [line for lines in (self.unvalidated or {}).values() for line in lines]

    def envelope_note(self):
        """One line for the gate's answer: ``envelope: none recorded`` (no envelope to check
        against), that the certified class lies inside the envelope's axes, or ``NOT VALIDATED``
        and the parts (:attr:`unvalidated`)."""
        return guarantees.envelope_note(self.unvalidated, "the certified class (|qdd_d| <= U_ff, R*_u) lies")


def certify_pair(gains: dict, model, u_max, u_ff: float, dt: float, allow_uncertified: bool = False,
                 u_e_ff_for=None):
    """The one gate for a change of observer or controller gains, whichever node receives it.

    For each joint the pair (its observer and its feedback law, one :class:`Gains`) must give
    a stable closed loop with the model's plant, and where the model has the joint's sets its
    R*_u must stay inside U_p for the sets the monitor checks (:func:`certify`, with the
    joint's own inflation, :meth:`~reachset_ros.conformance.model.ConformanceModel.joint_inflation`,
    and recorded U_e,ff). A joint no model covers (no model, or not in it)
    has no certificate: refused unless ``allow_uncertified``, which runs it on stability alone
    and is reported (``uncertified``). The observer node and the controller node both call
    this (start-up and every parameter change), with the same parameters (the synthesis node
    sets both), so neither can run gains the other's gate would refuse.

    Parameters
    ----------
    gains : dict
        joint -> :class:`Gains`.
    model : ConformanceModel or None
    u_max : sequence of float
        U_p half-width per joint (in the order of ``gains``).
    u_ff : float
        Bound of |qdd_d| (U_ff).
    dt : float
        The nodes' tick period; a model must have the same.
    allow_uncertified : bool
    u_e_ff_for : callable, optional
        ``u_e_ff_for(gains, joint_sets, plant, u_ff) -> (lo, hi) or None``: the ``U_e,ff`` of
        gains other than the model's, or of a model that records none (the nodes pass
        :func:`reachset_ros.synthesis.reference_error.u_e_ff_for_gains`, which bounds it over
        the model's reference class, or over every reference ``U_ff`` admits); None keeps the
        recorded one, which :func:`certify` accepts only for the model's own gains, and
        refuses a model without one.

    Returns
    -------
    PairCertificate
        With ``unvalidated`` (issue 37.3): where the model records a validated envelope, per
        certified joint the parts of the class the certificate covers (``|qdd_d| <= u_ff`` and
        the certified R*_u of u_p) that lie outside the envelope's axes
        (:func:`reachset_ros.conformance.envelope.unvalidated`). Naming, not refusing: the
        gate certifies the model, and the envelope says where the model was tested (paper,
        Def. 4); the callers report the lines (the nodes log them as a WARN at each change).

    Raises
    ------
    ReachsetError
        Naming the joint and the reason (unstable, R*_u outside U_p, no certificate).
    """
    if model is not None and abs(model.plant.dt - dt) > 1e-12 * dt:
        raise guarantees.refused("G4", f"the model's dt {model.plant.dt:g} s differs from the nodes' dt {dt:g} s")
    plant = model.plant if model is not None else lwa4p_joint_plant(dt=dt)
    u_max = list(u_max)
    laws, settling, certified, uncertified, bounds = {}, {}, {}, [], {}
    for i, (j, g) in enumerate(gains.items()):
        obs, ctrl = g.build(dt)
        cl = closedloop.close_loop(plant, obs, ctrl)
        st = closedloop.stability(cl)
        if not st.stable:
            raise guarantees.refused("G7", f"joint {j}: closed loop unstable ({st.message})")
        js = model.joints.get(j) if model is not None else None
        if js is not None:
            ue = u_e_ff_for(g, js, model.plant, u_ff) if u_e_ff_for is not None else None
            c = certify(g, js, model.joint_inflation(j), float(u_max[i]), u_ff, u_e_ff=ue, plant=model.plant)
            if not c.ok:
                raise guarantees.refused(c.row, f"joint {j}: {c.reason}")
            certified[j] = c
            bounds[j] = {"qdd_max": float(u_ff), "qdd_source": "U_ff, the bound of the reference's |qdd_d| the "
                                                               "certificate covers", "u": c.ru, "u_source": "R*_u"}
        else:
            if not allow_uncertified:
                raise guarantees.refused(
                    "G7", f"joint {j}: no model covers these gains ({'no model_file' if model is None else 'not in the model'}"
                    "): R*_u inside U_p cannot be certified; give a model_file, or set allow_uncertified to run "
                    "them on closed-loop stability alone")
            certified[j] = None
            uncertified.append(j)
        laws[j] = closedloop.FeedbackLaw.of(ctrl, obs)
        settling[j] = closedloop.settling_ticks(st.spectral_radius)
    return PairCertificate(dict(gains), laws, settling, certified, tuple(uncertified),
                           unvalidated=None if model is None else model.unvalidated(bounds))
