"""BC1 (DXT1) encoder/decoders and the .dds writer, checked against OpenImageIO's DDS reader."""

import numpy as np
import pytest
from tolerances import BC1_LINE_RMS
from usdbake.processors.radiosity import dds
from usdbake.processors.radiosity import bc1

def test_constant_blocks_are_exact_when_representable():
    # 565-representable colours (r, b multiples of 255/31 rounded; g of 255/63) round-trip exactly.
    levels5 = np.rint(np.arange(32) * 255 / 31)
    levels6 = np.rint(np.arange(64) * 255 / 63)
    image = np.zeros((8, 8, 3), np.float32)
    image[:4, :4] = [levels5[3], levels6[40], levels5[31]]
    image[:4, 4:] = [levels5[0], levels6[0], levels5[0]]
    image[4:, :4] = [levels5[31], levels6[63], levels5[31]]
    image[4:, 4:] = [levels5[17], levels6[5], levels5[9]]
    decoded = bc1.decode_bc1(bc1.encode_bc1(image), 8, 8)
    np.testing.assert_array_equal(decoded, image.astype(np.uint8))


def test_two_colour_block_is_exact():
    a = np.array([np.rint(20 * 255 / 31), np.rint(50 * 255 / 63), np.rint(3 * 255 / 31)])
    b = np.array([np.rint(2 * 255 / 31), np.rint(9 * 255 / 63), np.rint(30 * 255 / 31)])
    image = np.where((np.arange(16).reshape(4, 4) % 3 == 0)[:, :, None], a, b).astype(np.float32)
    np.testing.assert_array_equal(bc1.decode_bc1(bc1.encode_bc1(image), 4, 4), image.astype(np.uint8))


def test_four_levels_on_a_line_round_trip_within_endpoint_rounding():
    rng = np.random.default_rng(1)  # fixed seed: random lines in RGB, texels at t in {0, 1/3, 2/3, 1}
    image = np.empty((64, 64, 3), np.float32)
    for by in range(16):
        for bx in range(16):
            start, end = rng.uniform(0, 255, 3), rng.uniform(0, 255, 3)
            t = rng.permutation(np.repeat([0.0, 1 / 3, 2 / 3, 1.0], 4)).reshape(4, 4, 1)
            image[4 * by:4 * by + 4, 4 * bx:4 * bx + 4] = start + t * (end - start)
    decoded = bc1.decode_bc1(bc1.encode_bc1(image), 64, 64).astype(np.float32)
    assert np.sqrt(np.mean((decoded - image) ** 2)) < BC1_LINE_RMS


def test_encoder_handles_nan_and_out_of_range():
    image = np.full((4, 8, 3), np.nan, np.float32)
    image[:, 4:] = 1e9
    decoded = bc1.decode_bc1(bc1.encode_bc1(image), 4, 8)
    assert (decoded[:, :4] == 0).all() and (decoded[:, 4:] == 255).all()


def test_dds_header_and_round_trip():
    rng = np.random.default_rng(2)  # fixed seed
    blocks = rng.integers(0, 256, (6, 8), dtype=np.uint8)
    data = dds.dds_bc1_bytes(blocks, 12, 8)
    assert data[:4] == b"DDS " and len(data) == 4 + 124 + blocks.nbytes
    assert data[84:88] == b"DXT1"
    read, width, height = dds.read_dds_bc1(data)
    assert (width, height) == (12, 8)
    np.testing.assert_array_equal(read, blocks)
    with pytest.raises(ValueError):
        dds.dds_bc1_bytes(blocks, 16, 8)


def test_openimageio_decodes_our_dds_like_our_decoder(tmp_path):
    oiio = pytest.importorskip("OpenImageIO")
    rng = np.random.default_rng(3)  # fixed seed: random smooth + noisy content
    base = np.linspace(0, 255, 32)[None, :, None] * np.array([1.0, 0.6, 0.3])
    image = np.clip(base + rng.normal(0, 20, (16, 32, 3)), 0, 255)
    blocks = bc1.encode_bc1(image)
    path = tmp_path / "matrix.dds"
    path.write_bytes(dds.dds_bc1_bytes(blocks, 32, 16))
    reader = oiio.ImageInput.open(str(path))
    assert reader is not None, oiio.geterror()
    spec = reader.spec()
    pixels = reader.read_image(oiio.UINT8)
    reader.close()
    assert (spec.width, spec.height) == (32, 16)
    np.testing.assert_array_equal(pixels[..., :3], bc1.decode_bc1(blocks, 16, 32))
