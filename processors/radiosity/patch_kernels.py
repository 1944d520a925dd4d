"""Warp functions shared by form_factors and radiosity: patch fragments and their lookup from ray hits.

A triangle split into m x m congruent fragments (sub-triangles) is addressed in
barycentric grid coordinates (a, b) = (u m, v m) of the point u v0 + v v1 +
(1 - u - v) v2 (the ray core's convention, as wp.mesh_query_ray's): lower cells (i, j) with
i + j <= m - 1 are numbered row by row (j), then the upper cells (i, j) with
i + j <= m - 2 in the same order (geometry/patches.fragment_template builds the same
order in numpy).

The fragments are the pieces of the voxel clustering of Shcherbakov (MSU 2017),
section 5, precompute step 1 (processors/radiosity/patches.py): a ray hit is credited to
the patch of the fragment it lands in.
"""

import warp as wp

wp.set_module_options({"enable_backward": False, "fuse_fp": False})


@wp.func
def fragment_of_hit(face: int, u: float, v: float, tri_subdivision: wp.array(dtype=int),
                    tri_fragment_start: wp.array(dtype=int)) -> int:
    """Global fragment id of barycentrics (u, v) on triangle ``face`` (the inverse of fragment_template's order).

    Maps a ray hit to the fragment, so the voxel-clustered patch, of Shcherbakov
    (MSU 2017), section 5, precompute step 1. ``u``, ``v`` : trace_closest hit
    barycentrics (dimensionless, clamped to [0, 1]).
    """
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

