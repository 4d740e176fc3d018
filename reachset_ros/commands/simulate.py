"""``reachset simulate``: any arm's URDF, simulated in closed loop, recorded as a ros2_control arm records.

The project's simulated arm (:mod:`reachset_ros.sim.simulator`: Pinocchio forward dynamics
of a "true" robot with a realistic model error, encoder quantization, measurement noise,
the paper's one-sample input and output delays, torque limits, hard stops) under the
project's control law (per joint observer + controller, feedback linearization eq. (6)
with the nominal model: :func:`reachset_ros.sim.recordings.simulate_arm_recordings`), along
random point-to-point references inside the URDF's limits
(:meth:`reachset_ros.sim.reference.ReferenceConfig.for_robot`).

Written to a rosbag2 bag with **only** ``/joint_states`` (position = measured position,
velocity = measured velocity, effort = the torque command issued at that tick [N m], same
stamp: the convention of the real LWA-4P recordings, docs/any-arm.md), as an arm driven by
another controller is recorded; ``--plant-input`` also writes ``/plant_input`` (the u_p the
controller used). A fault of the simulator can be injected; the JSON reports the stamp at
which it first changes a measurement (``fault_onset_ns``, also ``fault.onset_ns``:
:meth:`reachset_ros.sim.simulator.SimulatedArm.onset_stamp`), and what the arm's hardware
did (``hard_stops`` reached, ``torque_clamped_ticks``, ``skipped_samples`` of a NaN fault).

Synopsis::

    reachset simulate --robot URDF [--joints a,b,...] [--nominal PARAMS.yaml] --seconds S --out BAG
                      [--seed N] [--storage mcap|sqlite3] [--plant-input]
                      [--fault payload|torque|acceleration|bias|frozen|nan [--fault-at S]
                       [--fault-joint J] [--fault-magnitude X]] [--json]

Bad input is refused (one line, exit 2) before anything is written; the bag is written
atomically (:class:`reachset_ros.bags.BagWriter`).
"""
import numpy as np

from .. import bags
from .. import robot as rb
from ..errors import ReachsetError
from ..robot.descriptions import resolve_urdf
from ..sim import recordings as sr
from ..sim import simulator as simm
from . import emit, help_of

NAME = "simulate"
HELP = help_of(NAME)

#: --fault KIND -> (fault class, the field --fault-magnitude sets, its unit, default)
FAULTS = {"payload": (simm.Payload, "mass", "kg", 2.0),
          "torque": (simm.TorqueDisturbance, "torque", "N m", 5.0),
          "acceleration": (simm.AccelerationDisturbance, "acceleration", "rad/s^2", 5.0),
          "bias": (simm.SensorBias, "bias", "rad", 0.01),
          "frozen": (simm.FrozenSensor, None, "", None),
          "nan": (simm.NaNSamples, "count", "samples", 1)}


def add_arguments(p):
    p.add_argument("--robot", required=True, metavar="URDF",
                   help="the arm's URDF: a path, or example-robot-data:<path> (e.g. "
                        "example-robot-data:panda_description/urdf/panda.urdf)")
    p.add_argument("--joints", metavar="a,b,...", help="the joints to simulate (the URDF's others are locked at "
                                                       "their neutral configuration); default all")
    p.add_argument("--nominal", metavar="PARAMS.yaml", help="identified parameters over the URDF (the nominal model)")
    p.add_argument("--seconds", type=float, required=True, help="duration [s]")
    p.add_argument("--out", required=True, metavar="BAG", help="bag directory to create")
    p.add_argument("--seed", type=int, default=0, help="seeds the reference, the model error and the noise")
    p.add_argument("--storage", choices=["mcap", "sqlite3"], default="mcap", help="rosbag2 storage plugin of the bag")
    p.add_argument("--plant-input", action="store_true", help="also write /plant_input (the controller's u_p)")
    p.add_argument("--fault", choices=sorted(FAULTS), help="inject a fault of the simulator")
    p.add_argument("--fault-at", type=float, default=None, metavar="S", help="fault start [s] (default: half-way)")
    p.add_argument("--fault-joint", default=None, metavar="J", help="the faulty joint (default: the first)")
    p.add_argument("--fault-magnitude", type=float, default=None, metavar="X",
                   help="payload kg (default 2), torque N m (5), acceleration rad/s^2 (5), bias rad (0.01), "
                        "nan: number of samples (1)")
    p.add_argument("--json", action="store_true", help="print one JSON object")


