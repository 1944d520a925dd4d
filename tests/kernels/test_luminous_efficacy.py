"""Perez et al. (1990) luminous efficacy of daylight against the Greensboro TMY3 file pvlib ships (its own
illuminance columns), against hours worked out by hand from the paper's formulas, and on night hours and
zeros.

The file's illuminance columns are themselves the Perez model, applied by the NSRDB without the
precipitable-water term (W = 0): diffuse as the global efficacy (eqn 6) less the beam. With W = 0 our beam
efficacy reproduces the file's hour by hour; with each hour's dew point (as gendaymtx -O0 does) the beam
reads ~6 % lower and the diffuse ~10 % higher than the file's (medians).
"""

import math
import warnings
from pathlib import Path

import numpy as np
import pytest
from tolerances import (EFFICACY_FILE_CONVENTION, EFFICACY_MEDIAN_MATCH, EFFICACY_NOMINAL,
                        EFFICACY_PRECIPITABLE_WATER, FLOAT64_ROUNDING, QUOTED_4_DECIMALS)
from usdbake.formats.weather import read_weather
from usdbake.kernels.luminous_efficacy import illuminance, perez_efficacy
from usdbake.kernels.solar import day_of_year, sun_position

pvlib = pytest.importorskip("pvlib")
TMY3 = Path(pvlib.__file__).parent / "data" / "723170TYA.CSV"

NO_PRECIPITABLE_WATER = -300.0
"""A dew point (degC) whose precipitable water exp(0.07 Td - 0.075) is ~1e-9 cm: the file's convention."""

BEAM_RANGE = (50.0, 160.0)
"""lm/W: daylight's beam efficacy with the sun above 15 degrees (the file's own: 65-110)."""
DIFFUSE_RANGE = (100.0, 180.0)
"""lm/W: the diffuse sky's (the file's own reach 175 under clear skies with a low sun; ours 108-167)."""


@pytest.fixture(scope="module")
def year():
    """The Greensboro year: weather, sun zenith (degrees, mid-hour), day of year, and the daylight hours
    with a beam (DNI > 50 W/m^2) and with a sky (DHI > 50 W/m^2)."""
    weather = read_weather(TMY3)
    zenith = sun_position(weather.times, weather.latitude, weather.longitude, weather.timezone).zenith
    day = day_of_year(weather.times)
    up = zenith < 90.0
    beam = up & (weather.direct_normal > 50.0)
    sky = up & (weather.diffuse_horizontal > 50.0)
    return weather, zenith, day, beam, sky


def file_efficacy(year):
    """(beam, diffuse) lm/W of the file itself over its beam and sky hours."""
    weather, _, _, beam, sky = year
    return (weather.direct_normal_illuminance[beam] / weather.direct_normal[beam],
            weather.diffuse_horizontal_illuminance[sky] / weather.diffuse_horizontal[sky])


def our_efficacy(year, dew_point):
    weather, zenith, day, beam, sky = year
    k_beam, k_diffuse = perez_efficacy(weather.direct_normal, weather.diffuse_horizontal, zenith, day, dew_point)
    return k_beam[beam], k_diffuse[sky]


def test_the_file_gives_daylight_efficacies_not_179(year):
    file_beam, file_diffuse = file_efficacy(year)
    assert np.median(file_beam) == pytest.approx(100.0, rel=EFFICACY_NOMINAL)
    assert np.median(file_diffuse) == pytest.approx(120.0, rel=EFFICACY_NOMINAL)


def test_in_the_files_convention_ours_reproduce_its_columns(year):
    """W = 0, as the NSRDB computed the file: the beam matches hour by hour, the diffuse in the median."""
    file_beam, file_diffuse = file_efficacy(year)
    beam, diffuse = our_efficacy(year, NO_PRECIPITABLE_WATER)
    assert np.median(beam / file_beam) == pytest.approx(1.0, abs=EFFICACY_FILE_CONVENTION)
    low, high = np.percentile(beam / file_beam, [10, 90])
    assert 1.0 - EFFICACY_FILE_CONVENTION < low and high < 1.0 + EFFICACY_FILE_CONVENTION
    assert np.median(diffuse / file_diffuse) == pytest.approx(1.0, abs=EFFICACY_FILE_CONVENTION)
    assert np.median(beam) == pytest.approx(np.median(file_beam), rel=EFFICACY_MEDIAN_MATCH)
    assert np.median(diffuse) == pytest.approx(np.median(file_diffuse), rel=EFFICACY_MEDIAN_MATCH)


def test_with_the_hours_dew_point_as_gendaymtx(year):
    """Each hour's dew point, as gendaymtx -O0 reads it from an EPW: humid air (b < 0 for the beam in the
    cloudy bins, b > 0 for the diffuse) moves the beam down and the diffuse up against the file."""
    weather = year[0]
    file_beam, file_diffuse = file_efficacy(year)
    beam, diffuse = our_efficacy(year, weather.dew_point)
    assert 1.0 - EFFICACY_PRECIPITABLE_WATER < np.median(beam / file_beam) < 1.0
    assert 1.0 < np.median(diffuse / file_diffuse) < 1.0 + EFFICACY_PRECIPITABLE_WATER
    assert np.median(beam) == pytest.approx(np.median(file_beam), rel=EFFICACY_PRECIPITABLE_WATER)
    assert np.median(diffuse) == pytest.approx(np.median(file_diffuse), rel=EFFICACY_PRECIPITABLE_WATER)


def test_a_clear_hour_worked_by_hand():
    """DNI 850, DHI 90 W/m^2, sun zenith 30 degrees, 21 June (day 172), dew point 15 degC."""
    z = math.radians(30.0)
    kz3 = 1.041 * z ** 3
    epsilon = ((90.0 + 850.0) / 90.0 + kz3) / (1.0 + kz3)  # eqn 1: 9.22
    assert 6.2 <= epsilon < 11.9  # the clear bin, the 8th
    air_mass = 1.0 / (math.cos(z) + 0.15 * (93.885 - 30.0) ** -1.253)  # Kasten 1966
    angle = 2.0 * math.pi * (172 - 1) / 365.0
    e0 = (1.00011 + 0.034221 * math.cos(angle) + 0.00128 * math.sin(angle) + 0.000719 * math.cos(2 * angle)
          + 0.000077 * math.sin(2 * angle))  # Spencer 1971
    delta = 90.0 * air_mass / (1367.0 * e0)  # eqn 2: 0.0785
    assert 0.01 < delta < 0.6
    w = math.exp(0.07 * 15.0 - 0.075)  # eqn 3, cm
    k_diffuse = 152.23 + 0.35 * w - 45.27 * math.cos(z) - 7.98 * math.log(delta)  # eqn 7, Table 4 bin 8
    k_beam = 101.18 + 1.58 * w - 1.10 * math.exp(5.73 * z - 5.0) - 8.29 * delta  # eqn 8, Table 4 bin 8
    assert (k_beam, k_diffuse) == (pytest.approx(104.5691, abs=QUOTED_4_DECIMALS),
                                   pytest.approx(134.2586, abs=QUOTED_4_DECIMALS))
    ours = perez_efficacy(850.0, 90.0, 30.0, 172, 15.0)
    assert ours == (pytest.approx(k_beam, rel=FLOAT64_ROUNDING), pytest.approx(k_diffuse, rel=FLOAT64_ROUNDING))
    lux = illuminance(850.0, 90.0, 30.0, 172, 15.0)
    assert lux == (pytest.approx(850.0 * k_beam, rel=FLOAT64_ROUNDING),
                   pytest.approx(90.0 * k_diffuse, rel=FLOAT64_ROUNDING))


def test_an_overcast_hour_worked_by_hand():
    """No beam, DHI 150 W/m^2, sun zenith 60 degrees, 15 January, dew point 5 degC."""
    z = math.radians(60.0)
    kz3 = 1.041 * z ** 3
    epsilon = ((150.0 + 0.0) / 150.0 + kz3) / (1.0 + kz3)  # eqn 1: exactly 1
    assert epsilon < 1.065  # the overcast bin, the 1st
    air_mass = 1.0 / (math.cos(z) + 0.15 * (93.885 - 60.0) ** -1.253)
    angle = 2.0 * math.pi * (15 - 1) / 365.0
    e0 = (1.00011 + 0.034221 * math.cos(angle) + 0.00128 * math.sin(angle) + 0.000719 * math.cos(2 * angle)
          + 0.000077 * math.sin(2 * angle))
    delta = 150.0 * air_mass / (1367.0 * e0)  # 0.211
    w = math.exp(0.07 * 5.0 - 0.075)
    k_diffuse = 97.24 - 0.46 * w + 12.00 * math.cos(z) - 8.91 * math.log(delta)  # Table 4 bin 1
    k_beam = 57.20 - 4.55 * w - 2.98 * math.exp(5.73 * z - 5.0) + 117.12 * delta
    assert (k_beam, k_diffuse) == (pytest.approx(67.8660, abs=QUOTED_4_DECIMALS),
                                   pytest.approx(116.4802, abs=QUOTED_4_DECIMALS))
    ours = perez_efficacy(0.0, 150.0, 60.0, 15, 5.0)
    assert ours == (pytest.approx(k_beam, rel=FLOAT64_ROUNDING), pytest.approx(k_diffuse, rel=FLOAT64_ROUNDING))
    assert illuminance(0.0, 150.0, 60.0, 15, 5.0) == (0.0, pytest.approx(150.0 * k_diffuse, rel=FLOAT64_ROUNDING))


def test_night_zeros_and_missing_values_give_finite_efficacies():
    dni = np.array([0.0, 0.0, 500.0, 0.0, np.nan, 300.0, 1e-9])
    dhi = np.array([0.0, 0.0, 0.0, 80.0, 50.0, np.nan, 0.0])
    zenith = np.array([120.0, 89.9, 40.0, 95.0, 50.0, 0.0, 180.0])
    dew = np.array([11.0, np.nan, -40.0, 30.0, 11.0, 11.0, np.nan])
    with warnings.catch_warnings(), np.errstate(all="raise"):
        warnings.simplefilter("error")
        k_beam, k_diffuse = perez_efficacy(dni, dhi, zenith, np.arange(1, 8) * 50, dew)
        direct, diffuse = illuminance(dni, dhi, zenith, 365, dew)
        night = perez_efficacy(0.0, 0.0, 150.0, 1)
    assert k_beam.shape == k_diffuse.shape == direct.shape == (7,)
    assert np.all(np.isfinite(k_beam)) and np.all(np.isfinite(k_diffuse))
    assert np.all(k_beam >= 0.0) and np.all(k_diffuse > 0.0)
    assert np.all(np.isfinite(direct)) and np.all(np.isfinite(diffuse))
    assert direct[0] == diffuse[0] == 0.0 and direct[4] == 0.0 and diffuse[5] == 0.0  # no light, NaN as none
    assert np.all(np.isfinite(night)) and np.ndim(night[0]) == 0
    # a beam with no diffuse light is the clearest sky: the clear bin's efficacy, as for a tiny DHI
    assert k_beam[2] == pytest.approx(perez_efficacy(500.0, 1e-6, 40.0, 150, -40.0)[0], rel=FLOAT64_ROUNDING)


def test_daylight_efficacies_are_physical(year):
    """Over the year's hours with the sun above 15 degrees: the beam in 50-160 lm/W, the diffuse sky in 100-180
    lm/W (bluer than sunlight, so more lumens per watt); far from Radiance's 179 for the beam."""
    weather, zenith, day, _, _ = year
    k_beam, k_diffuse = perez_efficacy(weather.direct_normal, weather.diffuse_horizontal, zenith, day,
                                       weather.dew_point)
    high = zenith < 75.0
    beam, sky = high & (weather.direct_normal > 50.0), high & (weather.diffuse_horizontal > 50.0)
    assert beam.sum() > 2000 and sky.sum() > 3000
    assert BEAM_RANGE[0] <= k_beam[beam].min() and k_beam[beam].max() <= BEAM_RANGE[1]
    assert DIFFUSE_RANGE[0] <= k_diffuse[sky].min() and k_diffuse[sky].max() <= DIFFUSE_RANGE[1]
    assert np.median(k_diffuse[sky]) > np.median(k_beam[beam])


def test_the_beam_loses_efficacy_towards_the_horizon_and_in_humid_air():
    """Longer paths through the air redden the beam: for one sky (DNI 800, DHI 100 W/m^2) the beam efficacy
    never rises as the sun sinks; humid air (dew point 25 against 0 degC) lowers it under a partly cloudy sky
    (Table 4: b < 0 in the bins below epsilon 4.5)."""
    zenith = np.linspace(3.0, 89.0, 87)
    k_beam, _ = perez_efficacy(np.full(87, 800.0), 100.0, zenith, 172)
    assert np.all(np.diff(k_beam) <= 0.0) and k_beam[0] > 100.0 > k_beam[-1]
    dry, humid = perez_efficacy(300.0, 200.0, 50.0, 100, np.array([0.0, 25.0]))[0]
    assert humid < dry
