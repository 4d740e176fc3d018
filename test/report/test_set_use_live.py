"""Issue 36.3: the live set use means something.

* ``reachset replay --json`` gives per joint the largest set use, and the monitor's tick code
  (``replay``'s :func:`~reachset_ros.commands.replay.replay_joints` and the monitor node's
  :class:`~reachset_ros.conformance.monitor_core.MonitorCore`, fed the bag's messages) gives per
  tick the set use of the batch side (:func:`reachset_ros.conformance.set_use.set_use`, ``reachset
  report``'s) to the bit, on the report tests' recordings (a clean bag and one with a fault);
* the plot of the monitor's set use from ``/conformance/status`` (the demo's figure) is linear
  with the boundary 1.0 drawn and a violation above it, not a log axis clipping negative margins;
  a bag recorded before the field existed is read with its own definition and its set use is
  ``deviation / (deviation + margin)``.

The same set use over DDS from the real monitor node: test/nodes/test_nodes.py
(``test_monitor_verdicts_on_a_recorded_closed_loop_equal_reachset_check``).
"""
import json
import subprocess

import numpy as np
import pytest
from rosbags.rosbag2 import Writer
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

from reachset_ros import bags
from reachset_ros import plots
from reachset_ros.commands.replay import replay_joints
from reachset_ros.conformance import kernels
from reachset_ros.conformance import model as mdl
from reachset_ros.conformance.monitor_core import MonitorCore
from reachset_ros.conformance.set_use import set_use
from reachset_ros.conformance.watches import TickEvent

from cli_helpers import run_cli
from report_case import JOINTS


def batch_use(model, series):
    thm = model.theorem1()
    return {n: set_use(model.plant, thm, model.estimator, model.checked_xi(n), s.y, s.u, s.segments,
                       model.horizon) for n, s in series.items()}


@pytest.mark.parametrize("which", ["train", "faulty"])
def test_replay_gives_the_batch_set_use_to_the_bit(case, which):
    model = mdl.load(case["model"])
    series, _ = bags.read_joint_series([case[which]], JOINTS, model.plant.dt)
    batch = batch_use(model, series)
    p = run_cli("replay", case[which], "--model", case["model"], "--json")
    assert p.returncode == (0 if which == "train" else 1), p.stderr
    res = json.loads(p.stdout)
    for n in JOINTS:
        finite = batch[n].use[np.isfinite(batch[n].use)]
        assert res["joints"][n]["largest_set_use"] == float(finite.max())       # JSON floats round-trip
        assert (res["joints"][n]["largest_set_use"] > 1.0) == (res["joints"][n]["violations"] > 0)
    if which == "faulty":
        assert res["joints"]["arm_2_joint"]["largest_set_use"] > 1.0
    # per tick: replay's monitor and the batch side
    uses = {}
    replay_joints(model, series, uses=uses)
    for n in JOINTS:
        assert uses[n].tobytes() == batch[n].use.tobytes(), n
        assert np.isnan(uses[n][:model.estimator.history]).all() and np.isfinite(uses[n][-100:]).all()


def test_the_monitor_nodes_core_gives_the_batch_set_use_of_the_bags_ticks(case):
    """MonitorCore (the node's code path: pairing by stamp and name, then the compiled tick) fed
    the faulty bag's /joint_states and /plant_input messages as they were recorded."""
    model = mdl.load(case["model"])
    series, _ = bags.read_joint_series([case["faulty"]], JOINTS, model.plant.dt)
    batch = batch_use(model, series)
    core = MonitorCore(model, JOINTS)
    assert core.monitor.kernel == (kernels.LIB is not None)   # the node's path: the compiled tick if built
    got = {}
    for topic, _t, m in bags.read_messages([case["faulty"]], [bags.JOINT_STATES, bags.PLANT_INPUT]):
        vals = m.position if topic == bags.JOINT_STATES else m.acceleration
        for ev in core.add("y" if topic == bags.JOINT_STATES else "u", bags.header_stamp_ns(m), list(m.name),
                           list(vals)):
            if isinstance(ev, TickEvent):
                got[ev.stamp] = ev.result["use"]
    for j, n in enumerate(JOINTS):
        st = series[n].stamps
        online = np.array([got[int(s)][j] for s in st])
        assert online.tobytes() == batch[n].use.tobytes(), n
    assert (batch["arm_2_joint"].use > 1).any()


