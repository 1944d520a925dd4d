"""Glazing: sky and sun light through transparent faces, with Radiance's thin-glass angular falloff.

A face whose ``Scene.tri_transmittance`` is above 0 (``bake:transmittance``, or 1 - opacity of its
UsdPreviewSurface; ``stages.materials``) is a pane of glass: a ray that crosses it keeps the pane's
transmittance at the ray's angle of incidence instead of being blocked. The angular falloff follows
Radiance's ``glass`` material (src/rt/m_glass.c, "thin glass surfaces", Ward): the normal-incidence
visible transmittance Tn (VLT) is turned into the transmissivity tn of the glass body, which is
raised to 1/cos(theta_t) along the refracted path, and each polarisation's Fresnel reflectance of the
two surfaces (index 1.52) is summed over the internal reflections.

``Glazing`` splits the scene into an opaque and a glass ray core built from the same points (so the
same ray meets the same geometry in both, and both have the same ``TraceScene.scale``): kernels test
occlusion against ``opaque_tracer.scene`` and multiply by ``segment_transmittance`` over
``glass_tracer.scene``.

Nothing is written to USD here; ``daylight`` and ``annual_daylight`` use it.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass

import numpy as np
import warp as wp

from ...kernels.tracer import Tracer
from ...kernels.traversal import TraceScene, trace_closest

wp.set_module_options({"enable_backward": False, "fuse_fp": False})

GLASS_INDEX = 1.52
"""Refractive index of Radiance's ``glass`` (RINDEX in m_glass.c): the transmissivity formula below holds for it."""

SURFACE_REFLECTANCE = ((GLASS_INDEX - 1.0) / (GLASS_INDEX + 1.0)) ** 2
"""Fresnel reflectance of one air/glass surface at normal incidence, R0 = ((n - 1) / (n + 1))^2 = 0.04258."""

CLEAR_TRANSMITTANCE = (1.0 - SURFACE_REFLECTANCE) / (1.0 + SURFACE_REFLECTANCE)
"""Normal-incidence transmittance of a pane of index 1.52 that absorbs nothing (tn = 1): 0.9183. A larger
VLT has no physical pane; it is given the clear pane's falloff scaled to the VLT (see
``radiance_glass_transmittance``)."""

MAX_CROSSINGS = 16
"""Panes a ray may cross in ``segment_transmittance``; one that meets more is counted as blocked."""

CROSSING_STEP = 1e-5
"""How far past a pane the walk restarts, relative to the larger of the distance travelled and the
coordinates' magnitude: ~170x float32's rounding of the restart point (6e-8 of it), so the pane just
crossed is not met again, and far below the gap of a double glazing (12 mm in a room of 10 m: 1e-3)."""

_TERM = float((1.0 - SURFACE_REFLECTANCE) ** 2)  # Radiance's .9166530661
_TERM_SQUARED = float((1.0 - SURFACE_REFLECTANCE) ** 4)  # .8402528435
_FOUR_R0_SQUARED = float(4.0 * SURFACE_REFLECTANCE ** 2)  # .0072522239 (Radiance's divisor .0036261119 is half)


# -- the angular falloff -------------------------------------------------------------------------------

def _transmissivity(normal_transmittance: np.ndarray) -> np.ndarray:
    """Radiance's tn = (sqrt(.8402528435 + .0072522239 Tn^2) - .9166530661) / .0036261119 / Tn (glass.c), the
    root of R0^2 Tn tn^2 + (1 - R0)^2 tn - Tn = 0, written without the cancellation at small Tn."""
    return 2.0 * normal_transmittance / (_TERM + np.sqrt(_TERM_SQUARED + _FOUR_R0_SQUARED * normal_transmittance ** 2))


