"""Typical-year weather files: EnergyPlus EPW and NREL TMY3 CSV, read with pvlib.

pvlib (``pvlib.iotools.read_epw`` / ``read_tmy3``) parses the files; before it
does, the layout is checked here line by line (row count, column count, numeric
irradiance, and dates that are days of the calendar: month 1..12, a day of that
month, hour 1..24, 29 February only in a leap year), because a broken file
should fail with one line naming the file, the line, the field and its value,
not with a pandas traceback. Times are local standard time at the
middle of each hour (both formats give the hour *ending* at the stamp).

Beside the irradiance the file may carry the hour's direct normal and diffuse
horizontal illuminance and its dew point (for the Perez luminous efficacy
model, ``kernels/luminous_efficacy.py``); these are optional: read from the rows
here, a missing or unreadable value is NaN, and a column with no value (or only
zeros, for illuminance) is None. Illuminance stored in hundreds of lux (TMY2,
and TMY3 files from before NREL's 2015 revision, such as the Greensboro file
pvlib ships) is recognised by its ratio to the irradiance and scaled to lux.
"""

from __future__ import annotations

import csv
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..core.errors import UsageError

HOURS = 8760
"""Rows of a typical year (a leap-year file has 8784; its 29 February is dropped, as EnergyPlus does)."""

EPW_HEADER_LINES = 8
EPW_COLUMNS = 35
EPW_DNI, EPW_DHI = 14, 15
"""0-based EPW fields: direct normal and diffuse horizontal irradiance, W/m^2."""
EPW_DNI_ILLUMINANCE, EPW_DHI_ILLUMINANCE = 17, 18
"""0-based EPW fields: direct normal and diffuse horizontal illuminance, lux (999999 = missing)."""
EPW_DEW_POINT = 7
"""0-based EPW field: dew point temperature, degC (99.9 = missing)."""

TMY3_HEADER_LINES = 2
TMY3_COLUMNS = 71
TMY3_DNI, TMY3_DHI = 7, 10
TMY3_DNI_ILLUMINANCE, TMY3_DHI_ILLUMINANCE = 16, 19
"""0-based TMY3 columns 'DN illum (lx)' and 'DH illum (lx)'."""
TMY3_DEW_POINT = 34
"""0-based TMY3 column 'Dew-point (C)'."""

MISSING_ILLUMINANCE = 999900.0
"""Illuminance at or above this (EPW writes 999999) or below 0 (TMY3 writes -9900) is missing."""
DEW_POINT_RANGE = (-90.0, 70.0)
"""degC; a dew point outside it (EPW writes 99.9, TMY3 -9900) is missing."""
HECTOLUX_RATIO = 10.0
"""A median illuminance / irradiance below this (daylight gives ~100 lm/W) means the file counts
illuminance in hundreds of lux."""


