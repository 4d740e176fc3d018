"""The recorded closed loop in a re-identification (``synthesis/recorded_loop.py``).

Real simulated closed-loop recordings (the per-joint plant with bounded disturbances, the
nodes' observer and law), real bags written and read back, the real LP. With Theorem 1's
initial-state set the open-loop test cases alone let the recorded tracking error leave the
re-identified ``R*_e`` (by 1.9 % on this recording); with the recorded loop's rows it stays
inside, and a bag recorded with other gains is recognised and not used as rows.
"""
import json
import re

import numpy as np
import pytest

from reachset_ros import conformance as cf
from reachset_ros import synthesis as sy
from reachset_ros.conformance.estimators import Estimator
from reachset_ros.sim import recordings as sr
from reachset_ros.synthesis import recorded_loop as rl
from reachset_ros.synthesis.config import components_from_gains
from reachset_ros.systems.plant import lwa4p_joint_plant
from cli_helpers import run_cli

NAME = "arm_6_joint"


@pytest.fixture(scope="module")
def recording():
    """8000 ticks (32 s) of arm 6's scenario at the default gains (HG 15/30, omega 20, zeta 1)."""
    return sr.simulate_recordings([NAME], 8000, seed=2, scenarios={NAME: sr.Scenario.for_joint(5)})


def _estimates(rec):
    return rec.stamps, np.column_stack([rec.x_hat, np.zeros(len(rec.y))])


def _extremes(rec, gains):
    series, refs = sr.recordings_series({NAME: rec})
    obs, ctrl = components_from_gains(gains)
    return rl.series_loop_extremes(lwa4p_joint_plant(), obs, ctrl, series[NAME], _estimates(rec), refs[NAME])


def test_the_replay_recognises_the_gains_that_ran_and_no_others(recording):
    rec = recording[NAME]
    ok = _extremes(rec, sr.DEFAULT_GAINS)
    assert ok.verified and ok.residual < 1e-8 and ok.checked > 7000 and ok.ticks > 7000
    for other in ({"omega": 21.0}, {"zeta": 1.1}, {"h1": 16.0}):
        bad = _extremes(rec, {**sr.DEFAULT_GAINS, **other})
        assert not bad.verified and bad.residual > 1e-4, other
    # the extremes merge exactly: two halves of the recording give the whole
    series, refs = sr.recordings_series({NAME: rec})
    s = series[NAME]
    obs, ctrl = components_from_gains(sr.DEFAULT_GAINS)
    halves = [rl.loop_extremes(lwa4p_joint_plant(), obs, ctrl, s.y, s.u, _estimates(rec)[1], rec.q_d, rec.qd_d,
                               rec.qdd_d, [seg]) for seg in ((0, 4000), (4000, 8000))]
    whole = rl.loop_extremes(lwa4p_joint_plant(), obs, ctrl, s.y, s.u, _estimates(rec)[1], rec.q_d, rec.qd_d,
                             rec.qdd_d, ((0, 4000), (4000, 8000)))
    m = rl.merge(halves + [None])
    assert np.array_equal(m.e_lo, whole.e_lo) and np.array_equal(m.e_hi, whole.e_hi)
    assert (m.ticks, m.checked, m.residual) == (whole.ticks, whole.checked, whole.residual)
    assert rl.merge([None, None]) is None


def test_reidentify_keeps_the_recorded_tracking_error_inside_r_e(recording):
    """Without the rows the re-identified R*_e (initial-state set) misses the recorded error
    (what the old code returned); with them it holds it, at a slightly larger ||R*_e||."""
    rec = recording[NAME]
    p = lwa4p_joint_plant()
    series, refs = sr.recordings_series({NAME: rec})
    pb = sy.problems_from_series(series, p, Estimator("fd"), 125, 100.0, 2.0, refs, 3,
                                 thm=cf.Theorem1.build(p, 125, Estimator("fd")))[0]
    ext = _extremes(rec, sr.DEFAULT_GAINS)

    def reach(res):
        return ext.reach(res.re_center) / np.asarray(res.re_radius)

    open_loop = sy.reidentify(pb, sr.DEFAULT_GAINS)
    assert reach(open_loop)[0] > 1.01           # the recorded error leaves R*_e
    held = rl.constrain(pb, sr.DEFAULT_GAINS, ext)
    assert held.loop_rows >= 1 and len(held.polytope.h) == len(pb.polytope.h) + held.loop_rows
    res = sy.reidentify(held, sr.DEFAULT_GAINS)
    assert np.all(reach(res) <= 1.0) and res.conformant and res.ru_inside
    assert open_loop.re_norm < res.re_norm < 1.05 * open_loop.re_norm
    d = res.extra["recorded_loop"]
    assert d["constrained"] and d["verified"] and d["inside"] and max(d["reach"]) <= 1.0
    # another loop's bag is only reported
    other = rl.constrain(pb, {**sr.DEFAULT_GAINS, "omega": 22.0}, _extremes(rec, {**sr.DEFAULT_GAINS, "omega": 22.0}))
    assert other.loop_rows is None and other.polytope is pb.polytope


