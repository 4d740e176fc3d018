"""Online conformance monitor core (paper Theorem 1, checked tick by tick; Def. 4 online).

Each tick a new sequential test case starts (Def. 3); every test case started in the last
k* ticks gets its k-th check ``N_k y_a <= D_k xi``. The immutable :class:`MonitorModel`
holds what the model file says (plant, estimator, offsets per k); the mutable monitors
hold the joints' state (last samples, nominal states of the active test cases): the
model/data split of Pinocchio.

The arithmetic is that of :func:`reachset_ros.conformance.kernels.sweep` (same estimator,
same element-wise kernels of :mod:`~reachset_ros.conformance.kernels`), so ``reachset
replay`` gives exactly ``reachset check``'s verdicts.

One tick, three implementations, all here but the C source:

* :meth:`Monitor._tick_numpy`, the reference: several joints with one-dimensional outputs
  (all N_k = [1]), k*+1 ring slots of test cases per joint, vectorised over joints and
  slots; any plant and estimator.
* ``_tick.c`` (``reachset_monitor_tick``, loaded by :mod:`~reachset_ros.conformance.kernels`),
  the fast path of :class:`Monitor` (:meth:`Monitor.tick`): a compiled copy of
  :meth:`Monitor._tick_numpy` for the per-joint LWA-4P plant with the ``fd`` estimator,
  the same floating-point operations in the same order; the ctypes mirror of its state is
  :class:`_TickState`. Pinned bit for bit, every output and the whole state, by
  ``test/conformance/test_monitor_kernel.py::test_kernel_equals_numpy_bit_for_bit``.
* :meth:`JointMonitor.tick`: one joint whose output may have any dimension. With ny > 1 the
  normals N_k change with k and have a different number q_k of rows for each k, so the
  checks do not vectorise over the ring as :class:`Monitor`'s do; JointMonitor loops over
  its test cases. For ny = 1 it takes a vectorised branch with the same arithmetic as
  :meth:`Monitor._tick_numpy` (the kernels' :func:`~reachset_ros.conformance.kernels.matvec`,
  the same estimator, the same offsets); it is not written as a call of that tick because
  it orders its test cases newest first, where Monitor orders them by ring slot, so on an
  exact tie of two margins it may report another test case (``step``, ``start_tick``).
  Pinned equal to :class:`Monitor` for ny = 1 (status, margin and the reported check, bit
  for bit) by ``test/conformance/test_monitor_kernel.py::test_joint_monitor_equals_numpy_tick``, and to
  ``reachset check`` for ny = 1 and ny = 2 by ``test/conformance/test_conformance.py``
  (``test_replay_equals_check_exactly_with_violations_and_gaps``,
  ``test_multidimensional_output_plant``).

What the monitor node makes of the ticks (pairing, faults, the events :class:`TickEvent
<reachset_ros.conformance.watches.TickEvent>` and :class:`FaultEvent
<reachset_ros.conformance.watches.FaultEvent>`, the coverage and stuck-sensor watches) is
:mod:`~reachset_ros.conformance.watches` and :mod:`~reachset_ros.conformance.monitor_core`.
"""
from __future__ import annotations

import ctypes
import time
import math
from dataclasses import dataclass

import numpy as np

from . import kernels
from .estimators import lsq_weights
from .kernels import advance, matvec, matvec_into, matvec_plan, predict_output
from .set_use import check_use


@dataclass(frozen=True)
class MonitorModel:
    """Per-joint immutable monitor data: plant, estimator, normals and offsets per k."""

    name: str
    plant: object
    estimator: object
    horizon: int
    normals: tuple
    dp: tuple
    dm: tuple

    @property
    def scalar(self):
        """One-dimensional output: N_k = [1] for every k, checks vectorised over test cases."""
        return self.plant.C.shape[0] == 1

    @property
    def dp_vec(self):
        return self._vec("dp")

    @property
    def dm_vec(self):
        return self._vec("dm")

    def _vec(self, which):
        cache = self.__dict__.setdefault("_cache", {})
        if which not in cache:
            cache[which] = np.array([d[0] for d in getattr(self, which)])
        return cache[which]

    @classmethod
    def from_model(cls, model, joint, thm=None):
        thm = thm or model.theorem1()
        offs = thm.offsets(model.checked_xi(joint))
        return cls(joint, model.plant, model.estimator, model.horizon, thm.normals,
                   tuple(o[0] for o in offs), tuple(o[1] for o in offs))


