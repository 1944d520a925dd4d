"""Where the light probes go: Sukys' placement (section 3.1), error-driven refinement, conforming meshes.

**Thesis placement** (``place_probes``). Jittered grid candidates over the placement box
(``placement_box``), dropped inside geometry (26-ray back-face vote) or nearer a surface than the
clearance (``CLEARANCE_FRACTION`` of ``min_spacing``); captured *decoupled* (the dome and bounced light,
not the real-time lights); then ``iterations`` rounds of gradient ascent on the variation
``V_i = max_j c_ij / |x_i - x_j|`` (``c_ij``: mean over 26 normals of ``|E_i - E_j| / (E_i + E_j + floor)``,
in [0, 1); gradient by least squares in ``processors/light_probes/ascent.py``; a move into darkness, into
or through geometry is reverted), spawn at the midpoints of contrasted long edges, merge of neighbours
that see the same light (``similar_probes``) and thinning to ``min_spacing``; k-means of the inside of
unlit regions (``cluster_dark_probes``); with ``leak_fix``, wall probes beside the blockers of
tetrahedron edges (``wall_probes``).

**Error-driven placement** (``refine_placement``): probes go where the cloud predicts its own
(decoupled) light worst among captured candidates.

**Conforming** (``conforming_placement``): the probes sit on fTetWild's mesh of the empty space
(``processors/light_probes/conforming.py``: one probe per vertex and side of every surface).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.cluster.vq import kmeans2
from scipy.spatial import cKDTree

from ...core.scene import Scene
from ...geometry.mesh import receiver_detail_box
from ...kernels.light_bundles import SceneLighting, scene_lighting
from ...kernels.lights import LUMINANCE
from ...kernels.sh import sh_basis_np
from . import tetrahedra
from .ascent import variation_gradient
from .capture import PROBE_DIRECTIONS, SKY_RAYS_PER_RAY, classify_points, compute_probe_sh
from .conforming import ConformingMesh, conforming_mesh
from .interpolation import build_cloud, interpolate_sh, segment_blocked

CONFORMING_DENSITY = 6.0
"""First guess of fTetWild's probes per cubic target edge length (measured on the thin-wall rooms); the edge
length is rescaled once when the count misses the budget by more than CONFORMING_TOLERANCE."""

CONFORMING_TOLERANCE = 0.25

CLEARANCE_FRACTION = 0.1
"""A probe must be at least this fraction of ``min_spacing`` away from any surface: a probe on a
surface sees half its sphere black and makes tetrahedra cut by the surface."""

CONTRAST_FLOOR_RELATIVE = 1e-3
"""Irradiance luminance below this fraction of the scene's largest probe luminance counts as
dark when contrasts are formed (E_i + E_j + floor), so noise in black areas is not variation."""

RECEIVER_MARGIN = 0.1
"""Without probe volumes, the placement box is the non-backdrop receivers' bounds grown by this share of their
diagonal on every side, so probes also surround them."""

MERGE_CONTRAST_SHARE = 0.25
"""Two probes whose edge contrast is below this share of the spawn ``contrast`` see the same light: one merges."""

DARK_CLUSTER_SIZE = 8
"""Interior probes of an unlit region are replaced by one probe per this many (k-means, Sukys 3.1.3)."""

CANDIDATES_PER_PROBE = 8
"""Error-driven placement captures this many candidate spots per probe of the budget."""

REFINE_START_SHARE = 0.25
"""Error-driven placement starts from a lattice of this share of the budget."""

REFINE_STEP_SHARE = 0.125
"""Each round of error-driven placement grows the cloud by this share."""

BOUNDS_MIN_RELATIVE = 0.05
"""Each axis of the placement box is at least this fraction of the diagonal (flat scenes)."""


def placement_box(scene: Scene) -> tuple[np.ndarray, np.ndarray]:
    """(lo, hi) float64: the union of the stage's probe volumes (prims with ProbeVolumeAPI); with none, the
    bounds of the receivers that are not backdrops (``backdrop_prims``) inflated by RECEIVER_MARGIN of their
    diagonal, or the scene bounds when no receiver is a backdrop; each axis at least BOUNDS_MIN_RELATIVE
    diagonals wide."""
    if len(scene.probe_volumes):
        lo, hi = scene.probe_volumes[:, 0].min(axis=0), scene.probe_volumes[:, 1].max(axis=0)
    else:
        lo, hi = (np.asarray(b, np.float64) for b in scene.bounds)
        detail = receiver_detail_box(scene)
        if detail is not None:
            inner_lo, inner_hi = detail
            margin = RECEIVER_MARGIN * float(np.linalg.norm(inner_hi - inner_lo))
            lo, hi = np.maximum(inner_lo - margin, lo), np.minimum(inner_hi + margin, hi)
    centre = 0.5 * (lo + hi)
    half = np.maximum(0.5 * (hi - lo), 0.5 * BOUNDS_MIN_RELATIVE * float(np.linalg.norm(hi - lo)))
    return centre - half, centre + half




def in_placement_volume(scene: Scene, points: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """(N,) bool: inside one of the probe volumes, or with none inside the placement box [lo, hi]."""
    points = np.asarray(points, np.float64).reshape(-1, 3)
    if not len(scene.probe_volumes):
        return ((points >= lo) & (points <= hi)).all(axis=1)
    volumes = scene.probe_volumes
    return ((points[:, None] >= volumes[None, :, 0]) & (points[:, None] <= volumes[None, :, 1])).all(axis=2).any(axis=1)


def grid_spacing(lo: np.ndarray, hi: np.ndarray, count: int) -> float:
    """Spacing of a grid of cell corners over [lo, hi] with at most ``count`` points (at least 2 per axis)."""
    extent = np.maximum(hi - lo, 1e-30)
    spacing = float((np.prod(extent) / max(count, 1)) ** (1.0 / 3.0))
    for _ in range(200):
        if np.prod(np.maximum(1, np.round(extent / spacing)) + 1) <= max(count, 8):
            break
        spacing *= 1.05
    return spacing


def candidate_grid(lo: np.ndarray, hi: np.ndarray, spacing: float, margin: float,
                   rng: np.random.Generator) -> np.ndarray:
    """Cell corners of a grid over [lo + margin, hi - margin] (so the probes' hull reaches the
    bounds), jittered by +-1/4 cell and kept inside that box."""
    inner_lo = lo + np.minimum(margin, 0.25 * (hi - lo))
    inner_hi = hi - np.minimum(margin, 0.25 * (hi - lo))
    extent = np.maximum(inner_hi - inner_lo, 1e-30)
    cells = np.maximum(1, np.round(extent / spacing)).astype(int)
    axes = [np.linspace(inner_lo[a], inner_hi[a], cells[a] + 1) for a in range(3)]
    grid = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
    jitter = rng.uniform(-0.25, 0.25, grid.shape) * (extent / cells)
    return np.clip(grid + jitter, inner_lo, inner_hi)


def sample_irradiance(sh: np.ndarray) -> np.ndarray:
    """(P, 26) luminance of irradiance SH (P, 9, 3) at Sukys' 26 directions (clamped at 0)."""
    basis = sh_basis_np(PROBE_DIRECTIONS)  # (26, 9)
    e = np.einsum("dk,pkc->pdc", basis, np.asarray(sh, np.float64))
    return np.maximum(e @ LUMINANCE, 0.0)


