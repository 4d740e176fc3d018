"""The compiled monitor tick (reachset_ros/conformance/_tick.c) equals the numpy tick bit for bit;
so does JointMonitor's tick for one-dimensional outputs."""
import numpy as np
import pytest

from reachset_ros import conformance as cf
from reachset_ros.conformance import kernels
from reachset_ros.conformance.estimators import Estimator
from reachset_ros.conformance.model import ConformanceModel, JointSets
from reachset_ros.conformance.monitor import JointMonitor, Monitor, MonitorModel
from reachset_ros.conformance.set_use import set_use
from reachset_ros.systems.plant import LinearPlant, lwa4p_joint_plant

T0 = 1_700_000_000_000_000_000
DT_NS = 4_000_000

needs_kernel = pytest.mark.skipif(kernels.LIB_PATH is None, reason="compiled kernel not built")


def closed_loop(p, T, J, seed):
    rng = np.random.default_rng(seed)
    Y, U, X = np.zeros((T, J)), np.zeros((T, J)), np.zeros((J, 5))
    for k in range(T):
        Y[k] = X[:, 0] + 2e-5 * rng.uniform(-1, 1, J)
        U[k] = np.sin(0.003 * k + np.arange(J)) - 100 * X[:, 1] - 20 * X[:, 2]
        X = X @ p.A.T + np.outer(U[k], p.B[:, 0]) + (p.Gw @ (np.array([[0.03], [3.0]]) * rng.uniform(-1, 1, (2, J)))).T
    return Y, U


def model_for(p, Y, U, K, scale=1.0, est=Estimator()):
    thm = cf.Theorem1.build(p, K)
    joints = {}
    for j in range(Y.shape[1]):
        s = cf.identify_sets(p, thm, cf.deviation_extremes(p, est, Y[:, j], U[:, j], ((0, len(Y)),), K, thm))
        joints[f"j{j}"] = JointSets(tuple(scale * s.alpha_w), tuple(scale * s.alpha_v), tuple(s.c_w), tuple(s.c_v))
    return ConformanceModel(p, {"kind": "lwa4p_joint", "dt": p.dt}, est, K, joints), thm


def messy_stream(Y, U, seed):
    """Stamps with gaps and a backwards step, NaN/inf samples in single joints and in all, a fault."""
    rng = np.random.default_rng(seed)
    T, J = Y.shape
    Y, U = Y.copy(), U.copy()
    stamps = T0 + DT_NS * np.arange(T, dtype=np.int64)
    stamps[300:] += 3 * DT_NS                      # a gap
    stamps[700:] -= 2 * DT_NS                      # a step backwards (also a gap)
    stamps[900:] += 1_000_000                      # 1.25 dt step: no gap
    for t in rng.choice(np.arange(50, T), 12, replace=False):
        Y[t, rng.integers(J)] = rng.choice([np.nan, np.inf, -np.inf])
    U[450, :] = np.nan
    U[1200, 2] = np.inf
    Y[1500:, 1] += 0.5 * 1e-4 * np.arange(T - 1500) ** 2 * 1e-2   # an acceleration fault on joint 1
    return stamps, Y, U


@needs_kernel
@pytest.mark.parametrize("plant_kind,estimator", [("lwa4p", "fd"), ("with_feedthrough", "fd"), ("lwa4p", "lsq")])
def test_kernel_equals_numpy_bit_for_bit(plant_kind, estimator):
    p = lwa4p_joint_plant()
    if plant_kind == "with_feedthrough":   # exercise the D-term, a non-unit normal is covered by N = 1 only
        p = LinearPlant(p.A, p.B, p.C, np.array([[0.25 * p.dt ** 2]]), p.Gw, p.Gv, p.dt)
    Y, U = closed_loop(p, 2200, 6, seed=1)
    model, thm = model_for(p, Y[:1000], U[:1000], K=40, scale=1.02, est=Estimator.named(estimator, p))
    mms = [MonitorModel.from_model(model, f"j{j}", thm) for j in range(6)]
    a, b = Monitor(mms, kernel=True), Monitor(mms, kernel=False)
    assert a.kernel and not b.kernel
    stamps, Ys, Us = messy_stream(Y, U, seed=2)
    seen = set()
    for t in range(len(stamps)):
        ra, rb = a.tick(int(stamps[t]), Ys[t], Us[t]), b.tick(int(stamps[t]), Ys[t], Us[t])
        assert ra["status"] == rb["status"], t
        seen.update(ra["status"])
        for key in ("margin", "checked", "step", "start_tick", "deviation", "bound", "longest", "use"):
            assert ra[key].tobytes() == rb[key].tobytes(), (t, key, ra[key], rb[key])
        if t % 97 == 0 or t == len(stamps) - 1:
            assert a.X.tobytes() == b.X.tobytes()
            for f in ("start", "ages", "active", "y_hist", "u_hist", "in_segment"):
                assert getattr(a, f).tobytes() == getattr(b, f).tobytes(), (t, f)
            assert (a.tick_index, a.last_stamp) == (b.tick_index, b.last_stamp)
    assert seen == {"ok", "violation", "invalid", "gap_reset"}


