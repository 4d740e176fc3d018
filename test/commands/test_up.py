"""`reachset up`, the fresh DDS domain of `up` and `demo`, and stopping children without orphans.

The pure parts (domain picking on a fake /proc, parameter files, bad input) run in
milliseconds; the rest are real processes over real DDS: `reachset up --sim --model M`
publishing /joint_states and /conformance/status in the domain it printed first, a
SIGTERM leaving no process of the suite behind, and a `reachset demo` stopped by SIGTERM
while its synthesis node runs `reachset synthesize` (at low priority) leaving nothing
behind either. Deadlines are generous and only bound a hang; nothing is timed.
"""
import json
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
import yaml
from helpers import cmdline, running, suite_processes

from reachset_ros import processes, params_file
from reachset_ros.domain import DOMAIN_RANGE, domain_of_port, domains_in_use, pick_domain_id
from reachset_ros.errors import ReachsetError


pytestmark = pytest.mark.dds   # real DDS participants / node processes

REPO = Path(__file__).resolve().parents[2]


# ---------------------------------------------------------------- the domain rule

def fake_proc(tmp_path, environs=(), ports=()):
    """A /proc with processes of this user (their environments) and bound UDP ports."""
    proc = tmp_path / "proc"
    (proc / "net").mkdir(parents=True)
    for i, env in enumerate(environs):
        d = proc / str(1000 + i)
        d.mkdir()
        (d / "environ").write_bytes(b"\0".join(f"{k}={v}".encode() for k, v in env.items()) + b"\0")
    header = "  sl  local_address rem_address   st tx_queue rx_queue tr tm->when retrnsmt   uid  timeout inode\n"
    rows = "".join(f"   {i}: 0100007F:{p:04X} 00000000:0000 07 00000000:00000000 00:00000000 00000000  1000 0 1 2\n"
                   for i, p in enumerate(ports))
    (proc / "net" / "udp").write_text(header + rows)
    (proc / "net" / "udp6").write_text(header)
    return proc


def test_domain_in_use_by_an_environment_or_by_rtps_ports(tmp_path):
    proc = fake_proc(tmp_path, environs=[{"ROS_DOMAIN_ID": "7", "PATH": "/bin"}, {"HOME": "/x"}],
                     ports=[7400 + 250 * 12 + 10, 7400 + 250 * 30 + 249, 22, 53])
    assert domains_in_use(proc) == {7, 12, 30}
    assert domain_of_port(7399) is None and domain_of_port(7400) == 0 and domain_of_port(7650) == 1


def test_pick_domain_id_avoids_the_domains_in_use(tmp_path):
    lo, hi = DOMAIN_RANGE
    free = {5, 77}
    used = [d for d in range(lo, hi + 1) if d not in free]
    proc = fake_proc(tmp_path, environs=[{"ROS_DOMAIN_ID": str(d)} for d in used[:50]],
                     ports=[7400 + 250 * d + 10 for d in used[50:]])
    assert {pick_domain_id(proc) for _ in range(40)} <= free
    (proc / "1999").mkdir()
    (proc / "1999" / "environ").write_bytes(b"ROS_DOMAIN_ID=5\0")
    (proc / "2000").mkdir()
    (proc / "2000" / "environ").write_bytes(b"ROS_DOMAIN_ID=77\0")
    with pytest.raises(ReachsetError, match="no free ROS_DOMAIN_ID"):
        pick_domain_id(proc)


def test_pick_domain_id_on_this_machine():
    d = pick_domain_id()
    assert DOMAIN_RANGE[0] <= d <= DOMAIN_RANGE[1] and d not in domains_in_use()


# ---------------------------------------------------------------- parameter files

def test_params_file_sections_and_merge(tmp_path):
    f = tmp_path / "p.yaml"
    f.write_text(yaml.safe_dump({"/**": {"ros__parameters": {"use_sim_time": False, "dt": 0.004}},
                                 "/monitor_node": {"ros__parameters": {"max_missing_ticks": 125, "dt": 0.002,
                                                                       "nested": {"a": [1.0, 2.0]}}},
                                 "sim_node": {"ros__parameters": None}}))
    s = params_file.load(f)
    assert set(s) == {"/**", "monitor_node", "sim_node"}
    assert params_file.for_node(s, "monitor_node") == {"use_sim_time": False, "dt": 0.002, "max_missing_ticks": 125,
                                                       "nested.a": [1.0, 2.0]}
    assert params_file.for_node(s, "observer_node") == {"use_sim_time": False, "dt": 0.004}


