"""preview/stream_client.py against a small HTTP server of the test's own that serves hand-built streams (a
4-vertex progressive mesh, a 2 x 2 x 2 irradiance grid whose vectors are exact in RGB9E5 and 8:8:8) by the
``usdbake serve`` protocol: the range each prefix asks for, the levels of detail and grid vertices a prefix
holds (worked out from the stream layout by hand), push-pull filling within the received values, the
interleaved ``/stream`` read to the same scene, and the errors for bad fractions and broken frame streams.
The real server is exercised in tests/stages/test_serve.py."""

from __future__ import annotations

import json
import math
import threading
from contextlib import contextmanager
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer

import numpy as np
import pytest
from tolerances import FLOAT32_STORAGE

from usdbake.formats.mesh_stream import encode_mesh_stream
from usdbake.formats.streaming import encode_stream
from usdbake.kernels.direction24 import AXES
from usdbake.kernels.rgb9e5 import encode_rgb9e5
from usdbake.preview.stream_client import STREAM_FRAME, fetch_scene, stream_scene

# A unit square fanned into (0, 1, 2) and (0, 2, 3); vertex r collapses onto r - 1. One vertex per packet:
# header 24 bytes, the collapse table 4 one-byte varints, then packets of 12 + 12 bytes (+ 12 per face
# completed: face (0, 1, 2) by vertex 2, face (0, 2, 3) by vertex 3).
SQUARE = np.array([(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0)], np.float32)
SQUARE_FACES = np.array([[0, 1, 2], [0, 2, 3]])
SQUARE_TABLE_END = 24 + 4
SQUARE_PACKETS = [24, 24, 36, 36]
# A triangle: vertex 2 collapses onto 0, 1 onto 0.
TRIANGLE = np.array([(0, 0, 2), (1, 0, 2), (0, 1, 2)], np.float32)
TRIANGLE_TABLE_END = 24 + 3
TRIANGLE_PACKETS = [24, 24, 36]

GRID_RESOLUTION = (2, 2, 2)
GRID_ORDER = np.array([5, 0, 3, 6, 1, 7, 2, 4])
"""The order the server sends the 8 vertices in."""
GRID_HEADER = 52
GRID_RECORD = 4 + 6 * 3 + 6 * 4  # index, six 8:8:8 directions, six RGB9E5 colours


def grid_colours(constant=False):
    """(8, 3) colour of each vertex, multiples of 1/4 up to 8: exact in RGB9E5."""
    v = np.arange(8)[:, None] + 1.0
    return np.full((8, 3), 0.75) if constant else v * np.array([0.25, 0.5, 1.0])


def grid_bytes(colours):
    """Every vertex with six vectors, vector h = colour along axis h (exact in 8:8:8)."""
    directions = np.tile((np.rint(AXES * 127) + 128).astype(np.uint8), (8, 1, 1))
    packed = encode_rgb9e5(np.repeat(colours[:, None, :], 6, axis=1))
    return encode_stream(GRID_RESOLUTION, (1.0, 2.0, 3.0), (0.5, 0.5, 0.5), GRID_ORDER, directions, packed)


def grid_vectors(colours):
    """(8, 6, 3, 3) the vectors as the client holds them: rows RGB, columns the direction."""
    return colours[:, None, :, None] * AXES[None, :, None, :].astype(np.float64)


STREAMS = {
    "square.pm": encode_mesh_stream(SQUARE, SQUARE_FACES, np.arange(4), np.array([-1, 0, 1, 2]), packet_vertices=1),
    "triangle.pm": encode_mesh_stream(TRIANGLE, np.array([[0, 1, 2]]), np.arange(3), np.array([-1, 0, 0]),
                                      packet_vertices=1),
    "grid.ivg": grid_bytes(grid_colours()),
}


def test_the_hand_worked_layout_matches_the_encoders():
    assert len(STREAMS["square.pm"]) == SQUARE_TABLE_END + sum(SQUARE_PACKETS)
    assert len(STREAMS["triangle.pm"]) == TRIANGLE_TABLE_END + sum(TRIANGLE_PACKETS)
    assert len(STREAMS["grid.ivg"]) == GRID_HEADER + 8 * GRID_RECORD


