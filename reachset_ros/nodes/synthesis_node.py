"""synthesis_node: offline identification / synthesis from bags, as a ROS service.

``~/synthesize`` (reachset_msgs/srv/Synthesize) runs the synthesis workflow
(:func:`reachset_ros.workflows.synthesize.synthesize`) on the given bags in a worker process
(:mod:`reachset_ros.commands._synthesis_worker`: the very same code path as ``reachset
synthesize``, whose options, ``extra_args`` included, it takes; it hands the result back as
the library's values, pickled, so the two agree to the bit). The node's executor waits for
it: the node answers nothing else meanwhile; the worker runs at low priority, nice +10, so
that it cannot starve the control loop, in a process group of its own that SIGINT/SIGTERM
to the node stops, and it gets SIGTERM if the node dies —
publishes the result on ``synthesis/result``
(latched), and, when ``apply`` is set and every joint is conformant with R_u inside U_p,
applies the gains and the model through the other nodes' parameter services:
``controller_node`` first (it re-checks stability and R_u ⊆ U_p and may refuse), then
``observer_node``, then ``monitor_node`` (each of the first two certifies the pair that will
run with the other's running half, :mod:`~reachset_ros.nodes.pair_gate`; when the controller
refuses that intermediate pair, the observer is tried first). Both also certify it under the
running monitor's model (row G19): when the pair running now is certified under the new model,
``monitor_node`` is set first instead, so the new gains never run under sets they are not
certified for. Nothing is applied from a failed or non-conformant result.

Gains are applied by joint name: the controller and observer read their per-joint arrays
in the order of their own ``joints`` parameter (an array of length 1 is one value for all
joints), so the node first reads each target's current ``joints``, types and arrays
(``get_parameters``) and sends full arrays in that order, the synthesised joints with their
new values and every other joint with its current one. It refuses before anything is
applied when a synthesised joint is not one of a target's joints, or when the synthesis'
observer/controller type differs from a target's while the synthesis does not cover all of
that target's joints (the type is one parameter per node). When a later target refuses,
the targets already updated are set back to their previous values of exactly the
parameters that were set, in reverse order, and the reason says whether that succeeded;
the node's own ``model_file`` changes only after every target accepted. Mode
``reidentify`` keeps the gains of the current model (``model_file`` parameter) and only
updates the sets.
"""
import pickle
import signal
import subprocess
import sys
import time
from pathlib import Path

import rclpy
from rclpy.node import Node
from rclpy.parameter import Parameter
from reachset_msgs.msg import JointSynthesis, SynthesisResult
from reachset_msgs.srv import Synthesize

from .. import defaults, processes
from ..atomic import write_yaml
from ..conformance import model as mdl
from ..errors import ReachsetError
from ..systems.gains import GAIN_KEYS, TYPE_KEYS, Gains, certify
from .pair_gate import certify_running_pair_under
from .common import SAFE_STOP_QOS, desc, get_remote_parameters, set_remote_parameters, spin_node

#: the worker process: a program run by module name (the node does not import the workflows)
WORKER = "reachset_ros.commands._synthesis_worker"
#: per-joint parameters each target takes from a synthesis, besides the ``observer`` and
#: ``controller`` types (the observer node has no use for the feedback gains omega, zeta)
#: both nodes get the whole pair (observer and controller gains), U_p and the model: each
#: certifies the pair it will be part of (gain_params.validate_pair, systems.gains.certify_pair)
#: the words of a roll-back that left a target with the new values (:meth:`SynthesisNode.roll_back`)
ROLLBACK_FAILED = "ROLLBACK FAILED"
TARGET_KEYS = {"controller_node": GAIN_KEYS + ("u_max",),
               "observer_node": GAIN_KEYS + ("u_max",)}
#: the loop structure, one string per node (GAIN_KEYS and TYPE_KEYS: defaults ``gains.keys``,
#: ``gains.types``); ``eso_input``: which plant input the ESO is fed, a model file without it
#: means ``gains.eso.eso_input`` ("previous"), as :meth:`Gains.from_model` reads it
TYPE_DEFAULTS = {"eso_input": defaults.get("gains.eso.eso_input")}


