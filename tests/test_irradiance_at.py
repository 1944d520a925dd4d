"""usdbake.irradiance_at: what a bake stored, read back at points, against values worked out here.

- radiosity: a vertex reads its own direct + indirect sum, a triangle's centroid the mean of its three,
  a point just off the surface its foot's; the normal picks between faces meeting at an unwelded corner;
  transforms and a session-layer bake are honoured;
- irradiance_grid: at a grid vertex an axis normal reads the RGB9E5 colour times the direction's axis
  component, decoded by hand; the normal offset the bake layer records is used, 0.5 cells otherwise;
- light_probes: inside one tetrahedron, the barycentric blend of the probes' SH evaluated with the real
  SH basis written out here; a prim transform turns points and normals; a cloud without the small lights'
  direct light is refused unless allow_partial;
- a small bake of all three under a uniform dome: each source agrees with the primvars the bake wrote and
  with pi L (the unoccluded upper hemisphere);
- bad queries and stages without a bake raise UsageError / StageError naming the value.
"""

import math

import numpy as np
import pytest
from pxr import Gf, Sdf, UsdGeom, UsdLux, Vt
from stage_builders import add_mesh, new_stage, world_points
from tolerances import BAKED_UNIFORM_SKY, FLOAT32_ACCUMULATED, FLOAT32_BARYCENTRIC, FLOAT32_STORAGE, FLOAT64_ROUNDING

import usdbake
from usdbake.core.errors import StageError, UsageError

UP = (0.0, 0.0, 1.0)


# -- radiosity ---------------------------------------------------------------------------------------


def triangle_sheet(stage, path, values_direct, values_indirect, **attributes):
    """A 3 x 3 point sheet in the xy plane (z = 0, facing +z), 8 triangles, with the two primvars."""
    points = [(x, y, 0.0) for y in range(3) for x in range(3)]
    tris = []
    for y in range(2):
        for x in range(2):
            a = 3 * y + x
            tris += [(a, a + 1, a + 4), (a, a + 4, a + 3)]
    mesh = add_mesh(stage, path, points, [3] * len(tris), np.ravel(tris).tolist(), **attributes)
    set_irradiance(mesh.GetPrim(), values_direct, values_indirect)
    return np.array(tris)


def set_irradiance(prim, direct, indirect):
    api = UsdGeom.PrimvarsAPI(prim)
    for name, values in (("bake:irradianceDirect", direct), ("bake:irradianceIndirect", indirect)):
        api.CreatePrimvar(name, Sdf.ValueTypeNames.Color3fArray, UsdGeom.Tokens.vertex).Set(
            Vt.Vec3fArray.FromNumpy(np.asarray(values, np.float32)))


def test_radiosity_reads_vertices_centroids_and_feet_through_a_transform():
    rng = np.random.default_rng(5)  # fixed seed: any values do
    direct, indirect = rng.uniform(0, 4, (9, 3)), rng.uniform(0, 1, (9, 3))
    stage = new_stage()
    xform = UsdGeom.Xform.Define(stage, "/World/Turned")
    xform.AddTranslateOp().Set(Gf.Vec3d(10, -2, 3))
    xform.AddRotateXYZOp().Set(Gf.Vec3f(90, 0, 30))
    tris = triangle_sheet(stage, "/World/Turned/Sheet", direct, indirect)
    world = world_points(stage, "/World/Turned/Sheet")
    normal = np.cross(world[1] - world[0], world[3] - world[0])
    normal /= np.linalg.norm(normal)
    total = np.asarray(direct, np.float32).astype(np.float64) + np.asarray(indirect, np.float32)

    at_vertices = usdbake.irradiance_at(stage, world, np.tile(normal, (9, 1)), source="radiosity")
    np.testing.assert_allclose(at_vertices, total, rtol=FLOAT32_ACCUMULATED, atol=FLOAT32_ACCUMULATED)
    centroids = world[tris].mean(axis=1)
    at_centroids = usdbake.irradiance_at(stage, centroids, np.tile(normal, (len(tris), 1)), source="radiosity")
    np.testing.assert_allclose(at_centroids, total[tris].mean(axis=1), rtol=FLOAT32_ACCUMULATED)
    # A point a little off the surface reads its foot; farther than max_distance is refused.
    lifted = centroids[:1] + 1e-3 * normal
    np.testing.assert_allclose(usdbake.irradiance_at(stage, lifted, [normal], source="radiosity"),
                               at_centroids[:1], rtol=FLOAT32_ACCUMULATED)
    with pytest.raises(UsageError, match=r"points\[0\] = .* from the nearest baked surface"):
        usdbake.irradiance_at(stage, centroids[:1] + 0.5 * normal, [normal], source="radiosity")
    np.testing.assert_allclose(usdbake.irradiance_at(stage, centroids[:1] + 0.5 * normal, [normal],
                                                     source="radiosity", max_distance=1.0),
                               at_centroids[:1], rtol=FLOAT32_ACCUMULATED)
    with pytest.raises(UsageError, match="max_distance=-1.0: expected a distance >= 0"):
        usdbake.irradiance_at(stage, centroids[:1], [normal], source="radiosity", max_distance=-1.0)