@dataclass
class TickResult:
    """Verdict of one tick for one joint."""

    conformant: bool
    status: str                 # ok | violation | invalid | gap_reset
    checked: int                # test cases checked this tick
    margin: float               # min (offset - N y_a) over the checks, rad (inf if none)
    step: int = -1              # k of the tightest (or violated) check
    start_tick: int = -1        # tick index at which that test case started
    deviation: float = 0.0      # N y_a of that check
    bound: float = 0.0          # its offset D_k xi
    use: float = math.nan       # set use: the largest |N y_a| / bound over the checks (NaN: none; set_use.check_use)

class JointMonitor:
    """Mutable state of one joint's monitor; feed it :meth:`tick` once per measurement."""

    def __init__(self, mm: MonitorModel):
        self.mm = mm
        self.reset()

    def reset(self):
        """Forget all test cases (after a gap, an invalid sample, or a reset service call)."""
        self._drop()                 # also: in_segment, consecutive valid ticks so far in this segment
        hist = self.mm.estimator.history
        self.y_hist = np.zeros((hist + 1, self.mm.plant.C.shape[0]))
        self.u_hist = np.zeros((hist + 1, self.mm.plant.B.shape[1]))
        self.last_stamp = None
        self.tick_index = -1

    def tick(self, stamp_ns: int, y, u) -> TickResult:
        """Process the measurement y and plant input u stamped ``stamp_ns``.

        A stamp step outside [0.5, 1.5] dt starts a new segment (test cases are dropped,
        exactly as the batch check never lets a test case span a gap); a non-finite sample
        returns status ``invalid`` and also ends the segment.
        """
        p = self.mm.plant
        self.tick_index += 1
        y = np.atleast_1d(np.asarray(y, dtype=np.float64))
        u = np.atleast_1d(np.asarray(u, dtype=np.float64))
        status = "ok"
        if self.last_stamp is not None:
            step = (stamp_ns - self.last_stamp) * 1e-9
            if not (0.5 * p.dt <= step <= 1.5 * p.dt):
                self._drop()
                status = "gap_reset"
        self.last_stamp = stamp_ns
        if not (np.all(np.isfinite(y)) and np.all(np.isfinite(u))):
            self._drop()
            return TickResult(False, "invalid", 0, -math.inf)
        # shift history, append current sample
        self.y_hist = np.vstack([self.y_hist[1:], y[None]])
        self.u_hist = np.vstack([self.u_hist[1:], u[None]])
        self.in_segment += 1
        hist = self.mm.estimator.history
        if self.in_segment > hist:
            x0 = self.mm.estimator.estimate(p, self.y_hist, self.u_hist, np.array([hist]))
            self.X = np.hstack([x0, self.X])
            self.ages = np.concatenate([[0], self.ages])
            self.starts = np.concatenate([[self.tick_index], self.starts])
        res = TickResult(False, status, 0, math.inf)    # nothing checked: never conformant
        if self.X.shape[1]:
            U = np.repeat(u[:, None], self.X.shape[1], axis=1)
            ya = y[:, None] - predict_output(p, self.X, U)
            if self.mm.scalar:
                Ny = matvec(self.mm.normals[0], ya)[0]
                mp = self.mm.dp_vec[self.ages] - Ny
                mm = self.mm.dm_vec[self.ages] + Ny
                use = float(np.fmax.reduce(check_use(Ny[None], self.mm.dp_vec[self.ages][None],
                                                     self.mm.dm_vec[self.ages][None])[0]))
                j, i = int(np.argmin(mp)), int(np.argmin(mm))
                if mp[j] <= mm[i] or math.isnan(mp[j]):
                    worst = (float(mp[j]), j, float(Ny[j]), float(self.mm.dp_vec[self.ages[j]]))
                else:
                    worst = (float(mm[i]), i, float(-Ny[i]), float(self.mm.dm_vec[self.ages[i]]))
            else:
                worst, use = (math.inf, -1, 0.0, 0.0), math.nan
                for col in range(self.X.shape[1]):
                    k = int(self.ages[col])
                    Ny = matvec(self.mm.normals[k], ya[:, col:col + 1])[:, 0]
                    mp = self.mm.dp[k] - Ny
                    mm = self.mm.dm[k] + Ny
                    use = float(np.fmax(use, check_use(Ny[:, None], self.mm.dp[k][:, None],
                                                       self.mm.dm[k][:, None])[0][0]))
                    j, i = int(np.argmin(mp)), int(np.argmin(mm))
                    if mp[j] < worst[0] or math.isnan(mp[j]):
                        worst = (float(mp[j]), col, float(Ny[j]), float(self.mm.dp[k][j]))
                    if mm[i] < worst[0] or math.isnan(mm[i]):
                        worst = (float(mm[i]), col, float(-Ny[i]), float(self.mm.dm[k][i]))
                    if math.isnan(worst[0]):
                        break                     # fail closed: a NaN margin is no margin
            margin, col, dev, bound = worst
            res = TickResult(margin >= 0, "ok" if margin >= 0 else "violation", self.X.shape[1], margin,
                             int(self.ages[col]), int(self.starts[col]), dev, bound, use=use)
            if status == "gap_reset" and res.status == "ok":
                res.status = "gap_reset"
            self.X = advance(p, self.X, U)
            self.ages = self.ages + 1
            keep = self.ages <= self.mm.horizon
            self.X, self.ages, self.starts = self.X[:, keep], self.ages[keep], self.starts[keep]
        return res

    def _drop(self):
        """End the segment: forget the test cases, count valid ticks anew."""
        n = self.mm.plant.A.shape[0]
        self.X = np.zeros((n, 0))
        self.ages = np.zeros(0, dtype=np.int64)
        self.starts = np.zeros(0, dtype=np.int64)
        self.in_segment = 0


