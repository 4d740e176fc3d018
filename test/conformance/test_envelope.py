"""The validated envelope (issue 37): features, classification, hold, the online tracker, the
model file's ``envelope`` block."""
import numpy as np
import pytest
import yaml

from reachset_ros.bags.series import JointSeries, segments_of
from reachset_ros.conformance import envelope as ev
from reachset_ros.conformance import model as mdl
from reachset_ros.errors import ReachsetError

from helpers import write_model

DT = 0.004


def series(y, u, stamps=None, name="j"):
    y, u = np.asarray(y, float), np.asarray(u, float)
    stamps = np.arange(len(y), dtype=np.int64) * 4_000_000 if stamps is None else np.asarray(stamps, np.int64)
    return JointSeries(name=name, stamps=stamps, y=y, u=u, segments=segments_of(stamps, np.isfinite(y) & np.isfinite(u),
                                                                                 DT), dt=DT)


def sweep(q0, q1, n, u=0.0):
    """A ramp of positions from q0 to q1 in n ticks (constant velocity), plant input u."""
    return np.linspace(q0, q1, n), np.full(n, u)


def test_features_are_causal_and_unknown_at_a_segments_start():
    """A tick's features use only samples up to it in its segment (the monitor computes them online)."""
    rng = np.random.default_rng(0)
    y, u = rng.normal(size=200), rng.normal(size=200)
    F = ev.series_features(y, u, ((0, 200),), DT)
    y2 = y.copy()
    y2[120:] += 5.0                                     # change the future of tick 119
    F2 = ev.series_features(y2, u, ((0, 200),), DT)
    assert np.array_equal(F[:120], F2[:120], equal_nan=True) and not np.array_equal(F[120:], F2[120:])
    assert np.isnan(F[:ev.VELOCITY_LAG, 1]).all() and np.isfinite(F[ev.VELOCITY_LAG:, 1]).all()
    assert np.isnan(F[:ev.HISTORY, 2]).all() and np.isfinite(F[ev.HISTORY:, 2]).all()
    assert F[50, 1] == (y[50] - y[46]) / (4 * DT)


def test_a_grid_tells_combinations_a_box_cannot():
    """Training: moving up at low positions, down at high ones. Moving down at a low position is
    inside the per-joint box (every feature in its range) but outside the (q, qd) grid."""
    ya, ua = sweep(0.0, 0.5, 500)
    yb, ub = sweep(2.0, 1.5, 500)
    y = np.concatenate([ya, [np.nan], yb])
    u = np.concatenate([ua, [0.0], ub])
    train = {"j": series(y, u)}
    yt, ut = sweep(0.5, 0.0, 500)                     # low position, moving down at the same speed
    test = series(yt, ut)
    box = ev.fit(train, bins=16, dilation=1, hold=0, grids=())
    grid = ev.fit(train, bins=16, dilation=1, hold=0)
    out_box, n = ev.classify_series(box, "j", test)
    out_grid, _ = ev.classify_series(grid, "j", test)
    assert n == 500 and out_box.sum() == 0
    assert out_grid[ev.VELOCITY_LAG:].all()          # from the first tick whose velocity is known
    # the training data themselves are inside
    assert ev.classify_series(grid, "j", train["j"])[0].sum() == 0


def test_hold_keeps_a_tick_outside_for_hold_ticks_of_its_segment():
    outside = np.zeros(30, dtype=bool)
    outside[5] = True
    held = ev.held_outside(outside, ((0, 10), (10, 30)), 3)
    assert np.flatnonzero(held).tolist() == [5, 6, 7, 8]
    outside[9] = True                                 # the next segment starts inside
    assert np.flatnonzero(ev.held_outside(outside, ((0, 10), (10, 30)), 3)).tolist() == [5, 6, 7, 8, 9]


