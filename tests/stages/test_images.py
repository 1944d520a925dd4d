"""stages.images: the sRGB table against the IEC 61966-2-1 transfer function, RgbRows' strips (scanline and
tiled files, grey and RGBA, float32, many strips when STRIP_BYTES is small) against the whole image read
plainly, image_mean against numpy's mean, and the errors of files OpenImageIO cannot read."""

import numpy as np
import OpenImageIO as oiio
import pytest

from stage_builders import write_png
from tolerances import FLOAT32_ROUNDING, FLOAT32_STORAGE, FLOAT64_ROUNDING
from usdbake.stages import images
from usdbake.stages.images import RgbRows, image_mean, srgb_table

RNG_SEED = 12  # fixed: the same texels on every run


def srgb_to_linear(value: np.ndarray) -> np.ndarray:
    """IEC 61966-2-1's decoding of sRGB values in [0, 1], written out."""
    value = np.asarray(value, np.float64)
    return np.where(value <= 0.04045, value / 12.92, ((value + 0.055) / 1.055) ** 2.4)


def random_codes(height: int, width: int, channels: int) -> np.ndarray:
    return np.random.default_rng(RNG_SEED).integers(0, 256, (height, width, channels), dtype=np.uint8)


def write_float(path, pixels: np.ndarray, *, tile: int = 0) -> str:
    """An (H, W, C) float32 image file (EXR or TIFF), tiled in ``tile`` x ``tile`` tiles when ``tile``."""
    height, width, channels = pixels.shape
    spec = oiio.ImageSpec(width, height, channels, oiio.FLOAT)
    if tile:
        spec.tile_width = spec.tile_height = tile
    out = oiio.ImageOutput.create(str(path))
    assert out is not None and out.open(str(path), spec), oiio.geterror()
    assert out.write_image(np.ascontiguousarray(pixels, np.float32)), out.geterror()
    out.close()
    return str(path)


def read_all(path: str, **kwargs) -> tuple[list[int], np.ndarray]:
    """(first row of each strip, the strips stacked)."""
    with RgbRows(path, **kwargs) as image:
        strips = list(image)
    return [first for first, _ in strips], np.concatenate([rows for _, rows in strips])


# --- the sRGB table ---------------------------------------------------------------------------


def test_the_srgb_table_is_the_transfer_function_of_each_code():
    table = srgb_table()
    assert table.shape == (256,) and table.dtype == np.float64
    # OpenImageIO's float of code c is c / 255 in float32: one float32 rounding, then the curve (slope <= 2.4)
    np.testing.assert_allclose(table, srgb_to_linear(np.arange(256) / 255.0), rtol=FLOAT32_STORAGE, atol=0)
    assert table[0] == 0.0 and table[255] == pytest.approx(1.0, abs=FLOAT64_ROUNDING)
    assert (np.diff(table) > 0).all()
    assert table[10] == pytest.approx(10 / 255 / 12.92, rel=FLOAT32_STORAGE)  # the linear toe (10/255 < 0.04045)


# --- strips -----------------------------------------------------------------------------------


@pytest.mark.parametrize("srgb", [True, False], ids=["srgb", "raw"])
def test_an_8_bit_rgb_png_is_read_as_the_table_or_the_plain_codes(tmp_path, srgb):
    codes = random_codes(9, 7, 3)
    path = write_png(tmp_path / "rgb.png", codes)
    with RgbRows(path, srgb=srgb) as image:
        assert (image.height, image.width) == (9, 7)
        assert image.exact_codes is srgb
    firsts, rows = read_all(path, srgb=srgb)
    assert firsts == [0] and rows.shape == (9, 7, 3) and rows.dtype == np.float64
    expected = srgb_table()[codes] if srgb else codes / 255.0
    np.testing.assert_allclose(rows, expected, rtol=FLOAT32_ROUNDING, atol=0)


def write_straight_png(path, pixels: np.ndarray) -> str:
    """An (H, W, C) uint8 PNG stored as given: alpha, if any, unassociated (straight), as PNG defines it and as
    painting programs write it (OpenImageIO's writer would otherwise divide the colour by alpha first)."""
    height, width, channels = pixels.shape
    spec = oiio.ImageSpec(width, height, channels, oiio.UINT8)
    spec.attribute("oiio:UnassociatedAlpha", 1)
    out = oiio.ImageOutput.create(str(path))
    assert out is not None and out.open(str(path), spec), oiio.geterror()
    assert out.write_image(np.ascontiguousarray(pixels, np.uint8)), out.geterror()
    out.close()
    return str(path)


def test_grey_is_repeated_into_rgb(tmp_path):
    codes = random_codes(5, 6, 1)
    _, rows = read_all(write_straight_png(tmp_path / "grey.png", codes), srgb=True)
    np.testing.assert_array_equal(rows, np.repeat(srgb_table()[codes], 3, axis=2))  # the same table entries


