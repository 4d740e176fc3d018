"""The node suite over real DDS: separate processes, parameter services, safe stop, watchdog."""
import os
import signal
import time
from types import SimpleNamespace

import numpy as np
import pytest
import rclpy
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from rclpy.node import Node
from reachset_msgs.msg import ConformanceStatus, JointEstimate, JointReference, PlantInput, SafeStop
from sensor_msgs.msg import JointState
from std_srvs.srv import Trigger

from helpers import (JOINTS, NO_VERDICTS, PATIENT_LOOP, PATIENT_REFERENCE, PUB_QOS, Recorder, plant_stream, spin_until,
                     wait_until, write_model)
from reachset_ros import bags
from reachset_ros import conformance as cf
from reachset_ros import processes
from reachset_ros.bags import read_messages
from reachset_ros.conformance import model as mdl
from reachset_ros.conformance.estimators import Estimator
from reachset_ros.errors import ReachsetError
from reachset_ros.nodes.common import MONITOR_STARTED, SAFE_STOP_QOS, TICK_QOS, set_remote_parameters, stamp_ns, to_stamp
from reachset_ros.nodes.controller_node import ControllerNode
from reachset_ros.nodes.gain_params import gains_from
from reachset_ros.systems.closedloop import FeedbackLaw, close_loop, closed_loop_tick, settling_ticks, stability
from reachset_ros.systems.gains import Gains
from reachset_ros.systems.late_reference import extrapolate
from reachset_ros.systems.plant import lwa4p_joint_plant


pytestmark = pytest.mark.dds   # real DDS participants / node processes


def test_controller_gains_through_parameter_service(ros, tmp_path):
    model = write_model(tmp_path / "m.yaml", alpha_w=(0.05, 4.0), alpha_v=(1e-4,))
    ctl = processes.start("controller_node", {"joints": JOINTS, "model_file": str(model), "u_max": [26.0, 26.0],
                                           "omega": [10.0], "zeta": [1.0], "pair_node": ""}, tmp_path)
    got = []
    ros.create_subscription(PlantInput, "plant_input", lambda m: got.append(m), TICK_QOS)
    est_pub = ros.create_publisher(JointEstimate, "observer/estimate", TICK_QOS)
    try:
        def send(k):
            e = JointEstimate(name=JOINTS, position=[0.1, -0.2], velocity=[0.0, 0.0], disturbance=[0.0, 0.0])
            to_stamp(e.header.stamp, 10**18 + k * 4_000_000)
            est_pub.publish(e)

        k = [0]

        def pump_until(cond, timeout=20):
            end = time.monotonic() + timeout
            while time.monotonic() < end:
                k[0] += 1
                send(k[0])
                if spin_until(ros, cond, 0.05):
                    return True
            return False

        # no reference: the controller regulates to the measured position (zero feedback)
        assert pump_until(lambda: len(got) > 0)
        ok, why = set_remote_parameters(ros, "controller_node", {"omega": [12.0, 14.0]})
        assert ok, why
        target = [-(12.0 ** 2) * 0.0, 0.0]
        # with a reference of 0 at the same stamp the law is -omega^2 q
        ref_pub = ros.create_publisher(JointReference, "reference", TICK_QOS)
        got.clear()

        def send_with_ref(kk):
            r = JointReference(name=JOINTS, position=[0.0, 0.0], velocity=[0.0, 0.0], acceleration=[0.0, 0.0])
            to_stamp(r.header.stamp, 10**18 + kk * 4_000_000)
            ref_pub.publish(r)
            time.sleep(0.01)
            send(kk)

        def reached():
            return any(abs(m.acceleration[0] + 144.0 * 0.1) < 1e-9 and abs(m.acceleration[1] - 196.0 * 0.2) < 1e-9
                       for m in got)
        end = time.monotonic() + 20
        while time.monotonic() < end and not reached():
            k[0] += 1
            send_with_ref(k[0])
            spin_until(ros, reached, 0.05)
        assert reached(), [list(m.acceleration) for m in got[-3:]]
        del target
        # an unsafe gain set is refused with its reason, and the running gains stay
        ok, why = set_remote_parameters(ros, "controller_node", {"omega": [60.0]})
        assert not ok and ("unstable" in why or "R_u" in why), why
        ok, why = set_remote_parameters(ros, "controller_node", {"zeta": [float("nan")]})
        assert not ok
        ok, why = set_remote_parameters(ros, "controller_node", {"model_file": str(tmp_path / "missing.yaml")})
        assert not ok and "not found" in why
        got.clear()
        end = time.monotonic() + 10
        while time.monotonic() < end and not reached():
            k[0] += 1
            send_with_ref(k[0])
            spin_until(ros, reached, 0.05)
        assert reached()
    finally:
        processes.stop([ctl])


def test_controller_pairs_estimate_and_reference_by_stamp(ros, tmp_path):
    """The reference may arrive after the estimate of the same stamp (two nodes, two paths):
    the controller waits for it; without one it uses the newest earlier reference, carried
    forward to the estimate's stamp (systems.late_reference).

    ``reference_timeout`` 1 s (its range's top), not 0.2: the wait is timed on the wall clock, so a
    controller process paused for 0.2 s between taking the estimate and taking its reference (its
    first ticks on a loaded machine) took the late path and carried the previous stamp's reference
    forward (a fresh clone's DDS run: 25.1608 for 25)."""
    ctl = processes.start("controller_node", {"joints": JOINTS, "u_max": [26.0, 26.0], "omega": [10.0], "zeta": [1.0],
                                           "reference_timeout": 1.0, "allow_uncertified": True}, tmp_path)
    got = {}
    ros.create_subscription(PlantInput, "plant_input", lambda m: got.setdefault(
        m.header.stamp.sec * 10**9 + m.header.stamp.nanosec, list(m.acceleration)), TICK_QOS)
    est_pub = ros.create_publisher(JointEstimate, "observer/estimate", TICK_QOS)
    ref_pub = ros.create_publisher(JointReference, "reference", TICK_QOS)

    def law(q_d, qd_d, qdd_d, q=(0.1, -0.2)):
        return [qdd_d[i] + 100.0 * (q_d[i] - q[i]) + 20.0 * (qd_d[i] - 0.0) for i in range(2)]

    try:
        k, stamp = 0, None
        ref = ([0.3, 0.1], [0.2, -0.1], [1.0, -0.5])
        end = time.monotonic() + 30
        while time.monotonic() < end:
            k += 1
            stamp = 10**18 + k * 4_000_000
            e = JointEstimate(name=JOINTS, position=[0.1, -0.2], velocity=[0.0, 0.0], disturbance=[0.0, 0.0])
            r = JointReference(name=JOINTS, position=ref[0], velocity=ref[1], acceleration=ref[2])
            to_stamp(e.header.stamp, stamp)
            to_stamp(r.header.stamp, stamp)
            est_pub.publish(e)              # the estimate first ...
            spin_until(ros, lambda: False, 0.03)
            ref_pub.publish(r)              # ... its reference 30 ms later
            if spin_until(ros, lambda: stamp in got, 0.3):
                break
        assert stamp in got
        assert got[stamp] == pytest.approx(law(*ref), abs=1e-12)
        # no reference for this stamp: after the timeout the newest earlier one, 4 ms on
        k += 1
        stamp2 = 10**18 + k * 4_000_000
        e = JointEstimate(name=JOINTS, position=[0.1, -0.2], velocity=[0.0, 0.0], disturbance=[0.0, 0.0])
        to_stamp(e.header.stamp, stamp2)
        est_pub.publish(e)
        assert spin_until(ros, lambda: stamp2 in got, 15.0)
        fwd = [list(a) for a in extrapolate(*ref, 0.004)]
        assert fwd[0] != ref[0]
        assert got[stamp2] == pytest.approx(law(*fwd), abs=1e-12)
    finally:
        processes.stop([ctl])


def identified_model(path, horizon=25):
    """A model identified (Theorem 1) on a clean stream, sets doubled (an inflation of 1 built in)."""
    p = lwa4p_joint_plant()
    data = list(plant_stream(3000, seed=11))
    Y = np.array([d[1] for d in data])
    U = np.array([d[2] for d in data])
    thm = cf.Theorem1.build(p, horizon)
    devs = [cf.deviation_extremes(p, Estimator("fd"), Y[:, j], U[:, j], ((0, 3000),), horizon, thm) for j in range(2)]
    sets = cf.identify_sets(p, thm, cf.combine(devs))
    return write_model(path, tuple(2 * sets.alpha_w), tuple(2 * sets.alpha_v), horizon=horizon)


