"""Bring the node suite up in order, keep it running, stop it: the engine of ``reachset up``.

:func:`plan` says which nodes run and with which parameters; :func:`run` starts them one
after the other (:func:`reachset_ros.processes.start`, each in a session of its own, its
output in ``WORKDIR/<node>.log``), each once the previous one is *up*: its node is in the
ROS graph, as seen by a small node of this process in the suite's domain. Then it watches
the processes until SIGINT or SIGTERM (:class:`reachset_ros.processes.StopRequest`) or until
one of them ends, and stops them all (:func:`reachset_ros.processes.stop`: SIGINT, SIGTERM,
SIGKILL, and what is left of each process group).

The order is the data flow's: the simulated arm and its reference generator (``--sim``),
the observer, the controller (``wait_for_monitor``: it holds the arm until the monitor's
latched ``/safe_stop`` state reaches it), the monitor, the synthesis node.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path

from .. import processes

#: the suite, in start-up order; ``SIM_NODES`` only with ``--sim``
SUITE = ("sim_node", "reference_node", "observer_node", "controller_node", "monitor_node", "synthesis_node")
SIM_NODES = ("sim_node", "reference_node")
#: nodes that get ``--model`` as their ``model_file`` (a node that does not declare it ignores it)
MODEL_NODES = ("observer_node", "controller_node", "monitor_node", "synthesis_node")
#: nodes that start with the gains ``--model`` carries (:func:`model_gains`)
GAIN_NODES = ("observer_node", "controller_node")


def defaults(node: str, workdir: Path, sim: bool = False) -> dict:
    """The parameters ``reachset up`` gives ``node`` unless the parameter file says otherwise.

    The controller waits for the monitor's latched state before it moves the arm; the
    monitor's offending windows and the synthesis node's models go under ``workdir``
    (absolute paths) rather than into the current directory. With ``sim`` (the simulated
    arm) the observer and controller may run gains no model certifies (``allow_uncertified``,
    the initial gains that record the first identification data); on a real arm that must be
    said explicitly in the parameter file, or a model given. With ``sim`` the controller also
    times its stop without estimates on the simulation's ``/clock`` (``use_sim_time``,
    :mod:`reachset_ros.nodes.estimate_watch`): the lockstep simulation waits for the loop.
    """
    pair = {"allow_uncertified": True} if sim else {}
    return {"controller_node": {"wait_for_monitor": True, **pair, **({"use_sim_time": True} if sim else {})},
            "observer_node": dict(pair),
            "monitor_node": {"window_dir": str(workdir / "windows")},
            "synthesis_node": {"workdir": str(workdir / "synthesis")}}.get(node, {})


def plan(sections: dict, sim: bool, workdir: Path, model: Path | None = None) -> dict:
    """The nodes to start, in order, each with its parameters.

    Parameters
    ----------
    sections : dict
        Sections of the user's parameter file (:func:`reachset_ros.params_file.load`).
    sim : bool
        Start the simulated arm and the reference generator.
    workdir : Path
        Absolute; where logs, parameter files, windows and models go.
    model : Path, optional
        Absolute path of the conformance model: ``model_file`` of ``MODEL_NODES``.

    Returns
    -------
    dict
        ``{node: parameters}`` in start-up order: :func:`defaults`, then the file's ``/**``
        section, then the node's own section, then ``model_file`` and, for the observer and
        the controller, the model's gains (:func:`model_gains`; ``allow_uncertified`` false
        unless the file sets it; a model without gains leaves both as they were). Without a model (neither ``model`` nor a ``model_file`` in
        the monitor's section) the monitor is not started, since it cannot check anything,
        and the controller does not wait for it: the suite runs UNMONITORED
        (:func:`unmonitored`), as for recording identification data.
    """
    from ..params_file import for_node
    out = {}
    monitored = model is not None or bool(for_node(sections, "monitor_node").get("model_file"))
    for node in SUITE:
        if node in SIM_NODES and not sim:
            continue
        if node == "monitor_node" and not monitored:
            continue          # a monitor without a model does not run (issue 34.1): UNMONITORED
        own = for_node(sections, node)
        params = {**defaults(node, workdir, sim), **own}
        if node == "controller_node" and not monitored:
            params["wait_for_monitor"] = bool(own.get("wait_for_monitor", False))   # none will come
        if model is not None and node in MODEL_NODES:
            params["model_file"] = str(model)
            gains = model_gains(model, node, params) if node in GAIN_NODES else {}
            if gains:
                # the model's gains are certified for it: they start through the gate unless the
                # file explicitly allows uncertified gains (a model without gains, identified and
                # not synthesised, leaves the start-up gains and their defaults as they were)
                params.update(gains)
                params["allow_uncertified"] = bool(own.get("allow_uncertified", False))
        out[node] = params
    return out


def unmonitored(nodes: dict) -> bool:
    """True when the plan (:func:`plan`) starts no monitor: nothing checks the arm."""
    return "monitor_node" not in nodes


def model_gains(model: Path, node: str, params: dict) -> dict:
    """The gains a model file carries (per joint, written by the synthesis) as the start
    parameters of ``node`` (``observer_node`` or ``controller_node``), in the order of its
    ``joints``: ``reachset up --model M`` runs the gains M was synthesised and certified for,
    which the node certifies at start against M (:func:`~reachset_ros.systems.gains.certify_pair`)
    as it does any gain change. The synthesis node's own mapping
    (:func:`~reachset_ros.nodes.synthesis_node.target_values`); empty when the model has no
    gains (an identified, not synthesised, model). Raises ReachsetError naming the model when
    its gains do not fit the node (a joint it does not have, two observer types)."""
    from ..conformance import model as mdl
    from ..errors import ReachsetError
    from ..robot.dynamics import JOINT_NAMES
    from ..systems.gains import DEFAULTS, TYPE_KEYS
    from .gain_params import default_u_max
    from .synthesis_node import TARGET_KEYS, target_values
    synthesis = {n: dict(j.gains) for n, j in mdl.load(model).joints.items() if j.gains}
    if not synthesis:
        return {}
    keys = TARGET_KEYS[node]
    start = {"joints": list(JOINT_NAMES), "u_max": default_u_max(), **{t: DEFAULTS[t] for t in TYPE_KEYS},
             **{k: [float(DEFAULTS[k])] for k in keys if k in DEFAULTS}}
    current = {k: params.get(k, v) for k, v in start.items()}
    values, why = target_values(node, current, synthesis, [k for k in keys if k in current])
    if values is None:
        raise ReachsetError(f"{model}: its gains do not fit {why}")
    return values


@dataclass
class Outcome:
    """How :func:`run` ended: ``status`` 0 (stopped by a signal) or 1 (a node failed),
    the signal, the reason of a failure, and the processes it started."""
    status: int
    signum: int | None = None
    reason: str = ""
    procs: list = field(default_factory=list)


class GraphWatch:
    """A node of this process in the suite's domain, only to read the ROS graph."""

    def __init__(self, domain_id: int):
        import rclpy
        from rclpy.signals import SignalHandlerOptions
        self.rclpy = rclpy
        self.context = rclpy.Context()
        processes.use_dds_profiles()
        rclpy.init(context=self.context, domain_id=domain_id, signal_handler_options=SignalHandlerOptions.NO)
        self.node = rclpy.create_node("reachset_up", context=self.context, start_parameter_services=False,
                                      enable_rosout=False)

    def node_names(self) -> set[str]:
        return {name for name, _ in self.node.get_node_names_and_namespaces()}

    def close(self):
        self.node.destroy_node()
        self.rclpy.try_shutdown(context=self.context)


def _died(p: processes.NodeProcess) -> str:
    status = p.exit_status()
    how = f"was killed by signal {-status}" if status is not None and status < 0 else f"exited with status {status}"
    last = p.last_log_line()
    return f"{p.name} {how} (log {p.log}" + (f": {last}" if last else "") + ")"


def run(nodes: dict, workdir: Path, env: dict, domain_id: int, stop: processes.StopRequest, log=print,
        timeout: float = 60.0, on_ready=None) -> Outcome:
    """Start ``nodes`` in order, each once the previous is in the graph; run until a signal.

    Parameters
    ----------
    nodes : dict
        ``{node: parameters}`` in start-up order (:func:`plan`).
    workdir : Path
        Logs ``<node>.log`` and parameter files ``<node>.params.yaml``.
    env : dict
        The nodes' environment (with ``ROS_DOMAIN_ID``).
    domain_id : int
        The suite's domain, for the graph watch.
    stop : reachset_ros.processes.StopRequest
        Installed by the caller; looked at between steps.
    log : callable
        Progress, one line per call.
    timeout : float
        Seconds a node may take to appear in the graph.
    on_ready : callable, optional
        Called with the started processes once every node is up.

    Returns
    -------
    Outcome
        Every process has been stopped and reaped when it returns.
    """
    procs = []
    out = Outcome(1, procs=procs)
    watch = None
    try:
        watch = GraphWatch(domain_id)
        for name, params in nodes.items():
            if stop:
                break
            p = processes.start(name, params, workdir, env=env, group=procs)
            log(f"started {name} (pid {p.proc.pid}), log {p.log}")
            end = time.monotonic() + timeout
            while not stop:
                dead = [q for q in procs if not q.alive()]
                if dead:
                    out.reason = _died(dead[0])
                    return out
                if name in watch.node_names():
                    log(f"{name} is up")
                    break
                if time.monotonic() > end:
                    out.reason = (f"{name} did not appear in the ROS graph within {timeout:g} s "
                                  f"(log {p.log}" + (f": {p.last_log_line()}" if p.last_log_line() else "") + ")")
                    return out
                time.sleep(0.1)
        watch.close()
        watch = None
        if not stop:
            if on_ready is not None:
                on_ready(procs)
            while not stop:
                dead = [q for q in procs if not q.alive()]
                if dead:
                    out.reason = _died(dead[0])
                    return out
                time.sleep(0.2)
        out.status, out.signum = 0, stop.signum
        return out
    finally:
        if watch is not None:
            watch.close()
        running = [q for q in procs if q.alive()]
        if running:
            log(f"stopping {', '.join(q.name for q in reversed(running))}")
        processes.stop(list(reversed(procs)))
