"""Atomic file output: nothing half-written is ever left at the destination."""
import os
import tempfile
from pathlib import Path


def write_yaml(path, doc, header="", **dump_kwargs):
    """Write ``doc`` as YAML to ``path`` through a temporary file in the same directory and
    a rename; on any error the temporary file is removed and ``path`` is untouched.

    ``header`` is written verbatim before the YAML (e.g. comment lines); ``dump_kwargs`` go
    to ``yaml.safe_dump`` (``sort_keys=False`` by default).
    """
    import yaml
    p = Path(path)
    dump_kwargs.setdefault("sort_keys", False)
    fd, tmp = tempfile.mkstemp(prefix=p.name + ".", suffix=".partial", dir=p.parent)
    try:
        with os.fdopen(fd, "w") as f:
            f.write(header)
            yaml.safe_dump(doc, f, **dump_kwargs)
        os.replace(tmp, p)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise
