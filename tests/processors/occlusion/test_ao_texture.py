"""ambient_occlusion's texture target end to end through the hook: values against the analytic AO of a floor
beside an (almost) infinite wall, the meshes untouched, the texture wired into the material."""

from __future__ import annotations

import numpy as np
import pytest
from pxr import Sdf, Usd, UsdGeom, UsdShade
from lightmap_checks import composed_meshes, read_image, saved_and_baked
from stage_builders import add_mesh, add_preview_material, bind, new_stage

import usdbake
from usdbake.core import ParamError

WALL = 400.0
"""Half-size of the wall (m): it hides half the cosine-weighted hemisphere of a floor point at distance d up to
a share of order d / WALL of it."""


def wall_and_floor_stage(tmp_path):
    """Y-up metres: a 1 m floor (x in [0.25, 1.25], z in [0, 1], st = its xz) beside the wall x = 0 (bake:skip),
    bound to a UsdPreviewSurface, and a tile without UVs (a generated layout)."""
    stage = new_stage(up_axis="Y", meters_per_unit=1.0)
    floor = add_mesh(stage, "/World/Floor", [(0.25, 0, 0), (0.25, 0, 1), (1.25, 0, 1), (1.25, 0, 0)], [4],
                     [0, 1, 2, 3])
    st = UsdGeom.PrimvarsAPI(floor).CreatePrimvar("st", Sdf.ValueTypeNames.TexCoord2fArray,
                                                  UsdGeom.Tokens.faceVarying)
    st.Set([(0, 0), (0, 1), (1, 1), (1, 0)])
    wall = add_mesh(stage, "/World/Wall", [(0, 0, -WALL), (0, WALL, -WALL), (0, WALL, WALL), (0, 0, WALL)], [4],
                    [0, 1, 2, 3])
    wall.GetPrim().CreateAttribute("bake:skip", Sdf.ValueTypeNames.Bool).Set(True)  # occludes, receives nothing
    add_mesh(stage, "/World/Tile", [(3, 0, 3), (3, 0, 3.5), (3.5, 0, 3.5), (3.5, 0, 3)], [4], [0, 1, 2, 3])
    bind(floor.GetPrim(), add_preview_material(stage, "/World/Looks/Floor", diffuse=(0.5, 0.5, 0.5)))
    path = tmp_path / "wall.usda"
    stage.GetRootLayer().Export(str(path))
    return Usd.Stage.Open(str(path))


@pytest.fixture(scope="module")
def baked(tmp_path_factory):
    tmp_path = tmp_path_factory.mktemp("ao_texture")
    stage = wall_and_floor_stage(tmp_path)
    before = composed_meshes(stage)
    layer = usdbake.bake(stage, "ambient_occlusion", {"ambient_occlusion": {"samples": 256}}, target="texture",
                         texture_dir=str(tmp_path))
    return stage, layer, before


def test_texels_match_the_analytic_half_hemisphere_and_none_are_black(baked):
    stage, _, _ = baked
    floor = stage.GetPrimAtPath("/World/Floor")
    assert floor.HasAPI("LightmapAPI") and "LightmapAPI:ao" in floor.GetAppliedSchemas()
    assert floor.GetAttribute("bake:lightmap:ao:uv").Get() == "st"
    file = floor.GetAttribute("bake:lightmap:ao:file").Get().resolvedPath
    image = read_image(file)[:, :, 0]
    assert image.shape == (32, 32)  # 1 m of floor at the default 32 texels per metre
    # analytic: 1/2 for an infinite wall; the finite one leaves a share of order d / WALL open
    assert abs(image.mean() - 0.5) < 4 * 0.5 / np.sqrt(image.size * 256) + 1.25 / WALL
    assert image.min() > 0.5 - 4 * 0.5 / 16  # each texel within 4 sigma of 256 rays: none black
    assert not stage.GetPrimAtPath("/World/Floor").HasAttribute("primvars:bake:ao")


def test_meshes_are_unchanged_and_the_generated_uvs_are_written(baked):
    stage, _, before = baked
    assert composed_meshes(stage) == before
    tile = stage.GetPrimAtPath("/World/Tile")
    uv = UsdGeom.PrimvarsAPI(tile).GetPrimvar("bake:lightmapST")
    assert uv.GetInterpolation() == UsdGeom.Tokens.faceVarying and len(uv.Get()) == 4
    assert tile.GetAttribute("bake:lightmap:ao:uv").Get() == "bake:lightmapST"
    assert not stage.GetPrimAtPath("/World/Wall").HasAttribute("bake:lightmap:ao:file")


def test_ao_texture_is_wired_into_the_bound_surface(baked):
    stage, _, _ = baked
    surface = UsdShade.Shader(stage.GetPrimAtPath("/World/Looks/Floor/Surface"))
    source = surface.GetInput("occlusion").GetConnectedSources()[0][0]
    texture = UsdShade.Shader(source.source.GetPrim())
    assert texture.GetIdAttr().Get() == "UsdUVTexture" and source.sourceName == "r"
    assert texture.GetInput("file").Get().resolvedPath == \
        stage.GetPrimAtPath("/World/Floor").GetAttribute("bake:lightmap:ao:file").Get().resolvedPath
    reader = UsdShade.Shader(texture.GetInput("st").GetConnectedSources()[0][0].source.GetPrim())
    assert reader.GetIdAttr().Get() == "UsdPrimvarReader_float2" and reader.GetInput("varname").Get() == "st"


@pytest.mark.parametrize("values", [{"texel_density": 0.0}, {"max_texture_size": 4}, {"target": "pixels"},
                                    {"margin": -1}])
def test_bad_texture_params_are_refused_before_compute(tmp_path, values):
    stage = wall_and_floor_stage(tmp_path)
    with pytest.raises(ParamError, match=next(iter(values))):
        usdbake.bake(stage, "ambient_occlusion", {"ambient_occlusion": values})


def test_bad_target_option_is_refused(tmp_path):
    with pytest.raises(ParamError, match="target='uv'"):
        usdbake.bake(wall_and_floor_stage(tmp_path), "ambient_occlusion", target="uv")


