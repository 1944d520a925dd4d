"""The viewer's daylight in headless Chromium (Debian's chromium, driven by playwright; skipped where either is
missing): the window_room baked with daylight_stream and a TMY3 year, served by ``usdbake serve``. The page's
per-face irradiance, read back from its render target, against the library's relighter for 10 (date, hour,
sky) cases; the controls driven as a person would (a new hour, summer and winter noon, an overcast sky, a
weather-file hour); a stream cut part way still relit, as the Python client relights the same prefix."""

from __future__ import annotations

import shutil

import numpy as np
import pytest

from daylight_served import CASES, bake_daylight, library, tmy3
from served_stage import running
from tolerances import BROWSER_FLOAT32, INDIRECT_CODE_RELIGHT
from usdbake.preview.stream_client import fetch_scene, stream_scene
from usdbake.stages.serve import make_app

playwright = pytest.importorskip("playwright.sync_api")
pytest.importorskip("pvlib")
CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
pytestmark = pytest.mark.skipif(CHROMIUM is None, reason="no chromium on this machine (apt-get install chromium)")


@pytest.fixture(scope="module")
def served(tmp_path_factory):
    folder = tmp_path_factory.mktemp("daylight_viewer")
    baked = bake_daylight(folder, tmy3())
    lib = library(tmy3())
    with running(make_app(str(baked))) as url, playwright.sync_playwright() as p:
        browser = p.chromium.launch(executable_path=CHROMIUM, args=["--no-sandbox", "--enable-unsafe-swiftshader",
                                                                    "--use-angle=swiftshader"])
        yield url, browser, lib, baked
        browser.close()


def open_page(browser, url: str, query: str = ""):
    page = browser.new_page(viewport={"width": 900, "height": 600})
    errors = []
    page.on("pageerror", lambda error: errors.append(str(error)))
    page.goto(f"{url}/{query}")
    page.wait_for_function("document.body.dataset.ready", timeout=120_000)
    assert page.evaluate("document.body.dataset.ready") == "1", (page.inner_text("#status"), errors)
    return page


def irradiance(page) -> np.ndarray:
    """The page's per-face irradiance in the bake's face order."""
    values = np.asarray(page.evaluate("window.usdbake.irradiance()"), np.float64).reshape(-1, 3)
    out = np.empty_like(values)
    out[np.asarray(page.evaluate("window.usdbake.faceId()"), np.int64)] = values
    return out


def set_controls(page, **values) -> dict:
    return page.evaluate("values => window.usdbake.setControls(values)", values)


def test_the_served_stream_is_the_in_process_bake(served):
    url, _, lib, _ = served
    scene = fetch_scene(url)
    assert scene.daylight is not None and scene.daylight.prefix.received == len(lib.areas)
    sidecar = next(served[3].parent.glob("room_daylight_*.bin"))
    assert sidecar.read_bytes() == lib.stream


def test_the_browser_relights_as_the_library(served):
    url, browser, lib, _ = served
    page = open_page(browser, url)
    client = fetch_scene(url).daylight
    for date, hour, sky in CASES:
        frame = set_controls(page, date=date, hour=hour, sky=sky)
        assert frame["sky"]["model"] == sky
        got = irradiance(page)
        want = lib.at(date, hour, sky)
        streamed = client.in_bake_order(client.at(str(np.datetime64(date) + np.timedelta64(int(hour * 60), "m")),
                                                  sky=sky))
        np.testing.assert_allclose(got, streamed, rtol=BROWSER_FLOAT32, atol=BROWSER_FLOAT32 * want.max())
        lit = want > 0.01 * want.max()
        error = np.abs(got - want)[lit] / want[lit]
        assert error.max() <= INDIRECT_CODE_RELIGHT, (date, hour, sky, float(error.max()))
        print(date, hour, sky, f"largest error {100 * error.max():.2f}%")
    page.close()


def test_the_controls_change_the_light(served, tmp_path):
    url, browser, lib, _ = served
    page = open_page(browser, url)
    pictures = []
    for hour in (9.0, 15.0):  # a new hour changes the picture
        set_controls(page, date="2026-06-21", hour=hour, sky="preetham")
        path = tmp_path / f"hour_{hour}.png"
        page.locator("#view").screenshot(path=str(path))
        pictures.append(path.read_bytes())
    assert pictures[0] != pictures[1]
    outside = np.array([p.endswith("Ground") for p in lib.prims])
    floor = np.array([p.endswith("Floor") for p in lib.prims])
    noon = {}
    for date in ("2026-06-21", "2026-12-21"):
        set_controls(page, date=date, hour=12.0, sky="preetham", sun=True)
        noon[date] = irradiance(page)[:, 1]
    # Summer noon lights the ground outside more; through the south window the low winter sun reaches deeper
    summer, winter = (lib.areas[outside] @ noon[d][outside] for d in ("2026-06-21", "2026-12-21"))
    assert summer > 1.5 * winter
    reach = {d: lib.centroids[floor, 1][noon[d][floor] > 2 * np.median(noon[d][floor])].max() for d in noon}
    assert reach["2026-12-21"] > reach["2026-06-21"] + 0.5  # metres further from the window (y = -2.5)
    # A clear sky casts a sun patch on the floor, an overcast sky none: its sun switch changes nothing
    set_controls(page, date="2026-12-21", hour=12.0, sky="preetham", sun=False)
    assert (noon["2026-12-21"][floor] > irradiance(page)[floor, 1] * 1.5).any()
    set_controls(page, sky="overcast", sun=True)
    with_sun = irradiance(page)
    set_controls(page, sun=False)
    np.testing.assert_array_equal(with_sun, irradiance(page))
    page.close()


