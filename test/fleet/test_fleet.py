"""Fleet scale (issue 18): ``identify|check|synthesize --workers N | --scheduler ADDRESS``.

Real Dask distributed (a LocalCluster of worker processes, and a separate LocalCluster reached
by its scheduler address), real bags written and read back, real solvers. The model file of a
fleet run equals the single-process one to the bit (provenance aside) for any split of the
bags; bags that disagree are refused before a sweep is sent; without the options Dask is not
imported.
"""
import json
import subprocess
import sys

import numpy as np
import pytest
import yaml

from reachset_ros import bags, cli
from reachset_ros import conformance as cf
from reachset_ros import fleet as fl
from reachset_ros.conformance.estimators import Estimator
from reachset_ros.errors import ReachsetError
from reachset_ros.fleet.cluster import Fleet
from reachset_ros.sim import recordings as sr
from reachset_ros.systems.plant import lwa4p_joint_plant

JOINTS = ["arm_1_joint", "arm_2_joint"]
T0 = 1_700_000_000_000_000_000
SEARCH = {"sobol_log2": 4, "local_starts": 2, "local_maxfev": 40}


@pytest.fixture(scope="module")
def fleet_bags(tmp_path_factory):
    """Four small bags of the simulated arm (different seeds, 10 s apart), with /reference."""
    d = tmp_path_factory.mktemp("fleet")
    out = []
    for i in range(4):
        recs = sr.simulate_recordings(JOINTS, 1200 + 150 * i, seed=40 + i, t0=T0 + i * 10_000_000_000)
        sr.write_recordings(d / f"robot{i}", recs)
        out.append(d / f"robot{i}")
    cfg = d / "synthesis.yaml"
    cfg.write_text(yaml.safe_dump({"search": SEARCH}))
    return d, out, cfg


@pytest.fixture(scope="module")
def scheduler():
    """A separate two-worker LocalCluster, reached by address (``--scheduler``)."""
    from dask.distributed import LocalCluster
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=":0") as c:
        yield c.scheduler_address


def run(argv, capsys, code=0):
    rc = cli.main(list(map(str, argv)))
    out = capsys.readouterr()
    assert rc == code, out.err
    return out


def model_body(path):
    """The model file without its provenance (when, which command, the bags' hashes)."""
    d = yaml.safe_load(open(path))
    prov = d.pop("provenance")
    return d, prov


# ------------------------------------------------------------------ pure parts
def test_check_from_extremes_is_the_batch_check_to_the_bit():
    """check_extremes gives check's verdict and worst margin exactly, conformant or not."""
    p = lwa4p_joint_plant()
    est = Estimator.named("fd", p)
    recs = sr.simulate_recordings(JOINTS[:1], 1500, seed=5)
    s = sr.recordings_series(recs)[0][JOINTS[0]]
    thm = cf.Theorem1.build(p, 60)
    devs = cf.deviation_extremes(p, est, s.y, s.u, s.segments, 60, thm)
    sets = cf.identify_sets(p, thm, devs)
    for scale, conformant in ((1.0, True), (1.5, True), (0.8, False), (0.3, False)):
        xi = cf.xi_of(sets.c_w, sets.c_v, sets.alpha_w * scale, sets.alpha_v * scale)
        r = cf.check(p, thm, est, xi, s.y, s.u, s.segments, 60)
        ok, margin = cf.check_extremes(thm, xi, devs)
        assert ok is conformant and (r.violations == 0) is conformant
        assert margin == r.worst_margin and np.float64(margin).tobytes() == np.float64(r.worst_margin).tobytes()


def test_per_bag_parts_merge_to_the_whole_sweep(fleet_bags, tmp_path):
    """The tasks run in this process: per-bag extremes merged in any grouping equal the
    single-process sweep of all bags (arrays to the bit, counts, the read report)."""
    _, paths, _ = fleet_bags
    p = lwa4p_joint_plant()
    est = Estimator.named("fd", p)
    thm = cf.Theorem1.build(p, 50)
    read = fl.ReadSpec(None, 0.004, (bags.JOINT_STATES, bags.PLANT_INPUT))
    sweep = fl.SweepSpec(p, est, 50, thm)
    series, report = bags.read_joint_series(paths, None, 0.004)
    whole = cf.deviation_extremes_many(p, est, series, 50, thm)
    parts = [fl.bag_extremes(b, read, sweep) for b in paths]
    merged = fl.merge_extremes(parts, est.history, 50, paths)
    regrouped = cf.combine([cf.combine([parts[3].devs[JOINTS[0]], parts[1].devs[JOINTS[0]]]),
                            cf.combine([parts[2].devs[JOINTS[0]], parts[0].devs[JOINTS[0]]])])
    for n in JOINTS:
        for got in (merged.devs[n],) + ((regrouped,) if n == JOINTS[0] else ()):
            assert got.test_cases == whole[n].test_cases and got.checks == whole[n].checks
            for a, b in zip(got.maxp + got.maxm, whole[n].maxp + whole[n].maxm):
                assert a.tobytes() == b.tobytes()
    assert merged.report.as_dict() == report.as_dict()
    # a bag too short for any test case contributes nothing (and is no error on its own) ...
    tiny = tmp_path / "tiny"
    sr.write_recordings(tiny, sr.simulate_recordings(JOINTS, est.history, seed=9, t0=T0 - 10**10))
    short = fl.bag_extremes(tiny, read, sweep)
    assert short.devs[JOINTS[0]].test_cases == 0 and np.isneginf(short.devs[JOINTS[0]].maxp[1]).all()
    again = fl.merge_extremes([short] + parts, est.history, 50, [tiny] + paths)
    assert all(again.devs[n].maxp[7].tobytes() == merged.devs[n].maxp[7].tobytes() for n in JOINTS)
    # ... but alone it is refused as the single process refuses it
    with pytest.raises(ReachsetError, match="too few samples for horizon 50"):
        fl.merge_extremes([short], est.history, 50, [tiny])


