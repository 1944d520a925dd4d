"""Stage -> Scene: triangulation, transforms, winding, instancing, visibility,
materials, lights, units, errors and the samples, on small in-memory stages.

The oracle for transforms is UsdGeom.XformCache / Gf, evaluated in the test;
Scene stores positions relative to ``scene.origin`` (world = origin + points).
"""

from repo_paths import SAMPLES
import re
import warnings
from pathlib import Path

import numpy as np
import pytest
from pxr import Gf, Sdf, Usd, UsdGeom, UsdLux, UsdShade, Vt
from stage_builders import (TETRA_COUNTS, TETRA_INDICES, TETRA_POINTS, UNIT_QUAD, add_mesh, add_preview_material,
                            add_quads, add_xform, bind, new_stage, world_points, write_png)
from tolerances import FLOAT32_ACCUMULATED, FLOAT32_STORAGE, FLOAT64_AMPLIFIED

from usdbake.core.scene import (LIGHT_DISK, LIGHT_DISTANT, LIGHT_DOME, LIGHT_RECT, LIGHT_SPHERE,
                                      Scene)
from usdbake.core.errors import StageError
from usdbake.stages.extract import extract_scene

SAMPLES_DIR = SAMPLES  # noqa: the name the tests here use


def prim_index(scene: Scene, path: str) -> int:
    return scene.prim_paths.index(path)


def prim_tris(scene: Scene, path: str) -> np.ndarray:
    return np.flatnonzero(scene.tri_prim == prim_index(scene, path))


def scene_world_points(scene: Scene, path: str) -> np.ndarray:
    return scene.origin + scene.points[scene.prim_points(prim_index(scene, path))].astype(np.float64)


# --- triangle counts and faces ----------------------------------------------------------------


def test_quads_give_two_triangles_each():
    stage = new_stage()
    add_quads(stage, "/World/Quads", count=3)
    scene = extract_scene(stage)
    assert scene.num_triangles == 6
    np.testing.assert_array_equal(scene.tri_face, [0, 0, 1, 1, 2, 2])
    np.testing.assert_array_equal(scene.prim_face_count, [3])
    np.testing.assert_allclose(scene.tri_areas, 0.5, rtol=FLOAT32_STORAGE)
    assert scene.warnings == ()


def test_mixed_faces_map_triangles_to_source_faces():
    stage = new_stage()
    pentagon = [(3, 0, 0), (4, 0, 0), (4.5, 1, 0), (3.5, 2, 0), (2.5, 1, 0)]
    points = UNIT_QUAD + pentagon + [(6, 0, 0), (7, 0, 0), (6, 1, 0)]
    add_mesh(stage, "/World/M", points, [4, 5, 3], [0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11])
    scene = extract_scene(stage)
    assert scene.num_triangles == 2 + 3 + 1
    np.testing.assert_array_equal(scene.tri_face, [0, 0, 1, 1, 1, 2])
    # Pentagon area by the shoelace formula: 2.5; the quad 1, the triangle 0.5.
    per_face = np.bincount(scene.tri_face, weights=scene.tri_areas)
    np.testing.assert_allclose(per_face, [1.0, 2.5, 0.5], rtol=FLOAT32_STORAGE)
    # Each triangle only uses its face's vertices.
    face_vertices = [set(range(0, 4)), set(range(4, 9)), set(range(9, 12))]
    for tri, face in zip(scene.tri_vertices, scene.tri_face):
        assert set(tri.tolist()) <= face_vertices[face]


def test_hole_faces_are_skipped_with_a_warning():
    stage = new_stage()
    add_quads(stage, "/World/Holey", count=3, holeIndices=Vt.IntArray([1]))
    scene = extract_scene(stage)
    np.testing.assert_array_equal(scene.tri_face, [0, 0, 2, 2])
    np.testing.assert_array_equal(scene.prim_face_count, [3])
    assert any("/World/Holey" in w and "hole" in w for w in scene.warnings), scene.warnings


def test_faces_with_fewer_than_three_vertices_warn():
    stage = new_stage()
    add_mesh(stage, "/World/M", UNIT_QUAD, [2, 4], [0, 1, 0, 1, 2, 3])
    scene = extract_scene(stage)
    np.testing.assert_array_equal(scene.tri_face, [1, 1])
    assert any("/World/M" in w and "fewer than 3" in w for w in scene.warnings), scene.warnings


