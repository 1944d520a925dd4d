"""usdbake: precomputed lighting for OpenUSD stages with NVIDIA Warp kernels.

The repository root is this package; ``usdbake.processors`` (pure compute),
``usdbake.stages`` (USD boundary, runner, CLI) and ``usdbake.schemas``
(codeless schema plugin) live in the folders of the same names.
"""

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

    return _bake(stage, processors=processors, params=params, **options)


__all__ = ["bake", "__version__"]