def test_monitor_safe_stop_reset_latch_and_watchdog(ros, tmp_path):
    model = identified_model(tmp_path / "m.yaml")
    # reset_clean_ticks 0: this test exercises the latch (the reset after a stop with no
    # data flowing); the rule that a reset waits for clean data has its own test.
    # max_missing_ticks 125 (0.5 s, the demo's): with 25 (100 ms of wall time) a stall of this
    # test's publishing loop under a loaded fresh-clone `make test` was a missing_data stop
    # before the injected fault (seen once at fa62d87)
    mon = processes.start("monitor_node", {"model_file": str(model), "max_missing_ticks": 125, "reset_clean_ticks": 0,
                                        "window_dir": str(tmp_path / "windows")}, tmp_path)
    status, stops = [], []
    # a listener spun by its own executor thread, so that no status message is missed
    import threading
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.qos import QoSProfile
    listener = Node("test_listener")
    status_sub = listener.create_subscription(ConformanceStatus, "conformance/status", lambda m: status.append(m),
                                              QoSProfile(depth=2000))
    listener.create_subscription(SafeStop, "safe_stop", lambda m: stops.append(m), SAFE_STOP_QOS)
    ex = SingleThreadedExecutor()
    ex.add_node(listener)
    th = threading.Thread(target=ex.spin, daemon=True)
    th.start()
    js_pub = ros.create_publisher(JointState, "joint_states", TICK_QOS)
    pi_pub = ros.create_publisher(PlantInput, "plant_input", TICK_QOS)
    t0 = 10**18

    def publish(k, y, u):
        js = JointState(name=JOINTS, position=[float(v) for v in y])
        to_stamp(js.header.stamp, t0 + k * 4_000_000)
        pi = PlantInput(name=list(reversed(JOINTS)), acceleration=[float(u[1]), float(u[0])])
        pi.header.stamp = js.header.stamp
        js_pub.publish(js)
        pi_pub.publish(pi)
        rclpy.spin_once(ros, timeout_sec=0.0)

    try:
        # every endpoint matched (not merely in the graph, which shows a publisher before the
        # endpoints match: the statuses of the first ticks would be lost, as helpers.Bus.status_matched says)
        end = time.monotonic() + 20
        while time.monotonic() < end and not (js_pub.get_subscription_count() and pi_pub.get_subscription_count()
                                              and status_sub.get_publisher_count()):
            time.sleep(0.05)
        time.sleep(0.5)   # and the other side of each match (the monitor's readers) a moment to settle
        fault_from = 400
        for k, y, u in plant_stream(900, fault_from=fault_from):
            publish(k, y, u)
            time.sleep(0.004)
        # (the start-up stop, kind not_ready, was released after k*+1 checked ticks: issue 34.1)
        assert spin_until(ros, lambda: any(s.active and s.kind != "not_ready" for s in stops), 5.0)
        stop = [s for s in stops if s.active and s.kind != "not_ready"][0]
        assert stop.kind == "violation" and stop.joint in JOINTS and stop.deviation > stop.bound
        stop_ns = stop.header.stamp.sec * 10**9 + stop.header.stamp.nanosec
        assert stop_ns >= t0 + fault_from * 4_000_000, "no safe stop before the fault"
        # status every tick (all ticks processed, the first ones before the fault conformant)
        spin_until(ros, lambda: status and status[-1].tick >= 900, 5.0)
        ticks = [s.tick for s in status]
        # every tick processed by the monitor (tick counter) and its status received, in order
        assert ticks[-1] >= 900 and ticks == list(range(ticks[0], ticks[0] + len(ticks)))
        assert len(status) >= 890
        # (a tick at which nothing was checked yet, the warm-up, is not conformant, and no violation)
        assert all(s.conformant == (s.active_test_cases > 0) and min(s.margin) >= 0 for s in status[:fault_from])
        # the window bag was written
        assert spin_until(ros, lambda: os.path.isdir(stop.window_bag), 10.0), stop.window_bag
        # latched: a late subscriber sees it
        late = []
        sub = ros.create_subscription(SafeStop, "safe_stop", lambda m: late.append(m), SAFE_STOP_QOS)
        assert spin_until(ros, lambda: bool(late), 5.0) and late[-1].active
        ros.destroy_subscription(sub)
        # only the reset service clears it
        cli = ros.create_client(Trigger, "/monitor_node/reset")
        assert cli.wait_for_service(timeout_sec=10)
        fut = cli.call_async(Trigger.Request())
        rclpy.spin_until_future_complete(ros, fut, timeout_sec=10)
        assert fut.result().success
        assert spin_until(ros, lambda: not stops[-1].active, 5.0)
        # stale data trips the watchdog: a few good ticks, then silence
        stops.clear()
        n_before = len(status)
        for k, y, u in plant_stream(50, seed=3):
            publish(2000 + k, y, u)
            time.sleep(0.004)
        assert spin_until(ros, lambda: any(s.active for s in stops), 5.0)
        assert status[n_before].tick == 1          # the tick counter restarts at the reset
        assert [s for s in stops if s.active][0].kind == "missing_data"
    finally:
        processes.stop([mon])
        ex.shutdown()
        listener.destroy_node()


# ------------------------------------------------------------------ closed loop: braking, bag = check
ALL_JOINTS = [f"arm_{i}_joint" for i in range(1, 7)]
INITIAL_GAINS = {"observer": "hg", "controller": "static", "omega": [15.0], "zeta": [1.0], "h1": [15.0],
                 "h2": [30.0], "eps": [0.01]}


def _ns(m):
    return m.header.stamp.sec * 1_000_000_000 + m.header.stamp.nanosec


def test_category_1_stop_holds_the_arm_against_a_fault_beyond_the_input_limits(ros, tmp_path):
    """Issue 19.1 over real DDS, judged from the recorded bag: the simulated arm tracks, a
    30 rad/s^2 disturbance (beyond u_max = 26) is injected on joint 1 and a safe stop is
    published 20 ms (stamp time) later. The controller's category-1 stop engages the holding
    brakes (/brake_command), the simulator's brakes hold: in the bag every joint is at rest
    (|qd| < 0.01 rad/s from then on) within REST_WITHIN_S of the stop, having moved at most
    TRAVEL_WITHIN_RAD, and no sample is NaN. Before: the braking law alone let joint 1 run
    away (13.7 rad/s after 1 s in the demo's bag)."""
    from reachset_msgs.msg import BrakeCommand
    from reachset_ros.bags.messages import BRAKE_TOPIC, JOINT_STATES, SAFE_STOP_TOPIC
    from reachset_ros.sim.safe_stop import REST_WITHIN_S, TRAVEL_WITHIN_RAD
    from reachset_ros.systems.stopping import rest_after_stop
    common = {"joints": ALL_JOINTS, **INITIAL_GAINS, "allow_uncertified": True}   # no model: initial gains
    stop_pub = ros.create_publisher(SafeStop, "safe_stop", SAFE_STOP_QOS)
    stop_pub.publish(SafeStop(active=False, kind="reset", reason="test: no safe stop active"))
    rec = Recorder("cat1_listener", {"joint_states": JointState, "brake_command": BrakeCommand})
    bag = tmp_path / "stop_bag"
    procs = [processes.start("sim_node", {"seed": 3, "realistic": True, **PATIENT_LOOP["sim_node"]}, tmp_path),
             processes.start("reference_node", {"seed": 3}, tmp_path),
             processes.start("observer_node", common, tmp_path),
             # the test's /safe_stop, no monitor: no verdicts (helpers.NO_VERDICTS)
             processes.start("controller_node", dict(common, wait_for_monitor=True, **NO_VERDICTS,
                                                     **PATIENT_LOOP["controller_node"]), tmp_path)]
    recorder = processes.start("recorder_node", {"output": str(bag), "topics": [JOINT_STATES, BRAKE_TOPIC,
                                                                             SAFE_STOP_TOPIC]}, tmp_path)
    try:
        js = rec.msgs["joint_states"]
        assert rec.wait(lambda: len(js) > 250 and max(abs(v) for v in js[-1][1].velocity) > 0.2, 90), \
            [p.log.read_text()[-500:] for p in procs]
        ok, why = set_remote_parameters(ros, "sim_node", {"fault_joint": "arm_1_joint", "fault_magnitude": 30.0,
                                                          "fault": "acceleration"})
        assert ok, why
        t_fault = _ns(js[-1][1])
        stop = SafeStop(active=True, kind="manual", reason="test: category-1 stop")
        to_stamp(stop.header.stamp, t_fault + 20_000_000)
        assert rec.wait(lambda: _ns(js[-1][1]) >= t_fault + 20_000_000, 30)
        stop_pub.publish(stop)
        assert rec.wait(lambda: any(all(m.engage) for _, m in list(rec.msgs["brake_command"])), 60)
        t_all = min(_ns(m) for _, m in list(rec.msgs["brake_command"]) if all(m.engage))
        assert rec.wait(lambda: _ns(js[-1][1]) >= t_all + 2_000_000_000, 60)
    finally:
        processes.stop([recorder])
        processes.stop(procs)
        rec.close()
        ros.destroy_publisher(stop_pub)
    t, q, qd, brakes, stops, braking_since = [], [], [], [], [], []
    for topic, _, m in read_messages([bag], (JOINT_STATES, BRAKE_TOPIC, SAFE_STOP_TOPIC)):
        if topic == JOINT_STATES:
            t.append(_ns(m))
            q.append(m.position)
            qd.append(m.velocity)
        elif topic == BRAKE_TOPIC:
            brakes.append((_ns(m), list(m.engage), m.reason))
            if m.braking_since_ns:
                braking_since.append(int(m.braking_since_ns))
        elif m.active:
            stops.append(_ns(m))
    assert stops, "the stop is not in the bag"
    assert braking_since, "no brake command of the stop in the bag"
    # judged from the stop's stamp, or from the first braking command when the test's stop
    # reached the controller later than its stamp: this test, not a monitor in lockstep with the
    # simulation, publishes the stop, and on a loaded machine the simulated arm runs on until it
    # arrives (under two test workers: arm_1 at rest 0.592 s after the stop's stamp, once)
    t_stop = max(stops[0], min(braking_since))
    order = np.argsort(t)
    rep = rest_after_stop(ALL_JOINTS, np.array(t)[order], np.array(q)[order], np.array(qd)[order], t_stop)
    print(f"braking from {(t_stop - stops[0]) / 1e6:.0f} ms after the stop's stamp; rest after it:", rep.as_dict(),
          "brakes:", [b for b in brakes if any(b[1])][:1])
    assert rep.seconds_after >= 1.5
    assert rep.failures(REST_WITHIN_S, TRAVEL_WITHIN_RAD) == [], rep.as_dict()
    assert brakes and all(brakes[-1][1])
    assert "holding brakes at stamp" in procs[0].log.read_text()