# --- transforms -------------------------------------------------------------------------------


def test_nested_transforms_match_xform_cache():
    stage = new_stage()
    add_xform(stage, "/World/Parent", translate=(1, 2, 3), rotate_xyz=(10, 20, 30), scale=(2, 1, 0.5))
    add_xform(stage, "/World/Parent/Child", translate=(-1, 0.5, 2), rotate_xyz=(0, 45, -15), scale=(1, 3, 1))
    mesh = add_mesh(stage, "/World/Parent/Child/Mesh", UNIT_QUAD + [(0.5, 0.5, 1)], [4, 3], [0, 1, 2, 3, 0, 1, 4])
    mesh.AddTranslateOp().Set(Gf.Vec3d(0.25, 0, -0.5))
    add_quads(stage, "/World/Plain")
    scene = extract_scene(stage)

    for path in ("/World/Parent/Child/Mesh", "/World/Plain"):
        np.testing.assert_allclose(scene_world_points(scene, path), world_points(stage, path), atol=FLOAT32_ACCUMULATED)
    # Areas follow the transformed geometry (non-uniform scale included).
    oracle = world_points(stage, "/World/Parent/Child/Mesh")
    corners = oracle[[[0, 1, 2], [0, 2, 3], [0, 1, 4]]]
    areas = 0.5 * np.linalg.norm(np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]), axis=1)
    np.testing.assert_allclose(scene.tri_areas[prim_tris(scene, "/World/Parent/Child/Mesh")], areas,
                               rtol=FLOAT32_ACCUMULATED)


def test_time_samples_are_read_at_the_requested_time():
    stage = new_stage()
    mesh = add_quads(stage, "/World/Q")
    op = mesh.AddTranslateOp()
    op.Set(Gf.Vec3d(0, 0, 0), 1.0)
    op.Set(Gf.Vec3d(0, 0, 10), 2.0)
    at_two = extract_scene(stage, time=2.0)
    assert at_two.time_code == 2.0
    np.testing.assert_allclose(scene_world_points(at_two, "/World/Q")[:, 2], 10.0, atol=FLOAT32_ACCUMULATED)


def test_big_coordinates_are_absorbed_by_the_origin():
    far = np.array([1e6, -2e6, 3e6])
    local = np.array(UNIT_QUAD + [(0.5, 0.5, 1e-3)], np.float64)  # a 1 mm bump
    stage = new_stage()
    mesh = add_mesh(stage, "/World/Far", local, [4, 3], [0, 1, 2, 3, 0, 1, 4])
    mesh.AddTranslateOp().Set(Gf.Vec3d(*far))
    scene = extract_scene(stage)

    center = far + (local.min(axis=0) + local.max(axis=0)) / 2
    np.testing.assert_allclose(scene.origin, center, rtol=0, atol=FLOAT64_AMPLIFIED)
    assert scene.origin.dtype == np.float64
    assert np.abs(scene.points).max() <= 0.5 + FLOAT32_STORAGE
    np.testing.assert_allclose(scene.points, local + far - scene.origin, atol=FLOAT32_STORAGE)
    np.testing.assert_allclose(scene.points[4] - scene.points[0], [0.5, 0.5, 1e-3], atol=FLOAT32_STORAGE)
    np.testing.assert_allclose(scene.tri_areas[:2], 0.5, rtol=FLOAT32_STORAGE)


# --- winding ----------------------------------------------------------------------------------


