"""systems.late_reference: a late reference carried forward at constant acceleration."""
import numpy as np
import pytest

from reachset_ros.sim.reference import ReferenceConfig, ReferenceGenerator
from reachset_ros.systems import late_reference as lr


def test_extrapolate_is_exact_at_constant_acceleration():
    q0, v, a = np.array([0.3, -1.2]), np.array([0.5, -0.25]), np.array([1.5, -2.0])
    for h in (0.004, 0.02, 0.1):
        q, qd, qdd = lr.extrapolate(q0, v, a, h)
        np.testing.assert_allclose(q, q0 + v * h + 0.5 * a * h * h, rtol=0, atol=1e-15)
        np.testing.assert_allclose(qd, v + a * h, rtol=0, atol=1e-15)
        assert np.array_equal(qdd, a)             # stays in the class |qdd_d| <= u_ff


def test_extrapolate_zero_age_is_the_reference_and_backwards_is_refused():
    ref = (np.array([0.1, 0.2]), np.array([0.3, 0.4]), np.array([0.5, 0.6]))
    out = lr.extrapolate(*ref, 0.0)
    assert all(np.array_equal(a, b) and a is not b for a, b in zip(out, ref))
    with pytest.raises(ValueError, match="carried forward only"):
        lr.extrapolate(*ref, -0.004)
    with pytest.raises(ValueError):
        lr.extrapolate(*ref, float("nan"))


def test_usable_ages():
    s = 10**18
    assert lr.usable(s, s + 100_000_000, 0.1)
    assert not lr.usable(s, s + 100_000_001, 0.1)
    assert not lr.usable(s + 4_000_000, s, 0.1)       # a newer reference is not carried back
    assert not lr.usable(None, s)


@pytest.mark.parametrize("kind", ["trapezoidal", "quintic"])
def test_error_on_the_reference_class_is_within_the_documented_bound(kind):
    """Against the generator's own moves: within a trapezoid the error is at most
    qdd_max h^2 (a phase change within h), within a quintic j_max h^3 / 6."""
    cfg = ReferenceConfig(kinds=(kind,))
    gen = ReferenceGenerator(cfg, seed=5)
    t, Q, QD, QDD = gen.trajectory(30.0)
    worst = 0.0
    for k in (1, 5, 25):
        h = 0.004 * k
        q_ex, _, _ = lr.extrapolate(Q[:-k], QD[:-k], QDD[:-k], h)
        err = np.abs(q_ex - Q[k:]).max()
        worst = max(worst, err)
        if kind == "trapezoidal":
            bound = np.max(cfg.qdd_max) * h * h
        else:   # the quintic's largest jerk: 60 |D| / T^3 for its moves
            jerk = max(np.max(np.abs(s.q1 - s.q0)) * 60.0 / s.T ** 3 for s in gen.segments if s.T > 0)
            bound = jerk * h ** 3 / 6.0
        assert err <= bound * (1 + 1e-9) + 1e-12, (kind, h, err, bound)
    assert worst > 0.0      # the check saw phase changes at all
