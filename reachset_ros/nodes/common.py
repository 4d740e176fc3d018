"""Small helpers shared by the nodes: stamps, QoS profiles, parameter descriptors, main()."""
import os
import signal
import sys
import time

import rclpy
from rcl_interfaces.msg import (FloatingPointRange, IntegerRange, Parameter, ParameterDescriptor, ParameterType,
                                ParameterValue)
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.parameter import parameter_value_to_python
from rclpy.parameter_client import AsyncParameterClient
from rclpy.duration import Duration
from rclpy.qos import DurabilityPolicy, HistoryPolicy, LivelinessPolicy, QoSProfile, ReliabilityPolicy
from rclpy.signals import SignalHandlerOptions
from rclpy.task import Future

from ..errors import ReachsetError
from ..processes import use_dds_profiles
from ..stacks import dump_on_sigusr1
from . import scheduling

try:
    from rclpy.experimental import EventsExecutor
except ImportError:  # an rclpy older than Jazzy's 7.1.x: make_executor falls back
    EventsExecutor = None

#: Liveliness lease of every /safe_stop publisher (DDS asserts it automatically while the
#: process runs): a monitor that died or froze is "not alive" this long after, and the
#: controller stops (issue 17.2). 1 s: with 0.5 s a monitor starved of CPU for a moment on
#: the 2-core machine (the demo's calibration running beside it) was once reported lost.
MONITOR_LEASE_S = 1.0

#: /safe_stop: reliable + transient local, so late subscribers (a restarted controller) see it;
#: automatic liveliness with a lease of MONITOR_LEASE_S (publishers offer it, the controller
#: requests it: a publisher with a longer or no lease does not match, so it cannot pose as the
#: monitor).
SAFE_STOP_QOS = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                           durability=DurabilityPolicy.TRANSIENT_LOCAL, history=HistoryPolicy.KEEP_LAST,
                           liveliness=LivelinessPolicy.AUTOMATIC,
                           liveliness_lease_duration=Duration(seconds=MONITOR_LEASE_S))

#: The reason of the state a monitor publishes when it releases its start-up stop (issue 34.1:
#: k* + 1 consecutive ticks checked to the horizon, all conformant, on every input; no stop
#: active): it releases a controller waiting for the monitor, but not a stop of the
#: controller's own (only the monitor's ~/reset does).
MONITOR_STARTED = "monitor ready: k*+1 consecutive ticks checked to the horizon, all conformant; no safe stop active"
#: The reason prefix of the stop a monitor starts with (``kind: not_ready``): no model, no
#: data, or fewer checked ticks than the release needs; the monitor releases it itself
#: (:data:`MONITOR_STARTED`), never a reset.
MONITOR_NOT_READY = "not ready:"
#: per-tick data: reliable, a few ticks of history.
TICK_QOS = QoSProfile(depth=50, reliability=ReliabilityPolicy.RELIABLE,
                      durability=DurabilityPolicy.VOLATILE, history=HistoryPolicy.KEEP_LAST)
#: /clock from the simulator: reliable (matches rclpy's best-effort TimeSource subscription
#: and a reliable one), only the newest time matters.
CLOCK_QOS = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                       durability=DurabilityPolicy.VOLATILE, history=HistoryPolicy.KEEP_LAST)


def stamp_ns(stamp) -> int:
    return int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)


