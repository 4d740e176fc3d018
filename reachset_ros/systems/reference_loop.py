"""The closed loop driven by references: plant + observer + controller with a reference input.

Superposition splits the closed loop into the disturbance part (the reachable sets R_e, R_u of
:mod:`~reachset_ros.systems.closedloop`) and the nominal loop driven by the reference, with
the control law ``u = u_ff + K (x_ref - x_hat)`` (paper eq. ``feedbackLaw``, ``u_ff = qdd_d``):

* :class:`LoopIO` / :func:`loop_io`: that loop as one LTI system with the reference,
  feedforward and disturbances as inputs (the algebraic loop solved exactly);
* :class:`LTIPlan` / :func:`lti_simulate`: its exact blocked simulation;
* :func:`reference_state`, :func:`reference_inputs`: a reference in the observer's estimate
  coordinates;
* :func:`steady_state`: the loop state on the forced response to a reference sample's
  quadratic extrapolation (a stretch that starts mid-motion starts without a transient);
* :func:`simulate_closed_loop`: a recording of the loop (what ``/joint_states`` and
  ``/plant_input`` carry).

The reference error of the paper's Appendix B is computed over this loop by
:mod:`reachset_ros.synthesis.reference_error`; the simulated recordings of
:mod:`reachset_ros.sim.recordings` run it.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import ReachsetError
from ..sets.reachability import reachable_subspace


@dataclass(frozen=True, eq=False, kw_only=True)
class LoopIO:
    """The closed loop driven by references and disturbances (superposition's other half).

    ``z[k+1] = A z + B r``, ``out = C z + D r`` with ``z = [x_p; x_o]``, inputs
    ``r = [u_ff (m), x_ref (ne), w (n_p), v (p)]`` and outputs ``[y (p), u (m), x_hat (ne)]``;
    ``x_ref`` in the observer's estimate coordinates (``estimate_names``). The control law is
    ``u = u_ff + K (x_ref - x_hat)`` with the algebraic loop solved exactly.
    """

    A: np.ndarray
    B: np.ndarray
    C: np.ndarray
    D: np.ndarray
    m: int
    ne: int
    n_p: int
    p: int
    estimate_names: tuple

    def inputs(self, *parts):
        """Column slice of ``B``/``D`` for the named input groups ("u_ff", "x_ref", "w", "v")."""
        offs = {"u_ff": (0, self.m), "x_ref": (self.m, self.m + self.ne),
                "w": (self.m + self.ne, self.m + self.ne + self.n_p),
                "v": (self.m + self.ne + self.n_p, self.m + self.ne + self.n_p + self.p)}
        idx = np.concatenate([np.arange(*offs[k]) for k in parts])
        return idx


def loop_io(plant, observer, controller):
    """:class:`LoopIO` of plant + observer + controller (same algebra as :func:`close_loop`)."""
    Ap, Bp, Cp, Dp = plant.A, plant.B, plant.C, plant.D
    npl, m, p = plant.n_states, plant.n_inputs, plant.n_outputs
    K = controller.gain_for(observer.estimate_names)
    ne = len(observer.estimate_names)
    Ao, Boy, Bou, Co, Doy, Dou = (observer.Ao, observer.Bo_y, observer.Bo_u, observer.Co,
                                  observer.Do_y, observer.Do_u)
    no = observer.n_states
    Xz = np.hstack([Doy @ Cp, Co])
    Dxu = Doy @ Dp + Dou
    L = np.eye(m) + K @ Dxu
    Li = np.linalg.inv(L)
    Fz = -Li @ K @ Xz
    nr = m + ne + npl + p
    Ur = np.zeros((m, nr))                    # u = Fz z + Ur r
    Ur[:, :m] = Li
    Ur[:, m:m + ne] = Li @ K
    Ur[:, m + ne + npl:] = -Li @ K @ Doy
    Ev = np.zeros((p, nr))
    Ev[:, m + ne + npl:] = np.eye(p)
    Yz = np.hstack([Cp, np.zeros((p, no))]) + Dp @ Fz   # y = Yz z + Yr r
    Yr = Dp @ Ur + Ev
    Hz = Xz + Dxu @ Fz                                   # x_hat = Hz z + Hr r
    Hr = Dxu @ Ur + Doy @ Ev
    Bu = np.vstack([Bp, Bou])
    By = np.vstack([np.zeros((npl, p)), Boy])
    Ew = np.zeros((npl + no, nr))
    Ew[:npl, m + ne:m + ne + npl] = np.eye(npl)
    A = np.block([[Ap, np.zeros((npl, no))], [np.zeros((no, npl)), Ao]]) + Bu @ Fz + By @ Yz
    B = Bu @ Ur + By @ Yr + Ew
    C = np.vstack([Yz, Fz, Hz])
    D = np.vstack([Yr, Ur, Hr])
    return LoopIO(A=A, B=B, C=C, D=D, m=m, ne=ne, n_p=npl, p=p, estimate_names=tuple(observer.estimate_names))


class LTIPlan:
    """Blocked exact simulation of ``z[k+1] = A z + B r[k]``, ``y[k] = C z + D r[k]``.

    Within a block of ``block`` ticks the response is a block-Toeplitz matrix product (one
    BLAS call for all blocks of a sequence); only the block-boundary states are propagated
    sequentially. The plan (Toeplitz and observability matrices) is built once and reused for
    many input sequences. Same result as the tick loop up to floating-point re-association.
    """

    def __init__(self, A, B, C, D, block=32):
        A, B, C, D = (np.atleast_2d(np.asarray(x, float)) for x in (A, B, C, D))
        n, m, p = A.shape[0], B.shape[1], C.shape[0]
        b = int(max(1, block))
        powers = [np.eye(n)]
        for _ in range(b):
            powers.append(A @ powers[-1])
        P = np.stack(powers[:b])                                   # (b, n, n)
        mk = np.concatenate([D[None], np.einsum("pn,knq,qm->kpm", C, P[:b - 1], B)])  # (b, p, m)
        i, j = np.meshgrid(np.arange(b), np.arange(b), indexing="ij")
        blocks = np.where((i >= j)[:, :, None, None], mk[np.clip(i - j, 0, b - 1)], 0.0)  # (b, b, p, m)
        self.ToeT = blocks.transpose(0, 2, 1, 3).reshape(b * p, b * m).T.copy()
        self.ObsT = np.vstack([C @ powers[i] for i in range(b)]).T
        self.CtrT = np.hstack([powers[b - 1 - j] @ B for j in range(b)]).T
        self.Ab = powers[b]
        self.n, self.m, self.p, self.b = n, m, p, b

    def run(self, r, z0=None):
        """Outputs ``(T, p)`` for inputs ``r`` ``(T, m)`` from the state ``z0`` (zero by default)."""
        r = np.asarray(r, float).reshape(len(r), -1)
        T = r.shape[0]
        n, m, p, b = self.n, self.m, self.p, self.b
        if T == 0:
            return np.zeros((0, p))
        nb = -(-T // b)
        R = np.zeros((nb * b, m))
        R[:T] = r
        R = R.reshape(nb, b * m)
        CR = R @ self.CtrT
        Z = np.empty((nb, n))
        z = np.zeros(n) if z0 is None else np.asarray(z0, float).copy()
        Ab = self.Ab
        for i in range(nb):
            Z[i] = z
            z = Ab @ z + CR[i]
        Y = Z @ self.ObsT + R @ self.ToeT
        return Y.reshape(nb * b, p)[:T]


def lti_simulate(A, B, C, D, r, z0=None, block=32):
    """Outputs of ``z[k+1] = A z + B r[k]``, ``y[k] = C z + D r[k]`` for ``k = 0..T-1`` (exact).

    See :class:`LTIPlan` (blocked; equal to the tick loop up to re-association).

    Parameters
    ----------
    A, B, C, D : array_like
    r : array_like, (T, m)
    z0 : array_like, (n,), optional

    Returns
    -------
    ndarray, (T, p)
    """
    r = np.asarray(r, float).reshape(len(r), -1)
    return LTIPlan(A, B, C, D, min(block, max(len(r), 1))).run(r, z0)


def reference_state(names, q, qd, qdd):
    """Reference in the observer's estimate coordinates (q, qd, d, q_prev, u_prev)."""
    T = len(q)
    out = np.zeros((T, len(names)))
    prev = lambda a: np.concatenate([a[:1], a[:-1]])  # noqa: E731
    for i, nm in enumerate(names):
        if nm == "q":
            out[:, i] = q
        elif nm == "qd":
            out[:, i] = qd
        elif nm == "q_prev":
            out[:, i] = prev(q)
        elif nm == "u_prev":
            out[:, i] = prev(qdd)
        elif nm == "d":
            pass
        else:
            raise ReachsetError(f"no reference for the estimate {nm!r}")
    return out


def simulate_closed_loop(plant, observer, controller, q_d, qd_d, qdd_d, w=None, v=None, x0=None,
                         xo0=None):
    """Simulate plant + observer + controller with a reference and disturbances (a recording).

    ``u[k] = qdd_d[k] + K (x_ref[k] - x_hat[k])``; the measurement ``y[k] = C x_p[k] + v[k]``
    is what ``/joint_states`` carries and ``u[k]`` what ``/plant_input`` carries.

    Parameters
    ----------
    plant, observer, controller
    q_d, qd_d, qdd_d : array_like, (T,)
        Reference (a single-input plant).
    w : array_like, (T, n_p), optional
        Raw process disturbances (plant-state vectors); zero by default.
    v : array_like, (T, p), optional
    x0 : array_like, optional
        Initial plant state (default: the loop's forced response to the quadratic
        extrapolation of the first reference sample, :func:`steady_state`).
    xo0 : array_like, optional
        Initial observer state (default: as ``x0``).

    Returns
    -------
    dict with ``y`` (T, p), ``u`` (T, m), ``x_hat`` (T, ne), ``x_ref`` (T, ne)
    """
    io = loop_io(plant, observer, controller)
    q_d, qd_d, qdd_d = (np.asarray(a, float).ravel() for a in (q_d, qd_d, qdd_d))
    T = len(q_d)
    xr = reference_state(io.estimate_names, q_d, qd_d, qdd_d)
    r = np.zeros((T, io.B.shape[1]))
    r[:, :io.m] = qdd_d[:, None]
    r[:, io.m:io.m + io.ne] = xr
    if w is not None:
        r[:, io.m + io.ne:io.m + io.ne + io.n_p] = np.asarray(w, float).reshape(T, io.n_p)
    if v is not None:
        r[:, io.m + io.ne + io.n_p:] = np.asarray(v, float).reshape(T, io.p)
    z0 = steady_state(io, plant, q_d[0], qd_d[0], qdd_d[0], io.inputs("u_ff", "x_ref"))
    if x0 is not None:
        z0[:plant.n_states] = np.asarray(x0, float)
    if xo0 is not None:
        z0[plant.n_states:] = np.asarray(xo0, float)
    out = lti_simulate(io.A, io.B, io.C, io.D, r, z0)
    p, m = io.p, io.m
    return {"y": out[:, :p], "u": out[:, p:p + m], "x_hat": out[:, p + m:], "x_ref": xr}


def reference_inputs(names, q, qd, qdd):
    """The reference inputs ``[u_ff = qdd_d, x_ref]`` of :class:`LoopIO`, one row per tick."""
    return np.hstack([np.asarray(qdd, float)[:, None], reference_state(names, q, qd, qdd)])


def steady_state(io, plant, q0, qd0, qdd0, cols, solver=None):
    """Loop state on the forced response to the quadratic extrapolation of a reference sample.

    For ``q_d[k] = q0 + qd0 dt k + qdd0 (dt k)^2 / 2`` (and the matching ``qd_d``, ``qdd_d``,
    shifted components) the loop has a quadratic particular solution
    ``z[k] = z0 + z1 k + z2 k^2``; ``z0`` is returned (min-norm, so the unreachable
    constant-disturbance state stays 0). A reference stretch that starts mid-motion then starts
    without an artificial transient.
    """
    dt = plant.dt
    ks = np.array([0.0, 1.0, 2.0])
    q = q0 + qd0 * dt * ks + 0.5 * qdd0 * (dt * ks) ** 2
    qd = qd0 + qdd0 * dt * ks
    qdd = np.full(3, float(qdd0))
    names = io.estimate_names
    r = reference_inputs(names, q, qd, qdd)
    # q_prev / u_prev at k = 0 must be the extrapolated k = -1 values
    for i, nm in enumerate(names):
        if nm == "q_prev":
            r[:, 1 + i] = q - qd0 * dt + 0.5 * qdd0 * dt * dt * (1 - 2 * ks)
        elif nm == "u_prev":
            r[:, 1 + i] = qdd0
    r2 = 0.5 * (r[2] - 2 * r[1] + r[0])
    r1 = r[1] - r[0] - r2
    r0 = r[0]
    B = io.B[:, cols]
    solve = solver or steady_state_solver(io, cols)
    z2 = solve(B @ r2)
    z1 = solve(B @ r1 - 2 * z2)
    return solve(B @ r0 - z1 - z2)


def steady_state_solver(io, cols):
    """``rhs -> z`` solving ``(I - A) z = rhs`` on the reachable subspace of the reference inputs."""
    V = reachable_subspace(io.A, io.B[:, cols])    # excludes e.g. the constant-disturbance state
    Mp = np.linalg.pinv((np.eye(io.A.shape[0]) - io.A) @ V)
    VM = V @ Mp
    return lambda rhs: VM @ rhs
