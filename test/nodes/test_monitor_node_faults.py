"""Bad input, faults and parameter updates at a real ``monitor_node`` process over DDS, fed by a
test node (docs/reliability.md, "Nodes"): a latched ``/safe_stop`` with its reason, or a skip
counted on ``/diagnostics``, each case ending with a check that the node still works.

Stamps increase across the whole test session (:func:`helpers.stamps`): a monitor hearing an
older test's late message must never see a stamp going backwards by accident.
"""
import math
import time

import pytest
import rclpy
import yaml
from diagnostic_msgs.msg import DiagnosticStatus
from reachset_msgs.msg import JointReference, SafeStop

from helpers import DT_NS, HISTORY, JOINTS, stamps, stream, write_model
from reachset_ros.conformance import model as mdl
from reachset_ros.nodes.common import SAFE_STOP_QOS, stamp_ns, to_stamp
from reachset_ros.conformance.monitor_core import MonitorCore


pytestmark = pytest.mark.dds   # real DDS participants / node processes


# ============================================================ real processes over DDS
def warm_up_then_conformant(st, segments=1):
    """Statuses of a clean stream: conformant, except at the first ``HISTORY`` ticks of each
    of its ``segments`` (after a start, reset or gap), where nothing was checked and the
    status says so (not conformant, no test case, tightest step -1, no violation). With
    ``segments=None`` only the rule is checked, not the count."""
    unchecked = [s for s in st if not s.active_test_cases]
    assert all(s.conformant for s in st if s.active_test_cases), "a checked tick not conformant"
    assert all(not s.conformant and set(s.tightest_step) == {-1} and min(s.margin) > 0 for s in unchecked)
    assert segments is None or len(unchecked) == HISTORY * segments, (len(unchecked), segments)
    return True


def corrupt(case, t_bad, t_old, y, u):
    """What to publish for a bad tick: (stamp, names of y, y values, u values)."""
    names, y, u = list(JOINTS), list(y), list(u)
    if case == "nan_y":
        y[1] = math.nan
    elif case == "inf_u":
        u[0] = math.inf
    elif case == "short_positions":
        y = y[:1]
    elif case == "missing_joint":
        names = [JOINTS[0], "gripper_joint"]
    elif case == "unknown_names":
        names = ["a", "b"]
    elif case == "duplicate_name":
        names, y = [JOINTS[0], JOINTS[0], JOINTS[1]], [y[0], y[0], y[1]]
    elif case == "stamp_backwards":
        return t_old, names, y, u
    return t_bad, names, y, u


BAD_CASES = [
    ("nan_y", "invalid_sample", "arm_2_joint", "non-finite"),
    ("inf_u", "invalid_sample", "arm_1_joint", "non-finite"),
    ("short_positions", "invalid_sample", "", "2 names but 1 values"),
    ("missing_joint", "name_mismatch", "arm_2_joint", "lacks joint arm_2_joint"),
    ("unknown_names", "name_mismatch", "arm_1_joint", "lacks joint arm_1_joint"),
    ("duplicate_name", "name_mismatch", "arm_1_joint", "names joint arm_1_joint twice"),
    ("stamp_backwards", "stamp_backwards", "", "/joint_states stamp went backwards"),
]


#: a missing-data limit (ticks, 40 s) that no pause of this test's own Python publisher reaches:
#: for the tests that are not about that limit
GENEROUS_MISSING_TICKS = 10000