def test_texture_and_vertex_targets_agree_where_vertices_are_dense(tmp_path):
    """A 2 m floor of 20 x 20 quads beside a 0.5 m box off its centre (so a flipped image would read the wrong
    side): the texel under each vertex (64 texels/m) against the vertex's own AO, away from the box's sharp
    contact shadow."""
    stage = new_stage(up_axis="Y", meters_per_unit=1.0)
    n = 20
    xs = np.linspace(-1.0, 1.0, n + 1)
    points = [(x, 0.0, z) for z in xs for x in xs]
    quads = [(j * (n + 1) + i, (j + 1) * (n + 1) + i, (j + 1) * (n + 1) + i + 1, j * (n + 1) + i + 1)
             for j in range(n) for i in range(n)]
    floor = add_mesh(stage, "/World/Floor", points, [4] * len(quads), [k for q in quads for k in q])
    uv = UsdGeom.PrimvarsAPI(floor).CreatePrimvar("st", Sdf.ValueTypeNames.TexCoord2fArray, UsdGeom.Tokens.vertex)
    uv.Set([((x + 1) / 2, (z + 1) / 2) for x, _, z in points])
    centre = np.array([0.35, 0.0, -0.35])
    box = [tuple(centre + corner) for corner in
           [(-0.25, 0, -0.25), (0.25, 0, -0.25), (0.25, 0, 0.25), (-0.25, 0, 0.25),
            (-0.25, 0.5, -0.25), (0.25, 0.5, -0.25), (0.25, 0.5, 0.25), (-0.25, 0.5, 0.25)]]
    faces = [(0, 1, 2, 3), (4, 7, 6, 5), (0, 4, 5, 1), (1, 5, 6, 2), (2, 6, 7, 3), (3, 7, 4, 0)]
    cube = add_mesh(stage, "/World/Box", box, [4] * 6, [k for f in faces for k in f])
    cube.GetPrim().CreateAttribute("bake:skip", Sdf.ValueTypeNames.Bool).Set(True)
    stage = saved_and_baked(stage, tmp_path / "dense.usda", "ambient_occlusion",
                            {"ambient_occlusion": {"samples": 1024, "texel_density": 64.0}}, "both")
    prim = stage.GetPrimAtPath("/World/Floor")
    vertex_ao = np.asarray(UsdGeom.PrimvarsAPI(prim).GetPrimvar("bake:ao").Get())
    image = read_image(prim.GetAttribute("bake:lightmap:ao:file").Get().resolvedPath)[::-1, :, 0]  # row 0: v = 0
    height, width = image.shape
    uvs = np.array([((x + 1) / 2, (z + 1) / 2) for x, _, z in points])
    texel = image[np.clip((uvs[:, 1] * height).astype(int), 0, height - 1),
                  np.clip((uvs[:, 0] * width).astype(int), 0, width - 1)]
    p = np.asarray(points)
    from_box = np.abs(p[:, [0, 2]] - centre[[0, 2]]).max(axis=1)
    away = (from_box > 0.4) & (np.abs(p[:, [0, 2]]).max(axis=1) < 0.99)
    difference = texel[away] - vertex_ao[away]
    noise = 0.5 / np.sqrt(1024)  # one i.i.d. estimate's bound; stratified rays have less
    assert abs(difference.mean()) < 4 * np.sqrt(2) * noise / np.sqrt(away.sum()) + 0.005
    assert np.sqrt(np.mean(difference ** 2)) < np.sqrt(2) * noise + 0.01


def test_denoise_without_pyoidn_is_refused_before_compute(tmp_path, monkeypatch):
    import importlib.util

    real = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec", lambda name, *a: None if name == "pyoidn" else real(name, *a))
    with pytest.raises(ParamError, match=r"denoise=true needs the pyoidn package"):
        usdbake.bake(wall_and_floor_stage(tmp_path), "ambient_occlusion", {"ambient_occlusion": {"denoise": True}})


def test_denoised_lightmap_is_closer_to_the_analytic_value_without_shifting_it(tmp_path):
    pytest.importorskip("pyoidn")
    stage = wall_and_floor_stage(tmp_path)
    errors, means = {}, {}
    for denoise in (False, True):
        layer_dir = tmp_path / str(denoise)
        layer_dir.mkdir()
        usdbake.bake(stage, "ambient_occlusion", {"ambient_occlusion": {"samples": 16, "denoise": denoise}},
                     target="texture", texture_dir=str(layer_dir))
        image = read_image(stage.GetPrimAtPath("/World/Floor").GetAttribute("bake:lightmap:ao:file").Get()
                           .resolvedPath)[:, :, 0]
        errors[denoise] = float(np.sqrt(np.mean((image - 0.5) ** 2)))
        means[denoise] = float(image.mean())
    assert errors[True] < 0.8 * errors[False], errors
    assert abs(means[True] - means[False]) < 0.002, means


def test_command_bakes_lightmaps_and_inspect_lists_them(tmp_path, capsys):
    import json

    from usdbake.cli.main import main

    wall_and_floor_stage(tmp_path)  # writes wall.usda
    out = tmp_path / "wall.baked.usda"
    assert main(["bake", str(tmp_path / "wall.usda"), "-o", str(out), "--target", "texture", "--set",
                 "ambient_occlusion.samples=16", "--cache", str(tmp_path / "cache")]) == 0
    capsys.readouterr()
    assert main(["inspect", str(out), "--json"]) == 0
    lightmaps = {row["path"]: row for row in json.loads(capsys.readouterr().out)["lightmaps"]}
    floor = lightmaps["/World/Floor.bake:lightmap:ao:file"]
    assert (floor["width"], floor["height"], floor["channels"], floor["format"]) == (32, 32, 1, "uint16")
    assert "/World/Tile.bake:lightmap:ao:file" in lightmaps and "/World/Wall.bake:lightmap:ao:file" not in lightmaps