def test_braking_law_brings_the_moving_arm_to_rest_within_the_limits_and_holds_it(ros, tmp_path):
    """Category 2 (``stop_category: 2``, no holding brakes): an active /safe_stop while the
    simulated arm (realistic model error and friction) tracks a moving reference. What controller_node promises (``braking_input``,
    ``hold_position``): from the first braking tick on, u_p = clip(64 (q_hold - q^) -
    16 q^d, +-U_p) with q_hold = q^ + q^d |q^d| / U_p fixed at that tick. Checked from
    /observer/estimate, /plant_input, /effort_commands and /joint_states: every input is
    that law, within U_p; every torque within the Table I limits; 1.5 s (stamp time) after
    braking began the arm is at rest, |qd| <= 0.03 rad/s per joint, and holds: it stays
    within 0.1 rad of q_hold and drifts by at most 30 mrad per joint over the next 2 s.
    (The wrist joint 5 creeps towards its equilibrium q_hold + d/64: the friction the
    controller's model underestimates makes the braking PD overdamped there.)

    On a loaded machine this listener falls behind (seconds were seen with two CPU burners)
    and can lose ticks (the publishers keep 50), so braking is found in the data, not by
    the time this test published the stop: q_hold is read off the last recorded inputs,
    where a joint that is not saturated gives q_hold = q^ + (u + 16 q^d) / 64."""
    from std_msgs.msg import Float64MultiArray
    from reachset_ros.robot import TABLE1_TAU_MAX
    u_max = np.array([26.0, 26.0, 26.0, 26.0, 100.0, 100.0])
    rec = Recorder("braking_listener", {"joint_states": JointState, "plant_input": PlantInput,
                                        "observer/estimate": JointEstimate, "effort_commands": Float64MultiArray})
    common = {"joints": ALL_JOINTS, **INITIAL_GAINS, "allow_uncertified": True}   # no model: initial gains
    # as the monitor does: the stop state latched before the controller starts, which holds
    # the arm until it has it; so once the arm moves, the controller's reader has matched
    # this writer (a writer that has matched the reader is not enough: under load the
    # reader's side of discovery came seconds later)
    stop_pub = ros.create_publisher(SafeStop, "safe_stop", SAFE_STOP_QOS)
    stop_pub.publish(SafeStop(active=False, kind="reset", reason="test: no safe stop active"))
    procs = [processes.start("sim_node", {"seed": 2, "realistic": True, **PATIENT_LOOP["sim_node"]}, tmp_path),
             processes.start("reference_node", {"seed": 2}, tmp_path),
             processes.start("observer_node", common, tmp_path),
             processes.start("controller_node", dict(common, wait_for_monitor=True, stop_category=2, **NO_VERDICTS,
                                                     **PATIENT_LOOP["controller_node"]), tmp_path)]
    try:
        js = rec.msgs["joint_states"]

        def moving():
            return len(js) > 250 and max(abs(v) for v in js[-1][1].velocity) > 0.2
        assert rec.wait(moving, 90), [p.log.read_text()[-500:] for p in procs]
        t_pub = _ns(js[-1][1])
        stop = SafeStop(active=True, kind="manual", reason="test: braking law")
        to_stamp(stop.header.stamp, t_pub)
        wall_pub = time.monotonic()
        stop_pub.publish(stop)

        def braking():
            """(each /plant_input with the estimate it was computed from, by stamp; q_hold;
            the index of the first tick from which on every input is the law with q_hold)"""
            est = {_ns(m): m for _, m in list(rec.msgs["observer/estimate"])}
            ins = sorted((_ns(m), np.array(est[_ns(m)].position), np.array(est[_ns(m)].velocity),
                          np.array(m.acceleration)) for _, m in list(rec.msgs["plant_input"]) if _ns(m) in est)
            if not ins:
                return ins, None, 0
            held = [np.where(np.abs(u) < u_max - 1e-6, q + (u + 16 * qd) / 64, np.nan)
                    for t, q, qd, u in ins if t >= ins[-1][0] - 500_000_000]
            q_hold = np.nanmedian(held, axis=0)
            err = np.array([np.abs(u - np.clip(64 * (q_hold - q) - 16 * qd, -u_max, u_max)).max()
                            for t, q, qd, u in ins])
            first = int(np.flatnonzero(~(err < 1e-9))[-1]) + 1 if np.any(~(err < 1e-9)) else 0
            return ins, q_hold, first

        # until 3.6 s of braking are recorded (this listener can be seconds behind the loop)
        deadline = time.monotonic() + 120
        while True:
            ins, q_hold, first = braking()
            if 0 < first < len(ins) and min(ins[-1][0], _ns(js[-1][1])) >= ins[first][0] + 3_600_000_000:
                break
            assert time.monotonic() < deadline, ("no braking tick, or braking before the stop", first, len(ins))
            time.sleep(1.0)
        assert np.all(np.isfinite(q_hold)), q_hold
        onset = ins[first][0]
        print(f"braking from stamp {(onset - t_pub) / 1e6:+.0f} ms after the stop's, "
              f"{time.monotonic() - wall_pub:.1f} s after it was published")
        assert len(ins) - first > 500 and np.all([np.all(np.abs(u) <= u_max) for *_, u in ins[first:]])
        # (the controller may brake an estimate stamped just before the stop's stamp: it may
        # have been behind)
        assert onset >= t_pub - 1_000_000_000, (onset - t_pub) / 1e6
        # q_hold is the stopping point at the first braked estimate: one after the last
        # tracked one (a late estimate whose reference came later can be braked after it)
        hold_at = [np.abs(q_hold - (q + qd * np.abs(qd) / u_max)).max()
                   for t, q, qd, _ in ins if ins[first - 1][0] < t <= onset + 40_000_000]
        assert min(hold_at) < 1e-9, hold_at
        assert "safe stop active: braking (manual: test: braking law" in procs[3].log.read_text()
        efforts = np.array([m.data for w, m in rec.msgs["effort_commands"] if w > wall_pub + 0.5])
        assert len(efforts) > 100 and np.all(np.abs(efforts) <= TABLE1_TAU_MAX), np.abs(efforts).max(axis=0)
        after = [(t - onset, np.array(m.position), np.array(m.velocity))
                 for t, m in ((_ns(m), m) for _, m in js) if t >= onset]
        v0 = np.abs(after[0][2]).max()
        rest = [(t, p, v) for t, p, v in after if 1_500_000_000 <= t <= 3_500_000_000]
        assert rest[-1][0] - rest[0][0] >= 1_990_000_000
        vmax = np.max([np.abs(v) for _, _, v in rest], axis=0)
        P = np.array([p for _, p, _ in rest])
        drift = P.max(axis=0) - P.min(axis=0)
        off = np.max([np.abs(p - q_hold) for _, p, _ in after], axis=0)
        print(f"braking from |qd| = {v0:.3f} rad/s; after 1.5 s |qd| <= {vmax.round(4).tolist()} rad/s, drift over 2 s "
              f"{(drift * 1e3).round(2).tolist()} mrad, |q - q_hold| <= {(off * 1e3).round(1).tolist()} mrad, "
              f"|tau| <= {np.abs(efforts).max(axis=0).round(1).tolist()} N m")
        assert v0 > 0.1                       # it was moving when braking began
        assert np.all(vmax <= 0.03), vmax
        assert np.all(off <= 0.1), off
        assert np.all(drift <= 0.03), drift
        assert all(p.alive() for p in procs)
    finally:
        processes.stop(procs)
        rec.close()
        ros.destroy_publisher(stop_pub)


