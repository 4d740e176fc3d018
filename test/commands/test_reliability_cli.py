"""Reliability of the offline tools (docs/reliability.md, "Offline tools").

Damaged or unusual bags and model files, run through the real command line: exit status
2, exactly one stderr line ``reachset CMD: error: ...`` naming the file, topic or joint,
and no output file (nor a temporary file beside it). Messy but usable bags: the same
identified sets and check verdicts as the clean bag holding the same data, with the
repairs counted in the JSON ``data`` report.
"""
import json
import math
import re
import subprocess
import sys

import numpy as np
import pytest
import yaml

from reachset_ros import bags
from reachset_ros.conformance import model as mdl
from reachset_ros.cli import main
from reachset_ros.systems.plant import lwa4p_joint_plant

T0 = 1_700_000_000_000_000_000
DT_NS = 4_000_000
JOINTS = ["arm_1_joint", "arm_2_joint"]
HORIZON = 20
TICKS = 600


# ------------------------------------------------------------------ data and bags
def simulate(T, seed, alpha_w=(0.03, 3.0), alpha_v=(3.5e-5,)):
    """Closed loop on the per-joint LWA-4P plant with bounded random disturbances."""
    p = lwa4p_joint_plant()
    rng = np.random.default_rng(seed)
    x = np.zeros(p.A.shape[0])
    y, u = np.zeros(T), np.zeros(T)
    for k in range(T):
        y[k] = (p.C @ x)[0] + (p.Gv @ (np.asarray(alpha_v) * rng.uniform(-1, 1, 1)))[0]
        u[k] = 2 * np.sin(0.01 * k) - 100.0 * x[1] - 20.0 * x[2]
        x = p.A @ x + p.B[:, 0] * u[k] + p.Gw @ (np.asarray(alpha_w) * rng.uniform(-1, 1, 2))
    return y, u


@pytest.fixture(scope="module")
def data():
    y = np.empty((TICKS, 2))
    u = np.empty((TICKS, 2))
    for j in range(2):
        y[:, j], u[:, j] = simulate(TICKS, seed=11 + j)
    return T0 + DT_NS * np.arange(TICKS), y, u


def write_bag(path, rows, js_topic=bags.JOINT_STATES, pi_topic=bags.PLANT_INPUT):
    """``rows``: (stamp, js_names, positions, pi_names, accelerations) in recording order.

    Receive times increase with the row index (the recording order); header stamps are
    the given stamps. ``js_topic``/``pi_topic`` None leaves that topic out.
    """
    with bags.BagWriter(path) as w:
        for i, (t, jn, q, pn, a) in enumerate(rows):
            recv = T0 + DT_NS * i
            if js_topic and jn is not None:
                w.write(js_topic, bags.joint_state(int(t), jn, q), recv)
            if pi_topic and pn is not None:
                w.write(pi_topic, bags.plant_input(int(t), pn, a), recv + 1000)
    return path


def clean_rows(stamps, y, u, idx=None):
    idx = range(len(stamps)) if idx is None else idx
    return [(stamps[i], JOINTS, y[i], JOINTS, u[i]) for i in idx]


def run(argv, capsys):
    """The real command line, in-process: (exit status, stdout, stderr)."""
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def run_json(argv, capsys):
    code, out, err = run([*argv, "--json"], capsys)
    d = json.loads(out) if out.strip() else None
    # check/replay exit 1 when not conformant (0 when conformant, 2 on bad input)
    assert d is not None and code == (0 if d.get("conformant", True) else 1), err
    return d


def all_finite(x):
    if isinstance(x, dict):
        return all(all_finite(v) for v in x.values())
    if isinstance(x, (list, tuple)):
        return all(all_finite(v) for v in x)
    if isinstance(x, float):
        return math.isfinite(x)
    return True


@pytest.fixture(scope="module")
def workdir(tmp_path_factory):
    return tmp_path_factory.mktemp("rel")


@pytest.fixture(scope="module")
def clean_bag(workdir, data):
    return write_bag(workdir / "clean", clean_rows(*data))


@pytest.fixture(scope="module")
def model_file(workdir, clean_bag):
    """A model identified on the clean bag."""
    out = workdir / "model.yaml"
    assert main(["identify", str(clean_bag), "--horizon", str(HORIZON), "--out", str(out)]) == 0
    return out


@pytest.fixture(scope="module")
def tight_model(workdir, model_file):
    """The clean bag's model with its sets shrunk: ``check`` finds violations."""
    m = mdl.load(model_file)
    joints = {n: mdl.JointSets(tuple(0.6 * a for a in j.alpha_w), tuple(0.6 * a for a in j.alpha_v),
                               j.c_w, j.c_v, j.test_cases, j.horizon) for n, j in m.joints.items()}
    out = workdir / "tight.yaml"
    mdl.save(m.with_joints(joints), out)
    return out


# ------------------------------------------------------------------ damaged or unusual bags
def _small(path, data, n=TICKS, **kw):
    stamps, y, u = data
    return write_bag(path, clean_rows(stamps[:n], y[:n], u[:n]), **kw)


