"""Preview images on disk: PNG / EXR writing, reading a reference, and the side-by-side comparison."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from ..core.errors import UsageError
from .color import srgb_decode
from .render import Image

DIFF_GAIN = 4.0
"""The difference panel of ``compare_images`` shows |A - B| * 4: an 8-bit step of 1/255 stays invisible,
a 0.05 difference reads as 20% grey."""


def to_uint8(display: np.ndarray) -> np.ndarray:
    """Display colour in [0, 1] -> uint8 with rounding."""
    return np.clip(np.rint(np.asarray(display, np.float64) * 255.0), 0, 255).astype(np.uint8)


def compare_images(reference: np.ndarray, image: np.ndarray) -> tuple[np.ndarray, float]:
    """Side-by-side [reference | image | difference] and the RMS difference.

    Both (H, W, 3) display colour in [0, 1] (use the 8-bit values / 255 of what was written).
    RMS = sqrt(mean over pixels and channels of (a - b)^2), in display units [0, 1].
    The difference panel shows |a - b| * DIFF_GAIN, clamped.
    """
    a = np.asarray(reference, np.float32)[..., :3]
    b = np.asarray(image, np.float32)[..., :3]
    if a.shape != b.shape:
        raise ValueError(f"images differ in size: {a.shape[1]} x {a.shape[0]} vs {b.shape[1]} x {b.shape[0]}")
    diff = a.astype(np.float64) - b
    rms = float(np.sqrt(np.mean(diff * diff))) if diff.size else 0.0
    panel = np.clip(np.abs(diff) * DIFF_GAIN, 0, 1).astype(np.float32)
    return np.concatenate([a, b, panel], axis=1), rms

def write_image(path: str, image: Image, value_name: str = "value") -> str:
    """PNG (8-bit display colour) or EXR (float32: R, G, B linear view, A coverage, then the raw value)."""
    import OpenImageIO as oiio

    suffix = Path(path).suffix.lower()
    try:
        Path(path).parent.mkdir(parents=True, exist_ok=True)
    except (FileExistsError, NotADirectoryError):
        raise UsageError(f"{path}: a parent of the output is a file, not a folder") from None
    if suffix == ".exr":
        view = image.linear
        channels = [view[..., 0], view[..., 1], view[..., 2], image.coverage]
        names = ["R", "G", "B", "A"]
        components = image.value.shape[2]
        label = re.sub(r"[^A-Za-z0-9_]", "_", value_name) or "value"
        for c in range(components):
            channels.append(image.value[..., c])
            names.append(f"{label}.{'RGB'[c]}" if components == 3 else label)
        pixels = np.ascontiguousarray(np.stack(channels, axis=2), np.float32)
        spec = oiio.ImageSpec(pixels.shape[1], pixels.shape[0], pixels.shape[2], oiio.FLOAT)
        spec.channelnames = tuple(names)
        spec.alpha_channel = 3
        spec.attribute("compression", "zip")
    elif suffix in (".png", ".jpg", ".jpeg", ".tif", ".tiff"):
        pixels = to_uint8(image.display)
        spec = oiio.ImageSpec(pixels.shape[1], pixels.shape[0], 3, oiio.UINT8)
    else:
        raise UsageError(f"{path}: unsupported image type {suffix or '(none)'}; use .png or .exr")
    output = oiio.ImageOutput.create(path)
    if output is None or not output.open(path, spec):
        raise UsageError(f"{path}: OpenImageIO cannot write it ({oiio.geterror()})")
    output.write_image(pixels)
    output.close()
    return path


def read_display_image(path: str) -> np.ndarray:
    """(H, W, 3) float32 display colour in [0, 1] of a PNG (or any 8-bit image OpenImageIO reads)."""
    import OpenImageIO as oiio

    if not Path(path).exists():
        raise UsageError(f"--compare {path}: no such file")
    buffer = oiio.ImageBuf(path)
    if buffer.has_error:
        raise UsageError(f"--compare {path}: cannot be read ({buffer.geterror()})")
    if buffer.spec().format == oiio.UINT8:  # exactly k / 255, as our own 8-bit output is compared
        pixels = np.asarray(buffer.get_pixels(oiio.UINT8), np.float32) / np.float32(255.0)
    else:
        pixels = np.asarray(buffer.get_pixels(oiio.FLOAT), np.float32)
    if pixels.ndim == 2:
        pixels = pixels[:, :, None]
    if pixels.shape[2] == 1:
        pixels = np.repeat(pixels, 3, axis=2)
    return pixels[..., :3]


def compare_with(reference_path: str, image: Image) -> tuple[Image, float]:
    """``--compare``: the [reference | image | difference] panel of ``image``'s 8-bit output, and the RMS."""
    reference = read_display_image(reference_path)
    ours = to_uint8(image.display).astype(np.float32) / np.float32(255.0)
    try:
        panel, rms = compare_images(reference, ours)
    except ValueError as error:
        raise UsageError(f"--compare {reference_path}: {error}") from None
    return Image(display=panel, linear=srgb_decode(panel), value=np.zeros(panel.shape[:2] + (1,), np.float32),
                 coverage=np.ones(panel.shape[:2], np.float32), view_width=panel.shape[1],
                 exposure=image.exposure, legend=image.legend), rms
