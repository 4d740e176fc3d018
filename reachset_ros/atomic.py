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
    dump_kwargs.setdefault("sort_keys", False)

    def fill(f):
        f.write(header)
        yaml.safe_dump(doc, f, **dump_kwargs)

    _replace(Path(path), fill)


def write_text(path, text):
    """Write ``text`` (UTF-8) to ``path`` as :func:`write_yaml` writes: a temporary file in the
    same directory, then a rename; nothing half-written is ever left at ``path``."""
    _replace(Path(path), lambda f: f.write(text))


def _replace(p, fill):
    """``fill(f)`` a temporary text file beside ``p``, then rename it to ``p`` (atomic); on any
    error remove it, ``p`` untouched; an ``OSError`` as a :class:`ReachsetError` naming ``p``."""
    try:
        fd, tmp = tempfile.mkstemp(prefix=p.name + ".", suffix=".partial", dir=p.parent)
    except OSError as e:
        raise ReachsetError(f"{p}: cannot write ({e.strerror or type(e).__name__})") from e
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as f:
            fill(f)
        os.replace(tmp, p)
    except BaseException as e:
        if os.path.exists(tmp):
            os.unlink(tmp)
        if isinstance(e, OSError):      # disk full, permissions, ...: one line naming the file
            raise ReachsetError(f"{p}: cannot write ({e.strerror or type(e).__name__})") from e
        raise
