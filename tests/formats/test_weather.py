"""Typical-year weather files: the TMY3 file pvlib ships (Greensboro NC, NREL, public domain), an EPW
written from it, and broken copies of both, each refused with one line naming the file and line."""

from __future__ import annotations

import csv
import os
from pathlib import Path

import numpy as np
import pytest

from usdbake.core.errors import UsageError
from usdbake.formats.weather import EPW_COLUMNS, HOURS, read_weather

pvlib = pytest.importorskip("pvlib")
TMY3 = Path(pvlib.__file__).parent / "data" / "723170TYA.CSV"


def tmy3_rows() -> list[list[str]]:
    with open(TMY3, newline="") as handle:
        return list(csv.reader(handle))


def write_epw(path: Path, *, latitude="36.10", timezone="-5.0", drop_row=None, short_row=None, edits=None,
              photometry=False) -> Path:
    """An EPW with the TMY3 file's irradiance (fields 15 and 16), other fields zero; ``edits`` maps (data row,
    0-based field) to the text written there instead. ``photometry`` writes the TMY3 file's dew point (field
    8) and its direct normal and diffuse horizontal illuminance in lux (fields 18 and 19; the TMY3 file
    counts hundreds of lux)."""
    rows = tmy3_rows()[2:]
    lines = [f"LOCATION,Greensboro,NC,USA,TMY3,723170,{latitude},-79.95,{timezone},273.0"]
    lines += [f"HEADER{k}" for k in range(7)]
    for index, row in enumerate(rows):
        if index == drop_row:
            continue
        month, day, year = row[0].split("/")
        hour = int(row[1].split(":")[0])
        fields = [year, str(int(month)), str(int(day)), str(hour), "60", "A7"] + ["0"] * (EPW_COLUMNS - 6)
        fields[14], fields[15] = row[7], row[10]
        if photometry:
            fields[7], fields[17], fields[18] = row[34], str(100 * int(row[16])), str(100 * int(row[19]))
        if index == short_row:
            fields = fields[:-1]
        for (at, field), text in (edits or {}).items():
            if at == index:
                fields[field] = text
        lines.append(",".join(fields))
    path.write_text("\n".join(lines) + "\n")
    return path


def test_shipped_tmy3_file_is_a_year_at_its_site():
    weather = read_weather(TMY3)
    rows = tmy3_rows()
    assert len(weather) == HOURS
    assert (weather.latitude, weather.longitude, weather.timezone, weather.elevation) == (36.1, -79.95, -5.0, 273.0)
    assert str(weather.times[0]) == "2025-01-01T00:30" and str(weather.times[-1]) == "2025-12-31T23:30"
    noon = 12 + 24 * 171  # 21 June, the hour ending 13:00
    assert weather.direct_normal[noon] == float(rows[2 + noon][7])
    assert weather.diffuse_horizontal[noon] == float(rows[2 + noon][10])


def test_an_epw_reads_the_same_year(tmp_path):
    epw = read_weather(write_epw(tmp_path / "greensboro.epw"))
    tmy3 = read_weather(TMY3)
    np.testing.assert_array_equal(epw.times, tmy3.times)
    np.testing.assert_array_equal(epw.direct_normal, tmy3.direct_normal)
    np.testing.assert_array_equal(epw.diffuse_horizontal, tmy3.diffuse_horizontal)
    assert (epw.latitude, epw.longitude, epw.timezone) == (36.1, -79.95, -5.0)


@pytest.mark.parametrize("kwargs, message", [
    ({"drop_row": 100}, "8759 hourly rows after the 8-line header; a typical year has 8760 (or 8784 in a leap "
                        "year): missing or extra hours"),
    ({"short_row": 41}, ", line 50: 34 fields, expected 35"),
    ({"latitude": "95.0"}, ", line 1: latitude 95.0 is outside -90..90"),
    ({"timezone": "20"}, ", line 1: time zone 20.0 h is not one (-12..14)"),
])
def test_broken_epw_is_refused_naming_file_and_line(tmp_path, kwargs, message):
    path = write_epw(tmp_path / "broken.epw", **kwargs)
    with pytest.raises(UsageError) as error:
        read_weather(path)
    assert str(error.value) == f"{path}{'' if message.startswith(',') else ': '}{message}"


@pytest.mark.parametrize("edits, line, problem", [
    ({(100, 1): "13"}, 109, "field 2 (month) is 13, not a month (1..12)"),
    ({(100, 1): "0"}, 109, "field 2 (month) is 0, not a month (1..12)"),
    ({(100, 2): "45"}, 109, "field 3 (day) is 45, not a day of January (1..31)"),
    ({(2400, 2): "31"}, 2409, "field 3 (day) is 31, not a day of April (1..30)"),
    ({(24 * 58, 0): "1999", (24 * 58, 2): "29"}, 8 + 24 * 58 + 1,
     "field 3 (day) is 29, not a day of February 1999 (1..28)"),
    ({(100, 3): "99"}, 109, "field 4 (hour) is 99, not an hour of the day (1..24, the hour ending at the stamp)"),
    ({(100, 3): "0"}, 109, "field 4 (hour) is 0, not an hour of the day (1..24, the hour ending at the stamp)"),
    ({(100, 3): "12.5"}, 109, "field 4 (hour) is '12.5', not a whole number"),
    ({(100, 1): "Jan"}, 109, "field 2 (month) is 'Jan', not a whole number"),
    ({(100, 2): ""}, 109, "field 3 (day) is '', not a whole number"),
    ({(100, 0): "99"}, 109, "field 1 (year) is 99, not a four-digit year"),
], ids=["month-13", "month-0", "day-45", "31-april", "29-february-1999", "hour-99", "hour-0", "hour-12.5",
        "month-Jan", "day-empty", "year-99"])
