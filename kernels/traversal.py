"""The ray core's device functions: closest hit, any hit and ray origins on an 8-wide, two-level BVH.

Every processor kernel traces through these (``trace_closest``, ``trace_any``, ``surface_origin``),
so rays are made and consumed in the kernel that needs them. The traversal is written here in C++
(``wp.func_native``) rather than with ``wp.mesh_query_ray``: Warp's binary BVH reached 0.2-0.3x
Embree per thread on incoherent rays, and a kernel-language traversal cannot keep a stack or a
child mask in registers. Measured alternatives are in docs/ray_core.md.

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

import warp as wp

from .bvh_build import CHILD_OFFSET, COUNT_OFFSET, LEAF_COUNT_BITS, NODE_FLOATS, PACKET

wp.set_module_options({"enable_backward": False})

FAR_SCALE = "1.0000004f"
"""The slab test's far distance is scaled by 1 + 2 gamma(3) (gamma(n) = n eps / (1 - n eps), eps = 2^-24; Ize
2013, section 3): with distances taken as (bound - origin) / direction, rounding never culls a box the ray
touches, however far from the world origin the scene lies."""

STACK_SIZE = 256
"""Traversal stack entries: 7 pushes per level of a tree 36 levels deep."""


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


_MACROS = r"""
#ifndef USDBAKE_CTZ
#ifdef __CUDA_ARCH__
#define USDBAKE_CTZ(x) (__ffs(x) - 1)
#define USDBAKE_POPCOUNT(x) __popc(x)
#define USDBAKE_FLOAT_BITS(x) __float_as_int(x)
#define USDBAKE_BITS_FLOAT(x) __int_as_float(x)
#else
#define USDBAKE_CTZ(x) __builtin_ctz(x)
#define USDBAKE_POPCOUNT(x) __builtin_popcount(x)
#define USDBAKE_FLOAT_BITS(x) __builtin_bit_cast(int, x)
#define USDBAKE_BITS_FLOAT(x) __builtin_bit_cast(float, x)
#endif
#endif
"""

_PRELUDE = _MACROS + r"""
const float* NODES = (const float*)scene.nodes;
const float* PACKETS = (const float*)scene.packets;
const int* LANES = (const int*)scene.packet_triangle;
const float* TO_OBJECT = (const float*)scene.instance_to_object;
const float* TO_WORLD = (const float*)scene.instance_to_world;
const int* ROOT = (const int*)scene.instance_root;
const int* FACE = (const int*)scene.instance_face;
const int* MIRRORED = (const int*)scene.instance_mirrored;
const int* TOP_INSTANCES = (const int*)scene.top_instances;
struct Ray {
  float o[3], d[3], inv[3], Sx, Sy, Sz; int kx, ky, kz, near_offset[3], far_offset[3];
  CUDA_CALLABLE void init(const float* org, const float* dir) {
    for (int k = 0; k < 3; ++k) {
      o[k] = org[k]; d[k] = dir[k];
      float x = dir[k];
      if (wp::abs(x) < 1e-30f) x = x < 0.0f ? -1e-30f : 1e-30f;
      inv[k] = 1.0f / x;
      near_offset[k] = inv[k] >= 0.0f ? 8 * k : 24 + 8 * k;  // lower bounds of axis k, or upper
      far_offset[k] = inv[k] >= 0.0f ? 24 + 8 * k : 8 * k;
    }
    kz = 0; if (wp::abs(d[1]) > wp::abs(d[kz])) kz = 1; if (wp::abs(d[2]) > wp::abs(d[kz])) kz = 2;
    kx = kz == 2 ? 0 : kz + 1; ky = kx == 2 ? 0 : kx + 1;
    if (d[kz] < 0.0f) { int s = kx; kx = ky; ky = s; }
    Sx = d[kx] / d[kz]; Sy = d[ky] / d[kz]; Sz = 1.0f / d[kz];
  }
  CUDA_CALLABLE void transformed(const Ray& r, const float* m) {
    float org[3], dir[3];
    for (int k = 0; k < 3; ++k) {
      org[k] = m[4 * k] * r.o[0] + m[4 * k + 1] * r.o[1] + m[4 * k + 2] * r.o[2] + m[4 * k + 3];
      dir[k] = m[4 * k] * r.d[0] + m[4 * k + 1] * r.d[1] + m[4 * k + 2] * r.d[2];
    }
    init(org, dir);
  }
};
struct Boxes {
  alignas(32) float tn[8]; unsigned mask;
  // Slab test of the node's 8 child boxes (Ize 2013), children beyond the node's count masked off.
  CUDA_CALLABLE void test(const float* n, const Ray& r, float tfar) {
#ifdef __CUDA_ARCH__
    float tf[8];
    for (int c = 0; c < 8; ++c) {
      float nx = (n[r.near_offset[0] + c] - r.o[0]) * r.inv[0], fx = (n[r.far_offset[0] + c] - r.o[0]) * r.inv[0];
      float ny = (n[r.near_offset[1] + c] - r.o[1]) * r.inv[1], fy = (n[r.far_offset[1] + c] - r.o[1]) * r.inv[1];
      float nz = (n[r.near_offset[2] + c] - r.o[2]) * r.inv[2], fz = (n[r.far_offset[2] + c] - r.o[2]) * r.inv[2];
      tn[c] = wp::max(wp::max(nx, ny), wp::max(nz, 0.0f));
      tf[c] = wp::min(wp::min(fx, fy), wp::min(fz, tfar)) * FAR_SCALE;
    }
    mask = 0;
    for (int c = 0; c < 8; ++c) mask |= (unsigned)(tn[c] <= tf[c]) << c;
#else
    // The same test on 8 lanes at once (clang vector extensions: AVX where the CPU has it). Nodes are
    // 256-byte records in a Warp array (64-byte aligned), so the 8-float loads are aligned.
    typedef float f8 __attribute__((ext_vector_type(8)));
    // The near and far planes of each axis are known from the direction's sign (Ray::near_offset).
    f8 nx = (*(const f8*)(n + r.near_offset[0]) - r.o[0]) * r.inv[0], fx = (*(const f8*)(n + r.far_offset[0]) - r.o[0]) * r.inv[0];
    f8 ny = (*(const f8*)(n + r.near_offset[1]) - r.o[1]) * r.inv[1], fy = (*(const f8*)(n + r.far_offset[1]) - r.o[1]) * r.inv[1];
    f8 nz = (*(const f8*)(n + r.near_offset[2]) - r.o[2]) * r.inv[2], fz = (*(const f8*)(n + r.far_offset[2]) - r.o[2]) * r.inv[2];
    f8 zero = 0.0f, far = tfar;
    f8 near_t = __builtin_elementwise_max(__builtin_elementwise_max(nx, ny), __builtin_elementwise_max(nz, zero));
    f8 far_t = __builtin_elementwise_min(__builtin_elementwise_min(fx, fy), __builtin_elementwise_min(fz, far)) * FAR_SCALE;
    typedef bool b8 __attribute__((ext_vector_type(8)));
    *(f8*)tn = near_t;
    mask = (unsigned)__builtin_bit_cast(unsigned char, __builtin_convertvector(near_t <= far_t, b8));
#endif
    mask &= (1u << ((const int*)n)[COUNT_OFFSET]) - 1u;
  }
};
struct Stack {
  int node[STACK_SIZE]; float t[STACK_SIZE]; int size;
  // Push the hit children but one and return that one, to visit them nearest first (near_first, for
  // closest hits: the far ones are culled once a hit is found) or farthest first (any hit from a surface:
  // the boxes around the origin hold its own surface, which it leaves; occluders lie farther out).
  CUDA_CALLABLE int push_children(const Boxes& b, const int* child, bool near_first) {
    unsigned mask = b.mask;
    int first = USDBAKE_CTZ(mask); mask &= mask - 1;
    if (mask == 0) return child[first];
    int second = USDBAKE_CTZ(mask); mask &= mask - 1;
    if (mask == 0) {
      if ((b.tn[second] < b.tn[first]) == near_first) { int s = first; first = second; second = s; }
      t[size] = b.tn[second]; node[size++] = child[second];
      return child[first];
    }
    // Three or more: rank each child by how many of the others are visited after it (ties by slot).
    int refs[8]; float ts[8];
    int count = USDBAKE_POPCOUNT(b.mask);
    mask = b.mask;
#ifndef __CUDA_ARCH__
    typedef float f8 __attribute__((ext_vector_type(8)));
    typedef int i8 __attribute__((ext_vector_type(8)));
    typedef bool b8 __attribute__((ext_vector_type(8)));
    f8 near = *(const f8*)b.tn;
    i8 slot = {0, 1, 2, 3, 4, 5, 6, 7};
#endif
    while (mask) {
      int c = USDBAKE_CTZ(mask); mask &= mask - 1;
#ifndef __CUDA_ARCH__
      unsigned later = (unsigned)__builtin_bit_cast(unsigned char, __builtin_convertvector(
          (near_first ? near > b.tn[c] : near < b.tn[c]) | ((near == b.tn[c]) & (slot < c)), b8));
#else
      unsigned later = 0;
      for (int d = 0; d < 8; ++d)
        later |= (unsigned)((near_first ? b.tn[d] > b.tn[c] : b.tn[d] < b.tn[c]) || (b.tn[d] == b.tn[c] && d < c)) << d;
#endif
      int rank = USDBAKE_POPCOUNT(later & b.mask);
      ts[rank] = b.tn[c]; refs[rank] = child[c];
    }
    for (int j = 0; j < count - 1; ++j) { t[size] = ts[j]; node[size++] = refs[j]; }
    return refs[count - 1];
  }
};
struct Packet {
  float t[4], U[4], V[4], W[4], det[4]; bool ok[4];
  // Watertight test (Woop et al. 2013) of the ray against the 4 triangles of packet p.
  CUDA_CALLABLE void test(const float* P, const Ray& r, float tfar) {
#ifdef __CUDA_ARCH__
    float ax[4], ay[4], bx[4], by[4], cx[4], cy[4], Ak[4], Bk[4], Ck[4];
    for (int l = 0; l < 4; ++l) {  // shear and scale the vertices into the ray's space (vectorizes)
      Ak[l] = P[4 * r.kz + l] - r.o[r.kz]; Bk[l] = P[12 + 4 * r.kz + l] - r.o[r.kz]; Ck[l] = P[24 + 4 * r.kz + l] - r.o[r.kz];
      ax[l] = P[4 * r.kx + l] - r.o[r.kx] - r.Sx * Ak[l]; ay[l] = P[4 * r.ky + l] - r.o[r.ky] - r.Sy * Ak[l];
      bx[l] = P[12 + 4 * r.kx + l] - r.o[r.kx] - r.Sx * Bk[l]; by[l] = P[12 + 4 * r.ky + l] - r.o[r.ky] - r.Sy * Bk[l];
      cx[l] = P[24 + 4 * r.kx + l] - r.o[r.kx] - r.Sx * Ck[l]; cy[l] = P[24 + 4 * r.ky + l] - r.o[r.ky] - r.Sy * Ck[l];
      U[l] = cx[l] * by[l] - cy[l] * bx[l]; V[l] = ax[l] * cy[l] - ay[l] * cx[l]; W[l] = bx[l] * ay[l] - by[l] * ax[l];
    }
    for (int l = 0; l < 4; ++l) {
      if (U[l] == 0.0f || V[l] == 0.0f || W[l] == 0.0f) {  // on an edge in float: decide in double
        U[l] = (float)((double)cx[l] * by[l] - (double)cy[l] * bx[l]);
        V[l] = (float)((double)ax[l] * cy[l] - (double)ay[l] * cx[l]);
        W[l] = (float)((double)bx[l] * ay[l] - (double)by[l] * ax[l]);
      }
    }
    for (int l = 0; l < 4; ++l) {
      det[l] = U[l] + V[l] + W[l];
      t[l] = r.Sz * (U[l] * Ak[l] + V[l] * Bk[l] + W[l] * Ck[l]) / det[l];
      ok[l] = ((U[l] >= 0.0f && V[l] >= 0.0f && W[l] >= 0.0f) || (U[l] <= 0.0f && V[l] <= 0.0f && W[l] <= 0.0f))
              && det[l] != 0.0f && t[l] >= 0.0f && t[l] < tfar;
    }
#else
    // The same on 4 lanes at once (clang vector extensions).
    typedef float f4 __attribute__((ext_vector_type(4)));
    typedef int i4 __attribute__((ext_vector_type(4)));
    f4 Ak = *(const f4*)(P + 4 * r.kz) - r.o[r.kz], Bk = *(const f4*)(P + 12 + 4 * r.kz) - r.o[r.kz];
    f4 Ck = *(const f4*)(P + 24 + 4 * r.kz) - r.o[r.kz];
    f4 ax = *(const f4*)(P + 4 * r.kx) - r.o[r.kx] - r.Sx * Ak, ay = *(const f4*)(P + 4 * r.ky) - r.o[r.ky] - r.Sy * Ak;
    f4 bx = *(const f4*)(P + 12 + 4 * r.kx) - r.o[r.kx] - r.Sx * Bk, by = *(const f4*)(P + 12 + 4 * r.ky) - r.o[r.ky] - r.Sy * Bk;
    f4 cx = *(const f4*)(P + 24 + 4 * r.kx) - r.o[r.kx] - r.Sx * Ck, cy = *(const f4*)(P + 24 + 4 * r.ky) - r.o[r.ky] - r.Sy * Ck;
    f4 u = cx * by - cy * bx, v = ax * cy - ay * cx, w = bx * ay - by * ax;
    i4 zero = (u == 0.0f) | (v == 0.0f) | (w == 0.0f);
    if (zero[0] | zero[1] | zero[2] | zero[3]) {
      for (int l = 0; l < 4; ++l) {
        if (zero[l]) {  // on an edge in float: decide in double
          u[l] = (float)((double)cx[l] * by[l] - (double)cy[l] * bx[l]);
          v[l] = (float)((double)ax[l] * cy[l] - (double)ay[l] * cx[l]);
          w[l] = (float)((double)bx[l] * ay[l] - (double)by[l] * ax[l]);
        }
      }
    }
    f4 d = u + v + w;
    f4 tt = r.Sz * (u * Ak + v * Bk + w * Ck) / d;
    i4 good = (((u >= 0.0f) & (v >= 0.0f) & (w >= 0.0f)) | ((u <= 0.0f) & (v <= 0.0f) & (w <= 0.0f)))
              & (d != 0.0f) & (tt >= 0.0f) & (tt < tfar);
    for (int l = 0; l < 4; ++l) { t[l] = tt[l]; U[l] = u[l]; V[l] = v[l]; W[l] = w[l]; det[l] = d[l]; ok[l] = good[l] != 0; }
#endif
  }
};
"""
_PRELUDE = (_PRELUDE.replace("STACK_SIZE", str(STACK_SIZE)).replace("COUNT_OFFSET", str(COUNT_OFFSET))
            .replace("FAR_SCALE", FAR_SCALE))
assert NODE_FLOATS == 64 and CHILD_OFFSET == 48 and PACKET == 4 and LEAF_COUNT_BITS == 3  # as the C++ reads them

_TRACE = _PRELUDE + r"""
struct Best { float t; int lane, instance; float u, v, det; };
struct Bottom {
  // Walk one bottom-level tree with ray r (already in its space); closest hit into `best`, or with
  // any = true stop at the first hit and return true.
  CUDA_CALLABLE static bool walk(const float* NODES, const float* PACKETS, const Ray& r, int root, int instance,
                                 bool any, Best& best) {
    Stack stack; stack.size = 0;
    int node = root;
    float tfar = best.t;  // a local: stores to the stack cannot alias it, so it stays in a register
    while (true) {
      if (node >= 0) {
        const float* n = NODES + 64 * node;
        Boxes b; b.test(n, r, tfar);
        if (b.mask) { node = stack.push_children(b, (const int*)n + 48, !any); continue; }
      } else {
        int code = -1 - node; int first = code >> 3, count = code & 7;
        for (int p = first; p < first + count; ++p) {
          Packet k; k.test(PACKETS + 36 * p, r, tfar);
          for (int l = 0; l < 4; ++l) {
            if (k.ok[l] && k.t[l] < tfar) {
              if (any) return true;
              tfar = k.t[l]; best.t = tfar; best.lane = 4 * p + l; best.instance = instance;
              best.u = k.U[l]; best.v = k.V[l]; best.det = k.det[l];
            }
          }
        }
      }
      bool found = false;
      while (stack.size > 0) { --stack.size; if (stack.t[stack.size] <= tfar) { node = stack.node[stack.size]; found = true; break; } }
      if (!found) return false;
    }
  }
};
// Closest (ANY = false) or any (ANY = true) hit along org + t dir, 0 <= t < tmax: the whole scene, or
// only instance `only` when only >= 0.
const float scaled_org[3] = {org[0] * scene.scale, org[1] * scene.scale, org[2] * scene.scale};
Ray world; world.init(scaled_org, &dir[0]);
Best best; best.t = tmax * scene.scale; best.lane = -1; best.instance = 0; best.u = best.v = best.det = 0.0f;
bool hit = false;
if (scene.top_root < 0 && only <= 0) {
  hit = Bottom::walk(NODES, PACKETS, world, ROOT[0], 0, ANY, best);
} else if (only >= 0) {
  Ray ray; ray.transformed(world, TO_OBJECT + 12 * only);
  hit = Bottom::walk(NODES, PACKETS, ray, ROOT[only], only, ANY, best);
} else {
  Stack top; top.size = 0;
  int node = scene.top_root;
  while (!hit) {
    if (node >= 0) {
      const float* n = NODES + 64 * node;
      Boxes b; b.test(n, world, best.t);
      if (b.mask) { node = top.push_children(b, (const int*)n + 48, !ANY); continue; }
    } else {
      int code = -1 - node;
      for (int item = code >> 3; item < (code >> 3) + (code & 7) && !hit; ++item) {
        int instance = TOP_INSTANCES[item];
        Ray ray; ray.transformed(world, TO_OBJECT + 12 * instance);
        hit = Bottom::walk(NODES, PACKETS, ray, ROOT[instance], instance, ANY, best);
      }
    }
    bool found = false;
    while (top.size > 0) { --top.size; if (top.t[top.size] <= best.t) { node = top.node[top.size]; found = true; break; } }
    if (!found) break;
  }
}
if (ANY) return wp::vec4(0.0f, 0.0f, 0.0f, hit ? 1.0f : 0.0f);
if (best.lane < 0) return wp::vec4(-1.0f, 0.0f, 0.0f, 0.0f);
float u = best.u / best.det, v = best.v / best.det;
bool mirrored = MIRRORED[best.instance] != 0;
if (mirrored) u = 1.0f - u - v;
int face = FACE[best.instance] + LANES[best.lane];
bool front = best.det > 0.0f;  // a mirrored instance's re-wound triangles flip the test's sign back
return wp::vec4(best.t / scene.scale, u, v, USDBAKE_BITS_FLOAT(face * 2 + (front ? 1 : 0)));
"""


@wp.func_native(_TRACE.replace("ANY", "false"))
def _closest(scene: TraceScene, only: int, org: wp.vec3, dir: wp.vec3, tmax: float) -> wp.vec4:
    ...


@wp.func_native(_TRACE.replace("ANY", "true"))
def _any(scene: TraceScene, only: int, org: wp.vec3, dir: wp.vec3, tmax: float) -> wp.vec4:
    ...


@wp.func_native(_MACROS + "return USDBAKE_FLOAT_BITS(x);")
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


_SURFACE_ORIGIN = _MACROS + r"""
// surface_origin (see the Warp-side docstring): q = p + eps inward, o = q + eps n, then o is moved to
// at least eps in front of every face through q (within eps / 2) whose normal is not opposite n.
const float* NODES = (const float*)scene.nodes;
const float* PACKETS = (const float*)scene.packets;
const int* LANES = (const int*)scene.packet_triangle;
const float* TO_OBJECT = (const float*)scene.instance_to_object;
const float* TO_WORLD = (const float*)scene.instance_to_world;
const int* ROOT = (const int*)scene.instance_root;
const int* FACE = (const int*)scene.instance_face;
const int* MIRRORED = (const int*)scene.instance_mirrored;
const int* TOP_INSTANCES = (const int*)scene.top_instances;
// In the arrays' scaled space (TraceScene.scale) throughout; the origin is scaled back on return.
const float epsilon = epsilon_units * scene.scale;
float q[3], o[3], nn[3];
for (int k = 0; k < 3; ++k) {
  const float pk = p[k] * scene.scale;  // its own statement: q's expression contracts as it did unscaled
  nn[k] = n[k]; q[k] = pk + inward[k] * epsilon; o[k] = q[k] + nn[k] * epsilon;
}
struct Overlap {
  // Push the children of node nd whose boxes overlap the box centre +- half.
  CUDA_CALLABLE static void push(const float* nd, const float* centre, const float* half, int* stack, int& size) {
    int count = ((const int*)nd)[COUNT_OFFSET];
    for (int c = 0; c < count; ++c) {
      bool overlap = true;
      for (int k = 0; k < 3; ++k)
        overlap = overlap && nd[8 * k + c] <= centre[k] + half[k] && nd[24 + 8 * k + c] >= centre[k] - half[k];
      if (overlap && size < STACK_SIZE) stack[size++] = ((const int*)nd)[48 + c];
    }
  }
};
const float reach = 2.0f * epsilon, tolerance = 0.5f * epsilon;
const bool two_level = scene.top_root >= 0;
for (int sweep = 0; sweep < 2; ++sweep) {  // a second sweep, after a move, settles faces that are not perpendicular
  bool moved = false;
  int top_stack[STACK_SIZE]; int top_size = 0;
  if (two_level) top_stack[top_size++] = scene.top_root; else top_stack[top_size++] = -1 - 1;  // leaf: instance 0, 1 item
  const float world_half[3] = {reach, reach, reach};
  while (top_size > 0) {
    int top_node = top_stack[--top_size];
    if (top_node >= 0) {
      Overlap::push(NODES + 64 * top_node, q, world_half, top_stack, top_size);
      continue;
    }
    int code = -1 - top_node;
    for (int item = code >> 3; item < (code >> 3) + (code & 7); ++item) {
      int instance = two_level ? TOP_INSTANCES[item] : 0;
      const float* M = TO_OBJECT + 12 * instance;
      const float* Wm = TO_WORLD + 12 * instance;
      bool mirrored = MIRRORED[instance] != 0;
      float center[3], half[3];  // the query box in the instance's space
      for (int k = 0; k < 3; ++k) {
        center[k] = two_level ? M[4 * k] * q[0] + M[4 * k + 1] * q[1] + M[4 * k + 2] * q[2] + M[4 * k + 3] : q[k];
        half[k] = two_level ? reach * (wp::abs(M[4 * k]) + wp::abs(M[4 * k + 1]) + wp::abs(M[4 * k + 2])) : reach;
      }
      int stack[STACK_SIZE]; int size = 0;
      stack[size++] = ROOT[instance];
      while (size > 0) {
        int node = stack[--size];
        if (node >= 0) {
          Overlap::push(NODES + 64 * node, center, half, stack, size);
          continue;
        }
        int leaf = -1 - node;
        for (int pk = leaf >> 3; pk < (leaf >> 3) + (leaf & 7); ++pk) {
          const float* P = PACKETS + 36 * pk;
          for (int l = 0; l < 4; ++l) {
            if (LANES[4 * pk + l] < 0) continue;
            bool apart = false;  // the lane's box misses the query box (instance space): most lanes stop here
            for (int k = 0; k < 3; ++k) {
              float lo = wp::min(P[4 * k + l], wp::min(P[12 + 4 * k + l], P[24 + 4 * k + l]));
              float hi = wp::max(P[4 * k + l], wp::max(P[12 + 4 * k + l], P[24 + 4 * k + l]));
              apart = apart || lo > center[k] + half[k] || hi < center[k] - half[k];
            }
            if (apart) continue;
            wp::vec3 corner[3];
            for (int v = 0; v < 3; ++v) {
              wp::vec3 x(P[12 * v + l], P[12 * v + 4 + l], P[12 * v + 8 + l]);
              if (two_level)
                x = wp::vec3(Wm[0] * x[0] + Wm[1] * x[1] + Wm[2] * x[2] + Wm[3],
                             Wm[4] * x[0] + Wm[5] * x[1] + Wm[6] * x[2] + Wm[7],
                             Wm[8] * x[0] + Wm[9] * x[1] + Wm[10] * x[2] + Wm[11]);
              corner[v] = x;
            }
            if (mirrored) { wp::vec3 s = corner[1]; corner[1] = corner[2]; corner[2] = s; }  // the scene's winding
            wp::vec3 a = corner[0], b = corner[1], c = corner[2];
            wp::vec3 normal = wp::cross(b - a, c - a);
            float area = wp::length(normal);
            if (!(area > 0.0f)) continue;
            normal = normal / area;
            wp::vec3 qv(q[0], q[1], q[2]), nv(nn[0], nn[1], nn[2]);
            if (wp::dot(normal, nv) <= -0.5f) continue;
            // through_point: the face passes within tolerance of q (near its plane, inside its edges).
            if (wp::abs(wp::dot(qv - a, normal)) > tolerance) continue;
            bool inside = true;
            for (int e = 0; e < 3; ++e) {
              wp::vec3 start = e == 0 ? a : (e == 1 ? b : c);
              wp::vec3 edge = (e == 0 ? b : (e == 1 ? c : a)) - start;
              float length = wp::length(edge);
              if (length > 0.0f && wp::dot(wp::cross(edge, qv - start), normal) < -tolerance * length) inside = false;
            }
            if (!inside) continue;
            float height = (o[0] - q[0]) * normal[0] + (o[1] - q[1]) * normal[1] + (o[2] - q[2]) * normal[2];
            if (height < epsilon) {
              for (int k = 0; k < 3; ++k) o[k] += normal[k] * (epsilon - height);
              moved = true;
            }
          }
        }
      }
    }
  }
  if (!moved) break;
}
return wp::vec3(o[0] / scene.scale, o[1] / scene.scale, o[2] / scene.scale);
""".replace("STACK_SIZE", str(STACK_SIZE)).replace("COUNT_OFFSET", str(COUNT_OFFSET))


@wp.func_native(_SURFACE_ORIGIN)
def surface_origin(scene: TraceScene, p: wp.vec3, n: wp.vec3, inward: wp.vec3, epsilon_units: float) -> wp.vec3:
    """Ray origin for point p on a surface with unit normal n. ``inward`` is a unit tangent pointing into
    the point's own surface (zero inside a face or a smooth region): at an unwelded crease it takes the
    origin off the crease line, to the side where its own face lies. The origin is q + epsilon n,
    q = p + epsilon inward, then moved to at least epsilon in front of every other face through q whose
    normal is not opposite n (the face a T-junction vertex rests on, a wall the point touches; their
    winding side, the outside of a solid). A ray from it meets no face through p at t <= 0. Stage units
    (``epsilon_units``, the tracer's ``epsilon``), whatever ``TraceScene.scale``."""
    ...
