"""``reachset replay``'s batch paths (issue 38.3) equal the monitor node's tick-by-tick ones:
``Monitor.tick_many`` (the compiled tick in a C loop, or numpy) equals ``Monitor.tick`` called per
tick, and ``envelope.track`` equals ``EnvelopeTracker.tick`` per tick, on streams with gaps, a
clock step back, non-finite samples and a fault."""
import numpy as np
import pytest

from reachset_ros.bags.series import JointSeries, segments_of
from reachset_ros.conformance import envelope as ev
from reachset_ros.conformance import kernels
from reachset_ros.conformance.monitor import Monitor, MonitorModel
from reachset_ros.systems.plant import lwa4p_joint_plant

from test_monitor_kernel import closed_loop, messy_stream, model_for

DT = 0.004


@pytest.mark.parametrize("kernel", [pytest.param(True, marks=pytest.mark.skipif(
    kernels.LIB_PATH is None, reason="compiled kernel not built")), False])
def test_tick_many_equals_tick_per_tick_bit_for_bit(kernel):
    p = lwa4p_joint_plant()
    Y, U = closed_loop(p, 2000, 4, seed=1)
    model, thm = model_for(p, Y[:1000], U[:1000], 40, scale=1.05)
    stamps, Ys, Us = messy_stream(Y, U, seed=2)
    mms = [MonitorModel.from_model(model, f"j{j}", thm) for j in range(4)]
    one, many = Monitor(mms, kernel=kernel), Monitor(mms, kernel=kernel)
    assert one.kernel == many.kernel == kernel
    rows = [one.tick(int(stamps[t]), Ys[t], Us[t]) for t in range(len(stamps))]
    cut = 1300                                    # replay resets the monitor at a bag boundary
    first = many.tick_many(stamps[:cut], Ys[:cut], Us[:cut])
    many.reset()
    one.reset()
    rows = rows[:cut] + [one.tick(int(stamps[t]), Ys[t], Us[t]) for t in range(cut, len(stamps))]
    second = many.tick_many(stamps[cut:], Ys[cut:], Us[cut:])
    got = {k: np.concatenate([first[k], second[k]]) for k in ("status", "checked", "use", "seconds")}
    status = np.array([[Monitor.STATUS.index(s) for s in r["status"]] for r in rows])
    assert np.array_equal(got["status"], status)
    assert np.array_equal(got["checked"], np.array([r["checked"] for r in rows]))
    assert got["use"].tobytes() == np.array([r["use"] for r in rows]).tobytes()
    assert set(np.unique(status)) == {0, 1, 2, 3} and (got["seconds"] >= 0).all() and got["seconds"].sum() > 0
    # the state after the ticks is the state after as many single ticks: the next tick agrees too
    a, b = one.tick(int(stamps[-1]) + 4_000_000, Ys[-1], Us[-1]), many.tick(int(stamps[-1]) + 4_000_000, Ys[-1], Us[-1])
    assert a["status"] == b["status"] and a["margin"].tobytes() == b["margin"].tobytes()


def series(y, u, name):
    stamps = np.arange(len(y), dtype=np.int64) * 4_000_000
    return JointSeries(name=name, stamps=stamps, y=y, u=u, segments=segments_of(stamps, np.isfinite(y) & np.isfinite(u),
                                                                                 DT), dt=DT)


def test_track_equals_the_tracker_tick_by_tick():
    rng = np.random.default_rng(3)
    t = np.arange(3000)[:, None] * DT
    wave = np.sin(2 * np.pi * 0.5 * t) * np.array([0.3, 0.2, 0.25])
    y, u = wave, -(np.pi ** 2) * wave + rng.normal(scale=0.05, size=(3000, 3))
    env = ev.fit({f"j{k}": series(y[:1500, k], u[:1500, k], f"j{k}") for k in range(3)}, bins=8, dilation=1,
                 hold=40)
    grow = np.linspace(0.6, 1.6, 1500)[:, None]               # from inside to outside and back in pieces
    ys, us = y[1500:] * grow, u[1500:] * grow
    ys[200:260] *= 3.0                                        # outside early, then inside again
    stamps = np.arange(len(ys), dtype=np.int64) * 4_000_000
    stamps[900:] += 40_000_000                                # a gap
    stamps[1100:] -= 30_000_000                               # a clock step back (a gap too)
    stamps[1300:] += 1_000_000                                # 1.25 dt: no gap
    ys[700, 1] = np.nan                                       # an invalid sample of one joint: all reset
    us[705, 2] = np.inf
    ys[706, :] = np.nan                                       # two invalid ticks in a row
    ys[707, 0] = np.nan
    names = ["j0", "j1", "j2"]
    tr = ev.EnvelopeTracker(env, names)
    online = np.array([tr.tick(int(stamps[i]), ys[i], us[i]) for i in range(len(stamps))])
    batch = ev.track(env, names, stamps, ys, us)
    assert batch.shape == online.shape and 0 < online.sum() < online.size - 100
    assert np.array_equal(batch, online)
    # a stretch starts as a new tracker does (replay restarts it where it resets the monitor)
    tr = ev.EnvelopeTracker(env, names)
    assert np.array_equal(ev.track(env, names, stamps[950:], ys[950:], us[950:]),
                          np.array([tr.tick(int(stamps[i]), ys[i], us[i]) for i in range(950, len(stamps))]))
    assert ev.track(env, names, stamps[:0], ys[:0], us[:0]).shape == (0, 3)
