"""The codeless usdBake schema plugin: registration, definitions, fallbacks,
and that files using it still open where the plugin is absent."""

import json
import os
import subprocess
import sys

import pytest

from usdbake import schemas

# The schema registry reads plugin definitions once, when it is first built;
# register before anything in this module touches a stage.
_REGISTERED = schemas.register()

from pxr import Gf, Sdf, Tf, Usd, UsdGeom, Vt  # noqa: E402

XFORMABLE_PROPS = {"proxyPrim", "purpose", "visibility", "xformOpOrder"}

TYPED_PROPS = {
    "LightProbeCloud": {
        "probePositions",
        "shCoefficients",
        "tetrahedra",
        "tetNeighbors",
        "shOrder",
        "shBasis",
    },
    "IrradianceVectorGrid": {
        "gridOrigin",
        "cellSize",
        "resolution",
        "directions",
        "colorsRGB9E5",
        "vectorsPerVertex",
        "streamFile",
    },
    "RadiosityPatches": {
        "centroids",
        "normals",
        "areas",
        "albedo",
        "trianglePatch",
        "matrixFile",
        "sparseFile",
        "bounces",
        "quantizationScale",
        "quantizationOffset",
        "permutation",
    },
}

API_PROPS = {
    "ProbeVolumeAPI": set(),
    "DisplacementFieldAPI": {
        "bake:field:file",
        "bake:field:center",
        "bake:field:radius",
        "bake:field:positionalSamples",
        "bake:field:directionMapSize",
        "bake:field:encoding",
        "bake:field:positionMapping",
        "bake:field:directionMapping",
        "bake:field:orientation",
    },
    "SkyVisibilityAPI": {
        "bake:sky:patchCount",
        "bake:sky:patchLayout",
        "bake:sky:subdivision",
        "bake:sky:patchDirections",
        "bake:sky:patchSolidAngles",
        "bake:sky:upAxis",
    },
}


def test_register_succeeds_and_is_idempotent():
    assert _REGISTERED, "schemas.register() ran after the schema registry was built"
    assert schemas.register() is True
    assert set(schemas.TYPED_SCHEMAS) == set(TYPED_PROPS)
    assert set(schemas.API_SCHEMAS) == set(API_PROPS)
    assert os.path.isfile(os.path.join(schemas.SCHEMA_DIR, "plugInfo.json"))


@pytest.mark.parametrize("name", sorted(TYPED_PROPS))
def test_typed_schema_definition(name):
    definition = Usd.SchemaRegistry().FindConcretePrimDefinition(name)
    assert definition is not None
    assert set(definition.GetPropertyNames()) == TYPED_PROPS[name] | XFORMABLE_PROPS

    tf_type = Usd.SchemaRegistry.GetTypeFromName(name)
    assert tf_type == Tf.Type.FindByName("UsdBake" + name)
    assert Usd.SchemaRegistry.IsConcrete(tf_type)
    assert tf_type.IsA(Tf.Type.FindByName("UsdGeomXformable"))

    stage = Usd.Stage.CreateInMemory()
    prim = stage.DefinePrim("/P", name)
    assert prim.IsA(tf_type)
    assert prim.IsA(UsdGeom.Xformable)
    assert UsdGeom.Xformable(prim)
    assert TYPED_PROPS[name] <= set(prim.GetPropertyNames())


@pytest.mark.parametrize("name", sorted(API_PROPS))
def test_api_schema_definition(name):
    definition = Usd.SchemaRegistry().FindAppliedAPIPrimDefinition(name)
    assert definition is not None
    assert set(definition.GetPropertyNames()) == API_PROPS[name]
    tf_type = Usd.SchemaRegistry.GetTypeFromName(name)
    assert tf_type == Tf.Type.FindByName("UsdBake" + name)
    assert Usd.SchemaRegistry.IsAppliedAPISchema(tf_type)
    assert not Usd.SchemaRegistry.IsMultipleApplyAPISchema(tf_type)


