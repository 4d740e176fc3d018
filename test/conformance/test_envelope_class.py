"""Issue 37.3: the reference class a certificate covers is checked against the model's validated
envelope, and the parts never validated are named (conformance.envelope.unvalidated; the gain
gate systems.gains.certify_pair carries them in its certificate)."""
from dataclasses import replace

import pytest

from reachset_ros.conformance import model as mdl
from reachset_ros.conformance.envelope import Axis, ClassBounds, Envelope, JointEnvelope, unvalidated
from reachset_ros.conformance.estimators import Estimator
from reachset_ros.systems.gains import Gains, certify_pair
from reachset_ros.systems.plant import lwa4p_joint_plant

AXES = {"q": Axis(origin=-0.5, cell=0.1, cells=10), "qd": Axis(origin=-0.3, cell=0.05, cells=10),
        "qdd": Axis(origin=-1.0, cell=0.25, cells=10), "u": Axis(origin=-2.0, cell=0.4, cells=10)}
#: validated ranges: q [-0.5, 0.5], qd [-0.3, 0.2], qdd [-1, 1.5], u [-2, 2]
ENV = Envelope(joints={"a": JointEnvelope(axes=AXES)}, dt=0.004, bins=8, dilation=1, hold=0)
INSIDE = ClassBounds(qdd_max=1.0, qdd_source="qdd_max", u=(-1.5, 1.8), u_source="R*_u", qd_max=0.2, q=(-0.4, 0.4))


def test_a_class_inside_every_axis_names_nothing():
    assert unvalidated(ENV, {"a": INSIDE}) == {"a": ()}


def test_a_class_beyond_one_feature_names_that_joint_feature_value_and_range():
    """One feature of one joint beyond its axis: exactly one line, naming the joint, the
    feature, the class' value and the validated range; the other features stay silent."""
    beyond_u = unvalidated(ENV, {"a": replace(INSIDE, u=(-1.5, 24.1))})["a"]
    assert beyond_u == ("a: u_p reaches 24.1 rad/s^2 (R*_u = [-1.5, 24.1]) but the model was validated on u_p "
                        "in [-2, 2]",)
    beyond_qdd = unvalidated(ENV, {"a": replace(INSIDE, qdd_max=1.2, qdd_source="U_ff")})["a"]
    # the class is symmetric: -1.2 < -1 leaves the axis although 1.2 < 1.5
    assert beyond_qdd == ("a: |qdd_d| reaches 1.2 rad/s^2 (U_ff) but the model was validated on qdd in [-1, 1.5]",)
    beyond_q = unvalidated(ENV, {"a": replace(INSIDE, q=(-0.4, 0.9))})["a"]
    assert len(beyond_q) == 1 and beyond_q[0].startswith("a: q spans [-0.4, 0.9] rad")
    assert beyond_q[0].endswith("validated on q in [-0.5, 0.5]")
    beyond_qd = unvalidated(ENV, {"a": replace(INSIDE, qd_max=0.25)})["a"]
    assert beyond_qd == ("a: |qd| reaches 0.25 rad/s (qd_max) but the model was validated on qd in [-0.3, 0.2]",)


def test_unknown_bounds_are_not_checked_and_an_unrecorded_joint_is_named():
    assert unvalidated(ENV, {"a": ClassBounds()}) == {"a": ()}
    out = unvalidated(ENV, {"a": INSIDE, "b": INSIDE})
    assert out["a"] == () and len(out["b"]) == 1 and out["b"][0].startswith("b: not recorded by the envelope")


#: Table II axis 1 with a U_e,ff = 0 record: R*_u about +-17.7 rad/s^2 for U_ff = +-2 (test_certify.py)
TABLE_II = Gains(omega=24.40, zeta=0.96, h1=15.0, h2=30.0)


def _model(envelope):
    js = mdl.JointSets((0.0348, 3.59), (3.49e-5,), (0.0,) * 5, (0.0,), 0, 125,
                       gains={**TABLE_II.model_dict(), "u_max": 26.0, "u_ff": 2.0},
                       extra={"reference_error": {"u_e_ff": [0.0, 0.0]}})
    return mdl.ConformanceModel(lwa4p_joint_plant(), {"kind": "lwa4p_joint", "dt": 0.004}, Estimator("fd"), 125,
                                {"arm_1_joint": js}, 0.0, envelope=envelope)


def _envelope(u_half, qdd_half):
    axes = {**AXES, "u": Axis(origin=-u_half, cell=2 * u_half / 10, cells=10),
            "qdd": Axis(origin=-qdd_half, cell=2 * qdd_half / 10, cells=10)}
    return Envelope(joints={"arm_1_joint": JointEnvelope(axes=axes)}, dt=0.004, bins=8, dilation=1, hold=0)


