"""Lazy package attributes: a package's public names are imported from their submodule on first
use, so that importing one name of a package does not import all of it.

The pattern of Scientific Python SPEC 1 (``lazy_loader.attach``, used by SciPy, scikit-image
and NetworkX): a package's ``__init__`` lists which submodule holds each public name and
``attach`` returns the module-level ``__getattr__`` (PEP 562) and ``__dir__`` that import it
when it is first asked for. ``from reachset_ros.bags import JOINT_STATES`` then imports
``reachset_ros.bags.messages`` only, not the bag readers and rosbags' storage plugins, and a
node or a command pays at start-up only for what it uses (issue 38.1: ``reachset --help`` took
1.5 s, a node 1.3 s, mostly for modules they never called).

May import: nothing of reachset_ros.
"""
from __future__ import annotations

import importlib
import importlib.util
import sys

__all__ = ["attach"]


def attach(package: str, exports: dict[str, list[str]]):
    """The lazy ``__getattr__`` and ``__dir__`` of ``package`` and the names it exports.

    Parameters
    ----------
    package : str
        The package's ``__name__``.
    exports : dict
        ``{submodule: [names]}``, the submodule relative to the package (``".messages"``,
        ``"..systems.plant"``).

    Returns
    -------
    __getattr__, __dir__ : callable
        For the package's module namespace (PEP 562).
    names : list of str
        Every exported name, in the order given.

    Notes
    -----
    A name is imported once and then stored in the package's namespace, so later lookups do
    not come back here. A submodule's name gives the submodule (imported then), as it did when
    the package imported every submodule at once. Any other name raises AttributeError.
    """
    where = {name: module for module, names in exports.items() for name in names}

    def __getattr__(name):
        module = where.get(name)
        if module is None:
            # a submodule asked for as an attribute (``bags.topics``), as an eager package had it
            if importlib.util.find_spec(f"{package}.{name}") is None:
                raise AttributeError(f"module {package!r} has no attribute {name!r}")
            return importlib.import_module(f"{package}.{name}")
        value = getattr(importlib.import_module(module, package), name)
        setattr(sys.modules[package], name, value)
        return value

    def __dir__():
        return sorted(set(where) | set(vars(sys.modules[package])))

    return __getattr__, __dir__, list(where)