@needs_kernel
@pytest.mark.parametrize("estimator", ["fd", "lsq"])
def test_kernel_verdicts_equal_the_batch_check(estimator):
    p = lwa4p_joint_plant()
    Y, U = closed_loop(p, 3000, 3, seed=4)
    est = Estimator.named(estimator, p)
    model, thm = model_for(p, Y[:2000], U[:2000], K=60, est=est)
    Y = Y.copy()
    Y[2400:, 0] += 2e-4 * np.arange(600) ** 2 * 4e-3      # fault on joint 0
    mms = [MonitorModel.from_model(model, f"j{j}", thm) for j in range(3)]
    m = Monitor(mms, kernel=True)
    first = [None] * 3
    viol = np.zeros(3, int)
    for t in range(len(Y)):
        r = m.tick(T0 + DT_NS * t, Y[t], U[t])
        for j, s in enumerate(r["status"]):
            if s == "violation":
                viol[j] += 1
                first[j] = t if first[j] is None else first[j]
    for j in range(3):
        res = cf.check(p, thm, est, model.joints[f"j{j}"].xi(model.inflation), Y[:, j], U[:, j],
                       ((0, len(Y)),), 60)
        assert res.violations == viol[j]
        assert res.first_violation_tick == (-1 if first[j] is None else first[j])
    assert viol[0] > 0


@pytest.mark.parametrize("plant_kind", ["lwa4p", "with_feedthrough"])
def test_joint_monitor_equals_numpy_tick(plant_kind):
    """JointMonitor (one joint, any output dimension) and Monitor's numpy tick, for ny = 1 on the
    messy stream: the same status, margin and reported check, bit for bit (Monitor's module
    docstring says why there are two)."""
    p = lwa4p_joint_plant()
    if plant_kind == "with_feedthrough":
        p = LinearPlant(p.A, p.B, p.C, np.array([[0.25 * p.dt ** 2]]), p.Gw, p.Gv, p.dt)
    Y, U = closed_loop(p, 2200, 3, seed=1)
    model, thm = model_for(p, Y[:1000], U[:1000], K=40, scale=1.02)
    mms = [MonitorModel.from_model(model, f"j{j}", thm) for j in range(3)]
    mon, jms = Monitor(mms, kernel=False), [JointMonitor(m) for m in mms]
    stamps, Ys, Us = messy_stream(Y, U, seed=2)
    seen = set()
    for t in range(len(stamps)):
        r = mon.tick(int(stamps[t]), Ys[t], Us[t])
        for j, jm in enumerate(jms):
            q = jm.tick(int(stamps[t]), Ys[t, j], Us[t, j])
            assert q.status == r["status"][j], (t, j)
            seen.add(q.status)
            for key in ("margin", "checked", "step", "start_tick", "deviation", "bound", "use"):
                assert np.float64(getattr(q, key)).tobytes() == np.float64(r[key][j]).tobytes(), (t, j, key)
    assert seen == {"ok", "violation", "invalid", "gap_reset"}


@needs_kernel
def test_the_loaded_kernel_has_the_state_layout_of_its_mirror():
    """A library built from an older _tick.c (a tick_state without ``use``) would leave the set
    use unwritten: kernels.py loads only one whose reachset_tick_abi is kernels.TICK_ABI."""
    assert kernels.LIB.reachset_tick_abi() == kernels.TICK_ABI == 4


def batch_segments(stamps, y, u, dt):
    """The segments ``reachset check`` cuts a stream into: a stamp step outside [0.5, 1.5] dt
    (the monitor's gap rule) ends one, a non-finite sample is left out of every one."""
    steps = np.diff(stamps) * 1e-9
    gap = np.concatenate([[False], ~((0.5 * dt <= steps) & (steps <= 1.5 * dt))])
    valid = np.isfinite(y).all(axis=1) & np.isfinite(u).all(axis=1)
    segs, s = [], None
    for t in range(len(stamps)):
        if s is not None and (gap[t] or not valid[t]):
            segs.append((s, t))
            s = None
        if valid[t] and s is None:
            s = t
    return segs + ([(s, len(stamps))] if s is not None else [])


