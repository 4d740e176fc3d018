"""The package's architecture rules, read from the source with ``ast`` (pure, fast, no import).

Every module under ``reachset_ros/`` is parsed, function-local imports included, and checked:

* (a) layers: a *unit* (a subpackage, or a top-level module such as ``errors`` or ``processes``)
  imports from reachset_ros only the units :data:`ALLOWED` lists for it; the table mirrors the
  ``May import:`` line of each subpackage's docstring (checked too, so the two cannot drift);
* (b) only ``nodes`` and ``workflows`` import rclpy or ROS interface packages;
* (c) no module over :data:`MAX_MODULE_LINES` lines, no function over
  :data:`MAX_FUNCTION_LINES` lines, no call with more than :data:`MAX_POSITIONAL` positional
  arguments (a ``*args`` counts as one);
* (d) no module named ``*driver*`` under ``nodes/`` (workflows are not nodes).

Bottom to top: errors, atomic, domain, params_file (leaves) -> sets -> systems -> robot,
conformance -> bags -> synthesis -> fleet -> sim -> processes (the process supervisor) -> nodes
-> workflows -> commands -> cli; ``plots`` (figures) sits above synthesis, below workflows,
``report`` (the HTML report) above plots.
The ``KNOWN_*`` sets (empty since issue 33 landed) are for a violation accepted while it is
being fixed; each entry must still be a violation (a fixed one fails
:func:`test_known_violations_are_still_violations` until it is removed), so they only shrink.
"""
import ast
import re
from pathlib import Path

import pytest

import reachset_ros

PKG = Path(reachset_ros.__file__).resolve().parent
ROOT = PKG.parent

MAX_MODULE_LINES = 700
MAX_FUNCTION_LINES = 100
MAX_POSITIONAL = 8

_LEAVES = {"errors", "atomic", "defaults", "guarantees"}
#: the pure core below the process and ROS layers
_CORE = _LEAVES | {"_lazy", "sets", "systems", "robot", "conformance", "bags", "synthesis", "fleet", "sim"}
_PROCESS = {"domain", "params_file", "processes", "stacks"}

#: unit -> the reachset_ros units it may import (its own unit always). For the pure core and the
#: leaves exactly what they import today; the layers above the core (nodes, workflows, commands)
#: anything below them.
ALLOWED = {
    "__init__": set(),
    "errors": set(),
    # lazy package attributes (SPEC 1's attach, issue 38.1): a leaf the packages' __init__ use
    "_lazy": set(),
    # the registry of defaults (python-control's config.py pattern): a leaf every layer may fill
    "defaults": {"errors"},
    # the guarantee's rows and the refusal naming one: a leaf every layer may raise
    "guarantees": {"errors"},
    "atomic": {"errors"},
    "domain": {"errors"},
    "params_file": {"errors"},
    "sets": {"errors", "_lazy"},
    "systems": {"errors", "defaults", "guarantees", "sets", "_lazy"},
    # bags: robot.lwa4p writes the imported LWA-4P recordings as bags (bags imports only errors)
    "robot": {"errors", "atomic", "bags", "_lazy"},
    "conformance": {"errors", "atomic", "defaults", "guarantees", "sets", "systems", "_lazy"},
    "bags": {"errors", "_lazy"},
    "synthesis": {"errors", "defaults", "guarantees", "sets", "systems", "conformance", "bags", "_lazy"},
    "fleet": {"errors", "robot", "conformance", "bags", "synthesis"},
    "sim": {"errors", "defaults", "systems", "robot", "conformance", "bags"},
    "plots": {"errors", "conformance", "bags", "synthesis"},
    # the HTML report (issue 36.4): beside plots, whose figures it inlines
    "report": {"errors", "atomic", "defaults", "guarantees", "sets", "systems", "conformance", "bags", "synthesis",
               "plots"},
    "processes": set(),
    # every thread's stack on SIGUSR1 (a process that seems hung): the command line, the nodes
    "stacks": set(),
    "nodes": _CORE | _PROCESS,
    "workflows": _CORE | _PROCESS | {"nodes", "plots", "report"},
    "commands": _CORE | _PROCESS | {"nodes", "plots", "report", "workflows"},
    "cli": {"errors", "commands", "stacks"},
}
#: units that may import rclpy and ROS interface packages
ROS_UNITS = {"nodes", "workflows"}
#: top-level names of ROS (needs a sourced ROS 2): rclpy and interface packages
_ROS = re.compile(r"^(rclpy|rcl_interfaces|rosidl_\w+|\w+_msgs|\w+_srvs|\w+_interfaces)$")

