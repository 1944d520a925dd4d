"""usdbake: precomputed lighting for OpenUSD stages with NVIDIA Warp kernels.

The repository root is this package, and this module is its Python front door: ``bake`` (into an open
stage, ``stages.hook``), ``bake_many`` (stage files, ``farm.batch``), ``init_warp`` and ``__version__``.
It sits above every folder: it may import any of them, and none imports it.
"""

from .core.version import __version__
from .kernels.startup import CUDA_DRIVER_NOTICE, init_warp
from .schemas import register as _register_schemas

# Register our schema plugin as early as possible: USD reads plugin schemas
# once, when the first stage is opened. In a DCC that opened stages before
# importing usdbake, set PXR_PLUGINPATH_NAME to usdbake/schemas instead.
SCHEMAS_REGISTERED = _register_schemas()


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


__all__ = ["CUDA_DRIVER_NOTICE", "bake", "bake_many", "init_warp", "__version__"]