@pytest.mark.parametrize("left_handed", [False, True], ids=["rightHanded", "leftHanded"])
@pytest.mark.parametrize("mirror", [False, True], ids=["plain", "mirrored"])
def test_winding_follows_orientation_and_determinant(left_handed, mirror):
    """Winding is reversed for leftHanded XOR a negative-determinant transform (as Hydra does).

    Quad in the xy plane, mirrored through it (scale z = -1): its front face
    is +z, -z when leftHanded or mirrored, +z again when both. A closed
    tetrahedron authored outward keeps outward normals under the mirror and
    turns inward only when declared leftHanded.
    """
    orientation = UsdGeom.Tokens.leftHanded if left_handed else UsdGeom.Tokens.rightHanded
    stage = new_stage()
    add_xform(stage, "/World/Box", translate=(3, 1, 2), scale=(1, 1, -1) if mirror else None)
    add_quads(stage, "/World/Box/Quad", orientation=orientation)
    add_mesh(stage, "/World/Box/Tetra", TETRA_POINTS, TETRA_COUNTS, TETRA_INDICES, orientation=orientation)
    scene = extract_scene(stage)
    flipped = left_handed != mirror

    quad = prim_tris(scene, "/World/Box/Quad")
    np.testing.assert_allclose(scene.tri_normals[quad], [[0, 0, -1 if flipped else 1]] * 2, atol=FLOAT32_STORAGE)

    tetra = prim_tris(scene, "/World/Box/Tetra")
    authored = np.reshape(TETRA_INDICES, (-1, 3)) + scene.prim_point_start[prim_index(scene, "/World/Box/Tetra")]
    np.testing.assert_array_equal(scene.tri_vertices[tetra], authored[:, ::-1] if flipped else authored)
    corners = scene.points[scene.tri_vertices[tetra]].astype(np.float64)
    solid_center = scene.points[scene.prim_points(prim_index(scene, "/World/Box/Tetra"))].mean(axis=0)
    outward = np.einsum("tc,tc->t", scene.tri_normals[tetra], corners.mean(axis=1) - solid_center)
    assert (np.sign(outward) == (-1 if left_handed else 1)).all(), outward


# --- instancing -------------------------------------------------------------------------------


def build_point_instancer(stage: Usd.Stage, invisible_ids=None):
    """An instancer with a triangle and a (transformed) quad prototype and 5 instances."""
    inst = UsdGeom.PointInstancer.Define(stage, "/World/Inst")
    inst.AddTranslateOp().Set(Gf.Vec3d(10, 0, 0))
    inst.AddRotateZOp().Set(90.0)
    add_mesh(stage, "/World/Inst/Protos/Tri", [(0, 0, 0), (1, 0, 0), (0, 1, 0)], [3], [0, 1, 2])
    add_xform(stage, "/World/Inst/Protos/Quad", translate=(0, 0, 1))
    add_quads(stage, "/World/Inst/Protos/Quad/Mesh").AddTranslateOp().Set(Gf.Vec3d(0.5, 0, 0))
    inst.CreatePrototypesRel().SetTargets([Sdf.Path("/World/Inst/Protos/Tri"), Sdf.Path("/World/Inst/Protos/Quad")])
    inst.CreateProtoIndicesAttr([0, 1, 1, 0, 1])
    inst.CreatePositionsAttr([Gf.Vec3f(3 * i, i, 0) for i in range(5)])
    inst.CreateOrientationsAttr([Gf.Quath(Gf.Rotation(Gf.Vec3d(0, 0, 1), 30 * i).GetQuat()) for i in range(5)])
    inst.CreateScalesAttr([Gf.Vec3f(1 + i, 1, 1) for i in range(5)])
    if invisible_ids is not None:
        inst.CreateInvisibleIdsAttr(invisible_ids)
    add_quads(stage, "/World/Ground")
    return inst


def expected_instance_matrices(inst: UsdGeom.PointInstancer, rows) -> list:
    """prototype xform * scale * orientation * position * instancer world (row vectors, as Gf)."""
    stage = inst.GetPrim().GetStage()
    cache = UsdGeom.XformCache()
    instancer_world = cache.GetLocalToWorldTransform(inst.GetPrim())
    targets = inst.GetPrototypesRel().GetTargets()
    proto_indices = inst.GetProtoIndicesAttr().Get()
    positions, orientations, scales = (inst.GetPositionsAttr().Get(), inst.GetOrientationsAttr().Get(),
                                       inst.GetScalesAttr().Get())
    matrices = []
    for i in rows:
        proto_local = cache.GetLocalTransformation(stage.GetPrimAtPath(targets[proto_indices[i]]))[0]
        instance = (Gf.Matrix4d().SetScale(Gf.Vec3d(scales[i]))
                    * Gf.Matrix4d().SetRotate(Gf.Quatd(orientations[i]))
                    * Gf.Matrix4d().SetTranslate(Gf.Vec3d(positions[i])))
        matrices.append(np.array(proto_local * instance * instancer_world))
    return matrices


