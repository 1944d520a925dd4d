"""A folder no file can be created in, for the tests of caches and outputs that cannot be written."""

from __future__ import annotations

import os
import shutil
import subprocess

import pytest


class ReadOnly:
    """Makes a folder one no file can be created in, for root too: immutable (``chattr +i``) where we
    are root, mode 0555 otherwise."""

    def __init__(self, folder):
        self.folder = folder
        self.root = os.geteuid() == 0

    def lock(self) -> str:
        """Make it read-only; the strerror a write there now fails with (skip where none fails)."""
        if self.root:
            if not shutil.which("chattr") or subprocess.run(["chattr", "+i", str(self.folder)]).returncode:
                pytest.skip("chattr +i is not available: root can write in any folder")
        else:
            self.folder.chmod(0o555)
        try:
            (self.folder / "probe").write_text("")
        except OSError as error:
            return error.strerror
        pytest.skip("this file system lets us write in a read-only folder")

    def unlock(self) -> None:
        if self.root and shutil.which("chattr"):
            subprocess.run(["chattr", "-i", str(self.folder)], check=False)
        self.folder.chmod(0o755)