def test_radiosity_normal_picks_the_face_at_an_unwelded_corner_and_reads_the_session_layer():
    stage = new_stage()
    floor = add_mesh(stage, "/World/Floor", [(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0)], [4], [0, 1, 2, 3])
    wall = add_mesh(stage, "/World/Wall", [(0, 0, 0), (0, 1, 0), (0, 1, 1), (0, 0, 1)], [4], [0, 1, 2, 3])
    stage.SetEditTarget(stage.GetSessionLayer())  # the bake's opinions in the session layer, as the hook puts them
    set_irradiance(floor.GetPrim(), np.full((4, 3), 2.0), np.full((4, 3), 1.0))
    set_irradiance(wall.GetPrim(), np.full((4, 3), 0.5), np.zeros((4, 3)))
    edge = [[0.0, 0.5, 0.0]] * 2
    np.testing.assert_allclose(usdbake.irradiance_at(stage, edge, [UP, (1.0, 0.0, 0.0)], source="radiosity"),
                               [[3.0] * 3, [0.5] * 3], rtol=FLOAT64_ROUNDING)


# -- irradiance grid ---------------------------------------------------------------------------------

AXES = np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]], np.float64)


def rgb9e5(values):
    """Pack (N, 3) non-negative floats (shared exponent, 9-bit mantissas, bias 15): the layout's definition."""
    values = np.asarray(values, np.float64)
    exponent = np.maximum(np.floor(np.log2(np.maximum(values.max(axis=1), 2.0 ** -16))) + 1, -15)
    mantissa = np.clip(np.round(values / 2.0 ** (exponent[:, None] - 9)), 0, 511).astype(np.uint64)
    bits = mantissa[:, 0] | mantissa[:, 1] << 9 | mantissa[:, 2] << 18 | (exponent + 15).astype(np.uint64) << 27
    return bits.astype(np.uint32)


def unpack_rgb9e5(bits):
    bits = np.asarray(bits, np.uint64)
    mantissa = np.stack([(bits >> shift) & 511 for shift in (0, 9, 18)], axis=1).astype(np.float64)
    return mantissa * 2.0 ** ((bits >> 27).astype(np.float64) - 15 - 9)[:, None]


