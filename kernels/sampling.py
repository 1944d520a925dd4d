"""Sampling maps shared by the processors, as Warp functions.

Their numpy twins, against which the tests check them (closed forms,
hypothesis), are in tests/kernel_twins.py.
"""

import math

import warp as wp

wp.set_module_options({"enable_backward": False, "fuse_fp": False})


@wp.func
def concentric_disk(u1: float, u2: float) -> wp.vec2:
    """Shirley-Chiu concentric map of [0,1)^2 onto the unit disk (area preserving, low distortion).

    Shirley & Chiu 1997, "A low distortion map between disk and square", JGT
    2(3), in the branch-reduced form of Pharr, Jakob & Humphreys, "Physically
    Based Rendering" (3rd ed.), sec. 13.6.2: concentric squares go to
    concentric circles, so uniform (u1, u2) give uniform points on the disk
    (pdf 1/pi per unit area). Dimensionless.
    """
    a = 2.0 * u1 - 1.0
    b = 2.0 * u2 - 1.0
    # phi = pi/4 (b/a) where |a| > |b|, else pi/2 - pi/4 (a/b): cos and sin of pi/4 x (|x| <= 1), swapped in
    # the second case. Chosen by selects, not branches: the case is a coin toss per sample, which a CPU's
    # branch predictor pays for in every ray generator.
    wide = a * a > b * b
    radius = wp.where(wide, a, b)
    if radius == 0.0:
        return wp.vec2(0.0, 0.0)
    sin_cos = sin_cos_quarter_turn((wp.pi / 4.0) * (wp.where(wide, b, a) / radius))
    return wp.vec2(radius * wp.where(wide, sin_cos[1], sin_cos[0]), radius * wp.where(wide, sin_cos[0], sin_cos[1]))


@wp.func
def sin_cos(x: float) -> wp.vec2:
    """(sin x, cos x): x reduced to r = x - k pi/2, |r| <= pi/4 (k the nearest integer; pi/2 in three parts
    of few bits, so each k * part is exact: Cody & Waite 1980, Cephes' constants), ``sin_cos_quarter_turn``
    of r, then turned by k quarter turns. Within 3e-7 of float64 for |x| < 100 (tested), several times
    faster than wp.sin and wp.cos on CPU."""
    k = wp.round(x * (2.0 / wp.pi))
    r = ((x - k * 1.5703125) - k * 4.837512969970703125e-4) - k * 7.54978995489188216e-8
    sc = sin_cos_quarter_turn(r)
    q = int(k) & 3
    if q == 0:
        return sc
    if q == 1:
        return wp.vec2(sc[1], -sc[0])
    if q == 2:
        return wp.vec2(-sc[0], -sc[1])
    return wp.vec2(-sc[1], sc[0])


@wp.func
def sin_cos_quarter_turn(x: float) -> wp.vec2:
    """(sin x, cos x) for |x| <= pi/4 by the minimax polynomials of Cephes' sinf/cosf (Moshier 1989), within
    2e-7 of libm there: 3x faster than wp.sin and wp.cos on CPU, where the ray generators spend their time."""
    z = x * x
    s = x + x * z * (-1.6666654611e-1 + z * (8.3321608736e-3 + z * -1.9515295891e-4))
    c = 1.0 - 0.5 * z + z * z * (4.166664568298827e-2 + z * (-1.388731625493765e-3 + z * 2.443315711809948e-5))
    return wp.vec2(s, c)


@wp.func
def cosine_hemisphere(u1: float, u2: float) -> wp.vec3:
    """Malley's method: lift the concentric disk sample to the +Z hemisphere, pdf = cos(theta) / pi.

    Malley 1988 (MS thesis, University of Utah), as in Pharr, Jakob &
    Humphreys, "Physically Based Rendering" (3rd ed.), sec. 13.6.3: uniform
    points on the disk projected up to the hemisphere have the density
    cos(theta) / pi per steradian, so the mean of V over such directions is
    E / (pi L) under a uniform radiance L. Returns a unit vector, z >= 0.
    """
    d = concentric_disk(u1, u2)
    z = wp.sqrt(wp.max(0.0, 1.0 - d[0] * d[0] - d[1] * d[1]))
    return wp.vec3(d[0], d[1], z)


@wp.func
def tangent_frame(n: wp.vec3) -> wp.mat33:
    """Orthonormal basis with n as third column (Duff et al. 2017, branchless and continuous).

    Duff, Burgess, Christensen, Hery, Kensler, Liani & Villemin, "Building an
    orthonormal basis, revisited", JCGT 6(1), 2017. ``n`` must be a unit
    vector; the frame maps local (x, y, z) to world, z along n.
    """
    sign = wp.where(n[2] >= 0.0, 1.0, -1.0)
    a = -1.0 / (sign + n[2])
    b = n[0] * n[1] * a
    t = wp.vec3(1.0 + sign * n[0] * n[0] * a, sign * b, -sign * n[0])
    s = wp.vec3(b, sign + n[1] * n[1] * a, -n[1])
    return wp.matrix_from_cols(t, s, n)


@wp.func
def stratified_pair(index: int, strata: int, state: wp.uint32) -> wp.vec2:
    """Jittered sample in cell ``index`` of a strata x strata grid over [0,1)^2.

    Jittered (stratified) sampling, Cook 1986, "Stochastic sampling in computer
    graphics", ACM TOG 5(1): one uniform point per cell of the grid, so the
    estimate's variance falls faster than with independent points.
    Dimensionless.

    The jitter comes from a generator seeded by (state, index). Warp passes
    ``state`` into a @wp.func by value, so drawing from it here would not
    advance the caller's generator and every cell would get the same jitter.
    """
    local = wp.rand_init(wp.int32(state), index)
    sy = index // strata
    sx = index - sy * strata  # one integer division, not two
    inv = 1.0 / float(strata)
    return wp.vec2((float(sx) + wp.randf(local)) * inv, (float(sy) + wp.randf(local)) * inv)


@wp.func
def triangle_point(a: wp.vec3, b: wp.vec3, c: wp.vec3, u1: float, u2: float) -> wp.vec3:
    """Uniform point on triangle abc from two uniforms (square-root warp; Osada et al. 2002).

    Osada, Funkhouser, Chazelle & Dobkin, "Shape distributions", ACM TOG 21(4),
    2002: P = (1 - sqrt(u1)) a + sqrt(u1) (1 - u2) b + sqrt(u1) u2 c has the
    uniform density 1 / area over the triangle (area in stage units^2).

    The caller draws u1 and u2, so its own generator advances (see stratified_pair).
    """
    r1 = wp.sqrt(u1)
    return a * (1.0 - r1) + b * (r1 * (1.0 - u2)) + c * (r1 * u2)


def strata_for(samples: int) -> int:
    """Side of a stratification grid: the square nearest to ``samples`` (at least 1)."""
    return max(1, int(round(math.sqrt(samples))))
