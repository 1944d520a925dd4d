"""preview/images.py: 8-bit rounding, the side-by-side comparison (RMS against a hand-computed value, the
difference panel's gain and clamp), PNG and EXR files read back with OpenImageIO (pixels, channel names,
alpha), reading references (grey, RGBA, float, missing or unreadable files) and the --compare panel."""

from __future__ import annotations

import re

import numpy as np
import OpenImageIO as oiio
import pytest
from stage_builders import write_png
from tolerances import FLOAT32_ROUNDING, FLOAT32_STORAGE

from usdbake.core.errors import UsageError
from usdbake.preview.images import DIFF_GAIN, compare_images, compare_with, read_display_image, to_uint8, \
    write_image
from usdbake.preview.render import Image


def make_image(height=6, width=8, components=1, seed=0):
    """An Image of random display / linear colour and values (no legend)."""
    rng = np.random.default_rng(seed)  # fixed seed: the pixel values
    display = rng.uniform(0, 1, (height, width, 3)).astype(np.float32)
    return Image(display=display, linear=rng.uniform(0, 4, (height, width, 3)).astype(np.float32),
                 value=rng.normal(size=(height, width, components)).astype(np.float32),
                 coverage=(rng.uniform(size=(height, width)) > 0.3).astype(np.float32), view_width=width,
                 exposure=0.5)


def test_to_uint8_rounds_to_nearest_and_clamps():
    k = np.arange(256)
    np.testing.assert_array_equal(to_uint8(k / 255.0), k)
    np.testing.assert_array_equal(to_uint8((k + 0.49) / 255.0)[:255], k[:255])  # just below the half-way point
    np.testing.assert_array_equal(to_uint8([-1.0, -0.0, 1.0, 2.0, 1e30]), [0, 0, 255, 255, 255])
    assert to_uint8(np.zeros((2, 3, 3))).dtype == np.uint8


def test_compare_images_rms_and_panel():
    a = np.zeros((4, 5, 3), np.float32)
    b = a.copy()
    b[0, 0] = [0.3, 0.0, 0.0]    # one channel of one pixel off by 0.3
    b[1, 1] = [0.01, 0.01, 0.01]
    panel, rms = compare_images(a, b)
    assert rms == pytest.approx(np.sqrt((0.3 ** 2 + 3 * 0.01 ** 2) / (4 * 5 * 3)), rel=FLOAT32_STORAGE)
    assert panel.shape == (4, 15, 3) and panel.dtype == np.float32
    np.testing.assert_array_equal(panel[:, :5], a)
    np.testing.assert_array_equal(panel[:, 5:10], b)
    np.testing.assert_allclose(panel[0, 10], [1.0, 0.0, 0.0])  # 0.3 x 4 clamps to 1
    np.testing.assert_allclose(panel[1, 11], [0.01 * DIFF_GAIN] * 3, rtol=FLOAT32_STORAGE)
    assert panel[:, 10:].sum() == pytest.approx(1.0 + 3 * 0.01 * DIFF_GAIN, rel=FLOAT32_STORAGE)


def test_compare_images_identical_alpha_and_size():
    image = make_image().display
    with_alpha = np.concatenate([image, np.zeros(image.shape[:2] + (1,), np.float32)], axis=2)
    panel, rms = compare_images(with_alpha, image)  # a fourth channel is left out
    assert rms == 0.0 and not panel[:, 16:].any()
    assert compare_images(np.zeros((0, 0, 3)), np.zeros((0, 0, 3)))[1] == 0.0
    with pytest.raises(ValueError, match="images differ in size: 8 x 6 vs 7 x 6"):
        compare_images(image, image[:, :7])


def read_back(path):
    buffer = oiio.ImageBuf(str(path))
    assert not buffer.has_error, buffer.geterror()
    return buffer.spec(), buffer.get_pixels(oiio.FLOAT if buffer.spec().format == oiio.FLOAT else oiio.UINT8)


@pytest.mark.parametrize("suffix", [".png", ".tif", ".PNG"])
def test_8_bit_files_hold_the_rounded_display(tmp_path, suffix):
    image = make_image()
    path = tmp_path / "deep" / "folder" / f"out{suffix}"  # missing folders are made
    assert write_image(str(path), image) == str(path)
    spec, pixels = read_back(path)
    assert (spec.width, spec.height, spec.nchannels, spec.format) == (8, 6, 3, oiio.UINT8)
    np.testing.assert_array_equal(pixels, np.clip(np.rint(image.display.astype(np.float64) * 255), 0, 255))


def test_exr_holds_linear_coverage_and_the_scalar_value(tmp_path):
    image = make_image()
    path = tmp_path / "out.exr"
    write_image(str(path), image, "irradiance+ao")
    spec, pixels = read_back(path)
    assert list(spec.channelnames) == ["R", "G", "B", "A", "irradiance_ao"]
    assert spec.alpha_channel == 3 and spec.format == oiio.FLOAT
    np.testing.assert_array_equal(pixels[..., :3], image.linear)
    np.testing.assert_array_equal(pixels[..., 3], image.coverage)
    np.testing.assert_array_equal(pixels[..., 4], image.value[..., 0])