# ------------------------------------------------------------------ the three modes, to the bit
@pytest.mark.slow
def test_identify_and_check_are_bit_identical_in_the_three_modes(fleet_bags, scheduler, capsys, tmp_path):
    """Issue 18 check: single process, ``--workers 2`` and ``--scheduler`` (a separate
    LocalCluster of two workers; the bags fall to the workers as they finish) give the same model file (provenance
    aside) and the same JSON; ``check`` of a non-conformant model too (violations, first
    violation stamp, worst margin)."""
    _, paths, _ = fleet_bags
    modes = {"single": [], "workers2": ["--workers", 2], "scheduler": ["--scheduler", scheduler]}
    models, jsons = {}, {}
    for name, extra in modes.items():
        out = tmp_path / f"{name}.yaml"
        r = run(["identify", *paths, "--horizon", 60, "--out", out, "--json", *extra], capsys)
        j = json.loads(r.out)
        j.pop("model")
        jsons[name] = j
        models[name] = model_body(out)
        if extra:     # progress: bags done, messages read, rate
            assert f"fleet sweep: {len(paths)}/{len(paths)} bags" in r.err and "messages/s" in r.err
        else:
            assert "fleet" not in r.err
    body0, prov0 = models["single"]
    for name in modes:
        body, prov = models[name]
        assert body == body0, name
        assert jsons[name] == jsons["single"], name
        assert [b["sha256"] for b in prov["bags"]] == [b["sha256"] for b in prov0["bags"]]
    assert open(tmp_path / "single.yaml").read().split("provenance:")[0] == \
        open(tmp_path / "workers2.yaml").read().split("provenance:")[0]
    # a model of the first bag alone is violated by the others: the same counts and first stamp
    one = tmp_path / "one.yaml"
    run(["identify", paths[0], "--horizon", 60, "--out", one], capsys)
    checks = {}
    for name, extra in modes.items():
        r = run(["check", *paths, "--model", one, "--json", *extra], capsys, code=1)
        checks[name] = json.loads(r.out)
    assert checks["single"]["conformant"] is False
    assert any(j["violations"] > 0 for j in checks["single"]["joints"].values())
    for name in modes:
        assert checks[name] == checks["single"], name


@pytest.mark.slow
def test_synthesize_is_bit_identical_with_workers(fleet_bags, capsys, tmp_path):
    """``synthesize --workers 2``: the same model (sets, gains, R_e, R_u, the recorded
    references' bound) as one process; ``--plot`` needs the series and is refused."""
    _, paths, cfg = fleet_bags
    outs = {}
    for name, extra in (("single", []), ("workers", ["--workers", 2])):
        outs[name] = tmp_path / f"{name}.yaml"
        r = run(["synthesize", *paths[:3], "--joints", JOINTS[1], "--config", cfg, "--horizon", 60, "--out",
                 outs[name], "--json", *extra], capsys)
        j = json.loads(r.out)
        assert all(v["conformant"] for v in j["joints"].values())
    a, b = model_body(outs["single"])[0], model_body(outs["workers"])[0]
    assert a == b and any(j.get("gains") for j in a["joints"].values())
    assert list(a["envelope"]["joints"]) == [JOINTS[1]]     # issue 37.3: the same envelope, read again on a fleet
    r = run(["synthesize", *paths[:1], "--config", cfg, "--plot", tmp_path / "p", "--workers", 2], capsys, code=2)
    assert "--plot needs the whole series in one process" in r.err and len(r.err.strip().splitlines()) == 1


@pytest.mark.slow
def test_reidentify_with_the_recorded_loop_is_bit_identical_with_workers(fleet_bags, capsys, tmp_path):
    """``synthesize --mode reidentify --workers 2``: the bags' recorded loop (estimates,
    references, the kept gains' replay) is reduced per bag on the workers and merged exactly:
    the same model and the same ``recorded_loop`` report as one process."""
    _, paths, cfg = fleet_bags
    kept = tmp_path / "kept.yaml"     # the gains the bags were recorded with (sr.DEFAULT_GAINS)
    run(["synthesize", *paths[:3], "--joints", JOINTS[1], "--config", cfg, "--horizon", 60, "--fix", "omega=20",
         "--fix", "zeta=1", "--out", kept], capsys)
    outs, loops = {}, {}
    for name, extra in (("single", []), ("workers", ["--workers", 2])):
        outs[name] = tmp_path / f"{name}.yaml"
        r = run(["synthesize", *paths[:3], "--mode", "reidentify", "--model", kept, "--out", outs[name], "--json",
                 *extra], capsys)
        loops[name] = json.loads(r.out)["joints"][JOINTS[1]]["recorded_loop"]
    assert loops["single"] == loops["workers"] and loops["single"]["verified"] and loops["single"]["inside"]
    assert model_body(outs["single"])[0] == model_body(outs["workers"])[0]


