"""The daylight stream: per-face daylight coefficients packed for the wire, coarse faces first.

What a browser needs to relight a baked room for any date, hour, place and sky (Bosch, Besuievsky &
Martin, Sec. 5: visibility precomputed so that the sky relights interactively): the refined faces, their
sky visibility factors V (N sky patches), the interreflected coefficients D and ground terms
(processors/daylight/interreflection.py), and the sun's visibility over its yearly path (a sun table:
one byte per face and grid node). Packed here as arrays; the light model lives in
kernels/daylight_relight.py and stages/viewer/.

**Order** (``progressive_faces``). Faces go out coarse to fine, as the irradiance grid's stream
(formats/streaming.py, after Pacanowski et al. 2008 sec. 4.1): face centroids are snapped to a
2^``LEVELS`` grid per axis, and at each level, coarsest first, one face per occupied cell (and facing
class: the dominant axis and sign of its normal) that no coarser level has taken is sent, cells in
bit-reversed Morton order (spread over the whole scene). Each face records its *parent*: the face sent
for its cell one level up, always earlier in the stream. A client that holds the first k faces shows a
missing face with the coefficients of its nearest received ancestor (``received_source``): the cut
stream degrades to coarser light, never to holes.

**File** (little-endian)::

    magic "USDBDLS1", uint32 header bytes, UTF-8 JSON header (``DaylightHeader``: counts, site, frame,
    patch layout, sun table grid, prims), then sections, each a uint32 kind, uint32 item count, uint32
    deflated bytes and that many bytes of zlib data:

    SKY (1)       float64 patch samples (N, 9, 3) ENU, solid angles (N,), centre directions (N, 3)
    GEOMETRY (2)  float32 points (P, 3); uint32 corners (F, 3); int16 unit normals x 32767 (F, 3);
                  uint8 albedo x 255 (F, 3); int32 parent (F,), -1 at the roots; uint32 face id (F,):
                  the face's index in the bake's face order; uint32 prim (F,): index into the header's prims
    CONTEXT (5)   float32 corners (T, 3, 3) and uint8 albedo x 255 (T, 3) of the scene's other triangles
                  (instances, prims that are not receivers): drawn for context, not relit  (only when any)
    WEATHER (3)   float64 local standard time, ms since 1970 (H,); float32 direct-normal and
                  diffuse-horizontal irradiance, W/m^2 (H,) each  (only when the bake names a weather file)
    FACES (4)     ``count`` faces from stream position ``start`` (uint32, first in the payload): uint8 V
                  codes (n, N) (V = code x visibility_scale, the bake's own bytes); uint8 D codes (K, n, N),
                  for K = 3 as G, R - G, B - G modulo 256 (``channel_deltas``),
                  and float32 per-face scales (K, n) (square-root codes: D = scale (code / 255)^2,
                  scale = max_j D; ``indirect_codes``); float32
                  ground direct (n,) and indirect (K, n); uint8 sun table shares (n, R)

All faces are in stream order; FACES sections follow the geometry in stream order, ``packet_faces``
each. A prefix ending at any section boundary decodes; a torn section is dropped.
"""

from __future__ import annotations

import json
import struct
import zlib
from dataclasses import dataclass

import numpy as np

MAGIC = b"USDBDLS1"
OVERLAY_MAGIC = b"USDBANN1"
HEAD = struct.Struct("<8sI")
SECTION = struct.Struct("<III")
"""kind, item count, deflated bytes."""
SKY, GEOMETRY, WEATHER, FACES, CONTEXT = 1, 2, 3, 4, 5
LEVELS = 10
"""Centroid grid of the progressive order: 2^LEVELS cells per axis at the finest level."""
NORMAL_SCALE = 32767.0


