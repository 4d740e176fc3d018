"""Benchmark: bag -> model for a 33-minute, 6-joint, 250 Hz recording (paper Sec. IV sizes).

Measures, on a simulated bag generated once and cached under ``benchmarks/.cache/``:

1. reading the bag (``reachset_ros.bags.read_joint_series``), and for comparison the
   message-by-message reading it replaced (rosbags ``deserialize_cdr`` per message) and
   plain iteration over the raw messages with rosbags and with ``mcap``'s ``iter_messages``;
2. per joint the Theorem-1 sweep over all test cases and the identification LPs;
3. the total wall time of ``reachset identify BAG --out MODEL`` (a fresh process);
4. the naive method the paper avoids: an explicit reachable set per test case (zonotopes
   built step by step, containment checked for every k), on a subset, extrapolated;
5. ``reachset replay`` of 30,000 ticks (6 joints) in a fresh process, per tick.

Syntax::

    .venv/bin/python benchmarks/bench_conformance.py [--quick] [--naive-cases N] [--json FILE]

``--quick`` skips the slow baselines (about a minute). Benchmarks assert nothing.
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import simbag  # noqa: E402

from reachset_ros import bags  # noqa: E402
from reachset_ros import conformance as cf  # noqa: E402
from reachset_ros.conformance.estimators import Estimator  # noqa: E402
from reachset_ros.systems.plant import lwa4p_joint_plant  # noqa: E402

TICKS = 497_883          # 497,880 test cases per joint with the 3-tick 'fd' estimator history
HORIZON = 125
REPLAY_TICKS = 30_000


def machine():
    cpu = ""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    return {"cores": os.cpu_count(), "cpu": cpu or platform.processor(), "python": platform.python_version(),
            "numpy": np.__version__}


def timed(fn, *a, **kw):
    t = time.perf_counter()
    out = fn(*a, **kw)
    return time.perf_counter() - t, out


def baseline_read(path):
    """The reader before the fast path: rosbags AnyReader + deserialize_cdr per message."""
    from rosbags.highlevel import AnyReader
    ts = bags.typestore()
    cols = {t: bags.topics._TopicColumns() for t in (bags.JOINT_STATES, bags.PLANT_INPUT)}
    with AnyReader([Path(path)], default_typestore=ts) as reader:
        conns = [c for c in reader.connections if c.topic in cols]
        for conn, _t, raw in reader.messages(connections=conns):
            msg = ts.deserialize_cdr(raw, conn.msgtype)
            vals = msg.position if conn.topic == bags.JOINT_STATES else msg.acceleration
            cols[conn.topic].add(bags.header_stamp_ns(msg), msg.name, vals)
    return cols


def raw_iteration(path):
    """Seconds to iterate over the raw messages (no decoding): rosbags, mcap log-time/file order."""
    from mcap.reader import make_reader
    from rosbags.highlevel import AnyReader
    out = {}
    t = time.perf_counter()
    with AnyReader([Path(path)], default_typestore=bags.typestore()) as reader:
        for _ in reader.messages(connections=reader.connections):
            pass
    out["rosbags_anyreader"] = time.perf_counter() - t
    f = next(Path(path).glob("*.mcap"))
    for key, order in (("mcap_iter_messages_log_time_order", True), ("mcap_iter_messages_file_order", False)):
        t = time.perf_counter()
        with open(f, "rb") as fh:
            for _ in make_reader(fh).iter_messages(log_time_order=order):
                pass
        out[key] = time.perf_counter() - t
    return out


def naive_check(plant, est, y, u, starts, horizon, alpha_w, alpha_v, c_w, c_v):
    """Explicit reachable sets per test case (the method Theorem 1 avoids).

    For each test case m: R_x[0] = {x0(m)}, R_x[k+1] = A R_x[k] + B u[m+k] (+) W, and
    y[m+k] must lie in C R_x[k] + D u[m+k] (+) V, checked with zonotope containment.
    Returns the number of (test case, k) checks outside.
    """
    from reachset_ros.sets.zonotope import Zonotope
    W = plant.W(alpha_w, c_w)
    V = plant.V(alpha_v, c_v)
    A, B, C, D = (np.asarray(M) for M in (plant.A, plant.B, plant.C, plant.D))
    y2, u2 = cf.as_2d(y), cf.as_2d(u)
    outside = 0
    for m in starts:
        x0 = est.estimate(plant, y2, u2, np.array([m]))[:, 0]
        R = Zonotope(x0, np.zeros((len(x0), 0)))
        for k in range(horizon + 1):
            if m + k >= len(y2):
                break
            Y = R.linear_map(C).minkowski_sum(D @ u2[m + k]).minkowski_sum(V)
            if not Y.contains(y2[m + k]):
                outside += 1
            R = R.linear_map(A).minkowski_sum(B @ u2[m + k]).minkowski_sum(W)
    return outside


def run_cli(*args):
    t = time.perf_counter()
    r = subprocess.run([sys.executable, "-m", "reachset_ros.cli", *map(str, args)], capture_output=True, text=True)
    wall = time.perf_counter() - t
    # check/replay exit 1 when not conformant: a result, not a failure
    if r.returncode not in ((0, 1) if str(args[0]) in ("check", "replay") else (0,)):
        raise SystemExit(f"reachset {' '.join(map(str, args))} failed ({r.returncode}): {r.stderr.strip()}")
    return wall, r.stdout


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="skip the message-by-message baseline read")
    ap.add_argument("--naive-cases", type=int, default=2000, help="test cases for the naive method")
    ap.add_argument("--json", help="also write the results to this file")
    args = ap.parse_args(argv)
    res = {"machine": machine()}
    print(f"machine: {res['machine']}", flush=True)

    bag = simbag.ensure_bag("sim6_33min", TICKS)
    short = simbag.ensure_bag("sim6_33min", TICKS, first=REPLAY_TICKS)
    size = sum(f.stat().st_size for f in bag.iterdir())
    res["bag"] = {"path": str(bag), "ticks": TICKS, "joints": len(simbag.JOINTS), "bytes": size,
                  "messages": 2 * TICKS}
    print(f"bag: {bag} ({TICKS} ticks x 6 joints, {2 * TICKS} messages, {size / 1e6:.0f} MB)", flush=True)

    # 1. reading
    bags.typestore()
    reads = [timed(bags.read_joint_series, [bag])[0] for _ in range(3)]
    series, report = bags.read_joint_series([bag])
    res["read_s"] = {"min": min(reads), "median": float(np.median(reads))}
    print(f"read_joint_series: {min(reads):.2f} s (median of 3: {np.median(reads):.2f} s, "
          f"{min(reads) / (2 * TICKS) * 1e6:.2f} us/message)", flush=True)
    # VmHWM (peak resident set of this process image; ru_maxrss would include the parent's)
    code = ("import re; from reachset_ros import bags; {}"
            "print(int(re.search(r'VmHWM:\\s+(\\d+)', open('/proc/self/status').read()).group(1)) // 1024)")
    rss = [int(subprocess.run([sys.executable, "-c", code.format(c)], capture_output=True, text=True,
                              check=True).stdout) for c in ("", f"bags.read_joint_series([{str(bag)!r}]); ")]
    res["read_peak_rss_mb"] = {"after_import": rss[0], "after_read": rss[1]}
    print(f"  peak RSS: {rss[1]} MB after reading ({rss[0]} MB after import)", flush=True)
    if not args.quick:
        tb, _ = timed(baseline_read, bag)
        res["read_baseline_s"] = tb
        print(f"  before (rosbags deserialize_cdr per message, topics only): {tb:.1f} s "
              f"-> {tb / min(reads):.0f}x faster", flush=True)
        raw = raw_iteration(bag)
        res["raw_iteration_s"] = raw
        print("  raw message iteration without decoding: " + ", ".join(f"{k} {v:.1f} s" for k, v in raw.items()),
              flush=True)

    # sqlite3: the same first 30,000 ticks through rosbags' reader and the batch decoder
    sq = simbag.ensure_bag("sim6_33min", TICKS, first=REPLAY_TICKS, storage="sqlite3")
    t_sq = min(timed(bags.read_joint_series, [sq])[0] for _ in range(3))
    t_mc = min(timed(bags.read_joint_series, [short])[0] for _ in range(3))
    res["read_30k_ticks_s"] = {"mcap": t_mc, "sqlite3": t_sq}
    print(f"read_joint_series, {REPLAY_TICKS} ticks: MCAP {t_mc:.3f} s, sqlite3 {t_sq:.3f} s", end="", flush=True)
    if not args.quick:
        t_sqb = timed(baseline_read, sq)[0]
        res["read_30k_ticks_s"]["sqlite3_baseline"] = t_sqb
        print(f" (sqlite3 before: {t_sqb:.2f} s)", end="")
    print(flush=True)

    # 2. sweep + LP per joint
    plant, est = lwa4p_joint_plant(), Estimator("fd")
    t_thm, thm = timed(cf.Theorem1.build, plant, HORIZON)
    per_joint = {}
    for name, s in series.items():
        t_sw, dev = timed(cf.deviation_extremes, plant, est, s.y, s.u, s.segments, HORIZON, thm)
        t_lp, sets = timed(cf.identify_sets, plant, thm, dev)
        t_st, _ = timed(cf.stable_horizon, plant, thm, dev)
        per_joint[name] = {"test_cases": dev.test_cases, "sweep_s": t_sw, "lp_s": t_lp, "stable_horizon_s": t_st,
                           "alpha_w": sets.alpha_w.tolist(), "alpha_v": sets.alpha_v.tolist(),
                           "c_w": sets.c_w.tolist(), "c_v": sets.c_v.tolist()}
        print(f"{name}: {dev.test_cases} test cases, sweep {t_sw:.2f} s, LP {t_lp * 1e3:.0f} ms, "
              f"Remark-3 horizon scan {t_st * 1e3:.0f} ms", flush=True)
    res["theorem1_build_s"] = t_thm
    res["joints"] = per_joint
    sweep_total = sum(j["sweep_s"] for j in per_joint.values())
    lp_total = sum(j["lp_s"] + j["stable_horizon_s"] for j in per_joint.values())
    print(f"math total: sweep {sweep_total:.1f} s + LPs {lp_total:.2f} s", flush=True)

    # 3. reachset identify, a fresh process
    tmp_dir = tempfile.TemporaryDirectory(prefix="reachset-bench-")   # removed at the end, or on an error
    tmp = Path(tmp_dir.name)
    model = tmp / "model.yaml"
    t_help, _ = run_cli("--help")
    t_id, out = run_cli("identify", bag, "--out", model, "--json")
    ident = json.loads(out)
    res["cli_startup_s"] = t_help
    res["identify_total_s"] = t_id
    print(f"reachset identify (6 joints, k*={HORIZON}): {t_id:.1f} s wall "
          f"(process start-up alone: {t_help:.1f} s)", flush=True)

    # 4. the naive method on a subset
    name0 = next(iter(series))
    s0, j0 = series[name0], ident["joints"][name0]
    starts = cf.test_case_starts(s0.segments, est.history)[0][:args.naive_cases]
    t_nv, outside = timed(naive_check, plant, est, s0.y, s0.u, starts, HORIZON, j0["alpha_w"], j0["alpha_v"],
                          j0["c_w"], j0["c_v"])
    per_case_naive = t_nv / len(starts)
    per_case_fast = per_joint[name0]["sweep_s"] / per_joint[name0]["test_cases"]
    # the batch check of the same model over all test cases, for a like-for-like comparison
    xi = cf.xi_of(j0["c_w"], j0["c_v"], j0["alpha_w"], j0["alpha_v"])
    t_chk, chk = timed(cf.check, plant, thm, est, xi, s0.y, s0.u, s0.segments, HORIZON)
    per_case_check = t_chk / chk.test_cases
    res["naive"] = {"test_cases": len(starts), "seconds": t_nv, "per_test_case_s": per_case_naive,
                    "outside": outside, "extrapolated_6_joints_s": per_case_naive * 6 * per_joint[name0]["test_cases"],
                    "theorem1_sweep_per_test_case_s": per_case_fast, "theorem1_check_per_test_case_s": per_case_check,
                    "ratio_vs_sweep": per_case_naive / per_case_fast, "ratio_vs_check": per_case_naive / per_case_check}
    print(f"naive (reachable set per test case): {len(starts)} test cases in {t_nv:.1f} s = "
          f"{per_case_naive * 1e3:.2f} ms/test case ({outside} checks outside); extrapolated to 6 x "
          f"{per_joint[name0]['test_cases']} test cases: {res['naive']['extrapolated_6_joints_s'] / 3600:.1f} h", flush=True)
    print(f"  Theorem 1: sweep {per_case_fast * 1e6:.2f} us/test case, check {per_case_check * 1e6:.2f} us/test case "
          f"-> naive is {res['naive']['ratio_vs_sweep']:.0f}x (vs sweep) / {res['naive']['ratio_vs_check']:.0f}x "
          f"(vs check) slower", flush=True)

    # 5. replay of 30,000 ticks, a fresh process
    t_rp, out = run_cli("replay", short, "--model", model, "--json")
    rep = json.loads(out)
    res["replay"] = {"ticks": rep["ticks"], "wall_s": t_rp, "wall_per_tick_us": t_rp / rep["ticks"] * 1e6,
                     "in_process_us_per_tick": rep.get("timing_us_per_tick"), "conformant": rep["conformant"]}
    print(f"reachset replay ({rep['ticks']} ticks, 6 joints): {t_rp:.2f} s wall incl. start-up = "
          f"{t_rp / rep['ticks'] * 1e6:.1f} us/tick; in-process per tick: {rep.get('timing_us_per_tick')}",
          flush=True)

    print("RESULT " + json.dumps(res, sort_keys=True), flush=True)
    if args.json:
        Path(args.json).write_text(json.dumps(res, indent=2, sort_keys=True) + "\n")
    tmp_dir.cleanup()
    return res


if __name__ == "__main__":
    main()
