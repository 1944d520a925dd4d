"""radiosity: direct light against closed forms, relight, transfer and the processor end to end."""

from repo_paths import SAMPLES
import math

import numpy as np
from lit_scenes import make_lights
from stage_builders import base_context
import pytest
from patch_scenes import box_parts, make_scene, quad
from tolerances import (DIRECT_TOLERANCE, DISTANT_CONE, FLOAT32_ACCUMULATED, FLOAT32_ROUNDING, FLOAT32_STORAGE,
                        RADIOSITY_PATH_TRACED)
from usdbake.processors.radiosity.products import FormFactorProduct, RadiosityProduct
from usdbake.processors.radiosity import form_factors as ff
from usdbake.processors.radiosity import radiosity as rad
from usdbake.core import Context, Primvar
from usdbake.geometry.mesh import vertex_normals
from usdbake.kernels.light_bundles import emissive_lights
from usdbake.core.scene import LIGHT_DISK, LIGHT_DISTANT, LIGHT_DOME, LIGHT_SPHERE
from usdbake.kernels.tracer import Tracer

def floor_scene(light_rows, extra_parts=()):
    floor = quad([-10, -10, 0], [20, 0, 0], [0, 20, 0])  # z = 0, normal +z
    return make_scene([floor, *extra_parts], lights=make_lights(*light_rows))


def direct_at_origin(scene, samples=1024):
    """Cosine rays alone for domes (no guide: exact under an open uniform sky; the guide's own tests are in
    tests/kernels/test_sky_guide.py)."""
    tracer = Tracer.from_scene(scene)
    return rad.compute_direct_irradiance(tracer, scene, np.array([[0, 0, 0.0]]), np.array([[0, 0, 1.0]]),
                                         light_samples=samples, sky_samples=samples, sky_training=0)[0]


def test_disk_light_on_axis_matches_closed_form():
    radius, height, radiance = 1.0, 2.0, 3.0
    scene = floor_scene([(LIGHT_DISK, [radiance] * 3, [0, 0, height], [0, 0, -1], [radius, radius])])
    expected = radiance * math.pi * radius ** 2 / (height ** 2 + radius ** 2)
    np.testing.assert_allclose(direct_at_origin(scene), expected, rtol=DIRECT_TOLERANCE)


def test_sphere_light_matches_closed_form():
    radius, distance, radiance = 0.5, 3.0, 2.0
    scene = floor_scene([(LIGHT_SPHERE, [radiance] * 3, [0, 0, distance], [0, 0, -1], [radius, radius])])
    expected = radiance * math.pi * (radius / distance) ** 2  # sphere straight above: pi L sin^2(alpha)
    np.testing.assert_allclose(direct_at_origin(scene), expected, rtol=DIRECT_TOLERANCE)


def test_distant_and_dome_lights():
    theta = math.radians(60)
    distant = floor_scene([(LIGHT_DISTANT, [5, 4, 3], [0, 0, 0], [math.sin(theta), 0, -math.cos(theta)], [0, 0])])
    np.testing.assert_allclose(direct_at_origin(distant), np.array([5, 4, 3]) * math.cos(theta),
                               rtol=FLOAT32_ACCUMULATED)
    # A cone of full angle 10 degrees straight down: E = L Omega <cos> with <cos> = (1 + cos_max) / 2.
    cone = floor_scene([(LIGHT_DISTANT, [2, 2, 2], [0, 0, 0], [0, 0, -1], [10, 10])])
    cos_max = math.cos(math.radians(5))
    np.testing.assert_allclose(direct_at_origin(cone), 2 * 2 * math.pi * (1 - cos_max) * (1 + cos_max) / 2,
                               rtol=DISTANT_CONE)
    dome = floor_scene([(LIGHT_DOME, [1.5] * 3, [0, 0, 0], [0, 0, -1], [0, 0])])
    np.testing.assert_allclose(direct_at_origin(dome), 1.5 * math.pi, rtol=FLOAT32_ACCUMULATED)


def test_emissive_triangles_light_like_a_rect_when_no_usdlux_lights():
    size, height, radiance = 1.0, 2.0, 4.0
    emitter = quad([-size / 2, -size / 2, height], [0, size, 0], [size, 0, 0])  # normal -z, facing the floor
    floor = quad([-10, -10, 0], [20, 0, 0], [0, 20, 0])
    scene = make_scene([floor, emitter], emission=np.array([[0, 0, 0], [radiance] * 3], np.float32))
    # Closed form for a square of side a at height h on axis (Howell C-3 with X = Y = a / 2h).
    x = size / (2 * height)
    f = 2 / math.pi * (2 * x / math.sqrt(1 + x * x) * math.atan(x / math.sqrt(1 + x * x)))
    np.testing.assert_allclose(direct_at_origin(scene), radiance * math.pi * f, rtol=DIRECT_TOLERANCE)
    assert emissive_lights(scene, "auto") and not emissive_lights(scene, "off")