@pytest.mark.parametrize("invisible_ids, rows", [(None, [0, 1, 2, 3, 4]), ([2], [0, 1, 3, 4])],
                         ids=["all", "invisibleIds"])
def test_point_instancer(invisible_ids, rows):
    stage = new_stage()
    inst = build_point_instancer(stage, invisible_ids)
    scene = extract_scene(stage)
    instances = scene.instances
    proto_indices = np.array([0, 1, 1, 0, 1])[rows]
    targets = ["/World/Inst/Protos/Tri", "/World/Inst/Protos/Quad"]

    assert len(instances) == len(rows)
    assert instances.instancer_paths == ("/World/Inst",)
    np.testing.assert_array_equal(instances.instance_instancer, 0)
    assert [instances.prototype_paths[p] for p in instances.instance_prototype] == [targets[p] for p in proto_indices]

    expected = np.array(expected_instance_matrices(inst, rows))
    expected[:, 3, :3] -= scene.origin
    np.testing.assert_allclose(instances.instance_transforms, expected, atol=FLOAT64_AMPLIFIED)

    # Flattened: one triangle per Tri instance, two per Quad instance, plus the ground quad.
    tris_per_proto = np.array([1, 2])
    instanced = scene.tri_instance >= 0
    assert instanced.sum() == tris_per_proto[proto_indices].sum()
    assert scene.num_triangles == instanced.sum() + 2
    np.testing.assert_array_equal(np.bincount(scene.tri_instance[instanced]), tris_per_proto[proto_indices])
    mesh_paths = ["/World/Inst/Protos/Tri", "/World/Inst/Protos/Quad/Mesh"]
    assert sorted(scene.prim_paths) == sorted([mesh_paths[p] for p in proto_indices] + ["/World/Ground"])

    ground = prim_index(scene, "/World/Ground")
    assert scene.prim_writable[ground] and (scene.tri_instance[scene.tri_prim == ground] == -1).all()
    cache = UsdGeom.XformCache()
    for instance, (proto, matrix) in enumerate(zip(proto_indices, expected_instance_matrices(inst, rows))):
        prims = np.unique(scene.tri_prim[scene.tri_instance == instance])
        assert len(prims) == 1 and not scene.prim_writable[prims[0]]
        assert scene.prim_paths[prims[0]] == mesh_paths[proto]
        mesh_prim = stage.GetPrimAtPath(mesh_paths[proto])
        relative = np.array(cache.ComputeRelativeTransform(mesh_prim, stage.GetPrimAtPath(targets[proto]))[0])
        local = np.array(UsdGeom.Mesh(mesh_prim).GetPointsAttr().Get(), np.float64)
        world = np.c_[local, np.ones(len(local))] @ relative @ matrix
        extracted = scene.origin + scene.points[scene.prim_points(prims[0])]
        np.testing.assert_allclose(extracted, world[:, :3], atol=FLOAT32_ACCUMULATED)


def test_instanceable_references_are_read_only_proxies():
    stage = new_stage()
    stage.CreateClassPrim("/Classes/Chair")
    add_quads(stage, "/Classes/Chair/Seat")
    for name, x in (("A", 0), ("B", 5)):
        prim = add_xform(stage, f"/World/{name}", translate=(x, 0, 1)).GetPrim()
        prim.GetReferences().AddInternalReference("/Classes/Chair")
        prim.SetInstanceable(True)
    add_quads(stage, "/World/Floor")
    scene = extract_scene(stage)

    assert sorted(scene.prim_paths) == ["/World/A/Seat", "/World/B/Seat", "/World/Floor"]
    for path in ("/World/A/Seat", "/World/B/Seat"):
        assert stage.GetPrimAtPath(path).IsInstanceProxy()
        assert not scene.prim_writable[prim_index(scene, path)]
        np.testing.assert_allclose(scene_world_points(scene, path), world_points(stage, path), atol=FLOAT32_ACCUMULATED)
    assert scene.prim_writable[prim_index(scene, "/World/Floor")]
    # each native instance is an instance of the one prototype (what it references), its root its 'instancer'
    instances = scene.instances
    assert instances.instancer_paths == ("/World/A", "/World/B") and instances.instancer_native.tolist() == [True] * 2
    assert instances.prototype_paths == ("/Classes/Chair",)
    assert instances.targets(0) == ("/World/A", "/World/B")
    for path, instance in (("/World/A/Seat", 0), ("/World/B/Seat", 1)):
        assert set(scene.tri_instance[scene.tri_prim == prim_index(scene, path)]) == {instance}
        assert scene.prim_instance_roots[prim_index(scene, path)] == (path.rsplit("/", 1)[0],)
        expected = np.array(UsdGeom.Xformable(stage.GetPrimAtPath(path.rsplit("/", 1)[0]))
                            .ComputeLocalToWorldTransform(Usd.TimeCode.Default()))
        expected[3, :3] -= scene.origin
        np.testing.assert_allclose(instances.instance_transforms[instance], expected)
    assert set(scene.tri_instance[scene.tri_prim == prim_index(scene, "/World/Floor")]) == {-1}