def test_monitor_verdicts_on_a_recorded_closed_loop_equal_reachset_check(ros, tmp_path):
    """sim + reference + observer + controller + monitor + recorder as processes; a fault
    injected through sim_node's parameters; the bag recorded. `reachset check` on that bag
    finds its first violation at exactly the stamp of the first non-conformant
    /conformance/status in the bag (the fault comes > k* + history ticks after the
    recording started, so no test case of either began before the recording)."""
    import json
    import subprocess
    import sys
    from std_msgs.msg import Header
    from reachset_ros.workflows.demo import LOCKSTEP_TIMEOUT, MONITOR_TOPICS
    p = lwa4p_joint_plant()
    horizon = 125
    # about 3x the sets identified on 15 s of this closed loop (alpha_w <= 1.9, alpha_v <= 3.6e-4)
    js = {j: mdl.JointSets((6.0, 0.0), (1e-3,), (0.0,) * 5, (0.0,), 0, horizon) for j in ALL_JOINTS}
    model = tmp_path / "model.yaml"
    mdl.save(mdl.ConformanceModel(p, {"kind": "lwa4p_joint", "dt": 0.004}, Estimator("fd"), horizon, js,
                                  input_source=mdl.PLANT_INPUT), model)
    bag = tmp_path / "run"
    rec = Recorder("bagcheck_listener", {"conformance/status": ConformanceStatus, "safe_stop": SafeStop,
                                         "sim/fault_onset": Header})
    common = {"joints": ALL_JOINTS, **INITIAL_GAINS, "allow_uncertified": True}   # no model: initial gains
    procs = [processes.start("recorder_node", {"output": str(bag), "topics": MONITOR_TOPICS}, tmp_path),
             processes.start("monitor_node", {"model_file": str(model), "max_missing_ticks": 125,
                                           "window_dir": str(tmp_path / "windows")}, tmp_path),
             # lockstep timeout 0.3 s (the demo's, default 50 ms): once, in a loaded `make test`, the
             # data left the sets 640 ms before the fault (check and monitor agreed: a real
             # violation); a simulator that holds a stale command, an input the recorded
             # /plant_input does not show, is the known way to that (docs/reliability.md, stall
             # diagnosis) -- not confirmed, the run's logs were gone
             processes.start("sim_node", {"seed": 3, "realistic": True, "lockstep_timeout": LOCKSTEP_TIMEOUT}, tmp_path),
             processes.start("reference_node", {"seed": 3}, tmp_path),
             processes.start("observer_node", common, tmp_path),
             processes.start("controller_node", dict(common, **PATIENT_REFERENCE), tmp_path)]
    try:
        status = rec.msgs["conformance/status"]
        assert rec.wait(lambda: len(status) > 0 and "recorder_node" in ros.get_node_names(), 90), \
            [p.log.read_text()[-800:] for p in procs]
        # the recorder subscribes at start, but on a loaded machine DDS may match its readers
        # seconds later (a CI run recorded one status and no /joint_states): wait until the
        # graph shows its subscriptions on the loop's topics, then count from there
        def recorder_subscribed():
            return all(any(i.node_name == "recorder_node" for i in ros.get_subscriptions_info_by_topic(t))
                       for t in ("/joint_states", "/plant_input", "/conformance/status"))
        assert rec.wait(recorder_subscribed, 60), [p.log.read_text()[-800:] for p in procs]
        t_first = _ns(status[-1][1])
        # > k* + history + 1 ticks of checked, recorded data before the fault
        assert rec.wait(lambda: _ns(status[-1][1]) > t_first + 3_000_000_000, 60)
        ok, why = set_remote_parameters(ros, "sim_node", {"fault_joint": "arm_1_joint", "fault_magnitude": 100.0,
                                                           "fault": "acceleration"})
        assert ok, why
        assert rec.wait(lambda: any(m.active and m.kind != "not_ready" for _, m in rec.msgs["safe_stop"]), 30), \
            [(p.name, p.log.read_text()[-1500:]) for p in procs]
        time.sleep(0.5)
        processes.stop(procs[:1])                      # the recorder closes the bag
        assert procs[0].proc.returncode == 0 and (bag / "metadata.yaml").is_file(), procs[0].log.read_text()
    finally:
        processes.stop(procs)
        rec.close()
    out = subprocess.run([sys.executable, "-m", "reachset_ros.cli", "check", str(bag), "--model", str(model),
                          "--json"], capture_output=True, text=True, timeout=300)
    chk = json.loads(out.stdout)
    assert out.returncode == (0 if chk["conformant"] else 1), out.stderr     # 1: not conformant
    first_check = min((j["first_violation_ns"] for j in chk["joints"].values() if j["first_violation_ns"]),
                      default=None)
    verdicts, stops, onset = [], [], None
    for topic, _t, m in read_messages([bag], ("/conformance/status", "/safe_stop", "/sim/fault_onset")):
        h = m if topic == "/sim/fault_onset" else m.header
        st = h.stamp.sec * 1_000_000_000 + h.stamp.nanosec
        if topic == "/conformance/status":
            verdicts.append((st, min(m.margin) >= 0))     # a violation is a margin < 0 (warm-up: not conformant)
        elif topic == "/safe_stop":
            stops.append((st, bool(m.active), m.kind))
        else:
            onset = st
    first_monitor = min((s for s, ok in verdicts if not ok), default=None)
    active = sorted(s for s, a, kind in stops if a and kind != "not_ready")   # not the start-up stop
    print(f"fault onset {onset}, first violation: monitor {first_monitor}, check {first_check}, "
          f"{(first_monitor - onset) / 1e6 if first_monitor and onset else None} ms after the onset; "
          f"{len(verdicts)} statuses, check: {sum(j['violations'] for j in chk['joints'].values())} violating ticks")
    assert onset is not None and first_monitor is not None
    # no false alarm before the fault (the simulator's log says how many steps held a stale command)
    assert first_monitor >= onset, procs[2].log.read_text()[-600:]
    assert first_check == first_monitor
    assert active and active[0] == first_monitor      # and that tick is the safe stop
    assert not chk["conformant"]
    _assert_status_set_use_is_the_batch_set_use(bag, model, [m for _t, m in status])


def _assert_status_set_use_is_the_batch_set_use(bag, model_path, live):
    """Issue 36.3: /conformance/status.set_use, as recorded in the bag, is the batch side's set use
    (set_use.set_use, ``reachset report``'s) of the same tick to the bit, at every tick at which
    both checked the same test cases (the monitor all k*+1 of them, ``active_test_cases``, and the
    bag's segment long enough: the monitor also checked test cases begun before the recording);
    above 1 exactly at the monitor's violations; the operator's commands (``status``, ``watch``:
    workflows.operator.set_use_of) show the field of the live messages."""
    from reachset_ros.conformance.set_use import set_use
    from reachset_ros.workflows.operator import set_use_of
    m = mdl.load(model_path)
    series, _ = bags.read_joint_series([bag], ALL_JOINTS, m.plant.dt)
    thm = m.theorem1()
    batch = {n: set_use(m.plant, thm, m.estimator, m.checked_xi(n), s.y, s.u, s.segments, m.horizon)
             for n, s in series.items()}
    compared, violated = 0, 0
    for _topic, _t, st in read_messages([bag], ("/conformance/status",)):
        assert list(st.name) == ALL_JOINTS and len(st.set_use) == len(ALL_JOINTS)
        assert (np.asarray(st.set_use) > 1).any() == (min(st.margin) < 0)
        if st.active_test_cases != m.horizon + 1:
            continue
        stamp = bags.header_stamp_ns(st)
        for j, n in enumerate(ALL_JOINTS):
            s = series[n]
            i = int(np.searchsorted(s.stamps, stamp))
            if i == len(s.stamps) or s.stamps[i] != stamp or not any(
                    a + m.estimator.history <= i - m.horizon and i < b for a, b in s.segments):
                continue
            assert np.float64(st.set_use[j]).tobytes() == np.float64(batch[n].use[i]).tobytes(), (stamp, n)
            compared += 1
            violated += bool(st.set_use[j] > 1)
    assert compared > 1000 and violated > 0, (compared, violated)
    for msg in live[-50:]:
        use = np.asarray(msg.set_use)
        assert set_use_of(msg) == {n: (float(u) if np.isfinite(u) else None) for n, u in zip(msg.name, use)}


