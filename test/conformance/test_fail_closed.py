"""A NaN margin is no margin (issue 34.12): every verdict fails closed.

The monitor's tick (compiled and numpy, bit-equal), the one-joint monitor, the batch check and
its exact shortcut from the extremes all compared margins with ``< 0``, and argmin hands the
first NaN over as the worst case: a NaN deviation (an overflowed prediction, a corrupted
state) was reported conformant. Inputs are validated finite upstream, so the NaN here is put
into the state or the extremes directly: what is tested is the comparison, not how a NaN came.
"""
from dataclasses import replace

import numpy as np
import pytest

from reachset_ros import conformance as cf
from reachset_ros.conformance import kernels
from reachset_ros.conformance.estimators import Estimator
from reachset_ros.conformance.monitor import JointMonitor, Monitor, MonitorModel
from reachset_ros.systems.plant import lwa4p_joint_plant
from test_monitor_kernel import DT_NS, T0, closed_loop, model_for

K = 20


@pytest.fixture(scope="module")
def setup():
    p = lwa4p_joint_plant()
    Y, U = closed_loop(p, 500, 2, seed=1)
    model, thm = model_for(p, Y[:400], U[:400], K=K, scale=1.02)
    return p, Y, U, model, thm


@pytest.mark.parametrize("kernel", [True, False])
def test_a_nan_in_the_monitors_prediction_is_a_violation(setup, kernel):
    p, Y, U, model, thm = setup
    if kernel and kernels.LIB_PATH is None:
        pytest.skip("compiled kernel not built")
    m = Monitor([MonitorModel.from_model(model, f"j{j}", thm) for j in range(2)], kernel=kernel)
    for t in range(300):
        assert m.tick(T0 + DT_NS * t, Y[t], U[t])["status"] == ["ok", "ok"]
    m.X[:, 0 * m.S + 1] = np.nan          # one active test case of joint 0 (not its newest)
    r = m.tick(T0 + DT_NS * 300, Y[300], U[300])
    assert r["status"][0] == "violation" and np.isnan(r["margin"][0]), r
    assert r["status"][1] == "ok"
    # the set use (issue 36.3) fails closed too: a NaN deviation uses the set infinitely
    assert r["use"][0] == np.inf and 0 <= r["use"][1] <= 1, r["use"]


def test_the_compiled_and_numpy_ticks_agree_on_a_nan(setup):
    p, Y, U, model, thm = setup
    if kernels.LIB_PATH is None:
        pytest.skip("compiled kernel not built")
    mms = [MonitorModel.from_model(model, f"j{j}", thm) for j in range(2)]
    a, b = Monitor(mms, kernel=True), Monitor(mms, kernel=False)
    for t in range(320):
        if t == 300:
            for m in (a, b):
                m.X[:, 1 * m.S + 3] = np.nan
        ra, rb = a.tick(T0 + DT_NS * t, Y[t], U[t]), b.tick(T0 + DT_NS * t, Y[t], U[t])
        assert ra["status"] == rb["status"], t
        for key in ("margin", "checked", "step", "start_tick", "deviation", "bound", "use"):
            assert ra[key].tobytes() == rb[key].tobytes(), (t, key)


@pytest.mark.parametrize("where", ["state", "upper_bound"])
def test_a_nan_in_the_one_joint_monitors_check_is_a_violation(setup, where):
    """A NaN in the state makes both sides' margins NaN; a NaN bound (one side only) was taken
    over by the other side's finite margin before."""
    p, Y, U, model, thm = setup
    mm = MonitorModel.from_model(model, "j0", thm)
    if where == "upper_bound":
        mm = replace(mm, dp=tuple(np.full_like(d, np.nan) if k == 3 else d for k, d in enumerate(mm.dp)))
    m = JointMonitor(mm)
    if where == "state":
        for t in range(300):
            assert m.tick(T0 + DT_NS * t, Y[t:t + 1, 0], U[t:t + 1, 0]).status == "ok"
        m.X[:, 1] = np.nan
        r = m.tick(T0 + DT_NS * 300, Y[300:301, 0], U[300:301, 0])
    else:                                   # the first tick that checks a test case at k = 3
        for t in range(300):
            r = m.tick(T0 + DT_NS * t, Y[t:t + 1, 0], U[t:t + 1, 0])
            if r.checked > 3:
                break
    assert r.status == "violation" and not r.conformant and np.isnan(r.margin), r
    assert r.use == np.inf        # the set use fails closed too (issue 36.3)


def test_a_nan_deviation_fails_the_batch_verdict_from_the_extremes(setup):
    p, Y, U, model, thm = setup
    devs = cf.deviation_extremes(p, Estimator(), Y[:400, 0], U[:400, 0], ((0, 400),), K, thm)
    xi = model.joints["j0"].xi(model.inflation)
    assert cf.check_extremes(thm, xi, devs)[0]
    maxp = list(devs.maxp)
    maxp[K // 2] = np.where(np.arange(len(maxp[K // 2])) == 0, np.nan, maxp[K // 2])
    ok, worst = cf.check_extremes(thm, xi, replace(devs, maxp=tuple(maxp)))
    assert not ok and np.isnan(worst)
