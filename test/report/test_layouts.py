"""Issue 36.3: the live-view layouts in config/ parse and name only topics and fields that exist.

* ``config/foxglove_layout.json`` (Foxglove / Lichtblick): JSON; every panel's message path
  ``/topic.field[i]...`` names a topic of the bag layout (:mod:`reachset_ros.bags.messages`,
  listed in docs/interfaces.md) and fields of its message type, indexed where the field is an
  array and ending at a number or bool;
* ``config/plotjuggler_layout.xml`` (PlotJuggler): XML; every curve ``/topic/field[i]`` likewise,
  and ``/joint_states/JOINT/position|velocity|effort`` (PlotJuggler names JointState series by
  joint) with the LWA-4P's joint names of ``config/lwa4p.yaml``.

The message types' fields come from their definitions: ``msg_defs/msg/*.msg`` and the standard
messages of the typestore the bags are read with (:func:`reachset_ros.bags.typestore`).
"""
import json
import re
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest
import yaml

from reachset_ros.bags import messages as m

REPO = Path(__file__).resolve().parents[2]
FOXGLOVE = REPO / "config" / "foxglove_layout.json"
PLOTJUGGLER = REPO / "config" / "plotjuggler_layout.xml"

#: topic -> message type: the bag layout's topics (docs/interfaces.md, "Topics")
TOPICS = {m.JOINT_STATES: m.JOINT_STATE_TYPE, m.PLANT_INPUT: m.PLANT_INPUT_TYPE,
          m.REFERENCE_TOPIC: m.REFERENCE_TYPE, m.ESTIMATE_TOPIC: m.ESTIMATE_TYPE,
          m.STATUS_TOPIC: m.STATUS_TYPE, m.SAFE_STOP_TOPIC: m.SAFE_STOP_TYPE,
          m.FAULT_ONSET_TOPIC: m.FAULT_ONSET_TYPE, m.BRAKE_TOPIC: m.BRAKE_TYPE}
NUMBERS = {"bool", "byte", "char", "int8", "uint8", "int16", "uint16", "int32", "uint32", "int64", "uint64",
           "float32", "float64"}
STEP = re.compile(r"^(\w+)(\[\d+\])?$")


def joints():
    """The LWA-4P's joints, in the ``joints`` parameter order of config/lwa4p.yaml."""
    doc = yaml.safe_load((REPO / "config" / "lwa4p.yaml").read_text())
    lists = [n["ros__parameters"].get("joints") for n in doc.values() if isinstance(n, dict)]
    return next(j for j in lists if j and all(j))


def _fields(msgtype):
    """``{field: (kind, type or base type, is array)}`` of a message type (typestore field defs)."""
    out = {}
    for name, (kind, desc) in m.typestore().fielddefs[msgtype][1]:
        if kind.name == "SEQUENCE" or kind.name == "ARRAY":
            (ekind, edesc) = desc[0]
            out[name] = (ekind.name, edesc if ekind.name == "NAME" else edesc[0], True)
        else:
            out[name] = (kind.name, desc if kind.name == "NAME" else desc[0], False)
    return out


def check_path(topic, steps):
    """Raise AssertionError unless ``steps`` (``field`` or ``field[i]``) walk ``topic``'s type
    to a number or bool."""
    assert topic in TOPICS, f"{topic}: not a topic of the suite"
    msgtype = TOPICS[topic]
    assert steps, f"{topic}: no field named"
    for i, step in enumerate(steps):
        mt = STEP.match(step)
        assert mt, f"{topic}: {step!r} is not a field (or field[index])"
        name, index = mt.group(1), mt.group(2)
        fields = _fields(msgtype)
        assert name in fields, f"{topic}: {msgtype} has no field {name!r}"
        kind, typ, is_array = fields[name]
        assert bool(index) == is_array, f"{topic}: {name} is {'an array' if is_array else 'not an array'}"
        if kind == "NAME":
            msgtype = typ
        else:
            assert i == len(steps) - 1, f"{topic}: {name} has no fields"
            assert typ in NUMBERS, f"{topic}: {name} is a {typ}, not plotted"
    assert kind != "NAME", f"{topic}: the path ends at a message, not a value"


