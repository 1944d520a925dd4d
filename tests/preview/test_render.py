"""preview/render.py: ``shade`` on hand-made Frames, pixel by pixel against closed forms: the headlight,
false colour (value k/255 of the range -> viridis entry k, grey without data, background), shaded channels
(albedo x value, irradiance / pi, exposure 2^EV, the automatic exposure's middle grey, tone curve written out),
the albedo view, spheres (headlit or per-pixel colours), the wire overlay, raw values, coverage and legend."""

from __future__ import annotations

import numpy as np
import pytest
from tolerances import FLOAT32_ROUNDING, FLOAT32_STORAGE

from usdbake.preview.color import BACKGROUND, MIDDLE_GREY, VIRIDIS, luminance, srgb_decode
from usdbake.preview.legend import legend_width
from usdbake.preview.raycast import Frame
from usdbake.preview.render import NO_DATA_GREY, WIRE_COLOR, WIRE_OPACITY, headlight, shade

H, W = 4, 6


def display_of(linear):
    """Narkowicz's ACES fit then the sRGB encoding, written out in float64."""
    x = np.maximum(np.asarray(linear, np.float64), 0.0)
    x = np.clip(x * (2.51 * x + 0.03) / (x * (2.43 * x + 0.59) + 0.14), 0.0, 1.0)
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * x ** (1 / 2.4) - 0.055)


def make_frame(hit_triangle, value=None, facing=None, wire=None, sphere=None, sphere_normal=None):
    """A Frame from per-pixel arrays; unset ones are zero (no wire, no sphere)."""
    hit_triangle = np.asarray(hit_triangle, np.int32)
    shape = hit_triangle.shape
    return Frame(
        hit_triangle=hit_triangle,
        hit_t=np.where(hit_triangle >= 0, 1.0, np.inf).astype(np.float32),
        value=np.zeros(shape + (3,), np.float32) if value is None else np.asarray(value, np.float32),
        facing=np.ones(shape, np.float32) if facing is None else np.asarray(facing, np.float32),
        wire=np.zeros(shape, bool) if wire is None else np.asarray(wire, bool),
        sphere=np.full(shape, -1, np.int32) if sphere is None else np.asarray(sphere, np.int32),
        sphere_normal=np.zeros(shape + (3,), np.float32) if sphere_normal is None else sphere_normal)


# Pixel layout shared by the tests: row 0 background, rows 1-3 triangles 0, 1, 2 (triangle 2 without data).
TRIANGLES = np.array([[-1] * W, [0] * W, [1] * W, [2] * W])
ALBEDO = np.array([[0.8, 0.8, 0.8], [0.2, 0.4, 0.6], [0.5, 0.5, 0.5]], np.float32)
HAS_VALUE = np.array([True, True, False])


def test_headlight_ranges_from_a_quarter_to_one():
    np.testing.assert_allclose(headlight(np.array([0.0, 0.5, 1.0])), [0.25, 0.625, 1.0])


def test_false_colour_maps_values_and_greys_out_surfaces_without_data():
    lo, hi = 10.0, 20.0
    k = np.arange(W) * 40  # viridis entries 0, 40, ..., 200
    value = np.zeros((H, W, 3), np.float32)
    value[1:, :, 0] = lo + k / 255.0 * (hi - lo)
    facing = np.full((H, W), 0.6, np.float32)
    image = shade(make_frame(TRIANGLES, value, facing), ALBEDO, tri_has_value=HAS_VALUE, channels=1,
                  style="falsecolor", value_range=(lo, hi), legend=False)
    display = image.display
    assert display.shape == (H, W, 3) and image.legend is None and image.exposure == 0.0
    np.testing.assert_array_equal(display[0], np.broadcast_to(BACKGROUND, (W, 3)))
    for row in (1, 2):
        np.testing.assert_array_equal(display[row], VIRIDIS[k])  # no shading on data
    np.testing.assert_allclose(display[3], NO_DATA_GREY * (0.25 + 0.75 * 0.6), rtol=FLOAT32_STORAGE)
    np.testing.assert_allclose(image.linear[1:], srgb_decode(display[1:]), rtol=FLOAT32_STORAGE)
    np.testing.assert_array_equal(image.linear[0], 0.0)
    np.testing.assert_array_equal(image.value[..., 0], np.where(HAS_VALUE[np.maximum(TRIANGLES, 0)]
                                                                & (TRIANGLES >= 0), value[..., 0], 0.0))
    np.testing.assert_array_equal(image.coverage, TRIANGLES >= 0)


