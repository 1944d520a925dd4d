"""preview/compose.py: --size parsing, the SH evaluation (the basis written out by hand, the Condon-Shortley
sign), a stage camera moved into the Scene's frame (against Gf.Frustum, far from the origin and at a time),
probe and grid spheres read off the stage (positions through transforms, decoded RGB9E5 means), their colours
in a render (SH irradiance as albedo E / pi at the sphere's centre pixel, headlit grid colours), and
``preview``'s report and its refusals of bad options."""

from __future__ import annotations

import math

import numpy as np
import OpenImageIO as oiio
import pytest
from pxr import Gf, Sdf, Usd, UsdGeom, Vt
from stage_builders import add_mesh, add_preview_material, add_xform, bind, new_stage
from tolerances import FLOAT32_STORAGE, FLOAT64_AMPLIFIED, PIXEL_TOLERANCE

from usdbake.core.errors import UsageError
from usdbake.kernels.rgb9e5 import encode_rgb9e5
from usdbake.preview.camera import auto_camera
from usdbake.preview.color import BACKGROUND, luminance, srgb_decode
from usdbake.preview.compose import (CONDON_SHORTLEY_SIGN, SPHERE_ALBEDO, SPHERE_RADIUS_RELATIVE, camera_from_stage,
                                     grid_spheres, parse_size, preview, probe_spheres, sh_irradiance)
from usdbake.stages.extract import extract_scene

C0 = 0.5 * math.sqrt(1 / math.pi)
C1 = math.sqrt(3 / (4 * math.pi))
C2 = 0.5 * math.sqrt(15 / math.pi)
C3 = 0.25 * math.sqrt(5 / math.pi)
C4 = 0.25 * math.sqrt(15 / math.pi)


# --------------------------------------------------------------------------------------------------
# parse_size and sh_irradiance


@pytest.mark.parametrize("text, size", [("640x480", (640, 480)), (" 64 X 48 ", (64, 48)), ("1x1", (1, 1)),
                                        ("16384x16384", (16384, 16384))])
def test_parse_size(text, size):
    assert parse_size(text) == size


@pytest.mark.parametrize("text, message", [("64", "expected WIDTHxHEIGHT"), ("64x", "expected WIDTHxHEIGHT"),
                                           ("-4x3", "expected WIDTHxHEIGHT"), ("4.5x3", "expected WIDTHxHEIGHT"),
                                           ("", "expected WIDTHxHEIGHT"), (None, "expected WIDTHxHEIGHT"),
                                           ("0x10", "within 1..16384"), ("16385x2", "within 1..16384")])
def test_parse_size_refuses(text, message):
    with pytest.raises(UsageError, match=message):
        parse_size(text)


def sh_by_hand(sh, n):
    """The real orthonormal L2 basis (no Condon-Shortley phase) written out, summed per channel."""
    x, y, z = n
    basis = [C0, C1 * y, C1 * z, C1 * x, C2 * x * y, C2 * y * z, C3 * (3 * z * z - 1), C2 * x * z,
             C4 * (x * x - y * y)]
    return sum(b * sh[k] for k, b in enumerate(basis))


def test_sh_irradiance_evaluates_the_basis():
    rng = np.random.default_rng(4)  # fixed seed: 10 random SH sets and directions
    sh = rng.normal(size=(10, 9, 3)).astype(np.float32)
    normals = rng.normal(size=(10, 3))
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    got = sh_irradiance(sh, normals)
    assert got.shape == (10, 3) and got.dtype == np.float32
    expected = np.array([sh_by_hand(sh[i].astype(np.float64), normals[i]) for i in range(10)])
    np.testing.assert_allclose(got, expected, atol=FLOAT32_STORAGE * 10)  # 9 float32 terms of order 1


def test_condon_shortley_flips_the_odd_m_coefficients():
    # m = k - l (l + 1): k = 1 (m -1), 3 (m +1), 5 (m -1), 7 (m +1) are odd.
    np.testing.assert_array_equal(CONDON_SHORTLEY_SIGN, [1, -1, 1, -1, 1, -1, 1, -1, 1])
    rng = np.random.default_rng(6)  # fixed seed: one SH set, five directions
    sh = rng.normal(size=(5, 9, 3)).astype(np.float32)
    normals = rng.normal(size=(5, 3))
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    flipped = sh * np.array([1, -1, 1, -1, 1, -1, 1, -1, 1], np.float32)[:, None]
    np.testing.assert_allclose(sh_irradiance(sh, normals, condon_shortley=True), sh_irradiance(flipped, normals),
                               atol=FLOAT32_STORAGE)


