"""The demo's conductor: a node that starts the others, records, synthesises, applies, injects.

``run_demo`` runs the whole story of ``reachset demo`` (see :mod:`reachset_ros.commands.demo`):
every node is a separate process talking over DDS; this process only starts/stops them,
calls their services and parameters, and listens to ``/safe_stop`` and ``/sim/fault_onset``.

The story's phases (training recordings, settling, the monitored run and the fault's
time in it) are timed on the simulation's clock (``/clock`` from sim_node, the driver and
the recorders run with ``use_sim_time``), as a simulation is, so that the story is the
same on a loaded machine where the simulation runs slower than real time: ``--duration
25 --inject-fault-at 18`` is 18 s of simulated, monitored motion before the fault. Each
phase's real-time factor (simulated / wall time) is reported.
"""
from __future__ import annotations

import json
import subprocess
import sys
import time
from dataclasses import replace
from pathlib import Path

import rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.signals import SignalHandlerOptions
from reachset_msgs.msg import SafeStop
from reachset_msgs.srv import Synthesize
from std_msgs.msg import Header
from std_srvs.srv import Trigger

from .. import launch
from ..conformance import model as mdl
from ..robot.dynamics import JOINT_NAMES, U_REF
from ..robot.lwa4p import default_nominal_path
from ..synthesis.config import config_path, load_config
from ..systems.gains import certified_inflation
from .common import SAFE_STOP_QOS, set_remote_parameters, stamp_ns

JOINTS = list(JOINT_NAMES)
CORE_TOPICS = ["/joint_states", "/plant_input", "/reference", "/observer/estimate", "/effort_commands"]
#: the simulated arm waits this long (s) for a late command before holding the previous one:
#: a held command is a disturbance the training data would then contain (a 250 ms stall of
#: the loaded 2-core machine once gave 6 such steps and sets 40x larger); below the monitor's
#: watchdog limit (125 ticks = 0.5 s) so that a stall is not taken for missing data
LOCKSTEP_TIMEOUT = 0.3
MONITOR_TOPICS = CORE_TOPICS + ["/conformance/status", "/safe_stop", "/diagnostics", "/sim/fault_onset",
                                 "/brake_command"]
#: the gains the demo starts with (observer and controller parameters, one value for all joints)
INITIAL_GAINS = {"observer": "hg", "controller": "static", "omega": [15.0], "zeta": [1.0],
                 "h1": [15.0], "h2": [30.0], "eps": [0.01]}


def wall_limit(seconds):
    """Wall time (s) after which a phase of ``seconds`` simulated seconds fails: the
    simulation then runs at less than about a fifth of real time (a stalled or dead node)."""
    return 30.0 + 5.0 * seconds


class DemoDriver(Node):
    """The conductor's node; ``stop`` (a :class:`reachset_ros.launch.StopRequest`) is looked at
    after every spin, where :class:`reachset_ros.launch.Interrupted` ends the story."""

    def __init__(self, stop=None):
        super().__init__("demo_driver", parameter_overrides=[Parameter("use_sim_time", value=True)])
        self.stop = stop
        self.stops = []
        self.onsets = []
        self.create_subscription(SafeStop, "safe_stop", lambda m: self.stops.append(m), SAFE_STOP_QOS)
        self.create_subscription(Header, "sim/fault_onset", lambda m: self.onsets.append(m), SAFE_STOP_QOS)
        # its own executor: /clock wakes it every tick, and rclpy.spin_once would add the node
        # to the global executor and remove it again at each wake-up. Not the nodes'
        # EventsExecutor: with it, this process once hung in rclpy's shutdown (in
        # Context._logging_fini) after the demo had finished.
        self.own_executor = SingleThreadedExecutor()   # Node.executor holds only a weak reference
        self.own_executor.add_node(self)

    def spin_once(self, timeout_sec):
        self.own_executor.spin_once(timeout_sec=timeout_sec)
        if self.stop is not None:
            self.stop.check()

    def spin_for(self, seconds, until=None):
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            self.spin_once(0.05)
            if until is not None and until():
                return True
        return False

    def sim_now(self):
        """The simulation's time, ns (0 before the first ``/clock``)."""
        return self.get_clock().now().nanoseconds

    def spin_sim(self, seconds, until=None, since=None):
        """Spin for ``seconds`` of simulated time (from ``since``, ns, default now), or until
        ``until()``; returns ``(until_met, real_time_factor)``. Raises when the simulation
        does not advance that far within ``wall_limit(seconds)`` of wall time."""
        wall0 = time.monotonic()
        wall_end = wall0 + wall_limit(seconds)
        while self.sim_now() == 0:
            if time.monotonic() > wall_end:
                raise RuntimeError("no /clock from sim_node: the simulation is not running")
            self.spin_once(0.05)
        start = since if since is not None else self.sim_now()
        sim0, end = self.sim_now(), start + int(seconds * 1e9)
        met = False
        while self.sim_now() < end:
            if time.monotonic() > wall_end:
                raise RuntimeError(f"the simulation advanced {(self.sim_now() - sim0) * 1e-9:.1f} s in "
                                   f"{time.monotonic() - wall0:.0f} s of wall time: a node is stalled or dead")
            self.spin_once(0.05)
            if until is not None and until():
                met = True
                break
        wall = time.monotonic() - wall0
        return met, ((self.sim_now() - sim0) * 1e-9 / wall if wall > 0 else float("nan"))

    def call(self, srv_type, name, request, timeout=600.0):
        client = self.create_client(srv_type, name)
        try:
            if not client.wait_for_service(timeout_sec=30.0):
                raise RuntimeError(f"service {name} not available")
            fut = client.call_async(request)
            end = time.monotonic() + timeout
            while not fut.done() and time.monotonic() < end:
                self.spin_once(0.1)
            if not fut.done():
                raise RuntimeError(f"service {name} timed out after {timeout:.0f} s")
            return fut.result()
        finally:
            self.destroy_client(client)


