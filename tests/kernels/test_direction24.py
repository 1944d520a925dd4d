"""kernels.direction24 on its own: the byte layout of a code, exact round trips of the codes whose
integer vector has length exactly 127, invariance under the vector's length, the hemisphere clamp for
vectors on the wrong side, the decoder on every kind of code, and ``dequantize_vectors`` against colours
and directions written out by hand.

The error bound over random directions and the fallbacks for zero or non-finite vectors are tested in
tests/kernels/test_rgb9e5.py and test_properties.py; they are not repeated here.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from tolerances import FLOAT32_STORAGE, FLOAT64_CONSTANT
from usdbake.kernels import direction24 as dir24
from usdbake.kernels.rgb9e5 import encode_rgb9e5


def exact_length_codes() -> np.ndarray:
    """(K, 3) int64: every integer vector q in [-127, 127]^3 with |q|^2 = 127^2 exactly (found by brute force)."""
    r = np.arange(-127, 128)
    a, b = np.meshgrid(r, r, indexing="ij")
    rest = 127 ** 2 - a * a - b * b
    c = np.rint(np.sqrt(np.maximum(rest, 0))).astype(np.int64)
    ok = (rest >= 0) & (c * c == rest)
    rows = [np.stack([a[ok], b[ok], c[ok]], 1), np.stack([a[ok], b[ok], -c[ok]], 1)]
    return np.unique(np.concatenate(rows), axis=0)


def test_the_constants_are_their_closed_forms():
    # The decoded direction nearest the rim: axis component 1, the other two 127 (and the bound is 0.55 deg).
    assert abs(dir24.MIN_AXIS_COSINE - 1 / math.sqrt(1 + 127 ** 2 + 127 ** 2)) <= FLOAT64_CONSTANT
    assert 0.55 < dir24.MAX_ANGLE_ERROR_DEG < 0.56
    np.testing.assert_array_equal(np.abs(dir24.AXES).sum(axis=1), np.ones(6))
    np.testing.assert_array_equal(dir24.AXES[0::2], -dir24.AXES[1::2])  # +axis then -axis
    np.testing.assert_array_equal(np.abs(dir24.AXES[0::2]), np.eye(3))  # x, y, z in that order


def test_code_bytes_are_the_rounded_components_plus_128():
    # (3, 4, 0) / 5 * 127 = (76.2, 101.6, 0): rounded (76, 102, 0); -(3, 4, 0)/5 -> (-76, -102, 0).
    codes = dir24.encode_directions(np.array([[3.0, 4.0, 0.0], [-3.0, -4.0, 0.0], [0.0, 0.0, -2.0]]), [2, 3, 5])
    assert codes.dtype == np.uint8 and codes.shape == (3, 3)
    np.testing.assert_array_equal(codes, [[204, 230, 128], [52, 26, 128], [128, 128, 1]])


def test_codes_of_length_exactly_127_round_trip_exactly_in_every_hemisphere_they_lie_in():
    q = exact_length_codes()
    assert len(q) > 100  # the search found more than the six axes (e.g. (10, 30, 123))
    for hemisphere, axis in enumerate(dir24.AXES.astype(np.int64)):
        inside = q[q @ axis >= 1]  # codes an encoder of this hemisphere can produce
        decoded = dir24.decode_directions((inside + 128).astype(np.uint8))
        np.testing.assert_allclose(decoded, inside / 127.0, atol=FLOAT32_STORAGE)
        again = dir24.encode_directions(decoded, np.full(len(inside), hemisphere))
        np.testing.assert_array_equal(again.astype(np.int64) - 128, inside)


def test_code_is_independent_of_the_vectors_length():
    rng = np.random.default_rng(5)  # fixed seed
    v = rng.normal(size=(2000, 3))
    h = np.where(v[:, 2] >= 0, 4, 5)  # +z or -z by the sign of z
    codes = dir24.encode_directions(v, h)
    for scale in (2.0 ** -60, 0.25, 8.0, 2.0 ** 70):  # powers of two: the unit vector is bit-identical
        np.testing.assert_array_equal(dir24.encode_directions(v * scale, h), codes)


def test_a_vector_on_the_wrong_side_is_clamped_into_its_hemisphere():
    # (-1, 0, 0) in +x: the x component is held at one step, on the +x side.
    codes = dir24.encode_directions(np.array([[-1.0, 0.0, 0.0], [0.6, -0.8, 0.0]]), [0, 2])
    np.testing.assert_array_equal(codes.astype(int) - 128, [[1, 0, 0], [76, 1, 0]])
    decoded = dir24.decode_directions(codes)
    np.testing.assert_allclose(decoded[0], [1.0, 0.0, 0.0], atol=FLOAT32_STORAGE)
    assert decoded[1] @ dir24.AXES[2] >= dir24.MIN_AXIS_COSINE - FLOAT32_STORAGE


def test_single_vector_input_and_shape_checks():
    one = dir24.encode_directions(np.array([0.0, 1.0, 0.0]), 2)  # (3,) and a scalar hemisphere
    np.testing.assert_array_equal(one, [[128, 255, 128]])
    assert dir24.encode_directions(np.zeros((0, 3)), np.zeros(0, int)).shape == (0, 3)
    assert dir24.decode_directions(np.zeros((0, 3), np.uint8)).shape == (0, 3)
    with pytest.raises(IndexError):
        dir24.encode_directions(np.array([[1.0, 0.0, 0.0]]), [6])  # no seventh hemisphere
    with pytest.raises(ValueError):
        dir24.encode_directions(np.ones((3, 3)), [0, 1])  # one hemisphere short


def test_decoder_returns_unit_float32_directions_and_zero_for_the_null_code():
    rng = np.random.default_rng(8)  # fixed seed
    codes = rng.integers(0, 256, size=(5000, 3)).astype(np.uint8)
    codes[0] = 128
    decoded = dir24.decode_directions(codes)
    assert decoded.dtype == np.float32
    np.testing.assert_array_equal(decoded[0], [0.0, 0.0, 0.0])
    np.testing.assert_allclose(np.linalg.norm(decoded[1:].astype(np.float64), axis=1), 1.0, atol=FLOAT32_STORAGE)
    q = codes[1:].astype(np.float64) - 128.0
    np.testing.assert_allclose(decoded[1:], q / np.linalg.norm(q, axis=1, keepdims=True), atol=FLOAT32_STORAGE)
    # Byte 0 is -128, a code no encoder writes, and still decodes along its axis.
    np.testing.assert_allclose(dir24.decode_directions(np.array([[0, 128, 128]], np.uint8)), [[-1, 0, 0]])


def test_dequantize_vectors_is_colour_times_direction_with_rgb_rows():
    # Colours exact in RGB9E5 (powers of two), directions exact (axes and a code of length exactly 127).
    colors_rgb = np.zeros((2, 6, 3))
    colors_rgb[0] = [[1.0, 0.5, 0.25]] * 6
    colors_rgb[1] = [[k, 2.0 * k, 0.0] for k in range(6)]
    directions = np.broadcast_to((dir24.AXES.astype(np.int64) * 127 + 128).astype(np.uint8), (2, 6, 3)).copy()
    directions[1, 4] = np.array([10, 30, 123]) + 128  # 10^2 + 30^2 + 123^2 = 127^2: a unit vector in +z
    vectors = dir24.dequantize_vectors(directions, encode_rgb9e5(colors_rgb))
    assert vectors.shape == (2, 6, 3, 3) and vectors.dtype == np.float32
    d = dir24.AXES.astype(np.float64)
    expected = np.stack([colors_rgb[n][:, :, None] * d[:, None, :] for n in range(2)])
    expected[1, 4] = colors_rgb[1, 4][:, None] * (np.array([10, 30, 123]) / 127.0)[None, :]
    np.testing.assert_allclose(vectors, expected, atol=FLOAT32_STORAGE * 10)  # values up to 10: 1e-6 relative
    # Flat inputs are accepted and regrouped by vertex.
    np.testing.assert_array_equal(dir24.dequantize_vectors(directions.reshape(-1, 3),
                                                           encode_rgb9e5(colors_rgb).ravel()), vectors)
