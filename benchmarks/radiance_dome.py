"""A stage's UsdLux sky (DomeLight, lat-long texture, DistantLight sun) for Radiance, and rtrace under it.

Part of the independent Radiance references (``sky_lit_references``): the lights are read back from the stage
with pxr and the texture with OpenImageIO, nothing of usdbake's light code is imported.

The dome (``read_stage_sky``)
    Each DomeLight's radiance is intensity x 2^exposure x color (UsdLux); the first one with an
    ``inputs:texture:file`` multiplies it by the texel seen along a direction. Texture layout (OpenEXR
    lat-long in the dome's frame, +Y the pole, as usdbake's ``sky_texel`` documents it): a world direction d
    goes to the dome frame by the inverse of the dome's rotation (l = R^-1 d), latitude asin(l_y), longitude
    atan2(l_x, l_z); the image column (pi - longitude) / 2 pi and the row from the top (pi/2 - latitude) / pi.
The sun
    A DistantLight of apex angle ``angle``: radiance L = intensity x 2^exposure x color over a cone of solid
    angle Omega = 2 pi (1 - cos(angle / 2)) about its +Z axis (it emits along -Z), so a surface facing it
    receives L Omega. Radiance's ``source`` of the same angle takes the same Omega (src.c), so the ``light``
    material gets the same L.
In Radiance (``sky_rad``)
    ``colorpict`` over the picture (``write_hdr``: the texture as a Radiance RGBE file, top row first) with
    the mapping of ``dome.cal`` (``dome_cal``): colorpict's (u, v) spans (0 .. 2, 0 .. 1) for a 2:1 picture,
    (0, 0) its lower left, so u = 2 x column fraction and v = 1 - row fraction; it modulates a ``glow`` of
    the dome's radiance on a 360 degree ``source`` (reached by ambient rays only, as ``radiance_scene``'s
    skies); the sun a ``light`` on a ``source`` of its angle (reached by shadow rays: direct light).
Checked (``horizontal_check``) on an empty scene: rtrace -I at the six axis normals against
``analytic_irradiance``, the texture integrated texel by texel (cos-weighted exact solid angles) plus L Omega
cos of each sun.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .radiance_binaries import _pyradiance
from .radiance_scene import _dummy_rays, _sensor_rays, _timed_run, rtrace_irradiance_command

AXIS_NORMALS = np.array([(1, 0, 0), (-1, 0, 0), (0, 1, 0), (0, -1, 0), (0, 0, 1), (0, 0, -1)], np.float64)


@dataclass(frozen=True)
class StageSky:
    """A stage's dome and distant lights, read with pxr (module docstring)."""

    dome_radiance: np.ndarray
    """(3,) float64 W/(m^2 sr): the sum of the DomeLights' intensity x 2^exposure x color."""
    texture: np.ndarray | None
    """(H, W, 3) float64 lat-long texel values (top row first), or None (a uniform dome)."""
    texture_path: str | None
    world_to_dome: np.ndarray
    """(3, 3) float64: dome-frame direction = world_to_dome @ world direction."""
    sun_directions: np.ndarray
    """(S, 3) float64 unit directions towards each DistantLight (its +Z axis)."""
    sun_radiance: np.ndarray
    """(S, 3) float64 W/(m^2 sr) over the cone."""
    sun_angles: np.ndarray
    """(S,) float64 apex angles, degrees."""

    @property
    def sun_solid_angles(self) -> np.ndarray:
        return 2.0 * np.pi * (1.0 - np.cos(np.radians(self.sun_angles) / 2.0))


def _radiance(prim, time) -> np.ndarray:
    from pxr import UsdLux

    light = UsdLux.LightAPI(prim)
    return float(light.GetIntensityAttr().Get(time)) * 2.0 ** float(light.GetExposureAttr().Get(time)) * \
        np.array(light.GetColorAttr().Get(time), np.float64)