def test_the_weather_hour_names_its_row(served):
    from usdbake.formats.weather import read_weather

    url, browser, _, _ = served
    weather = read_weather(tmy3())
    page = open_page(browser, url)
    assert page.is_visible("#weatherControls")
    row = int(np.argmax(weather.direct_normal))  # the clearest hour of the year
    frame = set_controls(page, useWeather=True, weatherHour=row)
    label = page.inner_text("#weatherLabel")
    when = str(weather.times[row].astype("datetime64[m]")).replace("T", " ")
    assert f"row {row + 1} of {len(weather.times)}" in label and when in label, label
    assert f"DNI {weather.direct_normal[row]:.0f}" in label and f"DHI {weather.diffuse_horizontal[row]:.0f}" in label
    assert frame["sky"]["model"] == "perez" and frame["row"] == row
    assert frame["sky"]["directNormal"] == pytest.approx(weather.direct_normal[row], rel=1e-6)
    page.close()


@pytest.mark.parametrize("share", [0.35, 0.7])
def test_a_cut_stream_is_relit_from_what_arrived(served, share):
    url, browser, _, _ = served
    page = open_page(browser, url, f"?limit={share}&chunk=4096")
    received = page.evaluate("window.usdbake.received()")
    faces = len(page.evaluate("window.usdbake.faceId()"))
    client = next(scene for got, scene in stream_scene(url, fractions=[share], chunk=4096)).daylight
    assert 0 < received < faces and received == client.prefix.received
    frame = set_controls(page, date="2026-03-20", hour=11.0, sky="preetham")
    assert frame["sunZenith"] < 90
    got = np.asarray(page.evaluate("window.usdbake.irradiance()"), np.float64).reshape(-1, 3)
    want = client.at("2026-03-20T11:00", sky="preetham")
    assert (want[:, 1] > 0).sum() > received  # the faces not received show their ancestors' light
    np.testing.assert_allclose(got, want, rtol=BROWSER_FLOAT32, atol=BROWSER_FLOAT32 * want.max())
    page.close()


def test_the_annual_overlays_are_the_bakes_metrics(served, tmp_path):
    from pxr import Usd

    url, browser, lib, baked = served
    stage = Usd.Stage.Open(str(baked))
    overlay = fetch_scene(url).overlay
    page = open_page(browser, url)
    assert page.is_visible("#overlayControls")
    report = stage.GetPrimAtPath("/usdbake/AnnualDaylight")
    assert page.inner_text("#annual") == (f"sDA {100 * report.GetAttribute('bake:annual:sDA').Get():.1f} %, "
                                          f"ASE {100 * report.GetAttribute('bake:annual:ASE').Get():.1f} %")
    # each face's DA, as the page holds it in stream order, is the primvar annual_daylight wrote on its prim
    order = np.asarray(page.evaluate("window.usdbake.faceId()"), np.int64)
    page_da = np.asarray(page.evaluate("window.usdbake.overlay('daylightAutonomy')"), np.float64)
    np.testing.assert_array_equal(page_da, overlay["daylightAutonomy"])
    by_face = np.empty_like(page_da)
    by_face[order] = page_da
    for path in sorted(set(lib.prims)):
        faces = np.flatnonzero(np.array(lib.prims) == path)
        written = stage.GetPrimAtPath(path).GetAttribute("primvars:bake:daylightAutonomy").Get()
        np.testing.assert_allclose(by_face[faces], np.asarray(written), rtol=0, atol=0)
    assert 0 < by_face.max() <= 1 and by_face.min() >= 0
    pictures = []
    for choice in ("light", "daylightAutonomy", "usefulDaylightWithin"):
        set_controls(page, overlay=choice)
        path = tmp_path / f"overlay_{choice}.png"
        page.locator("#view").screenshot(path=str(path))
        pictures.append(path.read_bytes())
    assert len(set(pictures)) == 3
    page.close()
