"""The story of ``reachset demo``: start the suite, record, synthesise, apply, monitor, inject.

``run_demo`` runs the whole story (see :mod:`reachset_ros.commands.demo`) through the
suite commander (:mod:`.commander`): every node is a separate process talking over DDS;
this process only starts/stops them, calls their services and parameters, and listens to
``/safe_stop`` and ``/sim/fault_onset``.

The story's phases (training recordings, settling, the monitored run and the fault's
time in it) are timed on the simulation's clock (``/clock`` from sim_node, the commander and
the recorders run with ``use_sim_time``), as a simulation is, so that the story is the
same on a loaded machine where the simulation runs slower than real time: ``--duration
25 --inject-fault-at 18`` is 18 s of simulated, monitored motion before the fault. Each
phase's real-time factor (simulated / wall time) is reported.
"""
from __future__ import annotations

from dataclasses import replace
from pathlib import Path

from .. import defaults
from ..conformance import model as mdl
from ..errors import ReachsetError
from ..nodes.common import get_remote_parameters, stamp_ns
from ..robot.dynamics import U_REF
from ..robot.lwa4p import default_nominal_path
from ..synthesis.config import config_path, load_config
from ..systems.gains import certified_inflation
from .commander import CORE_TOPICS, JOINTS, LOCKSTEP_TIMEOUT, MONITOR_TOPICS, open_commander, wall_limit
from .calibrate import calibrate_model
from .identify import IdentifyOptions, identify
from .worker import run_in_worker

__all__ = ["CORE_TOPICS", "INITIAL_GAINS", "JOINTS", "LOCKSTEP_TIMEOUT", "MONITOR_TOPICS", "calibrate_inflation",
           "run_demo", "wall_limit"]

#: the gains the demo starts with (observer and controller parameters, one value for all joints)
defaults.register("demo", {
    "initial_gains": ({"observer": "hg", "controller": "static", "omega": [15.0], "zeta": [1.0],
                       "h1": [15.0], "h2": [30.0], "eps": [0.01]},
                      "the gains the demo and the fault campaign start the observer and controller nodes "
                      "with, to record their training data: the HG observer of Sec. IV-A (defaults "
                      "gains.hg) with a static law between the nodes' start-up law (omega 10) and the "
                      "paper's (omega 20), one value for all joints"),
}, owner=__name__)
defaults.register("demo", {
    "training_lockstep_timeout": (1.0, "s; while the demo's simulation is held and stepped a fixed count per phase "
                                       "(training, synthesis), a step waits this long for its command before holding "
                                       "the previous one (sim_node lockstep_timeout): no stale step on a loaded "
                                       "machine (issue 35.4)"),
    "reference_lead": (1.0, "share of the reference node's moves led by one joint (in turn) at the class' full "
                            "qd_max and qdd_max (reference_node lead): the demo's 20 s training recordings reach the "
                            "class' limits on every joint, so the calibration's folds see each joint's need (issue "
                            "35.3; 0.0 left joints at a third of qd_max and calibrated 2.0-5.0)"),
    "training_reference_timeout": (0.5, "s; the controller's reference_timeout in the demo's training phases: it "
                                        "waits this long for a reference before carrying an older one forward"),
}, owner=__name__)
TRAINING_LOCKSTEP_TIMEOUT = defaults.get("demo.training_lockstep_timeout")
TRAINING_REFERENCE_TIMEOUT = defaults.get("demo.training_reference_timeout")
#: the observer and controller nodes' parameters of the training runs (defaults ``demo.initial_gains``)
INITIAL_GAINS = defaults.get("demo.initial_gains")


