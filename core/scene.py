"""The Scene: a flat, world-space, struct-of-arrays view of a USD stage.

Built once per run by ``usdbake.stages.extract`` and handed read-only to every
processor. No pxr here: processors see numpy arrays only.

Positions are stored relative to ``origin`` (float64), so a stage placed
1e6 units from the world origin keeps full float32 precision around its own
geometry; ``world = origin + points``.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass, field, fields
from typing import Any

import numpy as np

# Light kinds, in the order of UsdLux types we read.
LIGHT_DISTANT, LIGHT_DOME, LIGHT_SPHERE, LIGHT_RECT, LIGHT_DISK = range(5)
LIGHT_KIND_NAMES = ("distant", "dome", "sphere", "rect", "disk")


def _readonly(array: np.ndarray) -> np.ndarray:
    array = np.ascontiguousarray(array)
    array.flags.writeable = False
    return array


_NO_DOME_TEXTURE = _readonly(np.zeros((0, 0, 3), np.float32))


@dataclass(frozen=True)
class Lights:
    """UsdLux lights, one row each."""

    light_paths: tuple[str, ...] = ()
    light_kind: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int32))
    """(L,) int32, one of LIGHT_DISTANT .. LIGHT_DISK."""
    light_radiance: np.ndarray = field(default_factory=lambda: np.zeros((0, 3), np.float32))
    """(L, 3) float32 intensity * 2^exposure * color (normalize already applied)."""
    light_position: np.ndarray = field(default_factory=lambda: np.zeros((0, 3), np.float32))
    """(L, 3) float32 position relative to Scene.origin."""
    light_direction: np.ndarray = field(default_factory=lambda: np.zeros((0, 3), np.float32))
    """(L, 3) float32 unit emission direction (the light's -Z axis in world space)."""
    light_size: np.ndarray = field(default_factory=lambda: np.zeros((0, 2), np.float32))
    """(L, 2) float32 radius (sphere, disk), width/height (rect) or angle in degrees (distant)."""
    dome_source: Any = None
    """Where ``dome_texture`` comes from: None (no textured dome), an (H, W, 3) float32 array, or a
    zero-argument callable that reads it on first use and keeps it (``stages.sky_dome.DomeTexture``), so
    a run whose processors never read the lights (ambient occlusion) never reads the file."""
    dome_to_local: np.ndarray = field(default_factory=lambda: np.eye(3, dtype=np.float64))
    """(3, 3) float64 rotation taking a world direction into the textured dome's frame (row vectors)."""
    textured_dome: int = -1
    """Row of the DomeLight whose texture ``dome_texture`` is; the other domes stay uniform. -1: every dome
    is modulated by it (lights built as arrays, without a stage)."""

    @property
    def dome_texture(self) -> np.ndarray:
        """(H, W, 3) float32 linear RGB lat-long map of the (first) textured DomeLight, empty if none: it
        modulates the domes' radiance by direction (OpenEXR lat-long layout, +Y the pole of the dome).
        Read-only; read from ``dome_source`` on first access (the lights facet's fingerprint reads it)."""
        source = self.dome_source
        if source is None:
            return _NO_DOME_TEXTURE
        return _readonly(np.asarray(source() if callable(source) else source, np.float32))

    def __len__(self) -> int:
        return len(self.light_paths)


@dataclass(frozen=True)
class Instances:
    """UsdGeom.PointInstancer instances, kept as instances (issue: displacement fields)."""

    instancer_paths: tuple[str, ...] = ()
    prototype_paths: tuple[str, ...] = ()
    instance_instancer: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int32))
    """(I,) int32 index into instancer_paths."""
    instance_prototype: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int32))
    """(I,) int32 index into prototype_paths."""
    instance_transforms: np.ndarray = field(default_factory=lambda: np.zeros((0, 4, 4), np.float64))
    """(I, 4, 4) float64 prototype-to-world matrices (row-vector convention, as Gf), translation relative to origin."""
    instance_times: np.ndarray = field(default_factory=lambda: np.zeros(0, np.float64))
    """(F,) float64 authored time codes of the instancers' positions/orientations/scales (empty if none)."""
    instance_transforms_at_times: np.ndarray = field(default_factory=lambda: np.zeros((0, 0, 4, 4), np.float64))
    """(F, I, 4, 4) float64 instance_transforms at each of instance_times (same instances, same order)."""
    instance_index: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int32))
    """(I,) int32 row of the instance in its instancer's authored arrays (protoIndices; masked rows are skipped)."""
    instancer_instance_count: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int32))
    """(N,) int32 authored instances per instancer (len(protoIndices)), masked ones included."""
    instancer_native: np.ndarray = field(default_factory=lambda: np.zeros(0, bool))
    """(N,) bool: the 'instancer' is a native instance's root prim (one instance, of its USD prototype),
    not a PointInstancer. Per-instance data goes on it as a constant primvar."""
    prototype_targets: tuple[tuple[str, ...], ...] = ()
    """Per prototype: the prims its per-prototype data (a displacement field) is authored on: the
    PointInstancer prototype itself, or every root of a native prototype (its USD prototype is
    read-only). Empty: each prototype's own path."""

    def targets(self, prototype: int) -> tuple[str, ...]:
        """Where per-prototype data of ``prototype`` is authored (``prototype_targets``)."""
        if len(self.prototype_targets) == len(self.prototype_paths):
            return self.prototype_targets[prototype]
        return (self.prototype_paths[prototype],)

    def is_native(self, instancer: int) -> bool:
        return bool(len(self.instancer_native) == len(self.instancer_paths) and self.instancer_native[instancer])

    def __len__(self) -> int:
        return len(self.instance_prototype)