def test_reference_node_names_by_joint_and_holds(ros, tmp_path):
    """/reference carries the generator's joint names whatever the order (and extra names)
    of /joint_states, the value of each joint at the stamp; ``hold`` set through the
    parameter service freezes it at the end point of the move under way."""
    from reachset_ros.sim.reference import ReferenceGenerator
    from reachset_ros.robot import JOINT_NAMES
    node = processes.start("reference_node", {"seed": 4}, tmp_path)
    got = {}
    ros.create_subscription(JointReference, "reference", lambda m: got.setdefault(
        m.header.stamp.sec * 10**9 + m.header.stamp.nanosec, m), TICK_QOS)
    js_pub = ros.create_publisher(JointState, "joint_states", TICK_QOS)
    names = ["gripper_joint"] + list(reversed(JOINT_NAMES))   # another order, an extra joint first
    t0 = 10**18

    def send(k):
        m = JointState(name=names, position=[0.0] * len(names))
        to_stamp(m.header.stamp, t0 + k * 4_000_000)
        js_pub.publish(m)

    def exchange(k):     # one at a time: a burst could overrun the keep-last-50 queues
        send(k)
        assert spin_until(ros, lambda: t0 + k * 4_000_000 in got, 10.0), k

    try:
        assert spin_until(ros, lambda: (send(0), t0 in got)[1], 30.0)
        gen = ReferenceGenerator(seed=4)
        for k in range(1, 400):
            exchange(k)
        for k in (0, 1, 200, 399):
            m = got[t0 + k * 4_000_000]
            assert list(m.name) == list(JOINT_NAMES)
            q, qd, _ = gen.sample(k * 4_000_000 * 1e-9)
            assert list(m.position) == q.tolist() and list(m.velocity) == qd.tolist()
        ok, why = set_remote_parameters(ros, "reference_node", {"hold": True})
        assert ok, why
        end = gen.current_move(400 * 0.004).t_end
        k_rest = int(np.ceil(end / 0.004)) + 5
        for k in range(400, k_rest + 50):
            exchange(k)
        rest = [got[t0 + k * 4_000_000] for k in range(k_rest, k_rest + 50)]
        assert all(list(m.position) == list(rest[0].position) and not any(m.velocity) for m in rest)
        assert list(rest[0].position) == gen.current_move(400 * 0.004).q1.tolist()
    finally:
        processes.stop([node])


@pytest.mark.parametrize("params, words", [
    ({"omega": [60.0]}, "closed loop unstable"),
    ({"u_max": [float("nan")]}, "u_max must be finite"),
    ({"model_file": "/nonexistent/model.yaml"}, "model file not found"),
])
def test_controller_refuses_to_start_with_a_configuration_it_would_refuse_later(tmp_path, params, words):
    """The start-up parameters pass the same checks as a change through the parameter
    service: else the node exits with status 2 and one line naming the reason, never drives."""
    ctl = processes.start("controller_node", {"joints": JOINTS, "u_max": [26.0, 26.0], "allow_uncertified": True, **params},
                       tmp_path)
    try:
        assert ctl.proc.wait(timeout=60) == 2
    finally:
        processes.stop([ctl])
    lines = [ln for ln in ctl.log.read_text().splitlines() if ln.strip()]
    assert len(lines) == 1, lines
    assert lines[0].startswith("ControllerNode: error: ") and words in lines[0], lines[0]


def test_recorder_on_sim_time_logs_at_the_simulations_clock(ros, tmp_path):
    """sim_node publishes /clock with each measurement; a recorder with use_sim_time writes
    that clock as the log time, and a message that arrived before the first /clock (a
    latched /safe_stop) with the first clock's time, never 0. The simulation runs at about
    a tenth of real time here (each tick waits 40 ms for a command nobody sends), so
    wall-clock log times would be ten times as far apart as the stamps."""
    stop_pub = ros.create_publisher(SafeStop, "safe_stop", SAFE_STOP_QOS)
    stop_pub.publish(SafeStop(active=False, kind="reset", reason="latched before the simulation"))
    bag = tmp_path / "simtime"
    rec = processes.start("recorder_node", {"output": str(bag), "topics": ["/joint_states", "/safe_stop"],
                                         "use_sim_time": True}, tmp_path)
    sim = None
    try:
        assert spin_until(ros, lambda: stop_pub.get_subscription_count() > 0, 60), rec.log.read_text()[-800:]
        time.sleep(0.5)                              # the latched message is delivered, no /clock yet
        t_launch = time.time_ns()                    # the simulation's stamps start later than this
        sim = processes.start("sim_node", {"realistic": False, "lockstep_timeout": 0.04}, tmp_path)
        got = []
        sub = ros.create_subscription(JointState, "joint_states", got.append, TICK_QOS)
        # 120 ticks (about 5 s here): a loaded CI run once had the recorder match the
        # simulator 1.3 s after this test did, so it saw only 28 of 61 ticks
        assert spin_until(ros, lambda: len(got) > 120, 90), sim.log.read_text()[-800:]
        ros.destroy_subscription(sub)
        processes.stop([sim])
        time.sleep(2.0)                              # the recorder works off what it has received
        processes.stop([rec])
        assert rec.proc.returncode == 0, rec.log.read_text()[-800:]
    finally:
        processes.stop([rec] + ([sim] if sim else []))
        ros.destroy_publisher(stop_pub)
    js, stops = [], []
    for topic, t, m in read_messages([bag]):
        (js if topic == "/joint_states" else stops).append((_ns(m), t))
    js.sort()
    # (the recorder may discover the simulator a little later than this test does)
    assert len(stops) == 1 and len(js) >= 30, (len(stops), len(js), len(got), _ns(got[0]), _ns(got[-1]),
                                               js[0][0] if js else None, js[-1][0] if js else None)
    stamp = np.array([s for s, _ in js])
    log = np.array([t for _, t in js])
    lag = log - stamp
    print("log time - stamp, ms: min, median, max", lag.min() / 1e6, np.median(lag) / 1e6, lag.max() / 1e6)
    # on the simulation's clock: never before the stamp but for the tick whose /clock is on
    # its way, and a recorder's delay of a few hundred ms is a few ticks of this clock
    assert np.all((lag >= -4_000_000) & (lag <= 100_000_000)), (lag.min(), lag.max())
    assert (log[-1] - log[0]) <= 1.5 * (stamp[-1] - stamp[0]) + 100_000_000
    # the latched stop, received >= 0.5 s before the launch, is logged at the first /clock
    assert t_launch <= stops[0][1] <= stamp[0] + 8_000_000, (t_launch, stops[0][1], stamp[0])


def test_parameter_request_left_unanswered_is_sent_again(ros):
    """get/set_remote_parameters send an unanswered request again after RESEND_AFTER s (a
    freshly started node's answer can be lost while DDS still matches the caller's reply
    reader); the first answer that comes is used."""
    import threading
    from rcl_interfaces.msg import ParameterValue
    from rcl_interfaces.srv import GetParameters
    from rclpy.executors import SingleThreadedExecutor
    from reachset_ros.nodes.common import RESEND_AFTER, get_remote_parameters
    requests = []

    def answer(request, response):
        requests.append(time.monotonic())
        if len(requests) == 1:
            time.sleep(RESEND_AFTER + 1.0)       # the first answer comes too late
        response.values = [ParameterValue(type=3, double_value=7.5)]   # PARAMETER_DOUBLE
        return response

    server = Node("slow_parameter_server", start_parameter_services=False)
    server.create_service(GetParameters, "/slow_parameter_server/get_parameters", answer)
    ex = SingleThreadedExecutor()
    ex.add_node(server)
    threading.Thread(target=ex.spin, daemon=True).start()
    try:
        t0 = time.monotonic()
        values, why = get_remote_parameters(ros, "slow_parameter_server", ["x"], timeout=20.0)
        assert values == {"x": 7.5}, why
        # the server's one thread takes the resent request only after its late first answer is
        # out, so the caller can hold that answer before the server has logged the second
        # request (a fresh clone under load: one request logged when this was asserted at once)
        assert wait_until(lambda: len(requests) == 2, 15.0), requests
        assert requests[1] - requests[0] >= RESEND_AFTER, requests
        assert time.monotonic() - t0 < 20.0
    finally:
        ex.shutdown()
        server.destroy_node()


