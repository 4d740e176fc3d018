"""Subcommands of the ``reachset`` command line, one module per command.

Each module defines ``NAME``, ``HELP``, ``add_arguments(parser)`` and ``run(args)``;
``run`` prints its result (through :func:`emit`) and raises
:class:`reachset_ros.errors.ReachsetError` for bad input.

May import: everything below the command line: the pure core (:mod:`reachset_ros.errors`, :mod:`reachset_ros._lazy`, :mod:`reachset_ros.defaults`, :mod:`reachset_ros.guarantees`,
:mod:`reachset_ros.atomic`, :mod:`reachset_ros.sets`, :mod:`reachset_ros.systems`,
:mod:`reachset_ros.robot`, :mod:`reachset_ros.conformance`, :mod:`reachset_ros.bags`,
:mod:`reachset_ros.synthesis`, :mod:`reachset_ros.fleet`, :mod:`reachset_ros.sim`), the
processes (:mod:`reachset_ros.domain`, :mod:`reachset_ros.params_file`,
:mod:`reachset_ros.processes`, :mod:`reachset_ros.stacks`), :mod:`reachset_ros.nodes`, :mod:`reachset_ros.workflows`,
:mod:`reachset_ros.plots` and :mod:`reachset_ros.report`. Only the command line (``reachset_ros.cli``) imports this package.
"""
import json
import sys

#: The commands in the order ``reachset --help`` lists them: name -> (module under
#: reachset_ros.commands, one-line help). The help lives here and not in the module, so that
#: ``reachset --help`` and a command's parser import no other command (issue 38.1: start-up).
COMMANDS = {
    "selftest": ("selftest", "two real processes exchange PlantInput over DDS; a parameter is set across them"),
    "analyze": ("analyze", "reachable tracking error R_e and reachable input R_u of one joint's closed loop"),
    "inspect": ("inspect", "what a bag holds (topics, rates, joints, sampling period) and the identify command for it"),
    "identify": ("identify", "identify a reachset-conformant model (min ||W||+||V||, Theorem 1) from bags"),
    "check": ("check", "check bags for reachset conformance against a model (batch, vectorised)"),
    "replay": ("replay", "replay bags through the online monitor core tick by tick (same verdicts as check)"),
    "report": ("report", "write one self-contained HTML report of bags checked against a model (figures, stops, guarantee)"),
    "fit-lwa4p": ("fit_lwa4p", "identify the nominal LWA-4P model (inertias, armature, friction, torque scale) from recordings"),
    "import-lwa4p": ("import_lwa4p", "convert the real Schunk LWA-4P recordings to a rosbag2 bag (/joint_states, /plant_input)"),
    "synthesize": ("synthesize", "combined controller synthesis and reachset-conformant identification (paper eq. 10)"),
    "input-limits": ("input_limits", "largest input set U_p per axis from the torque limits (paper eq. 11, Table I), sound"),
    "simulate": ("simulate", "simulate any arm (URDF) in closed loop and record /joint_states with effort to a bag"),
    "excite": ("excite", "write identification references that reach the reference class' limits on every joint (a /reference bag)"),
    "demo": ("demo", "run the whole system on the simulated arm: record, synthesise, apply, monitor, inject a fault"),
    "up": ("up", "bring the node suite up in order in a fresh DDS domain; SIGINT/SIGTERM stop it"),
    "status": ("status", "nodes, stop state, rates, model, gains and set use of a running suite (`reachset up`)"),
    "watch": ("watch", "a live view of a running suite: per-joint set use, rates, a STOP banner (Ctrl-C ends it)"),
    "reset": ("reset", "the monitor's audited reset of the safe stop of a running suite; exit 1 if refused"),
    "stop": ("stop", "a manual, audited category-1 safe stop of a running suite (kind manual; `reachset reset` clears it)"),
    "gains": ("gains", "get or set (atomically, through the pair's gate) the controller/observer gains of a running suite"),
}
#: Modules under reachset_ros.commands, in the order ``reachset --help`` lists them.
MODULES = [module for module, _ in COMMANDS.values()]


def help_of(name: str) -> str:
    """The one-line help of command ``name`` (its module's ``HELP``)."""
    return COMMANDS[name][1]


def emit(args, result, human=None):
    """Print ``result`` as one JSON object with ``--json``, else ``human`` (or indented JSON)."""
    if getattr(args, "json", False):
        json.dump(result, sys.stdout, sort_keys=True, allow_nan=False)
        sys.stdout.write("\n")
    elif human is not None:
        print(human)
    else:
        print(json.dumps(result, indent=2, sort_keys=True, allow_nan=False))
