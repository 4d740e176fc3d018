"""The fault campaign's runner (issue 17): the whole simulated system over real DDS, faults
from a seeded schedule (:mod:`reachset_ros.sim.campaign`), every stop measured.

``run_campaign`` starts the suite through the suite commander (:mod:`.commander`) as the
demo does (calibrated simulated LWA-4P, reference, observer, controller), records ``train``
s ``train_runs`` times with the initial gains, identifies the monitor's model from those
recordings with the inflation calibrated by cross-validation on them, each recording a fold
(``reachset identify BAG1 ... BAGn --calibrate n --calibrate-margin m``: m grid steps above
what the folds needed, for a run much longer than a fold), starts the monitor with it (a
monitor without a model does not run; its start-up stop is released by checked ticks of the
held arm, issue 34.1) and then runs the events: for each, a
fault-free stretch of monitored running, the fault, the wait for the stop, the braking it
causes, and the recovery (faults cleared, a killed process restarted, the monitor reset, the
arm tracking again for ``RECOVER_S`` without a stop; a stop during the recovery is counted
apart and the reset repeated). The monitor reads ``/joint_states`` through a relay
(:mod:`reachset_ros.nodes.relay_node`, remapped), which the link events make drop or delay
samples. Every block of 8 events is recorded to its own bag (the campaign's topics), named in
the outcome of each of its events, so a miss or a false stop comes with its data. CPU
burners (one busy process per core, normal priority) run during the blocks the schedule
says. After the run, each outcome is completed from the bags (:func:`judge_stops`,
:func:`frozen_before_motion`, :func:`link_onsets`, :func:`bag_brakes`; :func:`bag_stops` for a
re-score).
"""
from __future__ import annotations

import collections
import itertools
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path
from types import SimpleNamespace

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray
from reachset_msgs.msg import BrakeCommand, JointReference, SafeStop
from sensor_msgs.msg import JointState

from ..bags import SAFE_STOP_TOPIC, read_messages, read_references
from ..bags.messages import BRAKE_TOPIC
from ..nodes.common import SAFE_STOP_QOS, TICK_QOS, stamp_ns
from ..robot.lwa4p import default_nominal_path
from ..sim import campaign as cp
from ..sim.simulator import DT as SIM_DT
from ..errors import ReachsetError
from .commander import CORE_TOPICS, JOINTS, LOCKSTEP_TIMEOUT, MONITOR_TOPICS, open_commander
from .identify import IdentifyOptions, identify
from .demo import INITIAL_GAINS
from .worker import run_in_worker

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
#: events per recorded block (each block its own bag)
BLOCK = 8
BURNER = "while True:\n    pass\n"
#: the suite's nodes, in the order they start
SUITE = ("sim_node", "reference_node", "observer_node", "controller_node", "relay_node", "monitor_node")


class CampaignListener:
    """Distinct active stops with the simulation time and wall time of their arrival, and the
    controller's brake commands that carry a stop's arrival."""

    #: references kept per joint (the newest FROZEN_RUN and those since :meth:`observable_ns` last looked)
    REFS_KEPT = 5000
    REF_PERIOD_NS = int(round(SIM_DT * 1e9))

    def __init__(self, driver):
        self.driver = driver
        self.stops = []          # (stop stamp, arrival sim ns, reason, kind, arrival wall)
        self.seen = set()
        self.brakes = []         # (braking_since_ns, stop_received_ns)
        self.last_js = None
        driver.create_subscription(SafeStop, "safe_stop", self.on_stop, SAFE_STOP_QOS)
        driver.create_subscription(BrakeCommand, "brake_command", self.on_brake, TICK_QOS)
        driver.create_subscription(JointState, "joint_states", self.on_js, TICK_QOS)
        driver.create_subscription(JointReference, "reference", self.on_ref, TICK_QOS)
        # joint -> its newest references (stamp, qd_d): when a frozen sensor becomes observable
        # (:meth:`observable_ns`)
        self.refs = collections.defaultdict(lambda: collections.deque(maxlen=self.REFS_KEPT))
        self.received = collections.Counter()     # references received per joint
        self._checked = {}         # (joint, fault) -> (references looked at, the window's start or None)
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
            self.refs[n].append((t, v))
            self.received[n] += 1

    def observable_ns(self, joint, fault_ns):
        """When a frozen sensor of ``joint`` at ``fault_ns`` became observable, or None yet: the
        score's rule (:func:`~reachset_ros.sim.campaign.frozen_observable_ns`) on the references
        received since the previous call and the run before them, where the first run of
        ``FROZEN_RUN`` fast ticks ends (a few references per call, as often as the waits call)."""
        key = (joint, int(fault_ns))
        looked, found = self._checked.get(key, (0, None))
        n = self.received[joint]
        if found is None and n > looked:
            q = self.refs[joint]
            got = [r for r in itertools.islice(q, max(0, len(q) - (n - looked) - cp.FROZEN_RUN), len(q))
                   if r[0] >= fault_ns - 2 * self.REF_PERIOD_NS]
            found = cp.frozen_observable_ns([SimpleNamespace(stamps=np.array([r[0] for r in got], dtype=np.int64),
                                                             qd=np.array([r[1] for r in got]))], fault_ns)
            self._checked[key] = (n, found)
        return found


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


