"""Small fake processors and stages for the runner, bake-layer, CLI and hook tests.

The processors are defined here at module scope but NOT registered on import:
tests register the ones they need through a fixture and remove them from
the registry afterwards, so broken graphs never leak into other tests.
``CALLS`` counts ``run`` calls per processor name, so tests can assert what
ran and what was reused from the cache.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass

import numpy as np

from usdbake.core import Params, Primvar, Processor, Result, param
from usdbake.core.scene import Scene

CALLS: Counter = Counter()


@dataclass(frozen=True)
class ProductA:
    values: np.ndarray


@dataclass(frozen=True)
class ProductB:
    values: np.ndarray


@dataclass(frozen=True)
class LightCount:
    count: int


class ProductNA:
    """Never made (its producer does not apply)."""


class ProductNobodyMakes:
    """Required, never provided."""


class ProductC:
    """Half of a cycle."""


class ProductD:
    """The other half."""


class FakeA(Processor):
    """Reads geometry, provides product 'a' (x coordinate of each point times scale)."""

    name = "fake_a"
    provides = (ProductA,)
    facets = ("geometry",)

    @dataclass(frozen=True)
    class Params(Params):
        scale: float = param(1.0, "multiplier", low=0.0, high=10.0)

    def run(self, ctx):
        CALLS[self.name] += 1
        return Result(products={ProductA: ProductA(ctx.scene.points[:, 0] * ctx.params.scale)})


class FakeB(Processor):
    """Requires 'a', provides 'b' and a vertex primvar on the first prim."""

    name = "fake_b"
    requires = (ProductA,)
    provides = (ProductB,)
    facets = ("geometry",)
    writes = ("primvars:bake:fakeB",)

    @dataclass(frozen=True)
    class Params(Params):
        gain: float = param(1.0, "multiplier of a", low=0.0, high=100.0)
        steps: int = param(4, "an int knob", low=1, high=64)
        enabled: bool = param(True, "a bool knob")

    def run(self, ctx):
        CALLS[self.name] += 1
        values = (ctx.products[ProductA].values * ctx.params.gain).astype(np.float32)
        prim = ctx.scene.prim_points(0)
        return Result(products={ProductB: ProductB(values)},
                      outputs=[Primvar(ctx.scene.prim_paths[0], "bake:fakeB", values[prim], "float", "vertex")])


class FakeLights(Processor):
    """Reads only the lights facet: geometry edits must not invalidate it."""

    name = "fake_lights"
    provides = (LightCount,)
    facets = ("lights",)

    def run(self, ctx):
        CALLS[self.name] += 1
        return Result(products={LightCount: LightCount(len(ctx.scene.lights))})


class FakeNotApplicable(Processor):
    name = "fake_na"
    provides = (ProductNA,)

    def applies(self, ctx):
        return False, "no lights in the scene"

    def run(self, ctx):  # pragma: no cover - must never run
        CALLS[self.name] += 1
        return Result()


class FakeAfterNA(Processor):
    name = "fake_after_na"
    requires = (ProductNA,)

    def run(self, ctx):  # pragma: no cover - must never run
        CALLS[self.name] += 1
        return Result()


class FakeBoom(Processor):
    name = "fake_boom"
    requires = (ProductA,)

    def run(self, ctx):
        CALLS[self.name] += 1
        raise RuntimeError("kaboom")


# Broken graphs ------------------------------------------------------------


class FakeDuplicateA(Processor):
    """A second producer of 'a'."""

    name = "fake_dup_a"
    provides = (ProductA,)


class FakeOrphan(Processor):
    """Requires a product nobody provides."""

    name = "fake_orphan"
    requires = (ProductNobodyMakes,)


class FakeCycleC(Processor):
    name = "fake_cycle_c"
    requires = (ProductD,)
    provides = (ProductC,)


class FakeCycleD(Processor):
    name = "fake_cycle_d"
    requires = (ProductC,)
    provides = (ProductD,)


# Scenes and stages ----------------------------------------------------------


def make_scene(points: np.ndarray | None = None, **overrides) -> Scene:
    """A Scene of one unit quad (two triangles) in the xz plane, built without pxr."""
    if points is None:
        points = np.array([[0, 0, 0], [1, 0, 0], [1, 0, 1], [0, 0, 1]], np.float32)
    fields = dict(
        points=points,
        tri_vertices=np.array([[0, 2, 1], [0, 3, 2]], np.int32),
        tri_normals=np.array([[0, 1, 0], [0, 1, 0]], np.float32),
        tri_areas=np.array([0.5, 0.5], np.float32),
        tri_albedo=np.full((2, 3), 0.5, np.float32),
        tri_emission=np.zeros((2, 3), np.float32),
        tri_prim=np.zeros(2, np.int32),
        tri_face=np.zeros(2, np.int32),
        tri_instance=np.full(2, -1, np.int32),
        tri_double_sided=np.zeros(2, bool),
        point_prim=np.zeros(len(points), np.int32),
        prim_paths=("/World/Ground",),
        prim_point_start=np.array([0, len(points)], np.int64),
        prim_face_count=np.array([1], np.int32),
        prim_writable=np.ones(1, bool),
        prim_skip=np.zeros(1, bool),
        prim_surface=("",),
    )
    fields.update(overrides)
    return Scene(**fields)


GROUND_N = 3
"""Ground quads per side: (GROUND_N + 1)^2 points, 2 * GROUND_N^2 triangles."""
GROUND_POINTS = (GROUND_N + 1) ** 2
CUBE_POINTS = 8


def build_stage(stage, *, material: bool = False):
    """Author /World with a subdivided ground quad and a unit cube standing on it (30 triangles)."""
    from pxr import Gf, Sdf, UsdGeom, UsdShade

    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y)
    world = UsdGeom.Xform.Define(stage, "/World")
    stage.SetDefaultPrim(world.GetPrim())

    ground = UsdGeom.Mesh.Define(stage, "/World/Ground")
    coords = np.linspace(-2.0, 2.0, GROUND_N + 1)
    ground.CreatePointsAttr([Gf.Vec3f(float(x), 0.0, float(z)) for z in coords for x in coords])
    indices = []
    for row in range(GROUND_N):
        for col in range(GROUND_N):
            a = row * (GROUND_N + 1) + col
            indices += [a, a + GROUND_N + 1, a + GROUND_N + 2, a + 1]  # counter-clockwise seen from +y
    ground.CreateFaceVertexCountsAttr([4] * GROUND_N * GROUND_N)
    ground.CreateFaceVertexIndicesAttr(indices)

    cube = UsdGeom.Mesh.Define(stage, "/World/Cube")
    cube.CreatePointsAttr([Gf.Vec3f(x, y, z) for x in (-0.5, 0.5) for y in (0.0, 1.0) for z in (-0.5, 0.5)])
    cube.CreateFaceVertexCountsAttr([4] * 6)
    cube.CreateFaceVertexIndicesAttr([0, 1, 3, 2, 4, 6, 7, 5, 0, 4, 5, 1, 2, 3, 7, 6, 0, 2, 6, 4, 1, 5, 7, 3])

    if material:
        mat = UsdShade.Material.Define(stage, "/World/Looks/Grey")
        shader = UsdShade.Shader.Define(stage, "/World/Looks/Grey/Surface")
        shader.CreateIdAttr("UsdPreviewSurface")
        shader.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f).Set(Gf.Vec3f(0.5, 0.5, 0.5))
        mat.CreateSurfaceOutput().ConnectToSource(shader.ConnectableAPI(), "surface")
        for path in ("/World/Ground", "/World/Cube"):
            UsdShade.MaterialBindingAPI.Apply(stage.GetPrimAtPath(path)).Bind(mat)
    return stage


def write_stage(path, *, material: bool = False) -> str:
    """Write the ground + cube stage to ``path`` (.usda) and return it as a string."""
    from pxr import Usd

    stage = Usd.Stage.CreateNew(str(path))
    build_stage(stage, material=material)
    stage.GetRootLayer().Save()
    return str(path)


class FakeUndeclared(Processor):
    """Writes a primvar its `writes` does not declare."""

    name = "fake_undeclared"
    facets = ("geometry",)

    def run(self, ctx):
        prim = ctx.scene.prim_points(0)
        values = np.zeros(prim.stop - prim.start, np.float32)
        return Result(outputs=[Primvar(ctx.scene.prim_paths[0], "bake:stray", values, "float", "vertex")])


class FakeSamePrimvar(Processor):
    """Writes the same primvar as fake_b (two estimators of one quantity), for the conflict check."""

    name = "fake_same_primvar"
    facets = ("geometry",)
    writes = ("primvars:bake:fakeB",)

    def run(self, ctx):
        prim = ctx.scene.prim_points(0)
        values = np.zeros(prim.stop - prim.start, np.float32)
        return Result(outputs=[Primvar(ctx.scene.prim_paths[0], "bake:fakeB", values, "float", "vertex")])
