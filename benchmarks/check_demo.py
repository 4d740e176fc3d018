"""Acceptance check of the demo (not in `make test`: timing-sensitive, ~3 min).
Run: .venv/bin/python -m pytest -q benchmarks/check_demo.py

`reachset demo` end to end: every node a separate process over DDS, the simulated arm,
synthesis applied live, a fault injected and caught (issue: node suite and demo)."""
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
from rosbags.highlevel import AnyReader

from reachset_ros.bags import typestore


def test_demo_detects_the_fault_and_agrees_with_check(tmp_path):
    record = tmp_path / "B"
    # exactly the command of the "done when" (plus where to put the logs)
    out = subprocess.run([sys.executable, "-m", "reachset_ros.cli", "demo", "--headless", "--duration", "25",
                          "--inject-fault-at", "18", "--record", str(record),
                          "--workdir", str(tmp_path / "work"), "--json"],
                         capture_output=True, text=True, timeout=600)
    assert out.returncode == 0, out.stderr[-2000:]
    res = json.loads(out.stdout)
    fault, stop = res["fault_injected_ns"], res["safe_stop_ns"]
    assert fault is not None and stop is not None
    # read the recorded bag back
    ts = typestore()
    status, stops = [], []
    with AnyReader([record], default_typestore=ts) as reader:
        conns = [c for c in reader.connections if c.topic in ("/conformance/status", "/safe_stop")]
        for c, _t, raw in reader.messages(connections=conns):
            m = ts.deserialize_cdr(raw, c.msgtype)
            st = m.header.stamp.sec * 1_000_000_000 + m.header.stamp.nanosec
            (status if c.topic == "/conformance/status" else stops).append((st, m, _t))
    active = sorted(st for st, m, _ in stops if m.active)
    assert active and active[0] >= fault, "no safe stop before the fault"
    assert active[0] - fault <= 100_000_000, f"safe stop {(active[0] - fault) / 1e6:.1f} ms after the fault"
    # >= 240 Hz until the stop, on the stamp clock (every tick has its status) and on the
    # bag's log time (the recorder's receive time: the loop runs in real time)
    st = np.array(sorted(s for s, _, _ in status if s <= active[0]))
    rate = (len(st) - 1) / ((st[-1] - st[0]) * 1e-9)
    assert rate >= 240.0, rate
    stop_log = min(t for st_, m, t in stops if m.active)
    lt = np.array(sorted(t for s, _, t in status if s <= active[0] and t <= stop_log))
    log_rate = (len(lt) - 1) / ((lt[-1] - lt[0]) * 1e-9)
    assert log_rate >= 240.0, log_rate
    # the monitor's verdicts equal `reachset check` on the same bag (after the first k*+history
    # ticks, whose test cases started before the recording did)
    model = res["monitor_model"]
    chk = subprocess.run([sys.executable, "-m", "reachset_ros.cli", "check", str(record), "--model", model, "--json"],
                         capture_output=True, text=True, timeout=300)
    assert chk.returncode == 0, chk.stderr
    chk = json.loads(chk.stdout)
    first_check = min((j["first_violation_ns"] for j in chk["joints"].values() if j["first_violation_ns"]),
                      default=None)
    first_monitor = min((s for s, m, _ in status if not m.conformant), default=None)
    assert first_check == first_monitor
    assert Path(res["workdir"]).is_dir()