@dataclass(frozen=True)
class Weather:
    """Hourly irradiance of a typical year and the site it was measured at."""

    source: str
    """The file, for messages and the report."""
    times: np.ndarray
    """(H,) datetime64[m] local standard time at the middle of each hour."""
    direct_normal: np.ndarray
    """(H,) float64 direct normal irradiance, W/m^2."""
    diffuse_horizontal: np.ndarray
    """(H,) float64 diffuse horizontal irradiance, W/m^2."""
    latitude: float
    """Degrees north."""
    longitude: float
    """Degrees east."""
    timezone: float
    """Hours east of UTC of the local standard time."""
    elevation: float
    """Metres."""
    lines: np.ndarray
    """(H,) int64 1-based line of each hour's row in the file, for messages."""
    direct_normal_illuminance: np.ndarray | None = None
    """(H,) float64 direct normal illuminance from the file, lux; NaN where the file says it is missing;
    None when the file has no such values (all missing or zero)."""
    diffuse_horizontal_illuminance: np.ndarray | None = None
    """(H,) float64 diffuse horizontal illuminance from the file, lux; NaN and None as above."""
    dew_point: np.ndarray | None = None
    """(H,) float64 dew point temperature, degC; NaN where missing; None when the file gives none."""

    def __len__(self) -> int:
        return len(self.times)

    def hour_at(self, when: np.datetime64) -> int:
        """Index of the row whose hour holds the local standard time ``when``; its year is ignored (a
        typical year is made of months from several years)."""
        moment = np.datetime64(when, "m").astype(object)
        if (moment.month, moment.day) == (2, 29):
            raise UsageError(f"{self.source}: 29 February is not in a typical year; choose another day")
        t = np.datetime64(f"{self.times[0].astype(object).year:04d}-{moment.month:02d}-{moment.day:02d}T"
                          f"{moment.hour:02d}:{moment.minute:02d}", "m")
        index = int(np.searchsorted(self.times - np.timedelta64(30, "m"), t, side="right")) - 1
        if index < 0 or abs(self.times[index] - t) > np.timedelta64(30, "m"):
            raise UsageError(f"{self.source}: no hour of the file holds {str(np.datetime64(when, 'm'))}")
        return index


SITE_TOLERANCE_DEGREES = 1.0
"""A weather station within about 100 km of the stage's site counts as the same place."""


def check_site(weather: Weather, site: dict) -> None:
    """Refuse a weather file measured elsewhere than the stage's site (``Scene.site``: latitude, longitude,
    timezone and the layer that says so); no site, no check."""
    if not site:
        return
    lon_gap = abs((weather.longitude - site["longitude"] + 180.0) % 360.0 - 180.0)
    if (abs(weather.latitude - site["latitude"]) > SITE_TOLERANCE_DEGREES or lon_gap > SITE_TOLERANCE_DEGREES
            or abs(weather.timezone - site["timezone"]) > 1e-6):
        raise UsageError(
            f"{weather.source}, line 1: the weather's site (latitude {weather.latitude:g}, longitude "
            f"{weather.longitude:g}, UTC{weather.timezone:+g}) disagrees with the stage's (latitude "
            f"{site['latitude']:g}, longitude {site['longitude']:g}, UTC{site['timezone']:+g}, written by "
            f"usdbake sky in {site['layer']}); use a weather file for that place or remake the sky")


def read_weather(path: str | Path) -> Weather:
    """An EPW (``.epw``) or TMY3 CSV (``.csv``) file; UsageError naming the file and line when it is broken."""
    path = Path(path)
    if not path.is_file():
        raise UsageError(f"{path}: no such weather file")
    suffix = path.suffix.lower()
    if suffix == ".epw":
        return _read_epw(path)
    if suffix == ".csv":
        return _read_tmy3(path)
    raise UsageError(f"{path}: unknown weather format {suffix or '(no extension)'!r}; expected .epw (EnergyPlus) "
                     f"or .csv (NREL TMY3)")


def _check_rows(path: Path, header: int, columns: int, numeric: tuple[int, ...]) -> list[list[str]]:
    """The data rows, each with ``columns`` fields and numbers in the ``numeric`` fields."""
    with open(path, newline="", encoding="latin-1") as handle:
        rows = list(csv.reader(handle))
    data = rows[header:]
    while data and not any(field.strip() for field in data[-1]):
        data.pop()  # trailing blank lines
    if len(data) not in (HOURS, HOURS + 24):
        raise UsageError(f"{path}: {len(data)} hourly rows after the {header}-line header; a typical year has "
                         f"{HOURS} (or {HOURS + 24} in a leap year): missing or extra hours")
    for index, row in enumerate(data):
        line = header + index + 1
        if len(row) != columns:
            raise UsageError(f"{path}, line {line}: {len(row)} fields, expected {columns}")
        for field in numeric:
            try:
                value = float(row[field])
            except ValueError:
                raise UsageError(f"{path}, line {line}: field {field + 1} is {row[field]!r}, not a number") from None
            if not np.isfinite(value) or value < 0 or value > 2000:
                raise UsageError(f"{path}, line {line}: irradiance {value} W/m^2 in field {field + 1} is outside "
                                 f"0..2000")
    return rows[:header] + data