def certify_synthesis(data, model_file):
    """Empty when every synthesised joint's R*_u is inside U_p for the model it will run with.

    Per joint of ``data["joints"]`` (``reachset synthesize --json``): the model file's gains
    and sets, the joint's ``inflation`` (the sets the monitor checks are scaled by ``1 + inflation``),
    ``U_ff`` and the recorded ``U_e,ff`` (:func:`~reachset_ros.systems.gains.certify`, with the
    joint's ``u_max`` and ``u_ff``). Otherwise the reason, one line, naming the joint.
    """
    try:
        model = mdl.load(model_file)
        for name, j in data["joints"].items():
            js = model.joints.get(name)
            if js is None:
                return f"joint {name}: not in the model {model_file}"
            c = certify(Gains.from_model(js.gains), js, model.joint_inflation(name), float(j["u_max"]),
                        float(j.get("u_ff", 2.0)), plant=model.plant)
            if not c.ok:
                return f"joint {name}: {c.reason}"
    except (ReachsetError, KeyError, TypeError, ValueError) as e:
        return f"the synthesis result cannot be certified: {one_line(e)}"
    return ""


def recorded_loop_outside(data):
    """Empty, or why a result may not be applied: a joint whose own recorded loop (the bags'
    tracking error with the kept gains, ``recorded_loop`` of ``reachset synthesize --json``,
    ``verified``) leaves its R*_e (``inside`` false; issue 34.5, the rule of
    :func:`reachset_ros.synthesis.recorded_loop.require_inside`)."""
    for name, j in data.get("joints", {}).items():
        d = j.get("recorded_loop") or {}
        if d.get("verified") and d.get("ticks") and not d.get("inside"):
            reach = max((r for r in d.get("reach", []) if r is not None), default=float("nan"))
            return f"joint {name}: the loop recorded with these gains leaves R*_e ({reach:.4g} of its radius)"
    return ""


def one_line(text):
    """``text`` with its line breaks and runs of white space folded into single spaces."""
    return " ".join(str(text).split())


def per_joint(value, n):
    """A per-joint array parameter as ``n`` floats, the way the nodes read it.

    Parameters
    ----------
    value : sequence of float
        The parameter's value: one value for all joints, or one per joint (a longer array
        gives its first ``n``, as the controller reads ``u_max``).
    n : int
        Number of joints of the node.

    Returns
    -------
    list of float or None
        None when ``value`` has neither 1 nor at least ``n`` values.
    """
    vals = [float(x) for x in value]
    if len(vals) == 1:
        return vals * n
    return vals[:n] if len(vals) >= n else None


def target_values(target, current, synthesis, keys):
    """New parameter values of a controller or observer node for a synthesis, by joint name.

    Parameters
    ----------
    target : str
        Node name (for the reason).
    current : dict
        The node's current ``joints``, ``observer``, ``controller`` and ``keys`` values.
    synthesis : dict
        ``{joint: gains}`` of the synthesised joints (model-file gains: ``observer``,
        ``controller``, the gain parameters, ``u_max``).
    keys : sequence of str
        The per-joint array parameters this node takes.

    Returns
    -------
    values : dict or None
        ``observer``, ``controller`` and, for every key all synthesised joints have, the
        full array in the order of the node's ``joints``: the synthesised joints' new
        values, the other joints' current ones. None when refused.
    reason : str
        Empty, or one line naming the node and the joint: a synthesised joint the node
        does not have, an array of the wrong length, or a type change (observer or
        controller) for a synthesis that does not cover all of the node's joints.
    """
    joints = [j for j in current["joints"] if j]
    for j in synthesis:
        if j not in joints:
            return None, f"{target}: joint {j} is not one of its joints ({', '.join(joints)})"
    uncovered = [j for j in joints if j not in synthesis]
    values = {}
    for t in TYPE_KEYS:
        kinds = {j: str(g.get(t, TYPE_DEFAULTS.get(t, ""))) for j, g in synthesis.items()}
        if len(set(kinds.values())) > 1:
            a, b = sorted(set(kinds.values()))[:2]
            ja = next(j for j, k in kinds.items() if k == a)
            jb = next(j for j, k in kinds.items() if k == b)
            return None, (f"{target}: the synthesis has {t} {a} for joint {ja} but {b} for joint {jb}; "
                          f"the node runs one {t} type for all its joints")
        kind = next(iter(kinds.values()))
        if kind != current[t] and uncovered:
            return None, (f"{target}: the synthesis' {t} is {kind}, the node's is {current[t]}, and joint "
                          f"{uncovered[0]} is not synthesised; the {t} type is one per node, so synthesise "
                          f"all of its joints ({', '.join(joints)})")
        values[t] = kind
    for k in keys:
        if not all(k in g for g in synthesis.values()):
            continue
        arr = per_joint(current[k], len(joints))
        if arr is None:
            return None, (f"{target}: parameter {k} has {len(current[k])} values for {len(joints)} joints "
                          f"(joint {joints[len(current[k])]} has none)")
        for j, g in synthesis.items():
            arr[joints.index(j)] = float(g[k])
        values[k] = arr
    return values, ""


