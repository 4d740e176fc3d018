"""``reachset up``: the node suite brought up in order in a fresh DDS domain (``ros2 launch`` stand-in).

Checks the input first (parameter file, model, working directory: exit status 2 and one
line, nothing started), picks a fresh ``ROS_DOMAIN_ID``
(:func:`reachset_ros.domain.pick_domain_id`) and prints it as the first line on stdout,
``ROS_DOMAIN_ID=N``, then starts the nodes one after the other
(:mod:`reachset_ros.nodes.bringup`): with ``--sim`` ``sim_node`` and ``reference_node``,
then ``observer_node``, ``controller_node``, ``monitor_node``, ``synthesis_node``, each
once the previous one is in the ROS graph. Runs until SIGINT or SIGTERM, then stops every
node and exits 0; exits 1 when a node ends by itself or does not come up (saying which,
and where its log is), after stopping the others.
"""
import json
import os
import signal
import sys
import tempfile
from pathlib import Path

from ..domain import pick_domain_id, write_suite_state
from ..errors import ReachsetError
from . import help_of

NAME = "up"
HELP = help_of(NAME)


#: said at the start and once every node is up when no model is given (issue 36.1)
UNMONITORED = ("UNMONITORED: no model (--model, or model_file in the monitor's section of the parameter file), so "
               "no monitor runs and nothing checks the arm or stops it on a fault; the controller does not wait "
               "for a monitor. Use this only to record identification data")


def add_arguments(p):
    p.add_argument("--params-file", metavar="F",
                   help="ROS 2 parameter file (NODE: {ros__parameters: {...}} and /** sections) whose sections "
                        "go to the matching nodes")
    p.add_argument("--model", metavar="M",
                   help="conformance model (identify/synthesize output): model_file of the monitor, the "
                        "controller, the synthesis node (and the observer, where it takes one)")
    p.add_argument("--sim", action="store_true", help="also start the simulated arm and the reference generator")
    p.add_argument("--workdir", metavar="DIR",
                   help="where the logs (DIR/NODE.log), parameter files, windows and models go, and DIR/up.json "
                        "(the domain, for `reachset status|watch|reset|stop|gains --workdir DIR`) "
                        "(default: a new temporary directory)")
    p.add_argument("--timeout", type=float, default=60.0, metavar="S",
                   help="seconds each node may take to appear in the ROS graph (default 60)")
    p.add_argument("--json", action="store_true",
                   help="after the ROS_DOMAIN_ID line, one JSON object once every node is up: ros_domain_id, "
                        "workdir, nodes (in start-up order: name, pid, log, params_file)")


def check_inputs(args):
    """The parameter file's sections and the model's absolute path; ReachsetError when bad."""
    from .. import params_file
    from ..conformance import model as mdl
    from ..nodes.bringup import SUITE
    sections = params_file.load(args.params_file) if args.params_file else {}
    unknown = [n for n in sections if n != params_file.WILDCARD and n not in SUITE]
    if unknown:
        raise ReachsetError(f"{args.params_file}: section {unknown[0]!r} names no node of the suite "
                            f"({', '.join(SUITE)})")
    # sections of sim_node and reference_node are ignored without --sim (one file serves both)
    model = None
    if args.model:
        model = Path(args.model).resolve()
        mdl.load(model)                # raises ReachsetError naming the file
    for params in sections.values():
        if params.get("model_file"):
            mdl.load(params["model_file"])
    if args.timeout <= 0:
        raise ReachsetError("--timeout must be positive")
    return sections, model


def run(args):
    from .. import processes
    from ..nodes import bringup
    sections, model = check_inputs(args)
    if args.workdir:
        workdir = Path(args.workdir).resolve()
        try:
            workdir.mkdir(parents=True, exist_ok=True)
        except OSError as e:
            raise ReachsetError(f"{workdir}: cannot create the working directory ({e.strerror})") from None
    else:
        workdir = Path(tempfile.mkdtemp(prefix="reachset_up_"))
    nodes = bringup.plan(sections, args.sim, workdir, model)
    domain = pick_domain_id()
    print(f"ROS_DOMAIN_ID={domain}", flush=True)
    env = dict(os.environ, ROS_DOMAIN_ID=str(domain))
    # WORKDIR/up.json: where the operator commands (`reachset status --workdir DIR`) find the suite
    write_suite_state(workdir, domain_id=domain, pid=os.getpid())
    # progress on stdout, or on stderr when stdout carries the JSON object
    out = sys.stderr if args.json else sys.stdout

    def log(line):
        print(f"reachset up: {line}", file=out, flush=True)

    def ready(procs):
        write_suite_state(workdir, domain_id=domain, pid=os.getpid(),
                          nodes=[{"name": p.name, "pid": p.proc.pid, "log": str(p.log)} for p in procs])
        if args.json:
            print(json.dumps({"ros_domain_id": domain, "workdir": str(workdir),
                              "nodes": [{"name": p.name, "pid": p.proc.pid, "log": str(p.log),
                                         "params_file": (str(workdir / f"{p.name}.params.yaml") if nodes[p.name]
                                                         else None)}
                                        for p in procs]}, sort_keys=True), flush=True)
        log(f"all {len(procs)} nodes up in ROS_DOMAIN_ID={domain}; `export ROS_DOMAIN_ID={domain}` to reach "
            f"them (or `reachset status --workdir {workdir}`); Ctrl-C or SIGTERM stops them")
        if bringup.unmonitored(nodes):
            log(UNMONITORED)

    log(f"logs and parameter files in {workdir}")
    if bringup.unmonitored(nodes):
        log(UNMONITORED)
    with processes.StopRequest() as stop:
        res = bringup.run(nodes, workdir, env, domain, stop, log=log, timeout=args.timeout, on_ready=ready)
    if res.status == 0:
        log("stopped" + (f" on {signal.Signals(res.signum).name}" if res.signum else "") + f"; logs in {workdir}")
        return 0
    print(f"reachset up: {res.reason}; stopped the other nodes", file=sys.stderr, flush=True)
    return 1