# --------------------------------------------------------------------------------------------------
# Stage cameras


def add_camera(stage, path, eye, target, focal=35.0, aperture=(36.0, 24.0), time=None):
    camera = UsdGeom.Camera.Define(stage, path)
    op = camera.GetPrim().GetAttribute("xformOp:transform")
    op = UsdGeom.Xformable(camera).AddTransformOp() if not op else UsdGeom.XformOp(op)
    matrix = Gf.Matrix4d().SetLookAt(Gf.Vec3d(*eye), Gf.Vec3d(*target), Gf.Vec3d(0, 1, 0)).GetInverse()
    op.Set(matrix, Usd.TimeCode.Default() if time is None else Usd.TimeCode(time))
    camera.CreateFocalLengthAttr(focal)
    camera.CreateHorizontalApertureAttr(aperture[0])
    camera.CreateVerticalApertureAttr(aperture[1])
    return camera


def gf_pixels(stage, path, world_points, width, height, time=None):
    """Pixels of world points by Gf.Frustum's view and projection matrices (the aperture as authored)."""
    code = Usd.TimeCode.Default() if time is None else Usd.TimeCode(time)
    frustum = UsdGeom.Camera(stage.GetPrimAtPath(path)).GetCamera(code).frustum
    matrix = frustum.ComputeViewMatrix() * frustum.ComputeProjectionMatrix()
    ndc = np.array([matrix.Transform(Gf.Vec3d(*map(float, p))) for p in world_points])
    return np.stack([(ndc[:, 0] + 1) / 2 * width, (1 - ndc[:, 1]) / 2 * height], axis=1)


def far_stage(offset=(1000.0, 20.0, -500.0)):
    """A 2 x 2 floor 1000 units from the origin, so the Scene's origin is far from zero."""
    stage = new_stage(up_axis="Y")
    ox, oy, oz = offset
    add_mesh(stage, "/World/Floor", [(ox - 1, oy, oz - 1), (ox - 1, oy, oz + 1), (ox + 1, oy, oz + 1),
                                     (ox + 1, oy, oz - 1)], [4], [0, 1, 2, 3])
    return stage, np.array(offset)


def test_stage_camera_projects_like_gf_in_the_scenes_frame():
    stage, centre = far_stage()
    add_camera(stage, "/World/Cam", centre + (2.0, 3.0, 4.0), centre + (0.2, 0.0, -0.1))
    scene = extract_scene(stage)
    assert np.linalg.norm(scene.origin) > 100  # the frame really is moved
    camera = camera_from_stage(stage, "/World/Cam", scene)
    assert camera.projection == "perspective" and camera.focal_length == pytest.approx(35.0)
    rng = np.random.default_rng(8)  # fixed seed: points around the floor
    world = centre + rng.uniform(-1, 1, (20, 3))
    pixels, depth = camera.project(world - scene.origin, 360, 240)  # 36 x 24 aperture: no conform needed
    assert (depth > 0).all()
    np.testing.assert_allclose(pixels, gf_pixels(stage, "/World/Cam", world, 360, 240), atol=FLOAT32_STORAGE * 360)


def test_stage_camera_is_read_at_the_time_asked_for():
    stage, centre = far_stage((0.0, 0.0, 0.0))
    add_camera(stage, "/World/Cam", (0, 5, 5), (0, 0, 0), time=1.0)
    add_camera(stage, "/World/Cam", (5, 5, 0), (0, 0, 0), time=2.0)
    scene = extract_scene(stage)
    np.testing.assert_allclose(camera_from_stage(stage, "/World/Cam", scene, time=2.0).eye, (5, 5, 0),
                               atol=FLOAT64_AMPLIFIED)
    np.testing.assert_allclose(camera_from_stage(stage, "/World/Cam", scene, time=1.0).eye, (0, 5, 5),
                               atol=FLOAT64_AMPLIFIED)


