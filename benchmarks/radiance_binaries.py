"""Radiance's binaries as ``pyradiance`` bundles them: whether they run, running one, and their CPU time.

``pip install pyradiance`` (the ``bench`` extra) ships gendaymtx, oconv, rcontrib, rtrace and the rest with
their library files (reinhart.cal, ...); importing it puts its bin/ on PATH and its lib/ on RAYPATH. The
Radiance references (``radiance_sky``, ``radiance_scene``, ``radiance_reference``, ``radiance_sun``) call them
through ``_run`` and time them with ``_children_cpu``.
"""

from __future__ import annotations

import os
import subprocess
from pathlib import Path


def _pyradiance():
    import pyradiance  # noqa: F401  (its import puts its bin/ on PATH and its lib/ on RAYPATH)

    return pyradiance


def _binary(name: str) -> str:
    from pyradiance.anci import BINPATH

    return str(Path(BINPATH) / name)


def radiance_available() -> bool:
    """True when pyradiance imports and its bundled gendaymtx, oconv and rcontrib run."""
    try:
        _pyradiance()
        for name in ("gendaymtx", "oconv", "rcontrib"):
            if not os.access(_binary(name), os.X_OK):
                return False
        probe = subprocess.run([_binary("rcontrib"), "-defaults"], capture_output=True, timeout=30)
        return probe.returncode == 0 and b"-ab" in probe.stdout
    except Exception:  # noqa: BLE001 - any failure means "not available"
        return False


def _children_cpu() -> float:
    """CPU seconds (user + system) of this process's finished children: Radiance's own time, robust to other
    load on the machine (its wall time on an idle machine is about this over the processes used)."""
    import resource

    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


def _run(cmd: list[str], **kwargs) -> bytes:
    cmd = [_binary(cmd[0])] + cmd[1:]
    done = subprocess.run(cmd, capture_output=True, **kwargs)
    if done.returncode != 0:
        raise RuntimeError(f"{' '.join(cmd)} failed ({done.returncode}): {done.stderr.decode(errors='replace')}")
    return done.stdout