def grid_stage(provenance=None, include_direct=True, translate=(0.0, 0.0, 0.0)):
    """A 3 x 2 x 2 IrradianceVectorGrid authored by hand in a sublayer; returns (stage, vertex positions,
    direction codes (V, 6, 3), colours (V, 6))."""
    rng = np.random.default_rng(11)  # fixed seed: any directions in their hemispheres and colours do
    resolution, origin, cell = (3, 2, 2), np.array([1.0, 2.0, 3.0]), 0.5
    count = int(np.prod(resolution))
    raw = rng.normal(size=(count, 6, 3))
    raw = raw / np.linalg.norm(raw, axis=2, keepdims=True)
    along = np.einsum("vhi,hi->vh", raw, AXES)
    raw += AXES * (np.abs(along) + 0.2)[:, :, None]  # into hemisphere h
    codes = (np.round(raw / np.linalg.norm(raw, axis=2, keepdims=True) * 127) + 128).astype(np.uint8)
    colors = rgb9e5(rng.uniform(0.1, 5.0, (count * 6, 3))).reshape(count, 6)
    layer = Sdf.Layer.CreateAnonymous("bake")
    if provenance is not None:
        layer.customLayerData = {"usdbake": {"processors": {"irradiance_grid": {"params": provenance}}}}
    stage = new_stage()
    stage.GetRootLayer().subLayerPaths.append(layer.identifier)
    stage.SetEditTarget(layer)
    prim = stage.DefinePrim("/usdbake/IrradianceGrid", "IrradianceVectorGrid")
    for name, kind, value in (
            ("gridOrigin", Sdf.ValueTypeNames.Point3f, Gf.Vec3f(*origin)),
            ("cellSize", Sdf.ValueTypeNames.Float3, Gf.Vec3f(cell, cell, cell)),
            ("resolution", Sdf.ValueTypeNames.Int3, Gf.Vec3i(*resolution)),
            ("directions", Sdf.ValueTypeNames.UCharArray, Vt.UCharArray.FromNumpy(codes.ravel())),
            ("colorsRGB9E5", Sdf.ValueTypeNames.UIntArray, Vt.UIntArray.FromNumpy(colors.ravel())),
            ("vectorsPerVertex", Sdf.ValueTypeNames.Int, 6),
            ("bake:includeDirect", Sdf.ValueTypeNames.Bool, include_direct)):
        prim.CreateAttribute(name, kind).Set(value)
    UsdGeom.Xformable(prim).AddTranslateOp().Set(Gf.Vec3d(*translate))
    i, j, k = np.meshgrid(*(np.arange(n) for n in resolution), indexing="ij")
    vertices = np.stack([i, j, k], -1).transpose(2, 1, 0, 3).reshape(-1, 3) * cell + origin + translate  # x fastest
    return stage, vertices, codes, colors


def axis_irradiance(codes, colors, hemisphere):
    """(V, 3) irradiance at each vertex for the normal AXES[hemisphere]: colour times d' . axis, by hand."""
    q = codes[:, hemisphere].astype(np.float64) - 128.0
    cosine = (q / np.linalg.norm(q, axis=1, keepdims=True)) @ AXES[hemisphere]
    return unpack_rgb9e5(colors[:, hemisphere]) * cosine[:, None]


@pytest.mark.parametrize("hemisphere", range(6))
def test_grid_vertices_read_their_decoded_axis_vector_with_the_recorded_offset(hemisphere):
    stage, vertices, codes, colors = grid_stage({"normal_offset": 0.0}, translate=(5.0, 0.0, -1.0))
    normals = np.tile(AXES[hemisphere], (len(vertices), 1))
    np.testing.assert_allclose(usdbake.irradiance_at(stage, vertices, normals, source="irradiance_grid"),
                               axis_irradiance(codes, colors, hemisphere), rtol=FLOAT32_STORAGE)


def test_grid_default_offset_is_half_a_cell_and_blends_trilinearly():
    stage, vertices, codes, colors = grid_stage()  # no provenance: the processor's default normal_offset
    expected = axis_irradiance(codes, colors, 4)
    normals = np.tile(UP, (2, 1))
    below = vertices[:2] - [0.0, 0.0, 0.25]  # half a 0.5 cell under vertices 0 and 1, moved up onto them
    np.testing.assert_allclose(usdbake.irradiance_at(stage, below, normals), expected[:2], rtol=FLOAT32_STORAGE)
    middle = below.mean(axis=0, keepdims=True)
    np.testing.assert_allclose(usdbake.irradiance_at(stage, middle, normals[:1]), expected[:2].mean(axis=0,
                                                                                                    keepdims=True),
                               rtol=FLOAT32_STORAGE)


def test_an_indirect_only_grid_needs_allow_partial():
    stage, vertices, _, _ = grid_stage(include_direct=False)
    with pytest.raises(StageError, match="IrradianceGrid.bake:includeDirect: false"):
        usdbake.irradiance_at(stage, vertices[:1], [UP])
    assert usdbake.irradiance_at(stage, vertices[:1], [UP], allow_partial=True).shape == (1, 3)


