"""The .dds writer and reader: header fields at the byte offsets Microsoft's DDS_HEADER documents."""

import struct

import numpy as np
import pytest
from usdbake.processors.radiosity.dds import dds_bc1_bytes, read_dds_bc1


def blocks_for(width: int, height: int) -> np.ndarray:
    count = ((width + 3) // 4) * ((height + 3) // 4)
    return np.arange(count * 8, dtype=np.uint64).astype(np.uint8).reshape(count, 8)


def test_header_fields_sit_at_the_documented_offsets():
    width, height = 10, 6  # 3 x 2 blocks of 8 bytes
    blocks = blocks_for(width, height)
    data = dds_bc1_bytes(blocks, width, height)
    assert len(data) == 4 + 124 + 6 * 8
    assert data[:4] == b"DDS "
    # DDS_HEADER: dwSize, dwFlags, dwHeight, dwWidth, dwPitchOrLinearSize, dwDepth, dwMipMapCount.
    size, flags, h, w, linear_size, _depth, mips = struct.unpack_from("<7I", data, 4)
    assert (size, h, w, linear_size, mips) == (124, height, width, 48, 1)
    assert flags == 0x1 | 0x2 | 0x4 | 0x1000 | 0x20000 | 0x80000  # CAPS HEIGHT WIDTH PIXELFORMAT MIPMAPCOUNT LINEARSIZE
    # DDS_PIXELFORMAT at byte 4 + 72: dwSize 32, dwFlags DDPF_FOURCC, dwFourCC "DXT1".
    pf_size, pf_flags, four_cc = struct.unpack_from("<II4s", data, 4 + 72)
    assert (pf_size, pf_flags, four_cc) == (32, 0x4, b"DXT1")
    assert struct.unpack_from("<I", data, 4 + 104)[0] == 0x1000  # dwCaps: DDSCAPS_TEXTURE
    assert data[128:] == blocks.tobytes()


@pytest.mark.parametrize("width, height", [(4, 4), (5, 3), (17, 9), (1, 1)])
def test_read_returns_what_was_written(width, height):
    blocks = blocks_for(width, height)
    read, w, h = read_dds_bc1(dds_bc1_bytes(blocks, width, height))
    assert (w, h) == (width, height)
    np.testing.assert_array_equal(read, blocks)


def test_a_wrong_block_count_is_refused():
    with pytest.raises(ValueError, match=r"needs \(4, 8\) blocks"):
        dds_bc1_bytes(blocks_for(4, 4), 8, 8)


@pytest.mark.parametrize("offset, replacement, message", [
    (0, b"PNG ", "bad magic"),
    (4, struct.pack("<I", 123), "header size 123"),
    (84, b"DXT5", "is not DXT1"),
])
def test_files_that_are_not_plain_dxt1_are_refused(offset, replacement, message):
    data = bytearray(dds_bc1_bytes(blocks_for(4, 4), 4, 4))
    data[offset:offset + 4] = replacement
    with pytest.raises(ValueError, match=message):
        read_dds_bc1(bytes(data))
