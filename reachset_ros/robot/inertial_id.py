"""Inertial-parameter identification of the rigid-body arm from joint torques.

The joint torque of eq. (5) is linear in the extended standard parameters
``theta = [pi_1..pi_n (10 per link, Pinocchio order m, mc_x, mc_y, mc_z, I_xx, I_xy, I_yy,
I_xz, I_yz, I_zz at the joint frame), armature, viscous, coulomb, offset]``, with the
regressor from ``pin.computeJointTorqueRegressor`` plus one column per joint for each of
the four joint terms (:func:`regressor`). :class:`BaseParameters` reduces it to identifiable
base parameters (QR with column pivoting on random samples); :func:`torque_gram` reduces a
data set to per-joint normal equations and :func:`identify_inertial` solves the
least-squares problem -- plain base-parameter least squares or, by default, the physically
consistent variant (pseudo-inertia LMIs, so that M(q) stays positive definite) -- including
a per-joint torque scale for logged torques whose units are unknown.

This fits the nominal model M_hat, psi_hat of the feedback linearization (paper eq. 6);
it is not the paper's reachset-conformant identification (:mod:`reachset_ros.conformance`).
"""
from __future__ import annotations

import warnings
from dataclasses import dataclass, field

import numpy as np
import pinocchio as pin

from ..errors import ReachsetError
from .dynamics import Friction, RobotModel, create_data, feedback_linearization

__all__ = ["PARAMS_PER_LINK", "LINK_PARAM_NAMES", "JOINT_PARAM_NAMES", "parameter_names",
           "parameter_vector", "with_parameters", "regressor", "regressor_batch", "random_states",
           "BaseParameters", "TorqueGram", "torque_gram", "Identification", "identify_inertial",
           "predict_logged"]

PARAMS_PER_LINK = 10
LINK_PARAM_NAMES = ("m", "mc_x", "mc_y", "mc_z", "I_xx", "I_xy", "I_yy", "I_xz", "I_yz", "I_zz")
JOINT_PARAM_NAMES = ("armature", "viscous", "coulomb", "offset")


def parameter_names(model: RobotModel) -> list:
    """Names of the extended standard parameters (see :func:`parameter_vector`)."""
    names = [f"{j}.{p}" for j in model.joint_names for p in LINK_PARAM_NAMES]
    names += [f"{j}.{p}" for p in JOINT_PARAM_NAMES for j in model.joint_names]
    return names


def parameter_vector(model: RobotModel) -> np.ndarray:
    """Extended standard parameters theta (length 14 n).

    ``[pi_1, ..., pi_n, armature, viscous, coulomb, offset]`` with ``pi_i`` the 10 dynamic
    parameters of link i in Pinocchio's order (inertia about the joint frame origin).
    """
    pm = model.pin_model
    pis = [pm.inertias[i].toDynamicParameters() for i in range(1, model.nv + 1)]
    fr = model.friction
    return np.concatenate(pis + [np.asarray(pm.armature), fr.viscous, fr.coulomb, fr.offset])


def with_parameters(model: RobotModel, theta, torque_scale=None, source=None) -> RobotModel:
    """A new :class:`RobotModel` with extended standard parameters ``theta``.

    Link parameters need not be physically consistent (Pinocchio accepts any inertia);
    check :func:`min_mass_eigenvalue` on the configurations of interest.
    """
    n = model.nv
    theta = np.asarray(theta, dtype=np.float64)
    if theta.size != 14 * n:
        raise ReachsetError(f"expected {14 * n} parameters, got {theta.size}")
    pm = model.pin_model.copy()
    for i in range(n):
        pm.inertias[i + 1] = pin.Inertia.FromDynamicParameters(theta[10 * i:10 * i + 10].copy())
    j = theta[10 * n:]
    pm.armature[:] = j[:n]
    fr = Friction(j[n:2 * n], j[2 * n:3 * n], j[3 * n:4 * n], model.friction.coulomb_velocity)
    return RobotModel(pm, fr, model.torque_scale if torque_scale is None else torque_scale,
                      source=model.source if source is None else source)