# -- light probes -------------------------------------------------------------------------------------


def sh_basis(n):
    """(N, 9) real orthonormal L2 SH without the Condon-Shortley phase, from the closed forms."""
    x, y, z = np.asarray(n, np.float64).T
    c0, c1 = math.sqrt(1 / (4 * math.pi)), math.sqrt(3 / (4 * math.pi))
    c2, c3, c4 = math.sqrt(15 / (4 * math.pi)), math.sqrt(5 / (16 * math.pi)), math.sqrt(15 / (16 * math.pi))
    return np.stack([np.full_like(x, c0), c1 * y, c1 * z, c1 * x, c2 * x * y, c2 * y * z, c3 * (3 * z * z - 1),
                     c2 * x * z, c4 * (x * x - y * y)], axis=1)


PROBES = np.array([[0.0, 0.0, 0.0], [2.0, 0.0, 0.0], [0.0, 2.0, 0.0], [0.0, 0.0, 2.0]])


def probe_stage(direct_lights="included", basis="realOrthonormal", rotate_z=0.0):
    """One tetrahedron of 4 probes with random SH, authored by hand at /usdbake/LightProbes."""
    rng = np.random.default_rng(3)  # fixed seed: any coefficients do
    sh = rng.uniform(-1, 1, (4, 9, 3)) + [[[4.0, 5.0, 6.0]] + [[0.0, 0.0, 0.0]] * 8]
    stage = new_stage()
    prim = stage.DefinePrim("/usdbake/LightProbes", "LightProbeCloud")
    for name, kind, value in (
            ("probePositions", Sdf.ValueTypeNames.Point3fArray, Vt.Vec3fArray.FromNumpy(PROBES.astype(np.float32))),
            ("shCoefficients", Sdf.ValueTypeNames.Float3Array,
             Vt.Vec3fArray.FromNumpy(sh.reshape(-1, 3).astype(np.float32))),
            ("tetrahedra", Sdf.ValueTypeNames.IntArray, Vt.IntArray([0, 1, 2, 3])),
            ("tetNeighbors", Sdf.ValueTypeNames.IntArray, Vt.IntArray([-1, -1, -1, -1])),
            ("shOrder", Sdf.ValueTypeNames.Int, 2), ("shBasis", Sdf.ValueTypeNames.Token, basis),
            ("bake:directLights", Sdf.ValueTypeNames.Token, direct_lights)):
        prim.CreateAttribute(name, kind).Set(value)
    UsdGeom.Xformable(prim).AddRotateZOp().Set(rotate_z)
    return stage, sh.astype(np.float32).astype(np.float64)


def random_directions(count, seed):
    d = np.random.default_rng(seed).normal(size=(count, 3))
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def test_probes_blend_barycentrically_and_turn_with_their_prim():
    stage, sh = probe_stage(rotate_z=90.0)
    rng = np.random.default_rng(8)  # fixed seed: points inside the tetrahedron
    bary = rng.dirichlet(np.ones(4), 20)
    local = bary @ PROBES
    normals_local = random_directions(20, seed=9)
    turn = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])  # +90 deg about z, column vectors
    expected = np.einsum("nk,nkc->nc", sh_basis(normals_local), np.einsum("nv,vkc->nkc", bary, sh))
    got = usdbake.irradiance_at(stage, local @ turn.T, normals_local @ turn.T, source="light_probes")
    np.testing.assert_allclose(got, expected, rtol=FLOAT32_BARYCENTRIC, atol=FLOAT32_BARYCENTRIC)


def test_probes_without_the_small_lights_are_refused_unless_allow_partial():
    stage, _ = probe_stage(direct_lights="excluded")
    point, normal = [[0.3, 0.3, 0.3]], [UP]
    complete = usdbake.irradiance_at(stage, point, normal)  # a dome-only stage: nothing was left out
    UsdLux.DistantLight.Define(stage, "/World/Sun")
    with pytest.raises(StageError, match=r"LightProbes.bake:directLights: 'excluded'.*/World/Sun"):
        usdbake.irradiance_at(stage, point, normal)
    np.testing.assert_array_equal(usdbake.irradiance_at(stage, point, normal, allow_partial=True), complete)


