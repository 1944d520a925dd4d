"""The host side of the light model (``kernels/lights.py``): which lights a scene has, and its lights and
surfaces packed into the ``Lights`` and ``Surfaces`` structs on a device, once per scene and device."""

from __future__ import annotations

import weakref
from dataclasses import dataclass

import numpy as np
import warp as wp

from ..core.scene import LIGHT_DISK, LIGHT_DISTANT, LIGHT_DOME, LIGHT_RECT, LIGHT_SPHERE, Scene
from .lights import LUMINANCE, Lights, Surfaces

MIN_DISTANCE_RELATIVE = 1e-4
"""Light-sample distances are clamped to this fraction of the scene diagonal: bounds the 1/d^2 spike
of an area-light sample landing next to the shaded point (a bias only within that distance)."""

EMISSIVE_MODES = ("auto", "on", "off")


def emissive_lights(scene: Scene, mode: str = "auto") -> bool:
    """Whether emissive triangles act as lights: 'on', 'off', or 'auto' = only when the stage has no
    UsdLux lights (a fixture modelled as a light and as an emissive quad would count twice)."""
    if mode not in EMISSIVE_MODES:
        raise ValueError(f"emissive mode {mode!r} is not one of {list(EMISSIVE_MODES)}")
    return mode == "on" or (mode == "auto" and len(scene.lights) == 0)


NO_LIGHTS = ("no lights (no UsdLux light with radiance and no emissive triangle): add a sky and sun with "
             "'usdbake sky STAGE -o STAGE.sky.usda' and bake that layer, or add a UsdLux DomeLight, a DistantLight "
             "or an emissive material")
"""Why a processor that needs light does not apply, and how to give the scene some."""


def has_light(scene: Scene) -> bool:
    """The scene holds a UsdLux light or an emissive triangle with positive radiance."""
    emissive = bool((scene.tri_emission.max(axis=1, initial=0.0) > 0).any()) if scene.num_triangles else False
    lit = bool((np.asarray(scene.lights.light_radiance).max(axis=1, initial=0.0) > 0).any()) \
        if len(scene.lights) else False
    return emissive or lit


def emitter_triangles(scene: Scene, mode: str = "auto") -> np.ndarray:
    """(E,) int32 triangles that act as area lights."""
    if not emissive_lights(scene, mode) or not scene.num_triangles:
        return np.zeros(0, np.int32)
    return np.flatnonzero((scene.tri_emission.max(axis=1) > 0) & (scene.tri_areas > 0)).astype(np.int32)


def light_bundle(scene: Scene, device, *, emissive: str = "auto") -> Lights:
    """The scene's lights as a ``Lights`` struct on ``device``."""
    lights = scene.lights
    tris = emitter_triangles(scene, emissive)
    emission = scene.tri_emission[tris].astype(np.float64)
    power = (emission @ LUMINANCE) * scene.tri_areas[tris] * np.where(scene.tri_double_sided[tris], 2.0, 1.0)
    dome = np.asarray(lights.light_kind) == LIGHT_DOME
    bundle = Lights()
    bundle.light_kind = _array(lights.light_kind, int, device)
    bundle.light_radiance = _array(lights.light_radiance, wp.vec3, device)
    bundle.light_position = _array(lights.light_position, wp.vec3, device)
    bundle.light_direction = _array(lights.light_direction, wp.vec3, device)
    bundle.light_size = _array(lights.light_size, wp.vec2, device)
    textured = dome if lights.textured_dome < 0 else np.arange(len(dome)) == lights.textured_dome
    radiance = np.asarray(lights.light_radiance, np.float64).reshape(-1, 3)
    bundle.light_textured = _array(textured.astype(np.int32), int, device)
    bundle.dome_radiance = wp.vec3(*radiance[dome].sum(axis=0).tolist())
    bundle.textured_radiance = wp.vec3(*radiance[textured].sum(axis=0).tolist())
    texture = np.asarray(lights.dome_texture, np.float32)
    if texture.size == 0:
        texture = np.ones((1, 1, 3), np.float32)
    bundle.sky_map = wp.array(np.ascontiguousarray(texture), dtype=wp.vec3, device=device)
    bundle.sky_to_local = wp.mat33(*np.asarray(lights.dome_to_local, np.float64).T.ravel().tolist())
    bundle.emitter_vertices = _array(scene.points[scene.tri_vertices[tris]].reshape(-1, 3), wp.vec3, device)
    bundle.emitter_normal = _array(scene.tri_normals[tris], wp.vec3, device)
    bundle.emitter_radiance = _array(scene.tri_emission[tris], wp.vec3, device)
    bundle.emitter_area = _array(scene.tri_areas[tris], float, device)
    bundle.emitter_two_sided = _array(scene.tri_double_sided[tris], int, device)
    bundle.emitter_cdf = _array(np.cumsum(np.maximum(power, 0.0)), float, device)
    bundle.min_d2 = float((MIN_DISTANCE_RELATIVE * max(scene.diagonal, 1e-30)) ** 2)
    return bundle