@pytest.mark.slow
def test_cli_reidentify_reports_the_recorded_loop(recording, tmp_path):
    """``synthesize --mode reidentify`` on a bag recorded with the model's gains: the recorded
    loop is verified, constrains the sets and lies inside R*_e; a model with other gains is
    recognised as not the bag's (reported, not used)."""
    bag = tmp_path / "bag"
    sr.write_recordings(bag, recording)
    out = {}
    for tag, omega in (("same", "20"), ("other", "22")):
        model = tmp_path / f"{tag}.yaml"
        r = run_cli("synthesize", bag, "--fix", f"omega={omega}", "--fix", "zeta=1", "--out", model, "--json")
        assert r.returncode == 0, r.stderr
        r = run_cli("synthesize", bag, "--mode", "reidentify", "--model", model, "--json")
        assert r.returncode == 0, r.stderr
        out[tag] = json.loads(r.stdout)["joints"][NAME]
    same, other = out["same"]["recorded_loop"], out["other"]["recorded_loop"]
    assert same["verified"] and same["constrained"] and same["inside"] and same["ticks"] > 7000
    assert not other["verified"] and not other["constrained"] and other["residual"] > 1e-4
    assert out["same"]["conformant"] and out["same"]["ru_inside_up"]


@pytest.mark.slow
def test_bags_with_overlapping_stamps_give_the_fleets_recorded_loop(recording, tmp_path):
    """Issue 34.12: two bags recorded at the same stamps (two runs of the same gains). One
    process paired each measurement with whichever bag's estimate and reference had its stamp;
    the fleet pairs them within each bag. Both now read the loop bag by bag: the same recorded
    loop to the bit, and equal to the exact merge of the bags' own loops."""
    second = sr.simulate_recordings([NAME], 8000, seed=3, scenarios={NAME: sr.Scenario.for_joint(5)})
    assert np.array_equal(second[NAME].stamps, recording[NAME].stamps)       # the same stamps
    bags = [tmp_path / "a", tmp_path / "b"]
    sr.write_recordings(bags[0], recording)
    sr.write_recordings(bags[1], second)
    model = tmp_path / "m.yaml"
    r = run_cli("synthesize", bags[0], "--fix", "omega=20", "--fix", "zeta=1", "--out", model, "--json")
    assert r.returncode == 0, r.stderr
    got = {}
    for how, extra in (("one", []), ("fleet", ["--workers", "2"])):
        r = run_cli("synthesize", *bags, "--mode", "reidentify", "--model", model, *extra, "--json")
        assert r.returncode == 0, r.stderr
        got[how] = json.loads(r.stdout)["joints"][NAME]["recorded_loop"]
    assert got["one"] == got["fleet"]
    own = rl.merge([_extremes(rec[NAME], sr.DEFAULT_GAINS) for rec in (recording, second)])
    assert got["one"]["ticks"] == own.ticks and got["one"]["verified"]


# ------------------------------------------------------------------ issue 34.5: every path refuses
def _loop_data(rec):
    """``(series, references, estimates)`` of one recording, as :func:`iterate`'s ``record`` returns it."""
    series, refs = sr.recordings_series({NAME: rec})
    return series, refs, {NAME: _estimates(rec)}


def _fixed_space():
    """The search space with every gain fixed at the recording's (no search): iterate keeps them."""
    fix = {k: v for k, v in sr.DEFAULT_GAINS.items() if k in ("omega", "zeta", "h1", "h2", "eps")}
    return sy.SearchSpace.from_config(sy.load_config(), "hg", free=[], fix=fix)