def test_the_gain_gate_names_the_part_of_its_class_never_validated():
    """certify_pair certifies (naming, not refusing) and its certificate carries the lines: the
    certified R*_u reaches beyond the u_p the model was validated on. Before issue 37.3 the
    certificate had no such field."""
    pc = certify_pair({"arm_1_joint": TABLE_II}, _model(_envelope(3.0, 3.0)), [26.0], 2.0, 0.004)
    ru = pc.certified["arm_1_joint"].ru
    assert ru[1] > 3.0
    lines = pc.unvalidated["arm_1_joint"]
    assert len(lines) == 1 and lines[0].startswith("arm_1_joint: u_p reaches ")
    assert "(R*_u = [" in lines[0] and lines[0].endswith("but the model was validated on u_p in [-3, 3]")
    assert pc.envelope_note().startswith("envelope: NOT VALIDATED") and lines[0] in pc.envelope_note()
    # |qdd_d| <= U_ff = 2 beyond a qdd axis of +-1.5: a second line, naming U_ff
    pc2 = certify_pair({"arm_1_joint": TABLE_II}, _model(_envelope(3.0, 1.5)), [26.0], 2.0, 0.004)
    assert len(pc2.unvalidated["arm_1_joint"]) == 2
    assert pc2.unvalidated["arm_1_joint"][0].startswith("arm_1_joint: |qdd_d| reaches 2 rad/s^2 (U_ff")


def test_the_gain_gate_says_inside_or_none_recorded_and_never_guesses():
    wide = certify_pair({"arm_1_joint": TABLE_II}, _model(_envelope(30.0, 3.0)), [26.0], 2.0, 0.004)
    assert wide.unvalidated == {"arm_1_joint": ()} and wide.unvalidated_lines() == []
    assert "inside the validated envelope" in wide.envelope_note()
    bare = certify_pair({"arm_1_joint": TABLE_II}, _model(None), [26.0], 2.0, 0.004)
    assert bare.unvalidated is None and bare.envelope_note() == "envelope: none recorded"
    alone = certify_pair({"arm_1_joint": TABLE_II}, None, [26.0], 2.0, 0.004, allow_uncertified=True)
    assert alone.unvalidated is None and alone.envelope_note() == "envelope: none recorded"


def test_the_model_file_round_trip_keeps_the_check(tmp_path):
    path = tmp_path / "m.yaml"
    mdl.save(_model(_envelope(3.0, 3.0)), path)
    loaded = mdl.load(path)
    assert loaded.unvalidated({"arm_1_joint": {"u": (-20.0, 20.0)}})["arm_1_joint"][0].startswith(
        "arm_1_joint: u_p reaches 20 rad/s^2")
    assert _model(None).unvalidated({"arm_1_joint": {"u": (-20.0, 20.0)}}) is None


class _Logger:
    """Records the lines a node would log (warning or info)."""

    def __init__(self):
        self.lines = []

    def warning(self, text):
        self.lines.append(("WARN", text))

    def info(self, text):
        self.lines.append(("INFO", text))


class _Node:
    """What validate_pair and log_envelope read of the observer and controller nodes."""

    joints, dt = ["arm_1_joint"], 0.004

    def __init__(self):
        self.logger = _Logger()

    def get_logger(self):
        return self.logger


VALUES = {"observer": "hg", "controller": "static", "eso_input": "previous", "omega": [24.40], "zeta": [0.96],
          "h1": [15.0], "h2": [30.0], "l1": [57.1], "l2": [103.3], "l3": [18.1], "eps": [0.01], "u_max": [26.0],
          "u_ff_bound": 2.0, "allow_uncertified": False}


def test_the_nodes_gate_hands_the_note_on_and_logs_one_warn_line_naming_the_parts():
    """What the observer and controller nodes call at start-up and at each gain change
    (gain_params.validate_pair, then log_envelope): a WARN line naming the parts never
    validated; an INFO line saying 'envelope: none recorded' for a model without one."""
    from reachset_ros.nodes.gain_params import log_envelope, validate_pair
    node = _Node()
    cfg = validate_pair(node, VALUES, _model(_envelope(3.0, 3.0)))
    assert len(cfg["unvalidated"]) == 1 and cfg["unvalidated"][0].startswith("arm_1_joint: u_p reaches ")
    log_envelope(node, cfg, "gain change")
    assert node.logger.lines == [("WARN", f"gain change: {cfg['envelope_note']}")]
    assert "NOT VALIDATED" in cfg["envelope_note"] and cfg["unvalidated"][0] in cfg["envelope_note"]
    bare = validate_pair(node, VALUES, _model(None))
    assert bare["unvalidated"] == [] and bare["envelope_note"] == "envelope: none recorded"
    log_envelope(node, bare, "start-up")
    assert node.logger.lines[-1] == ("INFO", "start-up: envelope: none recorded")


def test_log_envelope_logs_both_severities_through_a_real_rclpy_logger():
    """rclpy refuses one call site logging at two severities (ValueError 'Logger severity cannot
    be changed between calls'): a first version of log_envelope did, and the nodes' parameter
    callback failed on the second change (found by test_synthesis_node.py over DDS)."""
    import rclpy.logging
    from reachset_ros.nodes.gain_params import log_envelope, validate_pair

    class Node(_Node):
        ros_logger = rclpy.logging.get_logger("test_envelope_class")      # one logger, as a node's get_logger()

        def get_logger(self):
            return self.ros_logger

    Node.ros_logger.set_level(rclpy.logging.LoggingSeverity.DEBUG)     # INFO logged, not filtered before the check
    assert Node.ros_logger.is_enabled_for(rclpy.logging.LoggingSeverity.INFO)
    node = Node()
    warn, info = validate_pair(node, VALUES, _model(_envelope(3.0, 3.0))), validate_pair(node, VALUES, _model(None))
    for cfg in (warn, info, warn, info):
        log_envelope(node, cfg, "gain change")
