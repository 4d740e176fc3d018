"""Start-up (issue 38.1): what a command or a node imports is what it uses.

Each check runs a fresh interpreter and looks at ``sys.modules``: import counts, not times
(times are measured by ``benchmarks/startup.py``, never asserted in tests).
"""
import importlib
import inspect
import json
import pkgutil
import subprocess
import sys
from pathlib import Path

import pytest

import reachset_ros

LAZY_PACKAGES = ["bags", "conformance", "robot", "sets", "synthesis", "systems"]
#: the heavy libraries no node needs at import (each is imported where it is used)
HEAVY = ["scipy.optimize", "scipy.stats", "scipy.signal", "cvxpy", "matplotlib", "dask"]
NODES = ["controller_node", "observer_node", "monitor_node", "sim_node", "reference_node", "recorder_node",
         "synthesis_node"]


def imported_after(code):
    """The module names in ``sys.modules`` after running ``code`` in a fresh interpreter."""
    out = subprocess.run([sys.executable, "-c", code + "\nimport json, sys; print(json.dumps(sorted(sys.modules)))"],
                         capture_output=True, text=True, timeout=300, check=True)
    return set(json.loads(out.stdout.splitlines()[-1]))


@pytest.mark.parametrize("package", LAZY_PACKAGES)
def test_every_exported_name_resolves_and_none_is_shadowed_by_a_submodule(package):
    pkg = importlib.import_module(f"reachset_ros.{package}")
    submodules = {m.name for m in pkgutil.iter_modules(pkg.__path__)}
    exported = pkg._EXPORTED
    assert set(pkg.__all__) <= set(exported), "__all__ names a name the package does not export"
    for name in exported:
        value = getattr(pkg, name)
        assert value is not None
        if name in submodules:     # imported eagerly: the submodule's import must not replace it
            importlib.import_module(f"reachset_ros.{package}.{name}")
            assert getattr(pkg, name) is value and not inspect.ismodule(value), name
    assert set(exported) <= set(dir(pkg))
    with pytest.raises(AttributeError, match="no attribute 'not_a_name'"):
        getattr(pkg, "not_a_name")


def test_a_submodule_is_an_attribute_of_its_package_in_a_fresh_interpreter():
    """``bags.topics`` with only ``reachset_ros.bags`` imported: test/bags, run alone, failed
    with "module 'reachset_ros.bags' has no attribute 'topics'" once the package was lazy (the
    whole suite passed because another test had imported the submodule first)."""
    mods = imported_after("import reachset_ros.bags as b\nassert b.topics.read_topics\n"
                          "import reachset_ros.conformance as c\nassert c.envelope.Envelope")
    assert "reachset_ros.bags.topics" in mods


def test_one_name_of_a_package_imports_its_submodule_only():
    mods = imported_after("from reachset_ros.bags import JOINT_STATES")
    assert "reachset_ros.bags.messages" in mods
    assert not {"reachset_ros.bags.decoded", "reachset_ros.bags.series", "rosbags.rosbag2"} & mods


def test_help_and_a_usage_error_import_no_command():
    for argv in (["--help"], ["no-such-command"]):
        mods = imported_after("import sys\nfrom reachset_ros import cli\n"
                              f"try:\n    cli.main({argv!r})\nexcept SystemExit:\n    pass")
        commands = sorted(m for m in mods if m.startswith("reachset_ros.commands."))
        assert not commands, f"reachset {' '.join(argv)} imported {commands}"
        assert "numpy" not in mods


def test_a_commands_parser_imports_that_command_only():
    from reachset_ros.cli import command_in
    assert command_in(["--debug", "check", "bag", "--model", "m.yaml"]) == "check"
    assert command_in(["--help"]) == "" and command_in(["nope"]) == ""
    mods = imported_after("from reachset_ros import cli\ncli.build_parser(only='check')")
    commands = {m for m in mods if m.startswith("reachset_ros.commands.") and not m.split(".")[-1].startswith("_")}
    assert commands == {"reachset_ros.commands.check"}


@pytest.mark.parametrize("node", NODES)
def test_a_node_imports_no_heavy_library_it_does_not_use(node):
    mods = imported_after(f"import reachset_ros.nodes.{node}")
    assert not [h for h in HEAVY if h in mods], f"{node} imports {[h for h in HEAVY if h in mods]} at start-up"


def test_the_package_list_is_every_package_that_uses_attach():
    root = Path(reachset_ros.__file__).parent
    users = {p.parent.name for p in root.glob("*/__init__.py") if "attach(__name__" in p.read_text()}
    assert users == set(LAZY_PACKAGES)
