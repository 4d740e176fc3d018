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

from dataclasses import dataclass

import numpy as np

from .errors import ReachsetError


@dataclass(frozen=True)
class Estimator:
    """A named initial-state estimator.

    Attributes
    ----------
    name : str
        ``"fd"``: causal finite differences of positions, corrected with the model's input
        response (LWA-4P plant of Appendix A; exact on noise-free model data);
        ``"output"``: generic plant, x0 = pinv(C) y[m] (states not seen by C set to 0).
    history : int
        Number of past ticks (before m) the estimator reads, all in the same segment.
    """

    name: str = "fd"

    @property
    def history(self) -> int:
        return {"fd": 3, "output": 0}[self.name]

    def as_dict(self):
        return {"name": self.name}

    @classmethod
    def from_dict(cls, d):
        if not isinstance(d, dict) or not isinstance(d.get("name"), str) or d["name"] not in ESTIMATORS:
            raise ReachsetError(f"unknown initial-state estimator {d!r}; known: {sorted(ESTIMATORS)}")
        return cls(d["name"])

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
        return ESTIMATORS[self.name](plant, y, u, m)


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


ESTIMATORS = {"fd": _fd, "output": _output}
