"""Solar position against published ephemeris values and an independent algorithm; ISO 8601 time parsing."""

import math

import numpy as np
import pytest
from tolerances import DECLINATION_DEG, FLOAT64_ROUNDING, ISSUE_TOL_DEG, NOON_AZIMUTH_DEG, SPA_TOL_DEG
from usdbake.kernels.solar import parse_duration, parse_times, sun_position

def test_nrel_spa_worked_example():
    """Reda & Andreas (2004), NREL/TP-560-34302, Table A5.1: 2003-10-17 12:30:30 MST (UTC-7), 39.742476 N,
    105.1786 W, 820 mbar, 11 C -> topocentric zenith 50.11162 deg, azimuth 194.34024 deg."""
    sun = sun_position(["2003-10-17T12:30:30"], 39.742476, -105.1786, -7.0, pressure_mbar=820.0, temperature_c=11.0)
    assert abs(sun.zenith[0] - 50.11162) < SPA_TOL_DEG
    assert abs(sun.azimuth[0] - 194.34024) < SPA_TOL_DEG


def almanac_sun(utc: np.datetime64, latitude: float, longitude: float) -> tuple[float, float]:
    """Independent low-precision algorithm (Astronomical Almanac, as in Michalsky 1988, Solar Energy 40(3)):
    ecliptic longitude -> right ascension / declination, Greenwich mean sidereal time -> hour angle.
    No refraction. Returns (zenith, azimuth from north towards east) in degrees."""
    n = (utc - np.datetime64("2000-01-01T12:00:00", "s")).astype(float) / 86400.0
    mean_long = (280.460 + 0.9856474 * n) % 360
    anomaly = math.radians((357.528 + 0.9856003 * n) % 360)
    ecl_long = math.radians(mean_long + 1.915 * math.sin(anomaly) + 0.020 * math.sin(2 * anomaly))
    obliquity = math.radians(23.439 - 0.0000004 * n)
    ra = math.atan2(math.cos(obliquity) * math.sin(ecl_long), math.cos(ecl_long))
    dec = math.asin(math.sin(obliquity) * math.sin(ecl_long))
    hours = (utc - utc.astype("datetime64[D]")).astype(float) / 3600.0
    gmst = (6.697375 + 0.0657098242 * (n - hours / 24.0) + 1.00273790935 * hours) % 24  # n at 0h UT + UT
    lmst = (gmst + longitude / 15.0) % 24
    ha = math.radians(lmst * 15.0) - ra
    lat = math.radians(latitude)
    cos_z = math.sin(lat) * math.sin(dec) + math.cos(lat) * math.cos(dec) * math.cos(ha)
    zenith = math.degrees(math.acos(max(-1.0, min(1.0, cos_z))))
    azimuth = math.degrees(math.atan2(math.sin(ha), math.cos(ha) * math.sin(lat) - math.tan(dec) * math.cos(lat)))
    return zenith, (azimuth + 180.0) % 360.0


@pytest.mark.parametrize("latitude, longitude", [(41.98, 2.82), (39.742476, -105.1786), (-33.87, 151.21),
                                                 (64.15, -21.94), (0.0, 0.0)])
def test_agrees_with_independent_almanac_algorithm(latitude, longitude):
    rng = np.random.default_rng(3)  # fixed: 40 random instants over 2000-2040
    seconds = rng.integers(0, 40 * 365 * 86400, 40)
    for s in seconds:
        utc = np.datetime64("2000-01-01T00:00:00", "s") + np.timedelta64(int(s), "s")
        sun = sun_position([utc], latitude, longitude, 0.0, refract=False)
        zenith, azimuth = almanac_sun(utc, latitude, longitude)
        assert abs(sun.zenith[0] - zenith) < ISSUE_TOL_DEG
        if 0.5 < zenith < 179.5:  # azimuth is undefined at the zenith and nadir
            assert abs((sun.azimuth[0] - azimuth + 180) % 360 - 180) < ISSUE_TOL_DEG / math.sin(math.radians(zenith))


def test_seasons_and_solar_noon():
    # 2026 June solstice: declination = obliquity 23.436 deg; March equinox 2026-03-20 14:46 UTC: 0.
    assert abs(sun_position(["2026-06-21T08:24"], 0, 0).declination[0] - 23.436) < DECLINATION_DEG
    assert abs(sun_position(["2026-03-20T14:46"], 0, 0).declination[0]) < DECLINATION_DEG
    # At local solar noon the sun is due south (north of the tropics) and due north (south of them).
    for latitude, expected in ((45.0, 180.0), (-45.0, 0.0)):
        times = np.datetime64("2026-09-10T11:00") + np.arange(0, 120) * np.timedelta64(1, "m")
        sun = sun_position(times, latitude, 0.0, 0.0)
        noon = np.argmin(sun.zenith)
        assert abs((sun.azimuth[noon] - expected + 180) % 360 - 180) < NOON_AZIMUTH_DEG
    # The ENU vector is a unit vector pointing up when the sun is up.
    sun = sun_position(["2026-06-21T12:00"], 41.98, 2.82, 1.0)
    enu = sun.enu()[0]
    np.testing.assert_allclose(np.linalg.norm(enu), 1.0, rtol=FLOAT64_ROUNDING)
    assert enu[2] > 0.9 and enu[1] < 0  # high, and towards the south


def test_parse_times():
    times = parse_times("2026-06-21T06:00/18:00/PT30M")
    assert len(times) == 25
    assert times[0] == np.datetime64("2026-06-21T06:00") and times[-1] == np.datetime64("2026-06-21T18:00")
    assert len(parse_times("2026-06-21T06:00/2026-06-22T06:00/PT1H")) == 25
    assert len(parse_times("2026-06-21T12:00")) == 1
    assert len(parse_times("2026-06-21T09:00,2026-12-21T09:00")) == 2
    assert parse_duration("P1DT2H30M") == np.timedelta64(95400, "s")
    for bad in ("", "noon", "2026-06-21T18:00/06:00/PT1H", "2026-06-21T06:00/18:00/PT0M", "2026-06-21T06:00/18:00",
                "2026-06-21T06:00/18:00/30M"):
        with pytest.raises(ValueError):
            parse_times(bad)
