"""Texture files read strip by strip through OpenImageIO, so memory never holds a whole large image.

A dome texture (``stages.sky_dome.read_latlong``) and a material texture's mean colour
(``stages.materials``) read their files through ``RgbRows``: a strip of rows at a time as float64
linear RGB, about ``STRIP_BYTES`` whatever the file's size. A 285 KB PNG of 10000 x 10000 texels, read
whole as float64 and linearized, cost 10 GB and 40 s; read in strips, 40 MB and 2.4 s (CPU).
"""

from __future__ import annotations

import numpy as np

STRIP_BYTES = 1 << 24
"""Bytes of one strip of rows at 8 bytes a sample (16 MB): the rows a reader holds at once. With the
temporaries of linearizing and reducing a strip, a reader's numpy memory peaks at about 3 strips,
whatever the file's size (measured 42 MB on a 4000 x 4000 PNG)."""


class RgbRows:
    """An image file's rows as (first row, (r, W, 3) linear RGB of ``dtype``) strips, in order.

    8-bit data is linearized from sRGB when ``srgb`` (a 256-entry table of the transfer function applied
    to OpenImageIO's own float conversion of each code: the values a whole-image float read gave), grey
    is repeated into RGB and channels past the third are dropped. Scanline files are read with
    ``read_scanlines``, tiled ones by rows of tiles (``read_scanlines`` refuses tiled files). Raises
    ValueError with OpenImageIO's reason when the file cannot be opened or a strip cannot be read.
    ``dtype`` float32 halves the memory traffic of a large file (the values are the float64 ones,
    rounded); ``exact_codes`` says the data came through the 8-bit table (finite by construction).
    """

    def __init__(self, path: str, *, srgb: bool, dtype=np.float64):
        import OpenImageIO as oiio

        # The colour as stored: OpenImageIO would otherwise multiply it by alpha on read (its default for
        # PNG), darkening a cut-out texture's albedo; alpha itself is not read.
        config = oiio.ImageSpec()
        config.attribute("oiio:UnassociatedAlpha", 1)
        self._image = oiio.ImageInput.open(path, config)
        if self._image is None:
            raise ValueError(" ".join(oiio.geterror().split()) or "OpenImageIO cannot read it")
        spec = self._image.spec()
        self.height, self.width, self._channels = spec.height, spec.width, min(spec.nchannels, 3)
        if self.height < 1 or self.width < 1 or self._channels < 1:
            self.close()
            raise ValueError(f"an image of {spec.width} x {spec.height} texels and {spec.nchannels} channels")
        self._table = srgb_table().astype(dtype) if srgb and spec.format == oiio.UINT8 else None
        self.exact_codes = self._table is not None
        self._dtype = dtype
        self._fetch = oiio.UINT8 if self._table is not None else oiio.FLOAT
        self._tiled = spec.tile_width > 0
        step = max(1, STRIP_BYTES // (self.width * 3 * 8))  # 8: the table lookup's index (intp) per sample
        self._step = max(1, step // spec.tile_height) * spec.tile_height if self._tiled else step

    def __iter__(self):
        for first in range(0, self.height, self._step):
            last = min(first + self._step, self.height)
            if self._tiled:
                pixels = self._image.read_tiles(0, 0, 0, self.width, first, last, 0, 1, 0, self._channels,
                                                self._fetch)
            else:
                pixels = self._image.read_scanlines(0, 0, first, last, 0, 0, self._channels, self._fetch)
            if pixels is None:
                reason = " ".join(self._image.geterror().split())
                raise ValueError(reason or f"rows {first} to {last - 1} cannot be read")
            pixels = np.asarray(pixels).reshape(last - first, self.width, self._channels)
            rows = self._table[pixels] if self._table is not None else pixels.astype(self._dtype, copy=False)
            yield first, (np.repeat(rows[..., :1], 3, axis=2) if self._channels < 3 else rows)

    def close(self) -> None:
        if self._image is not None:
            self._image.close()
            self._image = None

    def __enter__(self) -> "RgbRows":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def srgb_table() -> np.ndarray:
    """(256,) float64 linear values of the 8-bit sRGB codes, from OpenImageIO's float value of each code."""
    import OpenImageIO as oiio

    codes = oiio.ImageBuf(np.arange(256, dtype=np.uint8).reshape(1, 256, 1))
    value = np.asarray(codes.get_pixels(oiio.FLOAT), np.float64).ravel()
    return np.where(value <= 0.04045, value / 12.92, ((value + 0.055) / 1.055) ** 2.4)


def image_mean(path: str, *, srgb: bool) -> np.ndarray:
    """(3,) float64 mean linear RGB of an image file, read strip by strip. Raises ValueError as RgbRows."""
    total, count = np.zeros(3, np.float64), 0
    with RgbRows(path, srgb=srgb) as image:
        for _, rows in image:
            flat = rows.reshape(-1, 3)
            if len(flat) == image.height * image.width:
                return flat.mean(axis=0)  # one strip: numpy's mean of the whole image, as a whole read gave
            total += flat.sum(axis=0)
            count += len(flat)
    return total / count
