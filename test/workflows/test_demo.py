"""`reachset demo` end to end, exactly as the issue's "done when" runs it (3-4 min).

Every node a separate process over Fast DDS, the simulated arm, two synthesis iterations
applied live through the parameter services, a fault injected and caught. The demo runs on
the simulation's time (``/clock``; the recorder writes it as the bag's log time, as
``ros2 bag record --use-sim-time`` does), so the story is the same however loaded the
machine is. Read back from the recorded bag: ``/conformance/status`` for every tick at
>= 240 Hz until the stop, on the message stamps and on the bag's log time; no safe stop
before the fault; the first active ``/safe_stop`` within 100 ms after it; at least 15 of
the 18 s of monitored ticks before the fault in the bag; the monitor's verdicts equal to
``reachset check`` on the same bag. How fast the simulation runs in wall-clock time is a
benchmark (benchmarks/bench_demo.py).
"""
import json
import subprocess
import sys
from pathlib import Path

import numpy as np

from reachset_ros.bags import read_messages
from reachset_ros.conformance import model as mdl
from reachset_ros.commands.demo import rate_hz
import pytest

pytestmark = pytest.mark.dds   # real DDS participants / node processes


def read_status_and_stops(record):
    """``[(stamp_ns, msg, log_time_ns)]`` of /conformance/status and of /safe_stop."""
    status, stops = [], []
    for topic, t, m in read_messages([record], ("/conformance/status", "/safe_stop")):
        st = m.header.stamp.sec * 1_000_000_000 + m.header.stamp.nanosec
        (status if topic == "/conformance/status" else stops).append((st, m, t))
    return status, stops