@dataclass(frozen=True)
class DaylightCoefficients:
    """Everything the stream carries, in the bake's face order: the encoder's input (a client decodes a
    ``DaylightPrefix``, in stream order)."""

    header: dict
    """JSON-able: faces, points, patches {layout, count, subdivision}, indirect_sets, bounces,
    ground_reflectance, visibility_scale, site {latitude, longitude, timezone, north}, to_world (3x3),
    origin (3), up_axis, sun_table {declinations, hour_angles, node_row, samples}, prims [{path, faces}],
    packet_faces, sky_tables (``kernels/daylight_relight.sky_model_tables``), weather {source, hours} or
    null."""
    patch_samples: np.ndarray
    """(N, 9, 3) float64 ENU."""
    solid_angles: np.ndarray
    """(N,) float64."""
    patch_directions: np.ndarray
    """(N, 3) float64."""
    points: np.ndarray
    """(P, 3) float32 relative to header origin."""
    corners: np.ndarray
    """(F, 3) uint32 point indices."""
    normals: np.ndarray
    """(F, 3) float32 unit."""
    albedo: np.ndarray
    """(F, 3) float32."""
    visibility: np.ndarray
    """(F, N) uint8 codes of V."""
    indirect: np.ndarray
    """(K, F, N) float32 D."""
    ground_direct: np.ndarray
    """(F,) float32."""
    ground_indirect: np.ndarray
    """(K, F) float32."""
    sun_hits: np.ndarray
    """(F, R) uint8 sun table shares, face-major."""
    face_prim: np.ndarray
    """(F,) uint32 index into ``header["prims"]``."""
    weather_times: np.ndarray | None = None
    """(H,) datetime64[ms] local standard time."""
    weather_direct: np.ndarray | None = None
    weather_diffuse: np.ndarray | None = None
    context: np.ndarray | None = None
    """(T, 3, 3) float32 the scene's triangles that are not faces here (instances, other prims), or None."""
    context_albedo: np.ndarray | None = None
    """(T, 3) float32."""


@dataclass(frozen=True)
class DaylightPrefix:
    """What a client holds after a prefix of the stream: arrays in stream order."""

    header: dict
    patch_samples: np.ndarray
    solid_angles: np.ndarray
    patch_directions: np.ndarray
    points: np.ndarray
    corners: np.ndarray
    normals: np.ndarray
    albedo: np.ndarray
    parent: np.ndarray
    """(F,) int32 stream position of each face's parent, -1 at the roots."""
    face_id: np.ndarray
    """(F,) uint32 bake face index of each stream position."""
    prim: np.ndarray
    """(F,) uint32 index into ``header["prims"]`` of each stream position."""
    received: int
    """Faces [0, received) have coefficients."""
    visibility: np.ndarray
    """(F, N) float32 V (zeros beyond ``received``)."""
    indirect: np.ndarray
    """(K, F, N) float32 dequantized D."""
    ground_direct: np.ndarray
    ground_indirect: np.ndarray
    sun_hits: np.ndarray
    """(F, R) uint8."""
    weather: tuple[np.ndarray, np.ndarray, np.ndarray] | None
    """(times datetime64[ms], direct normal, diffuse horizontal) or None."""
    context: np.ndarray
    """(T, 3, 3) float32 the context triangles (not relit), T = 0 when none arrived."""
    context_albedo: np.ndarray
    """(T, 3) float32."""


def _reversed_morton(cells: np.ndarray, bits: int) -> np.ndarray:
    """(n,) uint64 Morton code of (n, 3) cells with its 3 * bits bits reversed (a 3D van der Corput order)."""
    code = np.zeros(len(cells), np.uint64)
    for bit in range(bits):
        for axis in range(3):
            code |= ((cells[:, axis].astype(np.uint64) >> np.uint64(bit)) & np.uint64(1)) << np.uint64(3 * bit + axis)
    out = np.zeros_like(code)
    for bit in range(3 * bits):
        out |= ((code >> np.uint64(bit)) & np.uint64(1)) << np.uint64(3 * bits - 1 - bit)
    return out