def regressor(model: RobotModel, data: pin.Data, q, qd, qdd) -> np.ndarray:
    """Extended joint-torque regressor Y with ``tau = Y(q, qd, qdd) theta`` (n x 14 n).

    Columns: ``pin.computeJointTorqueRegressor`` (rigid bodies, 10 per link), then per
    joint ``qdd_j`` (armature), ``qd_j`` (viscous), ``tanh(qd_j / v_c)`` (Coulomb), ``1``
    (offset), each only in row j.
    """
    q, qd, qdd = (np.asarray(x, dtype=np.float64) for x in (q, qd, qdd))
    n = model.nv
    Y = np.zeros((n, 14 * n))
    Y[:, :10 * n] = pin.computeJointTorqueRegressor(model.pin_model, data, q, qd, qdd)
    d = np.arange(n)
    Y[d, 10 * n + d] = qdd
    Y[d, 11 * n + d] = qd
    Y[d, 12 * n + d] = np.tanh(qd / model.friction.coulomb_velocity)
    Y[d, 13 * n + d] = 1.0
    return Y


def regressor_batch(model: RobotModel, data: pin.Data, Q, QD, QDD) -> np.ndarray:
    """:func:`regressor` for N samples (arrays (N, n)); returns (N, n, 14 n)."""
    Q, QD, QDD = (np.atleast_2d(np.asarray(x, dtype=np.float64)) for x in (Q, QD, QDD))
    return np.stack([regressor(model, data, Q[k], QD[k], QDD[k]) for k in range(len(Q))])


def random_states(model: RobotModel, n_samples: int, rng, qd_max=2.0, qdd_max=10.0):
    """Random (q, qd, qdd) samples, q uniform within the model's position limits."""
    lo = np.maximum(model.lower, -np.pi)
    hi = np.minimum(model.upper, np.pi)
    Q = rng.uniform(lo, hi, (n_samples, model.nv))
    QD = rng.uniform(-qd_max, qd_max, (n_samples, model.nv))
    QDD = rng.uniform(-qdd_max, qdd_max, (n_samples, model.nv))
    return Q, QD, QDD


@dataclass(frozen=True)
class BaseParameters:
    """Base (identifiable) parameters ``beta = K theta`` of the extended regressor.

    ``Y theta = Y[:, independent] beta`` for every motion. Found by QR with column pivoting
    of the regressor stacked over random samples; ``beta_k = theta_{independent[k]} +
    sum_l K_d[k, l] theta_{dependent[l]}``.

    Attributes
    ----------
    independent : np.ndarray of int
        Columns of the extended regressor kept (the base regressor).
    dependent : np.ndarray of int
        Columns that are zero or linear combinations of the independent ones.
    K : np.ndarray, shape (r, 14 n)
        Projection from standard to base parameters.
    names : tuple of str
        Name of each base parameter (the standard parameter it is built on).
    """

    independent: np.ndarray
    dependent: np.ndarray
    K: np.ndarray
    names: tuple

    @property
    def rank(self) -> int:
        return len(self.independent)

    @classmethod
    def from_model(cls, model: RobotModel, n_samples: int = 300, seed: int = 0,
                   tol: float = 1e-9) -> "BaseParameters":
        """Compute the base parameters of ``model``'s kinematics (inertias irrelevant)."""
        data = create_data(model)
        rng = np.random.default_rng(seed)
        Y = regressor_batch(model, data, *random_states(model, n_samples, rng))
        Y = Y.reshape(-1, Y.shape[-1])
        import scipy.linalg  # lazy: scipy's start-up (issue 38.1)
        _, R, P = scipy.linalg.qr(Y, mode="economic", pivoting=True)
        diag = np.abs(np.diag(R))
        r = int(np.sum(diag > tol * diag[0]))
        ind, dep = P[:r], P[r:]
        Kd = scipy.linalg.solve_triangular(R[:r, :r], R[:r, r:])
        Kd[np.abs(Kd) < 1e-10] = 0.0
        order = np.argsort(ind)
        ind, Kd = ind[order], Kd[order]
        K = np.zeros((r, Y.shape[1]))
        K[np.arange(r), ind] = 1.0
        K[:, dep] = Kd
        names = parameter_names(model)
        for a in (ind, dep, K):
            a.setflags(write=False)
        return cls(ind, dep, K, tuple(names[i] for i in ind))

    def base(self, theta) -> np.ndarray:
        """Base parameters of standard parameters ``theta``."""
        return self.K @ np.asarray(theta, dtype=np.float64)

    def standard(self, beta, theta_prior) -> np.ndarray:
        """Standard parameters with base parameters ``beta``, closest to ``theta_prior``.

        Minimum-norm correction ``theta = prior + K^+ (beta - K prior)`` in parameter units
        scaled by ``max(|prior|, 1e-3)`` so that small and large parameters move alike.
        """
        prior = np.asarray(theta_prior, dtype=np.float64)
        w = np.maximum(np.abs(prior), 1e-3)
        Kw = self.K * w
        corr = np.linalg.lstsq(Kw, np.asarray(beta) - self.K @ prior, rcond=None)[0]
        return prior + w * corr


