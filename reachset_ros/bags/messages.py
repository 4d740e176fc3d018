"""The bag layout's messages: topic names and types, the ``reachset_msgs`` typestore, builders.

Every topic a ``reachset_ros`` bag can hold (``docs/interfaces.md``, "Topics" and
"Bags") is named here once, with its message type; code outside ``nodes/`` that reads a
bag names a topic by these constants. The custom ``reachset_msgs`` types are registered in
a rosbags typestore from their ``.msg`` texts (installed by ``msg_defs/`` under
``share/reachset_msgs/msg``, or the repository's ``msg_defs/msg`` in a source checkout),
so no rclpy is needed to write or decode them. The builders make rosbags message objects
(``joint_state``, ``plant_input``) with integer-nanosecond stamps (``stamp_msg``), and
``header_stamp_ns`` turns a message's header stamp back into nanoseconds.
"""
from __future__ import annotations

import os
from functools import lru_cache
from pathlib import Path

import numpy as np
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

from ..errors import ReachsetError

#: Topics of the bag layout (docs/interfaces.md).
JOINT_STATES = "/joint_states"
PLANT_INPUT = "/plant_input"
JOINT_STATE_TYPE = "sensor_msgs/msg/JointState"
PLANT_INPUT_TYPE = "reachset_msgs/msg/PlantInput"
#: Recorded by the closed loop (optional; the paper's Appendix-B reference error reads them).
REFERENCE_TOPIC = "/reference"
ESTIMATE_TOPIC = "/observer/estimate"
REFERENCE_TYPE = "reachset_msgs/msg/JointReference"
ESTIMATE_TYPE = "reachset_msgs/msg/JointEstimate"
#: Recorded from the monitor and the simulator (``reachset demo``'s monitored run).
STATUS_TOPIC = "/conformance/status"
SAFE_STOP_TOPIC = "/safe_stop"
FAULT_ONSET_TOPIC = "/sim/fault_onset"
#: ``diagnostic_msgs/msg/DiagnosticArray`` of the nodes (the controller's reports the transient windows).
DIAGNOSTICS_TOPIC = "/diagnostics"
STATUS_TYPE = "reachset_msgs/msg/ConformanceStatus"
SAFE_STOP_TYPE = "reachset_msgs/msg/SafeStop"
FAULT_ONSET_TYPE = "std_msgs/msg/Header"
#: The controller's holding-brake command (category-1 safe stop), with every effort command.
BRAKE_TOPIC = "/brake_command"
BRAKE_TYPE = "reachset_msgs/msg/BrakeCommand"
REACHSET_MSGS = ("PlantInput", "JointReference", "JointEstimate", "ConformanceStatus",
                 "SafeStop", "JointSynthesis", "SynthesisResult", "BrakeCommand")


def _msg_dirs():
    for prefix in os.environ.get("AMENT_PREFIX_PATH", "").split(os.pathsep):
        if prefix:
            yield Path(prefix) / "share" / "reachset_msgs" / "msg"
    yield Path(__file__).resolve().parents[2] / "msg_defs" / "msg"


def msg_definition(name: str) -> str:
    """Text of ``reachset_msgs/msg/<name>.msg``."""
    for d in _msg_dirs():
        p = d / f"{name}.msg"
        if p.is_file():
            return p.read_text()
    raise ReachsetError(f"message definition reachset_msgs/msg/{name}.msg not found "
                        "(is msg_defs/ installed?)")


@lru_cache(maxsize=1)
def typestore():
    """A Jazzy typestore with all ``reachset_msgs`` messages registered."""
    ts = get_typestore(Stores.ROS2_JAZZY)
    types = {}
    for name in REACHSET_MSGS:
        types.update(get_types_from_msg(msg_definition(name), f"reachset_msgs/msg/{name}"))
    ts.register(types)
    return ts


def stamp_msg(stamp_ns: int):
    """``builtin_interfaces/msg/Time`` of an integer nanosecond stamp."""
    Time = typestore().types["builtin_interfaces/msg/Time"]
    return Time(sec=int(stamp_ns // 1_000_000_000), nanosec=int(stamp_ns % 1_000_000_000))


def header_stamp_ns(msg) -> int:
    """Integer nanoseconds of ``msg.header.stamp`` (the inverse of :func:`stamp_msg`)."""
    s = msg.header.stamp
    return int(s.sec) * 1_000_000_000 + int(s.nanosec)


def header(stamp_ns: int, frame_id: str = ""):
    Header = typestore().types["std_msgs/msg/Header"]
    return Header(stamp=stamp_msg(stamp_ns), frame_id=frame_id)


def joint_state(stamp_ns, names, position, velocity=(), effort=()):
    """A ``sensor_msgs/msg/JointState`` (rosbags object)."""
    JS = typestore().types[JOINT_STATE_TYPE]
    return JS(header=header(stamp_ns), name=list(names),
              position=np.asarray(position, dtype=np.float64),
              velocity=np.asarray(velocity, dtype=np.float64),
              effort=np.asarray(effort, dtype=np.float64))


def plant_input(stamp_ns, names, acceleration):
    """A ``reachset_msgs/msg/PlantInput`` (rosbags object)."""
    PI = typestore().types[PLANT_INPUT_TYPE]
    return PI(header=header(stamp_ns), name=list(names),
              acceleration=np.asarray(acceleration, dtype=np.float64))