# ------------------------------------------------------------------ the deployed loop is the certified loop (issue 14)
#: every observer/controller kind the nodes run, with both plant inputs of the ESO
LOOP_KINDS = [
    {"observer": "hg", "controller": "static", "eso_input": "previous"},
    {"observer": "eso", "controller": "static", "eso_input": "previous"},
    {"observer": "eso", "controller": "static", "eso_input": "current"},
    {"observer": "eso", "controller": "compensated", "eso_input": "previous"},
    {"observer": "eso", "controller": "compensated", "eso_input": "current"},
]
#: different gains per joint (Table III's ESO rows), all stable in every kind
LOOP_GAINS = {"omega": [12.0, 14.0, 16.0, 18.0, 20.0, 22.0], "zeta": [1.0, 0.9, 1.1, 1.0, 0.8, 1.0],
              "h1": [15.0], "h2": [30.0], "l1": [57.1, 93.5, 75.6, 80.5, 57.1, 57.1],
              "l2": [103.3, 182.0, 113.7, 153.4, 103.3, 103.3], "l3": [18.1, 37.9, 16.5, 30.1, 18.1, 18.1],
              "eps": [0.01]}


def core_tick(loops, states, y, q_d, qd_d, qdd_d):
    """The certified loop's tick per joint (closed_loop_tick): (x0, u) per joint; advances ``states``."""
    out = {}
    for i, (j, (obs, ctrl)) in enumerate(loops.items()):
        st = states[j]
        x0 = st.partial_estimate([y[i]])
        x_ref = np.array([{"q": q_d[i], "qd": qd_d[i]}.get(n, 0.0) for n in obs.estimate_names])
        u, _, states[j] = closed_loop_tick(st, ctrl, [y[i]], x_ref, qdd_d[i])
        out[j] = (dict(zip(obs.estimate_names, x0)), u[0])
    return out


def test_node_parameters_and_law_are_the_certified_ones():
    """The nodes' parameters become the one Gains type with eso_input, and the controller's
    law (ControllerNode.law_input) is the core's FeedbackLaw: bit-equal to closed_loop_tick,
    including the algebraic loop of the ESO fed u_p[k] (which the hand-written law lacked)."""
    rng = np.random.default_rng(5)
    for kind in LOOP_KINDS:
        gains = gains_from({**kind, **LOOP_GAINS}, ALL_JOINTS)
        for i, j in enumerate(ALL_JOINTS):
            assert gains[j] == Gains(**kind, **{k: (v[i] if len(v) > 1 else v[0]) for k, v in LOOP_GAINS.items()})
        loops = {j: g.build(0.004) for j, g in gains.items()}
        if kind["eso_input"] == "current" and kind["observer"] == "eso":
            assert all(np.any(obs.Do_u != 0) for obs, _ in loops.values())
        node = SimpleNamespace(laws={j: FeedbackLaw.of(c, o) for j, (o, c) in loops.items()},
                               slots={j: o.estimate_names for j, (o, c) in loops.items()})
        states = {j: o.start_state(0.1) for j, (o, c) in loops.items()}
        for _ in range(50):
            y, q_d, qd_d, qdd_d = rng.uniform(-1, 1, (4, 6))
            core = core_tick(loops, states, y, q_d, qd_d, qdd_d)
            for i, j in enumerate(ALL_JOINTS):
                x0, u = core[j]
                got = ControllerNode.law_input(node, j, x0["q"], x0["qd"], x0.get("d", 0.0), q_d[i], qd_d[i], qdd_d[i])
                assert got == u, (kind, j)
    # refused: an unknown ESO input; a model whose dt is not the controller's (its loop would differ)
    with pytest.raises(ReachsetError, match="eso_input must be previous or current"):
        gains_from({**LOOP_KINDS[0], "eso_input": "later", **LOOP_GAINS}, ALL_JOINTS)
    ctl = SimpleNamespace(joints=ALL_JOINTS, dt=0.004)
    values = {**LOOP_KINDS[4], **LOOP_GAINS, "u_max": [26.0], "u_ff_bound": 2.0, "allow_uncertified": True}
    cfg = ControllerNode.validate(ctl, values, None)
    assert set(cfg["laws"]) == set(ALL_JOINTS) and all(k > 0 for k in cfg["settling"].values())
    assert cfg["uncertified"] == tuple(ALL_JOINTS)
    with pytest.raises(ReachsetError, match="no model covers these gains"):      # issue 19.4
        ControllerNode.validate(ctl, dict(values, allow_uncertified=False), None)
    with pytest.raises(ReachsetError, match="model's dt 0.002 s differs from the nodes' dt 0.004 s"):
        ControllerNode.validate(ctl, values, SimpleNamespace(plant=lwa4p_joint_plant(dt=0.002), joints={}))


def _latest_controller_diag(rec, cond=lambda kv: True, level=None):
    for _t, arr in reversed(list(rec.msgs["diagnostics"])):
        for st in arr.status:
            if st.name == "reachset_ros: controller" and (level is None or st.level == level):
                kv = {v.key: v.value for v in st.values}
                if cond(kv):
                    return st.level, st.message, kv
    return None


def test_observer_and_controller_nodes_run_the_certified_loop_to_the_bit(ros, tmp_path):
    """observer_node + controller_node over DDS, fed random /joint_states and /reference, for
    every observer/controller kind (both ESO inputs; switched live through the parameter
    services): each tick's published estimate and /plant_input equal the certified closed
    loop's (closed_loop_tick on the Gains' observer and controller) to the bit. Each switch
    starts a transient the controller reports with the closed loop's settling time; a
    reference with |qdd_d| > u_ff_bound is flagged on /diagnostics, and still controlled by the law."""
    params = {"joints": ALL_JOINTS, **LOOP_KINDS[0], **LOOP_GAINS, "allow_uncertified": True}
    obs_p = processes.start("observer_node", params, tmp_path)
    ctl_p = processes.start("controller_node", {**params, "reference_timeout": 1.0, "u_ff_bound": 2.0}, tmp_path)
    rec = Recorder("loop_listener", {"plant_input": PlantInput, "observer/estimate": JointEstimate,
                                     "diagnostics": DiagnosticArray})
    js_pub = ros.create_publisher(JointState, "joint_states", PUB_QOS)
    ref_pub = ros.create_publisher(JointReference, "reference", PUB_QOS)
    t0, dt_ns = 10**18, 4_000_000
    k = [0]

    def by_stamp(topic, t):
        return next((m for _w, m in reversed(list(rec.msgs[topic])) if stamp_ns(m.header.stamp) == t), None)

    def tick(y, q_d, qd_d, qdd_d):
        k[0] += 1
        t = t0 + k[0] * dt_ns
        r = JointReference(name=ALL_JOINTS, position=[float(v) for v in q_d], velocity=[float(v) for v in qd_d],
                           acceleration=[float(v) for v in qdd_d])
        to_stamp(r.header.stamp, t)
        js = JointState(name=ALL_JOINTS, position=[float(v) for v in y])
        to_stamp(js.header.stamp, t)
        ref_pub.publish(r)
        js_pub.publish(js)
        assert wait_until(lambda: by_stamp("plant_input", t) is not None and by_stamp("observer/estimate", t)
                          is not None, 15.0), (k[0], by_stamp("plant_input", t), by_stamp("observer/estimate", t),
                                               ctl_p.log.read_text()[-2000:], obs_p.log.read_text()[-2000:])
        time.sleep(0.03)   # the observer takes the plant input before the next measurement
        return t, by_stamp("observer/estimate", t), by_stamp("plant_input", t)

    try:
        assert wait_until(lambda: js_pub.get_subscription_count() >= 1 and ref_pub.get_subscription_count() >= 1
                          and ros.count_subscribers("/plant_input") >= 2
                          and ros.count_subscribers("/observer/estimate") >= 2
                          and rec.matched("plant_input") and rec.matched("observer/estimate"), 60.0), \
            ctl_p.log.read_text()
        time.sleep(0.5)
        rng = np.random.default_rng(14)
        plant = lwa4p_joint_plant()
        for n_kind, kind in enumerate(LOOP_KINDS):
            if n_kind:   # a live switch, as the synthesis node applies gains
                for node in ("observer_node", "controller_node"):
                    ok, why = set_remote_parameters(ros, node, kind)
                    assert ok, (node, why)
            loops = {j: g.build(0.004) for j, g in gains_from({**kind, **LOOP_GAINS}, ALL_JOINTS).items()}
            states, first = None, None
            for _ in range(25):
                y = rng.uniform(-0.5, 0.5, 6)
                q_d, qd_d, qdd_d = rng.uniform(-0.5, 0.5, 6), rng.uniform(-1, 1, 6), rng.uniform(-2, 2, 6)
                t, est, pi = tick(y, q_d, qd_d, qdd_d)
                first = first or t
                if states is None:   # the observer (re)starts at its first measurement
                    states = {j: o.start_state(y[i]) for i, (j, (o, c)) in enumerate(loops.items())}
                core = core_tick(loops, states, y, q_d, qd_d, qdd_d)
                ei = {n: i for i, n in enumerate(est.name)}
                ui = {n: i for i, n in enumerate(pi.name)}
                for j, (x0, u) in core.items():
                    got = (est.position[ei[j]], est.velocity[ei[j]], est.disturbance[ei[j]], pi.acceleration[ui[j]])
                    want = (x0["q"], x0["qd"], x0.get("d", 0.0), u)
                    assert got == want, (kind, j, t, got, want)
            # the switch (or the start) began a transient: reported with each joint's settling time
            assert wait_until(lambda: _latest_controller_diag(rec, lambda kv: kv.get("transient_start_ns") == str(first))
                              is not None, 5.0), kind
            _lvl, _msg, kv = _latest_controller_diag(rec, lambda kv: kv.get("transient_start_ns") == str(first))
            for j, (o, c) in loops.items():
                n = settling_ticks(stability(close_loop(plant, o, c)).spectral_radius)
                assert kv[f"settling_ticks/{j}"] == str(n) and kv[f"transient_end_ns/{j}"] == str(first + n * dt_ns)
            assert kv["transient_cause"] == ("start-up" if n_kind == 0 else "gain change")
        # a reference outside the class R_u is certified for (|qdd_d| > u_ff_bound = 2): the
        # same law runs, and the tick is flagged on /diagnostics at once (WARN, stamp, joint)
        y, q_d, qd_d = rng.uniform(-0.5, 0.5, (3, 6))
        qdd_d = rng.uniform(-2, 2, 6)
        qdd_d[2] = -3.5
        t, est, pi = tick(y, q_d, qd_d, qdd_d)
        core = core_tick(loops, states, y, q_d, qd_d, qdd_d)
        assert [pi.acceleration[list(pi.name).index(j)] for j in ALL_JOINTS] == [core[j][1] for j in ALL_JOINTS]
        # (the WARN published at once; a later 1 Hz report with the same counters is OK again)
        flagged = lambda: _latest_controller_diag(  # noqa: E731
            rec, lambda kv: kv.get("reference_out_of_class_last_ns") == str(t), DiagnosticStatus.WARN)
        assert wait_until(lambda: flagged() is not None, 5.0), _latest_controller_diag(rec)
        lvl, msg, kv = flagged()
        assert lvl == DiagnosticStatus.WARN, (lvl, msg)
        assert kv["reference_out_of_class"] == "1" and kv["reference_out_of_class_joint"] == ALL_JOINTS[2]
        assert "out of class" in msg and "u_ff_bound" in msg
    finally:
        processes.stop([ctl_p, obs_p])
        rec.close()
        ros.destroy_publisher(js_pub)
        ros.destroy_publisher(ref_pub)