@dataclass(frozen=True)
class TorqueGram:
    """Sufficient statistics of a torque data set for least squares, per joint.

    For the extended regressor ``Y`` (:func:`regressor`) and logged torques ``u`` over N
    samples: ``G[j] = sum_k Y_k[j]^T Y_k[j]``, ``c[j] = sum_k Y_k[j]^T u_k[j]``,
    ``uu[j] = sum_k u_k[j]^2``. Any residual ``Y theta / s - u`` has the squared norm
    ``theta^T G theta / s^2 - 2 c^T theta / s + uu`` per joint, so data sets of any length
    reduce to a few kilobytes and add up (``+``).
    """

    G: np.ndarray
    c: np.ndarray
    uu: np.ndarray
    N: int

    def __add__(self, other):
        return TorqueGram(self.G + other.G, self.c + other.c, self.uu + other.uu,
                          self.N + other.N)

    def sse(self, theta, s):
        """Sum of squared residuals per joint (logged units) of parameters and scales."""
        theta = np.asarray(theta, dtype=np.float64)
        g = 1.0 / np.asarray(s, dtype=np.float64)
        quad = np.einsum("p,npq,q->n", theta, self.G, theta)
        return np.maximum(g ** 2 * quad - 2 * g * (self.c @ theta) + self.uu, 0.0)

    def rms(self, theta, s):
        """RMS residual per joint (logged units)."""
        return np.sqrt(self.sse(theta, s) / max(self.N, 1))


def torque_gram(model: RobotModel, data: pin.Data, Q, QD, QDD, logged,
                chunk: int = 4000) -> TorqueGram:
    """:class:`TorqueGram` of samples ``(Q, QD, QDD)`` (N, n) with logged torques (N, n)."""
    Q, QD, QDD, U = (np.atleast_2d(np.asarray(x, dtype=np.float64)) for x in (Q, QD, QDD, logged))
    if not (QD.shape == QDD.shape == U.shape == Q.shape):
        raise ReachsetError("Q, QD, QDD and logged torques must have equal shapes")
    n, p = model.nv, 14 * model.nv
    G, c, uu = np.zeros((n, p, p)), np.zeros((n, p)), np.zeros(n)
    for a in range(0, len(Q), chunk):
        sl = slice(a, a + chunk)
        Y = regressor_batch(model, data, Q[sl], QD[sl], QDD[sl])
        G += np.einsum("knp,knq->npq", Y, Y)
        c += np.einsum("knp,kn->np", Y, U[sl])
        uu += np.sum(U[sl] ** 2, axis=0)
    return TorqueGram(G, c, uu, len(Q))


@dataclass(frozen=True)
class Identification:
    """Result of :func:`identify_inertial`.

    Attributes
    ----------
    model : RobotModel
        The identified model (torque scale included).
    theta : np.ndarray
        Extended standard parameters (:func:`parameter_vector` of ``model``).
    beta : np.ndarray
        Base parameters ``base.K @ theta``.
    base : BaseParameters
    torque_scale : np.ndarray
        N m per logged unit.
    rms : np.ndarray
        RMS residual per joint on the fitting data, in logged torque units.
    samples : int
    method : str
        ``"placeholder"``, ``"ls"`` or ``"lmi"``.
    settings : dict
        Weights and solver information.
    """

    model: RobotModel
    theta: np.ndarray
    beta: np.ndarray
    base: BaseParameters
    torque_scale: np.ndarray
    rms: np.ndarray
    samples: int
    method: str
    settings: dict = field(default_factory=dict)


