"""ROS 2 parameter files (``--params-file``) read and checked before anything is started.

The standard layout (the one ``ros2 run ... --ros-args --params-file`` and ``ros2 param
dump`` use)::

    /**:                        # every node
      ros__parameters:
        use_sim_time: false
    monitor_node:               # or /monitor_node
      ros__parameters:
        max_missing_ticks: 125
        window_dir: /var/log/reachset/windows

:func:`load` returns the sections by node name (``"/**"`` for the wildcard), each as a
flat mapping of parameter names (nested mappings joined with ``.``, as rcl does) to values,
after checking every value the way rcl's parser would take it: a bool, an integer, a
float, a string, or a non-empty list of one of these (integers and floats not mixed).
:func:`for_node` merges the wildcard and the node's section. Namespaced node names
(``/ns/node``, or ``ns: {node: {ros__parameters: ...}}``) and wildcards other than ``/**``
are not supported: ``reachset up`` starts every node in the root namespace.
"""
from __future__ import annotations

from pathlib import Path

import yaml

from .errors import ReachsetError

WILDCARD = "/**"
_SCALARS = (bool, int, float, str)


def _type_name(v):
    return "bool" if isinstance(v, bool) else type(v).__name__


def _check_value(where, v):
    """``v`` if rcl would take it as a parameter value, else ReachsetError naming ``where``."""
    if isinstance(v, _SCALARS):
        return v
    if isinstance(v, list):
        if not v:
            raise ReachsetError(f"{where}: an empty list has no parameter type (give at least one value)")
        if not all(isinstance(x, _SCALARS) for x in v):
            raise ReachsetError(f"{where}: lists may hold only bools, integers, floats or strings")
        kinds = {_type_name(x) for x in v}
        if len(kinds) > 1:
            raise ReachsetError(f"{where}: mixed types in a list ({', '.join(sorted(kinds))}); "
                                "write 1.0, not 1, in a list of floats")
        return v
    if v is None:
        raise ReachsetError(f"{where}: no value")
    raise ReachsetError(f"{where}: unsupported value of type {type(v).__name__}")


def _flatten(where, params, prefix=""):
    out = {}
    for k, v in params.items():
        if not isinstance(k, str) or not k:
            raise ReachsetError(f"{where}: parameter name {k!r} is not a string")
        name = prefix + k
        if isinstance(v, dict):
            out.update(_flatten(where, v, name + "."))
        else:
            out[name] = _check_value(f"{where}.{name}", v)
    return out


def load(path) -> dict[str, dict]:
    """Read a ROS 2 parameter file.

    Parameters
    ----------
    path : str or Path

    Returns
    -------
    dict
        ``{node name or "/**": {parameter: value}}`` (a leading ``/`` of a node name removed).

    Raises
    ------
    ReachsetError
        One line naming the file (and the node and parameter): not found, not YAML, not
        the layout above, or a value rcl cannot take.
    """
    p = Path(path)
    if not p.is_file():
        raise ReachsetError(f"{p}: parameter file not found" if not p.exists() else f"{p}: not a file")
    try:
        doc = yaml.safe_load(p.read_text())
    except yaml.YAMLError as e:
        mark = getattr(e, "problem_mark", None)
        at = f" at line {mark.line + 1}" if mark is not None else ""
        raise ReachsetError(f"{p}: not valid YAML{at} ({getattr(e, 'problem', None) or type(e).__name__})") from None
    except (OSError, UnicodeDecodeError) as e:
        raise ReachsetError(f"{p}: cannot read ({type(e).__name__})") from None
    layout = "expected `NODE_NAME: {ros__parameters: {NAME: VALUE}}` sections"
    if not isinstance(doc, dict) or not doc:
        raise ReachsetError(f"{p}: not a ROS 2 parameter file ({layout})")
    sections = {}
    for key, body in doc.items():
        if not isinstance(key, str):
            raise ReachsetError(f"{p}: section {key!r}: node names are strings ({layout})")
        name = key if key == WILDCARD else key.removeprefix("/")
        if name != WILDCARD and (not name or "/" in name or "*" in name or "?" in name):
            raise ReachsetError(f"{p}: section {key!r}: only plain node names and /** are supported "
                                "(no namespaces or other wildcards)")
        if not isinstance(body, dict) or "ros__parameters" not in body:
            raise ReachsetError(f"{p}: section {key!r} has no ros__parameters ({layout}; namespaced "
                                "sections are not supported)")
        extra = [k for k in body if k != "ros__parameters"]
        if extra:
            raise ReachsetError(f"{p}: section {key!r}: unexpected key {extra[0]!r} beside ros__parameters")
        params = body["ros__parameters"]
        if params is None:
            params = {}
        if not isinstance(params, dict):
            raise ReachsetError(f"{p}: section {key!r}: ros__parameters must be a mapping of names to values")
        if name in sections:
            raise ReachsetError(f"{p}: node {name} has two sections")
        sections[name] = _flatten(f"{p}: {name}", params)
    return sections


def for_node(sections: dict, node: str) -> dict:
    """The parameters of ``node``: the ``/**`` section, then the node's own over it."""
    return {**sections.get(WILDCARD, {}), **sections.get(node, {})}