def radiance_glass_transmittance(cos_incidence, normal_transmittance) -> np.ndarray:
    """Transmittance of a thin pane at an angle, from its visible transmittance at normal incidence.

    Follows Radiance's ``glass`` material (src/rt/m_glass.c): with cos_t = sqrt(1 - (1 - cos_i^2) / n^2)
    (Snell, n = 1.52), d = tn^(1 / cos_t) the body's transmission along the refracted path,
    r_s = ((cos_i - n cos_t) / (cos_i + n cos_t))^2 and r_p = ((cos_t - n cos_i) / (cos_t + n cos_i))^2,

        T = 1/2 sum_{r in r_s, r_p} (1 - r)^2 d / (1 - r^2 d^2)

    (both polarisations, all internal reflections). At normal incidence T = Tn; at grazing T = 0. A Tn
    above CLEAR_TRANSMITTANCE (Radiance would give tn > 1 and a pole near grazing) takes the clear pane's
    falloff scaled by Tn / CLEAR_TRANSMITTANCE, which is continuous at CLEAR_TRANSMITTANCE.

    Parameters
    ----------
    cos_incidence : array_like
        Cosine of the angle between the ray and the pane's normal (either side: its absolute value is used).
    normal_transmittance : array_like
        Visible transmittance at normal incidence (VLT) in [0, 1]; broadcast against ``cos_incidence``.

    Returns
    -------
    ndarray of float64, the broadcast shape, in [0, 1].
    """
    cos_i = np.clip(np.abs(np.asarray(cos_incidence, np.float64)), 0.0, 1.0)
    vlt = np.clip(np.asarray(normal_transmittance, np.float64), 0.0, 1.0)
    scale = np.where(vlt > CLEAR_TRANSMITTANCE, vlt / CLEAR_TRANSMITTANCE, 1.0)
    tn = np.minimum(_transmissivity(vlt), 1.0)
    n = GLASS_INDEX
    cos_t = np.sqrt(1.0 - (1.0 - cos_i * cos_i) / (n * n))
    d = tn ** (1.0 / cos_t)
    r_s = ((cos_i - n * cos_t) / (cos_i + n * cos_t)) ** 2
    r_p = ((cos_t - n * cos_i) / (cos_t + n * cos_i)) ** 2
    # (1 - r)^2 d / (1 - r^2 d^2) is 0/0 only at r = d = 1 (a clear pane at grazing), where it tends to 0
    through = sum((1.0 - r) ** 2 * d / np.maximum(1.0 - r * r * d * d, np.finfo(np.float64).tiny) for r in (r_s, r_p))
    return np.where((cos_i > 0.0) & (vlt > 0.0), 0.5 * through * scale, 0.0)


@wp.func
def glass_transmittance(cos_i: float, normal_transmittance: float) -> float:
    """Warp twin of ``radiance_glass_transmittance`` (float32): a pane of normal-incidence visible
    transmittance ``normal_transmittance`` crossed at cos(theta_i) = ``cos_i`` (either sign)."""
    c = wp.min(wp.abs(cos_i), 1.0)
    vlt = wp.clamp(normal_transmittance, 0.0, 1.0)
    if c <= 0.0 or vlt <= 0.0:
        return 0.0
    scale = 1.0
    if vlt > wp.static(float(CLEAR_TRANSMITTANCE)):
        scale = vlt / wp.static(float(CLEAR_TRANSMITTANCE))
    tn = 2.0 * vlt / (wp.static(_TERM) + wp.sqrt(wp.static(_TERM_SQUARED) + wp.static(_FOUR_R0_SQUARED) * vlt * vlt))
    tn = wp.min(tn, 1.0)
    n = wp.static(GLASS_INDEX)
    cos_t = wp.sqrt(1.0 - (1.0 - c * c) / (n * n))
    d = wp.pow(tn, 1.0 / cos_t)
    r_s = (c - n * cos_t) / (c + n * cos_t)
    r_s = r_s * r_s
    r_p = (cos_t - n * c) / (cos_t + n * c)
    r_p = r_p * r_p
    through_s = (1.0 - r_s) * (1.0 - r_s) * d / wp.max(1.0 - r_s * r_s * d * d, 1.0e-30)
    through_p = (1.0 - r_p) * (1.0 - r_p) * d / wp.max(1.0 - r_p * r_p * d * d, 1.0e-30)
    return 0.5 * (through_s + through_p) * scale


