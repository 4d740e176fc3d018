"""Issue 17: the fault campaign, short mode (about 3 min), and its schedule and score.

The short campaign is ``benchmarks/fault_campaign.py --short``: the whole simulated system
over real DDS, two training recordings, the monitor's model identified from them with the
inflation calibrated by cross-validation, then 10 events of a seeded schedule (simulator
faults, killed and frozen processes, stamp jumps, a fault-free stretch), each preceded by
fault-free monitored running. Asserted from the campaign's own JSON: 0 missed stops, 0
false stops, every stop followed by the controller's braking within one tick of the stop's
arrival (a killed controller excepted: the drives' watchdog brakes), and every stop's effect
judged from the recorded bag: the arm at rest. The long campaign and its numbers:
docs/reliability.md, "Fault campaign" (no timed assertion here)."""
import json
import sys
from pathlib import Path

import numpy as np
import pytest

from reachset_ros.sim import campaign as cp

ROOT = Path(__file__).resolve().parents[2]


def write_references(path, names, stamps, velocity):
    """A bag of ``/reference`` samples stamped ``stamps`` (ns) with joint velocities ``velocity``
    (one row per sample), positions and accelerations 0: what the score reads of a frozen
    sensor's joint."""
    from reachset_ros import bags
    JR = bags.typestore().types[bags.REFERENCE_TYPE]
    zero = np.zeros(len(names))
    with bags.BagWriter(path) as w:
        for t, v in zip(stamps.tolist(), np.asarray(velocity, dtype=np.float64)):
            w.write(bags.REFERENCE_TOPIC, JR(header=bags.header(t), name=list(names), position=zero,
                                             velocity=v.copy(), acceleration=zero), t, bags.REFERENCE_TYPE)


def test_schedule_is_seeded_and_covers_every_kind():
    a, b = cp.schedule(3, 64), cp.schedule(3, 64)
    assert a == b and a != cp.schedule(4, 64)
    kinds = {e.kind for e in a}
    assert kinds == {"sim", "kill", "freeze", "stamp_jump", "link", "quiet"}
    assert all(e.expect == "stop" for e in a if e.kind in ("sim", "kill", "stamp_jump"))
    # link faults: a heavy loss must stop (coverage), a sparse loss and a delay must not
    links = {e.fault: e for e in a if e.kind == "link"}
    assert set(links) == {"loss", "sparse", "delay"}
    assert links["loss"].expect == "stop" and links["loss"].magnitude == cp.LOSS_SHARE
    assert links["sparse"].expect == "none" and links["sparse"].magnitude == cp.SPARSE_EVERY
    assert links["delay"].expect == "none" and cp.DELAY_S[0] <= links["delay"].magnitude <= cp.DELAY_S[1]
    freezes = [e for e in a if e.kind == "freeze"]
    assert all(0.05 <= e.seconds <= 0.5 for e in freezes)
    assert all((e.expect == "none") == (e.seconds < cp.FREEZE_TOLERATED_S) for e in freezes)
    on = [e.burners for e in a]
    assert 0.4 <= np.mean(on) <= 0.6 and on[:8] == [True] * 8 and on[8:16] == [False] * 8
    # the simulator faults: every kind on every joint, each once before any repeats
    many = [e for e in cp.schedule(0, 400) if e.kind == "sim"]
    first = {(e.fault, e.joint) for e in many[:len(cp.SIM_FAULTS)]}
    assert first == {(f, j) for f, j, _ in cp.SIM_FAULTS}
    with pytest.raises(ValueError, match="unknown event kinds"):
        cp.schedule(0, 4, kinds=["meteor"])


