"""formats/daylight_stream.py on synthetic arrays: the file round-trips, V and the sun table bit for bit and D
within its square-root codes; the progressive order sends coarse faces first and parents before children; a
prefix decodes what it holds; the overlay codec round-trips."""

from __future__ import annotations

import numpy as np
import pytest

from usdbake.formats.daylight_stream import (CONTEXT, FACES, GEOMETRY, DaylightCoefficients, decode_daylight_stream,
                                             decode_indirect, decode_overlay, encode_daylight_stream, encode_overlay,
                                             geometry_end, indirect_codes, progressive_faces, received_source,
                                             section_ends)


def coefficients(faces: int = 300, patches: int = 12, sets: int = 1, rows: int = 7, seed: int = 0):
    rng = np.random.default_rng(seed)
    points = rng.uniform(-3, 3, (faces * 3, 3)).astype(np.float32)
    corners = np.arange(faces * 3, dtype=np.uint32).reshape(faces, 3)
    normals = rng.normal(size=(faces, 3)).astype(np.float32)
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    header = {"visibility_scale": 0.01, "site": {"latitude": 10.0, "longitude": 0.0, "timezone": 0.0, "north": 0.0},
              "prims": [{"path": "/A", "faces": faces}]}
    return DaylightCoefficients(
        header, rng.normal(size=(patches, 9, 3)), rng.uniform(0.01, 0.1, patches), rng.normal(size=(patches, 3)),
        points, corners, normals, rng.uniform(0, 1, (faces, 3)).astype(np.float32),
        rng.integers(0, 256, (faces, patches), dtype=np.uint8),
        (rng.uniform(0, 1, (sets, faces, patches)) ** 3).astype(np.float32), rng.uniform(0, 2, faces).astype(np.float32),
        rng.uniform(0, 1, (sets, faces)).astype(np.float32), rng.integers(0, 255, (faces, rows), dtype=np.uint8),
        np.zeros(faces, np.uint32), context=rng.uniform(-1, 1, (5, 3, 3)).astype(np.float32),
        context_albedo=np.full((5, 3), 0.4, np.float32))


@pytest.mark.parametrize("sets", [1, 3])
def test_the_stream_round_trips(sets):
    data = coefficients(sets=sets)
    decoded = decode_daylight_stream(encode_daylight_stream(data, packet_faces=64))
    order = decoded.face_id.astype(np.int64)
    assert decoded.received == 300 and sorted(order) == list(range(300))
    np.testing.assert_array_equal(decoded.visibility, data.visibility[order] * np.float32(0.01))
    np.testing.assert_array_equal(decoded.sun_hits, data.sun_hits[order])
    np.testing.assert_array_equal(decoded.corners, data.corners[order])
    np.testing.assert_allclose(decoded.normals, data.normals[order], atol=1 / 32767)
    np.testing.assert_array_equal(decoded.ground_direct, data.ground_direct[order])
    np.testing.assert_array_equal(decoded.context, data.context)  # not relit: in their own order
    np.testing.assert_allclose(decoded.context_albedo, 0.4, atol=0.5 / 255)
    scale = data.indirect.max(axis=2)[:, order]
    error = np.abs(decoded.indirect - data.indirect[:, order]) / scale[..., None]
    assert error.max() <= 1 / 255 + 1e-6


def test_square_root_codes_are_finer_at_small_values():
    values = np.array([[[1.0, 0.5, 0.1, 0.01, 0.001, 0.0]]], np.float32)
    scale, codes = indirect_codes(values)
    back = decode_indirect(codes, scale)
    assert back[0, 0, 0] == 1.0 and back[0, 0, -1] == 0.0
    relative = np.abs(back - values)[0, 0, 1:5] / values[0, 0, 1:5]
    assert relative[2] < 0.05 and relative[1] < 0.01  # linear 8-bit codes: up to 2% at 0.1 of the maximum
    assert not decode_indirect(*indirect_codes(np.zeros((1, 2, 4), np.float32))).any()