def to_stamp(msg_stamp, ns: int):
    msg_stamp.sec = int(ns // 1_000_000_000)
    msg_stamp.nanosec = int(ns % 1_000_000_000)
    return msg_stamp


def declare_realtime_priority(node):
    """Declare ``realtime_priority`` (read-only; :mod:`.scheduling`), which
    :func:`spin_node` applies to the process once the node and its executor exist."""
    node.declare_parameter(scheduling.PARAMETER, 0,
                           desc(scheduling.DESCRIPTION, 0, 99, integer=True, read_only=True))


def desc(description, lo=None, hi=None, integer=False, read_only=False):
    """A ParameterDescriptor with an optional range."""
    d = ParameterDescriptor(description=description, read_only=read_only)
    if lo is not None and hi is not None:
        if integer:
            d.integer_range = [IntegerRange(from_value=int(lo), to_value=int(hi), step=1)]
        else:
            d.floating_point_range = [FloatingPointRange(from_value=float(lo), to_value=float(hi))]
    return d


def spin_node(node_cls, args=None, **kwargs):
    """The usual ``main``: init, spin until SIGINT/SIGTERM or shutdown, clean up.

    An exception in one callback (including rclpy failing to take a message) is logged
    and counted, never fatal: a node must end in a defined state, and for the monitor a
    lost message is missing data, which its watchdog handles. SIGINT and SIGTERM only set
    a flag that the loop checks between callbacks, so no callback is cut off halfway (a
    tick half published, a bag half written).
    """
    argv = list(args if args is not None else sys.argv)
    own = argv[1:argv.index("--ros-args")] if "--ros-args" in argv else argv[1:]
    if "-h" in own or "--help" in own:
        print(node_help(node_cls))        # before rclpy: nothing starts
        sys.exit(0)
    dump_on_sigusr1()                     # kill -USR1: every thread's stack in the node's log
    use_dds_profiles()
    rclpy.init(args=argv, signal_handler_options=SignalHandlerOptions.NO)
    try:
        node = node_cls(**kwargs)
    except ReachsetError as e:
        # a configuration the node must not run with: one line, exit status 2, nothing started
        print(f"{node_cls.__name__}: error: {e}", file=sys.stderr)
        rclpy.try_shutdown()
        sys.exit(2)
    executor = make_executor()
    executor.add_node(node)
    if node.has_parameter(scheduling.PARAMETER):
        priority = int(node.get_parameter(scheduling.PARAMETER).value)
        try:
            n = scheduling.set_realtime(priority)
        except ReachsetError as e:
            print(f"{node_cls.__name__}: error: {e}", file=sys.stderr)
            executor.shutdown(timeout_sec=1.0)
            node.destroy_node()
            rclpy.try_shutdown()
            sys.exit(2)
        if n:
            node.get_logger().info(f"SCHED_FIFO priority {priority} on the process's {n} threads")
    log_start_summary(node)
    node.callback_errors = 0
    try:
        spin_until_signal(node, executor)
    finally:
        executor.shutdown(timeout_sec=1.0)
        if hasattr(node, "close"):
            node.close()
        node.destroy_node()
        rclpy.try_shutdown()


def node_help(node_cls):
    """``--help`` of a node's console script: usage, the module's docstring, where the
    parameters are documented; printed without starting rclpy or the node."""
    module = sys.modules[node_cls.__module__]
    name = node_cls.__module__.rsplit(".", 1)[-1]
    if name == "__main__":          # python -m reachset_ros.nodes.X: the script's file name
        name = os.path.basename(sys.argv[0]).removesuffix(".py")
    return "\n".join([
        f"usage: {name} [--help] [--ros-args [-p NAME:=VALUE]... [--params-file FILE] [-r FROM:=TO]...]", "",
        (module.__doc__ or "").strip(), "",
        "ROS arguments (after --ros-args): -p NAME:=VALUE sets a parameter, --params-file FILE loads a ROS 2",
        "parameter file (e.g. config/lwa4p.yaml), -r FROM:=TO remaps a topic or the node name",
        "(-r __node:=NAME), -r __ns:=/NS sets a namespace.",
        f"Parameters, topics and services of {name}: docs/nodes.md (or, while it runs,",
        f"`ros2 param describe /{name} NAME`)."])


def log_start_summary(node):
    """One INFO line when a node is up: what it subscribes to and publishes, its timers'
    rates, the files and directories its parameters name."""
    subs = sorted({s.topic_name for s in node.subscriptions})
    pubs = sorted({p.topic_name for p in node.publishers} - {"/rosout", "/parameter_events"})
    srvs = sorted({s.srv_name for s in node.services if not s.srv_name.rsplit("/", 1)[-1].startswith(
        ("describe_parameters", "get_parameter", "list_parameters", "set_parameters", "get_type_description"))})
    rates = sorted({round(1e9 / t.timer_period_ns, 3) for t in node.timers if t.timer_period_ns > 0}, reverse=True)
    files = []
    for name, p in sorted(node._parameters.items()):
        if any(w in name for w in ("file", "dir", "output", "params")) and isinstance(p.value, str) and p.value:
            files.append(f"{name}={os.path.abspath(p.value)}")
    node.get_logger().info(
        "up: subscribes " + (", ".join(subs) or "nothing") + "; publishes " + (", ".join(pubs) or "nothing")
        + ("; services " + ", ".join(srvs) if srvs else "")
        + ("; timers " + ", ".join(f"{r:g} Hz" for r in rates) if rates else "")
        + ("; files " + ", ".join(files) if files else ""))


def spin_until_signal(node, executor):
    """Spin ``executor`` until SIGINT, SIGTERM or rclpy shutdown; callback errors are counted.

    A node with an ``on_signal(signum)`` method has it called from the signal handler (in
    the main thread, between two Python instructions, possibly inside a callback): the
    synthesis node stops its ``reachset synthesize`` child there, which its service
    callback is waiting for.
    """
    stop = []

    def on_signal(signum, frame):
        stop.append(signum)
        hook = getattr(node, "on_signal", None)
        if hook is not None:
            hook(signum)

    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, on_signal)
    while rclpy.ok() and not stop:
        try:
            executor.spin_once(timeout_sec=0.1)
        except (KeyboardInterrupt, ExternalShutdownException):
            break
        except Exception as e:  # noqa: BLE001
            node.callback_errors = getattr(node, "callback_errors", 0) + 1
            node.get_logger().error(f"callback failed ({type(e).__name__}: {e}); continuing")