def test_orthographic_stage_cameras_stay_orthographic():
    stage, _ = far_stage((0.0, 0.0, 0.0))
    camera = add_camera(stage, "/World/Ortho", (0, 5, 0.001), (0, 0, 0))
    camera.CreateProjectionAttr(UsdGeom.Tokens.orthographic)
    assert camera_from_stage(stage, "/World/Ortho", extract_scene(stage)).projection == "orthographic"


@pytest.mark.parametrize("path, message", [("/World/Nope", "no such prim .*cameras in the stage: /World/Cam"),
                                           ("/World/Floor", "is a Mesh, not a Camera"),
                                           ("not a path!", "no such prim")])
def test_a_camera_that_is_not_there_is_a_usage_error(path, message):
    stage, _ = far_stage((0.0, 0.0, 0.0))
    add_camera(stage, "/World/Cam", (0, 5, 5), (0, 0, 0))
    with pytest.raises(UsageError, match=message):
        camera_from_stage(stage, path, extract_scene(stage))


# --------------------------------------------------------------------------------------------------
# Probe and grid spheres


def add_probe_cloud(stage, path, positions, sh=None, basis=None, translate=None):
    if translate is not None:
        add_xform(stage, path.rsplit("/", 1)[0], translate=translate)
    cloud = stage.DefinePrim(path, "LightProbeCloud")
    cloud.CreateAttribute("probePositions", Sdf.ValueTypeNames.Point3fArray).Set(
        Vt.Vec3fArray([Gf.Vec3f(*map(float, p)) for p in positions]))
    if sh is not None:
        cloud.CreateAttribute("shCoefficients", Sdf.ValueTypeNames.Float3Array).Set(
            Vt.Vec3fArray.FromNumpy(np.asarray(sh, np.float32).reshape(-1, 3)))
    if basis is not None:
        cloud.CreateAttribute("shBasis", Sdf.ValueTypeNames.Token).Set(basis)
    return cloud


def add_vector_grid(stage, path, resolution, origin, cell, colours=None, per_vertex=6):
    grid = stage.DefinePrim(path, "IrradianceVectorGrid")
    grid.CreateAttribute("resolution", Sdf.ValueTypeNames.Int3).Set(Gf.Vec3i(*resolution))
    grid.CreateAttribute("gridOrigin", Sdf.ValueTypeNames.Point3f).Set(Gf.Vec3f(*map(float, origin)))
    grid.CreateAttribute("cellSize", Sdf.ValueTypeNames.Float3).Set(Gf.Vec3f(*map(float, cell)))
    grid.CreateAttribute("vectorsPerVertex", Sdf.ValueTypeNames.Int).Set(per_vertex)
    if colours is not None:
        grid.CreateAttribute("colorsRGB9E5", Sdf.ValueTypeNames.UIntArray).Set(
            Vt.UIntArray([int(c) for c in np.asarray(colours).ravel()]))
    return grid


def test_probe_spheres_are_placed_through_transforms_with_their_sh():
    stage, centre = far_stage((10.0, 0.0, 0.0))
    sh = np.arange(2 * 9 * 3, dtype=np.float32).reshape(2, 9, 3)
    add_probe_cloud(stage, "/World/Rig/Probes", [(0, 1, 0), (1, 2, 3)], sh=sh, translate=(10, 0, 0),
                    basis="realOrthonormalCondonShortley")
    add_probe_cloud(stage, "/World/More", [(5, 5, 5)])  # no SH: zeros
    scene = extract_scene(stage)
    spheres = probe_spheres(stage, scene, None)
    world = np.array([(10, 1, 0), (11, 2, 3), (5, 5, 5)], np.float64)
    np.testing.assert_allclose(spheres.centers, world - scene.origin, atol=FLOAT32_STORAGE * 10)
    assert spheres.centers.dtype == np.float32
    # read into the real orthonormal basis: the Condon-Shortley phase (-1)^m flips the odd-m coefficients,
    # SH index k = l^2 + l + m: m = -1 and +1 of l = 1 (k 1, 3) and of l = 2 (k 5, 7)
    phase = np.array([1, -1, 1, -1, 1, -1, 1, -1, 1], np.float32)
    np.testing.assert_array_equal(spheres.sh[:2], sh * phase[:, None])
    np.testing.assert_array_equal(spheres.sh[2], 0.0)
    np.testing.assert_array_equal(spheres.colors, np.float32(SPHERE_ALBEDO))
    assert not spheres.condon_shortley and spheres.source == "/World/Rig/Probes, /World/More"