def test_an_epw_date_that_is_not_one_names_line_field_and_value(tmp_path, edits, line, problem):
    """Checked before pvlib reads the file: pvlib (pandas) raised a ValueError on each of these."""
    path = write_epw(tmp_path / "broken.epw", edits=edits)
    with pytest.raises(UsageError) as error:
        read_weather(path)
    assert str(error.value) == f"{path}, line {line}: {problem}"


def test_29_february_of_a_leap_year_is_read_and_left_out(tmp_path):
    path = write_epw(tmp_path / "leap.epw", edits={(24 * 58, 0): "2000", (24 * 58, 2): "29"})
    weather = read_weather(path)
    assert len(weather) == HOURS - 1  # the typical year's hour on 29 February is dropped, as EnergyPlus does
    assert 8 + 24 * 58 + 1 not in weather.lines


@pytest.mark.parametrize("field, text, problem", [
    (0, "13/01/1988", "field 1 (date) '13/01/1988' has month 13, not a month (1..12)"),
    (0, "04/31/1988", "field 1 (date) '04/31/1988' has day 31, not a day of April (1..30)"),
    (0, "01-21-1988", "field 1 (date) is '01-21-1988', not MM/DD/YYYY"),
    (0, "1/x/1988", "field 1 (date) '1/x/1988' has day 'x', not a whole number"),
    (1, "25:00", "field 2 (time) '25:00' has hour 25, not an hour of the day (1..24, the hour ending at the stamp)"),
    (1, "01:75", "field 2 (time) '01:75' has minutes 75, not 0..59"),
    (1, "noon", "field 2 (time) is 'noon', not HH:MM"),
], ids=["month-13", "31-april", "dashes", "day-x", "hour-25", "minute-75", "noon"])
def test_a_tmy3_date_that_is_not_one_names_line_field_and_value(tmp_path, field, text, problem):
    rows = tmy3_rows()
    rows[500][field] = text
    path = tmp_path / "broken.csv"
    with open(path, "w", newline="") as handle:
        csv.writer(handle).writerows(rows)
    with pytest.raises(UsageError) as error:
        read_weather(path)
    assert str(error.value) == f"{path}, line 501: {problem}"


def test_non_numeric_irradiance_names_the_line(tmp_path):
    rows = tmy3_rows()
    rows[500][7] = "n/a"
    path = tmp_path / "broken.csv"
    with open(path, "w", newline="") as handle:
        csv.writer(handle).writerows(rows)
    with pytest.raises(UsageError) as error:
        read_weather(path)
    assert str(error.value) == f"{path}, line 501: field 8 is 'n/a', not a number"


def test_missing_and_unknown_files(tmp_path):
    with pytest.raises(UsageError, match="no such weather file"):
        read_weather(tmp_path / "nowhere.epw")
    other = tmp_path / "weather.txt"
    other.write_text("x")
    with pytest.raises(UsageError, match=r"unknown weather format '.txt'; expected .epw \(EnergyPlus\) or .csv"):
        read_weather(other)


def test_tmy3_file_stays_untouched():
    before = os.path.getmtime(TMY3), TMY3.read_bytes()
    read_weather(TMY3)
    assert (os.path.getmtime(TMY3), TMY3.read_bytes()) == before


def test_the_hour_holding_a_time_is_its_row_whatever_the_year():
    weather = read_weather(TMY3)
    noon = 12 + 24 * 171  # 21 June, the hour 12:00-13:00 (ending 13:00)
    for when in ("2026-06-21T12:00", "2031-06-21T12:59", "2025-06-21T12:30"):
        assert weather.hour_at(np.datetime64(when)) == noon
    assert weather.hour_at(np.datetime64("2026-06-21T11:59")) == noon - 1
    assert weather.lines[noon] == 2 + noon + 1  # two header lines, 1-based
    with pytest.raises(UsageError, match="29 February is not in a typical year"):
        weather.hour_at(np.datetime64("2028-02-29T12:00"))


def test_a_weather_file_from_elsewhere_than_the_stage_is_refused():
    from usdbake.formats.weather import check_site

    weather = read_weather(TMY3)
    here = {"latitude": 36.3, "longitude": -80.5, "timezone": -5.0, "layer": "sky.usda"}
    check_site(weather, here)  # the same place, within a degree
    check_site(weather, {})  # a stage that does not say
    girona = {"latitude": 41.98, "longitude": 2.82, "timezone": 1.0, "layer": "sky.usda"}
    with pytest.raises(UsageError) as error:
        check_site(weather, girona)
    assert str(error.value) == (
        f"{TMY3}, line 1: the weather's site (latitude 36.1, longitude -79.95, UTC-5) disagrees with the stage's "
        f"(latitude 41.98, longitude 2.82, UTC+1, written by usdbake sky in sky.usda); use a weather file for "
        f"that place or remake the sky")
    with pytest.raises(UsageError, match="disagrees"):
        check_site(weather, {**here, "timezone": -6.0})