def test_false_colour_legend_panel_is_appended():
    lo, hi = 0.0, 4.0
    image = shade(make_frame(TRIANGLES), ALBEDO, tri_has_value=HAS_VALUE, channels=1, style="falsecolor",
                  value_range=(lo, hi), label="ao")
    panel = legend_width(lo, hi, H)
    assert image.display.shape == (H, W + panel, 3) and image.view_width == W
    assert image.linear.shape == (H, W, 3) and image.value.shape == (H, W, 1)
    assert (image.legend.lo, image.legend.hi, image.legend.label) == (lo, hi, "ao")
    assert image.legend.bar_x[0] >= W  # drawn in the panel, to the right of the view
    reserved = shade(make_frame(TRIANGLES), ALBEDO, tri_has_value=HAS_VALUE, channels=1, style="falsecolor",
                     value_range=(lo, hi), legend_panel=panel + 7)
    assert reserved.display.shape[1] == W + panel + 7


@pytest.mark.parametrize("irradiance", [False, True])
def test_shaded_scalar_is_albedo_times_value_then_exposure_and_the_curve(irradiance):
    value = np.zeros((H, W, 3), np.float32)
    value[..., 0] = np.linspace(-0.5, 3.0, H * W).reshape(H, W)  # negatives clamp to no light
    facing = np.full((H, W), 0.2, np.float32)
    image = shade(make_frame(TRIANGLES, value, facing), ALBEDO, tri_has_value=HAS_VALUE, channels=1,
                  style="shaded", exposure=1.5, irradiance=irradiance)
    scale = 2.0 ** 1.5
    for row, tri in ((1, 0), (2, 1)):
        light = np.maximum(value[row, :, 0].astype(np.float64), 0) / (np.pi if irradiance else 1.0)
        expected = ALBEDO[tri][None, :] * light[:, None] * scale
        np.testing.assert_allclose(image.linear[row], expected, rtol=FLOAT32_STORAGE, atol=FLOAT32_ROUNDING)
        np.testing.assert_allclose(image.display[row], display_of(expected), atol=FLOAT32_STORAGE)
    # Without data: half the albedo under the headlight.
    no_data = ALBEDO[2].astype(np.float64) * (0.25 + 0.75 * 0.2) * 0.5 * scale
    np.testing.assert_allclose(image.linear[3], np.broadcast_to(no_data, (W, 3)), rtol=FLOAT32_STORAGE)
    np.testing.assert_array_equal(image.display[0], np.broadcast_to(BACKGROUND, (W, 3)))
    assert image.exposure == 1.5 and image.legend is None and image.display.shape == (H, W, 3)


def test_shaded_colour_lights_each_channel():
    value = np.zeros((H, W, 3), np.float32)
    value[1:] = [0.5, 1.0, 2.0]
    image = shade(make_frame(TRIANGLES, value), ALBEDO, tri_has_value=HAS_VALUE, channels=3, style="shaded",
                  exposure=0.0)
    np.testing.assert_allclose(image.linear[2], np.broadcast_to(ALBEDO[1] * [0.5, 1.0, 2.0], (W, 3)),
                               rtol=FLOAT32_STORAGE)
    np.testing.assert_array_equal(image.value[1:3], value[1:3])
    np.testing.assert_array_equal(image.value[3], 0.0)  # no data on triangle 2: no raw value


def test_automatic_exposure_puts_the_median_of_lit_pixels_at_middle_grey():
    value = np.zeros((H, W, 3), np.float32)
    value[1:, :, 0] = np.arange(3 * W).reshape(3, W) + 1.0
    image = shade(make_frame(TRIANGLES, value), ALBEDO, tri_has_value=HAS_VALUE, channels=1, style="shaded")
    lit = luminance(image.linear[1:3].reshape(-1, 3))  # the pixels with data decide; no-data ones do not
    assert float(np.median(lit)) == pytest.approx(MIDDLE_GREY, rel=FLOAT32_STORAGE)
    albedo_view = shade(make_frame(TRIANGLES), ALBEDO, tri_has_value=None, channels=1, style="albedo")
    assert float(np.median(luminance(albedo_view.linear[1:].reshape(-1, 3)))) == pytest.approx(
        MIDDLE_GREY, rel=FLOAT32_STORAGE)


def test_albedo_view_is_albedo_under_the_headlight():
    facing = np.tile(np.linspace(0, 1, W, dtype=np.float32), (H, 1))
    image = shade(make_frame(TRIANGLES, facing=facing), ALBEDO, tri_has_value=None, channels=1, style="albedo",
                  exposure=0.0)
    for row, tri in ((1, 0), (2, 1), (3, 2)):  # every surface, data or not
        expected = ALBEDO[tri][None, :].astype(np.float64) * (0.25 + 0.75 * facing[row])[:, None]
        np.testing.assert_allclose(image.linear[row], expected, rtol=FLOAT32_STORAGE)
    np.testing.assert_array_equal(image.value, 0.0)


def test_a_frame_of_nothing_is_background():
    image = shade(make_frame(np.full((H, W), -1)), np.zeros((0, 3), np.float32), tri_has_value=None, channels=1,
                  style="albedo")
    np.testing.assert_array_equal(image.display, np.broadcast_to(BACKGROUND, (H, W, 3)))
    assert not image.coverage.any() and image.exposure == 0.0