class Server:
    """The usdbake serve protocol over http.server: /manifest, /files/NAME (one range), /stream."""

    def __init__(self, streams, *, grid="grid.ivg", meshes=("square.pm", "triangle.pm"), frames=None, chunk=16):
        self.streams, self.requests = streams, []
        self.manifest = {"stage": "test.usdc",
                         "meshes": [{"prim": f"/World/{name.split('.')[0].title()}", "url": f"/files/{name}",
                                     "bytes": len(streams[name])} for name in meshes],
                         "grid": {"url": f"/files/{grid}", "bytes": len(streams[grid])} if grid else None}
        self.order = list(meshes) + ([grid] if grid else [])
        self.frames = frames if frames is not None else round_robin([len(streams[n]) for n in self.order], chunk)

    def body(self, path, range_header):
        self.requests.append((path, range_header))
        if path == "/manifest":
            return 200, json.dumps(self.manifest).encode()
        if path.startswith("/files/"):
            data = self.streams[path[len("/files/"):]]
            if range_header:
                first, last = (int(x) for x in range_header.removeprefix("bytes=").split("-"))
                return 206, data[first:last + 1]
            return 200, data
        if path.startswith("/stream"):
            header = json.dumps(self.manifest).encode()
            out = [STREAM_FRAME.pack(0, len(header), 0), header]
            for index, offset, length in self.frames:
                known = 1 <= index <= len(self.order)
                payload = self.streams[self.order[index - 1]][offset:offset + length] if known else b"x" * length
                out += [STREAM_FRAME.pack(index, length, offset), payload]
            return 200, b"".join(out)
        return 404, b""


def round_robin(sizes, chunk):
    """(stream index from 1, offset, length) frames taking a chunk of each stream in turn."""
    frames, sent = [], [0] * len(sizes)
    while any(s < n for s, n in zip(sent, sizes)):
        for i, n in enumerate(sizes):
            if sent[i] < n:
                length = min(chunk, n - sent[i])
                frames.append((i + 1, sent[i], length))
                sent[i] += length
    return frames


@contextmanager
def serving(server: Server):
    class Handler(BaseHTTPRequestHandler):
        def do_GET(self):
            status, body = server.body(self.path, self.headers.get("Range"))
            self.send_response(status)
            self.send_header("Content-Length", str(len(body)))
            self.end_headers()
            self.wfile.write(body)

        def log_message(self, *args):
            pass

    httpd = ThreadingHTTPServer(("127.0.0.1", 0), Handler)
    thread = threading.Thread(target=httpd.serve_forever, kwargs={"poll_interval": 0.01}, daemon=True)
    thread.start()
    try:
        yield f"http://127.0.0.1:{httpd.server_address[1]}/"
    finally:
        httpd.shutdown()
        httpd.server_close()
        thread.join(5)


def whole_packets(received, table_end, packets):
    """Vertices a client holds after ``received`` bytes of a one-vertex-per-packet stream."""
    offset, count = table_end, 0
    for size in packets:
        if offset + size > received:
            break
        offset, count = offset + size, count + 1
    return count


def square_faces_at(level):
    return SQUARE_FACES[:max(0, level - 2)]  # face k is whole once vertex k + 2 arrived


def check_grid(grid, received_vertices, colours):
    expected = grid_vectors(colours)
    assert grid.resolution == GRID_RESOLUTION and grid.vectors.dtype == np.float32
    np.testing.assert_array_equal(grid.grid_origin, [1.0, 2.0, 3.0])
    np.testing.assert_array_equal(grid.cell_size, [0.5, 0.5, 0.5])
    np.testing.assert_array_equal(np.flatnonzero(grid.received), np.sort(received_vertices))
    np.testing.assert_array_equal(grid.vectors[grid.received], expected[grid.received])  # bit-exact
    if 0 < len(received_vertices) < 8:  # filled vertices: convex combinations of the received ones
        lo, hi = expected[grid.received].min(axis=0), expected[grid.received].max(axis=0)
        filled = grid.vectors[~grid.received]
        assert (filled >= lo - FLOAT32_STORAGE).all() and (filled <= hi + FLOAT32_STORAGE).all()
    if len(received_vertices) == 0:
        assert not grid.vectors.any()