def test_demo_detects_the_fault_and_agrees_with_check(tmp_path):
    record = tmp_path / "B"
    out = subprocess.run([sys.executable, "-m", "reachset_ros.cli", "demo", "--headless", "--duration", "25",
                          "--inject-fault-at", "18", "--record", str(record),
                          "--workdir", str(tmp_path / "work"), "--json"],
                         capture_output=True, text=True, timeout=900)
    assert out.returncode == 0, out.stderr[-2000:]
    res = json.loads(out.stdout)
    # the last line names the verdict and the summary file (issue 36.6), on stderr beside --json
    last = out.stderr.strip().splitlines()[-1]
    assert last.startswith("reachset demo: PASS") and "summary.json" in last, last
    # the monitored run's report page (issue 36.4), one self-contained file
    page = Path(res["report"]).read_text()
    assert "<section id='joint-arm_1_joint'" in page or 'id="joint-arm_1_joint"' in page, page[:500]
    fault, stop = res["fault_injected_ns"], res["safe_stop_ns"]
    assert fault is not None and stop is not None
    assert res["fault_kind"] == "acceleration"      # what the demo injected, not parsed from a log line
    assert res["failures"] == [] and res["early_stop"] is None
    # the stop held the arm (issue 19.1), judged from the bag: every joint at rest within the
    # stated time and travel (before: joint 1 ran away under the 30 rad/s^2 fault, 486 rad)
    eff = res["stop_effect"]
    assert eff["failures"] == [] and eff["seconds_after_stop"] >= 3.0, eff
    assert all(j["rest_s"] is not None and j["rest_s"] <= eff["rest_within_s"]
               and j["travel_rad"] <= eff["travel_within_rad"] and j["finite"] for j in eff["joints"].values()), eff
    assert eff["brakes_engaged"] and all(eff["brakes_engaged"].values()), eff
    # the gains were synthesised for the inflation the monitor checks: R*_u inside U_p holds for
    # the monitored sets; the inflation is calibrated on the training recordings (issue 16.3;
    # before: a constant 1.0)
    # and calibrated again on the synthesised sets the monitor checks (issue 34.11), recorded in its model
    cal = res["inflation_calibration"]
    ms = cal["monitor_sets"]
    assert cal["folds"] == 2 and ms["calibrated"] == max(ms["per_joint"].values()), cal
    assert res["inflation"] == ms["inflation"] == max(ms["calibrated"], max(cal["per_joint"].values())), cal
    assert ms["rule"] == "synthesis_min_re_norm", cal
    assert res["inflation_is_certified"] is True, res["inflation_certified"]
    assert all(v >= res["inflation"] for v in res["inflation_certified"].values()), res["inflation_certified"]
    # issue 35.1: each joint's own inflation, at least its value calibrated on identify's sets, the
    # model-level value their largest; the monitor's model carries them
    per = res["inflations"]
    assert max(per.values()) == res["inflation"] and all(per[n] >= v for n, v in cal["per_joint"].items()), per
    assert mdl.load(res["monitor_model"]).inflations() == per
    # the guarantee (issue 16.3): omega strictly inside its search box on every joint, every
    # judged tick (after the transient, before the fault) inside R*_e; the default fault (30 rad/s^2
    # on arm_1) within 50 ms, half the promise (detection.within_s)
    g = res["guarantee"]
    assert set(g) == set(res["reidentify"]["joints"])
    for name, j in g.items():
        lo, hi = j["omega_bounds"]
        assert lo < j["omega"] < hi, (name, j)
        assert j["inside_share"] == 1.0 and j["ticks"] > 2000, (name, j)
        assert j["transient_s"] >= 0.0
    assert res["guarantee_failures"] == [] and res["detection_latency_ms"] <= 50.0
    status, stops = read_status_and_stops(record)
    active = sorted(st for st, m, _ in stops if m.active)
    assert active and active[0] >= fault, "no safe stop before the fault"
    assert active[0] == stop
    assert active[0] - fault <= 100_000_000, f"safe stop {(active[0] - fault) / 1e6:.1f} ms after the fault"
    first = next(m for st, m, _ in sorted(stops, key=lambda s: s[0]) if m.active)
    assert first.kind == "violation" and first.joint == "arm_1_joint"     # the faulty joint
    # a status for every tick until the stop: >= 240 Hz, and no tick missing
    st = np.array(sorted(s for s, _, _ in status if s <= active[0]))
    rate = rate_hz(st)
    assert rate >= 240.0, rate
    assert np.all(np.diff(st) == 4_000_000), np.unique(np.diff(st))
    # the fault came 18 s of simulated time into the monitored run (less the first ticks,
    # before the recorder had matched the monitor's publisher: 0.6 s seen on a loaded machine)
    assert (fault - st[0]) * 1e-9 >= 15.0, (fault - st[0]) * 1e-9
    # the bag's log time is the simulation's clock: the same rate there, and each status
    # logged within a few ticks of its stamp (the monitor is not in the loop and may lag)
    log_t = np.array(sorted(t for s, _, t in status if s <= active[0]))
    log_rate = rate_hz(log_t)
    assert log_rate >= 240.0, log_rate
    lag = np.array([t - s for s, _, t in status]) * 1e-9
    assert np.all(lag > -0.1) and np.median(lag) < 0.5, (lag.min(), np.median(lag), lag.max())
    assert res["real_time_factor"] and all(v > 0 for v in res["real_time_factor"].values())
    # the monitor's verdicts equal `reachset check` on the same bag
    chk = subprocess.run([sys.executable, "-m", "reachset_ros.cli", "check", str(record), "--model",
                          res["monitor_model"], "--json"], capture_output=True, text=True, timeout=300)
    assert chk.returncode == 1, chk.stderr          # not conformant (the fault): exit 1, a CI gate
    chk = json.loads(chk.stdout)
    assert not chk["conformant"]
    first_check = min((j["first_violation_ns"] for j in chk["joints"].values() if j["first_violation_ns"]),
                      default=None)
    # a violation is a margin < 0 (a warm-up tick, nothing checked yet, is not conformant but no violation)
    first_monitor = min((s for s, m, _ in status if min(m.margin) < 0), default=None)
    assert first_check == first_monitor == active[0]
    # the summary compares the measured tracking errors with R*_e (not asserted: R*_e bounds
    # the errors once they are inside it, and the monitored run starts 3 s after a live gain
    # change, whose transient a slow synthesised loop may not have finished), plots written
    assert set(res["tracking"]) == set(res["reidentify"]["joints"])
    assert res["plots"] and all(Path(p).is_file() for p in res["plots"])
