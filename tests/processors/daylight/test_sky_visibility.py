"""Sky visibility: patch layouts (counts, solid angles, Radiance order), closed forms (open plane,
open-top box aperture), brute-force agreement on a sample, conforming refinement of receivers, closed
rooms never refined, degenerate and far-off geometry, and an end-to-end bake through USD."""

from repo_paths import SAMPLES
import math

import numpy as np
import pytest
from tolerances import (EXPOSURE_COMPARISON_SLACK, FLOAT32_ACCUMULATED, FLOAT32_LONG_CHAIN, FLOAT32_STORAGE,
                        FLOAT64_AMPLIFIED, FLOAT64_ROUNDING, MC_SIGMAS, SKY_PATCH_STRATIFICATION, SKY_VISIBILITY_RMS,
                        SPLIT_FACE_EXPOSURE, UINT8_HALF_STEP)
from usdbake.kernels.sky import (
    enu_to_world,
    patch_layout,
    patch_samples,
    reinhart_patches,
    uniform_patches,
)
from usdbake.processors.daylight.refine import boundary_edges, is_watertight, weld_points
from usdbake.core.scene import Scene
from usdbake.benchmarks.references import compute_point_sky_view
from usdbake.processors.daylight.patch_visibility import compute_patch_visibility
from usdbake.processors.daylight.sky_visibility import compute_sky_visibility
from usdbake.kernels.tracer import Tracer


# ---------------------------------------------------------------------------
# helpers


def make_scene(parts, *, up_axis="Z", writable=None) -> Scene:
    """A Scene from [(points (P, 3), triangles (T, 3)), ...], one prim per part, identity transforms."""
    points, tris, tri_prim, point_prim, starts, faces = [], [], [], [], [0], []
    for m, (p, t) in enumerate(parts):
        p = np.asarray(p, np.float32)
        t = np.asarray(t, np.int32)
        tris.append(t + starts[-1])
        points.append(p)
        tri_prim.append(np.full(len(t), m, np.int32))
        point_prim.append(np.full(len(p), m, np.int32))
        faces.append(np.arange(len(t), dtype=np.int32))
        starts.append(starts[-1] + len(p))
    points = np.concatenate(points)
    tris = np.concatenate(tris)
    c = points[tris].astype(np.float64)
    cross = np.cross(c[:, 1] - c[:, 0], c[:, 2] - c[:, 0])
    double = np.linalg.norm(cross, axis=1)
    normals = np.divide(cross, double[:, None], out=np.zeros_like(cross), where=double[:, None] > 0)
    n_prims = len(parts)
    return Scene(
        points=points, tri_vertices=tris, tri_normals=normals.astype(np.float32),
        tri_areas=(double / 2).astype(np.float32), tri_albedo=np.full((len(tris), 3), 0.5, np.float32),
        tri_emission=np.zeros((len(tris), 3), np.float32), tri_prim=np.concatenate(tri_prim),
        tri_face=np.concatenate(faces), tri_instance=np.full(len(tris), -1, np.int32),
        tri_double_sided=np.zeros(len(tris), bool), point_prim=np.concatenate(point_prim),
        prim_paths=tuple(f"/World/P{m}" for m in range(n_prims)), prim_point_start=np.array(starts, np.int64),
        prim_face_count=np.array([len(t) for _, t in parts], np.int32),
        prim_writable=np.ones(n_prims, bool) if writable is None else np.asarray(writable, bool),
        prim_skip=np.zeros(n_prims, bool), prim_surface=("",) * n_prims,
        prim_to_world=np.repeat(np.eye(4)[None], n_prims, axis=0), up_axis=up_axis,
    )


def quad(corners, flip=False):
    t = [[0, 1, 2], [0, 2, 3]]
    return np.asarray(corners, np.float32), np.asarray([r[::-1] for r in t] if flip else t)