def test_apply_api_and_has_api():
    stage = Usd.Stage.CreateInMemory()
    cloud = stage.DefinePrim("/Cloud", "LightProbeCloud")
    assert not cloud.HasAPI("SkyVisibilityAPI")
    assert cloud.CanApplyAPI("SkyVisibilityAPI")
    assert cloud.ApplyAPI("SkyVisibilityAPI")
    assert cloud.HasAPI("SkyVisibilityAPI")
    assert API_PROPS["SkyVisibilityAPI"] <= set(cloud.GetPropertyNames())

    mesh = stage.DefinePrim("/Mesh", "Mesh")
    assert mesh.AddAppliedSchema("DisplacementFieldAPI")
    assert mesh.HasAPI("DisplacementFieldAPI")
    assert "DisplacementFieldAPI" in mesh.GetAppliedSchemas()
    assert API_PROPS["DisplacementFieldAPI"] <= set(mesh.GetPropertyNames())


def test_fallbacks_for_unauthored_attributes():
    stage = Usd.Stage.CreateInMemory()
    prim = stage.DefinePrim("/P", "LightProbeCloud")
    prim.ApplyAPI("DisplacementFieldAPI")
    prim.ApplyAPI("SkyVisibilityAPI")
    grid = stage.DefinePrim("/G", "IrradianceVectorGrid")
    patches = stage.DefinePrim("/R", "RadiosityPatches")

    expected = [
        (prim, "shOrder", 2),
        (prim, "shBasis", "realOrthonormal"),
        (prim, "bake:field:encoding", "uint8"),
        (prim, "bake:field:positionMapping", "octahedralEqualArea"),
        (prim, "bake:field:directionMapping", "concentricMalley"),
        (prim, "bake:sky:patchLayout", "reinhart"),
        (prim, "bake:sky:subdivision", 1),
        (grid, "vectorsPerVertex", 6),
        (patches, "bounces", 3),
    ]
    for owner, attr_name, value in expected:
        attr = owner.GetAttribute(attr_name)
        assert attr.IsValid(), attr_name
        assert not attr.HasAuthoredValue(), attr_name
        assert attr.Get() == value, attr_name

    shbasis = prim.GetAttribute("shBasis")
    assert "realOrthonormal" in shbasis.GetMetadata("allowedTokens")
    encoding = prim.GetAttribute("bake:field:encoding")
    assert list(encoding.GetMetadata("allowedTokens")) == ["uint8", "bit1"]
    assert prim.GetAttribute("probePositions").GetTypeName() == Sdf.ValueTypeNames.Point3fArray
    # No fallback: unauthored arrays read back as None, not as empty arrays.
    assert prim.GetAttribute("probePositions").Get() is None


# Authored in the parent (plugin registered); read back in a child process
# that has never heard of the plugin. Values are exact in float32.
AUTHORED = {
    "probePositions": (Sdf.ValueTypeNames.Point3fArray, [[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]]),
    "shCoefficients": (Sdf.ValueTypeNames.Float3Array, [[0.5, 0.25, -0.125]] * 36),
    "tetrahedra": (Sdf.ValueTypeNames.IntArray, [0, 1, 2, 3]),
    "tetNeighbors": (Sdf.ValueTypeNames.IntArray, [-1, -1, -1, -1]),
    "shOrder": (Sdf.ValueTypeNames.Int, 2),
    "shBasis": (Sdf.ValueTypeNames.Token, "realOrthonormalCondonShortley"),
    "bake:field:file": (Sdf.ValueTypeNames.Asset, "./field.bin"),
    "bake:field:center": (Sdf.ValueTypeNames.Point3f, [1.5, -2.0, 0.25]),
    "bake:field:radius": (Sdf.ValueTypeNames.Float, 3.75),
    "bake:field:positionalSamples": (Sdf.ValueTypeNames.Int, 1024),
    "bake:field:directionMapSize": (Sdf.ValueTypeNames.Int2, [32, 16]),
    "bake:field:encoding": (Sdf.ValueTypeNames.Token, "bit1"),
    "bake:field:positionMapping": (Sdf.ValueTypeNames.Token, "octahedralEqualArea"),
    "bake:field:directionMapping": (Sdf.ValueTypeNames.Token, "concentricMalley"),
    "bake:field:orientation": (Sdf.ValueTypeNames.Quatf, [0.5, 0.5, 0.5, 0.5]),
}