def test_stop_hold_reset_and_tracking_resumes_without_a_new_stop(ros, tmp_path):
    """Issue 19.2 over real DDS, the whole suite (sim, reference, observer, controller,
    monitor with a model identified on the nodes' code path, inflation 1 as the demo): the
    simulated arm halts while the monitor is frozen (the simulator waits for its verdicts); a
    30 rad/s^2 fault beyond u_max stops the arm (the monitor's violation, category-1 brakes);
    the fault is cleared; ``~/reset`` is refused until the monitor has checked clean data to
    the horizon, then clears the stop; the reference restarts from the held position and
    tracking resumes with no new stop for 10 s (stamp time), the joints moving again.
    Before: the reference kept moving while the arm braked, the resume jumped 0.5-3.8 rad and
    a new stop fired 29-53 ms later (5 of 5 tries)."""
    from reachset_ros.sim.recordings import DEFAULT_GAINS, simulate_arm_recordings, write_recordings
    recs = simulate_arm_recordings(40.0, seed=4)
    bag = tmp_path / "train"
    write_recordings(bag, recs)
    model = tmp_path / "model.yaml"
    from reachset_ros import cli
    assert cli.main(["identify", str(bag), "--inflation", "1.0", "--out", str(model)]) == 0
    gains = {k: ([v] if isinstance(v, float) else v) for k, v in DEFAULT_GAINS.items()}
    common = {"joints": ALL_JOINTS, **gains, "allow_uncertified": True}   # the model has no gains
    rec = Recorder("reset_listener", {"joint_states": JointState, "safe_stop": SafeStop,
                                      "conformance/status": ConformanceStatus})
    from reachset_ros.workflows.demo import LOCKSTEP_TIMEOUT
    # lockstep timeout 0.3 s (the demo's; default 50 ms): in CI (and 1 of 10 runs here) a false
    # stop at k = 1 (N y_a twice the bound on arm_1) came before the fault. A step on a stale
    # command, an input /plant_input does not show, is the known way to that; with 50 ms the
    # simulator took one after the start-up in 1 of 18 runs here (those runs' logs kept; the
    # failing runs' logs were gone). On failure the assertion now shows the simulator's lines.
    procs = [processes.start("sim_node", {"seed": 4, "realistic": True, "lockstep_timeout": LOCKSTEP_TIMEOUT}, tmp_path),
             processes.start("reference_node", {"seed": 4}, tmp_path),
             processes.start("observer_node", common, tmp_path),
             processes.start("controller_node", dict(common, wait_for_monitor=True, **PATIENT_REFERENCE), tmp_path),
             processes.start("monitor_node", {"model_file": str(model), "max_missing_ticks": 125,
                                           "window_dir": str(tmp_path / "windows")}, tmp_path)]
    try:
        js, stops, status = rec.msgs["joint_states"], rec.msgs["safe_stop"], rec.msgs["conformance/status"]
        # running and checked to the horizon for 2 s
        assert rec.wait(lambda: sum(1 for _, s in list(status) if s.conformant) > 500, 120), \
            [p.log.read_text()[-800:] for p in procs]
        # issue 34.1: the monitor started with its start-up stop (the controller held the arm at
        # rest, u_p = 0) and released it after k*+1 ticks of the held arm checked conformant
        # (on a loaded machine this listener matched the monitor only after the release: the
        # latched stop state it then received was the release; the monitor's "ready:" log line
        # says the start-up stop held until then)
        assert stops and (stops[0][1].active and stops[0][1].kind == "not_ready" or (
            stops[0][1].reason == MONITOR_STARTED and "ready: " in procs[4].log.read_text())), \
            [m.kind for _, m in stops][:3]
        assert any(not m.active and m.reason == MONITOR_STARTED for _, m in list(stops)), \
            [(m.active, m.kind, m.reason[:120]) for _, m in list(stops)][:6]
        assert not any(m.active and m.kind != "not_ready" for _, m in list(stops)), (
            [m.reason for _, m in stops if m.active and m.kind != "not_ready"][:1], _stale_lines(procs[0]))
        # the simulator waits for the monitor's verdicts (monitor_lockstep_ticks, 5 by default): a
        # monitor frozen for 0.25 s (within the lockstep timeout) halts the simulated arm, which
        # would otherwise run on unchecked (in a slow make test the monitor trailed it by up to
        # 1.3 s of stamp time, and a stop came that much later in the arm's time)
        os.kill(procs[4].proc.pid, signal.SIGSTOP)
        t_frozen = time.monotonic()
        time.sleep(0.25)
        os.kill(procs[4].proc.pid, signal.SIGCONT)
        during = [_ns(m) for t, m in list(js) if t_frozen + 0.1 <= t <= t_frozen + 0.25]
        # judged by receipt here, or by the simulator's own account: on a loaded machine this
        # process received a backlog of earlier states inside the window (54 of them, with three
        # busy loops beside the test), while the simulator logged no step ahead of the monitor
        ahead = [ln for ln in procs[0].log.read_text().splitlines() if "stepped ahead of the monitor" in ln]
        assert len(during) <= 3 or not ahead, (len(during), during[:3], ahead[:2])
        # the reset client is discovered before the fault, so that the first request reaches the
        # monitor right after the stop, with the fault still on (in CI's run at 95d08f1 the
        # client was made after the fault was cleared; its discovery took longer than the k*+1
        # clean ticks, and the first request was granted: a test that needed a quick machine)
        cli_reset = ros.create_client(Trigger, "/monitor_node/reset")
        assert cli_reset.wait_for_service(timeout_sec=10)

        def ask_reset():
            fut = cli_reset.call_async(Trigger.Request())
            rclpy.spin_until_future_complete(ros, fut, timeout_sec=10)
            r = fut.result()
            return bool(r and r.success), (r.message if r else "no answer")

        ok, why = set_remote_parameters(ros, "sim_node", {"fault_joint": "arm_1_joint", "fault_magnitude": 30.0,
                                                          "fault": "acceleration"})
        assert ok, why
        assert rec.wait(lambda: any(m.active and m.kind != "not_ready" for _, m in list(stops)), 30)
        stop = next(m for _, m in list(stops) if m.active and m.kind != "not_ready")
        assert stop.kind == "violation", stop.reason
        first_ok, first_why = ask_reset()                      # right after the stop, the fault still on
        assert not first_ok and "has not cleared" in first_why, first_why
        ok, why = set_remote_parameters(ros, "sim_node", {"fault": "none"})
        assert ok, why
        refused, reset_ok = [first_why], False
        end = time.monotonic() + 60
        while time.monotonic() < end and not reset_ok:
            reset_ok, why = ask_reset()
            if not reset_ok:
                refused.append(why)
                time.sleep(0.3)
        assert reset_ok, refused[-3:]
        assert rec.wait(lambda: not list(stops)[-1][1].active, 10)
        t_reset = _ns(js[-1][1])
        # 10 s of stamp time after the reset
        assert rec.wait(lambda: _ns(js[-1][1]) >= t_reset + 10_000_000_000, 120)
        new = [m for _, m in list(stops) if m.active and _ns(m) > t_reset]
        assert not new, ([m.reason for m in new][:1], _stale_lines(procs[0]))
        after = [m for _, m in list(js) if _ns(m) > t_reset + 3_000_000_000]
        assert max(max(abs(v) for v in m.velocity) for m in after) > 0.1        # tracking moves again
        checked = [s for _, s in list(status) if _ns(s) > t_reset + 1_000_000_000]
        assert checked and all(s.conformant for s in checked if s.active_test_cases == 126)
        assert all(p.alive() for p in procs)
        assert "restarts from the arm's position" in procs[1].log.read_text()
    finally:
        processes.stop(procs)
        rec.close()


