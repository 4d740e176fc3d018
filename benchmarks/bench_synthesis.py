"""Benchmark: combined synthesis for one joint from a 5-minute bag (75,000 ticks at 250 Hz).

The target (issue 6): at most 30 s per joint on the 2-core machine, goal 10 s.

On simulated bags generated once and cached under ``benchmarks/.cache/`` (one joint,
:func:`reachset_ros.sim.recordings.simulate_recordings`, seed 1), with and without the
``/reference`` topic (with it, Appendix B method 3 runs inside the optimisation), this measures

1. the wall time of ``reachset synthesize BAG --json`` in a fresh process (start-up, bag
   reading, the Theorem-1 sweep, the separate approach and the combined search, the final
   conformance check) for the HG (omega, zeta) and the ESO (l1, l2, l3) search spaces;
2. in process: reading, preparing (sweep + reduced Theorem-1 rows), separate, combined;
3. ``reachset input-limits`` (the torque-derived U_p of the shipped model).

Syntax::

    .venv/bin/python benchmarks/bench_synthesis.py [--quick] [--json FILE]

``--quick``: only HG with references. ``--json FILE``: the results are merged into FILE
under the key ``"synthesis"``. Benchmarks assert nothing.
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import time
from pathlib import Path


from reachset_ros import synthesis as sy
from reachset_ros.bags.references import read_references
from reachset_ros.sim import recordings as sr
from reachset_ros.bags import read_joint_series
from reachset_ros.conformance.estimators import Estimator
from reachset_ros.systems.plant import lwa4p_joint_plant

HERE = Path(__file__).resolve().parent
CACHE = HERE / ".cache"
TICKS = 75_000
JOINT = "arm_1_joint"
VERSION = 1


def machine():
    cpu = ""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    try:
        load = os.getloadavg()[0]
    except OSError:
        load = None
    return {"cores": os.cpu_count(), "cpu": cpu or platform.processor(), "python": platform.python_version(),
            "load_1min_at_start": load}


def ensure_bag(reference):
    """The cached 5-minute bag (with or without /reference and /observer/estimate)."""
    path = CACHE / f"synth_v{VERSION}_T{TICKS}_{'ref' if reference else 'noref'}" / "bag"
    if path.is_dir():
        return path
    path.parent.mkdir(parents=True, exist_ok=True)
    t = time.perf_counter()
    recs = sr.simulate_recordings([JOINT], TICKS, seed=1)
    sr.write_recordings(path, recs, reference=reference, estimate=reference)
    print(f"[bench_synthesis] generated {path} in {time.perf_counter() - t:.1f} s", file=sys.stderr, flush=True)
    return path


def cli(*argv):
    t = time.perf_counter()
    r = subprocess.run([sys.executable, "-m", "reachset_ros.cli", *map(str, argv)], capture_output=True, text=True)
    dt = time.perf_counter() - t
    if r.returncode != 0:
        raise RuntimeError(f"reachset {' '.join(map(str, argv))} failed: {r.stderr.strip()}")
    return dt, json.loads(r.stdout)


def in_process(bag, observer):
    out = {}
    t = time.perf_counter()
    series, _ = read_joint_series([bag], [JOINT])
    refs = read_references([bag], [JOINT])
    out["read_s"] = time.perf_counter() - t
    plant = lwa4p_joint_plant()
    t = time.perf_counter()
    pb = sy.problems_from_series(series, plant, Estimator("fd"), 125, 26.0, 2.0, refs, 3)[0]
    out["prepare_s"] = time.perf_counter() - t
    out["theorem1_rows"] = [int(len(pb.polytope.h)), int(pb.polytope.rows_total)]
    cfg = sy.load_config()
    space = sy.SearchSpace.from_config(cfg, observer)
    loops = {}
    t = time.perf_counter()
    sep = sy.separate(pb, space, cfg["search"], loops=loops)
    out["separate_s"] = time.perf_counter() - t
    t = time.perf_counter()
    com = sy.combined(pb, space, cfg["search"], separate_result=sep, loops=loops)
    out["combined_s"] = time.perf_counter() - t
    out.update(separate_evaluations=sep.evaluations, combined_evaluations=com.evaluations,
               re_norm=com.re_norm, re_norm_separate=sep.re_norm, test_cases=com.test_cases)
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="HG with references only")
    ap.add_argument("--json", help="merge the results into this JSON file (key 'synthesis')")
    args = ap.parse_args(argv)
    res = {"machine": machine(), "ticks": TICKS, "joint": JOINT, "target_s": 30, "goal_s": 10}
    cases = [("hg", True)] if args.quick else [("hg", True), ("hg", False), ("eso", True), ("eso", False)]
    res["cli"] = {}
    for observer, ref in cases:
        bag = ensure_bag(ref)
        key = f"{observer}_{'reference' if ref else 'no_reference'}"
        # without /reference a reference class is required (issue 14.4); the bag's sum-of-sines lies in this one
        cls = [] if ref else ["--reference-class", "qdd_max=2,step_max=0.05"]
        wall, out = cli("synthesize", bag, "--observer", observer, "--json", *cls)
        j = out["joints"][JOINT]
        res["cli"][key] = {"wall_s": wall, "re_norm": j["re_norm"], "re_norm_separate": j["separate"]["re_norm"],
                           "evaluations": j["evaluations"] + j["separate"]["evaluations"],
                           "reported_s": out["seconds"], "reference_ticks": j["reference_error"]["ticks"]}
        print(f"reachset synthesize ({observer}, {'with' if ref else 'without'} /reference, {TICKS} ticks, 1 joint): "
              f"{wall:.1f} s wall (fresh process); ||R_e|| combined {j['re_norm']:.4g} vs separate "
              f"{j['separate']['re_norm']:.4g}", flush=True)
    t = time.perf_counter()
    res["in_process_hg_reference"] = in_process(ensure_bag(True), "hg")
    ip = res["in_process_hg_reference"]
    print(f"in process (hg, with /reference): read {ip['read_s']:.2f} s, prepare {ip['prepare_s']:.2f} s "
          f"({ip['theorem1_rows'][0]} of {ip['theorem1_rows'][1]} Theorem-1 rows kept), separate {ip['separate_s']:.2f} s "
          f"({ip['separate_evaluations']} evaluations), combined {ip['combined_s']:.2f} s "
          f"({ip['combined_evaluations']} evaluations)", flush=True)
    if not args.quick:
        wall, out = cli("input-limits", "--json")
        res["input_limits"] = {"wall_s": wall, "u_max": out["u_max"], "boxes": out["boxes"]}
        print(f"reachset input-limits: {wall:.1f} s wall, {out['boxes']} sub-boxes, U_p = "
              + ", ".join(f"{x:.4g}" for x in out["u_max"]), flush=True)
    print("RESULT " + json.dumps(res, sort_keys=True), flush=True)
    if args.json:
        p = Path(args.json)
        try:
            d = json.loads(p.read_text()) if p.exists() else {}
            if not isinstance(d, dict):
                d = {}
        except ValueError:
            d = {}
        d["synthesis"] = res
        p.write_text(json.dumps(d, indent=2, sort_keys=True) + "\n")
    return res


if __name__ == "__main__":
    main()