def test_iterate_keeps_its_own_recorded_loop_inside_r_e_or_refuses(recording, tmp_path):
    """Issue 34.5: the iterative procedure's re-identification holds the loop recorded with the
    kept gains (estimates handed back by ``record``, or read from its bags), as ``synthesize
    --mode reidentify`` does; when the rows cannot be in the problem (reference method 2) and
    the loop leaves R*_e it is refused. Before, iterate re-identified from the open-loop test
    cases alone: the recorded error reached 1.019 of R*_e and the result was returned."""
    bag = tmp_path / "bag"
    sr.write_recordings(bag, recording)
    hist = sy.iterate(lambda gains: [bag], [bag], _fixed_space(), iterations=1, u_max=100.0)
    final = hist[-1]["results"][NAME]
    assert hist[-1]["step"] == "re-identification" and final.gains()["omega"] == 20.0
    d = final.extra.get("recorded_loop")
    assert d is not None, "the recorded loop was not looked at"
    assert d["verified"] and d["constrained"] and d["inside"] and d["ticks"] > 7000
    data = _loop_data(recording[NAME])
    hist = sy.iterate(lambda gains: data, data[:2], _fixed_space(), iterations=1, u_max=100.0)
    d = hist[-1]["results"][NAME].extra["recorded_loop"]
    assert d["verified"] and d["constrained"] and d["inside"] and max(d["reach"]) <= 1.0
    with pytest.raises(rl.RecordedLoopError, match=r"joint arm_6_joint: the loop recorded with these gains leaves R\*_e"):
        sy.iterate(lambda gains: data, data[:2], _fixed_space(), iterations=1, u_max=100.0, reference_method=2)


@pytest.mark.slow
def test_cli_worker_and_node_refuse_a_reidentification_whose_recorded_loop_leaves_r_e(recording, tmp_path):
    """Issue 34.5: with reference method 2 the recorded loop's rows are not in the problem; the
    re-identified R*_e then misses the loop its own bag recorded. ``synthesize --mode
    reidentify`` and the synthesis node's worker (the node's path) refuse it in one line with
    exit 2, so the node gets no result to apply; the node's own check of a result refuses it
    too. Before, both wrote the model and reported ``inside: false``."""
    import subprocess
    import sys

    bag, model = tmp_path / "bag", tmp_path / "m.yaml"
    sr.write_recordings(bag, recording)
    r = run_cli("synthesize", bag, "--fix", "omega=20", "--fix", "zeta=1", "--out", model, "--json")
    assert r.returncode == 0, r.stderr
    args = [bag, "--mode", "reidentify", "--model", model, "--reference-method", "2", "--json"]
    r = run_cli("synthesize", *args, "--out", tmp_path / "re.yaml")
    assert r.returncode == 2 and not (tmp_path / "re.yaml").exists(), r.stdout
    line, = r.stderr.strip().splitlines()
    assert re.search(r"error: joint arm_6_joint: the loop recorded with these gains leaves R\*_e: its tracking error "
                     r"reaches 1\.\d+ of R\*_e's radius in q", line), line
    w = subprocess.run([sys.executable, "-m", "reachset_ros.commands._synthesis_worker", "synthesize", *map(str, args)],
                       capture_output=True, timeout=300)
    assert w.returncode == 2 and w.stdout == b"", w.stderr
    assert w.stderr.decode().strip().splitlines()[-1] == line
    # method 3 (default): the rows hold it, the same bag is accepted
    r = run_cli("synthesize", *args[:-3], "--json")
    assert r.returncode == 0 and json.loads(r.stdout)["joints"][NAME]["recorded_loop"]["inside"], r.stderr
    # the node's check of a result (its worker refuses first)
    from reachset_ros.nodes.synthesis_node import recorded_loop_outside
    out = {"joints": {NAME: {"recorded_loop": {"verified": True, "ticks": 10, "inside": False, "reach": [1.02, 0.3]}}}}
    assert recorded_loop_outside(out).startswith("joint arm_6_joint: the loop recorded with these gains leaves R*_e")
    out["joints"][NAME]["recorded_loop"]["verified"] = False        # another loop's bag: only reported
    assert recorded_loop_outside(out) == ""