# --------------------------------------------------------------------- known, being fixed elsewhere
#: (module, imported unit): synthesis <-> fleet (H1), conformance.calibration -> bags (H1)
KNOWN_IMPORT_VIOLATIONS = set()
#: nodes/*driver* modules moving to workflows (H2)
KNOWN_DRIVERS = set()
KNOWN_LONG_MODULES = set()
#: (module, function)
KNOWN_LONG_FUNCTIONS = set()
#: (module, called expression)
KNOWN_POSITIONAL_CALLS = set()


# --------------------------------------------------------------------- reading the source
class Module:
    """One parsed module: its path (relative to the repository), unit, package and tree."""

    def __init__(self, path: Path):
        self.path = path
        self.rel = path.relative_to(ROOT).as_posix()
        parts = path.relative_to(PKG).with_suffix("").parts
        self.is_init = parts[-1] == "__init__"
        self.unit = parts[0]                # a subpackage, a top-level module, or "__init__"
        # the package a relative import starts from (a package's __init__ is inside it)
        self.package = ".".join(("reachset_ros",) + parts[:-1])
        self.text = path.read_text(encoding="utf-8")
        self.tree = ast.parse(self.text, filename=str(path))

    def imports(self):
        """``(lineno, absolute dotted target)`` of every import, function-local ones included."""
        for node in ast.walk(self.tree):
            if isinstance(node, ast.Import):
                for a in node.names:
                    yield node.lineno, a.name
            elif isinstance(node, ast.ImportFrom):
                if node.level:
                    base = self.package.split(".")
                    base = base[:len(base) - (node.level - 1)]
                    mod = ".".join(base + ([node.module] if node.module else []))
                else:
                    mod = node.module
                if node.module is None or mod == "reachset_ros":
                    # ``from .. import bags``: each name may be a subpackage
                    for a in node.names:
                        yield node.lineno, f"{mod}.{a.name}"
                else:
                    yield node.lineno, mod


def _modules():
    return [Module(p) for p in sorted(PKG.rglob("*.py"))]


MODULES = _modules()


def _unit_of(target):
    """The reachset_ros unit of an absolute dotted module name, or None outside the package."""
    parts = target.split(".")
    if parts[0] != "reachset_ros":
        return None
    return parts[1] if len(parts) > 1 else "__init__"


def import_violations():
    """``{(module, unit): [line, ...]}`` of imports across units that :data:`ALLOWED` forbids."""
    out = {}
    for m in MODULES:
        allowed = ALLOWED.get(m.unit, set())
        for line, target in m.imports():
            u = _unit_of(target)
            if u is None or u == m.unit or u in allowed:
                continue
            out.setdefault((m.rel, u), []).append(line)
    return out


def ros_imports():
    """``{(module, top-level name): [line, ...]}`` of ROS imports outside :data:`ROS_UNITS`."""
    out = {}
    for m in MODULES:
        if m.unit in ROS_UNITS:
            continue
        for line, target in m.imports():
            top = target.split(".")[0]
            if _ROS.match(top):
                out.setdefault((m.rel, top), []).append(line)
    return out


def long_modules():
    return {m.rel: len(m.text.splitlines()) for m in MODULES if len(m.text.splitlines()) > MAX_MODULE_LINES}


def long_functions():
    """``{(module, function): lines}`` (from ``def`` to its last line, nested functions counted in)."""
    out = {}
    for m in MODULES:
        for node in ast.walk(m.tree):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                n = node.end_lineno - node.lineno + 1
                if n > MAX_FUNCTION_LINES:
                    out[(m.rel, node.name)] = max(n, out.get((m.rel, node.name), 0))
    return out


def positional_calls():
    """``{(module, called expression): [(line, positional args), ...]}`` over the limit."""
    out = {}
    for m in MODULES:
        for node in ast.walk(m.tree):
            if isinstance(node, ast.Call) and len(node.args) > MAX_POSITIONAL:
                out.setdefault((m.rel, ast.unparse(node.func)), []).append((node.lineno, len(node.args)))
    return out


def drivers():
    return {m.rel for m in MODULES if m.rel.startswith("reachset_ros/nodes/") and "driver" in m.path.name}


def _described(found, known):
    return {k: v for k, v in found.items() if k not in known}


# --------------------------------------------------------------------- the rules
def test_every_unit_has_a_layer():
    units = {m.unit for m in MODULES}
    missing = units - set(ALLOWED)
    assert not missing, f"units without an entry in ALLOWED (add them, with their package docstring): {missing}"
    for unit, allowed in ALLOWED.items():
        assert unit not in allowed


