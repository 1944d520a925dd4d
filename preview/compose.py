"""``usdbake preview``: render the baked data of a stage to an image.

Stage -> Scene (``extract_scene``, so a refined mesh authored by a bake is
what gets drawn), the baked channel read from the composed stage and mapped
onto the Scene's triangles as per-corner values, a camera from a
UsdGeom.Camera or framed automatically, then ``usdbake.processors.render``.

Channel names (``--channel``):

- ``ao`` reads ``primvars:bake:ao`` (then ``primvars:ao``); a name that
  starts with ``primvars:`` is read as given.
- ``A+B`` sums channels (``irradianceDirect+irradianceIndirect``);
  ``irradiance`` falls back to that sum when no ``bake:irradiance`` exists.
- ``NAME[k]`` picks element k of a primvar with elementSize > 1 (without
  ``[k]`` such a primvar is averaged over its elements).
- Interpolation as authored: vertex/varying values are interpolated
  barycentrically, uniform values are constant per authored face (through
  ``Scene.tri_face``), constant values per prim, faceVarying per face corner.
  A per-instance primvar on a PointInstancer (one value per instance)
  colours each instance.
- Channels whose name starts with ``irradiance``, ``daylight`` or
  ``radiosity`` are irradiance: shaded as Lambertian radiance albedo * E / pi.

Scalar channels default to false colour with a legend, colour channels to
shading + tone mapping (see render.py for the curve).
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from pxr import Gf, Sdf, Tf, Usd, UsdGeom

from . import render
from ..core.scene import Scene
from ..kernels.tracer import Tracer
from ..core.errors import UsageError
from ..stages.extract import extract_scene

IRRADIANCE_PREFIXES = ("irradiance", "daylight", "radiosity")
STYLES = ("auto", "falsecolor", "shaded")
PROBE_TYPES = ("LightProbeCloud",)
GRID_TYPES = ("IrradianceVectorGrid",)
SPHERE_RADIUS_RELATIVE = 0.004
"""Probe / grid spheres: radius as a fraction of the scene diagonal (visible at 640 x 480, small enough
not to hide each other in a typical probe spacing)."""

SH_BASIS_L2 = (0.282095, 0.488603, 0.488603, 0.488603, 1.092548, 1.092548, 0.315392, 1.092548, 0.546274)
"""Real orthonormal SH constants, order (l, m) = (0,0), (1,-1), (1,0), (1,1), (2,-2), (2,-1), (2,0), (2,1), (2,2)."""


@dataclass
class Channel:
    """A baked channel mapped onto the Scene's triangles."""

    name: str
    corner_values: np.ndarray
    """(T, 3, 3) float32 value at each triangle corner (scalars in component 0)."""
    tri_has_value: np.ndarray
    """(T,) bool: the triangle's prim carries the channel."""
    components: int
    """1 (scalar) or 3 (colour)."""
    lo: float
    hi: float
    """Range of all values read (finite ones)."""
    irradiance: bool
    attributes: list[str] = field(default_factory=list)
    """Attribute paths read."""
    messages: list[str] = field(default_factory=list)


# ---------------------------------------------------------------------------
# Channels


def attribute_candidates(name: str) -> list[str]:
    """Property names to try for a channel name, in order."""
    if name.startswith("primvars:"):
        return [name]
    if name.startswith("bake:"):
        return [f"primvars:{name}"]
    return [f"primvars:bake:{name}", f"primvars:{name}"]


_ELEMENT = re.compile(r"^(?P<name>[^\[\]]+)\[(?P<index>\d+)\]$")