def test_blocker_casts_a_shadow():
    blocker = quad([-1, -1, 1], [0, 2, 0], [2, 0, 0])
    scene = floor_scene([(LIGHT_DISK, [1] * 3, [0, 0, 2], [0, 0, -1], [0.3, 0.3])], [blocker])
    assert direct_at_origin(scene, 64).max() == 0.0


def test_processor_skips_without_lights_with_a_reason():
    ok, reason = rad.Radiosity().applies(base_context(make_scene(box_parts())))
    assert not ok and reason.startswith("no lights (no UsdLux light with radiance and no emissive triangle): add")
    lit = make_scene(box_parts(), emission=np.array([[1, 1, 1]] + [[0, 0, 0]] * 5, np.float32))
    assert rad.Radiosity().applies(base_context(lit))[0]


def test_transfer_is_smooth_and_respects_normals():
    centroids = np.array([[0, 0, 0], [1, 0, 0], [0.5, 0, 0.01]], np.float32)
    normals = np.array([[0, 0, 1], [0, 0, 1], [0, 0, -1]], np.float32)
    values = np.array([[1, 1, 1], [3, 3, 3], [100, 100, 100]], np.float32)
    xs = np.linspace(0, 1, 11)
    points = np.stack([xs, np.zeros_like(xs), np.zeros_like(xs)], 1).astype(np.float32)
    out = rad.transfer_to_vertices(points, np.tile([0, 0, 1.0], (11, 1)).astype(np.float32), centroids, normals,
                                   values, neighbors=3, smoothing=0.1)
    # the back-facing patch is ignored
    assert (out[:, 0] < 3 + FLOAT32_ACCUMULATED).all() and (out[:, 0] > 1 - FLOAT32_ACCUMULATED).all()
    assert (np.diff(out[:, 0]) >= -FLOAT32_STORAGE).all()  # monotone between the two patches: no blocky steps
    assert len(np.unique(out[:, 0].round(4))) > 5


@pytest.fixture(scope="module")
def lit_box():
    # A closed 2 m room with a disk light under the ceiling, one grey prim per face; k = 3 bounces (not
    # the default closed form), so the path tracer and the energy bound below can stop at k.
    parts = box_parts(size=2.0, grid=2)
    light = (LIGHT_DISK, [10, 9, 8], [1, 1, 1.9], [0, 0, -1], [0.3, 0.3])
    scene = make_scene(parts, albedo=(0.6, 0.5, 0.4), lights=make_lights(light))
    tracer = Tracer.from_scene(scene)
    params = ff.FormFactors.Params(target_patches=300, rays=256, infinite=False)
    product = ff.FormFactors().run(Context(scene=scene, params=params, tracer=tracer)).products[FormFactorProduct]
    return scene, tracer, product


def test_processor_end_to_end(lit_box):
    scene, tracer, product = lit_box
    params = rad.Radiosity.Params(light_samples=16, gather_rays=64)
    result = rad.Radiosity().run(Context(scene=scene, params=params, tracer=tracer,
                                         products={FormFactorProduct: product}))
    primvars = [r for r in result.outputs if isinstance(r, Primvar)]
    assert {r.name for r in primvars} == {"bake:irradianceDirect", "bake:irradianceIndirect"}
    assert len(primvars) == 2 * len(scene.prim_paths)
    for record in primvars:
        assert record.type_name == "color3f" and record.interpolation == "vertex"
        assert record.values.shape == (scene.prim_points(scene.prim_paths.index(record.prim)).stop
                                       - scene.prim_points(scene.prim_paths.index(record.prim)).start, 3)
        assert np.isfinite(record.values).all() and (record.values >= 0).all()
    radiosity = result.products[RadiosityProduct]
    n = product.patches.count
    assert radiosity.patch_radiosity.shape == (n, 3)
    direct, indirect = radiosity.patch_irradiance_direct, radiosity.patch_irradiance_indirect
    assert indirect.min() >= 0 and indirect.sum() > 0
    # The ceiling faces away from the light: no direct light, only indirect.
    ceiling = product.patches.patch_normals[:, 2] < -0.5
    assert direct[ceiling].max() == 0 and indirect[ceiling].min() > 0
    # Energy: indirect power <= direct power * rho / (1 - rho) (closed room, albedo <= 0.6).
    areas = product.patches.patch_areas[:, None]
    assert ((areas * indirect).sum(0) <= (areas * direct).sum(0) * 0.6 / 0.4).all()