class Monitor:
    """Mutable monitor state of several joints with one-dimensional outputs, vectorised.

    All joints share plant, estimator and horizon (their sets differ). Test cases live in a
    ring of k*+1 slots per joint (slot = start tick mod (k*+1)), so a tick allocates
    nothing per test case; nominal states of all joints and slots are advanced together
    with the same element-wise kernels as :func:`reachset_ros.conformance.kernels.sweep`, hence
    verdicts equal ``reachset check``'s exactly.

    Two implementations of one tick share this state: the compiled kernel
    ``reachset_ros/conformance/_tick.c`` (per-joint LWA-4P plant with the ``fd`` estimator; built by
    ``pip install``/colcon with ``-ffp-contract=off``) and :meth:`_tick_numpy` (any
    plant and estimator). They perform the same floating-point operations in the same
    order, so their results are bitwise equal (``test/conformance/test_monitor_kernel.py``).

    Syntax::

        mon = Monitor([MonitorModel.from_model(model, j) for j in joints])
        res = mon.tick(stamp_ns, y, u)      # y, u: shape (J,)

    Parameters
    ----------
    models : sequence of MonitorModel
    kernel : bool or None
        None (default): the compiled kernel when it is built and applies, else numpy;
        False: always numpy; True: the compiled kernel or ValueError.

    Each joint is reset on its own invalid sample; a stamp step outside [0.5, 1.5] dt
    resets all joints (a gap: test cases never span it).
    """

    STATUS = ("ok", "violation", "invalid", "gap_reset")

    def __init__(self, models, kernel=None):
        self.models = tuple(models)
        m0 = self.models[0]
        for m in self.models:
            if not m.scalar:
                raise ValueError(f"joint {m.name}: Monitor needs one-dimensional outputs; use JointMonitor")
            if m.horizon != m0.horizon or m.estimator != m0.estimator or m.plant is not m0.plant and not (
                    np.array_equal(m.plant.A, m0.plant.A) and np.array_equal(m.plant.B, m0.plant.B)
                    and np.array_equal(m.plant.C, m0.plant.C) and np.array_equal(m.plant.D, m0.plant.D)):
                raise ValueError("all joints of a Monitor must share plant, estimator and horizon")
        self.plant, self.estimator, self.horizon = m0.plant, m0.estimator, m0.horizon
        self.names = tuple(m.name for m in self.models)
        self.J, self.S = len(self.models), self.horizon + 1
        self.dp = np.ascontiguousarray(np.stack([m.dp_vec for m in self.models]))   # (J, S) offsets per k
        self.dm = np.ascontiguousarray(np.stack([m.dm_vec for m in self.models]))
        applies = _tick_kernel_applies(self.plant, self.estimator, self.J)
        if kernel and not applies:
            raise ValueError("the compiled monitor kernel is not built or does not apply to this plant/estimator")
        self.kernel = bool(applies if kernel is None else kernel and applies)
        self.reset()

    @property
    def X(self):
        """Nominal states of all joints and slots, shape (n, J*(k*+1)), column = j*(k*+1) + slot."""
        return self._Xbuf[self._cur[0]]

    def reset(self):
        """Forget all test cases and samples (the reset service, a new model)."""
        p, H, J, S = self.plant, self.estimator.history, self.J, self.S
        n, N = p.A.shape[0], self.J * self.S
        self._planA, self._planB, self._planC = matvec_plan(p.A), matvec_plan(p.B), matvec_plan(p.C)
        self._planD = matvec_plan(p.D) if np.any(p.D) else None
        self._planN = matvec_plan(self.models[0].normals[0])
        self._Xbuf = np.zeros((2, n, N))
        self._cur = np.zeros(1, dtype=np.int64)
        self._BU = np.empty((p.B.shape[0], N))
        self._Y = np.empty((p.C.shape[0], N))
        self._DU = np.empty((p.C.shape[0], N))
        self._U = np.empty((1, N))
        self._Ny = np.empty((1, N))
        self.start = np.full((J, S), -1, dtype=np.int64)
        self.ages = np.zeros((J, S), dtype=np.int64)
        self.active = np.zeros((J, S), dtype=bool)
        self._flat = (np.arange(J) * S)[:, None]
        self._dpf, self._dmf = self.dp.ravel(), self.dm.ravel()
        self.y_hist = np.zeros((J, H + 1))
        self.u_hist = np.zeros((J, H + 1))
        self.in_segment = np.zeros(J, dtype=np.int64)
        self._clock = np.array([-1, 0, 0], dtype=np.int64)   # tick index, last stamp, has last
        if self.kernel:
            self._kernel_setup()

    @property
    def tick_index(self):
        return int(self._clock[0])

    @property
    def last_stamp(self):
        return int(self._clock[1]) if self._clock[2] else None

    def reached_horizon(self):
        """Per joint: whether the last tick checked a test case at step k* (the slot started k* ticks ago)."""
        return self.active[:, (int(self._clock[0]) + 1) % self.S]

    def longest_step(self):
        """Per joint: the largest step k checked at the last tick (-1: nothing checked)."""
        return np.where(self.active, self.ages, -1).max(axis=1)

    def tick(self, stamp_ns, y, u):
        """Check one tick; returns a dict of per-joint arrays.

        Keys: ``status`` (list of ok | violation | invalid | gap_reset), ``margin`` (J,),
        ``checked`` (J,), ``step`` (J,), ``start_tick`` (J,), ``deviation`` (J,), ``bound`` (J,),
        ``longest`` (J,): the largest step k checked at this tick (-1: nothing checked; k*:
        the test case started k* ticks ago was checked, Theorem 1's last row), ``use`` (J,):
        the set use, the largest ``|N y_a| / bound`` over the checks of this tick
        (:func:`~reachset_ros.conformance.set_use.check_use`, the batch side's
        :func:`~reachset_ros.conformance.set_use.set_use` of the same tick; NaN: nothing checked).
        """
        if not self.kernel:
            return self._tick_numpy(stamp_ns, y, u)
        k = self._k
        k["y"][:] = y
        k["u"][:] = u
        ok = kernels.LIB.reachset_monitor_tick(k["ptr"], int(stamp_ns), k["mp_ptr"], k["mm_ptr"])
        if ok:
            status = list(self._all_ok)
        else:
            status = [self.STATUS[s] for s in k["out"]["status"].tolist()]
        margin, deviation, bound, use = k["F"].copy()          # rows of this tick's own copy
        checked, step, start_tick, longest = k["I"].copy()
        return {"status": status, "margin": margin, "checked": checked, "step": step, "start_tick": start_tick,
                "deviation": deviation, "bound": bound, "longest": longest, "use": use}

    def tick_many(self, stamps, Y, U):
        """:meth:`tick` for the ticks of a recording in a row (``reachset replay``).

        ``stamps`` (T,), ``Y`` and ``U`` (T, J). The compiled kernel runs the monitor's very tick
        function once per tick in one call (``reachset_monitor_ticks``), numpy calls
        :meth:`tick`; the verdicts are those of :meth:`tick` called T times, to the bit.

        Returns
        -------
        dict
            ``status`` (T, J) int8: index into :attr:`STATUS`; ``checked`` (T, J); ``use`` (T, J);
            ``seconds`` (T,): each tick's duration (the kernel's own, timed in C; with numpy,
            :meth:`tick`'s).
        """
        stamps = np.ascontiguousarray(stamps, dtype=np.int64)
        Y = np.ascontiguousarray(np.reshape(Y, (len(stamps), self.J)), dtype=np.float64)
        U = np.ascontiguousarray(np.reshape(U, (len(stamps), self.J)), dtype=np.float64)
        T = len(stamps)
        out = {"status": np.zeros((T, self.J), np.int8), "checked": np.zeros((T, self.J), np.int64),
               "use": np.full((T, self.J), np.nan), "seconds": np.zeros(T)}
        if self.kernel and T:
            k, ns, p = self._k, np.zeros(T, np.int64), kernels.ptr
            args = (k["ptr"], T, p(stamps), p(Y), p(U), k["mp_ptr"], k["mm_ptr"],   # state, ticks, inputs, scratch
                    p(out["status"]), p(out["checked"]), p(out["use"]), p(ns))      # per tick and joint; per tick
            if kernels.LIB.reachset_monitor_ticks(*args) < 0:
                raise RuntimeError("reachset_monitor_ticks failed")
            out["seconds"] = ns * 1e-9
            return out
        code = {s: i for i, s in enumerate(self.STATUS)}
        for t in range(T):
            t0 = time.perf_counter()
            r = self.tick(int(stamps[t]), Y[t], U[t])
            out["seconds"][t] = time.perf_counter() - t0
            out["status"][t] = [code[s] for s in r["status"]]
            out["checked"][t], out["use"][t] = r["checked"], r["use"]
        return out

    def _kernel_setup(self):
        p, J, S = self.plant, self.J, self.S
        N = J * S
        f8 = lambda a: np.ascontiguousarray(a, dtype=np.float64)   # noqa: E731
        k = {"A": f8(p.A), "B": f8(p.B), "C": f8(p.C), "D": f8(p.D), "y": np.zeros(J), "u": np.zeros(J),
             "mp": np.empty(N), "mm": np.empty(N), "BUn": np.empty((p.A.shape[0], N)),
             "act": self.active.view(np.uint8),
             # the outputs, rows of two blocks: a tick's result is two copies (issue 38.4)
             "F": np.empty((4, J)), "I": np.empty((4, J), np.int64)}
        if self.estimator.name == "lsq":       # its weights (the numpy path computes the same ones)
            k["EP"], k["ER"] = (f8(w) for w in lsq_weights(p, self.estimator.window))
        else:
            k["EP"] = k["ER"] = np.zeros(1)
        F, I = k["F"], k["I"]
        o = k["out"] = {"margin": F[0], "deviation": F[1], "bound": F[2], "use": F[3], "checked": I[0], "step": I[1],
                        "start_tick": I[2], "longest": I[3], "status": np.empty(J, np.int8)}
        ptr = kernels.ptr
        cl = self._clock
        st = _TickState(
            n=p.A.shape[0], J=J, S=S, H=self.estimator.history, dt=float(p.dt),
            A=ptr(k["A"]), B=ptr(k["B"]), C=ptr(k["C"]), D=ptr(k["D"]), has_d=int(self._planD is not None),
            N=float(self.models[0].normals[0][0, 0]), dp=ptr(self._dpf), dm=ptr(self._dmf),
            X0=ptr(self._Xbuf[0]), X1=ptr(self._Xbuf[1]), cur=ptr(self._cur),
            start=ptr(self.start), ages=ptr(self.ages), active=ptr(k["act"]),
            y_hist=ptr(self.y_hist), u_hist=ptr(self.u_hist), in_segment=ptr(self.in_segment),
            tick_index=ptr(cl[0:1]), last_stamp=ptr(cl[1:2]), has_last=ptr(cl[2:3]),
            Y=ptr(self._Y), Ny=ptr(self._Ny), U=ptr(self._U), BU=ptr(k["BUn"]),
            y_in=ptr(k["y"]), u_in=ptr(k["u"]),
            margin=ptr(o["margin"]), deviation=ptr(o["deviation"]), bound=ptr(o["bound"]),
            checked=ptr(o["checked"]), step=ptr(o["step"]), start_tick=ptr(o["start_tick"]),
            status=ptr(o["status"]), longest=ptr(o["longest"]), use=ptr(o["use"]),
            est_kind=int(self.estimator.name == "lsq"), EP=ptr(k["EP"]), ER=ptr(k["ER"]))
        k["state"] = st
        k["ptr"] = ctypes.cast(ctypes.pointer(st), ctypes.c_void_p)
        k["mp_ptr"], k["mm_ptr"] = ptr(k["mp"]), ptr(k["mm"])
        self._k = k
        self._all_ok = ("ok",) * J

    def _drop(self, rows):
        self.start[rows] = -1
        self.active[rows] = False
        self.in_segment[rows] = 0

    def _tick_numpy(self, stamp_ns, y, u):
        """:meth:`tick` in numpy (any plant and estimator); the reference for the kernel."""
        p, H, S, J = self.plant, self.estimator.history, self.S, self.J
        self._clock[0] += 1
        t = int(self._clock[0])
        y = np.asarray(y, dtype=np.float64).reshape(J)
        u = np.asarray(u, dtype=np.float64).reshape(J)
        gap = False
        if self._clock[2]:
            step = (int(stamp_ns) - int(self._clock[1])) * 1e-9
            if not (0.5 * p.dt <= step <= 1.5 * p.dt):
                gap = True
                self._drop(slice(None))
        self._clock[1], self._clock[2] = int(stamp_ns), 1
        valid = np.isfinite(y) & np.isfinite(u)
        all_valid = bool(valid.all())
        if not all_valid:
            self._drop(~valid)
            y = np.where(valid, y, 0.0)
            u = np.where(valid, u, 0.0)
        self.y_hist[:, :-1] = self.y_hist[:, 1:]
        self.y_hist[:, -1] = y
        self.u_hist[:, :-1] = self.u_hist[:, 1:]
        self.u_hist[:, -1] = u
        if all_valid:
            self.in_segment += 1
        else:
            self.in_segment[valid] += 1
        slot = t % S
        self.ages += 1
        self.active[:, slot] = False
        new = self.in_segment > H
        X = self.X
        if new.all():
            x0 = self.estimator.estimate_latest(p, self.y_hist, self.u_hist)
            X[:, slot::S] = x0
            self.start[:, slot] = t
            self.ages[:, slot] = 0
            self.active[:, slot] = True
        elif new.any():
            js = np.flatnonzero(new)
            x0 = self.estimator.estimate_latest(p, self.y_hist[js], self.u_hist[js])
            X[:, js * S + slot] = x0
            self.start[js, slot] = t
            self.ages[js, slot] = 0
            self.active[js, slot] = True
        active = self.active
        U = self._U
        U.reshape(J, S)[:] = u[:, None]
        Ystar = matvec_into(self._planC, X, self._Y)
        if self._planD is not None:
            Ystar += matvec_into(self._planD, U, self._DU)
        ya = np.repeat(y, S)[None, :] - Ystar
        Ny = matvec_into(self._planN, ya, self._Ny)[0].reshape(J, S)
        ages = np.minimum(self.ages, S - 1)
        idx = self._flat + ages
        mp = np.where(active, self._dpf[idx] - Ny, np.inf)
        mm = np.where(active, self._dmf[idx] + Ny, np.inf)
        # the set use of the checks (set_use.check_use, the batch side's formula), largest per joint
        r = check_use(Ny.reshape(1, -1), self._dpf[idx].reshape(1, -1), self._dmf[idx].reshape(1, -1))[0]
        use = np.fmax.reduce(np.where(active, r.reshape(J, S), np.nan), axis=1)
        jp, jm = mp.argmin(axis=1), mm.argmin(axis=1)
        r = np.arange(J)
        vp, vm = mp[r, jp], mm[r, jm]
        use_p = vp <= vm
        col = np.where(use_p, jp, jm)
        # fail closed: a NaN among the margins (argmin returns the first) is no margin at all
        margin = np.where(np.isnan(vp) | np.isnan(vm), np.nan, np.where(use_p, vp, vm))
        checked = active.sum(axis=1)
        # advance all nominal states: X <- A X + B U (same arithmetic as conformance.advance)
        Xn = matvec_into(self._planA, X, self._Xbuf[1 - self._cur[0]])
        Xn += matvec_into(self._planB, U, self._BU)
        self._cur[0] = 1 - self._cur[0]
        if all_valid and not gap and margin.min() >= 0:
            status = ["ok"] * J
        else:
            status = ["invalid" if not valid[j] else "violation" if not margin[j] >= 0 else
                      ("gap_reset" if gap else "ok") for j in range(J)]
        k = ages[r, col]
        has = checked > 0
        return {"status": status, "margin": np.where(valid, margin, -np.inf), "checked": checked,
                "step": np.where(has, k, -1), "start_tick": np.where(has, self.start[r, col], -1),
                "deviation": np.where(has, np.where(use_p, Ny[r, col], -Ny[r, col]), 0.0),
                "bound": np.where(has, np.where(use_p, self.dp[r, k], self.dm[r, k]), 0.0),
                "longest": np.where(active, self.ages, -1).max(axis=1), "use": use}


