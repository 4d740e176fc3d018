"""synthesis_node: offline identification / synthesis from bags, as a ROS service.

``~/synthesize`` (reachset_msgs/srv/Synthesize) runs ``reachset synthesize`` on the given
bags — the very same code path as the command line, in a child process so the node stays
responsive and the two agree to the bit — publishes the result on ``synthesis/result``
(latched), and, when ``apply`` is set and every joint is conformant with R_u inside U_p,
applies the gains and the model through the other nodes' parameter services:
``controller_node`` first (it re-checks stability and R_u ⊆ U_p and may refuse), then
``observer_node``, then ``monitor_node``. Nothing is applied from a failed or
non-conformant result. Mode ``reidentify`` keeps the gains of the current model
(``model_file`` parameter, updated after each successful apply) and only updates the sets.
"""
import json
import subprocess
import sys
import time
from pathlib import Path

import rclpy
from rclpy.node import Node
from rclpy.parameter import Parameter
from reachset_msgs.msg import JointSynthesis, SynthesisResult
from reachset_msgs.srv import Synthesize

from .common import SAFE_STOP_QOS, desc, set_remote_parameters, spin_node

GAIN_KEYS = ("omega", "zeta", "h1", "h2", "l1", "l2", "l3", "eps")


def gain_parameters(joints, per_joint_gains):
    """Parameter values for the observer/controller nodes from per-joint gains dicts."""
    first = per_joint_gains[joints[0]]
    vals = {"observer": first["observer"], "controller": first["controller"]}
    for k in GAIN_KEYS:
        if all(k in per_joint_gains[j] for j in joints):
            vals[k] = [float(per_joint_gains[j][k]) for j in joints]
    return vals


class SynthesisNode(Node):
    def __init__(self):
        super().__init__("synthesis_node")
        self.declare_parameter("workdir", "bags/synthesis", desc("where result models are written"))
        self.declare_parameter("model_file", "", desc("current model (reidentify keeps its gains)"))
        self.declare_parameter("observer", "hg", desc("observer of combined/separate synthesis: hg | eso"))
        self.declare_parameter("extra_args", [""], desc("extra `reachset synthesize` arguments"))
        self.declare_parameter("targets", ["controller_node", "observer_node", "monitor_node"],
                               desc("nodes the gains/model are applied to"))
        self.pub = self.create_publisher(SynthesisResult, "synthesis/result", SAFE_STOP_QOS)
        self.create_service(Synthesize, "~/synthesize", self.on_synthesize)
        self.count = 0
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
                    res.message = f"{msg}; applied to {', '.join(self.get_parameter('targets').value)}"
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
        workdir = Path(self.get_parameter("workdir").value)
        workdir.mkdir(parents=True, exist_ok=True)
        self.count += 1
        out = workdir / f"model_{int(time.time())}_{self.count}_{mode}.yaml"
        cmd = [sys.executable, "-m", "reachset_ros.cli", "synthesize", *req.bags, "--mode", mode,
               "--out", str(out), "--json"]
        if req.joints:
            cmd += ["--joints", ",".join(req.joints)]
        if mode == "reidentify":
            current = self.get_parameter("model_file").value
            if not current:
                return False, "reidentify needs a current model (none applied yet)", None, ""
            cmd += ["--model", current]
        else:
            cmd += ["--observer", self.get_parameter("observer").value]
        cmd += [a for a in self.get_parameter("extra_args").value if a]
        p = subprocess.run(cmd, capture_output=True, text=True)
        if p.returncode != 0:
            return False, (p.stderr.strip().splitlines() or ["synthesis failed"])[-1], None, ""
        data = json.loads(p.stdout)
        bad = [n for n, j in data.get("joints", {}).items()
               if not j.get("conformant", False) or not j.get("ru_inside_up", True)]
        if bad:
            return False, f"joint {bad[0]}: result not conformant or R_u outside U_p", data, ""
        norms = ", ".join(f"{n} {j['re_norm']:.3g}" for n, j in data["joints"].items())
        return True, f"{mode}: ||R_e|| {norms}; model {out}", data, str(out)

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
        joints = list(data["joints"])
        gains = {n: j["gains"] for n, j in data["joints"].items()}
        vals = gain_parameters(joints, gains)
        targets = list(self.get_parameter("targets").value)
        steps = []
        if "controller_node" in targets:
            u_max = [float(data["joints"][n].get("u_max", 26.0)) for n in joints]
            steps.append(("controller_node", {**vals, "model_file": model_file, "u_max": u_max}))
        if "observer_node" in targets:
            steps.append(("observer_node", {k: v for k, v in vals.items() if k != "zeta" and k != "omega"}))
        if "monitor_node" in targets:
            steps.append(("monitor_node", {"model_file": model_file}))
        for node, values in steps:
            ok, why = set_remote_parameters(self.client_node, node, values)
            if not ok:
                return False, f"{node} refused: {why}"
        self.set_parameters([Parameter("model_file", value=model_file)])
        return True, ""


def main(args=None):
    spin_node(SynthesisNode, args)


if __name__ == "__main__":
    main()
