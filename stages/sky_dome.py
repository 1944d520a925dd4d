"""A sky model as UsdLux lights, so every processor that reads lights is daylit.

``daylight`` and ``annual_daylight`` evaluate the sky models of ``kernels/sky.py`` (Preetham, Perez
all-weather from DNI and DHI, CIE overcast) on their own patches; radiosity, light_probes and
irradiance_grid read UsdLux lights. ``write_sky_layer`` bridges the two: for one place and time it
writes a layer over the input holding a DomeLight whose lat-long texture (OpenEXR layout, +Y pole,
read back through the one light model's ``sky_texel``) is the model's sky radiance above the
horizon and a grey ground below it (albedo x global horizontal irradiance / pi), and a
DistantLight of the sun's 0.53 degree disk carrying the model's direct normal irradiance.

The other way round, ``DomeTexture`` reads a DomeLight's lat-long file for the light model: when a
processor first asks for it (an ambient-occlusion bake never does), strip by strip through OpenImageIO,
reduced to at most ``DOME_MAP_MAX_HEIGHT`` x ``DOME_MAP_MAX_WIDTH`` texels by an area average that keeps
the radiant power of every output texel's patch of sky (``reduce_latlong``), in float32.
"""

from __future__ import annotations

import math
import os
import threading
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from pxr import Gf, Sdf, Usd, UsdGeom, UsdLux

from ..core.errors import StageError, UsageError
from ..core.records import Texture
from .sidecars import write_texture
from .images import RgbRows

SKY_PRIM = "/SkyLights"
MODELS = ("preetham", "perez", "overcast")


@dataclass(frozen=True)
class SkyLights:
    """A sky for one time and place: the dome's texture, its rotation, the sun."""

    texture: np.ndarray
    """(H, W, 3) float32 radiance W/(m^2 sr) in the OpenEXR lat-long layout of the dome's frame."""
    dome_rotate_x: float
    """Degrees about X that turn the dome's +Y pole onto the stage's up axis (0 for Y-up, 90 for Z-up)."""
    sun_world: np.ndarray | None
    """(3,) unit direction towards the sun in the stage frame, None below the horizon or without a sun."""
    sun_irradiance: np.ndarray
    """(3,) W/m^2 direct normal irradiance of the sun."""
    diffuse_horizontal: float
    """W/m^2 (green channel) the dome gives an open horizontal face."""


def texel_directions(height: int, width: int) -> tuple[np.ndarray, np.ndarray]:
    """((H, W, 3) unit directions of the texel centres in the dome's frame, (H, W) solid angles):
    latitude (pi/2 - (row + 1/2) pi / H), longitude (pi - (column + 1/2) 2 pi / W), +Y the pole."""
    latitude = 0.5 * np.pi - (np.arange(height) + 0.5) * np.pi / height
    longitude = np.pi - (np.arange(width) + 0.5) * 2.0 * np.pi / width
    lat, lon = np.meshgrid(latitude, longitude, indexing="ij")
    directions = np.stack([np.cos(lat) * np.sin(lon), np.sin(lat), np.cos(lat) * np.cos(lon)], axis=-1)
    edges = 0.5 * np.pi - np.arange(height + 1) * np.pi / height
    solid = (np.sin(edges[:-1]) - np.sin(edges[1:]))[:, None] * np.full(width, 2.0 * np.pi / width)
    return directions, solid


DOME_MAP_MAX_HEIGHT, DOME_MAP_MAX_WIDTH = 512, 1024
"""Largest dome map kept (rows, columns): 0.35 degree texels. The light model looks up one texel per
ray (``sky_texel``, nearest), so finer texels add memory, not accuracy, to a few thousand rays per
point; a larger file is reduced by ``reduce_latlong``."""


