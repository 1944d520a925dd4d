"""Baked channels (``--channel``) mapped onto the Scene's triangles as per-corner values.

The primvars are read by ``usdbake.stages.baked_data.read_primvar``; this
module only names, selects, sums and maps them (numpy).

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
- A channel no prim has as a primvar but some mesh has as a lightmap
  (``bake:lightmap:<name>:file``, the texture target) is read from its image:
  the corners carry the lightmap UVs (and the page), and ``sample_textures``
  reads the image bilinearly (repeat wrap, as the bake wires it) at each
  pixel's interpolated UV.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field

import numpy as np

from ..core.errors import UsageError
from ..core.scene import Scene
from ..stages.baked_data import PrimvarValues, has_attribute, read_lightmap, read_lightmap_image, read_primvar

IRRADIANCE_PREFIXES = ("irradiance", "daylight", "radiosity")
"""Channels whose last name part starts with one of these are irradiance (W/m^2), shaded as albedo * E / pi."""


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
    textures: list[np.ndarray] | None = None
    """Lightmap channel: the images ((H, W, C), row 0 at v = 0); ``corner_values`` then hold (u, v, image)."""


def attribute_candidates(name: str) -> list[str]:
    """Property names to try for a channel name, in order."""
    if name.startswith("primvars:"):
        return [name]
    if name.startswith("bake:"):
        return [f"primvars:{name}"]
    return [f"primvars:bake:{name}", f"primvars:{name}"]


_ELEMENT = re.compile(r"^(?P<name>[^\[\]]+)\[(?P<index>\d+)\]$")


def read_channel(stage, scene: Scene, name: str, time: float | None = None) -> Channel:
    """Read channel ``name`` (see the module docstring) of the Usd.Stage ``stage`` onto ``scene``'s triangles."""
    parts = [p.strip() for p in name.split("+")]
    if not all(parts):
        raise UsageError(f"--channel {name!r}: empty term")

    def exists(part: str) -> bool:
        return has_attribute(stage, scene.prim_paths, attribute_candidates(part))

    if len(parts) == 1 and not exists(parts[0]) and \
            has_attribute(stage, scene.prim_paths, [f"bake:lightmap:{parts[0]}:file"]):
        return _read_lightmaps(stage, scene, parts[0], time)

    if len(parts) == 1 and parts[0] == "irradiance" and not exists("irradiance"):
        if exists("irradianceDirect"):
            parts = ["irradianceDirect", "irradianceIndirect"] if exists("irradianceIndirect") \
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


def _read_single(stage, scene: Scene, name: str, time: float | None) -> Channel:
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
        values, primvar = found
        attribute, c = primvar.attribute, primvar.components
        if components is None:
            components = c
        elif c != components:
            raise UsageError(f"{attribute}: {c} components where other prims have {components}")
        mapped = _map_to_corners(scene, m, tris, values, primvar, messages)
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
        finite = tri_values[tri_mask][np.isfinite(tri_values[tri_mask]).all(axis=1)]
        if len(finite):
            lows.append(finite.min())
            highs.append(finite.max())

    if not has.any():
        tried = " or ".join(candidates)
        raise UsageError(f"no prim in {scene.source or 'the stage'} has {tried}"
                         + (f" at time {time:g}" if time is not None else "")
                         + "; bake it first (usdbake bake ...) or check `usdbake inspect`")
    if not lows:
        raise UsageError(f"{', '.join(attributes)}: no finite value (every value is NaN or infinite)")
    return Channel(name=name, corner_values=corners, tri_has_value=has, components=components or 1,
                   lo=float(min(lows)), hi=float(max(highs)),
                   irradiance=base_name.split(":")[-1].startswith(IRRADIANCE_PREFIXES),
                   attributes=attributes, messages=messages)


def _read_prim_values(stage, path: str, candidates: list[str], element: int | None, time, messages):
    """(values (N, C) float64 of element ``element``, the PrimvarValues read) of the first candidate on ``path``."""
    primvar = read_primvar(stage, path, candidates, time)
    if primvar is None:
        return None
    if primvar.values is None:
        messages.append(f"{primvar.attribute}: no value" + (f" at time {time:g}" if time is not None else ""))
        return None
    return _select_element(primvar.values, primvar.element_size, element, primvar.attribute, messages), primvar


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