def read_stage_sky(stage) -> StageSky:
    """The stage's DomeLights and DistantLights (no other light kinds in these scenes)."""
    from pxr import Usd, UsdGeom, UsdLux

    time = Usd.TimeCode.Default()
    cache = UsdGeom.XformCache(time)
    dome, texture, path, to_dome = np.zeros(3), None, None, np.eye(3)
    dirs, suns, angles = [], [], []
    for prim in stage.Traverse():
        world = np.array(cache.GetLocalToWorldTransform(prim), np.float64)[:3, :3]  # rows: local axes in world
        world = world / np.linalg.norm(world, axis=1, keepdims=True)
        if prim.IsA(UsdLux.DomeLight):
            dome = dome + _radiance(prim, time)
            asset = UsdLux.DomeLight(prim).GetTextureFileAttr().Get(time)
            if texture is None and asset and asset.resolvedPath:
                path = asset.resolvedPath
                texture = read_texture(path)
                to_dome = np.linalg.inv(world.T)  # world = world.T @ local (column vectors)
        elif prim.IsA(UsdLux.DistantLight):
            dirs.append(world[2] / np.linalg.norm(world[2]))
            suns.append(_radiance(prim, time))
            angles.append(float(UsdLux.DistantLight(prim).GetAngleAttr().Get(time)))
    return StageSky(dome, texture, path, to_dome, np.array(dirs).reshape(-1, 3), np.array(suns).reshape(-1, 3),
                    np.array(angles, np.float64))


def read_texture(path: str) -> np.ndarray:
    """(H, W, 3) float64 RGB of an image file (OpenImageIO), top row first."""
    import OpenImageIO as oiio

    image = oiio.ImageInput.open(path)
    if image is None:
        raise RuntimeError(f"{path}: {oiio.geterror()}")
    try:
        pixels = image.read_image(0, 0, 0, 3, "float")
    finally:
        image.close()
    return np.asarray(pixels, np.float64)[..., :3]


def write_hdr(texture: np.ndarray, path: str | os.PathLike) -> str:
    """The texture as a Radiance RGBE picture (OpenImageIO's HDR writer: top row first, -Y H +X W)."""
    import OpenImageIO as oiio

    texture = np.ascontiguousarray(texture, np.float32)
    out = oiio.ImageOutput.create(str(path))
    if out is None or not out.open(str(path), oiio.ImageSpec(texture.shape[1], texture.shape[0], 3, "float")):
        raise RuntimeError(f"{path}: {oiio.geterror()}")
    out.write_image(texture)
    out.close()
    return str(path)


def texel_directions(height: int, width: int) -> tuple[np.ndarray, np.ndarray]:
    """((H, W, 3) unit dome-frame directions of the texel centres, (H, W) exact solid angles (sr)): row r at
    latitude pi/2 - (r + 1/2) pi / H, column c at longitude pi - (c + 1/2) 2 pi / W, from the layout above
    (written here from the layout, not imported)."""
    lat = 0.5 * np.pi - (np.arange(height) + 0.5) * np.pi / height
    lon = np.pi - (np.arange(width) + 0.5) * 2.0 * np.pi / width
    lat, lon = np.meshgrid(lat, lon, indexing="ij")
    d = np.stack([np.cos(lat) * np.sin(lon), np.sin(lat), np.cos(lat) * np.cos(lon)], axis=-1)
    edges = 0.5 * np.pi - np.arange(height + 1) * np.pi / height
    omega = (np.sin(edges[:-1]) - np.sin(edges[1:]))[:, None] * np.full(width, 2.0 * np.pi / width)
    return d, omega


