"""Rewrite the build machine's include paths hard-coded in the ROS wheels' CMake exports.

The PyPI Jazzy wheels were built under /opt/python/cp311-cp311; their
``share/*/cmake/*.cmake`` files name that interpreter's include directory and numpy's.
This script replaces them with this interpreter's paths (idempotent).
See docs/ros2-from-pypi.md.
"""
import glob
import os
import sys
import sysconfig

import numpy

OLD_PY = "/opt/python/cp311-cp311/include/python3.11"
OLD_NP = "/opt/python/cp311-cp311/lib/python3.11/site-packages/numpy/_core/include"


def main() -> int:
    prefix = sys.prefix
    new_py = sysconfig.get_paths()["include"]
    new_np = numpy.get_include()
    changed = 0
    for path in glob.glob(os.path.join(prefix, "share", "*", "cmake", "*.cmake")):
        with open(path, encoding="utf-8", errors="surrogateescape") as f:
            text = f.read()
        new = text.replace(OLD_NP, new_np).replace(OLD_PY, new_py)
        if new != text:
            with open(path, "w", encoding="utf-8", errors="surrogateescape") as f:
                f.write(new)
            changed += 1
    print(f"patch_ament_cmake: {changed} file(s) rewritten under {prefix}/share")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
