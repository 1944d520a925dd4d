"""A minimal DirectDraw Surface (.dds) writer and reader for BC1 (DXT1) textures.

OpenImageIO reads DDS but does not write block-compressed data, so usdbake
writes the file itself: the 4-byte magic ``"DDS "``, the standard 124-byte
``DDS_HEADER`` (with its 32-byte ``DDS_PIXELFORMAT``, FourCC ``DXT1``), then the
blocks, block rows top to bottom. One mip level, no DX10 extension header.

Reference: Microsoft, "DDS_HEADER structure" and "DDS_PIXELFORMAT structure".
"""

from __future__ import annotations

import struct

import numpy as np

MAGIC = b"DDS "
DDSD_CAPS, DDSD_HEIGHT, DDSD_WIDTH, DDSD_PIXELFORMAT, DDSD_MIPMAPCOUNT, DDSD_LINEARSIZE = (
    0x1, 0x2, 0x4, 0x1000, 0x20000, 0x80000)
DDPF_FOURCC = 0x4
DDSCAPS_TEXTURE = 0x1000
HEADER_SIZE = 124
PIXELFORMAT_SIZE = 32


def dds_bc1_bytes(blocks: np.ndarray, width: int, height: int) -> bytes:
    """A complete .dds file holding one BC1 image of ``width`` x ``height`` texels.

    Parameters
    ----------
    blocks : (ceil(H/4) * ceil(W/4), 8) uint8, block rows top to bottom.
    """
    blocks = np.ascontiguousarray(blocks, np.uint8)
    expected = ((width + 3) // 4) * ((height + 3) // 4)
    if blocks.shape != (expected, 8):
        raise ValueError(f"{width}x{height} BC1 needs ({expected}, 8) blocks, got {blocks.shape}")
    flags = DDSD_CAPS | DDSD_HEIGHT | DDSD_WIDTH | DDSD_PIXELFORMAT | DDSD_MIPMAPCOUNT | DDSD_LINEARSIZE
    pixel_format = struct.pack("<II4sIIIII", PIXELFORMAT_SIZE, DDPF_FOURCC, b"DXT1", 0, 0, 0, 0, 0)
    header = struct.pack("<IIIIIII", HEADER_SIZE, flags, height, width, blocks.nbytes, 0, 1)
    header += b"\0" * 44 + pixel_format + struct.pack("<IIIII", DDSCAPS_TEXTURE, 0, 0, 0, 0)
    assert len(header) == HEADER_SIZE
    return MAGIC + header + blocks.tobytes()


def read_dds_bc1(data: bytes) -> tuple[np.ndarray, int, int]:
    """Parse a .dds written by dds_bc1_bytes (or any plain DXT1 file): (blocks, width, height)."""
    if data[:4] != MAGIC:
        raise ValueError("not a DDS file (bad magic)")
    size, _flags, height, width = struct.unpack_from("<IIII", data, 4)
    if size != HEADER_SIZE:
        raise ValueError(f"DDS header size {size} != {HEADER_SIZE}")
    four_cc = struct.unpack_from("<4s", data, 4 + 72 + 8)[0]
    if four_cc != b"DXT1":
        raise ValueError(f"DDS pixel format {four_cc!r} is not DXT1")
    count = ((width + 3) // 4) * ((height + 3) // 4)
    offset = 4 + HEADER_SIZE
    blocks = np.frombuffer(data, np.uint8, count * 8, offset).reshape(count, 8).copy()
    return blocks, width, height