def test_score_counts_misses_false_stops_and_latency():
    ev = cp.schedule(1, 8)
    stop = [e for e in ev if e.expect == "stop"]
    none = [e for e in ev if e.expect == "none"]
    out = [cp.Outcome(stop[0], fault_ns=1000, stops=[(1000 + 8_000_000, 1000 + 12_000_000, "violation")],
                      braking_ticks=1.0, quiet_sim_s=30.0),
           cp.Outcome(stop[1], fault_ns=5000, quiet_sim_s=30.0),                              # missed
           cp.Outcome(none[0], fault_ns=0, stops=[(7, 8, "missing_data")], quiet_sim_s=30.0),  # false
           cp.Outcome(none[0], quiet_stops=[(1, 2, "violation")], quiet_sim_s=30.0),          # false
           cp.Outcome(cp.Event(9, "sim", 1.0, "stop", fault="frozen", joint="a"), fault_ns=100,
                      note="unobservable: the joint's reference did not move")]                # not scored
    s = cp.score(out)
    assert (s["faults_injected"], s["stops"], s["missed_stops"], s["false_stops"]) == (2, 1, 1, 2)
    assert s["latency_ms"]["max"] == pytest.approx(12.0) and s["stamp_latency_ms"]["max"] == pytest.approx(8.0)
    assert s["fault_free_minutes"] == pytest.approx(2.0)
    assert s["misses"][0]["event"] == stop[1].label() and len(s["unobservable"]) == 1
    # a frozen sensor's latency counts from its joint's first motion after the fault
    fr = cp.Outcome(cp.Event(9, "sim", 1.0, "stop", fault="frozen", joint="a"), fault_ns=0,
                    observable_ns=500_000_000, stops=[(520_000_000, 524_000_000, "violation")])
    assert cp.score([fr])["latency_ms"]["max"] == pytest.approx(24.0)
    assert cp.score([fr])["detection_ms"]["max"] == pytest.approx(4.0)
    # a stop after the detection window (1 s from the first motion) is a missed stop
    late = cp.Outcome(cp.Event(9, "sim", 1.0, "stop", fault="frozen", joint="a"), fault_ns=0,
                      observable_ns=500_000_000, stops=[(1_700_000_000, 1_780_000_000, "violation")])
    sl = cp.score([late, fr])
    assert (sl["stops"], sl["missed_stops"]) == (1, 1) and "after the 1 s window" in sl["misses"][0]["note"]
    assert sl["latency_ms"]["n"] == 2 and sl["latency_ms"]["max"] == pytest.approx(1280.0)
    # a stamp jump's stop carries the jumped-back stamp: detection counts from the fault's
    jump = cp.Outcome(cp.Event(10, "stamp_jump", 1.0, "stop", seconds=0.3), fault_ns=1_000_000_000,
                      stops=[(700_000_000, 1_004_000_000, "stamp_backwards")])
    assert cp.score([jump])["detection_ms"]["max"] == pytest.approx(4.0)
    # split by the CPU burners
    hot = cp.Outcome(cp.Event(11, "sim", 1.0, "stop", fault="bias", joint="a", burners=True), fault_ns=0,
                     stops=[(0, 30_000_000, "violation")])
    sb = cp.score([hot, jump])
    assert (sb["detection_ms_burners"]["max"], sb["detection_ms_quiet"]["max"]) == pytest.approx((30.0, 4.0))
    assert sb["detection_ms_burners"]["n"] == sb["detection_ms_quiet"]["n"] == 1
    assert "with the CPU burners on / off" in cp.table(sb)
    assert s["detection_ms"]["max"] == pytest.approx(4.0)
    assert s["stamp_latency_ms_by_kind"] and "detection and delivery" in cp.table(s)
    text = cp.table(s)
    assert "missed: " + stop[1].label() in text and text.count("false stop:") == 2


def test_judge_rest_from_samples():
    ev = cp.Event(0, "sim", 1.0, "stop", fault="frozen", joint="b")
    t = np.arange(0, 400) * 4_000_000
    q = np.zeros((400, 2))
    qd = np.zeros((400, 2))
    qd[:50, 0] = 0.5                  # joint a moves for 0.2 s after the stop, then rests
    q[:50, 0] = np.arange(50) * 0.002
    q[50:, 0] = q[49, 0]
    qd[:, 1] = 0.3                    # the frozen sensor of b shows motion: not judged
    r = cp.judge_rest(ev, ["a", "b"], t, q, qd, 0, int(t[-1]))
    assert r["ok"] and r["judged"] == 1 and r["rest_s"] == pytest.approx(0.2)
    qd[:200, 0] = 0.5                 # still moving 0.8 s after the stop: not within REST_WITHIN_S
    r = cp.judge_rest(cp.Event(0, "kill", 1.0, "stop", target="observer_node"), ["a", "b"], t, q, qd, 0, int(t[-1]))
    assert not r["ok"] and r["judged"] == 2


