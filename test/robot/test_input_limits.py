"""Input limits U_p from the torque limits (paper eq. 11, Table I): soundness and the command."""
import json

import numpy as np
import pinocchio as pin
import pytest

from reachset_ros import cli
from reachset_ros.robot import input_limits as il
from reachset_ros.robot import interval as iv
from reachset_ros import robot as rb
from reachset_ros.errors import InfeasibleError


@pytest.fixture(scope="module")
def model():
    return rb.load_model()


@pytest.fixture(scope="module")
def limits(model):
    return il.input_limits(model, refine=3, samples=500)


def test_interval_rnea_is_exact_on_points_and_encloses_boxes(model):
    data = rb.create_data(model)
    rng = np.random.default_rng(0)
    for _ in range(5):
        q, qd, qdd = rng.uniform(-2, 2, 6), rng.uniform(-1, 1, 6), rng.uniform(-3, 3, 6)
        lo, hi = iv.interval_rnea(model, q[None], q[None], qd, qd, qdd)
        ref = pin.rnea(model.pin_model, data, q, qd, qdd)
        assert np.all(lo[0] <= ref) and np.all(ref <= hi[0]) and np.max(hi - lo) < 1e-9
    # a batch of boxes of 0.3 rad, velocities in [-0.7, 0.7]: every sample inside
    c = rng.uniform(-2, 2, (8, 6))
    lo, hi = iv.interval_rnea(model, c - 0.15, c + 0.15, -0.7, 0.7, np.array([1.0, -2, 0.5, 0, 3, -1]))
    for b in range(8):
        for _ in range(50):
            q = c[b] + rng.uniform(-0.15, 0.15, 6)
            tau = pin.rnea(model.pin_model, data, q, rng.uniform(-0.7, 0.7, 6), np.array([1.0, -2, 0.5, 0, 3, -1]))
            assert np.all(lo[b] <= tau) and np.all(tau <= hi[b])


def test_trigonometric_bounds_enclose_mass_matrix_and_gravity(model):
    data = rb.create_data(model)
    tb = il.TrigBounds(model, [1, 2, 3, 4, 5])
    assert max(tb.verify_error) < 1e-9
    rng = np.random.default_rng(1)
    c = rng.uniform(-2, 2, (20, 6))
    c[:, 0] = 0.0
    r = np.full((20, 6), 0.4)
    r[:, 0] = 0.0
    mbar, gbar, _, _ = tb.box_bounds(c, r)
    for b in range(20):
        for _ in range(40):
            q = c[b] + rng.uniform(-1, 1, 6) * r[b]
            M = rb.mass_matrix(model, data, q)
            g = pin.computeGeneralizedGravity(model.pin_model, data, q)
            assert np.all(np.abs(M) <= mbar[b]) and np.all(np.abs(g) <= gbar[b])
    # Coriolis/centrifugal: global bound holds at the velocity box's corners
    cb = tb.coriolis_bound(rb.TABLE1_QD_MAX)
    for _ in range(200):
        q = rng.uniform(-np.pi, np.pi, 6)
        qd = rb.TABLE1_QD_MAX * rng.choice([-1.0, 1.0], 6)
        cor = pin.nonLinearEffects(model.pin_model, data, q, qd) - pin.computeGeneralizedGravity(model.pin_model, data, q)
        assert np.all(np.abs(cor) <= cb)


def test_random_samples_never_need_more_torque_than_the_limits(model, limits):
    """(q, qd, u) inside Q x dQ x U_p: |M(q) u + psi(q, qd)| <= tau_max, for the limits found."""
    data = rb.create_data(model)
    rng = np.random.default_rng(2)
    a = limits.a
    worst = np.zeros(6)
    for k in range(3000):
        q = rng.uniform(-rb.TABLE1_Q_MAX, rb.TABLE1_Q_MAX)
        qd = rb.TABLE1_QD_MAX * (rng.choice([-1.0, 1.0], 6) if k % 2 else rng.uniform(-1, 1, 6))
        u = a * (rng.choice([-1.0, 1.0], 6) if k % 3 else rng.uniform(-1, 1, 6))
        tau = rb.feedback_linearization(model, data, q, qd, u)
        worst = np.maximum(worst, np.abs(tau))
    assert np.all(worst <= rb.TABLE1_TAU_MAX), (worst, a)
    assert np.all(limits.worst_torque <= rb.TABLE1_TAU_MAX * (1 + 1e-12))
    assert np.all(limits.sampled_torque <= limits.worst_torque)
    # the sound bound is not wildly conservative on the binding axis
    b = limits.binding[0]
    assert limits.sampled_torque[b] >= 0.7 * limits.worst_torque[b]
    assert np.all(a > 10.0)


def test_paper_table_i_limits_are_certified_for_the_shipped_model(model):
    ok, worst = il.check_limits(model, [26, 26, 26, 26, 100, 100])
    assert ok and np.all(worst <= rb.TABLE1_TAU_MAX)
    ok, _ = il.check_limits(model, [500.0] * 6)
    assert not ok


def test_gravity_alone_beyond_the_limits_is_infeasible(model):
    with pytest.raises(InfeasibleError, match="gravity"):
        il.input_limits(model, tau_max=[160, 5, 160, 160, 40, 40], refine=0, samples=0)


def test_cli_input_limits(capsys, tmp_path):
    out = tmp_path / "up.yaml"
    code = cli.main(["input-limits", "--json", "--refine", "1", "--samples", "50", "--weights", "equal",
                     "--out", str(out)])
    res = json.loads(capsys.readouterr().out)
    assert code == 0
    assert len(res["u_max"]) == 6 and len(set(round(x, 9) for x in res["u_max"])) == 1   # equal weights
    assert res["joints"][0] == "arm_1_joint" and res["invariant_joints"] == ["arm_1_joint"]
    import yaml
    assert yaml.safe_load(out.read_text())["u_max"]["arm_1_joint"] == pytest.approx(res["u_max"][0], rel=1e-6)
    code = cli.main(["input-limits", "--check", "26", "26", "26", "26", "100", "100", "--json"])
    res = json.loads(capsys.readouterr().out)
    assert code == 0 and res["ok"] is True
    code = cli.main(["input-limits", "--tau-max", "1", "2"])
    err = capsys.readouterr().err
    assert code == 2 and "--tau-max" in err and len(err.strip().splitlines()) == 1