# ------------------------------------------------------------------ the compiled kernel
class _TickState(ctypes.Structure):
    """Mirror of ``tick_state`` in ``_tick.c`` (pointers into the Monitor's numpy arrays)."""

    _fields_ = ([(f, ctypes.c_int64) for f in ("n", "J", "S", "H")] + [("dt", ctypes.c_double)]
                + [(f, ctypes.c_void_p) for f in ("A", "B", "C", "D")] + [("has_d", ctypes.c_int64),
                                                                         ("N", ctypes.c_double)]
                + [(f, ctypes.c_void_p) for f in (
                    "dp", "dm", "X0", "X1", "cur", "start", "ages", "active", "y_hist", "u_hist",
                    "in_segment", "tick_index", "last_stamp", "has_last", "Y", "Ny", "U", "BU",
                    "y_in", "u_in", "margin", "deviation", "bound", "checked", "step", "start_tick",
                    "status", "longest", "use")]
                + [("est_kind", ctypes.c_int64), ("EP", ctypes.c_void_p), ("ER", ctypes.c_void_p)])


def _tick_kernel_applies(plant, estimator, joints):
    """The compiled kernel covers the per-joint LWA-4P plant (5 states, 1 in, 1 out) with ``fd``
    or ``lsq``."""
    return (kernels.LIB is not None and estimator.name in ("fd", "lsq") and plant.A.shape == (5, 5)
            and plant.B.shape == (5, 1) and plant.C.shape == (1, 5) and plant.D.shape == (1, 1)
            and 0 < joints <= 64)