def baked_with_few_rays(stage, path):
    """``saved_and_baked`` with AO's texture target at 4 rays a texel."""
    return saved_and_baked(stage, path, "ambient_occlusion", {"ambient_occlusion": {"samples": 4}}, "texture")


def test_a_material_shared_by_meshes_on_different_pages_gets_a_variant_each(tmp_path):
    stage = new_stage(up_axis="Y", meters_per_unit=1.0)
    look = add_preview_material(stage, "/World/Looks/Oak", diffuse=(0.5, 0.35, 0.2))
    for name, x in (("Left", 0.0), ("Right", 2.0)):
        mesh = add_mesh(stage, f"/World/{name}", [(x, 0, 0), (x, 0, 1), (x + 1, 0, 1), (x + 1, 0, 0)], [4],
                        [0, 1, 2, 3])
        UsdGeom.PrimvarsAPI(mesh).CreatePrimvar("st", Sdf.ValueTypeNames.TexCoord2fArray,
                                                UsdGeom.Tokens.faceVarying).Set([(0, 0), (0, 1), (1, 1), (1, 0)])
        bind(mesh.GetPrim(), look)
    stage = baked_with_few_rays(stage, tmp_path / "shared.usda")
    files = set()
    for name in ("Left", "Right"):
        prim = stage.GetPrimAtPath(f"/World/{name}")
        material, _ = UsdShade.MaterialBindingAPI(prim).ComputeBoundMaterial()
        assert str(material.GetPath()).startswith("/World/Looks/Oak_bakeAo")
        surface = material.ComputeSurfaceSource()[0]
        assert surface.GetInput("diffuseColor").Get() == (0.5, 0.35, 0.2)  # the variant is the material
        texture = surface.GetInput("occlusion").GetConnectedSources()[0][0].source.GetPrim()
        file = texture.GetAttribute("inputs:file").Get().resolvedPath
        assert file == prim.GetAttribute("bake:lightmap:ao:file").Get().resolvedPath
        files.add(file)
    assert len(files) == 2
    original = UsdShade.Shader(stage.GetPrimAtPath("/World/Looks/Oak/Surface"))
    assert not original.GetInput("occlusion")  # the authored material is left as it was


