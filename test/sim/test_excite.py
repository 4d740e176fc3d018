"""Issue 35.3: ``reachset excite`` writes references that reach the reference class' limits on
every joint, alone and together, inside the joint limits, from rest back to rest; the bag reads
back as the reference node plays it (:class:`reachset_ros.sim.excite.TrajectoryPlayer`)."""
import json
import subprocess
import sys

import numpy as np
import pytest

from reachset_ros.cli import main
from reachset_ros.robot.dynamics import JOINT_NAMES, load_model
from reachset_ros.sim import excite as ex
from reachset_ros.sim.reference import ReferenceConfig

QD, QDD = 0.7, 2.0


def _lwa4p(**kw):
    rc = ReferenceConfig()
    return ex.ExciteConfig(names=tuple(JOINT_NAMES), q_min=rc.q_min, q_max=rc.q_max, qd_max=QD, qdd_max=QDD, **kw)


def test_the_excitation_stays_inside_the_joint_limits_and_the_class_and_reaches_its_limits_on_every_joint():
    cfg = _lwa4p(fractions=(0.5, 1.0))
    tr = ex.excitation(cfg)
    model = load_model()
    lo, hi = cfg.box
    tol = 1e-12
    # inside the box, hence the Table I box and the URDF's limits
    assert np.all(tr.q >= lo - tol) and np.all(tr.q <= hi + tol)
    assert np.all(tr.q >= model.lower) and np.all(tr.q <= model.upper)
    # inside the class, and at its limits on every joint (to the bit where the grid allows)
    assert np.max(np.abs(tr.qd)) <= QD * (1 + 1e-12) and np.max(np.abs(tr.qdd)) <= QDD * (1 + 1e-12)
    assert np.allclose(np.max(np.abs(tr.qd), axis=0), QD, rtol=1e-9, atol=0)
    assert np.allclose(np.max(np.abs(tr.qdd), axis=0), QDD, rtol=1e-12, atol=0)
    # both signs of velocity and acceleration on every joint
    for a in (tr.qd, tr.qdd):
        assert np.all(a.max(axis=0) > 0.99 * a.max()) and np.all(a.min(axis=0) < 0.99 * a.min())
    # the positions used: most of the box on every joint
    used = (tr.q.max(axis=0) - tr.q.min(axis=0)) / (hi - lo)
    assert np.all(used > 0.99), used
    # alone: ticks at which one joint is at full speed and every other at rest, for each joint
    fast = np.abs(tr.qd) >= QD * (1 - 1e-9)
    still = np.abs(tr.qd) == 0
    for j in range(cfg.q_min.size):
        others = np.delete(still, j, axis=1).all(axis=1)
        assert np.any(fast[:, j] & others), JOINT_NAMES[j]
    # together: ticks at which every joint is at full speed, in the same and in alternating directions
    together = fast.all(axis=1)
    signs = {tuple(np.sign(tr.qd[k]).astype(int)) for k in np.flatnonzero(together)}
    assert (1,) * 6 in signs and (-1,) * 6 in signs and (1, -1, 1, -1, 1, -1) in signs, signs
    # from rest at the box centre back to rest (within a tick's travel), and continuous
    assert np.array_equal(tr.q[0], cfg.q0) and not np.any(tr.qd[0]) and not np.any(tr.qdd[0])
    assert not np.any(tr.qd[-1]) and not np.any(tr.qdd[-1]) and np.all(np.abs(tr.q[-1] - cfg.q0) <= QD * cfg.dt)
    assert np.max(np.abs(np.diff(tr.qd, axis=0))) <= QDD * cfg.dt * (1 + 1e-12)
    # the samples are the exact integrals of the piecewise-constant acceleration
    assert np.allclose(tr.q[1:], tr.q[:-1] + tr.qd[:-1] * cfg.dt + tr.qdd[:-1] * cfg.dt ** 2 / 2, atol=1e-12)
    s = ex.summary(tr, cfg)
    assert all(v["velocity_fraction"] > 1 - 1e-9 and v["acceleration_fraction"] > 1 - 1e-12 for v in s.values())


