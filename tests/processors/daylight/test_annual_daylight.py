"""Annual daylight by daylight coefficients: checked against closed forms (an open horizontal face sees
DF 100% and the weather file's global horizontal illuminance), per-hour relights of the same sky,
a closed box (DA 0) and the command end to end. Weather: the TMY3 file pvlib ships (Greensboro NC)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from pxr import Usd

from stage_builders import add_mesh, new_stage
from tolerances import (FLOAT32_STORAGE, PEREZ_EFFICACY_ANNUAL, SKY_MATRIX_NORMALISATION, SKY_PATCH_INTEGRATION,
                        TREGENZA_PATCH_INTEGRATION)
from usdbake.cli.main import main
from usdbake.formats.weather import read_weather
from usdbake.kernels.sky import LUMINOUS_EFFICACY, patch_radiance, patch_samples, tregenza_patches
from usdbake.processors.daylight.sky_matrix import perez_sky_matrix
from usdbake.kernels.solar import day_of_year, sun_position
from usdbake.kernels.tracer import Tracer
from usdbake.processors.daylight.annual_daylight import compute_annual_daylight, overcast_factors
from usdbake.processors.daylight.sky_visibility import compute_sky_visibility
from usdbake.stages.extract import extract_scene

pvlib = pytest.importorskip("pvlib")
TMY3 = Path(pvlib.__file__).parent / "data" / "723170TYA.CSV"
from repo_paths import SAMPLES


@pytest.fixture(scope="module")
def weather():
    return read_weather(TMY3)


def visibility(stage: Usd.Stage):
    scene = extract_scene(stage)
    tracer = Tracer.from_scene(scene)
    product, _ = compute_sky_visibility(tracer, scene, patches=tregenza_patches(), samples=16, adaptive=False)
    return scene, tracer, product


def open_plane():
    """A horizontal 1 x 1 quad facing up (Z-up), nothing around it."""
    stage = new_stage(up_axis="Z")
    add_mesh(stage, "/World/Plane", [(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0)], [4], [0, 1, 2, 3])
    return visibility(stage)


def test_sky_matrix_matches_the_per_hour_model_and_the_diffuse_horizontal(weather):
    patches = tregenza_patches()
    suns = sun_position(weather.times, weather.latitude, weather.longitude, weather.timezone).enu()
    days = day_of_year(weather.times)
    matrix = perez_sky_matrix(patches, suns, weather.direct_normal, weather.diffuse_horizontal, days)
    cosine = np.maximum(patch_samples(patches, 3)[..., 2], 0.0).mean(axis=1)  # patch-mean cosine
    for hour in np.flatnonzero((suns[:, 2] > 0.2) & (weather.diffuse_horizontal > 50))[::400]:
        reference = patch_radiance(patches, "perez", suns[hour], direct_normal=weather.direct_normal[hour],
                                   diffuse_horizontal=weather.diffuse_horizontal[hour], day_of_year=int(days[hour]))
        np.testing.assert_allclose(matrix[:, hour], reference[:, 0], rtol=SKY_MATRIX_NORMALISATION,
                                   atol=FLOAT32_STORAGE)
        # the patch integral of L cos over the dome is the hour's diffuse horizontal irradiance
        horizontal = float((matrix[:, hour] * patches.patch_solid_angles * cosine).sum())
        assert horizontal == pytest.approx(weather.diffuse_horizontal[hour], rel=TREGENZA_PATCH_INTEGRATION)
    assert np.all(matrix[:, suns[:, 2] <= 0] == 0)


def test_open_horizontal_face_has_daylight_factor_100():
    _, _, product = open_plane()
    np.testing.assert_allclose(overcast_factors(product), 100.0, rtol=SKY_PATCH_INTEGRATION)


def test_open_horizontal_face_sees_the_global_horizontal_illuminance(weather):
    """In Radiance's units (179 lm/W) and in the file's own lux: its illuminance columns, independent of the
    Perez efficacy model, which the default reproduces within its scatter."""
    scene, tracer, product = open_plane()
    suns = sun_position(weather.times, weather.latitude, weather.longitude, weather.timezone).enu()
    up = suns[:, 2] > 0
    global_horizontal = weather.diffuse_horizontal * up + weather.direct_normal * np.maximum(suns[:, 2], 0)
    metrics, stats = compute_annual_daylight(tracer, scene, product, weather, occupied=(0.0, 24.0), efficacy="179")
    np.testing.assert_allclose(metrics.mean_illuminance, LUMINOUS_EFFICACY * global_horizontal.mean(),
                               rtol=SKY_PATCH_INTEGRATION)
    assert stats["occupied_hours"] == 8760 and 100 < stats["sun_bins"] < 2305
    lux = (np.nan_to_num(weather.diffuse_horizontal_illuminance) * up
           + np.nan_to_num(weather.direct_normal_illuminance) * np.maximum(suns[:, 2], 0)).mean()
    metrics, _ = compute_annual_daylight(tracer, scene, product, weather, occupied=(0.0, 24.0), efficacy="weather")
    np.testing.assert_allclose(metrics.mean_illuminance, lux, rtol=SKY_PATCH_INTEGRATION)
    metrics, _ = compute_annual_daylight(tracer, scene, product, weather, occupied=(0.0, 24.0))
    np.testing.assert_allclose(metrics.mean_illuminance, lux, rtol=PEREZ_EFFICACY_ANNUAL)


def test_annual_sky_illuminance_is_the_sum_of_hourly_relights(weather):
    """Without the sun, the annual mean is the mean of per-hour products V (L dw) K with the per-hour model."""
    scene, tracer, product = open_plane()
    metrics, _ = compute_annual_daylight(tracer, scene, product, weather, sun=False, occupied=(12.0, 13.0),
                                         efficacy="179")
    patches = product.patches
    suns = sun_position(weather.times, weather.latitude, weather.longitude, weather.timezone).enu()
    days = day_of_year(weather.times)
    noon = np.flatnonzero(np.array([str(t)[11:13] == "12" for t in weather.times]))
    total = 0.0
    for hour in noon:
        if suns[hour, 2] <= 0 or weather.diffuse_horizontal[hour] <= 0:
            continue
        radiance = patch_radiance(patches, "perez", suns[hour], direct_normal=weather.direct_normal[hour],
                                  diffuse_horizontal=weather.diffuse_horizontal[hour], day_of_year=int(days[hour]))
        total += float(product.visibility_float()[0] @ (radiance[:, 0] * patches.patch_solid_angles))
    assert metrics.mean_illuminance[0] == pytest.approx(LUMINOUS_EFFICACY * total / len(noon),
                                                        rel=SKY_MATRIX_NORMALISATION)


def test_a_closed_box_gets_no_daylight(weather):
    stage = new_stage(up_axis="Z")
    corners = [(x, y, z) for z in (0, 1) for y in (0, 1) for x in (0, 1)]
    faces = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    add_mesh(stage, "/World/Box", corners, [4] * 6, [i for face in faces for i in face])  # every face inward
    scene, tracer, product = visibility(stage)
    metrics, _ = compute_annual_daylight(tracer, scene, product, weather)
    for values in (metrics.daylight_factor, metrics.autonomy, metrics.sun_hours, metrics.mean_illuminance):
        assert np.all(values == 0)
    np.testing.assert_array_equal(metrics.useful, np.tile([1.0, 0.0, 0.0], (product.num_faces, 1)))


def test_north_turns_the_sun_not_the_sky_integral(weather):
    """A vertical south-facing window wall gets more sun than the same wall facing north."""
    results = {}
    for north in (0.0, 180.0):
        stage = new_stage(up_axis="Z")  # a wall facing -Y (south when north is +Y)
        add_mesh(stage, "/World/Wall", [(0, 0, 0), (1, 0, 0), (1, 0, 1), (0, 0, 1)], [4], [0, 1, 2, 3])
        scene, tracer, product = visibility(stage)
        metrics, _ = compute_annual_daylight(tracer, scene, product, weather, north=north)
        results[north] = metrics.sun_hours[0]
    assert results[0.0] > 1000 and results[180.0] < 0.3 * results[0.0]


def test_bake_writes_metrics_and_report(tmp_path, capsys):
    out = tmp_path / "out.usda"
    code = main(["bake", str(SAMPLES / "window_room.usda"), "-o", str(out), "-p", "annual_daylight",
                 "--set", f"annual_daylight.weather={TMY3}", "--set", "annual_daylight.sensor_prims=Floor",
                 "--set", "sky_visibility.patch_layout=tregenza"])
    err = capsys.readouterr().err
    assert code == 0, err
    assert "annual_daylight: sDA" in " ".join(err.split())
    stage = Usd.Stage.Open(str(out))
    report = stage.GetPrimAtPath("/usdbake/AnnualDaylight")
    assert 0.0 <= report.GetAttribute("bake:annual:sDA").Get() <= 1.0
    data = json.loads(Path(report.GetAttribute("bake:annual:report").Get().resolvedPath).read_text())
    floor = data["prims"]["/World/Room/Floor"]
    assert 0.0 < floor["mean_daylight_factor"] < 20.0 and data["sensor_faces"] > 0
    autonomy = np.asarray(stage.GetPrimAtPath("/World/Room/Floor").GetAttribute("primvars:bake:daylightAutonomy").Get())
    assert autonomy.min() >= 0.0 and autonomy.max() <= 1.0 and autonomy.max() > autonomy.min()


def test_no_weather_file_skips_with_how_to_set_one(capsys):
    code = main(["plan", str(SAMPLES / "window_room.usda"), "-p", "annual_daylight", "--json"])
    assert code == 0
    steps = {step["processor"]: step for step in json.loads(capsys.readouterr().out)}
    assert steps["annual_daylight"]["reason"] == ("not applicable: no weather file: set annual_daylight.weather="
                                                  "FILE.epw (or an NREL TMY3 .csv)")


def test_a_broken_weather_file_is_one_line(tmp_path, capsys):
    broken = tmp_path / "broken.epw"
    broken.write_text("LOCATION,x\n")
    code = main(["bake", str(SAMPLES / "window_room.usda"), "-o", str(tmp_path / "o.usda"), "-p", "annual_daylight",
                 "--set", f"annual_daylight.weather={broken}"])
    assert code == 2
    assert capsys.readouterr().err.strip().splitlines()[-1] == (
        f"usdbake: error: {broken}: 0 hourly rows after the 8-line header; a typical year has 8760 (or 8784 in a "
        f"leap year): missing or extra hours")


def test_a_weather_file_from_elsewhere_than_the_stage_sky_is_refused(tmp_path, capsys):
    sky = tmp_path / "sky.usda"
    assert main(["sky", str(SAMPLES / "window_room.usda"), "-o", str(sky), "--latitude", "41.98", "--longitude",
                 "2.82", "--timezone", "1"]) == 0
    capsys.readouterr()
    code = main(["plan", str(sky), "-p", "annual_daylight", "--set", f"annual_daylight.weather={TMY3}"])
    assert code == 2
    assert capsys.readouterr().err.strip().splitlines()[-1] == (
        f"usdbake: error: {TMY3}, line 1: the weather's site (latitude 36.1, longitude -79.95, UTC-5) disagrees "
        f"with the stage's (latitude 41.98, longitude 2.82, UTC+1, written by usdbake sky in {sky}); use a "
        f"weather file for that place or remake the sky")
