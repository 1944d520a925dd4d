"""The browser viewer in headless Chromium (Debian's chromium, driven by playwright; skipped where either is
missing): after 10 %, 50 % and 100 % of /stream it holds the same levels of detail as the Python client, its
picture fills in, and with the whole stream its per-vertex irradiance is the grid reconstruction's."""

from __future__ import annotations

import shutil

import numpy as np
import pytest
from pxr import Usd

from served_stage import bake_streams, running
from usdbake.formats.streaming import decode_stream
from usdbake.kernels.direction24 import dequantize_vectors
from usdbake.preview.stream_client import stream_scene
from usdbake.processors.irradiance_grid.vector_grid import GridLayout, reconstruct_irradiance, trilinear
from usdbake.stages.serve import make_app

playwright = pytest.importorskip("playwright.sync_api")
CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
pytestmark = pytest.mark.skipif(CHROMIUM is None, reason="no chromium on this machine (apt-get install chromium)")
SHARES = (0.1, 0.5, 1.0)


@pytest.fixture(scope="module")
def baked(tmp_path_factory):
    return bake_streams(tmp_path_factory.mktemp("viewed"))
IRRADIANCE_FLOAT32 = 1e-4
"""Relative difference of the page's float32 reconstruction from numpy's float64 (same received vectors)."""


def area_normals(positions: np.ndarray, faces: np.ndarray) -> np.ndarray:
    normals = np.zeros_like(positions, np.float64)
    corners = positions[faces].astype(np.float64)
    cross = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    for k in range(3):
        np.add.at(normals, faces[:, k], cross)
    length = np.linalg.norm(normals, axis=1, keepdims=True)
    return np.where(length > 0, normals / np.where(length > 0, length, 1), 0)


def test_the_viewer_sharpens_into_the_bake(baked, tmp_path):
    with running(make_app(str(baked))) as url, playwright.sync_playwright() as p:
        browser = p.chromium.launch(executable_path=CHROMIUM, args=["--no-sandbox", "--enable-unsafe-swiftshader",
                                                                    "--use-angle=swiftshader"])
        states, pictures = [], []
        for share in SHARES:
            page = browser.new_page(viewport={"width": 800, "height": 600})
            page.goto(f"{url}/?limit={share}&chunk=1024")
            page.wait_for_function("document.body.dataset.ready", timeout=60_000)
            assert page.evaluate("document.body.dataset.ready") == "1", page.inner_text("#status")
            states.append(page.evaluate("window.usdbakeState"))
            path = tmp_path / f"viewer_{int(100 * share)}.png"
            page.locator("#view").screenshot(path=str(path))
            pictures.append(np.frombuffer(path.read_bytes(), np.uint8))
            page.close()
        browser.close()
        client = {round(share, 2): scene for share, scene in stream_scene(url, fractions=SHARES)}
    assert all(state["drawn"] for state in states), "WebGL2 unavailable in headless chromium"
    for state, share in zip(states, SHARES):  # each page stopped at its share, within a 1 KiB frame
        assert share <= state["share"] <= share + 1024 / 20_000 + 1e-9
    full = states[-1]
    reference = client[1.0]
    for mesh in full["meshes"]:
        expected = reference.meshes[mesh["prim"]]
        assert mesh["level"] == len(expected.positions)
        np.testing.assert_array_equal(np.asarray(mesh["faces"]).reshape(-1, 3), expected.faces)
    # Levels of detail grow with the share, and the 10 % page holds fewer faces than the whole.
    faces = [sum(len(m["faces"]) for m in state["meshes"]) for state in states]
    assert faces[0] < faces[-1] and faces == sorted(faces)
    assert len({bytes(p) for p in pictures}) == len(pictures), "the picture did not change as data arrived"
    # Irradiance at the whole stream: the page's reconstruction is the grid's (all vertices received).
    stage = Usd.Stage.Open(str(baked))
    grid_file = stage.GetPrimAtPath("/usdbake/IrradianceGrid").GetAttribute("streamFile").Get()
    stream = decode_stream(open(grid_file.resolvedPath, "rb").read())
    count = int(np.prod(stream.resolution))
    vectors = np.zeros((count, 6, 3, 3), np.float32)
    vectors[stream.vertex_index] = dequantize_vectors(stream.directions, stream.colors)
    layout = GridLayout(stream.grid_origin.astype(np.float64), stream.cell_size.astype(np.float64),
                        tuple(stream.resolution))
    received = np.zeros(count, bool)
    received[stream.vertex_index] = True
    compared = 0
    for mesh in full["meshes"]:
        expected = reference.meshes[mesh["prim"]]
        if not len(expected.faces) or len(expected.faces) != expected.total_faces:
            continue
        normals = area_normals(expected.positions, expected.faces)
        want = reconstruct_irradiance(layout, vectors, expected.positions, normals)
        got = np.asarray(mesh["irradiance"], np.float64).reshape(-1, 3)
        # Grid vertices inside geometry are never streamed: the page leaves them out of the weights, the
        # Python client fills them by push-pull. Where all eight corners arrived, the two must agree.
        index, weight = trilinear(layout, expected.positions + normals * 0.5 * float(layout.cell_size.min()))
        whole = ((weight == 0) | received[index]).all(axis=1)
        compared += int(whole.sum())
        np.testing.assert_allclose(got[whole], want[whole], rtol=IRRADIANCE_FLOAT32,
                                   atol=IRRADIANCE_FLOAT32 * float(want.max()))
    assert compared >= 20