def edge_contrast(samples: np.ndarray, edges: np.ndarray, floor: float) -> np.ndarray:
    """(E,) mean over directions of |E_a - E_b| / (E_a + E_b + floor), in [0, 1)."""
    a, b = samples[edges[:, 0]], samples[edges[:, 1]]
    return (np.abs(a - b) / (a + b + floor)).mean(axis=1)


def variation(positions: np.ndarray, samples: np.ndarray, edges: np.ndarray,
              floor: float) -> tuple[np.ndarray, np.ndarray]:
    """V (P,) = max over incident edges of contrast / length, and the per-edge contrast."""
    contrast = edge_contrast(samples, edges, floor)
    length = np.linalg.norm(positions[edges[:, 0]] - positions[edges[:, 1]], axis=1)
    rate = contrast / np.maximum(length, 1e-30)
    v = np.zeros(len(positions))
    np.maximum.at(v, edges[:, 0], rate)
    np.maximum.at(v, edges[:, 1], rate)
    return v, contrast


def cloud_edges(positions: np.ndarray) -> np.ndarray | None:
    """(E, 2) edges of the probes' Delaunay tetrahedra, or None when the probes span no volume."""
    try:
        return tetrahedra.edge_list(tetrahedra.tetrahedralize(positions).tet_vertices)[0]
    except tetrahedra.DegenerateProbesError:
        return None


