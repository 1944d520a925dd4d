"""usdbake serve on loopback: the manifest lists a baked stage's streams, range requests and ETags work,
the client rebuilds exactly the baked meshes and grid from the whole streams and valid levels of detail
from prefixes (push-pull never touches a received grid vertex), and no request reaches a file the bake
did not name."""

from __future__ import annotations

import json
import signal
import socket
import subprocess
import sys
import time
import urllib.error
import urllib.request
from contextlib import ExitStack

import numpy as np
import pytest
from aiohttp import web
from hypothesis import given, settings
from hypothesis import strategies as st
from pxr import Usd

from repo_paths import SAMPLES
from served_stage import bake_streams, get, running
from usdbake.formats.mesh_stream import decode_mesh_stream
from usdbake.kernels.direction24 import dequantize_vectors
from usdbake.preview.stream_client import fetch_scene, stream_scene
from usdbake.stages.serve import interleave, make_app


@pytest.fixture(scope="module")
def baked(tmp_path_factory):
    return bake_streams(tmp_path_factory.mktemp("served"))


def test_whole_streams_rebuild_the_bake(baked):
    stage = Usd.Stage.Open(str(baked))
    with running(make_app(str(baked))) as url:
        scene = fetch_scene(url)
        status, _, page = get(url + "/")
    assert status == 200 and b"/viewer.js" in page
    meshes = [p for p in stage.Traverse() if p.GetAttribute("bake:pmStreamFile").HasAuthoredValue()]
    assert set(scene.meshes) == {str(p.GetPath()) for p in meshes} and len(meshes) >= 5
    for prim in meshes:
        file = baked.parent / prim.GetAttribute("bake:pmStreamFile").Get().path
        expected = decode_mesh_stream(file.read_bytes())
        got = scene.meshes[str(prim.GetPath())]
        np.testing.assert_array_equal(got.positions, expected.positions)
        np.testing.assert_array_equal(got.faces, expected.faces)
        assert len(got.faces) == got.total_faces
    grid = stage.GetPrimAtPath("/usdbake/IrradianceGrid")
    valid = np.asarray(grid.GetAttribute("bake:vertexValid").Get(), bool)
    directions = np.asarray(grid.GetAttribute("directions").Get(), np.uint8)
    colors = np.asarray(grid.GetAttribute("colorsRGB9E5").Get(), np.uint32)
    np.testing.assert_array_equal(scene.grid.received, valid)
    np.testing.assert_array_equal(scene.grid.vectors[valid], dequantize_vectors(directions, colors)[valid])


def test_prefixes_are_valid_and_push_pull_keeps_received_vertices(baked):
    with running(make_app(str(baked))) as url:
        full = fetch_scene(url)
        for fraction in (0.0, 0.1, 0.5):
            part = fetch_scene(url, fraction=fraction)
            assert part.bytes_read < full.bytes_read
            for prim, mesh in part.meshes.items():
                k = len(mesh.positions)
                np.testing.assert_array_equal(mesh.positions, full.meshes[prim].positions[:k])
                assert len(mesh.faces) == 0 or (mesh.faces.min() >= 0 and mesh.faces.max() < k)
                assert (mesh.faces[:, 0] != mesh.faces[:, 1]).all() and (mesh.faces[:, 1] != mesh.faces[:, 2]).all()
            got = part.grid
            np.testing.assert_array_equal(got.vectors[got.received], full.grid.vectors[got.received])
            if got.received.any():
                assert np.isfinite(got.vectors).all()


def test_range_requests_etags_and_only_the_bake_files(baked, tmp_path):
    (baked.parent / "secret.txt").write_text("SECRET-CONTENT")
    (baked.parent / "link.bin").symlink_to(baked.parent / "secret.txt")
    with running(make_app(str(baked))) as url:
        _, _, manifest = get(url + "/manifest")
        first = json.loads(manifest)["meshes"][0]
        status, headers, whole = get(url + first["url"])
        assert status == 200 and len(whole) == first["bytes"] and headers["ETag"]
        status, _, part = get(url + first["url"], {"Range": "bytes=10-29"})
        assert status == 206 and part == whole[10:30]
        status, _, _ = get(url + first["url"], {"If-None-Match": headers["ETag"]})
        assert status == 304
        for attack in ("/files/secret.txt", "/files/link.bin", "/files/..%2Fsecret.txt", "/files/%2Fetc%2Fpasswd",
                       "/files/../secret.txt", "/" + str(baked.parent / "secret.txt").lstrip("/")):
            status, _, body = get(url + attack)
            assert status == 404 and b"SECRET-CONTENT" not in body, attack


def test_a_stage_without_streams_is_refused(tmp_path):
    from usdbake.core.errors import UsageError

    with pytest.raises(UsageError, match="no streams to serve"):
        make_app(str(SAMPLES / "cornell_box.usda"))