def reduce_latlong(height: int, width: int, strips, *, out_height: int, out_width: int) -> np.ndarray:
    """(out_height, out_width, 3) float64 area average of a lat-long map given as ``strips``, an iterable of
    (first row, (r, width, 3) float rows) in row order, holding one strip in memory at a time; sums in
    float64.

    Each output texel is the mean radiance over its own patch of the sphere: columns are averaged over
    the exact fractions of the input texels they cover (longitude is uniform), rows over the fractions
    weighted by their solid angle, cos(latitude) d(latitude) integrated exactly (sin(a) - sin(b)). So
    sum(L_out * Omega_out) equals sum(L_in * Omega_in) over every output texel's patch: the dome's radiant
    power, and each region's, is kept, whatever the ratio. ImageBufAlgo.resize does not do this: its box
    filter weights whole source texels by their centres (a 1000 x 1000 map resized to 1024 x 512 lost
    1.6% of its power), it knows no solid angles, its default lanczos3 rings (negative texels around a
    sun), and it needs the whole source in memory at once. Axes already small enough are copied.
    """
    out = np.zeros((out_height, out_width, 3), np.float64)
    weight = np.zeros(out_height, np.float64)
    for first, rows in strips:
        rows = _average_columns(rows, out_width)
        if out_height == height:
            out[first:first + len(rows)] = rows
            continue
        y = np.arange(first, first + len(rows), dtype=np.int64)
        row = (y * out_height) // height  # the output row holding each input row's top edge (exact integers)
        boundary = (row + 1) * height / out_height  # that output row's bottom edge, in input rows
        split = boundary < y + 1
        top = _latitude_band(y, np.where(split, boundary, y + 1.0), height)
        bottom = _latitude_band(np.where(split, boundary, y + 1.0), y + 1.0, height)
        np.add.at(out, row, top[:, None, None] * rows)
        np.add.at(weight, row, top)
        np.add.at(out, row[split] + 1, bottom[split, None, None] * rows[split])
        np.add.at(weight, row[split] + 1, bottom[split])
    if out_height != height:
        out /= weight[:, None, None]
    return out


def _average_columns(rows: np.ndarray, out_width: int) -> np.ndarray:
    """(r, out_width, 3) means of (r, W, 3) ``rows`` over out_width equal spans of columns, each input
    texel counted by the fraction of it a span covers.

    Span j runs from edge e_j = j W / out_width to e_(j+1); with c = floor(e) and f = e - c, its integral
    is the sum of columns c_j .. c_(j+1) - 1, less f_j of column c_j, plus f_(j+1) of column c_(j+1).
    """
    width = rows.shape[1]
    if out_width == width:
        return rows
    edges = np.arange(out_width + 1, dtype=np.float64) * width / out_width
    column = np.minimum(edges.astype(np.int64), width)
    part = edges - column  # 0 at the last edge (column = width: no texel there)
    whole = np.add.reduceat(rows, column[:-1], axis=1, dtype=np.float64)
    last = np.minimum(column[1:], width - 1)
    spans = whole - part[:-1, None] * rows[:, column[:-1]] + part[1:, None] * rows[:, last]
    return spans * (out_width / width)


def _latitude_band(start: np.ndarray, end: np.ndarray, height: int) -> np.ndarray:
    """Solid angle per radian of longitude between rows ``start`` and ``end`` (fractional rows of a map
    ``height`` rows tall): sin(lat(start)) - sin(lat(end)) = 2 sin(mid) sin(half), which keeps its
    precision for thin bands."""
    a = np.asarray(start, np.float64) * np.pi / height
    b = np.asarray(end, np.float64) * np.pi / height
    return 2.0 * np.sin(0.5 * (a + b)) * np.sin(0.5 * (b - a))


def read_latlong(path: str, *, srgb: bool, max_height: int = DOME_MAP_MAX_HEIGHT,
                 max_width: int = DOME_MAP_MAX_WIDTH) -> np.ndarray:
    """(H, W, 3) float32 linear RGB of the lat-long image at ``path``, at most max_height x max_width.

    Read strip by strip as float32 (``stages.images.RgbRows``: memory stays near its ``STRIP_BYTES``
    whatever the file's size) and reduced by ``reduce_latlong`` (sums in float64); a map within the
    bounds is returned texel for texel.
    Raises ValueError with the reason: OpenImageIO's, or where the first non-finite texel is.
    """
    with RgbRows(path, srgb=srgb, dtype=np.float32) as image:
        strips = image if image.exact_codes else _finite(image)
        out = reduce_latlong(image.height, image.width, strips, out_height=min(image.height, max_height),
                             out_width=min(image.width, max_width))
    return out.astype(np.float32)


