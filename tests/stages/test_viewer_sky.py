"""stages/viewer/sky.js, the viewer's port of the sun position, sky models and daylight weights, run in Node
against the Python it ports (kernels/solar.py, kernels/sky.py, kernels/luminous_efficacy.py and the daylight
relighting helpers): float64 on both sides, so they agree to 1e-6 relative (1e-9 of the largest value
absolute). Skipped where there is no ``node``."""

from __future__ import annotations

import json
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest
from tolerances import JAVASCRIPT_PORT, JAVASCRIPT_PORT_ABSOLUTE

from usdbake.kernels.luminous_efficacy import perez_efficacy
from usdbake.kernels.sky import (patch_layout, patch_radiance, patch_samples, perez_coefficients, perez_sky_state,
                                 sun_normal_irradiance, tregenza_patches)
from usdbake.kernels.solar import day_of_year, refraction, sun_position

from usdbake.kernels.daylight_relight import (ground_radiance, horizontal_cosines, sky_model_tables, sky_weights,
                                              sun_normal, sun_patch_weights, visible_factors)

NODE = shutil.which("node")
if NODE is None:
    pytest.skip("no node on this machine", allow_module_level=True)

SKY_JS = Path(__file__).resolve().parents[2] / "stages" / "viewer" / "sky.js"
RTOL = JAVASCRIPT_PORT
ATOL_OF_MAX = JAVASCRIPT_PORT_ABSOLUTE

DRIVER = r"""
"use strict";
const fs = require("fs"), vm = require("vm");
const path = process.argv[2];
const sky = require(path);
// As a plain <script>: no module object, the functions become globals of the context.
const context = vm.createContext({});
vm.runInContext(fs.readFileSync(path, "utf8"), context, {filename: path});
const globals = Object.keys(sky).filter((name) => vm.runInContext(`typeof ${name}`, context) !== "undefined");
const input = JSON.parse(fs.readFileSync(0, "utf8"));
const tables = {};
for (const [name, values] of Object.entries(input.tables)) tables[name] = Float64Array.from(values);
const decode = (a) => (a !== null && typeof a === "object" && !Array.isArray(a) && "table" in a) ? tables[a.table] : a;
const encode = (v) => ArrayBuffer.isView(v) ? Array.from(v)
  : Array.isArray(v) ? v.map(encode)
  : (v !== null && typeof v === "object") ? Object.fromEntries(Object.entries(v).map(([k, x]) => [k, encode(x)]))
  : v;
sky.setSkyTables(input.skyTables);
const results = input.calls.map(([fn, args]) => encode(sky[fn](...args.map(decode))));
process.stdout.write(JSON.stringify({exports: Object.keys(sky), globals, results}));
"""

# (local standard time, latitude, longitude, timezone): mid-latitudes both sides of the equator, the NREL SPA
# paper's example, half-hour zones, polar night and day, the sun below the horizon and near it, 1900..2099.
SUN_CASES = [
    ("2026-06-21T12:00", 41.98, 2.82, 1.0),
    ("2026-12-21T08:30", 41.98, 2.82, 1.0),
    ("2003-10-17T12:30:30", 39.742476, -105.1786, -7.0),
    ("2026-03-20T07:05", -33.87, 151.21, 10.0),
    ("2026-07-01T15:45", -33.87, 151.21, 10.0),
    ("2026-01-15T23:10", -33.87, 151.21, 10.0),
    ("2025-02-28T06:20", 28.61, 77.21, 5.5),
    ("2025-09-09T17:50", 27.72, 85.32, 5.75),
    ("2024-02-29T13:00", 47.56, -52.71, -3.5),
    ("2026-12-21T12:00", 69.65, 18.96, 1.0),
    ("2026-06-21T00:30", 69.65, 18.96, 1.0),
    ("2026-12-21T12:00", 90.0, 0.0, 0.0),
    ("2026-06-21T12:00", 90.0, 0.0, 0.0),
    ("2026-12-21T06:00", -90.0, 0.0, 0.0),
    ("2026-06-10T10:00", -77.85, 166.67, 12.0),
    ("2026-03-21T06:05", 0.0, -78.5, -5.0),
    ("2026-09-23T18:10", -0.2, -78.5, -5.0),
    ("1900-01-01T00:00", 51.48, 0.0, 0.0),
    ("1969-12-31T23:59", 40.71, -74.01, -5.0),
    ("2099-12-31T16:20", -54.8, -68.3, -3.0),
    ("2026-11-05T05:45", 64.14, -21.94, 0.0),
    ("2026-08-15T19:59", 35.68, 139.69, 9.0),
]


