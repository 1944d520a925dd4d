"""usdbake preview: camera, channel mapping, false colour, wire, spheres, compare and image files."""

from __future__ import annotations

import numpy as np
import OpenImageIO as oiio
import pytest
from pxr import Gf, Sdf, Usd, UsdGeom, UsdShade, Vt
from stage_builders import add_mesh, add_preview_material, new_stage
from tolerances import (ACES_WHITE, CONTRAST_MARGIN, EDGE_BAND, FLOAT32_LONG_CHAIN, FLOAT32_STORAGE, FRAME_EDGE_PX,
                        PIXEL_TOLERANCE, QUOTED_6_DECIMALS, VIRIDIS_TOLERANCE)

import usdbake
from usdbake.cli import main as cli
from usdbake.core.errors import UsageError
from usdbake.kernels.rgb9e5 import decode_rgb9e5
from usdbake.preview.camera import auto_camera
from usdbake.preview.channels import read_channel
from usdbake.preview.color import VIRIDIS, aces_fitted, false_color, luminance, srgb_decode
from usdbake.preview.compose import preview, sh_irradiance
from usdbake.preview.legend import text_mask
from usdbake.preview.raycast import polygon_edges
from usdbake.stages.extract import extract_scene

def grid_mesh(stage, path, size, n, height=0.0, material=None, double_sided=False):
    """An n x n grid of quads in the xz plane (Y-up), facing +y, centred at the origin."""
    ticks = np.linspace(-size / 2, size / 2, n + 1)
    points = [(x, height, z) for z in ticks for x in ticks]
    indices = []
    for j in range(n):
        for i in range(n):
            a = j * (n + 1) + i
            indices += [a, a + n + 1, a + n + 2, a + 1]  # counter-clockwise seen from +y
    mesh = add_mesh(stage, path, points, [4] * (n * n), indices, doubleSided=double_sided)
    if material is not None:
        bind(mesh, material)
    return mesh


def bind(mesh, material):
    UsdShade.MaterialBindingAPI.Apply(mesh.GetPrim()).Bind(material)


def box_mesh(stage, path, lo, hi):
    """Axis-aligned closed box with outward faces (counter-clockwise seen from outside)."""
    x0, y0, z0 = lo
    x1, y1, z1 = hi
    points = [(x0, y0, z0), (x1, y0, z0), (x1, y1, z0), (x0, y1, z0),
              (x0, y0, z1), (x1, y0, z1), (x1, y1, z1), (x0, y1, z1)]
    faces = [(0, 3, 2, 1), (4, 5, 6, 7), (0, 1, 5, 4), (3, 7, 6, 2), (0, 4, 7, 3), (1, 2, 6, 5)]
    return add_mesh(stage, path, points, [4] * 6, [i for f in faces for i in f])


def add_camera(stage, path, eye, target, up=(0, 1, 0), focal=35.0, aperture=(36.0, 27.0), offset=(0.0, 0.0)):
    camera = UsdGeom.Camera.Define(stage, path)
    matrix = Gf.Matrix4d().SetLookAt(Gf.Vec3d(*eye), Gf.Vec3d(*target), Gf.Vec3d(*up)).GetInverse()
    camera.AddTransformOp().Set(matrix)
    camera.CreateFocalLengthAttr(focal)
    camera.CreateHorizontalApertureAttr(aperture[0])
    camera.CreateVerticalApertureAttr(aperture[1])
    camera.CreateHorizontalApertureOffsetAttr(offset[0])
    camera.CreateVerticalApertureOffsetAttr(offset[1])
    camera.CreateClippingRangeAttr(Gf.Vec2f(0.01, 1000.0))
    return camera


def project_with_gf(stage, camera_path, point, width, height):
    """Pixel (x right, y down) of a world point through Gf.Frustum's view and projection matrices."""
    gf_camera = UsdGeom.Camera(stage.GetPrimAtPath(camera_path)).GetCamera(Usd.TimeCode.Default())
    frustum = gf_camera.frustum
    ndc = (frustum.ComputeViewMatrix() * frustum.ComputeProjectionMatrix()).Transform(Gf.Vec3d(*point))
    return np.array([(ndc[0] + 1) / 2 * width, (1 - ndc[1]) / 2 * height])


