"""Issue 35.3 through the real command line: ``identify`` reports per joint how much of the
reference class its data covered and warns when thin (naming the joint and ``reachset excite``);
``--calibrate K`` refuses folds too small to mean anything (fewer than
``MIN_FOLD_HORIZONS (k* + 1)`` samples), one line naming the numbers."""
import numpy as np
import pytest

from reachset_ros.conformance.calibration import MIN_FOLD_HORIZONS
from reachset_ros.robot.dynamics import JOINT_NAMES
from reachset_ros.sim import excite as ex
from reachset_ros.sim import recordings as sr
from reachset_ros.sim.reference import ReferenceConfig

from test_reliability_cli import DT_NS, T0, assert_one_line_error, clean_rows, run, run_json, simulate, write_bag

EXCITED = ("arm_1_joint", "arm_2_joint")


@pytest.fixture(scope="module")
def excited_bag(tmp_path_factory):
    """The simulated LWA-4P in closed loop along ``reachset excite --joints arm_1_joint,arm_2_joint
    --fractions 1`` (the other joints rest), recorded with /reference."""
    rc = ReferenceConfig()
    cfg = ex.ExciteConfig(names=tuple(JOINT_NAMES), q_min=rc.q_min, q_max=rc.q_max, qd_max=0.7, qdd_max=2.0,
                          fractions=(1.0,), rest=0.2, excited=EXCITED)
    tr = ex.excitation(cfg)
    recs = sr.simulate_arm_recordings(tr.t[-1], seed=1, reference=(tr.q, tr.qd, tr.qdd))
    return sr.write_recordings(tmp_path_factory.mktemp("cov") / "excited", recs, estimate=False)


@pytest.mark.slow
def test_identify_reports_the_class_coverage_per_joint_and_warns_for_the_thin_ones(excited_bag, capsys):
    """Before, nothing told that a joint's data never moved near the class' limits (the fault
    campaign trained arm_2 at 0.18 rad/s of 0.7 and then stopped on fault-free motion)."""
    code, out, err = run(["identify", excited_bag, "--horizon", 20, "--json"], capsys)
    assert code == 0, err
    import json
    res = json.loads(out)
    thin = [n for n in JOINT_NAMES if n not in EXCITED]
    assert res["thin_coverage"] == thin
    for n in EXCITED:
        c = res["coverage"][n]
        assert c["acceleration_source"] == "reference" and c["max_abs_acceleration"] == pytest.approx(2.0)
        assert 0.95 <= c["velocity_fraction"] <= 1.2 and not c["thin"], c
        assert c["position_range"][1] - c["position_range"][0] > 1.0
    for n in thin:
        c = res["coverage"][n]
        assert c["thin"] and c["velocity_fraction"] < 0.8 and c["max_abs_acceleration"] == 0.0, c
    lines = err.strip().splitlines()
    assert len(lines) == len(thin), err
    for n, line in zip(thin, lines):
        assert line.startswith(f"reachset identify: warning: joint {n}: the data cover") and "reachset excite" in line
    # the threshold is the user's: at 0 nothing is thin
    code, out, err = run(["identify", excited_bag, "--horizon", 20, "--coverage-threshold", 0, "--json"], capsys)
    assert code == 0 and err == "" and json.loads(out)["thin_coverage"] == []
    code, out, err = run(["identify", excited_bag, "--coverage-threshold", 2], capsys)
    assert_one_line_error(code, out, err, "identify", ["--coverage-threshold must be in [0, 1], got 2"])


def test_calibrate_refuses_folds_too_small_to_mean_anything(tmp_path, capsys):
    """Before, one short recording was halved into K blocks of a few test cases each
    ("5 folds of 1 runs") and calibrated on. Now a fold needs MIN_FOLD_HORIZONS (k*+1) samples."""
    N, H = 600, 20
    y, u = np.empty((N, 2)), np.empty((N, 2))
    for j in range(2):
        y[:, j], u[:, j] = simulate(N, seed=7 + j)
    bag = write_bag(tmp_path / "short", clean_rows(T0 + DT_NS * np.arange(N), y, u))
    need = MIN_FOLD_HORIZONS * (H + 1)
    assert N // 4 < need <= N // 2          # 3 folds: blocks of 150, 150 and 300 (the longest halved)
    code, out, err = run(["identify", bag, "--horizon", H, "--calibrate", 3, "--out", tmp_path / "m.yaml"], capsys)
    assert_one_line_error(code, out, err, "identify",
                          ["--calibrate 3: fold", "holds 150 samples (0.60 s; 1 runs cut into 3 blocks for 3 folds)",
                           f"at least {MIN_FOLD_HORIZONS} horizons of k*+1 = {H + 1} samples ({need} samples, 0.84 s)",
                           "fewer folds [guarantee G20: "])
    assert not (tmp_path / "m.yaml").exists()
    res = run_json(["identify", bag, "--horizon", H, "--calibrate", 2], capsys)        # 300 samples a fold: enough
    assert all(j["calibration"]["blocks"] == 2 for j in res["joints"].values())
