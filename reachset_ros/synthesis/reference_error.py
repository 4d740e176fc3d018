"""The reference error of the paper's Appendix B (over recorded references or a class of them).

Superposition splits the closed loop into the disturbance part (the reachable sets R_e, R_u of
:mod:`reachset_ros.systems.closedloop`) and the nominal loop driven by the reference
(:class:`~reachset_ros.systems.reference_loop.LoopIO`, simulated exactly by
:class:`~reachset_ros.systems.reference_loop.LTIPlan`; both in
:mod:`reachset_ros.systems.reference_loop`). That nominal loop tracks the
reference with the *reference error* ``y_e,ref`` (estimate minus reference) and needs the
extra input ``u_e,ff = u_p - u_ff`` (Appendix B). :func:`reference_error` encloses both in
boxes (:class:`ReferenceErrorSets`) over every reference found in the bags (``/reference``,
:class:`reachset_ros.bags.references.Reference`).

Appendix B's three ways to account for it (:class:`ReferenceMethod`): method 3 (default)
encloses ``y_e,ref`` and ``u_e,ff`` of the nominal closed loop driven by every reference found
in the bags in boxes and adds them to ``R_e`` and ``R_u`` inside the optimisation; method 2
optimises ``R_e``/``R_u`` alone and checks ``R_u (+) u_e,ff`` for the recorded references
afterwards; method 1 assumes the controller tracks ``y_cl,ref`` (no ``u_e,ff``).

The reference error is never taken as zero: this plant has one-sample input and output delays
and the observer lags, so the feedforward ``u_ff = qdd_d`` does not reproduce the reference.
Without recorded references the sets come from an explicit :class:`ReferenceClass` (bounds on
``qdd_d`` and on its variation per tick): :func:`class_reference_error` gives a *sound* box
over every reference of the class (an l1 impulse-response bound with a proven tail,
:func:`reachset_ros.sets.reachability.radius_coefficients`), used by all three methods.
"""
from __future__ import annotations

import enum
import math
from dataclasses import dataclass

import numpy as np

from ..errors import ReachsetError
from ..sets.reachability import NotStableError, radius_coefficients, reachable_subspace
from ..systems.gains import is_model_gains
from ..systems.reference_loop import LTIPlan, loop_io, reference_inputs, steady_state, steady_state_solver


class ReferenceMethod(enum.IntEnum):
    """How the reference error enters the synthesis (paper Appendix B, methods 1-3).

    An ``IntEnum``: the model file, the JSON output and ``--reference-method`` keep the
    integers 1, 2, 3.
    """

    #: 1: the controller tracks ``y_cl,ref = y_ref + y_e,ref`` instead of ``y_ref``, so
    #: ``u_e,ff`` vanishes; ``R_e`` is relative to ``y_cl,ref``.
    TRACK_CLOSED_LOOP_REFERENCE = 1
    #: 2: the reference error is precomputed per trajectory; ``R_e``/``R_u`` are optimised
    #: without it and ``R*_u = u_e,ff (+) R_u`` is checked for the recorded references afterwards.
    PRECOMPUTED = 2
    #: 3 (default, the paper's experiments): eq. 10 is solved for a predefined set of
    #: references (the bags'); ``Y_e,ref`` and ``U_e,ff`` are added to ``R_e`` and ``R_u``.
    REFERENCE_SET = 3


@dataclass(frozen=True, kw_only=True)
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
        raise ReachsetError("no references to bound the reference error with (record /reference or "
                            "give a reference class)")
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
        r = reference_inputs(io.estimate_names, ref.q, ref.qd, ref.qdd)
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
        raise ReachsetError("the references have no samples (record /reference or give a reference class)")
    return ReferenceErrorSets(e_lo=lo[1:], e_hi=hi[1:], u_lo=float(lo[0]), u_hi=float(hi[0]), qdd_max=qmax,
                              ticks=ticks, stretches=len(references),
                              argext=tuple(arg_lo[1:] + arg_hi[1:] + [arg_lo[0], arg_hi[0]]), exact=exact)


# ====================================================================== a class of references
#: Relative allowance added to :func:`class_reference_error`'s bound for the round-off of the
#: steady-state solves that build the error system (their residuals are checked <= 1e-8).
CLASS_ROUNDOFF = 1e-6
#: Scale of the stopping-reference column in :func:`class_reference_error` (see there).
STOP_SCALE = 1e4