@pytest.mark.dds
def test_short_fault_campaign_every_fault_stops_the_arm_and_nothing_else_does(tmp_path):
    from helpers import run_or_explain
    # about 3 minutes; a hang (CI once waited out 1200 s after the first event) fails with the
    # stacks of the runner and of every node and the nodes' logs (helpers.run_or_explain)
    p = run_or_explain([sys.executable, str(ROOT / "benchmarks" / "fault_campaign.py"), "--short",
                        "--workdir", str(tmp_path)], timeout=900, workdir=tmp_path)
    print(p.stdout)
    print(p.stderr[-6000:])
    res = json.loads((tmp_path / "campaign.json").read_text())
    s = res["score"]
    kinds = {o["event"].split()[0] for o in res["outcomes"]}
    assert {"sim", "kill", "freeze", "stamp", "link"} <= kinds
    assert s["faults_injected"] >= 7
    assert s["missed_stops"] == 0, s["misses"]
    assert s["false_stops"] == 0, s["false"]
    assert s["stops"] == s["faults_injected"]
    # braking: the controller's first braking command at most one tick after the newest
    # estimate it had when the stop arrived; every stop but a killed process'
    assert s["unbraked"] == [] and s["braking_ticks_max"] <= 1.0
    # a killed process: its braking is reported, not asserted (after a SIGKILL Fast DDS can
    # block the controller's sends for seconds, docs/reliability.md "Fault campaign")
    # the effect: every judged stop left the arm at rest, read from the recorded bags
    assert s["rest_judged"] >= s["stops"] - sum(1 for o in res["outcomes"] if o["event"] == "kill sim_node")
    assert s["not_at_rest"] == [], s["not_at_rest"]
    # the safety evidence sheet (issue 35.6) beside it, consistent with the score
    ev = json.loads((tmp_path / "evidence.json").read_text())
    assert f"evidence: {tmp_path / 'evidence.json'}" in p.stdout and (tmp_path / "evidence.html").is_file()
    assert {k: ev["score"][k] for k in ("faults_injected", "stops", "missed_stops", "false_stops")} == \
        {k: s[k] for k in ("faults_injected", "stops", "missed_stops", "false_stops")}
    assert sum(c["n"] for c in ev["detection"].values()) == s["faults_injected"]
    assert sum(c["stopped"] for c in ev["detection"].values()) == s["stops"]
    assert ev["miss_upper_bound"] == pytest.approx(1 - 0.05 ** (1 / s["faults_injected"]))
    assert ev["false_stops"]["false_stops"] == 0 and ev["stops"]["alarms"] == 0
    # the report of its bags against its model (issue 36.4), its path printed
    page = tmp_path / "report.html"
    assert f"report: {page}" in p.stdout and "<section id='joint-arm_1_joint'" in page.read_text()
    assert ev["response"]["detect_ms"]["n"] == s["stamp_latency_ms"]["n"]
    assert p.returncode == 0


