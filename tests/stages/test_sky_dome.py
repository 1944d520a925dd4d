"""A sky model written as UsdLux lights (``usdbake sky``) lights a face as the model says: an open
horizontal face gets the model's diffuse horizontal irradiance plus DNI sin(altitude), read back
through extraction and the one light model. A DomeLight's texture is read strip by strip, reduced to
at most 1024 x 512 float32 texels with its radiant power kept, and only by processors that use light."""

from __future__ import annotations

import math
import tracemalloc
from pathlib import Path

import numpy as np
import OpenImageIO as oiio
import pytest
from pxr import Usd, UsdLux

from open_irradiance import direct_irradiance_at
from stage_builders import add_mesh, new_stage
from tolerances import FLOAT32_STORAGE, FLOAT32_UNIT_ROUNDOFF
from usdbake.cli.main import main
from usdbake.core.errors import StageError
from usdbake.kernels.solar import parse_times, sun_position
from usdbake.stages import sky_dome
from usdbake.stages.extract import extract_scene
from usdbake.stages.images import STRIP_BYTES, srgb_table
from usdbake.stages.sky_dome import DOME_MAP_MAX_HEIGHT, DOME_MAP_MAX_WIDTH, read_latlong, reduce_latlong, \
    texel_directions

PLACE = ["--latitude", "41.98", "--longitude", "2.82", "--timezone", "1", "--time", "2026-06-21T12:00"]
TEXEL_INTEGRATION = 0.02
"""A 256 x 128 lat-long map integrated by 64 x 64 cosine-weighted rays, nearest texel: ~1% measured."""


def write_input(folder, up):
    path = folder / "in.usda"
    stage = new_stage(up_axis=up)
    add_mesh(stage, "/World/Speck", [(0, -100, 0), (0.01, -100, 0), (0, -100, 0.01)], [3], [0, 1, 2])
    stage.GetRootLayer().Export(str(path))
    return path


@pytest.mark.parametrize("up", ["Y", "Z"])
@pytest.mark.parametrize("model", ["perez", "preetham"])
def test_open_horizontal_face_gets_diffuse_plus_direct(tmp_path, capsys, up, model):
    source = write_input(tmp_path, up)
    before = source.read_bytes()
    out = tmp_path / "sky.usda"
    code = main(["sky", str(source), "-o", str(out), "--model", model, "--dni", "700", "--dhi", "120", *PLACE,
                 "--efficacy", "179"])  # Radiance's solar units: the Perez sky's DNI and DHI as given
    assert code == 0, capsys.readouterr().err
    assert source.read_bytes() == before
    scene = extract_scene(Usd.Stage.Open(str(out)))
    assert scene.lights.dome_texture.shape == (128, 256, 3) and len(scene.lights) == 2
    measured = float(direct_irradiance_at(scene, -scene.origin[None, :], scene.up_vector[None, :], strata=4,
                                          seed=3)[0, 1])
    altitude = math.radians(90.0 - float(sun_position(parse_times("2026-06-21T12:00"), 41.98, 2.82, 1.0).zenith[0]))
    report = capsys.readouterr().out
    diffuse = float(report.split("diffuse horizontal ")[1].split(" W/m^2")[0])
    sun = float(report.split("sun ")[1].split(" W/m^2")[0])
    if model == "perez":
        assert diffuse == pytest.approx(120.0, rel=TEXEL_INTEGRATION) and sun == pytest.approx(700.0)
    assert measured == pytest.approx(diffuse + sun * math.sin(altitude), rel=TEXEL_INTEGRATION)


def test_a_sky_needs_one_time(tmp_path, capsys):
    source = write_input(tmp_path, "Y")
    code = main(["sky", str(source), "-o", str(tmp_path / "sky.usda"), *PLACE[:-2], "--time",
                 "2026-06-21T06:00/18:00/PT1H"])
    assert code == 2
    assert "a sky dome is for one time, not 13" in capsys.readouterr().err


