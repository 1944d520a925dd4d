"""usdbake: precomputed lighting for OpenUSD stages with NVIDIA Warp kernels.

The repository root is this package; ``usdbake.processors`` (pure compute),
``usdbake.stages`` (USD boundary, runner, CLI) and ``usdbake.schemas``
(codeless schema plugin) live in the folders of the same names.
"""

import contextlib
import os
import sys
from importlib.metadata import PackageNotFoundError, version

from .schemas import register as _register_schemas

# Register our schema plugin as early as possible: USD reads plugin schemas
# once, when the first stage is opened. In a DCC that opened stages before
# importing usdbake, set PXR_PLUGINPATH_NAME to usdbake/schemas instead.
SCHEMAS_REGISTERED = _register_schemas()

try:
    __version__ = version("usdbake")
except PackageNotFoundError:  # running from a source tree that was never installed
    __version__ = "0.0.0+source"


def bake(stage, processors=None, params=None, **options):
    """Bake into an open Usd.Stage; see usdbake.stages.hook.bake."""
    from .stages.hook import bake as _bake
    from .stages.inputs import check_device

    check_device(options.get("device", "cpu"), option="device=")  # before Warp starts on a device it may lack
    init_warp(options.get("device", "cpu"))
    return _bake(stage, processors=processors, params=params, **options)


def bake_many(paths, output_dir=None, **options):
    """Bake many stage files, one task per stage, locally or on a Dask cluster; see usdbake.farm.batch.bake_many."""
    from .farm.batch import bake_many as _bake_many

    init_warp(options.get("device", "cpu"))
    return _bake_many(paths, output_dir, **options)


CUDA_DRIVER_NOTICE = "Could not find or load the NVIDIA CUDA driver"
"""The line Warp's native library prints at init on a machine without the CUDA driver."""


def init_warp(device: str = "cpu") -> None:
    """Initialise Warp once, with no init banner, and with no CUDA-driver notice unless ``device`` is CUDA.

    The one place usdbake starts Warp (the CLI and :func:`bake` call it before any kernel runs; a
    second call does nothing). Warp prints its banner through its logger, so a scoped
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


__all__ = ["bake", "bake_many", "init_warp", "__version__"]