def test_shipped_tmy3_file_gives_illuminance_in_lux_and_dew_point():
    """The Greensboro file (TMY3 from before NREL's 2015 revision) counts illuminance in hundreds of lux
    although its header says lx: read as lux (x 100)."""
    weather = read_weather(TMY3)
    rows = tmy3_rows()
    noon = 12 + 24 * 171  # 21 June, the hour ending 13:00
    assert weather.direct_normal_illuminance[noon] == 100.0 * float(rows[2 + noon][16])
    assert weather.diffuse_horizontal_illuminance[noon] == 100.0 * float(rows[2 + noon][19])
    assert weather.dew_point[noon] == float(rows[2 + noon][34])
    for column in (weather.direct_normal_illuminance, weather.diffuse_horizontal_illuminance, weather.dew_point):
        assert column.shape == (HOURS,) and column.dtype == np.float64 and not np.isnan(column).any()
    assert 50_000.0 < weather.direct_normal_illuminance.max() < 130_000.0  # lux of full sun


def test_an_epw_reads_the_same_illuminance_and_dew_point(tmp_path):
    epw = read_weather(write_epw(tmp_path / "greensboro.epw", photometry=True))
    tmy3 = read_weather(TMY3)
    np.testing.assert_array_equal(epw.direct_normal_illuminance, tmy3.direct_normal_illuminance)
    np.testing.assert_array_equal(epw.diffuse_horizontal_illuminance, tmy3.diffuse_horizontal_illuminance)
    np.testing.assert_array_equal(epw.dew_point, tmy3.dew_point)


def test_illuminance_and_dew_point_the_file_lacks_are_none(tmp_path):
    """Zero illuminance fields (a file without them) and EPW's missing codes: 999999 lux, 99.9 degC."""
    zero = read_weather(write_epw(tmp_path / "zero.epw"))
    assert zero.direct_normal_illuminance is None and zero.diffuse_horizontal_illuminance is None
    missing = {(row, field): text for row in range(HOURS) for field, text in ((7, "99.9"), (17, "999999"),
                                                                               (18, "999999"))}
    weather = read_weather(write_epw(tmp_path / "missing.epw", photometry=True, edits=missing))
    assert weather.direct_normal_illuminance is None and weather.diffuse_horizontal_illuminance is None
    assert weather.dew_point is None
    np.testing.assert_array_equal(weather.direct_normal, read_weather(TMY3).direct_normal)


def test_a_missing_hour_of_illuminance_or_dew_point_is_nan(tmp_path):
    noon = 12 + 24 * 171
    edits = {(noon, 17): "999999", (noon, 7): "99.9", (noon + 1, 18): "n/a"}
    weather = read_weather(write_epw(tmp_path / "gaps.epw", photometry=True, edits=edits))
    tmy3 = read_weather(TMY3)
    assert np.isnan(weather.direct_normal_illuminance[noon]) and np.isnan(weather.dew_point[noon])
    assert np.isnan(weather.diffuse_horizontal_illuminance[noon + 1])
    assert np.isnan(weather.direct_normal_illuminance).sum() == np.isnan(weather.dew_point).sum() == 1
    assert weather.diffuse_horizontal_illuminance[noon] == tmy3.diffuse_horizontal_illuminance[noon]


@pytest.mark.parametrize("field, text, problem", [
    (14, "9999", "irradiance 9999.0 W/m^2 in field 15 is outside 0..2000"),
    (15, "9999", "irradiance 9999.0 W/m^2 in field 16 is outside 0..2000"),
    (14, "", "field 15 is '', not a number"),
    (15, "", "field 16 is '', not a number"),
], ids=["dni-missing", "dhi-missing", "dni-empty", "dhi-empty"])
def test_an_epw_without_dni_or_dhi_is_refused_though_it_has_illuminance(tmp_path, field, text, problem):
    """9999 is EPW's code for missing irradiance: the illuminance and dew point columns never stand in for it,
    and the refusal comes when the file is read (annual_daylight reads it before any compute)."""
    path = write_epw(tmp_path / "no_irradiance.epw", photometry=True, edits={(100, field): text})
    with pytest.raises(UsageError) as error:
        read_weather(path)
    assert str(error.value) == f"{path}, line 109: {problem}"


def test_a_tmy3_file_without_dhi_is_refused(tmp_path):
    rows = tmy3_rows()
    for row in rows[2:]:
        row[10] = ""
    path = tmp_path / "no_dhi.csv"
    with open(path, "w", newline="") as handle:
        csv.writer(handle).writerows(rows)
    with pytest.raises(UsageError) as error:
        read_weather(path)
    assert str(error.value) == f"{path}, line 3: field 11 is '', not a number"