def test_probes_in_another_basis_are_refused():
    stage, _ = probe_stage(basis="realOrthonormalCondonShortley")
    with pytest.raises(StageError, match="LightProbes.shBasis: 'realOrthonormalCondonShortley'"):
        usdbake.irradiance_at(stage, [[0.3, 0.3, 0.3]], [UP])


# -- a small bake of all three ------------------------------------------------------------------------

SKY = np.array([0.2, 0.5, 1.0])
"""Uniform dome radiance (W/(m^2 sr)): an unoccluded surface facing up receives pi L."""


@pytest.fixture(scope="module")
def baked_floor():
    """A 4 m floor of 32 triangles under a uniform dome, baked with light_probes, irradiance_grid and radiosity
    at small settings (a few seconds on 2 cores)."""
    from lit_scenes import merge, quad

    stage = new_stage(up_axis="Z")
    points, tris = merge([quad([x, y, 0], [1, 0, 0], [0, 1, 0]) for x in (-2, -1, 0, 1) for y in (-2, -1, 0, 1)])
    add_mesh(stage, "/World/Floor", points.tolist(), [3] * len(tris), tris.ravel().tolist())
    UsdLux.DomeLight.Define(stage, "/World/Sky").CreateColorAttr(Gf.Vec3f(*SKY))
    usdbake.bake(stage, processors=["light_probes", "irradiance_grid", "radiosity"], params={
        "light_probes": {"probes": 16, "rays": 64, "placement_rays": 16},
        "irradiance_grid": {"vertices": 27, "rays": 64},
        "form_factors": {"rays": 16, "target_patches": 16}, "radiosity": {"gather_rays": 4, "sky_samples": 64}})
    return stage


def test_a_bake_reads_back_as_its_primvars_and_as_pi_l(baked_floor):
    stage = baked_floor
    floor = stage.GetPrimAtPath("/World/Floor")
    vertices = world_points(stage, "/World/Floor")
    up = np.tile(UP, (len(vertices), 1))
    get = lambda name: np.asarray(floor.GetAttribute(f"primvars:bake:{name}").Get(), np.float64)  # noqa: E731
    np.testing.assert_allclose(usdbake.irradiance_at(stage, vertices, up, source="irradiance_grid"),
                               get("irradianceGrid"), rtol=FLOAT32_STORAGE)
    # The floor's 16 quads share positions, not points: a shared position reads the mean of its points.
    total = get("irradianceDirect") + get("irradianceIndirect")
    _, seam, count = np.unique(np.round(vertices, 6), axis=0, return_inverse=True, return_counts=True)
    seam = seam.ravel()
    mean = np.stack([np.bincount(seam, total[:, c]) for c in range(3)], axis=1) / count[:, None]
    np.testing.assert_allclose(usdbake.irradiance_at(stage, vertices, up, source="radiosity"), mean[seam],
                               rtol=FLOAT32_STORAGE)
    above = np.array([[0.3, 0.2, 0.5], [-1.2, 0.7, 1.0]])
    for source in ("light_probes", "irradiance_grid"):
        np.testing.assert_allclose(usdbake.irradiance_at(stage, above, up[:2], source=source),
                                   np.tile(math.pi * SKY, (2, 1)), rtol=BAKED_UNIFORM_SKY)
    np.testing.assert_allclose(usdbake.irradiance_at(stage, vertices, up, source="radiosity"),
                               np.tile(math.pi * SKY, (len(vertices), 1)), rtol=BAKED_UNIFORM_SKY)
    np.testing.assert_array_equal(usdbake.irradiance_at(stage, above, up[:2]),  # auto: the probes come first
                                  usdbake.irradiance_at(stage, above, up[:2], source="light_probes"))


