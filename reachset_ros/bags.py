"""rosbag2 bags (MCAP by default, sqlite3 readable): writing and reading with rosbags.

No rclpy: the custom ``reachset_msgs`` types are registered in a rosbags typestore from
their ``.msg`` texts (installed by ``msg_defs/`` under ``share/reachset_msgs/msg``, or the
repository's ``msg_defs/msg`` in a source checkout), and every bag written here carries
its message definitions, so any rosbags or mcap reader decodes it without this package.
"""
from __future__ import annotations

import os
import shutil
from functools import lru_cache
from pathlib import Path

import numpy as np
from rosbags.rosbag2 import Writer
from rosbags.rosbag2.enums import StoragePlugin
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

from .errors import ReachsetError

#: Topics of the bag layout (../shared/INTERFACES.md).
JOINT_STATES = "/joint_states"
PLANT_INPUT = "/plant_input"
JOINT_STATE_TYPE = "sensor_msgs/msg/JointState"
PLANT_INPUT_TYPE = "reachset_msgs/msg/PlantInput"
REACHSET_MSGS = ("PlantInput", "JointReference", "JointEstimate", "ConformanceStatus",
                 "SafeStop", "JointSynthesis", "SynthesisResult")


def _msg_dirs():
    for prefix in os.environ.get("AMENT_PREFIX_PATH", "").split(os.pathsep):
        if prefix:
            yield Path(prefix) / "share" / "reachset_msgs" / "msg"
    yield Path(__file__).resolve().parent.parent / "msg_defs" / "msg"


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


class BagWriter:
    """Write a rosbag2 directory atomically: into ``<path>.partial``, renamed on success.

    Syntax::

        with BagWriter("bags/run1") as bag:
            bag.write("/joint_states", joint_state(t, names, q), t)

    Parameters
    ----------
    path : str or Path
        Bag directory to create; it must not exist.
    storage : {"mcap", "sqlite3"}
        Storage plugin (default MCAP).

    On an exception inside the ``with`` block nothing is left at ``path``.
    """

    TYPES = {JOINT_STATES: JOINT_STATE_TYPE, PLANT_INPUT: PLANT_INPUT_TYPE}

    def __init__(self, path, storage: str = "mcap"):
        self.path = Path(path)
        if self.path.exists():
            raise ReachsetError(f"{self.path}: output bag already exists")
        self.tmp = self.path.with_name(self.path.name + ".partial")
        if self.tmp.exists():
            shutil.rmtree(self.tmp)
        plugin = {"mcap": StoragePlugin.MCAP, "sqlite3": StoragePlugin.SQLITE3}[storage]
        self._writer = Writer(self.tmp, version=9, storage_plugin=plugin)
        self._conns = {}

    def __enter__(self):
        self._writer.open()
        return self

    def connection(self, topic: str, msgtype: str | None = None):
        if topic not in self._conns:
            msgtype = msgtype or self.TYPES[topic]
            self._conns[topic] = self._writer.add_connection(topic, msgtype, typestore=typestore())
        return self._conns[topic]

    def write(self, topic: str, msg, timestamp_ns: int, msgtype: str | None = None):
        """Serialize ``msg`` (rosbags object) and write it with receive time ``timestamp_ns``."""
        conn = self.connection(topic, msgtype)
        self._writer.write(conn, int(timestamp_ns), typestore().serialize_cdr(msg, conn.msgtype))

    def write_raw(self, topic: str, data: bytes, timestamp_ns: int, msgtype: str):
        """Write already CDR-serialized bytes (e.g. from rclpy's ``serialize_message``)."""
        self._writer.write(self.connection(topic, msgtype), int(timestamp_ns), data)

    def __exit__(self, exc_type, exc, tb):
        try:
            self._writer.close()
        finally:
            if exc_type is None:
                os.replace(self.tmp, self.path)
            else:
                shutil.rmtree(self.tmp, ignore_errors=True)
        return False