def _site(path: Path, latitude: float, longitude: float, timezone: float) -> None:
    if not -90.0 <= latitude <= 90.0:
        raise UsageError(f"{path}, line 1: latitude {latitude} is outside -90..90")
    if not -180.0 <= longitude <= 180.0:
        raise UsageError(f"{path}, line 1: longitude {longitude} is outside -180..180")
    if not -12.0 <= timezone <= 14.0:
        raise UsageError(f"{path}, line 1: time zone {timezone} h is not one (-12..14)")


_DAYS_BEFORE_MONTH = np.cumsum([0, 31, 28, 31, 30, 31, 30, 31, 31, 30, 31, 30])
_DAYS_IN_MONTH = (31, 28, 31, 30, 31, 30, 31, 31, 30, 31, 30, 31)
MONTHS = ("January", "February", "March", "April", "May", "June", "July", "August", "September", "October",
          "November", "December")


def _whole(path: Path, line: int, text: str, said: str) -> int:
    """``text`` as a whole number; else UsageError naming the file, the line, the field (``said``, e.g.
    ``field 2 (month) is``) and its text."""
    try:
        return int(text.strip())
    except ValueError:
        raise UsageError(f"{path}, line {line}: {said} {text.strip()!r}, not a whole number") from None


def _check_date(path: Path, line: int, year: int, month: int, day: int, hour: float, described) -> None:
    """Refuse a row whose date is not one of the calendar, naming the file, the line and the field:
    ``described(name, value)`` says where ``name`` (year, month, day, hour) came from, e.g. ``field 2 (month)
    is 13``. Hours end at the stamp (1..24, 0 < hour <= 24 with minutes); 29 February needs a leap year."""
    where = f"{path}, line {line}: "
    if not 1000 <= year <= 9999:
        raise UsageError(f"{where}{described('year', year)}, not a four-digit year")
    if not 1 <= month <= 12:
        raise UsageError(f"{where}{described('month', month)}, not a month (1..12)")
    leap = month == 2 and (year % 4 == 0 and (year % 100 != 0 or year % 400 == 0))
    last = _DAYS_IN_MONTH[month - 1] + leap
    if not 1 <= day <= last:
        of = f"{MONTHS[month - 1]} {year}" if month == 2 and day == 29 else MONTHS[month - 1]
        raise UsageError(f"{where}{described('day', day)}, not a day of {of} (1..{last})")
    if not 0 < hour <= 24:
        raise UsageError(f"{where}{described('hour', f'{hour:g}')}, not an hour of the day (1..24, the hour "
                         f"ending at the stamp)")


def _epw_time(path: Path, line: int, row: list[str]) -> tuple[int, int, float]:
    """(month, day, hour ending) of an EPW data row, from its fields 1-4: year, month, day, hour (1..24)."""
    names = ("year", "month", "day", "hour")
    year, month, day, hour = (_whole(path, line, row[k], f"field {k + 1} ({names[k]}) is") for k in range(4))
    _check_date(path, line, year, month, day, hour,
                lambda name, value: f"field {names.index(name) + 1} ({name}) is {value}")
    return month, day, float(hour)