def box(side, height, *, closed, inward=True, z0=0.0):
    """Box [-s/2, s/2]^2 x [z0, z0 + h] as 5 or 6 quads sharing 8 vertices, wound to face inward (or outward)."""
    a = side / 2
    points = np.array([[x, y, z] for z in (z0, z0 + height) for y in (-a, a) for x in (-a, a)], np.float32)
    quads = [[0, 1, 3, 2], [0, 4, 5, 1], [1, 5, 7, 3], [3, 7, 6, 2], [2, 6, 4, 0]]
    if closed:
        quads.append([4, 6, 7, 5])
    triangles = np.array([[q[0], q[1], q[2]] for q in quads] + [[q[0], q[2], q[3]] for q in quads], np.int32)
    return points, (triangles if inward else triangles[:, ::-1])


def corner_view_factor(a, b, h):
    """Differential area to a parallel a x b rectangle at height h above one corner (Howell B-3)."""
    A, B = a / h, b / h
    sa, sb = math.sqrt(1 + A * A), math.sqrt(1 + B * B)
    return (A / sa * math.atan(B / sa) + B / sb * math.atan(A / sb)) / (2 * math.pi)


# ---------------------------------------------------------------------------
# patch layouts


def radiance_reinhart(mf):
    """Radiance's reinhartb.cal / genskyvec expressions (x1 = x2 = .5), transcribed: bins 1..Rmax."""
    alpha = 90.0 / (mf * 7 + 0.5)
    tnaz = (30, 30, 24, 24, 18, 12, 6)

    def rnaz(r):
        return 1 if r > 7 * mf - 0.5 else mf * tnaz[int(math.floor((r + 0.5) / mf))]

    rows = []
    for r in range(7 * mf + 1):
        for col in range(rnaz(r)):
            rows.append((r, col))
    rah = math.radians(alpha)
    directions, omegas = [], []
    for index, (r, col) in enumerate(rows):
        width = 2 * math.pi / rnaz(r)
        azi = col * width
        alt = (r + 0.5) * rah
        last = index == len(rows) - 1
        omega = 2 * math.pi * (1 - math.cos(rah / 2)) if last else width * (math.sin(rah * (r + 1)) - math.sin(rah * r))
        directions.append((math.sin(azi) * math.cos(alt), math.cos(azi) * math.cos(alt), math.sin(alt)))
        omegas.append(omega)
    return np.array(directions), np.array(omegas)


@pytest.mark.parametrize("mf, count", [(1, 145), (2, 577), (4, 2305)])
def test_reinhart_layouts_match_radiance(mf, count):
    patches = reinhart_patches(mf)
    assert len(patches) == count
    directions, omegas = radiance_reinhart(mf)
    np.testing.assert_allclose(patches.patch_solid_angles, omegas, rtol=FLOAT64_ROUNDING)
    np.testing.assert_allclose(patches.patch_directions, directions, atol=FLOAT64_ROUNDING)
    np.testing.assert_allclose(patches.patch_solid_angles.sum(), 2 * np.pi, rtol=FLOAT64_ROUNDING)


def test_tregenza_known_patches():
    patches = patch_layout("tregenza")
    d = patches.patch_directions
    # Patch 1 (ours 0): horizon row, centred on north at 6 deg altitude; patch 2 is 12 deg towards east.
    np.testing.assert_allclose(d[0], [0, math.cos(math.radians(6)), math.sin(math.radians(6))], atol=FLOAT64_ROUNDING)
    np.testing.assert_allclose(np.degrees(np.arctan2(d[1, 0], d[1, 1])), 12.0, atol=FLOAT64_AMPLIFIED)
    # Row 2 starts at patch 31 (ours 30), 18 deg altitude; row 7 (6 patches) starts at 139 (ours 138); zenith last.
    np.testing.assert_allclose(np.degrees(np.arcsin(d[30, 2])), 18.0, atol=FLOAT64_AMPLIFIED)
    np.testing.assert_allclose(np.degrees(np.arcsin(d[138, 2])), 78.0, atol=FLOAT64_AMPLIFIED)
    np.testing.assert_allclose(d[144], [0, 0, 1], atol=FLOAT64_ROUNDING)
    # Tregenza's horizon-band patch: 2 pi / 30 * sin(12 deg) sr.
    np.testing.assert_allclose(patches.patch_solid_angles[0], 2 * np.pi / 30 * math.sin(math.radians(12)))