# --- visibility, purpose, active --------------------------------------------------------------


def test_only_visible_active_renderable_prims_are_extracted():
    stage = new_stage()
    add_quads(stage, "/World/Visible")
    add_quads(stage, "/World/Render").CreatePurposeAttr(UsdGeom.Tokens.render)
    add_xform(stage, "/World/Hidden").CreateVisibilityAttr(UsdGeom.Tokens.invisible)
    add_quads(stage, "/World/Hidden/Child")
    add_quads(stage, "/World/InvisibleMesh").CreateVisibilityAttr(UsdGeom.Tokens.invisible)
    add_quads(stage, "/World/Guide").CreatePurposeAttr(UsdGeom.Tokens.guide)
    add_quads(stage, "/World/Proxy").CreatePurposeAttr(UsdGeom.Tokens.proxy)
    add_xform(stage, "/World/GuideGroup").CreatePurposeAttr(UsdGeom.Tokens.guide)
    add_quads(stage, "/World/GuideGroup/Child")  # inherits purpose guide
    add_quads(stage, "/World/Inactive").GetPrim().SetActive(False)
    add_xform(stage, "/World/InactiveGroup")
    add_quads(stage, "/World/InactiveGroup/Child")
    stage.GetPrimAtPath("/World/InactiveGroup").SetActive(False)
    scene = extract_scene(stage)
    assert sorted(scene.prim_paths) == ["/World/Render", "/World/Visible"]
    assert scene.num_triangles == 4


# --- materials --------------------------------------------------------------------------------


def test_materials_display_color_and_default_grey():
    stage = new_stage()
    red = add_preview_material(stage, "/World/Looks/Red", diffuse=(0.8, 0.1, 0.2), emissive=(2.0, 3.0, 4.0))
    glow = add_preview_material(stage, "/World/Looks/Glow", emissive=(1.0, 0.0, 0.5))
    bind(add_quads(stage, "/World/Red").GetPrim(), red)
    bind(add_quads(stage, "/World/Glow").GetPrim(), glow)
    add_quads(stage, "/World/Painted").CreateDisplayColorAttr([Gf.Vec3f(0.2, 0.4, 0.6)])
    add_quads(stage, "/World/Plain")
    scene = extract_scene(stage)

    def shading(path):
        tris = prim_tris(scene, path)
        return scene.tri_albedo[tris], scene.tri_emission[tris]

    expected = {
        "/World/Red": ((0.8, 0.1, 0.2), (2.0, 3.0, 4.0)),
        "/World/Glow": ((0.18, 0.18, 0.18), (1.0, 0.0, 0.5)),  # UsdPreviewSurface's diffuseColor default
        "/World/Painted": ((0.2, 0.4, 0.6), (0, 0, 0)),
        "/World/Plain": ((0.5, 0.5, 0.5), (0, 0, 0)),
    }
    for path, (albedo, emission) in expected.items():
        got_albedo, got_emission = shading(path)
        np.testing.assert_allclose(got_albedo, [albedo] * 2, atol=FLOAT32_STORAGE, err_msg=path)
        np.testing.assert_allclose(got_emission, [emission] * 2, atol=FLOAT32_STORAGE, err_msg=path)
    assert scene.prim_surface[prim_index(scene, "/World/Red")] == "/World/Looks/Red/Surface"
    assert scene.prim_surface[prim_index(scene, "/World/Plain")] == ""