def _fault(args, names):
    if args.fault is None:
        for opt in ("fault_at", "fault_joint", "fault_magnitude"):
            if getattr(args, opt) is not None:
                raise ReachsetError(f"--{opt.replace('_', '-')} needs --fault")
        return None, None
    cls, field, unit, default = FAULTS[args.fault]
    at = args.seconds / 2 if args.fault_at is None else args.fault_at
    if not (np.isfinite(at) and 0 <= at < args.seconds):
        raise ReachsetError(f"--fault-at must be in [0, {args.seconds}) s, got {at}")
    kw = {"start_s": float(at)}
    joint = None
    if args.fault != "payload":
        joint = args.fault_joint or names[0]
        if joint not in names:
            raise ReachsetError(f"--fault-joint: no joint {joint} (simulated: {', '.join(names)})")
        kw["joint"] = joint
    elif args.fault_joint is not None:
        raise ReachsetError("--fault-joint: a payload acts on the last link, not on one joint")
    mag = default if args.fault_magnitude is None else args.fault_magnitude
    if field is None:
        if args.fault_magnitude is not None:
            raise ReachsetError(f"--fault-magnitude: a {args.fault} fault has none")
    else:
        if not np.isfinite(mag):
            raise ReachsetError(f"--fault-magnitude must be finite, got {mag}")
        if args.fault in ("payload", "nan") and mag <= 0:
            raise ReachsetError(f"--fault-magnitude must be > 0 for a {args.fault} fault, got {mag}")
        if field == "count" and mag != int(mag):
            raise ReachsetError(f"--fault-magnitude of a nan fault is a number of samples, got {mag}")
        kw[field] = int(mag) if field == "count" else float(mag)
    return cls(**kw), {"kind": args.fault, "joint": joint, "magnitude": None if field is None else kw[field],
                       "unit": unit, "at_s": float(at)}


def _max_abs(a):
    """Largest finite |a| (None if there is none: a JSON value)."""
    a = np.abs(np.asarray(a, dtype=np.float64))
    a = a[np.isfinite(a)]
    return float(a.max()) if a.size else None


def run(args):
    if not (np.isfinite(args.seconds) and args.seconds >= 2 * simm.DT):
        raise ReachsetError(f"--seconds must be > 0 and give two samples (>= {2 * simm.DT} s at "
                            f"{1 / simm.DT:.0f} Hz), got {args.seconds}")
    from pathlib import Path
    out = Path(args.out)
    if out.exists():
        raise ReachsetError(f"{out}: output bag already exists")
    if not out.parent.is_dir():
        raise ReachsetError(f"{out.parent}: output directory not found")
    urdf = resolve_urdf(args.robot)
    joints = None if args.joints is None else [j.strip() for j in args.joints.split(",") if j.strip()]
    model = rb.load_model(urdf, args.nominal, joints)
    names = list(model.joint_names)
    fault, fdesc = _fault(args, names)
    log = {}
    cfg = simm.SimConfig.realistic(robot=model, seed=args.seed)
    recs = sr.simulate_arm_recordings(args.seconds, seed=args.seed, sim_config=cfg,
                                      faults=() if fault is None else (fault,), log=log)
    stamps, Q, QD, EFF = log["stamps"], log["q"], log["qd"], log["effort"]
    onset = None if fault is None else int(log["fault_onsets"][0])
    if onset is not None and onset > stamps[-1]:
        raise ReachsetError(f"--fault-at {fdesc['at_s']}: the fault would first change the measurement stamped "
                            f"{onset}, after the recording's last ({int(stamps[-1])}); start it earlier")
    # everything is computed before the bag is written: a refusal leaves nothing behind
    err = {n: _max_abs(r.y[1:] - r.q_d[:-1]) for n, r in recs.items()}
    counters = log["counters"]
    res = {"bag": str(out), "robot": str(urdf), "joints": names, "ticks": int(len(stamps)),
           "seconds": float(args.seconds), "seed": args.seed, "plant_input": bool(args.plant_input),
           "storage": args.storage, "period_ns": int(round(cfg.dt * 1e9)),
           "first_stamp_ns": int(stamps[0]), "last_stamp_ns": int(stamps[-1]),
           "max_tracking_error_rad": err,
           "max_abs_effort": {n: _max_abs(EFF[:, j]) for j, n in enumerate(names)},
           "effort_limit": dict(zip(names, model.effort_limit.tolist())),
           "hard_stops": int(counters["hard_stop"]), "torque_clamped_ticks": int(counters["torque_clamped"]),
           "skipped_samples": dict(zip(names, log["skipped_samples"].tolist())),
           "fault_onset_ns": onset,
           "fault": None if fault is None else {**fdesc, "onset_ns": onset}}
    with bags.BagWriter(out, storage=args.storage) as w:
        for k, st in enumerate(stamps):
            st = int(st)
            w.write(bags.JOINT_STATES, bags.joint_state(st, names, Q[k], QD[k], EFF[k]), st)
            if args.plant_input:
                w.write(bags.PLANT_INPUT, bags.plant_input(st, names, [recs[n].u[k] for n in names]), st)
    fmt = lambda v: "-" if v is None else f"{v:.3g}"      # noqa: E731
    lines = [f"simulate: {len(names)} joints of {urdf.name}, {res['ticks']} ticks -> {out}",
             "max tracking error [rad]: " + ", ".join(f"{n} {fmt(v)}" for n, v in err.items()),
             "max |effort| / limit [N m]: " + ", ".join(f"{n} {fmt(res['max_abs_effort'][n])}/{lim:g}"
                                                        for n, lim in res["effort_limit"].items()),
             f"hard stops hit: {res['hard_stops']}, ticks with a clamped torque: {res['torque_clamped_ticks']}"]
    if fault is not None:
        lines.append(f"fault {fdesc['kind']} from {fdesc['at_s']} s: first changed measurement at stamp {onset}")
    emit(args, res, "\n".join(lines))