def read_channel(stage: Usd.Stage, scene: Scene, name: str, time: float | None = None) -> Channel:
    """Read channel ``name`` (see the module docstring) and map it onto ``scene``'s triangles."""
    parts = [p.strip() for p in name.split("+")]
    if not all(parts):
        raise UsageError(f"--channel {name!r}: empty term")
    if len(parts) == 1 and parts[0] == "irradiance" and not _exists(stage, scene, "irradiance"):
        if _exists(stage, scene, "irradianceDirect"):
            parts = ["irradianceDirect", "irradianceIndirect"] if _exists(stage, scene, "irradianceIndirect") \
                else ["irradianceDirect"]
    channels = [_read_single(stage, scene, part, time) for part in parts]
    if len({c.components for c in channels}) > 1:
        raise UsageError(f"--channel {name!r}: cannot add scalar and colour channels")
    total = channels[0]
    for other in channels[1:]:
        both = total.tri_has_value & other.tri_has_value
        total.corner_values = np.where(both[:, None, None], total.corner_values + other.corner_values,
                                       np.where(total.tri_has_value[:, None, None], total.corner_values,
                                                other.corner_values))
        total.tri_has_value = total.tri_has_value | other.tri_has_value
        total.attributes += other.attributes
        total.messages += other.messages
    total.name = name
    if len(channels) > 1:
        values = total.corner_values[total.tri_has_value][..., :total.components]
        values = values[np.isfinite(values)]
        total.lo, total.hi = (float(values.min()), float(values.max())) if values.size else (0.0, 1.0)
    total.irradiance = any(c.irradiance for c in channels)
    return total


def _exists(stage: Usd.Stage, scene: Scene, name: str) -> bool:
    for path in set(scene.prim_paths):
        prim = stage.GetPrimAtPath(path)
        if prim and any(prim.HasAttribute(a) for a in attribute_candidates(name)):
            return True
    return False


def _timecode(time: float | None) -> Usd.TimeCode:
    return Usd.TimeCode.Default() if time is None else Usd.TimeCode(time)


def _flattened(primvar: UsdGeom.Primvar, time: float | None):
    """Values at ``time``; at the default time, the first time sample when only samples exist."""
    value = primvar.ComputeFlattened(_timecode(time))
    if value is None and time is None:
        samples = primvar.GetAttr().GetTimeSamples()
        if samples:
            value = primvar.ComputeFlattened(Usd.TimeCode(samples[0]))
    return value


def _as_components(values: np.ndarray, type_name: Sdf.ValueTypeName, attribute: str) -> tuple[np.ndarray, int]:
    """(N, C) float64 values, C = 1 or 3."""
    scalar = type_name.scalarType
    dims = tuple(scalar.dimensions) if hasattr(scalar, "dimensions") else ()
    array = np.asarray(values, np.float64)
    if array.ndim == 1:
        return array[:, None], 1
    if array.ndim == 2 and array.shape[1] == 3:
        return array, 3
    raise UsageError(f"{attribute}: type {type_name} cannot be previewed (need a float or a 3-vector/colour, "
                     f"got shape {array.shape[1:] or dims})")