def run_demo(*, workdir: Path, record: Path, duration: float, fault_at: float | None, train: float,
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
    two training recordings (``reachset identify BAG1 BAG2 --calibrate 2 --initial-state-set --estimator fd``,
    :mod:`reachset_ros.conformance.calibration`), and the second synthesis is certified for
    it. ``stop``: a :class:`reachset_ros.processes.StopRequest`; once it
    has a signal, the next spin raises :class:`reachset_ros.processes.Interrupted` and every node
    started is stopped before it propagates. The nodes run in this process' ``ROS_DOMAIN_ID``
    (``reachset demo`` sets a fresh one)."""
    workdir.mkdir(parents=True, exist_ok=True)
    initial = initial or INITIAL_GAINS
    with open_commander(workdir=workdir, stop=stop) as commander:
        story = _Story(commander=commander, workdir=workdir, log=log, settle=settle)
        story.start_suite(seed=seed, initial=initial, inflation=inflation)
        # 0. the loop starts (unmonitored: no model exists yet); identification data start
        # after its start-up transient has settled
        story.timed("start-up", settle)
        calibrate = inflation is None
        res, inflation = story.train_and_synthesize(train=train, initial=initial, inflation=inflation)
        story.apply_monitor_model(res, inflation=inflation, calibrate=calibrate)
        story.monitored_run(record=record, duration=duration, fault_at=fault_at, fault=fault)
        story.out["bringup"] = write_bringup(workdir=workdir, seed=seed, model=Path(story.out["monitor_model"]))
        return story.out


class _Story:
    """The demo's phases over one commander; ``out`` collects what happened."""

    def __init__(self, *, commander, workdir, log, settle):
        self.cmd = commander
        self.workdir = workdir
        self.log = log
        self.settle = settle
        self.out = {"phases": [], "real_time_factor": {}}
        self.held = False            # the simulation steps only as far as the workflow lets it
        self.reference_timeout = None

    def start_suite(self, *, seed, initial, inflation):
        """Start the simulated arm, reference, observer, controller and synthesis node. The
        training phases run unmonitored (simulation only, the initial gains explicitly
        uncertified): the monitor starts once its model exists (:meth:`apply_monitor_model`;
        a monitor without a model does not run, issue 34.1), so the controller does not wait
        for it here."""
        cmd, workdir = self.cmd, self.workdir
        # the initial gains run before any model exists (identification data): explicitly
        # uncertified; the synthesised gains are certified against the synthesised model
        common = {"joints": JOINTS, "allow_uncertified": True}
        # held (measurement_limit 0) until the loop is up, and stepped a fixed count per phase
        # until the monitor starts (issue 35.4); a step waits up to TRAINING_LOCKSTEP_TIMEOUT for
        # its command, the controller up to TRAINING_REFERENCE_TIMEOUT for its reference: the
        # training recordings are a function of the seed, not of the machine's load
        cmd.start("sim_node", {"seed": seed, "calibrated": True, "measurement_limit": 0,
                               "lockstep_timeout": TRAINING_LOCKSTEP_TIMEOUT})
        cmd.start("reference_node", {"seed": seed, "lead": float(defaults.get("demo.reference_lead"))})
        cmd.start("observer_node", {**common, **initial})
        # use_sim_time: the stop without estimates is timed on the lockstep simulation's clock
        cmd.start("controller_node", {**common, **initial, "wait_for_monitor": False, "use_sim_time": True,
                                      "robot_params": str(default_nominal_path())})
        extra, self.out["search_box"] = synthesis_arguments()
        # the gains are synthesised for the sets the monitor will check (inflated by 1 + inflation),
        # so R*_u inside U_p is certified for them (synthesize --inflation); the first synthesis,
        # before the inflation is calibrated, for the sets as identified
        cmd.start("synthesis_node", {"workdir": str(workdir / "synthesis"), "extra_args": extra,
                                     "inflation": float(inflation or 0.0)})
        cmd.wait_for_loop()
        values, why = get_remote_parameters(cmd, "controller_node", ["reference_timeout"])
        if values is None:
            raise RuntimeError(f"controller node: {why}")
        self.reference_timeout = float(values["reference_timeout"])     # its own, for the monitored run
        cmd.set_parameters("controller_node", {"reference_timeout": float(TRAINING_REFERENCE_TIMEOUT)},
                           refused="controller node")
        self.held = True

    def release(self):
        """The simulation runs on without a step limit, with the monitored run's timeouts: a
        command or reference later than LOCKSTEP_TIMEOUT (below the monitor's watchdog) or the
        controller's default ``reference_timeout`` is then a late one, as on a real arm."""
        cmd = self.cmd
        cmd.set_parameters("sim_node", {"lockstep_timeout": LOCKSTEP_TIMEOUT}, refused="sim node")
        cmd.set_parameters("controller_node", {"reference_timeout": self.reference_timeout},
                           refused="controller node")
        cmd.release_sim()
        self.held = False

    def record_phase(self, name, seconds, topics, path):
        """A recorder started (stopped with the others if a phase fails); ``(process, sim ns)``."""
        node = "recorder_node_" + name.replace(" ", "_")
        rec = self.cmd.record(path, topics, node_name=node)
        self.log(f"[demo] {name}: recording {seconds:.0f} s of simulated time to {path}")
        return rec, self.cmd.sim_now()

    def timed(self, name, seconds, **kw):
        """Spin ``seconds`` of simulated time; the phase's real-time factor goes to ``out``."""
        met, rtf = self.cmd.run_steps(seconds) if self.held and not kw else self.cmd.spin_sim(seconds, **kw)
        self.out["real_time_factor"][name] = round(rtf, 3)
        return met

    def train(self, *, recording, phase, seconds, path):
        """A training recording ``recording`` of ``seconds`` simulated s (timed as ``phase``)."""
        rec, _ = self.record_phase(recording, seconds, CORE_TOPICS, path)
        self.timed(phase, seconds)
        self.cmd.spin_for(0.5)     # held: the last step's estimate and commands reach the recorder
        self.cmd.stop_processes([rec])

    def train_and_synthesize(self, *, train, initial, inflation):
        """Phases 1-3: the training recordings, the two synthesis iterations (paper Sec. III-D)
        and, when ``inflation`` is None, its calibration; returns ``(response, inflation)``."""
        cmd, out, log, workdir = self.cmd, self.out, self.log, self.workdir
        # 1. initial gains, recorded for identification and synthesis
        bag1 = workdir / "train_initial_gains"
        self.train(recording="initial", phase="initial gains", seconds=train, path=bag1)
        out["phases"].append({"name": "initial gains", "bag": str(bag1), "gains": initial})
        # 2. combined synthesis on that bag, applied live through the parameter services
        # training phases run unmonitored: the monitor gets the model only after re-identification
        cmd.set_parameters("synthesis_node", {"targets": ["controller_node", "observer_node"]},
                           refused="synthesis node")
        log("[demo] synthesis node: combined synthesis on the recorded bag")
        res = cmd.synthesize([bag1], joints=JOINTS)
        out["synthesis"] = _result_dict(res)
        if not res.success:
            raise RuntimeError(f"synthesis failed: {res.message}")
        log(f"[demo] synthesised and applied: {res.message}")
        # the held arm switched gains: the switch's transient settles before the next recording
        self.timed("settle after the new gains", self.settle)
        # 3. run with the new gains, re-identify the sets (paper Sec. III-D, iteration 2)
        bag2 = workdir / "train_new_gains"
        self.training_bags = [bag1, bag2]
        self.train(recording="new gains", phase="new gains", seconds=train, path=bag2)
        if inflation is None:
            inflation, out["inflation_calibration"] = calibrate_inflation(bags=[bag1, bag2], workdir=workdir)
            log(f"[demo] inflation calibrated by 2-fold cross-validation on the training recordings: {inflation:g}")
            cmd.set_parameters("synthesis_node", {"inflation": float(inflation)}, refused="synthesis node")
        log("[demo] synthesis node: second iteration, combined synthesis on both recordings")
        res2 = cmd.synthesize([bag1, bag2], joints=JOINTS)
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
        self.timed("settle", self.settle)
        return res, inflation

    def apply_monitor_model(self, res, *, inflation, calibrate=False):
        """The monitor gets the synthesised model, whose gains were synthesised and certified for
        the demo's inflation of the sets (synthesize --inflation): R*_u inside U_p holds for the
        sets it checks. ``calibrate``: that inflation was calibrated on identify's sets, so it is
        calibrated again on the synthesised sets the monitor checks (issue 34.11,
        :func:`reachset_ros.workflows.calibrate.calibrate_model`, 2 folds of the training
        recordings; the model records it); each joint's inflation is the larger of its two values
        (issue 35.1: per joint, at most the one the gains were synthesised for when the joint's own
        recalibration needs no more). The certificate is checked again here, per joint, for the
        joint's own inflation (systems.gains.certified_inflation); if it did not cover the
        inflation the demo says so (NOT CERTIFIED) and records it."""
        out, workdir = self.out, self.workdir
        monitor_model = workdir / "monitor_model.yaml"
        synthesized = mdl.load(res.result.model_file)
        monitor = replace(synthesized.with_inflation(float(inflation)), calibration=None)    # a given inflation
        if calibrate:
            # per joint at least its inflation calibrated on identify's sets (the synthesis was for
            # the largest of them, so each is certified; a larger one only grows the sets)
            floor = (out.get("inflation_calibration") or {}).get("per_joint") or float(inflation)
            cm = run_in_worker(calibrate_model, synthesized, bags=[str(b) for b in self.training_bags], folds=2,
                               floor=floor)
            monitor, inflation = cm.model, cm.model.largest_inflation()
            self.log(f"[demo] inflation calibrated again on the synthesised sets the monitor checks: "
                     f"{cm.calibrated:g}; the monitor's {inflation:g}")
            out.setdefault("inflation_calibration", {})["monitor_sets"] = {
                "calibrated": cm.calibrated, "inflation": float(inflation),
                "per_joint": cm.model.calibration["per_joint"], "rule": cm.rule["sets"]}
        _, per_joint = certified_inflation(synthesized, float(inflation))
        certified = all(monitor.joint_inflation(j) <= per_joint[j] for j in per_joint)
        if not certified:
            self.log(f"[demo] NOT CERTIFIED: the monitor's inflation {inflation:g} is beyond the R*_u certificate "
                     f"of the synthesised gains (largest certified per joint: "
                     + ", ".join(f"{j} {v:.4g}" for j, v in per_joint.items())
                     + "); the monitor's sets are a detection threshold here, not a guarantee")
        mdl.save(monitor, monitor_model)
        self.release()
        # the monitor starts with its model and a stop (not ready): the controller brakes and
        # holds the arm, the reference rests at it, k*+1 checked ticks of the held arm release
        # the stop, and the reference restarts from the arm's position (no jump); the loop
        # settles before the monitored run
        self.cmd.start_monitor({"window_dir": str(workdir / "windows"), "max_missing_ticks": 125,
                                "model_file": str(monitor_model)})
        self.timed("monitor start-up", self.settle)
        out["monitor_model"] = str(monitor_model)
        out["inflation_requested"] = float(inflation)
        out["inflation_certified"] = per_joint
        out["inflation_is_certified"] = bool(certified)
        out["inflation"] = float(inflation)
        out["inflations"] = monitor.inflations()    # each joint's, the monitor's sets (issue 35.1)
        out["margin"] = out["inflation"]   # deprecated name of "inflation", kept for readers of old results

    def monitored_run(self, *, record, duration, fault_at, fault):
        """Phase 4: the monitored run, fault injected (the monitor starts fresh with the new model)."""
        cmd, out = self.cmd, self.out
        cmd.reset_monitor()
        cmd.stops.clear()
        rec, t0 = self.record_phase("monitored", duration, MONITOR_TOPICS, record)
        if fault_at is not None and fault_at < duration:
            self.timed("monitored before the fault", fault_at, until=lambda: bool(cmd.active_stops()))
            early = cmd.active_stops()
            if early:
                out["early_stop"] = {"reason": early[0].reason, "stamp_ns": stamp_ns(early[0].header.stamp)}
            kind, joint, mag = fault
            cmd.inject_fault(kind, joint=joint, magnitude=mag)
            out["fault_injected"] = {"kind": kind, "joint": joint, "magnitude": float(mag)}
            cmd.wait_for_onset(2.0)
            self.timed("monitored after the fault", duration, since=t0)
        else:
            self.timed("monitored", duration)
        cmd.stop_processes([rec])
        active = cmd.active_stops()
        out["fault_injected_ns"] = stamp_ns(cmd.onsets[0].stamp) if cmd.onsets else None
        out["fault"] = cmd.onsets[0].frame_id if cmd.onsets else None
        out["safe_stop_ns"] = stamp_ns(active[0].header.stamp) if active else None
        out["safe_stop"] = ({"reason": active[0].reason, "kind": active[0].kind, "joint": active[0].joint,
                             "step": active[0].step, "window_bag": active[0].window_bag} if active else None)
        out["record"] = str(record)


def write_bringup(*, workdir, seed, model):
    """``WORKDIR/bringup.params.yaml``: the demo's simulated arm, reference, controller and
    monitor settings as a ROS 2 parameter file, and the ``reachset up`` command that runs the
    suite again with it and the monitor's model (whose gains ``up --model`` applies, issue
    36.1). Returns ``{"params_file", "command"}``."""
    from ..atomic import write_yaml
    path = Path(workdir).resolve() / "bringup.params.yaml"
    doc = {"sim_node": {"seed": int(seed), "calibrated": True, "lockstep_timeout": LOCKSTEP_TIMEOUT},
           "reference_node": {"seed": int(seed), "lead": float(defaults.get("demo.reference_lead"))},
           "controller_node": {"robot_params": str(default_nominal_path())},
           "monitor_node": {"max_missing_ticks": 125}}
    write_yaml(path, {n: {"ros__parameters": p} for n, p in doc.items()},
               header="# written by reachset demo: the suite of the demo, run again with\n"
                      f"#   reachset up --sim --params-file {path} --model {model}\n")
    return {"params_file": str(path), "command": f"reachset up --sim --params-file {path} --model {model}"}


def synthesis_arguments():
    """The synthesis node's ``extra_args`` for the demo and the search box of its ``hg``
    structure: ``(extra_args, {gain: [lo, hi]})``. R*_e and R*_u for every reference the
    reference node can send (its U_ref), not only the recorded ones: the monitored run's
    motions are new samples of that class."""
    cfg = config_path()
    demo_cfg = cfg.parent / "demo_synthesis.yaml" if cfg is not None else None
    demo_cfg = demo_cfg if demo_cfg is not None and demo_cfg.is_file() else None
    extra = ["--config", str(demo_cfg)] if demo_cfg is not None else []
    extra += ["--reference-class", f"qdd_max={U_REF:g}"]
    hg = load_config(demo_cfg)["structures"]["hg"]
    return extra, {n: [float(x) for x in hg["bounds"][n]] for n in hg["free"]}


def calibrate_inflation(*, bags, workdir):
    """The monitor's inflation from the training recordings alone: the identification workflow
    with ``calibrate=2`` and ``initial_state_set`` (``reachset identify BAGS --calibrate 2
    --initial-state-set --estimator E``, E the synthesis' estimator ``synthesis.estimator``: its
    Theorem-1 rows; each recording a fold: the sets identified on one must hold on the other,
    :func:`reachset_ros.conformance.calibration.cross_validate`), in a low-priority worker
    process. Returns ``(inflation, details)``; a flagged joint (no grid value held) is
    reported, and its largest grid value is used."""
    # the synthesis' estimator (synthesis.estimator), not identify's default: its rows are calibrated
    est = defaults.get("synthesis.estimator")
    command = " ".join(["reachset identify", *map(str, bags), f"--calibrate 2 --initial-state-set --estimator {est}"])
    opts = IdentifyOptions(bags=tuple(map(str, bags)), calibrate=2, initial_state_set=True, estimator=est,
                           command=command)
    try:
        r = run_in_worker(identify, opts).to_json()
    except ReachsetError as e:
        raise RuntimeError(f"inflation calibration failed: {e}") from e
    per = {n: float(j["inflation"]) for n, j in r["joints"].items()}
    flagged = [n for n, j in r["joints"].items() if j["calibration"].get("flagged")]
    return float(r["inflation"]), {"folds": 2, "command": command, "per_joint": per, "flagged": flagged}


def _result_dict(res):
    r = res.result
    return {"success": res.success, "message": res.message, "model_file": r.model_file, "applied": r.applied,
            "joints": {j.name: {"re_norm": j.re_norm, "re_radius": list(j.re_radius), "ru": [j.ru_lower, j.ru_upper],
                                "alpha_w": list(j.alpha_w), "alpha_v": list(j.alpha_v),
                                "gains": dict(zip(j.param_names, j.param_values)), "observer": j.observer,
                                "controller": j.controller, "conformant": j.conformant,
                                "test_cases": j.test_cases}
                       for j in r.joints}}