@pytest.mark.parametrize("count", [1, 2, 7, 64, 145, 256, 1024])
def test_uniform_layout_has_equal_solid_angles(count):
    patches = uniform_patches(count)
    assert len(patches) == count
    np.testing.assert_allclose(patches.patch_solid_angles, 2 * np.pi / count, rtol=FLOAT64_AMPLIFIED)
    # Sample directions of each patch lie within its angular radius of the centre (the horizon test relies on it).
    samples = patch_samples(patches, 5)
    cos = np.einsum("nkc,nc->nk", samples, patches.patch_directions)
    assert (np.arccos(np.clip(cos, -1, 1)) <= patches.patch_radius[:, None]).all()


def test_up_axis_frames_are_right_handed():
    for up, expected_up, expected_north in (("Z", [0, 0, 1], [0, 1, 0]), ("Y", [0, 1, 0], [0, 0, -1])):
        m = enu_to_world(up)
        np.testing.assert_allclose(np.linalg.det(m), 1.0)
        np.testing.assert_allclose(m @ [0, 0, 1], expected_up, atol=FLOAT64_ROUNDING)
        np.testing.assert_allclose(m @ [0, 1, 0], expected_north, atol=FLOAT64_ROUNDING)


# ---------------------------------------------------------------------------
# visibility factors: closed forms


def test_open_upward_plane_sees_the_whole_sky():
    scene = make_scene([quad([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]])])
    tracer = Tracer.from_scene(scene)
    patches = uniform_patches(256)
    v, partial = compute_patch_visibility(tracer, scene.points[scene.tri_vertices], scene.tri_normals, patches,
                                          enu_to_world("Z"), samples=16)
    # For a ring patch, mean cos over the patch is exactly (z_lo + z_hi) / 2; each sample lies inside it.
    z_lo, z_hi = patches.patch_bounds[:, 0], patches.patch_bounds[:, 1]
    assert ((v >= z_lo - FLOAT32_STORAGE) & (v <= z_hi + FLOAT32_STORAGE)).all()
    assert not partial.any()
    # Irradiance under a uniform sky L: pi L (stratified z: per-patch error <= dz / 8, they average out).
    irradiance = v.astype(np.float64) @ patches.patch_solid_angles
    np.testing.assert_allclose(irradiance, np.pi, rtol=SKY_PATCH_STRATIFICATION)


def test_floor_of_open_top_box_sees_the_aperture_view_factor():
    side, height = 2.0, 1.0
    probe = quad([[-0.01, -0.01, 0.001], [0.01, -0.01, 0.001], [0.01, 0.01, 0.001], [-0.01, 0.01, 0.001]])
    scene = make_scene([box(side, height, closed=False), probe])
    tracer = Tracer.from_scene(scene)
    product, _ = compute_sky_visibility(tracer, scene, patches=uniform_patches(256), samples=64, adaptive=False,
                                        prims=np.array([1]))
    expected = 4 * corner_view_factor(side / 2, side / 2, height)  # 0.553 for a 2 x 2 x 1 box
    # MC: 2 triangles x 256 patches x 64 rays; stratified and quantized to 1/255 per factor.
    tol = MC_SIGMAS * math.sqrt(expected * (1 - expected) / (2 * 256 * 64)) + UINT8_HALF_STEP
    np.testing.assert_allclose(product.exposure, expected, atol=tol)
    # The brute-force point reference agrees too (4096 cosine-weighted rays).
    view = compute_point_sky_view(tracer, [[0, 0, 0.001]], [[0, 0, 1]], scene.up_vector, samples=4096)
    np.testing.assert_allclose(view, expected, atol=MC_SIGMAS * math.sqrt(expected * (1 - expected) / 4096))


# ---------------------------------------------------------------------------
# adaptive refinement


def occluded_ground():
    """A 4 x 4 ground (receiver, 2 triangles) with a closed 1 x 1 x 1 box standing on it (occluder)."""
    ground = quad([[-2, -2, 0], [2, -2, 0], [2, 2, 0], [-2, 2, 0]])
    return make_scene([ground, box(1.0, 1.0, closed=True, inward=False, z0=0.0)], writable=[True, False])


