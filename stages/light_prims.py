"""UsdLux light prims read into the Scene's ``Lights``: radiance (intensity, exposure, colour, colour
temperature, normalize), world position and direction, size, and the first DomeLight's lat-long texture."""

from __future__ import annotations

import numpy as np
from pxr import UsdLux

from ..core.errors import StageError
from ..core.scene import LIGHT_DISK, LIGHT_DISTANT, LIGHT_DOME, LIGHT_RECT, LIGHT_SPHERE, Lights
from .sky_dome import DomeTexture

LIGHT_TYPES = (
    (UsdLux.DistantLight, LIGHT_DISTANT), (UsdLux.DomeLight, LIGHT_DOME), (UsdLux.SphereLight, LIGHT_SPHERE),
    (UsdLux.RectLight, LIGHT_RECT), (UsdLux.DiskLight, LIGHT_DISK),
)


def read_lights(prims: list, xforms, timecode, origin: np.ndarray) -> Lights:
    """The light prims as ``Lights`` (positions relative to ``origin``); StageError for a radiance that is not
    finite."""
    rows = []
    for prim in prims:
        kind = next(k for light_type, k in LIGHT_TYPES if prim.IsA(light_type))
        light = UsdLux.LightAPI(prim)
        world = np.array(xforms.GetLocalToWorldTransform(prim), np.float64)
        intensity = float(light.GetIntensityAttr().Get(timecode))
        exposure = float(light.GetExposureAttr().Get(timecode))
        color = np.array(light.GetColorAttr().Get(timecode), np.float64)
        if light.GetEnableColorTemperatureAttr().Get(timecode):
            color *= np.array(UsdLux.BlackbodyTemperatureAsRgb(light.GetColorTemperatureAttr().Get(timecode)))
        radiance = intensity * 2.0 ** exposure * color
        if not np.isfinite(radiance).all():
            raise StageError(str(prim.GetPath()), "inputs:intensity", f"light radiance {radiance} is not finite")
        size, area = _light_size(prim, kind, world, timecode)
        if light.GetNormalizeAttr().Get(timecode) and area > 0:
            radiance = radiance / area
        direction = -world[2, :3]
        norm = np.linalg.norm(direction)
        rows.append((str(prim.GetPath()), kind, radiance, world[3, :3] - origin,
                     direction / norm if norm > 0 else np.array([0.0, 0.0, -1.0]), size))
    texture, to_local = _dome_texture([p for p in prims if p.IsA(UsdLux.DomeLight)], xforms, timecode)
    paths = [r[0] for r in rows]
    return Lights(
        dome_source=texture, dome_to_local=to_local,
        textured_dome=paths.index(texture.prim) if texture is not None and texture.prim in paths else -1,
        light_paths=tuple(r[0] for r in rows),
        light_kind=np.array([r[1] for r in rows], np.int32),
        light_radiance=np.array([r[2] for r in rows], np.float32).reshape(-1, 3),
        light_position=np.array([r[3] for r in rows], np.float32).reshape(-1, 3),
        light_direction=np.array([r[4] for r in rows], np.float32).reshape(-1, 3),
        light_size=np.array([r[5] for r in rows], np.float32).reshape(-1, 2),
    )


def _dome_texture(domes: list, xforms, timecode) -> tuple[DomeTexture | None, np.ndarray]:
    """(the texture file of the first DomeLight with one, world-to-dome rotation); the file is opened here
    (its header: a missing or unreadable file fails before any compute) and its texels read when a
    processor first reads the lights (``DomeTexture``). StageError naming the light and the file when it
    cannot be read or is not a lat-long map."""
    for prim in domes:
        dome = UsdLux.DomeLight(prim)
        asset = dome.GetTextureFileAttr().Get(timecode)
        if not asset or not asset.path:
            continue
        path = str(prim.GetPath())
        layout = dome.GetTextureFormatAttr().Get(timecode) or UsdLux.Tokens.automatic
        if layout not in (UsdLux.Tokens.automatic, UsdLux.Tokens.latlong):
            raise StageError(path, "inputs:texture:format", f"{layout!r}: only lat-long dome textures are read "
                                                            f"(automatic or latlong)")
        if not asset.resolvedPath:
            raise StageError(path, "inputs:texture:file", f"{asset.path}: not found")
        texture = DomeTexture(path, asset.path, asset.resolvedPath, srgb=True)
        texture.check()
        rotation = np.array(xforms.GetLocalToWorldTransform(prim), np.float64)[:3, :3]
        rotation /= np.maximum(np.linalg.norm(rotation, axis=1, keepdims=True), 1e-300)  # drop scale
        return texture, np.linalg.inv(rotation)
    return None, np.eye(3)


def _light_size(prim, kind: int, world: np.ndarray, timecode) -> tuple[tuple[float, float], float]:
    """(size pair, world-space emitting area) of a light."""
    scale = np.linalg.norm(world[:3, :3], axis=1)  # row lengths: x, y, z axis scales
    if kind == LIGHT_SPHERE:
        radius = float(UsdLux.SphereLight(prim).GetRadiusAttr().Get(timecode)) * float(scale.max())
        return (radius, radius), 4.0 * np.pi * radius * radius
    if kind == LIGHT_DISK:
        radius = float(UsdLux.DiskLight(prim).GetRadiusAttr().Get(timecode)) * float(scale[:2].max())
        return (radius, radius), np.pi * radius * radius
    if kind == LIGHT_RECT:
        rect = UsdLux.RectLight(prim)
        width = float(rect.GetWidthAttr().Get(timecode)) * float(scale[0])
        height = float(rect.GetHeightAttr().Get(timecode)) * float(scale[1])
        return (width, height), width * height
    if kind == LIGHT_DISTANT:
        angle = float(UsdLux.DistantLight(prim).GetAngleAttr().Get(timecode))
        return (angle, angle), 0.0
    return (0.0, 0.0), 0.0
