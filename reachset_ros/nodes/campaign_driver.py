"""The fault campaign's runner (issue 17): the whole simulated system over real DDS, faults
from a seeded schedule (:mod:`reachset_ros.sim.campaign`), every stop measured.

``run_campaign`` starts the suite as the demo does (calibrated simulated LWA-4P, reference,
observer, controller with ``wait_for_monitor``, monitor), records ``train`` s ``train_runs``
times with the initial gains, identifies the monitor's model from those recordings with the
inflation calibrated by cross-validation on them, each recording a fold (``reachset identify
BAG1 ... BAGn --calibrate n --calibrate-margin m``: m grid steps above what the folds
needed, for a run much longer than a fold), resets the monitor and then runs the events: for each, a fault-free stretch of
monitored running, the fault, the wait for the stop, the braking it causes, and the recovery
(faults cleared, a killed process restarted, the monitor reset, the arm tracking again for
``RECOVER_S`` without a stop; a stop during the recovery is counted apart and the reset
repeated). The monitor reads ``/joint_states`` through a relay (:mod:`.relay_node`, remapped),
which the link events make drop or delay samples. Every block of 8 events is recorded to its own bag (the campaign's topics),
named in the outcome of each of its events, so a miss or a false stop comes with its data.
CPU burners (one busy process per core, normal priority) run during the blocks the
schedule says.
"""
from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import rclpy
from diagnostic_msgs.msg import DiagnosticArray
from reachset_msgs.msg import BrakeCommand, JointReference, SafeStop
from rclpy.signals import SignalHandlerOptions
from sensor_msgs.msg import JointState
from std_srvs.srv import Trigger

from .. import launch
from ..bags.references import read_references
from ..robot.lwa4p import default_nominal_path
from ..sim import campaign as cp
from ..sim.simulator import DT as SIM_DT
from .common import SAFE_STOP_QOS, TICK_QOS, set_remote_parameters, stamp_ns
from .demo_driver import CORE_TOPICS, INITIAL_GAINS, JOINTS, LOCKSTEP_TIMEOUT, MONITOR_TOPICS, DemoDriver

#: ``Outcome.note`` of a fault that must stop when the runner saw no stop in its window
#: (:func:`bag_stops` looks in the bag for one it did not wait for)
NO_STOP_NOTE = "no stop within the detection window"
#: after a reset the arm must track this long (simulated s) without a stop before the next event
RECOVER_S = 2.0
#: after a stop, the reset waits until this long (simulated s) after the stop's stamp (judge_rest)
JUDGE_S = 1.0
#: an event expecting no stop is watched this long (simulated s) after it
WATCH_S = 2.0
#: a refused reset is tried again for this long (simulated s) before the campaign gives up
RESET_PATIENCE_S = 20.0
#: the monitor's /joint_states, as the relay lets them through (link events)
RELAYED = "/campaign/relayed/joint_states"
#: resets tried before the campaign gives up on recovering
MAX_RESETS = 6
#: training recordings tried while a brake engaged during them, before the campaign gives up
TRAIN_TRIES = 3
#: share of the reference's moves led by one joint at its full limits (training and events alike)
REFERENCE_LEAD = 0.5
BURNER = "while True:\n    pass\n"