def make_bad_bag(case, tmp_path, data):
    """Returns (bag path, words the error line must contain)."""
    path = tmp_path / "bag"
    stamps, y, u = data
    if case == "missing_path":
        return path, [str(path), "no such bag"]
    if case == "regular_file":
        path.write_bytes(b"\x89MCAP0\r\n" + bytes(100))
        return path, [str(path), "not a rosbag2 bag", ".mcap or .db3 file"]
    if case == "empty_dir":
        path.mkdir()
        return path, [str(path), "not a rosbag2 directory", "metadata.yaml"]
    if case == "dir_with_random_file":
        path.mkdir()
        (path / "data.bin").write_bytes(np.random.default_rng(0).bytes(4096))
        return path, [str(path), "not a rosbag2 directory"]
    if case == "no_joint_states":
        _small(path, data, js_topic=None)
        return path, [str(path), "topic /joint_states missing"]
    if case == "no_plant_input":
        _small(path, data, pi_topic=None)
        return path, [str(path), "topic /plant_input missing"]
    if case == "no_common_joints":
        write_bag(path, [(stamps[i], JOINTS, y[i], ["other_joint"], u[i, :1]) for i in range(100)])
        return path, [str(path), "no joint is on both /joint_states and /plant_input"]
    if case == "too_few_samples":
        _small(path, data, n=HORIZON)            # fewer ticks than history + horizon + 1
        return path, ["arm_1_joint", "too few samples", f"horizon {HORIZON}"]
    if case == "mcap_bad_payload":             # an intact file holding one damaged message
        ts = bags.typestore()
        with bags.BagWriter(path) as w:
            for i in range(100):
                t = int(stamps[i])
                js = bytearray(ts.serialize_cdr(bags.joint_state(t, JOINTS, y[i]), bags.JOINT_STATE_TYPE))
                if i == 60:
                    js[16:20] = (1000).to_bytes(4, "little")      # frame_id length beyond the message
                w.write_raw(bags.JOINT_STATES, bytes(js), t, bags.JOINT_STATE_TYPE)
                w.write(bags.PLANT_INPUT, bags.plant_input(t, JOINTS, u[i]), t)
        return path, [str(path), "unreadable bag", "bag.mcap", f"message on /joint_states at log time {stamps[60]} ns"]
    if case == "zstd_chunk_damaged":           # the zstd frame of a compressed chunk overwritten
        from mcap.reader import make_reader
        from rosbags.rosbag2 import Writer
        from rosbags.rosbag2.enums import CompressionFormat, CompressionMode, StoragePlugin
        ts = bags.typestore()
        w = Writer(path, version=9, storage_plugin=StoragePlugin.MCAP)
        w.set_compression(CompressionMode.STORAGE, CompressionFormat.ZSTD)
        with w:
            cj = w.add_connection(bags.JOINT_STATES, bags.JOINT_STATE_TYPE, typestore=ts)
            cp = w.add_connection(bags.PLANT_INPUT, bags.PLANT_INPUT_TYPE, typestore=ts)
            for i in range(200):
                t = int(stamps[i])
                w.write(cj, t, ts.serialize_cdr(bags.joint_state(t, JOINTS, y[i]), bags.JOINT_STATE_TYPE))
                w.write(cp, t, ts.serialize_cdr(bags.plant_input(t, JOINTS, u[i]), bags.PLANT_INPUT_TYPE))
        mcap = path / "bag.mcap"
        with open(mcap, "rb") as f:
            ci = make_reader(f).get_summary().chunk_indexes[0]
        assert ci.compression == "zstd"
        b = bytearray(mcap.read_bytes())
        at = ci.chunk_start_offset + 9 + 8 + 8 + 8 + 4 + 4 + len("zstd") + 8   # start of the compressed data
        b[at:at + 4] = bytes(4)                                                 # the zstd frame magic
        mcap.write_bytes(bytes(b))
        return path, [str(path), f"unreadable bag (bag.mcap: chunk at offset {ci.chunk_start_offset}: ZstdError"]
    if case == "sqlite3_null_message":         # found by benchmarks/fuzz_inputs.py (traceback before)
        import sqlite3
        with bags.BagWriter(path, storage="sqlite3") as w:
            for i in range(100):
                w.write(bags.JOINT_STATES, bags.joint_state(int(stamps[i]), JOINTS, y[i]), int(stamps[i]))
                w.write(bags.PLANT_INPUT, bags.plant_input(int(stamps[i]), JOINTS, u[i]), int(stamps[i]))
        con = sqlite3.connect(path / "bag.db3")
        (sql,) = con.execute("SELECT sql FROM sqlite_master WHERE name = 'messages'").fetchone()
        con.executescript("ALTER TABLE messages RENAME TO old; "
                          + sql.replace("data BLOB NOT NULL", "data BLOB") + "; "
                          "INSERT INTO messages SELECT * FROM old; DROP TABLE old; "
                          "UPDATE messages SET data = NULL WHERE id = 41;")
        con.close()
        return path, [str(path), "unreadable message on /", "(message 40 of the bag): no data"]
    _small(path, data)
    mcap = path / "bag.mcap"
    raw = mcap.read_bytes()
    if case == "truncated_mcap":
        mcap.write_bytes(raw[:len(raw) // 2])
        return path, [str(path), "bag.mcap", "truncated"]
    if case == "mcap_not_mcap":
        mcap.write_bytes(np.random.default_rng(1).bytes(len(raw)))
        return path, [str(path), "bag.mcap", "not an MCAP file"]
    if case == "mcap_corrupt_chunk":
        b = bytearray(raw)
        mid = len(b) // 3
        b[mid:mid + 64] = bytes(64)
        mcap.write_bytes(bytes(b))
        return path, [str(path), "unreadable bag", "bag.mcap"]
    if case == "mcap_huge_length":
        b = bytearray(raw)
        b[9:17] = (2**62).to_bytes(8, "little")     # the header record's length
        mcap.write_bytes(bytes(b))
        return path, [str(path), "unreadable bag", "bag.mcap", "MemoryError"]
    if case == "mcap_missing_file":
        mcap.unlink()
        return path, [str(path), "bag.mcap"]
    meta = path / "metadata.yaml"
    if case == "metadata_garbage":
        meta.write_text("rosbag2_bagfile_information: {{{ [")
        return path, [str(path), "metadata"]
    if case == "metadata_incomplete":
        meta.write_text("rosbag2_bagfile_information:\n  version: 9\n")
        return path, [str(path), "metadata"]
    if case == "metadata_binary":
        meta.write_bytes(b"\xff\xfe\x00garbage\x80\x81")
        return path, [str(path), "metadata"]
    if case == "metadata_removed":
        meta.unlink()
        return path, [str(path), "not a rosbag2 directory", "metadata.yaml"]
    if case == "metadata_not_a_mapping":
        meta.write_text("- 1\n- 2\n")
        return path, [str(path), "metadata"]
    if case == "metadata_key_missing":
        d = yaml.safe_load(meta.read_text())
        del d["rosbag2_bagfile_information"]["topics_with_message_count"][0]["topic_metadata"]["type"]
        meta.write_text(yaml.safe_dump(d))
        return path, [str(path), "unreadable bag (metadata.yaml: ReaderError: A metadata key is missing"]
    if case == "metadata_topic_not_a_string":          # found by benchmarks/fuzz_inputs.py
        d = yaml.safe_load(meta.read_text())
        d["rosbag2_bagfile_information"]["topics_with_message_count"][0]["topic_metadata"]["name"] = ["x"]
        meta.write_text(yaml.safe_dump(d))
        return path, [str(path), "metadata.yaml", "bad topic entry ['x']"]
    raise AssertionError(case)


BAD_BAGS = ["missing_path", "regular_file", "empty_dir", "dir_with_random_file", "no_joint_states",
            "no_plant_input", "no_common_joints", "too_few_samples", "truncated_mcap", "mcap_not_mcap",
            "mcap_corrupt_chunk", "mcap_huge_length", "mcap_bad_payload", "zstd_chunk_damaged",
            "sqlite3_null_message", "mcap_missing_file", "metadata_garbage",
            "metadata_incomplete", "metadata_binary", "metadata_removed", "metadata_not_a_mapping",
            "metadata_key_missing", "metadata_topic_not_a_string"]


def assert_one_line_error(code, out, err, cmd, words):
    assert code == 2, err
    lines = err.splitlines()
    assert len(lines) == 1 and err.endswith("\n"), err
    assert lines[0].startswith(f"reachset {cmd}: error: "), err
    assert "Traceback" not in err
    for w in words:
        assert w in lines[0], (w, err)
    assert out == ""


def assert_no_output(out_file):
    assert not out_file.exists()
    assert not list(out_file.parent.glob(out_file.name + "*")), list(out_file.parent.iterdir())


@pytest.mark.parametrize("cmd", ["identify", "check", "replay"])
@pytest.mark.parametrize("case", BAD_BAGS)
def test_bad_bag_exits_2_with_one_line_naming_it(case, cmd, tmp_path, data, model_file, capsys):
    bag, words = make_bad_bag(case, tmp_path, data)
    out = tmp_path / "out" / "model.yaml"
    out.parent.mkdir()
    if cmd == "identify":
        argv = ["identify", bag, "--horizon", HORIZON, "--out", out]
    else:
        argv = [cmd, bag, "--model", model_file]
    code, so, se = run(argv, capsys)
    assert_one_line_error(code, so, se, cmd, words)
    assert_no_output(out)


@pytest.mark.parametrize("case", ["truncated_mcap", "no_plant_input", "no_common_joints", "empty_dir", "too_few_samples"])
def test_bad_bag_synthesize_exits_2_and_writes_nothing(case, tmp_path, data, capsys):
    bag, words = make_bad_bag(case, tmp_path, data)
    out = tmp_path / "out" / "gains.yaml"
    out.parent.mkdir()
    code, so, se = run(["synthesize", bag, "--horizon", HORIZON, "--out", out], capsys)
    assert_one_line_error(code, so, se, "synthesize", words)
    assert_no_output(out)


def test_validation_bag_too_short_for_the_horizon(tmp_path, data, clean_bag, capsys):
    bag, words = make_bad_bag("too_few_samples", tmp_path, data)
    out = tmp_path / "m.yaml"
    code, so, se = run(["identify", clean_bag, "--horizon", HORIZON, "--validate", bag, "--out", out], capsys)
    assert_one_line_error(code, so, se, "identify", [str(bag), *words])
    assert_no_output(out)


def test_second_bag_damaged_names_that_bag(tmp_path, data, clean_bag, capsys):
    bag, words = make_bad_bag("truncated_mcap", tmp_path, data)
    out = tmp_path / "m.yaml"
    code, so, se = run(["identify", clean_bag, bag, "--horizon", HORIZON, "--out", out], capsys)
    assert_one_line_error(code, so, se, "identify", words)
    assert str(clean_bag) + ":" not in se
    assert_no_output(out)


def test_absent_joint_named(tmp_path, clean_bag, capsys):
    out = tmp_path / "m.yaml"
    code, so, se = run(["identify", clean_bag, "--joints", "arm_1_joint,zzz", "--out", out], capsys)
    assert_one_line_error(code, so, se, "identify", ["joint zzz", "/joint_states"])
    assert_no_output(out)


def test_model_joint_absent_from_bag_named(tmp_path, data, model_file, capsys):
    stamps, y, u = data
    bag = write_bag(tmp_path / "b", [(stamps[i], JOINTS[:1], y[i, :1], JOINTS[:1], u[i, :1]) for i in range(200)])
    for cmd in ("check", "replay"):
        code, so, se = run([cmd, bag, "--model", model_file], capsys)
        assert_one_line_error(code, so, se, cmd, ["joint arm_2_joint", "not found"])


@pytest.mark.parametrize("case", ["out_is_a_directory", "out_parent_missing"])
def test_bad_out_path_exits_2_before_any_work(case, tmp_path, clean_bag, capsys):
    out = tmp_path / "models" if case == "out_is_a_directory" else tmp_path / "nowhere" / "m.yaml"
    if case == "out_is_a_directory":
        out.mkdir()
    code, so, se = run(["identify", clean_bag, "--horizon", HORIZON, "--out", out], capsys)
    assert_one_line_error(code, so, se, "identify", [str(out if case == "out_is_a_directory" else out.parent)])
    assert sorted(p.name for p in tmp_path.iterdir()) == (["models"] if case == "out_is_a_directory" else [])


def test_failed_write_leaves_old_model_untouched_and_no_partial_file(tmp_path, clean_bag, capsys, monkeypatch):
    """Disk full in the middle of writing the model: one line naming the file, the previous
    model file unchanged, no temporary file left."""
    out = tmp_path / "model.yaml"
    out.write_text("previous model\n")
    real = yaml.safe_dump

    def disk_full(doc, stream=None, **kw):
        stream.write(real(doc, **kw)[:100])
        raise OSError(28, "No space left on device")
    monkeypatch.setattr(yaml, "safe_dump", disk_full)
    code, so, se = run(["identify", clean_bag, "--horizon", HORIZON, "--out", out], capsys)
    assert_one_line_error(code, so, se, "identify", [str(out), "cannot write", "No space left on device"])
    assert out.read_text() == "previous model\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["model.yaml"]


def test_debug_shows_the_traceback_subprocess(tmp_path, data):
    """As users run it: one line without --debug, the full traceback with it."""
    bag, words = make_bad_bag("truncated_mcap", tmp_path, data)
    out = tmp_path / "m.yaml"
    base = [sys.executable, "-m", "reachset_ros.cli"]
    r = subprocess.run([*base, "identify", str(bag), "--out", str(out)], capture_output=True, text=True,
                       timeout=120)
    assert_one_line_error(r.returncode, r.stdout, r.stderr, "identify", words)
    r = subprocess.run([*base, "--debug", "identify", str(bag), "--out", str(out)], capture_output=True,
                       text=True, timeout=120)
    assert r.returncode == 1 and r.stdout == ""
    assert "Traceback (most recent call last)" in r.stderr and "ReachsetError" in r.stderr
    assert "bag.mcap" in r.stderr
    assert_no_output(out)


# ------------------------------------------------------------------ infeasible synthesis
SMALL_SEARCH = {"sobol_log2": 4, "local_starts": 2, "local_maxfev": 40}


@pytest.mark.slow
@pytest.mark.parametrize("case", ["u_ff_exceeds_u_p", "r_u_radius", "reidentify_fixed_controller"])
def test_infeasible_synthesis_names_the_binding_constraint(case, tmp_path, clean_bag, capsys):
    """Exit 2, one line naming the joint and the constraint that binds, no file written.
    (test_synthesis.py::test_cli_infeasible_u_max_exits_2_with_one_line_and_no_file covers
    the same on the synthesis tests' simulated arm.)"""
    cfg = tmp_path / "synthesis.yaml"
    cfg.write_text(yaml.safe_dump({"search": SMALL_SEARCH}))
    out = tmp_path / "out" / "gains.yaml"
    out.parent.mkdir()
    # the bag has no /reference: the class of constant-velocity references (zero reference error)
    refs = ["--reference-class", "qdd_max=0"]
    base = ["synthesize", clean_bag, "--joints", "arm_1_joint", "--horizon", HORIZON, "--config", cfg, *refs]
    if case == "u_ff_exceeds_u_p":
        argv, want = base + ["--u-max", "1.5"], (
            r"joint arm_1_joint: combined synthesis: U_ff \(\+-2\) and the reference error \(0\) alone "
            r"exceed U_p = \[-1\.5, 1\.5\]$")
    elif case == "r_u_radius":
        argv, want = base + ["--u-max", "2.01"], (
            r"joint arm_1_joint: combined synthesis: no gains keep R_u inside U_p: smallest achievable R_u "
            r"radius [0-9.]+ > u_max 2\.01 - u_ff 2 = 0\.01 \(best of \d+ parameter vectors, at omega=[0-9.]+, "
            r"zeta=[0-9.]+\)$")
    else:
        gains = tmp_path / "g.yaml"
        assert run(["synthesize", clean_bag, "--horizon", HORIZON, "--config", cfg, "--u-max", "8", *refs,
                    "--out", gains], capsys)[0] == 0
        argv, want = ["synthesize", clean_bag, "--mode", "reidentify", "--model", gains, "--u-max", "2.01"], (
            r"joint arm_1_joint: re-identification with the fixed controller: the controller cannot keep R_u "
            r"inside U_p with sets conformant to these data: smallest achievable R_u radius [0-9.]+ > u_max 2\.01 - "
            r"u_ff 2 = 0\.01 \(omega=[0-9.]+, zeta=[0-9.]+, h1=[0-9.]+, h2=[0-9.]+\); synthesise again with these data$")
    code, so, se = run([*argv, "--out", out], capsys)
    assert_one_line_error(code, so, se, "synthesize", [])
    assert re.fullmatch(r"reachset synthesize: error: " + want, se.strip()), se
    assert_no_output(out)


# ------------------------------------------------------------------ model files
def make_bad_model(case, tmp_path, model_file):
    path = tmp_path / "m.yaml"
    text = model_file.read_text()
    if case == "missing":
        return path, ["model file not found"]
    if case == "directory":
        path.mkdir()
        return path, ["is a directory, not a model file"]
    if case == "not_yaml":
        path.write_text("format: reachset_ros/model/1\njoints: {{{ [\n")
        return path, ["does not parse"]
    if case == "binary":
        path.write_bytes(b"\x00\xff\xfe\x80garbage")
        return path, ["does not parse"]
    if case == "empty":
        path.write_text("")
        return path, ["not a model file"]
    if case == "wrong_format":
        path.write_text(text.replace("reachset_ros/model/1", "something/else"))
        return path, ["unknown format"]
    if case == "negative_alpha":
        d = yaml.safe_load(text)
        d["joints"]["arm_2_joint"]["alpha_w"][1] = -1.0
        path.write_text(yaml.safe_dump(d))
        return path, ["joint arm_2_joint", "negative"]
    if case == "nan_alpha":
        d = yaml.safe_load(text)
        d["joints"]["arm_1_joint"]["alpha_v"] = [".nan"]
        path.write_text(yaml.safe_dump(d).replace("'.nan'", ".nan"))
        return path, ["joint arm_1_joint", "alpha_v", "finite"]
    if case == "alpha_not_numbers":
        d = yaml.safe_load(text)
        d["joints"]["arm_1_joint"]["alpha_w"] = ["a", "b"]
        path.write_text(yaml.safe_dump(d))
        return path, ["joint arm_1_joint", "alpha_w"]
    if case == "bad_plant":
        d = yaml.safe_load(text)
        d["plant"] = {"kind": "matrices", "A": [[1, 2]]}
        path.write_text(yaml.safe_dump(d))
        return path, ["plant"]
    if case == "bad_horizon":
        path.write_text(text.replace("horizon: 20\n", "horizon: twenty\n", 1))
        return path, ["horizon must be an integer"]
    # found by benchmarks/fuzz_inputs.py (tracebacks before)
    d = yaml.safe_load(text)
    if case == "test_cases_null":
        d["joints"]["arm_1_joint"]["test_cases"] = None
        words = ["joint arm_1_joint test_cases must be an integer"]
    elif case == "horizon_nan":
        d["joints"]["arm_2_joint"]["horizon"] = float("nan")
        words = ["joint arm_2_joint horizon must be an integer"]
    elif case == "horizon_huge":
        d["horizon"] = 10**9
        words = ["horizon must be in [0, 100000]"]
    elif case == "estimator_name_list":
        d["estimator"] = {"name": ["fd"]}
        words = ["unknown initial-state estimator"]
    elif case == "plant_matrix_missing":
        d["plant"] = {"kind": "matrices", "A": [[1.0]], "C": [[1.0]], "Gw": [[1.0]], "Gv": [[1.0]]}
        words = ["bad plant: no B given"]
    else:
        raise AssertionError(case)
    path.write_text(yaml.safe_dump(d))
    return path, words


BAD_MODELS = ["missing", "directory", "not_yaml", "binary", "empty", "wrong_format", "negative_alpha",
              "nan_alpha", "alpha_not_numbers", "bad_plant", "bad_horizon", "test_cases_null", "horizon_nan",
              "horizon_huge", "estimator_name_list", "plant_matrix_missing"]


@pytest.mark.parametrize("cmd", ["check", "replay"])
@pytest.mark.parametrize("case", BAD_MODELS)
def test_bad_model_file_exits_2_naming_it(case, cmd, tmp_path, clean_bag, model_file, capsys):
    path, words = make_bad_model(case, tmp_path, model_file)
    code, so, se = run([cmd, clean_bag, "--model", path], capsys)
    assert_one_line_error(code, so, se, cmd, [str(path), *words])


def test_bad_model_for_reidentify_names_it(tmp_path, clean_bag, model_file, capsys):
    path, words = make_bad_model("negative_alpha", tmp_path, model_file)
    out = tmp_path / "gains.yaml"
    code, so, se = run(["synthesize", clean_bag, "--mode", "reidentify", "--model", path, "--out", out], capsys)
    assert_one_line_error(code, so, se, "synthesize", [str(path), *words])
    assert_no_output(out)


# ------------------------------------------------------------------ messy but usable bags
def identify_json(bag_args, capsys):
    d = run_json(["identify", *bag_args, "--horizon", HORIZON], capsys)
    assert all_finite(d["joints"])
    return d


def sets_of(d):
    return {n: {k: j[k] for k in ("alpha_w", "alpha_v", "c_w", "c_v", "test_cases", "horizon")}
            for n, j in d["joints"].items()}


def verdicts(cmd, bag_args, model, capsys):
    d = run_json([cmd, *bag_args, "--model", model], capsys)
    assert all_finite(d)
    return {n: {k: j[k] for k in ("violations", "first_violation_ns", "test_cases")}
            for n, j in d["joints"].items()}, d


def make_messy(case, tmp_path, data):
    """(messy bag, clean bag holding the same data, expected report entries)."""
    stamps, y, u = data
    messy, same = tmp_path / "messy", tmp_path / "same"
    if case == "nan_inf_samples":
        y2, u2 = y.copy(), u.copy()
        y2[300, 0] = np.nan              # one invalid tick for each joint
        u2[300, 1] = np.inf
        y2[450, :] = -np.inf
        write_bag(messy, clean_rows(stamps, y2, u2))
        keep = [i for i in range(TICKS) if i not in (300, 450)]
        write_bag(same, clean_rows(stamps, y, u, keep))      # the same data with ticks missing
        return [messy], [same], {"invalid_samples": {"arm_1_joint": 2, "arm_2_joint": 2},
                                 "gaps": {"arm_1_joint": 2, "arm_2_joint": 2}}
    if case == "duplicate_stamps":
        idx = list(range(TICKS))
        idx[100:100] = [100]                    # the same message twice
        rows = clean_rows(stamps, y, u, idx)
        at = next(k for k, r in enumerate(rows) if r[0] == stamps[399]) + 1
        rows.insert(at, (stamps[399], JOINTS, y[399] + 1.0, JOINTS, u[399] + 1.0))    # later, other values
        write_bag(messy, rows)
        return [messy], None, {"duplicates": {"arm_1_joint": 4, "arm_2_joint": 4}}
    if case == "out_of_order_stamps":
        idx = list(range(TICKS))
        idx[200], idx[201] = idx[201], idx[200]
        idx = idx[:50] + idx[51:] + [50]        # one message arrives much later
        write_bag(messy, clean_rows(stamps, y, u, idx))
        return [messy], None, {"out_of_order": {"/joint_states": 2, "/plant_input": 2}}
    if case == "joint_order_changes":
        rows = []
        for i in range(TICKS):
            o = [1, 0] if i % 3 == 1 else [0, 1]
            p = [1, 0] if i % 2 == 0 else [0, 1]
            rows.append((stamps[i], [JOINTS[j] for j in o], y[i, o], [JOINTS[j] for j in p], u[i, p]))
        write_bag(messy, rows)
        return [messy], None, {"name_list_changes": {"/joint_states": TICKS // 3, "/plant_input": TICKS // 2}}
    if case == "extra_unknown_joints":
        rows = []
        for i in range(TICKS):
            jn, q = JOINTS + ["gripper"], np.r_[y[i], 0.01]
            pn, a = JOINTS, u[i]
            if i % 4 == 0:
                pn, a = ["tool_joint"] + JOINTS, np.r_[0.0, u[i]]
            rows.append((stamps[i], jn, q, pn, a))
        write_bag(messy, rows)
        return [messy], None, {"ignored_joints": ["gripper", "tool_joint"]}
    if case == "pause_between_recordings":
        st = stamps.copy()
        st[TICKS // 2:] += 3_000_000_000        # 3 s pause
        write_bag(messy, clean_rows(st, y, u))
        a = write_bag(tmp_path / "first", clean_rows(stamps, y, u, range(TICKS // 2)))
        b = write_bag(tmp_path / "second", clean_rows(st, y, u, range(TICKS // 2, TICKS)))
        return [messy], [a, b], {"gaps": {"arm_1_joint": 1, "arm_2_joint": 1}}
    raise AssertionError(case)


MESSY = ["nan_inf_samples", "duplicate_stamps", "out_of_order_stamps", "joint_order_changes",
         "extra_unknown_joints", "pause_between_recordings"]


@pytest.mark.parametrize("case", MESSY)
def test_messy_bag_same_results_as_clean_and_counted(case, tmp_path, data, clean_bag, tight_model, capsys):
    messy, same, expect = make_messy(case, tmp_path, data)
    same = same or [clean_bag]
    got, want = identify_json(messy, capsys), identify_json(same, capsys)
    assert sets_of(got) == sets_of(want)
    for key, value in expect.items():
        rep = got["data"][key]
        if isinstance(value, dict):
            assert {k: rep[k] for k in value} == value, (key, rep)
        else:
            assert rep == value, (key, rep)
    for cmd in ("check", "replay"):
        vm, dm = verdicts(cmd, messy, tight_model, capsys)
        vc, _ = verdicts(cmd, same, tight_model, capsys)
        assert vm == vc
        assert sum(j["violations"] for j in vm.values()) > 0       # the tight model is violated
        assert dm["data"] == got["data"]


def test_clean_bag_reports_nothing_repaired(clean_bag, capsys):
    rep = identify_json([clean_bag], capsys)["data"]
    assert rep["messages"] == {"/joint_states": TICKS, "/plant_input": TICKS}
    for key in ("duplicates", "unpaired", "invalid_samples", "gaps"):
        assert set(rep[key].values()) == {0}, key
    assert set(rep["out_of_order"].values()) == {0} and set(rep["name_list_changes"].values()) == {0}
    assert rep["ignored_joints"] == []


def test_unpaired_samples_are_counted(tmp_path, data, capsys):
    """A /joint_states sample without its /plant_input (and the other way round) is a gap."""
    stamps, y, u = data
    rows = clean_rows(stamps, y, u)
    rows[250] = (stamps[250], JOINTS, y[250], None, None)
    rows[350] = (stamps[350], None, None, JOINTS, u[350])
    messy = write_bag(tmp_path / "messy", rows)
    same = write_bag(tmp_path / "same", clean_rows(stamps, y, u, [i for i in range(TICKS) if i not in (250, 350)]))
    got, want = identify_json([messy], capsys), identify_json([same], capsys)
    assert sets_of(got) == sets_of(want)
    assert got["data"]["unpaired"] == {"arm_1_joint": 2, "arm_2_joint": 2}
    assert got["data"]["gaps"] == {"arm_1_joint": 2, "arm_2_joint": 2}


# ------------------------------------------------------------------ guarantee integrity (issue 14)
@pytest.mark.parametrize("cmd", ["identify", "synthesize"])
@pytest.mark.parametrize("horizon", [0, 1])
def test_horizon_below_the_minimum_is_refused(cmd, horizon, tmp_path, clean_bag, capsys):
    """k* = 0 or 1 leaves alpha_W out of every Theorem-1 row of the LWA-4P joint plant (one
    sample of input and output delay): refused, naming the minimum 2 and the flag."""
    out = tmp_path / "out" / "m.yaml"
    out.parent.mkdir()
    code, so, se = run([cmd, clean_bag, "--horizon", horizon, "--out", out], capsys)
    assert_one_line_error(code, so, se, cmd, [f"horizon {horizon} is below the minimum horizon 2",
                                              "--allow-weak-horizon"])
    assert_no_output(out)


def test_weak_horizon_only_with_the_flag_and_recorded(tmp_path, clean_bag, capsys):
    out = tmp_path / "weak.yaml"
    d = run_json(["identify", clean_bag, "--horizon", 1, "--allow-weak-horizon", "--out", out], capsys)
    assert d["horizon_below_minimum"] is True and d["minimum_horizon"] == 2 and d["horizon"] == 1
    assert all(j["alpha_w"] == [0.0, 0.0] for j in d["joints"].values())   # what the rule guards against
    raw = yaml.safe_load(out.read_text())
    assert raw["horizon_below_minimum"] is True and raw["minimum_horizon"] == 2
    m = mdl.load(out)
    assert m.horizon_below_minimum and m.minimum_horizon == 2
    # at the minimum: no flag needed, nothing weak recorded, alpha_W constrained by the data
    ok = tmp_path / "ok.yaml"
    d = run_json(["identify", clean_bag, "--horizon", 2, "--out", ok], capsys)
    assert d["horizon_below_minimum"] is False and d["minimum_horizon"] == 2
    assert all(max(j["alpha_w"]) > 0 for j in d["joints"].values())
    raw = yaml.safe_load(ok.read_text())
    assert "horizon_below_minimum" not in raw and raw["minimum_horizon"] == 2


def test_synthesize_weak_horizon_recorded(tmp_path, clean_bag, capsys):
    """``synthesize`` obeys the same rule (one function, also used by the synthesis node's
    child process): a re-identification at k* = 1 is refused, and with the flag recorded."""
    cfg = tmp_path / "synthesis.yaml"
    cfg.write_text(yaml.safe_dump({"search": SMALL_SEARCH}))
    gains, out = tmp_path / "gains.yaml", tmp_path / "weak.yaml"
    refs = ["--reference-class", "qdd_max=2"]
    d = run_json(["synthesize", clean_bag, "--joints", "arm_1_joint", "--horizon", HORIZON, "--config", cfg,
                  *refs, "--out", gains], capsys)
    assert d["horizon_below_minimum"] is False and d["minimum_horizon"] == 2
    base = ["synthesize", clean_bag, "--mode", "reidentify", "--model", gains, "--horizon", 1, *refs]
    code, so, se = run([*base, "--out", out], capsys)
    assert_one_line_error(code, so, se, "synthesize", ["horizon 1 is below the minimum horizon 2",
                                                       "--allow-weak-horizon"])
    assert_no_output(out)
    d = run_json([*base, "--allow-weak-horizon", "--out", out], capsys)
    assert d["horizon_below_minimum"] is True and d["minimum_horizon"] == 2 and d["horizon"] == 1
    m = mdl.load(out)
    assert m.horizon_below_minimum and m.minimum_horizon == 2 and m.horizon == 1
    # re-identifying that model keeps its horizon: refused again without the flag
    code, so, se = run(["synthesize", clean_bag, "--mode", "reidentify", "--model", out, *refs], capsys)
    assert_one_line_error(code, so, se, "synthesize", ["horizon 1 is below the minimum horizon 2"])


def test_check_and_replay_agree_at_bag_boundaries(tmp_path, capsys):
    """Two different recordings, the second stamped exactly one tick after the first, as two
    bags: ``check`` cuts the test cases at the bag boundary, and so must ``replay`` (on
    555f6a7 replay continued the first recording's test cases into the second)."""
    n = 300
    parts = []
    for seeds, offset in (((41, 42), 0.0), ((51, 52), 0.4)):      # a second run, elsewhere in the workspace
        y, u = np.empty((n, 2)), np.empty((n, 2))
        for j, seed in enumerate(seeds):
            y[:, j], u[:, j] = simulate(n, seed, alpha_w=(0.05, 2.0))
        parts.append((y + offset, u))
    stamps_a = T0 + DT_NS * np.arange(n)
    stamps_b = stamps_a[-1] + DT_NS * (1 + np.arange(n))          # exactly one tick after the first bag
    bag_a = write_bag(tmp_path / "a", clean_rows(stamps_a, *parts[0]))
    bag_b = write_bag(tmp_path / "b", clean_rows(stamps_b, *parts[1]))
    model = tmp_path / "m.yaml"
    assert run(["identify", bag_a, bag_b, "--horizon", HORIZON, "--out", model], capsys)[0] == 0
    m = mdl.load(model)
    tight = tmp_path / "tight.yaml"
    mdl.save(m.with_joints({n_: mdl.JointSets(tuple(0.6 * a for a in j.alpha_w), tuple(0.6 * a for a in j.alpha_v),
                                              j.c_w, j.c_v, j.test_cases, j.horizon)
                            for n_, j in m.joints.items()}), tight)
    keys = ("violations", "first_violation_ns", "test_cases", "checks")
    for mf, conformant in ((model, True), (tight, False)):
        for joints in ("all", "arm_2_joint"):
            c = run_json(["check", bag_a, bag_b, "--model", mf, "--joints", joints], capsys)
            r = run_json(["replay", bag_a, bag_b, "--model", mf, "--joints", joints], capsys)
            assert c["conformant"] is conformant
            for name, jc in c["joints"].items():
                assert {k: r["joints"][name][k] for k in keys} == {k: jc[k] for k in keys}, (mf.name, name)


@pytest.mark.parametrize("cmd", ["check", "replay"])
def test_a_model_below_the_minimum_horizon_is_refused_unless_it_records_the_flag(cmd, tmp_path, clean_bag, capsys):
    """Issue 34.7: a horizon-0 (or 1) model left alpha_W out of every Theorem-1 row, and ``check``,
    ``replay`` and the monitor called faulty data conformant with it. Every reader refuses a
    model below the plant's minimum horizon (2 for the LWA-4P joint plant) unless it records
    ``horizon_below_minimum: true`` (identified with ``--allow-weak-horizon``), and a recorded
    minimum that is not the plant's."""
    weak = tmp_path / "weak.yaml"
    run_json(["identify", clean_bag, "--horizon", 1, "--allow-weak-horizon", "--out", weak], capsys)
    run_json([cmd, clean_bag, "--model", weak], capsys)          # the flag: a weaker guarantee, on purpose
    doc = yaml.safe_load(weak.read_text())
    for edit, words in (
            (lambda d: d.pop("horizon_below_minimum"), ["horizon 1 is below the plant's minimum horizon 2",
                                                         "--allow-weak-horizon"]),
            (lambda d: (d.pop("horizon_below_minimum"), d.update(horizon=0),
                        [j.update(horizon=0) for j in d["joints"].values()]),
             ["horizon 0 is below the plant's minimum horizon 2"]),
            (lambda d: d.update(minimum_horizon=0), ["minimum_horizon 0 is not the plant's minimum horizon 2"])):
        d = yaml.safe_load(yaml.safe_dump(doc))
        edit(d)
        bad = tmp_path / "bad.yaml"
        bad.write_text(yaml.safe_dump(d))
        code, so, se = run([cmd, clean_bag, "--model", bad, "--json"], capsys)
        assert_one_line_error(code, so, se, cmd, [str(bad), *words])