# -- rays through panes --------------------------------------------------------------------------------

@wp.func
def _max_abs(v: wp.vec3) -> float:
    return wp.max(wp.abs(v[0]), wp.max(wp.abs(v[1]), wp.abs(v[2])))


@wp.func
def segment_transmittance(glass: TraceScene, glass_tn: wp.array(dtype=float), glass_normal: wp.array(dtype=wp.vec3),
                          origin: wp.vec3, direction: wp.vec3, max_t: float, epsilon: float) -> float:
    """Share of light that crosses the panes between ``origin`` and ``origin + max_t direction``: the
    product of ``glass_transmittance`` over every glass triangle met (1 when none is; 0 past
    MAX_CROSSINGS). ``glass`` is ``Glazing.glass_tracer.scene``; ``glass_tn`` and ``glass_normal``
    (``Glazing.glass_tn``, ``Glazing.glass_normal``) are indexed by its triangles (``RayHit.face``);
    ``max_t`` is in units of ``direction`` (as ``trace_closest``), which need not be unit length.

    The walk repeats ``trace_closest`` from just past each hit (CROSSING_STEP of the coordinates' magnitude,
    and at least the tracer's ``epsilon``, the ray-origin offset: a hit on a pane far larger than the
    distances around the ray is placed only to the precision of the pane's own coordinates, and a shorter
    step finds the same pane again), so a ray through the shared edge of two triangles of one pane counts
    the pane once."""
    length = wp.length(direction)
    if length <= 0.0:
        return 1.0
    unit = direction / length
    reach = _max_abs(origin) / length  # coordinates' magnitude, in units of direction
    transmittance = float(1.0)
    travelled = float(0.0)
    crossings = int(0)
    while travelled < max_t:
        hit = trace_closest(glass, origin + direction * travelled, direction, max_t - travelled)
        if not hit.result:
            return transmittance
        if crossings == wp.static(MAX_CROSSINGS):
            return 0.0
        crossings += 1
        transmittance *= glass_transmittance(wp.dot(unit, glass_normal[hit.face]), glass_tn[hit.face])
        if transmittance <= 0.0:
            return 0.0
        at = travelled + hit.t
        magnitude = wp.max(at, wp.max(reach, _max_abs(origin + direction * at) / length))
        travelled = at + wp.max(wp.static(CROSSING_STEP) * magnitude, epsilon / length)
    return transmittance


# -- the glass and opaque ray cores --------------------------------------------------------------------