def _friction_cols(n, terms):
    """Columns of the extended parameters of the friction ``terms`` (all joints)."""
    off = {"viscous": 11, "coulomb": 12, "offset": 13}
    return {t: np.arange(off[t] * n, off[t] * n + n) for t in terms}


def _stage1(model, gram, theta0, fit_scale, terms):
    """Placeholder stage: rigid + armature (and friction terms not in ``terms``) fixed at
    ``theta0``; per joint least squares in ``(1/s, friction/s)``."""
    n = model.nv
    fc = _friction_cols(n, terms)
    free = np.concatenate([fc[t] for t in terms]) if terms else np.zeros(0, int)
    tf = theta0.copy()
    tf[free] = 0.0
    theta = theta0.copy()
    s = np.ones(n)
    k = len(terms)
    for j in range(n):
        cols = [fc[t][j] for t in terms]
        # columns [Y theta_fixed, F_free]; their Gram matrix and right-hand side.
        T = np.zeros((14 * n, 1 + k))
        T[:, 0] = tf
        T[cols, np.arange(1, 1 + k)] = 1.0
        H = T.T @ gram.G[j] @ T
        g = T.T @ gram.c[j]
        if fit_scale:
            x = np.linalg.lstsq(H, g, rcond=None)[0]
            if not x[0] >= 1e-6:                   # no positive scale: friction only
                x[0] = 1e-6
                x[1:] = np.linalg.lstsq(H[1:, 1:], g[1:] - H[1:, 0] * x[0], rcond=None)[0]
            s[j] = 1.0 / x[0]
            theta[cols] = x[1:] * s[j]
        else:
            x = np.linalg.lstsq(H[1:, 1:], g[1:] - H[1:, 0], rcond=None)[0]
            theta[cols] = x
    return theta, s


def _lmi_step(model, *, H, g, theta_ref, D2, prior_weight, min_armature, cache,
              fixed=(), nonneg=()):
    """min theta^T H theta - 2 g^T theta + w ||D (theta - theta_ref)||^2 subject to
    physical consistency (pseudo-inertia of every link PSD) and armature >= min_armature;
    columns ``fixed`` stay at ``theta_ref``, columns ``nonneg`` are >= 0. ``cache`` keeps the
    compiled cvxpy problem."""
    import cvxpy as cp  # heavy optional dependency: only the LMI method needs it
    n = model.nv
    p = 14 * n
    if "prob" not in cache:
        th = cp.Variable(p)
        R = cp.Parameter((p, p))
        gp = cp.Parameter(p)
        cons = []
        for i in range(n):
            m, hx, hy, hz, ixx, ixy, iyy, ixz, iyz, izz = (th[10 * i + k] for k in range(10))
            J = cp.Variable((4, 4), PSD=True)
            tr = (ixx + iyy + izz) / 2
            cons += [J[0, 0] == tr - ixx, J[1, 1] == tr - iyy, J[2, 2] == tr - izz,
                     J[0, 1] == -ixy, J[0, 2] == -ixz, J[1, 2] == -iyz,
                     J[0, 3] == hx, J[1, 3] == hy, J[2, 3] == hz, J[3, 3] == m]
        cons += [th[10 * n:11 * n] >= min_armature]
        if len(fixed):
            cons += [th[np.asarray(fixed)] == theta_ref[np.asarray(fixed)]]
        if len(nonneg):
            cons += [th[np.asarray(nonneg)] >= 0]
        prob = cp.Problem(cp.Minimize(cp.sum_squares(R @ th) - 2 * gp @ th), cons)
        cache.update(prob=prob, th=th, R=R, g=gp)
    Ht = H + prior_weight * np.diag(D2)
    rhs = g + prior_weight * D2 * theta_ref
    L = np.linalg.cholesky(Ht + 1e-12 * np.trace(Ht) / p * np.eye(p))
    cache["R"].value = L.T
    cache["g"].value = rhs
    try:
        with warnings.catch_warnings():       # "inaccurate" is judged by the status below
            warnings.simplefilter("ignore", UserWarning)
            cache["prob"].solve(solver="CLARABEL", tol_gap_abs=1e-10, tol_gap_rel=1e-10,
                                tol_feas=1e-10, max_iter=500)
    except Exception:  # noqa: BLE001  (solver failure: retry with SCS)
        cache["prob"].solve(solver="SCS", eps=1e-9, max_iters=200000)
    if cache["th"].value is None or cache["prob"].status not in ("optimal", "optimal_inaccurate"):
        raise ReachsetError(f"identification: the physically consistent fit failed "
                            f"({cache['prob'].status})")
    return np.array(cache["th"].value)