def test_materials_bound_to_geom_subsets_are_wired_too(tmp_path):
    """A slab of two faces on its own st, each face a GeomSubset bound to its own material (Oak, Paint), and a
    tile without UVs (a generated page) bound to Oak: Paint is wired in place, Oak gets a variant per page, and
    the Left subset is bound to the slab's."""
    stage = new_stage(up_axis="Y", meters_per_unit=1.0)
    oak = add_preview_material(stage, "/World/Looks/Oak", diffuse=(0.5, 0.35, 0.2))
    paint = add_preview_material(stage, "/World/Looks/Paint", diffuse=(0.8, 0.8, 0.8))
    slab = add_mesh(stage, "/World/Slab", [(0, 0, 0), (0, 0, 1), (1, 0, 1), (1, 0, 0), (2, 0, 1), (2, 0, 0)],
                    [4, 4], [0, 1, 2, 3, 3, 2, 4, 5])
    UsdGeom.PrimvarsAPI(slab).CreatePrimvar("st", Sdf.ValueTypeNames.TexCoord2fArray, UsdGeom.Tokens.faceVarying).Set(
        [(0, 0), (0, 1), (0.5, 1), (0.5, 0), (0.5, 0), (0.5, 1), (1, 1), (1, 0)])
    binding = UsdShade.MaterialBindingAPI.Apply(slab.GetPrim())
    for name, face, look in (("Left", 0, oak), ("Right", 1, paint)):
        subset = binding.CreateMaterialBindSubset(name, [face], UsdGeom.Tokens.face)
        UsdShade.MaterialBindingAPI.Apply(subset.GetPrim()).Bind(look)
    tile = add_mesh(stage, "/World/Tile", [(3, 0, 0), (3, 0, 1), (4, 0, 1), (4, 0, 0)], [4], [0, 1, 2, 3])
    bind(tile.GetPrim(), oak)
    stage = baked_with_few_rays(stage, tmp_path / "subsets.usda")

    def occlusion_file(material):
        surface = material.ComputeSurfaceSource()[0]
        texture = surface.GetInput("occlusion").GetConnectedSources()[0][0].source.GetPrim()
        return texture.GetAttribute("inputs:file").Get().resolvedPath

    slab_file = stage.GetPrimAtPath("/World/Slab").GetAttribute("bake:lightmap:ao:file").Get().resolvedPath
    tile_file = stage.GetPrimAtPath("/World/Tile").GetAttribute("bake:lightmap:ao:file").Get().resolvedPath
    assert slab_file != tile_file
    left, _ = UsdShade.MaterialBindingAPI(stage.GetPrimAtPath("/World/Slab/Left")).ComputeBoundMaterial()
    assert str(left.GetPath()).startswith("/World/Looks/Oak_bakeAo") and occlusion_file(left) == slab_file
    right, _ = UsdShade.MaterialBindingAPI(stage.GetPrimAtPath("/World/Slab/Right")).ComputeBoundMaterial()
    assert str(right.GetPath()) == "/World/Looks/Paint" and occlusion_file(right) == slab_file
    on_tile, _ = UsdShade.MaterialBindingAPI(stage.GetPrimAtPath("/World/Tile")).ComputeBoundMaterial()
    assert on_tile.GetPath() != left.GetPath() and occlusion_file(on_tile) == tile_file


