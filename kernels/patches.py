"""Warp functions shared by form_factors and radiosity: patch fragments and their lookup from ray hits.

A triangle split into m x m congruent fragments (sub-triangles) is addressed in
barycentric grid coordinates (a, b) = (u m, v m) of the point u v0 + v v1 +
(1 - u - v) v2 (Warp's mesh_query_ray convention): lower cells (i, j) with
i + j <= m - 1 are numbered row by row (j), then the upper cells (i, j) with
i + j <= m - 2 in the same order (form_factors.fragment_template builds the same
order in numpy).
"""

import warp as wp

wp.set_module_options({"enable_backward": False})


@wp.func
def fragment_of_hit(face: int, u: float, v: float, tri_subdivision: wp.array(dtype=int),
                    tri_fragment_start: wp.array(dtype=int)) -> int:
    """Fragment id of barycentrics (u, v) on triangle ``face``."""
    m = tri_subdivision[face]
    a = wp.clamp(u, 0.0, 1.0) * float(m)
    b = wp.clamp(v, 0.0, 1.0) * float(m)
    i = wp.clamp(int(wp.floor(a)), 0, m - 1)
    j = wp.clamp(int(wp.floor(b)), 0, m - 1)
    if i + j > m - 1:
        i = m - 1 - j
    upper = (a - float(i)) + (b - float(j)) > 1.0 and i + j <= m - 2
    local = int(0)
    if upper:
        local = m * (m + 1) // 2 + j * (m - 1) - j * (j - 1) // 2 + i
    else:
        local = j * m - j * (j - 1) // 2 + i
    return tri_fragment_start[face] + local


@wp.func
def point_in_triangle(a: wp.vec3, b: wp.vec3, c: wp.vec3, r1: float, r2: float) -> wp.vec3:
    """Uniform point on triangle abc from two uniform numbers (square-root warp)."""
    s = wp.sqrt(r1)
    return a * (1.0 - s) + b * (s * (1.0 - r2)) + c * (s * r2)