def run_demo(workdir: Path, record: Path, duration: float, fault_at: float | None, train: float,
             seed: int = 1, log=print, fault=("acceleration", "arm_1_joint", 30.0), initial=None,
             inflation=None, settle=3.0, stop=None):
    """Run the demo; returns a dict of what happened (stamps in ns of the stamp clock).

    The simulated arm is the LWA-4P calibrated to the real one (``sim_node`` ``calibrated``;
    the controller linearizes with the identified nominal model). The synthesis bounds the
    reference error over the reference generator's whole class (``--reference-class
    qdd_max=U_REF``, Appendix B), so ``R*_e`` covers the monitored run's motions, which the
    training runs did not record.

    ``inflation``: the monitor checks against the identified sets scaled by ``1 + inflation``
    (the model's ``inflation``). None (default): calibrated by 2-fold cross-validation on the
    two training recordings (``reachset identify BAG1 BAG2 --calibrate 2 --initial-state-set``,
    :mod:`reachset_ros.conformance.calibration`), and the second synthesis is certified for
    it. ``stop``: a :class:`reachset_ros.launch.StopRequest`; once it
    has a signal, the next spin raises :class:`reachset_ros.launch.Interrupted` and every node
    started is stopped before it propagates. The nodes run in this process' ``ROS_DOMAIN_ID``
    (``reachset demo`` sets a fresh one)."""
    workdir.mkdir(parents=True, exist_ok=True)
    initial = initial or INITIAL_GAINS
    out = {"phases": [], "real_time_factor": {}}
    procs = []
    own = not rclpy.ok()
    if own:   # signals are the caller's (StopRequest), not rclpy's (which would shut the context down)
        launch.use_dds_profiles()
        rclpy.init(signal_handler_options=SignalHandlerOptions.NO)
    driver = DemoDriver(stop)
    try:
        # the initial gains run before any model exists (identification data): explicitly
        # uncertified; the synthesised gains are certified against the synthesised model
        common = {"joints": JOINTS, "allow_uncertified": True}
        launch.start("sim_node", {"seed": seed, "calibrated": True, "lockstep_timeout": LOCKSTEP_TIMEOUT}, workdir,
                     group=procs)
        launch.start("reference_node", {"seed": seed}, workdir, group=procs)
        launch.start("observer_node", {**common, **initial}, workdir, group=procs)
        launch.start("controller_node", {**common, **initial, "wait_for_monitor": True,
                                         "robot_params": str(default_nominal_path())}, workdir, group=procs)
        launch.start("monitor_node", {"window_dir": str(workdir / "windows"), "max_missing_ticks": 125},
                     workdir, group=procs)
        cfg = config_path()
        demo_cfg = cfg.parent / "demo_synthesis.yaml" if cfg is not None else None
        demo_cfg = demo_cfg if demo_cfg is not None and demo_cfg.is_file() else None
        extra = ["--config", str(demo_cfg)] if demo_cfg is not None else []
        # R*_e and R*_u for every reference the reference node can send (its U_ref), not only the
        # recorded ones: the monitored run's motions are new samples of that class
        extra += ["--reference-class", f"qdd_max={U_REF:g}"]
        hg = load_config(demo_cfg)["structures"]["hg"]
        out["search_box"] = {n: [float(x) for x in hg["bounds"][n]] for n in hg["free"]}
        # the gains are synthesised for the sets the monitor will check (inflated by 1 + inflation),
        # so R*_u inside U_p is certified for them (synthesize --inflation); the first synthesis,
        # before the inflation is calibrated, for the sets as identified
        launch.start("synthesis_node", {"workdir": str(workdir / "synthesis"), "extra_args": extra,
                                        "inflation": float(inflation or 0.0)}, workdir, group=procs)

        def record_phase(name, seconds, topics, path):
            node = "recorder_node_" + name.replace(" ", "_")
            rec = launch.start("recorder_node", {"output": str(path), "topics": topics, "use_sim_time": True},
                               workdir, node_name=node, group=procs)   # stopped with the others if a phase fails
            # recording starts when the recorder has subscribed to every topic (a loaded machine
            # can take many seconds to start a process), not after a fixed pause
            if not driver.spin_for(60.0, until=lambda: all(
                    any(i.node_name == node for i in driver.get_subscriptions_info_by_topic(t)) for t in topics)):
                raise RuntimeError(f"{node} did not subscribe to {topics} within 60 s")
            driver.spin_for(0.5)  # matching with the publishers
            log(f"[demo] {name}: recording {seconds:.0f} s of simulated time to {path}")
            return rec, driver.sim_now()

        def timed(name, seconds, **kw):
            met, rtf = driver.spin_sim(seconds, **kw)
            out["real_time_factor"][name] = round(rtf, 3)
            return met

        # 0. the controller holds the arm until the monitor's start state reaches it (a slow
        # start on a loaded machine: seconds), while the reference runs on; the release is a
        # jump that saturates the torques for a few ticks, where the recorded u_p is not the
        # applied one. Identification data start after it has settled.
        if not driver.spin_for(120.0, until=lambda: bool(driver.stops)):
            raise RuntimeError("no /safe_stop state from the monitor within 120 s")
        timed("start-up", settle)
        # 1. initial gains, recorded for identification and synthesis
        bag1 = workdir / "train_initial_gains"
        rec, _ = record_phase("initial", train, CORE_TOPICS, bag1)
        timed("initial gains", train)
        launch.stop([rec])
        out["phases"].append({"name": "initial gains", "bag": str(bag1), "gains": initial})
        # 2. combined synthesis on that bag, applied live through the parameter services
        # training phases run unmonitored: the monitor gets the model only after re-identification
        ok, why = set_remote_parameters(driver, "synthesis_node", {"targets": ["controller_node", "observer_node"]})
        if not ok:
            raise RuntimeError(f"synthesis node: {why}")
        log("[demo] synthesis node: combined synthesis on the recorded bag")
        req = Synthesize.Request(bags=[str(bag1)], joints=JOINTS, mode="combined", apply=True)
        res = driver.call(Synthesize, "/synthesis_node/synthesize", req)
        out["synthesis"] = _result_dict(res)
        if not res.success:
            raise RuntimeError(f"synthesis failed: {res.message}")
        log(f"[demo] synthesised and applied: {res.message}")
        # 3. run with the new gains, re-identify the sets (paper Sec. III-D, iteration 2)
        bag2 = workdir / "train_new_gains"
        rec, _ = record_phase("new gains", train, CORE_TOPICS, bag2)
        timed("new gains", train)
        launch.stop([rec])
        if inflation is None:
            inflation, out["inflation_calibration"] = calibrate_inflation([bag1, bag2], workdir)
            log(f"[demo] inflation calibrated by 2-fold cross-validation on the training recordings: {inflation:g}")
            ok, why = set_remote_parameters(driver, "synthesis_node", {"inflation": float(inflation)})
            if not ok:
                raise RuntimeError(f"synthesis node: {why}")
        log("[demo] synthesis node: second iteration, combined synthesis on both recordings")
        req = Synthesize.Request(bags=[str(bag1), str(bag2)], joints=JOINTS, mode="combined", apply=True)
        res2 = driver.call(Synthesize, "/synthesis_node/synthesize", req)
        out["reidentify"] = _result_dict(res2)
        if res2.success:
            res = res2
        else:
            # keep the first iteration's gains (still running) and model; say so
            out["second_iteration_failed"] = res2.message
            out["reidentify"] = out["synthesis"]
            log(f"[demo] second iteration not applied ({res2.message}); keeping the first iteration's "
                "gains and model")
        # let the transient of the live gain change settle before monitoring starts: the
        # switch itself (estimates and commands jump) is not a motion the training covered
        timed("settle", settle)
        # the monitor gets the synthesised model, whose gains were synthesised and certified for
        # the demo's inflation of the sets (synthesize --inflation): R*_u inside U_p holds for the
        # sets it checks. The certificate is checked again here (systems.gains.certify); if it
        # did not cover the inflation the demo would say so (NOT CERTIFIED) and record it.
        monitor_model = workdir / "monitor_model.yaml"
        synthesized = mdl.load(res.result.model_file)
        used, per_joint = certified_inflation(synthesized, float(inflation))
        if used < float(inflation):
            log(f"[demo] NOT CERTIFIED: the monitor's inflation {inflation:g} is beyond the R*_u certificate of "
                f"the synthesised gains (largest certified per joint: "
                + ", ".join(f"{j} {v:.4g}" for j, v in per_joint.items())
                + "); the monitor's sets are a detection threshold here, not a guarantee")
        mdl.save(replace(synthesized, inflation=float(inflation)), monitor_model)
        ok, why = set_remote_parameters(driver, "monitor_node", {"model_file": str(monitor_model)})
        if not ok:
            raise RuntimeError(f"monitor refused the model: {why}")
        out["monitor_model"] = str(monitor_model)
        out["inflation_requested"] = float(inflation)
        out["inflation_certified"] = per_joint
        out["inflation_is_certified"] = bool(used >= float(inflation))
        out["inflation"] = float(inflation)
        out["margin"] = out["inflation"]   # deprecated name of "inflation", kept for readers of old results
        # 4. monitored run, fault injected (the monitor starts fresh with the new model)
        reset = driver.call(Trigger, "/monitor_node/reset", Trigger.Request(), timeout=30.0)
        if not reset.success:
            raise RuntimeError(f"monitor reset failed: {reset.message}")
        driver.stops.clear()
        rec, t0 = record_phase("monitored", duration, MONITOR_TOPICS, record)
        if fault_at is not None and fault_at < duration:
            timed("monitored before the fault", fault_at, until=lambda: bool([s for s in driver.stops if s.active]))
            early = [s for s in driver.stops if s.active]
            if early:
                out["early_stop"] = {"reason": early[0].reason, "stamp_ns": stamp_ns(early[0].header.stamp)}
            kind, joint, mag = fault
            ok, why = set_remote_parameters(driver, "sim_node", {"fault_joint": joint, "fault_magnitude": float(mag),
                                                                  "fault": kind})
            if not ok:
                raise RuntimeError(f"fault injection refused: {why}")
            driver.spin_for(2.0, until=lambda: bool(driver.onsets))
            timed("monitored after the fault", duration, since=t0)
        else:
            timed("monitored", duration)
        launch.stop([rec])
        active = [s for s in driver.stops if s.active]
        out["fault_injected_ns"] = stamp_ns(driver.onsets[0].stamp) if driver.onsets else None
        out["fault"] = driver.onsets[0].frame_id if driver.onsets else None
        out["safe_stop_ns"] = stamp_ns(active[0].header.stamp) if active else None
        out["safe_stop"] = ({"reason": active[0].reason, "kind": active[0].kind, "joint": active[0].joint,
                             "step": active[0].step, "window_bag": active[0].window_bag} if active else None)
        out["record"] = str(record)
        return out
    finally:
        launch.stop(procs)
        driver.own_executor.shutdown(timeout_sec=1.0)
        driver.destroy_node()
        if own:
            rclpy.try_shutdown()


