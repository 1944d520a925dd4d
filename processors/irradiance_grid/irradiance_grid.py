"""Irradiance vector grid: six irradiance vectors per grid vertex, quantized and streamable.

Pacanowski, Raynaud, Granier, Reuter, Schlick, Poulin, "Efficient Streaming
of 3D Scenes with Complex Geometry and Complex Lighting", Web3D 2008
(doi:10.1145/1394209.1394214), sections 3 and 4.1.

**Grid.** A regular grid of cubic cells over the union of the stage's probe
volumes (prims with the ProbeVolumeAPI schema), or, with none, over the
receivers that are not backdrops (``geometry.mesh.backdrop_prims``: a room on
a 200 m ground plane gets its grid around the room, not on the lawn, and the
result names the backdrops left out) grown by ``vector_grid.RECEIVER_MARGIN``
of their diagonal (the scene bounds when nothing is a backdrop): ``cell_size``
stage units, or (``cell_size = 0``) the size that gives at most ``vertices``
vertices. Each axis has ``n = max(2, ceil(extent / h + 0.5) + 1)`` vertices
centred on the bounds, so the outer vertices lie between h/4 and 3h/4
outside the bounds, never on the outer walls. Vertex (i, j, k) has index
``i + nx * (j + ny * k)`` (x fastest).

**Irradiance vectors** (paper eq. 1, Arvo 1994). For each vertex p and each
axis hemisphere delta in (+x, -x, +y, -y, +z, -z), per colour channel::

    I_delta(p) = integral_{w . delta > 0} L(p <- w) w dw        (W/m^2, a vector)

Its component along delta is the irradiance of a surface facing delta, its
direction the mean direction the light comes from; for a uniform sky of radiance L it is
``pi L delta``. Estimated with ``rays`` stratified uniform sphere directions
(strata^2, jittered, seeded per vertex), each ray counted in the three
hemispheres it belongs to with weight 4 pi / N. Incident radiance: an
escaped ray sees the dome lights (sum of their radiance, textures ignored);
a ray that hits the front of a triangle (either side if double-sided) sees
``albedo / pi * E_direct`` with E_direct from one shadow-ray sample per
light (``kernels/lighting.py``: the light_probes light model), plus the
triangle's emission only when the stage has no UsdLux lights (a lamp
modelled as a light and an emissive quad, as in cornell_box.usda, would
count twice); the back of a single-sided triangle is black. The non-dome
UsdLux lights (distant, sphere, rect, disk) are added directly
(``sample_light``): ``rays`` stratified shadow-ray samples each (one for a
zero-angle distant light), each adding ``L weight w`` (weight = the solid
angle the sample stands for) to every hemisphere containing w.
``bounces = k`` > 1 carries more light: k - 1 indirect-only passes come first
(no dome, no emission, no small lights: pass j holds the light reflected 1 .. j
times), and in each later pass a hit y also reflects ``rho(y) / pi E_ind(y)``
with E_ind(y) read from the previous pass's indirect grid
(``grid_irradiance.visible_grid_irradiance``)::

    E_ind(y) = max(0, sum_c w_c V_c sum_a n_a^2 (I_{c,a} . n)) / sum_c w_c V_c

over the trilinear corners c of p = y + min(BOUNCE_OFFSET cells, t_n / 2) n,
V_c = 0 for a corner behind y's plane or hidden from p (a shadow ray), so a
hit never reads vertices beyond its wall (a sky-lit lawn outside a room's
single-sided wall made each pass add light that is not there; black
vertices outside a closed box dropped a third of each bounce); a hit more
than half a cell off the grid reads 0. The paper's weights make the read a
lower bound of the corners' light (``I_a . n <= E(n)``, ``sum n_a^2 = 1``), so
the passes converge from below; what remains is first order in the cell size
(the first vertex layer lies up to a cell off the wall: +5% of a bounce with
14 cells across a closed box, tests/processors/irradiance_grid/test_grid_bounces.py).
With ``extrapolate`` (the default, bounces >= 3) the last pass reads, instead
of G_{k-1}, the indirect grid with all bounces estimated from the passes'
geometric tail (``bounce_tail``: G_inf = G_j + dG_j r / (1 - r), r the ratio of
the last two increments): four passes carry about all of the bounces (furnished
daylight room against Radiance, free space: bounces 1 / 3 / 6 without the tail
0.455 / 0.157 / 0.081 median error in 3.0 / 11.0 / 19.6 s; 4 with it 0.084
in 12.9 s, and 0.094 in 7.7 s with the default 64 ``bounce_rays`` in the
passes before the last).
``include_direct = false`` keeps only the light the scene reflects (no dome,
no emission, no direct lights): the paper's indirect-only grid, for a
renderer that adds direct light itself.

**Inside geometry.** A vertex whose rays hit the back of single-sided
triangles more than half of the time is *invalid* (inside closed geometry);
its vectors are filled by 3D push-pull (``streaming.push_pull``) from the
valid ones.

**Quantization** (paper section 3.3). For hemisphere delta with RGB vectors
``I^R, I^G, I^B``::

    d = (I^R + I^G + I^B) / |I^R + I^G + I^B|      -> 8:8:8 bits (kernels/direction24.py)
    c = [I^R . delta, I^G . delta, I^B . delta] / (d' . delta)   -> RGB9E5 (kernels/rgb9e5.py)

with ``d'`` the *decoded* direction, so ``M delta = c (d' . delta)`` holds
exactly for the stored direction (the paper's guarantee, kept through
quantization). d takes 24 bits as in the paper, one signed byte a component
(at most 0.55 degrees off, axis directions exact): 6 x (3 + 4) = 42 bytes a
vertex.

**Reconstruction** (paper section 3.2) at a point p with unit normal n:
trilinear interpolation of the decoded vectors ``I_delta = c d'`` of the 8
surrounding vertices, for the three hemispheres chosen by the signs of n,
then::

    I_n(p) = I_x(p) n_x^2 + I_y(p) n_y^2 + I_z(p) n_z^2
    E(p, n) = max(0, I_n(p) . n)    per channel (irradiance, W/m^2; eq. 2: L_r = rho / pi E)

The point is moved ``normal_offset`` cells along n first, so a surface
reads the grid on its lit side rather than half inside the wall it lies on.
Options beyond the paper (measured in docs/irradiance_grid.md):
``reconstruction = normalized`` divides E by ``sum |n_a|^3`` (exact for a
uniform sky too; the paper's formula gives ``pi L sum |n_a|^3``), and
``behind_cutoff`` drops the trilinear corners behind the surface's plane.

**Streaming** (paper section 4.1, ``streaming.py``): the valid vertices in
progressive (coarse-to-fine, stratified) order, written to a stream file a
client can read a prefix of and complete by push-pull.

USD written (bake layer): an ``IrradianceVectorGrid`` at
``/usdbake/IrradianceGrid`` (``/usdbake`` is a Scope; a root prim, so the
grid does not depend on the default prim's transform; world space):

====================== ========== ===============================================================
property               type       value
====================== ========== ===============================================================
gridOrigin             point3f    world position of vertex (0, 0, 0)
cellSize               float3     cell size along x, y, z (stage units)
resolution             int3       vertices along x, y, z
directions             uchar[]    6 x 3 per vertex (+x, -x, +y, -y, +z, -z; x, y, z as q + 128)
colorsRGB9E5           uint[]     6 per vertex, the colour c above
vectorsPerVertex       int        6
streamFile             asset      ``usdbake_irradiance_grid_<hash>.bin`` (streaming.py format)
bake:vertexValid       uchar[]    1 = computed, 0 = inside geometry (filled by push-pull)
bake:directionEncoding token      ``snorm888`` (uniform)
bake:includeDirect     bool       the include_direct parameter
bake:rays              int        rays per vertex
bake:bounces           int        the bounces parameter
====================== ========== ===============================================================

and on every writable mesh ``primvars:bake:irradianceGrid`` (color3f[],
vertex): the reconstructed irradiance E at its points with the area-weighted
vertex normals (``usdbake preview --channel irradianceGrid``).

Product: an ``IrradianceGridProduct`` (products.py; scene frame).

Parameters: ``usdbake list irradiance_grid`` or docs/irradiance_grid.md, both generated from ``Params`` below.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass

import numpy as np
import warp as wp

from ...core import Attribute, Context, File, Params, Prim, Primvar, Processor, Result, param
from ...core.chunks import SceneChunks
from .products import IrradianceGridProduct
from ...core.scene import Scene
from ...formats import streaming
from ...geometry.mesh import backdrop_prims, receiver_prims, vertex_normals
from ...kernels.light_bundles import NO_LIGHTS, SceneLighting, emissive_lights, has_light, scene_lighting
from ...kernels.lights import Lights, Surfaces, hit_radiance, light_sample_count, sky_radiance, visible_light_sample
from ...kernels.direction24 import AXES, decode_directions, dequantize_vectors, encode_directions
from .grid_irradiance import GridVectors, bounce_tail, grid_vectors, visible_grid_irradiance
from ...kernels.rgb9e5 import encode_rgb9e5
from ...kernels.sampling import strata_for, stratified_pair
from ...kernels.sh import uniform_sphere
from ...kernels.tracer import FAR
from ...kernels.traversal import TraceScene, trace_closest
from .vector_grid import (MAX_GRID_VERTICES, RECONSTRUCTIONS, GridLayout, grid_bounds, grid_layout,
                          reconstruct_irradiance)

wp.set_module_options({"enable_backward": False, "fuse_fp": False})

GRID_PRIM = "/usdbake/IrradianceGrid"
VECTORS_PER_VERTEX = 6

BOUNCE_OFFSET = 0.5
"""A hit reads the previous pass's grid this many cells off its surface (as a mesh vertex reads the grid)."""