def progressive_faces(centroids: np.ndarray, normals: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(order, parent): bake face index of each stream position, and each position's parent position
    (-1 at the roots), as the module docstring's **Order**."""
    count = len(centroids)
    if count == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    centroids = np.nan_to_num(np.asarray(centroids, np.float64))
    low, high = centroids.min(axis=0), centroids.max(axis=0)
    span = np.maximum(high - low, 1e-30)
    cells = np.minimum(((centroids - low) / span * (1 << LEVELS)).astype(np.int64), (1 << LEVELS) - 1)
    axis = np.argmax(np.abs(normals), axis=1)
    facing = 2 * axis + (np.asarray(normals)[np.arange(count), axis] < 0)
    level_of = np.full(count, -2, np.int64)  # level a face is sent at (-1: finer than the grid)
    representative = np.arange(count)  # per face: the face sent for its cell at the level above
    parent_face = np.full(count, -1, np.int64)
    rank = np.zeros(count, np.uint64)
    for level in range(LEVELS, -2, -1):
        shifted = cells >> max(level, 0)
        keys = np.column_stack([facing, shifted, np.arange(count) if level < 0 else np.zeros(count, np.int64)])
        _, cell = np.unique(keys, axis=0, return_inverse=True)
        cell = cell.ravel()
        taken = level_of > -2
        order = np.lexsort((np.arange(count), ~taken, cell))  # per cell: a face already sent first
        first = np.ones(count, bool)
        first[1:] = cell[order][1:] != cell[order][:-1]
        chosen = order[first]
        head = np.empty(cell.max() + 1, np.int64)
        head[cell[chosen]] = chosen
        new = chosen[~taken[chosen]]
        level_of[new] = level
        parent_face[new] = np.where(level == LEVELS, -1, representative[new])
        rank[new] = _reversed_morton(shifted[new], LEVELS - max(level, 0))
        representative = head[cell]
    order = np.lexsort((np.arange(count), rank, -level_of))
    position = np.empty(count, np.int64)
    position[order] = np.arange(count)
    parent = np.where(parent_face[order] >= 0, position[np.maximum(parent_face[order], 0)], -1)
    return order, parent


def received_source(parent: np.ndarray, received: int) -> np.ndarray:
    """(F,) stream position whose coefficients each position shows: itself when received, else its nearest
    received ancestor (-1 when none is: before the first FACES section)."""
    source = np.arange(len(parent))
    missing = source >= received
    while missing.any():
        source[missing] = parent[source[missing]]
        missing = source >= received  # -1 (a root not received) stops too
    return source


def indirect_codes(indirect: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(scale (K, F) float32, codes (K, F, N) uint8) of D >= 0: square-root codes c = round(255 sqrt(D / s)) with
    s = max_j D_ij per face, so D = s (c / 255)^2. The square root spends the byte's steps where a face's
    small coefficients are: relit errors 2-3x below linear codes (the sun's patches are often a face's
    small ones), at most s / 255 at the top."""
    scale = indirect.max(axis=-1, initial=0.0).astype(np.float32)
    share = np.clip(indirect / np.where(scale > 0, scale, 1.0)[..., None], 0.0, 1.0)
    return scale, np.round(np.sqrt(share) * 255.0).astype(np.uint8)


def channel_deltas(codes: np.ndarray, *, inverse: bool = False) -> np.ndarray:
    """Three sets of codes (R, G, B) as G and R - G, B - G modulo 256 (``inverse``: back). The colours of a
    face's bounced light move together: the differences deflate 25 % smaller than the codes themselves. One
    set (grey) is left as it is."""
    if len(codes) != 3:
        return codes
    out = codes.copy()
    green = codes[1].astype(np.int16) * (1 if inverse else -1)
    out[0] = ((codes[0] + green) % 256).astype(np.uint8)
    out[2] = ((codes[2] + green) % 256).astype(np.uint8)
    return out


def decode_indirect(codes: np.ndarray, scale: np.ndarray) -> np.ndarray:
    """D = s (c / 255)^2, float32 (``indirect_codes``' inverse)."""
    share = codes.astype(np.float32) / np.float32(255.0)
    return share * share * np.asarray(scale, np.float32)[..., None]


def _section(kind: int, count: int, *arrays: np.ndarray) -> bytes:
    payload = zlib.compress(b"".join(np.ascontiguousarray(a).tobytes() for a in arrays), 6)
    return SECTION.pack(kind, count, len(payload)) + payload


def encode_daylight_stream(data: DaylightCoefficients, *, packet_faces: int = 2048) -> bytes:
    """The stream file (module docstring) of ``data``."""
    faces = len(data.corners)
    corners_xyz = data.points[data.corners.astype(np.int64)].astype(np.float64)
    order, parent = progressive_faces(corners_xyz.mean(axis=1), data.normals)
    header = dict(data.header, faces=faces, points=len(data.points), packet_faces=int(packet_faces),
                  indirect_sets=int(len(data.indirect)), sun_rows=int(data.sun_hits.shape[1]),
                  patch_count=int(len(data.solid_angles)))
    text = json.dumps(header).encode()
    parts = [HEAD.pack(MAGIC, len(text)), text,
             _section(SKY, len(data.solid_angles), data.patch_samples.astype("<f8"),
                      data.solid_angles.astype("<f8"), data.patch_directions.astype("<f8")),
             _section(GEOMETRY, faces, data.points.astype("<f4"), data.corners[order].astype("<u4"),
                      np.round(np.clip(data.normals[order], -1, 1) * NORMAL_SCALE).astype("<i2"),
                      np.round(np.clip(data.albedo[order], 0, 1) * 255).astype(np.uint8),
                      parent.astype("<i4"), order.astype("<u4"), data.face_prim[order].astype("<u4"))]
    if data.context is not None and len(data.context):
        parts.append(_section(CONTEXT, len(data.context), data.context.astype("<f4"),
                              np.round(np.clip(data.context_albedo, 0, 1) * 255).astype(np.uint8)))
    if data.weather_times is not None:
        parts.append(_section(WEATHER, len(data.weather_times),
                              data.weather_times.astype("datetime64[ms]").astype(np.int64).astype("<f8"),
                              data.weather_direct.astype("<f4"), data.weather_diffuse.astype("<f4")))
    scale, codes = indirect_codes(data.indirect)
    for start in range(0, faces, packet_faces):
        rows = order[start:start + packet_faces]
        parts.append(_section(FACES, len(rows), np.array([start], "<u4"), data.visibility[rows],
                              channel_deltas(codes[:, rows]), scale[:, rows].astype("<f4"),
                              data.ground_direct[rows].astype("<f4"), data.ground_indirect[:, rows].astype("<f4"),
                              data.sun_hits[rows]))
    return b"".join(parts)


def section_ends(data: bytes) -> list[tuple[int, int]]:
    """(kind, byte offset where it ends) of every whole section of a stream (prefix)."""
    at, ends = HEAD.size + HEAD.unpack_from(data)[1], []
    while at + SECTION.size <= len(data):
        kind, _, size = SECTION.unpack_from(data, at)
        if at + SECTION.size + size > len(data):
            break
        at += SECTION.size + size
        ends.append((kind, at))
    return ends


def geometry_end(read) -> int:
    """Bytes a prefix needs to decode (the header, SKY and GEOMETRY sections), found from ``read(end)``, which
    returns the stream's first ``end`` bytes (fewer when it is shorter); a stream cut before them gives more
    than it holds."""
    head = read(HEAD.size)
    if len(head) < HEAD.size or head[:8] != MAGIC:
        raise ValueError("not a usdbake daylight stream (bad magic)")
    at = HEAD.size + HEAD.unpack(head)[1]
    for _ in range(2):  # SKY, then GEOMETRY
        section = read(at + SECTION.size)[at:]
        if len(section) < SECTION.size:
            return at + SECTION.size
        at += SECTION.size + SECTION.unpack(section)[2]
    return at


class _Reader:
    """A section's arrays in order, from its zlib data inflated to exactly the bytes they take (no more: a
    section that inflates past them, or stops short, is refused)."""

    def __init__(self, payload: bytes, kind: int, sizes: list[tuple[str, tuple]]):
        expected = sum(np.dtype(dtype).itemsize * int(np.prod(shape)) for dtype, shape in sizes)
        inflater = zlib.decompressobj()
        try:
            self.payload = inflater.decompress(payload, expected + 1)
        except zlib.error as error:
            raise ValueError(f"daylight stream: section {kind} is not zlib data ({error})") from None
        if len(self.payload) != expected or inflater.unconsumed_tail:
            raise ValueError(f"daylight stream: section {kind} holds {len(self.payload)}"
                             f"{'+' if inflater.unconsumed_tail else ''} bytes, not the {expected} its counts need")
        self.arrays = iter(sizes)
        self.at = 0

    def take(self) -> np.ndarray:
        dtype, shape = next(self.arrays)
        count = int(np.prod(shape))
        out = np.frombuffer(self.payload, dtype, count, self.at).reshape(shape)
        self.at += out.nbytes
        return out


def _header(data: bytes) -> tuple[dict, int]:
    """The JSON header and where the sections begin; ValueError naming a missing or impossible count."""
    if len(data) < HEAD.size or data[:8] != MAGIC:
        raise ValueError("not a usdbake daylight stream (bad magic)")
    length = HEAD.unpack_from(data)[1]
    try:
        header = json.loads(data[HEAD.size:HEAD.size + length])
    except (UnicodeDecodeError, json.JSONDecodeError) as error:
        raise ValueError(f"daylight stream: unreadable header ({error})") from None
    for key in ("faces", "points", "patch_count", "indirect_sets", "sun_rows"):
        value = header.get(key) if isinstance(header, dict) else None
        if not isinstance(value, int) or not 0 <= value < 1 << 31:
            raise ValueError(f"daylight stream: header {key} = {value!r} is not a count")
    if header["indirect_sets"] not in (1, 3):
        raise ValueError(f"daylight stream: header indirect_sets = {header['indirect_sets']} (1 or 3)")
    return header, HEAD.size + length


def decode_daylight_stream(data: bytes) -> DaylightPrefix:
    """The coefficients of a stream prefix (any length from the end of GEOMETRY on); faces of FACES sections
    not yet whole are not received. ValueError for anything that is not such a stream."""
    header, at = _header(data)
    faces, n, k, r = header["faces"], header["patch_count"], header["indirect_sets"], header["sun_rows"]
    out: dict = {"weather": None, "received": 0, "context": np.zeros((0, 3, 3), np.float32),
                 "context_albedo": np.zeros((0, 3), np.float32)}
    scale = np.float32(header.get("visibility_scale", 0.0))
    while at + SECTION.size <= len(data):
        kind, count, size = SECTION.unpack_from(data, at)
        if at + SECTION.size + size > len(data):
            break  # a torn section
        payload = data[at + SECTION.size:at + SECTION.size + size]
        at += SECTION.size + size
        if kind == SKY:
            reader = _Reader(payload, kind, [("<f8", (n, 9, 3)), ("<f8", (n,)), ("<f8", (n, 3))])
            out.update(patch_samples=reader.take(), solid_angles=reader.take(), patch_directions=reader.take())
        elif kind == GEOMETRY:
            reader = _Reader(payload, kind, [("<f4", (header["points"], 3)), ("<u4", (faces, 3)), ("<i2", (faces, 3)),
                                             ("u1", (faces, 3)), ("<i4", (faces,)), ("<u4", (faces,)), ("<u4", (faces,))])
            out.update(points=reader.take(), corners=reader.take(),
                       normals=reader.take().astype(np.float32) / np.float32(NORMAL_SCALE),
                       albedo=reader.take().astype(np.float32) / np.float32(255),
                       parent=reader.take().astype(np.int64), face_id=reader.take(), prim=reader.take())
            if (out["corners"] >= header["points"]).any() or (out["parent"] >= np.arange(faces)).any():
                raise ValueError("daylight stream: a corner or a parent points past what it may")
            out.update(visibility=np.zeros((faces, n), np.float32), indirect=np.zeros((k, faces, n), np.float32),
                       ground_direct=np.zeros(faces, np.float32), ground_indirect=np.zeros((k, faces), np.float32),
                       sun_hits=np.zeros((faces, r), np.uint8))
        elif kind == CONTEXT:
            reader = _Reader(payload, kind, [("<f4", (count, 3, 3)), ("u1", (count, 3))])
            out.update(context=reader.take(), context_albedo=reader.take().astype(np.float32) / np.float32(255))
        elif kind == WEATHER:
            reader = _Reader(payload, kind, [("<f8", (count,)), ("<f4", (count,)), ("<f4", (count,))])
            out["weather"] = (reader.take().astype(np.int64).astype("datetime64[ms]"), reader.take(), reader.take())
        elif kind == FACES and "corners" in out:
            reader = _Reader(payload, kind, [("<u4", (1,)), ("u1", (count, n)), ("u1", (k, count, n)),
                                             ("<f4", (k, count)), ("<f4", (count,)), ("<f4", (k, count)),
                                             ("u1", (count, r))])
            start = int(reader.take()[0])
            if start + count > faces:
                raise ValueError(f"daylight stream: faces {start}..{start + count} past its {faces}")
            rows = slice(start, start + count)
            out["visibility"][rows] = reader.take().astype(np.float32) * scale
            codes = channel_deltas(reader.take(), inverse=True)
            out["indirect"][:, rows] = decode_indirect(codes, reader.take())
            out["ground_direct"][rows] = reader.take()
            out["ground_indirect"][:, rows] = reader.take()
            out["sun_hits"][rows] = reader.take()
            out["received"] = max(out["received"], start + count)
        else:
            raise ValueError(f"daylight stream: section {kind} out of place")
    if "corners" not in out or "patch_samples" not in out:
        raise ValueError("daylight stream: cut before its geometry")
    return DaylightPrefix(header=header, **out)


def encode_overlay(metrics: dict[str, np.ndarray], summary: dict) -> bytes:
    """Per-face overlays (each (F,) float32, stream order) and a JSON summary: ``OVERLAY_MAGIC``, uint32 JSON
    bytes, the JSON ({"metrics": names, "faces": F, **summary}), then zlib data of the (M, F) float32 values."""
    names = list(metrics)
    faces = len(next(iter(metrics.values()))) if metrics else 0
    text = json.dumps({"metrics": names, "faces": faces, **summary}).encode()
    values = np.array([metrics[name] for name in names], "<f4").reshape(len(names), faces)
    return HEAD.pack(OVERLAY_MAGIC, len(text)) + text + zlib.compress(values.tobytes(), 6)


def decode_overlay(data: bytes) -> tuple[dict, dict[str, np.ndarray]]:
    """(summary, {metric: (F,) float32}) of ``encode_overlay``'s bytes."""
    if len(data) < HEAD.size or data[:8] != OVERLAY_MAGIC:
        raise ValueError("not a usdbake overlay stream (bad magic)")
    length = HEAD.unpack_from(data)[1]
    try:
        summary = json.loads(data[HEAD.size:HEAD.size + length])
        names, faces = list(summary["metrics"]), int(summary["faces"])
    except (UnicodeDecodeError, ValueError, KeyError, TypeError) as error:
        raise ValueError(f"overlay stream: unreadable header ({error})") from None
    reader = _Reader(data[HEAD.size + length:], 0, [("<f4", (len(names), faces))])
    return summary, dict(zip(names, reader.take()))