class CampaignListener:
    """Distinct active stops with the simulation time and wall time of their arrival, and the
    controller's brake commands that carry a stop's arrival."""

    def __init__(self, driver: DemoDriver):
        self.driver = driver
        self.stops = []          # (stop stamp, arrival sim ns, reason, kind, arrival wall)
        self.seen = set()
        self.brakes = []         # (braking_since_ns, stop_received_ns)
        self.last_js = None
        driver.create_subscription(SafeStop, "safe_stop", self.on_stop, SAFE_STOP_QOS)
        driver.create_subscription(BrakeCommand, "brake_command", self.on_brake, TICK_QOS)
        driver.create_subscription(JointState, "joint_states", self.on_js, TICK_QOS)
        driver.create_subscription(JointReference, "reference", self.on_ref, TICK_QOS)
        self.moving = {}         # joint -> stamp of the first reference with |qd_d| > FROZEN_MOTION
        driver.create_subscription(DiagnosticArray, "diagnostics", self.on_diag, 50)
        self.braked = 0          # /brake_command messages with an engaged brake
        self.brake_reason = ""   # the newest one's reason
        # the simulators' steps on a stale command and ahead of the monitor's verdicts, summed
        # over restarts
        self.sim_steps = {"stale_effort": 0, "ahead_of_monitor": 0}
        self._sim_last = dict.fromkeys(self.sim_steps, 0)

    def on_diag(self, arr):
        for st in arr.status:
            if st.name == "reachset_ros: simulator":
                v = {kv.key: kv.value for kv in st.values}
                for key, last in self._sim_last.items():
                    n = int(v.get(key, "0"))
                    # a restarted simulator counts from 0 again
                    self.sim_steps[key] += n - last if n >= last else n
                    self._sim_last[key] = n

    def on_stop(self, m):
        if not m.active:
            self.seen.clear()    # a reset: the next stop with any stamp is new
            return
        key = (stamp_ns(m.header.stamp), m.kind, m.reason)
        if key in self.seen:     # the monitor repeats an active stop every tick until reset
            return
        self.seen.add(key)
        self.stops.append((key[0], self.driver.sim_now(), f"{m.kind}: {m.reason}"[:300], m.kind, time.monotonic()))

    def on_brake(self, m):
        if m.stop_received_ns and m.braking_since_ns:
            self.brakes.append((int(m.braking_since_ns), int(m.stop_received_ns)))
        if any(m.engage):
            self.braked += 1
            self.brake_reason = m.reason

    def on_js(self, m):
        self.last_js = m

    def on_ref(self, m):
        t = stamp_ns(m.header.stamp)
        for n, v in zip(m.name, m.velocity):
            if abs(v) > cp.FROZEN_MOTION:
                self.moving.setdefault(n, t)      # the first since the entry was cleared


class Burners:
    """One busy process per core while on (normal priority: they compete with the nodes)."""

    def __init__(self, n=None):
        self.n = n or os.cpu_count() or 2
        self.procs = []

    def set(self, on):
        if on and not self.procs:
            self.procs = [subprocess.Popen([sys.executable, "-c", BURNER], start_new_session=True)
                          for _ in range(self.n)]
        elif not on and self.procs:
            self.off()

    def off(self):
        for p in self.procs:
            p.kill()
            p.wait()
        self.procs = []


