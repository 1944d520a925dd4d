"""RGB9E5 (EXT_texture_shared_exponent): round-trip error bounds, special values, the bit layout,
agreement of the Warp decoder and the preview's decoder with ours, and the 8-bit hemisphere
direction code's error bound."""


import numpy as np
import warp as wp
from hypothesis import given, settings
from hypothesis import strategies as st
from tolerances import FLOAT32_STORAGE, FLOAT64_ROUNDING
from usdbake.kernels import direction24 as dir24
from usdbake.kernels.rgb9e5 import (
    ABSOLUTE_ERROR,
    MAX_RGB9E5,
    RELATIVE_ERROR,
    decode_rgb9e5,
    encode_rgb9e5,
    rgb9e5_decode,
)

wp.set_module_options({"enable_backward": False})


def bound(clamped: np.ndarray) -> np.ndarray:
    """Per-colour error bound of the format: half a mantissa step of the shared exponent."""
    return np.maximum(RELATIVE_ERROR * clamped.max(axis=-1), ABSOLUTE_ERROR)


def test_max_value_is_the_extensions_constant():
    # (2^9 - 1) / 2^9 * 2^(31 - 15)
    assert MAX_RGB9E5 == 65408.0


@given(st.lists(st.floats(min_value=0.0, max_value=MAX_RGB9E5, allow_nan=False, width=32), min_size=3,
                max_size=3))
@settings(max_examples=300, deadline=None)
def test_round_trip_within_half_a_mantissa_step(rgb):
    rgb = np.asarray(rgb, np.float64)
    decoded = decode_rgb9e5(encode_rgb9e5(rgb)).astype(np.float64)
    assert np.all(np.abs(decoded - rgb) <= bound(rgb) * (1 + FLOAT64_ROUNDING))


def test_round_trip_over_many_magnitudes():
    rng = np.random.default_rng(7)  # fixed seed
    rgb = rng.random((100_000, 3)) * np.exp2(rng.uniform(-30, 16, (100_000, 1)))
    rgb = np.minimum(rgb, MAX_RGB9E5)
    decoded = decode_rgb9e5(encode_rgb9e5(rgb)).astype(np.float64)
    error = np.abs(decoded - rgb).max(axis=1)
    assert np.all(error <= bound(rgb))
    # The bound is tight: the format does use (nearly) all of it.
    normal = rgb.max(axis=1) > 1e-3
    assert (error[normal] / rgb[normal].max(axis=1)).max() > 0.9 * 2.0**-9


def test_exact_values_round_trip_exactly():
    rgb = np.array([[1.0, 0.5, 0.25], [MAX_RGB9E5, 0.0, 128.0], [3.0, 5.0, 7.0], [2.0**-24, 0, 0]])
    np.testing.assert_array_equal(decode_rgb9e5(encode_rgb9e5(rgb)), rgb.astype(np.float32))


def test_zero_is_zero():
    packed = encode_rgb9e5(np.zeros((4, 3)))
    np.testing.assert_array_equal(packed, 0)
    np.testing.assert_array_equal(decode_rgb9e5(packed), 0.0)


def test_special_inputs_give_finite_sane_outputs():
    rgb = np.array([[np.nan, 1.0, 2.0], [-5.0, 1.0, 0.0], [np.inf, 0.0, 0.0], [-np.inf, np.nan, -0.0],
                    [1e30, 1e30, 1e30], [1e-40, 1e-40, 0.0]])
    decoded = decode_rgb9e5(encode_rgb9e5(rgb))
    assert np.isfinite(decoded).all() and (decoded >= 0).all() and (decoded <= MAX_RGB9E5).all()
    np.testing.assert_allclose(decoded[0], [0.0, 1.0, 2.0])  # NaN -> 0
    np.testing.assert_allclose(decoded[1], [0.0, 1.0, 0.0])  # negative -> 0
    np.testing.assert_allclose(decoded[2], [MAX_RGB9E5, 0, 0])  # +inf -> MAX
    np.testing.assert_array_equal(decoded[3], 0.0)
    np.testing.assert_allclose(decoded[4], MAX_RGB9E5)  # huge -> clamped to MAX
    np.testing.assert_array_equal(decoded[5], 0.0)  # below the smallest step


