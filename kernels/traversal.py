"""The ray core's device functions: closest hit, any hit and ray origins on an 8-wide, two-level BVH.

Every processor kernel traces through these (``trace_closest``, ``trace_any``, ``surface_origin``),
so rays are made and consumed in the kernel that needs them. The traversal is written in C++, in
files of its own (``native/``, read here and handed to ``wp.func_native``), rather than with
``wp.mesh_query_ray``: Warp's binary BVH reached 0.2-0.3x Embree per thread on incoherent rays, and a
kernel-language traversal cannot keep a stack or a child mask in registers. Measured alternatives are
in docs/ray_core.md.

The scene (``TraceScene``, built by ``kernels.tracer``) is bottom-level trees (one per prototype,
triangles in packets of 4, ``kernels.bvh_build``) under a top-level tree of instances, each with a
3 x 4 world-to-object matrix; a scene without instances has one identity instance and the top level
is skipped. A ray is moved into an instance's space (t is unchanged: directions are transformed,
not renormalized) and tested against its triangles with the watertight test of Woop, Benthin & Wald
("Watertight ray/triangle intersection", JCGT 2013), section 3, eq. (2)-(6): with the ray's dominant
axis kz and the shear S, each vertex A is mapped to A' = (A_kx - S_x A_kz, A_ky - S_y A_kz) and

    U = C'_x B'_y - C'_y B'_x,  V = A'_x C'_y - A'_y C'_x,  W = B'_x A'_y - B'_y A'_x

(recomputed in double when one is 0); the ray hits when U, V, W share a sign, at
t = S_z (U A_kz + V B_kz + W C_kz) / (U + V + W). A ray through a shared edge or vertex therefore
hits at least one of the triangles there. Node boxes use the robust slab test of Ize ("Robust BVH
ray traversal", JCGT 2013): the far distance is enlarged by 2 ulp-scale factors so rounding never
culls a box the ray touches.

Results follow Warp's mesh-query conventions: the hit point is u v0 + v v1 + (1 - u - v) v2 of the
scene triangle ``face``; ``sign`` > 0 on the front (winding) side.
"""

from __future__ import annotations

from pathlib import Path

import warp as wp

from .bvh_build import CHILD_OFFSET, COUNT_OFFSET, LEAF_COUNT_BITS, NODE_FLOATS, PACKET, WIDTH

wp.set_module_options({"enable_backward": False, "fuse_fp": False})


@wp.struct
class TraceScene:
    """Everything a kernel needs to trace rays: pass it as a kernel argument (``Tracer.scene``).

    The fields are device addresses of arrays the Tracer keeps alive (a struct of arrays would be copied,
    array headers and all, into every call of the traversal)."""

    nodes: wp.uint64
    """float32: wide nodes of every bottom-level tree, then the top-level tree (bvh_build layout)."""
    packets: wp.uint64
    """float32 (P, 9, 4): triangle packets of every bottom-level tree."""
    packet_triangle: wp.uint64
    """int32 (P, 4): triangle of each packet lane within its prototype, -1 for an empty lane."""
    instance_to_object: wp.uint64
    """float32 (I, 3, 4): world-to-object matrices (object = M[:, :3] world + M[:, 3])."""
    instance_to_world: wp.uint64
    """float32 (I, 3, 4): object-to-world matrices."""
    instance_root: wp.uint64
    """int32 (I,): root node of the instance's bottom-level tree."""
    instance_face: wp.uint64
    """int32 (I,): scene index of the instance's first triangle (an instance's triangles are consecutive)."""
    instance_mirrored: wp.uint64
    """int32 (I,): 1 where the scene lists the instance's triangles with reversed winding."""
    top_instances: wp.uint64
    """int32 (I,): instances in top-level leaf order; a top-level leaf addresses a run of this array."""
    top_root: int
    """Root of the top-level tree, or -1: one identity instance (0), traced without the top level."""
    scale: float
    """Power of two the arrays' coordinates are stored multiplied by (``kernels.tracer.trace_scale``): 1 for
    a scene of ordinary size. Ray origins and lengths are multiplied by it on the way in and distances
    divided by it on the way out, all exact, so a scene 1e15 or 1e-14 units across is traced as one a
    unit across (the watertight test's t carries products of three coordinates, which overflow float32
    beyond ~7e12 units and underflow below ~2e-13) and an ordinary one bit for bit as before."""