def identify_inertial(model: RobotModel, gram: TorqueGram, *, method: str = "lmi",
             fit_scale: bool = True, prior_weight: float = 1e-3, scale_weight: float = 1.0,
             min_armature: float = 1e-3, friction_terms=("viscous", "coulomb", "offset"),
             nonnegative_friction: bool = False, base=None, max_iter: int = 200,
             tol: float = 1e-10) -> Identification:
    """Least-squares identification from a :class:`TorqueGram` of logged torques.

    The torque of joint j is ``s_j * logged_j = Y(q, qd, qdd)_j theta`` (eq. 5 written
    with the regressor of :func:`regressor`) with an unknown torque scale ``s_j`` [N m per
    logged unit]. Residuals are measured in logged units (where the noise is),
    ``r_j = Y_j theta / s_j - logged_j``, rows of joint j weighted by the inverse residual
    RMS of the placeholder stage. The data fix ``theta`` and ``s`` only up to a common factor
    (to which ``u_p = M^-1 (tau - psi)`` is invariant) and barely see some directions
    (joint 6 hardly moves in the LWA-4P data), so two priors close the problem: a
    scale-free ridge ``prior_weight * ||D (theta - theta_0)||^2`` towards ``model``
    (``D`` the regressor's column norms) and ``scale_weight * N * ||log s - log s_0||^2``
    towards the placeholder stage's scales ``s_0``. Absolute N m values are therefore only
    as right as the prior's overall size.

    Methods
    -------
    ``"placeholder"``
        Rigid-body and armature parameters of ``model`` kept; per joint, linear least
        squares in ``(1/s_j, friction_j/s_j)`` (viscous, Coulomb, offset). The baseline.
    ``"ls"``
        Base parameters (:class:`BaseParameters`) by ridge least squares, scales by
        variable projection (L-BFGS over ``log s``, ``beta`` eliminated in closed form).
        Fast, but nothing keeps M(q) positive definite (on the LWA-4P data it is not).
    ``"lmi"`` (default)
        Physically consistent: every link's pseudo-inertia ``[[tr(I)/2 - I, h], [h^T, m]]``
        PSD (Wensing, Kim, Slotine 2017) and armature >= ``min_armature``, so
        ``M(q) >= min_armature * I`` everywhere. Friction is left free: a logged motor
        command need not show a textbook friction curve. For fixed scales the problem is
        convex (cvxpy, Clarabel); the scales are optimised over this profile by L-BFGS-B
        with the exact gradient (envelope theorem), ``max_iter`` iterations, ``tol``. Convex (cvxpy, Clarabel) for fixed
        scales; alternated with the closed-form per-joint scale update until the cost
        changes by less than ``tol`` (relative).

    Parameters
    ----------
    model : RobotModel
        Prior / placeholder model (kinematics, prior parameters, Coulomb smoothing).
    gram : TorqueGram
        Data (:func:`torque_gram`).
    fit_scale : bool
        False: the logged torques are N m (``s = 1`` fixed).
    prior_weight, scale_weight : float
        Prior weights (see above).
    min_armature : float
        Lower bound on the armature [kg m^2] (``"lmi"``).
    friction_terms : tuple of str
        Friction terms fitted (subset of viscous, coulomb, offset); the others keep
        ``model``'s values (``"placeholder"`` and ``"lmi"`` only).
    nonnegative_friction : bool
        Constrain viscous and Coulomb coefficients to be >= 0 (``"lmi"``).
    base : BaseParameters, optional
        Precomputed base parameters of ``model``.

    Returns
    -------
    Identification
    """
    if method not in ("placeholder", "ls", "lmi"):
        raise ReachsetError(f"unknown identification method {method!r}")
    n = model.nv
    N = gram.N
    if N < 20 * n:
        raise ReachsetError(f"identify: {N} samples are too few")
    base = base or BaseParameters.from_model(model)
    theta0 = parameter_vector(model)
    terms = tuple(friction_terms)
    if set(terms) - {"viscous", "coulomb", "offset"}:
        raise ReachsetError(f"unknown friction terms {terms}")
    if method == "ls" and len(terms) != 3:
        raise ReachsetError("method 'ls' fits all friction terms")
    theta, s = _stage1(model, gram, theta0, fit_scale, terms)
    rms1 = gram.rms(theta, s)
    settings = {"prior_weight": prior_weight, "scale_weight": scale_weight,
                "friction_terms": list(terms), "nonnegative_friction": nonnegative_friction,
                "placeholder_rms": rms1.tolist(), "placeholder_scale": s.tolist()}
    if method == "ls":
        data = _WeightedData.of(gram, rms1, s, scale_weight)
        theta, s = _fit_ls(data, base=base, theta0=theta0, prior_weight=prior_weight, fit_scale=fit_scale,
                           settings=settings)
    elif method == "lmi":
        data = _WeightedData.of(gram, rms1, s, scale_weight)
        theta, s = _fit_lmi(data, model=model, theta0=theta0, prior_weight=prior_weight,
                            min_armature=min_armature, terms=terms, nonnegative_friction=nonnegative_friction,
                            fit_scale=fit_scale, max_iter=max_iter, tol=tol, settings=settings)
    ident = with_parameters(model, theta, torque_scale=s, source=f"identified ({method})")
    return Identification(model=ident, theta=theta, beta=base.base(theta), base=base, torque_scale=s,
                          rms=gram.rms(theta, s), samples=N, method=method, settings=settings)