def run_campaign(*, workdir: Path, events, seed=1, train=20.0, log=print, model=None, train_runs=3,
                 calibrate_margin=0, realtime_priority=0, monitor_lockstep_ticks=None):
    """Run ``events`` (:func:`reachset_ros.sim.campaign.schedule`); returns ``(outcomes, info)``.

    ``model``: a model file for the monitor (skips the training recordings and the
    identification); ``calibrate_margin``: grid steps of inflation above the cross-validated
    one (``identify --calibrate-margin``); ``realtime_priority``: SCHED_FIFO priority of the
    simulator, reference, observer, controller, monitor and relay (0: the default policy;
    :mod:`reachset_ros.nodes.scheduling`); ``monitor_lockstep_ticks``: the simulator's
    parameter (``None``: its default; 0: the simulation does not wait for the monitor's
    verdicts); ``info`` has the model, its inflation (and the cross-validated one) and the
    nodes' logs directory."""
    workdir = Path(workdir).resolve()
    workdir.mkdir(parents=True, exist_ok=True)
    info = {"workdir": str(workdir), "seed": seed, "realtime_priority": int(realtime_priority),
            "monitor_lockstep_ticks": monitor_lockstep_ticks}
    with open_commander(workdir=workdir) as commander:
        run = _Campaign(commander=commander, workdir=workdir, log=log, info=info,
                        params=suite_parameters(workdir=workdir, seed=seed, realtime_priority=realtime_priority,
                                                monitor_lockstep_ticks=monitor_lockstep_ticks))
        try:
            run.start_suite()
            if model is None:
                model = run.train_model(train=train, train_runs=train_runs, calibrate_margin=calibrate_margin)
            info["model"] = str(model)
            outcomes = run.run_events(events, model=model)
            judge_stops(outcomes)
            frozen_before_motion(outcomes)
            link_onsets(outcomes)
            bag_brakes(outcomes)
            return outcomes, info
        finally:
            run.close()
            info["logs"] = str(workdir)