@wp.struct
class RayHit:
    """A closest hit, with wp.mesh_query_ray's field names."""

    result: wp.bool
    t: float
    face: int
    u: float
    v: float
    sign: float


NATIVE = Path(__file__).with_name("native")
"""The ray core's C++ (``wp.func_native`` snippets, pasted into the bodies of the functions below): ``bits.h``,
``ray_core.h`` (rays, node and packet tests, the one tree walk), ``trace.h`` and ``surface_origin.h``."""
NATIVE_SOURCES = tuple(sorted(NATIVE.glob("*.h")))
"""The C++ this module reads: part of its code for the result cache (``core.cache.code_fingerprint``)."""

assert WIDTH == 8 and PACKET == 4  # the C++'s vector widths (and the node layout's offsets 8 k, 24 + 8 k)


def _native(*names: str) -> str:
    """The text of ``native`` files, joined (read at import: Warp hashes a snippet's text, so an edit recompiles)."""
    return "".join((NATIVE / name).read_text() for name in names)


_LAYOUT = (f"constexpr int NODE_FLOATS = {NODE_FLOATS}, CHILD_OFFSET = {CHILD_OFFSET}, COUNT_OFFSET = {COUNT_OFFSET}, "
           f"LEAF_COUNT_BITS = {LEAF_COUNT_BITS}, PACKET_FLOATS = {9 * PACKET};\n")
"""bvh_build's layout (a packet is 9 coordinates of 4 triangles), as ray_core.h reads it."""
_RAY_CORE = _LAYOUT + _native("bits.h", "ray_core.h")


@wp.func_native(_RAY_CORE + "constexpr bool ANY_HIT = false;\n" + _native("trace.h"))
def _closest(scene: TraceScene, only: int, org: wp.vec3, dir: wp.vec3, tmax: float) -> wp.vec4:
    ...


@wp.func_native(_RAY_CORE + "constexpr bool ANY_HIT = true;\n" + _native("trace.h"))
def _any(scene: TraceScene, only: int, org: wp.vec3, dir: wp.vec3, tmax: float) -> wp.vec4:
    ...


@wp.func_native(_native("bits.h") + "return USDBAKE_FLOAT_BITS(x);")
def _float_bits(x: float) -> int:
    ...


@wp.func
def trace_closest(scene: TraceScene, origin: wp.vec3, direction: wp.vec3, max_t: float) -> RayHit:
    """Closest hit along origin + t direction, 0 <= t < max_t (direction need not be unit: t is in its units)."""
    packed = _closest(scene, -1, origin, direction, max_t)
    hit = RayHit()
    hit.result = packed[0] >= 0.0
    hit.t = packed[0]
    hit.u = packed[1]
    hit.v = packed[2]
    hit.face = -1
    hit.sign = 0.0
    if hit.result:
        bits = _float_bits(packed[3])
        hit.face = bits // 2
        hit.sign = wp.where(bits % 2 == 1, 1.0, -1.0)
    return hit


@wp.func
def trace_any(scene: TraceScene, origin: wp.vec3, direction: wp.vec3, max_t: float) -> bool:
    """Whether anything lies along origin + t direction, 0 <= t < max_t (stops at the first hit found)."""
    return _any(scene, -1, origin, direction, max_t)[3] > 0.0


@wp.func
def trace_any_in_instance(scene: TraceScene, instance: int, origin: wp.vec3, direction: wp.vec3, max_t: float) -> bool:
    """``trace_any`` against one instance's triangles only (e.g. a prototype's own geometry)."""
    return _any(scene, instance, origin, direction, max_t)[3] > 0.0


@wp.func_native(_RAY_CORE + _native("surface_origin.h"))
def surface_origin(scene: TraceScene, p: wp.vec3, n: wp.vec3, inward: wp.vec3, epsilon_units: float) -> wp.vec3:
    """Ray origin for point p on a surface with unit normal n. ``inward`` is a unit tangent pointing into
    the point's own surface (zero inside a face or a smooth region): at an unwelded crease it takes the
    origin off the crease line, to the side where its own face lies. The origin is q + epsilon n,
    q = p + epsilon inward, then moved to at least epsilon in front of every other face through q whose
    normal is not opposite n (the face a T-junction vertex rests on, a wall the point touches; their
    winding side, the outside of a solid). A ray from it meets no face through p at t <= 0. Stage units
    (``epsilon_units``, the tracer's ``epsilon``), whatever ``TraceScene.scale``."""
    ...