def surface_bundle(scene: Scene, device) -> Surfaces:
    """The scene's per-triangle materials as a ``Surfaces`` struct on ``device``."""
    surfaces = Surfaces()
    surfaces.tri_normals = _array(scene.tri_normals, wp.vec3, device)
    surfaces.tri_albedo = _array(scene.tri_albedo, wp.vec3, device)
    surfaces.tri_emission = _array(scene.tri_emission, wp.vec3, device)
    surfaces.tri_double_sided = _array(scene.tri_double_sided, int, device)
    return surfaces


@dataclass(frozen=True)
class SceneLighting:
    """A scene's surfaces and lights on one device, built once per run and passed to every launch."""

    surfaces: Surfaces
    lights: Lights
    shadow_rays: int
    """Shadow rays of one ``direct_irradiance`` call with one sample per light."""


_LIGHTING: dict[tuple[int, str, str], SceneLighting] = {}


def scene_lighting(scene: Scene, device, *, emissive: str = "auto") -> SceneLighting:
    """The scene's lighting on ``device``: built on first use, then shared by every processor, pass and
    chunk of the scene (as the run's Runtime shares its BVH), and dropped with the scene."""
    key = (id(scene), str(wp.get_device(device)), emissive)
    lighting = _LIGHTING.get(key)
    if lighting is None:
        lighting = SceneLighting(surface_bundle(scene, device), light_bundle(scene, device, emissive=emissive),
                                 shadow_rays_per_point(scene, emissive=emissive))
        _LIGHTING[key] = lighting
        weakref.finalize(scene, _LIGHTING.pop, key, None)
    return lighting


def shadow_rays_per_point(scene: Scene, *, strata: int = 1, sky_strata: int = 1, emissive: str = "auto") -> int:
    """Shadow rays ``direct_irradiance`` casts at one point (for the rays-per-second figures)."""
    kind = np.asarray(scene.lights.light_kind)
    delta = (kind == LIGHT_DISTANT) & (np.asarray(scene.lights.light_size).reshape(-1, 2)[:, 0] <= 0)
    domes = int((kind == LIGHT_DOME).sum())
    sampled = int(np.isin(kind, (LIGHT_DISTANT, LIGHT_SPHERE, LIGHT_RECT, LIGHT_DISK)).sum()) - int(delta.sum())
    emitters = strata * strata if len(emitter_triangles(scene, emissive)) else 0
    return int(delta.sum()) + sampled * strata * strata + domes * sky_strata * sky_strata + emitters


def _array(values, dtype, device) -> wp.array:
    numpy_type = np.int32 if dtype is int else np.float32
    width = {wp.vec3: 3, wp.vec2: 2}.get(dtype)
    values = np.ascontiguousarray(np.asarray(values, numpy_type).reshape((-1, width) if width else (-1,)))
    return wp.array(values, dtype=dtype, device=device)