def make_executor():
    """The executor every node spins: rclpy's ``EventsExecutor`` (C++, callbacks in arrival order).

    On the 2-core machine the demo's closed loop (sim, reference, observer, controller,
    monitor) ran at 83-101 % of real time with it and at 42-44 % with the
    ``SingleThreadedExecutor``, which rebuilds its wait set in Python for every callback
    (about 70 % of each node's CPU time): ``benchmarks/bench_closed_loop.py``,
    docs/performance.md. ``REACHSET_EXECUTOR=single`` selects the ``SingleThreadedExecutor``, as
    does an rclpy without ``rclpy.experimental.EventsExecutor`` (older than Jazzy's 7.1.x).
    """
    if os.environ.get("REACHSET_EXECUTOR", "events") == "single":
        return SingleThreadedExecutor()
    if EventsExecutor is None:
        return SingleThreadedExecutor()
    return EventsExecutor()


def parameter_value(v):
    """An rcl_interfaces ParameterValue of a Python value (bool, int, float, str, lists)."""
    pv = ParameterValue()
    if isinstance(v, bool):
        pv.type, pv.bool_value = ParameterType.PARAMETER_BOOL, v
    elif isinstance(v, int):
        pv.type, pv.integer_value = ParameterType.PARAMETER_INTEGER, v
    elif isinstance(v, float):
        pv.type, pv.double_value = ParameterType.PARAMETER_DOUBLE, v
    elif isinstance(v, str):
        pv.type, pv.string_value = ParameterType.PARAMETER_STRING, v
    elif isinstance(v, (list, tuple)) and v and all(isinstance(x, str) for x in v):
        pv.type, pv.string_array_value = ParameterType.PARAMETER_STRING_ARRAY, list(v)
    elif isinstance(v, (list, tuple)):
        pv.type, pv.double_array_value = ParameterType.PARAMETER_DOUBLE_ARRAY, [float(x) for x in v]
    else:
        raise TypeError(f"unsupported parameter value {v!r}")
    return pv


def spin_until_complete(node, future, timeout):
    """Spin ``node`` until ``future`` is done or ``timeout`` s have passed: with the executor
    the node belongs to, else with rclpy's global one (which takes the node in and out, and
    leaves ``node.executor`` set).

    A ``timeout`` at or below zero spins once without waiting: rclpy's own
    ``spin_until_future_complete`` reads a negative timeout as *wait forever*, and a caller's
    remaining time (``deadline - now``) goes negative when it is preempted at its deadline (a
    CI run's ``reachset gains set --timeout 60`` hung past 300 s on a request no node answered)."""
    timeout = max(0.0, float(timeout))
    executor = node.executor
    if executor is not None and node in executor.get_nodes():
        executor.spin_until_future_complete(future, timeout_sec=timeout)
    else:
        rclpy.spin_until_future_complete(node, future, timeout_sec=timeout)


#: a parameter request still unanswered after this many seconds is sent again (see
#: :func:`call_parameter_service`)
RESEND_AFTER = 2.0