def analytic_irradiance(sky: StageSky, normals: np.ndarray, supersample: int = 4) -> np.ndarray:
    """(N, 3) float64 irradiance (W/m^2) of unobstructed surfaces with unit ``normals`` (world): the dome
    integrated texel by texel (each texel split in supersample^2 sub-texels for the cosine; nearest texel),
    plus each sun's L Omega max(0, n . s)."""
    normals = np.asarray(normals, np.float64).reshape(-1, 3)
    out = np.zeros((len(normals), 3))
    if sky.texture is None:
        out += sky.dome_radiance * np.pi  # a uniform sphere: pi L on any face
    else:
        h, w = sky.texture.shape[:2]
        d, omega = texel_directions(h * supersample, w * supersample)
        radiance = np.repeat(np.repeat(sky.texture, supersample, 0), supersample, 1) * sky.dome_radiance
        world = d.reshape(-1, 3) @ sky.world_to_dome  # d_world = world_to_dome^T d_local (rows)
        cos = np.maximum(normals @ world.T, 0.0)  # (N, texels)
        out += cos @ (radiance.reshape(-1, 3) * omega.reshape(-1, 1))
    for direction, radiance, omega in zip(sky.sun_directions, sky.sun_radiance, sky.sun_solid_angles):
        out += np.maximum(normals @ direction, 0.0)[:, None] * (radiance * omega)
    return out


def dome_cal(world_to_dome: np.ndarray) -> str:
    """The .cal file mapping a ray direction (Dx, Dy, Dz: Radiance's frame = the stage's, Z up) to colorpict's
    (dome_u, dome_v) of the lat-long picture (module docstring)."""
    m = np.asarray(world_to_dome, np.float64)
    rows = [" + ".join(f"({m[i, j]:.12g})*{axis}" for j, axis in enumerate(("Dx", "Dy", "Dz"))) for i in range(3)]
    return (
        "{ usdbake DomeLight lat-long texture: +Y pole in the dome frame, longitude atan2(x, z) }\n"
        f"dome_x = {rows[0]};\ndome_y = {rows[1]};\ndome_z = {rows[2]};\n"
        "dome_yc = if(dome_y - 1, 1, if(-1 - dome_y, -1, dome_y));\n"
        f"dome_u = ({math.pi!r} - atan2(dome_x, dome_z)) / {math.pi!r};\n"
        f"dome_v = (asin(dome_yc) + {0.5 * math.pi!r}) / {math.pi!r};\n")


def sky_rad(sky: StageSky, folder: str | os.PathLike) -> str:
    """The Radiance sky of ``sky`` (module docstring); its picture and .cal file are written to ``folder``
    (absolute paths in the text, so rtrace may run anywhere)."""
    folder = Path(folder).resolve()
    r, g, b = sky.dome_radiance
    if sky.texture is None:
        text = f"void glow skyglow\n0\n0\n4 {r:.9g} {g:.9g} {b:.9g} 0\n\n"
    else:
        picture = write_hdr(sky.texture, folder / "dome.hdr")
        cal = folder / "dome.cal"
        cal.write_text(dome_cal(sky.world_to_dome))
        text = (f"void colorpict skypict\n7 red green blue {picture} {cal} dome_u dome_v\n0\n0\n\n"
                f"skypict glow skyglow\n0\n0\n4 {r:.9g} {g:.9g} {b:.9g} 0\n\n")
    text += "skyglow source skydome\n0\n0\n4 0 0 1 360\n"
    for k, (direction, radiance, angle) in enumerate(zip(sky.sun_directions, sky.sun_radiance, sky.sun_angles)):
        text += (f"\nvoid light solar{k}\n0\n0\n3 {radiance[0]:.9g} {radiance[1]:.9g} {radiance[2]:.9g}\n\n"
                 f"solar{k} source sun{k}\n0\n0\n4 {direction[0]:.12g} {direction[1]:.12g} {direction[2]:.12g} "
                 f"{angle:.9g}\n")
    return text


DIRECT_OPTIONS = ["-dt", "0", "-dc", "1", "-dj", "0", "-ds", "0", "-dr", "0"]
"""Every source's shadow ray cast (-dt 0 -dc 1), to the disc's centre (-dj 0), no subdivision or mirrors."""