def test_probe_sh_of_the_wrong_size_is_left_out():
    stage, _ = far_stage()
    add_probe_cloud(stage, "/World/Probes", [(0, 1, 0), (1, 2, 3)], sh=np.ones((9, 3)))  # one probe's worth
    spheres = probe_spheres(stage, extract_scene(stage), None)
    assert len(spheres.centers) == 2 and not spheres.sh.any() and not spheres.condon_shortley


def test_no_probe_cloud_or_grid_means_no_spheres():
    stage, _ = far_stage()
    stage.DefinePrim("/World/Empty", "LightProbeCloud")  # no positions
    add_vector_grid(stage, "/World/Flat", (0, 2, 2), (0, 0, 0), (1, 1, 1))  # no vertices
    scene = extract_scene(stage)
    assert probe_spheres(stage, scene, None) is None and grid_spheres(stage, scene, None) is None


def test_grid_spheres_sit_on_the_lattice_coloured_by_their_mean_vector():
    stage, _ = far_stage((0.0, 0.0, 0.0))
    add_xform(stage, "/World/Lattice", translate=(1.0, 2.0, 3.0))
    # Per vertex: three vectors (1, 0.5, 0.25) and three (0, 0.5, 0.75) times the vertex number + 1; all
    # exact in RGB9E5, so the mean is (0.5, 0.5, 0.5) x (v + 1).
    vertices = 2 * 3 * 1
    colours = np.array([[(v + 1) * np.array(c) for c in [(1, 0.5, 0.25)] * 3 + [(0, 0.5, 0.75)] * 3]
                        for v in range(vertices)])
    add_vector_grid(stage, "/World/Lattice/Grid", (2, 3, 1), (0.5, 0.0, -1.0), (0.5, 1.0, 2.0),
                    encode_rgb9e5(colours))
    scene = extract_scene(stage)
    spheres = grid_spheres(stage, scene, None)
    lattice = np.array([(1.0 + 0.5 + 0.5 * i, 2.0 + j, 3.0 - 1.0) for j in range(3) for i in range(2)])  # x fastest
    np.testing.assert_allclose(spheres.centers, lattice - scene.origin, atol=FLOAT32_STORAGE * 10)
    np.testing.assert_array_equal(spheres.colors, 0.5 * (np.arange(vertices)[:, None] + 1.0) * np.ones(3))
    assert spheres.sh is None and spheres.source == "/World/Lattice/Grid"


def test_grid_colours_of_the_wrong_count_fall_back_to_the_sphere_albedo():
    stage, _ = far_stage()
    add_vector_grid(stage, "/World/Grid", (2, 1, 1), (0, 0, 0), (1, 1, 1), encode_rgb9e5(np.ones((5, 3))))
    spheres = grid_spheres(stage, extract_scene(stage), None)
    np.testing.assert_array_equal(spheres.colors, np.full((2, 3), SPHERE_ALBEDO, np.float32))


PROBE = np.array([0.0, 0.5, 0.0])


def sphere_stage(tmp_path, view_from):
    """A dark 2 x 2 floor, a camera 0.5 from PROBE looking at it from ``view_from`` (a unit direction)."""
    stage = new_stage(up_axis="Y")
    dark = add_preview_material(stage, "/World/Looks/Dark", diffuse=(0.05, 0.05, 0.05))
    bind(add_mesh(stage, "/World/Floor", [(-1, 0, -1), (-1, 0, 1), (1, 0, 1), (1, 0, -1)], [4], [0, 1, 2, 3]).GetPrim(),
         dark)
    up = (0, 0, 1) if abs(view_from[1]) > 0.9 else (0, 1, 0)
    camera = UsdGeom.Camera.Define(stage, "/World/Cam")
    eye = PROBE + 0.5 * np.asarray(view_from, float)
    matrix = Gf.Matrix4d().SetLookAt(Gf.Vec3d(*eye), Gf.Vec3d(*PROBE), Gf.Vec3d(*up)).GetInverse()
    camera.AddTransformOp().Set(matrix)
    camera.CreateFocalLengthAttr(100.0)
    camera.CreateHorizontalApertureAttr(36.0)
    camera.CreateVerticalApertureAttr(36.0 * 49 / 65)
    return stage


