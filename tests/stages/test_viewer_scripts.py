"""The viewer's scripts parse (``node --check``): a syntax error would leave the page blank in every browser,
and the browser tests skip where Chromium is missing. Skipped where Node is missing."""

from __future__ import annotations

import shutil
import subprocess

import pytest

from usdbake.stages.serve import VIEWER, VIEWER_SCRIPTS

NODE = shutil.which("node")


@pytest.mark.skipif(NODE is None, reason="no node on this machine")
@pytest.mark.parametrize("name", VIEWER_SCRIPTS)
def test_the_viewer_script_parses(name):
    checked = subprocess.run([NODE, "--check", str(VIEWER / name)], capture_output=True, text=True, timeout=60)
    assert checked.returncode == 0, checked.stderr
