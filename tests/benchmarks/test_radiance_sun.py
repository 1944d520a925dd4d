"""The sharp-sun Radiance reference of ASE (benchmarks/radiance_sun.py, benchmarks/office_sun_reference.py): an
open sensor receives the sun's direct normal illuminance times cos(zenith), a roofed one nothing, glass passes
Radiance glass's angular transmittance, the sun matrix's patch of each hour is the one nearest to the sun, the
suns are in reinhart.cal's bin order, and ``ase`` counts occupied hours as LM-83 does."""

from __future__ import annotations

import subprocess

import numpy as np
import pytest

pytest.importorskip("pyradiance")
pytest.importorskip("pvlib")

from usdbake.benchmarks import radiance_binaries as rbin  # noqa: E402
from usdbake.benchmarks import radiance_scene as rscene  # noqa: E402
from usdbake.benchmarks import radiance_sky as rsky  # noqa: E402
from usdbake.benchmarks import radiance_sun as rs  # noqa: E402
from usdbake.benchmarks.office_sun_reference import ase, occupied_hours  # noqa: E402

MF = 6
FLOAT32 = 1e-5
"""rcontrib writes float32: the coefficients of an unobstructed sun equal cos(incidence) to float32 precision."""
SUN_POSITION = 0.02
"""Median |relative difference| of the open sensor's hourly lux from E_dn cos(zenith) with pvlib's zenith, sun
above 20 degrees: Radiance's sun position (0.3-0.7 degrees from pvlib's) and the snap to an MF:6 patch centre
(<= ~1.4 degrees) tilt cos(zenith) by tan(zenith) x that angle (measured median 0.9%, p95 3.8%, max 7.3%)."""
SUN_POSITION_P95 = 0.05
SUN_POSITION_MAX = 0.10
PATCH_ANGLE = 3.0
"""Degrees: the patch gendaymtx -5 puts each hour's sun in is within this of pvlib's sun (measured max 2.24:
half a patch diagonal, ~1.4, plus Radiance's sun position)."""
ROOF = 1000.0
"""Half-width (m) of the opaque roof 1 m above the roofed sensor and of the pane 1 m above the glazed one: the
lowest sun (1.06 degrees up, MF:6's first ring) cannot pass under their edges (atan(1 / 1000) = 0.06 degrees)."""


def _square(x0, x1, y0, y1, z):
    return np.array([[[x0, y0, z], [x1, y0, z], [x1, y1, z]], [[x0, y0, z], [x1, y1, z], [x0, y1, z]]], float)


@pytest.fixture(scope="module")
def weather():
    return rsky._tmy3_example()


@pytest.fixture(scope="module")
def run(weather):
    """One run: sensor 0 open and up, 1 under an opaque roof, 2 under a horizontal pane of VLT 0.6 (far from the
    roof), 3 open facing south."""
    if not rbin.radiance_available():
        pytest.skip("Radiance binaries of pyradiance do not run here")
    triangles = np.concatenate([_square(-ROOF, ROOF, -ROOF, ROOF, 1.0),
                                _square(5000 - ROOF, 5000 + ROOF, -ROOF, ROOF, 1.0)])
    transmittance = np.array([0.0, 0.0, 0.6, 0.6])
    sensors = np.array([[-5000.0, 0, 0], [0.0, 0, 0], [5000.0, 0, 0], [-5000.0, 50, 0]])
    normals = np.array([[0.0, 0, 1], [0.0, 0, 1], [0.0, 0, 1], [0.0, -1, 0]])
    timings: dict = {}
    times, lux, dc, sun = rs.direct_sun_illuminance(triangles, 0.5, transmittance, sensors, normals, weather,
                                                    mf=MF, processes=2, timings=timings, return_coefficients=True)
    return {"times": times, "lux": lux, "dc": dc, "sun": sun, "timings": timings}


@pytest.fixture(scope="module")
def pvlib_sun(weather):
    """(H, 3) unit ENU direction of pvlib's (geometric) sun at each mid-hour of the weather file."""
    import pandas as pd
    from pvlib import solarposition

    rows = rsky.read_weather_rows(weather)
    local = pd.DatetimeIndex(rows.times.astype("datetime64[ns]"))
    when = (local - pd.Timedelta(hours=rows.timezone)).tz_localize("UTC")
    sun = solarposition.get_solarposition(when, rows.latitude, rows.longitude, altitude=rows.elevation)
    zenith, azimuth = np.radians(sun["zenith"].to_numpy()), np.radians(sun["azimuth"].to_numpy())
    return np.column_stack([np.sin(zenith) * np.sin(azimuth), np.sin(zenith) * np.cos(azimuth), np.cos(zenith)])


