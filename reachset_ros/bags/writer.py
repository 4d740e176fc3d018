"""Writing rosbag2 bags (MCAP by default, sqlite3) atomically, with rosbags.

Every bag written here carries its message definitions (from the typestore of
:mod:`.messages`), so any rosbags or mcap reader decodes it without this package.
"""
from __future__ import annotations

import os
import shutil
from pathlib import Path


from ..errors import ReachsetError
from .messages import JOINT_STATE_TYPE, JOINT_STATES, PLANT_INPUT, PLANT_INPUT_TYPE, typestore


class BagWriter:
    """Write a rosbag2 directory atomically: into ``<path>.partial/<name>``, renamed on success.

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
        # written as <path>.partial/<name> and renamed on success, so that the storage
        # file is named after the bag (<name>.mcap), not after the temporary directory
        self._tmp_parent = self.path.with_name(self.path.name + ".partial")
        if self._tmp_parent.exists():
            shutil.rmtree(self._tmp_parent)
        self.tmp = self._tmp_parent / self.path.name
        from rosbags.rosbag2 import Writer  # lazy: rosbags.rosbag2's start-up (issue 38.1)
        from rosbags.rosbag2.enums import StoragePlugin
        plugin = {"mcap": StoragePlugin.MCAP, "sqlite3": StoragePlugin.SQLITE3}[storage]
        self._writer = Writer(self.tmp, version=9, storage_plugin=plugin)
        self._conns = {}

    def __enter__(self):
        try:
            self._writer.open()      # creates the temporary directories
        except BaseException:
            shutil.rmtree(self._tmp_parent, ignore_errors=True)
            raise
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
            if exc_type is None:
                os.replace(self.tmp, self.path)
        finally:
            shutil.rmtree(self._tmp_parent, ignore_errors=True)
        return False
