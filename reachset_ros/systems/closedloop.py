"""Closed loops of plant, observer and controller; reachable tracking error and input.

:func:`close_loop` composes a :class:`~reachset_ros.systems.plant.LinearPlant`, a
:class:`~reachset_ros.systems.observers.LinearObserver` and a
:class:`~reachset_ros.systems.controllers.LinearController` into the *error system* of paper
Sec. III-A: reference and feedforward set to zero (superposition), inputs the unit-box
coefficients of the disturbance generators, outputs ``[q_hat, qd_hat, u_p]``
(``y~_cl = [y_cl, u_p]``)::

    z[k+1] = A z[k] + Bw w[k] + Bv v[k]         z = [x_p; x_o]
    out[k] = C z[k] + Dv v[k]                    w in W_p, v in V_p

The algebraic loop that arises when the estimate depends on the current input
(``Do_u != 0``, the ESO; or a plant with ``D != 0``) is solved exactly:
``(I + K (Do_y D_p + Do_u)) u = -K (...)``.

:func:`analyze` returns ``R_e`` (projection onto the estimate errors) and
``R_u = projection (+) U_ff`` of the minimal robust positively invariant set, both as a
sound outer bound and as the truncated inner sum (:mod:`reachset_ros.sets.reachability`).

Pure numpy/scipy; no ROS import.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..sets import reachability as reach
from ..sets.zonotope import Zonotope

__all__ = ["ClosedLoop", "close_loop", "Stability", "stability", "Analysis", "analyze",
           "radius_coefficients", "center_coefficients", "FeedbackLaw", "closed_loop_tick", "simulate",
           "simulate_ticks", "SETTLING_TOLERANCE", "settling_ticks", "settling_time"]


def _ro(a):
    a = np.array(a, dtype=float, copy=True)
    a.setflags(write=False)
    return a


@dataclass(frozen=True, eq=False, kw_only=True)
class ClosedLoop:
    """Closed-loop error system (reference and feedforward zero).

    Attributes
    ----------
    A : ndarray, (nz, nz)
        Closed-loop matrix on ``z = [x_p; x_o]``.
    Bw : ndarray, (nz, n_p)
        Input matrix of the raw process disturbance ``w`` (a plant-state vector).
    Bv : ndarray, (nz, p)
        Input matrix of the raw measurement noise ``v``.
    C : ndarray, (n_out, nz)
        Outputs ``[selected estimates..., u_p...]``.
    Dv : ndarray, (n_out, p)
        Direct feedthrough of ``v`` to the outputs (the estimate uses the current measurement).
    Ew, Ev : ndarray
        ``Bw G'_W`` and ``Bv G'_V``: the disturbance generators (unscaled) in ``z``.
    DEv : ndarray
        ``Dv G'_V``.
    Fz, Fv : ndarray
        Plant input ``u = Fz z + Fv v``.
    output_names : tuple of str
    n_error : int
        Number of tracking-error outputs (the first ``n_error`` outputs; the rest are ``u_p``).
    plant, observer, controller
        The components.
    """

    A: np.ndarray
    Bw: np.ndarray
    Bv: np.ndarray
    C: np.ndarray
    Dv: np.ndarray
    Ew: np.ndarray
    Ev: np.ndarray
    DEv: np.ndarray
    Fz: np.ndarray
    Fv: np.ndarray
    output_names: tuple
    n_error: int
    plant: object = field(repr=False)
    observer: object = field(repr=False)
    controller: object = field(repr=False)

    @property
    def n_states(self):
        """Dimension of ``z``."""
        return self.A.shape[0]


def close_loop(plant, observer, controller, errors=("q", "qd")):
    """Compose plant + observer + controller into the error system (paper Sec. III-A).

    Parameters
    ----------
    plant : LinearPlant
        ``x_p[k+1] = A_p x_p + B_p u + w``, ``y = C_p x_p + D_p u + v``.
    observer : LinearObserver
        Fed ``(y[k], u[k])``; its input dimensions must match the plant.
    controller : LinearController
        ``u = u_ff + K (x_ref - x_hat)``; its estimate names must be provided by the observer.
    errors : sequence of str
        Estimates whose errors form ``R_e`` (default ``("q", "qd")``: ``y_cl = [q_hat, qd_hat]``).

    Returns
    -------
    ClosedLoop

    Raises
    ------
    ValueError
        On mismatched dimensions/names, or an ill-posed algebraic loop
        (``I + K (Do_y D_p + Do_u)`` singular).
    """
    Ap, Bp, Cp, Dp = plant.A, plant.B, plant.C, plant.D
    npl, m, p = plant.n_states, plant.n_inputs, plant.n_outputs
    if observer.Bo_y.shape[1] != p or observer.Bo_u.shape[1] != m:
        raise ValueError(f"observer {observer.name!r} takes {observer.Bo_y.shape[1]} measurements and "
                         f"{observer.Bo_u.shape[1]} inputs; plant {plant.name!r} has {p} and {m}")
    if controller.n_inputs != m:
        raise ValueError(f"controller {controller.name!r} computes {controller.n_inputs} inputs; "
                         f"plant {plant.name!r} has {m}")
    if abs(observer.dt - plant.dt) > 1e-12 * plant.dt:
        raise ValueError(f"observer dt {observer.dt} differs from plant dt {plant.dt}")
    K = controller.gain_for(observer.estimate_names)
    sel = [observer.index(nm) for nm in errors]
    Ao, Boy, Bou, Co, Doy, Dou = (observer.Ao, observer.Bo_y, observer.Bo_u, observer.Co,
                                  observer.Do_y, observer.Do_u)
    no = observer.n_states
    # x_hat = Xz z + Xv v + Dxu u ;  u = -K x_hat
    Xz = np.hstack([Doy @ Cp, Co])
    Xv = Doy
    Dxu = Doy @ Dp + Dou
    L = np.eye(m) + K @ Dxu
    if np.linalg.cond(L) > 1e12:
        raise ValueError("the algebraic loop between observer and controller is ill-posed "
                         "(I + K (Do_y D_p + Do_u) is singular)")
    Fz = -np.linalg.solve(L, K @ Xz)
    Fv = -np.linalg.solve(L, K @ Xv)
    Hz = Xz + Dxu @ Fz
    Hv = Xv + Dxu @ Fv
    Yz = np.hstack([Cp, np.zeros((p, no))]) + Dp @ Fz
    Yv = np.eye(p) + Dp @ Fv
    Bu = np.vstack([Bp, Bou])
    By = np.vstack([np.zeros((npl, p)), Boy])
    A = np.block([[Ap, np.zeros((npl, no))], [np.zeros((no, npl)), Ao]]) + Bu @ Fz + By @ Yz
    Bw = np.vstack([np.eye(npl), np.zeros((no, npl))])
    Bv = Bu @ Fv + By @ Yv
    C = np.vstack([Hz[sel], Fz])
    Dv = np.vstack([Hv[sel], Fv])
    names = tuple(f"{nm}_hat" for nm in errors) + tuple(plant.input_names)
    return ClosedLoop(A=_ro(A), Bw=_ro(Bw), Bv=_ro(Bv), C=_ro(C), Dv=_ro(Dv), Ew=_ro(Bw @ plant.Gw),
                      Ev=_ro(Bv @ plant.Gv), DEv=_ro(Dv @ plant.Gv), Fz=_ro(Fz), Fv=_ro(Fv),
                      output_names=names, n_error=len(sel), plant=plant, observer=observer,
                      controller=controller)


# ---------------------------------------------------------------------- stability
@dataclass(frozen=True, kw_only=True)
class Stability:
    """Stability of the closed loop on the disturbances' reachable subspace.

    Attributes
    ----------
    stable : bool
    spectral_radius : float
        On the reachable subspace.
    reachable_dim, n_states : int
    unstable_eigenvalues : tuple of complex
        Eigenvalues with modulus >= 1 on the reachable subspace.
    message : str
        A one-line human-readable answer.
    """

    stable: bool
    spectral_radius: float
    reachable_dim: int
    n_states: int
    unstable_eigenvalues: tuple
    message: str


def stability(cl, tol=1e-10):
    """Asymptotic stability of ``cl`` on the reachable subspace of ``(A, [Ew, Ev])``.

    Modes the disturbances cannot reach (e.g. the plant's constant disturbance ``d``,
    eigenvalue 1) do not count; they do not affect ``R_e``/``R_u``.

    Returns
    -------
    Stability
    """
    V = reach.reachable_subspace(cl.A, np.hstack([cl.Ew, cl.Ev]), tol)
    ev = np.linalg.eigvals(V.T @ cl.A @ V) if V.shape[1] else np.zeros(0)
    rho = float(np.max(np.abs(ev), initial=0.0))
    bad = tuple(complex(e) for e in ev if abs(e) >= 1.0 - 1e-12)
    if bad:
        msg = (f"closed loop unstable: spectral radius {rho:.6g} >= 1 on the {V.shape[1]}-dimensional "
               f"subspace the disturbances reach ({len(bad)} eigenvalue(s) on or outside the unit circle)")
    else:
        msg = f"closed loop stable: spectral radius {rho:.6g} on the {V.shape[1]}-dimensional reachable subspace"
    return Stability(stable=not bad, spectral_radius=rho, reachable_dim=V.shape[1], n_states=cl.n_states,
                     unstable_eigenvalues=bad, message=msg)


# ---------------------------------------------------------------------- linear coefficients
def _alphas(cl, alpha_w, alpha_v):
    gw, gv = cl.Ew.shape[1], cl.Ev.shape[1]
    aw = np.atleast_1d(np.asarray(alpha_w, dtype=float))
    av = np.atleast_1d(np.asarray(alpha_v, dtype=float))
    if aw.shape != (gw,) or av.shape != (gv,):
        raise ValueError(f"alpha_w needs {gw} and alpha_v {gv} entries, got {aw.size} and {av.size}")
    for nm, a in (("alpha_w", aw), ("alpha_v", av)):
        if not np.all(np.isfinite(a)) or np.any(a < 0):
            raise ValueError(f"{nm} must be finite and non-negative, got {a.tolist()}")
    return aw, av


def radius_coefficients(cl, H=None, eps=reach.EPS, return_info=False):
    """Box radius of ``H`` times the outer invariant output set: ``Kw alpha_w + Kv alpha_v``.

    Thin wrapper of :func:`reachset_ros.sets.reachability.radius_coefficients` for a
    :class:`ClosedLoop` (outputs ``[q_hat, qd_hat, u_p]`` unless ``errors`` was changed).

    Returns
    -------
    Kw : ndarray, (q, gw)
    Kv : ndarray, (q, gv)
    info : RadiusInfo, only with ``return_info``
    """
    return reach.radius_coefficients(cl.A, cl.Ew, cl.Ev, cl.C, Dw=None, Dv=cl.DEv, H=H, eps=eps,
                                     return_info=return_info)


def center_coefficients(cl, tol=1e-10):
    """Centre of the invariant output set as ``Mw c_w + Mv c_v`` (constant disturbance centres).

    ``c_w`` (a plant-state vector) and ``c_v`` (an output vector) are the centres of
    ``W_p`` and ``V_p``. The steady state is ``z_c = (I - A)^-1 (Bw c_w + Bv c_v)``; it
    exists only for centre directions in a stable invariant subspace, so each column of
    ``[Bw, Bv]`` that reaches a mode with eigenvalue 1 (e.g. a ``c_w`` entry on the
    constant-disturbance state) gives a column of NaN.

    Returns
    -------
    Mw : ndarray, (n_out, n_p)
    Mv : ndarray, (n_out, p)
    """
    B = np.hstack([cl.Bw, cl.Bv])
    M = np.full((cl.C.shape[0], B.shape[1]), np.nan)
    for j in range(B.shape[1]):
        b = B[:, j]
        if not np.any(b):
            M[:, j] = 0.0
            continue
        V = reach.reachable_subspace(cl.A, b[:, None], tol)
        Ar = V.T @ cl.A @ V
        if np.max(np.abs(np.linalg.eigvals(Ar))) < 1.0 - 1e-12:
            M[:, j] = cl.C @ (V @ np.linalg.solve(np.eye(V.shape[1]) - Ar, V.T @ b))
    nw = cl.Bw.shape[1]
    Mv = M[:, nw:] + cl.Dv
    return M[:, :nw], Mv


# ---------------------------------------------------------------------- analysis
@dataclass(frozen=True, eq=False, kw_only=True)
class Analysis:
    """Reachable tracking error ``R_e`` and reachable input ``R_u`` of a closed loop.

    Attributes
    ----------
    stable : bool
    stability : Stability
    re_center, re_radius : ndarray or None
        ``R_e`` interval hull (sound outer bound): centre and half-widths.
    re_norm : float or None
        Sum of the interval hull's edge lengths, ``2 sum(re_radius)`` (the paper's tables).
    ru : tuple (lo, hi) or None
        ``R_u = projection (+) U_ff`` (outer), for a single plant input; an array pair for several.
    re_radius_inner, re_norm_inner, ru_inner
        The same from the truncated sum ``(+)_{i<s}`` (inner approximation, not sound alone).
    s : int
        Truncation length; ``a``: contraction factor of the tail bound.
    re_set, ru_set : Zonotope or None
        Outer zonotopes (only with ``sets=True``).
    """

    stable: bool
    stability: Stability
    re_center: np.ndarray = None
    re_radius: np.ndarray = None
    re_norm: float = None
    ru: tuple = None
    re_radius_inner: np.ndarray = None
    re_norm_inner: float = None
    ru_inner: tuple = None
    s: int = 0
    a: float = float("nan")
    re_set: Zonotope = None
    ru_set: Zonotope = None

    def as_dict(self):
        """JSON-ready dictionary (``None`` where unstable)."""
        def lst(x):
            return None if x is None else np.asarray(x, float).tolist()
        return dict(stable=self.stable, spectral_radius=self.stability.spectral_radius,
                    re_norm=self.re_norm, re_radius=lst(self.re_radius), re_center=lst(self.re_center),
                    ru=lst(self.ru), re_norm_inner=self.re_norm_inner,
                    re_radius_inner=lst(self.re_radius_inner), ru_inner=lst(self.ru_inner),
                    truncation_steps=self.s,
                    tail_contraction=self.a if self.stable else None,
                    message=self.stability.message)


def analyze(cl, alpha_w, alpha_v, u_ff=0.0, c_w=None, c_v=None, eps=reach.EPS, sets=False):
    """``R_e`` and ``R_u`` of the closed loop (paper Sec. III-A), outer and inner.

    ``R_e = [I 0] R~_cl,e[k_inf]``, ``R_u = [0 I] R~_cl,e[k_inf] (+) U_ff`` with
    ``U_ff = [-u_ff, u_ff]`` and ``R~_cl,e[k_inf]`` the mRPI set of the error system
    (outer bound: :func:`reachset_ros.sets.reachability.radius_coefficients`).

    Parameters
    ----------
    cl : ClosedLoop
    alpha_w, alpha_v : array_like
        Generator scalings (non-negative).
    u_ff : float or array_like
        Half-width of the feedforward set ``U_ff`` (paper: ``|qdd_d| <= 2``).
    c_w, c_v : array_like, optional
        Centres of ``W_p`` and ``V_p``.
    eps : float
        Relative size of the tail bound.
    sets : bool
        Also build the outer zonotopes (slower; the numbers come from the same bound).

    Returns
    -------
    Analysis
        With ``stable=False`` and no numbers when the loop is unstable (not an error).
    """
    aw, av = _alphas(cl, alpha_w, alpha_v)
    try:
        Kw, Kv, info = radius_coefficients(cl, eps=eps, return_info=True)
    except reach.NotStableError as e:
        st = stability(cl)
        if st.stable:  # spectral radius below one, but too close to it for the tail bound
            st = Stability(stable=False, spectral_radius=st.spectral_radius, reachable_dim=st.reachable_dim,
                           n_states=st.n_states, unstable_eigenvalues=(), message=str(e))
        return Analysis(stable=False, stability=st)
    st = Stability(stable=True, spectral_radius=info.spectral_radius, reachable_dim=info.reachable_dim,
                   n_states=cl.n_states, unstable_eigenvalues=(),
                   message=f"closed loop stable: spectral radius {info.spectral_radius:.6g} on the "
                           f"{info.reachable_dim}-dimensional reachable subspace")
    rad = Kw @ aw + Kv @ av
    rad_in = info.Kw_inner @ aw + info.Kv_inner @ av
    cen = np.zeros(cl.C.shape[0])
    if c_w is not None or c_v is not None:
        Mw, Mv = center_coefficients(cl)
        cw = np.zeros(Mw.shape[1]) if c_w is None else np.asarray(c_w, float)
        cv = np.zeros(Mv.shape[1]) if c_v is None else np.asarray(c_v, float)
        nzw, nzv = cw != 0, cv != 0  # columns of NaN (no steady state) only matter if used
        cen = Mw[:, nzw] @ cw[nzw] + Mv[:, nzv] @ cv[nzv]
        if not np.all(np.isfinite(cen)):
            raise ValueError("a disturbance centre drives a mode with eigenvalue 1 (e.g. c_w on the "
                             "constant-disturbance state): the reachable set is unbounded")
    ne = cl.n_error
    uff = np.broadcast_to(np.abs(np.asarray(u_ff, float)), (cl.C.shape[0] - ne,))

    def ru_of(r):
        lo, hi = cen[ne:] - r[ne:] - uff, cen[ne:] + r[ne:] + uff
        return (float(lo[0]), float(hi[0])) if lo.size == 1 else (lo, hi)

    re_set = ru_set = None
    if sets:
        G = np.diag(rad)
        re_set = Zonotope(cen[:ne], G[:ne, :ne])
        ru_set = Zonotope(cen[ne:], G[ne:, ne:]) + Zonotope(np.zeros(uff.size), np.diag(uff))
    return Analysis(stable=True, stability=st, re_center=cen[:ne], re_radius=rad[:ne],
                    re_norm=float(2 * rad[:ne].sum()), ru=ru_of(rad), re_radius_inner=rad_in[:ne],
                    re_norm_inner=float(2 * rad_in[:ne].sum()), ru_inner=ru_of(rad_in), s=info.s, a=info.a,
                    re_set=re_set, ru_set=ru_set)


# ---------------------------------------------------------------------- simulation
@dataclass(frozen=True, eq=False)
class FeedbackLaw:
    """The control law of one loop, as certified and as deployed (paper eqs. 5-7).

    ``u = u_ff + K (x_ref - x_hat)`` with ``x_hat = x0 + Do_u u``, where
    ``x0 = Co xo + Do_y y`` is the observer's estimate without the current input's
    feedthrough (:meth:`~reachset_ros.systems.observers.ObserverState.partial_estimate`, what
    the observer node publishes). With ``Do_u != 0`` (the ESO fed u_p[k]) this is an
    algebraic loop, solved exactly: ``(I + K Do_u) u = u_ff + K (x_ref - x0)``; the same
    solution :func:`close_loop` builds into the certified matrices (``Fz``, ``Fv``).

    :func:`closed_loop_tick` (the simulation of the certified loop tick by tick) and
    ``controller_node`` both call :meth:`__call__`: there is no second copy of the law.

    Build with :meth:`of`.
    """

    K: np.ndarray
    Do_u: np.ndarray
    estimate_names: tuple

    @classmethod
    def of(cls, controller, observer):
        """The law of ``controller`` acting on the estimates of ``observer``."""
        return cls(controller.gain_for(observer.estimate_names), observer.Do_u, tuple(observer.estimate_names))

    def __call__(self, x0, x_ref=None, u_ff=0.0):
        """Plant input and full estimate for the partial estimate ``x0``.

        Parameters
        ----------
        x0 : array_like, (ne,)
            ``Co xo + Do_y y``, ordered as ``estimate_names``.
        x_ref : array_like, (ne,), optional
            Reference in the same coordinates (zero for estimates without one, e.g. ``d``).
        u_ff : float or array_like
            Feedforward (``qdd_d``).

        Returns
        -------
        u : ndarray, (m,)
        x_hat : ndarray, (ne,)
        """
        x0 = np.atleast_1d(np.asarray(x0, float))
        K = self.K
        e = -x0 if x_ref is None else np.asarray(x_ref, float) - x0
        rhs = np.atleast_1d(np.asarray(u_ff, float)) + K @ e
        if np.any(self.Do_u):
            u = np.linalg.solve(np.eye(K.shape[0]) + K @ self.Do_u, rhs)
        else:
            u = rhs
        return u, x0 + self.Do_u @ u


def closed_loop_tick(observer_state, controller, y, x_ref=None, u_ff=0.0):
    """One controller/observer tick with the algebraic loop solved exactly.

    ``x_hat = x0 + Do_u u`` with ``x0 = Co xo + Do_y y``, and
    ``u = u_ff + K (x_ref - x_hat)``, so ``(I + K Do_u) u = u_ff + K (x_ref - x0)``
    (:class:`FeedbackLaw`, the law the controller node runs).

    Parameters
    ----------
    observer_state : ObserverState
    controller : LinearController
    y : array_like
        Current measurement ``y[k]``.
    x_ref : array_like, optional
        Reference in the observer's estimate coordinates (zero by default).
    u_ff : float or array_like

    Returns
    -------
    u : ndarray
        Plant input ``u[k]``.
    x_hat : ndarray
        Estimate ``x_hat[k]``.
    next_state : ObserverState
    """
    y = np.atleast_1d(np.asarray(y, float))
    u, x_hat = FeedbackLaw.of(controller, observer_state.observer)(observer_state.partial_estimate(y), x_ref, u_ff)
    return u, x_hat, observer_state.advance(y, u)


#: relative size to which the slowest mode of a transient has decayed when it counts as settled
SETTLING_TOLERANCE = 1e-3


def settling_ticks(spectral_radius, tol=SETTLING_TOLERANCE, initial=1.0):
    """Ticks after which a transient has decayed: the smallest ``k`` with ``initial rho^k <= tol``.

    ``R_e`` and ``R_u`` (paper Sec. III-A) are the reachable sets from zero initial error;
    after a start, a gain change or the end of braking the error starts elsewhere and
    decays like ``rho^k`` (``rho`` the closed loop's spectral radius, :func:`stability`), so
    the standard settling time ``k = ceil(ln(tol / initial) / ln(rho))`` is the window
    during which the tracking error is not claimed to lie in ``R*_e``. It is the asymptotic
    rate: a strongly non-normal ``A`` can take longer by the factor of its transient growth.

    Parameters
    ----------
    spectral_radius : float
        In [0, 1); a closed loop that is not stable never settles (ValueError).
    tol : float
        Size of the transient at which it counts as settled, in the units of ``initial``.
    initial : float
        Size (bound) of the initial error; default 1 makes ``tol`` relative.

    Returns
    -------
    int
    """
    rho, tol, initial = float(spectral_radius), float(tol), float(initial)
    if not (0.0 <= rho < 1.0):
        raise ValueError(f"a closed loop with spectral radius {rho:.6g} does not settle (needs < 1)")
    if not (tol > 0 and np.isfinite(tol)) or not (initial >= 0 and np.isfinite(initial)):
        raise ValueError(f"settling tolerance must be > 0 and the initial error finite, got {tol}, {initial}")
    if initial <= tol:
        return 0
    if rho == 0.0:
        return 1
    k = max(int(np.ceil(np.log(tol / initial) / np.log(rho))), 1)
    while initial * rho ** k > tol:   # the rounding of the logarithms, outward
        k += 1
    return k


def settling_time(cl, tol=SETTLING_TOLERANCE, initial=1.0):
    """:func:`settling_ticks` of the closed loop ``cl`` (its spectral radius on the
    reachable subspace, :func:`stability`), in ticks."""
    return settling_ticks(stability(cl).spectral_radius, tol, initial)


def simulate(cl, w, v, z0=None):
    """Simulate the closed-loop error system with the composed matrices.

    Parameters
    ----------
    cl : ClosedLoop
    w : array_like, (T, n_p) or (T, N, n_p)
        Raw process disturbances (plant-state vectors); a middle axis runs ``N``
        trajectories at once.
    v : array_like, (T, p) or (T, N, p)
    z0 : array_like, optional

    Returns
    -------
    ndarray, (T, [N,] n_out)
        Outputs ``[q_hat, qd_hat, u_p]`` at ``k = 0..T-1``.
    """
    w, v = np.asarray(w, float), np.asarray(v, float)
    batch = w.ndim == 3
    if not batch:
        w, v = w[:, None, :], v[:, None, :]
    T, N = w.shape[:2]
    z = np.zeros((N, cl.n_states)) if z0 is None else np.broadcast_to(np.asarray(z0, float), (N, cl.n_states)).copy()
    out = np.empty((T, N, cl.C.shape[0]))
    AT, BwT, BvT, CT, DvT = cl.A.T, cl.Bw.T, cl.Bv.T, cl.C.T, cl.Dv.T
    for k in range(T):
        out[k] = z @ CT + v[k] @ DvT
        z = z @ AT + w[k] @ BwT + v[k] @ BvT
    return out if batch else out[:, 0, :]


def simulate_ticks(plant, observer, controller, w, v, errors=("q", "qd"), x_ref=None, u_ff=None):
    """Simulate plant + observer + controller tick by tick (the nodes' code path).

    Uses :func:`closed_loop_tick` and :class:`~reachset_ros.systems.observers.ObserverState`.

    Parameters
    ----------
    plant, observer, controller
    w : array_like, (T, n_p)
    v : array_like, (T, p)
    errors : sequence of str
    x_ref : array_like, (T, ne), optional
    u_ff : array_like, (T, m), optional

    Returns
    -------
    ndarray, (T, len(errors) + m)
        ``[x_hat[errors] - x_ref[errors], u]`` per tick.
    """
    w, v = np.asarray(w, float), np.asarray(v, float)
    T = w.shape[0]
    xp = np.zeros(plant.n_states)
    st = observer.initial_state()
    sel = [observer.index(nm) for nm in errors]
    out = np.empty((T, len(sel) + plant.n_inputs))
    if np.any(plant.D):
        raise NotImplementedError("tick simulation with plant feedthrough D != 0")
    for k in range(T):
        y = plant.C @ xp + v[k]
        xr = None if x_ref is None else x_ref[k]
        uf = 0.0 if u_ff is None else u_ff[k]
        u, xh, st = closed_loop_tick(st, controller, y, xr, uf)
        e = xh if xr is None else xh - xr
        out[k] = np.concatenate([e[sel], u])
        xp = plant.A @ xp + plant.B @ u + w[k]
    return out