_CHILD = r"""
import json, sys
from pxr import Sdf, Usd

def plain(v):
    if isinstance(v, Sdf.AssetPath):
        return v.path
    if isinstance(v, (str, bool, int, float)):
        return v
    if hasattr(v, "GetReal"):  # a quaternion: (real, i, j, k)
        return [v.GetReal(), *v.GetImaginary()]
    try:
        return [plain(x) for x in v]
    except TypeError:
        return v

path, prim_path, names = sys.argv[1], sys.argv[2], json.loads(sys.argv[3])
stage = Usd.Stage.Open(path)
prim = stage.GetPrimAtPath(prim_path)
out = {
    "plugin_known": not Usd.SchemaRegistry.GetTypeFromName("LightProbeCloud").isUnknown,
    "type_name": str(prim.GetTypeName()),
    "api_schemas": [str(s) for s in prim.GetMetadata("apiSchemas").GetAddedOrExplicitItems()],
    "attrs": {},
}
for name in names:
    attr = prim.GetAttribute(name)
    out["attrs"][name] = {
        "valid": attr.IsValid(),
        "authored": attr.HasAuthoredValue(),
        "type": str(attr.GetTypeName()),
        "value": plain(attr.Get()),
    }
print(json.dumps(out))
"""


def _as_vt(type_name, value):
    if type_name == Sdf.ValueTypeNames.Asset:
        return Sdf.AssetPath(value)
    if type_name in (Sdf.ValueTypeNames.Point3f,):
        return Gf.Vec3f(*value)
    if type_name == Sdf.ValueTypeNames.Int2:
        return Gf.Vec2i(*value)
    if type_name == Sdf.ValueTypeNames.Quatf:
        return Gf.Quatf(*value)
    if type_name in (Sdf.ValueTypeNames.Point3fArray, Sdf.ValueTypeNames.Float3Array):
        return Vt.Vec3fArray([Gf.Vec3f(*v) for v in value])
    if type_name == Sdf.ValueTypeNames.IntArray:
        return Vt.IntArray(value)
    return value


def test_file_opens_without_plugin(tmp_path):
    path = tmp_path / "probes.usda"
    stage = Usd.Stage.CreateNew(str(path))
    prim = stage.DefinePrim("/World/Probes", "LightProbeCloud")
    assert prim.ApplyAPI("DisplacementFieldAPI")
    for name, (type_name, value) in AUTHORED.items():
        attr = prim.GetAttribute(name)
        assert attr.IsValid() and attr.GetTypeName() == type_name, name
        assert attr.Set(_as_vt(type_name, value)), name
    stage.GetRootLayer().Save()

    env = {k: v for k, v in os.environ.items() if k != "PXR_PLUGINPATH_NAME"}
    result = subprocess.run(
        [sys.executable, "-c", _CHILD, str(path), "/World/Probes", json.dumps(list(AUTHORED))],
        env=env,
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=120,
        check=True,
    )
    seen = json.loads(result.stdout.strip().splitlines()[-1])

    assert seen["plugin_known"] is False, "child process must not see the plugin"
    assert seen["type_name"] == "LightProbeCloud"
    assert seen["api_schemas"] == ["DisplacementFieldAPI"]
    for name, (type_name, value) in AUTHORED.items():
        got = seen["attrs"][name]
        assert got["valid"] and got["authored"], name
        assert got["type"] == str(type_name), name
        assert got["value"] == value, name
