"""Generate the parameter tables of docs/nodes.md from the nodes' declared parameters.

Usage::

    .venv/bin/python tools/node_docs.py           # rewrite the tables in docs/nodes.md
    .venv/bin/python tools/node_docs.py --check   # exit 1, naming the node, if a table is stale

One process: ``rclpy.init()`` (on localhost only, in a private domain), then every node
class is constructed with its defaults, inside a temporary working directory (the recorder
creates its bag there), and each declared parameter's descriptor is read back. A table
goes between ``<!-- params:NODE -->`` and ``<!-- /params:NODE -->`` in docs/nodes.md;
the text outside the markers is written by hand.
"""
import argparse
import importlib
import os
import random
import re
import sys
import tempfile
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
DOC = REPO / "docs" / "nodes.md"

#: node (module in reachset_ros.nodes) -> its Node class, in the order of docs/nodes.md
NODES = {"sim_node": "SimNode", "reference_node": "ReferenceNode", "observer_node": "ObserverNode",
         "controller_node": "ControllerNode", "monitor_node": "MonitorNode",
         "synthesis_node": "SynthesisNode", "recorder_node": "RecorderNode", "relay_node": "RelayNode"}

TYPES = {1: "bool", 2: "integer", 3: "double", 4: "string", 5: "byte[]", 6: "bool[]",
         7: "integer[]", 8: "double[]", 9: "string[]"}


def literal(value):
    """A parameter value as one would write it in a ``--params-file`` (YAML flow style).

    Parameters
    ----------
    value : bool, int, float, str or sequence of these
        The parameter's value.

    Returns
    -------
    str
        E.g. ``true``, ``0.004``, ``''``, ``[26.0, 100.0]``.
    """
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, str):
        return value if value else "''"
    if isinstance(value, (int, float)):
        return repr(value)
    return "[" + ", ".join(literal(v) for v in list(value)) + "]"


def cell(text):
    """Escape ``text`` for a Markdown table cell."""
    return str(text).replace("|", "\\|").replace("\n", " ")


def value_range(d):
    """The range of a ParameterDescriptor as ``[from, to]`` (with the step when not 0/1), or a dash."""
    for r in list(d.floating_point_range) + list(d.integer_range):
        step = f", step {literal(r.step)}" if r.step not in (0, 1) else ""
        return f"`[{literal(r.from_value)}, {literal(r.to_value)}]`{step}"
    return "—"


#: parameters the probe overrides so that every node starts with its defaults otherwise
#: (observer and controller refuse uncertified gains without a model): the declared default
#: is shown
PROBE_OVERRIDES = {"allow_uncertified": (True, False)}     # name -> (probe value, declared default)
#: per node, parameters the probe sets (``-p NODE:NAME:=VALUE``) so that the node starts at
#: all, shown with their declared defaults: a monitor without a model does not run (issue
#: 34.1), the probe gives it a one-joint model (:func:`probe_model`)
NODE_PROBES = {"monitor_node": {"model_file": ""}}         # node -> {name: declared default}
#: read-only parameters whose value is set at start, not declared in advance: the table says what
#: they hold instead of one run's value
STARTED_VALUES = {("sim_node", "start_stamp_ns"): "(wall time at start)"}


def probe_model(directory):
    """A one-joint conformance model written to ``directory`` for the probe; its path."""
    from reachset_ros.conformance import model as mdl
    from reachset_ros.conformance.estimators import Estimator
    from reachset_ros.systems.plant import lwa4p_joint_plant
    sets = {"arm_1_joint": mdl.JointSets((0.15, 0.0), (4e-4,), (0.0,) * 5, (0.0,), 0, 25)}
    path = Path(directory) / "probe_model.yaml"
    mdl.save(mdl.ConformanceModel(lwa4p_joint_plant(), {"kind": "lwa4p_joint", "dt": 0.004}, Estimator("fd"), 25,
                                  sets, input_source=mdl.PLANT_INPUT), path)
    return path