class TestMonitorNode:
    """One monitor_node process for the class, reset before each test."""

    @pytest.fixture
    def mon(self, monitor, bus):
        proc, path, d = monitor
        ok, why = bus.set_params("monitor_node", {"max_missing_ticks": GENEROUS_MISSING_TICKS,
                                                  "gap_window": MonitorCore.GAP_WINDOW})
        assert ok, why
        assert bus.call_trigger("/monitor_node/reset").success
        assert bus.wait(lambda: bus.stops and not bus.stops[-1].active)
        bus.clear()
        yield proc, path, d
        assert proc.alive(), proc.log.read_text()[-3000:]

    def alive_and_checking(self, bus, proc, seed=9):
        """The node answers its reset service and checks a fresh clean stream again. The
        missing-data limit goes back to the generous one first: a test that set 200 ms to provoke
        that stop saw it again here once in a loaded fresh clone (2026-12-01), both topics silent
        for 201 ms between the reset and this test's first sample."""
        assert proc.alive()
        ok, why = bus.set_params("monitor_node", {"max_missing_ticks": GENEROUS_MISSING_TICKS})
        assert ok, why
        assert bus.call_trigger("/monitor_node/reset").success
        Y, U = stream(40, seed)
        ts = stamps(40)
        bus.send_ticks(ts, Y, U)
        assert bus.wait(lambda: len(bus.statuses(ts)) == 40), len(bus.statuses(ts))
        st = bus.statuses(ts)
        assert all(not s.safe_stop_active for s in st) and warm_up_then_conformant(st)

    @pytest.mark.parametrize("case, kind, joint, words", BAD_CASES)
    def test_bad_sample_latches_safe_stop_with_reason(self, bus, mon, case, kind, joint, words):
        proc, _, _ = mon
        Y, U = stream(90, seed=1)
        ts = stamps(90)
        bus.send_ticks(ts[:60], Y, U)
        assert bus.wait(lambda: len(bus.statuses(ts[:60])) == 60)
        t, names, y, u = corrupt(case, ts[60], ts[30], Y[60], U[60])
        bus.send_y(t, names, y)
        bus.send_u(ts[60], JOINTS, u)
        bus.send_ticks(ts[62:], Y[62:], U[62:])
        assert bus.wait(lambda: bus.active_stops())
        stop = bus.active_stops()[0]
        assert (stamp_ns(stop.header.stamp), stop.kind, stop.joint) == (t, kind, joint), stop
        assert words in stop.reason, stop.reason
        # no verdict before it was wrong, none for the bad tick; checking went on afterwards
        assert bus.wait(lambda: len(bus.statuses(ts[62:])) == 28), len(bus.statuses(ts[62:]))
        assert warm_up_then_conformant(bus.statuses(ts[:60]))
        assert not [s for s in bus.statuses(ts) if stamp_ns(s.header.stamp) == ts[60]]
        assert all(s.safe_stop_active for s in bus.statuses(ts[62:]))
        assert warm_up_then_conformant(bus.statuses(ts[62:]))
        # first cause wins: later ones publish no other stop; the stop itself is repeated every
        # tick period until a reset (issue 17.2: bounded delivery)
        assert len(bus.distinct_active_stops()) == 1
        assert bus.wait(lambda: len(bus.active_stops()) >= 3)
        self.alive_and_checking(bus, proc)

    def test_violation_names_its_test_case_on_the_models_tick(self, bus, mon):
        """A violation's stop names joint, step k and the stamp where its test case began:
        k ticks of the model's dt (4 ms) before. (The node's ``dt`` parameter, the watchdog's
        tick, is read-only since issue 19.6 and never enters the test case's stamp.)"""
        Y, U = stream(80, seed=4)
        Y[60, 0] += 0.01                          # a jump no set of this model allows
        ts = stamps(80)
        bus.send_ticks(ts, Y, U)
        assert bus.wait(lambda: bus.active_stops())
        stop = bus.active_stops()[0]
        assert (stop.kind, stop.joint, stamp_ns(stop.header.stamp)) == ("violation", JOINTS[0], ts[60]), stop
        assert stop.step >= 1 and stop.test_case_start_ns == ts[60] - stop.step * DT_NS, stop

    def test_a_stuck_sensor_while_the_reference_moves_latches_a_stop(self, bus, mon):
        """The stuck-sensor rule over DDS: /joint_states, /reference and /plant_input as the
        running system publishes them; joint 2's reading frozen at tick 60 while its reference
        moves at 0.1 rad/s latches an ``invalid_sample`` stop naming the joint at its fifth
        repeat (a reference that arrives after its tick was processed is used at the next
        tick, hence up to two ticks later); nothing stops while the readings change."""
        Y, U = stream(120, seed=12)
        Y[60:, 1] = Y[60, 1]
        ts = stamps(120)
        for k, t in enumerate(ts):
            bus.send_y(t, JOINTS, Y[k])
            r = JointReference(name=JOINTS, position=[0.0, 0.0], velocity=[0.3, 0.1], acceleration=[0.0, 0.0])
            to_stamp(r.header.stamp, t)
            bus.ref.publish(r)
            bus.send_u(t, JOINTS, U[k])
            time.sleep(0.002)
        assert bus.wait(lambda: bus.active_stops())
        stop = bus.active_stops()[0]
        assert (stop.kind, stop.joint) == ("invalid_sample", JOINTS[1]), stop
        assert "stuck sensor" in stop.reason and "repeated" in stop.reason, stop.reason
        assert ts[65] <= stamp_ns(stop.header.stamp) <= ts[67], (stamp_ns(stop.header.stamp) - ts[60]) / DT_NS
        assert not [s for s in bus.statuses(ts[:60]) if not s.conformant and s.active_test_cases]

    def test_extra_names_are_ignored_and_counted(self, bus, mon):
        Y, U = stream(50, seed=2)
        ts = stamps(50)
        before = bus.counters()
        for k, t in enumerate(ts):
            bus.send_y(t, ["gripper_joint", JOINTS[1], JOINTS[0]], [123.0, Y[k, 1], Y[k, 0]])
            bus.send_u(t, JOINTS + ["other_joint"], list(U[k]) + [math.nan])
            time.sleep(0.002)
        assert bus.wait(lambda: len(bus.statuses(ts)) == 50)
        assert warm_up_then_conformant(bus.statuses(ts)) and not bus.active_stops()

        def delta():
            c = bus.counters()
            return tuple(c.get(k, 0) - before.get(k, 0) for k in ("extra_names_y", "extra_names_u", "ticks"))
        assert bus.wait(lambda: delta() == (50, 50, 50)), delta()

    def test_repeated_stamps_are_skipped_and_counted(self, bus, mon):
        Y, U = stream(60, seed=3)
        ts = stamps(60)
        before = bus.counters()
        bus.send_ticks(ts[:40], Y, U)
        bus.send_y(ts[39], JOINTS, Y[39])          # the last sample again
        bus.send_u(ts[39], JOINTS, U[39])
        bus.send_y(ts[40], JOINTS, Y[40])
        bus.send_y(ts[40], JOINTS, [9.0, 9.0])     # a second, different sample at the same stamp
        bus.send_u(ts[40], JOINTS, U[40])
        bus.send_ticks(ts[41:], Y[41:], U[41:])
        assert bus.wait(lambda: len(bus.statuses(ts)) == 60), len(bus.statuses(ts))
        assert warm_up_then_conformant(bus.statuses(ts)) and not bus.active_stops()

        def delta():
            c = bus.counters()
            return tuple(c.get(k, 0) - before.get(k, 0) for k in ("duplicate_y", "duplicate_u", "ticks"))
        assert bus.wait(lambda: delta() == (2, 1, 60)), delta()

    def test_dropped_messages_are_counted_gaps(self, bus, mon):
        Y, U = stream(300, seed=5)
        ts = stamps(300)
        before = bus.counters()
        bus.send_ticks(ts, Y, U, drop_y={100, 200, 201, 202}, drop_u={150, 200, 201, 202})
        assert bus.wait(lambda: len(bus.statuses(ts)) == 295), len(bus.statuses(ts))
        got = [stamp_ns(s.header.stamp) for s in bus.statuses(ts)]
        assert got == [t for k, t in enumerate(ts) if k not in (100, 150, 200, 201, 202)]
        assert warm_up_then_conformant(bus.statuses(ts), segments=4) and not bus.active_stops()

        def delta():
            c = bus.counters()
            return tuple(c.get(k, 0) - before.get(k, 0) for k in ("ticks", "dropped_incomplete", "gaps",
                                                                    "missing_ticks"))
        assert bus.wait(lambda: delta() == (295, 2, 3, 5)), delta()

    def test_burst_every_processed_tick_has_a_status_and_losses_are_counted(self, bus, mon):
        """800 ticks published back to back, faster than the monitor checks them. The
        lossy-link rule is off here (``gap_window`` 0): ticks lost again within 25 ticks of
        each other are a coverage stop with it (``test_core_samples_lost_again_*``), which a
        burst that overflows the queues may cause; this test checks the accounting."""
        proc, _, _ = mon
        ok, why = bus.set_params("monitor_node", {"gap_window": 0})
        assert ok, why
        n = 800
        Y, U = stream(n + 50, seed=7)
        ts = stamps(n + 50)
        before = bus.counters()
        bus.send_ticks(ts[:n], Y, U, pace=0)
        # then single ticks on the same grid until one is checked: both topics and the status
        # are ordered, so by then every tick of the burst that reached the monitor was checked
        # and its status is here
        for k in range(n, n + 50):
            bus.send_ticks(ts[k:k + 1], Y[k:k + 1], U[k:k + 1], pace=0)
            if bus.wait(lambda: bus.statuses(ts[n:]), 5.0):
                break
        st = bus.statuses(ts)
        got = [stamp_ns(s.header.stamp) for s in st]
        assert got and got[-1] >= ts[n]
        assert got == sorted(got) and len(set(got)) == len(got)
        assert warm_up_then_conformant(st, segments=None) and not bus.active_stops()
        # the diagnostics account for every tick between the first and the last checked one
        assert bus.wait(lambda: bus.counters()["ticks"] - before.get("ticks", 0) >= len(st))
        c = bus.counters()
        assert c["ticks"] - before.get("ticks", 0) == len(st), (c, before, len(st))
        missing = c.get("missing_ticks", 0) - before.get("missing_ticks", 0)
        print(f"burst of {n}: {len(st)} checked, {missing} missing in gaps, "
              f"{c.get('dropped_incomplete', 0) - before.get('dropped_incomplete', 0)} half ticks dropped")
        assert len(st) + missing == (got[-1] - got[0]) // DT_NS + 1
        # the tick counter in the statuses has no holes: each checked tick was published
        ticks = [s.tick for s in st]
        assert ticks == list(range(ticks[0], ticks[0] + len(ticks)))
        self.alive_and_checking(bus, proc)

    def test_plant_input_not_yet_arriving_is_reported_not_a_stop(self, bus, mon):
        """/joint_states flows, /plant_input has never come (a controller still starting):
        the monitor waits, says so on /diagnostics and counts the half ticks it drops; once
        /plant_input comes it checks every tick."""
        proc, _, _ = mon
        ok, why = bus.set_params("monitor_node", {"max_missing_ticks": 50})
        assert ok, why
        before = bus.counters()
        Y, U = stream(700, seed=8)
        ts = stamps(700)
        t_start = time.monotonic()
        for k in range(500):                       # 1 s and more: five times the watchdog's limit
            bus.send_y(ts[k], JOINTS, Y[k])
            time.sleep(0.002)
        assert time.monotonic() - t_start > 1.0
        c = bus.counters()                          # a fresh /diagnostics message
        level, message = bus.diags["reachset_ros: conformance monitor"][:2]
        assert not bus.active_stops()
        assert (level, message) == (DiagnosticStatus.WARN, "waiting for /plant_input")
        assert c["dropped_incomplete"] - before.get("dropped_incomplete", 0) > 0
        assert c.get("ticks", 0) == before.get("ticks", 0)
        # the second half checks that every tick is checked, not the watchdog: give it 1 s, so
        # that a pause of this test's own Python publisher (a CI run saw one of 200 ms in the
        # full suite, with the loop's data intact) is not taken for the stream going silent
        ok, why = bus.set_params("monitor_node", {"max_missing_ticks": 250})
        assert ok, why
        bus.send_ticks(ts[500:], Y[500:], U[500:])
        assert bus.wait(lambda: len(bus.statuses(ts)) == 200)
        assert warm_up_then_conformant(bus.statuses(ts)) and not bus.active_stops()
        self.alive_and_checking(bus, proc)

    def test_stamps_that_never_pair_are_missing_data(self, bus, mon):
        """Both topics arrive, but /plant_input is stamped half a period off (a controller
        stamping with its own clock): no tick ever completes, a safe stop says why."""
        proc, _, _ = mon
        ok, why = bus.set_params("monitor_node", {"max_missing_ticks": 50})
        assert ok, why
        Y, U = stream(5000, seed=13)
        ts = stamps(5000)
        for k, t in enumerate(ts):
            bus.send_y(t, JOINTS, Y[k])
            bus.send_u(t + DT_NS // 2, JOINTS, U[k])
            time.sleep(0.002)
            if bus.active_stops():
                break
        stops = bus.active_stops()
        assert stops and stops[0].kind == "missing_data", stops
        assert "limit 200 ms" in stops[0].reason and "stamps do not pair" in stops[0].reason, stops[0].reason
        assert not bus.statuses(ts)
        self.alive_and_checking(bus, proc)

    def test_topic_going_silent_is_missing_data(self, bus, mon):
        proc, _, _ = mon
        ok, why = bus.set_params("monitor_node", {"max_missing_ticks": 50})
        assert ok, why
        Y, U = stream(5000, seed=10)
        ts = stamps(5000)
        bus.send_ticks(ts[:100], Y, U)
        for k in range(100, 5000):
            bus.send_u(ts[k], JOINTS, U[k])      # /joint_states went silent
            time.sleep(0.002)
            if bus.active_stops():
                break
        stops = bus.active_stops()
        assert stops and stops[0].kind == "missing_data", stops
        assert "/joint_states silent for" in stops[0].reason, stops[0].reason
        assert bus.wait(lambda: len(bus.statuses(ts[:100])) == 100)
        assert warm_up_then_conformant(bus.statuses(ts[:100]))
        assert stamp_ns(stops[0].header.stamp) == ts[99]   # the last tick checked
        self.alive_and_checking(bus, proc)

    def test_stream_at_the_wrong_period_is_a_coverage_stop(self, bus, mon):
        """/joint_states and /plant_input at 125 Hz for a 4 ms model: every step is a gap, so
        nothing is ever checked. No status says conformant; a latched safe stop of kind
        ``coverage`` names the measured period, at the second step (the lossy-link rule:
        samples lost again within ``gap_window`` ticks; without it, within the missing-data
        limit after the warm-up, as the core's test checks); /diagnostics says nothing was
        checked."""
        proc, _, _ = mon
        ok, why = bus.set_params("monitor_node", {"max_missing_ticks": 50})   # 200 ms: no watchdog stop on a stall
        assert ok, why
        Y, U = stream(200, seed=15)
        base = stamps(400)[0]
        ts = [base + 2 * DT_NS * k for k in range(200)]
        for k, t in enumerate(ts):
            bus.send_y(t, JOINTS, Y[k])
            bus.send_u(t, JOINTS, U[k])
            time.sleep(0.008)
            if bus.active_stops():
                break
        assert bus.wait(lambda: bus.active_stops())
        stop = bus.active_stops()[0]
        assert stop.kind == "coverage" and "measured stream period 8 ms" in stop.reason, stop
        assert "samples lost again" in stop.reason and "dt of 4 ms" in stop.reason, stop.reason
        at = stamp_ns(stop.header.stamp)
        assert at == ts[2], (at - ts[0]) / 1e6
        assert bus.wait(lambda: bus.statuses([ts[0], at]) and stamp_ns(bus.statuses([ts[0], at])[-1].header.stamp) == at)
        st = bus.statuses(ts)
        assert st and not any(s.conformant for s in st), [s.conformant for s in st]
        assert all(s.active_test_cases == 0 and set(s.tightest_step) == {-1} for s in st)
        c = bus.counters(newer_than=time.monotonic())
        assert c["longest_step"] == -1 and c["unchecked_ticks"] >= len(st) and c["coverage_faults"] >= 1, c
        # latched: a late subscriber sees it
        late = []
        sub = bus.caller.create_subscription(SafeStop, "safe_stop", late.append, SAFE_STOP_QOS)
        try:
            end = time.monotonic() + 10
            while time.monotonic() < end and not late:
                rclpy.spin_once(bus.caller, timeout_sec=0.1)
            assert late and late[-1].active and late[-1].kind == "coverage"
        finally:
            bus.caller.destroy_subscription(sub)
        self.alive_and_checking(bus, proc)

    def test_bad_parameter_updates_are_refused_and_change_nothing(self, bus, mon, tmp_path):
        proc, path, _ = mon
        model_id = mdl.file_sha256(path)[:12]
        garbage = tmp_path / "garbage.yaml"
        garbage.write_text("format: [unclosed\n  {{ :\n")
        negative = tmp_path / "negative.yaml"
        negative.write_text(path.read_text().replace("- 0.15", "- -0.15", 1))
        assert negative.read_text() != path.read_text()
        other = write_model(tmp_path / "other.yaml", alpha_w=(0.3, 0.0))
        cases = [
            ({"model_file": str(tmp_path / "missing.yaml")}, "model file not found"),
            ({"model_file": str(garbage)}, "does not parse"),
            ({"model_file": str(negative)}, "negative scaling factor"),
            ({"model_file": ""}, "must not be empty"),
            ({"joints": ["arm_3_joint"]}, "arm_3_joint is not in the model"),
            ({"model_file": str(other), "joints": ["arm_1_joint", "arm_9_joint"]}, "arm_9_joint is not in the model"),
            ({"max_missing_ticks": 0}, "out of range"),
            ({"dt": math.nan}, "read-only"),       # read at start-up only (issue 19.6)
            ({"dt": -0.004}, "read-only"),
        ]
        for values, words in cases:
            ok, why = bus.set_params("monitor_node", values)
            assert not ok and words in why, (values, why)
        assert bus.get_param("monitor_node", "model_file") == str(path)
        assert bus.get_param("monitor_node", "joints") == [""]
        assert bus.get_param("monitor_node", "max_missing_ticks") == GENEROUS_MISSING_TICKS
        # the running model is the one it had: same id, same verdicts
        Y, U = stream(60, seed=11)
        ts = stamps(60)
        bus.send_ticks(ts, Y, U)
        assert bus.wait(lambda: len(bus.statuses(ts)) == 60)
        assert all(s.model_id == model_id and list(s.name) == JOINTS for s in bus.statuses(ts))
        assert warm_up_then_conformant(bus.statuses(ts))
        assert not bus.active_stops()
        # a valid update is applied (the refusals above were not vacuous), and back
        ok, why = bus.set_params("monitor_node", {"model_file": str(other), "joints": ["arm_2_joint"]})
        assert ok, why
        ts = stamps(20)
        bus.send_ticks(ts, Y, U)
        assert bus.wait(lambda: len(bus.statuses(ts)) == 20)
        assert all(s.model_id == mdl.file_sha256(other)[:12] and list(s.name) == ["arm_2_joint"]
                   for s in bus.statuses(ts))
        ok, why = bus.set_params("monitor_node", {"model_file": str(path), "joints": [""]})
        assert ok, why
        self.alive_and_checking(bus, proc)

    def test_a_model_bound_to_another_u_p_or_other_sets_is_refused(self, bus, mon, tmp_path):
        """Issue 34.10/11 on the monitor (input_source plant_input): a model identified from
        effort, one that records no input_source, and one whose calibration names other sets
        are refused, naming why; the running model stays. Before, all three were loaded."""
        proc, path, _ = mon
        doc = yaml.safe_load(path.read_text())
        cases = []
        for name, edit, words in (
                ("effort", lambda d: d.update(input_source={"kind": "effort", "urdf_sha256": "0" * 64,
                                                            "params_sha256": None, "locked_joints": [],
                                                            "joints": JOINTS, "torque_scale": [1.0, 1.0]}),
                 "identified with u_p from effort"),
                ("unbound", lambda d: d.pop("input_source"), "records no input_source"),
                ("other_sets", lambda d: d.update(calibration={"sets_sha256": "0" * 64, "inflation": 0.0}),
                 "calibrated on other sets")):
            d = yaml.safe_load(yaml.safe_dump(doc))
            edit(d)
            (tmp_path / f"{name}.yaml").write_text(yaml.safe_dump(d))
            cases.append((tmp_path / f"{name}.yaml", words))
        for f, words in cases:
            ok, why = bus.set_params("monitor_node", {"model_file": str(f)})
            assert not ok and words in why, (f, why)
        assert bus.get_param("monitor_node", "model_file") == str(path)
        self.alive_and_checking(bus, proc)