def test_vertex_and_texel_indirect_agree_with_a_path_tracer(lit_box):
    """The vertices, and the same points given as texels (the texture target's path, its own seeds)."""
    from usdbake.benchmarks.references import path_traced_indirect

    scene, tracer, product = lit_box
    ids = np.arange(scene.num_points)
    params = rad.Radiosity.Params(light_samples=16, gather_rays=256)
    normals = vertex_normals(scene.points, scene.tri_vertices, scene.tri_normals, scene.tri_areas)
    positions = rad.vertex_sample_positions(scene.points, scene.tri_vertices, scene.tri_areas)
    solved = rad.solve(tracer, scene, product, params, ids, texels=(positions, normals))
    # The final gather reflects the patches' k-bounce light once more: k + 1 bounces at the vertices.
    reference = path_traced_indirect(tracer, scene, positions, normals, paths=2048, bounces=product.bounces + 1)
    for key in ("vertex_indirect", "texel_indirect"):
        error = np.sqrt(np.mean((solved[key] - reference) ** 2) / np.mean(reference ** 2))
        assert error < RADIOSITY_PATH_TRACED, (key, error)
    np.testing.assert_allclose(solved["texel_direct"], solved["vertex_direct"], rtol=DIRECT_TOLERANCE * 4,
                               atol=DIRECT_TOLERANCE * float(solved["vertex_direct"].max()))


def test_results_do_not_depend_on_thread_count(lit_box):
    scene, _, product = lit_box
    ids = np.arange(scene.num_points)
    params = rad.Radiosity.Params(light_samples=4, gather_rays=16)
    one = rad.solve(Tracer.from_scene(scene, threads=1), scene, product, params, ids)
    two = rad.solve(Tracer.from_scene(scene, threads=2), scene, product, params, ids)
    for key in one.keys() - {"transfer_seconds"}:  # every result; the timing is not one
        np.testing.assert_allclose(one[key], two[key], rtol=FLOAT32_ACCUMULATED, atol=FLOAT32_ROUNDING)


def test_bake_cornell_box_through_the_cli(tmp_path):
    from pathlib import Path

    from pxr import Sdf, Usd

    from usdbake.cli.main import main

    sample = SAMPLES / "cornell_box.usda"
    out = tmp_path / "cornell.usdc"
    code = main(["bake", str(sample), "-o", str(out), "-p", "radiosity", "--cache", str(tmp_path / "cache"),
                 "--set", "form_factors.target_patches=200", "--set", "form_factors.rays=64",
                 "--set", "radiosity.gather_rays=16", "--set", "radiosity.light_samples=4"])
    assert code == 0
    stage = Usd.Stage.Open(str(out))
    patches = stage.GetPrimAtPath(ff.PATCHES_PRIM)
    assert patches.GetTypeName() == "RadiosityPatches"
    count = len(patches.GetAttribute("areas").Get())
    assert len(patches.GetAttribute("permutation").Get()) == count
    asset = patches.GetAttribute("matrixFile").Get()
    assert isinstance(asset, Sdf.AssetPath)
    matrix = Path(asset.resolvedPath or (tmp_path / asset.path))
    assert matrix.exists() and (tmp_path / patches.GetAttribute("sparseFile").Get().path).exists()
    oiio = pytest.importorskip("OpenImageIO")
    reader = oiio.ImageInput.open(str(matrix))
    assert reader.spec().width == (count + 3) // 4 * 4
    reader.close()
    floor = stage.GetPrimAtPath("/World/CornellBox/Floor")
    points = len(floor.GetAttribute("points").Get())
    for name in ("primvars:bake:irradianceDirect", "primvars:bake:irradianceIndirect"):
        attr = floor.GetAttribute(name)
        assert attr.GetMetadata("interpolation") == "vertex"
        values = np.array(attr.Get())
        assert values.shape == (points, 3) and np.isfinite(values).all() and values.sum() > 0


SHARED_PATCH_MARGIN = 0.02
"""Relative RMS that patches shared across instances may lose against patches of their own (the same
spheres as receiver meshes, about the same patch count) at the floor's vertices: measured -0.003 here
(shared better), -0.06 to +0.012 on denser layouts; both estimates meet the same reference, so its noise
(~0.04 at 4096 paths) largely cancels in the difference."""


