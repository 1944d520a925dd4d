"""A sky model written as UsdLux lights (``usdbake sky``) lights a face as the model says: an open
horizontal face gets the model's diffuse horizontal irradiance plus DNI sin(altitude), read back
through extraction and the one light model."""

from __future__ import annotations

import math
from pathlib import Path

import pytest
from pxr import Usd

from open_irradiance import direct_irradiance_at
from stage_builders import add_mesh, new_stage
from usdbake.cli.main import main
from usdbake.kernels.solar import parse_times, sun_position
from usdbake.stages.extract import extract_scene

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
    code = main(["sky", str(source), "-o", str(out), "--model", model, "--dni", "700", "--dhi", "120", *PLACE])
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
    code = main(["sky", str(source), "-o", str(out), "--weather", tmy3, "--time", "2026-06-21T12:00"])
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