@pytest.fixture(scope="module")
def ao_stage():
    """A 4 x 4 m floor (16 x 16 quads) with a 1 m box on it, AO baked in-process, and a camera."""
    stage = new_stage(up_axis="Y")
    white = add_preview_material(stage, "/World/Looks/White", diffuse=(0.8, 0.8, 0.8))
    grid_mesh(stage, "/World/Floor", 4.0, 16, material=white)
    box = box_mesh(stage, "/World/Box", (-0.5, 0.0, -0.5), (0.5, 1.0, 0.5))
    bind(box, white)
    add_camera(stage, "/World/Cam", eye=(2.5, 3.0, 4.0), target=(0.0, 0.3, 0.0))
    # 64 rays per point: AO of the box top (1.0) and the floor at the box's foot (< 0.6) are far apart.
    usdbake.bake(stage, ["ambient_occlusion"], {"ambient_occlusion": {"samples": 64, "seed": 1}})
    return stage


def test_unoccluded_face_renders_brighter_than_occluded(ao_stage, tmp_path):
    width, height = 128, 96
    top = (0.0, 1.0, 0.0)      # box top centre: nothing above it (baked AO ~0.9)
    foot = (0.0, 0.0, 0.56)    # floor in front of the box's +z face, which the camera sees (AO ~0.2)
    ao_top = ao_stage.GetPrimAtPath("/World/Box").GetAttribute("primvars:bake:ao").Get()
    assert max(ao_top) > 0.9  # the baked data has the contrast this test relies on
    for style in ("shaded", "falsecolor"):
        report = preview(ao_stage, str(tmp_path / f"{style}.png"), camera="/World/Cam", channel="ao",
                         size=(width, height), style=style, legend=False, exposure=0.0)
        display = report["image"].display
        lum = luminance(srgb_decode(display))
        (tx, ty), (fx, fy) = (project_with_gf(ao_stage, "/World/Cam", p, width, height) for p in (top, foot))
        top_lum = lum[int(ty), int(tx)]
        foot_lum = lum[int(fy), int(fx)]
        assert top_lum > foot_lum + CONTRAST_MARGIN, (style, top_lum, foot_lum)