def _status(ts, stamp, names, margin, deviation, use=None):
    C = ts.types[bags.STATUS_TYPE]
    kw = dict(header=bags.header(stamp), conformant=True, safe_stop_active=False, tick=1, horizon=3,
              active_test_cases=4, name=list(names), margin=np.array(margin, float),
              deviation=np.array(deviation, float), tightest_step=np.zeros(len(names), np.int32),
              check_duration=1e-5, model_id="x")
    if use is not None:
        kw["set_use"] = np.array(use, float)
    return C(**kw)


T0 = 1_700_000_000_000_000_000


def test_the_set_use_plot_is_linear_with_the_boundary_and_the_violation_visible(tmp_path):
    """/conformance/status with a violation (use 1.6, margin < 0) and ticks where nothing was
    checked (NaN): the figure's axis is linear from 0, its lines are the set use unclipped, 1.0 is
    drawn, the violating ticks are marked; the PNG is written."""
    ts = bags.typestore()
    names = ["arm_1_joint", "arm_2_joint"]
    use = np.array([[np.nan, np.nan], [0.2, 0.3], [0.5, 0.9], [0.7, 1.6], [0.4, 1.2]])
    bag = tmp_path / "status"
    with bags.BagWriter(bag) as w:
        for i, u in enumerate(use):
            margin = [1e300 if np.isnan(x) else 0.01 * (1 - x) for x in u]
            w.write(bags.STATUS_TOPIC, _status(ts, T0 + i * 4_000_000, names, margin, [0.0, 0.0], u),
                    T0 + i * 4_000_000, bags.STATUS_TYPE)
    msgs = [m for _t, _l, m in bags.read_messages([bag], [bags.STATUS_TOPIC])]
    got_names, stamps, got = plots.status_set_use(msgs)
    assert got_names == names and got.tobytes() == use.tobytes()
    assert np.array_equal(stamps, T0 + 4_000_000 * np.arange(5))
    fig, ax = plots.set_use_figure(names, (stamps - T0) * 1e-9, got, {"safe stop": 0.012})
    try:
        assert ax.get_yscale() == "linear" and ax.get_ylim()[0] == 0.0 and ax.get_ylim()[1] > 1.6
        lines = {ln.get_label(): ln for ln in ax.get_lines()}
        for i, n in enumerate(names):
            assert np.array_equal(lines[n].get_ydata(), use[:, i], equal_nan=True)
        assert any(np.all(np.asarray(ln.get_ydata()) == 1.0) for ln in ax.get_lines())   # the boundary
        marked = [ln for ln in ax.get_lines() if ln.get_marker() == "x"]
        assert len(marked) == 1 and np.array_equal(marked[0].get_ydata(), [1.6, 1.2])
    finally:
        import matplotlib.pyplot as plt
        plt.close(fig)
    out = plots.plot_status_set_use(tmp_path / "use.png", msgs, {"safe stop": T0 + 12_000_000})
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_a_bag_recorded_before_the_field_existed_is_read_and_its_set_use_derived(tmp_path):
    """The old ConformanceStatus definition (no set_use) in the bag: read_messages decodes it with
    the bag's own definition (with ours the payload is too short), and the set use is
    deviation / (deviation + margin) of the tightest check, NaN where nothing was checked."""
    text = bags.msg_definition("ConformanceStatus")
    old = text[:text.index("float64[] set_use")]
    assert "set_use" in text and "set_use" not in old
    ts = get_typestore(Stores.ROS2_JAZZY)
    ts.register(get_types_from_msg(old, bags.STATUS_TYPE))
    bag = tmp_path / "old"
    with Writer(bag, version=8) as w:
        conn = w.add_connection(bags.STATUS_TOPIC, bags.STATUS_TYPE, typestore=ts)
        for i, (margin, dev) in enumerate([([1e300, 1e300], [0.0, 0.0]), ([0.03, -0.01], [0.01, 0.05])]):
            msg = _status(ts, T0 + i * 4_000_000, ["a", "b"], margin, dev)
            w.write(conn, T0 + i * 4_000_000, ts.serialize_cdr(msg, bags.STATUS_TYPE))
    with pytest.raises(Exception):
        bags.typestore().deserialize_cdr(ts.serialize_cdr(msg, bags.STATUS_TYPE), bags.STATUS_TYPE)
    msgs = [m for _t, _l, m in bags.read_messages([bag], [bags.STATUS_TOPIC])]
    assert len(msgs) == 2 and not hasattr(msgs[0], "set_use")
    _names, _stamps, use = plots.status_set_use(msgs)
    assert np.isnan(use[0]).all()
    assert use[1].tolist() == [0.01 / (0.01 + 0.03), 0.05 / (0.05 - 0.01)]
    assert plots.plot_status_set_use(tmp_path / "old.png", msgs).is_file()
