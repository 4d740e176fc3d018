"""Linear feedback controllers acting on observer estimates.

Every controller is a static gain on the estimate error::

    u_p = u_ff + K (x_ref - x_hat)

where ``x_hat`` are the observer's estimates named ``estimate_names`` and ``x_ref`` the
reference in the same coordinates (zero for components without a reference, e.g. the
disturbance estimate ``d``). With the reference and feedforward set to zero (the
superposition split of paper Sec. III-A) this is ``u_p = -K x_hat``.

* :func:`static_feedback` - paper eq. ``staticfeedback``: ``u_p = qdd_d + w^2 (q_d - q_hat) + 2 z w (qd_d - qd_hat)``;
* :func:`compensated_feedback` - paper eq. ``feedbackLaw`` with the order of SPEC.md:
  ``u_p = qdd_d + w^2 (q_d - q_hat) + 2 z w (qd_d - qd_hat) - d_hat`` (the paper prints
  ``w^2`` and ``2 z w`` swapped; its Table III is reproduced only with this order);
* :func:`lqr` - discrete LQR on a plant model (paper Sec. IV-B);
* :class:`LinearController` - any user-given gain matrix.

Pure numpy/scipy; no ROS import.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .observers import kalman_filter, paper_lqg_covariances

__all__ = ["LinearController", "static_feedback", "compensated_feedback", "lqr_gain", "lqr",
           "lqg", "control_input"]


@dataclass(frozen=True, eq=False)
class LinearController:
    """Static linear feedback ``u = u_ff + K (x_ref - x_hat)``.

    Parameters
    ----------
    K : array_like, (m, ne)
        Gain on the named estimates.
    estimate_names : tuple of str
        Names of the estimates the columns of ``K`` act on; the closed loop matches them
        against the observer's ``estimate_names``.
    name : str
    params : dict
    """

    K: np.ndarray
    estimate_names: tuple
    name: str = "controller"
    params: dict = field(default_factory=dict)

    def __post_init__(self):
        K = np.array(self.K, dtype=float, copy=True)
        if K.ndim == 1:
            K = K.reshape(1, -1)
        names = tuple(self.estimate_names)
        if K.ndim != 2 or K.shape[1] != len(names):
            raise ValueError(f"controller gain of shape {K.shape} does not match {len(names)} estimate names")
        if not np.all(np.isfinite(K)):
            raise ValueError("controller gain contains non-finite entries")
        K.setflags(write=False)
        object.__setattr__(self, "K", K)
        object.__setattr__(self, "estimate_names", names)
        object.__setattr__(self, "params", dict(self.params))

    @property
    def n_inputs(self):
        """Number of plant inputs ``m``."""
        return self.K.shape[0]

    def gain_for(self, names):
        """The gain re-ordered onto estimates ``names`` (zero columns for unused ones).

        Raises
        ------
        ValueError
            If the controller needs an estimate that ``names`` lacks.
        """
        names = tuple(names)
        Kf = np.zeros((self.K.shape[0], len(names)))
        for j, nm in enumerate(self.estimate_names):
            if nm not in names:
                if np.any(self.K[:, j] != 0):
                    raise ValueError(f"controller {self.name!r} needs the estimate {nm!r}, which the "
                                     f"observer does not provide (it estimates {', '.join(names)})")
                continue
            Kf[:, names.index(nm)] += self.K[:, j]
        return Kf


def control_input(ctrl, x_hat, x_ref=None, u_ff=0.0):
    """``u = u_ff + K (x_ref - x_hat)`` with ``x_hat`` ordered as ``ctrl.estimate_names``."""
    x_hat = np.atleast_1d(np.asarray(x_hat, dtype=float))
    e = -x_hat if x_ref is None else np.atleast_1d(np.asarray(x_ref, dtype=float)) - x_hat
    return np.atleast_1d(np.asarray(u_ff, dtype=float)) + ctrl.K @ e


def _check(omega, zeta):
    if not (np.isfinite(omega) and omega > 0):
        raise ValueError(f"natural frequency omega must be positive, got {omega}")
    if not (np.isfinite(zeta) and zeta > 0):
        raise ValueError(f"damping ratio zeta must be positive, got {zeta}")


def static_feedback(omega, zeta):
    """Static feedback, paper eq. ``staticfeedback``: ``K = [w^2, 2 z w]`` on ``(q_hat, qd_hat)``.

    Parameters
    ----------
    omega : float
        Natural frequency ``w`` (``k_p = w^2``).
    zeta : float
        Damping ratio ``z`` (``k_d = 2 z w``).

    Returns
    -------
    LinearController
    """
    _check(omega, zeta)
    return LinearController(K=[[omega ** 2, 2 * zeta * omega]], estimate_names=("q", "qd"), name="static",
                            params=dict(omega=float(omega), zeta=float(zeta)))


def compensated_feedback(omega, zeta):
    """Disturbance-compensated feedback (paper eq. ``feedbackLaw``, term order as in SPEC.md).

    ``u_p = qdd_d + w^2 (q_d - q_hat) + 2 z w (qd_d - qd_hat) - d_hat``, i.e.
    ``K = [w^2, 2 z w, 1]`` on ``(q_hat, qd_hat, d_hat)`` with ``d_ref = 0``.

    Returns
    -------
    LinearController
    """
    _check(omega, zeta)
    return LinearController(K=[[omega ** 2, 2 * zeta * omega, 1.0]], estimate_names=("q", "qd", "d"),
                            name="compensated", params=dict(omega=float(omega), zeta=float(zeta)))


def lqr_gain(A, B, Q, R):
    """Discrete infinite-horizon LQR gain ``K = (R + B^T P B)^-1 B^T P A``.

    ``P`` solves the DARE (``scipy.linalg.solve_discrete_are``); ``u = -K x`` minimises
    ``sum x^T Q x + u^T R u`` (paper eq. ``LQR``).
    """
    A, B = np.atleast_2d(A), np.atleast_2d(B)
    Q, R = np.atleast_2d(np.asarray(Q, float)), np.atleast_2d(np.asarray(R, float))
    from scipy.linalg import solve_discrete_are  # lazy: scipy.linalg's start-up (issue 38.1)
    P = solve_discrete_are(A, B, Q, R)
    return np.linalg.solve(R + B.T @ P @ B, B.T @ P @ A)


def lqr(model, Q, r):
    """LQR state feedback on a plant model (paper Sec. IV-B).

    Parameters
    ----------
    model : LinearPlant
        Design model; the paper uses the 4-state robot model (eq. ``robotLinearDynamics``) with
        ``Q = diag(1000, 1000, 0.01, r)``.
    Q : array_like, (n, n)
    r : float or array_like (m, m)

    Returns
    -------
    LinearController
        Acting on estimates named like the model's states.
    """
    R = np.atleast_2d(np.asarray(r, dtype=float))
    if np.any(np.linalg.eigvalsh((R + R.T) / 2) <= 0):
        raise ValueError(f"LQR input weight r must be positive definite, got {r}")
    K = lqr_gain(model.A, model.B, Q, R)
    return LinearController(K=K, estimate_names=tuple(model.state_names), name="lqr",
                            params=dict(r=np.asarray(r).tolist()))


def lqg(model, r, alpha_w, alpha_v, Q=None, form="predictor", squared=True):
    """LQG baseline of the paper (Sec. IV-B): steady-state Kalman filter + LQR.

    Parameters
    ----------
    model : LinearPlant
        Design model (paper: 4-state robot model, :func:`~reachset_ros.systems.plant.lwa4p_robot_model`).
    r : float
        Input weight.
    alpha_w, alpha_v : array_like
        Disturbance scalings; the Kalman covariances are
        :func:`~reachset_ros.systems.observers.paper_lqg_covariances`.
    Q : array_like, optional
        State weight; default ``diag(1000, 1000, 0.01, r)`` as in the paper.
    form : {"predictor", "current"}
        Kalman estimate ``x[k|k-1]`` (MATLAB ``lqg`` default) or ``x[k|k]``.
    squared : bool
        Passed to :func:`~reachset_ros.systems.observers.paper_lqg_covariances`.

    Returns
    -------
    observer : LinearObserver
    controller : LinearController
    """
    if Q is None:
        if model.n_states != 4:
            raise ValueError("the paper's default Q = diag(1000, 1000, 0.01, r) needs a 4-state model")
        Q = np.diag([1000.0, 1000.0, 0.01, float(r)])
    Sw, Sv = paper_lqg_covariances(model, alpha_w, alpha_v, squared=squared)
    return kalman_filter(model, Sw, Sv, form=form), lqr(model, Q, r)