def test_refinement_concentrates_where_visibility_is_partial():
    scene = occluded_ground()
    tracer = Tracer.from_scene(scene)
    product, stats = compute_sky_visibility(tracer, scene, patches=uniform_patches(64), samples=4, max_level=4,
                                            tolerance=0.05)
    assert stats["triangles_out"] > 4 * stats["triangles_in"]
    assert (product.face_prim == 0).all()  # the non-writable occluder is not refined
    centroid = product.face_points[product.face_vertices].mean(axis=1)
    ring = np.abs(centroid[:, :2]).max(axis=1)
    near = (ring > 0.5) & (ring < 0.75)  # just outside the box's foot
    corners = product.face_points[product.face_vertices][:, :, :2]
    corner = (np.abs(corners) == 2.0).all(axis=2).any(axis=1)  # faces touching a corner of the ground
    # Faces along the box's foot reach the finest level (8 / 4^4); the far corners stay coarser.
    np.testing.assert_allclose(product.face_areas[near], 8.0 / 4 ** 4, rtol=FLOAT32_ACCUMULATED)
    assert product.face_areas[corner].mean() > 2 * product.face_areas[near].mean()
    np.testing.assert_allclose(product.face_areas.sum(), 16.0, rtol=FLOAT32_STORAGE)
    # Conforming: a T-junction would leave an edge used once inside the ground; all such edges lie on its rim.
    rim = product.face_points[boundary_edges(product.face_vertices, np.arange(len(product.face_points))).ravel()]
    assert np.isclose(np.abs(rim[:, :2]).max(axis=1), 2.0).all()


def test_closed_room_interior_is_never_refined_and_watertight_box_stays_watertight():
    room = box(2.0, 2.0, closed=True, inward=True)
    shell = box(2.2, 2.2, closed=True, inward=False, z0=-0.1)
    tower = box(1.0, 6.0, closed=True, inward=False, z0=-0.1)
    tower = (tower[0] + np.array([2.0, 0.0, 0.0], np.float32), tower[1])  # casts onto the shell's top and side
    ground = quad([[-5, -5, -0.1], [5, -5, -0.1], [5, 5, -0.1], [-5, 5, -0.1]])
    scene = make_scene([room, shell, tower, ground], writable=[True, True, False, False])
    tracer = Tracer.from_scene(scene)
    product, _ = compute_sky_visibility(tracer, scene, patches=uniform_patches(64), samples=4, max_level=3)
    inside = product.face_prim == 0
    assert inside.sum() == 12  # no sky inside a closed room: nothing to refine
    assert (product.visibility[inside] == 0).all()
    shell_faces = product.face_prim == 1
    assert shell_faces.sum() > 12  # the tower hides part of the shell's sky
    weld = weld_points(product.face_points)
    assert is_watertight(product.face_vertices[shell_faces], weld)


def test_matches_brute_force_reference_on_window_room():
    """The issue's accuracy figure at default settings, on the window room (fast enough for the default run)."""
    from pxr import Usd
    from usdbake.stages.extract import extract_scene

    scene = extract_scene(Usd.Stage.Open(str(SAMPLES / "window_room.usda")))
    tracer = Tracer.from_scene(scene)
    product, _ = compute_sky_visibility(tracer, scene, patches=uniform_patches(256))
    centroid = product.face_points[product.face_vertices].mean(axis=1)
    reference = compute_point_sky_view(tracer, centroid, product.face_normals, scene.up_vector, samples=4096, seed=11)
    estimate = product.visibility_float() @ product.patches.patch_solid_angles.astype(np.float32) / np.pi
    a = product.face_areas
    relative_rms = math.sqrt((a * (estimate - reference) ** 2).sum() / (a * reference ** 2).sum())
    assert relative_rms < SKY_VISIBILITY_RMS, relative_rms


def test_results_do_not_depend_on_thread_count():
    scene = occluded_ground()
    patches = uniform_patches(64)
    one, _ = compute_sky_visibility(Tracer.from_scene(scene, threads=1), scene, patches=patches, max_level=2)
    two, _ = compute_sky_visibility(Tracer.from_scene(scene, threads=2), scene, patches=patches, max_level=2)
    np.testing.assert_array_equal(one.visibility, two.visibility)
    np.testing.assert_array_equal(one.face_vertices, two.face_vertices)


