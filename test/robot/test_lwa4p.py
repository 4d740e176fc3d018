"""The real LWA-4P recordings: reading, nominal identification (the 75 training runs only), bag import."""
import shutil

import numpy as np
import pytest
import yaml

from reachset_ros import bags

from reachset_ros.robot import lwa4p
from reachset_ros import robot as rb
from reachset_ros.cli import main
from reachset_ros.errors import ReachsetError

NOMINAL = lwa4p.default_nominal_path()


def test_parse_runs():
    assert lwa4p.parse_runs("train") == [r for r in range(1, 101) if r % 4]
    assert lwa4p.parse_runs("heldout") == list(range(4, 101, 4))
    assert lwa4p.parse_runs("1-10:train") == [1, 2, 3, 5, 6, 7, 9, 10]
    assert lwa4p.parse_runs("1-10:heldout") == [4, 8]
    for bad in ("1-3:heldout", "1-5:test"):
        with pytest.raises(ReachsetError):
            lwa4p.parse_runs(bad)
    assert lwa4p.parse_runs("1-3") == [1, 2, 3]
    assert lwa4p.parse_runs("71-72,5") == [71, 72, 5]
    assert lwa4p.parse_runs("7") == [7]
    for bad in ("3-1", "0-2", "a-b", "1-", "1,1"):
        with pytest.raises(ReachsetError, match="bad run range"):
            lwa4p.parse_runs(bad)


def _copy_runs(src, dst, runs):
    for i in runs:
        shutil.copytree(src / f"measurement_{i}", dst / f"measurement_{i}")
    return dst


@pytest.mark.parametrize("corrupt, match", [
    (lambda d: (d / "input.csv").write_text("1,2,3\n"), "input.csv"),
    (lambda d: (d / "trajectory.csv").write_text("1,2,x" + ",0" * 9 + "\n"), "trajectory.csv"),
    (lambda d: (d / "time.csv").unlink(), "time.csv: file not found"),
    (lambda d: (d / "time.csv").write_text("0\n0.004\n0.01\n"), "time.csv"),
])
def test_malformed_recordings_name_the_file(lwa4p_dir, tmp_path, corrupt, match):
    data = _copy_runs(lwa4p_dir, tmp_path / "data", [1])
    corrupt(data / "measurement_1")
    with pytest.raises(ReachsetError, match=match):
        lwa4p.read_run(data, 1)


def test_recordings_lie_within_the_urdf_limits(lwa4p_dir):
    m = rb.load_model()
    for r in lwa4p.read_runs(lwa4p_dir, "1-100"):
        assert np.all(r.q >= m.lower) and np.all(r.q <= m.upper)
        assert np.all(np.abs(r.qd) <= m.velocity_limit)


def _read_bag(path):
    out = {bags.JOINT_STATES: [], bags.PLANT_INPUT: []}
    for topic, t, msg in bags.read_messages([path]):
        out[topic].append((t, msg))
    return out


def test_import_writes_a_bag_equal_to_the_csvs(lwa4p_dir, tmp_path, capsys):
    out = tmp_path / "real.bag"
    assert main(["import-lwa4p", str(lwa4p_dir), "--runs", "70-72", "--out", str(out),
                 "--json"]) == 0
    assert not list(tmp_path.glob("*.partial"))
    runs = lwa4p.read_runs(lwa4p_dir, "70-72")
    msgs = _read_bag(out)
    js, pi = msgs[bags.JOINT_STATES], msgs[bags.PLANT_INPUT]
    assert len(js) == sum(r.n_samples for r in runs)
    assert len(pi) == sum(r.n_samples - 1 for r in runs)
    model = lwa4p.load_nominal()
    i = j = 0
    prev_end = None
    for r in runs:
        up = lwa4p.plant_inputs(model, r)
        block = js[i:i + r.n_samples]
        stamps = np.array([m.header.stamp.sec * 10 ** 9 + m.header.stamp.nanosec
                           for _, m in block])
        np.testing.assert_array_equal(stamps, [t for t, _ in block])      # stamp = receive time
        np.testing.assert_array_equal(stamps - stamps[0],
                                      np.round((r.t - r.t[0]) * 1e9).astype(np.int64))
        if prev_end is not None:
            assert stamps[0] - prev_end >= 1_000_000_000                   # runs apart
        prev_end = stamps[-1]
        for k, (_, m) in enumerate(block):
            assert list(m.name) == list(rb.JOINT_NAMES)
            np.testing.assert_array_equal(m.position, r.q[k])
            np.testing.assert_array_equal(m.velocity, r.qd[k])
            if k < r.n_samples - 1:
                np.testing.assert_array_equal(m.effort, r.tau[k])
            else:
                assert len(m.effort) == 0                 # the last sample has no torque
        pblock = pi[j:j + r.n_samples - 1]
        pstamps = [p.header.stamp.sec * 10 ** 9 + p.header.stamp.nanosec for _, p in pblock]
        np.testing.assert_array_equal(pstamps, stamps[:-1])
        for k, (_, p) in enumerate(pblock):
            assert list(p.name) == list(rb.JOINT_NAMES)
            np.testing.assert_allclose(p.acceleration, up[k], rtol=1e-12, atol=1e-12)
        i += r.n_samples
        j += r.n_samples - 1
    # u_p really is M_hat^-1 (s tau - psi_hat) (eq. 6 inverted) at the measured state
    data = rb.create_data(model)
    r = runs[0]
    M = rb.mass_matrix(model, data, r.q[5])
    np.testing.assert_allclose(
        M @ up_first(model, r) + rb.psi(model, data, r.q[5], r.qd[5]),
        model.torque_scale * r.tau[5], rtol=1e-9, atol=1e-9)