@settings(max_examples=40, deadline=None)
@given(st.lists(st.integers(0, 5000), min_size=1, max_size=8), st.integers(1, 700))
def test_interleaving_keeps_every_stream_at_the_same_share(sizes, chunk):
    frames = interleave(sizes, chunk)
    sent = [0] * len(sizes)
    for index, offset, length in frames:
        assert offset == sent[index] and 0 < length <= chunk  # each stream in order, no gaps
        sent[index] += length
        shares = [sent[i] / size for i, size in enumerate(sizes) if size]
        # The stream just served was the least far along: nothing is more than a chunk ahead of another.
        assert max(shares) - min(shares) <= max(chunk / size for size in sizes if size) + 1e-12
    assert sent == sizes


def test_the_interleaved_stream_sharpens_into_the_bake(baked):
    with running(make_app(str(baked))) as url:
        full = fetch_scene(url)
        seen = list(stream_scene(url, fractions=(0.25, 0.6, 1.0), chunk=1024))
    assert [round(share, 2) >= mark for (share, _), mark in zip(seen, (0.25, 0.6, 1.0))] == [True] * 3
    last = seen[-1][1]
    assert set(last.meshes) == set(full.meshes)
    for prim, mesh in last.meshes.items():
        np.testing.assert_array_equal(mesh.positions, full.meshes[prim].positions)
        np.testing.assert_array_equal(mesh.faces, full.meshes[prim].faces)
    np.testing.assert_array_equal(last.grid.vectors, full.grid.vectors)
    middle = seen[1][1]
    assert 0 < middle.grid.received.sum() < full.grid.received.sum()
    for prim, mesh in middle.meshes.items():
        assert len(mesh.positions) <= len(full.meshes[prim].positions)
        assert len(mesh.faces) == 0 or mesh.faces.max() < len(mesh.positions)


def test_stream_slots_bound_all_clients_and_one_address():
    """Any free slot while at least half are free; past that, at most max_per_peer for one address."""
    from usdbake.stages.serve import Limits, Slots

    slots = Slots(Limits(max_clients=8, max_per_peer=2))
    with ExitStack() as held:
        for _ in range(4):
            held.enter_context(slots.hold("a"))  # a alone may take half of the slots
        with pytest.raises(web.HTTPServiceUnavailable) as refused:
            held.enter_context(slots.hold("a"))
        assert refused.value.headers["Retry-After"] == "1"
        for peer in ("b", "b", "c", "d"):
            held.enter_context(slots.hold(peer))
        assert slots.taken == {"a": 4, "b": 2, "c": 1, "d": 1}
        for peer in ("b", "e"):  # b is at its share; nobody gets a ninth slot
            with pytest.raises(web.HTTPServiceUnavailable):
                held.enter_context(slots.hold(peer))
    assert not slots.taken  # every slot came back
    with slots.hold("a"):
        assert slots.taken == {"a": 1}


def test_range_forms_head_and_conditional_requests(baked):
    with running(make_app(str(baked))) as url:
        _, _, manifest = get(url + "/manifest")
        grid = json.loads(manifest)["grid"]
        status, headers, whole = get(url + grid["url"])
        size, etag = len(whole), headers["ETag"]
        assert status == 200 and size == grid["bytes"] and headers["Accept-Ranges"] == "bytes"
        for asked, part, content_range in (("bytes=-5", whole[-5:], f"bytes {size - 5}-{size - 1}/{size}"),
                                           ("bytes=7-", whole[7:], f"bytes 7-{size - 1}/{size}"),
                                           (f"bytes=3-{size + 50}", whole[3:], f"bytes 3-{size - 1}/{size}")):
            status, headers, body = get(url + grid["url"], {"Range": asked})
            assert (status, body, headers["Content-Range"]) == (206, part, content_range), asked
        for asked in (f"bytes={size}-", "bytes=9-3", "bytes=0-1,4-5", "pages=1-2"):
            status, headers, _ = get(url + grid["url"], {"Range": asked})
            assert (status, headers["Content-Range"]) == (416, f"bytes */{size}"), asked
        for condition in (etag, "W/" + etag, "*", f'"other", {etag}'):
            assert get(url + grid["url"], {"If-None-Match": condition})[0] == 304, condition
        assert get(url + grid["url"], {"If-None-Match": '"other"'})[0] == 200
        request = urllib.request.Request(url + grid["url"], method="HEAD")
        with urllib.request.urlopen(request, timeout=10) as response:
            assert response.status == 200 and response.headers["Content-Length"] == str(size)
            assert response.read() == b""


@pytest.mark.parametrize("stop", [signal.SIGINT, signal.SIGTERM])
def test_the_command_serves_until_stopped_then_exits_cleanly(baked, stop):
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    process = subprocess.Popen(
        [sys.executable, "-c", "import sys; from usdbake.cli.main import main; sys.exit(main(sys.argv[1:]))",
         "serve", str(baked), "--port", str(port)], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 60
        while True:
            try:
                status, _, body = get(f"http://127.0.0.1:{port}/manifest")
                break
            except urllib.error.URLError:
                assert process.poll() is None and time.monotonic() < deadline, process.stderr.read()
                time.sleep(0.2)
        assert status == 200 and json.loads(body)["meshes"]
        process.send_signal(stop)
        out, err = process.communicate(timeout=30)
    finally:
        process.kill()
    assert process.returncode == 0 and "Traceback" not in err, err
    assert f"127.0.0.1:{port}" in out + err  # the address it listens on, on the console
