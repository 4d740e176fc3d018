"""docs/nodes.md: the parameter tables equal what the nodes declare (tools/node_docs.py --check)."""
import os
import subprocess
import sys
from pathlib import Path
import pytest

pytestmark = pytest.mark.dds   # real DDS participants / node processes

REPO = Path(__file__).resolve().parents[2]


def test_node_parameter_tables_match_the_code():
    p = subprocess.run([sys.executable, str(REPO / "tools" / "node_docs.py"), "--check"],
                       env=dict(os.environ), capture_output=True, text=True, timeout=60)
    assert p.returncode == 0, p.stderr
