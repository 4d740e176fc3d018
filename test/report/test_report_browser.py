"""Issue 36.4: the report as a browser renders it, offline: Debian's headless Chromium
(``.ci/run`` installs it) takes a screenshot of the page (not blank) and dumps the rendered DOM
(each joint's section is there). No network: every fetch is refused by the page itself (no
reference outside it) and Chromium runs without its background services.
"""
import shutil
import subprocess

import numpy as np
import pytest

from cli_helpers import run_cli
from report_case import JOINTS

CHROMIUM = "/usr/bin/chromium"
#: headless, offline, throw-away profile (the profile directory is appended per call)
FLAGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
         "--disable-background-networking", "--disable-component-update", "--disable-sync"]


@pytest.fixture(scope="module")
def report(case, tmp_path_factory):
    out = tmp_path_factory.mktemp("browser") / "report.html"
    p = run_cli("report", case["train"], case["faulty"], "--model", case["model"], "--out", out)
    assert p.returncode == 0, p.stderr
    return out


def _chromium(tmp_path, *args):
    exe = CHROMIUM if shutil.which(CHROMIUM) else shutil.which("chromium")
    assert exe, "Debian's chromium is not installed (.ci/run installs it: apt-get install -y chromium)"
    profile = tmp_path / "profile"
    profile.mkdir(exist_ok=True)
    return subprocess.run([exe, *FLAGS, f"--user-data-dir={profile}", *args], capture_output=True, text=True,
                          timeout=600)


@pytest.mark.slow
def test_the_rendered_page_is_not_blank(report, tmp_path):
    from matplotlib.image import imread
    shot = tmp_path / "report.png"
    p = _chromium(tmp_path, "--window-size=1280,2400", f"--screenshot={shot}", report.as_uri())
    assert shot.is_file(), p.stderr[-2000:]
    img = imread(shot)[..., :3]
    grey = img.mean(axis=2)
    assert img.shape[0] >= 1000 and img.shape[1] >= 1000
    # text, tables and figures: a blank (or error) page is one flat colour
    assert grey.std() > 0.05
    assert (grey < 0.5).mean() > 0.005            # dark ink (text, lines) covers some of it
    assert len(np.unique((img * 255).astype(np.uint8).reshape(-1, 3), axis=0)) > 50   # the figures' colours


def test_each_joints_section_is_in_the_rendered_dom(report, tmp_path):
    p = _chromium(tmp_path, "--dump-dom", report.as_uri())
    assert p.returncode == 0, p.stderr[-2000:]
    dom = p.stdout
    assert "Reachset conformance report" in dom
    for n in JOINTS:
        assert f'<section id="joint-{n}" class="joint">' in dom
        assert f"<h2>{n}</h2>" in dom
    assert dom.count('src="data:image/png;base64,') == 2 * len(JOINTS)