def test_material_bound_to_a_geom_subset_overrides_its_faces():
    stage = new_stage()
    red = add_preview_material(stage, "/World/Looks/Red", diffuse=(0.8, 0.1, 0.2), emissive=(1, 1, 1))
    blue = add_preview_material(stage, "/World/Looks/Blue", diffuse=(0.1, 0.2, 0.9))
    mesh = add_quads(stage, "/World/M", count=3)
    bind(mesh.GetPrim(), red)
    subset = UsdShade.MaterialBindingAPI(mesh.GetPrim()).CreateMaterialBindSubset("blue", Vt.IntArray([1]))
    bind(subset.GetPrim(), blue)
    scene = extract_scene(stage)

    np.testing.assert_array_equal(scene.tri_face, [0, 0, 1, 1, 2, 2])
    red_rgb, blue_rgb = (0.8, 0.1, 0.2), (0.1, 0.2, 0.9)
    np.testing.assert_allclose(scene.tri_albedo, [red_rgb] * 2 + [blue_rgb] * 2 + [red_rgb] * 2, atol=FLOAT32_STORAGE)
    np.testing.assert_allclose(scene.tri_emission, [(1, 1, 1)] * 2 + [(0, 0, 0)] * 2 + [(1, 1, 1)] * 2,
                               atol=FLOAT32_STORAGE)


def srgb_to_linear(c: np.ndarray) -> np.ndarray:
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)


def test_diffuse_texture_mean(tmp_path):
    rng = np.random.default_rng(7)  # fixed seed: a reproducible 4x4 texture
    pixels = rng.integers(0, 256, size=(4, 4, 3), dtype=np.uint8)
    texture = write_png(tmp_path / "albedo.png", pixels)
    stage = new_stage()
    # The same file read raw and as sRGB: each material must get its own mean.
    raw = add_preview_material(stage, "/World/Looks/Raw", texture=texture, color_space="raw")
    srgb = add_preview_material(stage, "/World/Looks/Srgb", texture=texture, color_space="sRGB")
    auto = add_preview_material(stage, "/World/Looks/Auto", texture=texture)
    for name, material in (("Raw", raw), ("Srgb", srgb), ("Auto", auto)):
        bind(add_quads(stage, f"/World/{name}").GetPrim(), material)
    scene = extract_scene(stage)

    values = pixels.reshape(-1, 3) / 255.0
    expected = {
        "/World/Raw": values.mean(axis=0),
        "/World/Srgb": srgb_to_linear(values).mean(axis=0),
        "/World/Auto": srgb_to_linear(values).mean(axis=0),  # 8-bit "auto" is sRGB
    }
    for path, mean in expected.items():
        np.testing.assert_allclose(scene.tri_albedo[prim_tris(scene, path)], [mean] * 2, atol=FLOAT32_STORAGE,
                                   err_msg=path)


# --- lights -----------------------------------------------------------------------------------


def define_light(stage, schema, path, translate=(0, 0, 0), rotate_xyz=None, intensity=3.0, exposure=1.0,
                 color=(1.0, 0.5, 0.25), normalize=False):
    light = schema.Define(stage, path)
    light.AddTranslateOp().Set(Gf.Vec3d(*translate))
    if rotate_xyz is not None:
        light.AddRotateXYZOp().Set(Gf.Vec3f(*rotate_xyz))
    api = UsdLux.LightAPI(light.GetPrim())
    api.CreateIntensityAttr(intensity)
    api.CreateExposureAttr(exposure)
    api.CreateColorAttr(Gf.Vec3f(*color))
    api.CreateNormalizeAttr(normalize)
    return light