def _read_single(stage: Usd.Stage, scene: Scene, name: str, time: float | None) -> Channel:
    match = _ELEMENT.match(name)
    element = int(match["index"]) if match else None
    base_name = match["name"] if match else name
    candidates = attribute_candidates(base_name)
    num_tris = scene.num_triangles
    corners = np.zeros((num_tris, 3, 3), np.float32)
    has = np.zeros(num_tris, bool)
    components = None
    attributes, messages = [], []
    lows, highs = [], []
    per_path: dict[str, tuple | None] = {}
    tri_order = np.argsort(scene.tri_prim, kind="stable")
    tri_bounds = np.searchsorted(scene.tri_prim[tri_order], np.arange(len(scene.prim_paths) + 1))

    for m, path in enumerate(scene.prim_paths):
        tris = tri_order[tri_bounds[m]:tri_bounds[m + 1]]
        if len(tris) == 0:
            continue
        if path not in per_path:
            per_path[path] = _read_prim_values(stage, path, candidates, element, time, messages)
        found = per_path[path]
        if found is None:
            continue
        values, interpolation, attribute, c = found
        if components is None:
            components = c
        elif c != components:
            raise UsageError(f"{attribute}: {c} components where other prims have {components}")
        mapped = _map_to_corners(stage, scene, m, tris, values, interpolation, attribute, time, messages)
        if mapped is None:
            continue
        corners[tris, :, :c] = mapped
        has[tris] = True
        if attribute not in attributes:
            attributes.append(attribute)
        finite = values[np.isfinite(values).all(axis=1)]
        if len(finite):
            lows.append(finite.min())
            highs.append(finite.max())

    instanced = _read_instance_values(stage, scene, candidates, element, time, has, messages)
    if instanced is not None:
        tri_values, tri_mask, c, attribute = instanced
        components = components or c
        if c != components:
            raise UsageError(f"{attribute}: {c} components where other prims have {components}")
        corners[tri_mask, :, :c] = tri_values[tri_mask][:, None, :]
        has |= tri_mask
        attributes.append(attribute)
        lows.append(tri_values[tri_mask].min())
        highs.append(tri_values[tri_mask].max())

    if not has.any():
        tried = " or ".join(candidates)
        raise UsageError(f"no prim in {scene.source or 'the stage'} has {tried}"
                         + (f" at time {time:g}" if time is not None else "")
                         + "; bake it first (usdbake bake ...) or check `usdbake inspect`")
    return Channel(name=name, corner_values=corners, tri_has_value=has, components=components or 1,
                   lo=float(min(lows)), hi=float(max(highs)),
                   irradiance=base_name.split(":")[-1].startswith(IRRADIANCE_PREFIXES),
                   attributes=attributes, messages=messages)


def _read_prim_values(stage, path: str, candidates: list[str], element: int | None, time, messages):
    """(values (N, C) float64, interpolation, attribute path, C) of the first candidate on ``path``."""
    prim = stage.GetPrimAtPath(path)
    if not prim:
        return None
    for candidate in candidates:
        if not prim.HasAttribute(candidate):
            continue
        primvar = UsdGeom.Primvar(prim.GetAttribute(candidate))
        attribute = f"{path}.{candidate}"
        raw = _flattened(primvar, time)
        if raw is None:
            messages.append(f"{attribute}: no value" + (f" at time {time:g}" if time is not None else ""))
            return None
        values, c = _as_components(raw, primvar.GetTypeName(), attribute)
        values = _select_element(values, primvar.GetElementSize(), element, attribute, messages)
        return values, primvar.GetInterpolation(), attribute, c
    return None


