"""The synthesis result of one joint (:class:`JointResult`) and how it is finalised.

With ``inflation > 0`` (the monitor checks the sets scaled by ``1 + inflation``) the reported
``R_e`` and ``R_u`` are those of the scaled sets; the stored ``alpha`` stay the identified ones.

:func:`finalize` turns the search's optimum into the reported result: the sets are made sound
in floating point (:func:`reachset_ros.conformance.make_sound`), the final ``R_e`` and ``R_u``
(plus the reference error of Appendix B, by :class:`~reachset_ros.synthesis.reference_error.ReferenceMethod`)
are computed and conformance is checked on every test case (Theorem 1).
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from .. import conformance as cf
from ..bags.messages import REFERENCE_TOPIC
from ..errors import InfeasibleError
from ..sets.reachability import NotStableError
from ..systems.closedloop import analyze, close_loop
from ..systems.gains import Gains
from .config import PARAMS
from .reference_error import ReferenceMethod


# ====================================================================== results
@dataclass(kw_only=True)
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
    inflation: float = 0.0          # R_e, R_u are for the sets scaled by 1 + inflation
    notes: list = field(default_factory=list)
    extra: dict = field(default_factory=dict)
    separate: object = None

    @property
    def ru_inside(self):
        return bool(-self.u_max <= self.ru[0] and self.ru[1] <= self.u_max)

    def gains(self):
        """The model file's ``gains`` entry (also what the controller/observer nodes read):
        :meth:`reachset_ros.systems.gains.Gains.model_dict` plus the certified numbers."""
        g = Gains(observer=self.observer, controller=self.controller, eso_input=self.eso_input,
                  eps=float(self.params["eps"]),
                  **{n: float(self.params[n]) for n in PARAMS[self.observer]}).model_dict()
        g.update(re_norm=float(self.re_norm), re_radius=[float(x) for x in self.re_radius],
                 ru=[float(self.ru[0]), float(self.ru[1])], u_max=float(self.u_max), u_ff=float(self.u_ff),
                 mode=self.mode,
                 reference_method=int(self.reference.get("method", ReferenceMethod.REFERENCE_SET)))
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
             "inflation": float(self.inflation),
             "evaluations": int(self.evaluations), "seconds": round(float(self.seconds), 4)}
        if self.notes:
            d["notes"] = list(self.notes)
        d.update(self.extra)
        return d


def finalize(problem, space, values, alpha, mode, evaluations=0, t0=None, notes=(), check=True):
    """Make the sets sound in floating point, compute the final R_e, R_u, check conformance."""
    pb = problem
    pw = pb.plant.Gw.shape[1]
    n, ny = pb.plant.A.shape[0], pb.plant.C.shape[0]
    c_w, c_v = np.zeros(n), np.zeros(ny)
    aw, av = np.array(alpha[:pw], float), np.array(alpha[pw:], float)
    aw, av, bump = cf.make_sound(pb.plant, pb.thm, pb.devs, c_w, c_v, aw, av)
    obs, ctrl = space.build(values)
    cl = close_loop(pb.plant, obs, ctrl)
    # R_e and R_u of the sets the monitor checks: W, V scaled by 1 + inflation (JointSets.xi)
    an = analyze(cl, pb.set_scale * aw, pb.set_scale * av, u_ff=0.0)
    if not an.stable:
        raise InfeasibleError(f"joint {pb.name}: the chosen closed loop is not stable ({an.stability.message})")
    refd = {"method": int(pb.reference_method)}
    try:                                          # Appendix B: recorded references or the class
        ref_obj = pb.reference_sets(obs, ctrl)
    except NotStableError as e:
        raise InfeasibleError(f"joint {pb.name}: the reference error cannot be bounded for this loop "
                              f"({str(e).splitlines()[0]})") from None
    refd.update(ref_obj.as_dict())
    rc = pb.reference_class
    if rc is not None:
        refd["reference_class"] = rc.as_dict()
        ticks = sum(len(r) for r in pb.references)
        refd["source"] = (f"reference class {rc.spec}: {rc.describe()}"
                          + (f"; the recorded {REFERENCE_TOPIC} ({ticks} ticks) lies in it" if ticks else ""))
    else:
        refd["source"] = f"{REFERENCE_TOPIC} ({ref_obj.ticks} ticks in {ref_obj.stretches} stretches)"
    r_u = float(an.ru[1])
    re_rad = np.asarray(an.re_radius, float)
    center = np.zeros_like(re_rad)
    lo_u, hi_u = -r_u - pb.u_ff, r_u + pb.u_ff
    if pb.reference_method == ReferenceMethod.REFERENCE_SET:
        re_rad = re_rad + 0.5 * (ref_obj.e_hi - ref_obj.e_lo)
        center = 0.5 * (ref_obj.e_hi + ref_obj.e_lo)
        lo_u, hi_u = lo_u + ref_obj.u_lo, hi_u + ref_obj.u_hi
    elif pb.reference_method == ReferenceMethod.PRECOMPUTED:
        star = (lo_u + ref_obj.u_lo, hi_u + ref_obj.u_hi)
        refd["ru_star"] = [float(star[0]), float(star[1])]
        refd["ru_star_inside_up"] = bool(-pb.u_max <= star[0] and star[1] <= pb.u_max)
        refd["re_star_norm"] = float(an.re_norm + ref_obj.norm)
    elif pb.reference_method == ReferenceMethod.TRACK_CLOSED_LOOP_REFERENCE:
        refd["note"] = ("the controller must track y_cl,ref = y_ref + y_e,ref (Appendix B, method 1); "
                        "R_e is relative to y_cl,ref")
    re_norm = float(2.0 * re_rad.sum())
    res_check = None
    if check:
        xi = cf.xi_of(c_w, c_v, aw, av)
        res_check = pb.check(xi)
    return JointResult(
        name=pb.name, mode=mode, observer=space.observer, controller=space.controller, params=dict(values),
        free=space.free, alpha_w=aw, alpha_v=av, c_w=c_w, c_v=c_v,
        re_norm=re_norm, re_radius=re_rad, re_center=center, re_norm_disturbance=float(an.re_norm),
        ru=(float(lo_u), float(hi_u)), ru_radius=r_u, u_max=pb.u_max, u_ff=pb.u_ff,
        reference=refd, test_cases=pb.test_cases, horizon=pb.horizon,
        conformant=bool(res_check.violations == 0) if res_check else True,
        violations=int(res_check.violations) if res_check else 0,
        worst_margin=float(res_check.worst_margin) if res_check else float("nan"),
        soundness_inflation=float(bump),
        spectral_radius=float(an.stability.spectral_radius), evaluations=evaluations,
        seconds=0.0 if t0 is None else time.perf_counter() - t0, eso_input=space.eso_input,
        inflation=float(pb.inflation), notes=list(notes))