def run_campaign(workdir: Path, events, seed=1, train=20.0, log=print, model=None, train_runs=3,
                 calibrate_margin=0, realtime_priority=0, monitor_lockstep_ticks=None):
    """Run ``events`` (:func:`reachset_ros.sim.campaign.schedule`); returns ``(outcomes, info)``.

    ``model``: a model file for the monitor (skips the training recordings and the
    identification); ``calibrate_margin``: grid steps of inflation above the cross-validated
    one (``identify --calibrate-margin``); ``realtime_priority``: SCHED_FIFO priority of the
    simulator, reference, observer, controller, monitor and relay (0: the default policy;
    :mod:`.scheduling`); ``monitor_lockstep_ticks``: the simulator's parameter (``None``: its
    default; 0: the simulation does not wait for the monitor's verdicts); ``info`` has the
    model, its inflation (and the cross-validated one) and the nodes' logs directory."""
    workdir = Path(workdir).resolve()
    workdir.mkdir(parents=True, exist_ok=True)
    procs = {}
    group = []
    own = not rclpy.ok()
    if own:
        launch.use_dds_profiles()
        rclpy.init(signal_handler_options=SignalHandlerOptions.NO)
    driver = DemoDriver()
    lis = CampaignListener(driver)
    burners = Burners()
    jump_pub = driver.create_publisher(JointState, "joint_states", TICK_QOS)
    common = {"joints": JOINTS, "allow_uncertified": True}
    params = {
        "sim_node": {"seed": seed, "calibrated": True, "lockstep_timeout": LOCKSTEP_TIMEOUT},
        # led moves: the training reaches the reference class' limits on every joint (the
        # synchronised moves alone left arm_2 at a third of qd_max: false stops on its fast moves)
        "reference_node": {"seed": seed, "lead": REFERENCE_LEAD},
        "observer_node": {**common, **INITIAL_GAINS},
        "controller_node": {**common, **INITIAL_GAINS, "wait_for_monitor": True,
                            "robot_params": str(default_nominal_path())},
        "monitor_node": {"window_dir": str(workdir / "windows")},
        # the monitor's /joint_states pass through the relay: the link events drop or delay them
        "relay_node": {"input_topic": "/joint_states", "output_topic": RELAYED, "seed": seed},
    }
    if realtime_priority:
        # the loop and the stop path (the relay stands for the monitor's link) preempt the
        # burners; the recorder and this driver keep the default policy
        for name in ("sim_node", "reference_node", "observer_node", "controller_node", "monitor_node", "relay_node"):
            params[name]["realtime_priority"] = int(realtime_priority)
    if monitor_lockstep_ticks is not None:
        params["sim_node"]["monitor_lockstep_ticks"] = int(monitor_lockstep_ticks)
    remaps = {"monitor_node": {"joint_states": RELAYED}}
    info = {"workdir": str(workdir), "seed": seed, "realtime_priority": int(realtime_priority),
            "monitor_lockstep_ticks": monitor_lockstep_ticks}
    outcomes = []
    rec = None

    def start(name):
        procs[name] = launch.start(name, params[name], workdir, group=group, remap=remaps.get(name))

    def set_link(drop_share=0.0, drop_every=0, delay_s=0.0):
        ok, why = set_remote_parameters(driver, "relay_node", {"drop_share": float(drop_share),
                                                                "drop_every": int(drop_every),
                                                                "delay_s": float(delay_s)})
        if not ok:
            raise RuntimeError(f"the relay refused the link fault: {why}")

    def sim_wait(seconds, until=None):
        return driver.spin_sim(seconds, until=until)[0]

    def reset_monitor(o=None, patience_s=RESET_PATIENCE_S):
        """The monitor's ~/reset, tried again every 0.25 s of simulated time while it is refused
        because the stop's condition has not cleared (the arm still coming to rest)."""
        t0 = driver.sim_now()
        while True:
            r = driver.call(Trigger, "/monitor_node/reset", Trigger.Request(), timeout=30.0)
            if r.success:
                if o is not None and not o.reset_ns:
                    o.reset_ns = driver.sim_now()
                return
            if o is not None:
                o.resets_refused += 1
            if driver.sim_now() - t0 > patience_s * 1e9:
                raise RuntimeError(f"monitor reset refused for {patience_s:g} s: {r.message}")
            sim_wait(0.25)

    def recover(ev, o):
        if ev.kind == "link":
            set_link()
        if ev.kind == "sim":
            ok, why = set_remote_parameters(driver, "sim_node", {"fault": "none"})
            if not ok:
                raise RuntimeError(f"clearing the fault: {why}")
        if ev.kind == "kill":
            launch.stop([procs[ev.target]], timeout=2.0)
            old = procs[ev.target].log       # keep the killed process' log beside the new one
            old.rename(old.with_name(f"{old.stem}.killed_event{ev.index:03d}.log"))
            start(ev.target)
            if ev.target == "sim_node":   # a new simulation (new clock): wait for it
                c0 = driver.sim_now()
                if not driver.spin_for(60.0, until=lambda: driver.sim_now() > c0 + 200_000_000):
                    raise RuntimeError("the restarted sim_node does not tick")
            else:
                driver.spin_for(3.0)
        if o.stops and not (ev.kind == "kill" and ev.target == "sim_node"):
            # the stop's effect is judged from the bag up to the reset: let it show first (a
            # restarted simulator has a new clock and an arm at rest: nothing to wait for)
            left = (o.stops[0][0] - driver.sim_now()) * 1e-9 + JUDGE_S
            if left > 0:
                sim_wait(left)
        for attempt in range(MAX_RESETS):
            reset_monitor(o)
            n = len(lis.stops)
            sim_wait(RECOVER_S, until=lambda: len(lis.stops) > n)
            if len(lis.stops) == n:
                return
            o.recovery_stops += 1
            log(f"[campaign]   recovery stop {attempt + 1}: {lis.stops[-1][2][:160]}")
            sim_wait(0.5)
        raise RuntimeError(f"no recovery after {ev.label()}: {MAX_RESETS} resets, each followed by a stop")

    def run_event(ev, bag):
        o = cp.Outcome(ev, bag=str(bag))
        steps0 = dict(lis.sim_steps)
        burners.set(ev.burners)
        n = len(lis.stops)
        t0 = driver.sim_now()
        sim_wait(ev.quiet_s, until=lambda: len(lis.stops) > n)
        o.quiet_sim_s = (driver.sim_now() - t0) * 1e-9
        if len(lis.stops) > n:
            o.quiet_stops = [s[:3] for s in lis.stops[n:]]
            log(f"[campaign]   FALSE STOP in the fault-free stretch: {lis.stops[n][2][:200]}")
            recover(ev if ev.kind == "none" else cp.Event(ev.index, "quiet", 0.0, "none"), o)
            o.reset_ns = 0      # that reset ended the false stop; the event's own stop is judged up to its own
        n = len(lis.stops)
        nb = len(lis.brakes)
        wall0 = window_wall = time.monotonic()
        if ev.kind == "sim":
            driver.onsets.clear()
            ok, why = set_remote_parameters(driver, "sim_node", {"fault_joint": ev.joint,
                                                                  "fault_magnitude": float(ev.magnitude),
                                                                  "fault": ev.fault})
            if not ok:
                raise RuntimeError(f"fault injection refused: {why}")
            if not driver.spin_for(10.0, until=lambda: bool(driver.onsets)):
                raise RuntimeError("no /sim/fault_onset after the injection")
            o.fault_ns = stamp_ns(driver.onsets[-1].stamp)
            if ev.fault == "frozen":
                # observable only once the joint moves: wait (up to FROZEN_WAIT_S) for its
                # reference to move, the detection window starts there
                lis.moving.pop(ev.joint, None)
                sim_wait(cp.FROZEN_WAIT_S, until=lambda: ev.joint in lis.moving or len(lis.stops) > n)
                o.observable_ns = max(o.fault_ns, lis.moving.get(ev.joint, 0)) if (
                    ev.joint in lis.moving or len(lis.stops) > n) else 0
                window_wall = time.monotonic()   # the wall-time guard, too, starts with the window
        elif ev.kind == "kill":
            o.fault_ns = driver.sim_now()
            os.kill(procs[ev.target].proc.pid, signal.SIGKILL)
        elif ev.kind == "freeze":
            o.fault_ns = driver.sim_now()
            pid = procs[ev.target].proc.pid
            os.kill(pid, signal.SIGSTOP)
            try:
                driver.spin_for(ev.seconds)
            finally:
                os.kill(pid, signal.SIGCONT)
        elif ev.kind == "stamp_jump":
            js = lis.last_js
            o.fault_ns = driver.sim_now()
            bad = JointState()
            bad.header.stamp.sec, bad.header.stamp.nanosec = divmod(
                stamp_ns(js.header.stamp) - int(ev.seconds * 1e9), 1_000_000_000)
            bad.name, bad.position, bad.velocity, bad.effort = list(js.name), list(js.position), \
                list(js.velocity), list(js.effort)
            jump_pub.publish(bad)
        elif ev.kind == "link":
            o.fault_ns = driver.sim_now()
            set_link(**{"loss": {"drop_share": ev.magnitude}, "sparse": {"drop_every": int(ev.magnitude)},
                        "delay": {"delay_s": ev.magnitude}}[ev.fault])
            if ev.expect == "none":        # the tolerated link faults last ev.seconds, then the watch below
                sim_wait(ev.seconds, until=lambda: len(lis.stops) > n)
                set_link()
        if ev.expect == "stop" and ev.fault == "frozen" and not o.observable_ns:
            o.note = f"unobservable: the joint's reference did not move within {cp.FROZEN_WAIT_S:g} s"
            log(f"[campaign]   {o.note}")
        elif ev.expect == "stop":
            end = o.latency_from() + int(cp.detect_within_s(ev) * 1e9)
            # (from the window's start: a frozen sensor's joint may first move seconds after the
            # event began; the seventh long run lost a stop 20 ms after such a motion, 8.5 s in)
            wall_end = window_wall + cp.DETECT_WITHIN_WALL_S
            while len(lis.stops) == n and driver.sim_now() < end and time.monotonic() < wall_end:
                driver.spin_once(0.01)
        else:
            wall_end = time.monotonic() + 30.0
            t1 = driver.sim_now()
            while len(lis.stops) == n and driver.sim_now() < t1 + int(WATCH_S * 1e9) and time.monotonic() < wall_end:
                driver.spin_once(0.02)
        o.stops = [s[:3] for s in lis.stops[n:]]
        if o.stops:
            o.wall_latency_s = lis.stops[n][4] - wall0
            if not (ev.kind == "kill" and ev.target == "controller_node"):
                driver.spin_for(6.0, until=lambda: len(lis.brakes) > nb)
                mine = [b for b in lis.brakes[nb:] if b[1] > 0]
                if mine:
                    o.braking_ticks = (mine[0][0] - mine[0][1]) / (SIM_DT * 1e9)   # in the loop's ticks
            after = o.latency_ns() * 1e-6
            log(f"[campaign]   stop {o.stops[0][2][:140]!r}: {after:.1f} ms after the "
                f"fault (stop stamp {(o.stops[0][0] - o.fault_ns) * 1e-6:+.1f} ms), braking "
                f"{o.braking_ticks} ticks after its arrival")
        elif ev.expect == "stop" and not o.note:
            o.note = NO_STOP_NOTE
            log(f"[campaign]   MISSED: no stop within {cp.detect_within_s(ev)} s")
        if o.stops or ev.kind in ("sim", "kill", "link"):
            recover(ev, o)
        # as reported so far (/diagnostics at 1 Hz)
        o.stale_steps = lis.sim_steps["stale_effort"] - steps0["stale_effort"]
        o.ahead_steps = lis.sim_steps["ahead_of_monitor"] - steps0["ahead_of_monitor"]
        return o

    try:
        for name in ("sim_node", "reference_node", "observer_node", "controller_node", "relay_node",
                     "monitor_node"):
            start(name)
        if not driver.spin_for(120.0, until=lambda: bool(driver.stops)):
            raise RuntimeError("no /safe_stop state from the monitor within 120 s")
        sim_wait(3.0)
        if model is None:
            bags = []
            for i in range(1, train_runs + 1):
                bag = workdir / f"train{i}"
                for attempt in range(1, TRAIN_TRIES + 1):
                    # the arm must move through the whole recording: a stop the controller latched
                    # on its own (a reference lost at start-up on a slow machine) held every brake
                    # through the training of a fresh-clone make test, and the model identified on
                    # the held arm stopped the campaign at once on fault-free running
                    reset_monitor()
                    sim_wait(0.5)   # brake commands still in flight from before the reset
                    braked0 = lis.braked
                    r = _record(driver, workdir, bag, CORE_TOPICS, f"recorder_train{i}_{attempt}", group)
                    sim_wait(train)
                    launch.stop([r])
                    if lis.braked == braked0:
                        break
                    log(f"[campaign] training recording {i}: a brake engaged during it ({lis.brake_reason}); "
                        f"recorded again ({attempt} of {TRAIN_TRIES})")
                    shutil.rmtree(bag, ignore_errors=True)
                else:
                    raise RuntimeError(f"training recording {i}: a brake engaged in each of {TRAIN_TRIES} tries "
                                       f"(last: {lis.brake_reason})")
                bags.append(bag)
            model = workdir / "monitor_model.yaml"
            cmd = [sys.executable, "-m", "reachset_ros.cli", "identify", *map(str, bags),
                   "--calibrate", str(train_runs), "--calibrate-margin", str(calibrate_margin),
                   "--out", str(model), "--json"]
            p = launch.start_background(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
            out, err = p.communicate()
            if p.returncode != 0:
                raise RuntimeError("identify: " + ((err.strip().splitlines() or ["?"])[-1]))
            res = json.loads(out)
            info["inflation"], info["calibrated_inflation"] = res["inflation"], res["calibrated_inflation"]
            log(f"[campaign] monitor model identified, inflation {info['inflation']:g} (cross-validated "
                f"{info['calibrated_inflation']:g}, {calibrate_margin} grid steps of margin)")
            # what the training covered: a motion faster than this on a joint is outside the
            # data its sets were identified on (benchmarks/false_stop_coverage.py)
            refs = read_references(bags)
            info["training_fastest_qd"] = {
                n: float(max(np.abs(r.qd).max() for r in rs)) for n, rs in sorted(refs.items())}
            log("[campaign] training's fastest |qd_d| per joint, rad/s: " + ", ".join(
                f"{n} {v:.3f}" for n, v in info["training_fastest_qd"].items()))
        info["model"] = str(model)

        def block_bag(i):
            return workdir / f"block{i:03d}", f"recorder_block{i:03d}"
        # the recorder of a block starts before the monitor judges (a process starting on the
        # loaded machine is the campaign's apparatus, not a fault): the first before the
        # reset, each next one at the end of the previous block (a stop it causes is reported
        # as the apparatus', with the bag, and reset)
        bag, name = block_bag(0)
        rec = _record(driver, workdir, bag, MONITOR_TOPICS, name, group)
        ok, why = set_remote_parameters(driver, "monitor_node", {"model_file": str(model)})
        if not ok:
            raise RuntimeError(f"monitor refused the model: {why}")
        reset_monitor()
        sim_wait(RECOVER_S)
        wall0 = time.monotonic()
        apparatus = []
        for ev in events:
            if ev.index % 8 == 0 and ev.index > 0:
                n = len(lis.stops)
                bag, name = block_bag(ev.index // 8)
                new = _record(driver, workdir, bag, MONITOR_TOPICS, name, group)
                launch.stop([rec])
                rec = new
                sim_wait(0.5)
                if len(lis.stops) > n:
                    apparatus += [s[:3] + (str(bag),) for s in lis.stops[n:]]
                    log(f"[campaign] stop while the recorder switched bags (apparatus): {lis.stops[n][2][:160]}")
                    reset_monitor(patience_s=RESET_PATIENCE_S)
                    sim_wait(RECOVER_S)
            log(f"[campaign] event {ev.index}: {ev.label()} (expect {ev.expect}; burners "
                f"{'on' if ev.burners else 'off'}; {ev.quiet_s:g} s fault-free before)")
            outcomes.append(run_event(ev, bag))
        info["apparatus_stops"] = apparatus
        info["wall_s"] = time.monotonic() - wall0
        if rec is not None:
            launch.stop([rec])
            rec = None
        judge_stops(outcomes)
        frozen_before_motion(outcomes)
        link_onsets(outcomes)
        bag_brakes(outcomes)
        return outcomes, info
    finally:
        burners.off()
        if rec is not None:
            launch.stop([rec])
        launch.stop(group)
        info["logs"] = str(workdir)
        driver.own_executor.shutdown(timeout_sec=1.0)
        driver.destroy_node()
        if own:
            rclpy.try_shutdown()


def _record(driver, workdir, bag, topics, node, group):
    rec = launch.start("recorder_node", {"output": str(bag), "topics": topics, "use_sim_time": True}, workdir,
                       node_name=node, group=group)
    if not driver.spin_for(60.0, until=lambda: all(
            any(i.node_name == node for i in driver.get_subscriptions_info_by_topic(t)) for t in topics)):
        raise RuntimeError(f"{node} did not subscribe to {topics} within 60 s")
    driver.spin_for(0.5)
    return rec


def _by_bag(outcomes):
    """``{bag: [outcome, ...]}`` of ``outcomes``, in their order (each bag read once)."""
    groups = {}
    for o in outcomes:
        groups.setdefault(o.bag, []).append(o)
    return groups


def frozen_before_motion(outcomes):
    """Mark the frozen-sensor events that stopped before their joint's reference moved at more
    than :data:`~reachset_ros.sim.campaign.FROZEN_MOTION` after the fault
    (``Outcome.stopped_before_motion``), from the recorded ``/reference`` of each event's bag:
    their detection window had not begun (the window of a frozen sensor starts at that motion),
    so the score does not count them late. The runner stops waiting for the motion once a stop
    arrives, so the bag, not the runner's clock, decides (the same for a re-score)."""
    from ..bags.references import read_references
    for bag, group in _by_bag(o for o in outcomes
                              if o.event.kind == "sim" and o.event.fault == "frozen" and o.stops and o.bag).items():
        refs = read_references([bag], joints=sorted({o.event.joint for o in group}))
        for o in group:
            # the joint's references from the fault to the stop: some recorded, none fast
            window = [(r.stamps > o.fault_ns) & (r.stamps <= o.stops[0][0]) for r in refs.get(o.event.joint, [])]
            fast = [w & (np.abs(r.qd) > cp.FROZEN_MOTION) for w, r in zip(window, refs.get(o.event.joint, []))]
            o.stopped_before_motion = any(w.any() for w in window) and not any(f.any() for f in fast)


def bag_stops(outcomes):
    """A stop the runner did not wait for, read from its block's bag: for each fault that must
    stop with no stop recorded, the first active ``/safe_stop`` stamped from the fault's stamp
    to the end of its detection window (which starts at ``observable_ns`` when set). Its
    arrival is taken as its stamp (the bag has no listener's arrival), and ``note`` says so.
    For re-scoring a run whose runner stopped waiting early (the wall-time guard of the seventh
    long run, counted from the event's start instead of the window's)."""
    from ..bags.messages import SAFE_STOP_TOPIC
    from ..bags import read_messages
    for bag, group in _by_bag(o for o in outcomes if o.event.expect == "stop" and not o.stops and o.bag
                              and o.note == NO_STOP_NOTE).items():
        active = sorted((stamp_ns(m.header.stamp), m.kind, m.reason)
                        for _, _, m in read_messages([bag], [SAFE_STOP_TOPIC]) if m.active)
        for o in group:
            end = o.latency_from() + int(cp.detect_within_s(o.event) * 1e9)
            hit = [a for a in active if o.fault_ns <= a[0] <= end]
            if hit:
                st, kind, reason = hit[0]
                o.stops = [(st, st, f"{kind}: {reason}")]
                o.note = "stop read from the bag (the runner had stopped waiting)"


def bag_brakes(outcomes):
    """The stop's arrival at the controller (:attr:`~reachset_ros.sim.campaign.Outcome.controller_ns`),
    from its block's bag: the earliest ``braking_since_ns`` of a ``/brake_command`` from the
    later of the stop's stamp and the fault's up to the reset (the first measurement the
    controller commanded with the stop); only where :func:`~reachset_ros.sim.campaign.controller_acts`.
    Unchanged where the bag has no such command."""
    from ..bags.messages import BRAKE_TOPIC
    from ..bags import read_messages
    for bag, group in _by_bag(o for o in outcomes if o.stops and o.bag and cp.controller_acts(o.event)).items():
        since = sorted({int(m.braking_since_ns) for _, _, m in read_messages([bag], [BRAKE_TOPIC])
                        if m.braking_since_ns})
        for o in group:
            lo = max(o.stops[0][0], o.fault_ns)
            hit = [t for t in since if t >= lo and (not o.reset_ns or t <= o.reset_ns)]
            if hit:
                o.controller_ns = hit[0]


def link_onsets(outcomes):
    """The fault's stamp of each link loss that stopped, from its bag: the first sample the
    link lost (``Outcome.observable_ns``), i.e. the first ``/joint_states`` stamp after the
    injection without a ``/conformance/status`` of the monitor (one per tick it received).
    The runner's ``fault_ns`` is the simulation's time when it asked the relay (a parameter
    service call, which takes ticks on the loaded machine); the first lost sample is the
    first affected measurement, as ``/sim/fault_onset`` is for the simulator's faults. A status
    the recorder lost makes the onset earlier, so the latency longer (conservative). Leaves
    ``observable_ns`` unset when the bag shows no loss before the stop."""
    from ..bags import read_messages
    for bag, group in _by_bag(o for o in outcomes
                              if o.event.kind == "link" and o.event.fault == "loss" and o.stops and o.bag).items():
        js, status = set(), set()
        for topic, _, m in read_messages([bag], ["/joint_states", "/conformance/status"]):
            (js if topic == "/joint_states" else status).add(stamp_ns(m.header.stamp))
        for o in group:
            lost = [t for t in js - status if o.fault_ns <= t <= o.stops[0][0]]
            if lost:
                o.observable_ns = min(lost)


def judge_stops(outcomes):
    """Each stop's effect from its block's bag (:func:`reachset_ros.sim.campaign.judge_rest`):
    the recorded ``/joint_states`` from the stop's stamp to the reset. A killed simulator has
    no arm left to judge (the restarted one starts at rest): not judged."""
    from ..bags import read_messages
    for bag, group in _by_bag(o for o in outcomes if o.stops and o.reset_ns
                              and not (o.event.kind == "kill" and o.event.target == "sim_node")).items():
        t, q, qd, names = [], [], [], None
        for _, _, m in read_messages([bag], ["/joint_states"]):
            if names is None:
                names = list(m.name)
            if list(m.name) != names or len(m.position) != len(names) or len(m.velocity) != len(names):
                continue       # a stamp-jump sample of the campaign has the same names; others are not the sim's
            t.append(stamp_ns(m.header.stamp))
            q.append(m.position)
            qd.append(m.velocity)
        order = sorted(range(len(t)), key=t.__getitem__)
        t = [t[i] for i in order]
        q = [q[i] for i in order]
        qd = [qd[i] for i in order]
        for o in group:
            if not t:
                o.rest = {"ok": False, "why": "no /joint_states in the bag", "judged": 0}
                continue
            # from the stop's stamp; a stamp jump's stop carries the jumped sample's stamp: from the fault's
            o.rest = cp.judge_rest(o.event, names, t, q, qd, max(o.stops[0][0], o.fault_ns), o.reset_ns)
