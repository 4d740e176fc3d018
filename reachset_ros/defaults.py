"""One home for defaults: a registry each module fills once, at import.

The pattern of python-control's ``control/config.py``: the module that owns a concept
registers its defaults under a dotted name (``gains.hg.h1``, ``lwa4p.u_max``,
``analyze.hg.omega``), each with the sentence that says what it means, and everything else
(node parameter descriptors, argparse options, the synthesis configuration, the YAML files
users edit, docs/nodes.md) takes its value from here: ``test/test_defaults.py`` fails when a
copy disagrees. Two defaults that are different concepts (the nodes' start-up gains, the
simulator's recording gains, the paper's fixed feedback law) get distinct names, never one
merged value.

This module is a leaf of the layers: it imports nothing of reachset_ros but
:mod:`reachset_ros.errors`.
"""
from __future__ import annotations

import copy
from dataclasses import dataclass

from .errors import ReachsetError

__all__ = ["Default", "register", "get", "table", "doc", "entries"]


@dataclass(frozen=True, kw_only=True)
class Default:
    """One registered default: its dotted ``name``, ``value``, the ``doc`` sentence saying
    what it means (with the paper's section or table where it comes from) and the ``owner``
    module that registered it."""

    name: str
    value: object
    doc: str
    owner: str


_REGISTRY: dict[str, Default] = {}


def register(prefix: str, entries: dict, *, owner: str) -> None:
    """Register ``{key: (value, doc)}`` under ``prefix.key`` (once per name).

    Registering a name again with the same value (a module reloaded) is a no-op; with
    another value it raises, so two modules cannot hold two defaults under one name.

    Parameters
    ----------
    prefix : str
        Dotted prefix of the names (``"gains.hg"``).
    entries : dict
        ``key -> (value, doc)``.
    owner : str
        The registering module (``__name__``).

    Raises
    ------
    ReachsetError
        A name registered before with a different value, or an entry without its doc.
    """
    for key, entry in entries.items():
        try:
            value, text = entry
        except (TypeError, ValueError):
            raise ReachsetError(f"default {prefix}.{key}: give (value, doc)") from None
        if not isinstance(text, str) or not text:
            raise ReachsetError(f"default {prefix}.{key}: the doc must say what it means")
        name = f"{prefix}.{key}"
        old = _REGISTRY.get(name)
        if old is not None and old.value != value:
            raise ReachsetError(f"default {name} registered twice with different values "
                                f"({old.value!r} by {old.owner}, {value!r} by {owner})")
        _REGISTRY[name] = Default(name=name, value=copy.deepcopy(value), doc=text, owner=owner)


def get(name: str):
    """The value registered under ``name`` (a copy: callers may change it)."""
    try:
        return copy.deepcopy(_REGISTRY[name].value)
    except KeyError:
        raise ReachsetError(f"no default named {name!r} (is its module imported?)") from None


def doc(name: str) -> str:
    """What the default ``name`` means."""
    try:
        return _REGISTRY[name].doc
    except KeyError:
        raise ReachsetError(f"no default named {name!r} (is its module imported?)") from None


def table(prefix: str) -> dict:
    """``{key: value}`` of the names ``prefix.key`` (direct children only, copies)."""
    head = prefix + "."
    out = {n[len(head):]: copy.deepcopy(d.value) for n, d in _REGISTRY.items()
           if n.startswith(head) and "." not in n[len(head):]}
    if not out:
        raise ReachsetError(f"no defaults under {prefix!r} (is its module imported?)")
    return out


def entries(prefix: str = "") -> tuple:
    """Every registered :class:`Default` whose name starts with ``prefix``, by name."""
    return tuple(d for n, d in sorted(_REGISTRY.items()) if n.startswith(prefix))