def suite_parameters(*, workdir, seed, realtime_priority, monitor_lockstep_ticks):
    """The ROS parameters of each of the campaign's nodes (:data:`SUITE`)."""
    common = {"joints": JOINTS, "allow_uncertified": True}
    params = {
        "sim_node": {"seed": seed, "calibrated": True, "lockstep_timeout": LOCKSTEP_TIMEOUT},
        # led moves: the training reaches the reference class' limits on every joint (the
        # synchronised moves alone left arm_2 at a third of qd_max: false stops on its fast moves)
        "reference_node": {"seed": seed, "lead": REFERENCE_LEAD},
        "observer_node": {**common, **INITIAL_GAINS},
        # the training runs unmonitored (no model yet): the controller waits for the monitor
        # only once one runs (set when it starts, for a restarted controller)
        # use_sim_time: the stop without estimates is timed on the lockstep simulation's clock
        "controller_node": {**common, **INITIAL_GAINS, "wait_for_monitor": False, "use_sim_time": True,
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
    return params


def identify_model(*, bags, folds, calibrate_margin, out):
    """The monitor's model from the training recordings: the identification workflow of
    ``reachset identify BAGS --calibrate FOLDS --calibrate-margin M --out OUT`` in a
    low-priority worker process (it must not starve the running suite); returns its ``--json``
    dict."""
    command = " ".join(["reachset identify", *map(str, bags), f"--calibrate {folds}",
                        f"--calibrate-margin {calibrate_margin}", f"--out {out}"])
    opts = IdentifyOptions(bags=tuple(map(str, bags)), calibrate=folds, calibrate_margin=calibrate_margin,
                           out=Path(out), command=command)
    try:
        return run_in_worker(identify, opts).to_json()
    except ReachsetError as e:
        raise RuntimeError(f"identify: {e}") from e


class _Campaign:
    """One campaign's state over a commander: the listener, the burners, the block's recorder."""

    def __init__(self, *, commander, workdir, log, info, params):
        self.cmd = commander
        self.workdir = workdir
        self.log = log
        self.info = info
        self.params = params
        self.remaps = {"monitor_node": {"joint_states": RELAYED}}
        self.lis = CampaignListener(commander)
        self.burners = Burners()
        self.jump_pub = commander.create_publisher(JointState, "joint_states", TICK_QOS)
        self.rec = None          # the current block's recorder

    def close(self):
        self.burners.off()
        if self.rec is not None:
            self.cmd.stop_processes([self.rec])
        self.cmd.stop_all()

    def start(self, name):
        return self.cmd.start(name, self.params[name], remap=self.remaps.get(name))

    def start_suite(self):
        """Every node but the monitor, which starts once its model exists (:meth:`start_monitor`)."""
        for name in SUITE:
            if name != "monitor_node":
                self.start(name)
        self.cmd.sim_wait(3.0)

    def start_monitor(self, model):
        """The monitor with ``model``, once its start-up stop is released (issue 34.1: a monitor
        without a model does not run); a controller restarted from now on waits for it."""
        self.params["monitor_node"]["model_file"] = str(model)
        self.params["controller_node"]["wait_for_monitor"] = True
        self.cmd.start_monitor(self.params["monitor_node"], remap=self.remaps.get("monitor_node"))

    def reset_monitor(self, o=None, patience_s=RESET_PATIENCE_S):
        """The monitor's ~/reset, tried again every 0.25 s of simulated time while it is refused
        because the stop's condition has not cleared (the arm still coming to rest); counted in
        ``o`` (an :class:`~reachset_ros.sim.campaign.Outcome`) when given."""
        r = self.cmd.reset_monitor(patience_s=patience_s)
        if o is not None:
            o.resets_refused += r.refused
            if not o.reset_ns:
                o.reset_ns = r.at_ns

    # ------------------------------------------------------------------ training
    def record_training(self, i, train):
        """Training recording ``i`` (unmonitored: no model yet), recorded again (up to
        TRAIN_TRIES times, the controller restarted first) while a brake engaged during it. The arm must move through the whole
        recording: a stop the controller latched on its own (a reference lost at start-up on
        a slow machine) held every brake through the training of a fresh-clone make test, and
        the model identified on the held arm stopped the campaign at once on fault-free
        running."""
        cmd, lis = self.cmd, self.lis
        bag = self.workdir / f"train{i}"
        for attempt in range(1, TRAIN_TRIES + 1):
            if attempt > 1:     # no monitor yet, no reset: a stop of the controller's own ends with it
                self.restart_node("controller_node", f"training{i}_try{attempt - 1}")
            cmd.sim_wait(0.5)   # brake commands still in flight from before
            braked0 = lis.braked
            r = cmd.record(bag, CORE_TOPICS, node_name=f"recorder_train{i}_{attempt}")
            cmd.sim_wait(train)
            cmd.stop_processes([r])
            if lis.braked == braked0:
                return bag
            self.log(f"[campaign] training recording {i}: a brake engaged during it ({lis.brake_reason}); "
                     f"recorded again ({attempt} of {TRAIN_TRIES})")
            shutil.rmtree(bag, ignore_errors=True)
        raise RuntimeError(f"training recording {i}: a brake engaged in each of {TRAIN_TRIES} tries "
                           f"(last: {lis.brake_reason})")

    def train_model(self, *, train, train_runs, calibrate_margin):
        """The training recordings and the monitor's model identified on them; its path."""
        info, log = self.info, self.log
        bags = [self.record_training(i, train) for i in range(1, train_runs + 1)]
        model = self.workdir / "monitor_model.yaml"
        res = identify_model(bags=bags, folds=train_runs, calibrate_margin=calibrate_margin, out=model)
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
        return model

    # ------------------------------------------------------------------ the events
    def block_bag(self, i):
        return self.workdir / f"block{i:03d}", f"recorder_block{i:03d}"

    def run_events(self, events, *, model):
        """The monitor gets ``model`` and is reset, then every event runs; its outcomes.

        The recorder of a block starts before the monitor judges (a process starting on the
        loaded machine is the campaign's apparatus, not a fault): the first before the reset,
        each next one at the end of the previous block (a stop it causes is reported as the
        apparatus', with the bag, and reset)."""
        cmd, info = self.cmd, self.info
        bag, name = self.block_bag(0)
        self.rec = cmd.record(bag, MONITOR_TOPICS, node_name=name)
        self.start_monitor(model)
        self.reset_monitor()
        cmd.sim_wait(RECOVER_S)
        wall0 = time.monotonic()
        apparatus = []
        outcomes = []
        for ev in events:
            if ev.index % BLOCK == 0 and ev.index > 0:
                bag = self.switch_block(ev.index // BLOCK, apparatus)
            self.log(f"[campaign] event {ev.index}: {ev.label()} (expect {ev.expect}; burners "
                     f"{'on' if ev.burners else 'off'}; {ev.quiet_s:g} s fault-free before)")
            outcomes.append(self.run_event(ev, bag))
        info["apparatus_stops"] = apparatus
        info["wall_s"] = time.monotonic() - wall0
        if self.rec is not None:
            cmd.stop_processes([self.rec])
            self.rec = None
        return outcomes

    def switch_block(self, i, apparatus):
        """Block ``i``'s recorder started, the previous one stopped; its bag. A stop meanwhile
        is the apparatus' (appended to ``apparatus`` with the bag) and reset."""
        cmd, lis = self.cmd, self.lis
        n = len(lis.stops)
        bag, name = self.block_bag(i)
        new = cmd.record(bag, MONITOR_TOPICS, node_name=name)
        cmd.stop_processes([self.rec])
        self.rec = new
        cmd.sim_wait(0.5)
        if len(lis.stops) > n:
            apparatus += [s[:3] + (str(bag),) for s in lis.stops[n:]]
            self.log(f"[campaign] stop while the recorder switched bags (apparatus): {lis.stops[n][2][:160]}")
            self.reset_monitor(patience_s=RESET_PATIENCE_S)
            cmd.sim_wait(RECOVER_S)
        return bag

    def run_event(self, ev, bag):
        """One event: the fault-free stretch, the fault, the wait for the stop, its braking and
        the recovery; its :class:`~reachset_ros.sim.campaign.Outcome`."""
        lis = self.lis
        o = cp.Outcome(ev, bag=str(bag))
        steps0 = dict(lis.sim_steps)
        self.burners.set(ev.burners)
        self.quiet_stretch(ev, o)
        n = len(lis.stops)
        nb = len(lis.brakes)
        wall0 = time.monotonic()
        window_wall = self.inject(ev, o, n)
        if window_wall is None:
            window_wall = wall0
        self.await_stop(ev, o, n, window_wall)
        o.stops = [s[:3] for s in lis.stops[n:]]
        if o.stops:
            self.measure_stop(ev, o, n, nb, wall0)
        elif ev.expect == "stop" and not o.note:
            o.note = NO_STOP_NOTE
            self.log(f"[campaign]   MISSED: no stop within {cp.detect_within_s(ev)} s")
        if o.stops or ev.kind in ("sim", "kill", "link"):
            self.recover(ev, o)
        # as reported so far (/diagnostics at 1 Hz)
        o.stale_steps = lis.sim_steps["stale_effort"] - steps0["stale_effort"]
        o.ahead_steps = lis.sim_steps["ahead_of_monitor"] - steps0["ahead_of_monitor"]
        return o

    def quiet_stretch(self, ev, o):
        """The fault-free stretch before ``ev``: a stop in it is a false stop, recovered from."""
        cmd, lis = self.cmd, self.lis
        n = len(lis.stops)
        t0 = cmd.sim_now()
        cmd.sim_wait(ev.quiet_s, until=lambda: len(lis.stops) > n)
        o.quiet_sim_s = (cmd.sim_now() - t0) * 1e-9
        if len(lis.stops) > n:
            o.quiet_stops = [s[:3] for s in lis.stops[n:]]
            self.log(f"[campaign]   FALSE STOP in the fault-free stretch: {lis.stops[n][2][:200]}")
            self.recover(ev if ev.kind == "none" else cp.Event(ev.index, "quiet", 0.0, "none"), o)
            o.reset_ns = 0      # that reset ended the false stop; the event's own stop is judged up to its own

    def inject(self, ev, o, n):
        """The event's fault (``o.fault_ns`` its stamp); ``n`` the stops before it. Returns the
        wall time the detection window starts at when later than the injection, else None."""
        cmd = self.cmd
        if ev.kind == "sim":
            return self.inject_sim(ev, o, n)
        if ev.kind == "kill":
            o.fault_ns = cmd.sim_now()
            cmd.kill(ev.target)
        elif ev.kind == "freeze":
            o.fault_ns = cmd.sim_now()
            cmd.freeze(ev.target, ev.seconds)
        elif ev.kind == "stamp_jump":
            self.inject_stamp_jump(ev, o)
        elif ev.kind == "link":
            o.fault_ns = cmd.sim_now()
            cmd.set_link(**{"loss": {"drop_share": ev.magnitude}, "sparse": {"drop_every": int(ev.magnitude)},
                            "delay": {"delay_s": ev.magnitude}}[ev.fault])
            if ev.expect == "none":        # the tolerated link faults last ev.seconds, then the watch below
                cmd.sim_wait(ev.seconds, until=lambda: len(self.lis.stops) > n)
                cmd.set_link()
        return None

    def inject_sim(self, ev, o, n):
        """A simulator fault; a frozen sensor's detection window starts at its joint's motion."""
        cmd, lis = self.cmd, self.lis
        cmd.onsets.clear()
        cmd.inject_fault(ev.fault, joint=ev.joint, magnitude=ev.magnitude)
        if not cmd.wait_for_onset(10.0):
            raise RuntimeError("no /sim/fault_onset after the injection")
        o.fault_ns = stamp_ns(cmd.onsets[-1].stamp)
        if ev.fault != "frozen":
            return None
        # observable only once the joint moves (for the stuck-sensor rule's FROZEN_RUN ticks):
        # wait (up to FROZEN_WAIT_S) for its reference to move so, the detection window starts there
        cmd.sim_wait(cp.FROZEN_WAIT_S, until=lambda: lis.observable_ns(ev.joint, o.fault_ns) is not None
                     or len(lis.stops) > n)
        seen = lis.observable_ns(ev.joint, o.fault_ns)
        o.observable_ns = max(o.fault_ns, seen or 0) if (seen is not None or len(lis.stops) > n) else 0
        return time.monotonic()   # the wall-time guard, too, starts with the window

    def inject_stamp_jump(self, ev, o):
        """A second publisher's ``/joint_states`` sample stamped ``ev.seconds`` before the newest."""
        js = self.lis.last_js
        o.fault_ns = self.cmd.sim_now()
        bad = JointState()
        bad.header.stamp.sec, bad.header.stamp.nanosec = divmod(
            stamp_ns(js.header.stamp) - int(ev.seconds * 1e9), 1_000_000_000)
        bad.name, bad.position, bad.velocity, bad.effort = list(js.name), list(js.position), \
            list(js.velocity), list(js.effort)
        self.jump_pub.publish(bad)

    def await_stop(self, ev, o, n, window_wall):
        """Spin until a new stop, the end of the event's detection window (an event that must
        stop) or its watch (one that must not)."""
        cmd, lis = self.cmd, self.lis
        if ev.expect == "stop" and ev.fault == "frozen" and not o.observable_ns:
            o.note = f"unobservable: the joint's reference did not move within {cp.FROZEN_WAIT_S:g} s"
            self.log(f"[campaign]   {o.note}")
        elif ev.expect == "stop":
            end = o.latency_from() + int(cp.detect_within_s(ev) * 1e9)
            # (from the window's start: a frozen sensor's joint may first move seconds after the
            # event began; the seventh long run lost a stop 20 ms after such a motion, 8.5 s in)
            wall_end = window_wall + cp.DETECT_WITHIN_WALL_S
            while len(lis.stops) == n and cmd.sim_now() < end and time.monotonic() < wall_end:
                cmd.spin_once(0.01)
        else:
            wall_end = time.monotonic() + 30.0
            t1 = cmd.sim_now()
            while len(lis.stops) == n and cmd.sim_now() < t1 + int(WATCH_S * 1e9) and time.monotonic() < wall_end:
                cmd.spin_once(0.02)

    def measure_stop(self, ev, o, n, nb, wall0):
        """The stop's wall latency and the braking it caused (``nb``: brake commands before)."""
        cmd, lis = self.cmd, self.lis
        o.wall_latency_s = lis.stops[n][4] - wall0
        if not (ev.kind == "kill" and ev.target == "controller_node"):
            cmd.spin_for(6.0, until=lambda: len(lis.brakes) > nb)
            mine = [b for b in lis.brakes[nb:] if b[1] > 0]
            if mine:
                o.braking_ticks = (mine[0][0] - mine[0][1]) / (SIM_DT * 1e9)   # in the loop's ticks
        after = o.latency_ns() * 1e-6
        self.log(f"[campaign]   stop {o.stops[0][2][:140]!r}: {after:.1f} ms after the "
                 f"fault (stop stamp {(o.stops[0][0] - o.fault_ns) * 1e-6:+.1f} ms), braking "
                 f"{o.braking_ticks} ticks after its arrival")

    def restart_node(self, name, suffix="restarted"):
        """Stop ``name`` (if still running) and start it again, its old log kept beside the new one."""
        proc = self.cmd.procs[name]
        self.cmd.stop_processes([proc], timeout=2.0)
        old = proc.log
        old.rename(old.with_name(f"{old.stem}.{suffix}.log"))
        self.start(name)

    def restart(self, ev):
        """The killed process of ``ev`` started again (its old log kept beside the new one)."""
        cmd = self.cmd
        self.restart_node(ev.target, f"killed_event{ev.index:03d}")
        if ev.target == "sim_node":   # a new simulation (new clock): wait for it
            c0 = cmd.sim_now()
            if not cmd.spin_for(60.0, until=lambda: cmd.sim_now() > c0 + 200_000_000):
                raise RuntimeError("the restarted sim_node does not tick")
        else:
            cmd.spin_for(3.0)

    def recover(self, ev, o):
        """Faults cleared, a killed process restarted, the monitor reset and the arm tracking
        for RECOVER_S without a stop (a stop meanwhile is counted in ``o.recovery_stops`` and
        the reset repeated, up to MAX_RESETS)."""
        cmd, lis = self.cmd, self.lis
        if ev.kind == "link":
            cmd.set_link()
        if ev.kind == "sim":
            cmd.clear_fault()
        if ev.kind == "kill":
            self.restart(ev)
        if o.stops and not (ev.kind == "kill" and ev.target == "sim_node"):
            # the stop's effect is judged from the bag up to the reset: let it show first (a
            # restarted simulator has a new clock and an arm at rest: nothing to wait for)
            left = (o.stops[0][0] - cmd.sim_now()) * 1e-9 + JUDGE_S
            if left > 0:
                cmd.sim_wait(left)
        for attempt in range(MAX_RESETS):
            self.reset_monitor(o)
            n = len(lis.stops)
            cmd.sim_wait(RECOVER_S, until=lambda: len(lis.stops) > n)
            if len(lis.stops) == n:
                return
            o.recovery_stops += 1
            self.log(f"[campaign]   recovery stop {attempt + 1}: {lis.stops[-1][2][:160]}")
            cmd.sim_wait(0.5)
        raise RuntimeError(f"no recovery after {ev.label()}: {MAX_RESETS} resets, each followed by a stop")


# ---------------------------------------------------------------------- the outcomes from the bags
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
    arrives, so the bag, not the runner's clock, decides (the same for a re-score); the window's
    start (``Outcome.observable_ns``) is set from the bag as well, so that a re-score of a run
    scored with an earlier rule (before 2026-11-28: the first fast reference) applies today's."""
    for bag, group in _by_bag(o for o in outcomes
                              if o.event.kind == "sim" and o.event.fault == "frozen" and o.stops and o.bag).items():
        refs = read_references([bag], joints=sorted({o.event.joint for o in group}))
        for o in group:
            # the joint's references from the fault to the stop: some recorded, none fast
            mine = refs.get(o.event.joint, [])
            recorded = any(np.any((r.stamps > o.fault_ns) & (r.stamps <= o.stops[0][0])) for r in mine)
            seen = cp.frozen_observable_ns(mine, o.fault_ns)
            o.stopped_before_motion = recorded and (seen is None or seen > o.stops[0][0])
            # the window's start, from the bag (a re-score applies today's rule); a stop before it
            # is reported with its latency from the fault
            o.observable_ns = o.fault_ns if seen is None or seen > o.stops[0][0] else max(o.fault_ns, seen)


def bag_stops(outcomes):
    """A stop the runner did not wait for, read from its block's bag: for each fault that must
    stop with no stop recorded, the first active ``/safe_stop`` stamped from the fault's stamp
    to the end of its detection window (which starts at ``observable_ns`` when set). Its
    arrival is taken as its stamp (the bag has no listener's arrival), and ``note`` says so.
    For re-scoring a run whose runner stopped waiting early (the wall-time guard of the seventh
    long run, counted from the event's start instead of the window's)."""
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
    for bag, group in _by_bag(o for o in outcomes
                              if o.event.kind == "link" and o.event.fault == "loss" and o.stops and o.bag).items():
        js, status = set(), set()
        for topic, _, m in read_messages([bag], ["/joint_states", "/conformance/status"]):
            (js if topic == "/joint_states" else status).add(stamp_ns(m.header.stamp))
        for o in group:
            lost = [t for t in js - status if o.fault_ns <= t <= o.stops[0][0]]
            if lost:
                o.observable_ns = min(lost)


def _joint_states(bag):
    """The sim's ``/joint_states`` of ``bag`` sorted by stamp: ``(names, stamps, q, qd)``."""
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
    return names, [t[i] for i in order], [q[i] for i in order], [qd[i] for i in order]


def judge_stops(outcomes):
    """Each stop's effect from its block's bag (:func:`reachset_ros.sim.campaign.judge_rest`):
    the recorded ``/joint_states`` from the stop's stamp to the reset. A killed simulator has
    no arm left to judge (the restarted one starts at rest): not judged."""
    for bag, group in _by_bag(o for o in outcomes if o.stops and o.reset_ns
                              and not (o.event.kind == "kill" and o.event.target == "sim_node")).items():
        names, t, q, qd = _joint_states(bag)
        for o in group:
            if not t:
                o.rest = {"ok": False, "why": "no /joint_states in the bag", "judged": 0}
                continue
            # from the stop's stamp; a stamp jump's stop carries the jumped sample's stamp: from the fault's
            o.rest = cp.judge_rest(o.event, names, t, q, qd, max(o.stops[0][0], o.fault_ns), o.reset_ns)