@dataclass(frozen=True)
class ReferenceClass:
    """A class of references: every reference the generator may send (Appendix B without recordings).

    The references are the samples ``q_d[k] = q_d(t_k)``, ``qd_d[k]``, ``qdd_d[k]`` of a
    trajectory whose acceleration obeys ``|qdd_d(t)| <= qdd_max`` and varies by at most
    ``step_max`` within each tick: ``|qdd_d(t) - qdd_d(t_k)| <= step_max`` on
    ``[t_k, t_k+1]`` (the next sample included). Piecewise-constant (trapezoidal) profiles
    switching anywhere inside a tick are in it with ``step_max`` their largest jump; references
    that are exact zero-order-hold integrals of ``qdd_d`` too. ``step_max`` defaults to
    ``2 qdd_max``, which the level bound already implies (no extra assumption). Position and
    velocity need no bound: the closed loop follows ramps without error (checked by
    :func:`class_reference_error`).

    Parameters
    ----------
    qdd_max : float
        Bound of ``|qdd_d|``, rad/s^2 (must lie in ``U_ff``).
    step_max : float, optional
        Bound of the variation of ``qdd_d`` within one tick, rad/s^2.
    """

    qdd_max: float
    step_max: float = None

    def __post_init__(self):
        a = float(self.qdd_max)
        s = 2.0 * a if self.step_max is None else float(self.step_max)
        if not (math.isfinite(a) and a >= 0):
            raise ReachsetError(f"reference class: qdd_max must be a non-negative finite number, got {self.qdd_max}")
        if not (math.isfinite(s) and s >= 0):
            raise ReachsetError(f"reference class: step_max must be a non-negative finite number, got {self.step_max}")
        object.__setattr__(self, "qdd_max", a)
        object.__setattr__(self, "step_max", s)

    @classmethod
    def parse(cls, text):
        """``"qdd_max=F[,step_max=F]"`` (the ``--reference-class`` syntax)."""
        vals = {}
        for item in str(text).split(","):
            if not item.strip():
                continue
            k, sep, v = item.partition("=")
            k = k.strip()
            if not sep or k not in ("qdd_max", "step_max"):
                raise ReachsetError(f"--reference-class: expected qdd_max=F[,step_max=F], got {text!r}")
            try:
                vals[k] = float(v)
            except ValueError:
                raise ReachsetError(f"--reference-class: {k}={v.strip()!r} is not a number") from None
        if "qdd_max" not in vals:
            raise ReachsetError(f"--reference-class: qdd_max is required (qdd_max=F[,step_max=F]), got {text!r}")
        return cls(vals["qdd_max"], vals.get("step_max"))

    @classmethod
    def from_dict(cls, d):
        """Inverse of :meth:`as_dict` (a model file's synthesis record)."""
        try:
            return cls(d["qdd_max"], d.get("step_max"))
        except (KeyError, TypeError, AttributeError):
            raise ReachsetError(f"reference class: expected {{qdd_max, step_max}}, got {d!r}") from None

    @property
    def spec(self):
        """The ``--reference-class`` text of this class."""
        return f"qdd_max={self.qdd_max:g},step_max={self.step_max:g}"

    def as_dict(self):
        return {"qdd_max": self.qdd_max, "step_max": self.step_max}

    def describe(self):
        return (f"|qdd_d| <= {self.qdd_max:g} rad/s^2, varying by <= {self.step_max:g} rad/s^2 within a tick "
                "(sound bound, Appendix B)")

    def violation(self, ref, dt):
        """Why the recorded :class:`Reference` ``ref`` is not in the class, or ``None``.

        Checks the samples ``|qdd_d| <= qdd_max``, ``|qdd_d[k+1] - qdd_d[k]| <= step_max`` and
        the tick means the class implies, ``(qd_d[k+1] - qd_d[k]) / dt`` and
        ``2 (q_d[k+1] - q_d[k] - dt qd_d[k]) / dt^2``: within ``qdd_max`` and within
        ``step_max`` of ``qdd_d[k]`` (relative tolerance 1e-6 for the recording's rounding).
        """
        a, s = self.qdd_max, self.step_max
        tol = 1e-6 * max(a, s, 1e-3)
        q, qd, qdd = (np.asarray(x, float) for x in (ref.q, ref.qd, ref.qdd))
        if len(qdd) == 0:
            return None
        checks = [("|qdd_d|", np.abs(qdd), a)]
        if len(qdd) > 1:
            av = np.diff(qd) / dt
            ap = 2.0 * (np.diff(q) - dt * qd[:-1]) / (dt * dt)
            checks += [("the step of qdd_d per tick", np.abs(np.diff(qdd)), s),
                       ("the tick mean of qdd_d (from qd_d)", np.abs(av), a),
                       ("the tick mean of qdd_d (from q_d)", np.abs(ap), a),
                       ("the variation of qdd_d within a tick (from qd_d)", np.abs(av - qdd[:-1]), s),
                       ("the variation of qdd_d within a tick (from q_d)", np.abs(ap - qdd[:-1]), s)]
        for what, x, bound in checks:
            k = int(np.argmax(x))
            if x[k] > bound + tol:
                return f"{what} reaches {x[k]:.4g} > {bound:g} at tick {k}"
        return None