def _tmy3_time(path: Path, line: int, row: list[str]) -> tuple[int, int, float]:
    """(month, day, hour ending) of a TMY3 data row, from field 1 (date, MM/DD/YYYY) and 2 (time, HH:MM)."""
    date, time = row[0].strip(), row[1].strip()
    parts, clock = date.split("/"), time.split(":")
    if len(parts) != 3:
        raise UsageError(f"{path}, line {line}: field 1 (date) is {date!r}, not MM/DD/YYYY")
    if len(clock) != 2:
        raise UsageError(f"{path}, line {line}: field 2 (time) is {time!r}, not HH:MM")
    month, day, year = (_whole(path, line, part, f"field 1 (date) {date!r} has {name}")
                        for part, name in zip(parts, ("month", "day", "year")))
    hours, minutes = (_whole(path, line, part, f"field 2 (time) {time!r} has {name}")
                      for part, name in zip(clock, ("hours", "minutes")))
    if not 0 <= minutes < 60:
        raise UsageError(f"{path}, line {line}: field 2 (time) {time!r} has minutes {minutes}, not 0..59")

    def described(name: str, value) -> str:
        field = "field 2 (time)" if name == "hour" else "field 1 (date)"
        return f"{field} {time if name == 'hour' else date!r} has {name} {value}"

    hour = hours + minutes / 60.0
    _check_date(path, line, year, month, day, hour, described)
    return month, day, hour


def _times(path: Path, header: int, rows: list[list[str]], read) -> list[tuple]:
    """``read(path, line, row)`` -> (month, day, hour ending) for every data row, checked before pvlib
    parses the file (which raises a pandas error on a date that is not one)."""
    return [read(path, header + index + 1, row) for index, row in enumerate(rows)]


def _year(path: Path, header: int, months: list[int], days: list[int], hours: list[float],
          frame) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(mid-hour local times, DNI, DHI, file lines): times from each row's month, day and hour ending (1..24), in
    one non-leap year (typical years mix source years, some leap: 29 February is dropped), irradiance
    from pvlib's frame, row for row. The dates are checked already (``_check_date``)."""
    months, days, hours = np.asarray(months), np.asarray(days), np.asarray(hours, np.float64)
    keep = ~((months == 2) & (days == 29))
    day = _DAYS_BEFORE_MONTH[months[keep] - 1] + days[keep] - 1
    minutes = np.rint((day * 24 + hours[keep] - 0.5) * 60).astype(np.int64)
    times = np.datetime64("2025-01-01T00:00", "m") + minutes.astype("timedelta64[m]")
    lines = header + 1 + np.flatnonzero(keep)
    return times, frame["dni"].to_numpy(np.float64)[keep], frame["dhi"].to_numpy(np.float64)[keep], lines


def _optional_column(rows: list[list[str]], lines: np.ndarray, field: int, low: float,
                     high: float) -> np.ndarray | None:
    """The (H,) float64 values of ``field`` in the kept rows (``lines``, 1-based), NaN where a value is not a
    number or is outside [low, high) (the file's code for missing); None when no value is left."""
    values = np.full(len(lines), np.nan)
    for index, line in enumerate(lines):
        try:
            value = float(rows[line - 1][field])
        except (ValueError, IndexError):
            continue
        if low <= value < high:
            values[index] = value
    return None if np.isnan(values).all() else values


def _illuminance(rows: list[list[str]], lines: np.ndarray, fields: tuple[int, int],
                 irradiance: tuple[np.ndarray, np.ndarray]) -> list[np.ndarray | None]:
    """[direct normal, diffuse horizontal] illuminance in lux from ``fields``, each None when the file has no
    non-zero value. Counted in hundreds of lux (TMY2, pre-2015 TMY3) when the median ratio to the
    irradiance over hours above 50 W/m^2 is below ``HECTOLUX_RATIO``, then scaled to lux."""
    columns = []
    for field in fields:
        column = _optional_column(rows, lines, field, 0.0, MISSING_ILLUMINANCE)
        columns.append(column if column is not None and np.nanmax(column) > 0.0 else None)
    ratios = []
    for column, watts in zip(columns, irradiance):
        if column is not None:
            lit = (watts > 50.0) & (column > 0.0)
            ratios.append(column[lit] / watts[lit])
    ratios = np.concatenate(ratios) if ratios else np.empty(0)
    if ratios.size and np.median(ratios) < HECTOLUX_RATIO:
        columns = [None if column is None else column * 100.0 for column in columns]
    return columns