def centre_pixel(stage, tmp_path, **options):
    """Linear colour of the 65 x 49 render's centre pixel, whose ray runs through PROBE's centre."""
    report = preview(stage, str(tmp_path / "s.exr"), camera="/World/Cam", size=(65, 49), exposure=0.0, **options)
    image = report["image"]
    assert image.coverage[24, 32] == 1 and image.value[24, 32].sum() == 0  # a sphere: drawn, no channel value
    return report, image.linear[24, 32]


def test_a_probe_shows_its_sh_irradiance_as_a_lambertian_sphere(tmp_path):
    stage = sphere_stage(tmp_path, (0, 0, 1))
    sh = np.zeros((1, 9, 3), np.float32)
    sh[0, 0] = [1 / C0, 0.5 / C0, 0.25 / C0]  # E = (1, 0.5, 0.25) in every direction
    add_probe_cloud(stage, "/World/Probes", [PROBE], sh=sh)
    report, colour = centre_pixel(stage, tmp_path, probes=True)
    assert report["spheres"] == 1
    np.testing.assert_allclose(colour, SPHERE_ALBEDO * np.array([1, 0.5, 0.25]) / np.pi, rtol=FLOAT32_STORAGE)
    # The sphere's radius is a share of the scene's diagonal (the floor's: sqrt 8): at 0.5 units with
    # f = 100 mm over 36 mm and 65 pixels, it spans about 2 r f / (0.5 x 36) x 65 pixels across.
    radius_px = SPHERE_RADIUS_RELATIVE * math.sqrt(8) * 100 / (0.5 * 36) * 65
    row = report["image"].coverage[24]
    assert abs(row.sum() - 2 * radius_px) <= 2  # a chord through the centre, to whole pixels


@pytest.mark.parametrize("basis, lit", [(None, True), ("realOrthonormal", True),
                                        ("realOrthonormalCondonShortley", False)])
def test_the_condon_shortley_basis_turns_the_x_lobe_around(tmp_path, basis, lit):
    """SH with only the x coefficient 1 / C1: E(n) = n_x, or -n_x with the Condon-Shortley phase. Seen from
    +x, the centre pixel's normal is +x: lit (E = 1) or black (E = -1, clamped to 0)."""
    stage = sphere_stage(tmp_path, (1, 0, 0))
    sh = np.zeros((1, 9, 3), np.float32)
    sh[0, 3] = 1 / C1
    add_probe_cloud(stage, "/World/Probes", [PROBE], sh=sh, basis=basis)
    _, colour = centre_pixel(stage, tmp_path, probes=True)
    np.testing.assert_allclose(colour, SPHERE_ALBEDO / np.pi if lit else 0.0, rtol=FLOAT32_STORAGE,
                               atol=FLOAT32_STORAGE)


def test_grid_spheres_show_their_colour_under_the_headlight_beside_sh_probes(tmp_path):
    stage = sphere_stage(tmp_path, (0, 1, 0))  # from straight above
    add_vector_grid(stage, "/World/Grid", (1, 1, 1), PROBE, (1, 1, 1),
                    encode_rgb9e5(np.array([(0.5, 0.25, 0.125)] * 6)))
    sh = np.zeros((1, 9, 3), np.float32)
    sh[0, 0] = 1 / C0
    add_probe_cloud(stage, "/World/Probes", [(0.9, 0.05, 0.9)], sh=sh)  # elsewhere, with SH
    report, colour = centre_pixel(stage, tmp_path, probes=True, grid=True)
    assert report["spheres"] == 2
    np.testing.assert_allclose(colour, [0.5, 0.25, 0.125], rtol=FLOAT32_STORAGE)  # facing 1: headlight 1
    _, alone = centre_pixel(stage, tmp_path, grid=True)
    np.testing.assert_allclose(alone, [0.5, 0.25, 0.125], rtol=FLOAT32_STORAGE)