@pytest.mark.parametrize("fraction", [0.0, 0.2, 0.5, 0.8, 0.99, 1.0])
def test_a_prefix_holds_the_levels_of_detail_and_vertices_its_bytes_cover(fraction):
    server = Server(STREAMS)
    with serving(server) as url:
        scene = fetch_scene(url, fraction=fraction)
    expected_bytes = 0
    for prim, name, points, table_end, packets in (
            ("/World/Square", "square.pm", SQUARE, SQUARE_TABLE_END, SQUARE_PACKETS),
            ("/World/Triangle", "triangle.pm", TRIANGLE, TRIANGLE_TABLE_END, TRIANGLE_PACKETS)):
        total = len(STREAMS[name])
        end = min(total, max(table_end, math.ceil(fraction * total)))  # at least the collapse table
        expected_bytes += end
        assert (f"/files/{name}", f"bytes=0-{end - 1}") in server.requests
        assert (f"/files/{name}", "bytes=0-23") in server.requests  # the header first, for the table's size
        mesh = scene.meshes[prim]
        k = whole_packets(end, table_end, packets)
        np.testing.assert_array_equal(mesh.positions, points[:k])
        assert mesh.total_vertices == len(points) and mesh.packets == k
        if name == "square.pm":
            np.testing.assert_array_equal(mesh.faces, square_faces_at(k))
        else:
            np.testing.assert_array_equal(mesh.faces, [[0, 1, 2]] if k == 3 else np.zeros((0, 3)))
    total = len(STREAMS["grid.ivg"])
    end = min(total, max(GRID_HEADER, math.ceil(fraction * total)))
    expected_bytes += end
    records = (end - GRID_HEADER) // GRID_RECORD
    check_grid(scene.grid, GRID_ORDER[:records], grid_colours())
    assert scene.bytes_read == expected_bytes
    assert server.requests[0] == ("/manifest", None)


def test_push_pull_fills_a_constant_grid_with_the_constant():
    streams = dict(STREAMS, **{"flat.ivg": grid_bytes(grid_colours(constant=True))})
    with serving(Server(streams, grid="flat.ivg", meshes=())) as url:
        scene = fetch_scene(url, fraction=(GRID_HEADER + 2 * GRID_RECORD) / len(streams["flat.ivg"]))
    assert scene.meshes == {} and scene.grid.received.sum() == 2
    np.testing.assert_allclose(scene.grid.vectors, grid_vectors(grid_colours(constant=True)), atol=FLOAT32_STORAGE)


def linear_grid_stream():
    """A 3 x 3 x 3 grid, colour (1 + i + 2 j + 4 k) x (1, 0.5, 0.25) at vertex (i, j, k) (exact in RGB9E5),
    its 8 corners sent first; and the (27, 6, 3, 3) vectors of the whole field."""
    ijk = np.array([(i, j, k) for k in range(3) for j in range(3) for i in range(3)])  # x fastest
    colours = (1.0 + ijk @ [1.0, 2.0, 4.0])[:, None] * np.array([1.0, 0.5, 0.25])
    corners = np.flatnonzero((ijk != 1).all(axis=1))
    order = np.r_[corners, np.setdiff1d(np.arange(27), corners)]
    directions = np.tile((np.rint(AXES * 127) + 128).astype(np.uint8), (27, 1, 1))
    packed = encode_rgb9e5(np.repeat(colours[:, None, :], 6, axis=1))
    data = encode_stream((3, 3, 3), (0, 0, 0), (1, 1, 1), order, directions, packed)
    return data, colours[:, None, :, None] * AXES[None, :, None, :].astype(np.float64)


def test_without_smoothing_the_corners_fill_a_linear_field_exactly():
    """Push-pull without the filter interpolates the received corners linearly, which reproduces a linear
    field; the [1, 2, 1] filter, truncated at the grid's faces, does not. Received vertices never change."""
    data, vectors = linear_grid_stream()
    fraction = (GRID_HEADER + 8 * GRID_RECORD) / len(data)
    with serving(Server({"line.ivg": data}, grid="line.ivg", meshes=())) as url:
        sharp = fetch_scene(url, fraction=fraction, smooth=False).grid
        smooth = fetch_scene(url, fraction=fraction).grid
    assert sharp.received.sum() == 8
    np.testing.assert_allclose(sharp.vectors, vectors, rtol=FLOAT32_STORAGE, atol=FLOAT32_STORAGE)
    np.testing.assert_array_equal(smooth.vectors[smooth.received], vectors[smooth.received])
    assert np.abs(smooth.vectors - vectors).max() > 0.1  # the filter is applied when asked for