def test_exr_names_colour_values_per_channel(tmp_path):
    image = make_image(components=3)
    path = tmp_path / "colour.exr"
    write_image(str(path), image, "primvars:bake:tint")
    spec, pixels = read_back(path)
    assert list(spec.channelnames) == ["R", "G", "B", "A", "primvars_bake_tint.R", "primvars_bake_tint.G",
                                       "primvars_bake_tint.B"]
    np.testing.assert_array_equal(pixels[..., 4:], image.value)
    write_image(str(tmp_path / "unnamed.exr"), make_image(), "")
    assert list(read_back(tmp_path / "unnamed.exr")[0].channelnames)[4] == "value"


@pytest.mark.parametrize("name, shown", [("out.bmp2", ".bmp2"), ("out", "(none)"), ("out.usda", ".usda")])
def test_unsupported_types_are_refused(tmp_path, name, shown):
    with pytest.raises(UsageError, match=re.escape(f"unsupported image type {shown}; use .png or .exr")):
        write_image(str(tmp_path / name), make_image())


def test_a_path_oiio_cannot_write_is_a_usage_error(tmp_path):
    (tmp_path / "folder.png").mkdir()
    with pytest.raises(UsageError, match="OpenImageIO cannot write it"):
        write_image(str(tmp_path / "folder.png"), make_image())


def test_a_file_in_place_of_the_folder_is_a_usage_error(tmp_path):
    (tmp_path / "file").write_text("not a folder")
    with pytest.raises(UsageError):
        write_image(str(tmp_path / "file" / "out.png"), make_image())


def test_reading_a_reference_gives_exact_8_bit_steps(tmp_path):
    pixels = np.arange(4 * 5 * 3, dtype=np.uint8).reshape(4, 5, 3) * 4
    read = read_display_image(write_png(tmp_path / "ref.png", pixels))
    assert read.dtype == np.float32 and read.shape == (4, 5, 3)
    np.testing.assert_array_equal(read, pixels.astype(np.float32) / np.float32(255.0))


def test_grey_and_rgba_references_become_rgb(tmp_path):
    grey = np.array([[[0], [128]], [[255], [3]]], np.uint8)
    read = read_display_image(write_png(tmp_path / "grey.png", grey))
    np.testing.assert_array_equal(read, np.repeat(grey, 3, axis=2) / np.float32(255.0))
    rgba = np.zeros((2, 2, 4), np.uint8)
    rgba[..., 0], rgba[..., 2], rgba[..., 3] = 200, 7, 255  # opaque: the colour is kept, alpha dropped
    read = read_display_image(write_png(tmp_path / "rgba.png", rgba))
    np.testing.assert_array_equal(read, rgba[..., :3].astype(np.float32) / np.float32(255))


def test_a_float_reference_is_read_as_floats(tmp_path):
    image = make_image()
    path = str(tmp_path / "ref.exr")
    write_image(path, image)
    np.testing.assert_array_equal(read_display_image(path), image.linear)  # the EXR's R, G, B


def test_missing_and_unreadable_references_are_usage_errors(tmp_path):
    with pytest.raises(UsageError, match="no such file"):
        read_display_image(str(tmp_path / "missing.png"))
    junk = tmp_path / "junk.png"
    junk.write_bytes(b"this is not a PNG")
    with pytest.raises(UsageError, match="cannot be read"):
        read_display_image(str(junk))


def test_compare_with_measures_the_8_bit_output(tmp_path):
    image = make_image(height=5, width=7)
    reference = to_uint8(image.display).astype(np.int64)
    reference[2, 3, 1] += 51 if reference[2, 3, 1] <= 204 else -51  # one channel differs by 51 / 255 = 0.2
    path = write_png(tmp_path / "ref.png", reference.astype(np.uint8))
    panel_image, rms = compare_with(path, image)
    assert rms == pytest.approx(np.sqrt(0.2 ** 2 / (5 * 7 * 3)), rel=FLOAT32_STORAGE)
    assert panel_image.display.shape == (5, 21, 3) and panel_image.view_width == 21
    np.testing.assert_array_equal(panel_image.display[:, :7], reference.astype(np.float32) / np.float32(255.0))
    np.testing.assert_array_equal(panel_image.display[:, 7:14], to_uint8(image.display) / np.float32(255.0))
    np.testing.assert_allclose(panel_image.display[2, 14 + 3], [0.0, 0.2 * DIFF_GAIN, 0.0], atol=FLOAT32_ROUNDING)
    assert panel_image.exposure == image.exposure and panel_image.legend is None
    assert (panel_image.coverage == 1).all() and not panel_image.value.any()
    with pytest.raises(UsageError, match="--compare .*differ in size"):
        compare_with(path, make_image(height=5, width=6))