def _random_sun_cases(count: int) -> list[tuple[str, float, float, float]]:
    rng = np.random.default_rng(20260621)
    cases = []
    for _ in range(count):
        minutes = int(rng.integers(0, 200 * 365 * 1440))
        time = np.datetime64("1900-01-01T00:00", "m") + np.timedelta64(minutes, "m")
        longitude = float(rng.uniform(-180, 180))
        cases.append((str(time), float(rng.uniform(-90, 90)), longitude, float(round(longitude / 15.0))))
    return cases


def local_ms(text: str) -> int:
    return int((np.datetime64(text, "ms") - np.datetime64("1970-01-01T00:00", "ms")).astype(np.int64))


def unit(vector) -> np.ndarray:
    vector = np.asarray(vector, np.float64)
    return vector / np.linalg.norm(vector)


def altaz(altitude_deg: float, azimuth_deg: float) -> np.ndarray:
    alt, az = np.radians(altitude_deg), np.radians(azimuth_deg)
    return np.array([np.sin(az) * np.cos(alt), np.cos(az) * np.cos(alt), np.sin(alt)])


def assert_close(js, expected, label: str) -> None:
    js = np.asarray(js, np.float64)
    expected = np.asarray(expected, np.float64)
    assert js.shape == expected.shape, f"{label}: shape {js.shape} != {expected.shape}"
    scale = float(np.abs(expected).max()) if expected.size else 0.0
    np.testing.assert_allclose(js, expected, rtol=RTOL, atol=ATOL_OF_MAX * scale, err_msg=label)


def assert_angle_close(js: float, expected: float, period: float, label: str) -> None:
    difference = (js - expected + period / 2) % period - period / 2
    assert abs(difference) <= RTOL * max(abs(expected), 1.0), f"{label}: {js} != {expected}"


class Calls:
    """JS calls collected for one Node run; arrays shared by many calls travel once, as named tables."""

    def __init__(self) -> None:
        self.tables: dict[str, list[float]] = {}
        self.calls: list = []
        self.checks: dict[str, list] = {}

    def table(self, name: str, values) -> dict:
        self.tables[name] = np.asarray(values, np.float64).ravel().tolist()
        return {"table": name}

    def add(self, group: str, label: str, fn: str, args: list, expected) -> None:
        self.checks.setdefault(group, []).append((label, len(self.calls), expected))
        self.calls.append((fn, args))


def suns() -> list[tuple[str, np.ndarray]]:
    """Sun directions for the sky models: from sun_position, plus low, high, nearly overhead and set suns."""
    out = []
    for text, lat, lon, tz in SUN_CASES[:6]:
        out.append((f"sun {text} {lat}", sun_position(np.datetime64(text), lat, lon, tz).enu()[0]))
    out += [("sun alt 3", altaz(3.0, 250.0)), ("sun alt 75", altaz(75.0, 100.0)),
            ("sun alt 89.9", altaz(89.9, 33.0)), ("sun alt -4", altaz(-4.0, 300.0)),
            ("sun not unit", 2.5 * altaz(40.0, 200.0))]
    return out


