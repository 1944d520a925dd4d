"""The light probe cloud and its interpolation: tetrahedra, leak rule, lookup of irradiance SH.

Cupisz, "Light probe interpolation using tetrahedral tessellations", GDC 2012; Sukys 2014, tetrahedral
grid and barycentric traversal 3.2.1, leaks 3.2.2. The device walk of ``processors/light_probes/lookup.py``
(the float64 walk of ``processors.light_probes.tetrahedra`` for points it leaves outside the hull or in a
flat tetrahedron); outside the hull, the boundary tetrahedron's barycentrics clamped. Delaunay clouds with
``leak_fix`` store a 6-bit blocked-edge mask per tetrahedron (two rays per edge, ``segment_blocked``) and
``tetrahedra.leak_weights`` keeps only the query's side of the blockers; a lookup with a tracer tests the
four probes' visibility instead (``visible_weights``); conforming clouds need neither.
"""
from __future__ import annotations

import numpy as np

from .products import ProbeCloud
from ...core.scene import Scene
from ...kernels.sh import sh_basis_np
from . import tetrahedra
from .capture import LIGHT_SAMPLES, direct_light_irradiance
from .lookup import ProbeLookup


def segment_blocked(tracer, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(N,) bool: geometry lies on the segment a -> b or b -> a (two rays, as Sukys for thick walls)."""
    a = np.asarray(a, np.float32).reshape(-1, 3)
    b = np.asarray(b, np.float32).reshape(-1, 3)
    if len(a) == 0:
        return np.zeros(0, bool)
    d = (b - a).astype(np.float64)
    length = np.linalg.norm(d, axis=1)
    unit = np.where(length[:, None] > 0, d / np.maximum(length, 1e-30)[:, None], 0.0).astype(np.float32)
    blocked = np.zeros(len(a), bool)
    for origin, direction in ((a, unit), (b, -unit)):
        # Tracer.occluded takes one max_t per launch and edges differ in length: closest hit, then compare.
        hits = tracer.closest_hit(origin, direction)
        blocked |= hits.hit_t < length
    return blocked & (length > 0)


def build_cloud(positions: np.ndarray, sh: np.ndarray, tracer=None, *, leak_fix: bool = True,
                direct_lights: bool = True) -> ProbeCloud:
    """Tetrahedralize probes and (with a tracer and leak_fix) ray-cast the edges for blockers."""
    positions = np.asarray(positions, np.float32).reshape(-1, 3)
    tetra = tetrahedra.tetrahedralize(positions)
    blocked = np.zeros(tetra.num_tets, np.uint8)
    if leak_fix and tracer is not None and tetra.num_tets:
        edges, index = tetrahedra.edge_list(tetra.tet_vertices)
        edge_blocked = segment_blocked(tracer, positions[edges[:, 0]], positions[edges[:, 1]])
        blocked = tetrahedra.edge_masks(index, edge_blocked)
    return ProbeCloud(positions, np.asarray(sh, np.float32).reshape(-1, 9, 3), tetra.tet_vertices,
                      tetra.tet_neighbors, blocked, tetra, direct_lights)


def cloud_from_arrays(positions, sh, tet_vertices, tet_neighbors, tet_blocked=None, *, direct_lights: bool = True,
                      capture_positions=None) -> ProbeCloud:
    """A ProbeCloud from stored arrays (e.g. the attributes of a LightProbeCloud prim)."""
    positions = np.asarray(positions, np.float32).reshape(-1, 3)
    tetra = tetrahedra.from_arrays(positions, tet_vertices, tet_neighbors)
    blocked = np.zeros(tetra.num_tets, np.uint8) if tet_blocked is None else np.asarray(tet_blocked, np.uint8)
    capture = None if capture_positions is None else np.asarray(capture_positions, np.float32).reshape(-1, 3)
    return ProbeCloud(positions, np.asarray(sh, np.float32).reshape(-1, 9, 3), tetra.tet_vertices,
                      tetra.tet_neighbors, blocked, tetra, direct_lights, capture)


def interpolation_weights(cloud: ProbeCloud, points: np.ndarray, tracer=None) -> tuple[np.ndarray, np.ndarray]:
    """(N, 4) probe indices and (N, 4) weights at points (N, 3): walk (the device walk of
    ``processors.light_probes.lookup``; the float64 one of ``processors.light_probes.tetrahedra`` for the points it leaves outside
    the hull or in a flat tetrahedron of cospherical probes), clamp outside, then the leak rule; with a
    ``tracer``, visibility instead: a probe that geometry hides from the point gets no weight
    (``visible_weights``)."""
    points = np.asarray(points, np.float64).reshape(-1, 3)
    tet, bary, inside = ProbeLookup(cloud.tetra).locate(points)
    tet, bary = tet.astype(np.int64), bary.astype(np.float64)
    flat = cloud.tetra.tet_flat
    redo = ~inside if flat is None else ~inside | flat[tet]
    if redo.any():
        tet[redo], bary[redo], _ = tetrahedra.locate(cloud.tetra, points[redo])
    weights = tetrahedra.clamp_weights(bary)
    probes = cloud.tet_vertices[tet].astype(np.int64)
    blocked = cloud.tet_blocked is not None and np.any(cloud.tet_blocked)
    if tracer is not None and blocked:
        return probes, visible_weights(tracer, cloud, points, probes, weights,
                                       tetrahedra.leak_weights(weights, cloud.tet_blocked[tet]))
    if blocked:
        weights = tetrahedra.leak_weights(weights, cloud.tet_blocked[tet])
    return probes, weights


def visible_weights(tracer, cloud: ProbeCloud, points: np.ndarray, probes: np.ndarray, weights: np.ndarray,
                    fallback: np.ndarray) -> np.ndarray:
    """(N, 4) weights with the probes geometry hides from each point (a ray from the point to the probe's
    capture position meets something first) set to 0 and the rest renormalized, as a renderer's
    visibility-tested probe lookup; ``fallback`` (the leak rule's) where every probe with weight is hidden."""
    at = cloud.probe_positions if cloud.capture_positions is None else cloud.capture_positions
    targets = at[probes].astype(np.float64).reshape(-1, 3)
    origins = np.repeat(points, 4, axis=0)
    hidden = segment_blocked(tracer, origins, targets).reshape(-1, 4)
    kept = np.where(hidden, 0.0, weights)
    total = kept.sum(axis=1, keepdims=True)
    return np.where(total > 0, kept / np.maximum(total, 1e-300), fallback)


def interpolate_sh(cloud: ProbeCloud, points: np.ndarray, tracer=None) -> np.ndarray:
    """(N, 9, 3) float32 irradiance SH at points (N, 3) in the scene frame (``interpolation_weights``)."""
    probes, weights = interpolation_weights(cloud, points, tracer)
    return np.einsum("nv,nvkc->nkc", weights, cloud.probe_sh[probes].astype(np.float64)).astype(np.float32)


def irradiance_at(cloud: ProbeCloud, points: np.ndarray, normals: np.ndarray, *, tracer=None,
                  scene: Scene | None = None, light_samples: int = LIGHT_SAMPLES) -> np.ndarray:
    """(N, 3) float32 irradiance E(n) = sum_k c_k Y_k(n) (W/m^2) at points (scene frame) with unit normals.
    With a ``tracer``: probes hidden from a point do not count (``visible_weights``, clouds with leak
    fixing); with a ``scene`` too, a cloud baked with direct_lights=lookup gets the lights' direct light
    at the points (``direct_light_irradiance``, ``light_samples`` per area light)."""
    sh = interpolate_sh(cloud, points, tracer).astype(np.float64)
    basis = sh_basis_np(np.asarray(normals, np.float64).reshape(-1, 3))
    e = np.einsum("nk,nkc->nc", basis, sh)
    if not cloud.direct_lights and tracer is not None and scene is not None:
        e += direct_light_irradiance(tracer, scene, points, normals, samples=light_samples)
    return e.astype(np.float32)