INSIDE_BACK_FRACTION = 0.5
"""A vertex is inside geometry when more than this fraction of its rays hit single-sided back faces."""


# ---------------------------------------------------------------------------
# Warp


@wp.func
def add_to_hemispheres(m: wp.array(dtype=wp.mat33), base: int, w: wp.vec3, o: wp.mat33):
    """Add o to the (up to) three hemisphere accumulators whose half-space contains w: the six vectors
    of a grid vertex integrate over the +-x, +-y, +-z hemispheres (Pacanowski et al. section 3.1, eq. 1)."""
    if w[0] > 0.0:
        m[base + 0] = m[base + 0] + o
    elif w[0] < 0.0:
        m[base + 1] = m[base + 1] + o
    if w[1] > 0.0:
        m[base + 2] = m[base + 2] + o
    elif w[1] < 0.0:
        m[base + 3] = m[base + 3] + o
    if w[2] > 0.0:
        m[base + 4] = m[base + 4] + o
    elif w[2] < 0.0:
        m[base + 5] = m[base + 5] + o


@wp.kernel
def irradiance_vectors_kernel(
    start: int,
    scene: TraceScene,
    surfaces: Surfaces,
    lights: Lights,
    positions: wp.array(dtype=wp.vec3),
    strata: int,
    seed: int,
    first: int,
    epsilon: float,
    include_direct: int,
    see_emission: int,
    bounce: GridVectors,
    use_bounce: int,
    bounce_offset: float,
    vectors: wp.array(dtype=wp.mat33),
    back_hits: wp.array(dtype=int),
):
    """Vertex i: the six hemisphere irradiance vectors (paper eq. 1), I = integral L(w) w dw over each
    hemisphere, rows = RGB channels, by strata^2 stratified uniform sphere rays (weight 4 pi / N) whose
    hits return ``hit_radiance``, plus the small lights sampled directly (``light_sample_at``). With
    ``use_bounce`` a hit y also reflects rho(y) / pi E_ind(y), E_ind read from the previous pass's
    indirect grid ``bounce`` at y moved ``bounce_offset`` along its normal (``grid_irradiance``).
    Vertex i draws from (seed, first + i): ``first`` is the global index of positions[0] (a chunk's start)."""
    i = start + wp.tid()
    p = positions[i]
    state = wp.rand_init(seed, first + i)
    samples = strata * strata
    weight = 4.0 * wp.pi / float(samples)
    base = i * 6
    back = int(0)
    for k in range(samples):
        u = stratified_pair(k, strata, state)
        d = uniform_sphere(u[0], u[1])
        value = wp.vec3(0.0, 0.0, 0.0)
        q = trace_closest(scene, p, d, FAR)
        if not q.result:
            if include_direct != 0:
                value = sky_radiance(lights, d)
        else:
            if wp.dot(surfaces.tri_normals[q.face], d) >= 0.0 and surfaces.tri_double_sided[q.face] == 0:
                back += 1
            value = hit_radiance(scene, surfaces, lights, p, d, q.face, q.t, see_emission, epsilon,
                                 wp.rand_init(wp.int32(state), samples + k))
            hn = surfaces.tri_normals[q.face]
            if use_bounce != 0 and (wp.dot(hn, d) < 0.0 or surfaces.tri_double_sided[q.face] != 0):
                if wp.dot(hn, d) > 0.0:
                    hn = -hn  # the side the ray sees
                e_ind = visible_grid_irradiance(scene, bounce, p + d * q.t, hn, bounce_offset, epsilon)
                value += wp.cw_mul(surfaces.tri_albedo[q.face], e_ind) * (1.0 / wp.pi)
        if wp.length_sq(value) > 0.0:
            add_to_hemispheres(vectors, base, d, wp.outer(value * weight, d))
    back_hits[i] = back
    if include_direct == 0:
        return
    for l in range(lights.light_kind.shape[0]):  # the small lights; domes are seen by the escaped rays above
        for k in range(light_sample_count(lights, l, strata)):
            s = visible_light_sample(scene, lights, l, p, k, strata, state)
            if s.weight > 0.0:
                add_to_hemispheres(vectors, base, s.direction,
                                   wp.outer(lights.light_radiance[l] * s.weight, s.direction))