def test_a_frozen_sensor_stopped_before_its_joint_moved_is_not_late(tmp_path):
    """A frozen sensor's window starts at the first reference motion of its joint above
    FROZEN_MOTION; one stopped (by the sets) during a slower move, 1.5 s after the fault, is
    marked from the bag's /reference (``frozen_before_motion``) and counted as a stop, not as
    a late one (the runner had used the fault's stamp: a miss); the same stop after a fast
    move is late. Its latency from the fault is still reported."""
    from reachset_ros.workflows.campaign import frozen_before_motion
    T0, DT = 10**18, 4_000_000
    out = {}
    for case, speed in (("slow", 0.03), ("fast", 0.3)):
        path = tmp_path / case
        write_references(path, ["a", "b"], T0 + DT * np.arange(600), np.tile([speed, 0.5], (600, 1)))
        ev = cp.Event(9, "sim", 1.0, "stop", fault="frozen", joint="a")
        stop = T0 + 1_500_000_000
        o = cp.Outcome(ev, fault_ns=T0 + 4 * DT, observable_ns=T0 + 4 * DT, stops=[(stop, stop + DT, "violation")],
                       bag=str(path))
        frozen_before_motion([o])
        out[case] = (o.stopped_before_motion, cp.score([o]))
    (slow, s_slow), (fast, s_fast) = out["slow"], out["fast"]
    assert slow and not fast
    assert (s_slow["stops"], s_slow["missed_stops"]) == (1, 0) and len(s_slow["stopped_before_motion"]) == 1
    assert s_slow["stopped_before_motion"][0]["latency_ms"] == pytest.approx(1488.0)
    assert (s_fast["stops"], s_fast["missed_stops"]) == (0, 1)
    assert "stopped before their joint moved" in cp.table(s_slow)


def test_a_link_loss_counts_from_its_first_lost_sample(tmp_path):
    """The runner's fault_ns of a link loss is when it asked the relay (a service call that
    takes ticks); the latency counts from the first sample the link lost, read from the bag:
    the first /joint_states stamp without a /conformance/status."""
    from reachset_ros import bags
    from reachset_ros.workflows.campaign import link_onsets
    T0, DT = 10**18, 4_000_000
    CS = bags.typestore().types[bags.STATUS_TYPE]
    path = tmp_path / "block"
    first_lost = 12
    with bags.BagWriter(path) as w:
        for k in range(40):
            t = T0 + k * DT
            w.write(bags.JOINT_STATES, bags.joint_state(t, ["a"], [0.0]), t + 1)
            if k < first_lost or k % 2:       # from tick 12 on, every other sample lost
                w.write(bags.STATUS_TOPIC, CS(header=bags.header(t), conformant=True, safe_stop_active=False, tick=k,
                                              horizon=3, active_test_cases=1, name=["a"], margin=np.zeros(1),
                                              deviation=np.zeros(1), tightest_step=np.zeros(1, np.int32),
                                              check_duration=0.0, model_id="m", set_use=np.zeros(1)), t + 2,
                                              bags.STATUS_TYPE)
    ev = cp.Event(3, "link", 1.0, "stop", fault="loss", magnitude=0.5)
    stop = T0 + 16 * DT
    o = cp.Outcome(ev, fault_ns=T0 + 4 * DT, stops=[(stop, stop + DT, "coverage")], bag=str(path))
    assert o.latency_ns() == 13 * DT
    link_onsets([o])
    assert o.observable_ns == T0 + first_lost * DT
    assert o.latency_ns() == 5 * DT
    # no loss between the injection and the stop in the bag: the runner's stamp stays
    o2 = cp.Outcome(ev, fault_ns=T0 + 4 * DT, stops=[(T0 + 8 * DT, T0 + 9 * DT, "coverage")], bag=str(path))
    link_onsets([o2])
    assert o2.observable_ns == 0 and o2.latency_ns() == 5 * DT


