"""Sky visibility's refined mesh and factors, and what daylight and annual_daylight make of them.

Types of what one processor hands to the next (how they are wired: core/products.py, which holds
those that cross techniques); these stay within this technique.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ...kernels.lightmap_bake import TexelSamples
from ...kernels.lightmap_layout import LightmapLayout
from ...kernels.sky import SkyPatches


@dataclass(frozen=True)
class SkyVisibilityProduct:
    """The refined receiver mesh and its per-face sky visibility factors (product ``sky_visibility``)."""

    face_points: np.ndarray
    """(P, 3) float64 refined mesh vertices relative to Scene.origin."""
    face_vertices: np.ndarray
    """(F, 3) int32 indices into face_points (scene winding)."""
    face_normals: np.ndarray
    """(F, 3) float32 unit normals (those of the source triangles)."""
    face_areas: np.ndarray
    """(F,) float32."""
    face_source: np.ndarray
    """(F,) int32 source triangle (index into the Scene's triangles)."""
    face_prim: np.ndarray
    """(F,) int32 prim index (Scene.prim_paths)."""
    face_face: np.ndarray
    """(F,) int32 authored face of the source prim."""
    face_level: np.ndarray
    """(F,) int32 area halvings below the source triangle."""
    face_corner_weights: np.ndarray
    """(F, 3, 3) float64 barycentric coordinates of each face corner in its source triangle."""
    point_source: np.ndarray
    """(P,) int64 Scene point each of face_points is (-1 for a point the refinement added)."""
    visibility: np.ndarray
    """(F, N) uint8 V_ij * 255 (rounded)."""
    visibility_scale: float
    """V = visibility * visibility_scale."""
    exposure: np.ndarray
    """(F,) float32 sum_j V_ij dw_j / pi."""
    patches: SkyPatches
    """The patch layout V refers to."""
    to_world: np.ndarray
    """(3, 3) float64 ENU -> scene frame for the stage's up axis (north = the layout's north)."""
    up_axis: str
    prims: np.ndarray
    """(R,) int32 receiver prims (faces of prim prims[r] are face_prim == prims[r], in order)."""
    texels: "TexelReceivers | None" = None
    """The texture target's lightmap texels and their own V (``texel_receivers``); None for the vertex target."""
    mesh_written: bool = True
    """The refined mesh and its per-face results are authored (target vertex or both); with the texture
    target alone the refined faces only carry light between surfaces (interreflection's transport)."""
    _cache: dict = field(default_factory=dict, compare=False, repr=False)

    @property
    def num_faces(self) -> int:
        return len(self.face_vertices)

    def visibility_float(self) -> np.ndarray:
        """(F, N) float32 dequantized V, computed once and kept (4 bytes per factor)."""
        if "float" not in self._cache:
            self._cache["float"] = self.visibility.astype(np.float32) * np.float32(self.visibility_scale)
        return self._cache["float"]

    def visibility_patch_major(self) -> np.ndarray:
        """(N, F) float32 dequantized V, patch-major (the layout ``daylight.relight_daylight`` streams fastest)."""
        if "patch_major" not in self._cache:
            self._cache["patch_major"] = np.ascontiguousarray(self.visibility.T, np.float32) * np.float32(
                self.visibility_scale)
        return self._cache["patch_major"]

    def __getstate__(self):
        state = dict(self.__dict__)
        state["_cache"] = {}
        return state

    def __setstate__(self, state):
        self.__dict__.update(state)


@dataclass(frozen=True)
class AnnualDaylightProduct:
    """Annual daylight metrics per face of the sky_visibility mesh (product of ``annual_daylight``)."""

    daylight_factor: np.ndarray
    """(F,) float32 percent, CIE overcast sky."""
    autonomy: np.ndarray
    """(F,) float32 share of occupied hours at or above the threshold."""
    useful: np.ndarray
    """(F, 3) float32 UDI shares of occupied hours: below, within, above the band."""
    sun_hours: np.ndarray
    """(F,) float32 occupied hours of direct sunlight at or above the ASE level."""
    mean_illuminance: np.ndarray
    """(F,) float32 lux, mean over occupied hours."""
    sensors: np.ndarray
    """(F,) bool faces the spatial metrics are taken over."""
    sda: float
    ase: float
    texels: "AnnualDaylightProduct | None" = None
    """The same at the texture target's texels (sDA and ASE over them, footprint-weighted) when the faces are
    written too; with the texture target alone, this product is the texels' own."""


@dataclass(frozen=True)
class DaylightProduct:
    """Product ``daylight``: radiance per refined face and time."""

    times: np.ndarray
    """(K,) datetime64[us] local times."""
    face_radiance: np.ndarray
    """(K, F, 3) float32 outgoing radiance, W/(m^2 sr)."""
    sun_zenith: np.ndarray
    """(K,) degrees."""
    sun_azimuth: np.ndarray
    """(K,) degrees from north towards east."""
    face_irradiance: np.ndarray
    """(K, F, 3) float32 total irradiance (sky, sun, interreflected light, ground), visible-equivalent W/m^2
    (x 179 = lux)."""
    texels: "DaylightProduct | None" = None
    """The same at the texture target's texels (their faces are texels), else None."""


@dataclass(frozen=True)
class InterreflectionProduct:
    """Indirect daylight coefficients per refined face (product of ``interreflection``)."""

    bounces: int
    ground_reflectance: float
    sky_indirect: np.ndarray
    """(K, F, N) float32 D_ij: irradiance after 1..bounces reflections per unit L_j dw_j of sky patch j; K = 1
    when every face is grey (one set serves the three channels), else 3 (R, G, B)."""
    ground_direct: np.ndarray
    """(F,) float32 pi g_i: irradiance per unit radiance of the ground outside the model, seen directly."""
    ground_indirect: np.ndarray
    """(K, F) float32 the same ground's light after 1..bounces reflections, per unit ground radiance."""

    texels: "InterreflectionProduct | None" = None
    """The same coefficients for the texture target's texels (``SkyVisibilityProduct.texels``), else None."""

    def channel(self, c: int) -> int:
        """Index into the K axis for colour channel c."""
        return min(c, len(self.sky_indirect) - 1)


@dataclass(frozen=True)
class TexelReceivers:
    """The lightmap texels of the receivers, in page order, and the daylight product computed at them."""

    layout: LightmapLayout
    pages: list[TexelSamples]
    view: "SkyVisibilityProduct"
    """``SkyVisibilityProduct`` whose face k is texel k (pages concatenated): its V, exposure, corners
    (the inset faces), face normals, areas (footprints) and owning triangles."""
    margin: int
    denoise: bool

    @property
    def count(self) -> int:
        return sum(len(page.texel) for page in self.pages)

    def page_slices(self) -> list[slice]:
        """Texel rows of each page in ``view``."""
        bounds = np.cumsum([0] + [len(page.texel) for page in self.pages])
        return [slice(int(lo), int(hi)) for lo, hi in zip(bounds[:-1], bounds[1:])]