SKY_MODELS = [
    ("preetham", dict(turbidity=3.0)), ("preetham", dict(turbidity=2.2)), ("preetham", dict(turbidity=7.5)),
    ("perez", dict(direct_normal=600.0, diffuse_horizontal=150.0, day_of_year=172)),
    ("perez", dict(direct_normal=0.0, diffuse_horizontal=300.0, day_of_year=15)),  # overcast: clearness bin 1
    ("perez", dict(direct_normal=850.0, diffuse_horizontal=60.0, day_of_year=200)),  # clear: bin 8
    ("perez", dict(direct_normal=120.0, diffuse_horizontal=210.0, day_of_year=300)),
    ("overcast", {}), ("uniform", dict(radiance=1000.0)),
]


def js_params(kwargs: dict) -> dict:
    names = {"direct_normal": "directNormal", "diffuse_horizontal": "diffuseHorizontal", "day_of_year": "dayOfYear"}
    return {names.get(key, key): value for key, value in kwargs.items()}


def build() -> Calls:
    calls = Calls()
    for text, lat, lon, tz in SUN_CASES + _random_sun_cases(14):
        position = sun_position(np.datetime64(text), lat, lon, tz)
        expected = dict(zenith=position.zenith[0], azimuth=position.azimuth[0], declination=position.declination[0],
                        hourAngle=position.hour_angle[0], equationOfTime=position.equation_of_time[0],
                        enu=position.enu()[0], dayOfYear=int(day_of_year(np.datetime64(text))[0]))
        calls.add("sun", f"{text} lat {lat} lon {lon} tz {tz}", "sunPosition", [local_ms(text), lat, lon, tz], expected)
        calls.add("day", text, "dayOfYear", [local_ms(text)], expected["dayOfYear"])
    for elevation in (-7.0, -0.6, -0.2, 0.0, 2.5, 4.9, 5.1, 30.0, 84.0, 86.0):
        calls.add("refraction", f"elevation {elevation}", "refraction", [elevation], refraction(elevation))

    layouts = [("uniform256", patch_layout("uniform", count=256)), ("tregenza", tregenza_patches())]
    for name, patches in layouts:
        samples = calls.table(f"{name}/samples", patch_samples(patches, 3))
        solid = calls.table(f"{name}/solid", patches.patch_solid_angles)
        directions = calls.table(f"{name}/directions", patches.patch_directions)
        cosines = horizontal_cosines(patches)
        calls.add("cosines", name, "horizontalCosines", [samples, len(patches)], cosines)
        for sun_label, sun in suns():
            for model, kwargs in SKY_MODELS:
                label = f"{name} {model} {kwargs} {sun_label}"
                calls.add("radiance", label, "patchRadiance", [samples, model, sun.tolist(), js_params(kwargs)],
                          patch_radiance(patches, model, sun, **kwargs).ravel())
                for efficacy in ("perez", "179") if model == "perez" else ("perez",):
                    full = {"turbidity": 3.0, "radiance": 1.0, **kwargs}
                    weights = sky_weights(patches, model, sun, efficacy=efficacy, **full)
                    calls.add("weights", f"{label} {efficacy}", "skyWeights",
                              [samples, solid, model, sun.tolist(), dict(js_params(full), efficacy=efficacy)],
                              weights.ravel())
            if sun[2] > 0:  # the sun's light spread over the patches nearest it (zeros below the horizon)
                normal = sun_normal_irradiance(sun, 3.0, 172)
                calls.add("sun patches", f"{name} {sun_label}", "sunPatchWeights",
                          [directions, sun.tolist(), normal.tolist()],
                          sun_patch_weights(patches, sun, normal).ravel())
            weights = sky_weights(patches, "preetham", sun, turbidity=3.0, radiance=1.0).astype(np.float64)
            normal = sun_normal_irradiance(sun, 3.0, 172)
            for e_normal in (normal, None):
                calls.add("ground", f"{name} {sun_label} sun {e_normal is not None}", "groundRadiance",
                          [calls.table(f"{name}/cosines", cosines), weights.ravel().tolist(), sun.tolist(),
                           None if e_normal is None else e_normal.tolist(), 0.2],
                          ground_radiance(patches, weights, sun, e_normal, 0.2))

    for sun_label, sun in suns():
        for turbidity in (1.9, 3.0, 9.0):
            for day in (1, 172, 355):
                calls.add("sun normal", f"{sun_label} T {turbidity} day {day}", "sunNormalIrradiance",
                          [sun.tolist(), turbidity, day], sun_normal_irradiance(sun, turbidity, day))
        for dni, dhi, day in ((600.0, 150.0, 172), (0.0, 300.0, 15), (850.0, 60.0, 200), (40.0, 0.0, 90),
                              (0.0, 0.0, 1), (300.0, 400.0, 365)):
            for efficacy in ("perez", "179"):
                calls.add("visible", f"{sun_label} {dni} {dhi} {day} {efficacy}", "visibleFactors",
                          [efficacy, dni, dhi, sun.tolist(), day],
                          list(visible_factors(efficacy, dni, dhi, sun, day)))
        site = unit(sun)
        for sky in ("preetham", "perez", "overcast", "uniform"):
            for efficacy in ("perez", "179"):
                expected = sun_normal(sky, site, turbidity=4.0, direct_normal=700.0, day_of_year=80,
                                      diffuse_horizontal=110.0, efficacy=efficacy)
                calls.add("sun normal model", f"{sky} {efficacy} {sun_label}", "sunNormal",
                          [sky, site.tolist(), dict(turbidity=4.0, directNormal=700.0, dayOfYear=80,
                                                    diffuseHorizontal=110.0, efficacy=efficacy)],
                          None if expected is None else expected.tolist())
    return calls


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    calls = build()
    driver = tmp_path_factory.mktemp("sky_js") / "driver.js"
    driver.write_text(DRIVER)
    done = subprocess.run([NODE, str(driver), str(SKY_JS)], input=json.dumps({"tables": calls.tables,
                                                                              "skyTables": sky_model_tables(),
                                                                              "calls": calls.calls}),
                          capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stderr
    output = json.loads(done.stdout)
    return calls, output


def checks(run, group: str):
    calls, output = run
    assert calls.checks[group], group
    for label, index, expected in calls.checks[group]:
        yield label, output["results"][index], expected


def test_sky_js_is_a_plain_script_exporting_its_functions(run):
    _, output = run
    for name in ("sunPosition", "dayOfYear", "patchRadiance", "sunNormalIrradiance", "visibleFactors", "sunNormal",
                 "sunPatchWeights", "horizontalCosines", "groundRadiance", "skyWeights", "perezEfficacy"):
        assert name in output["exports"]
        assert name in output["globals"], f"{name} is not a global of the plain script"


def test_sun_position(run):
    for label, js, expected in checks(run, "sun"):
        for key in ("zenith", "declination", "equationOfTime"):
            assert_close(js[key], expected[key], f"{label} {key}")
        assert_angle_close(js["azimuth"], expected["azimuth"], 360.0, f"{label} azimuth")
        assert_angle_close(js["hourAngle"], expected["hourAngle"], 360.0, f"{label} hour angle")
        assert_close(js["enu"], expected["enu"], f"{label} enu")
    zeniths = [expected["zenith"] for _, _, expected in checks(run, "sun")]
    assert min(zeniths) < 30 and max(zeniths) > 120, "the cases span day and night"
    for label, js, expected in checks(run, "day"):
        assert js == expected, label
    for label, js, expected in checks(run, "refraction"):
        assert_close(js, expected, label)


def test_patch_radiance_and_sky_weights(run):
    for group in ("radiance", "weights"):
        for label, js, expected in checks(run, group):
            assert_close(js, expected, f"{group} {label}")
    lit = [label for label, _, expected in checks(run, "radiance") if "preetham" in label and np.max(expected) > 0]
    assert lit, "the preetham sky is lit for some suns"


def test_sun_irradiance_and_visible_factors(run):
    for group in ("sun normal", "visible"):
        for label, js, expected in checks(run, group):
            assert_close(js, expected, f"{group} {label}")
    for label, js, expected in checks(run, "sun normal model"):
        if expected is None:
            assert js is None, label
        else:
            assert_close(js, expected, label)


def test_interreflection_helpers(run):
    for group in ("cosines", "sun patches", "ground"):
        for label, js, expected in checks(run, group):
            assert_close(js, expected, f"{group} {label}")
    for label, js, expected in checks(run, "sun patches"):
        assert np.count_nonzero(np.asarray(js).reshape(-1, 3)[:, 0]) == 4, label


def test_sun_patch_ties_go_to_the_lower_index(tmp_path):
    """The sun at the zenith is equally near the six patches of Tregenza's top ring: the JS takes the lowest
    indices (numpy's default argsort leaves ties in any order); both spread the same irradiance."""
    patches = tregenza_patches()
    sun, normal = np.array([0.0, 0.0, 1.0]), np.array([500.0, 400.0, 300.0])
    script = tmp_path / "ties.js"
    script.write_text(f"const sky = require({json.dumps(str(SKY_JS))});\n"
                      f"const out = sky.sunPatchWeights(Float64Array.from({json.dumps(patches.patch_directions.ravel().tolist())}),"
                      f" {sun.tolist()}, {normal.tolist()});\nprocess.stdout.write(JSON.stringify(Array.from(out)));\n")
    done = subprocess.run([NODE, str(script)], capture_output=True, text=True, timeout=30)
    assert done.returncode == 0, done.stderr
    js = np.asarray(json.loads(done.stdout)).reshape(-1, 3)
    assert np.flatnonzero(js[:, 0]).tolist() == [138, 139, 140, 144]
    expected = sun_patch_weights(patches, sun, normal).astype(np.float64)
    assert_close(js.sum(axis=0), expected.sum(axis=0), "total")
    assert_close(np.sort(js[:, 0][js[:, 0] > 0]), np.sort(expected[:, 0][expected[:, 0] > 0]), "weights")


def test_perez_sky_state_and_coefficients_in_every_bin(tmp_path):
    """perezSkyState, perezCoefficients and perezEfficacy over the clearness bins (bin 1's own c and d too)."""
    cases = []
    for zenith in (0.1, 0.7, 1.2, 1.5):
        for dni, dhi in ((0.0, 250.0), (20.0, 240.0), (80.0, 200.0), (200.0, 180.0), (400.0, 150.0),
                         (600.0, 120.0), (800.0, 100.0), (900.0, 50.0)):
            cases.append((zenith, dni, dhi, 100))
    script = tmp_path / "perez.js"
    script.write_text(f"const sky = require({json.dumps(str(SKY_JS))});\nconst cases = {json.dumps(cases)};\n"
                      f"sky.setSkyTables({json.dumps(sky_model_tables())});\n"
                      "process.stdout.write(JSON.stringify(cases.map(([z, dni, dhi, day]) => {\n"
                      "  const state = sky.perezSkyState(z, dni, dhi, day);\n"
                      "  return [state, sky.perezCoefficients(z, state[0], state[1]),\n"
                      "          sky.perezEfficacy(dni, dhi, z * 180 / Math.PI, day)];\n"
                      "})));\n")
    done = subprocess.run([NODE, str(script)], capture_output=True, text=True, timeout=30)
    assert done.returncode == 0, done.stderr
    bins = set()
    for (zenith, dni, dhi, day), (state, coefficients, efficacy) in zip(cases, json.loads(done.stdout)):
        expected = perez_sky_state(zenith, dni, dhi, day)
        bins.add(int(np.searchsorted([1.065, 1.230, 1.500, 1.950, 2.800, 4.500, 6.200], expected[0], "right")))
        assert_close(state, expected, f"state {zenith} {dni} {dhi}")
        assert_close(coefficients, perez_coefficients(zenith, *expected), f"coefficients {zenith} {dni} {dhi}")
        beam, diffuse = perez_efficacy(dni, dhi, np.degrees(zenith), day)
        assert_close(efficacy, [beam, diffuse], f"efficacy {zenith} {dni} {dhi}")
    assert bins == set(range(8))
