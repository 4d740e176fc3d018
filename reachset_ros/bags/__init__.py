"""rosbag2 bags (MCAP by default, sqlite3 readable): the project's bag layout, writing, reading.

The layout (``docs/interfaces.md``): ``/joint_states`` (``sensor_msgs/msg/JointState``,
``position`` is y_p) and ``/plant_input`` (``reachset_msgs/msg/PlantInput``, u_p) are what
identification and checking need; a closed loop also records ``/reference`` and
``/observer/estimate`` (the paper's Appendix-B reference error), the monitor
``/conformance/status`` and ``/safe_stop``, the simulator ``/sim/fault_onset``. Samples are
paired by header stamp and joint name, never by arrival order or index. No rclpy: every bag
written here carries its message definitions, so any rosbags or mcap reader decodes it
without this package.

Submodules
----------
messages
    Topic names and types of the layout, the ``reachset_msgs`` typestore (from the ``.msg``
    texts), message builders (:func:`joint_state`, :func:`plant_input`, ...).
writer
    :class:`BagWriter`: atomic writing with rosbags.
series
    The reader's entry point for identification and checking: :func:`read_joint_series`
    (per-joint paired y, u_p series and their segments, :func:`segments_of`), the sampling
    period a bag must have (:func:`check_period`), several bags as one
    (:func:`concat_series`, :func:`merge_reports`).
topics
    Streamed reading of topics into per-joint columns (:func:`read_topics`,
    :func:`read_fields`) and what a bag path may be (:func:`check_bag_path`, :func:`check_bag`).
decoded
    Messages decoded one by one: :func:`read_messages` (small bags), :func:`read_topic_rows`.
cdr
    Fast CDR decoding of ``JointState``/``PlantInput`` payloads with numpy (equal to
    rosbags' ``deserialize_cdr`` message by message, ``test/bags/test_bags.py``).
mcap
    MCAP storage files read chunk by chunk, and the checks of a bag's storage files.
references
    References and observer estimates of a bag (:func:`read_references`).

Timings: ``docs/performance.md``. Every public name is importable from this package
(``from reachset_ros.bags import read_joint_series``); code outside the package imports from it
rather than from the submodules.

May import: :mod:`reachset_ros._lazy` (the package's lazy attributes), :mod:`reachset_ros.errors` only.
"""
from .._lazy import attach

# each public name is imported from its submodule on first use (reachset_ros._lazy, issue 38.1)
__getattr__, __dir__, _EXPORTED = attach(__name__, {
    ".cdr": [
        "FAST_TYPES", "CdrError", "cdr_layout", "decode_payloads", "decode_rows",
    ],
    ".messages": [
        "ESTIMATE_TOPIC", "ESTIMATE_TYPE", "FAULT_ONSET_TOPIC", "FAULT_ONSET_TYPE", "JOINT_STATE_TYPE",
        "JOINT_STATES", "PLANT_INPUT", "PLANT_INPUT_TYPE", "REACHSET_MSGS", "REFERENCE_TOPIC",
        "REFERENCE_TYPE", "SAFE_STOP_TOPIC", "SAFE_STOP_TYPE", "STATUS_TOPIC", "STATUS_TYPE", "header",
        "header_stamp_ns", "joint_state", "msg_definition", "plant_input", "stamp_msg", "typestore",
    ],
    ".decoded": [
        "read_messages", "read_topic_rows",
    ],
    ".references": [
        "Reference", "read_estimates", "read_references",
    ],
    ".series": [
        "PERIOD_TOLERANCE", "JointSeries", "ReadReport", "check_period", "concat_series", "measured_period",
        "merge_reports", "read_joint_series", "segments_of",
    ],
    ".mcap": [
        "TRUNCATED_MCAP",
    ],
    ".topics": [
        "VALUE_FIELDS", "check_bag", "check_bag_path", "read_fields", "read_topics",
    ],
    ".writer": [
        "BagWriter",
    ],
})

__all__ = [
    # layout and messages
    "JOINT_STATES", "PLANT_INPUT", "JOINT_STATE_TYPE", "PLANT_INPUT_TYPE",
    "REFERENCE_TOPIC", "ESTIMATE_TOPIC", "REFERENCE_TYPE", "ESTIMATE_TYPE",
    "STATUS_TOPIC", "SAFE_STOP_TOPIC", "FAULT_ONSET_TOPIC", "STATUS_TYPE", "SAFE_STOP_TYPE",
    "FAULT_ONSET_TYPE", "REACHSET_MSGS",
    "msg_definition", "typestore", "stamp_msg", "header_stamp_ns", "header", "joint_state",
    "plant_input",
    # writing
    "BagWriter",
    # reading
    "JointSeries", "ReadReport", "read_joint_series", "read_topics", "read_fields", "read_topic_rows",
    "read_messages", "segments_of", "measured_period", "check_period", "PERIOD_TOLERANCE",
    "merge_reports", "concat_series", "check_bag_path", "check_bag", "TRUNCATED_MCAP", "VALUE_FIELDS",
    "Reference", "read_references", "read_estimates",
    # fast decoding
    "FAST_TYPES", "CdrError", "cdr_layout", "decode_rows", "decode_payloads",
]
