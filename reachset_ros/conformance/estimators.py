"""Initial-state estimators of test cases (paper Def. 3: the test case's x_p[0]).

How the initial state of a test case is estimated from data is a named, configurable
choice; it is stored in the model file, and the online monitor uses exactly the same
one, or the offline guarantees do not transfer. Every estimator here is *causal*: the
initial state of the test case starting at tick m uses only samples up to tick m.

The estimators are written with element-wise array operations only, so that the batch
computation over all test cases (``reachset check``) and the monitor's one-tick-at-a-time
computation give bitwise identical results.
"""
from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

from .. import defaults
from ..errors import ReachsetError
from .kernels import matvec

defaults.register("estimator", {
    "lsq_window": (3, "samples - 1 of the 'lsq' initial-state estimator (identify --estimator-window): on the real "
                      "LWA-4P (real-data protocol) 3 calibrated the same inflation as 'fd' (0.5) with 0 held-out "
                      "violations and caught a +6 rad/s^2 fault 0-12 ms sooner per joint; 4 calibrated 0.2 and left "
                      "5 held-out violating ticks on arm_5 (docs/performance.md, 'The lsq estimator')"),
}, owner=__name__)


#: the windows the windowed estimators accept, inclusive (:func:`_window`)
WINDOW_RANGE = {"lsq": (1, 1000), "observer": (1, 10_000)}


def _window(name, w):
    """``w`` as the window of estimator ``name`` (:data:`WINDOW_RANGE`): the one check of a
    window, given on the command line, in code or read from a model file."""
    lo, hi = WINDOW_RANGE[name]
    if isinstance(w, bool) or not isinstance(w, (int, np.integer)) or not lo <= w <= hi:
        raise ReachsetError(f"{name} estimator: window must be an integer in [{lo}, {hi}], got {w!r}")
    return int(w)