def test_texels_on_either_side_of_a_uv_seam_agree_within_noise():
    """A smooth sphere resting on a floor, charted by xatlas: texel pairs of different charts that sit at one
    world point with one normal differ by no more than two independent estimates do."""
    from scipy.spatial import cKDTree

    from usdbake.core.scene import Scene
    from usdbake.geometry.mesh import vertex_normals
    from usdbake.kernels.lightmap_bake import texel_samples
    from usdbake.kernels.lightmap_layout import lightmap_layout
    from usdbake.kernels.tracer import Tracer
    from usdbake.processors.occlusion.ambient_occlusion import texel_ao_chunk

    rings, segments = 24, 48
    theta, phi = np.meshgrid(np.linspace(0, np.pi, rings + 1), np.linspace(0, 2 * np.pi, segments, endpoint=False),
                             indexing="ij")
    sphere = np.stack([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta) + 1.0], -1)
    points = sphere.reshape(-1, 3)
    index = np.arange(len(points)).reshape(rings + 1, segments)
    a, b = index[:-1], np.roll(index[:-1], -1, axis=1)
    c, d = index[1:], np.roll(index[1:], -1, axis=1)
    tris = np.concatenate([np.stack([a, c, d], -1).reshape(-1, 3), np.stack([a, d, b], -1).reshape(-1, 3)])
    floor = np.array([[-3, -3, 0], [3, -3, 0], [3, 3, 0], [-3, 3, 0]], np.float64)
    tris = np.concatenate([tris, np.array([[0, 1, 2], [0, 2, 3]]) + len(points)]).astype(np.int32)
    points = np.concatenate([points, floor]).astype(np.float32)
    corners = points[tris].astype(np.float64)
    cross = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    areas = 0.5 * np.linalg.norm(cross, axis=1)
    keep = areas > 1e-9  # the poles' collapsed triangles
    tris, cross, areas = tris[keep], cross[keep], areas[keep]
    n = len(tris)
    prim = (tris[:, 0] >= len(points) - 4).astype(np.int32)
    scene = Scene(points=points, tri_vertices=tris, tri_normals=(cross / (2 * areas[:, None])).astype(np.float32),
                  tri_areas=areas.astype(np.float32), tri_albedo=np.full((n, 3), 0.5, np.float32),
                  tri_emission=np.zeros((n, 3), np.float32), tri_prim=prim, tri_face=np.arange(n, dtype=np.int32),
                  tri_instance=np.full(n, -1, np.int32), tri_double_sided=np.zeros(n, bool),
                  point_prim=(np.arange(len(points)) >= len(points) - 4).astype(np.int32),
                  prim_paths=("/World/Sphere", "/World/Floor"), prim_point_start=np.array([0, len(points) - 4,
                                                                                             len(points)]),
                  prim_face_count=np.array([n - 2, 2], np.int32), prim_writable=np.ones(2, bool),
                  prim_skip=np.array([False, True]), prim_surface=("", ""))
    density = 24.0
    layout = lightmap_layout(scene, np.array([0]), density=density, max_size=1024)
    assert layout.meshes[0].source == "generated"
    (page,) = texel_samples(scene, layout, vertex_normals(scene.points, scene.tri_vertices, scene.tri_normals,
                                                          scene.tri_areas))
    tracer = Tracer.from_scene(scene)
    first = texel_ao_chunk(tracer, 0, page.points, page.normals, page.corners, samples=1024, max_distance=np.inf,
                           seed=0)
    second = texel_ao_chunk(tracer, 0, page.points, page.normals, page.corners, samples=1024, max_distance=np.inf,
                            seed=1)
    pairs = cKDTree(page.points.astype(np.float64)).query_pairs(0.25 / density, output_type="ndarray")
    apart = np.hypot(*(np.stack([page.texel % page.width, page.texel // page.width])[:, pairs[:, 0]]
                       - np.stack([page.texel % page.width, page.texel // page.width])[:, pairs[:, 1]]))
    same_normal = (page.normals[pairs[:, 0]] * page.normals[pairs[:, 1]]).sum(axis=1) > 0.99
    seams = pairs[(apart > 2.5) & same_normal]
    assert len(seams) > 50  # xatlas cut the sphere into charts
    difference = first[seams[:, 0]] - first[seams[:, 1]]
    noise = np.sqrt(np.mean((first[seams] - second[seams]) ** 2) / 2)
    assert np.sqrt(np.mean(difference ** 2)) < 1.5 * np.sqrt(2) * noise + 0.002


def test_a_texture_bake_after_refinement_reads_the_carried_uvs(tmp_path):
    """With sky_visibility (vertex target) refining the floor in the same run, AO bakes its lightmap on the
    refined triangles, whose st is carried by barycentric weights: the same map over the floor, so the same
    texel points as without refinement."""
    images = {}
    for processors in (["ambient_occlusion"], ["sky_visibility", "ambient_occlusion"]):
        folder = tmp_path / str(len(processors))
        folder.mkdir()
        stage = wall_and_floor_stage(folder)
        params = {"ambient_occlusion": {"samples": 64, "target": "texture"}}
        if len(processors) == 2:
            params["sky_visibility"] = {"patch_count": 32, "tolerance": 0.01, "max_level": 3}
        usdbake.bake(stage, processors, params, texture_dir=str(folder))
        floor = stage.GetPrimAtPath("/World/Floor")
        if len(processors) == 2:
            assert len(UsdGeom.Mesh(floor).GetFaceVertexCountsAttr().Get()) > 1  # refined
        images[len(processors)] = read_image(floor.GetAttribute("bake:lightmap:ao:file").Get().resolvedPath)
    assert images[1].shape == images[2].shape
    assert np.abs(images[1] - images[2]).mean() < 0.01