def test_instances_sharing_patches_light_the_floor_as_well_as_patches_of_their_own():
    """Issue 27: instances cluster into patches spanning several of them (the patch count then follows
    target_patches, not the instance count); the floor they stand on is lit as accurately as when every
    sphere had patches of its own, against a path tracer."""
    import dataclasses

    from instanced_scenes import build_scene, grid, icosphere, translate
    from usdbake.benchmarks.references import path_traced_indirect

    sphere, triangles = icosphere(2)
    ticks = (np.arange(4) + 0.5) / 4 * 8.0 - 4.0
    instances = [(0, translate(x, 0.5, z, scale=(0.5, 0.5, 0.5))) for x in ticks for z in ticks]
    sun = np.array([0.3, -1.0, 0.2]) / np.linalg.norm([0.3, -1.0, 0.2])
    lights = make_lights((LIGHT_DISTANT, [3, 3, 3], [0, 0, 0], sun, [0.53, 0]),
                         (LIGHT_DOME, [0.3, 0.3, 0.3], [0, 0, 0], [0, -1, 0], [0, 0]))
    scene = dataclasses.replace(build_scene([("/World/Floor", *grid(5.0, 20))],
                                            [("/World/Proto/Sphere", sphere, triangles)], instances), lights=lights)
    ids = np.flatnonzero(scene.point_prim == 0)
    floor = scene.tri_prim == 0
    normals = vertex_normals(scene.points, scene.tri_vertices[floor], scene.tri_normals[floor],
                             scene.tri_areas[floor])[ids]
    positions = rad.vertex_sample_positions(scene.points, scene.tri_vertices[floor], scene.tri_areas[floor])[ids]
    tracer = Tracer.from_scene(scene)
    reference = path_traced_indirect(tracer, scene, positions, normals, paths=4096, bounces=4)
    errors, counts = {}, {}
    for own in (False, True):  # own: the spheres writable (receivers), one patch set per sphere
        case = dataclasses.replace(scene, prim_writable=np.full(len(scene.prim_paths), own)) if own else scene
        tracer = Tracer.from_scene(case)
        product, _ = ff.precompute(tracer, case, ff.FormFactors.Params(target_patches=100, rays=256))
        solved = rad.solve(tracer, case, product, rad.Radiosity.Params(light_samples=16, gather_rays=256), ids)
        errors[own] = float(np.sqrt(np.mean((solved["vertex_indirect"] - reference) ** 2) / np.mean(reference ** 2)))
        counts[own] = product.patches.count
    assert counts[False] <= 1.2 * 100 and counts[True] >= 16 * 6  # a sphere's own patches: one per normal axis
    assert errors[False] < RADIOSITY_PATH_TRACED, errors
    assert errors[False] <= errors[True] + SHARED_PATCH_MARGIN, errors


@pytest.mark.parametrize("infinite, bounces", [(False, 1), (False, 2), (False, 4), (True, 3)])
def test_a_glowing_closed_box_follows_the_bounce_series(infinite, bounces):
    """Every inward wall of a closed box emits L_e and reflects rho, nothing else lights it: the direct
    irradiance is pi L_e everywhere (every direction sees a glowing wall), and each bounce multiplies the
    whole field by rho, so a patch's indirect irradiance after k operator bounces is pi L_e (rho + ... +
    rho^k), and pi L_e rho / (1 - rho) with all of them (the closed form); the vertices' final gather adds
    one reflection (k + 1). Means within 3 % (the form factors' ray-cast row sums, 256 rays a patch). The
    vertex check takes the faces' interior vertices: at the box's edges the emitters' 1/d^2 is clamped
    (``light_bundles`` min_d2), which darkens vertices there (a bias of area lights, not of the bounces)."""
    rho, emission = 0.5, 2.0
    parts = box_parts(size=2.0, grid=4)
    scene = make_scene(parts, albedo=(rho,) * 3, emission=np.full((len(parts), 3), emission))
    tracer = Tracer.from_scene(scene)
    product = ff.FormFactors().run(Context(scene=scene, tracer=tracer, params=ff.FormFactors.Params(
        target_patches=96, rays=256, bounces=bounces, infinite=infinite))).products[FormFactorProduct]
    solved = rad.solve(tracer, scene, product, rad.Radiosity.Params(light_samples=64, gather_rays=256),
                       np.arange(scene.num_points))
    def series(k):
        return math.pi * emission * (rho / (1 - rho) if infinite else sum(rho ** j for j in range(1, k + 1)))
    areas = product.patches.patch_areas
    np.testing.assert_allclose(np.average(solved["patch_direct"][:, 0], weights=areas), math.pi * emission,
                               rtol=0.03)
    np.testing.assert_allclose(np.average(solved["patch_indirect"][:, 0], weights=areas), series(bounces), rtol=0.03)
    gathered = math.pi * emission * rho / (1 - rho) if infinite else series(bounces + 1)
    interior = ((scene.points > 0.01) & (scene.points < 1.99)).sum(axis=1) == 2  # off the box's edges
    np.testing.assert_allclose(solved["vertex_indirect"][interior, 0].mean(), gathered, rtol=0.03)