@dataclass(frozen=True)
class Scene:
    """Triangulated world-space geometry, materials, lights and instances.

    Vertices (``points``) are kept per source prim, in the prim's authored
    point order, so vertex-interpolated results map straight back onto the
    prim's ``points``. Instanced geometry is flattened into the triangle
    arrays (so it occludes) and marked with ``tri_instance``.
    """

    points: np.ndarray
    """(P, 3) float32 vertex positions relative to ``origin``."""
    tri_vertices: np.ndarray
    """(T, 3) int32 indices into ``points``."""
    tri_normals: np.ndarray
    """(T, 3) float32 unit geometric normals (zero for degenerate triangles)."""
    tri_areas: np.ndarray
    """(T,) float32 triangle areas in stage units^2."""
    tri_albedo: np.ndarray
    """(T, 3) float32 diffuse reflectance in [0, 1]."""
    tri_emission: np.ndarray
    """(T, 3) float32 emitted radiance (emissiveColor)."""
    tri_prim: np.ndarray
    """(T,) int32 index into ``prim_paths``."""
    tri_face: np.ndarray
    """(T,) int32 index of the authored polygon within its prim."""
    tri_instance: np.ndarray
    """(T,) int32 point-instancer instance index, -1 for ordinary geometry."""
    tri_double_sided: np.ndarray
    """(T,) bool."""
    point_prim: np.ndarray
    """(P,) int32 index into ``prim_paths``."""
    prim_paths: tuple[str, ...]
    """Source mesh prim paths (an instanced prototype appears once per instance)."""
    prim_point_start: np.ndarray
    """(M + 1,) int64: the points of prim m are points[start[m]:start[m + 1]]."""
    prim_face_count: np.ndarray
    """(M,) int32 number of authored polygons per prim."""
    prim_writable: np.ndarray
    """(M,) bool: False for instance proxies and point-instancer prototypes (read-only in USD)."""
    prim_skip: np.ndarray
    """(M,) bool: the prim carries ``bake:skip = true``."""
    prim_surface: tuple[str, ...]
    """Path of the bound UsdPreviewSurface shader per prim, '' if none."""
    lights: Lights = field(default_factory=Lights)
    instances: Instances = field(default_factory=Instances)
    origin: np.ndarray = field(default_factory=lambda: np.zeros(3, np.float64))
    """(3,) float64 world position of the local frame the points are stored in."""
    prim_to_world: np.ndarray = field(default_factory=lambda: np.zeros((0, 4, 4), np.float64))
    """(M, 4, 4) float64 local-to-world matrix per prim (row-vector convention, as Gf), translation
    relative to ``origin``: ``points[prim_points(m)] ~ [local, 1] @ prim_to_world[m]``."""
    up_axis: str = "Y"
    meters_per_unit: float = 1.0
    probe_volumes: np.ndarray = field(default_factory=lambda: np.zeros((0, 2, 3), np.float64))
    """(K, 2, 3) float64 (min, max) world bounds, relative to ``origin``, of the prims with ProbeVolumeAPI:
    where light volumes (the irradiance grid) go; none: the whole scene."""
    site: dict = field(default_factory=dict)
    """The stage's place, when its layer stack says (a ``usdbake sky`` layer): latitude, longitude (degrees),
    timezone (hours east of UTC) and the layer's identifier; empty when unknown."""
    time_code: float | None = None
    """USD time code the stage was read at; None for the default time."""
    source: str = ""
    """Identifier of the stage's root layer (for messages only)."""
    warnings: tuple[str, ...] = ()
    """What extraction left out and why (holes, degenerate faces), for people."""
    tri_corner: np.ndarray | None = None
    """(T, 3) int32 face-vertex slot of each triangle corner: its position in the prim's authored
    faceVertexIndices, in ``tri_vertices`` corner order (faceVarying data of corner k is
    ``data[tri_corner[:, k]]``). -1 where unknown (a Scene not read from USD: the default)."""

    prim_instance_roots: tuple[tuple[str, ...], ...] | None = None
    """Per prim: the native instances (instanceable prims) it is an instance proxy under, outermost
    first; () for a prim that is not (the default). Where per-instance results go, and what
    de-instancing a receiver unsets."""
    tri_transmittance: np.ndarray | None = None
    """(T,) float32 visible transmittance at normal incidence in [0, 1] (glazing: ``bake:transmittance``, or
    1 - opacity of a UsdPreviewSurface), 0 for opaque faces (the default)."""

    tri_st: np.ndarray | None = None
    """(T, 3, 2) float32 UV of each triangle corner in the prim's main UV set (``prim_st``), in ``tri_vertices``
    corner order, finite; 0 where the prim has none (the default)."""
    prim_st: tuple[str, ...] | None = None
    """Per prim: the primvar ``tri_st`` was read from ('st', ...), '' when none."""
    tri_lightmap_uv: np.ndarray | None = None
    """(T, 3, 2) float32 UV of each corner in the prim's dedicated lightmap UV set (``prim_lightmap_uv``),
    finite; 0 where it has none (the default)."""
    prim_lightmap_uv: tuple[str, ...] | None = None
    """Per prim: the primvar ``tri_lightmap_uv`` was read from ('st1', ...), '' when none."""
    prim_subset_surfaces: tuple[tuple[tuple[str, str], ...], ...] | None = None
    """Per prim: (GeomSubset path, its bound UsdPreviewSurface shader path) of each material-bound GeomSubset
    whose material has one; None for a Scene not read from USD (the default)."""
    prim_corner_count: np.ndarray | None = None
    """(prims,) int64 face-vertex slots of each prim (len(faceVertexIndices)): the length of its faceVarying
    primvars; by default one past the largest slot its triangles use."""

    def __post_init__(self) -> None:
        if self.prim_instance_roots is None:
            object.__setattr__(self, "prim_instance_roots", ((),) * len(self.prim_paths))
        if self.tri_corner is None:
            object.__setattr__(self, "tri_corner", np.full((len(self.tri_vertices), 3), -1, np.int32))
        if self.prim_corner_count is None:
            counts = np.zeros(len(self.prim_paths), np.int64)
            if len(self.tri_prim):
                np.maximum.at(counts, self.tri_prim, self.tri_corner.max(axis=1).astype(np.int64) + 1)
            object.__setattr__(self, "prim_corner_count", counts)
        for uvs, names in (("tri_st", "prim_st"), ("tri_lightmap_uv", "prim_lightmap_uv")):
            if getattr(self, uvs) is None:
                object.__setattr__(self, uvs, np.zeros((len(self.tri_vertices), 3, 2), np.float32))
            if getattr(self, names) is None:
                object.__setattr__(self, names, ("",) * len(self.prim_paths))
        if self.tri_transmittance is None:
            object.__setattr__(self, "tri_transmittance", np.zeros(len(self.tri_vertices), np.float32))
        for f in fields(self):
            value = getattr(self, f.name)
            if isinstance(value, np.ndarray):
                object.__setattr__(self, f.name, _readonly(value))

    @property
    def num_triangles(self) -> int:
        return len(self.tri_vertices)

    @property
    def num_points(self) -> int:
        return len(self.points)

    @property
    def up_vector(self) -> np.ndarray:
        """(3,) float32 unit up direction from the stage's upAxis."""
        return np.array([0, 0, 1] if self.up_axis == "Z" else [0, 1, 0], np.float32)

    @property
    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """(min, max) corners of the points, each (3,) float32."""
        if self.num_points == 0:
            zero = np.zeros(3, np.float32)
            return zero, zero
        return self.points.min(axis=0), self.points.max(axis=0)

    @property
    def diagonal(self) -> float:
        lo, hi = self.bounds
        return float(np.linalg.norm(hi.astype(np.float64) - lo))

    def prim_points(self, prim: int) -> slice:
        return slice(int(self.prim_point_start[prim]), int(self.prim_point_start[prim + 1]))

    def fingerprint(self, facets: tuple[str, ...]) -> str:
        """Content hash of the named facets (dtype, shape and bytes of every array)."""
        digest = hashlib.sha256()
        for facet in facets:
            for name in FACETS[facet]:
                _hash_value(digest, name, _lookup(self, name))
        return digest.hexdigest()


