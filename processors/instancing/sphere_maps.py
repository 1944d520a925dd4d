"""Sphere and hemisphere layouts with constant-time inverses, as Warp functions (numpy twins in tests/).

Two maps back the displacement fields (Gaitatzes, Chrysanthou & Papaioannou,
"Presampled visibility for ambient occlusion", WSCG 2008):

**Positional samples: equal-area octahedral map** (Clarberg, "Fast equal-area
mapping of the (hemi)sphere using SIMD", JGT 13(3), 2008; the form used in
pbrt-v4). The unit square is folded onto an octahedron and each octant is
warped so that area is preserved *exactly*: an N x N grid of cells over the
square gives N^2 cells of exactly equal solid angle 4*pi/N^2 on the sphere.
The positional samples are the cell centres; the inverse map sends any point
of the sphere back to its cell in O(1) (one atan, one sqrt) -- the role
Slater's subdivision plays in the paper. Uniformity: equal area by
construction; the cells are not equal in shape (they shear along the
octahedron's edges), which ``cell_spacing_ratio_np`` measures: the largest
over the smallest nearest-neighbour distance between cell centres is 1.34
for N = 33, 65 and 129 (N^2 = 4225 is the paper's 4226): the spacing does
not degrade with resolution, unlike latitude-longitude grids whose ratio
grows like N.
The square's border is folded (``(1, v) ~ (1, -v)`` in [-1, 1]^2
coordinates), so grid neighbours across the border are found with
``octahedral_wrap``.

**Directions: concentric map + Malley** (Shirley & Chiu, "A low distortion
map between disk and square", JGT 2(3), 1997; Malley 1988): the square maps
to the disk with area preserved, the disk lifts to the +Z hemisphere, so
texel (a, b) of an M x M map holds an equal share of the cosine-weighted
hemisphere: the map the paper found best (its Figure 5). The inverse projects
a direction to the disk (drop z) and inverts the concentric map.

All [0,1]^2 coordinates are (u, v) with u along the grid's columns (x) and v
along its rows (y).
"""

from __future__ import annotations

import warp as wp

wp.set_module_options({"enable_backward": False, "fuse_fp": False})

# ---------------------------------------------------------------------------
# Warp functions


@wp.func
def equal_area_square_to_sphere(u: float, v: float) -> wp.vec3:
    """Clarberg's equal-area octahedral map, [0,1]^2 -> unit sphere (pbrt-v4 EqualAreaSquareToSphere).

    Clarberg, "Fast equal-area mapping of the (hemi)sphere using SIMD", JGT
    13(3), 2008: equal areas of the square go to equal solid angles, so an N x N
    grid gives cells of exactly 4 pi / N^2 sr. The positional samples of the
    displacement fields (Gaitatzes, Chrysanthou & Papaioannou 2008, Sec. 3.3,
    "Selecting Samples around the Object"; the paper uses Slater's subdivision).
    """
    a = 2.0 * u - 1.0
    b = 2.0 * v - 1.0
    ap = wp.abs(a)
    bp = wp.abs(b)
    signed_distance = 1.0 - (ap + bp)
    r = 1.0 - wp.abs(signed_distance)
    phi = wp.pi / 4.0
    if r > 0.0:
        phi = ((bp - ap) / r + 1.0) * wp.pi / 4.0
    z = wp.where(signed_distance >= 0.0, 1.0 - r * r, -(1.0 - r * r))
    cos_phi = wp.where(a >= 0.0, wp.cos(phi), -wp.cos(phi))
    sin_phi = wp.where(b >= 0.0, wp.sin(phi), -wp.sin(phi))
    s = r * wp.sqrt(wp.max(0.0, 2.0 - r * r))
    return wp.vec3(cos_phi * s, sin_phi * s, z)