def test_false_color_legend_range_matches_data(ao_stage, tmp_path):
    report = preview(ao_stage, str(tmp_path / "legend.png"), camera="/World/Cam", channel="ao", size=(160, 120))
    values = np.concatenate([np.asarray(ao_stage.GetPrimAtPath(p).GetAttribute("primvars:bake:ao").Get())
                             for p in ("/World/Floor", "/World/Box")])
    image = report["image"]
    legend = image.legend
    assert legend.lo == pytest.approx(values.min(), abs=FLOAT32_STORAGE)
    assert legend.hi == pytest.approx(values.max(), abs=FLOAT32_STORAGE)
    assert legend.ticks[0] == legend.lo and legend.ticks[-1] == legend.hi
    assert report["range"] == [legend.lo, legend.hi]
    # The bar runs from the map's first colour (bottom) to its last (top).
    x = (legend.bar_x[0] + legend.bar_x[1]) // 2 - 1
    np.testing.assert_allclose(image.display[legend.bar_top, x], VIRIDIS[255], atol=FLOAT32_STORAGE)
    np.testing.assert_allclose(image.display[legend.bar_bottom, x], VIRIDIS[0], atol=FLOAT32_STORAGE)
    assert image.display.shape[1] == 160 and image.view_width < 160
    # A surface pixel's colour is the map of its interpolated value on that scale.
    frame_value = image.value[..., 0]
    hit = image.coverage > 0
    y, x = np.argwhere(hit)[len(np.argwhere(hit)) // 2]
    np.testing.assert_allclose(image.display[y, x], false_color(frame_value[y, x], legend.lo, legend.hi),
                               atol=FLOAT32_STORAGE)


def bright_quad_stage(offset=(0.0, 0.0), aperture=(36.0, 27.0)):
    """A 0.1 x 0.1 white quad at a known off-centre point, a dark floor, and a rotated camera."""
    stage = new_stage(up_axis="Y")
    dark = add_preview_material(stage, "/World/Looks/Dark", diffuse=(0.02, 0.02, 0.02))
    white = add_preview_material(stage, "/World/Looks/White", diffuse=(1.0, 1.0, 1.0))
    grid_mesh(stage, "/World/Floor", 6.0, 1, material=dark)
    center = np.array([0.7, 0.01, -0.4])
    h = 0.06
    quad = add_mesh(stage, "/World/Marker", [center + d for d in ((-h, 0, -h), (-h, 0, h), (h, 0, h), (h, 0, -h))],
                    [4], [0, 1, 2, 3])
    bind(quad, white)
    add_camera(stage, "/World/Cam", eye=(-1.0, 3.5, 2.5), target=(0.2, 0.0, -0.3), focal=30.0,
               aperture=aperture, offset=offset)
    return stage, center


@pytest.mark.parametrize("offset", [(0.0, 0.0), (3.0, -2.0)])
def test_stage_camera_is_honoured(tmp_path, offset):
    width, height = 128, 96
    stage, center = bright_quad_stage(offset)
    report = preview(stage, str(tmp_path / "cam.png"), camera="/World/Cam", size=(width, height), exposure=0.0)
    lum = luminance(srgb_decode(report["image"].display))
    ys, xs = np.nonzero(lum > 0.3)
    assert len(xs) >= 4, "the marker is not visible"
    centroid = np.array([xs.mean() + 0.5, ys.mean() + 0.5])
    expected = project_with_gf(stage, "/World/Cam", center, width, height)
    np.testing.assert_allclose(centroid, expected, atol=PIXEL_TOLERANCE)


def test_aperture_is_expanded_to_the_image_aspect(tmp_path):
    """A 36 x 24 aperture rendered at 4:3 shows what a 36 x 27 aperture shows (expandAperture conform)."""
    images = []
    for aperture in ((36.0, 24.0), (36.0, 27.0)):
        stage, _ = bright_quad_stage(aperture=aperture)
        images.append(preview(stage, str(tmp_path / "a.png"), camera="/World/Cam", size=(64, 48),
                              exposure=0.0)["image"].display)
    np.testing.assert_array_equal(images[0], images[1])


def test_vertex_values_interpolate_and_uniform_values_stay_per_face(tmp_path):
    """A ramp 0..1 across x as vertex data; two faces with 0.25 / 0.75 as uniform data; seen from above."""
    stage = new_stage(up_axis="Y")
    points = [(0, 0, 0), (1, 0, 0), (2, 0, 0), (0, 0, -1), (1, 0, -1), (2, 0, -1)]
    mesh = add_mesh(stage, "/World/Strip", points, [4, 4], [0, 1, 4, 3, 1, 2, 5, 4])
    ramp = UsdGeom.PrimvarsAPI(mesh).CreatePrimvar("bake:ramp", Sdf.ValueTypeNames.FloatArray,
                                                   UsdGeom.Tokens.vertex)
    ramp.Set(Vt.FloatArray([0.0, 0.5, 1.0, 0.0, 0.5, 1.0]))
    faces = UsdGeom.PrimvarsAPI(mesh).CreatePrimvar("bake:faces", Sdf.ValueTypeNames.FloatArray,
                                                    UsdGeom.Tokens.uniform)
    faces.Set(Vt.FloatArray([0.25, 0.75]))
    add_camera(stage, "/World/Top", eye=(1.0, 3.0, -0.5), target=(1.0, 0.0, -0.5), up=(0, 0, -1),
               aperture=(36.0, 27.0))
    width, height = 64, 48
    ramp_image = preview(stage, str(tmp_path / "r.png"), camera="/World/Top", channel="ramp",
                         size=(width, height), legend=False)["image"]
    face_image = preview(stage, str(tmp_path / "f.png"), camera="/World/Top", channel="faces",
                         size=(width, height), legend=False)["image"]
    gf_camera = UsdGeom.Camera(stage.GetPrimAtPath("/World/Top")).GetCamera(Usd.TimeCode.Default())
    frustum = gf_camera.frustum
    checked = 0
    for y in range(height):
        for x in range(width):
            if ramp_image.coverage[y, x] == 0:
                continue
            ray = frustum.ComputePickRay(Gf.Vec2d((x + 0.5) / width * 2 - 1, 1 - (y + 0.5) / height * 2))
            hit = ray.startPoint + ray.direction * (-ray.startPoint[1] / ray.direction[1])
            assert ramp_image.value[y, x, 0] == pytest.approx(hit[0] / 2, abs=FLOAT32_LONG_CHAIN)
            if abs(hit[0] - 1) > EDGE_BAND:
                assert face_image.value[y, x, 0] == pytest.approx(0.25 if hit[0] < 1 else 0.75, abs=FLOAT32_STORAGE)
            checked += 1
    assert checked > width * height / 4


def test_wire_marks_polygon_edges_not_triangulation_diagonals(tmp_path):
    stage = new_stage(up_axis="Y")
    add_mesh(stage, "/World/Quad", [(0, 0, 0), (1, 0, 0), (1, 0, -1), (0, 0, -1)], [4], [0, 1, 2, 3])
    add_camera(stage, "/World/Top", eye=(0.5, 2.0, -0.5), target=(0.5, 0.0, -0.5), up=(0, 0, -1),
               aperture=(36.0, 36.0))
    scene = extract_scene(stage)
    mask = polygon_edges(scene.tri_vertices, scene.tri_prim, scene.tri_face)
    assert sorted(np.unpackbits(mask.astype(np.uint8)[:, None], axis=1)[:, -3:].sum(axis=1)) == [2, 2]
    size = 64
    frame_report = preview(stage, str(tmp_path / "w.png"), camera="/World/Top", size=(size, size), wire=True)
    corners = [project_with_gf(stage, "/World/Top", p, size, size) for p in ((0, 0, 0), (1, 0, -1))]
    (x0, y0), (x1, y1) = corners
    lum = luminance(srgb_decode(frame_report["image"].display))
    dark = lum < 0.05
    # Pixels along the quad's border are wire; pixels along its diagonal (away from the border) are not.
    mid_y = int((y0 + y1) / 2)
    assert dark[mid_y, int(min(x0, x1))] or dark[mid_y, int(min(x0, x1)) + 1]
    for t in np.linspace(0.3, 0.7, 5):
        x, y = x0 + t * (x1 - x0), y0 + t * (y1 - y0)
        assert not dark[int(y), int(x)]
        x, y = x0 + t * (x1 - x0), y1 + t * (y0 - y1)
        assert not dark[int(y), int(x)]


def test_compare_rms_zero_for_identical_and_positive_for_different(ao_stage, tmp_path):
    first = tmp_path / "first.png"
    preview(ao_stage, str(first), camera="/World/Cam", channel="ao", size=(64, 48))
    same = preview(ao_stage, str(tmp_path / "same.png"), camera="/World/Cam", channel="ao", size=(64, 48),
                   compare=str(first))
    assert same["rms"] == 0.0
    written = oiio.ImageBuf(str(tmp_path / "same.png"))
    assert written.spec().width == 3 * 64
    other = preview(ao_stage, str(tmp_path / "other.png"), camera="/World/Cam", size=(64, 48), compare=str(first))
    assert other["rms"] > 0.01
    with pytest.raises(UsageError, match="differ in size"):
        preview(ao_stage, str(tmp_path / "x.png"), camera="/World/Cam", size=(32, 24), compare=str(first))


def test_exr_round_trips_floats(ao_stage, tmp_path):
    path = tmp_path / "ao.exr"
    report = preview(ao_stage, str(path), camera="/World/Cam", channel="ao", size=(48, 36), style="shaded",
                     exposure=1.0)
    image = report["image"]
    buffer = oiio.ImageBuf(str(path))
    spec = buffer.spec()
    assert list(spec.channelnames) == ["R", "G", "B", "A", "ao"]
    assert spec.format == oiio.FLOAT
    pixels = buffer.get_pixels(oiio.FLOAT)
    np.testing.assert_array_equal(pixels[..., :3], image.linear)
    np.testing.assert_array_equal(pixels[..., 3], image.coverage)
    np.testing.assert_array_equal(pixels[..., 4], image.value[..., 0])
    assert np.unique(pixels[..., 4]).size > 10  # real data, not a constant


def test_channel_sum_and_elements(ao_stage):
    scene = extract_scene(ao_stage)
    single = read_channel(ao_stage, scene, "ao")
    double = read_channel(ao_stage, scene, "ao+ao")
    np.testing.assert_allclose(double.corner_values, 2 * single.corner_values, rtol=FLOAT32_STORAGE)
    assert double.hi == pytest.approx(2 * single.hi)
    with pytest.raises(UsageError, match="no prim"):
        read_channel(ao_stage, scene, "nothingHere")
    with pytest.raises(UsageError, match="elementSize is 1"):
        read_channel(ao_stage, scene, "ao[2]")


def test_probes_are_drawn_as_spheres_where_they_project(tmp_path):
    stage, _ = bright_quad_stage()
    cloud = stage.DefinePrim("/World/Probes", "LightProbeCloud")
    positions = [(-0.5, 0.5, 0.0), (0.5, 0.8, -0.5)]
    cloud.CreateAttribute("probePositions", Sdf.ValueTypeNames.Point3fArray).Set(
        Vt.Vec3fArray([Gf.Vec3f(*p) for p in positions]))
    sh = np.zeros((2, 9, 3), np.float32)
    sh[:, 0] = 1.0 / 0.282095  # constant irradiance 1 in every direction
    cloud.CreateAttribute("shCoefficients", Sdf.ValueTypeNames.Float3Array).Set(
        Vt.Vec3fArray.FromNumpy(sh.reshape(-1, 3)))
    width, height = 128, 96
    report = preview(stage, str(tmp_path / "p.png"), camera="/World/Cam", size=(width, height), probes=True,
                     exposure=0.0)
    assert report["spheres"] == 2
    lum = luminance(srgb_decode(report["image"].display))
    for p in positions:
        x, y = project_with_gf(stage, "/World/Cam", p, width, height)
        assert lum[int(y), int(x)] > 0.1  # a lit sphere over the dark floor
    nothing = preview(stage, str(tmp_path / "g.png"), camera="/World/Cam", size=(32, 24), grid=True)
    assert any("nothing to draw" in m for m in nothing["messages"])


def test_sh_and_rgb9e5_helpers():
    normals = np.array([[0, 0, 1.0], [1.0, 0, 0]])
    sh = np.zeros((2, 9, 3), np.float32)
    sh[:, 2] = 1.0  # Y_1^0 = 0.488603 z
    np.testing.assert_allclose(sh_irradiance(sh, normals)[:, 0], [0.488603, 0.0], atol=QUOTED_6_DECIMALS)
    # RGB9E5: mantissa 256 with exponent 15 + 1 -> 256 * 2^(16 - 24) = 1.0
    packed = np.array([(16 << 27) | (256 << 18) | (128 << 9) | 256], np.uint32)
    np.testing.assert_allclose(decode_rgb9e5(packed), [[1.0, 0.5, 1.0]])


def test_auto_camera_frames_every_corner():
    rng = np.random.default_rng(7)  # fixed seed: 20 random boxes and aspects
    for _ in range(20):
        lo = rng.uniform(-100, 0, 3)
        hi = lo + rng.uniform(0.01, 50, 3)
        width, height = int(rng.integers(16, 800)), int(rng.integers(16, 800))
        for up in ("Y", "Z"):
            camera = auto_camera(lo, hi, up, width, height).conformed(width, height)
            corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
            pixels, depth = camera.project(corners, width, height)
            assert (depth > 0).all()
            assert (pixels >= -FRAME_EDGE_PX).all() and (pixels[:, 0] <= width + FRAME_EDGE_PX).all() \
                and (pixels[:, 1] <= height + FRAME_EDGE_PX).all()


def test_viridis_table_matches_matplotlib():
    matplotlib = pytest.importorskip("matplotlib")
    reference = matplotlib.colormaps["viridis"](np.linspace(0, 1, 256))[:, :3]
    np.testing.assert_allclose(VIRIDIS, reference, atol=VIRIDIS_TOLERANCE)
    lightness = luminance(srgb_decode(VIRIDIS))
    assert (np.diff(lightness) > 0).all()  # brighter means larger: the property the AO test relies on


def test_tone_curve_and_font():
    x = np.linspace(0, 20, 200)
    y = aces_fitted(x)
    assert (np.diff(y) >= 0).all() and y[0] == 0 and y[-1] == pytest.approx(1.0, abs=ACES_WHITE)
    mask = text_mask("0.25", 2)
    assert mask.shape == (10, 30) and mask.any()


def test_cli_preview_and_usage_errors(ao_stage, tmp_path, capsys):
    path = tmp_path / "stage.usda"
    ao_stage.Flatten().Export(str(path))
    out = tmp_path / "cli.png"
    assert cli.main(["preview", str(path), "-o", str(out), "--camera", "/World/Cam", "--channel", "ao",
                     "--size", "64x48"]) == 0
    assert oiio.ImageBuf(str(out)).spec().width == 64
    assert cli.main(["preview", str(path), "-o", str(out), "--compare", str(out), "--channel", "ao",
                     "--camera", "/World/Cam", "--size", "64x48"]) == 0
    assert "RMS difference: 0.000000" in capsys.readouterr().out
    for bad in (["--channel", "nope"], ["--size", "64"], ["--camera", "/World/Floor"], ["--camera", "/Nope"]):
        assert cli.main(["preview", str(path), "-o", str(out), *bad]) == cli.EXIT_USAGE, bad
    assert cli.main(["preview", str(tmp_path / "missing.usda"), "-o", str(out)]) == cli.EXIT_USAGE
    assert cli.main(["preview", str(path), "-o", str(tmp_path / "x.bmp2")]) == cli.EXIT_USAGE


def test_per_instance_primvar_colours_each_instance(tmp_path):
    """One value per PointInstancer instance: every instanced pixel shows one of the authored values."""
    stage = new_stage(up_axis="Y")
    grid_mesh(stage, "/World/Floor", 6.0, 1)
    box_mesh(stage, "/World/Protos/Box", (-0.2, 0.0, -0.2), (0.2, 0.4, 0.2))
    instancer = UsdGeom.PointInstancer.Define(stage, "/World/Scatter")
    instancer.CreatePrototypesRel().SetTargets([Sdf.Path("/World/Protos/Box")])
    positions = [(x, 0.0, z) for x in (-2.0, -1.0, 0.0, 1.0, 2.0) for z in (-1.0, 0.0, 1.0)]
    instancer.CreatePositionsAttr([Gf.Vec3f(*p) for p in positions])
    instancer.CreateProtoIndicesAttr([0] * len(positions))
    UsdGeom.Imageable(stage.GetPrimAtPath("/World/Protos")).MakeInvisible()
    values = np.linspace(0.1, 0.9, len(positions)).astype(np.float32)
    UsdGeom.PrimvarsAPI(instancer).CreatePrimvar("bake:level", Sdf.ValueTypeNames.FloatArray,
                                                 UsdGeom.Tokens.varying).Set(Vt.FloatArray(values.tolist()))
    add_camera(stage, "/World/Cam", eye=(0.0, 6.0, 4.0), target=(0.0, 0.0, 0.0))
    report = preview(stage, str(tmp_path / "i.png"), camera="/World/Cam", channel="level", size=(128, 96),
                     legend=False)
    shown = report["image"].value[..., 0]
    shown = shown[shown > 0]
    distance = np.abs(shown[:, None] - values[None, :])
    assert distance.min(axis=1).max() < FLOAT32_STORAGE  # constant per instance, never blended across instances
    assert set(distance.argmin(axis=1)) == set(range(len(positions)))  # every instance shows its value
    for k, p in enumerate(positions):
        x, y = project_with_gf(stage, "/World/Cam", (p[0], 0.4, p[2]), 128, 96)  # top face centre
        assert report["image"].value[int(y), int(x), 0] == pytest.approx(values[k], abs=FLOAT32_STORAGE)