def test_lights():
    stage = new_stage()
    add_quads(stage, "/World/Ground").AddTranslateOp().Set(Gf.Vec3d(100, 0, 0))  # origin away from (0, 0, 0)
    define_light(stage, UsdLux.DistantLight, "/World/Sun", rotate_xyz=(90, 0, 0)).CreateAngleAttr(1.5)
    define_light(stage, UsdLux.SphereLight, "/World/Ball", (1, 2, 3), normalize=True).CreateRadiusAttr(2.0)
    define_light(stage, UsdLux.SphereLight, "/World/Bulb", (4, 5, 6)).CreateRadiusAttr(2.0)
    rect = define_light(stage, UsdLux.RectLight, "/World/Panel", (0, 3, 0), rotate_xyz=(0, 90, 0), normalize=True)
    rect.CreateWidthAttr(2.0)
    rect.CreateHeightAttr(3.0)
    define_light(stage, UsdLux.DiskLight, "/World/Disk", (0, 0, 7), normalize=True).CreateRadiusAttr(0.5)
    define_light(stage, UsdLux.DomeLight, "/World/Sky", intensity=2.0, exposure=0.0, normalize=True)
    scene = extract_scene(stage)
    lights = scene.lights

    base = 3.0 * 2.0 * np.array([1.0, 0.5, 0.25])  # intensity * 2^exposure * color
    expected = {
        # path: (kind, radiance, world position, direction, size)
        "/World/Sun": (LIGHT_DISTANT, base, (0, 0, 0), (0, 1, 0), (1.5, 1.5)),
        "/World/Ball": (LIGHT_SPHERE, base / (4 * np.pi * 4), (1, 2, 3), (0, 0, -1), (2, 2)),
        "/World/Bulb": (LIGHT_SPHERE, base, (4, 5, 6), (0, 0, -1), (2, 2)),
        "/World/Panel": (LIGHT_RECT, base / 6, (0, 3, 0), (-1, 0, 0), (2, 3)),
        "/World/Disk": (LIGHT_DISK, base / (np.pi * 0.25), (0, 0, 7), (0, 0, -1), (0.5, 0.5)),
        "/World/Sky": (LIGHT_DOME, 2.0 * np.array([1.0, 0.5, 0.25]), (0, 0, 0), (0, 0, -1), (0, 0)),
    }
    assert sorted(lights.light_paths) == sorted(expected)
    assert len(lights) == len(expected)
    for row, path in enumerate(lights.light_paths):
        kind, radiance, position, direction, size = expected[path]
        assert lights.light_kind[row] == kind, path
        np.testing.assert_allclose(lights.light_radiance[row], radiance, rtol=FLOAT32_STORAGE, err_msg=path)
        np.testing.assert_allclose(lights.light_position[row] + scene.origin, position, atol=FLOAT32_ACCUMULATED,
                                   err_msg=path)
        np.testing.assert_allclose(lights.light_direction[row], direction, atol=FLOAT32_STORAGE, err_msg=path)
        np.testing.assert_allclose(lights.light_size[row], size, rtol=FLOAT32_STORAGE, err_msg=path)


def test_light_direction_under_a_parent_rotation():
    stage = new_stage()
    add_xform(stage, "/World/Rig", rotate_xyz=(0, 0, 90))
    define_light(stage, UsdLux.DistantLight, "/World/Rig/Sun", rotate_xyz=(90, 0, 0))
    scene = extract_scene(stage)
    # -Z -> (0, 1, 0) by rotateX 90, then (-1, 0, 0) by the parent's rotateZ 90.
    np.testing.assert_allclose(scene.lights.light_direction, [[-1, 0, 0]], atol=FLOAT32_STORAGE)


# --- units ------------------------------------------------------------------------------------


@pytest.mark.parametrize("up_axis, meters_per_unit", [("Z", 0.01), ("Y", 1.0), ("Z", 0.3048)])
def test_units_from_stage_metadata(up_axis, meters_per_unit):
    stage = new_stage(up_axis=up_axis, meters_per_unit=meters_per_unit)
    add_quads(stage, "/World/Q")
    scene = extract_scene(stage)
    assert scene.up_axis == up_axis
    assert scene.meters_per_unit == pytest.approx(meters_per_unit)
    np.testing.assert_array_equal(scene.up_vector, [0, 0, 1] if up_axis == "Z" else [0, 1, 0])


# --- errors -----------------------------------------------------------------------------------


def test_nan_point_is_a_stage_error_naming_prim_attribute_and_value():
    stage = new_stage()
    add_mesh(stage, "/World/Bad", [(0, 0, 0), (1, float("nan"), 0), (0, 1, 0)], [3], [0, 1, 2])
    with pytest.raises(StageError) as error:
        extract_scene(stage)
    message = str(error.value)
    assert "/World/Bad" in message and "points" in message and "nan" in message.lower()
    assert error.value.prim == "/World/Bad" and error.value.attribute == "points"