def call_parameter_service(node, send, timeout):
    """Call a parameter service (idempotent: get, set) through ``send()`` (one of the request
    methods of an :class:`rclpy.parameter_client.AsyncParameterClient`, returning a future),
    sending the request again while no answer has come, first after ``RESEND_AFTER`` s and
    then after twice the previous wait, until ``timeout`` s have passed.

    A node that has just started can answer before Fast DDS has matched the caller's reply
    reader; the answer is then dropped ("failed to send response (timeout): client will not
    receive response") and the caller would wait out its whole timeout (seen in a CI run).
    Setting the same parameters twice gives the same configuration (a node takes a repeat of
    its running values as it is: :func:`~reachset_ros.nodes.param_callbacks.repeats_current`).
    The waits double because an unanswered request may only be slow (a gate that certifies
    for seconds on a loaded machine): every copy sent is handled in turn. Returns the
    response, or None when none came in time.
    """
    deadline = time.monotonic() + timeout
    answered = Future()             # the first answer to any of the copies sent
    wait = RESEND_AFTER
    while time.monotonic() < deadline:
        send().add_done_callback(lambda f: answered.done() or answered.set_result(f.result()))
        spin_until_complete(node, answered, min(wait, deadline - time.monotonic()))
        if answered.done():
            return answered.result()
        wait *= 2
    return None


class _ParameterClient:
    """rclpy's :class:`~rclpy.parameter_client.AsyncParameterClient` of node ``target``, used
    for one request and closed: ``ready(service)`` waits for that one service (a node may
    offer only some of the parameter services), ``close()`` destroys the clients it made."""

    def __init__(self, node, target):
        self.node = node
        before = set(node.clients)
        self.client = AsyncParameterClient(node, f"/{target}")
        self._made = {c.srv_name.rsplit("/", 1)[-1]: c for c in node.clients if c not in before}

    def ready(self, service, timeout):
        return self._made[service].wait_for_service(timeout_sec=timeout)

    def close(self):
        for c in self._made.values():
            self.node.destroy_client(c)


def set_remote_parameters(node, target: str, values: dict, timeout=10.0, atomically=True):
    """Set parameters of node ``target`` through its parameter service (rclpy's
    ``AsyncParameterClient``: ``set_parameters_atomically`` or ``set_parameters``).

    Returns ``(ok, reason)``; with ``atomically`` all are applied together or none.
    """
    params = [Parameter(name=k, value=parameter_value(v)) for k, v in values.items()]
    pc = _ParameterClient(node, target)
    try:
        if not pc.ready("set_parameters_atomically" if atomically else "set_parameters", timeout):
            return False, f"{target}: parameter service not available"
        send = pc.client.set_parameters_atomically if atomically else pc.client.set_parameters
        res = call_parameter_service(node, lambda: send(params), timeout)
        if res is None:
            return False, f"{target}: parameter service timed out"
        results = [res.result] if atomically else list(res.results)
        bad = [r.reason for r in results if not r.successful]
        return (not bad), "; ".join(bad)
    finally:
        pc.close()


def get_remote_parameters(node, target: str, names, timeout=10.0):
    """Read parameters of node ``target`` through its ``get_parameters`` service (rclpy's
    ``AsyncParameterClient.get_parameters``).

    Parameters
    ----------
    node : rclpy.node.Node
        The node that creates the client and is spun until the answer arrives (not one that
        an executor is spinning right now).
    target : str
        Name of the node whose parameters are read (``/{target}/get_parameters``).
    names : sequence of str
    timeout : float
        Seconds to wait for the service, and again for the answer.

    Returns
    -------
    values : dict or None
        ``{name: value}`` with Python values (``rclpy.parameter.parameter_value_to_python``:
        bool, int, float, str, arrays as lists); None when the service is not available,
        does not answer in time, or a name is not a declared parameter of ``target``.
    reason : str
        Empty on success, else one line naming ``target`` and the problem.
    """
    names = list(names)
    pc = _ParameterClient(node, target)
    try:
        if not pc.ready("get_parameters", timeout):
            return None, f"{target}: parameter service not available"
        res = call_parameter_service(node, lambda: pc.client.get_parameters(names), timeout)
        if res is None:
            return None, f"{target}: parameter service timed out"
        got = list(res.values)
        if len(got) != len(names):
            return None, f"{target}: get_parameters answered {len(got)} values for {len(names)} names"
        values = {n: parameter_value_to_python(v) for n, v in zip(names, got)}
        unset = [n for n, v in values.items() if v is None]
        if unset:
            return None, f"{target}: no parameter {unset[0]}"
        return values, ""
    finally:
        pc.close()


#: /conformance/status: reliable with a deep queue, so a slow subscriber (a recorder under
#: load) does not lose ticks.
STATUS_QOS = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE,
                        durability=DurabilityPolicy.VOLATILE, history=HistoryPolicy.KEEP_LAST)

