"""monitor_node: the online conformance monitor (Theorem 1 each 4 ms tick) with safe stop.

Pairs ``/joint_states`` (y = position) and ``/plant_input`` (u_p) by header stamp and joint
name, feeds :class:`reachset_ros.monitor.Monitor` one tick at a time, publishes
``/conformance/status`` every tick and ``/diagnostics`` at about 1 Hz. On the first
violation, or on a fault (missing data for more than ``max_missing_ticks`` ticks, an
invalid sample, a joint-name mismatch), it publishes a latched ``/safe_stop`` (reliable,
transient local) and writes the offending window (the last k* + history ticks) to a bag.
Only the ``~/reset`` service (std_srvs/Trigger) clears the stop. The model (sets, horizon,
estimator) comes from ``model_file`` and can be swapped through the parameter service.
"""
from __future__ import annotations

import collections
import threading
import time
from pathlib import Path

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rcl_interfaces.msg import SetParametersResult
from rclpy.node import Node
from reachset_msgs.msg import ConformanceStatus, PlantInput, SafeStop
from sensor_msgs.msg import JointState
from std_srvs.srv import Trigger

from .. import model as mdl
from ..bags import BagWriter, joint_state, plant_input
from ..conformance import Theorem1
from ..errors import ReachsetError
from ..monitor import Monitor, MonitorModel
from .common import SAFE_STOP_QOS, STATUS_QOS, TICK_QOS, desc, spin_node, stamp_ns, to_stamp


class MonitorCore:
    """Pairing, fault detection and the monitor, without ROS (so it is testable and reusable).

    ``add_y``/``add_u`` take (stamp, names, values); completed ticks are processed in stamp
    order and returned as events: ("tick", stamp, result) or ("fault", stamp, kind, reason, joint).
    """

    def __init__(self, model: mdl.ConformanceModel, joints=None):
        self.model = model
        self.joints = list(joints or model.joints)
        missing = [j for j in self.joints if j not in model.joints]
        if missing:
            raise ReachsetError(f"joint {missing[0]} is not in the model")
        thm = Theorem1.build(model.plant, model.horizon)
        self.monitor = Monitor([MonitorModel.from_model(model, j, thm) for j in self.joints])
        self.pending = collections.OrderedDict()
        # ticks waiting for their other half: a stalled controller may lag by many ticks
        self.max_pending = 2 * (model.horizon + 1)
        self.last_stamp = None
        self.counters = collections.Counter()
        keep = model.horizon + model.estimator.history + 2
        self.window = collections.deque(maxlen=keep)

    def _pick(self, names, values, what, stamp):
        idx = {n: i for i, n in enumerate(names)}
        missing = [j for j in self.joints if j not in idx]
        if missing or len(values) < len(names):
            return None, ("name_mismatch", f"{what} at {stamp} ns lacks joint {missing[0] if missing else '?'}",
                          missing[0] if missing else "")
        return np.array([values[idx[j]] for j in self.joints], dtype=np.float64), None

    def add(self, kind, stamp, names, values):
        events = []
        if self.last_stamp is not None and stamp <= self.last_stamp:
            self.counters["stale_" + kind] += 1
            return events
        vals, err = self._pick(names, values, "/joint_states" if kind == "y" else "/plant_input", stamp)
        if err:
            return [("fault", stamp) + err]
        entry = self.pending.setdefault(stamp, {})
        entry[kind] = vals
        if "y" in entry and "u" in entry:
            # older incomplete ticks can no longer be completed: they are missing data
            for s in [s for s in self.pending if s < stamp]:
                self.counters["dropped_incomplete"] += 1
                del self.pending[s]
            del self.pending[stamp]
            events.append(self._process(stamp, entry["y"], entry["u"]))
        while len(self.pending) > self.max_pending:
            self.pending.popitem(last=False)
            self.counters["dropped_incomplete"] += 1
        return events

    def _process(self, stamp, y, u):
        self.last_stamp = stamp
        self.window.append((stamp, y, u))
        t0 = time.perf_counter()
        res = self.monitor.tick(stamp, y, u)
        res["duration"] = time.perf_counter() - t0
        self.counters["ticks"] += 1
        bad = [j for j, s in enumerate(res["status"]) if s == "invalid"]
        if bad:
            j = self.joints[bad[0]]
            return ("fault", stamp, "invalid_sample", f"invalid (non-finite) sample of joint {j} at {stamp} ns", j)
        return ("tick", stamp, res)