def _select_element(values: np.ndarray, element_size: int, element: int | None, attribute: str, messages):
    element_size = max(int(element_size), 1)
    if element is not None and element >= element_size:
        raise UsageError(f"{attribute}: element {element} requested but elementSize is {element_size}")
    if element_size == 1:
        return values
    if len(values) % element_size:
        raise UsageError(f"{attribute}: {len(values)} values are not a multiple of elementSize {element_size}")
    grouped = values.reshape(len(values) // element_size, element_size, values.shape[1])
    if element is None:
        messages.append(f"{attribute}: elementSize {element_size}, showing the mean of the elements "
                        f"(pick one with NAME[k])")
        return grouped.mean(axis=1)
    return grouped[:, element]


def _map_to_corners(stage, scene: Scene, m: int, tris: np.ndarray, values: np.ndarray, interpolation: str,
                    attribute: str, time, messages) -> np.ndarray | None:
    """(len(tris), 3, C) values at the corners of prim m's triangles, or None (with a message)."""
    span = scene.prim_points(m)
    num_points = span.stop - span.start
    face_count = int(scene.prim_face_count[m])
    if interpolation in (UsdGeom.Tokens.vertex, UsdGeom.Tokens.varying):
        if len(values) != num_points:
            messages.append(f"{attribute}: {len(values)} {interpolation} values for {num_points} points; skipped")
            return None
        return values[scene.tri_vertices[tris] - span.start]
    if interpolation == UsdGeom.Tokens.uniform:
        if len(values) != face_count:
            messages.append(f"{attribute}: {len(values)} uniform values for {face_count} faces; skipped")
            return None
        return np.repeat(values[scene.tri_face[tris]][:, None, :], 3, axis=1)
    if interpolation == UsdGeom.Tokens.constant:
        return np.broadcast_to(values[0], (len(tris), 3, values.shape[1]))
    if interpolation == UsdGeom.Tokens.faceVarying:
        mesh = UsdGeom.Mesh(stage.GetPrimAtPath(scene.prim_paths[m]))
        counts = np.asarray(mesh.GetFaceVertexCountsAttr().Get(_timecode(time)) or [], np.int64)
        indices = np.asarray(mesh.GetFaceVertexIndicesAttr().Get(_timecode(time)) or [], np.int64)
        if len(values) != len(indices):
            messages.append(f"{attribute}: {len(values)} faceVarying values for {len(indices)} face corners; "
                            f"skipped")
            return None
        offsets = np.concatenate([[0], np.cumsum(counts)])[:-1]
        faces = scene.tri_face[tris].astype(np.int64)
        local = scene.tri_vertices[tris].astype(np.int64) - span.start
        position = np.full(local.shape, -1, np.int64)
        for j in range(int(counts.max()) if len(counts) else 0):
            slot = offsets[faces] + j
            valid = (j < counts[faces])[:, None]
            hit = valid & (indices[np.minimum(slot, len(indices) - 1)][:, None] == local) & (position < 0)
            position = np.where(hit, slot[:, None], position)
        position = np.maximum(position, 0)
        return values[position]
    messages.append(f"{attribute}: interpolation {interpolation!r} is not supported; skipped")
    return None


def _read_instance_values(stage, scene: Scene, candidates, element, time, has: np.ndarray, messages):
    """Per-instance primvars on PointInstancers (one value per instance, any interpolation but constant)."""
    instances = scene.instances
    if len(instances) == 0:
        return None
    tri_values = np.zeros((scene.num_triangles, 3), np.float64)
    tri_mask = np.zeros(scene.num_triangles, bool)
    components, attribute = None, ""
    for k, path in enumerate(instances.instancer_paths):
        found = _read_prim_values(stage, path, candidates, element, time, messages)
        if found is None:
            continue
        values, interpolation, attribute, c = found
        members = np.flatnonzero(instances.instance_instancer == k)
        if interpolation == UsdGeom.Tokens.constant or len(values) != len(members):
            messages.append(f"{attribute}: {len(values)} values for {len(members)} instances; skipped")
            continue
        components = c
        per_instance = np.zeros((len(instances), 3), np.float64)
        per_instance[members, :c] = values
        tris = np.flatnonzero(np.isin(scene.tri_instance, members) & ~has)
        tri_values[tris] = per_instance[scene.tri_instance[tris]]
        tri_mask[tris] = True
    if not tri_mask.any():
        return None
    return tri_values[:, :components], tri_mask, components, attribute


# ---------------------------------------------------------------------------
# Cameras


def camera_from_stage(stage: Usd.Stage, path: str, scene: Scene, time: float | None = None) -> render.Camera:
    """A render.Camera from the UsdGeom.Camera at ``path`` (focal length, apertures, offsets, transform)."""
    prim = stage.GetPrimAtPath(path) if Sdf.Path.IsValidPathString(path) else None
    if not prim:
        cameras = [str(p.GetPath()) for p in stage.Traverse() if p.IsA(UsdGeom.Camera)]
        raise UsageError(f"--camera {path}: no such prim (cameras in the stage: {', '.join(cameras) or 'none'})")
    if not prim.IsA(UsdGeom.Camera):
        raise UsageError(f"--camera {path}: is a {prim.GetTypeName() or 'typeless prim'}, not a Camera")
    gf_camera = UsdGeom.Camera(prim).GetCamera(_timecode(time))
    if gf_camera.horizontalAperture <= 0 or gf_camera.verticalAperture <= 0 or gf_camera.focalLength <= 0:
        raise UsageError(f"{path}: focal length {gf_camera.focalLength} and apertures "
                         f"{gf_camera.horizontalAperture} x {gf_camera.verticalAperture} must be positive")
    matrix = np.array(gf_camera.transform, np.float64)
    matrix[3, :3] -= scene.origin
    return render.Camera(
        camera_to_world=matrix, focal_length=float(gf_camera.focalLength),
        horizontal_aperture=float(gf_camera.horizontalAperture),
        vertical_aperture=float(gf_camera.verticalAperture),
        horizontal_aperture_offset=float(gf_camera.horizontalApertureOffset),
        vertical_aperture_offset=float(gf_camera.verticalApertureOffset),
        projection="orthographic" if gf_camera.projection == Gf.Camera.Orthographic else "perspective")


# ---------------------------------------------------------------------------
# Probes and grids


@dataclass
class Spheres:
    centers: np.ndarray
    """(S, 3) float32 scene-local."""
    colors: np.ndarray
    """(S, 3) float32 linear colour (headlight-shaded)."""
    sh: np.ndarray | None = None
    """(S, 9, 3) float32 SH irradiance coefficients (probes), evaluated at each pixel's sphere normal."""
    condon_shortley: bool = False
    source: str = ""


def find_prims(stage: Usd.Stage, type_names: tuple[str, ...]) -> list[Usd.Prim]:
    return [p for p in stage.Traverse() if p.GetTypeName() in type_names]


def _to_local(stage, prim, points: np.ndarray, scene: Scene, time) -> np.ndarray:
    world = np.array(UsdGeom.Xformable(prim).ComputeLocalToWorldTransform(_timecode(time)), np.float64) \
        if prim.IsA(UsdGeom.Xformable) else np.eye(4)
    homogeneous = np.c_[np.asarray(points, np.float64).reshape(-1, 3), np.ones(len(points))]
    return ((homogeneous @ world)[:, :3] - scene.origin).astype(np.float32)


def probe_spheres(stage: Usd.Stage, scene: Scene, time) -> Spheres | None:
    """Probe positions of every LightProbeCloud, with their SH coefficients when present."""
    centers, sh, sources = [], [], []
    condon_shortley = False
    for prim in find_prims(stage, PROBE_TYPES):
        positions = prim.GetAttribute("probePositions").Get(_timecode(time)) if prim.HasAttribute(
            "probePositions") else None
        if not positions:
            continue
        positions = np.asarray(positions, np.float64).reshape(-1, 3)
        centers.append(_to_local(stage, prim, positions, scene, time))
        coefficients = prim.GetAttribute("shCoefficients").Get(_timecode(time)) if prim.HasAttribute(
            "shCoefficients") else None
        coefficients = np.asarray(coefficients if coefficients is not None else [], np.float32).reshape(-1, 3)
        sh.append(coefficients.reshape(len(positions), 9, 3) if len(coefficients) == 9 * len(positions)
                  else np.zeros((len(positions), 9, 3), np.float32))
        basis = prim.GetAttribute("shBasis").Get() if prim.HasAttribute("shBasis") else None
        condon_shortley = condon_shortley or basis == "realOrthonormalCondonShortley"
        sources.append(str(prim.GetPath()))
    if not centers:
        return None
    points = np.concatenate(centers)
    return Spheres(points, np.full((len(points), 3), 0.8, np.float32), np.concatenate(sh), condon_shortley,
                   ", ".join(sources))


def decode_rgb9e5(packed: np.ndarray) -> np.ndarray:
    """(N,) uint32 RGB9E5 -> (N, 3) float32: 9-bit mantissas (R low bits) and a 5-bit exponent, bias 15."""
    packed = np.asarray(packed, np.uint32)
    mantissa = np.stack([(packed >> shift) & 0x1FF for shift in (0, 9, 18)], axis=1).astype(np.float32)
    exponent = ((packed >> 27) & 0x1F).astype(np.float32)
    return mantissa * np.exp2(exponent - 15.0 - 9.0)[:, None]


def grid_spheres(stage: Usd.Stage, scene: Scene, time) -> Spheres | None:
    """Vertices of every IrradianceVectorGrid, coloured by the mean of their decoded vectors."""
    centers, colors, sources = [], [], []
    for prim in find_prims(stage, GRID_TYPES):
        def get(name, default=None):
            attr = prim.GetAttribute(name)
            value = attr.Get(_timecode(time)) if attr else None
            return default if value is None else value
        resolution = np.asarray(get("resolution", (0, 0, 0)), np.int64)
        if (resolution <= 0).any():
            continue
        origin = np.asarray(get("gridOrigin", (0, 0, 0)), np.float64)
        cell = np.asarray(get("cellSize", (1, 1, 1)), np.float64)
        k, j, i = np.meshgrid(*(np.arange(n) for n in resolution[::-1]), indexing="ij")
        points = origin + np.stack([i.ravel(), j.ravel(), k.ravel()], axis=1) * cell  # x fastest
        packed = np.asarray(get("colorsRGB9E5", []), np.uint32)
        per_vertex = int(get("vectorsPerVertex", 6))
        if per_vertex > 0 and len(packed) == len(points) * per_vertex:
            color = decode_rgb9e5(packed).reshape(len(points), per_vertex, 3).mean(axis=1)
        else:
            color = np.full((len(points), 3), 0.8, np.float32)
        centers.append(_to_local(stage, prim, points, scene, time))
        colors.append(color.astype(np.float32))
        sources.append(str(prim.GetPath()))
    if not centers:
        return None
    return Spheres(np.concatenate(centers), np.concatenate(colors), None, False, ", ".join(sources))


def sh_irradiance(sh: np.ndarray, normals: np.ndarray, condon_shortley: bool = False) -> np.ndarray:
    """(N, 3) value of L2 SH ``sh`` ((N, 9, 3)) at unit ``normals`` ((N, 3)), real orthonormal basis."""
    x, y, z = (np.asarray(normals, np.float32)[:, k] for k in range(3))
    c = SH_BASIS_L2
    sign = -1.0 if condon_shortley else 1.0
    basis = np.stack([np.full_like(x, c[0]), sign * c[1] * y, c[2] * z, sign * c[3] * x, c[4] * x * y,
                      sign * c[5] * y * z, c[6] * (3 * z * z - 1), sign * c[7] * x * z, c[8] * (x * x - y * y)],
                     axis=1)
    return np.einsum("nk,nkc->nc", basis, sh)


# ---------------------------------------------------------------------------
# Images


def parse_size(text: str) -> tuple[int, int]:
    match = re.fullmatch(r"\s*(\d+)\s*[xX]\s*(\d+)\s*", text or "")
    if not match:
        raise UsageError(f"--size {text!r}: expected WIDTHxHEIGHT, e.g. 640x480")
    width, height = int(match[1]), int(match[2])
    if not (1 <= width <= 16384 and 1 <= height <= 16384):
        raise UsageError(f"--size {text}: width and height must be within 1..16384")
    return width, height


def write_image(path: str, image: render.Image, value_name: str = "value") -> str:
    """PNG (8-bit display colour) or EXR (float32: R, G, B linear view, A coverage, then the raw value)."""
    import OpenImageIO as oiio

    suffix = Path(path).suffix.lower()
    Path(path).parent.mkdir(parents=True, exist_ok=True)
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
        pixels = render.to_uint8(image.display)
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


# ---------------------------------------------------------------------------
# The command


def preview(stage: str | Usd.Stage, output: str, *, camera: str | None = None, channel: str | None = None,
            time: float | None = None, size: tuple[int, int] = (640, 480), exposure: float | None = None,
            style: str = "auto", value_range: tuple[float, float] | None = None, legend: bool = True,
            wire: bool = False, probes: bool = False, grid: bool = False, compare: str | None = None,
            orbit: tuple[float, float] | None = None, device: str = "cpu") -> dict:
    """Render ``stage`` to ``output`` (.png or .exr); returns a report (what was drawn, timings, RMS).

    camera : path of a UsdGeom.Camera, or None for the automatic three-quarter view.
    orbit : (azimuth, elevation) in degrees for the automatic view (azimuth from the stage's front
        axis, +Z for Y-up and -Y for Z-up, towards +X); None tries the front, back and side views
        and keeps the one that sees the most surface.
    """
    import time as clock

    started = clock.perf_counter()
    if camera and orbit is not None:
        raise UsageError("--camera and --orbit exclude each other (--orbit places the automatic camera)")
    if style not in STYLES:
        raise UsageError(f"--style {style!r}: expected one of {', '.join(STYLES)}")
    width, height = size
    timings: dict[str, float] = {}
    mark = [clock.perf_counter()]

    def lap(name: str) -> None:
        now = clock.perf_counter()
        timings[name] = now - mark[0]
        mark[0] = now

    stage_obj = _open(stage)
    scene = extract_scene(stage_obj, time=time)
    report: dict = {"output": output, "messages": list(scene.warnings), "timings": timings}
    lap("read_stage")
    if scene.num_triangles == 0:
        report["messages"].append("the stage has no renderable meshes; the image shows only the background")

    data = read_channel(stage_obj, scene, channel, time) if channel else None
    lap("read_channel")
    if data is not None:
        report["messages"] += data.messages
        report["attributes"] = data.attributes
    mode = "albedo"
    if data is not None:
        mode = style if style != "auto" else ("falsecolor" if data.components == 1 else "shaded")
        if mode == "falsecolor" and data.components != 1:
            raise UsageError(f"--style falsecolor needs a scalar channel; {channel} has 3 components")
    lo, hi = (value_range if value_range is not None else ((data.lo, data.hi) if data is not None else (0.0, 1.0)))
    if value_range is not None and not lo < hi:
        raise UsageError(f"--range {lo} {hi}: the low end must be below the high end")
    panel = render.legend_width(lo, hi, height) if mode == "falsecolor" and legend else 0
    view_width = width - panel
    if view_width < 1:
        raise UsageError(f"--size {width}x{height}: too narrow for the legend ({panel} px); use --no-legend")

    tracer = Tracer.from_scene(scene, device=device)
    lap("build_bvh")
    if camera:
        cam = camera_from_stage(stage_obj, camera, scene, time).conformed(view_width, height)
        report["camera"] = camera
    elif orbit is not None:
        if not -90.0 <= orbit[1] <= 90.0:
            raise UsageError(f"--orbit {orbit[0]:g} {orbit[1]:g}: elevation must be within -90..90 degrees")
        lo_b, hi_b = scene.bounds
        cam = render.auto_camera(lo_b, hi_b, scene.up_axis, view_width, height, azimuth_deg=orbit[0],
                                 elevation_deg=orbit[1]).conformed(view_width, height)
        report["camera"] = f"auto (azimuth {orbit[0]:g}, elevation {orbit[1]:g})"
    else:
        cam = render.choose_auto_camera(tracer, scene, view_width, height)
        report["camera"] = "auto"

    spheres = _extra_spheres(stage_obj, scene, time, probes, grid, report["messages"])
    lap("camera")
    frame = render.trace_frame(
        tracer, scene, cam, view_width, height,
        corner_values=data.corner_values if data is not None else None, wire=wire,
        spheres=spheres.centers if spheres is not None else None,
        sphere_radius=SPHERE_RADIUS_RELATIVE * max(scene.diagonal, 1e-9))
    sphere_colors = None
    if spheres is not None:
        sphere_colors = spheres.colors
        on = frame.sphere >= 0
        if spheres.sh is not None and on.any() and np.any(spheres.sh):
            index = frame.sphere[on]
            # SH irradiance E(n) at the sphere normal, shown as a Lambertian sphere of albedo 0.8:
            # L = 0.8 E / pi. Spheres without SH keep their colour under the headlight.
            lit = 0.8 * np.maximum(sh_irradiance(spheres.sh[index], frame.sphere_normal[on],
                                                 spheres.condon_shortley), 0.0) / np.pi
            plain = spheres.colors[index] * (0.25 + 0.75 * frame.facing[on])[:, None]
            per_pixel = np.zeros((height, view_width, 3), np.float32)
            per_pixel[on] = np.where(np.any(spheres.sh[index] != 0, axis=(1, 2))[:, None], lit, plain)
            sphere_colors = per_pixel
    image = render.shade(
        frame, scene.tri_albedo, tri_has_value=data.tri_has_value if data is not None else None,
        channels=data.components if data is not None else 1, style=mode, value_range=(lo, hi),
        label=channel or "", exposure=exposure, irradiance=bool(data and data.irradiance), legend=legend,
        legend_panel=panel if panel else None, sphere_colors=sphere_colors)
    lap("render")

    if compare:
        reference = read_display_image(compare)
        ours = render.to_uint8(image.display).astype(np.float32) / np.float32(255.0)
        try:
            panel_image, rms = render.compare_images(reference, ours)
        except ValueError as error:
            raise UsageError(f"--compare {compare}: {error}") from None
        report["rms"] = rms
        image = render.Image(display=panel_image, linear=render.srgb_decode(panel_image),
                             value=np.zeros(panel_image.shape[:2] + (1,), np.float32),
                             coverage=np.ones(panel_image.shape[:2], np.float32), view_width=panel_image.shape[1],
                             exposure=image.exposure, legend=image.legend)
    write_image(output, image, channel or "value")
    lap("write_image")
    report.update({
        "mode": mode, "size": [width, height], "view_width": view_width, "exposure": image.exposure,
        "range": [lo, hi] if mode == "falsecolor" else None, "triangles": scene.num_triangles,
        "spheres": 0 if spheres is None else len(spheres.centers), "seconds": clock.perf_counter() - started,
    })
    report["image"] = image
    return report


def _open(stage: str | Usd.Stage) -> Usd.Stage:
    if isinstance(stage, Usd.Stage):
        return stage
    if not Path(stage).exists():
        raise UsageError(f"{stage}: no such file")
    try:
        opened = Usd.Stage.Open(str(stage))
    except Tf.ErrorException as error:
        raise UsageError(f"{stage}: cannot be read as USD ({' '.join(str(error).split())[-200:]})") from None
    if opened is None:
        raise UsageError(f"{stage}: cannot be read as USD")
    return opened


def _extra_spheres(stage, scene: Scene, time, probes: bool, grid: bool, messages: list) -> Spheres | None:
    found = []
    if probes:
        spheres = probe_spheres(stage, scene, time)
        if spheres is None:
            messages.append("--probes: no LightProbeCloud prim with probePositions in the stage; nothing to draw")
        else:
            found.append(spheres)
    if grid:
        spheres = grid_spheres(stage, scene, time)
        if spheres is None:
            messages.append("--grid: no IrradianceVectorGrid prim with a resolution in the stage; nothing to draw")
        else:
            found.append(spheres)
    if not found:
        return None
    if len(found) == 1:
        return found[0]
    sh = [s.sh if s.sh is not None else np.zeros((len(s.centers), 9, 3), np.float32) for s in found]
    return Spheres(np.concatenate([s.centers for s in found]), np.concatenate([s.colors for s in found]),
                   np.concatenate(sh), found[0].condon_shortley, ", ".join(s.source for s in found))