@pytest.mark.parametrize("fraction", [-0.1, 1.5, float("nan")])
def test_a_fraction_outside_0_1_is_refused_before_any_request(fraction):
    server = Server(STREAMS)
    with serving(server) as url:
        with pytest.raises(ValueError, match="between 0 and 1"):
            fetch_scene(url, fraction=fraction)
    assert server.requests == []


def test_a_manifest_without_grid_or_meshes():
    with serving(Server(STREAMS, grid=None, meshes=("triangle.pm",))) as url:
        scene = fetch_scene(url)
        last = list(stream_scene(url, fractions=(1.0,)))[-1][1]
    assert scene.grid is None and set(scene.meshes) == {"/World/Triangle"}
    assert last.grid is None and len(last.meshes["/World/Triangle"].positions) == 3


def test_the_interleaved_stream_sharpens_into_the_whole_scene():
    server = Server(STREAMS, chunk=16)
    sizes = [len(STREAMS[n]) for n in server.order]
    total = sum(sizes)
    with serving(server) as url:
        whole = fetch_scene(url)
        seen = list(stream_scene(url, fractions=(0.6, 0.25, 1.0, 0.25), chunk=2048))
    assert server.requests[-1] == ("/stream?chunk=2048", None)
    assert [round(share, 6) >= mark for (share, _), mark in zip(seen, (0.25, 0.6, 1.0))] == [True] * 3
    assert len(seen) == 3 and seen[-1][0] == 1.0
    # Replay the frames: each yield comes with the first frame that reaches its mark.
    received, got, marks = [0] * len(sizes), [], [0.25, 0.6, 1.0]
    for index, _, length in server.frames:
        received[index - 1] += length
        while marks and sum(received) / total >= marks[0]:
            marks.pop(0)
            got.append((sum(received) / total, list(received)))
    assert [share for share, _ in seen] == [share for share, _ in got]
    for (_, scene), (_, counts) in zip(seen, got):
        assert scene.bytes_read == sum(counts)
        square, triangle, grid = counts
        if square >= SQUARE_TABLE_END:
            k = whole_packets(square, SQUARE_TABLE_END, SQUARE_PACKETS)
            np.testing.assert_array_equal(scene.meshes["/World/Square"].positions, SQUARE[:k])
            np.testing.assert_array_equal(scene.meshes["/World/Square"].faces, square_faces_at(k))
        else:
            assert "/World/Square" not in scene.meshes  # the collapse table has not arrived
        if triangle >= TRIANGLE_TABLE_END:
            k = whole_packets(triangle, TRIANGLE_TABLE_END, TRIANGLE_PACKETS)
            np.testing.assert_array_equal(scene.meshes["/World/Triangle"].positions, TRIANGLE[:k])
        else:
            assert "/World/Triangle" not in scene.meshes
        if grid >= GRID_HEADER:
            check_grid(scene.grid, GRID_ORDER[:(grid - GRID_HEADER) // GRID_RECORD], grid_colours())
        else:
            assert scene.grid is None
    last = seen[-1][1]
    for prim, mesh in whole.meshes.items():
        np.testing.assert_array_equal(last.meshes[prim].positions, mesh.positions)
        np.testing.assert_array_equal(last.meshes[prim].faces, mesh.faces)
    np.testing.assert_array_equal(last.grid.vectors, whole.grid.vectors)
    np.testing.assert_array_equal(whole.grid.vectors, grid_vectors(grid_colours()))


def test_an_early_mark_sees_the_header_only():
    """At 1 % of the bytes the round robin has sent a 4-byte chunk of two streams: no collapse table, no grid
    header yet."""
    with serving(Server(STREAMS, chunk=4)) as url:
        share, scene = next(stream_scene(url, fractions=(0.01,)))
    assert share >= 0.01 and scene.meshes == {} and scene.grid is None


@pytest.mark.parametrize("frames, message", [
    ([(1, 0, 16), (1, 32, 16)], "frame for stream 1 at 32 is out of order"),
    ([(1, 0, 16), (9, 0, 16)], "frame for stream 9 at 0 is out of order"),
    ([(0, 0, 16)], "frame for stream 0 at 0 is out of order"),
    ([(1, 0, 16), (2, 0, 16)], "the stream ended after 32 of"),
])
def test_a_broken_frame_stream_is_an_error(frames, message):
    with serving(Server(STREAMS, frames=frames)) as url:
        with pytest.raises(ValueError, match=message):
            list(stream_scene(url, fractions=(1.0,)))