def _finite(strips):
    """The strips, checked for NaN and infinity (ValueError naming the first such texel)."""
    for first, rows in strips:
        bad = ~np.isfinite(rows)
        if bad.any():
            row, column, channel = np.argwhere(bad)[0]
            raise ValueError(f"holds non-finite texels (row {first + row}, column {column}: "
                             f"{rows[row, column, channel]})")
        yield first, rows


class DomeTexture:
    """A DomeLight's lat-long texture file, read by ``read_latlong`` the first time it is called and kept.

    ``stages.extract`` checks at once that the file opens (a bad file fails before any compute); the
    texels are read only when a processor reads the lights (its fingerprint included), so an ambient
    occlusion bake of a stage with a 10000 x 10000 sky never reads them. Errors name the light, the
    attribute and the file: ``/World/Sky.inputs:texture:file: sky.png: holds non-finite texels (...)``.
    """

    def __init__(self, prim: str, asset: str, resolved: str, *, srgb: bool = True):
        self.prim, self.asset, self.resolved, self.srgb = prim, asset, resolved, srgb
        self._texture: np.ndarray | None = None
        self._lock = threading.Lock()

    def check(self) -> None:
        """Raise StageError when OpenImageIO cannot open the file (its header only is read)."""
        try:
            RgbRows(self.resolved, srgb=self.srgb).close()
        except ValueError as error:
            raise StageError(self.prim, "inputs:texture:file", f"{self.asset}: cannot be read ({error})") from None

    def __call__(self) -> np.ndarray:
        with self._lock:
            if self._texture is None:
                try:
                    texture = read_latlong(self.resolved, srgb=self.srgb)
                except ValueError as error:
                    problem = str(error)
                    problem = problem if problem.startswith("holds ") else f"cannot be read ({problem})"
                    raise StageError(self.prim, "inputs:texture:file", f"{self.asset}: {problem}") from None
                texture.flags.writeable = False
                self._texture = texture
            return self._texture

    def __getstate__(self) -> dict:  # a lock does not pickle (a Dask scatter of the scene)
        state = dict(self.__dict__)
        del state["_lock"]
        return state

    def __setstate__(self, state: dict) -> None:
        self.__dict__.update(state, _lock=threading.Lock())

    def __repr__(self) -> str:
        return f"DomeTexture({self.prim!r}, {self.asset!r})"