def up_first(model, run):
    return lwa4p.plant_inputs(model, run)[5]


def test_import_errors_leave_nothing_behind(lwa4p_dir, tmp_path, capsys):
    data = _copy_runs(lwa4p_dir, tmp_path / "data", [1, 2, 3])
    (data / "measurement_3" / "input.csv").write_text("1,2,3,4,5,6\nbad\n")
    out = tmp_path / "bag"
    assert main(["import-lwa4p", str(data), "--runs", "1-3", "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "measurement_3/input.csv" in err and len(err.strip().splitlines()) == 1
    assert not out.exists() and not list(tmp_path.glob("bag*"))
    assert main(["import-lwa4p", str(data), "--runs", "5-3", "--out", str(out)]) == 2
    assert "bad run range" in capsys.readouterr().err
    assert main(["import-lwa4p", str(tmp_path / "nope"), "--runs", "1", "--out", str(out)]) == 2
    assert "not found" in capsys.readouterr().err
    assert main(["import-lwa4p", str(data), "--runs", "4", "--out", str(out)]) == 2
    assert "measurement_4" in capsys.readouterr().err
    out.mkdir()
    assert main(["import-lwa4p", str(data), "--runs", "1", "--out", str(out)]) == 2
    assert "already exists" in capsys.readouterr().err


@pytest.fixture(scope="module")
def refit(lwa4p_dir):
    """The shipped model's command, re-run; records which runs the fit reads."""
    read = []
    orig = lwa4p.read_run

    def spy(root, index):
        read.append(index)
        return orig(root, index)

    lwa4p.read_run = spy
    try:
        fit = lwa4p.fit_nominal(lwa4p_dir, "train")
    finally:
        lwa4p.read_run = orig
    return fit, read


@pytest.mark.slow
def test_shipped_nominal_is_what_its_command_produces(refit):
    fit, read = refit
    # the protocol: no held-out run (divisible by 4) is ever read by the fit
    assert sorted(read) == [r for r in range(1, 101) if r % 4] and not any(lwa4p.is_held_out(r) for r in read)
    doc = yaml.safe_load(NOMINAL.read_text())
    assert doc["command"].startswith("reachset fit-lwa4p ")
    assert doc["command"].split()[2:6] == ["--runs", "train", "--out", "config/lwa4p_nominal.yaml"]
    assert lwa4p.parse_runs(doc["data"]["runs"]) == lwa4p.parse_runs("train")
    shipped = lwa4p.load_nominal()
    np.testing.assert_allclose(shipped.torque_scale, fit.identified.torque_scale, rtol=1e-4)
    np.testing.assert_allclose(rb.BaseParameters.from_model(shipped).base(
        rb.parameter_vector(shipped)), fit.identified.beta, rtol=1e-3, atol=1e-4)
    assert fit.min_mass_eigenvalue > 0


def test_identified_model_predicts_held_out_torques_better_than_placeholder(refit, lwa4p_dir):
    fit, _ = refit
    held = lwa4p.read_runs(lwa4p_dir, "heldout")
    ident = lwa4p.torque_rms(fit.identified.model, held)
    ph = lwa4p.torque_rms(fit.placeholder.model, held)
    u = np.vstack([r.tau for r in held])
    std = u.std(axis=0)
    # total squared error, each joint normalised by its held-out torque variance
    e_id = np.sum((np.array(ident["raw"]) / std) ** 2)
    e_ph = np.sum((np.array(ph["raw"]) / std) ** 2)
    print("\nheld-out RMS (raw logged torque) identified:", np.round(ident["raw"], 3),
          "\n                          placeholder:", np.round(ph["raw"], 3),
          f"\nnormalised total squared error identified {e_id:.2f} placeholder {e_ph:.2f}")
    assert e_id < e_ph
    # and on the fitting data the identified model is better on every joint
    assert np.all(fit.identified.rms <= fit.placeholder.rms + 1e-12)


def test_fit_command_refuses_overlap_and_existing_output(lwa4p_dir, tmp_path, capsys):
    out = tmp_path / "m.yaml"
    assert main(["fit-lwa4p", str(lwa4p_dir), "--runs", "1-8", "--out", str(out)]) == 2
    assert "held-out run 4" in capsys.readouterr().err and not out.exists()
    assert main(["fit-lwa4p", str(lwa4p_dir), "--runs", "1-3", "--out", str(out),
                 "--evaluate", "3-6"]) == 2
    assert "overlaps" in capsys.readouterr().err
    out.write_text("x")
    assert main(["fit-lwa4p", str(lwa4p_dir), "--runs", "1-3", "--out", str(out)]) == 2
    assert "already exists" in capsys.readouterr().err


def test_fit_command_writes_a_loadable_model(lwa4p_dir, tmp_path, capsys):
    out = tmp_path / "m.yaml"
    assert main(["fit-lwa4p", str(lwa4p_dir), "--runs", "1-10:train", "--out", str(out),
                 "--json"]) == 0
    m = rb.load_model(params=out)
    assert m.joint_names == rb.JOINT_NAMES and np.all(m.torque_scale > 0)
    assert "--runs 1-10:train" in yaml.safe_load(out.read_text())["command"]
    assert not list(tmp_path.glob("*.partial"))