def test_the_online_tracker_classifies_every_tick_as_the_batch_does():
    """EnvelopeTracker (the monitor's, replay's) equals classify_series (check's) tick for tick,
    across a stamp gap and an invalid sample, for two joints at once."""
    rng = np.random.default_rng(3)
    t = np.arange(3000)[:, None] * DT
    wave = np.sin(2 * np.pi * 0.5 * t) * np.array([0.3, 0.2])
    y, u = wave, -(np.pi ** 2) * wave + rng.normal(scale=0.05, size=(3000, 2))
    train = {f"j{k}": series(y[:1500, k], u[:1500, k], name=f"j{k}") for k in range(2)}
    env = ev.fit(train, bins=8, dilation=1, hold=40)
    grow = np.linspace(0.6, 1.6, 1500)[:, None]           # from inside to outside
    ys, us = y[1500:] * grow, u[1500:] * grow
    stamps = np.arange(len(ys), dtype=np.int64) * 4_000_000
    stamps[900:] += 40_000_000                           # a gap
    ys[700, 1] = np.nan                                  # an invalid sample (of joint j1; the monitor resets all)
    us[700, :] = np.where(np.isnan(ys[700]), np.nan, us[700])
    test = {f"j{k}": series(ys[:, k], us[:, k], stamps, name=f"j{k}") for k in range(2)}
    tr = ev.EnvelopeTracker(env, ["j0", "j1"])
    online = np.array([tr.tick(int(stamps[i]), ys[i], us[i]) for i in range(len(stamps))])
    valid = np.isfinite(ys).all(axis=1)
    for k in range(2):
        s = test[f"j{k}"]
        # the monitor sees one tick of all joints: j1's invalid sample ends j0's segment too
        s = JointSeries(name=s.name, stamps=s.stamps, y=np.where(valid, s.y, np.nan), u=s.u,
                        segments=segments_of(stamps, valid, DT), dt=DT)
        batch, _ = ev.classify_series(env, s.name, s)
        assert 0 < batch.sum() < len(batch) - 1
        assert np.array_equal(online[:, k], batch)


def test_the_model_file_round_trips_the_envelope_and_refuses_a_bad_one(tmp_path):
    rng = np.random.default_rng(1)
    y = np.cumsum(rng.normal(scale=0.002, size=800))
    env = ev.fit({"arm_1_joint": series(y, rng.normal(size=800), name="arm_1_joint")}, bins=16, dilation=1, hold=125)
    path = tmp_path / "m.yaml"
    write_model(path, joints=["arm_1_joint"])
    old = mdl.load(path)
    assert old.envelope is None and ev.summary(old.envelope)["recorded"] is False
    mdl.save(mdl.ConformanceModel(**{**old.__dict__, "envelope": env}), path)
    back = mdl.load(path).envelope
    probe = ev.series_features(rng.normal(scale=0.05, size=400) + y[:400], rng.normal(size=400), ((0, 400),), DT)
    assert np.array_equal(ev.inside(back.joints["arm_1_joint"], probe), ev.inside(env.joints["arm_1_joint"], probe))
    assert (back.bins, back.dilation, back.hold, back.grids) == (16, 1, 125, (("q", "qd"), ("qd", "u")))
    d = yaml.safe_load(path.read_text())
    d["envelope"]["joints"]["arm_1_joint"]["grids"][0]["rows"][0] += "1"
    with pytest.raises(ReachsetError, match=r"^m: envelope joint arm_1_joint grid \(q, qd\): rows must be"):
        mdl.from_dict(d, "m")
    d = yaml.safe_load(path.read_text())
    d["envelope"]["velocity_lag"] = 2
    with pytest.raises(ReachsetError, match="envelope features/lags are not this version's"):
        mdl.from_dict(d, "m")