def test_degenerate_triangles_and_far_coordinates_give_finite_output():
    offset = np.array([1e6, -2e6, 5e5], np.float32)
    ground = quad([[-2, -2, 0], [2, -2, 0], [2, 2, 0], [-2, 2, 0]])
    sliver = (np.array([[0, 0, 0.5], [1, 0, 0.5], [2, 0, 0.5]], np.float32), np.array([[0, 1, 2]]))  # zero area
    scene = make_scene([ground, sliver, box(1.0, 1.0, closed=True, inward=False)])
    # The Scene stores points relative to its origin, so the far-off frame only enters through ``origin``.
    scene = Scene(**{**scene.__dict__, "origin": offset.astype(np.float64)})
    tracer = Tracer.from_scene(scene)
    product, _ = compute_sky_visibility(tracer, scene, patches=uniform_patches(64), max_level=3)
    assert np.isfinite(product.face_points).all() and np.isfinite(product.exposure).all()
    assert (product.visibility[product.face_prim == 1] == 0).all()  # the sliver has no normal: V = 0


# ---------------------------------------------------------------------------
# end to end through USD


def test_bake_authors_refined_mesh_in_local_space():
    import usdbake
    from pxr import Usd, UsdGeom
    from stage_builders import add_mesh, add_xform, new_stage

    stage = new_stage(up_axis="Z")
    # A mirrored, rotated, far-off ground and a box on it: local points must round-trip, faces face up.
    add_xform(stage, "/World/Site", translate=(1e6, 2e6, 0), rotate_xyz=(0, 0, 30), scale=(-1, 1, 1))
    add_mesh(stage, "/World/Site/Ground", [(-4, -4, 0), (4, -4, 0), (4, 4, 0), (-4, 4, 0)], [4], [0, 1, 2, 3])
    pts, tris = box(3.0, 2.0, closed=True, inward=False)
    add_mesh(stage, "/World/Site/Box", pts.tolist(), [3] * len(tris), tris.ravel().tolist())
    usdbake.bake(stage, ["sky_visibility"], {"sky_visibility": {"patch_count": 64, "max_level": 3}})
    baked = stage
    mesh = UsdGeom.Mesh(baked.GetPrimAtPath("/World/Site/Ground"))
    points = np.array(mesh.GetPointsAttr().Get())
    indices = np.array(mesh.GetFaceVertexIndicesAttr().Get()).reshape(-1, 3)
    assert len(indices) > 2
    # Local space: the original corners are still there, in the authored frame, and all points lie on z = 0.
    for corner in [(-4, -4, 0), (4, 4, 0)]:
        assert np.min(np.linalg.norm(points - corner, axis=1)) < FLOAT32_LONG_CHAIN
    np.testing.assert_allclose(points[:, 2], 0.0, atol=FLOAT32_LONG_CHAIN)
    # Winding: the authored faces keep facing up (+Z) through orientation rightHanded and the mirroring
    # transform (a mirror turns the transformed winding's cross product around, hence the determinant's sign).
    world = np.array(UsdGeom.Xformable(mesh).ComputeLocalToWorldTransform(Usd.TimeCode.Default()))
    c = np.c_[points, np.ones(len(points))] @ world
    n = np.cross(c[indices[:, 1], :3] - c[indices[:, 0], :3], c[indices[:, 2], :3] - c[indices[:, 0], :3])
    assert (n[:, 2] * np.sign(np.linalg.det(world[:3, :3])) > 0).all()
    assert mesh.GetOrientationAttr().Get() == UsdGeom.Tokens.rightHanded
    primvars = UsdGeom.PrimvarsAPI(mesh)
    vis = primvars.GetPrimvar("bake:skyVisibility")
    assert vis.GetInterpolation() == "uniform" and vis.GetElementSize() == 64
    assert len(vis.Get()) == 64 * len(indices)
    source_face = primvars.GetPrimvar("bake:sourceFace")
    assert set(np.array(source_face.Get()).tolist()) == {0}
    exposure = np.array(primvars.GetPrimvar("bake:skyExposure").Get())
    assert exposure.shape == (len(indices),) and np.isfinite(exposure).all() and exposure.max() <= 1.0
    prim = mesh.GetPrim()
    assert "SkyVisibilityAPI" in prim.GetAppliedSchemas()
    assert prim.GetAttribute("bake:sky:patchCount").Get() == 64
    assert abs(sum(prim.GetAttribute("bake:sky:patchSolidAngles").Get()) - 2 * math.pi) < FLOAT32_LONG_CHAIN
    ok, reason = UsdGeom.Mesh.ValidateTopology(mesh.GetFaceVertexIndicesAttr().Get(),
                                               mesh.GetFaceVertexCountsAttr().Get(), len(points))
    assert ok, reason
    # The closed box is authored back watertight (its faces are split for size before tracing, conformingly).
    box_mesh = UsdGeom.Mesh(baked.GetPrimAtPath("/World/Site/Box"))
    bp = np.array(box_mesh.GetPointsAttr().Get())
    bi = np.array(box_mesh.GetFaceVertexIndicesAttr().Get()).reshape(-1, 3)
    assert len(bi) > 12 and is_watertight(bi, weld_points(bp))