@pytest.mark.parametrize("kernel", [pytest.param(True, marks=needs_kernel), False])
def test_online_set_use_equals_the_batch_set_use_bit_for_bit(kernel):
    """Issue 36.3: the set use the monitor reports per tick and joint (``use``, published as
    ConformanceStatus.set_use) is set_use.set_use's (``reachset report``'s) of the same tick, to
    the bit: gaps, a clock step back, non-finite samples (NaN where nothing is checked) and a
    fault with violations (use > 1 exactly at the violating ticks). JointMonitor's too."""
    p = lwa4p_joint_plant()
    Y, U = closed_loop(p, 2200, 6, seed=1)
    model, thm = model_for(p, Y[:1000], U[:1000], K=40, scale=1.02)
    mms = [MonitorModel.from_model(model, f"j{j}", thm) for j in range(6)]
    mon, jms = Monitor(mms, kernel=kernel), [JointMonitor(m) for m in mms]
    stamps, Ys, Us = messy_stream(Y, U, seed=2)
    online, single = np.empty(Ys.shape), np.empty(Ys.shape)
    violating = np.zeros(Ys.shape, dtype=bool)
    for t in range(len(stamps)):
        r = mon.tick(int(stamps[t]), Ys[t], Us[t])
        online[t] = r["use"]
        violating[t] = [s == "violation" for s in r["status"]]
        single[t] = [jm.tick(int(stamps[t]), Ys[t, j], Us[t, j]).use for j, jm in enumerate(jms)]
    assert single.tobytes() == online.tobytes()
    for j in range(6):
        y, u = Ys[:, j:j + 1], Us[:, j:j + 1]
        segs = batch_segments(stamps, y, u, p.dt)
        batch = set_use(p, thm, Estimator(), model.checked_xi(f"j{j}"), np.where(np.isfinite(y), y, 0.0),
                        np.where(np.isfinite(u), u, 0.0), segs, 40)
        assert batch.use.tobytes() == online[:, j].tobytes(), j
        assert np.array_equal(batch.violating, violating[:, j]) and np.array_equal(online[:, j] > 1, violating[:, j])
    assert np.isnan(online).any() and (online > 1).any() and ((online > 0.5) & (online <= 1)).any()


def test_joint_monitor_set_use_equals_the_batch_set_use_for_two_outputs():
    """JointMonitor's set use with a two-dimensional output (normals N_k of several rows that
    change with k): the batch side's, bit for bit, violations included."""
    dt = 0.01
    A = np.array([[1, dt, 0], [0, 0.98, dt], [0, 0, 0.9]])
    C = np.array([[1.0, 0, 0], [0, 1.0, 0]])
    p = LinearPlant(A=A, B=np.array([[0], [0], [dt]]), C=C, Gw=np.array([[dt, 0], [0, dt], [0, 0]]), Gv=np.eye(2),
                    dt=dt)
    rng = np.random.default_rng(5)
    T, K = 1200, 8
    x, y, u = np.zeros(3), np.zeros((T, 2)), np.zeros((T, 1))
    for k in range(T):
        y[k] = C @ x + 1e-3 * rng.uniform(-1, 1, 2)
        u[k] = -5 * x[0] - 2 * x[1] + np.sin(0.01 * k)
        x = A @ x + p.B @ u[k] + p.Gw @ (0.5 * rng.uniform(-1, 1, 2))
    est = Estimator("output")
    thm = cf.Theorem1.build(p, K)
    sets = cf.identify_sets(p, thm, cf.deviation_extremes(p, est, y, u, ((0, T),), K, thm))
    js = {"j": JointSets(tuple(0.8 * sets.alpha_w), tuple(0.8 * sets.alpha_v), tuple(sets.c_w), tuple(sets.c_v))}
    model = ConformanceModel(p, {"kind": "matrices", "dt": dt}, est, K, js)
    y = y.copy()
    y[600, 1] = np.nan                                    # a hole: NaN use while the test cases restart
    jm = JointMonitor(MonitorModel.from_model(model, "j"))
    stamps = T0 + 10_000_000 * np.arange(T, dtype=np.int64)
    online = np.array([jm.tick(int(stamps[i]), y[i], u[i]).use for i in range(T)])
    batch = set_use(p, thm, est, model.checked_xi("j"), np.where(np.isfinite(y), y, 0.0), u,
                    batch_segments(stamps, y, u, dt), K)
    assert batch.use.tobytes() == online.tobytes()
    assert (online > 1).any() and np.isnan(online[600])