def table(node, skip):
    """The Markdown parameter table of ``node``.

    Parameters
    ----------
    node : rclpy.node.Node
        A constructed node, not spun.
    skip : set of str
        Parameter names every rclpy node declares (left out of the table).

    Returns
    -------
    str
        Header row, separator row and one row per parameter, in declaration order.
    """
    names = [n for n in node._descriptors if n not in skip]
    rows = ["| name | type | default | range | read-only | description |",
            "|---|---|---|---|---|---|"]
    for name, d in zip(names, node.describe_parameters(names)):
        value = node.get_parameter(name).value
        if name in PROBE_OVERRIDES:
            value = PROBE_OVERRIDES[name][1]
        value = NODE_PROBES.get(node.get_name(), {}).get(name, value)
        default = STARTED_VALUES.get((node.get_name(), name)) or literal(value)
        rows.append("| " + " | ".join([
            f"`{name}`", TYPES.get(d.type, str(d.type)), f"`{cell(default)}`", value_range(d),
            "yes" if d.read_only else "no", cell(d.description)]) + " |")
    return "\n".join(rows)


def generate():
    """Construct every node with its defaults and read its parameter descriptors.

    Returns
    -------
    dict of str to str
        ``{node name: Markdown parameter table}``, in the order of ``NODES``.
    """
    os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    os.environ.setdefault("ROS_DOMAIN_ID", str(random.SystemRandom().randint(101, 200)))
    import rclpy
    import rclpy.logging
    tables = {}
    cwd = os.getcwd()
    with tempfile.TemporaryDirectory(prefix="node_docs_") as tmp:
        model = probe_model(tmp)
        rclpy.init(args=["--ros-args"] + [a for n, (v, _) in PROBE_OVERRIDES.items()
                                           for a in ("-p", f"{n}:={str(v).lower()}")]
                   + [a for node, names in NODE_PROBES.items() for n in names
                      for a in ("-p", f"{node}:{n}:={model}")])
        try:
            os.chdir(tmp)   # relative defaults (the recorder's bag) land here, not in the repo
            try:
                probe = rclpy.create_node("node_docs_probe")
                skip = set(probe._descriptors)      # use_sim_time etc., common to all nodes
                probe.destroy_node()
                for name, cls_name in NODES.items():
                    rclpy.logging.set_logger_level(name, rclpy.logging.LoggingSeverity.WARN)
                    cls = getattr(importlib.import_module(f"reachset_ros.nodes.{name}"), cls_name)
                    node = cls()
                    try:
                        tables[name] = table(node, skip)
                    finally:
                        if hasattr(node, "close"):
                            node.close()
                        if hasattr(node, "client_node"):
                            node.client_node.destroy_node()
                        node.destroy_node()
            finally:
                os.chdir(cwd)
        finally:
            rclpy.try_shutdown()
    return tables


def render(text, tables):
    """Put each node's table between its markers.

    Parameters
    ----------
    text : str
        The Markdown page.
    tables : dict of str to str
        ``{node name: table}``.

    Returns
    -------
    new_text : str
        ``text`` with the tables in place.
    missing : list of str
        Nodes whose markers were not found.
    """
    missing = []
    for name, tab in tables.items():
        pattern = re.compile(rf"(<!-- params:{name} -->\n).*?(<!-- /params:{name} -->)", re.S)
        if not pattern.search(text):
            missing.append(name)
            continue
        text = pattern.sub(lambda m: m.group(1) + tab + "\n" + m.group(2), text)
    return text, missing


def main(argv=None):
    """Rewrite docs/nodes.md, or with ``--check`` only compare it.

    Returns
    -------
    int
        Exit status: 0, or 1 when markers are missing or (``--check``) a table differs.
    """
    ap = argparse.ArgumentParser(description="Generate the parameter tables of docs/nodes.md.")
    ap.add_argument("--check", action="store_true",
                    help="do not write; exit 1 naming the nodes whose table differs")
    check = ap.parse_args(argv).check
    text = DOC.read_text(encoding="utf-8")
    tables = generate()
    new, missing = render(text, tables)
    problems = [f"no <!-- params:{n} --> ... <!-- /params:{n} --> markers" for n in missing]
    if check:
        problems += [f"parameter table of {n} is out of date (run tools/node_docs.py)"
                     for n in tables if n not in missing and render(text, {n: tables[n]})[0] != text]
    if problems:
        for p in problems:
            print(f"{DOC}: {p}", file=sys.stderr)
        return 1
    if check:
        return 0
    if new != text:
        DOC.write_text(new, encoding="utf-8")
        print(f"updated {DOC}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