def _map_to_corners(scene: Scene, m: int, tris: np.ndarray, values: np.ndarray, primvar: PrimvarValues,
                    messages) -> np.ndarray | None:
    """(len(tris), 3, C) values at the corners of prim m's triangles, or None (with a message)."""
    attribute, interpolation = primvar.attribute, primvar.interpolation
    span = scene.prim_points(m)
    num_points = span.stop - span.start
    face_count = int(scene.prim_face_count[m])
    if interpolation in ("vertex", "varying"):
        if len(values) != num_points:
            messages.append(f"{attribute}: {len(values)} {interpolation} values for {num_points} points; skipped")
            return None
        return values[scene.tri_vertices[tris] - span.start]
    if interpolation == "uniform":
        if len(values) != face_count:
            messages.append(f"{attribute}: {len(values)} uniform values for {face_count} faces; skipped")
            return None
        return np.repeat(values[scene.tri_face[tris]][:, None, :], 3, axis=1)
    if interpolation == "constant":
        return np.broadcast_to(values[0], (len(tris), 3, values.shape[1]))
    if interpolation == "faceVarying":
        counts, indices = primvar.face_vertex_counts, primvar.face_vertex_indices
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


def _read_lightmaps(stage, scene: Scene, name: str, time: float | None) -> Channel:
    """A lightmap channel (module docstring): per-corner UVs and pages, the images, their value range."""
    corners = np.zeros((scene.num_triangles, 3, 3), np.float32)
    has = np.zeros(scene.num_triangles, bool)
    textures: list[np.ndarray] = []
    files: dict[str, int] = {}
    attributes, messages = [], []
    order = np.argsort(scene.tri_prim, kind="stable")
    bounds = np.searchsorted(scene.tri_prim[order], np.arange(len(scene.prim_paths) + 1))
    for m, path in enumerate(scene.prim_paths):
        tris = order[bounds[m]:bounds[m + 1]]
        lightmap = read_lightmap(stage, path, name, time) if len(tris) else None
        if lightmap is None:
            continue
        mapped = _map_to_corners(scene, m, tris, lightmap.uvs.values, lightmap.uvs, messages)
        if mapped is None:
            continue
        page = files.setdefault(lightmap.file, len(textures))
        if page == len(textures):
            textures.append(read_lightmap_image(lightmap.file))
        corners[tris, :, :2] = mapped
        corners[tris, :, 2] = page
        has[tris] = True
        attributes.append(lightmap.attribute)
    components = {image.shape[2] for image in textures}
    if len(components) > 1:
        raise UsageError(f"--channel {name}: its lightmaps have {sorted(components)} channels")
    values = np.concatenate([image.reshape(-1, image.shape[2]) for image in textures])
    values = values[np.isfinite(values).all(axis=1)]
    return Channel(name=name, corner_values=corners, tri_has_value=has, components=min(components.pop(), 3),
                   lo=float(values.min()) if len(values) else 0.0, hi=float(values.max()) if len(values) else 1.0,
                   irradiance=name.startswith(IRRADIANCE_PREFIXES), attributes=attributes, messages=messages,
                   textures=textures)


def sample_textures(channel: Channel, uv_page: np.ndarray, covered: np.ndarray) -> np.ndarray:
    """(H, W, 3) float32 the channel's images sampled bilinearly (repeat wrap; texel centres at
    ((x + 0.5) / W, (y + 0.5) / H)) at each pixel's interpolated (u, v, page), 0 where not ``covered``."""
    out = np.zeros(uv_page.shape[:2] + (3,), np.float32)
    pages = np.rint(uv_page[..., 2]).astype(np.int64)
    for page, image in enumerate(channel.textures or []):
        mask = covered & (pages == page)
        if not mask.any():
            continue
        height, width, count = image.shape
        x = uv_page[..., 0][mask] * width - 0.5
        y = uv_page[..., 1][mask] * height - 0.5
        x0, y0 = np.floor(x).astype(np.int64), np.floor(y).astype(np.int64)
        fx, fy = (x - x0)[:, None], (y - y0)[:, None]
        def texel(xi, yi):
            return image[np.mod(yi, height), np.mod(xi, width)]
        value = ((1 - fx) * (1 - fy) * texel(x0, y0) + fx * (1 - fy) * texel(x0 + 1, y0)
                 + (1 - fx) * fy * texel(x0, y0 + 1) + fx * fy * texel(x0 + 1, y0 + 1))
        out[mask, :min(count, 3)] = value[:, :3]
    return out


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
        values, primvar = found
        attribute = primvar.attribute
        members = np.flatnonzero(instances.instance_instancer == k)
        native = instances.is_native(k)  # a native instance's root: its one value is constant
        if (primvar.interpolation == "constant") != native or len(values) != len(members):
            messages.append(f"{attribute}: {len(values)} values for {len(members)} instances; skipped")
            continue
        components = primvar.components
        per_instance = np.zeros((len(instances), 3), np.float64)
        per_instance[members, :components] = values
        tris = np.flatnonzero(np.isin(scene.tri_instance, members) & ~has)
        tri_values[tris] = per_instance[scene.tri_instance[tris]]
        tri_mask[tris] = True
    if not tri_mask.any():
        return None
    return tri_values[:, :components], tri_mask, components, attribute