def test_a_sky_from_a_weather_file_hour_is_its_perez_sky_at_its_site(tmp_path, capsys):
    from usdbake.formats.weather import read_weather
    from usdbake.stages.extract import stage_site

    pvlib = pytest.importorskip("pvlib")
    tmy3 = str(Path(pvlib.__file__).parent / "data" / "723170TYA.CSV")
    weather = read_weather(tmy3)
    row = weather.hour_at(parse_times("2026-06-21T12:00")[0])
    source = write_input(tmp_path, "Z")
    out = tmp_path / "sky.usda"
    code = main(["sky", str(source), "-o", str(out), "--weather", tmy3, "--time", "2026-06-21T12:00",
                 "--efficacy", "179"])
    assert code == 0, capsys.readouterr().err
    report = capsys.readouterr().out
    assert f"{tmy3} line {weather.lines[row]} (DNI {weather.direct_normal[row]:g}" in report
    sun = float(report.split("sun ")[1].split(" W/m^2")[0])
    diffuse = float(report.split("diffuse horizontal ")[1].split(" W/m^2")[0])
    assert sun == pytest.approx(weather.direct_normal[row])
    assert diffuse == pytest.approx(weather.diffuse_horizontal[row], rel=TEXEL_INTEGRATION)
    stage = Usd.Stage.Open(str(out))
    site = stage_site(stage)
    assert (site["latitude"], site["longitude"], site["timezone"]) == (36.1, -79.95, -5.0)
    # The sun stands where it does in Greensboro at that hour, not at the default place.
    scene = extract_scene(stage)
    position = sun_position(parse_times("2026-06-21T12:00"), 36.1, -79.95, -5.0)
    altitude = math.radians(90.0 - float(position.zenith[0]))
    measured = float(direct_irradiance_at(scene, -scene.origin[None, :], scene.up_vector[None, :], strata=4,
                                          seed=3)[0, 1])
    assert measured == pytest.approx(diffuse + sun * math.sin(altitude), rel=TEXEL_INTEGRATION)


@pytest.mark.parametrize("extra, message", [
    (["--model", "preetham"], "--model preetham --weather"),
    (["--latitude", "10"], "--latitude 10 disagrees with"),
    (["--dni", "500"], "--dni with --weather"),
])
def test_a_weather_sky_refuses_what_the_file_already_says(tmp_path, capsys, extra, message):
    pvlib = pytest.importorskip("pvlib")
    tmy3 = str(Path(pvlib.__file__).parent / "data" / "723170TYA.CSV")
    source = write_input(tmp_path, "Y")
    code = main(["sky", str(source), "-o", str(tmp_path / "sky.usda"), "--weather", tmy3, *extra])
    assert code == 2
    assert message in capsys.readouterr().err
    assert not (tmp_path / "sky.usda").exists()


# ---------------------------------------------------------------------------
# Reading a DomeLight's texture (issue 27: a 285 KB 10000 x 10000 PNG cost 10 GB and 40 s per bake)

POWER_SUM = 1e-12
"""Relative error of sum(L Omega) over ~1e6 float64 products, summed in float64: measured 1e-13."""

STEP_QUADRATURE = 1e-5
"""The trapezoid rule over 200001 points of a step function (the reference band means): ~1e-5."""


def in_strips(image: np.ndarray, rows: int):
    return ((first, image[first:first + rows]) for first in range(0, len(image), rows))


def radiant_power(image: np.ndarray) -> np.ndarray:
    """(3,) sum of L * Omega over the texels of a lat-long map (per-texel solid angles)."""
    _, solid = texel_directions(*image.shape[:2])
    return (image * solid[..., None]).sum(axis=(0, 1))


def write_png(path, height: int, width: int, row_code) -> str:
    """An 8-bit RGB PNG whose row r holds the sRGB code row_code(r) in every texel, written strip by strip."""
    out = oiio.ImageOutput.create(str(path))
    assert out.open(str(path), oiio.ImageSpec(width, height, 3, oiio.UINT8))
    for first in range(0, height, 256):
        rows = np.arange(first, min(first + 256, height))
        block = np.broadcast_to(np.asarray(row_code(rows), np.uint8)[:, None, None], (len(rows), width, 3))
        assert out.write_scanlines(int(first), int(first + len(rows)), 0, np.ascontiguousarray(block))
    out.close()
    return str(path)