def test_the_layers_have_no_cycle():
    """The allowed edges form a DAG (so the layers are an order, not just a list)."""
    state = {}

    def visit(u, path):
        if state.get(u) == 1:
            raise AssertionError(f"cycle in ALLOWED: {' -> '.join(path + [u])}")
        if state.get(u) == 2:
            return
        state[u] = 1
        for v in sorted(ALLOWED.get(u, ())):
            visit(v, path + [u])
        state[u] = 2

    for u in sorted(ALLOWED):
        visit(u, [])


def test_imports_follow_the_layers():
    bad = _described(import_violations(), KNOWN_IMPORT_VIOLATIONS)
    assert not bad, "imports against the layer rules (module, unit imported): lines\n" + "\n".join(
        f"  {k}: {v}" for k, v in sorted(bad.items()))


def test_only_nodes_and_workflows_import_ros():
    bad = ros_imports()
    assert not bad, f"ROS imported outside {sorted(ROS_UNITS)}: {bad}"


def test_no_module_over_the_limit():
    bad = _described(long_modules(), KNOWN_LONG_MODULES)
    assert not bad, f"modules over {MAX_MODULE_LINES} lines: {bad}"


def test_no_function_over_the_limit():
    bad = _described(long_functions(), KNOWN_LONG_FUNCTIONS)
    assert not bad, f"functions over {MAX_FUNCTION_LINES} lines: {bad}"


def test_no_call_with_too_many_positional_arguments():
    bad = _described(positional_calls(), KNOWN_POSITIONAL_CALLS)
    assert not bad, f"calls with more than {MAX_POSITIONAL} positional arguments: {bad}"


def test_no_driver_module_under_nodes():
    bad = drivers() - KNOWN_DRIVERS
    assert not bad, f"workflows are not nodes: move {sorted(bad)} to reachset_ros/workflows"


def test_known_violations_are_still_violations():
    """A fixed item must leave its KNOWN set (the sets only shrink, to empty)."""
    stale = {
        "KNOWN_IMPORT_VIOLATIONS": KNOWN_IMPORT_VIOLATIONS - set(import_violations()),
        "KNOWN_DRIVERS": KNOWN_DRIVERS - drivers(),
        "KNOWN_LONG_MODULES": KNOWN_LONG_MODULES - set(long_modules()),
        "KNOWN_LONG_FUNCTIONS": KNOWN_LONG_FUNCTIONS - set(long_functions()),
        "KNOWN_POSITIONAL_CALLS": KNOWN_POSITIONAL_CALLS - set(positional_calls()),
    }
    stale = {k: v for k, v in stale.items() if v}
    assert not stale, f"fixed: remove from the KNOWN sets of test_architecture.py: {stale}"


# --------------------------------------------------------------------- the docstrings say the same
_MOD_REF = re.compile(r":mod:`~?reachset_ros\.(\w+)")


def may_import(docstring):
    """The units a package docstring's ``May import:`` paragraph allows: its
    ``:mod:`reachset_ros.X``` references before any "never" / "not" (what follows is what it
    may not import). None without such a paragraph."""
    m = re.search(r"May import:(.*?)(?:\n\s*\n|\Z)", docstring or "", re.S)
    if m is None:
        return None
    text = re.split(r"\b(?:never|not|Never|Not)\b", m.group(1))[0]
    return set(_MOD_REF.findall(text))


PACKAGES = sorted(m.unit for m in MODULES if m.is_init and m.unit != "__init__")


@pytest.mark.parametrize("unit", PACKAGES)
def test_package_docstring_says_what_it_may_import(unit):
    init = next(m for m in MODULES if m.is_init and m.unit == unit)
    said = may_import(ast.get_docstring(init.tree))
    assert said is not None, f"{init.rel}: its docstring has no 'May import:' paragraph"
    assert said == ALLOWED[unit], (f"{init.rel}: 'May import:' says {sorted(said)}, the rules "
                                   f"(ALLOWED in test_architecture.py) {sorted(ALLOWED[unit])}")


# --------------------------------------------------------------------- the checker itself
def test_the_checker_sees_function_local_and_relative_imports(tmp_path):
    """The walk finds imports inside functions and resolves relative ones."""
    src = "def f():\n    from ..bags import read_messages\n    from .. import fleet\n    import rclpy\n"
    tree = ast.parse(src)
    m = Module.__new__(Module)
    m.package, m.tree = "reachset_ros.synthesis", tree
    targets = {t for _, t in m.imports()}
    assert targets == {"reachset_ros.bags", "reachset_ros.fleet", "rclpy"}
    assert may_import("x\n\nMay import: :mod:`reachset_ros.sets` and :mod:`~reachset_ros.errors`;\n"
                      "never :mod:`reachset_ros.sim`.\n") == {"sets", "errors"}
