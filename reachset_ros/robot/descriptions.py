"""Where a robot's URDF is: a path, or ``example-robot-data:<path>`` inside that package.

``example-robot-data`` (PyPI, a requirement) ships the URDFs of many arms (Franka Panda,
UR3/5/10, Kinova, ...) under ``<site-packages>/cmeel.prefix/share/example-robot-data/robots``.
:func:`resolve_urdf` turns ``example-robot-data:panda_description/urdf/panda.urdf`` into that
file, so commands and node parameters can name a packaged robot without a machine-specific
path. Nothing here is specific to one robot.
"""
from __future__ import annotations

import sys
import sysconfig
from pathlib import Path

from ..errors import ReachsetError

__all__ = ["PACKAGES", "resolve_urdf"]

#: ``prefix:`` -> the package's robots directory, relative to a site-packages directory.
PACKAGES = {"example-robot-data": Path("cmeel.prefix/share/example-robot-data/robots")}


def _roots():
    seen = []
    for p in [sysconfig.get_paths()["purelib"], *sys.path]:
        if p and p not in seen:
            seen.append(p)
            yield Path(p)


def resolve_urdf(spec) -> Path:
    """The URDF file named by ``spec`` (a path, or ``example-robot-data:<relative path>``).

    Raises ReachsetError naming what was looked for when it does not exist."""
    text = str(spec)
    prefix, sep, rel = text.partition(":")
    if sep and prefix in PACKAGES:
        for root in _roots():
            f = root / PACKAGES[prefix] / rel
            if f.is_file():
                return f.resolve()
        raise ReachsetError(f"{text}: no {rel} in the {prefix} package (is it installed? pip install {prefix})")
    p = Path(text)
    if not p.is_file():
        raise ReachsetError(f"{p}: URDF not found")
    return p.resolve()
