"""Arguments and loading shared by the bag-consuming subcommands."""
from pathlib import Path

from ..bags import read_joint_series
from ..bags.messages import JOINT_STATES, PLANT_INPUT
from ..conformance.kernels import require_horizon  # noqa: F401  (re-exported for the commands)
from ..errors import ReachsetError


def add_bag_arguments(p, joints=True):
    p.add_argument("bags", nargs="+", metavar="BAG", help="rosbag2 directories (MCAP or sqlite3), or bare .mcap / .db3 files")
    if joints:
        p.add_argument("--joints", default="all", help="comma-separated joint names, or 'all' (default)")
    p.add_argument("--joint-states-topic", default=JOINT_STATES, metavar="T",
                   help=f"the measurement topic, sensor_msgs/msg/JointState: its position is y_p (default {JOINT_STATES})")
    p.add_argument("--input-topic", default=PLANT_INPUT, metavar="T",
                   help=f"the plant-input topic, reachset_msgs/msg/PlantInput (default {PLANT_INPUT})")
    p.add_argument("--input", choices=["topic", "effort"], default="topic",
                   help="where u_p comes from: the plant-input topic (default), or the measurement topic's "
                        "effort with the robot's URDF: u_p = M^-1(q) (tau - psi(q, qd)) (needs --robot)")
    p.add_argument("--robot", metavar="URDF", help="--input effort: the robot's URDF (the nominal model M, psi)")
    p.add_argument("--nominal", metavar="PARAMS.yaml",
                   help="--input effort: identified parameters applied over the URDF (e.g. config/lwa4p_nominal.yaml)")
    p.add_argument("--lock-joints", metavar="a,b,...",
                   help="--input effort: URDF joints locked at their neutral configuration (e.g. a gripper's "
                        "fingers that the bag does not carry)")
    p.add_argument("--joint-names", metavar="a,b,...",
                   help="names of the arrays of JointState messages whose name[] is empty (otherwise refused)")
    p.add_argument("--json", action="store_true", help="print one JSON object on stdout")


def topics_of(args):
    """(measurement topic, plant-input topic) of the command line."""
    return (getattr(args, "joint_states_topic", JOINT_STATES), getattr(args, "input_topic", PLANT_INPUT))


def reader_options(args):
    """``read_joint_series`` keyword arguments of the command line: ``effort`` (an
    :class:`~reachset_ros.robot.effort.EffortInput` for ``--input effort``) and ``joint_names``."""
    mode = getattr(args, "input", "topic")
    robot, nominal = getattr(args, "robot", None), getattr(args, "nominal", None)
    effort = None
    if mode == "effort":
        if robot is None:
            raise ReachsetError("--input effort needs --robot URDF")
        from ..robot.effort import load_effort_input   # Pinocchio: only when asked for
        lock = getattr(args, "lock_joints", None)
        effort = load_effort_input(robot, nominal, lock=_names(lock, "--lock-joints") if lock else None)
    elif robot is not None or nominal is not None or getattr(args, "lock_joints", None):
        raise ReachsetError("--robot, --nominal and --lock-joints are only used with --input effort")
    names = getattr(args, "joint_names", None)
    return {"effort": effort, "joint_names": None if names is None else _names(names, "--joint-names")}


def _names(text, option):
    names = [j.strip() for j in str(text).split(",") if j.strip()]
    if not names or len(set(names)) != len(names):
        raise ReachsetError(f"{option}: give distinct, non-empty joint names, e.g. a,b,c")
    return names


def parse_joints(text):
    names = [j.strip() for j in str(text).split(",") if j.strip()]
    if not names:
        raise ReachsetError("--joints: no joint names given")
    return None if names == ["all"] else names


def load_series(bags, joints, dt=0.004, restrict=None, topics=(JOINT_STATES, PLANT_INPUT), options=None):
    """Per-joint series from the bags; ``restrict`` limits 'all' to the model's joints;
    ``topics``: (measurement topic, plant-input topic); ``options``: :func:`reader_options`."""
    names = parse_joints(joints) if isinstance(joints, str) else joints
    opts = options or {}
    if names is None and restrict is not None:
        series, report = read_joint_series([Path(b) for b in bags], None, dt, topics, **opts)
        missing = [j for j in restrict if j not in series]
        if missing:
            raise ReachsetError(f"joint {missing[0]} of the model not found in the bags")
        return {j: series[j] for j in restrict}, report
    return read_joint_series([Path(b) for b in bags], names, dt, topics, **opts)


def check_out_path(out):
    if out is None:
        return None
    p = Path(out)
    if p.exists() and p.is_dir():
        raise ReachsetError(f"{p}: --out is a directory")
    if not p.parent.exists():
        raise ReachsetError(f"{p.parent}: output directory does not exist")
    return p


def add_fleet_arguments(p):
    """``--workers N`` / ``--scheduler ADDRESS``: the sweep on Dask distributed (:mod:`reachset_ros.fleet`)."""
    g = p.add_mutually_exclusive_group()
    g.add_argument("--workers", type=int, metavar="N",
                   help="read and sweep the bags in N local worker processes (a Dask LocalCluster, one task per "
                        "bag); the result is the single-process one to the bit")
    g.add_argument("--scheduler", metavar="ADDRESS",
                   help="run the per-bag tasks on an existing Dask distributed cluster (e.g. tcp://host:8786); "
                        "its workers must see the bags at the paths given")


def fleet_of(args, refused=()):
    """A :class:`~reachset_ros.fleet.cluster.Fleet` for ``--workers``/``--scheduler`` (not yet
    started: use it as a context manager), or None without them (Dask is then not imported).

    ``refused``: ``(option set?, "--option")`` pairs that a fleet run cannot compute from
    per-bag reductions; given with a fleet option, they are a clear error.
    """
    workers, scheduler = getattr(args, "workers", None), getattr(args, "scheduler", None)
    if workers is None and scheduler is None:
        return None
    flag = "--workers" if workers is not None else "--scheduler"
    for given, option in refused:
        if given:
            raise ReachsetError(f"{option} needs the whole series in one process: run it without {flag}")
    if workers is not None and workers < 1:
        raise ReachsetError(f"--workers must be >= 1, got {workers}")
    from ..fleet.cluster import Fleet
    return Fleet(workers=workers, scheduler=scheduler)


def read_spec(args, joints, dt):
    """The :class:`~reachset_ros.fleet.ReadSpec` of the command line (what ``load_series`` with
    :func:`reader_options` reads, as plain values for the workers)."""
    from ..fleet.tasks import ReadSpec
    names = parse_joints(joints) if isinstance(joints, str) else joints
    opts = reader_options(args)         # the same checks (and errors) as a one-process run
    effort = None
    if opts["effort"] is not None:      # the workers rebuild the robot model from these
        lock = getattr(args, "lock_joints", None)
        effort = (args.robot, args.nominal, None if lock is None else tuple(_names(lock, "--lock-joints")))
    jn = opts["joint_names"]
    return ReadSpec(None if names is None else tuple(names), float(dt), tuple(topics_of(args)), effort,
                    None if jn is None else tuple(jn))