def test_out_of_range_index_is_a_stage_error():
    stage = new_stage()
    add_mesh(stage, "/World/Bad", UNIT_QUAD, [4], [0, 1, 2, 7])
    with pytest.raises(StageError, match=r"/World/Bad.*faceVertexIndices.*7"):
        extract_scene(stage)


def test_counts_indices_mismatch_is_a_stage_error():
    stage = new_stage()
    add_mesh(stage, "/World/Bad", UNIT_QUAD, [4, 3], [0, 1, 2, 3])
    with pytest.raises(StageError, match=r"/World/Bad.*faceVertexCounts"):
        extract_scene(stage)


# --- bake:skip and degenerate geometry --------------------------------------------------------


def test_bake_skip_attribute():
    stage = new_stage()
    add_quads(stage, "/World/Skipped").GetPrim().CreateAttribute(
        "bake:skip", Sdf.ValueTypeNames.Bool, custom=True).Set(True)
    add_quads(stage, "/World/NotSkipped").GetPrim().CreateAttribute(
        "bake:skip", Sdf.ValueTypeNames.Bool, custom=True).Set(False)
    add_quads(stage, "/World/Plain")
    scene = extract_scene(stage)
    skip = {path: bool(scene.prim_skip[i]) for i, path in enumerate(scene.prim_paths)}
    assert skip == {"/World/Skipped": True, "/World/NotSkipped": False, "/World/Plain": False}


def test_degenerate_triangles_have_zero_normals_and_areas():
    stage = new_stage()
    points = [(0, 0, 0), (1, 0, 0), (2, 0, 0), (0, 1, 0), (0, 1, 0)]
    # good, collinear, two coincident points, repeated index, collinear quad
    counts = [3, 3, 3, 3, 4]
    indices = [0, 1, 3, 0, 1, 2, 3, 4, 1, 0, 0, 1, 0, 1, 2, 1]
    add_mesh(stage, "/World/Degenerate", points, counts, indices)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no divide-by-zero RuntimeWarning either
        scene = extract_scene(stage)
    assert scene.num_triangles == 6
    assert np.isfinite(scene.tri_normals).all() and np.isfinite(scene.tri_areas).all()
    np.testing.assert_allclose(scene.tri_normals[0], [0, 0, 1], atol=FLOAT32_STORAGE)
    np.testing.assert_allclose(scene.tri_areas[0], 0.5, rtol=FLOAT32_STORAGE)
    np.testing.assert_array_equal(scene.tri_normals[1:], 0.0)
    np.testing.assert_array_equal(scene.tri_areas[1:], 0.0)


def test_empty_stage():
    scene = extract_scene(new_stage())
    assert scene.num_triangles == 0 and scene.num_points == 0
    assert scene.tri_vertices.shape == (0, 3) and len(scene.lights) == 0 and len(scene.instances) == 0


# --- samples ----------------------------------------------------------------------------------

SAMPLES = sorted(SAMPLES_DIR.glob("*.usda"))


def authored_up_axis(path: Path) -> str:
    """upAxis from the layer's own text (the oracle); USD's fallback is Y."""
    match = re.search(r'\bupAxis\s*=\s*"([YZ])"', path.read_text(errors="replace")[:4000])
    return match.group(1) if match else "Y"


@pytest.mark.parametrize("sample", SAMPLES or [None], ids=[p.stem for p in SAMPLES] or ["none"])
def test_sample_extracts(sample):
    if sample is None:
        pytest.skip(f"no samples in {SAMPLES_DIR}")
    stage = Usd.Stage.Open(str(sample))
    scene = extract_scene(stage)
    assert scene.num_triangles > 0
    assert np.isfinite(scene.points).all() and np.isfinite(scene.origin).all()
    assert (scene.tri_vertices >= 0).all() and (scene.tri_vertices < scene.num_points).all()
    assert np.isfinite(scene.tri_normals).all()
    assert scene.up_axis == authored_up_axis(sample)
    if sample.stem == "instanced_props":
        assert len(scene.instances) >= 50