def sky_irradiance(triangles: np.ndarray | None, albedo: np.ndarray | None, points: np.ndarray,
                   normals: np.ndarray, sky_text: str, *, ambient_bounces: int = 7, ambient_divisions: int = 8192,
                   limit_weight: float | None = None, offset: float = 0.0, processes: int | None = None,
                   seed: int | None = None, workdir: str | os.PathLike | None = None,
                   timings: dict | None = None) -> np.ndarray:
    """(N, 3) float64 RGB irradiance (W/m^2) at points under ``sky_text`` (``sky_rad``) by ``rtrace -I``.

    As ``radiance_scene.uniform_sky_irradiance`` (plastic RGB materials, ``-ab ambient_bounces + 1 -ad
    ambient_divisions -aa 0 -as 0 -lw 0.2 / -ad``, ``seed`` an independent draw by dummy rays, ``timings``),
    with any sky, Z-up stage coordinates and ``DIRECT_OPTIONS`` for the sun."""
    _pyradiance()
    points = np.asarray(points, np.float64).reshape(-1, 3)
    if processes is None:
        processes = max(1, min(os.cpu_count() or 1, len(points)))
    dummies = _dummy_rays(seed, processes)
    points, rays = _sensor_rays(points, normals, "Z", offset, dummies)
    command = rtrace_irradiance_command("scene.oct", ambient_bounces=ambient_bounces,
                                        ambient_divisions=ambient_divisions, limit_weight=limit_weight,
                                        processes=processes)
    command = command[:-1] + DIRECT_OPTIONS + command[-1:]
    out = _timed_run(command, sky_text, triangles, albedo, None, "Z", rays, processes=processes, workdir=workdir,
                     timings=timings, stdin="points")
    values = np.frombuffer(out, dtype=np.float32)
    if values.size != (dummies + len(points)) * 3:
        raise RuntimeError(f"rtrace wrote {values.size} floats, expected {dummies + len(points)} x 3")
    return values.reshape(-1, 3)[dummies:].astype(np.float64)


def horizontal_check(sky: StageSky, folder: str | os.PathLike, *, ambient_divisions: int = 65536) -> dict:
    """Radiance against ``analytic_irradiance`` on an empty scene at the six axis normals (up checks the
    latitude mapping and the sun; the four vertical faces the longitude), with the sun and without it (the
    sky alone, where a mirrored or turned mapping cannot hide behind the sun): relative differences of
    luminance-weighted (Rec. 709) irradiance, keys ``relative_difference`` / ``sky_only_relative_difference``
    by normal, their largest magnitude ``max_abs_relative_difference`` and ``horizontal_relative_difference``
    (up, with the sun)."""
    from dataclasses import replace

    from usdbake.kernels.lights import LUMINANCE  # the weights only

    names = ("+x", "-x", "+y", "-y", "+z", "-z")
    out = {}
    for label, case in (("", sky), ("sky_only_", replace(sky, sun_directions=np.zeros((0, 3)),
                                                          sun_radiance=np.zeros((0, 3)), sun_angles=np.zeros(0)))):
        radiance = sky_irradiance(None, None, np.zeros((6, 3)), AXIS_NORMALS, sky_rad(case, folder),
                                  ambient_bounces=0, ambient_divisions=ambient_divisions, processes=1)
        radiance, analytic = radiance @ LUMINANCE, analytic_irradiance(case, AXIS_NORMALS) @ LUMINANCE
        rel = radiance / np.maximum(analytic, 1e-300) - 1.0
        out.update({f"{label}radiance": dict(zip(names, radiance.round(3).tolist())),
                    f"{label}analytic": dict(zip(names, analytic.round(3).tolist())),
                    f"{label}relative_difference": dict(zip(names, rel.round(5).tolist()))})
    both = [v for key in ("relative_difference", "sky_only_relative_difference") for v in out[key].values()]
    return {**out, "horizontal_relative_difference": out["relative_difference"]["+z"],
            "max_abs_relative_difference": float(np.abs(both).max())}