class MonitorNode(Node):
    """ROS adapter of :class:`MonitorCore`."""

    def __init__(self):
        super().__init__("monitor_node")
        self.declare_parameter("model_file", "", desc("conformance model YAML (identify/synthesize output)"))
        self.declare_parameter("joints", [""], desc("joints to monitor (default: all of the model)"))
        self.declare_parameter("max_missing_ticks", 25, desc("ticks without a complete sample before a fault",
                                                               1, 10000, integer=True))
        self.declare_parameter("window_dir", "bags/safe_stop", desc("where offending windows are written"))
        self.declare_parameter("dt", 0.004, desc("tick period, s", 1e-4, 1.0))
        self.core = None
        self.stop_active = False
        self.stop_msg = None
        self.last_tick_wall = None
        self.status_pub = self.create_publisher(ConformanceStatus, "conformance/status", STATUS_QOS)
        self.stop_pub = self.create_publisher(SafeStop, "safe_stop", SAFE_STOP_QOS)
        self.diag_pub = self.create_publisher(DiagnosticArray, "diagnostics", 10)
        self.create_subscription(JointState, "joint_states", self.on_joint_states, TICK_QOS)
        self.create_subscription(PlantInput, "plant_input", self.on_plant_input, TICK_QOS)
        self.create_service(Trigger, "~/reset", self.on_reset)
        self.create_timer(1.0, self.publish_diagnostics)
        self.create_timer(float(self.get_parameter("dt").value), self.watchdog)
        self.add_on_set_parameters_callback(self.on_set_parameters)
        path = self.get_parameter("model_file").value
        if path:
            ok, why = self.load(path)
            if not ok:
                self.get_logger().error(why)
        self.model_id = ""

    # -- configuration ------------------------------------------------------------------
    def load(self, path, joints=None):
        try:
            model = mdl.load(path)
            joints = joints if joints is not None else [j for j in self.get_parameter("joints").value if j]
            core = MonitorCore(model, joints or None)
        except ReachsetError as e:
            return False, str(e)
        self.core = core
        self.model_id = mdl.file_sha256(path)[:12]
        self.last_tick_wall = None
        self.get_logger().info(f"monitoring joints {core.joints} with model {path} (k*={model.horizon})")
        return True, ""

    def on_set_parameters(self, params):
        for p in params:
            if p.name == "model_file":
                if not p.value:
                    return SetParametersResult(successful=False, reason="model_file must not be empty")
                ok, why = self.load(p.value)
                if not ok:
                    return SetParametersResult(successful=False, reason=why)
            if p.name == "joints" and self.core is not None:
                ok, why = self.load(self.get_parameter("model_file").value, [j for j in p.value if j])
                if not ok:
                    return SetParametersResult(successful=False, reason=why)
        return SetParametersResult(successful=True)

    # -- data ---------------------------------------------------------------------------
    def on_joint_states(self, msg):
        self.handle_events(self.core.add("y", stamp_ns(msg.header.stamp), list(msg.name), list(msg.position))
                    if self.core else [])

    def on_plant_input(self, msg):
        self.handle_events(self.core.add("u", stamp_ns(msg.header.stamp), list(msg.name), list(msg.acceleration))
                    if self.core else [])

    def handle_events(self, events):
        for ev in events:
            if ev[0] == "fault":
                _, stamp, kind, reason, joint = ev
                self.trigger(stamp, kind, reason, joint)
                continue
            _, stamp, res = ev
            self.last_tick_wall = time.monotonic()
            self.publish_status(stamp, res)
            viol = [j for j, s in enumerate(res["status"]) if s == "violation"]
            if viol:
                j = viol[0]
                self.trigger(stamp, "violation",
                             f"joint {self.core.joints[j]} left its reachable set at step k={int(res['step'][j])}: "
                             f"N y_a = {res['deviation'][j]:.6g} > bound {res['bound'][j]:.6g}",
                             self.core.joints[j], int(res["step"][j]),
                             int(res["start_tick"][j]), float(res["deviation"][j]), float(res["bound"][j]))

    def publish_status(self, stamp, res):
        m = ConformanceStatus()
        to_stamp(m.header.stamp, stamp)
        m.conformant = bool(all(s in ("ok", "gap_reset") for s in res["status"]))
        m.safe_stop_active = self.stop_active
        m.tick = int(self.core.counters["ticks"])
        m.horizon = int(self.core.model.horizon)
        m.active_test_cases = int(max(res["checked"])) if len(res["checked"]) else 0
        m.name = list(self.core.joints)
        m.margin = [float(x) if np.isfinite(x) else (1e300 if x > 0 else -1e300) for x in res["margin"]]
        m.deviation = [float(x) for x in res["deviation"]]
        m.tightest_step = [int(x) for x in res["step"]]
        m.check_duration = float(res["duration"])
        m.model_id = self.model_id
        self.status_pub.publish(m)

    def trigger(self, stamp, kind, reason, joint="", step=-1, start_tick=-1, deviation=0.0, bound=0.0):
        """Latch the safe stop (first cause wins) and write the offending window."""
        if self.stop_active:
            return
        self.stop_active = True
        m = SafeStop()
        to_stamp(m.header.stamp, stamp)
        m.active, m.kind, m.reason, m.joint = True, kind, reason, joint
        m.step = int(step)
        m.deviation, m.bound = float(deviation), float(bound)
        if start_tick >= 0 and self.core is not None:
            m.test_case_start_ns = int(stamp - step * round(self.get_parameter("dt").value * 1e9))
        m.window_bag = self.write_window(stamp, kind)
        self.stop_msg = m
        self.stop_pub.publish(m)
        self.get_logger().error(f"SAFE STOP ({kind}): {reason}")

    def write_window(self, stamp, kind):
        if self.core is None or not self.core.window:
            return ""
        rows = list(self.core.window)
        names = list(self.core.joints)
        out = Path(self.get_parameter("window_dir").value) / f"safe_stop_{stamp}_{kind}"

        def write():
            try:
                out.parent.mkdir(parents=True, exist_ok=True)
                with BagWriter(out) as w:
                    for s, y, u in rows:
                        w.write("/joint_states", joint_state(s, names, y), s)
                        w.write("/plant_input", plant_input(s, names, u), s)
            except Exception as e:  # never kill the node for a failed write
                self.get_logger().error(f"could not write window bag {out}: {e}")

        threading.Thread(target=write, daemon=True).start()
        return str(out)

    def watchdog(self):
        if self.core is None or self.stop_active or self.last_tick_wall is None:
            return
        limit = self.get_parameter("max_missing_ticks").value * self.get_parameter("dt").value
        silent = time.monotonic() - self.last_tick_wall
        if silent > limit:
            stamp = self.core.last_stamp or self.get_clock().now().nanoseconds
            self.trigger(stamp, "missing_data",
                         f"no complete /joint_states + /plant_input sample for {silent * 1000:.0f} ms "
                         f"(limit {limit * 1000:.0f} ms)")

    def on_reset(self, request, response):
        was = self.stop_active
        self.stop_active = False
        if self.core is not None:
            self.core.monitor.reset()
            self.core.pending.clear()
            self.core.last_stamp = None
        self.last_tick_wall = None
        m = SafeStop()
        m.header.stamp = self.get_clock().now().to_msg()
        m.active, m.kind, m.reason = False, "reset", "reset through ~/reset"
        self.stop_msg = m
        self.stop_pub.publish(m)
        response.success = True
        response.message = "safe stop cleared" if was else "no safe stop was active"
        return response

    def publish_diagnostics(self):
        arr = DiagnosticArray()
        arr.header.stamp = self.get_clock().now().to_msg()
        st = DiagnosticStatus(name="reachset_ros: conformance monitor", hardware_id="")
        if self.core is None:
            st.level, st.message = DiagnosticStatus.WARN, "no model loaded"
        elif self.stop_active:
            st.level, st.message = DiagnosticStatus.ERROR, f"safe stop: {self.stop_msg.reason}"
        else:
            st.level, st.message = DiagnosticStatus.OK, "conformant"
        if self.core is not None:
            st.values = [KeyValue(key=k, value=str(v)) for k, v in sorted(self.core.counters.items())]
        arr.status = [st]
        self.diag_pub.publish(arr)


def main(args=None):
    spin_node(MonitorNode, args)


if __name__ == "__main__":
    main()