# ------------------------------------------------------------------ refusals
@pytest.mark.slow
def test_bags_that_disagree_are_refused_before_any_sweep(fleet_bags, capsys, tmp_path):
    """Different joints, or a different sampling period: exit 2 with one line naming the bag,
    after the header pass and before any sweep task; no model file."""
    _, paths, _ = fleet_bags
    odd = tmp_path / "three_joints"
    sr.write_recordings(odd, sr.simulate_recordings(JOINTS + ["arm_3_joint"], 400, seed=1))
    slow = tmp_path / "eight_ms"
    sr.write_recordings(slow, sr.simulate_recordings(JOINTS, 400, seed=2, plant=lwa4p_joint_plant(dt=0.008)))
    out = tmp_path / "m.yaml"
    for bad, msg in ((odd, "bags have different joints"), (slow, "sampling period of /joint_states is 8 ms")):
        r = run(["identify", paths[0], bad, "--horizon", 60, "--out", out, "--workers", 2], capsys, code=2)
        lines = r.err.strip().splitlines()
        assert msg in lines[-1] and str(bad) in lines[-1] and "Traceback" not in r.err
        assert "fleet header" in r.err and "fleet sweep" not in r.err
        assert not out.exists()
    # the single process refuses them too (while reading)
    r = run(["identify", paths[0], slow, "--horizon", 60, "--out", out], capsys, code=2)
    assert "sampling period" in r.err and not out.exists()


def test_bad_fleet_options_and_an_unreachable_scheduler(fleet_bags, capsys):
    _, paths, _ = fleet_bags
    r = run(["identify", paths[0], "--workers", 0], capsys, code=2)
    assert r.err.strip() == "reachset identify: error: --workers must be >= 1, got 0"
    r = run(["identify", paths[0], "--calibrate", 2, "--workers", 2], capsys, code=2)
    assert "--calibrate needs the whole series in one process: run it without --workers" in r.err
    with pytest.raises(SystemExit):       # argparse: the two options exclude each other
        cli.main(["check", str(paths[0]), "--model", "m.yaml", "--workers", "2", "--scheduler", "tcp://x:1"])
    capsys.readouterr()
    with pytest.raises(ReachsetError, match="cannot start or reach the Dask cluster"):
        with Fleet(scheduler="tcp://127.0.0.1:9", timeout=1):
            pass


def test_no_dask_import_without_the_options(fleet_bags, tmp_path):
    """Without --workers/--scheduler nothing changes: Dask is not even imported."""
    _, paths, _ = fleet_bags
    code = ("import sys; from reachset_ros import cli; "
            f"rc = cli.main(['identify', {str(paths[0])!r}, '--horizon', '60', '--json']); "
            "print(rc, sorted(m for m in sys.modules if m.split('.')[0] in ('dask', 'distributed')))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip().splitlines()[-1] == "0 []"


def test_problem_check_without_the_series_equals_the_batch_check(fleet_bags):
    """A fleet's synthesis problem holds the extremes, not the series: its check of a
    conformant xi (from the extremes) and of a violated one (the Checker's pass over the
    bags on the cluster) equal the batch check of the concatenated series, field by field."""
    from reachset_ros.synthesis.problem import JointProblem
    _, paths, _ = fleet_bags
    p = lwa4p_joint_plant()
    est = Estimator.named("fd", p)
    thm = cf.Theorem1.build(p, 60)
    series, _ = bags.read_joint_series(paths, None, 0.004)
    refs = bags.read_references(paths, JOINTS, 0.004)
    s = series[JOINTS[1]]
    read = fl.ReadSpec(None, 0.004, (bags.JOINT_STATES, bags.PLANT_INPUT))
    sweep = fl.SweepSpec(p, est, 60, thm)
    devs = cf.deviation_extremes(p, est, s.y, s.u, s.segments, 60, thm)
    sets = cf.identify_sets(p, thm, devs)
    with Fleet(workers=1, progress=None) as fleet:
        pb = JointProblem.prepare(JOINTS[1], p, est, None, None, None, 60, thm=thm, references=refs[JOINTS[1]],
                                  devs=devs, checker=fl.Checker(fleet, paths, read, sweep))
        for scale in (1.0, 0.5):
            xi = cf.xi_of(sets.c_w, sets.c_v, sets.alpha_w * scale, sets.alpha_v * scale)
            want = cf.check(p, thm, est, xi, s.y, s.u, s.segments, 60)
            got = pb.check(xi)
            assert got == want and (got.violations > 0) == (scale < 1)