@wp.func
def equal_area_sphere_to_square(d: wp.vec3) -> wp.vec2:
    """Inverse of equal_area_square_to_sphere: unit vector -> [0,1]^2 (O(1): one atan2, one sqrt).

    Clarberg 2008 (JGT 13(3)); the constant-time lookup of a positional sample
    that Slater's method provides in Gaitatzes et al. 2008, Sec. 3.3 (used by
    the lookup of Sec. 3.2, "Displacement Field Indexing").
    """
    x = wp.abs(d[0])
    y = wp.abs(d[1])
    z = wp.abs(d[2])
    r = wp.sqrt(wp.max(0.0, 1.0 - z))
    phi = float(0.0)
    if x > 0.0 or y > 0.0:
        phi = wp.atan2(y, x) * (2.0 / wp.pi)
    v = phi * r
    u = r - v
    if d[2] < 0.0:
        t = u
        u = 1.0 - v
        v = 1.0 - t
    u = wp.where(d[0] >= 0.0, u, -u)
    v = wp.where(d[1] >= 0.0, v, -v)
    return wp.vec2(0.5 * (u + 1.0), 0.5 * (v + 1.0))


@wp.func
def octahedral_wrap(i: int, j: int, n: int) -> wp.vec2i:
    """Cell (i, j) of an n x n octahedral grid, one step outside the grid folded back inside.

    The square's border is folded onto itself ((1, v) ~ (1, -v) in [-1,1]^2), so the cell
    beyond the right edge at row j is (n-1, n-1-j); the corners chain both folds.
    The fold is that of Clarberg's octahedral square (JGT 13(3), 2008); it finds
    the neighbouring positional samples of Gaitatzes et al. 2008, Sec. 3.2
    ("Displacement Field Indexing") across the border. Cell indices, no units.
    """
    ii = i
    jj = j
    if ii < 0:
        ii = 0
        jj = n - 1 - jj
    elif ii >= n:
        ii = n - 1
        jj = n - 1 - jj
    if jj < 0:
        jj = 0
        ii = n - 1 - ii
    elif jj >= n:
        jj = n - 1
        ii = n - 1 - ii
    return wp.vec2i(wp.clamp(ii, 0, n - 1), wp.clamp(jj, 0, n - 1))


@wp.func
def concentric_disk_to_square(x: float, y: float) -> wp.vec2:
    """Inverse Shirley-Chiu concentric map: unit disk -> [0,1]^2.

    Shirley & Chiu 1997, "A low distortion map between disk and square", JGT
    2(3) (the inverse of sampling.concentric_disk; dimensionless).
    """
    r = wp.sqrt(x * x + y * y)
    if r <= 0.0:
        return wp.vec2(0.5, 0.5)
    phi = wp.atan2(y, x)
    if phi < -wp.pi / 4.0:
        phi = phi + 2.0 * wp.pi
    a = float(0.0)
    b = float(0.0)
    quarter = wp.pi / 4.0
    if phi < quarter:
        a = r
        b = phi * a / quarter
    elif phi < 3.0 * quarter:
        b = r
        a = -(phi - wp.pi / 2.0) * b / quarter
    elif phi < 5.0 * quarter:
        a = -r
        b = (phi - wp.pi) * a / quarter
    else:
        b = -r
        a = -(phi - 1.5 * wp.pi) * b / quarter
    return wp.vec2(wp.clamp(0.5 * (a + 1.0), 0.0, 1.0), wp.clamp(0.5 * (b + 1.0), 0.0, 1.0))


@wp.func
def malley_direction_to_square(d: wp.vec3) -> wp.vec2:
    """Inverse of sampling.cosine_hemisphere (concentric + Malley): +Z-hemisphere unit vector -> [0,1]^2.

    The directional layout of Gaitatzes et al. 2008, Sec. 3.4 ("Sampling a
    Hemisphere of Directions": the concentric map with Malley's method, the
    best of their Figure 5): each texel of an M x M map covers an equal share
    of the cosine-weighted hemisphere (pdf cos(theta) / pi per sr).
    """
    x = d[0]
    y = d[1]
    r2 = x * x + y * y
    if r2 > 1.0:  # rounding just outside the disk: pull back onto the rim
        s = 1.0 / wp.sqrt(r2)
        x = x * s
        y = y * s
    return concentric_disk_to_square(x, y)