@pytest.mark.parametrize("text, match", [
    ("monitor_node: [1, 2", "not valid YAML at line"),
    ("- 1\n- 2\n", "not a ROS 2 parameter file"),
    ("monitor_node: {max_missing_ticks: 3}\n", "has no ros__parameters"),
    ("/ns/monitor_node: {ros__parameters: {a: 1}}\n", "no namespaces"),
    ("monitor_node: {ros__parameters: {u_max: [1, 2.5]}}\n", "monitor_node.u_max: mixed types"),
    ("monitor_node: {ros__parameters: {joints: []}}\n", "monitor_node.joints: an empty list"),
    ("monitor_node: {ros__parameters: {a: 1}}\n/monitor_node: {ros__parameters: {b: 1}}\n", "two sections"),
])
def test_params_file_errors_name_the_problem(tmp_path, text, match):
    f = tmp_path / "p.yaml"
    f.write_text(text)
    with pytest.raises(ReachsetError, match=match):
        params_file.load(f)


def cli(*args, **kw):
    return subprocess.run([sys.executable, "-m", "reachset_ros.cli", *args], capture_output=True, text=True,
                          timeout=120, **kw)


@pytest.mark.parametrize("case", ["missing params", "unknown section", "missing model", "bad model",
                                  "bad model in params"])
def test_up_bad_input_exits_2_with_one_line_and_starts_nothing(tmp_path, case):
    bad_model = tmp_path / "bad.yaml"
    bad_model.write_text("format: nonsense\n")
    params = tmp_path / "p.yaml"
    args = {"missing params": ["--params-file", str(tmp_path / "none.yaml")],
            "unknown section": ["--params-file", str(params)],
            "missing model": ["--model", str(tmp_path / "none.yaml")],
            "bad model": ["--model", str(bad_model)],
            "bad model in params": ["--params-file", str(params)]}[case]
    params.write_text(yaml.safe_dump(
        {"monitr_node": {"ros__parameters": {"a": 1}}} if case == "unknown section"
        else {"monitor_node": {"ros__parameters": {"model_file": str(bad_model)}}}))
    work = tmp_path / "work"
    out = cli("up", "--sim", "--workdir", str(work), *args)
    assert out.returncode == 2, out.stderr
    assert out.stdout == ""                       # not even a domain: nothing started
    assert len(out.stderr.strip().splitlines()) == 1 and out.stderr.startswith("reachset up: error: ")
    assert "Traceback" not in out.stderr
    assert not work.exists()


# ---------------------------------------------------------------- stopping children

def kill_left_over(marker):
    """Clean-up after a failed test: SIGKILL whatever of the suite is still running."""
    for pid, _ in suite_processes(marker):
        try:
            os.kill(pid, signal.SIGKILL)
        except OSError:
            pass


def test_stop_kills_what_a_node_left_in_its_group():
    # the leader exits on SIGINT; a background job of sh (SIGINT ignored) stays in its group
    proc = subprocess.Popen(["sh", "-c", "sleep 300 & echo $!; exec sleep 300"], stdout=subprocess.PIPE,
                            text=True, start_new_session=True)
    left = int(proc.stdout.readline())
    n = processes.NodeProcess("sh", proc, Path("/dev/null"))
    assert n.alive() and running(left)
    processes.stop([n], timeout=10)
    assert proc.returncode is not None
    assert gone(left), "a process of the node's group outlived stop()"


def gone(pid, limit=30.0):
    """Wait (up to ``limit`` s: a SIGKILLed process may not have run yet) until ``pid`` is not running."""
    end = time.monotonic() + limit
    while running(pid) and time.monotonic() < end:
        time.sleep(0.02)
    return not running(pid)


def test_background_child_low_priority_own_group_and_ended_with_its_parent(tmp_path):
    # a parent that starts a background child and is then SIGKILLed: the child gets SIGTERM
    code = ("import sys, time; from reachset_ros import processes; "
            "p = processes.start_background(['sleep', '300']); print(p.pid, flush=True); time.sleep(300)")
    parent = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True,
                              env=dict(os.environ, PYTHONPATH=str(REPO)))
    try:
        child = int(parent.stdout.readline())
        assert os.getpgid(child) == child != os.getpgid(parent.pid)       # its own group
        nice = lambda pid: int(Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[16])  # noqa: E731
        assert nice(child) == min(19, nice(parent.pid) + processes.BACKGROUND_NICE)
        parent.kill()
        parent.wait()
        assert gone(child), "the background child outlived its parent"
    finally:
        parent.kill()
        parent.wait()


# ---------------------------------------------------------------- reachset up, end to end