def test_a_stop_the_runner_did_not_wait_for_is_read_from_the_bag(tmp_path):
    """The seventh long run: a frozen sensor's joint first moved 8.5 s after the fault, the
    stuck-sensor rule stopped 20 ms later, but the runner's wall-time guard had started with
    the event and had lapsed during the wait for motion, so it recorded a miss. ``bag_stops``
    (run by ``--rescore``) takes the first active /safe_stop of the bag inside the event's
    window; a stop after the window stays a miss."""
    from reachset_ros import bags
    from reachset_ros.workflows.campaign import bag_stops
    T0, DT = 10**18, 4_000_000
    SS = bags.typestore().types[bags.SAFE_STOP_TYPE]
    ev = cp.Event(42, "sim", 1.0, "stop", fault="frozen", joint="a")
    observable = T0 + 2125 * DT                       # 8.5 s after the fault

    def outcome(stop_tick):
        path = tmp_path / f"block{stop_tick}"
        with bags.BagWriter(path) as w:
            for k, active in ((0, False), (stop_tick, True), (stop_tick + 1, True)):
                t = T0 + k * DT
                w.write(bags.SAFE_STOP_TOPIC, SS(header=bags.header(t), active=active, reason="stuck sensor",
                                                 kind="invalid_sample" if active else "reset", joint="a", step=-1,
                                                 test_case_start_ns=0, deviation=0.0, bound=0.0, window_bag=""),
                        t + 1, bags.SAFE_STOP_TYPE)
        return cp.Outcome(ev, fault_ns=T0, observable_ns=observable, bag=str(path),
                          note="no stop within the detection window")

    inside, late = outcome(2130), outcome(2125 + 300)     # 20 ms and 1.2 s after the motion
    bag_stops([inside, late])
    assert inside.stops == [(T0 + 2130 * DT, T0 + 2130 * DT, "invalid_sample: stuck sensor")]
    assert inside.latency_ns() == 5 * DT and "read from the bag" in inside.note
    assert late.stops == [] and late.note == "no stop within the detection window"
    s = cp.score([inside, late])
    assert (s["stops"], s["missed_stops"]) == (1, 1)


def test_the_stops_arrival_at_the_controller_is_read_from_the_bags_brake_commands(tmp_path):
    """The seventh long run's one delivery of 184 ms was the campaign's listener (a
    normal-priority process beside the burners) receiving late: the controller had the stop
    4 ms after the fault and braked from the next measurement (block038's /brake_command).
    ``bag_brakes`` takes the stop's arrival at the controller from the bag: the first
    braking measurement at or after the stop's stamp, up to the reset; a killed controller's
    (its restarted successor's first command) is not taken. ``score`` reports it apart from
    the listener's arrival."""
    from reachset_ros import bags
    from reachset_ros.workflows.campaign import bag_brakes
    T0, DT = 10**18, 4_000_000
    BC = bags.typestore().types[bags.messages.BRAKE_TYPE]
    path = tmp_path / "block038"
    # an earlier stop (braking since T0 - 40 ticks, before this event), tracking, then this
    # stop: received with the estimate of T0 + 1 tick, braking from T0 + 2 ticks
    with bags.BagWriter(path) as w:
        for k, since, received in ((-45, T0 - 40 * DT, T0 - 41 * DT), (-1, 0, 0), (0, 0, 0),
                                   (2, T0 + 2 * DT, T0 + DT), (3, T0 + 2 * DT, T0 + DT)):
            t = T0 + k * DT
            w.write(bags.messages.BRAKE_TOPIC, BC(header=bags.header(t), name=["a"], engage=np.array([False]), reason="",
                                                  braking_since_ns=since, stop_received_ns=received),
                    t + 1, bags.messages.BRAKE_TYPE)
    bias = cp.Event(0, "sim", 1.0, "stop", fault="bias", joint="a", burners=True)
    listener_late = T0 + 46 * DT                                # the listener's arrival: 184 ms
    o = cp.Outcome(bias, fault_ns=T0, stops=[(T0, listener_late, "violation: a")], reset_ns=T0 + 500 * DT,
                   bag=str(path))
    killed = cp.Outcome(cp.Event(1, "kill", 1.0, "stop", target="controller_node"), fault_ns=T0,
                        stops=[(T0, T0 + DT, "missing_data: a")], reset_ns=T0 + 500 * DT, bag=str(path))
    after_reset = cp.Outcome(bias, fault_ns=T0, stops=[(T0, T0 + DT, "violation: a")], reset_ns=T0 + DT,
                             bag=str(path))
    bag_brakes([o, killed, after_reset])
    assert o.controller_ns == T0 + 2 * DT
    assert killed.controller_ns == 0 and after_reset.controller_ns == 0
    s = cp.score([o, killed])
    assert s["latency_ms"]["max"] == 184.0                      # the listener's
    assert s["controller_latency_ms"]["max"] == 8.0 and s["controller_latency_ms"]["n"] == 1
    assert s["controller_detection_ms_burners"]["max"] == 8.0
    assert s["controller_unmeasured"] == []
    assert "arrival at the controller, bias" in cp.table(s)
    s = cp.score([after_reset])
    assert s["controller_unmeasured"] == [after_reset.event.label()]