@pytest.mark.parametrize("kernel", [pytest.param(True, marks=needs_kernel), False])
def test_longest_step_and_horizon_reached_say_how_much_was_checked(kernel):
    """After each tick, per joint: the largest step k checked is min(valid ticks in the segment
    - history - 1, k*) (-1 while nothing could be checked: the warm-up after a start, a gap
    or an invalid sample), and the horizon is reached exactly when that is k*; a tick with
    nothing checked is never conformant, for Monitor and for JointMonitor."""
    p = lwa4p_joint_plant()
    K, H = 40, 3
    Y, U = closed_loop(p, 2200, 3, seed=1)
    model, thm = model_for(p, Y[:1000], U[:1000], K=K, scale=1.02)
    mms = [MonitorModel.from_model(model, f"j{j}", thm) for j in range(3)]
    mon = Monitor(mms, kernel=kernel)
    jm = JointMonitor(mms[0])
    stamps, Ys, Us = messy_stream(Y, U, seed=2)
    seen = set()
    for t in range(len(stamps)):
        r = mon.tick(int(stamps[t]), Ys[t], Us[t])
        q = jm.tick(int(stamps[t]), Ys[t, 0], Us[t, 0])
        expect = np.where(mon.in_segment > H, np.minimum(mon.in_segment - H - 1, K), -1)
        longest = mon.longest_step()
        assert np.array_equal(longest, expect), (t, longest, expect)
        assert np.array_equal(r["longest"], expect), (t, r["longest"], expect)
        assert np.array_equal(mon.reached_horizon(), expect == K), t
        assert np.array_equal(r["checked"] > 0, longest >= 0), t
        assert q.checked == r["checked"][0] and q.conformant == (q.checked > 0 and q.status in ("ok", "gap_reset"))
        seen.update(int(x) for x in longest)
    assert {-1, 0, K - 1, K} <= seen


def test_numpy_fallback_when_the_kernel_does_not_apply():
    """A plant the kernel does not cover (two states) runs the numpy tick; kernel=True refuses it."""
    A = np.array([[1.0, 0.004], [0.0, 1.0]])
    p = LinearPlant(A, np.array([[0.0], [0.004]]), np.array([[1.0, 0.0]]), np.zeros((1, 1)),
                    np.eye(2), np.eye(1), 0.004)
    js = {"j": JointSets((0.01, 0.01), (1e-4,), (0.0, 0.0), (0.0,))}
    model = ConformanceModel(p, {"kind": "matrices", "dt": 0.004}, Estimator("output"), 10, js)
    mm = MonitorModel.from_model(model, "j")
    assert not Monitor([mm]).kernel
    with pytest.raises(ValueError):
        Monitor([mm], kernel=True)
    r = Monitor([mm]).tick(T0, [0.0], [0.0])
    assert r["status"] == ["ok"] and r["checked"][0] == 1


def _collect(plant, y, u, segments, horizon, block):
    seen = []
    cf.sweep(plant, Estimator("fd" if plant.A.shape[0] == 5 and plant.C.shape[0] == 1 else "output"), y, u, segments,
             horizon, lambda k, m, t, ya: seen.append((k, m.copy(), t.copy(), ya.copy())), block=block)
    return seen


@needs_kernel
@pytest.mark.parametrize("plant_kind", ["lwa4p", "two_outputs_with_feedthrough"])
def test_compiled_sweep_equals_numpy_sweep_bit_for_bit(plant_kind, monkeypatch):
    p = lwa4p_joint_plant()
    Y, U = closed_loop(p, 1500, 1, seed=5)
    if plant_kind == "two_outputs_with_feedthrough":
        C = np.vstack([p.C, [[0.0, 0.0, 1.0, 0.0, 0.0]]])
        p = LinearPlant(p.A, p.B, C, np.array([[0.0], [0.5 * p.dt]]), p.Gw, np.eye(2) * 1e-4, p.dt)
        Y = np.hstack([Y, np.cumsum(Y, axis=0) * 1e-3])
    segments = ((0, 40), (41, 700), (703, 1500))      # one segment shorter than the horizon
    compiled = _collect(p, Y, U, segments, 60, block=128)
    monkeypatch.setattr(kernels, "LIB", None)
    reference = _collect(p, Y, U, segments, 60, block=16384)
    assert len(compiled) > len(reference)          # different blocking, same per-k content
    by_k = {}
    for k, m, t, ya in compiled:
        by_k.setdefault(k, []).append((m, t, ya))
    for k, m, t, ya in reference:
        mc = np.concatenate([b[0] for b in by_k[k]])
        yac = np.concatenate([b[2] for b in by_k[k]], axis=1)
        assert np.array_equal(mc, m) and np.array_equal(np.concatenate([b[1] for b in by_k[k]]), t)
        assert yac.tobytes() == ya.tobytes(), k