@pytest.mark.parametrize("out_height, out_width", [(512, 1024), (333, 1999), (1000, 7), (1, 1)])
def test_reduction_keeps_the_radiant_power_of_the_map(out_height, out_width):
    """Random radiance with two suns, 1000 x 1999 texels, reduced to sizes that divide nothing: the power
    sum(L Omega) of the map is kept, and no texel goes below the input's least (OpenImageIO's box
    resize lost 1.6% of the power at 1024 x 512; its default lanczos3 made texels of -44 around a sun)."""
    rng = np.random.default_rng(7)  # fixed seed: a reproducible map
    image = rng.random((1000, 1999, 3))
    image[5:7, 100:103] = 1e5  # a sun near the pole, where rows differ most in solid angle
    image[500, 7] = 3e4
    out = reduce_latlong(1000, 1999, in_strips(image, 37), out_height=out_height, out_width=out_width)
    np.testing.assert_allclose(radiant_power(out), radiant_power(image), rtol=POWER_SUM)
    assert out.min() >= image.min()


def test_each_output_row_averages_its_band_of_the_sphere_by_solid_angle():
    """Rows weighted by cos(latitude): a map whose row r holds r, reduced to 4 rows, gives each output
    row the solid-angle mean of r over its band (numerical integral over the exact band edges)."""
    height = 10
    image = np.broadcast_to(np.arange(height, dtype=np.float64)[:, None, None], (height, 3, 3)).copy()
    out = reduce_latlong(height, 3, in_strips(image, 3), out_height=4, out_width=3)
    for row in range(4):
        v = np.linspace(row * height / 4, (row + 1) * height / 4, 200001)  # input-row coordinate
        weight = np.cos(0.5 * np.pi - v * np.pi / height)  # cos(latitude)
        expected = np.trapezoid(np.floor(v) * weight, v) / np.trapezoid(weight, v)
        np.testing.assert_allclose(out[row], expected, rtol=STEP_QUADRATURE)


def test_a_constant_map_stays_constant_and_a_small_map_is_kept_texel_for_texel():
    image = np.full((700, 1500, 3), 2.5)
    np.testing.assert_allclose(reduce_latlong(700, 1500, in_strips(image, 64), out_height=512, out_width=1024),
                               2.5, rtol=4 * FLOAT32_UNIT_ROUNDOFF)
    small = np.random.default_rng(1).random((32, 64, 3))  # fixed seed
    np.testing.assert_array_equal(reduce_latlong(32, 64, in_strips(small, 5), out_height=32, out_width=64), small)


def test_eight_bit_texels_are_linearized_as_a_whole_float_read_did(tmp_path):
    """Every sRGB code, through the table, equals OpenImageIO's float read followed by the transfer function
    in float64 (the previous reader), texel for texel once stored as float32."""
    path = write_png(tmp_path / "codes.png", 256, 4, lambda rows: rows)
    whole = np.asarray(oiio.ImageBuf(path).get_pixels(oiio.FLOAT), np.float64)
    linear = np.where(whole <= 0.04045, whole / 12.92, ((whole + 0.055) / 1.055) ** 2.4)
    np.testing.assert_array_equal(read_latlong(path, srgb=True), linear.astype(np.float32))
    np.testing.assert_array_equal(srgb_table()[[0, 255]], [0.0, 1.0])


