"""Atomic file output: nothing half-written is ever left at the destination."""
import os
import tempfile
from pathlib import Path

import yaml

from .errors import ReachsetError


def write_yaml(path, doc, header="", **dump_kwargs):
    """Write ``doc`` as YAML to ``path`` through a temporary file in the same directory and
    a rename; on any error the temporary file is removed and ``path`` is untouched.

    ``header`` is written verbatim before the YAML (e.g. comment lines); ``dump_kwargs`` go
    to ``yaml.safe_dump`` (``sort_keys=False`` by default). An ``OSError`` (disk full, no
    permission) becomes a :class:`ReachsetError` naming ``path``.
    """
    p = Path(path)
    dump_kwargs.setdefault("sort_keys", False)
    try:
        fd, tmp = tempfile.mkstemp(prefix=p.name + ".", suffix=".partial", dir=p.parent)
    except OSError as e:
        raise ReachsetError(f"{p}: cannot write ({e.strerror or type(e).__name__})") from e
    try:
        with os.fdopen(fd, "w") as f:
            f.write(header)
            yaml.safe_dump(doc, f, **dump_kwargs)
        os.replace(tmp, p)
    except BaseException as e:
        if os.path.exists(tmp):
            os.unlink(tmp)
        if isinstance(e, OSError):      # disk full, permissions, ...: one line naming the file
            raise ReachsetError(f"{p}: cannot write ({e.strerror or type(e).__name__})") from e
        raise
