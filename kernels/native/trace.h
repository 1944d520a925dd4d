// Body of kernels/traversal.py's _closest (ANY_HIT false) and _any (ANY_HIT true), after ray_core.h:
// the closest or any hit along org + t dir, 0 <= t < tmax, through the whole scene, or only instance
// `only` when only >= 0. Returns (t, u, v, bits of 2 face + front) or (-1, 0, 0, 0) for a miss; any
// hit: w = 1 for a hit, 0 for none.
const float scaled_org[3] = {org[0] * scene.scale, org[1] * scene.scale, org[2] * scene.scale};
Ray world; world.init(scaled_org, &dir[0]);
struct Hit { int lane, instance; float u, v, det; };
Hit best = {-1, 0, 0.0f, 0.0f, 0.0f};
float extent = tmax * scene.scale;  // the ray's, in the arrays' space: shortened to each closer hit
// The triangles of one instance, the ray moved into its space in a two-level scene: the closest hit into
// `best`, shortening tfar (false returned), or true at the first hit for ANY_HIT.
auto trace_instance = [&](int instance, float& tfar) -> bool {
  Ray moved;
  if (scene.top_root >= 0) moved.transformed(world, TO_OBJECT + 12 * instance);
  const Ray& r = scene.top_root >= 0 ? moved : world;
  auto boxes = [&](Boxes& b, const float* n, float t) { b.hit_by(n, r, t); };
  return walk(ROOT[instance], tfar, !ANY_HIT, boxes, [&](int first, int end, float& t) -> bool {
    for (int p = first; p < end; ++p) {
      Packet k; k.test(PACKETS + PACKET_FLOATS * p, r, t);
      for (int l = 0; l < 4; ++l) {
        if (k.ok[l] && k.t[l] < t) {
          if (ANY_HIT) return true;
          t = k.t[l]; best = {4 * p + l, instance, k.U[l], k.V[l], k.det[l]};
        }
      }
    }
    return false;
  });
};
auto world_boxes = [&](Boxes& b, const float* n, float t) { b.hit_by(n, world, t); };
const bool hit = only >= 0 ? trace_instance(only, extent) : instances(extent, !ANY_HIT, world_boxes, trace_instance);
if (ANY_HIT) return wp::vec4(0.0f, 0.0f, 0.0f, hit ? 1.0f : 0.0f);
if (best.lane < 0) return wp::vec4(-1.0f, 0.0f, 0.0f, 0.0f);
float u = best.u / best.det, v = best.v / best.det;
bool mirrored = MIRRORED[best.instance] != 0;
if (mirrored) u = 1.0f - u - v;
int face = FACE[best.instance] + LANES[best.lane];
bool front = best.det > 0.0f;  // a mirrored instance's re-wound triangles flip the test's sign back
return wp::vec4(extent / scene.scale, u, v, USDBAKE_BITS_FLOAT(face * 2 + (front ? 1 : 0)));
