"""The daylight family's texture target (sky_visibility, interreflection, daylight, annual_daylight with
target=texture) end to end through the hook, against closed forms at each texel's own point:

- sky exposure beside a long wall of height h at distance d: 1/2 (1 + d / sqrt(d^2 + h^2)) (the 2D view factor
  of an infinitely long strip, Hottel's crossed strings);
- irradiance beside an infinitely tall wall of reflectance rho under a uniform sky L, the floor black and no
  ground outside: pi L (1/2 + rho / 4) (half the sky, plus the wall's radiance rho L / 2 over half the
  hemisphere);
- an open floor over a year: the weather file's global horizontal illuminance, daylight factor 100 %.

The meshes stay byte-identical, the files are described on each mesh, and a daylight per time is a
time-sampled file attribute.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from pxr import Sdf, Usd

from lightmap_checks import composed_meshes, read_image
from stage_builders import add_mesh, add_preview_material, bind, new_stage
from tolerances import SKY_PATCH_INTEGRATION

import usdbake

FAR = 400.0
"""Half-length of the walls (m): an 'infinitely long' wall to within d / FAR of the view factors."""
SAMPLE_RAYS = 4 * 128
"""Rays a texel's exposure is estimated from at the defaults (4 per patch, ~128 of 256 patches above a
floor): its standard deviation is at most sqrt(1/4 / SAMPLE_RAYS) (a Bernoulli share)."""
TEXEL_SIGMA = np.sqrt(0.25 / SAMPLE_RAYS)


def floor_and_wall(tmp_path: Path, height: float, floor_albedo: float, wall_albedo: float) -> Usd.Stage:
    """Y-up metres: a 1 m floor (x in [0.25, 1.25], z in [0, 1], st = its xz) beside the wall x = 0 of the given
    height and length 2 FAR (bake:skip: it occludes and reflects but receives nothing)."""
    stage = new_stage(up_axis="Y", meters_per_unit=1.0)
    floor = add_mesh(stage, "/World/Floor", [(0.25, 0, 0), (0.25, 0, 1), (1.25, 0, 1), (1.25, 0, 0)], [4],
                     [0, 1, 2, 3])
    st = floor.GetPrim().CreateAttribute("primvars:st", Sdf.ValueTypeNames.TexCoord2fArray)
    st.Set([(0, 0), (0, 1), (1, 1), (1, 0)])
    floor.GetPrim().GetAttribute("primvars:st").SetMetadata("interpolation", "faceVarying")
    wall = add_mesh(stage, "/World/Wall", [(0, 0, -FAR), (0, height, -FAR), (0, height, FAR), (0, 0, FAR)], [4],
                    [0, 1, 2, 3])
    wall.GetPrim().CreateAttribute("bake:skip", Sdf.ValueTypeNames.Bool).Set(True)
    bind(floor.GetPrim(), add_preview_material(stage, "/World/Looks/Floor", diffuse=(floor_albedo,) * 3))
    bind(wall.GetPrim(), add_preview_material(stage, "/World/Looks/Wall", diffuse=(wall_albedo,) * 3))
    path = tmp_path / "floor.usda"
    stage.GetRootLayer().Export(str(path))
    return Usd.Stage.Open(str(path))


def texel_centres_x(size: int) -> np.ndarray:
    """(size, size) x of each texel centre's point on the floor, in file rows (row 0 at the top: v = 1).
    st = (x - 0.25, z), so u = x - 0.25."""
    u = (np.arange(size) + 0.5) / size
    return np.broadcast_to(0.25 + u[None, :], (size, size))


def lightmap(stage: Usd.Stage, prim: str, channel: str, time=Usd.TimeCode.Default()) -> np.ndarray:
    attribute = stage.GetPrimAtPath(prim).GetAttribute(f"bake:lightmap:{channel}:file")
    return read_image(attribute.Get(time).resolvedPath)


def test_sky_exposure_per_texel_follows_the_wall_view_factor(tmp_path):
    height = 1.0
    stage = floor_and_wall(tmp_path, height, 0.5, 0.5)
    before = composed_meshes(stage)
    usdbake.bake(stage, "sky_visibility", target="texture", texture_dir=str(tmp_path))
    assert composed_meshes(stage) == before  # no mesh refined or changed
    floor = stage.GetPrimAtPath("/World/Floor")
    assert "LightmapAPI:skyExposure" in floor.GetAppliedSchemas()
    assert not floor.HasAttribute("primvars:bake:skyVisibility")
    assert floor.GetAttribute("bake:lightmap:skyExposure:uv").Get() == "st"
    assert floor.GetAttribute("bake:lightmap:skyExposure:units").Get() == "fraction"
    exposure = lightmap(stage, "/World/Floor", "skyExposure")[:, :, 0]
    assert exposure.shape == (32, 32)
    d = texel_centres_x(32)
    expected = 0.5 * (1.0 + d / np.sqrt(d * d + height * height))  # from 0.62 at the wall to 0.89 at 1.25 m
    error = exposure - expected
    assert abs(error.mean()) < 4 * TEXEL_SIGMA / np.sqrt(error.size) + SKY_PATCH_INTEGRATION
    assert np.sqrt((error ** 2).mean()) < TEXEL_SIGMA + SKY_PATCH_INTEGRATION
    assert np.abs(error).max() < 5 * TEXEL_SIGMA + SKY_PATCH_INTEGRATION
    # the gradient is resolved texel by texel, not one value per face (the floor is two triangles)
    assert np.corrcoef(exposure.ravel(), expected.ravel())[0, 1] > 0.95


def test_interreflected_daylight_per_texel_matches_the_closed_form(tmp_path):
    radiance, rho = 1000.0, 0.5
    stage = floor_and_wall(tmp_path, FAR, 0.0, rho)
    before = composed_meshes(stage)
    usdbake.bake(stage, "daylight", {
        "daylight": {"times": "2026-06-21T09:00,2026-06-21T12:00", "sky": "uniform", "sun": False,
                     "uniform_radiance": radiance},
        "interreflection": {"ground_reflectance": 0.0}}, target="texture", texture_dir=str(tmp_path))
    assert composed_meshes(stage) == before
    floor = stage.GetPrimAtPath("/World/Floor")
    attribute = floor.GetAttribute("bake:lightmap:daylightIrradiance:file")
    assert attribute.GetTimeSamples() == [0.0, 1.0]  # one image per time
    assert not floor.HasAttribute("primvars:bake:daylightIrradiance")
    expected = np.pi * radiance * (0.5 + rho / 4.0)
    for time in (0.0, 1.0):
        irradiance = lightmap(stage, "/World/Floor", "daylightIrradiance", time)
        assert irradiance.shape == (32, 32, 3)
        assert np.isfinite(irradiance).all()
        # the sky half is exact per patch above the wall's top; the wall's bounce is gathered with 128 rays per
        # texel (a Bernoulli share of rho L / 2 each)
        noise = np.pi * radiance * (rho / 2.0) * np.sqrt(0.25 / 128)
        assert abs(irradiance.mean() / expected - 1.0) < 2 * SKY_PATCH_INTEGRATION
        assert np.abs(irradiance - expected).max() < 5 * noise + 2 * SKY_PATCH_INTEGRATION * expected


def test_annual_metrics_per_texel_on_an_open_floor(tmp_path):
    pvlib = pytest.importorskip("pvlib")
    weather = Path(pvlib.__file__).parent / "data" / "723170TYA.CSV"
    from usdbake.formats.weather import read_weather
    from usdbake.kernels.solar import sun_position

    stage = new_stage(up_axis="Z", meters_per_unit=1.0)
    add_mesh(stage, "/World/Plane", [(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0)], [4], [0, 1, 2, 3])
    path = tmp_path / "plane.usda"
    stage.GetRootLayer().Export(str(path))
    stage = Usd.Stage.Open(str(path))
    usdbake.bake(stage, "annual_daylight", {"annual_daylight": {"weather": str(weather), "occupied": "0-24",
                                                                "efficacy": "weather"}},
                 target="texture", texture_dir=str(tmp_path))
    plane = stage.GetPrimAtPath("/World/Plane")
    assert plane.GetAttribute("bake:lightmap:meanIlluminance:uv").Get() == "bake:lightmapST"  # no st: generated
    assert not plane.HasAttribute("primvars:bake:meanIlluminance")
    year = read_weather(weather)
    suns = sun_position(year.times, year.latitude, year.longitude, year.timezone).enu()
    lux = (np.nan_to_num(year.diffuse_horizontal_illuminance) * (suns[:, 2] > 0)
           + np.nan_to_num(year.direct_normal_illuminance) * np.maximum(suns[:, 2], 0)).mean()
    filled = lightmap(stage, "/World/Plane", "meanIlluminance")[:, :, 0]
    np.testing.assert_allclose(filled, lux, rtol=SKY_PATCH_INTEGRATION)
    np.testing.assert_allclose(lightmap(stage, "/World/Plane", "daylightFactor")[:, :, 0], 100.0,
                               rtol=SKY_PATCH_INTEGRATION)
    useful = lightmap(stage, "/World/Plane", "usefulDaylight")
    np.testing.assert_allclose(useful.sum(axis=2), 1.0, atol=3.0 / 65535)  # 16-bit shares of every hour
    report = stage.GetPrimAtPath("/usdbake/AnnualDaylight")
    assert report.GetAttribute("bake:annual:sensorArea").Get() == pytest.approx(1.0, rel=0.01)  # texel footprints


def test_both_targets_write_the_refined_mesh_and_the_lightmaps(tmp_path):
    stage = floor_and_wall(tmp_path, 1.0, 0.5, 0.5)
    usdbake.bake(stage, "daylight", {"daylight": {"sky": "uniform", "sun": False}}, target="both",
                 texture_dir=str(tmp_path))
    floor = stage.GetPrimAtPath("/World/Floor")
    assert floor.HasAttribute("primvars:bake:skyVisibility") and floor.HasAttribute("primvars:bake:daylight")
    assert "LightmapAPI:daylightIrradiance" in floor.GetAppliedSchemas()
    face = np.asarray(floor.GetAttribute("primvars:bake:daylightIrradiance").Get())
    texels = lightmap(stage, "/World/Floor", "daylightIrradiance")
    areas = face_areas(floor)
    # the same light, integrated per refined face and per texel, agrees on the floor's mean
    assert np.average(face[:, 0], weights=areas) == pytest.approx(texels[:, :, 0].mean(), rel=0.02)


def face_areas(prim: Usd.Prim) -> np.ndarray:
    points = np.asarray(prim.GetAttribute("points").Get(), np.float64)
    indices = np.asarray(prim.GetAttribute("faceVertexIndices").Get()).reshape(-1, 3)
    corners = points[indices]
    return 0.5 * np.linalg.norm(np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]), axis=1)


def test_a_daylight_per_time_is_listed_and_read_at_its_time(tmp_path):
    from usdbake.cli.main import main
    from usdbake.stages.baked_data import read_lightmap
    from usdbake.stages.inspect import inspect_layer

    floor_and_wall(tmp_path, 1.0, 0.5, 0.5)
    out = tmp_path / "floor.baked.usda"
    assert main(["bake", str(tmp_path / "floor.usda"), "-o", str(out), "-p", "daylight", "--target", "texture",
                 "--set", "daylight.times=2026-06-21T09:00,2026-06-21T15:00"]) == 0
    rows = {row["path"]: row for row in inspect_layer(str(out))["lightmaps"]}
    row = rows["/World/Floor.bake:lightmap:daylightIrradiance:file"]
    assert row["times"] == 2 and (row["width"], row["height"], row["channels"]) == (32, 32, 3)
    stage = Usd.Stage.Open(str(out))
    morning, afternoon = (read_lightmap(stage, "/World/Floor", "daylightIrradiance", time) for time in (0.0, 1.0))
    assert morning.file != afternoon.file  # the sun moved: another page
    assert read_lightmap(stage, "/World/Floor", "daylightIrradiance").file == morning.file  # no time: the first


def test_texels_beyond_the_memory_budget_are_refused_before_any_ray(tmp_path):
    from usdbake.geometry.mesh import receiver_prims, vertex_normals
    from usdbake.kernels.lightmap_bake import texel_samples
    from usdbake.kernels.lightmap_layout import LightmapError, lightmap_layout
    from usdbake.processors.daylight.texel_receivers import check_texel_memory, daylight_texel_bytes
    from usdbake.stages.extract import extract_scene

    scene = extract_scene(floor_and_wall(tmp_path, 1.0, 0.5, 0.5))
    layout = lightmap_layout(scene, receiver_prims(scene), density=32.0, max_size=4096)
    pages = texel_samples(scene, layout, vertex_normals(scene.points, scene.tri_vertices, scene.tri_normals,
                                                        scene.tri_areas))
    needed = daylight_texel_bytes(32 * 32, 256, 1)  # the grey floor's 1024 texels
    check_texel_memory(scene, pages, 256, density=32.0, max_size=4096, budget=needed)
    with pytest.raises(LightmapError, match=r"1,024 texels would hold .* /World/Floor 1,024.*bake:skip.*"
                                            r"texel_density \(32\)"):
        check_texel_memory(scene, pages, 256, density=32.0, max_size=4096, budget=needed - 1)


def test_both_targets_lay_generated_uvs_on_the_refined_mesh(tmp_path):
    """A mesh without UVs that sky_visibility refines: its generated lightmap UVs are laid out on the refined
    faces it writes (one per refined face corner), and the texels still bake the open sky."""
    stage = new_stage(up_axis="Z", meters_per_unit=1.0)
    add_mesh(stage, "/World/Plane", [(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0)], [4], [0, 1, 2, 3])
    path = tmp_path / "plane.usda"
    stage.GetRootLayer().Export(str(path))
    stage = Usd.Stage.Open(str(path))
    usdbake.bake(stage, "sky_visibility", target="both", texture_dir=str(tmp_path))
    plane = stage.GetPrimAtPath("/World/Plane")
    faces = len(plane.GetAttribute("faceVertexCounts").Get())
    assert faces > 2  # refined (large faces are split before tracing)
    uvs = plane.GetAttribute("primvars:bake:lightmapST")
    assert uvs.GetMetadata("interpolation") == "faceVarying" and len(uvs.Get()) == 3 * faces
    np.testing.assert_allclose(lightmap(stage, "/World/Plane", "skyExposure")[:, :, 0], 1.0, atol=0.01)