class Listener:
    """Subscriptions in DDS domain ``domain`` (an rclpy context of its own), spun by a thread."""

    def __init__(self, domain, topics):
        import rclpy
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.signals import SignalHandlerOptions
        self.rclpy = rclpy
        self.context = rclpy.Context()
        rclpy.init(context=self.context, domain_id=domain, signal_handler_options=SignalHandlerOptions.NO)
        self.node = rclpy.create_node("test_up_listener", context=self.context)
        self.got = {t: 0 for t in topics}
        for t, typ in topics.items():
            self.node.create_subscription(typ, t, lambda m, t=t: self.got.__setitem__(t, self.got[t] + 1), 10)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self.running = True
        self.thread = threading.Thread(target=self._spin, daemon=True)
        self.thread.start()

    def _spin(self):
        while self.running:
            self.executor.spin_once(timeout_sec=0.1)

    def close(self):
        self.running = False
        self.thread.join(5)
        self.executor.shutdown(timeout_sec=1.0)
        self.node.destroy_node()
        self.rclpy.try_shutdown(context=self.context)


def test_up_brings_the_suite_up_in_a_fresh_domain_and_sigterm_stops_everything(tmp_path):
    from helpers import write_model
    from reachset_msgs.msg import ConformanceStatus
    from sensor_msgs.msg import JointState
    model = write_model(tmp_path / "model.yaml")
    params = tmp_path / "params.yaml"
    params.write_text(yaml.safe_dump({"/**": {"ros__parameters": {"use_sim_time": False}},
                                      "monitor_node": {"ros__parameters": {"max_missing_ticks": 125}},
                                      "sim_node": {"ros__parameters": {"seed": 3}}}))
    work = tmp_path / "work"
    up = subprocess.Popen([sys.executable, "-m", "reachset_ros.cli", "up", "--sim", "--model", str(model),
                           "--params-file", str(params), "--workdir", str(work), "--json"],
                          stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    listener = None
    try:
        first = up.stdout.readline()
        assert first.startswith("ROS_DOMAIN_ID="), (first, up.stderr.read() if up.poll() is not None else "")
        domain = int(first.strip().split("=", 1)[1])
        assert DOMAIN_RANGE[0] <= domain <= DOMAIN_RANGE[1]
        ready = json.loads(up.stdout.readline() or "null")     # once every node is up
        assert ready is not None, up.stderr.read()
        assert ready["ros_domain_id"] == domain and [n["name"] for n in ready["nodes"]] == [
            "sim_node", "reference_node", "observer_node", "controller_node", "monitor_node", "synthesis_node"]
        # the parameters reached their nodes: up's defaults, the file's sections, the model
        mon = yaml.safe_load((work / "monitor_node.params.yaml").read_text())["monitor_node"]["ros__parameters"]
        assert mon["max_missing_ticks"] == 125 and mon["model_file"] == str(model.resolve())
        assert mon["use_sim_time"] is False and mon["window_dir"] == str(work.resolve() / "windows")
        ctl = yaml.safe_load((work / "controller_node.params.yaml").read_text())["controller_node"]["ros__parameters"]
        assert ctl["wait_for_monitor"] is True and ctl["model_file"] == str(model.resolve())
        sim = yaml.safe_load((work / "sim_node.params.yaml").read_text())["sim_node"]["ros__parameters"]
        assert sim["seed"] == 3 and "model_file" not in sim
        pids = [n["pid"] for n in ready["nodes"]]
        for p in pids:
            assert f"ROS_DOMAIN_ID={domain}".encode() in Path(f"/proc/{p}/environ").read_bytes().split(b"\0")
        # the suite works in that domain
        listener = Listener(domain, {"/joint_states": JointState, "/conformance/status": ConformanceStatus})
        end = time.monotonic() + 180
        while not all(listener.got.values()) and time.monotonic() < end and up.poll() is None:
            time.sleep(0.1)
        assert all(listener.got.values()), (listener.got, up.poll())
        listener.close()
        listener = None
        up.send_signal(signal.SIGTERM)
        rc = up.wait(timeout=120)
        err = up.stderr.read()
        assert rc == 0, err
        assert "stopped on SIGTERM" in err
        assert not [p for p in pids if running(p)]
        assert suite_processes(str(work), domain) == []
        for n in ready["nodes"]:
            assert Path(n["log"]).is_file() and Path(n["log"]).parent == work.resolve()
    finally:
        if listener is not None:
            listener.close()
        if up.poll() is None:
            up.kill()
            up.wait()
        kill_left_over(str(work))


def test_up_reports_a_node_that_dies_and_stops_the_rest(tmp_path):
    # a start-up configuration the controller refuses (u_max must be > 0): it exits 2 at once
    params = tmp_path / "params.yaml"
    # (the observer starts: no model, the initial gains explicitly uncertified)
    params.write_text(yaml.safe_dump({"/**": {"ros__parameters": {"allow_uncertified": True}},
                                      "controller_node": {"ros__parameters": {"u_max": [-1.0]}}}))
    work = tmp_path / "work"
    out = subprocess.run([sys.executable, "-m", "reachset_ros.cli", "up", "--params-file", str(params),
                          "--workdir", str(work)], capture_output=True, text=True, timeout=300)
    assert out.returncode == 1, out.stderr
    assert out.stdout.startswith("ROS_DOMAIN_ID=")
    domain = int(out.stdout.splitlines()[0].split("=")[1])
    last = out.stderr.strip().splitlines()[-1]
    assert "controller_node exited with status 2" in last and str(work / "controller_node.log") in last, last
    assert "observer_node is up" in out.stdout
    assert suite_processes(str(work), domain) == []


# ---------------------------------------------------------------- reachset demo stopped by SIGTERM

def test_demo_stopped_by_sigterm_during_synthesis_leaves_no_process(tmp_path):
    work = tmp_path / "demo"
    demo = subprocess.Popen([sys.executable, "-m", "reachset_ros.cli", "demo", "--headless", "--train", "3",
                             "--duration", "2", "--workdir", str(work)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        first = demo.stdout.readline()
        assert first.startswith("[demo] ROS_DOMAIN_ID="), first
        domain = int(first.split("=")[1].split()[0])
        for line in demo.stdout:                      # until the synthesis node is asked to synthesise
            if "combined synthesis on the recorded bag" in line:
                break
        else:
            pytest.fail(f"the demo ended before the synthesis: {demo.wait()} {demo.stderr.read()[-2000:]}")
        synth = []
        end = time.monotonic() + 120
        while not synth and time.monotonic() < end and demo.poll() is None:
            synth = [(p, c) for p, c in suite_processes(str(work)) if " synthesize " in c]
            time.sleep(0.02)
        assert synth, "no `reachset synthesize` child seen"
        spid = synth[0][0]
        node = [p for p, c in suite_processes(str(work)) if "reachset_ros.nodes.synthesis_node" in c][0]
        nice = lambda pid: int(Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[16])  # noqa: E731
        assert nice(spid) == min(19, nice(node) + processes.BACKGROUND_NICE)
        assert os.getpgid(spid) == spid != os.getpgid(node)
        demo.send_signal(signal.SIGTERM)
        rc = demo.wait(timeout=120)
        err = demo.stderr.read()
        assert rc == 128 + signal.SIGTERM, err[-2000:]
        assert "stopped on SIGTERM" in err
        assert not running(spid), "the synthesize child outlived the demo"
        assert suite_processes(str(work), domain) == []
    finally:
        if demo.poll() is None:
            demo.kill()
            demo.wait()
        kill_left_over(str(work))


# ---------------------------------------------------------------- the launch file (colcon users)

def test_launch_file_compiles_and_starts_the_same_suite(tmp_path, monkeypatch):
    """`launch` is not installed here: the file compiles, and with stand-ins for the launch
    API its nodes and parameters are those of `reachset up`'s plan."""
    import py_compile
    import types
    from reachset_ros.nodes import bringup
    path = REPO / "launch" / "reachset.launch.py"
    py_compile.compile(str(path), doraise=True)

    class Action:
        def __init__(self, *args, **kw):
            self.args, self.kw = args, kw

    stand_ins = {"launch": {"LaunchDescription": lambda actions: actions},
                 "launch.actions": {"DeclareLaunchArgument": Action, "OpaqueFunction": Action},
                 "launch_ros": {}, "launch_ros.actions": {"Node": Action}, "ament_index_python": {},
                 "ament_index_python.packages": {"get_package_share_directory": lambda p: f"/share/{p}"}}
    for name, attrs in stand_ins.items():
        mod = types.ModuleType(name)
        for k, v in attrs.items():
            setattr(mod, k, v)
        monkeypatch.setitem(sys.modules, name, mod)
    ns = {"__name__": "reachset_launch", "__file__": str(path)}
    exec(compile(path.read_text(), str(path), "exec"), ns)
    actions = ns["generate_launch_description"]()
    args = {a.args[0]: a.kw["default_value"] for a in actions if "default_value" in a.kw}
    assert args == {"sim": "false", "model": "", "params_file": "", "workdir": ""}
    opaque = [a for a in actions if "function" in a.kw][0]
    params = tmp_path / "p.yaml"
    params.write_text(yaml.safe_dump({"sim_node": {"ros__parameters": {"seed": 4}}}))
    model = synthesised_model(tmp_path / "m.yaml")
    work = tmp_path / "w"
    context = types.SimpleNamespace(launch_configurations={"sim": "true", "model": str(model),
                                                           "params_file": str(params), "workdir": str(work)})
    nodes = opaque.kw["function"](context)
    plan = bringup.plan(params_file.load(params), True, work, model)
    assert [n.kw["name"] for n in nodes] == [n.kw["executable"] for n in nodes] == list(plan)
    for n in nodes:
        assert n.kw["parameters"] == ([plan[n.kw["name"]]] if plan[n.kw["name"]] else []), n.kw["name"]
    context.launch_configurations = {"sim": "false", "model": "", "params_file": "", "workdir": str(work)}
    nodes = opaque.kw["function"](context)
    assert [n.kw["name"] for n in nodes] == list(bringup.plan({}, False, work))
    assert "monitor_node" not in [n.kw["name"] for n in nodes]          # no model: unmonitored


def synthesised_model(path, omega=22.5):
    """A six-joint model whose joints carry synthesised gains (as ``synthesize`` writes them)."""
    from reachset_ros.conformance import model as mdl
    from reachset_ros.conformance.estimators import Estimator
    from reachset_ros.robot.dynamics import JOINT_NAMES
    from reachset_ros.systems.plant import lwa4p_joint_plant
    gains = {"observer": "hg", "controller": "static", "omega": omega, "zeta": 1.1, "h1": 15.0, "h2": 30.0,
             "eps": 0.01}
    js = {j: mdl.JointSets((0.15, 0.0), (4e-4,), (0.0,) * 5, (0.0,), 0, 25, dict(gains, omega=omega + i))
          for i, j in enumerate(JOINT_NAMES)}
    mdl.save(mdl.ConformanceModel(lwa4p_joint_plant(), {"kind": "lwa4p_joint", "dt": 0.004}, Estimator("fd"), 25, js,
                                  input_source=mdl.PLANT_INPUT), path)
    return Path(path)


def test_up_with_a_model_starts_the_pair_with_its_gains_through_the_gate(tmp_path):
    """Issue 36.1. Before: ``up --model M`` gave the observer and controller M as their model but
    their start-up gains (omega 10, not the 22.6 M was synthesised for), with ``allow_uncertified``
    under ``--sim``; and without a model it started a monitor that cannot check (it exits 2).
    Now the pair starts with M's gains, per joint in the node's joint order, certified at start
    (``allow_uncertified`` false unless the file says so); without a model no monitor starts,
    the controller does not wait for one, and ``up`` says UNMONITORED."""
    from reachset_ros.nodes import bringup
    from reachset_ros.robot.dynamics import JOINT_NAMES
    model = synthesised_model(tmp_path / "m.yaml")
    plan = bringup.plan({}, True, tmp_path, model)
    for node in ("observer_node", "controller_node"):
        p = plan[node]
        assert p["omega"] == [22.5 + i for i in range(len(JOINT_NAMES))] and p["zeta"] == [1.1] * len(JOINT_NAMES)
        assert p["observer"] == "hg" and p["controller"] == "static" and p["allow_uncertified"] is False
        assert p["model_file"] == str(model)
    assert not bringup.unmonitored(plan) and plan["controller_node"]["wait_for_monitor"] is True
    # a file that orders the joints differently gets each joint's own gains
    order = list(reversed(JOINT_NAMES))
    p = bringup.plan({"controller_node": {"joints": order}}, True, tmp_path, model)["controller_node"]
    assert p["omega"] == [22.5 + JOINT_NAMES.index(j) for j in order]
    # an identified model without gains: the start-up gains, with --sim's allow_uncertified, as before
    from helpers import write_model
    plain = bringup.plan({}, True, tmp_path, write_model(tmp_path / "plain.yaml"))
    assert plain["controller_node"]["allow_uncertified"] is True and "omega" not in plain["controller_node"]
    bare = bringup.plan({}, True, tmp_path, None)
    assert bringup.unmonitored(bare) and "monitor_node" not in bare
    assert bare["controller_node"]["wait_for_monitor"] is False and "omega" not in bare["controller_node"]
    from reachset_ros.commands.up import UNMONITORED
    assert UNMONITORED.startswith("UNMONITORED")
