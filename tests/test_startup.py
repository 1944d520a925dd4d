"""Startup: nothing computed at import, no Warp behind --help, no CUDA notice or banner for a CPU run."""

from __future__ import annotations

import subprocess
import sys

from usdbake import CUDA_DRIVER_NOTICE


def run(code: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)


def test_help_loads_no_warp():
    done = run("import sys\nfrom usdbake.cli.main import main\n"
               "try:\n    main(['--help'])\nexcept SystemExit:\n    pass\n"
               "print(sorted(m for m in ('warp', 'scipy', 'pytetwild', 'pyvista') if m in sys.modules))")
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip().splitlines()[-1] == "[]"


def test_cpu_init_prints_no_cuda_notice_and_no_banner():
    done = run("import usdbake\nusdbake.init_warp('cpu')\nimport warp as wp\nprint(wp.get_device('cpu'))")
    assert done.returncode == 0, done.stderr
    assert CUDA_DRIVER_NOTICE not in done.stderr
    assert done.stdout.strip() == "cpu"  # no "Warp 1.x initialized:" banner


def test_cpu_init_keeps_every_other_line_warp_writes_to_stderr():
    # Stand-in for the native library: writes the notice and another line to file descriptor 2.
    done = run("import os, usdbake, warp as wp\n"
               f"wp.init = lambda: os.write(2, b'Warp CUDA warning: {CUDA_DRIVER_NOTICE}.\\nnative line\\n')\n"
               "usdbake.init_warp('cpu')\n")
    assert done.returncode == 0, done.stderr
    assert done.stderr == "native line\n"


def test_a_cuda_request_keeps_the_notice():
    done = run("import os, usdbake, warp as wp\n"
               f"wp.init = lambda: os.write(2, b'Warp CUDA warning: {CUDA_DRIVER_NOTICE}.\\n')\n"
               "usdbake.init_warp('cuda:0')\n")
    assert done.returncode == 0, done.stderr
    assert CUDA_DRIVER_NOTICE in done.stderr
