// The ray core's shared native code (docs/ray_core.md): the scene's arrays, rays, the node and packet
// tests, and `walk`, the one depth-first walk of a tree that every query goes through.
//
// wp.func_native pastes a snippet into the body of the function it defines, so this is function-body
// code: it reads the function's `scene` argument, and it is written with local structs (no templates:
// C++ forbids them in a function) and generic lambdas (`walk` takes the node and leaf tests as
// arguments). kernels/traversal.py writes bvh_build's layout constants (NODE_FLOATS, CHILD_OFFSET,
// COUNT_OFFSET, LEAF_COUNT_BITS, PACKET_FLOATS) and bits.h before it. One source for the CPU (clang,
// vector extensions) and CUDA (NVRTC, the scalar branches under __CUDA_ARCH__).

constexpr int STACK_SIZE = 256;  // traversal stack entries: 7 pushes per level of a tree 36 levels deep
// The slab test's far distance is scaled by 1 + 2 gamma(3) (gamma(n) = n eps / (1 - n eps), eps = 2^-24;
// Ize 2013, section 3): with distances taken as (bound - origin) / direction, rounding never culls a box
// the ray touches, however far from the world origin the scene lies.
constexpr float FAR_SCALE = 1.0000004f;

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
// A node's children to enter (mask) and where each is entered (tn), from one of the two node tests.
struct Boxes {
  alignas(32) float tn[8]; unsigned mask;
  // Slab test of the node's 8 child boxes (Ize 2013), children beyond the node's count masked off.
  CUDA_CALLABLE void hit_by(const float* n, const Ray& r, float tfar) {
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
  // The children whose boxes overlap the box centre +- half, each entered at distance 0 (a box query).
  CUDA_CALLABLE void overlapping(const float* n, const float* centre, const float* half) {
    float lo[3], hi[3];
    for (int k = 0; k < 3; ++k) { lo[k] = centre[k] - half[k]; hi[k] = centre[k] + half[k]; }
#ifdef __CUDA_ARCH__
    mask = 0;
    for (int c = 0; c < 8; ++c) {
      bool overlap = true;
      for (int k = 0; k < 3; ++k) overlap = overlap && n[8 * k + c] <= hi[k] && n[24 + 8 * k + c] >= lo[k];
      mask |= (unsigned)overlap << c;
      tn[c] = 0.0f;
    }
#else
    // The same on 8 lanes at once, axis by axis: lower bound <= hi, upper bound >= lo.
    typedef float f8 __attribute__((ext_vector_type(8)));
    typedef bool b8 __attribute__((ext_vector_type(8)));
    typedef int i8 __attribute__((ext_vector_type(8)));
    i8 in = (*(const f8*)n <= hi[0]) & (*(const f8*)(n + 24) >= lo[0]) & (*(const f8*)(n + 8) <= hi[1])
            & (*(const f8*)(n + 32) >= lo[1]) & (*(const f8*)(n + 16) <= hi[2]) & (*(const f8*)(n + 40) >= lo[2]);
    mask = (unsigned)__builtin_bit_cast(unsigned char, __builtin_convertvector(in, b8));
    *(f8*)tn = 0.0f;
#endif
    mask &= (1u << ((const int*)n)[COUNT_OFFSET]) - 1u;
  }
};
struct Stack {
  int node[STACK_SIZE]; float t[STACK_SIZE]; int size;
  // Push the hit children but one and return that one, to visit them nearest first (near_first, for
  // closest hits: the far ones are culled once a hit is found) or farthest first (any hit from a surface:
  // the boxes around the origin hold its own surface, which it leaves; occluders lie farther out).
  // Children entered at equal distances are visited in slot order, or (farthest first) its reverse.
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
  // The last pushed node entered within tfar into `next`; false when none is left.
  CUDA_CALLABLE bool pop(float tfar, int& next) {
    while (size > 0) { --size; if (t[size] <= tfar) { next = node[size]; return true; } }
    return false;
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

// The one walk of a tree, depth first from node `root`. test(boxes, node, tfar) gives the node's
// children to enter and their entry distances (Boxes::hit_by for a ray, Boxes::overlapping for a box
// query); they are entered nearest first (near_first) or farthest first, those entered beyond tfar
// skipped. leaf(first, end, tfar) tests the items first .. end - 1 of a leaf (packets, or instances in
// a top-level tree), may shorten tfar, and returns true to stop the walk: walk then returns true.
auto walk = [&](int root, float& tfar, bool near_first, auto&& test, auto&& leaf) -> bool {
  Stack stack; stack.size = 0;
  float t = tfar;  // a local: stores to the stack cannot alias it, so it stays in a register
  bool stopped = false;
  int node = root;
  while (true) {
    if (node >= 0) {
      const float* n = NODES + NODE_FLOATS * node;
      Boxes b; test(b, n, t);
      // Entered only while the stack has room for 7 children: a tree too deep for it loses its deepest nodes
      // rather than overflow it (bvh_build's trees need far less: 58 entries for a million triangles).
      if (b.mask && stack.size <= STACK_SIZE - 7) {
        node = stack.push_children(b, (const int*)n + CHILD_OFFSET, near_first);
        continue;
      }
    } else {
      int code = -1 - node, first = code >> LEAF_COUNT_BITS;
      if (leaf(first, first + (code & ((1 << LEAF_COUNT_BITS) - 1)), t)) { stopped = true; break; }
    }
    if (!stack.pop(t, node)) break;
  }
  tfar = t;
  return stopped;
};
// The instances whose top-level boxes `test` selects (as in walk), each handed to visit(instance, tfar)
// until one returns true; a scene without a top level (scene.top_root < 0) is its one instance 0.
auto instances = [&](float& tfar, bool near_first, auto&& test, auto&& visit) -> bool {
  if (scene.top_root < 0) return visit(0, tfar);
  return walk(scene.top_root, tfar, near_first, test, [&](int first, int end, float& t) -> bool {
    for (int item = first; item < end; ++item)
      if (visit(TOP_INSTANCES[item], t)) return true;
    return false;
  });
};