@dataclass(frozen=True)
class Estimator:
    """A named initial-state estimator.

    Attributes
    ----------
    name : str
        ``"fd"``: causal finite differences of positions, corrected with the model's input
        response (LWA-4P plant of Appendix A; exact on noise-free model data);
        ``"output"``: generic plant, x0 = pinv(C) y[m] (states not seen by C set to 0);
        ``"observer"``: a Kalman predictor (gains ``gain``) run over the last ``window``
        ticks, started from pinv(C) y[m - window] (:func:`observer_gains`, :func:`_observer`);
        ``"lsq"``: position and velocity fitted by least squares to the last ``window`` + 1
        samples through the model's input response (LWA-4P plant; exact on noise-free model
        data, so it works with the initial-state set; :func:`lsq_weights`).
    window : int
        Ticks the ``observer`` runs over; the ``lsq`` fit's samples minus one (0 for the others).
    gain : tuple
        The ``observer``'s gains L_0..L_{window-1}, each (n, ny) (:func:`observer_gains`;
        empty for the others).

    The estimator is part of the model file; the monitor uses exactly this one.
    """

    name: str = "fd"
    window: int = 0
    gain: tuple = ()

    @property
    def history(self) -> int:
        """Number of past ticks (before m) the estimator reads, all in the same segment."""
        return {"fd": 3, "output": 0, "observer": self.window, "lsq": self.window + 2}[self.name]

    @classmethod
    def observer(cls, plant, window=20, noise_ratio=1e-4):
        """The ``observer`` estimator for ``plant`` (:func:`observer_gains`)."""
        window = _window("observer", window)
        G = observer_gains(plant, window, noise_ratio)
        return cls("observer", window, _tuple3(G))

    @classmethod
    def lsq(cls, plant, window=None):
        """The ``lsq`` estimator over ``window`` + 1 samples (:func:`lsq_weights`; None: the
        default ``estimator.lsq_window``)."""
        window = _window("lsq", defaults.get("estimator.lsq_window") if window is None else window)
        lsq_weights(plant, window)            # refuses a plant it is not for
        return cls("lsq", window)

    @classmethod
    def named(cls, name, plant, window=None):
        """The estimator ``name`` for ``plant`` (the command line's choice); ``window``: the
        ``lsq`` or ``observer`` window (None: its default), refused for the others."""
        if name not in ESTIMATORS:
            raise ReachsetError(f"unknown initial-state estimator {name!r}; known: {sorted(ESTIMATORS)}")
        if name == "observer":
            return cls.observer(plant) if window is None else cls.observer(plant, window)
        if name == "lsq":
            return cls.lsq(plant, window)
        if window is not None:
            raise ReachsetError(f"--estimator-window is for the 'lsq' and 'observer' estimators, not {name!r}")
        return cls(name)

    def as_dict(self):
        if self.name == "observer":
            return {"name": self.name, "window": int(self.window),
                    "gains": [[list(r) for r in L] for L in self.gain]}
        if self.name == "lsq":
            return {"name": self.name, "window": int(self.window)}
        return {"name": self.name}

    @classmethod
    def from_dict(cls, d):
        if not isinstance(d, dict) or not isinstance(d.get("name"), str) or d["name"] not in ESTIMATORS:
            raise ReachsetError(f"unknown initial-state estimator {d!r}; known: {sorted(ESTIMATORS)}")
        if d["name"] == "lsq":
            return cls("lsq", _window("lsq", d.get("window")))
        if d["name"] != "observer":
            return cls(d["name"])
        w, g = _window("observer", d.get("window")), d.get("gains")
        try:
            G = np.array(g, dtype=np.float64)
        except (TypeError, ValueError):
            G = np.zeros((0,))
        if G.ndim != 3 or G.shape[0] != w or G.size == 0 or not np.all(np.isfinite(G)):
            raise ReachsetError("observer estimator: gains must be `window` matrices of finite numbers")
        return cls("observer", w, _tuple3(G))

    def validate(self, plant):
        """Raise :class:`ReachsetError` if the ``observer``'s gains cannot be used with ``plant``
        (wrong shape, or they estimate a state the closed-loop sets assume zero, see
        :func:`observer_gains`), or ``lsq`` is given a plant it is not for; model files are
        checked on loading."""
        if self.name == "observer":
            _observer_gains_for(plant, self.window, self.gain)
        elif self.name == "lsq":
            lsq_weights(plant, self.window)

    def estimate_latest(self, plant, y_hist, u_hist):
        """Initial states of test cases starting at the newest sample of each row.

        ``y_hist``, ``u_hist``: shape (J, history + 1), oldest first, one row per joint with
        a one-dimensional output/input. Same arithmetic as :meth:`estimate`.
        """
        if self.name == "fd":
            if plant.A.shape[0] != 5:
                return self.estimate(plant, y_hist.reshape(-1, 1), u_hist.reshape(-1, 1),
                                     np.arange(y_hist.shape[0]) * y_hist.shape[1] + self.history)
            return fd_formula(plant.dt, y_hist[:, 3], y_hist[:, 2], u_hist[:, 2], u_hist[:, 1], u_hist[:, 0])
        H = y_hist.shape[1]
        return self.estimate(plant, y_hist.reshape(-1, 1), u_hist.reshape(-1, 1),
                             np.arange(y_hist.shape[0]) * H + self.history)

    def estimate(self, plant, y, u, m):
        """Initial states of the test cases starting at ticks ``m``.

        Parameters
        ----------
        plant : LinearPlant
        y : ndarray, shape (T, ny)
        u : ndarray, shape (T, nu)
        m : ndarray of int, shape (M,)
            Start ticks; ``m - history`` must be in the same segment.

        Returns
        -------
        X0 : ndarray, shape (n, M)
        """
        if self.name == "observer":
            return _observer(plant, y, u, m, self.window, self.gain)
        if self.name == "lsq":
            return _lsq(plant, y, u, m, self.window)
        return ESTIMATORS[self.name](plant, y, u, m)