def _photometry(rows: list[list[str]], lines: np.ndarray, illuminance: tuple[int, int], dew_point: int,
                dni: np.ndarray, dhi: np.ndarray) -> dict:
    """Weather's optional fields: illuminance (lux) and dew point (degC) of the kept rows."""
    direct, diffuse = _illuminance(rows, lines, illuminance, (dni, dhi))
    return {"direct_normal_illuminance": direct, "diffuse_horizontal_illuminance": diffuse,
            "dew_point": _optional_column(rows, lines, dew_point, *DEW_POINT_RANGE)}


def _pvlib_frame(path: Path, read, **kwargs):
    """pvlib's data frame of the file; a failure left after the checks here is still one line, naming the file."""
    try:
        frame, _ = read(str(path), **kwargs)
    except (ValueError, KeyError, IndexError) as error:
        reason = " ".join(str(error).split("\n")[0].split())
        raise UsageError(f"{path}: pvlib cannot read it ({reason})") from None
    return frame


def _pvlib_reader(name: str):
    """``pvlib.iotools.<name>``, or a UsageError saying how to install it."""
    try:
        from pvlib import iotools
    except ImportError:
        raise UsageError("weather files are read with pvlib, which is not installed: "
                         "pip install 'usdbake[daylight]'") from None
    return getattr(iotools, name)


def _read_epw(path: Path) -> Weather:
    read_epw = _pvlib_reader("read_epw")

    rows = _check_rows(path, EPW_HEADER_LINES, EPW_COLUMNS, (EPW_DNI, EPW_DHI))
    location = rows[0]
    if len(location) < 10 or location[0].strip().upper() != "LOCATION":
        raise UsageError(f"{path}, line 1: expected 'LOCATION,city,state,country,source,WMO,latitude,longitude,"
                         f"timezone,elevation'")
    try:
        latitude, longitude, timezone, elevation = (float(v) for v in location[6:10])
    except ValueError:
        raise UsageError(f"{path}, line 1: latitude, longitude, time zone and elevation must be numbers") from None
    _site(path, latitude, longitude, timezone)
    when = _times(path, EPW_HEADER_LINES, rows[EPW_HEADER_LINES:], _epw_time)
    frame = _pvlib_frame(path, read_epw)
    times, dni, dhi, lines = _year(path, EPW_HEADER_LINES, *zip(*when), frame)
    extra = _photometry(rows, lines, (EPW_DNI_ILLUMINANCE, EPW_DHI_ILLUMINANCE), EPW_DEW_POINT, dni, dhi)
    return Weather(str(path), times, dni, dhi, latitude, longitude, timezone, elevation, lines, **extra)


def _read_tmy3(path: Path) -> Weather:
    read_tmy3 = _pvlib_reader("read_tmy3")

    rows = _check_rows(path, TMY3_HEADER_LINES, TMY3_COLUMNS, (TMY3_DNI, TMY3_DHI))
    site = rows[0]
    try:
        timezone, latitude, longitude, elevation = (float(v) for v in site[3:7])
    except (ValueError, IndexError):
        raise UsageError(f"{path}, line 1: expected 'USAF,name,state,timezone,latitude,longitude,elevation'") \
            from None
    _site(path, latitude, longitude, timezone)
    when = _times(path, TMY3_HEADER_LINES, rows[TMY3_HEADER_LINES:], _tmy3_time)
    frame = _pvlib_frame(path, read_tmy3, map_variables=True)
    times, dni, dhi, lines = _year(path, TMY3_HEADER_LINES, *zip(*when), frame)
    extra = _photometry(rows, lines, (TMY3_DNI_ILLUMINANCE, TMY3_DHI_ILLUMINANCE), TMY3_DEW_POINT, dni, dhi)
    return Weather(str(path), times, dni, dhi, latitude, longitude, timezone, elevation, lines, **extra)
