"""Linear observers: high-gain (HG), extended-state (ESO) and steady-state Kalman filter.

Every observer is an immutable discrete-time linear system with inputs ``(y, u_p)`` and
the state estimate as output (paper Sec. II-C: the closed loop must stay linear)::

    xo[k+1]   = Ao xo[k] + Bo_y y[k] + Bo_u u[k]
    x_hat[k]  = Co xo[k] + Do_y y[k] + Do_u u[k]

``estimate_names`` names the components of ``x_hat`` (``"q"``, ``"qd"``, ``"d"``, ...);
controllers and the closed loop match estimates by these names.

Continuous-time observers are discretised with the bilinear (Tustin) transform in its
state-space form with direct feedthrough (as ``scipy.signal.cont2discrete(...,
method="bilinear")``): the estimate ``x_hat[k]`` is the trapezoidal-rule solution at
``t = k dt`` and therefore depends on the *current* inputs ``y[k]`` (and ``u[k]``).
When ``Do_u != 0`` (e.g. the ESO fed the current plant input) the estimate and the
control law form an algebraic loop; :func:`reachset_ros.systems.closedloop.close_loop` and
:func:`reachset_ros.systems.closedloop.closed_loop_tick` solve it exactly.

Pure numpy/scipy; no ROS import.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

__all__ = ["LinearObserver", "ObserverState", "bilinear", "high_gain_observer",
           "extended_state_observer", "kalman_filter", "paper_lqg_covariances",
           "observer_output", "observer_update"]


def _ro(a, shape, name):
    a = np.array(a, dtype=float, copy=True)
    if a.shape != shape:
        raise ValueError(f"observer matrix {name} has shape {a.shape}, expected {shape}")
    if not np.all(np.isfinite(a)):
        raise ValueError(f"observer matrix {name} contains non-finite entries")
    a.setflags(write=False)
    return a


@dataclass(frozen=True, eq=False)
class LinearObserver:
    """Discrete-time linear observer with inputs ``(y, u)`` and output ``x_hat``.

    Parameters
    ----------
    Ao, Bo_y, Bo_u, Co, Do_y, Do_u : array_like
        Shapes ``(no, no)``, ``(no, p)``, ``(no, m)``, ``(ne, no)``, ``(ne, p)``, ``(ne, m)``.
    estimate_names : tuple of str
        Names of the ``ne`` estimates.
    dt : float
    name : str
    params : dict
        The design parameters (gains), for reports.
    """

    Ao: np.ndarray
    Bo_y: np.ndarray
    Bo_u: np.ndarray
    Co: np.ndarray
    Do_y: np.ndarray
    Do_u: np.ndarray
    estimate_names: tuple
    dt: float = 0.004
    name: str = "observer"
    params: dict = field(default_factory=dict)

    def __post_init__(self):
        Ao = np.asarray(self.Ao, dtype=float)
        no = Ao.shape[0]
        By = np.atleast_2d(np.asarray(self.Bo_y, dtype=float))
        Bu = np.atleast_2d(np.asarray(self.Bo_u, dtype=float))
        if By.shape[0] != no:
            By = By.T
        if Bu.shape[0] != no:
            Bu = Bu.T
        p, m = By.shape[1], Bu.shape[1]
        names = tuple(self.estimate_names)
        ne = len(names)
        vals = dict(Ao=_ro(Ao, (no, no), "Ao"), Bo_y=_ro(By, (no, p), "Bo_y"),
                    Bo_u=_ro(Bu, (no, m), "Bo_u"), Co=_ro(self.Co, (ne, no), "Co"),
                    Do_y=_ro(self.Do_y, (ne, p), "Do_y"), Do_u=_ro(self.Do_u, (ne, m), "Do_u"),
                    estimate_names=names, params=dict(self.params), dt=float(self.dt))
        if len(set(names)) != ne:
            raise ValueError(f"duplicate estimate names {names}")
        for k, v in vals.items():
            object.__setattr__(self, k, v)

    @property
    def n_states(self):
        """Number of internal observer states."""
        return self.Ao.shape[0]

    def index(self, name):
        """Position of estimate ``name`` in ``x_hat``."""
        try:
            return self.estimate_names.index(name)
        except ValueError:
            raise ValueError(f"observer {self.name!r} has no estimate {name!r} "
                             f"(it estimates {', '.join(self.estimate_names)})") from None

    def initial_state(self, x_hat=None, y=None, u=None):
        """Internal state ``xo`` whose estimate is ``x_hat`` for the given ``y``, ``u``.

        Solves ``Co xo = x_hat - Do_y y - Do_u u`` in the least-squares sense; zeros by default.
        """
        if x_hat is None:
            return ObserverState(self, np.zeros(self.n_states))
        rhs = np.asarray(x_hat, float).copy()
        if y is not None:
            rhs -= self.Do_y @ np.atleast_1d(np.asarray(y, float))
        if u is not None:
            rhs -= self.Do_u @ np.atleast_1d(np.asarray(u, float))
        xo = np.linalg.lstsq(self.Co, rhs, rcond=None)[0]
        return ObserverState(self, xo)

    def start_state(self, y0):
        """The state an observer starts from at its first measurement ``y0`` (a scalar
        position): the estimate is ``q = y0`` and zero for every other component, with a
        zero plant input (``observer_node`` starts and restarts here; the closed loop's
        transient from this state is what :func:`~reachset_ros.systems.closedloop.settling_ticks`
        measures)."""
        x_hat = np.zeros(len(self.estimate_names))
        x_hat[self.index("q")] = float(y0)
        return self.initial_state(x_hat, [float(y0)], [0.0] * self.Bo_u.shape[1])


def observer_output(obs, xo, y, u):
    """Estimate ``x_hat = Co xo + Do_y y + Do_u u``."""
    return obs.Co @ xo + obs.Do_y @ y + obs.Do_u @ u


def observer_update(obs, xo, y, u):
    """Next internal state ``xo[k+1] = Ao xo + Bo_y y + Bo_u u``."""
    return obs.Ao @ xo + obs.Bo_y @ y + obs.Bo_u @ u


@dataclass(frozen=True, eq=False)
class ObserverState:
    """Immutable tick-by-tick state of a :class:`LinearObserver` (used by the observer node).

    Examples
    --------
    >>> st = obs.initial_state()
    >>> x_hat = st.estimate(y, u)
    >>> st = st.advance(y, u)
    """

    observer: LinearObserver
    x: np.ndarray

    def __post_init__(self):
        x = np.array(self.x, dtype=float, copy=True).reshape(self.observer.n_states)
        x.setflags(write=False)
        object.__setattr__(self, "x", x)

    def estimate(self, y, u):
        """Estimate at this tick for measurement ``y`` and plant input ``u``."""
        return observer_output(self.observer, self.x, np.atleast_1d(np.asarray(y, float)),
                               np.atleast_1d(np.asarray(u, float)))

    def partial_estimate(self, y):
        """Estimate without the plant-input feedthrough: ``Co xo + Do_y y``.

        The full estimate is ``partial_estimate(y) + Do_u u``; with ``Do_u != 0`` the
        control law must solve for ``u`` (see :func:`reachset_ros.systems.closedloop.closed_loop_tick`).
        """
        return self.observer.Co @ self.x + self.observer.Do_y @ np.atleast_1d(np.asarray(y, float))

    def advance(self, y, u):
        """The state at the next tick after measurement ``y`` and input ``u``."""
        return ObserverState(self.observer, observer_update(
            self.observer, self.x, np.atleast_1d(np.asarray(y, float)),
            np.atleast_1d(np.asarray(u, float))))


def bilinear(Ac, Bc, Cc, Dc, dt):
    """Bilinear (Tustin) discretisation in state-space form with direct feedthrough.

    ``M = I - Ac dt/2``, ``Ad = M^-1 (I + Ac dt/2)``, ``Bd = M^-1 Bc dt``,
    ``Cd = Cc M^-1``, ``Dd = Dc + Cc M^-1 Bc dt/2`` (identical to
    ``scipy.signal.cont2discrete(..., method="bilinear")``). The output ``Cd xd[k] + Dd u[k]``
    equals the trapezoidal-rule solution of the continuous system at ``t = k dt``.

    Parameters
    ----------
    Ac, Bc, Cc, Dc : array_like
        Continuous-time system.
    dt : float

    Returns
    -------
    Ad, Bd, Cd, Dd : ndarray
    """
    Ac, Bc, Cc, Dc = (np.atleast_2d(np.asarray(a, dtype=float)) for a in (Ac, Bc, Cc, Dc))
    n = Ac.shape[0]
    M = np.eye(n) - 0.5 * dt * Ac
    Ad = np.linalg.solve(M, np.eye(n) + 0.5 * dt * Ac)
    Bd = np.linalg.solve(M, dt * Bc)
    Cd = np.linalg.solve(M.T, Cc.T).T
    Dd = Dc + 0.5 * (Cc @ Bd)
    return Ad, Bd, Cd, Dd


def _check_positive(**kw):
    for k, v in kw.items():
        if not (np.isfinite(v) and v > 0):
            raise ValueError(f"observer gain {k} must be positive and finite, got {v}")


def high_gain_observer(h1, h2, eps=0.01, dt=0.004):
    """High-gain observer of the paper (Sec. IV-A, after Nicosia & Tomei), Tustin-discretised.

    Continuous time: ``d/dt [q_hat, qd_hat] = [[-h1/eps, 1], [-h2/eps^2, 0]] [q_hat, qd_hat]
    + [h1/eps, h2/eps^2] y_p``. Discretised with :func:`bilinear`; the estimate includes
    the direct feedthrough of the current measurement. The observer does not use ``u_p``.

    Parameters
    ----------
    h1, h2 : float
        Gains (paper Table II experiment: ``h1 = 15``, ``h2 = 30``).
    eps : float
        High-gain parameter (paper: 0.01).
    dt : float

    Returns
    -------
    LinearObserver
        Estimates ``("q", "qd")``, inputs ``y`` (1) and ``u`` (1, unused).
    """
    _check_positive(h1=h1, h2=h2, eps=eps, dt=dt)
    Ac = np.array([[-h1 / eps, 1.0], [-h2 / eps ** 2, 0.0]])
    By = np.array([[h1 / eps], [h2 / eps ** 2]])
    Bc = np.hstack([By, np.zeros((2, 1))])
    Ad, Bd, Cd, Dd = bilinear(Ac, Bc, np.eye(2), np.zeros((2, 2)), dt)
    return LinearObserver(Ao=Ad, Bo_y=Bd[:, :1], Bo_u=Bd[:, 1:], Co=Cd, Do_y=Dd[:, :1], Do_u=Dd[:, 1:],
                          estimate_names=("q", "qd"), dt=dt, name="hg",
                          params=dict(h1=float(h1), h2=float(h2), eps=float(eps)))


def extended_state_observer(l1, l2, l3, eps=0.01, dt=0.004, u_input="previous"):
    """Extended-state observer of the paper (Sec. IV-C, after Chen et al.), Tustin-discretised.

    Continuous time, with ``e = y_p - q_hat``::

        d/dt q_hat  = qd_hat + (l1/eps) e
        d/dt qd_hat = d_hat + u + (l2/eps^2) e
        d/dt d_hat  = (l3/eps^3) e

    discretised with :func:`bilinear` for the inputs ``(y_p, u)`` (trapezoidal rule over
    both; the estimate at tick ``k`` includes the feedthrough of ``y_p[k]`` and of ``u``).
    Which plant input is ``u`` at tick ``k``:

    * ``u_input="previous"`` (default): ``u = u_p[k-1]``, the input that actually acts on
      the plant at tick ``k`` (Appendix A: one sample of input delay). The observer keeps
      ``u_p[k-1]`` as an extra internal state, so it is still fed ``(y_p[k], u_p[k])``
      and has ``Do_u = 0`` (no algebraic loop). With ``eps = 0.01`` this reproduces the
      ESO rows of the paper's Table III to within 0.1 % (test/systems/test_closedloop.py).
    * ``u_input="current"``: ``u = u_p[k]``. Then ``Do_u != 0`` and the compensated law
      ``u_p = ... - d_hat`` closes an algebraic loop, solved exactly by
      :func:`reachset_ros.systems.closedloop.close_loop` / :func:`~reachset_ros.systems.closedloop.closed_loop_tick`.
      (Reproduces Table III axes 1-4 at ``eps = 0.01`` but gives 11-27 % larger sets for
      axes 5-6.)

    Parameters
    ----------
    l1, l2, l3 : float
        Gains (paper Table III).
    eps : float
        Scaling of the gains (0.01 reproduces the paper).
    dt : float
    u_input : {"previous", "current"}

    Returns
    -------
    LinearObserver
        Estimates ``("q", "qd", "d")``, inputs ``y_p`` (1) and ``u_p`` (1).
    """
    _check_positive(l1=l1, l2=l2, l3=l3, eps=eps, dt=dt)
    L = np.array([[l1 / eps], [l2 / eps ** 2], [l3 / eps ** 3]])
    Ac = np.array([[0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [0.0, 0.0, 0.0]]) - L @ np.array([[1.0, 0.0, 0.0]])
    Bc = np.hstack([L, np.array([[0.0], [1.0], [0.0]])])
    Ad, Bd, Cd, Dd = bilinear(Ac, Bc, np.eye(3), np.zeros((3, 2)), dt)
    params = dict(l1=float(l1), l2=float(l2), l3=float(l3), eps=float(eps), u_input=u_input)
    names = ("q", "qd", "d")
    if u_input == "current":
        return LinearObserver(Ao=Ad, Bo_y=Bd[:, :1], Bo_u=Bd[:, 1:], Co=Cd, Do_y=Dd[:, :1], Do_u=Dd[:, 1:],
                              estimate_names=names, dt=dt, name="eso", params=params)
    if u_input != "previous":
        raise ValueError(f"u_input must be 'previous' or 'current', got {u_input!r}")
    # internal state [xi; u_prev]: the Tustin system is driven by u_p[k-1]
    Ao = np.block([[Ad, Bd[:, 1:]], [np.zeros((1, 4))]])
    By = np.vstack([Bd[:, :1], [[0.0]]])
    Bu = np.vstack([np.zeros((3, 1)), [[1.0]]])
    Co = np.hstack([Cd, Dd[:, 1:]])
    return LinearObserver(Ao=Ao, Bo_y=By, Bo_u=Bu, Co=Co, Do_y=Dd[:, :1], Do_u=np.zeros((3, 1)),
                          estimate_names=names, dt=dt, name="eso", params=params)


def kalman_filter(model, Sw, Sv, form="predictor"):
    """Steady-state Kalman filter for a :class:`~reachset_ros.systems.plant.LinearPlant` model.

    The filter assumes ``x[k+1] = A x + B u + w``, ``y = C x + D u + v`` with
    ``cov(w) = Sw``, ``cov(v) = Sv``; the error covariance ``P`` solves the filter DARE
    (``scipy.linalg.solve_discrete_are(A.T, C.T, Sw, Sv)``).

    Parameters
    ----------
    model : LinearPlant
        Design model (the paper uses the 4-state robot model, eq. ``robotLinearDynamics``).
    Sw : array_like, (n, n)
    Sv : array_like, (p, p)
    form : {"predictor", "current"}
        ``"predictor"``: the estimate is ``x[k|k-1]`` (MATLAB ``lqg``'s default for
        discrete time); ``"current"``: ``x[k|k]``, using the current measurement.

    Returns
    -------
    LinearObserver
        Estimates named like the model's states, inputs ``(y, u)``.
    """
    A, B, C, D = model.A, model.B, model.C, model.D
    n, p = A.shape[0], C.shape[0]
    Sw = np.atleast_2d(np.asarray(Sw, dtype=float))
    Sv = np.atleast_2d(np.asarray(Sv, dtype=float))
    if Sw.shape != (n, n) or Sv.shape != (p, p):
        raise ValueError(f"Kalman covariances have shapes {Sw.shape}, {Sv.shape}; expected {(n, n)}, {(p, p)}")
    scale = float(np.max(np.abs(Sv))) or float(np.max(np.abs(Sw))) or 1.0
    from scipy.linalg import solve_discrete_are  # lazy: scipy.linalg's start-up (issue 38.1)
    P = solve_discrete_are(A.T, C.T, Sw / scale, Sv / scale) * scale
    S = C @ P @ C.T + Sv
    M = np.linalg.solve(S.T, (P @ C.T).T).T  # innovation gain P C^T S^-1
    I = np.eye(n)
    if form == "predictor":
        Lp = A @ M
        Ao, By, Bu = A - Lp @ C, Lp, B - Lp @ D
        Co, Dy, Du = I, np.zeros((n, p)), np.zeros((n, B.shape[1]))
    elif form == "current":
        Co, Dy, Du = I - M @ C, M, -M @ D
        Ao, By, Bu = A @ Co, A @ M, B - A @ M @ D
    else:
        raise ValueError(f"unknown Kalman filter form {form!r} (use 'predictor' or 'current')")
    return LinearObserver(Ao=Ao, Bo_y=By, Bo_u=Bu, Co=Co, Do_y=Dy, Do_u=Du, estimate_names=tuple(model.state_names),
                          dt=model.dt, name="kalman", params=dict(form=form))


def paper_lqg_covariances(model, alpha_w, alpha_v, squared=True):
    """Noise covariances of the paper's LQG baseline (Sec. IV-B).

    The paper sets ``S_W = (1/3 G_W G_W^T)^2`` and ``S_V = (1/3 G_V G_V^T)^2`` with
    ``G_W = G'_W diag(alpha_W)`` ("the sets represent three standard deviations"); with
    ``squared=True`` this is taken literally (matrix square). ``squared=False`` gives the
    usual ``(G/3)(G/3)^T``.

    Returns
    -------
    Sw, Sv : ndarray
    """
    Gw = model.Gw * np.atleast_1d(np.asarray(alpha_w, dtype=float))
    Gv = model.Gv * np.atleast_1d(np.asarray(alpha_v, dtype=float))
    if squared:
        Sw = np.linalg.matrix_power(Gw @ Gw.T / 3.0, 2)
        Sv = np.linalg.matrix_power(Gv @ Gv.T / 3.0, 2)
    else:
        Sw = (Gw / 3.0) @ (Gw / 3.0).T
        Sv = (Gv / 3.0) @ (Gv / 3.0).T
    return Sw, Sv