def test_a_baked_probe_reads_its_own_sh(baked_floor):
    cloud = baked_floor.GetPrimAtPath("/usdbake/LightProbes")
    positions = np.asarray(cloud.GetAttribute("probePositions").Get(), np.float64)
    sh = np.asarray(cloud.GetAttribute("shCoefficients").Get(), np.float64).reshape(-1, 9, 3)
    normals = random_directions(len(positions), seed=4)
    expected = np.einsum("nk,nkc->nc", sh_basis(normals), sh)
    np.testing.assert_allclose(usdbake.irradiance_at(baked_floor, positions, normals, source="light_probes"),
                               expected, rtol=FLOAT32_BARYCENTRIC, atol=FLOAT32_BARYCENTRIC * np.abs(expected).max())


# -- errors ---------------------------------------------------------------------------------------------


@pytest.mark.parametrize("points, normals, message", [
    ([[0, 0]], [UP], r"points: expected shape \(N, 3\), got \(1, 2\)"),
    ([[0, 0, 0], [1, 1, 1]], [UP], "normals: 1 rows for 2 points"),
    ([[0, 0, 0], [0, np.nan, 0]], [UP, UP], r"points\[1\] = \(0.0, nan, 0.0\) is not finite"),
    ([[0, 0, 0]], [[0, 0, 2]], r"normals\[0\] = \(0.0, 0.0, 2.0\) has length 2, not 1"),
    ("here", [UP], "points: expected"),
])
def test_bad_queries_are_refused(points, normals, message):
    stage, _ = probe_stage()
    with pytest.raises(UsageError, match=message):
        usdbake.irradiance_at(stage, points, normals)


def test_an_unknown_or_missing_source_is_named():
    stage, _ = probe_stage()
    with pytest.raises(UsageError, match="source='probes': expected 'auto' or one of 'light_probes'"):
        usdbake.irradiance_at(stage, [[0, 0, 0]], [UP], source="probes")
    with pytest.raises(UsageError, match="no radiosity bake: looked for meshes with primvars:bake:irradianceDirect"):
        usdbake.irradiance_at(stage, [[0, 0, 0]], [UP], source="radiosity")
    bare = new_stage()
    add_mesh(bare, "/World/Floor", [(0, 0, 0), (1, 0, 0), (1, 1, 0)], [3], [0, 1, 2])
    with pytest.raises(UsageError, match="no baked irradiance: looked for a LightProbeCloud.*IrradianceVectorGrid"):
        usdbake.irradiance_at(bare, [[0, 0, 0]], [UP])
    with pytest.raises(UsageError, match="no such file"):
        usdbake.irradiance_at("/nonexistent/stage.usda", [[0, 0, 0]], [UP])
    with pytest.raises(UsageError, match="stage=NoneType: expected an open Usd.Stage or the path of a stage file"):
        usdbake.irradiance_at(None, [[0, 0, 0]], [UP])


def test_a_stage_file_reads_like_the_open_stage(tmp_path):
    stage, _ = probe_stage()
    stage.GetRootLayer().Export(str(tmp_path / "probes.usda"))
    point, normal = [[0.3, 0.3, 0.3]], [UP]
    np.testing.assert_array_equal(usdbake.irradiance_at(str(tmp_path / "probes.usda"), point, normal),
                                  usdbake.irradiance_at(stage, point, normal))


def test_baked_arrays_of_the_wrong_size_name_the_attribute():
    stage, _ = probe_stage()
    stage.GetPrimAtPath("/usdbake/LightProbes").GetAttribute("shCoefficients").Set(Vt.Vec3fArray(5))
    with pytest.raises(StageError, match="/usdbake/LightProbes.shCoefficients: 5 entries, expected 36"):
        usdbake.irradiance_at(stage, [[0.3, 0.3, 0.3]], [UP])
    sheet = new_stage()
    triangle_sheet(sheet, "/World/Sheet", np.ones((9, 3)), np.ones((9, 3)))
    sheet.GetPrimAtPath("/World/Sheet").GetAttribute("primvars:bake:irradianceIndirect").Set(Vt.Vec3fArray(4))
    with pytest.raises(StageError, match="/World/Sheet.primvars:bake:irradianceIndirect: 4 values .* for 9 points"):
        usdbake.irradiance_at(sheet, [[0.5, 0.5, 0.0]], [UP])