def _reference_error_system(plant, observer, controller, errors=("q", "qd")):
    """The LTI map from a class reference's innovations to ``[y_e,ref; u_e,ff]``.

    A reference of :class:`ReferenceClass` evolves over one tick as
    ``q_d[k+1] = q_d + dt qd_d + dt^2/2 (qdd_d[k] + dp[k])``, ``qd_d[k+1] = qd_d + dt (qdd_d[k] +
    dv[k])`` with ``dv``, ``dp`` the (weighted) tick means of ``qdd_d(t) - qdd_d(t_k)``
    (zero for zero-order-hold references). The loop state ``z`` (:class:`LoopIO`) minus its
    ramp response ``M [q_d; qd_d]`` (``M F = A M + B R_g``, ``F`` the ramp's dynamics) gives
    ``zeta``, driven by ``nu = [qdd_d, dv, dp]`` and its previous value (``q_prev``,
    ``u_prev``). Because the loop follows ramps exactly (checked: ``C M + D R_g`` equals the
    reference's own (q, qd) rows), the outputs ``x_hat_sel - x_ref_sel`` and ``u - u_ff``
    depend on ``nu`` alone: ``X[k+1] = Ae X + Be nu``, ``out = Ce X + De nu``, ``X = [zeta;
    nu[k-1]]``, outputs ``[errors..., u_e,ff]``.

    Raises
    ------
    ReachsetError
        If the loop does not follow ramp references without error (then position and velocity
        bounds would be needed).
    """
    io = loop_io(plant, observer, controller)
    dt = float(plant.dt)
    names = io.estimate_names
    cols = io.inputs("u_ff", "x_ref")
    nc = len(cols)
    Rg, Rn, Rp = np.zeros((nc, 2)), np.zeros((nc, 3)), np.zeros((nc, 3))
    Rn[0, 0] = 1.0                                    # u_ff = qdd_d[k]
    for i, nm in enumerate(names):
        c = 1 + i
        if nm == "q":
            Rg[c] = [1.0, 0.0]
        elif nm == "qd":
            Rg[c] = [0.0, 1.0]
        elif nm == "q_prev":                          # q_d[k-1] in terms of q_d[k], qd_d[k], nu[k-1]
            Rg[c] = [1.0, -dt]
            Rp[c] = [dt * dt / 2, dt * dt, -dt * dt / 2]
        elif nm == "u_prev":
            Rp[c] = [1.0, 0.0, 0.0]
        elif nm != "d":
            raise ReachsetError(f"no reference for the estimate {nm!r}")
    A, B = io.A, io.B[:, cols]
    solve = steady_state_solver(io, cols)
    m_q = solve(B @ Rg[:, 0])
    m_qd = solve(B @ Rg[:, 1] - dt * m_q)
    M = np.column_stack([m_q, m_qd])
    F = np.array([[1.0, dt], [0.0, 1.0]])
    sel = [names.index(nm) for nm in errors]
    p, m = io.p, io.m
    rows = [p + m + i for i in sel] + [p]
    C, D = io.C[rows], io.D[np.ix_(rows, cols)]
    E = np.zeros((len(rows), 2))
    for j, i in enumerate(sel):
        E[j] = Rg[1 + i]
    res_m = np.abs(M @ F - A @ M - B @ Rg).max()
    res_y = np.abs(C @ M + D @ Rg - E).max()
    scale = max(1.0, float(np.abs(M).max()), float(np.abs(C @ M).max()))
    if not (res_m <= 1e-8 * scale and res_y <= 1e-8 * scale):
        raise ReachsetError(f"reference class: this closed loop does not follow ramp references without error "
                            f"(residual {max(res_m, res_y):.3g}); bound the reference error with recorded references")
    n = A.shape[0]
    Gn = np.array([[dt * dt / 2, 0.0, dt * dt / 2], [dt, dt, 0.0]])
    Ae = np.block([[A, B @ Rp], [np.zeros((3, n)), np.zeros((3, 3))]])
    Be = np.vstack([B @ Rn - M @ Gn, np.eye(3)])
    Ce = np.hstack([C, D @ Rp])
    De = D @ Rn
    De[-1, 0] -= 1.0                                  # u_e,ff = u - u_ff
    return Ae, Be, Ce, De


