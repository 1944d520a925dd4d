"""Codeless USD schema plugin for the data usdbake writes.

This folder is a USD plugin of ``Type: "resource"`` (no compiled code):

- ``schema.usda``: the human-authored schema source (``skipCodeGeneration``;
  library ``usdBake``, prefix ``UsdBake``);
- ``generatedSchema.usda`` and ``plugInfo.json``: what ``usdGenSchema`` makes
  of it (regenerate with ``usdGenSchema schema.usda .`` after editing it).

It defines three concrete typed schemas based on ``Xformable``
(``LightProbeCloud``, ``IrradianceVectorGrid``, ``RadiosityPatches``) and three
single-apply API schemas (their properties live under ``bake:``)
(``DisplacementFieldAPI``, ``ProbeVolumeAPI``, ``SkyVisibilityAPI``).

A DCC or any other USD application picks the schemas up by setting
``PXR_PLUGINPATH_NAME`` to this folder (``SCHEMA_DIR``) before USD starts, or
by calling :func:`register` early. Without the plugin, files written by
usdbake still open everywhere: the prims keep their type names and every
authored value reads back as a plain attribute; only the schema fallbacks and
property definitions are missing.
"""

import os

from pxr import Plug, Usd

SCHEMA_DIR = os.path.dirname(os.path.abspath(__file__))

TYPED_SCHEMAS = ("LightProbeCloud", "IrradianceVectorGrid", "RadiosityPatches")
API_SCHEMAS = ("DisplacementFieldAPI", "ProbeVolumeAPI", "SkyVisibilityAPI")


def register() -> bool:
    """Register this folder's schemas with USD; return True if USD knows them.

    Must run before the first ``Usd.SchemaRegistry`` use in the process,
    which opening or creating any stage does: the schema registry reads the
    plugins' ``generatedSchema.usda`` files once, when that singleton is
    built, and never again. Registered later, the types exist but have no
    prim definitions, and this returns False.

    Calling it again is harmless (Plug registers a folder only once).
    """
    Plug.Registry().RegisterPlugins(SCHEMA_DIR)
    registry = Usd.SchemaRegistry()
    return all(
        registry.FindConcretePrimDefinition(name) is not None for name in TYPED_SCHEMAS
    ) and all(registry.FindAppliedAPIPrimDefinition(name) is not None for name in API_SCHEMAS)