class Glazing:
    """The scene's glass apart from its opaque triangles, each in a ray core of its own.

    Built from the same points, so both tracers have the same ``scale`` and ``epsilon`` as a tracer of
    the whole scene (``Tracer`` sizes both from the points' extent). Trees are flat (instanced
    prototypes are flattened, as every glass pane must be met by its own triangle index).

    Attributes
    ----------
    opaque_tracer : Tracer
        The triangles of transmittance 0 (``hit.face`` indexes ``opaque_triangles``).
    opaque_triangles : (O,) int32
        Scene triangle of each opaque tracer triangle.
    glass_tracer : Tracer
        The triangles of transmittance > 0 (``hit.face`` indexes ``glass_triangles``).
    glass_triangles : (G,) int32
        Scene triangle of each glass tracer triangle.
    glass_tn : wp.array (G,) float32
        Visible transmittance at normal incidence per glass tracer triangle, on the device.
    glass_normal : wp.array (G,) vec3
        Unit geometric normal per glass tracer triangle (Scene.tri_normals), on the device.
    """

    def __init__(self, points: np.ndarray, tri_vertices: np.ndarray, tri_normals: np.ndarray,
                 tri_transmittance: np.ndarray, *, device: str = "cpu", threads: int | None = None):
        tri_transmittance = np.asarray(tri_transmittance, np.float32).reshape(-1)
        if len(tri_transmittance) != len(tri_vertices):
            raise ValueError(f"Glazing: {len(tri_transmittance)} transmittances for {len(tri_vertices)} triangles")
        glass = tri_transmittance > 0.0
        self.opaque_triangles = np.flatnonzero(~glass).astype(np.int32)
        self.glass_triangles = np.flatnonzero(glass).astype(np.int32)
        self.opaque_tracer = Tracer(points, tri_vertices[self.opaque_triangles], device=device, threads=threads)
        self.glass_tracer = Tracer(points, tri_vertices[self.glass_triangles], device=device, threads=threads)
        if self.opaque_tracer.scale != self.glass_tracer.scale:  # same points, same extent: never
            raise AssertionError("Glazing: the opaque and glass ray cores are scaled differently")
        self.device = self.glass_tracer.device
        self.glass_tn = wp.array(tri_transmittance[self.glass_triangles], dtype=float, device=self.device)
        normals = np.ascontiguousarray(np.asarray(tri_normals, np.float32)[self.glass_triangles])
        self.glass_normal = wp.array(normals, dtype=wp.vec3, device=self.device)

    @classmethod
    def of_scene(cls, scene, device: str = "cpu", *, threads: int | None = None) -> "Glazing | None":
        """The scene's glazing, or None when no triangle transmits (every kernel then traces as before)."""
        if not (scene.tri_transmittance > 0.0).any():
            return None
        return cls(scene.points, scene.tri_vertices, scene.tri_normals, scene.tri_transmittance,
                   device=device, threads=threads)

    @property
    def glass_scene(self) -> TraceScene:
        """``glass_tracer.scene``: the first argument of ``segment_transmittance``."""
        return self.glass_tracer.scene


def glass_arguments(tracer, glazing: "Glazing | None") -> list:
    """The four trailing kernel arguments of a kernel that traces through glazing: (has_glass, glass scene,
    glass_tn, glass_normal); without glazing a flag of 0 and placeholders on ``tracer``'s device."""
    if glazing is None:
        return [0, tracer.scene, wp.zeros(1, dtype=float, device=tracer.device),
                wp.zeros(1, dtype=wp.vec3, device=tracer.device)]
    return [1, glazing.glass_scene, glazing.glass_tn, glazing.glass_normal]


@dataclass(frozen=True)
class GlassPanes:
    """A scene's triangles and transmittances as plain arrays (what a chunk sent to another process can
    carry), built into a ``Glazing`` once per process and device (``glazing``)."""

    points: np.ndarray
    tri_vertices: np.ndarray
    tri_normals: np.ndarray
    tri_transmittance: np.ndarray
    key: str
    """Digest of the arrays: the ``Glazing`` built for it is kept and reused."""

    @classmethod
    def of_scene(cls, scene) -> "GlassPanes | None":
        """None when no triangle transmits."""
        if not (scene.tri_transmittance > 0.0).any():
            return None
        digest = hashlib.sha256()
        for values in (scene.points, scene.tri_vertices, scene.tri_transmittance):
            digest.update(np.ascontiguousarray(values).tobytes())
        return cls(scene.points, scene.tri_vertices, scene.tri_normals, scene.tri_transmittance, digest.hexdigest())

    def glazing(self, tracer) -> Glazing:
        """The ``Glazing`` of these panes on ``tracer``'s device (built once per process)."""
        key = (self.key, str(tracer.device))
        if key not in _BUILT:
            _BUILT.clear()  # one scene at a time: the opaque tracer is as large as the scene's
            _BUILT[key] = Glazing(self.points, self.tri_vertices, self.tri_normals, self.tri_transmittance,
                                  device=str(tracer.device), threads=tracer.threads)
        return _BUILT[key]


_BUILT: dict = {}


def scene_glazing(scene, tracer) -> "Glazing | None":
    """The scene's ``Glazing`` on ``tracer``'s device, built once per process (``GlassPanes.glazing``), so
    sky visibility, the bounces, the sun and the year share one pair of ray cores; None without glass."""
    panes = GlassPanes.of_scene(scene)
    return panes.glazing(tracer) if panes is not None else None