def _split_topic(path, sep):
    """``(topic, rest)``: the longest topic of the suite ``path`` starts with, then ``sep``."""
    for t in sorted(TOPICS, key=len, reverse=True):
        if path.startswith(t + sep):
            return t, path[len(t) + len(sep):]
    raise AssertionError(f"{path}: names no topic of the suite")


def foxglove_paths():
    doc = json.loads(FOXGLOVE.read_text())
    out = []
    for pid, cfg in doc["configById"].items():
        out += [p["value"] for p in cfg.get("paths", [])]
        if "path" in cfg:
            out.append(cfg["path"])
    return doc, out


def plotjuggler_curves():
    root = ET.parse(PLOTJUGGLER).getroot()
    return root, [c.get("name") for c in root.iter("curve")]


def test_the_foxglove_layout_parses_and_names_only_what_exists():
    doc, paths = foxglove_paths()
    assert len(paths) > 20
    for p in paths:
        topic, rest = _split_topic(p, ".")
        check_path(topic, rest.split("."))
    for cfg in doc["configById"].values():
        if "topicPath" in cfg:
            assert cfg["topicPath"] in TOPICS
    # the layout's tree names exactly its panels
    ids = set()

    def walk(node):
        if isinstance(node, str):
            ids.add(node)
        else:
            walk(node["first"])
            walk(node["second"])

    walk(doc["layout"])
    assert ids == set(doc["configById"])
    # what the operator looks at: the set use (issue 36.3) and the margins of every joint, the
    # stop, positions against estimates
    n = len(joints())
    for field in ("set_use", "margin", "deviation", "tightest_step"):
        assert {f"/conformance/status.{field}[{i}]" for i in range(n)} <= set(paths)
    # the set use on a linear axis from 0, not clipped above (a violation, > 1, stays visible)
    [use] = [c for c in doc["configById"].values() if any(".set_use[" in p["value"] for p in c.get("paths", []))]
    assert use.get("minYValue") == 0 and "maxYValue" not in use and "1.0" in use["title"]
    assert "/safe_stop.active" in paths and "/observer/estimate.position[0]" in paths


def test_the_plotjuggler_layout_parses_and_names_only_what_exists():
    root, curves = plotjuggler_curves()
    assert root.tag == "root" and root.find("tabbed_widget") is not None
    assert len(curves) > 20
    names = set(joints())
    for c in curves:
        topic, rest = _split_topic(c, "/")
        steps = rest.split("/")
        if topic == m.JOINT_STATES:          # PlotJuggler: /joint_states/JOINT/position
            assert len(steps) == 2 and steps[0] in names, c
            check_path(topic, [steps[1] + "[0]"])
        else:
            check_path(topic, steps)
    assert {f"/joint_states/{j}/position" for j in names} <= set(curves)
    assert {f"/conformance/status/set_use[{i}]" for i in range(len(names))} <= set(curves)
    assert "/safe_stop/active" in curves


@pytest.mark.parametrize("path, why", [("/conformance/status.set_uses[0]", "no field"),
                                       ("/conformance/status.margin", "an array"),
                                       ("/safe_stop.reason", "not plotted"),
                                       ("/conformance/status.header", "ends at a message"),
                                       ("/conformance/status.margin[0].x", "has no fields"),
                                       ("/no/topic.x", "no topic")])
def test_the_checker_refuses_what_does_not_exist(path, why):
    """The checks above could fail: a field the monitor does not publish (yet), an array
    without an index, a string, a message, a field of a number, an unknown topic."""
    with pytest.raises(AssertionError, match=why):
        topic, rest = _split_topic(path, ".")
        check_path(topic, rest.split("."))


def test_the_docs_say_where_the_layouts_are():
    text = (REPO / "docs" / "nodes.md").read_text()
    assert "config/foxglove_layout.json" in text and "config/plotjuggler_layout.xml" in text
    topics = (REPO / "docs" / "interfaces.md").read_text()
    for t in TOPICS:
        assert f"`{t}`" in topics