def test_a_stop_the_controller_acted_on_in_time_is_not_late_however_late_the_listener():
    """The long campaign's event 132 (docs/reliability.md): a frozen sensor's stop stamped 16 ms
    after the fault, the controller braking from 20 ms, the starved listener receiving it at
    1,288 ms. Scored by the listener it was a missed stop; judged by its effect it is in time.
    Without the controller's arrival in the bag the listener's still decides. (A bias here: the
    frozen sensor's own window rules are tested apart.)"""
    T0, MS = 10**18, 1_000_000
    ev = cp.Event(132, "sim", 1.0, "stop", fault="bias", joint="a", burners=True)
    acted = cp.Outcome(ev, fault_ns=T0, stops=[(T0 + 16 * MS, T0 + 1288 * MS, "violation: a")],
                       controller_ns=T0 + 20 * MS)
    assert acted.acted_latency_ns() == 20 * MS
    s = cp.score([acted])
    assert s["missed_stops"] == 0 and s["stops"] == 1
    assert s["latency_ms"]["max"] == 1288.0                     # the listener's, still reported
    unknown = cp.Outcome(ev, fault_ns=T0, stops=[(T0 + 16 * MS, T0 + 1288 * MS, "violation: a")])
    s = cp.score([unknown])
    assert s["missed_stops"] == 1 and "1288 ms after the fault's stamp" in s["misses"][0]["note"]
    slow = cp.Outcome(ev, fault_ns=T0, stops=[(T0 + 16 * MS, T0 + 30 * MS, "violation: a")],
                      controller_ns=T0 + 1500 * MS)            # the listener's arrival is the earlier
    assert slow.acted_latency_ns() == 30 * MS and cp.score([slow])["missed_stops"] == 0


def test_a_frozen_sensor_is_observable_from_motion_the_stuck_sensor_rule_can_use():
    """A freeze that lands on the tail of a move (its joint's reference above FROZEN_MOTION for
    fewer than the stuck-sensor rule's 6 ticks after the fault, then at rest) gives no evidence
    any rule of the monitor can use until the next move: the window opens there, at the first
    run of FROZEN_RUN fast ticks; the run may begin on the tick before the fault (the reading the
    freeze holds). Before: the window opened at the tail's first tick, and a stop by the rule
    at the next move 2.8 s later counted as missed (the long campaign's event 44, session 26).
    The stuck-sensor rule itself cannot fire on the tail and fires at the run's sixth tick."""
    from types import SimpleNamespace
    from reachset_ros.conformance.watches import StuckSensorWatch
    dt = 4_000_000
    t0, fault = 10**18, 10**18 + 100 * dt                 # the freeze holds the reading of tick 99
    move = 800                                            # the next move starts at tick 800 (2.8 s)
    k = np.arange(1200)
    qd = np.where((k >= 60) & (k < 103), 0.3, 0.0)        # a move whose tail runs to tick 102
    qd = np.where(k >= move, 0.2, qd)
    refs = [SimpleNamespace(stamps=t0 + k * dt, qd=qd)]
    assert cp.frozen_observable_ns(refs, fault, run=1) == fault + dt           # the old rule: the tail
    assert cp.frozen_observable_ns(refs, fault) == t0 + move * dt
    # five fast ticks after the fault and the one before it: the rule's six, the window opens
    qd5 = np.where((k >= 60) & (k < 105), 0.3, 0.0)
    assert cp.frozen_observable_ns([SimpleNamespace(stamps=t0 + k * dt, qd=qd5)], fault) == fault + dt
    # a reference lost in the run breaks it (the rule needs each tick's reference)
    gap = k != move + 2
    assert cp.frozen_observable_ns([SimpleNamespace(stamps=(t0 + k * dt)[gap], qd=qd[gap])], fault) == \
        t0 + (move + 3) * dt
    # the stuck-sensor rule on the same references and a reading frozen from the fault on
    w = StuckSensorWatch(["j"], dt)
    fired = None
    for i in range(1200):
        st = t0 + i * dt
        w.add_reference(st, [qd[i]])
        ev = w.update(st, [0.5 if st >= fault - dt else 1e-3 * i])
        if ev is not None:
            fired = st
            break
    assert fired == t0 + (move + 5) * dt                   # the run's sixth tick