def _stale_lines(sim_proc):
    """The simulator's log lines on steps with a stale command (an input the monitor never sees)."""
    return [ln for ln in sim_proc.log.read_text().splitlines() if "stale" in ln or "watchdog" in ln]


def test_controller_never_commands_back_in_stamp(ros):
    """An estimate waiting for its reference when a safe stop begins: the next (braking)
    estimate used to be commanded first and the waiting one 20 ms later, an older stamp on
    /plant_input, which the monitor takes for a clock going back (a stamp_backwards stop seen
    in CI right after a reset). The waiting estimate is now controlled first; a command for
    an older tick than the last one sent is never published."""
    node, commands, _ = _ref_node(reference_timeout=0.02)
    try:
        def est(stamp):
            e = JointEstimate(name=JOINTS, position=[0.1, -0.2], velocity=[0.0, 0.0], disturbance=[0.0, 0.0])
            to_stamp(e.header.stamp, stamp)
            return e
        s1, s2 = 10**18 + 4_000_000, 10**18 + 8_000_000
        node.on_estimate(est(s1))                       # no reference yet: waits
        assert [s for s, _ in commands] == []
        node.on_safe_stop(SafeStop(active=True, kind="manual", reason="test"))
        node.on_estimate(est(s2))                       # braking
        time.sleep(0.03)
        node.on_wait_timer()
        node.on_estimate(est(s1))                       # a late duplicate of an older tick
        sent = [s for s, _ in commands]
        assert sent == [s1, s2], sent
        assert node.counters["stale_estimate"] == 1
    finally:
        node.destroy_node()


def _ref_node(**extra):
    """A controller node (real rclpy) whose callbacks the test calls in a chosen order."""
    from rclpy.parameter import Parameter
    over = {"joints": JOINTS, "u_max": [26.0, 26.0], "omega": [10.0], "zeta": [1.0], "allow_uncertified": True,
            "reference_timeout": 0.0, **extra}
    node = ControllerNode(parameter_overrides=[Parameter(k, value=v) for k, v in over.items()])
    sent, brakes = [], []
    publish, publish_b = node.input_pub.publish, node.brake_pub.publish
    node.input_pub.publish = lambda m: (sent.append((stamp_ns(m.header.stamp), list(m.acceleration))), publish(m))
    node.brake_pub.publish = lambda m: (brakes.append(list(m.engage)), publish_b(m))
    return node, sent, brakes


_S0 = 10**18
_Q0, _V, _A = np.array([0.3, -0.4]), np.array([0.5, -0.3]), np.array([1.2, -0.8])


def _ref_at(i):
    """The reference at tick i: constant acceleration, so carrying it forward is exact."""
    t = 0.004 * i
    m = JointReference(name=JOINTS, position=list(_Q0 + _V * t + 0.5 * _A * t * t), velocity=list(_V + _A * t),
                       acceleration=list(_A))
    to_stamp(m.header.stamp, _S0 + 4_000_000 * i)
    return m


def _est_at(i):
    e = JointEstimate(name=JOINTS, position=[0.31, -0.41], velocity=[0.45, -0.25], disturbance=[0.0, 0.0])
    to_stamp(e.header.stamp, _S0 + 4_000_000 * i)
    return e


def test_late_references_are_carried_forward_not_held(ros):
    """References that come just after their estimates (a backlog, as after the recorder switch
    of the fifth long campaign): each tick is controlled with the newest earlier reference
    carried forward to it. The old rule held the last on-time reference for as long as
    the backlog lasted (136 ticks there: q_d stood still while the reference moved on)."""
    node, sent, _ = _ref_node()
    try:
        node.on_reference(_ref_at(0))
        node.on_estimate(_est_at(0))           # on time
        for i in range(1, 11):
            node.on_estimate(_est_at(i))       # its reference is not here: late
            node.on_reference(_ref_at(i))      # ... and comes after it
        assert [s for s, _ in sent] == [_S0 + 4_000_000 * i for i in range(11)]
        e = _est_at(0)
        for i, (_, u) in enumerate(sent):
            r = _ref_at(i)
            want = [node.law_input(j, e.position[k], e.velocity[k], 0.0, r.position[k], r.velocity[k],
                                   r.acceleration[k]) for k, j in enumerate(JOINTS)]
            np.testing.assert_allclose(u, want, rtol=0, atol=1e-9, err_msg=f"tick {i}")
        assert node.counters["late_reference"] == 10
        assert node.counters["reference_age_max_ns"] == 4_000_000
        assert node.own_stop is None
    finally:
        node.destroy_node()


def test_a_reference_older_than_reference_max_age_is_a_stop_of_the_controllers_own(ros):
    """No reference for longer than reference_max_age (here 0.1 s of stamps): the controller stops on
    its own (every brake), latched until the monitor's reset; up to that age it tracks the
    carried-forward reference. The old rule tracked the held reference for ever."""
    node, sent, brakes = _ref_node(reference_max_age=0.1)
    try:
        node.on_reference(_ref_at(0))
        node.on_estimate(_est_at(0))
        for i in range(1, 26):                 # ages 4 .. 100 ms: tracked
            node.on_estimate(_est_at(i))
        assert node.own_stop is None and not any(any(b) for b in brakes)
        assert node.counters["reference_age_max_ns"] == 100_000_000
        node.on_estimate(_est_at(26))          # 104 ms
        assert node.own_stop is not None and "reference lost" in node.own_stop, node.own_stop
        assert brakes[-1] == [True, True]
        node.on_reference(_ref_at(27))
        node.on_estimate(_est_at(27))          # a reference again: the stop stays latched
        assert node.own_stop is not None and brakes[-1] == [True, True]
        node.on_safe_stop(SafeStop(active=False, kind="reset", reason="reset through ~/reset"))   # the audited reset
        assert node.own_stop is None and node.last_ref is None
        node.on_reference(_ref_at(28))
        node.on_estimate(_est_at(28))          # tracking again, on the new reference
        assert brakes[-1] == [False, False]
        r, e = _ref_at(28), _est_at(28)
        want = [node.law_input(j, e.position[k], e.velocity[k], 0.0, r.position[k], r.velocity[k], r.acceleration[k])
                for k, j in enumerate(JOINTS)]
        np.testing.assert_allclose(sent[-1][1], want, rtol=0, atol=0)
    finally:
        node.destroy_node()


def test_a_backlog_of_estimates_finds_its_own_references(ros):
    """References of 120 ticks (480 ms) arrive before any of their estimates (the observer
    frozen, the references flowing): every estimate is then controlled with the reference of
    its own stamp, none late. The controller kept only the newest 50 references (200 ms):
    the first 70 estimates were late."""
    node, sent, _ = _ref_node()
    try:
        for i in range(120):
            node.on_reference(_ref_at(i))
        for i in range(120):
            node.on_estimate(_est_at(i))
        assert len(sent) == 120
        assert node.counters["late_reference"] == 0 and node.counters["no_reference"] == 0
        assert not node.refs                   # each used, the older dropped
    finally:
        node.destroy_node()
