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


def nearest_front_hit(points: np.ndarray, corners: np.ndarray, eye, direction) -> tuple[int, np.ndarray]:
    """(face, distances): a plainly written float64 ray cast over every face, fronts only (counter-clockwise
    seen from the eye, as the page draws them); distances inf where missed."""
    a, b, c = (points[corners[:, k]].astype(np.float64) for k in range(3))
    d, o = np.asarray(direction, np.float64), np.asarray(eye, np.float64)
    e1, e2 = b - a, c - a
    normal = np.cross(e1, e2)
    facing = normal @ d < 0
    t = ((a - o) * normal).sum(axis=1) / np.where(facing, normal @ d, -1.0)
    hit = o + t[:, None] * d
    inside = np.ones(len(a), bool)
    for p, q in ((a, b), (b, c), (c, a)):
        inside &= (np.cross(q - p, hit - p) * normal).sum(axis=1) >= 0
    distance = np.where(facing & inside & (t > 0), t, np.inf)
    return int(np.argmin(distance)) if np.isfinite(distance).any() else -1, distance


def test_a_click_reads_the_face_under_it(served):
    url, browser, lib, _ = served
    page = open_page(browser, url)
    set_controls(page, date="2026-12-21", hour=12.0, sky="preetham", sun=True, useWeather=False, overlay="light")
    page.evaluate("v => window.usdbake.setCamera(v)", {"yaw": -2.2, "pitch": 0.95, "distance": 7.5,
                                                      "target": [-1.2, -0.6, 0.8]})
    prefix = fetch_scene(url).daylight.prefix
    irradiance_now = np.asarray(page.evaluate("window.usdbake.irradiance()"), np.float64).reshape(-1, 3)
    width, height = page.evaluate("[document.getElementById('view').width, document.getElementById('view').height]")
    hits = 0
    for x, y in ((width // 2, height // 2), (width // 2 + 60, height // 2 + 40), (width // 2 - 80, height // 2 + 90),
                 (width // 2 + 150, height // 2 - 60), (5, 5)):
        probe = page.evaluate("([x, y]) => window.usdbake.probe(x, y)", [x, y])
        face, distance = nearest_front_hit(prefix.points, prefix.corners, probe["eye"], probe["direction"])
        if face < 0:
            assert probe["face"] == -1 and page.inner_text("#probe") == ""
            continue
        hits += 1
        assert probe["face"] == face or distance[probe["face"]] <= distance[face] * (1 + 1e-6), (x, y)  # an edge
        luma = np.array([0.2126, 0.7152, 0.0722])
        assert probe["lux"] == pytest.approx(179.0 * irradiance_now[probe["face"]] @ luma, rel=1e-6)
        assert probe["prim"] == lib.prims[int(prefix.face_id[probe["face"]])]
    assert hits >= 3
    page.mouse.click(width // 2, height // 2)  # as a person: the panel names the prim and the lux
    label = page.inner_text("#probe")
    assert "lux" in label and lib.prims[int(prefix.face_id[
        page.evaluate(f"window.usdbake.probe({width // 2}, {height // 2}).face")])] in label
    page.close()