def test_a_prefix_decodes_what_it_holds():
    stream = encode_daylight_stream(coefficients(), packet_faces=64)
    ends = section_ends(stream)
    assert [kind for kind, _ in ends][:3] == [1, GEOMETRY, CONTEXT] and [kind for kind, _ in ends][3:] == [FACES] * 5
    assert geometry_end(lambda end: stream[:end]) == ends[1][1]
    with pytest.raises(ValueError, match="cut before its geometry"):
        decode_daylight_stream(stream[:ends[1][1] - 1])
    for k, (_, end) in enumerate(ends[2:]):
        prefix = decode_daylight_stream(stream[:end + 3])  # a few bytes of the next section: dropped
        assert prefix.received == min(300, 64 * k)
        assert not prefix.visibility[prefix.received:].any()
    with pytest.raises(ValueError, match="bad magic"):
        decode_daylight_stream(b"not a stream at all")


def test_progressive_order_sends_coarse_faces_first_and_parents_before_children():
    rng = np.random.default_rng(3)
    centroids = rng.uniform(-5, 5, (5000, 3))
    normals = rng.normal(size=(5000, 3))
    order, parent = progressive_faces(centroids, normals)
    assert sorted(order) == list(range(5000))
    assert ((parent < np.arange(5000)) & (parent >= -1)).all()
    assert (parent == -1).sum() <= 6  # one root per facing class
    octants = {tuple(x) for x in (centroids[order[:625]] > 0).astype(int)}  # the first eighth spans the box
    assert len(octants) == 8
    source = received_source(parent, 100)
    assert (source < 100).all() and (source[:100] == np.arange(100)).all()
    assert (received_source(parent, 0) == -1).all()


def test_degenerate_centroids_still_order():
    order, parent = progressive_faces(np.zeros((10, 3)), np.tile([0.0, 0.0, 1.0], (10, 1)))
    assert sorted(order) == list(range(10)) and (parent < np.arange(10)).all()
    order, parent = progressive_faces(np.full((3, 3), np.nan), np.tile([0.0, 0.0, 1.0], (3, 1)))
    assert sorted(order) == [0, 1, 2]


def test_the_overlay_round_trips():
    values = {"daylightAutonomy": np.array([0.0, 0.5, 1.0], np.float32), "daylightFactor": np.array([1, 2, 3], np.float32)}
    summary, decoded = decode_overlay(encode_overlay(values, {"sDA": 0.5}))
    assert summary["sDA"] == 0.5 and summary["faces"] == 3
    for name in values:
        np.testing.assert_array_equal(decoded[name], values[name])
    with pytest.raises(ValueError, match="bad magic"):
        decode_overlay(b"USDBDLS1" + bytes(8))


def test_a_broken_stream_is_refused_with_what_is_wrong():
    import json
    import struct
    import zlib

    stream = encode_daylight_stream(coefficients(), packet_faces=64)
    length = struct.unpack_from("<I", stream, 8)[0]
    header = json.loads(stream[12:12 + length])

    def with_header(**changes):
        text = json.dumps(dict(header, **changes)).encode()
        return stream[:8] + struct.pack("<I", len(text)) + text + stream[12 + length:]

    with pytest.raises(ValueError, match="header faces = -1 is not a count"):
        decode_daylight_stream(with_header(faces=-1))
    with pytest.raises(ValueError, match="header patch_count = 'many'"):
        decode_daylight_stream(with_header(patch_count="many"))
    with pytest.raises(ValueError, match="section 1 holds .* not the"):  # counts that the data does not hold
        decode_daylight_stream(with_header(patch_count=13))
    with pytest.raises(ValueError, match="unreadable header"):
        decode_daylight_stream(stream[:12] + b"\xff" * length + stream[12 + length:])
    bomb = zlib.compress(bytes(50_000_000))  # inflates far past what the counts need: stopped at the need
    section = struct.pack("<III", 1, 12, len(bomb)) + bomb
    with pytest.raises(ValueError, match=r"holds \d+\+ bytes"):
        decode_daylight_stream(stream[:12 + length] + section)
    with pytest.raises(ValueError, match="not zlib data"):
        decode_daylight_stream(stream[:12 + length] + struct.pack("<III", 1, 12, 4) + b"junk")