@pytest.mark.dds
def test_the_runner_opens_a_frozen_sensors_window_where_the_score_does(ros):
    """The campaign's listener decides online when a frozen sensor's window opens (it waits for
    it, up to FROZEN_WAIT_S), from the references it receives, one message at a time; it asks
    the score's own rule (frozen_observable_ns) on the references since it last looked, and
    answers as the rule does on the whole recording."""
    from reachset_msgs.msg import JointReference
    from reachset_ros.nodes.common import to_stamp
    from reachset_ros.workflows.campaign import CampaignListener
    lis = CampaignListener(ros)
    dt, t0 = 4_000_000, 10**18
    fault = t0 + 100 * dt
    k = np.arange(1000)
    qd = np.where((k >= 60) & (k < 103), 0.3, 0.0)        # a tail of 3 ticks after the fault ...
    qd = np.where((k >= 700) & (k < 720), -0.2, qd)        # ... and the next move
    want = cp.frozen_observable_ns([type("R", (), {"stamps": t0 + k * dt, "qd": qd})], fault)
    assert want == t0 + 700 * dt
    got = None
    for i in range(1000):
        m = JointReference(name=["arm_1_joint", "arm_2_joint"], position=[0.0, 0.0], velocity=[0.0, float(qd[i])],
                           acceleration=[0.0, 0.0])
        to_stamp(m.header.stamp, int(t0 + i * dt))
        lis.on_ref(m)
        if i % 3 == 0 or i > 690:                         # looked at after one or several messages
            seen = lis.observable_ns("arm_2_joint", fault)
            if seen is not None and got is None:
                got = (i, seen)
    assert got == (705, want)                              # known at the run's sixth tick, not at the tail
    assert lis.observable_ns("arm_1_joint", fault) is None


def test_a_rescore_opens_a_frozen_sensors_window_after_a_moves_tail(tmp_path):
    """A run scored with the old window (the first fast reference: a move's tail of 3 ticks after
    the fault), its stop by the stuck-sensor rule 20 ms into the next move 2.8 s later: the bag
    sets the window's start to that move (``frozen_before_motion``), and the stop is in time.
    Before: the window stayed at the tail and the stop counted as missed (event 44)."""
    from reachset_ros.workflows.campaign import frozen_before_motion
    T0, DT = 10**18, 4_000_000
    path = tmp_path / "tail"
    move = 800
    k = np.arange(1000)
    write_references(path, ["a"], T0 + DT * k, np.where(((k >= 60) & (k < 103)) | (k >= move), 0.3, 0.0)[:, None])
    ev = cp.Event(44, "sim", 1.0, "stop", fault="frozen", joint="a")
    fault, stop = T0 + 100 * DT, T0 + (move + 5) * DT
    o = cp.Outcome(ev, fault_ns=fault, observable_ns=fault + DT, stops=[(stop, stop + DT, "invalid_sample")],
                   bag=str(path))
    frozen_before_motion([o])
    assert o.observable_ns == T0 + move * DT and not o.stopped_before_motion
    s = cp.score([o])
    assert (s["stops"], s["missed_stops"]) == (1, 0)
    # stopped by the sets on the tail itself, at the fault's own stamp (no reference between the
    # two): its latency counts from the fault, not from the later window (never negative)
    early = cp.Outcome(ev, fault_ns=fault, observable_ns=fault + DT, stops=[(fault, fault + 2 * DT, "violation")],
                       bag=str(path))
    frozen_before_motion([early])
    assert early.observable_ns == fault and early.latency_ns() == 2 * DT