@pytest.mark.parametrize("channels", [2, 4], ids=["grey-alpha", "rgba"])
def test_alpha_is_dropped_and_leaves_the_colour_as_stored(tmp_path, channels):
    codes = random_codes(5, 6, channels)
    codes[..., -1] = 128  # half-transparent everywhere
    _, rows = read_all(write_straight_png(tmp_path / "alpha.png", codes), srgb=True)
    colour = codes[..., :1].repeat(3, axis=2) if channels == 2 else codes[..., :3]
    np.testing.assert_array_equal(rows, srgb_table()[colour])


def test_float32_rows_are_the_float64_values_rounded(tmp_path):
    path = write_png(tmp_path / "rgb.png", random_codes(8, 8, 3))
    _, wide = read_all(path, srgb=True)
    _, narrow = read_all(path, srgb=True, dtype=np.float32)
    assert narrow.dtype == np.float32
    np.testing.assert_array_equal(narrow, wide.astype(np.float32))


def test_a_small_strip_budget_reads_many_strips_that_make_the_whole_image(tmp_path, monkeypatch):
    codes = random_codes(23, 10, 3)
    path = write_png(tmp_path / "rgb.png", codes)
    monkeypatch.setattr(images, "STRIP_BYTES", 10 * 3 * 8 * 4)  # four rows of 10 texels per strip
    firsts, rows = read_all(path, srgb=True)
    assert firsts == [0, 4, 8, 12, 16, 20]  # the last strip holds the 3 rows left
    np.testing.assert_array_equal(rows, srgb_table()[codes])


def test_a_budget_below_one_row_still_reads_one_row_at_a_time(tmp_path, monkeypatch):
    codes = random_codes(3, 50, 3)
    path = write_png(tmp_path / "rgb.png", codes)
    monkeypatch.setattr(images, "STRIP_BYTES", 1)
    firsts, rows = read_all(path, srgb=False)
    assert firsts == [0, 1, 2]
    np.testing.assert_allclose(rows, codes / 255.0, rtol=FLOAT32_ROUNDING, atol=0)


@pytest.mark.parametrize("suffix", [".exr", ".tif"])
def test_a_tiled_file_is_read_by_rows_of_tiles_and_float_data_is_never_linearized(tmp_path, monkeypatch, suffix):
    pixels = np.random.default_rng(RNG_SEED).random((37, 40, 3)).astype(np.float32)
    path = write_float(tmp_path / f"tiled{suffix}", pixels, tile=16)
    monkeypatch.setattr(images, "STRIP_BYTES", 40 * 3 * 8 * 20)  # 20 rows: rounded down to one row of tiles
    with RgbRows(path, srgb=True) as image:
        assert image.exact_codes is False  # float texels: srgb applies to 8-bit data only
    firsts, rows = read_all(path, srgb=True)
    assert firsts == [0, 16, 32]  # strips start at tile rows; the last is 5 rows of a partial tile row
    np.testing.assert_array_equal(rows, pixels.astype(np.float64))


def test_a_scanline_float_file_reads_back_its_values(tmp_path):
    pixels = np.random.default_rng(RNG_SEED).random((6, 5, 3)).astype(np.float32) * 100.0  # HDR: above 1
    path = write_float(tmp_path / "sky.exr", pixels)
    _, rows = read_all(path, srgb=False)
    np.testing.assert_array_equal(rows, pixels.astype(np.float64))


# --- image_mean -------------------------------------------------------------------------------


@pytest.mark.parametrize("strip_bytes", [images.STRIP_BYTES, 10 * 3 * 8 * 3], ids=["one-strip", "many-strips"])
def test_image_mean_is_the_mean_of_the_linear_texels(tmp_path, monkeypatch, strip_bytes):
    codes = random_codes(31, 10, 3)
    path = write_png(tmp_path / "rgb.png", codes)
    monkeypatch.setattr(images, "STRIP_BYTES", strip_bytes)
    mean = image_mean(path, srgb=True)
    assert mean.shape == (3,)
    np.testing.assert_allclose(mean, srgb_table()[codes].reshape(-1, 3).mean(axis=0), rtol=FLOAT64_ROUNDING)
    np.testing.assert_allclose(image_mean(path, srgb=False), codes.reshape(-1, 3).mean(axis=0) / 255.0,
                               rtol=FLOAT32_ROUNDING)


# --- files that cannot be read ----------------------------------------------------------------


def test_a_missing_or_unreadable_file_is_a_value_error_with_openimageios_reason(tmp_path):
    garbage = tmp_path / "garbage.png"
    garbage.write_bytes(b"\x89PNG\r\n\x1a\n but nothing after the signature")
    for path in (tmp_path / "missing.png", garbage):
        with pytest.raises(ValueError) as raised:
            RgbRows(str(path), srgb=True)
        assert str(raised.value).strip() and "\n" not in str(raised.value)
        with pytest.raises(ValueError):
            image_mean(str(path), srgb=True)


def test_close_is_safe_twice_and_the_context_closes(tmp_path):
    path = write_png(tmp_path / "rgb.png", random_codes(2, 2, 3))
    with RgbRows(path, srgb=True) as image:
        pass
    assert image._image is None
    image.close()  # again: nothing to do