def _tuple3(G):
    return tuple(tuple(tuple(float(x) for x in row) for row in L) for L in np.asarray(G, dtype=np.float64))


def _fd(plant, y, u, m):
    """Appendix-A state [q[k-1], q[k], qdot[k], d[k], u_p[k-1]] from y[m-1..m], u[m-3..m-1].

    Causal finite differences corrected with the model's own input response, so that the
    estimate is exact on data that follow the nominal model (d = 0): with y[k] = q[k-1],

        qdot[m-2] = (y[m] - y[m-1]) / dt - dt/2 u[m-3]
        qdot[m-1] = qdot[m-2] + dt u[m-3]
        q[m]      = y[m] + dt qdot[m-1] + dt^2/2 u[m-2]
        qdot[m]   = qdot[m-1] + dt u[m-2]

    and x0 = [y[m], q[m], qdot[m], 0, u[m-1]]. The disturbance state starts at 0.
    """
    if plant.A.shape[0] != 5 or y.shape[1] != 1:
        raise ReachsetError("estimator 'fd' is for the per-joint LWA-4P plant (5 states, 1 output); "
                            "use 'output' for other plants")
    return fd_formula(plant.dt, y[m, 0], y[m - 1, 0], u[m - 1, 0], u[m - 2, 0], u[m - 3, 0])


def fd_formula(dt, ym, ym1, u1, u2, u3):
    """The ``fd`` estimate from y[m], y[m-1], u[m-1], u[m-2], u[m-3] (arrays of equal shape)."""
    v2 = (ym - ym1) / dt - 0.5 * dt * u3
    v1 = v2 + dt * u3
    X0 = np.zeros((5, len(ym)))
    X0[0] = ym
    X0[1] = ym + dt * v1 + 0.5 * dt * dt * u2
    X0[2] = v1 + dt * u2
    X0[4] = u1
    return X0


def _output(plant, y, u, m):
    P = np.linalg.pinv(plant.C)
    n = plant.A.shape[0]
    Y = y[m].T  # (ny, M)
    X0 = np.zeros((n, len(m)))
    for i in range(n):
        acc = np.zeros(len(m))
        for j in range(P.shape[1]):
            if P[i, j] != 0.0:
                acc = acc + P[i, j] * Y[j]
        X0[i] = acc
    return X0


def pinned_states(plant):
    """Indices of the states that neither the input nor the disturbances reach.

    Rows of the controllability matrix ``[B, G'_W, A B, A G'_W, ...]`` that are identically
    zero (exactly, in floating point): for the per-joint LWA-4P plant the disturbance state
    ``d``. The closed-loop sets ``R_e``, ``R_u`` are computed on the reachable subspace of
    ``(A, G'_W)`` with these states at zero (:func:`reachset_ros.sets.reachability.reachable_subspace`),
    so a test case may not start with them non-zero: an initial state with ``d != 0`` would
    let Theorem 1 explain a slowly varying model error by a constant ``d`` that ``R_e`` does not
    contain (measured tracking errors then leave ``R*_e`` while the model is conformant).
    Raises :class:`ReachsetError` if the unreachable subspace is not spanned by such states
    (the ``observer`` estimator is then not offered for that plant).
    """
    A = np.asarray(plant.A, float)
    M = np.hstack([np.asarray(plant.B, float), np.asarray(plant.Gw, float)])
    n = A.shape[0]
    blocks, V = [M], M
    for _ in range(n - 1):
        V = A @ V
        blocks.append(V)
    K = np.hstack(blocks)
    pinned = [i for i in range(n) if not np.any(K[i] != 0.0)]
    if np.linalg.matrix_rank(K) != n - len(pinned):
        raise ReachsetError("observer estimator: the states the input and disturbances cannot reach are not "
                            "single state coordinates; use the 'fd' or 'output' estimator for this plant")
    return tuple(pinned)