def apply_orders(plan, monitor_first=False):
    """The orders in which :meth:`SynthesisNode.apply` tries to set ``plan``'s targets: as
    planned (controller, observer, monitor), then, when the controller refused first, with the
    observer first. Each of the two certifies the pair that will run after its change with the
    other's running half and under the running monitor's model (:mod:`~reachset_ros.nodes.pair_gate`,
    issue 34.6, rows G16 and G19): of the two intermediate pairs (new controller with the old
    observer, or the reverse) one may be certified when the other is not. With
    ``monitor_first`` (the pair running now is certified under the new model, checked by the
    caller) the same two orders follow with the monitor set first: the new gains need not be
    certified under the monitor's old model then."""
    names = [p[0] for p in plan]
    orders = [plan]
    if names[:2] == ["controller_node", "observer_node"]:
        orders.append([plan[1], plan[0], *plan[2:]])
    if monitor_first and names[-1] == "monitor_node":
        # every moment then runs gains certified under the monitored sets: the running pair
        # under the new model (checked by the caller), then each new half under it (the gate)
        orders = [[order[-1], *order[:-1]] for order in orders]
    yield from orders


class SynthesisNode(Node):
    def __init__(self):
        super().__init__("synthesis_node")
        self.declare_parameter("workdir", "bags/synthesis", desc("where result models are written"))
        self.declare_parameter("model_file", "", desc("current model (reidentify keeps its gains)"))
        self.declare_parameter("observer", "hg", desc("observer of combined/separate synthesis: hg | eso"))
        self.declare_parameter("extra_args", [""], desc("extra `reachset synthesize` arguments"))
        self.declare_parameter("inflation", -1.0, desc("the monitor's set inflation the gains are certified for "
                                                       "(`reachset synthesize --inflation`); < 0: the current "
                                                       "model's (model_file: calibrated by identify --validate or "
                                                       "synthesised for), 0 without one", -1.0, 1e3))
        self.declare_parameter("targets", ["controller_node", "observer_node", "monitor_node"],
                               desc("nodes the gains/model are applied to"))
        self.pub = self.create_publisher(SynthesisResult, "synthesis/result", SAFE_STOP_QOS)
        self.create_service(Synthesize, "~/synthesize", self.on_synthesize)
        self.count = 0
        self.child = None          # the running synthesis worker (subprocess.Popen)
        self.stopping = False      # SIGINT/SIGTERM received
        # parameter clients live on their own node, spun on demand: the service callback
        # cannot spin the node that is running it
        self.client_node = rclpy.create_node("synthesis_node_client")

    def on_synthesize(self, req, resp):
        res = SynthesisResult()
        res.header.stamp = self.get_clock().now().to_msg()
        res.mode, res.bags = req.mode or "combined", list(req.bags)
        ok, msg, data, model_file = self.run(req)
        res.success, res.message = ok, msg
        if data:
            for name, j in data.get("joints", {}).items():
                res.joints.append(self.joint_msg(name, j))
        if ok:
            res.model_file = model_file
            if req.apply:
                applied, why = self.apply(data, model_file)
                res.applied = applied
                if not applied:
                    res.success, res.message = False, f"{msg}; NOT applied: {why}"
                else:
                    res.message = (f"{msg}; applied to {', '.join(self.get_parameter('targets').value)}"
                                   + (f"; parameters in {self.applied_params_file}"
                                      if getattr(self, "applied_params_file", None) else ""))
        resp.success, resp.message, resp.result = res.success, res.message, res
        self.pub.publish(res)
        if res.success:
            self.get_logger().info(res.message)
        else:
            self.get_logger().error(res.message)
        return resp

    def run(self, req):
        mode = req.mode or "combined"
        if mode not in ("combined", "separate", "reidentify"):
            return False, f"unknown mode {mode!r} (combined, separate, reidentify)", None, ""
        if not req.bags:
            return False, "no bags given", None, ""
        # absolute: the model path is handed to other nodes, whose working directory may differ
        workdir = Path(self.get_parameter("workdir").value).resolve()
        workdir.mkdir(parents=True, exist_ok=True)
        self.count += 1
        out = workdir / f"model_{int(time.time())}_{self.count}_{mode}.yaml"
        # "--json": the command line recorded in the model is the one `reachset synthesize` records
        cmd = [sys.executable, "-m", WORKER, "synthesize", *req.bags, "--mode", mode, "--out", str(out), "--json"]
        if req.joints:
            cmd += ["--joints", ",".join(req.joints)]
        current = self.get_parameter("model_file").value
        if mode == "reidentify":
            if not current:
                return False, "reidentify needs a current model (none applied yet)", None, ""
            cmd += ["--model", current]
        else:
            cmd += ["--observer", self.get_parameter("observer").value]
        inflation = float(self.get_parameter("inflation").value)
        if current and mode != "reidentify":
            # the current model's Theorem-1 rows (initial-state set or not) and, by default, its
            # inflation (calibrated on held-out data by `identify --validate`, or the one the
            # gains were synthesised for); reidentify takes both from --model itself
            try:
                cur = mdl.load(current)
            except ReachsetError as e:
                return False, f"the current model {current}: {e}", None, ""
            if inflation < 0:
                inflation = float(cur.inflation)
            cmd += ["--initial-state-set" if cur.initial_state_set else "--no-initial-state-set"]
        if inflation >= 0:
            cmd += ["--inflation", repr(inflation)]
        cmd += [a for a in self.get_parameter("extra_args").value if a]
        p = self.run_child(cmd)
        if self.stopping:
            return False, "synthesis stopped: the node is shutting down", None, ""
        if p.returncode != 0:
            return False, (p.stderr.strip().splitlines() or ["synthesis failed"])[-1], None, ""
        data = pickle.loads(p.stdout)   # the worker's own result (the command's --json object)
        bad = [n for n, j in data.get("joints", {}).items()
               if not j.get("conformant", False) or not j.get("ru_inside_up", True)]
        if bad:
            return False, f"joint {bad[0]}: result not conformant or R_u outside U_p", data, ""
        why = recorded_loop_outside(data)
        if why:            # the worker refuses it already (recorded_loop.require_inside); never applied
            return False, why, data, ""
        norms = ", ".join(f"{n} {j['re_norm']:.3g}" for n, j in data["joints"].items())
        # issue 37.3: the parts of the reference class the model was never validated on (named, not refused)
        envelope = (data.get("envelope") or {}).get("note") or "envelope: none recorded"
        return True, f"{mode}: ||R_e|| {norms}; model {out}; {envelope}", data, str(out)

    def run_child(self, cmd):
        """Run ``cmd`` (the synthesis worker) to its end: at low priority, in a process
        group of its own (:func:`reachset_ros.processes.start_background`), stopped with its
        group when the node gets SIGINT/SIGTERM (:meth:`on_signal`) or is closed.

        Returns
        -------
        subprocess.CompletedProcess
            ``returncode``, ``stdout`` (bytes: the worker's pickled result), ``stderr`` (text).
        """
        if self.stopping:               # the node is shutting down: start nothing
            return subprocess.CompletedProcess(cmd, -signal.SIGTERM, b"", "")
        proc = processes.start_background(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
        self.child = proc
        try:
            if self.stopping:           # a signal came while it was being started
                processes.signal_group(proc, signal.SIGTERM)
            out, err = proc.communicate()
        finally:
            self.child = None
            if proc.returncode is None:     # communicate() did not finish
                self.stop_child(proc)
        return subprocess.CompletedProcess(cmd, proc.returncode, out, err.decode(errors="replace"))

    def on_signal(self, signum):
        """SIGINT/SIGTERM (called from the signal handler of
        :func:`~reachset_ros.nodes.common.spin_until_signal`): stop a running synthesis, so
        the service callback returns and the node can shut down; SIGTERM to the child's
        group, SIGKILL from the second signal on (``processes.stop`` escalates with SIGTERM)."""
        again = self.stopping
        self.stopping = True
        if self.child is not None:
            processes.signal_group(self.child, signal.SIGKILL if again else signal.SIGTERM)

    @staticmethod
    def stop_child(proc, grace=3.0):
        """SIGTERM to ``proc``'s group, SIGKILL after ``grace`` s; reaps it."""
        processes.signal_group(proc, signal.SIGTERM)
        try:
            proc.wait(timeout=grace)
        except subprocess.TimeoutExpired:
            processes.signal_group(proc, signal.SIGKILL)
            proc.wait()

    def close(self):
        """Node shutdown: no synthesis worker is left running."""
        if self.child is not None:
            self.stop_child(self.child)

    def joint_msg(self, name, j):
        m = JointSynthesis(name=name)
        g = j.get("gains", {})
        m.conformant = bool(j.get("conformant", False))
        m.observer, m.controller = str(g.get("observer", "")), str(g.get("controller", ""))
        keys = [k for k in GAIN_KEYS if k in g]
        m.param_names, m.param_values = keys, [float(g[k]) for k in keys]
        m.re_norm = float(j.get("re_norm", 0.0))
        m.re_radius = [float(x) for x in j.get("re_radius", [])]
        m.ru_lower, m.ru_upper = (float(x) for x in j.get("ru", [0.0, 0.0]))
        m.alpha_w = [float(x) for x in j.get("alpha_w", [])]
        m.alpha_v = [float(x) for x in j.get("alpha_v", [])]
        m.c_w = [float(x) for x in j.get("c_w", [])]
        m.c_v = [float(x) for x in j.get("c_v", [])]
        m.test_cases, m.horizon = int(j.get("test_cases", 0)), int(j.get("horizon", 0))
        return m

    def apply(self, data, model_file):
        """Apply a successful synthesis to the ``targets``, by joint name, all or nothing.

        Parameters
        ----------
        data : dict
            The ``reachset synthesize --json`` output; its ``joints`` are the synthesised
            joints, each with its ``gains`` and ``u_max``.
        model_file : str
            The model it wrote.

        Returns
        -------
        applied : bool
        reason : str
            Empty when applied, else one line: which node refused or could not be read
            (naming the joint where one is at fault), and, when earlier targets had
            accepted, whether setting them back succeeded.

        Notes
        -----
        First every joint is certified for the model file (:func:`certify_synthesis`: R*_u of
        the sets the monitor checks inside U_p), whatever the targets. Then per target, in
        the order controller_node, observer_node, monitor_node (those in
        ``targets``), the current values are read through ``get_parameters`` and the new
        ones planned (:func:`target_values`; the controller and the observer get the whole
        pair's gains, ``u_max`` and ``model_file``, the monitor ``model_file``) before anything is set, so a plan that
        cannot work (a joint a target lacks, a partial synthesis that would change a node's
        observer/controller type, a target not answering) changes nothing. Each target's
        parameters are set atomically; on a refusal the targets already updated get their
        previous values of the same parameters back, the last updated first. The node's
        own ``model_file`` is set only when every target accepted. The controller and the
        observer each certify the pair that will run after their change with the other's
        running half (:mod:`~reachset_ros.nodes.pair_gate`); when the controller refuses first
        (nothing applied yet), the observer is set first instead (:func:`apply_orders`). Both
        also certify it under the running monitor's model (row G19), so the monitor is set
        first when the pair running now is certified under the new model
        (:func:`~reachset_ros.nodes.pair_gate.certify_running_pair_under`), last otherwise.
        """
        why = certify_synthesis(data, model_file)
        if why:
            return False, f"not certified: {why}"
        synthesis = {n: {**j.get("gains", {}), **({"u_max": j["u_max"]} if "u_max" in j else {})}
                     for n, j in data["joints"].items()}
        targets = list(self.get_parameter("targets").value)
        plan = []      # (node, new values, previous values of the same parameters)
        for node, keys in TARGET_KEYS.items():
            if node not in targets:
                continue
            names = ["joints", *TYPE_KEYS, *keys, "model_file"]
            current, why = get_remote_parameters(self.client_node, node, names)
            if current is None:
                return False, why
            values, why = target_values(node, current, synthesis, keys)
            if values is None:
                return False, why
            values["model_file"] = model_file
            previous = {k: current[k] for k in values}
            # the reason goes with the change into the PRIVILEGED log line of the target
            values["change_reason"] = f"{self.get_name()}: applying the synthesis {model_file}"
            previous["change_reason"] = f"{self.get_name()}: rolled back, another target refused {model_file}"
            plan.append((node, values, previous))
        if "monitor_node" in targets:
            current, why = get_remote_parameters(self.client_node, "monitor_node", ["model_file"])
            if current is None:
                return False, why
            plan.append(("monitor_node", {"model_file": model_file}, current))
        refusals = []
        monitor_first = False
        if "monitor_node" in targets and {"controller_node", "observer_node"} <= set(targets):
            # the monitor may switch first only when the pair running now is certified under
            # the new model (row G19: no moment runs gains the monitored sets do not certify)
            monitor_first = not certify_running_pair_under(self.client_node, mdl.load(model_file))
        for order in apply_orders(plan, monitor_first):
            ok, why, applied_some = self.set_in_order(order)
            if ok:
                break
            refusals.append(f"{' -> '.join(n for n, _, _ in order)}: {why}")
            if applied_some and ROLLBACK_FAILED in why:   # a target keeps the new values: no second order from there
                break
        if not ok:
            return False, "; then ".join(refusals)
        self.set_parameters([Parameter("model_file", value=model_file)])
        self.write_applied(plan)
        return True, ""

    def set_in_order(self, plan):
        """Set the targets of ``plan`` one after the other; on a refusal set the ones done back.

        Returns
        -------
        ok : bool
        reason : str
            Which node refused and why, and what the roll-back did.
        applied_some : bool
            A target had accepted before the refusal.
        """
        done = []
        for node, values, previous in plan:
            ok, why = set_remote_parameters(self.client_node, node, values)
            if not ok:
                return False, f"{node} refused: {one_line(why)}; {self.roll_back(done)}", bool(done)
            done.append((node, previous))
        return True, "", bool(done)

    def write_applied(self, plan):
        """The applied values as a ROS 2 parameter file (``--params-file``), so that a restart
        keeps them: ``<workdir>/applied_gains.params.yaml``, written atomically, logged."""
        doc = {}
        for node, values, _ in plan:
            doc[node] = {"ros__parameters": {k: (list(v) if isinstance(v, (list, tuple)) else v)
                                             for k, v in values.items() if k != "change_reason"}}
        path = Path(self.get_parameter("workdir").value).resolve() / "applied_gains.params.yaml"
        try:
            write_yaml(path, doc, header="# written by synthesis_node after applying a synthesis; "
                                          "use with --ros-args --params-file (or reachset up --params-file)\n")
            self.applied_params_file = str(path)
            self.get_logger().info(f"applied parameters written to {path}")
        except ReachsetError as e:
            self.get_logger().error(f"could not write the applied parameters: {e}")

    def roll_back(self, done):
        """Set the targets in ``done`` (``(node, previous values)``) back, the last first.

        Returns
        -------
        str
            What happened, for the refusal's reason: nothing to undo, rolled back, or which
            node could not be set back (and why): that node keeps the new values.
        """
        if not done:
            return "nothing was applied"
        back, failed = [], []
        for node, previous in reversed(done):
            ok, why = set_remote_parameters(self.client_node, node, previous)
            if ok:
                back.append(node)
            else:
                failed.append(f"{node} ({one_line(why)})")
        if not failed:
            return f"rolled back {', '.join(back)} to the previous values"
        return ((f"rolled back {', '.join(back)}; " if back else "")
                + f"{ROLLBACK_FAILED} for {', '.join(failed)}, which keeps the new values")


def main(args=None):
    spin_node(SynthesisNode, args)


if __name__ == "__main__":
    main()