def calibrate_inflation(bags, workdir):
    """The monitor's inflation from the training recordings alone: ``reachset identify BAGS
    --calibrate 2 --initial-state-set --json`` (the synthesis' Theorem-1 rows; each recording a
    fold: the sets identified on one must hold on the other, :func:`reachset_ros.conformance.calibration.cross_validate`). Returns
    ``(inflation, details)``; a flagged joint (no grid value held) is reported, and its
    largest grid value is used."""
    cmd = [sys.executable, "-m", "reachset_ros.cli", "identify", *map(str, bags), "--calibrate", "2",
           "--initial-state-set", "--json"]
    # at low priority, as the synthesis node's child: it must not starve the running nodes
    p = launch.start_background(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    out, err = p.communicate()
    (Path(workdir) / "calibration.log").write_text(err)
    if p.returncode != 0:
        raise RuntimeError("inflation calibration failed: " + ((err.strip().splitlines() or ["?"])[-1]))
    r = json.loads(out)
    per = {n: float(j["inflation"]) for n, j in r["joints"].items()}
    flagged = [n for n, j in r["joints"].items() if j["calibration"].get("flagged")]
    return float(r["inflation"]), {"folds": 2, "command": " ".join(cmd[2:]), "per_joint": per, "flagged": flagged}


def _result_dict(res):
    r = res.result
    return {"success": res.success, "message": res.message, "model_file": r.model_file, "applied": r.applied,
            "joints": {j.name: {"re_norm": j.re_norm, "re_radius": list(j.re_radius), "ru": [j.ru_lower, j.ru_upper],
                                "alpha_w": list(j.alpha_w), "alpha_v": list(j.alpha_v),
                                "gains": dict(zip(j.param_names, j.param_values)), "observer": j.observer,
                                "controller": j.controller, "conformant": j.conformant,
                                "test_cases": j.test_cases}
                       for j in r.joints}}