def test_headlit_spheres_cover_surfaces_and_carry_no_value():
    sphere = np.full((H, W), -1)
    sphere[1, :2], sphere[2, 4:] = 0, 1
    facing = np.full((H, W), 0.4, np.float32)
    colours = np.array([[1.0, 0.0, 0.0], [0.0, 0.5, 0.0]], np.float32)
    value = np.ones((H, W, 3), np.float32)
    image = shade(make_frame(TRIANGLES, value, facing, sphere=sphere), ALBEDO, tri_has_value=HAS_VALUE,
                  channels=1, style="shaded", exposure=-1.0, sphere_colors=colours)
    lit = 0.25 + 0.75 * 0.4
    np.testing.assert_allclose(image.linear[1, :2], np.broadcast_to(colours[0] * lit * 0.5, (2, 3)),
                               rtol=FLOAT32_STORAGE)
    np.testing.assert_allclose(image.linear[2, 4:], np.broadcast_to(colours[1] * lit * 0.5, (2, 3)),
                               rtol=FLOAT32_STORAGE)
    np.testing.assert_allclose(image.display[1, :2], display_of(image.linear[1, :2]), atol=FLOAT32_STORAGE)
    np.testing.assert_array_equal(image.value[sphere >= 0], 0.0)
    np.testing.assert_array_equal(image.value[1, 2:, 0], 1.0)  # the surface beside them keeps its value


def test_spheres_over_the_background_count_as_coverage_and_take_per_pixel_colours():
    sphere = np.full((H, W), -1)
    sphere[0, 1:3] = 0  # over the background row
    per_pixel = np.zeros((H, W, 3), np.float32)
    per_pixel[0, 1] = [0.3, 0.2, 0.1]
    per_pixel[0, 2] = [0.0, 0.0, 0.9]
    facing = np.full((H, W), 0.1, np.float32)  # a per-pixel colour ignores the headlight
    image = shade(make_frame(TRIANGLES, facing=facing, sphere=sphere), ALBEDO, tri_has_value=None, channels=1,
                  style="albedo", exposure=1.0, sphere_colors=per_pixel)
    np.testing.assert_allclose(image.linear[0, 1:3], per_pixel[0, 1:3] * 2.0, rtol=FLOAT32_STORAGE)
    np.testing.assert_array_equal(image.coverage[0], [0, 1, 1, 0, 0, 0])
    np.testing.assert_array_equal(image.display[0, 0], BACKGROUND)


def test_false_colour_spheres_use_no_exposure():
    sphere = np.full((H, W), -1)
    sphere[1, 0] = 0
    image = shade(make_frame(TRIANGLES, sphere=sphere), ALBEDO, tri_has_value=HAS_VALUE, channels=1,
                  style="falsecolor", value_range=(0.0, 1.0), legend=False, exposure=5.0,
                  sphere_colors=np.array([[0.5, 0.5, 0.5]], np.float32))
    np.testing.assert_allclose(image.linear[1, 0], [0.5, 0.5, 0.5], rtol=FLOAT32_STORAGE)  # facing 1: headlight 1


def test_wire_darkens_surface_pixels_but_not_spheres():
    wire = np.zeros((H, W), bool)
    wire[:, 3] = True  # a column across background, surfaces and a sphere
    sphere = np.full((H, W), -1)
    sphere[2, 3] = 0
    frame = make_frame(TRIANGLES, wire=wire, sphere=sphere)
    plain = shade(make_frame(TRIANGLES, sphere=sphere), ALBEDO, tri_has_value=None, channels=1, style="albedo",
                  exposure=0.0, sphere_colors=np.ones((1, 3), np.float32))
    wired = shade(frame, ALBEDO, tri_has_value=None, channels=1, style="albedo", exposure=0.0,
                  sphere_colors=np.ones((1, 3), np.float32))
    on = wire & (sphere < 0)
    np.testing.assert_allclose(wired.display[on], plain.display[on] * (1 - WIRE_OPACITY) + WIRE_COLOR * WIRE_OPACITY,
                               rtol=FLOAT32_STORAGE)
    np.testing.assert_array_equal(wired.display[~on], plain.display[~on])
    np.testing.assert_array_equal(wired.linear, plain.linear)  # the overlay is display-only


def test_display_is_clamped_float32():
    value = np.full((H, W, 3), 1e6, np.float32)
    image = shade(make_frame(TRIANGLES, value), ALBEDO, tri_has_value=HAS_VALUE, channels=1, style="shaded",
                  exposure=0.0)
    assert image.display.dtype == np.float32 and image.display.min() >= 0 and image.display.max() <= 1
    np.testing.assert_allclose(image.display[1:3], 1.0, atol=FLOAT32_ROUNDING)  # saturated white
