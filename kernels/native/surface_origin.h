// Body of kernels/traversal.py's surface_origin (see its docstring), after ray_core.h: q = p + eps inward,
// o = q + eps n, then o is moved to at least eps in front of every face through q (within eps / 2) whose
// normal is not opposite n. In the arrays' scaled space (TraceScene.scale) throughout; the origin is
// scaled back on return.
const float epsilon = epsilon_units * scene.scale;
float q[3], o[3], nn[3];
for (int k = 0; k < 3; ++k) {
  const float pk = p[k] * scene.scale;  // its own statement: q's expression contracts as it did unscaled
  nn[k] = n[k]; q[k] = pk + inward[k] * epsilon; o[k] = q[k] + nn[k] * epsilon;
}
const float reach = 2.0f * epsilon, tolerance = 0.5f * epsilon;
const wp::vec3 qv(q[0], q[1], q[2]), nv(nn[0], nn[1], nn[2]);
// Whether triangle abc (world space, the scene's winding) passes within tolerance of q (near its plane,
// inside its edges) with a normal not opposite n; its unit normal to ``normal``. This depends on q only, not
// on o, so the faces it accepts are the same in every sweep.
auto touches = [&](wp::vec3 a, wp::vec3 b, wp::vec3 c, wp::vec3& normal) -> bool {
  normal = wp::cross(b - a, c - a);
  float area = wp::length(normal);
  if (!(area > 0.0f)) return false;
  normal = normal / area;
  if (wp::dot(normal, nv) <= -0.5f) return false;
  if (wp::abs(wp::dot(qv - a, normal)) > tolerance) return false;
  for (int e = 0; e < 3; ++e) {
    wp::vec3 start = e == 0 ? a : (e == 1 ? b : c);
    wp::vec3 edge = (e == 0 ? b : (e == 1 ? c : a)) - start;
    float length = wp::length(edge);
    if (length > 0.0f && wp::dot(wp::cross(edge, qv - start), normal) < -tolerance * length) return false;
  }
  return true;
};
// Move o to at least epsilon in front of a touching face's plane (unit normal).
auto lift = [&](const wp::vec3& normal) -> bool {
  float height = (o[0] - q[0]) * normal[0] + (o[1] - q[1]) * normal[1] + (o[2] - q[2]) * normal[2];
  if (height >= epsilon) return false;
  for (int k = 0; k < 3; ++k) o[k] += normal[k] * (epsilon - height);
  return true;
};
// The touching faces' normals in the order the first sweep met them: a second sweep lifts o over them
// again without a second query (the query is most of the cost; a vertex has a handful of faces).
constexpr int KEPT = 32;
wp::vec3 kept[KEPT];
int touching = 0;
const float world_half[3] = {reach, reach, reach};
const bool two_level = scene.top_root >= 0;
float no_limit = 0.0f;  // a box query's tfar: every child it enters is entered at distance 0
auto world_overlap = [&](Boxes& b, const float* node, float) { b.overlapping(node, q, world_half); };
for (int sweep = 0; sweep < 2; ++sweep) {  // a second sweep, after a move, settles faces that are not perpendicular
  bool moved = false;
  if (sweep == 1 && touching <= KEPT) {  // the faces of the first sweep, in its order: the same moves as a query
    for (int f = 0; f < touching; ++f) lift(kept[f]);
    break;
  }
  // Every triangle whose box overlaps the query box, instance by instance in the instance's space.
  instances(no_limit, false, world_overlap, [&](int instance, float& tfar) -> bool {
    const float* M = TO_OBJECT + 12 * instance;
    const float* Wm = TO_WORLD + 12 * instance;
    bool mirrored = MIRRORED[instance] != 0;
    float center[3], half[3];  // the query box in the instance's space
    for (int k = 0; k < 3; ++k) {
      center[k] = two_level ? M[4 * k] * q[0] + M[4 * k + 1] * q[1] + M[4 * k + 2] * q[2] + M[4 * k + 3] : q[k];
      half[k] = two_level ? reach * (wp::abs(M[4 * k]) + wp::abs(M[4 * k + 1]) + wp::abs(M[4 * k + 2])) : reach;
    }
    auto overlap = [&](Boxes& b, const float* node, float) { b.overlapping(node, center, half); };
    return walk(ROOT[instance], tfar, false, overlap, [&](int first, int end, float&) -> bool {
      for (int pk = first; pk < end; ++pk) {
        const float* P = PACKETS + PACKET_FLOATS * pk;
        // Lanes whose triangle's box misses the query box (most of them), the four at once: axis by axis over
        // the lanes, without short cuts, so the compiler can test them as one vector.
        bool apart[4];
        for (int l = 0; l < 4; ++l) apart[l] = LANES[4 * pk + l] < 0;
        for (int k = 0; k < 3; ++k) {
          const float below = center[k] - half[k], above = center[k] + half[k];
          for (int l = 0; l < 4; ++l) {
            float lo = wp::min(P[4 * k + l], wp::min(P[12 + 4 * k + l], P[24 + 4 * k + l]));
            float hi = wp::max(P[4 * k + l], wp::max(P[12 + 4 * k + l], P[24 + 4 * k + l]));
            apart[l] = apart[l] | (lo > above) | (hi < below);
          }
        }
        for (int l = 0; l < 4; ++l) {
          if (apart[l]) continue;
          wp::vec3 corner[3];
          for (int v = 0; v < 3; ++v) {
            wp::vec3 x(P[12 * v + l], P[12 * v + 4 + l], P[12 * v + 8 + l]);
            if (two_level)
              x = wp::vec3(Wm[0] * x[0] + Wm[1] * x[1] + Wm[2] * x[2] + Wm[3],
                           Wm[4] * x[0] + Wm[5] * x[1] + Wm[6] * x[2] + Wm[7],
                           Wm[8] * x[0] + Wm[9] * x[1] + Wm[10] * x[2] + Wm[11]);
            corner[v] = x;
          }
          // A mirrored instance's triangles are re-wound to the scene's winding.
          wp::vec3 normal;
          if (!touches(corner[0], corner[mirrored ? 2 : 1], corner[mirrored ? 1 : 2], normal)) continue;
          if (sweep == 0) {
            if (touching < KEPT) kept[touching] = normal;
            ++touching;
          }
          if (lift(normal)) moved = true;
        }
      }
      return false;  // box queries visit every leaf they reach
    });
  });
  if (!moved) break;
}
return wp::vec3(o[0] / scene.scale, o[1] / scene.scale, o[2] / scene.scale);
