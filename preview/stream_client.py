"""A client of ``usdbake serve``: fetch a prefix of every stream and rebuild meshes and light from it.

What a remote viewer does (Pacanowski et al. 2008, section 4): read the
manifest, take the first ``fraction`` of each stream with an HTTP range
request, decode the meshes' levels of detail (``formats/mesh_stream.py``)
and the grid vertices received so far (``formats/streaming.py``), and fill
the grid vertices not received yet by 3D push-pull, which never modifies a
received value. Plain ``urllib``: a client needs no server library.
"""

from __future__ import annotations

import json
import struct
import urllib.request
from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np

from ..formats.daylight_stream import (DaylightPrefix, decode_daylight_stream, decode_overlay, geometry_end,
                                       received_source)
from ..formats.mesh_stream import MESH_HEADER, MeshPrefix, decode_mesh_stream
from ..formats.streaming import HEADER, decode_stream, push_pull
from ..kernels.daylight_relight import IndirectCoefficients, Receivers, Relighter, SunTable
from ..kernels.direction24 import dequantize_vectors
from ..kernels.sky import patch_layout


@dataclass(frozen=True)
class GridPrefix:
    """The irradiance grid as a client holds it after a prefix of its stream."""

    resolution: tuple[int, int, int]
    grid_origin: np.ndarray
    cell_size: np.ndarray
    vectors: np.ndarray
    """(V, 6, 3, 3) float32: received vertices decoded, the others filled by push-pull (zeros when none)."""
    received: np.ndarray
    """(V,) bool."""


class StreamedDaylight:
    """The daylight stream as a client holds it, relit as the library relights (``kernels/daylight_relight``):
    what the browser viewer must match. Faces not received yet show their nearest received ancestor's
    coefficients (``formats/daylight_stream.received_source``)."""

    def __init__(self, prefix: DaylightPrefix):
        self.prefix = prefix
        header = prefix.header
        source = received_source(prefix.parent, prefix.received)
        self.shown = source >= 0
        """(F,) bool per stream position: has coefficients (its own or an ancestor's)."""
        take = np.maximum(source, 0)
        known = self.shown.astype(np.float32)
        patches = patch_layout(header["patches"]["layout"], count=header["patches"]["count"],
                               subdivision=header["patches"]["subdivision"])
        visibility = np.ascontiguousarray((prefix.visibility[take] * known[:, None]).T)
        table = header["sun_table"]
        hits = np.ascontiguousarray(prefix.sun_hits[take].T) * self.shown.astype(np.uint8)[None, :]
        sun = SunTable(np.asarray(table["declinations"]), np.asarray(table["hour_angles"]),
                       np.asarray(table["node_row"], np.int64), hits, int(table["samples"]))
        indirect = IndirectCoefficients(prefix.indirect[:, take] * known[None, :, None],
                                        prefix.ground_direct[take] * known, prefix.ground_indirect[:, take] * known,
                                        float(header["ground_reflectance"]))
        site = header["site"]
        self.relighter = Relighter(Receivers(visibility, patches, np.asarray(header["to_world"]), prefix.normals),
                                   sun, latitude=site["latitude"], longitude=site["longitude"],
                                   timezone=site["timezone"], north=site["north"], indirect=indirect)

    def at(self, time, **sky) -> np.ndarray:
        """(F, 3) float32 irradiance (W/m^2) per face in stream order at local standard ``time``, with
        ``Relighter.at``'s sky keywords; faces without coefficients yet are 0."""
        return self.relighter.at(np.datetime64(time), **sky)

    def in_bake_order(self, values: np.ndarray) -> np.ndarray:
        """Per-face ``values`` in stream order rearranged into the bake's face order."""
        out = np.empty_like(values)
        out[self.prefix.face_id.astype(np.int64)] = values
        return out


@dataclass(frozen=True)
class StreamedScene:
    meshes: dict[str, MeshPrefix]
    """Prim path -> level of detail held."""
    grid: GridPrefix | None
    bytes_read: int
    daylight: StreamedDaylight | None = None
    overlay: dict[str, np.ndarray] | None = None
    """annual_daylight's metrics per daylight face (stream order), when the server sends them."""


def _get(url: str, *, end: int | None = None, timeout: float = 30.0) -> bytes:
    """The body of ``url``, or its bytes [0, end) by a range request."""
    request = urllib.request.Request(url, headers={"Range": f"bytes=0-{end - 1}"} if end else {})
    with urllib.request.urlopen(request, timeout=timeout) as response:
        return response.read()


def _prefix_end(total: int, fraction: float, least: int) -> int:
    return int(min(total, max(least, np.ceil(fraction * total))))


