"""``reachset excite``: identification references that cover the reference class on every joint.

Cross-validation (``identify --calibrate``) cannot see what no fold contains: training that
never moved a joint near the class' limits gives sets that hold for the training and a
monitor that stops the arm the first time it moves as the class allows (the fault campaign's
false stops, docs/reliability.md). This command writes a reference
(:func:`reachset_ros.sim.excite.excitation`) that reaches the class' acceleration
``|qdd_d| = qdd_max`` (u_ff, the paper's U_ref) and velocity ``|qd_d| = qd_max`` on every
joint, alone and all together (same and alternating directions), at each level of
``--fractions``, inside the position box (Table I and the URDF's limits for the LWA-4P; the
URDF's range for ``--robot``) shrunk by ``--margin``, from rest at the box centre back to rest.

Written to a bag with one topic, ``/reference`` (``reachset_msgs/msg/JointReference``, stamps
from 0), with the project's bag writer: ``reference_node`` plays it
(``trajectory_file:=BAG``) while the run is recorded for ``reachset identify``.

Synopsis::

    reachset excite --out BAG [--robot URDF] [--joints a,b,...] [--qd-max V] [--qdd-max A]
                    [--fractions F ...] [--margin M] [--rest S] [--dt DT] [--storage mcap|sqlite3] [--json]

``--json``: ``{bag, seconds, samples, dt, fractions, margin, rest, start, joints: {name:
{max_abs_velocity, velocity_limit, velocity_fraction, max_abs_acceleration, acceleration_limit,
acceleration_fraction, position_range, position_box}}}``. Bad input is refused (one line,
exit 2) before anything is written; the bag is written atomically.
"""
from pathlib import Path

import numpy as np

from .. import defaults
from ..errors import ReachsetError
from ..sim import excite as ex
from ..sim.reference import ReferenceConfig
from . import emit, help_of

NAME = "excite"
HELP = help_of(NAME)


def add_arguments(p):
    d = defaults.table("excite")
    p.add_argument("--out", required=True, metavar="BAG", help="bag directory to create")
    p.add_argument("--robot", metavar="URDF", default=None,
                   help="the arm's URDF (a path, or example-robot-data:<path>); its position range is the box. "
                        "Default: the shipped LWA-4P with the reference node's box (Table I and the URDF's limits)")
    p.add_argument("--joints", metavar="a,b,...", default=None,
                   help="the joints to excite (the others rest at the start); default all")
    p.add_argument("--qd-max", type=float, default=d["qd_max"], metavar="V",
                   help=f"the class' velocity limit, rad/s (reference_node qd_max; default {d['qd_max']:g})")
    p.add_argument("--qdd-max", type=float, default=d["qdd_max"], metavar="A",
                   help=f"the class' acceleration limit u_ff, rad/s^2 (default {d['qdd_max']:g})")
    p.add_argument("--fractions", type=float, nargs="+", default=d["fractions"], metavar="F",
                   help="levels of the limits, ascending in (0, 1] (default "
                        + " ".join(f"{f:g}" for f in d["fractions"]) + ")")
    p.add_argument("--margin", type=float, default=d["margin"], metavar="M",
                   help=f"share of the box's width kept free at both ends (default {d['margin']:g})")
    p.add_argument("--rest", type=float, default=d["rest"], metavar="S",
                   help=f"seconds at rest after each move (default {d['rest']:g})")
    p.add_argument("--dt", type=float, default=0.004, help="sampling period, s (default 0.004)")
    p.add_argument("--storage", choices=["mcap", "sqlite3"], default="mcap", help="rosbag2 storage plugin of the bag")
    p.add_argument("--json", action="store_true", help="print one JSON object")


def _box(args):
    """``(names, q_min, q_max, qd_max, robot)`` of the arm."""
    if args.robot is None:
        from ..robot.dynamics import JOINT_NAMES
        rc = ReferenceConfig()
        return tuple(JOINT_NAMES), rc.q_min, rc.q_max, np.full(rc.n, args.qd_max), "lwa4p"
    from .. import robot as rb
    from ..robot.descriptions import resolve_urdf
    urdf = resolve_urdf(args.robot)
    model = rb.load_model(urdf, None, None)
    rc = ReferenceConfig.for_robot(model, margin=0.0, qd_max=args.qd_max, qdd_max=args.qdd_max)
    return tuple(model.joint_names), rc.q_min, rc.q_max, rc.qd_max, str(urdf)


def config_of(args):
    """The :class:`~reachset_ros.sim.excite.ExciteConfig` of the command line (refusing bad input)."""
    for opt in ("qd_max", "qdd_max", "margin", "rest", "dt"):
        if not np.isfinite(getattr(args, opt)):
            raise ReachsetError(f"--{opt.replace('_', '-')} must be finite, got {getattr(args, opt)}")
    if args.qd_max <= 0 or args.qdd_max <= 0 or args.dt <= 0:
        raise ReachsetError("--qd-max, --qdd-max and --dt must be > 0")
    names, lo, hi, vmax, robot = _box(args)
    excited = None
    if args.joints is not None:
        excited = tuple(j.strip() for j in args.joints.split(",") if j.strip())
        unknown = [j for j in excited if j not in names]
        if not excited or unknown:
            raise ReachsetError(f"--joints: no joint {', '.join(unknown) or '(none given)'} "
                                f"(the arm's: {', '.join(names)})")
    cfg = ex.ExciteConfig(names=names, q_min=lo, q_max=hi, qd_max=vmax, qdd_max=args.qdd_max,
                          fractions=tuple(args.fractions), margin=args.margin, rest=args.rest, dt=args.dt,
                          excited=excited)
    return cfg, robot


def run(args):
    out = Path(args.out)
    if out.exists():
        raise ReachsetError(f"{out}: output bag already exists")
    if not out.parent.is_dir():
        raise ReachsetError(f"{out.parent}: output directory not found")
    cfg, robot = config_of(args)
    traj = ex.excitation(cfg)
    per = ex.summary(traj, cfg)
    res = {"bag": str(out), "robot": robot, "seconds": float(traj.t[-1]), "samples": len(traj), "dt": cfg.dt,
           "fractions": list(cfg.fractions), "margin": cfg.margin, "rest": cfg.rest,
           "start": cfg.q0.tolist(), "joints": per}
    ex.write_trajectory(out, traj, storage=args.storage)
    lines = [f"excite: {len(traj)} samples ({traj.t[-1]:.1f} s) of /reference -> {out}",
             "joint: max |qd_d| / qd_max, max |qdd_d| / qdd_max, position range [rad]"]
    lines += [f"{n}: {v['max_abs_velocity']:.3g}/{v['velocity_limit']:g}, {v['max_abs_acceleration']:.3g}/"
              f"{v['acceleration_limit']:g}, [{v['position_range'][0]:.3f}, {v['position_range'][1]:.3f}]"
              for n, v in per.items()]
    lines.append(f"play it: reference_node with trajectory_file:={out}")
    emit(args, res, "\n".join(lines))