def class_reference_error(plant, observer, controller, reference_class, errors=("q", "qd")):
    """Sound boxes ``Y_e,ref`` and ``U_e,ff`` over every reference of a :class:`ReferenceClass`.

    Paper Appendix B (the sets of method 3, the reference error of methods 1-2) for a class
    instead of recorded references. With the error system of :func:`_reference_error_system`
    (impulse responses ``h_0`` of ``qdd_d``, ``h_v``, ``h_p`` of the within-tick terms
    ``dv``, ``dp``; ``|qdd_d| <= a``, steps ``<= s``, ``|dv|, |dp| <= min(s, 2a)``), each
    output ``r`` obeys, for every reference of the class and any past,
    ``|out_r| <= min(B1, B2, B3)`` with

    * ``B1 = ||h_0||_1 a + (||h_v||_1 + ||h_p||_1) min(s, 2a)``;
    * ``B2 = |G| a + sum_{j>=1} |S_j| s + (||h_v||_1 + ||h_p||_1) min(s, 2a)`` (summation by
      parts: ``out = G qdd_d[k] + sum_{j>=1} S_j (qdd_d[k-j] - qdd_d[k-j+1])``, ``G`` the DC
      gain, ``S_j = sum_{i>=j} h_0,i`` the tail sums);
    * ``B3 = ||h_0 - h_v - h_p||_1 a + (||h_v||_1 + ||h_p||_1) a`` (in terms of the sample
      and the two tick means of ``qdd_d``, each bounded by ``a``).

    Every l1 norm is an infinite sum bounded by
    :func:`~reachset_ros.sets.reachability.radius_coefficients` (truncated sum plus a proven
    geometric tail bound on the stable part); the result is widened by
    :data:`CLASS_ROUNDOFF` (relative) for the round-off of the steady-state solves. It is an
    outer bound: the channels are bounded independently although they are coupled. The
    boxes are symmetric (the class is).

    Returns
    -------
    ReferenceErrorSets
        ``ticks = stretches = 0`` (no recording), ``qdd_max`` the class's.
    """
    rc = reference_class
    Ae, Be, Ce, De = _reference_error_system(plant, observer, controller, errors)
    a, s = rc.qdd_max, rc.step_max
    sd = min(s, 2.0 * a)
    # on the reachable subspace of the three channels (the plant's constant-disturbance mode,
    # eigenvalue 1, is not reachable from references and stays out of the DC-gain solve)
    V = reachable_subspace(Ae, Be)
    Ar, Er, Cr = V.T @ Ae @ V, V.T @ Be, Ce @ V
    if max(abs(np.linalg.eigvals(Ar)), default=0.0) >= 1.0:
        raise NotStableError("reference class: the closed loop is not stable")
    bt = np.linalg.solve(np.eye(V.shape[1]) - Ar, Er[:, 0])   # sum_i Ar^i b_0
    G = De[:, 0] + Cr @ bt                                      # DC gain of qdd_d
    # one call for all channels: [h_0, h_v, h_p, tail sums S_j (j >= 1), h_0 - h_v - h_p], and a
    # copy of h_0 scaled by STOP_SCALE: radius_coefficients stops once every tail is below
    # eps (1e-6 of the row's largest entry + the entry), which a response that is ~0 in a row
    # (e.g. dp on qd_e) never meets within its rounding floor; the copy sets that floor's
    # scale. The bounds returned include their tails whatever the stopping point (sound).
    E = np.column_stack([Er, bt, Er[:, 0] - Er[:, 1] - Er[:, 2], STOP_SCALE * Er[:, 0]])
    Dw = np.column_stack([De, np.zeros(len(De)), De[:, 0] - De[:, 1] - De[:, 2], np.zeros(len(De))])
    K, _ = radius_coefficients(Ar, E, np.zeros((V.shape[1], 0)), Cr, Dw=Dw)
    K0, Kd, Kt, K3 = K[:, 0], K[:, 1] + K[:, 2], K[:, 3], K[:, 4]
    b1 = K0 * a + Kd * sd
    b2 = np.abs(G) * a + Kt * s + Kd * sd
    bnd3 = K3 * a + Kd * a
    bound = np.minimum(np.minimum(b1, b2), bnd3) * (1.0 + CLASS_ROUNDOFF)
    e, u = bound[:-1], float(bound[-1])
    return ReferenceErrorSets(e_lo=-e, e_hi=e.copy(), u_lo=-u, u_hi=u, qdd_max=a, ticks=0, stretches=0)