def test_bit_layout_matches_the_extension():
    # R = 1.0 with exponent 16 (2^(16-15-9) * 256 = 1): mantissas 256, 128, 64 in bits 0, 9, 18.
    packed = int(encode_rgb9e5(np.array([1.0, 0.5, 0.25])))
    assert packed & 0x1FF == 256
    assert (packed >> 9) & 0x1FF == 128
    assert (packed >> 18) & 0x1FF == 64
    assert packed >> 27 == 16


def test_exponent_bump_when_the_mantissa_rounds_up():
    # Just below 1.0: 511.9 / 512 rounds to 512 -> exponent + 1, mantissa 256.
    packed = int(encode_rgb9e5(np.array([1.0 - 2.0**-12, 0.0, 0.0])))
    assert packed & 0x1FF == 256 and packed >> 27 == 16


@wp.kernel
def _decode_kernel(packed: wp.array(dtype=wp.uint32), out: wp.array(dtype=wp.vec3)):
    i = wp.tid()
    out[i] = rgb9e5_decode(packed[i])


def test_warp_decoder_agrees_bit_for_bit():
    rng = np.random.default_rng(3)  # fixed seed
    packed = rng.integers(0, 2**32, 5000, dtype=np.uint64).astype(np.uint32)
    out = wp.zeros(len(packed), dtype=wp.vec3, device="cpu")
    wp.launch(_decode_kernel, len(packed), [wp.array(packed, dtype=wp.uint32, device="cpu"), out], device="cpu")
    np.testing.assert_array_equal(out.numpy(), decode_rgb9e5(packed))


# -- 24-bit (8:8:8) hemisphere directions ---------------------------------------------------------


def test_direction_code_error_bound_over_each_hemisphere():
    rng = np.random.default_rng(11)  # fixed seed
    v = rng.normal(size=(120_000, 3))
    h = rng.integers(0, 6, len(v))
    v *= np.sign(np.einsum("ni,ni->n", v, dir24.AXES[h]))[:, None]
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    decoded = dir24.decode_directions(dir24.encode_directions(v, h))
    angle = np.degrees(np.arccos(np.clip(np.einsum("ni,ni->n", v, decoded), -1, 1)))
    assert angle.max() <= dir24.MAX_ANGLE_ERROR_DEG < 0.6
    # Decoded directions stay in their hemisphere, above the rim.
    assert np.einsum("ni,ni->n", decoded, dir24.AXES[h]).min() >= dir24.MIN_AXIS_COSINE - FLOAT32_STORAGE


def test_axes_are_exact_and_degenerate_input_falls_back_to_the_axis():
    for k in range(6):
        axis = dir24.AXES[k][None]
        np.testing.assert_array_equal(dir24.decode_directions(dir24.encode_directions(axis, [k])), axis)
        for bad in ([0.0, 0, 0], [np.nan, np.nan, np.nan], [np.inf, -np.inf, np.nan]):  # no direction left
            np.testing.assert_array_equal(dir24.decode_directions(dir24.encode_directions(np.array([bad]), [k])),
                                          axis)
        partly = dir24.decode_directions(dir24.encode_directions(np.array([[np.nan, 1.0, 0.0]]), [k]))[0]
        assert np.isfinite(partly).all() and partly @ axis[0] >= dir24.MIN_AXIS_COSINE - FLOAT32_STORAGE
    # On the rim (perpendicular to the axis) the axis component is kept at one step, inside.
    rim = dir24.decode_directions(dir24.encode_directions(np.array([[0.0, 1.0, 0.0]]), [0]))[0]
    np.testing.assert_allclose(rim, np.array([1.0, 127.0, 0.0]) / np.hypot(1, 127), rtol=FLOAT32_STORAGE)
