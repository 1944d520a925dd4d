"""Starting Warp: once per process, without its banner, and without the CUDA-driver notice on a CPU run.

The package root (``usdbake.bake``, ``bake_many``), the command and farm workers start Warp here before any
kernel runs. Nothing is imported from Warp until a function is called, so importing this costs nothing.
"""

import contextlib
import os
import sys

CUDA_DRIVER_NOTICE = "Could not find or load the NVIDIA CUDA driver"
"""The line Warp's native library prints at init on a machine without the CUDA driver."""


def init_warp(device: str = "cpu") -> None:
    """Initialise Warp once, with no init banner, and with no CUDA-driver notice unless ``device`` is CUDA.

    A second call does nothing. Warp prints its banner through its logger, so a scoped
    ``wp.LOG_WARNING`` (``wp.config.quiet`` before Warp 1.14) hides it. The driver notice
    ("Warp CUDA warning: Could not find or load the NVIDIA CUDA driver. GPU execution will not be
    available.") is an ``fprintf(stderr)`` in the native ``wp_init`` with no setting to turn it off,
    so for a CPU run the process's stderr (file descriptor 2) is captured during ``wp.init()`` and
    everything but that line is written back. When ``device`` names a CUDA device the notice is
    left alone: it explains why that device is missing.
    """
    import warp as wp

    if getattr(wp, "ScopedLogLevel", None) is not None:
        banner_off = wp.ScopedLogLevel(wp.LOG_WARNING)
    else:  # Warp < 1.14: the banner follows config.quiet
        banner_off = _scoped_attribute(wp.config, "quiet", True)
    with banner_off:
        if str(device).startswith("cuda"):
            wp.init()
            # A failed launch (too many registers for the block, out of memory) otherwise passes silently and
            # leaves its outputs unwritten; usdbake synchronizes after its launches anyway.
            wp.config.verify_cuda = True
            return
        with _native_stderr_without(CUDA_DRIVER_NOTICE):
            wp.init()


def start_warp_quietly(device: str = "cpu") -> None:
    """``init_warp`` with only warnings logged from then on: Warp logs module loads to stdout, which must stay
    clean for ``--json``, and a farm worker would log them for every task."""
    import warp as wp

    if hasattr(wp, "LOG_WARNING"):
        wp.config.log_level = wp.LOG_WARNING
    else:  # Warp < 1.14
        wp.config.quiet = True
    init_warp(device)


@contextlib.contextmanager
def _scoped_attribute(owner, name: str, value):
    saved = getattr(owner, name, None)
    setattr(owner, name, value)
    try:
        yield
    finally:
        setattr(owner, name, saved)


@contextlib.contextmanager
def _native_stderr_without(text: str):
    """Send file descriptor 2 (native code's stderr too) to a temporary file; afterwards write back
    every line that does not contain ``text``. Without a usable fd 2 (a GUI host), filter nothing."""
    import tempfile  # here, not at import: `usdbake --help` should not pay for it

    try:
        sys.stderr.flush()
        sink = tempfile.TemporaryFile()
        saved = os.dup(2)
    except (OSError, ValueError, AttributeError):
        saved = None
    if saved is None:
        yield
        return
    with sink:
        os.dup2(sink.fileno(), 2)
        try:
            yield
        finally:
            with contextlib.suppress(OSError, ValueError, AttributeError):
                sys.stderr.flush()
            os.dup2(saved, 2)
            os.close(saved)
            sink.seek(0)
            lines = sink.read().decode("utf-8", "replace").splitlines(keepends=True)
            kept = "".join(line for line in lines if text not in line)
            if kept:
                sys.stderr.write(kept)
                sys.stderr.flush()