def observer_gains(plant, window, noise_ratio=1e-4, p0=1e4):
    """Gains L_0..L_{window-1} of a Kalman predictor started with covariance ``p0`` I.

    The time-varying Kalman filter over a finite window from an uninformative start: with
    P_0 = p0 I, for i = 0..window-1

        S_i = C P_i C^T + R,   L_i = A P_i C^T S_i^-1,   P_{i+1} = A P_i A^T + Q - L_i S_i L_i^T,

    Q = G'_W G'_W^T + 1e-12 I, R = noise_ratio^2 G'_V G'_V^T (the unscaled generators: the
    ratio says how much larger the process disturbances are than the measurement noise;
    1e-4 fits the LWA-4P, alpha_V about 1e-4 rad against alpha_W about 1). On noise-free
    model data the error decays with the window (test/conformance/test_estimators.py).

    The states of :func:`pinned_states` (the LWA-4P's disturbance state ``d``) have zero rows
    and columns in ``P_0`` and ``Q``, so their gain rows are exactly zero and the estimate
    keeps them at 0, the value the closed-loop sets assume (as ``fd`` does). Estimating ``d``
    too (as this estimator did before) hides slowly varying model error in ``d``, which
    ``R_e`` does not cover: on simulated recordings the measured tracking error then left
    ``R*_e`` by up to 10 % (test_estimators.py). Any causal estimator used identically offline
    and online keeps Theorem 1 sound; the pinned states keep the closed-loop guarantee sound
    too. Returns an array of shape (window, n, ny).
    """
    A, C = plant.A, plant.C
    n = A.shape[0]
    keep = np.ones(n)
    keep[list(pinned_states(plant))] = 0.0
    Pin = np.diag(keep)
    Q = Pin @ (plant.Gw @ plant.Gw.T + 1e-12 * np.eye(n)) @ Pin
    R = noise_ratio ** 2 * (plant.Gv @ plant.Gv.T)
    P = p0 * Pin
    out = []
    for _ in range(int(window)):
        S = C @ P @ C.T + R
        L = A @ P @ C.T @ np.linalg.inv(S)
        P = A @ P @ A.T + Q - L @ S @ L.T
        P = 0.5 * (P + P.T)
        out.append(L)
    G = np.array(out)
    if not np.all(np.isfinite(G)):
        raise ReachsetError("observer estimator: the Kalman gains are not finite")
    return G


def _observer_gains_for(plant, window, gains):
    """The ``observer``'s gains as an array, checked against ``plant``; ``(G, pinned)``."""
    G = np.array(gains, dtype=np.float64)
    n, ny = plant.A.shape[0], plant.C.shape[0]
    if G.shape != (window, n, ny):
        raise ReachsetError(f"observer estimator: gains have shape {G.shape}, the plant and window need "
                            f"({window}, {n}, {ny})")
    pinned = list(pinned_states(plant))
    if np.any(G[:, pinned, :] != 0.0):
        raise ReachsetError("observer estimator: its gains estimate the disturbance state, which the closed-loop "
                            "sets assume zero (a model identified before this was fixed); identify again")
    return G, pinned


def _observer(plant, y, u, m, window, gains):
    """Kalman predictor over y[m-window .. m-1], u[m-window .. m-1]; returns x_hat[m | m-1].

        x_hat[m-window]   = pinv(C) y[m-window]        (then corrected by L_0 with the same y)
        x_hat[t+1]        = A x_hat[t] + B u[t] + L_i (y[t] - C x_hat[t] - D u[t]),  t = m-window+i

    Every product is the element-wise :func:`reachset_ros.conformance.kernels.matvec`, so the
    result for one test case does not depend on how many are computed together (batch
    check and monitor agree to the bit). Causal: it reads only samples before m.
    """
    G, pinned = _observer_gains_for(plant, window, gains)
    m = np.asarray(m)
    hasD = bool(np.any(plant.D))
    P = np.linalg.pinv(plant.C)
    P[pinned, :] = 0.0
    X = matvec(P, y[m - window].T)
    for i in range(window):
        t = m - window + i
        Yt, Ut = y[t].T, u[t].T
        innov = Yt - matvec(plant.C, X)
        if hasD:
            innov = innov - matvec(plant.D, Ut)
        X = matvec(plant.A, X) + matvec(plant.B, Ut) + matvec(G[i], innov)
    return X


