"""Light probe cloud: automatic placement, L2 SH irradiance capture, tetrahedral interpolation.

Sukys, "Light probe cloud generation for games", MSc thesis, Chalmers 2014
(placement: section 3.1, spawn and merge 3.1.1, gradient ascent and light
decoupling 3.1.2, unlit areas 3.1.3; tetrahedral grid and barycentric traversal
3.2.1; leaks 3.2.2), after Cupisz, "Light probe interpolation using tetrahedral
tessellations", GDC 2012. docs/light_probes.md has the whole account and figures.

**Placement** (``processors/light_probes/placement.py``). ``placement=thesis``: jittered grid
candidates in the empty space, captured *decoupled* (the dome and bounced light, not the real-time
lights), moved by gradient ascent on the variation ``V_i = max_j c_ij / |x_i - x_j|`` of irradiance
between Delaunay neighbours, spawned at the midpoints of contrasted long edges, merged where neighbours
see the same light, clustered in unlit regions, and with ``leak_fix`` wall probes beside the blockers
of tetrahedron edges; ``placement=refine``: probes go where the cloud predicts its own (decoupled)
light worst among captured candidates. ``tetrahedra=conforming`` places the probes on fTetWild's mesh
of the empty space instead (``processors/light_probes/conforming.py``: one probe per vertex and side of
every surface).

**Capture** (``processors/light_probes/capture.py``). ``rays`` stratified sphere
directions per probe and ``sky_rays`` stratified visibility rays that see the dome (its
part of the radiance estimated apart, so a probe lit through a window is not decided by a
few rays); hits return
``L_e + rho (E0 + E_ind) / pi`` with ``bounces`` bounces; the lights that are not
geometry are projected as visible sources only with ``direct_lights=probes``,
otherwise ``irradiance_at`` adds them at the lookup by shadow rays. The
radiance SH is convolved with the clamped cosine, so ``shCoefficients`` hold
irradiance: ``E(n) = sum_k c_k Y_k(n)`` (W/m^2). De-ringing windows probes whose
L2 irradiance goes negative (``kernels.sh.dering``).

**Interpolation** (``processors/light_probes/interpolation.py``). Barycentric weights of the
tetrahedron holding the point (clamped outside the hull); Delaunay clouds with ``leak_fix`` store a
6-bit blocked-edge mask per tetrahedron and keep only the query's side of the blockers, or, with a
tracer, test the four probes' visibility; conforming clouds need neither.

USD written (bake layer): a ``LightProbeCloud`` prim at ``/usdbake/LightProbes``
(``cloud_records``: world-space positions, irradiance SH, tetrahedra,
neighbours, blocked edges, barycentric matrices, ``bake:directLights``, capture
positions of a conforming cloud). Product: a ``ProbeCloud`` (scene frame).

Parameters: ``usdbake list light_probes`` or docs/light_probes.md, both generated from ``Params`` below.
"""
from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from ...core import Attribute, Context, Params, Prim, Processor, Result, param
from .products import ProbeCloud
from ...geometry.mesh import backdrop_prims
from ...kernels.light_bundles import NO_LIGHTS, has_light, scene_lighting
from ...kernels.sh import dering
from . import tetrahedra
from .capture import probe_sh_chunk
from .interpolation import build_cloud, cloud_from_arrays
from .placement import conforming_placement, place_probes, refine_placement

CLOUD_PRIM = "/usdbake/LightProbes"

PLACEMENTS = ("refine", "thesis")
TETRAHEDRA = ("delaunay", "conforming")
DIRECT_LIGHTS = ("lookup", "probes")


def cloud_records(cloud: ProbeCloud, origin: np.ndarray) -> list:
    """Prim and attribute records of a LightProbeCloud at CLOUD_PRIM (world-space positions)."""
    path = CLOUD_PRIM
    world = (cloud.probe_positions.astype(np.float64) + np.asarray(origin, np.float64)).astype(np.float32)
    return [
        Prim("/usdbake", "Scope"), Prim(path, "LightProbeCloud"),
        Attribute(path, "probePositions", world, "point3f[]"),
        Attribute(path, "shCoefficients", cloud.probe_sh.reshape(-1, 3), "float3[]"),
        Attribute(path, "tetrahedra", cloud.tet_vertices.reshape(-1).astype(np.int32), "int[]"),
        Attribute(path, "tetNeighbors", cloud.tet_neighbors.reshape(-1).astype(np.int32), "int[]"),
        Attribute(path, "shOrder", 2, "int"),
        Attribute(path, "shBasis", "realOrthonormal", "token"),
        Attribute(path, "bake:tetBlockedEdges", cloud.tet_blocked.astype(np.uint8), "uchar[]"),
        Attribute(path, "bake:shQuantity", "irradiance", "token", uniform=True),
        # An engine's lookup without our code: b = M (p - v0) with M per tetrahedron, b0 = 1 - b1 - b2 - b3.
        Attribute(path, "bake:tetBarycentricMatrices", cloud.tetra.tet_inverse.reshape(-1).astype(np.float32),
                  "float[]"),
        Attribute(path, "bake:directLights", "included" if cloud.direct_lights else "excluded", "token",
                  uniform=True),
    ] + ([] if cloud.capture_positions is None else [
        Attribute(path, "bake:capturePositions", (cloud.capture_positions.astype(np.float64)
                                                  + np.asarray(origin, np.float64)).astype(np.float32), "point3f[]")])