def test_asking_for_spheres_that_are_not_there_says_so(tmp_path):
    stage = sphere_stage(tmp_path, (0, 0, 1))
    report = preview(stage, str(tmp_path / "n.png"), camera="/World/Cam", size=(32, 24), probes=True, grid=True)
    assert report["spheres"] == 0
    assert any("--probes: no LightProbeCloud" in m and "nothing to draw" in m for m in report["messages"])
    assert any("--grid: no IrradianceVectorGrid" in m and "nothing to draw" in m for m in report["messages"])


# --------------------------------------------------------------------------------------------------
# preview: the report and refusals


@pytest.fixture
def lit_stage(tmp_path):
    """A floor with a scalar and a colour channel, a camera, written to a file."""
    stage = new_stage(up_axis="Y")
    mesh = add_mesh(stage, "/World/Floor", [(-1, 0, -1), (-1, 0, 1), (1, 0, 1), (1, 0, -1)], [4], [0, 1, 2, 3])
    api = UsdGeom.PrimvarsAPI(mesh)
    api.CreatePrimvar("bake:ao", Sdf.ValueTypeNames.FloatArray, UsdGeom.Tokens.vertex).Set(
        Vt.FloatArray([0.2, 0.4, 0.6, 0.8]))
    api.CreatePrimvar("bake:tint", Sdf.ValueTypeNames.Color3fArray, UsdGeom.Tokens.constant).Set(
        Vt.Vec3fArray([Gf.Vec3f(1, 0.5, 0.25)]))
    add_camera(stage, "/World/Cam", (0, 3, 3), (0, 0, 0), aperture=(36.0, 27.0))
    path = tmp_path / "lit.usda"
    stage.GetRootLayer().Export(str(path))
    return str(path)


def test_the_report_says_what_was_drawn(lit_stage, tmp_path):
    out = tmp_path / "sub" / "ao.png"
    report = preview(lit_stage, str(out), camera="/World/Cam", channel="ao", size=(120, 90))
    assert out.exists() and oiio.ImageBuf(str(out)).spec().width == 120
    assert report["mode"] == "falsecolor" and report["size"] == [120, 90] and report["camera"] == "/World/Cam"
    assert report["view_width"] < 120 and report["image"].view_width == report["view_width"]
    assert report["range"] == pytest.approx([0.2, 0.8]) and report["triangles"] == 2 and report["spheres"] == 0
    assert report["attributes"] == ["/World/Floor.primvars:bake:ao"] and report["exposure"] == 0.0
    assert set(report["timings"]) == {"read_stage", "read_channel", "build_bvh", "camera", "render", "write_image"}
    colour = preview(lit_stage, str(tmp_path / "t.png"), camera="/World/Cam", channel="tint", size=(40, 30))
    assert colour["mode"] == "shaded" and colour["range"] is None and colour["view_width"] == 40
    plain = preview(lit_stage, str(tmp_path / "p.png"), camera="/World/Cam", size=(40, 30))
    assert plain["mode"] == "albedo" and "attributes" not in plain


def test_a_given_range_sets_the_legend(lit_stage, tmp_path):
    report = preview(lit_stage, str(tmp_path / "r.png"), camera="/World/Cam", channel="ao", size=(120, 90),
                     value_range=(0.0, 2.0))
    assert report["range"] == [0.0, 2.0]
    assert (report["image"].legend.lo, report["image"].legend.hi) == (0.0, 2.0)
    shaded = preview(lit_stage, str(tmp_path / "s.png"), camera="/World/Cam", channel="ao", size=(40, 30),
                     style="shaded")
    assert shaded["mode"] == "shaded" and shaded["image"].legend is None
    no_legend = preview(lit_stage, str(tmp_path / "n.png"), camera="/World/Cam", channel="ao", size=(40, 30),
                        legend=False)
    assert no_legend["view_width"] == 40 and no_legend["image"].display.shape == (30, 40, 3)


