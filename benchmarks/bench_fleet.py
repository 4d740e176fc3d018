"""Benchmark: ``reachset identify`` over a fleet's bags, one process vs Dask workers (issue 18).

N simulated bags (default 8 x 33.2 min, 6 joints, 250 Hz: the bags of ``bench_conformance.py``
with seeds 0..N-1, cached under ``benchmarks/.cache/``), identified with k* = 125 by
``reachset identify BAG... --out M.yaml`` in a fresh process:

1. one process (the default: the bags read one after the other, each joint's sweep in a
   thread per core);
2. ``--workers 1`` and ``--workers 2`` (a LocalCluster of worker processes, one task per bag);
3. ``--scheduler ADDRESS`` of a separately started LocalCluster with 2 workers.

For each: wall time, speed-up, peak RSS of the client and the largest peak RSS of any other
process of the run (a worker; sampled every 50 ms with psutil). ``--workers 2`` is also run on
2 and 4 of the bags: a worker's peak memory should not grow with the number of bags. The
model files are compared (provenance aside): they must be identical.

Syntax::

    .venv/bin/python benchmarks/bench_fleet.py [--bags 8] [--ticks 497883] [--json FILE]

Benchmarks assert nothing; the numbers go to docs/performance.md.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import psutil
import yaml

sys.path.insert(0, str(Path(__file__).resolve().parent))
import simbag  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
REACHSET = [sys.executable, "-m", "reachset_ros.cli"]
HORIZON = 125


class PeakRSS:
    """Peak resident memory per process of a process tree, sampled every ``every`` s."""

    def __init__(self, pid, every=0.05):
        self.root, self.every, self.peak, self._stop = pid, every, {}, threading.Event()
        self._t = threading.Thread(target=self._run, daemon=True)
        self._t.start()

    def _run(self):
        try:
            root = psutil.Process(self.root)
        except psutil.NoSuchProcess:
            return
        while not self._stop.is_set():
            try:
                procs = [root] + root.children(recursive=True)
            except psutil.NoSuchProcess:
                break
            for p in procs:
                try:
                    rss = p.memory_info().rss
                except psutil.Error:
                    continue
                self.peak[p.pid] = max(self.peak.get(p.pid, 0), rss)
            time.sleep(self.every)

    def stop(self):
        self._stop.set()
        self._t.join()
        return self.peak


def identify(paths, out, extra, watch=None):
    """Wall time and peak RSS (client, largest other process) of one ``reachset identify`` run."""
    t = time.perf_counter()
    p = subprocess.Popen(REACHSET + ["identify", *map(str, paths), "--horizon", str(HORIZON), "--out", str(out),
                                     *extra], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    rss = PeakRSS(p.pid)
    ext = PeakRSS(watch) if watch else None
    so, se = p.communicate()
    wall = time.perf_counter() - t
    peak = rss.stop()
    other = ext.stop() if ext else {}
    if p.returncode != 0:
        raise SystemExit(f"identify {extra} failed: {se.strip().splitlines()[-1:]}")
    client = peak.pop(p.pid, 0)
    workers = list(peak.values()) + list(other.values())
    return {"wall_s": round(wall, 2), "client_peak_mb": round(client / 2**20),
            "worker_peak_mb": round(max(workers) / 2**20) if workers else None,
            "progress": [ln for ln in se.splitlines() if ln.startswith("fleet sweep")][-1:]}


def model_body(path):
    d = yaml.safe_load(open(path))
    d.pop("provenance")
    return d


CLUSTER = """
import sys
from dask.distributed import LocalCluster
c = LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=":0")
print(c.scheduler_address, flush=True)
sys.stdin.read()
c.close()
"""


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--bags", type=int, default=8)
    ap.add_argument("--ticks", type=int, default=497_883)
    ap.add_argument("--json", help="write the results here")
    a = ap.parse_args()
    paths = [simbag.ensure_bag("bench", a.ticks, seed=s) for s in range(a.bags)]
    size = sum(f.stat().st_size for p in paths for f in Path(p).rglob("*") if f.is_file())
    rows, models = {}, {}
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        for name, extra in (("one process (default)", []), ("--workers 1", ["--workers", "1"]),
                            ("--workers 2", ["--workers", "2"])):
            out = tmp / f"{len(rows)}.yaml"
            rows[name] = identify(paths, out, extra)
            models[name] = model_body(out)
            print(name, rows[name], flush=True)
        cl = subprocess.Popen([sys.executable, "-c", CLUSTER], stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                              text=True)
        try:
            addr = cl.stdout.readline().strip()
            name = "--scheduler (LocalCluster, 2 workers)"
            out = tmp / "sched.yaml"
            rows[name] = identify(paths, out, ["--scheduler", addr], watch=cl.pid)
            models[name] = model_body(out)
            print(name, rows[name], flush=True)
        finally:
            cl.stdin.close()
            cl.wait(timeout=60)
        scaling = {}
        for n in sorted({2, 4, a.bags}):
            if n > a.bags:
                continue
            r = rows["--workers 2"] if n == a.bags else identify(paths[:n], tmp / f"s{n}.yaml", ["--workers", "2"])
            scaling[n] = {"wall_s": r["wall_s"], "worker_peak_mb": r["worker_peak_mb"],
                          "client_peak_mb": r["client_peak_mb"]}
            print(f"--workers 2 on {n} bags", scaling[n], flush=True)
    base = rows["one process (default)"]["wall_s"]
    one = rows["--workers 1"]["wall_s"]
    for r in rows.values():
        r["speedup_vs_one_process"] = round(base / r["wall_s"], 2)
        r["speedup_vs_workers_1"] = round(one / r["wall_s"], 2)
    first = next(iter(models.values()))
    res = {"bags": a.bags, "ticks_per_bag": a.ticks, "minutes_per_bag": round(a.ticks * 0.004 / 60, 1),
           "joints": len(simbag.JOINTS), "bag_mb": round(size / 2**20), "horizon": HORIZON,
           "cores": os.cpu_count(), "modes": rows, "worker_memory_by_bags": scaling,
           "models_identical": all(m == first for m in models.values())}
    print(json.dumps(res, indent=1))
    if a.json:
        Path(a.json).write_text(json.dumps(res, indent=1))


if __name__ == "__main__":
    main()