# ---------------------------------------------------------------------------
# Compute


def see_emission(scene: Scene, include_direct: bool) -> int:
    """1 when rays count the emission of the triangles they hit: direct light is wanted and emissive
    triangles are lights (``emissive_lights``: a lamp modelled as a light *and* an emissive quad, as in
    cornell_box.usda, would otherwise count twice; its light comes from the UsdLux light)."""
    return int(bool(include_direct) and emissive_lights(scene))


def compute_irradiance_vectors(tracer, scene: Scene, positions: np.ndarray, *, rays: int, seed: int = 0,
                               include_direct: bool = True, lighting: SceneLighting | None = None,
                               bounce: tuple | None = None, first: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Irradiance vectors at points (module docstring, paper eq. 1).

    bounce : (layout, vectors) of an indirect-only grid whose light the hits reflect once more (``bounces``).
    first : global index of positions[0], which seeds its rays (a chunk of a larger set, core.chunks)

    Parameters
    ----------
    positions : (N, 3) float32 points in the scene frame

    Returns
    -------
    vectors : (N, 6, 3, 3) float32, [point, hemisphere (+x, -x, +y, -y, +z, -z), channel RGB, xyz] (W/m^2)
    back_fraction : (N,) float32 fraction of rays that hit single-sided triangles from behind
    """
    positions = np.ascontiguousarray(positions, np.float32).reshape(-1, 3)
    count = len(positions)
    if count == 0:
        return np.zeros((0, 6, 3, 3), np.float32), np.zeros(0, np.float32)
    lighting = lighting or scene_lighting(scene, tracer.device)
    strata = strata_for(rays)
    vectors = wp.zeros(count * 6, dtype=wp.mat33, device=tracer.device)
    back = wp.zeros(count, dtype=int, device=tracer.device)
    if bounce is None:
        previous, offset = grid_vectors(np.zeros((1, 6, 3, 3)), (1, 1, 1), (0, 0, 0), (1, 1, 1), tracer.device), 0.0
    else:
        layout, grid = bounce
        previous = grid_vectors(grid, layout.resolution, layout.grid_origin, layout.cell_size, tracer.device)
        offset = BOUNCE_OFFSET * float(np.min(layout.cell_size))
    tracer.launch(irradiance_vectors_kernel, count, [
        tracer.scene, lighting.surfaces, lighting.lights, tracer.array(positions, wp.vec3), strata, int(seed),
        int(first), tracer.epsilon, int(bool(include_direct)), see_emission(scene, include_direct), previous,
        int(bounce is not None), offset, vectors, back,
    ])
    tracer.rays_cast += count * strata * strata * (1 + lighting.shadow_rays + len(scene.lights))
    out = np.nan_to_num(vectors.numpy().reshape(count, 6, 3, 3), nan=0.0, posinf=0.0, neginf=0.0)
    return out.astype(np.float32), (back.numpy() / float(strata * strata)).astype(np.float32)


def irradiance_vectors_chunk(tracer, first: int, positions: np.ndarray, *, scene: Scene, rays: int, seed: int,
                             include_direct: bool, bounce: tuple | None) -> tuple[np.ndarray, np.ndarray]:
    """``compute_irradiance_vectors`` of grid vertices first .. first + len(positions) - 1: one chunk
    (core.chunks)."""
    return compute_irradiance_vectors(tracer, scene, positions, rays=rays, seed=seed, include_direct=include_direct,
                                      bounce=bounce, first=first)


def quantize_vectors(vectors: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Compress (N, 6, 3, 3) vectors to (directions (N, 6, 3) uint8, colors (N, 6) uint32) (paper 3.3):
    42 bytes a vertex."""
    vectors = np.nan_to_num(np.asarray(vectors, np.float64).reshape(-1, 6, 3, 3), nan=0.0, posinf=0.0, neginf=0.0)
    n = len(vectors)
    hemisphere = np.broadcast_to(np.arange(6), (n, 6)).reshape(-1)
    total = vectors.sum(axis=2).reshape(-1, 3)  # I^R + I^G + I^B
    codes = encode_directions(total, hemisphere)
    decoded = decode_directions(codes).astype(np.float64)
    axes = AXES[hemisphere].astype(np.float64)
    along = np.einsum("nci,ni->nc", vectors.reshape(-1, 3, 3), axes)  # I^c . delta
    cosine = np.einsum("ni,ni->n", decoded, axes)  # >= direction24.MIN_AXIS_COSINE
    colors = encode_rgb9e5(np.maximum(along, 0.0) / cosine[:, None])
    return codes.reshape(n, 6, 3), colors.reshape(n, 6)


def fill_invalid(vectors: np.ndarray, resolution, valid: np.ndarray, *, smooth: bool = True) -> np.ndarray:
    """(V, 6, 3, 3): invalid vertices replaced by push-pull of the valid ones."""
    shape = vectors.shape
    if valid.all():
        return vectors
    filled = streaming.push_pull(vectors.reshape(len(vectors), -1), resolution, valid, smooth=smooth)
    return filled.reshape(shape).astype(np.float32)


def bake_grid(tracer, scene: Scene, layout: GridLayout, *, rays: int, seed: int = 0, include_direct: bool = True,
              smooth: bool = True, bounces: int = 1, bounce_rays: int | None = None, extrapolate: bool = False,
              progress=lambda f: None, chunks=None) -> IrradianceGridProduct:
    """Compute, fill and quantize the grid (module docstring); ``bounces`` - 1 indirect-only passes first
    (``bounce_rays`` rays a vertex, default ``rays``), each reflected once more by the next, their geometric
    tail added with ``extrapolate`` (``bounce_tail``). ``chunks`` (core.chunks; default: in process on
    ``tracer``) computes each pass's vectors by vertex ranges."""
    chunks = chunks if chunks is not None else SceneChunks(tracer)
    bounce, passes = None, [np.zeros((layout.count, VECTORS_PER_VERTEX, 3, 3), np.float32)]
    for step in range(bounces - 1):
        indirect, back = chunks.map(irradiance_vectors_chunk, (layout.positions(),), scene=scene,
                                    rays=bounce_rays or rays, seed=seed + 1000 * (step + 1), include_direct=False,
                                    bounce=bounce)
        passes.append(fill_invalid(indirect, layout.resolution, back <= INSIDE_BACK_FRACTION, smooth=smooth))
        bounce = (layout, bounce_tail(*passes[-3:]) if extrapolate and step == bounces - 2 else passes[-1])
        progress(0.8 * (step + 1) / bounces)
    vectors, back = chunks.map(irradiance_vectors_chunk, (layout.positions(),), scene=scene, rays=rays, seed=seed,
                               include_direct=include_direct, bounce=bounce)
    progress(0.8)
    valid = back <= INSIDE_BACK_FRACTION
    # Fill from the dequantized valid vertices, as a client completing the full stream does.
    directions, colors = quantize_vectors(vectors)
    received = dequantize_vectors(directions, colors)
    if not valid.all():
        filled = fill_invalid(received, layout.resolution, valid, smooth=smooth)
        fd, fc = quantize_vectors(filled[~valid])
        directions[~valid], colors[~valid] = fd, fc
        vectors = fill_invalid(vectors, layout.resolution, valid, smooth=smooth)
    return IrradianceGridProduct(layout, directions, colors, valid, vectors)


# ---------------------------------------------------------------------------
# The processor


def grid_records(grid: IrradianceGridProduct, origin: np.ndarray, stream_file: str, *, rays: int,
                 include_direct: bool, bounces: int) -> list:
    """Prim and attribute records of the IrradianceVectorGrid at GRID_PRIM (world space)."""
    path = GRID_PRIM
    layout = grid.layout
    world = (layout.grid_origin + np.asarray(origin, np.float64)).astype(np.float32)
    return [
        Prim("/usdbake", "Scope"), Prim(path, "IrradianceVectorGrid"),
        Attribute(path, "gridOrigin", world, "point3f"),
        Attribute(path, "cellSize", layout.cell_size.astype(np.float32), "float3"),
        Attribute(path, "resolution", np.asarray(layout.resolution, np.int32), "int3"),
        Attribute(path, "directions", grid.directions.reshape(-1), "uchar[]"),
        Attribute(path, "colorsRGB9E5", grid.colors.reshape(-1), "uint[]"),
        Attribute(path, "vectorsPerVertex", VECTORS_PER_VERTEX, "int"),
        Attribute(path, "streamFile", stream_file, "asset"),
        Attribute(path, "bake:vertexValid", grid.vertex_valid.astype(np.uint8), "uchar[]"),
        Attribute(path, "bake:directionEncoding", "snorm888", "token", uniform=True),
        Attribute(path, "bake:includeDirect", bool(include_direct), "bool"),
        Attribute(path, "bake:rays", int(rays), "int"),
        Attribute(path, "bake:bounces", int(bounces), "int"),
    ]


def stream_bytes(grid: IrradianceGridProduct, origin: np.ndarray) -> bytes:
    """The stream file of the grid's valid vertices in progressive order."""
    layout = grid.layout
    order = streaming.progressive_order(layout.resolution)
    order = order[grid.vertex_valid[order]]
    return streaming.encode_stream(layout.resolution, layout.grid_origin + np.asarray(origin, np.float64),
                                   layout.cell_size, order, grid.directions, grid.colors)


class IrradianceGrid(Processor):
    name = "irradiance_grid"
    version = "4"
    summary = "Irradiance vector grid: 6 vectors per vertex, 8-bit direction + RGB9E5, progressive stream."
    facets = ("geometry", "materials", "lights")
    follows_refinement = True
    writes = ("primvars:bake:irradianceGrid",)
    provides = (IrradianceGridProduct,)

    @dataclass(frozen=True)
    class Params(Params):
        cell_size: float = param(0.0, "cell size in stage units; 0 = from vertices", low=0.0)
        vertices: int = param(20000, "target vertex count when cell_size is 0 (an upper bound)", low=8,
                              high=MAX_GRID_VERTICES)
        rays: int = param(256, "rays per grid vertex (rounded to a square for stratification)", low=1,
                          high=1_000_000)
        include_direct: bool = param(True, "store direct light too (false: one-bounce indirect only)")
        normal_offset: float = param(0.5, "reconstruction point moved this many cells along the normal",
                                     low=0.0, high=4.0)
        reconstruction: str = param("paper", "E = I_n . n (paper) or divided by sum |n_a|^3 (normalized)",
                                    choices=RECONSTRUCTIONS)
        behind_cutoff: bool = param(False, "reconstruction ignores grid vertices behind the surface's plane")
        smooth: bool = param(True, "pyramidal smoothing in the push-pull fill of invalid vertices")
        bounces: int = param(4, "light bounces the grid carries: 1 = surfaces reflect direct light (the paper); "
                             "k adds k - 1 capture passes, each hit reflecting the previous pass's indirect light "
                             "read from the grid", low=1, high=8)
        bounce_rays: int = param(64, "rays per vertex of each indirect pass before the last (the light they carry "
                                 "is smooth, and the last pass averages it over its own rays)", low=1,
                                 high=1_000_000)
        extrapolate: bool = param(True, "the last pass reads the earlier passes' geometric tail (all bounces; "
                                  "needs bounces >= 3) instead of the k - 1 bounces they hold")
        seed: int = param(0, "random seed (identical results across thread counts)", low=0, high=2**31 - 1)

    def applies(self, ctx: Context) -> tuple[bool, str]:
        scene = ctx.scene
        if scene.num_triangles == 0:
            return False, "no geometry"
        if not has_light(scene):
            return False, NO_LIGHTS
        return True, ""

    def run(self, ctx: Context) -> Result:
        scene, p = ctx.scene, ctx.params
        lo, hi = grid_bounds(scene)
        layout = grid_layout(lo, hi, cell_size=p.cell_size, vertices=p.vertices)
        ctx.progress(0.0)
        grid = bake_grid(ctx.tracer, scene, layout, rays=p.rays, seed=p.seed, include_direct=p.include_direct,
                         bounces=p.bounces, bounce_rays=p.bounce_rays, extrapolate=p.extrapolate, smooth=p.smooth,
                         progress=ctx.progress, chunks=ctx.chunks)
        data = stream_bytes(grid, scene.origin)
        stream_file = f"usdbake_irradiance_grid_{hashlib.sha256(data).hexdigest()[:10]}.bin"
        outputs = [*grid_records(grid, scene.origin, stream_file, rays=strata_for(p.rays) ** 2, bounces=p.bounces,
                                 include_direct=p.include_direct), File(stream_file, data)]
        receivers = receiver_prims(scene)
        normals = vertex_normals(scene.points, scene.tri_vertices, scene.tri_normals, scene.tri_areas)
        decoded = dequantize_vectors(grid.directions, grid.colors)
        for prim in receivers:
            sl = scene.prim_points(prim)
            values = reconstruct_irradiance(layout, decoded, scene.points[sl], normals[sl],
                                            normal_offset=p.normal_offset, reconstruction=p.reconstruction,
                                            behind_cutoff=p.behind_cutoff)
            outputs.append(Primvar(scene.prim_paths[prim], "bake:irradianceGrid", values, "color3f", "vertex"))
        ctx.progress(1.0)
        v = layout.count
        rays = strata_for(p.rays) ** 2 + (p.bounces - 1) * strata_for(p.bounce_rays) ** 2
        stats = {"rays": float(v * rays), "vertices": float(v), "valid_vertices": float(grid.vertex_valid.sum()),
                 "cell_size": float(layout.cell_size[0]), "stream_bytes": float(len(data)),
                 "quantized_bytes": float(grid.directions.nbytes + grid.colors.nbytes),
                 "float_bytes": float(v * VECTORS_PER_VERTEX * 9 * 4)}
        messages = []
        if len(scene.probe_volumes):
            messages.append(f"grid over {len(scene.probe_volumes)} probe volume(s) (ProbeVolumeAPI): "
                            f"{' x '.join(f'{x:.3g}' for x in hi - lo)} stage units, cell {layout.cell_size[0]:.3g}")
        backdrops, _ = backdrop_prims(scene)
        if not len(scene.probe_volumes) and len(backdrops):
            stats["backdrops_left_out"] = float(len(backdrops))
            messages.append(f"grid placed around the receivers, leaving out the backdrop(s) "
                            f"{', '.join(scene.prim_paths[int(b)] for b in backdrops[:3])}"
                            f"{' ...' if len(backdrops) > 3 else ''} (a ProbeVolumeAPI prim says where the grid "
                            f"goes): {' x '.join(f'{x:.3g}' for x in hi - lo)} stage units, cell "
                            f"{layout.cell_size[0]:.3g}")
        invalid = v - int(grid.vertex_valid.sum())
        if invalid:
            messages.append(f"{invalid} of {v} grid vertices are inside geometry (filled by push-pull)")
        return Result(products={IrradianceGridProduct: grid}, outputs=outputs, stats=stats, messages=messages)