def u_e_ff_for_gains(gains, joint_sets, plant, u_ff=None):
    """``U_e,ff = (lo, hi)`` of ``gains`` for a model joint, or None (paper Appendix B).

    For the gate of the nodes (:func:`reachset_ros.systems.gains.certify_pair`): ``U_e,ff``
    depends on the loop and on the references, and the controller accepts every reference
    with ``|qdd_d| <= u_ff`` (its ``u_ff_bound``): the class ``A`` = ``qdd_max = u_ff``,
    ``step_max = 2 u_ff`` (:class:`ReferenceClass`). A bound is sound for the running loop
    only if it covers ``A`` (issue 34.4):

    * A recorded reference class that covers ``A`` (``qdd_max >= u_ff``, ``step_max >=
      2 u_ff``): for the model's own gains the recorded ``U_e,ff`` (None: the recorded value),
      for other gains the class's sound bound (:func:`class_reference_error`).
    * Otherwise (a record over recorded references, which the controller's class is not
      inside; a recorded class narrower than ``A``; no record at all, a model from
      ``reachset identify``): the sound bound over ``A`` itself, for these gains. Before, a
      synthesis over recorded references certified its own gains with the recorded
      references' ``U_e,ff`` (+-0.006) while the controller accepted +-2 rad/s^2 references
      (class bound +-6.9).
    * Without ``u_ff`` (``A`` unknown): the recorded value for the model's own gains, a
      recorded class's bound for other gains, else None (:func:`~reachset_ros.systems.gains.certify`
      then refuses, :data:`~reachset_ros.systems.gains.NO_U_E_FF`).

    None also when the bound does not converge (refused then, too).
    """
    rec = (getattr(joint_sets, "extra", None) or {}).get("reference_error") or {}
    rc = ReferenceClass.from_dict(rec["reference_class"]) if rec.get("reference_class") else None
    own = not getattr(joint_sets, "gains", None) or is_model_gains(gains, joint_sets)
    if u_ff is None:
        if rec.get("u_e_ff") is not None and (rc is None or own):
            return None
        cls = rc
    else:
        accepted = ReferenceClass(qdd_max=abs(float(u_ff)))
        covers = rc is not None and rc.qdd_max >= accepted.qdd_max and rc.step_max >= accepted.step_max
        if covers and own and rec.get("u_e_ff") is not None:
            return None
        cls = rc if covers else accepted
    if cls is None:
        return None
    key = (tuple(sorted(gains.model_dict().items())), _plant_key(plant), float(cls.qdd_max), float(cls.step_max))
    if key not in _CLASS_U_E_FF:
        obs, ctrl = gains.build(plant.dt)
        try:
            r = class_reference_error(plant, obs, ctrl, cls)
            _CLASS_U_E_FF[key] = (float(r.u_lo), float(r.u_hi))
        except NotStableError:
            _CLASS_U_E_FF[key] = None
        while len(_CLASS_U_E_FF) > _CLASS_U_E_FF_SIZE:
            _CLASS_U_E_FF.pop(next(iter(_CLASS_U_E_FF)))
    return _CLASS_U_E_FF[key]


#: the class bounds :func:`u_e_ff_for_gains` computed: (gains, plant, class) -> (lo, hi) or None.
#: The bound is a pure function of these (seconds each: the nodes' gate runs it for every
#: joint at every gain change, six times for one pair of gains); oldest first out.
_CLASS_U_E_FF = {}
_CLASS_U_E_FF_SIZE = 256


def _plant_key(plant):
    """The plant's matrices and dt as bytes: two equal plants give equal keys."""
    arrays = (plant.A, plant.B, plant.C, plant.D, plant.Gw, plant.Gv)
    return (float(plant.dt),) + tuple(None if a is None else (np.asarray(a, np.float64).shape,
                                                            np.asarray(a, np.float64).tobytes()) for a in arrays)