@dataclass(frozen=True, kw_only=True)
class _WeightedData:
    """The data of the second stage of :func:`identify_inertial`: the gram's rows of joint j
    weighted by the inverse squared residual RMS of the placeholder stage, and the prior on
    the log torque scales (``rho0``: the placeholder stage's, implausible ones replaced by
    the median)."""

    Gw: np.ndarray
    cw: np.ndarray
    uuw: np.ndarray
    rho0: np.ndarray
    N: int
    scale_weight: float

    @classmethod
    def of(cls, gram, rms1, s, scale_weight):
        w2 = 1.0 / np.maximum(rms1, 1e-9 * rms1.max()) ** 2
        ok = s < 1e5
        rho0 = np.log(s)
        rho0[~ok] = np.median(rho0[ok]) if ok.any() else 0.0
        return cls(Gw=gram.G * w2[:, None, None], cw=gram.c * w2[:, None], uuw=gram.uu * w2, rho0=rho0,
                   N=gram.N, scale_weight=scale_weight)

    def data_cost(self, th, rho):
        gi = np.exp(-rho)
        return float(np.sum(gi ** 2 * np.einsum("p,npq,q->n", th, self.Gw, th)
                            - 2 * gi * (self.cw @ th) + self.uuw))

    def scale_prior(self, rho):
        return self.scale_weight * self.N * float(np.sum((rho - self.rho0) ** 2))