def lsq_weights(plant, window):
    """The ``lsq`` estimate's weights: ``x0 = P y[m-N..m] + R u[m-N-2..m-1]`` (N = ``window``).

    Per-joint LWA-4P plant (Appendix A), disturbance state d = 0. With y[t] = q[t-1], the
    N + 1 samples y[m-N..m] are the positions q[m-N-1..m-1], which the nominal model makes
    affine in the position and velocity at t0 = m-N-1 and the inputs that acted:

        q[t+1] = q[t] + dt qdot[t] + dt^2/2 u[t-1],   qdot[t+1] = qdot[t] + dt u[t-1].

    Those two are fitted by least squares (equal weights) and propagated to
    x0 = [q[m-1], q[m], qdot[m], 0, u[m-1]]. Exact on noise-free model data (so
    :func:`~reachset_ros.conformance.theorem1.initial_error_maps` exists); ``window = 1`` is
    the exact interpolation of two samples, the ``fd`` estimate up to rounding. A longer window
    averages the measurement noise (a step of the samples reads as less motion) and lets the
    model's disturbances over the window into the estimate.
    Returns ``(P, R)``, shapes (5, N + 1) and (5, N + 2).
    """
    if plant.A.shape[0] != 5 or plant.C.shape[0] != 1:
        raise ReachsetError("estimator 'lsq' is for the per-joint LWA-4P plant (5 states, 1 output); "
                            "use 'output' or 'observer' for other plants")
    return _lsq_weights(float(plant.dt), int(window))


@functools.lru_cache(maxsize=32)
def _lsq_weights(h, N):
    """:func:`lsq_weights` for time step ``h`` and window ``N`` (computed once, read-only)."""
    nU = N + 2                                   # u[m-N-2 .. m-1]; u[t] is U[t - (m-N-2)]
    dim = 2 + nU                                 # coefficients over [q[t0], qdot[t0], U...]
    q, qd = np.zeros(dim), np.zeros(dim)
    q[0], qd[1] = 1.0, 1.0
    rows = []
    for j in range(N + 1):                       # t = t0 + j; y[t + 1] = q[t]
        rows.append(q.copy())
        up = np.zeros(dim)
        up[2 + j] = 1.0                          # u[t-1] = u[m-N-2+j]
        q, qd = q + h * qd + 0.5 * h * h * up, qd + h * up
    # after the loop: q, qd at t0 + N + 1 = m; rows[-1] = q[m-1]
    F = np.array(rows)
    Fp = np.linalg.pinv(F[:, :2])
    X = np.zeros((5, dim))
    X[0], X[1], X[2] = rows[-1], q, qd
    X[4, 2 + nU - 1] = 1.0                       # u[m-1]
    P = X[:, :2] @ Fp
    R = X[:, 2:] - X[:, :2] @ Fp @ F[:, 2:]
    P.flags.writeable = False
    R.flags.writeable = False
    return P, R


def _lsq(plant, y, u, m, window):
    """The ``lsq`` estimate (:func:`lsq_weights`), element-wise, in a fixed order."""
    P, R = lsq_weights(plant, window)
    m = np.asarray(m)
    N = int(window)
    X0 = np.zeros((5, len(m)))
    for i in range(5):
        acc = np.zeros(len(m))
        for j in range(N + 1):
            if P[i, j] != 0.0:
                acc = acc + P[i, j] * y[m - N + j, 0]
        for j in range(N + 2):
            if R[i, j] != 0.0:
                acc = acc + R[i, j] * u[m - N - 2 + j, 0]
        X0[i] = acc
    return X0


ESTIMATORS = {"fd": _fd, "output": _output, "observer": _observer, "lsq": _lsq}