@pytest.mark.parametrize("options, message", [
    (dict(camera="/World/Cam", orbit=(0.0, 10.0)), "--camera and --orbit exclude each other"),
    (dict(style="neon"), "--style 'neon'"),
    (dict(channel="ao", value_range=(1.0, 1.0)), "the low end must be below the high end"),
    (dict(channel="ao", value_range=(2.0, 1.0)), "the low end must be below the high end"),
    (dict(channel="tint", style="falsecolor"), "needs a scalar channel"),
    (dict(channel="ao", size=(12, 90)), "too narrow for the legend"),
    (dict(orbit=(0.0, 91.0)), "elevation must be within -90..90"),
    (dict(channel="nothing"), "no prim"),
    (dict(camera="/World/Floor"), "not a Camera"),
])
def test_bad_options_are_usage_errors(lit_stage, tmp_path, options, message):
    options.setdefault("size", (40, 30))
    with pytest.raises(UsageError, match=message):
        preview(lit_stage, str(tmp_path / "x.png"), **options)


def test_a_missing_stage_is_a_usage_error(tmp_path):
    with pytest.raises(UsageError, match="no such file"):
        preview(str(tmp_path / "missing.usda"), str(tmp_path / "x.png"))


def test_an_empty_stage_renders_background_with_a_message(tmp_path):
    stage = new_stage(up_axis="Y")
    report = preview(stage, str(tmp_path / "e.png"), size=(16, 12))
    assert report["triangles"] == 0 and report["camera"] == "auto"
    assert any("no renderable meshes" in m for m in report["messages"])
    np.testing.assert_array_equal(report["image"].display, np.broadcast_to(BACKGROUND, (12, 16, 3)))


def test_orbit_places_the_automatic_camera(tmp_path):
    """A bright marker on a dark floor lands where auto_camera with the orbit's angles projects it."""
    stage = new_stage(up_axis="Y")
    dark = add_preview_material(stage, "/World/Looks/Dark", diffuse=(0.02, 0.02, 0.02))
    white = add_preview_material(stage, "/World/Looks/White", diffuse=(1.0, 1.0, 1.0))
    bind(add_mesh(stage, "/World/Floor", [(-2, 0, -2), (-2, 0, 2), (2, 0, 2), (2, 0, -2)], [4],
                  [0, 1, 2, 3]).GetPrim(), dark)
    marker = np.array([0.8, 0.01, -0.6])
    h = 0.08
    bind(add_mesh(stage, "/World/Marker", [marker + d for d in ((-h, 0, -h), (-h, 0, h), (h, 0, h), (h, 0, -h))],
                  [4], [0, 1, 2, 3]).GetPrim(), white)
    width, height = 96, 72
    report = preview(stage, str(tmp_path / "o.png"), orbit=(120.0, 50.0), size=(width, height), exposure=0.0)
    assert report["camera"] == "auto (azimuth 120, elevation 50)"
    scene = extract_scene(stage)
    camera = auto_camera(*scene.bounds, "Y", width, height, azimuth_deg=120.0, elevation_deg=50.0).conformed(
        width, height)
    expected, _ = camera.project(marker - scene.origin, width, height)
    bright = luminance(srgb_decode(report["image"].display)) > 0.3
    ys, xs = np.nonzero(bright)
    assert len(xs) >= 4
    np.testing.assert_allclose([xs.mean() + 0.5, ys.mean() + 0.5], expected[0], atol=PIXEL_TOLERANCE)


def test_each_probe_cloud_keeps_its_own_sh_basis(tmp_path):
    stage = sphere_stage(tmp_path, (1, 0, 0))
    sh = np.zeros((1, 9, 3), np.float32)
    sh[0, 3] = 1 / C1  # E(n) = n_x in the realOrthonormal basis: 1 at the centre pixel seen from +x
    add_probe_cloud(stage, "/World/Plain", [PROBE], sh=sh, basis="realOrthonormal")
    add_probe_cloud(stage, "/World/Phased", [(-0.9, 0.05, 0.9)], sh=sh, basis="realOrthonormalCondonShortley")
    _, colour = centre_pixel(stage, tmp_path, probes=True)
    np.testing.assert_allclose(colour, SPHERE_ALBEDO / np.pi, rtol=FLOAT32_STORAGE)