def test_open_sensor_gets_direct_normal_times_cos_zenith(run, pvlib_sun):
    sun, lux = run["sun"], run["lux"]
    normal = np.zeros(len(run["times"]))
    np.add.at(normal, sun.hours, sun.normal_illuminance())
    # Exactly: each hour's E_dn times the cosine at its patch centre (the suns' radiance and solid angle, the
    # modifier order).
    dirs, _ = rsky.reinhart_patches(MF)
    exact = np.zeros_like(normal)
    np.add.at(exact, sun.hours, sun.normal_illuminance() * dirs[sun.patches + 1, 2])
    assert np.allclose(lux[:, 0], exact, rtol=FLOAT32, atol=1e-6)
    # Independently of the patches: E_dn cos(zenith) with pvlib's sun, on sunny hours with the sun above 20 deg.
    reference = normal * np.maximum(pvlib_sun[:, 2], 0.0)
    sunny = (normal > 1000.0) & (pvlib_sun[:, 2] > np.sin(np.radians(20.0)))
    assert sunny.sum() > 2000
    rel = np.abs(lux[sunny, 0] / reference[sunny] - 1.0)
    assert np.median(rel) < SUN_POSITION
    assert np.percentile(rel, 95) < SUN_POSITION_P95
    assert rel.max() < SUN_POSITION_MAX
    # A vertical south-facing sensor: cos(incidence) = -y of the sun, same bounds.
    reference = normal * np.maximum(-pvlib_sun[:, 1], 0.0)
    facing = sunny & (-pvlib_sun[:, 1] > 0.5)
    rel = np.abs(lux[facing, 3] / reference[facing] - 1.0)
    assert np.median(rel) < SUN_POSITION


def test_coefficients_are_cosines_and_glass(run):
    dirs, _ = rsky.reinhart_patches(MF)
    up = dirs[1:, 2]
    dc = run["dc"]
    assert dc.shape == (4, 144 * MF * MF + 1, 3)
    assert np.allclose(dc[0], up[:, None], atol=FLOAT32)
    assert np.allclose(dc[3], np.maximum(-dirs[1:, 1], 0.0)[:, None], atol=FLOAT32)
    glass = rscene.glass_transmittance(rscene.glass_transmissivity(0.6), up) * up
    assert np.allclose(dc[2], glass[:, None], rtol=FLOAT32, atol=1e-7)


def test_roofed_sensor_gets_nothing(run):
    assert np.all(run["dc"][1] == 0.0)
    assert np.all(run["lux"][:, 1] == 0.0)
    assert run["lux"][:, 0].max() > 50000.0


def test_sun_matrix_one_patch_per_hour_nearest_the_sun(run, pvlib_sun):
    sun = run["sun"]
    assert len(np.unique(sun.hours)) == len(sun.hours) > 4000  # one patch per sunny hour
    assert sun.patches.min() >= 0 and sun.patches.max() < 144 * MF * MF + 1
    dirs, _ = rsky.reinhart_patches(MF)
    up = pvlib_sun[sun.hours, 2] > 0.0
    cos = np.sum(dirs[sun.patches + 1] * pvlib_sun[sun.hours], axis=1)
    assert np.degrees(np.arccos(np.clip(cos[up], -1.0, 1.0))).max() < PATCH_ANGLE
    assert {"rcontrib_seconds", "gendaymtx_seconds", "seconds", "command"} <= set(run["timings"])


def test_suns_in_reinhart_cal_bin_order():
    rbin._pyradiance()
    dirs, _ = rsky.reinhart_patches(MF)
    text, names = rs.suns_rad(MF)
    assert names == [f"solar{row}" for row in range(1, len(dirs))]
    lines = "".join(f"{d[0]:.9f} {d[1]:.9f} {d[2]:.9f}\n" for d in dirs[1:])
    done = subprocess.run([rbin._binary("rcalc"), "-e", f"MF:{MF}", "-f", "reinhart.cal", "-e",
                           "Dx=$1;Dy=$2;Dz=$3", "-e", "$1=rbin"], input=lines, capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    assert np.array_equal(np.array(done.stdout.split(), float), np.arange(1, len(dirs)))


def test_ase_counts_occupied_hours():
    times = np.datetime64("2025-01-01T00:30", "m") + np.arange(24 * 30).astype("timedelta64[h]")
    occupied = occupied_hours(times)
    assert occupied.sum() == 10 * 30  # 8:30 .. 17:30
    lux = np.zeros((len(times), 3))
    lux[occupied, 0] = 1000.0  # 300 occupied hours at the threshold
    lux[~occupied, 1] = 5000.0  # sun only outside occupied hours
    lux[np.flatnonzero(occupied)[:249], 2] = 2000.0  # one hour short
    hours, share = ase(lux, times)
    assert hours.tolist() == [300, 0, 249]
    assert share == pytest.approx(1 / 3)