def sky_lights(model: str, time: str, *, latitude: float, longitude: float, timezone: float, up_axis: str,
               north: float = 0.0, turbidity: float = 3.0, direct_normal: float = 600.0,
               diffuse_horizontal: float = 150.0, ground_albedo: float = 0.2, width: int = 256,
               efficacy: str = "perez") -> SkyLights:
    """The dome texture and sun of ``model`` at local standard ``time`` (ISO 8601) and the place.

    Radiance is in visible-equivalent W/(m^2 sr) (x 179 = cd/m^2), as ``daylight`` writes it: the Perez
    model's solar watts (its DNI and DHI) are turned into light by the Perez et al. 1990 luminous efficacy
    (``efficacy = perez``, gendaymtx -O0) or taken as visible (``179``, gendaymtx -O1); Preetham and CIE
    overcast are luminance models already.

    The sky models are the kernels' (numpy), imported here when a sky is made: the one place stages/
    reads kernels/ (tests/test_import_rules.py lists it)."""
    from ..kernels.luminous_efficacy import perez_efficacy
    from ..kernels.sky import LUMINOUS_EFFICACY, enu_to_world, overcast_radiance, perez_radiance, \
        preetham_radiance, sun_normal_irradiance
    from ..kernels.solar import day_of_year, parse_times, sun_position

    if model not in MODELS:
        raise UsageError(f"sky model {model!r} is not one of {', '.join(MODELS)}")
    if efficacy not in ("perez", "179"):
        raise UsageError(f"efficacy {efficacy!r} is not perez or 179")
    times = parse_times(time)
    if len(times) != 1:
        raise UsageError(f"--time {time!r}: a sky dome is for one time, not {len(times)}")
    position = sun_position(times, latitude, longitude, timezone)
    sun_enu = position.enu()[0]
    day = int(day_of_year(times)[0])
    to_world = enu_to_world(up_axis, north)  # world = to_world @ enu
    rotate_x = 90.0 if up_axis == "Z" else 0.0
    c, s = math.cos(math.radians(rotate_x)), math.sin(math.radians(rotate_x))
    local_to_world = np.array([[1.0, 0.0, 0.0], [0.0, c, s], [0.0, -s, c]])  # xformOp:rotateX, row vectors
    directions, solid = texel_directions(width // 2, width)
    enu = (directions.reshape(-1, 3) @ local_to_world) @ to_world  # row vectors: local -> world -> ENU
    above = enu[:, 2] > 0.0
    radiance = np.zeros((len(enu), 3))
    if model == "preetham":
        radiance[above] = preetham_radiance(enu[above], sun_enu, turbidity)
    elif model == "perez":
        radiance[above] = perez_radiance(enu[above], sun_enu, direct_normal, diffuse_horizontal, day)
        beam, sky_light = LUMINOUS_EFFICACY, LUMINOUS_EFFICACY
        if efficacy == "perez":
            zenith = math.degrees(math.acos(min(1.0, max(-1.0, float(sun_enu[2])))))
            beam, sky_light = (float(k) for k in perez_efficacy(direct_normal, diffuse_horizontal, zenith, day))
        radiance *= sky_light / LUMINOUS_EFFICACY
        direct_normal = float(direct_normal) * beam / LUMINOUS_EFFICACY
    else:
        radiance[above] = overcast_radiance(enu[above], sun_enu)
    diffuse = (radiance * (np.maximum(enu[:, 2], 0.0) * solid.ravel())[:, None]).sum(axis=0)
    sun_up = sun_enu[2] > 0.0 and model != "overcast"
    if model == "preetham":
        sun = sun_normal_irradiance(sun_enu, turbidity, day) if sun_up else np.zeros(3)
    else:
        sun = np.full(3, float(direct_normal)) if sun_up else np.zeros(3)
    ground = ground_albedo * (diffuse + sun * max(float(sun_enu[2]), 0.0)) / np.pi
    radiance[~above] = ground
    return SkyLights(radiance.reshape(width // 2, width, 3).astype(np.float32), rotate_x,
                     (to_world @ sun_enu) if sun_up else None, sun, float(diffuse[1]))


def check_sky_time(text: str) -> None:
    """Raise ValueError unless ``text`` is an ISO 8601 local time ``usdbake sky`` can place the sun at
    (checked when the arguments are parsed, before the stage is read)."""
    from ..kernels.solar import parse_times

    parse_times(text)


def weather_hour(path: str, time: str) -> tuple[dict, dict, str]:
    """(site, Perez irradiance, a note naming the row) of the weather file's hour holding ``time``: a sky
    dome from a typical year. The reader is formats/weather.py, imported here when asked for
    (tests/test_import_rules.py lists it)."""
    from ..formats.weather import read_weather
    from ..kernels.solar import parse_times

    weather = read_weather(path)
    try:
        times = parse_times(time)
    except ValueError as error:
        raise UsageError(f"--time {time!r}: {error}") from None
    if len(times) != 1:
        raise UsageError(f"--time {time!r}: a sky dome is for one time, not {len(times)}")
    row = weather.hour_at(times[0])
    site = {"latitude": weather.latitude, "longitude": weather.longitude, "timezone": weather.timezone}
    irradiance = {"direct_normal": float(weather.direct_normal[row]),
                  "diffuse_horizontal": float(weather.diffuse_horizontal[row])}
    note = (f"{path} line {weather.lines[row]} (DNI {irradiance['direct_normal']:g}, DHI "
            f"{irradiance['diffuse_horizontal']:g} W/m^2); ")
    return site, irradiance, note


SKY_LAYER_KEY = "usdbakeSky"
"""customLayerData marking a sky layer (so it may be replaced by the next ``usdbake sky``; it is not a bake
layer: a bake over it reads it, lights included)."""


def check_sky_output(output: str, source: str) -> None:
    """Refuse an output that is not a layer file, is the input, or is someone's layer."""
    path = Path(output)
    if path.suffix.lower() not in (".usd", ".usda", ".usdc"):
        raise UsageError(f"{output}: the sky layer must be a .usd, .usda or .usdc file")
    if path.resolve() == Path(source).resolve():
        raise UsageError(f"{output}: refusing to overwrite the input layer; choose another -o")
    if path.exists():
        layer = Sdf.Layer.OpenAsAnonymous(str(path), metadataOnly=True)
        if layer is None or SKY_LAYER_KEY not in dict(layer.customLayerData):
            raise UsageError(f"{output}: exists and was not written by usdbake sky; refusing to replace it")


def make_sky(source: str, output: str, model: str, time: str, **options) -> tuple[list[str], SkyLights]:
    """Check the output, make the sky for the input stage's up axis and write the layer: (files, sky)."""
    check_sky_output(output, source)
    stage = Usd.Stage.Open(source)
    sky = sky_lights(model, time, up_axis=str(UsdGeom.GetStageUpAxis(stage)), **options)
    site = {key: float(options[key]) for key in ("latitude", "longitude", "timezone")}
    return write_sky_layer(source, output, sky, site), sky


def write_sky_layer(source: str, output: str, sky: SkyLights, site: dict) -> list[str]:
    """A layer at ``output`` over ``source`` holding the sky's DomeLight (texture beside it) and sun, its
    customLayerData the ``site`` (latitude, longitude, timezone: the stage's place from now on, checked
    against weather files); returns the files written. The input is never touched."""
    out = Path(output).resolve()
    texture = write_texture(Texture(f"{out.stem}_sky.exr", sky.texture), str(out.parent))
    layer = Sdf.Layer.CreateNew(str(out))
    if layer is None:
        raise UsageError(f"{output}: cannot create a layer there")
    layer.customLayerData = {SKY_LAYER_KEY: site}
    layer.subLayerPaths.append(Path(os.path.relpath(Path(source).resolve(), out.parent)).as_posix())
    stage = Usd.Stage.Open(layer)
    source_stage = Usd.Stage.Open(source)
    UsdGeom.SetStageUpAxis(stage, UsdGeom.GetStageUpAxis(source_stage))
    UsdGeom.SetStageMetersPerUnit(stage, UsdGeom.GetStageMetersPerUnit(source_stage))
    UsdGeom.Scope.Define(stage, SKY_PRIM)
    dome = UsdLux.DomeLight.Define(stage, f"{SKY_PRIM}/Sky")
    dome.CreateTextureFileAttr(Sdf.AssetPath(f"./{Path(texture).name}"))
    dome.CreateTextureFormatAttr(UsdLux.Tokens.latlong)
    dome.CreateIntensityAttr(1.0)
    if sky.dome_rotate_x:
        UsdGeom.Xformable(dome).AddRotateXOp().Set(sky.dome_rotate_x)
    if sky.sun_world is not None and sky.sun_irradiance.max() > 0:
        from ..kernels.sky import SUN_ANGULAR_DIAMETER  # the disk the daylight processors trace

        half = math.radians(SUN_ANGULAR_DIAMETER / 2)
        solid = 2.0 * math.pi * (1.0 - math.cos(half))  # the disk's solid angle: E = L Omega
        peak = float(sky.sun_irradiance.max())
        sun = UsdLux.DistantLight.Define(stage, f"{SKY_PRIM}/Sun")
        sun.CreateAngleAttr(SUN_ANGULAR_DIAMETER)
        sun.CreateIntensityAttr(peak / solid)
        sun.CreateColorAttr(Gf.Vec3f(*(sky.sun_irradiance / peak).tolist()))
        rotation = Gf.Rotation(Gf.Vec3d(0, 0, 1), Gf.Vec3d(*sky.sun_world.tolist()))  # its +Z to the sun: emits along -Z
        UsdGeom.Xformable(sun).AddOrientOp().Set(Gf.Quatf(rotation.GetQuat()))
    layer.Save()
    return [str(out), texture]
