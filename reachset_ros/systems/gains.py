"""Controller and observer gains of one joint as a value, and their safety check.

The nodes receive gains through ROS parameters, the synthesis writes them into the model
file (``JointSets.gains``); both go through :class:`Gains`, which builds the observer and
controller of the core and checks a proposed set of gains against the identified sets:
the closed loop must be stable and its reachable input R_u must stay inside U_p.
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass, replace

from . import closedloop
from .controllers import compensated_feedback, static_feedback
from ..errors import ReachsetError
from .observers import extended_state_observer, high_gain_observer
from .plant import lwa4p_joint_plant

__all__ = ["Gains", "check_gains", "DEFAULTS"]

DEFAULTS = dict(observer="hg", controller="static", omega=10.0, zeta=1.0, h1=15.0, h2=30.0,
                l1=57.1, l2=103.3, l3=18.1, eps=0.01)


@dataclass(frozen=True)
class Gains:
    """Observer and controller parameters of one joint (SI units: omega rad/s, eps s)."""

    observer: str = "hg"
    controller: str = "static"
    omega: float = 10.0
    zeta: float = 1.0
    h1: float = 15.0
    h2: float = 30.0
    l1: float = 57.1
    l2: float = 103.3
    l3: float = 18.1
    eps: float = 0.01

    def __post_init__(self):
        if self.observer not in ("hg", "eso"):
            raise ReachsetError(f"observer must be hg or eso, not {self.observer!r}")
        if self.controller not in ("static", "compensated"):
            raise ReachsetError(f"controller must be static or compensated, not {self.controller!r}")
        if self.controller == "compensated" and self.observer != "eso":
            raise ReachsetError("the compensated controller needs the ESO's disturbance estimate")
        for k in ("omega", "zeta", "h1", "h2", "l1", "l2", "l3", "eps"):
            v = getattr(self, k)
            if not isinstance(v, (int, float)) or not math.isfinite(v) or v <= 0:
                raise ReachsetError(f"gain {k} must be a positive finite number, got {v!r}")

    @classmethod
    def from_dict(cls, d):
        known = {k: d[k] for k in DEFAULTS if k in d}
        for k, v in known.items():
            if k not in ("observer", "controller"):
                try:
                    known[k] = float(v)
                except (TypeError, ValueError):
                    raise ReachsetError(f"gain {k} must be a number, got {v!r}") from None
        return cls(**known)

    def as_dict(self):
        return asdict(self)

    def with_(self, **kw):
        return replace(self, **kw)

    def build_observer(self, dt=0.004):
        if self.observer == "hg":
            return high_gain_observer(self.h1, self.h2, eps=self.eps, dt=dt)
        return extended_state_observer(self.l1, self.l2, self.l3, eps=self.eps, dt=dt)

    def build_controller(self):
        if self.controller == "static":
            return static_feedback(self.omega, self.zeta)
        return compensated_feedback(self.omega, self.zeta)


def check_gains(gains: Gains, joint_sets, u_max: float, u_ff: float = 2.0, plant=None):
    """Would these gains be safe under the identified sets?

    Returns ``(ok, reason, analysis)``: ``ok`` is False when the closed loop is unstable or
    when R_u (sound outer bound, plus |u_ff|) leaves U_p = [-u_max, u_max].
    """
    plant = plant or lwa4p_joint_plant()
    cl = closedloop.close_loop(plant, gains.build_observer(plant.dt), gains.build_controller())
    st = closedloop.stability(cl)
    if not st.stable:
        return False, f"closed loop unstable ({st.message})", None
    a = closedloop.analyze(cl, joint_sets.alpha_w, joint_sets.alpha_v, u_ff=u_ff,
                           c_w=joint_sets.c_w, c_v=joint_sets.c_v)
    lo, hi = a.ru
    if lo < -u_max or hi > u_max:
        return False, f"reachable input R_u = [{lo:.3g}, {hi:.3g}] leaves U_p = +-{u_max:g} rad/s^2", a
    return True, "", a