def test_a_large_png_is_read_in_bounded_memory_to_a_bounded_float32_map(tmp_path):
    """A 4000 x 4000 8-bit PNG (a whole float64 copy is 384 MB): the map is 512 x 1024 float32, the reader's
    numpy allocations peak under 4 strips, and the map keeps the radiant power of the file's texels
    (bands of 400 rows of one sRGB code each)."""
    path = write_png(tmp_path / "sky.png", 4000, 4000, lambda rows: (rows // 400) * 25)
    tracemalloc.start()
    try:
        texture = read_latlong(path, srgb=True)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert texture.shape == (DOME_MAP_MAX_HEIGHT, DOME_MAP_MAX_WIDTH, 3) and texture.dtype == np.float32
    assert peak < 4 * STRIP_BYTES, f"{peak / 2**20:.0f} MB"
    rows = srgb_table()[(np.arange(4000) // 400) * 25]  # each row is uniform: one column stands for it
    np.testing.assert_allclose(radiant_power(texture.astype(np.float64)),
                               radiant_power(np.repeat(rows[:, None, None], 3, axis=2)), rtol=FLOAT32_STORAGE)


def dome_stage_with(texture: str):
    stage = new_stage()
    add_mesh(stage, "/World/Floor", [(-1, 0, -1), (1, 0, -1), (1, 0, 1), (-1, 0, 1)], [4], [0, 3, 2, 1])
    add_mesh(stage, "/World/Box", [(0, 0, 0), (0.5, 0, 0), (0.5, 0.5, 0), (0, 0.5, 0)], [4], [0, 1, 2, 3])
    dome = UsdLux.DomeLight.Define(stage, "/World/Sky")
    dome.CreateIntensityAttr(1.0)
    dome.CreateTextureFileAttr(texture)
    return stage


def test_the_dome_texture_is_read_only_by_processors_that_use_light(tmp_path, monkeypatch):
    """An ambient-occlusion bake of a stage with a dome texture never reads its texels (the header only,
    at extraction); a bake whose processor reads the lights reads them once."""
    import usdbake

    path = write_png(tmp_path / "sky.png", 64, 128, lambda rows: 200 - rows)
    reads = []
    real = sky_dome.read_latlong
    monkeypatch.setattr(sky_dome, "read_latlong", lambda *a, **k: reads.append(a) or real(*a, **k))
    usdbake.bake(dome_stage_with(path), ["ambient_occlusion"], params={"ambient_occlusion": {"samples": 16}})
    assert reads == []
    usdbake.bake(dome_stage_with(path), ["irradiance_grid"])
    assert len(reads) == 1


def test_non_finite_texels_are_named_when_the_texture_is_read(tmp_path):
    image = np.ones((16, 32, 3), np.float32)
    image[3, 7, 1] = np.nan
    path = tmp_path / "nan.exr"
    out = oiio.ImageOutput.create(str(path))
    out.open(str(path), oiio.ImageSpec(32, 16, 3, oiio.FLOAT))
    out.write_image(image)
    out.close()
    scene = extract_scene(dome_stage_with(str(path)))  # the header is fine: extraction passes
    with pytest.raises(StageError) as error:
        scene.lights.dome_texture
    assert str(error.value) == f"/World/Sky.inputs:texture:file: {path}: holds non-finite texels (row 3, column 7: nan)"


def test_the_perez_sky_is_in_light_by_its_luminous_efficacy(tmp_path, capsys):
    """By default the Perez dome and sun hold visible-equivalent watts (x 179 = lux, as daylight writes): the
    given DHI and DNI times the Perez et al. 1990 efficacies over 179 lm/W; the weather file's own illuminance
    columns agree within the two models' scatter."""
    from usdbake.formats.weather import read_weather
    from usdbake.kernels.luminous_efficacy import perez_efficacy
    from usdbake.kernels.solar import day_of_year

    pvlib = pytest.importorskip("pvlib")
    tmy3 = str(Path(pvlib.__file__).parent / "data" / "723170TYA.CSV")
    weather = read_weather(tmy3)
    when = parse_times("2026-06-21T12:00")
    row = weather.hour_at(when[0])
    source = write_input(tmp_path, "Z")
    assert main(["sky", str(source), "-o", str(tmp_path / "sky.usda"), "--weather", tmy3, "--time",
                 "2026-06-21T12:00"]) == 0
    report = capsys.readouterr().out
    sun = float(report.split("sun ")[1].split(" W/m^2")[0])
    diffuse = float(report.split("diffuse horizontal ")[1].split(" W/m^2")[0])
    zenith = float(sun_position(when, 36.1, -79.95, -5.0).zenith[0])
    beam, sky = perez_efficacy(weather.direct_normal[row], weather.diffuse_horizontal[row], zenith,
                               day_of_year(when)[0])
    assert sun == pytest.approx(weather.direct_normal[row] * float(beam) / 179.0, abs=0.1)
    assert diffuse == pytest.approx(weather.diffuse_horizontal[row] * float(sky) / 179.0, rel=TEXEL_INTEGRATION)
    assert 179.0 * diffuse == pytest.approx(weather.diffuse_horizontal_illuminance[row], rel=0.15)
    assert 179.0 * sun == pytest.approx(weather.direct_normal_illuminance[row], rel=0.15)