@dataclass(frozen=True)
class Placement:
    """Where the probes went, and what the placement did (counts for the stats)."""

    positions: np.ndarray
    """(P, 3) float32 probe positions (scene frame)."""
    min_spacing: float
    """Merge radius used (stage units)."""
    candidates: int
    """Grid candidates before the inside / clearance test."""
    dropped_inside: int
    """Candidates inside geometry, too close to it, or out of the box."""
    moved: int
    """Accepted gradient-ascent moves, summed over rounds."""
    spawned: int
    merged: int
    wall_probes: int = 0
    """Probes added beside blockers (leak fixing)."""


def place_probes(tracer, scene: Scene, *, probes: int, min_spacing: float = 0.0, iterations: int = 3,
                 contrast: float = 0.25, placement_rays: int = 64, seed: int = 0,
                 leak_probes: bool = True, bounces: int = 1, lighting: SceneLighting | None = None,
                 progress=lambda f: None) -> Placement:
    """Probe positions in the empty space of the scene (module docstring, Sukys 3.1)."""
    reserve = probes // 4 if leak_probes else 0  # room kept for the probes beside blockers
    lighting = lighting or scene_lighting(scene, tracer.device)
    rng = np.random.default_rng(seed)  # seeded: the placement is reproducible
    lo, hi = placement_box(scene)
    spacing = grid_spacing(lo, hi, max(8, probes // 2))
    spacing_min = float(min_spacing) if min_spacing > 0 else 0.5 * spacing
    clearance = CLEARANCE_FRACTION * spacing_min
    grid = candidate_grid(lo, hi, spacing, clearance * 1.01, rng)

    def valid(points: np.ndarray) -> np.ndarray:
        inside, nearest = classify_points(tracer, lighting, points)
        return ~inside & (nearest >= clearance) & in_placement_volume(scene, points, lo, hi)

    keep = valid(grid)
    positions = grid[keep].astype(np.float64)
    dropped = int((~keep).sum())
    stats = {"moved": 0, "spawned": 0, "merged": 0}

    def capture(points: np.ndarray, capture_seed: int) -> np.ndarray:
        # Light decoupling (Sukys 3.1.2): placement sees the dome and light that bounced, not the real-time lights.
        return compute_probe_sh(tracer, scene, points, rays=placement_rays, seed=capture_seed, lighting=lighting,
                                bounces=bounces, direct_lights=False, sky_rays=SKY_RAYS_PER_RAY * placement_rays)

    sh = capture(positions, seed + 1)
    capture_seed = seed + 2
    for round_ in range(iterations):
        progress(0.1 + 0.5 * round_ / max(iterations, 1))
        edges = cloud_edges(positions)
        if edges is None:
            break
        samples = sample_irradiance(sh)
        floor = CONTRAST_FLOOR_RELATIVE * max(float(samples.max(initial=0.0)), 1e-30)
        v, _ = variation(positions, samples, edges, floor)

        # Gradient ascent on V, with the "second order" revert.
        gradient, mean_edge = variation_gradient(tracer, positions, v, edges)
        norm = np.linalg.norm(gradient, axis=1)
        movers = np.flatnonzero((norm > 0) & (v > 0))
        if len(movers):
            step = (0.5 * mean_edge[movers] * 0.5 ** round_)[:, None] * gradient[movers] / norm[movers, None]
            target = positions[movers] + step
            ok = valid(target) & ~segment_blocked(tracer, positions[movers], target)
            movers, target = movers[ok], target[ok]
            if len(movers):
                new_sh = capture(target, capture_seed)
                capture_seed += 1
                lit = np.abs(new_sh).max(axis=(1, 2)) > 0
                positions[movers[lit]] = target[lit]
                sh[movers[lit]] = new_sh[lit]
                stats["moved"] += int(lit.sum())

        # Spawn at the midpoints of contrasted, long edges.
        edges = cloud_edges(positions)
        if edges is None:
            break
        samples = sample_irradiance(sh)
        v, edge_c = variation(positions, samples, edges, floor)
        length = np.linalg.norm(positions[edges[:, 0]] - positions[edges[:, 1]], axis=1)
        room = probes - reserve - len(positions)
        wanted = np.flatnonzero((edge_c > contrast) & (length > 2.0 * spacing_min))
        if room > 0 and len(wanted):
            wanted = wanted[np.argsort(-edge_c[wanted], kind="stable")][: 2 * room]
            mid = 0.5 * (positions[edges[wanted, 0]] + positions[edges[wanted, 1]])
            mid = mid[valid(mid)][:room]  # blocked edges too: their midpoint may lie in a space between blockers
            if len(mid):
                new_sh = capture(mid, capture_seed)
                capture_seed += 1
                positions = np.concatenate([positions, mid])
                sh = np.concatenate([sh, new_sh])
                v = np.concatenate([v, np.full(len(mid), np.inf)])  # new probes survive the merge
                stats["spawned"] += len(mid)

        # Merge: probes that see the same light fold into their more varied neighbour, then greedy
        # thinning, higher variation first.
        edges = cloud_edges(positions)
        alike = np.zeros(len(positions), bool) if edges is None else similar_probes(
            positions, sample_irradiance(sh), v, edges, floor, MERGE_CONTRAST_SHARE * contrast, 2.0 * spacing_min)
        order = np.argsort(-v, kind="stable")
        survivors = thin(positions, order[~alike[order]], spacing_min)
        stats["merged"] += len(positions) - len(survivors)
        positions, sh = positions[survivors], sh[survivors]

    positions, sh, clustered = cluster_dark_probes(positions, sh, rng)
    stats["merged"] += clustered

    added = 0
    if leak_probes and len(positions) >= 4:
        extra = wall_probes(tracer, positions, valid, spacing_min, clearance, probes - len(positions))
        positions = np.concatenate([positions, extra])
        added = len(extra)
    if len(positions) > probes:
        positions = positions[:probes]
    return Placement(positions.astype(np.float32), spacing_min, len(grid), dropped, stats["moved"],
                     stats["spawned"], stats["merged"], added)


def similar_probes(positions: np.ndarray, samples: np.ndarray, v: np.ndarray, edges: np.ndarray, floor: float,
                   threshold: float, max_length: float) -> np.ndarray:
    """(P,) bool: probes merged away (Sukys 3.1.1, merge). Edges shorter than ``max_length`` whose contrast
    (bounded in [0, 1), ``edge_contrast``) is below ``threshold`` are taken least contrasted first; the
    probe of lower variation V of each goes, at most one per edge and none whose partner already went."""
    contrast = edge_contrast(samples, edges, floor)
    length = np.linalg.norm(positions[edges[:, 0]] - positions[edges[:, 1]], axis=1)
    gone = np.zeros(len(positions), bool)
    touched = np.zeros(len(positions), bool)
    candidates = np.flatnonzero((contrast < threshold) & (length < max_length))
    for e in candidates[np.argsort(contrast[candidates], kind="stable")]:
        a, b = edges[e]
        if touched[a] or touched[b]:
            continue
        gone[a if v[a] < v[b] else b] = True
        touched[a] = touched[b] = True
    return gone


def cluster_dark_probes(positions: np.ndarray, sh: np.ndarray, rng: np.random.Generator):
    """Sukys 3.1.3, completely unlit areas: probes that see no light and whose Delaunay neighbours see none
    either (the inside of a dark region; dark probes beside lit ones keep the shadow's edge) are replaced
    by one probe per k-means cluster of DARK_CLUSTER_SIZE (scipy), the member nearest its centroid so
    the survivor is a valid spot. Returns positions, sh and how many probes went."""
    edges = cloud_edges(positions)
    samples = sample_irradiance(sh).max(axis=1)
    dark = samples <= CONTRAST_FLOOR_RELATIVE * max(float(samples.max(initial=0.0)), 1e-30)
    if edges is None or dark.sum() <= DARK_CLUSTER_SIZE:
        return positions, sh, 0
    lit_neighbour = np.zeros(len(positions), bool)
    for i, j in ((0, 1), (1, 0)):
        lit_neighbour[edges[~dark[edges[:, j]], i]] = True
    interior = np.flatnonzero(dark & ~lit_neighbour)
    if len(interior) <= DARK_CLUSTER_SIZE:
        return positions, sh, 0
    clusters = int(np.ceil(len(interior) / DARK_CLUSTER_SIZE))
    centroids, labels = kmeans2(positions[interior], clusters, minit="++", seed=rng)
    keep = np.ones(len(positions), bool)
    keep[interior] = False
    for c in np.unique(labels):
        members = interior[labels == c]
        keep[members[np.argmin(np.linalg.norm(positions[members] - centroids[c], axis=1))]] = True
    return positions[keep], sh[keep], int((~keep).sum())


def refine_placement(tracer, scene: Scene, *, probes: int, placement_rays: int = 64, bounces: int = 1,
                     seed: int = 0, leak_fix: bool = True, lighting: SceneLighting | None = None,
                     progress=lambda f: None) -> Placement:
    """Error-driven placement: probes go where the cloud predicts its own light worst.

    Candidates: a jittered grid of CANDIDATES_PER_PROBE x ``probes`` valid spots (as the thesis grid: outside
    geometry, off surfaces, in the placement volume), captured decoupled at ``placement_rays``. The cloud
    starts from the candidates nearest a lattice of REFINE_START_SHARE x ``probes`` points; each round
    tetrahedralizes it (with the leak rule when ``leak_fix``), interpolates it at every candidate and adds the
    candidates with the largest error (RMS over Sukys' 26 directions of the luminance difference to their own
    capture), REFINE_STEP_SHARE of the cloud per round, none within two candidate spacings of another pick.
    Sum-of-squares error is what the relative RMS of a lookup measures, so each pick removes the largest
    share of it the cloud can see (a greedy, cross-validation-style refinement; the thesis's spawn at edge
    midpoints is its heuristic form)."""
    lighting = lighting or scene_lighting(scene, tracer.device)
    rng = np.random.default_rng(seed)  # seeded: the placement is reproducible
    lo, hi = placement_box(scene)
    spacing = grid_spacing(lo, hi, CANDIDATES_PER_PROBE * probes)
    clearance = CLEARANCE_FRACTION * spacing
    grid = candidate_grid(lo, hi, spacing, 1.01 * clearance, rng)
    inside, nearest = classify_points(tracer, lighting, grid)
    keep = ~inside & (nearest >= clearance) & in_placement_volume(scene, grid, lo, hi)
    candidates = grid[keep].astype(np.float64)
    empty = Placement(candidates.astype(np.float32), spacing, len(grid), int((~keep).sum()), 0, 0, 0)
    if len(candidates) <= 4:
        return empty
    sh = compute_probe_sh(tracer, scene, candidates, rays=placement_rays, seed=seed + 1, lighting=lighting,
                          bounces=bounces, direct_lights=False, sky_rays=SKY_RAYS_PER_RAY * placement_rays)
    truth = sample_irradiance(sh)
    start = candidate_grid(lo, hi, grid_spacing(lo, hi, max(8, int(REFINE_START_SHARE * probes))), 0.0, rng)
    in_cloud = np.zeros(len(candidates), bool)
    in_cloud[np.unique(cKDTree(candidates).query(start)[1])] = True
    target = min(probes, len(candidates))
    while in_cloud.sum() < target:
        progress(0.1 + 0.5 * in_cloud.sum() / target)
        members = np.flatnonzero(in_cloud)
        try:
            cloud = build_cloud(candidates[members], sh[members], tracer, leak_fix=leak_fix)
        except tetrahedra.DegenerateProbesError:
            in_cloud[rng.choice(np.flatnonzero(~in_cloud), min(4, int((~in_cloud).sum())), replace=False)] = True
            continue
        error = np.sqrt(np.mean((sample_irradiance(interpolate_sh(cloud, candidates)) - truth) ** 2, axis=1))
        error[in_cloud] = -1.0
        room = min(target - int(in_cloud.sum()), max(1, int(REFINE_STEP_SHARE * in_cloud.sum())))
        picked = separated_worst(candidates, error, room, 2.0 * spacing)
        if not len(picked):
            break
        in_cloud[picked] = True
    return Placement(candidates[in_cloud].astype(np.float32), spacing, len(grid), int((~keep).sum()), 0,
                     int(in_cloud.sum()), 0)


def separated_worst(points: np.ndarray, error: np.ndarray, count: int, radius: float) -> np.ndarray:
    """Indices of up to ``count`` points of positive error, largest first, none within ``radius`` of an
    earlier pick (so one bright spot does not take a round's whole share)."""
    picked: list[int] = []
    for i in np.argsort(-error, kind="stable"):
        if error[i] <= 0 or len(picked) >= count:
            break
        if picked and np.min(np.linalg.norm(points[picked] - points[i], axis=1)) < radius:
            continue
        picked.append(int(i))
    return np.asarray(picked, np.int64)


def wall_probes(tracer, positions: np.ndarray, valid, min_spacing: float, clearance: float,
                room: int) -> np.ndarray:
    """Sukys 3.2.2: where a tetrahedron edge meets geometry, a probe on each side of the blocker,
    2 clearances before the hit, if that is at least min_spacing / 2 from the edge's own end; valid
    spots only, thinned to min_spacing / 2 against all probes, at most ``room``."""
    if room <= 0:
        return np.zeros((0, 3))
    try:
        tetra = tetrahedra.tetrahedralize(positions)
    except tetrahedra.DegenerateProbesError:
        return np.zeros((0, 3))
    edges, _ = tetrahedra.edge_list(tetra.tet_vertices)
    a, b = positions[edges[:, 0]], positions[edges[:, 1]]
    d = b - a
    length = np.linalg.norm(d, axis=1)
    unit = d / np.maximum(length, 1e-30)[:, None]
    offset = 2.0 * clearance
    found = []
    for origin, direction in ((a, unit), (b, -unit)):
        t = tracer.closest_hit(origin.astype(np.float32), direction.astype(np.float32)).hit_t.astype(np.float64)
        ok = (t < length) & (t - offset >= 0.5 * min_spacing)
        found.append(origin[ok] + direction[ok] * (t[ok] - offset)[:, None])
    candidates = np.concatenate(found)
    if len(candidates) == 0:
        return candidates
    candidates = candidates[valid(candidates)]
    everything = np.concatenate([positions, candidates])
    survivors = thin(everything, np.arange(len(everything)), 0.5 * min_spacing)  # existing probes first
    return everything[survivors[survivors >= len(positions)]][:room]


def thin(positions: np.ndarray, order: np.ndarray, radius: float) -> np.ndarray:
    """Indices (sorted) kept by greedy thinning in ``order``: none closer than ``radius`` to a kept one."""
    if len(positions) == 0:
        return np.zeros(0, np.int64)
    tree = cKDTree(positions)
    removed = np.zeros(len(positions), bool)
    kept = []
    for i in order:
        if removed[i]:
            continue
        kept.append(i)
        for j in tree.query_ball_point(positions[i], radius):
            if j != i:
                removed[j] = True
    return np.sort(np.asarray(kept, np.int64))


def conforming_placement(tracer, scene: Scene, lighting: SceneLighting, probes: int, *, threads: int = 0,
                         density_from: np.ndarray | None = None) -> ConformingMesh:
    """The conforming probe mesh (``processors.light_probes.conforming``) of the placement box, its target edge length set so
    the probe count is near ``probes`` (a first guess from CONFORMING_DENSITY, rescaled once). With
    ``density_from`` (a placed cloud's positions), the target edge length varies as that cloud's spacing
    (fTetWild's background sizing mesh: the cloud's Delaunay tetrahedra, each probe's mean edge length)."""
    lo, hi = placement_box(scene)
    triangles = scene.points[scene.tri_vertices].astype(np.float64)

    def classify(points):
        return classify_points(tracer, lighting, points)

    edge = float((CONFORMING_DENSITY * np.prod(hi - lo) / max(probes, 4)) ** (1.0 / 3.0))
    sizing = None
    if density_from is not None and len(density_from) >= 4:
        tetra = tetrahedra.tetrahedralize(density_from)
        edges, _ = tetrahedra.edge_list(tetra.tet_vertices)
        length = np.linalg.norm(density_from[edges[:, 0]] - density_from[edges[:, 1]], axis=1)
        spacing = np.bincount(edges.ravel(), np.repeat(length, 2), len(density_from)) / np.maximum(
            np.bincount(edges.ravel(), minlength=len(density_from)), 1)
        sizing = (np.asarray(density_from, np.float64), tetra.tet_vertices, spacing)
    mesh = conforming_mesh(tracer, classify, triangles, lo, hi, edge, threads, sizing)
    count = len(mesh.positions)
    # Rescaled once; not when the count is over twice the budget: then the surfaces' detail sets it, and
    # longer edges would not bring it down (atrium: 28k probes for a budget of 1024).
    if abs(count - probes) > CONFORMING_TOLERANCE * probes and count < 2 * probes:
        scale = (count / probes) ** (1.0 / 3.0)
        edge *= scale
        sizing = None if sizing is None else (sizing[0], sizing[1], sizing[2] * scale)
        mesh = conforming_mesh(tracer, classify, triangles, lo, hi, edge, threads, sizing)
    return mesh
