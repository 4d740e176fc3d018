"""``reachset import-lwa4p DIR --runs A-B --out BAG``: the real LWA-4P recordings to a bag.

``/joint_states`` (position, velocity, effort = logged torque as logged) and
``/plant_input`` (u_p = M_hat(q)^-1 (s tau - psi_hat(q, qd)) with the identified nominal
model, config/lwa4p_nominal.yaml by default), header stamps = receive times, runs separated
by a pause in the stamps. See reachset_ros.robot.lwa4p.import_runs for the exact layout.
"""
from ..errors import ReachsetError
from ..robot import lwa4p
from . import emit, help_of

NAME = "import-lwa4p"
HELP = help_of(NAME)


def add_arguments(p):
    p.add_argument("dir", metavar="DIR", nargs="?", default=None,
                   help="data directory with measurement_i/ folders (default: the recordings "
                        "shipped in reachset_ros/data/lwa4p_iros2018)")
    p.add_argument("--runs", required=True, help="runs to import: train, heldout, a range (1-70), or A-B:train / A-B:heldout")
    p.add_argument("--out", required=True, metavar="BAG", help="bag directory to create")
    p.add_argument("--model", default=None, metavar="MODEL.yaml",
                   help="nominal model (default: the shipped config/lwa4p_nominal.yaml)")
    p.add_argument("--gap", type=float, default=1.0, help="pause between runs in the stamps [s]")
    p.add_argument("--storage", choices=["mcap", "sqlite3"], default="mcap", help="rosbag2 storage plugin of the bag")
    p.add_argument("--json", action="store_true", help="print one JSON object")


def run(args):
    if not args.gap > 0:
        raise ReachsetError(f"--gap must be > 0 s, got {args.gap}")
    runs = lwa4p.parse_runs(args.runs)
    model = lwa4p.load_nominal(args.model)
    res = lwa4p.import_runs(args.dir, runs, args.out, model,
                            gap_ns=int(round(args.gap * 1e9)), storage=args.storage)
    res["model"] = str(args.model or lwa4p.default_nominal_path())
    emit(args, res, f"import-lwa4p: {len(res['runs'])} runs, {res['samples']} samples, "
                    f"{res['plant_inputs']} plant inputs -> {res['bag']}")