class LightProbes(Processor):
    name = "light_probes"
    version = "6"
    summary = "Light probe cloud: placement by gradient ascent + spawn/merge, L2 SH irradiance, tetrahedra."
    facets = ("geometry", "materials", "lights")
    provides = (ProbeCloud,)

    @dataclass(frozen=True)
    class Params(Params):
        probes: int = param(1024, "probe budget (grid: at most half; a quarter kept for wall probes)",
                            low=4, high=1_000_000)
        min_spacing: float = param(0.0, "probes closer than this (stage units) merge; 0 = half the grid spacing",
                                   low=0.0)
        iterations: int = param(3, "rounds of gradient ascent + spawn + merge (0: the grid only)", low=0, high=100)
        contrast: float = param(0.25, "edge contrast above which a probe is spawned at the midpoint",
                                low=0.0, high=1.0)
        rays: int = param(1024, "capture rays per probe (rounded to a square; 256 left 12-14 % noise in a "
                          "sky-lit room)", low=1, high=1_000_000)
        sky_rays: int = param(1024, "visibility rays per probe that look for the dome (rounded to a square; "
                              "cheap any-hit rays, so the sky seen through a window is not left to the few capture "
                              "rays that leave through it)", low=1, high=1_000_000)
        placement_rays: int = param(64, "capture rays per probe while placing", low=1, high=1_000_000)
        leak_fix: bool = param(True, "delaunay: wall probes, ray-cast tetrahedron edges, stop interpolation "
                                     "across blockers")
        placement: str = param("refine", "refine: probes go where the cloud predicts its own (decoupled) light "
                               "worst among captured candidates; thesis: Sukys' grid + gradient ascent + spawn and "
                               "merge (iterations, contrast, min_spacing) + wall probes", choices=PLACEMENTS)
        tetrahedra: str = param("delaunay", "delaunay: the placed cloud's Delaunay tetrahedra (scipy) with the leak "
                                "rule; conforming: fTetWild's mesh of the empty space, a probe per vertex and side "
                                "of every surface (no tetrahedron crosses one)", choices=TETRAHEDRA)
        direct_lights: str = param("lookup", "lookup: probes hold the dome and bounced light, the direct light of "
                                   "distant/sphere/rect/disk lights is added where the cloud is read (shadow rays; "
                                   "an engine's real-time lights); probes: it is in the SH too", choices=DIRECT_LIGHTS)
        bounces: int = param(6, "bounces of light the probes see (1: surfaces lit directly; 3 left 8-15 % of a "
                             "sky-lit room's light out)", low=1, high=16)
        dering: bool = param(True, "window each ringing probe's SH by the least Gaussian exp(-s l(l+1)) that makes "
                                   "its irradiance non-negative in every direction (probes that do not ring are kept)")
        seed: int = param(0, "random seed (identical results across thread counts)", low=0, high=2**31 - 1)

    def applies(self, ctx: Context) -> tuple[bool, str]:
        scene = ctx.scene
        if scene.num_triangles == 0 or scene.diagonal <= 0:
            return False, "no empty space (the stage has no geometry to place probes around)"
        if not has_light(scene):
            return False, NO_LIGHTS
        return True, ""

    def run(self, ctx: Context) -> Result:
        scene, p, tracer = ctx.scene, ctx.params, ctx.tracer
        ctx.progress(0.0)
        lighting = scene_lighting(scene, tracer.device)
        rays_before = tracer.rays_cast
        stats: dict[str, float] = {}
        started = time.perf_counter()
        if p.tetrahedra == "conforming":
            density = None
            if p.placement == "refine":
                density = refine_placement(tracer, scene, probes=p.probes, placement_rays=p.placement_rays,
                                           bounces=p.bounces, seed=p.seed, leak_fix=False, lighting=lighting,
                                           progress=ctx.progress).positions.astype(np.float64)
            mesh = conforming_placement(tracer, scene, lighting, p.probes, threads=ctx.threads or 0,
                                        density_from=density)
            positions, capture_at = mesh.positions.astype(np.float32), mesh.capture_positions.astype(np.float32)
            stats.update({"mesh_vertices": float(mesh.mesh_vertices), "solid_tets": float(mesh.solid_tets),
                          "covered_faces": float(mesh.covered_faces), "tetwild_seconds": mesh.seconds})
        else:
            if p.placement == "refine":
                placement = refine_placement(tracer, scene, probes=p.probes, placement_rays=p.placement_rays,
                                             bounces=p.bounces, seed=p.seed, leak_fix=p.leak_fix, lighting=lighting,
                                             progress=ctx.progress)
            else:
                placement = place_probes(tracer, scene, probes=p.probes, min_spacing=p.min_spacing,
                                         iterations=p.iterations, contrast=p.contrast,
                                         placement_rays=p.placement_rays, seed=p.seed, leak_probes=p.leak_fix,
                                         bounces=p.bounces, lighting=lighting, progress=ctx.progress)
            if len(placement.positions) < 4:
                raise ValueError(f"light_probes: only {len(placement.positions)} probe positions in empty space "
                                 f"({placement.dropped_inside} of {placement.candidates} candidates were inside or "
                                 "next to geometry); raise probes or lower min_spacing")
            positions = capture_at = placement.positions
            stats.update({"candidates": float(placement.candidates), "dropped_inside": float(placement.dropped_inside),
                          "moved": float(placement.moved), "spawned": float(placement.spawned),
                          "merged": float(placement.merged), "wall_probes": float(placement.wall_probes),
                          "min_spacing": float(placement.min_spacing)})
        ctx.progress(0.6)
        stats["placement_seconds"] = time.perf_counter() - started
        started = time.perf_counter()
        direct_in_probes = p.direct_lights == "probes"
        sh = ctx.chunks.map(probe_sh_chunk, (capture_at,), scene=scene, rays=p.rays, seed=p.seed + 1_000_003,
                            bounces=p.bounces, direct_lights=direct_in_probes, sky_rays=p.sky_rays)
        stats["capture_seconds"] = time.perf_counter() - started
        deringed = 0
        if p.dering:
            windowed, strengths = dering(sh)
            sh, deringed = windowed.astype(np.float32), int((strengths > 0).sum())
        ctx.progress(0.9)
        try:
            if p.tetrahedra == "conforming":
                cloud = cloud_from_arrays(positions, sh, mesh.tet_vertices, mesh.tet_neighbors,
                                          direct_lights=direct_in_probes, capture_positions=capture_at)
            else:
                cloud = build_cloud(positions, sh, tracer, leak_fix=p.leak_fix, direct_lights=direct_in_probes)
        except tetrahedra.DegenerateProbesError as error:
            raise ValueError(f"light_probes: {error}") from None
        ctx.progress(1.0)
        blocked_edges = int(np.unpackbits(cloud.tet_blocked[:, None], axis=1).sum())
        stats.update({"probes": float(len(cloud.probe_positions)), "tetrahedra": float(len(cloud.tet_vertices)),
                      "blocked_tet_edges": float(blocked_edges), "deringed_probes": float(deringed),
                      "rays": float(tracer.rays_cast - rays_before)})
        messages = []
        backdrops, _ = backdrop_prims(scene)
        if not len(scene.probe_volumes) and len(backdrops):
            stats["backdrops_left_out"] = float(len(backdrops))
            messages.append(f"probes placed around the receivers, leaving out the backdrop(s) "
                            f"{', '.join(scene.prim_paths[int(b)] for b in backdrops[:3])}"
                            f"{' ...' if len(backdrops) > 3 else ''} (a ProbeVolumeAPI prim says where probes go)")
        if p.tetrahedra == "conforming" and len(cloud.probe_positions) > 2 * p.probes:
            messages.append(f"conforming tetrahedra need {len(cloud.probe_positions)} probes to follow this stage's "
                            f"surfaces, over twice the budget of {p.probes} (tetrahedra=delaunay keeps the budget)")
        if len(scene.probe_volumes):
            stats["probe_volumes"] = float(len(scene.probe_volumes))
            messages.append(f"{len(cloud.probe_positions)} probes placed in {len(scene.probe_volumes)} probe "
                            "volume(s) (ProbeVolumeAPI)")
        return Result(products={ProbeCloud: cloud}, outputs=cloud_records(cloud, scene.origin), stats=stats,
                      messages=messages)