def courtyard_scene():
    """A 20 x 20 m floor of two triangles at the bottom of a 30 m deep courtyard (Z-up): the floor sees
    a small share of the sky through the opening, and each of its two faces is 200 m^2."""
    from pxr import Usd, UsdGeom
    from usdbake.stages.extract import extract_scene

    stage = Usd.Stage.CreateInMemory()
    UsdGeom.SetStageUpAxis(stage, "Z")
    w, h = 20.0, 30.0
    quads = [[(0, 0, 0), (w, 0, 0), (w, w, 0), (0, w, 0)],  # floor, up
             [(w, 0, 0), (0, 0, 0), (0, 0, h), (w, 0, h)], [(0, w, 0), (w, w, 0), (w, w, h), (0, w, h)],
             [(0, 0, 0), (0, w, 0), (0, w, h), (0, 0, h)], [(w, w, 0), (w, 0, 0), (w, 0, h), (w, w, h)]]
    for k, quad in enumerate(quads):
        mesh = UsdGeom.Mesh.Define(stage, f"/World/Part_{k}")
        mesh.CreatePointsAttr(quad)
        mesh.CreateFaceVertexCountsAttr([3, 3])
        mesh.CreateFaceVertexIndicesAttr([0, 1, 2, 0, 2, 3])
    return extract_scene(stage)


def test_large_faces_are_split_before_tracing_and_match_a_reference():
    scene = courtyard_scene()
    tracer = Tracer.from_scene(scene)
    floor = 0
    rng = np.random.default_rng(3)
    points = np.c_[rng.uniform(0, 20, (2048, 2)), np.zeros(2048)] - scene.origin
    reference = float(compute_point_sky_view(tracer, points, np.tile([0, 0, 1.0], (2048, 1)), scene.up_vector,
                                             samples=4096).mean())
    estimates = {}
    for cap in (0.0, 1e-3):
        product, _ = compute_sky_visibility(tracer, scene, patches=uniform_patches(256), samples=4, adaptive=False,
                                            max_face_area=cap)
        faces = product.face_prim == floor
        areas = product.face_areas[faces].astype(np.float64)
        estimates[cap] = float((product.exposure[faces] * areas).sum() / areas.sum())
        if cap:
            assert product.face_areas.max() <= cap * scene.diagonal ** 2
            assert faces.sum() >= 200 / (cap * scene.diagonal ** 2)
    assert 0.02 < reference < 0.2
    # measured: reference 0.1107; split into 512 faces 0.1108; whole (2 faces, 4 points per patch) 0.1003
    assert abs(estimates[1e-3] - reference) < SPLIT_FACE_EXPOSURE * reference
    assert abs(estimates[1e-3] - reference) < abs(estimates[0.0] - reference) + EXPOSURE_COMPARISON_SLACK * reference
