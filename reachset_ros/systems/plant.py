"""Discrete-time linear plant models (paper eq. ``discreteSystem`` and Appendix A).

``x[k+1] = A x[k] + B u[k] + w[k]``, ``y[k] = C x[k] + D u[k] + v[k]`` with
``w[k] in W = (c_W, G'_W diag(alpha_W))`` and ``v[k] in V = (c_V, G'_V diag(alpha_V))``.
:class:`LinearPlant` stores the unscaled generator matrices ``G'_W`` (``Gw``) and ``G'_V``
(``Gv``); the scalings ``alpha`` are identified from data and are passed separately.

Pure numpy; no ROS import.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..sets.zonotope import Zonotope

__all__ = ["LinearPlant", "lwa4p_joint_plant", "lwa4p_robot_model"]


def _matrix(name, a, shape=None):
    a = np.array(a, dtype=float, copy=True)
    if a.ndim == 0:
        a = a.reshape(1, 1)
    elif a.ndim == 1:
        # a vector is a column when the row count is prescribed, else a row
        a = a.reshape(-1, 1) if shape is not None and shape[0] is not None else a.reshape(1, -1)
    if a.ndim != 2:
        raise ValueError(f"{name} must be a matrix, got {a.ndim} dimensions")
    if shape is not None:
        for got, want, ax in zip(a.shape, shape, ("rows", "columns")):
            if want is not None and got != want:
                raise ValueError(f"{name} has {got} {ax}, expected {want}")
    if not np.all(np.isfinite(a)):
        raise ValueError(f"{name} contains non-finite entries")
    a.setflags(write=False)
    return a


@dataclass(frozen=True, eq=False)
class LinearPlant:
    """A discrete-time linear plant with zonotopic disturbance generators (paper eq. ``discreteSystem``).

    Parameters
    ----------
    A : array_like, (n, n)
    B : array_like, (n, m)
    C : array_like, (p, n)
    D : array_like, (p, m), optional
        Defaults to zeros.
    Gw : array_like, (n, gw)
        Unscaled process-disturbance generators ``G'_W``.
    Gv : array_like, (p, gv)
        Unscaled measurement-noise generators ``G'_V``.
    dt : float
        Sampling time in seconds.
    state_names : tuple of str, optional
        Defaults to ``("x0", "x1", ...)``.
    name : str

    Notes
    -----
    Immutable; arrays are read-only copies. Any output dimension ``p`` is allowed.
    """

    A: np.ndarray
    B: np.ndarray
    C: np.ndarray
    D: np.ndarray = None
    Gw: np.ndarray = None
    Gv: np.ndarray = None
    dt: float = 0.004
    state_names: tuple = None
    name: str = "plant"
    input_names: tuple = field(default=None)
    output_names: tuple = field(default=None)

    def __post_init__(self):
        A = _matrix("A", self.A)
        n = A.shape[0]
        if A.shape != (n, n):
            raise ValueError(f"A must be square, got shape {A.shape}")
        B = _matrix("B", self.B, (n, None))
        C = _matrix("C", self.C, (None, n))
        m, p = B.shape[1], C.shape[0]
        D = _matrix("D", np.zeros((p, m)) if self.D is None else self.D, (p, m))
        Gw = _matrix("Gw", np.eye(n) if self.Gw is None else self.Gw, (n, None))
        Gv = _matrix("Gv", np.eye(p) if self.Gv is None else self.Gv, (p, None))
        if not (np.isfinite(self.dt) and self.dt > 0):
            raise ValueError(f"sampling time dt must be positive, got {self.dt}")
        names = tuple(self.state_names) if self.state_names is not None else tuple(f"x{i}" for i in range(n))
        if len(names) != n:
            raise ValueError(f"{len(names)} state names for {n} states")
        inames = tuple(self.input_names) if self.input_names is not None else tuple(f"u{i}" for i in range(m))
        onames = tuple(self.output_names) if self.output_names is not None else tuple(f"y{i}" for i in range(p))
        if len(inames) != m or len(onames) != p:
            raise ValueError("input/output names do not match B/C dimensions")
        for k, v in dict(A=A, B=B, C=C, D=D, Gw=Gw, Gv=Gv, dt=float(self.dt), state_names=names,
                         input_names=inames, output_names=onames).items():
            object.__setattr__(self, k, v)

    @property
    def n_states(self):
        """Number of states ``n``."""
        return self.A.shape[0]

    @property
    def n_inputs(self):
        """Number of inputs ``m``."""
        return self.B.shape[1]

    @property
    def n_outputs(self):
        """Number of outputs ``p``."""
        return self.C.shape[0]

    def W(self, alpha_w, c_w=None):
        """Process-disturbance zonotope ``(c_W, G'_W diag(alpha_W))`` (paper eq. ``discreteSystem``)."""
        a = _alpha(alpha_w, self.Gw.shape[1], "alpha_w")
        c = np.zeros(self.n_states) if c_w is None else np.asarray(c_w, float)
        return Zonotope(c, self.Gw * a)

    def V(self, alpha_v, c_v=None):
        """Measurement-noise zonotope ``(c_V, G'_V diag(alpha_V))`` (paper eq. ``discreteSystem``)."""
        a = _alpha(alpha_v, self.Gv.shape[1], "alpha_v")
        c = np.zeros(self.n_outputs) if c_v is None else np.asarray(c_v, float)
        return Zonotope(c, self.Gv * a)

    def step(self, x, u, w=None):
        """One step of the difference equation: ``A x + B u + w``."""
        x1 = self.A @ np.asarray(x, float) + self.B @ np.atleast_1d(np.asarray(u, float))
        return x1 if w is None else x1 + w

    def output(self, x, u, v=None):
        """Output equation ``C x + D u + v``."""
        y = self.C @ np.asarray(x, float) + self.D @ np.atleast_1d(np.asarray(u, float))
        return y if v is None else y + v


def _alpha(alpha, k, name):
    a = np.atleast_1d(np.asarray(alpha, dtype=float))
    if a.shape == (1,) and k != 1:
        a = np.full(k, a[0])
    if a.shape != (k,):
        raise ValueError(f"{name} must have {k} entries, got {a.shape[0]}")
    if np.any(~np.isfinite(a)) or np.any(a < 0):
        raise ValueError(f"{name} must be finite and non-negative, got {a.tolist()}")
    return a


def lwa4p_joint_plant(dt=0.004, name="lwa4p_joint"):
    """Per-joint plant of the feedback-linearized LWA-4P (paper Appendix A).

    State ``x_p = [q[k-1], q[k], qdot[k], d[k], u_p[k-1]]``, input ``u_p`` (the
    feedback-linearized acceleration command), output ``y_p[k] = q[k-1] + v[k]``
    (``C_p = [1, 0, 0, 0, 0]``: input and output each carry one sample of delay);
    ``d`` is a constant disturbance (``qddot = u_p + d``, ``ddot = 0``).

    ``G'_W = [[0, 0], [dt, dt^2/2], [0, dt], [0, 0], [0, 0]]`` (velocity and acceleration
    disturbances, scaled by ``alpha_W``), ``G'_V = [[1]]``.

    Parameters
    ----------
    dt : float
        Sampling time (paper: 0.004 s).

    Returns
    -------
    LinearPlant
    """
    h = float(dt)
    A = [[0, 1, 0, 0, 0],
         [0, 1, h, h * h / 2, h * h / 2],
         [0, 0, 1, h, h],
         [0, 0, 0, 1, 0],
         [0, 0, 0, 0, 0]]
    B = [[0], [0], [0], [0], [1]]
    C = [[1, 0, 0, 0, 0]]
    Gw = [[0, 0], [h, h * h / 2], [0, h], [0, 0], [0, 0]]
    return LinearPlant(A=A, B=B, C=C, Gw=Gw, Gv=[[1.0]], dt=h,
                       state_names=("q_prev", "q", "qd", "d", "u_prev"), name=name,
                       input_names=("u_p",), output_names=("y_p",))


def lwa4p_robot_model(dt=0.004, name="lwa4p_robot"):
    """The 4-state nominal robot model of paper eq. ``robotLinearDynamics``, used for LQR/Kalman design.

    State ``x_r = [q[k-1], q[k], qdot[k], u_r[k-1]]``, output ``q[k-1]``. ``Gw`` is the
    Appendix-A generator matrix without the disturbance-state row:
    ``[[0, 0], [dt, dt^2/2], [0, dt], [0, 0]]``.

    Parameters
    ----------
    dt : float

    Returns
    -------
    LinearPlant
    """
    h = float(dt)
    A = [[0, 1, 0, 0],
         [0, 1, h, h * h / 2],
         [0, 0, 1, h],
         [0, 0, 0, 0]]
    return LinearPlant(A=A, B=[[0], [0], [0], [1]], C=[[1, 0, 0, 0]],
                       Gw=[[0, 0], [h, h * h / 2], [0, h], [0, 0]], Gv=[[1.0]], dt=h,
                       state_names=("q_prev", "q", "qd", "u_prev"), name=name,
                       input_names=("u_p",), output_names=("y_p",))