def fetch_scene(base_url: str, *, fraction: float = 1.0, smooth: bool = True, timeout: float = 30.0) -> StreamedScene:
    """Every stream of the server at ``base_url`` cut to its first ``fraction`` (at least its header and, for a
    mesh, its collapse table), decoded."""
    if not 0.0 <= fraction <= 1.0:
        raise ValueError(f"fraction {fraction}: between 0 and 1")
    base = base_url.rstrip("/")
    manifest = json.loads(_get(f"{base}/manifest", timeout=timeout))
    meshes, read = {}, 0
    for mesh in manifest["meshes"]:
        header = _get(base + mesh["url"], end=MESH_HEADER.size, timeout=timeout)
        table_end = MESH_HEADER.size + MESH_HEADER.unpack(header)[4]
        data = _get(base + mesh["url"], end=_prefix_end(mesh["bytes"], fraction, table_end), timeout=timeout)
        meshes[mesh["prim"]] = decode_mesh_stream(data)
        read += len(data)
    grid = None
    if manifest["grid"]:
        data = _get(base + manifest["grid"]["url"], end=_prefix_end(manifest["grid"]["bytes"], fraction, HEADER.size),
                    timeout=timeout)
        read += len(data)
        grid = _grid_from(data, smooth)
    daylight = None
    if manifest.get("daylight"):
        url, size = base + manifest["daylight"]["url"], manifest["daylight"]["bytes"]
        least = geometry_end(lambda end: _get(url, end=min(end, size), timeout=timeout))
        data = _get(url, end=_prefix_end(size, fraction, least), timeout=timeout)
        read += len(data)
        daylight = StreamedDaylight(decode_daylight_stream(data))
    overlay = decode_overlay(_get(base + manifest["overlay"]["url"], timeout=timeout))[1] if manifest.get("overlay") else None
    return StreamedScene(meshes, grid, read, daylight, overlay)


def _grid_from(data: bytes, smooth: bool) -> GridPrefix:
    stream = decode_stream(data)
    count = int(np.prod(stream.resolution))
    vectors = np.zeros((count, 6, 3, 3), np.float32)
    received = np.zeros(count, bool)
    vectors[stream.vertex_index] = dequantize_vectors(stream.directions, stream.colors)
    received[stream.vertex_index] = True
    if received.any() and not received.all():
        vectors = push_pull(vectors.reshape(count, -1), stream.resolution, received,
                            smooth=smooth).reshape(vectors.shape).astype(np.float32)
    return GridPrefix(stream.resolution, stream.grid_origin, stream.cell_size, vectors, received)


STREAM_FRAME = struct.Struct("<IIQ")
"""``/stream`` frame header (stages/serve.py FRAME): stream index (0 = manifest), payload length, offset."""


def stream_scene(base_url: str, *, fractions=(0.1, 0.5, 1.0), chunk: int | None = None, smooth: bool = True,
                 timeout: float = 30.0) -> Iterator[tuple[float, StreamedScene]]:
    """Read the server's interleaved ``/stream`` in one request and yield (share received, scene) each time
    the share of all stream bytes received passes one of ``fractions`` (and at the end): what a viewer
    shows as the scene sharpens."""
    url = base_url.rstrip("/") + "/stream" + (f"?chunk={chunk}" if chunk else "")
    marks = sorted(set(float(f) for f in fractions))
    with urllib.request.urlopen(url, timeout=timeout) as response:
        index, length, _ = STREAM_FRAME.unpack(response.read(STREAM_FRAME.size))
        manifest = json.loads(response.read(length))
        sizes = [m["bytes"] for m in manifest["meshes"]] + [manifest[k]["bytes"] for k in ("grid", "daylight", "overlay")
                                                           if manifest.get(k)]
        buffers = [bytearray() for _ in sizes]
        total, received = max(1, sum(sizes)), 0
        while True:
            head = response.read(STREAM_FRAME.size)
            if len(head) < STREAM_FRAME.size:
                break
            index, length, offset = STREAM_FRAME.unpack(head)
            payload = response.read(length)
            if index < 1 or index > len(buffers) or offset != len(buffers[index - 1]) or len(payload) != length:
                raise ValueError(f"{url}: frame for stream {index} at {offset} is out of order")
            buffers[index - 1] += payload
            received += length
            while marks and received / total >= marks[0]:
                marks.pop(0)
                yield received / total, _scene_from(manifest, buffers, smooth, received)
    if received < total:
        raise ValueError(f"{url}: the stream ended after {received} of {total} bytes")


def _scene_from(manifest: dict, buffers: list, smooth: bool, received: int) -> StreamedScene:
    meshes = {}
    for mesh, data in zip(manifest["meshes"], buffers):
        if len(data) >= MESH_HEADER.size and len(data) >= MESH_HEADER.size + MESH_HEADER.unpack_from(data)[4]:
            meshes[mesh["prim"]] = decode_mesh_stream(bytes(data))
    grid_data = bytes(buffers[len(manifest["meshes"])]) if manifest["grid"] else b""
    grid = _grid_from(grid_data, smooth) if len(grid_data) >= HEADER.size else None
    daylight = overlay = None
    tail = len(manifest["meshes"]) + bool(manifest["grid"])
    if manifest.get("daylight"):
        data = bytes(buffers[tail])
        if geometry_end(lambda end: data[:end]) <= len(data):
            daylight = StreamedDaylight(decode_daylight_stream(data))
    if manifest.get("overlay") and len(buffers[-1]) == manifest["overlay"]["bytes"]:
        overlay = decode_overlay(bytes(buffers[-1]))[1]
    return StreamedScene(meshes, grid, received, daylight, overlay)