def test_the_monitor_core_classifies_as_check_and_says_so_in_a_violations_reason(tmp_path):
    """MonitorCore (the monitor node without ROS) classifies every tick with the tracker, as
    classify_series does (check), across a gap; a model without an envelope classifies nothing."""
    from helpers import JOINTS, stream, write_envelope_model
    from reachset_ros.conformance.monitor_core import MonitorCore
    from reachset_ros.conformance.watches import TickEvent
    m = mdl.load(write_envelope_model(tmp_path / "m.yaml"))
    Y, U = stream(600, seed=5)
    Y[300:] += np.linspace(0.0, 0.3, 300)[:, None]        # drifts out of the envelope (and violates)
    stamps = np.arange(600, dtype=np.int64) * 4_000_000
    stamps[200:] += 80_000_000                            # a gap
    core = MonitorCore(m)
    got = {}
    for i in range(600):
        for e in core.add_y(int(stamps[i]), JOINTS, Y[i]) + core.add_u(int(stamps[i]), JOINTS, U[i]):
            if isinstance(e, TickEvent):
                got[i] = e.outside_envelope
    assert sorted(got) == list(range(600))
    online = np.array([got[i] for i in range(600)])
    for k, j in enumerate(JOINTS):
        s = JointSeries(name=j, stamps=stamps, y=Y[:, k], u=U[:, k], segments=segments_of(stamps, np.ones(600, bool),
                                                                                           DT), dt=DT)
        batch, _ = ev.classify_series(m.envelope, j, s)
        assert np.array_equal(online[:, k], batch) and batch[:300].sum() < 50 and batch[400:].all()
    assert core.counters["outside_envelope_ticks"] == int(online.any(axis=1).sum())
    bare = MonitorCore(mdl.load(write_model(tmp_path / "bare.yaml")))
    ev_bare = [e for e in bare.add_y(0, JOINTS, Y[0]) + bare.add_u(0, JOINTS, U[0]) if isinstance(e, TickEvent)]
    assert bare.envelope is None and ev_bare[0].outside_envelope is None
    assert "OUTSIDE the validated envelope" in ev.violation_note(True)
    assert "inside the validated envelope" in ev.violation_note(False)
    assert "records no validated envelope" in ev.violation_note(None)


def test_reference_limits_cut_the_class_to_the_envelopes_axes_and_name_the_cuts():
    """Issue 37.3: a reference class reaching beyond the envelope is cut to its position,
    velocity and acceleration axes, each cut named (the part never validated); a class inside
    is unchanged; a joint the envelope does not record keeps its limits, named."""
    import numpy as np
    import pytest
    from reachset_ros.conformance.envelope import Axis, Envelope, JointEnvelope, axis_range, reference_limits
    from reachset_ros.errors import ReachsetError
    axes = {"q": Axis(origin=-0.5, cell=0.1, cells=10), "qd": Axis(origin=-0.3, cell=0.05, cells=10),
            "qdd": Axis(origin=-1.0, cell=0.25, cells=10), "u": Axis(origin=-2.0, cell=0.4, cells=10)}
    env = Envelope(joints={"a": JointEnvelope(axes=axes)}, dt=0.004, bins=8, dilation=1, hold=0)
    assert axis_range(env.joints["a"], "qd") == pytest.approx((-0.3, 0.2))
    inside, cut = reference_limits(env, ["a"], q_min=-0.4, q_max=0.4, qd_max=0.1, qdd_max=1.0)
    assert cut == [] and inside["qd_max"].tolist() == [0.1] and inside["q_min"].tolist() == [-0.4]
    lim, cut = reference_limits(env, ["a", "b"], q_min=[-2.0, -2.0], q_max=[2.0, 2.0], qd_max=0.7, qdd_max=2.0)
    assert lim["q_min"].tolist() == pytest.approx([-0.5, -2.0]) and lim["q_max"].tolist() == pytest.approx([0.5, 2.0])
    assert lim["qd_max"].tolist() == pytest.approx([0.2, 0.7])       # min(0.3, 0.2): symmetric references
    assert lim["qdd_max"].tolist() == pytest.approx([1.0, 2.0])
    assert len(cut) == 4 and cut[0].startswith("a: positions [-2, 2] rad, validated [-0.5, 0.5]")
    assert "a: |qd| up to 0.7 rad/s, validated up to 0.2" in cut and cut[-1].startswith("b: not recorded")
    skew = Envelope(joints={"a": JointEnvelope(axes={**axes, "qd": Axis(origin=0.1, cell=0.1, cells=3)})},
                    dt=0.004, bins=8, dilation=1, hold=0)
    with pytest.raises(ReachsetError, match="qd axis .* does not contain 0"):
        reference_limits(skew, ["a"], q_min=-0.4, q_max=0.4, qd_max=0.1, qdd_max=1.0)
    assert np.all(np.isfinite(lim["q_min"]))