# Which Scene fields each fingerprint facet reads.
FACETS: dict[str, tuple[str, ...]] = {
    "geometry": (
        "points", "tri_vertices", "tri_corner", "tri_prim", "tri_face", "tri_instance", "tri_double_sided",
        "point_prim", "prim_paths", "prim_point_start", "prim_writable", "prim_skip", "prim_instance_roots",
        "origin", "up_axis", "meters_per_unit", "prim_to_world", "probe_volumes",
    ),
    "materials": ("tri_albedo", "tri_emission", "tri_transmittance", "prim_surface", "prim_subset_surfaces"),
    "lights": (
        "lights.light_paths", "lights.light_kind", "lights.light_radiance",
        "lights.light_position", "lights.light_direction", "lights.light_size", "lights.dome_texture",
        "lights.dome_to_local", "lights.textured_dome",
    ),
    "instancers": (
        "instances.instancer_paths", "instances.prototype_paths", "instances.instance_instancer",
        "instances.instance_prototype", "instances.instance_transforms",
        "instances.instance_times", "instances.instance_transforms_at_times",
        "instances.instance_index", "instances.instancer_instance_count", "instances.instancer_native",
        "instances.prototype_targets",
    ),
    "time": ("time_code",),
    "uvs": ("tri_st", "prim_st", "tri_lightmap_uv", "prim_lightmap_uv", "prim_corner_count"),
}


def _lookup(scene: Scene, dotted: str):
    value = scene
    for part in dotted.split("."):
        value = getattr(value, part)
    return value


def _hash_value(digest, name: str, value) -> None:
    digest.update(name.encode())
    if isinstance(value, np.ndarray):
        digest.update(f"{value.dtype.str}{value.shape}".encode())
        digest.update(np.ascontiguousarray(value).tobytes())
    else:
        digest.update(repr(value).encode())