def test_the_player_is_exact_between_samples_holds_at_a_rest_and_rests_at_the_end():
    tr = ex.excitation(_lwa4p(fractions=(1.0,), rest=0.2))
    p = ex.TrajectoryPlayer(tr)
    t0 = 10 ** 18
    assert np.array_equal(p.at(t0)[0], tr.q[0])
    for k in (1, 100, 777, 5000):
        q, qd, qdd = p.at(t0 + k * 4_000_000 + 1_000_000)        # a quarter tick after sample k
        tau = 0.001
        assert np.allclose(q, tr.q[k] + tr.qd[k] * tau + tr.qdd[k] * tau ** 2 / 2, atol=1e-15)
        assert np.array_equal(qdd, tr.qdd[k])
    # hold: runs on to the next sample at rest and stays there
    k = 5001
    q_h = [p.at(t0 + (k + i) * 4_000_000, hold=True) for i in range(2000)]
    rest = np.flatnonzero(np.all((tr.qd == 0) & (tr.qdd == 0), axis=1))
    r = rest[rest >= k][0]
    assert np.array_equal(q_h[-1][0], tr.q[r]) and not np.any(q_h[-1][1])
    # past the end: the last sample, at rest
    q, qd, qdd = ex.TrajectoryPlayer(tr).at(t0), None, None
    pl = ex.TrajectoryPlayer(tr)
    pl.at(t0)
    q, qd, qdd = pl.at(t0 + int(1e9 * (tr.t[-1] + 5)))
    assert np.array_equal(q, tr.q[-1]) and not np.any(qd) and not np.any(qdd) and pl.done


def test_cli_writes_the_bag_the_reference_node_reads_and_reports_each_joint(tmp_path, capsys):
    out = tmp_path / "excite"
    assert main(["excite", "--out", str(out), "--fractions", "1", "--rest", "0.2", "--json"]) == 0
    res = json.loads(capsys.readouterr().out)
    tr = ex.load_trajectory(out, qd_max=QD, qdd_max=QDD)
    assert tr.names == tuple(JOINT_NAMES) and len(tr) == res["samples"]
    model = load_model()
    for j, n in enumerate(JOINT_NAMES):
        v = res["joints"][n]
        assert v["max_abs_velocity"] == pytest.approx(QD, rel=1e-9) and v["velocity_fraction"] == pytest.approx(1.0)
        assert v["max_abs_acceleration"] == pytest.approx(QDD, rel=1e-12)
        assert v["position_range"] == [pytest.approx(tr.q[:, j].min()), pytest.approx(tr.q[:, j].max())]
        assert model.lower[j] < v["position_range"][0] and v["position_range"][1] < model.upper[j]
        assert v["position_box"][0] <= v["position_range"][0] and v["position_range"][1] <= v["position_box"][1]
    # --joints: only those move; the others rest at the start
    out2 = tmp_path / "two"
    assert main(["excite", "--out", str(out2), "--fractions", "1", "--joints", "arm_2_joint", "--json"]) == 0
    res2 = json.loads(capsys.readouterr().out)
    assert res2["joints"]["arm_2_joint"]["velocity_fraction"] == pytest.approx(1.0)
    assert all(res2["joints"][n]["max_abs_velocity"] == 0 for n in JOINT_NAMES if n != "arm_2_joint")


@pytest.mark.parametrize("args, words", [
    (["--fractions", "1", "0.5"], "--fractions must be ascending"),
    (["--fractions", "0"], "--fractions must be ascending"),
    (["--joints", "elbow"], "--joints: no joint elbow"),
    (["--margin", "0.5"], "--margin must be in [0, 0.5)"),
    (["--qd-max", "-1"], "--qd-max, --qdd-max and --dt must be > 0"),
    (["--qdd-max", "nan"], "--qdd-max must be finite"),
])
def test_bad_input_exits_2_with_one_line_and_writes_nothing(tmp_path, args, words):
    out = tmp_path / "b"
    p = subprocess.run([sys.executable, "-m", "reachset_ros.cli", "excite", "--out", str(out), *args],
                       capture_output=True, text=True, timeout=120)
    lines = p.stderr.strip().splitlines()
    assert p.returncode == 2 and len(lines) == 1 and words in lines[0], p.stderr
    assert list(tmp_path.iterdir()) == []


def test_a_file_outside_the_class_or_not_at_rest_is_refused_naming_it(tmp_path):
    tr = ex.excitation(_lwa4p(fractions=(1.0,), rest=0.1, excited=("arm_1_joint",)))
    ex.write_trajectory(tmp_path / "ok", tr)
    with pytest.raises(Exception, match=r"\|qd_d\| of arm_1_joint reaches 0.7, outside the class \(0.5\)"):
        ex.load_trajectory(tmp_path / "ok", qd_max=0.5, qdd_max=QDD)
    moving = ex.Trajectory(names=tr.names, t=tr.t[100:], q=tr.q[100:], qd=tr.qd[100:], qdd=tr.qdd[100:])
    ex.write_trajectory(tmp_path / "moving", moving)
    with pytest.raises(Exception, match="must start at rest"):
        ex.load_trajectory(tmp_path / "moving")