def _fit_ls(data: _WeightedData, *, base, theta0, prior_weight, fit_scale, settings):
    """Method ``"ls"`` of :func:`identify_inertial`: base parameters by ridge least squares,
    scales by variable projection. Returns ``(theta, s)``; ``settings`` gets the iterations."""
    Gw, cw, uuw, rho0 = data.Gw, data.cw, data.uuw, data.rho0
    ind = base.independent
    Gb, cb = Gw[:, ind][:, :, ind], cw[:, ind]
    beta0 = base.base(theta0)
    D2 = np.einsum("npp,n->p", Gb, np.exp(-2 * rho0))
    D2 = np.maximum(D2, 1e-9 * D2.max())

    def solve(rho):
        gi = np.exp(-rho)
        H = np.einsum("n,npq->pq", gi ** 2, Gb) + prior_weight * np.diag(D2)
        return np.linalg.solve(H, np.einsum("n,np->p", gi, cb)
                               + prior_weight * D2 * beta0)

    def cost(rho):
        b = solve(rho)
        gi = np.exp(-rho)
        dc = np.sum(gi ** 2 * np.einsum("p,npq,q->n", b, Gb, b) - 2 * gi * (cb @ b) + uuw)
        return dc + prior_weight * np.sum(D2 * (b - beta0) ** 2) + data.scale_prior(rho)

    rho = rho0
    if fit_scale:
        import scipy.optimize  # lazy: scipy's start-up (issue 38.1)
        sol = scipy.optimize.minimize(cost, rho0, method="L-BFGS-B",
                                      bounds=[(r - 5.0, r + 5.0) for r in rho0])
        rho = sol.x
        settings.update(iterations=int(sol.nit))
    return base.standard(solve(rho), theta0), np.exp(rho)


def _fit_lmi(data: _WeightedData, *, model, theta0, prior_weight, min_armature, terms, nonnegative_friction,
             fit_scale, max_iter, tol, settings):
    """Method ``"lmi"`` of :func:`identify_inertial`: the physically consistent fit for fixed
    scales (:func:`_lmi_step`), the scales by L-BFGS-B over its profile. Returns ``(theta, s)``;
    ``settings`` gets the solver's report."""
    Gw, cw, rho0, N = data.Gw, data.cw, data.rho0, data.N
    n = model.nv
    D2 = np.einsum("npp,n->p", Gw, np.exp(-2 * rho0))
    D2 = np.maximum(D2, 1e-6 * D2.max())
    cache = {}
    last = {}
    fc = _friction_cols(n, ("viscous", "coulomb", "offset"))
    fixed = np.concatenate([fc[t] for t in fc if t not in terms] + [np.zeros(0, int)])
    nonneg = (np.concatenate([fc["viscous"], fc["coulomb"]]) if nonnegative_friction
              else np.zeros(0, int))

    def profile(rho):
        """Cost with theta optimal for these scales, and its exact gradient
        (envelope theorem: the constraints do not depend on the scales)."""
        gi = np.exp(-rho)
        H = np.einsum("n,npq->pq", gi ** 2, Gw)
        g = np.einsum("n,np->p", gi, cw)
        th = _lmi_step(model, H=H, g=g, theta_ref=theta0, D2=D2, prior_weight=prior_weight,
                       min_armature=min_armature, cache=cache, fixed=fixed, nonneg=nonneg)
        last["theta"] = th
        a = np.einsum("p,npq,q->n", th, Gw, th)
        b = cw @ th
        total = (data.data_cost(th, rho) + data.scale_prior(rho)
                 + prior_weight * float(np.sum(D2 * (th - theta0) ** 2)))
        grad = (-2 * gi ** 2 * a + 2 * gi * b + 2 * data.scale_weight * N * (rho - rho0))
        return total / N, grad / N      # per sample: O(1) numbers for L-BFGS

    rho = rho0.copy()
    if fit_scale:
        import scipy.optimize  # lazy: scipy's start-up (issue 38.1)
        sol = scipy.optimize.minimize(profile, rho0, jac=True, method="L-BFGS-B",
                                      bounds=[(r - 5.0, r + 5.0) for r in rho0],
                                      options={"maxiter": max_iter, "ftol": tol,
                                               "gtol": 1e-9})
        rho = sol.x
        settings.update(iterations=int(sol.nit), evaluations=int(sol.nfev),
                        converged=bool(sol.success), message=str(sol.message))
    profile(rho)
    settings.update(min_armature=min_armature)
    return last["theta"], np.exp(rho)


def predict_logged(model: RobotModel, data: pin.Data, Q, QD, QDD) -> np.ndarray:
    """Logged torque predicted by ``model``: ``(M qdd + psi) / torque_scale`` (N, n)."""
    Q, QD, QDD = (np.atleast_2d(np.asarray(x, dtype=np.float64)) for x in (Q, QD, QDD))
    return np.stack([feedback_linearization(model, data, Q[k], QD[k], QDD[k])
                     for k in range(len(Q))]) / model.torque_scale
