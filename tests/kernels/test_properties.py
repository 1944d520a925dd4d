"""Property-based tests (hypothesis) for the pure math of the processors (issue #6).

Each property holds for *every* input of its domain, so hypothesis draws the inputs (derandomized:
the same examples on every run, so CI is reproducible) and each test compares against an
independent computation or a bound stated by the format, never against stored outputs:

- L2 spherical harmonics (kernels/sh.py): projection of a band-limited function recovers its
  coefficients under an exact quadrature; rotating coefficients equals projecting the rotated
  function (band-limited exactly, a non-band-limited lobe within quadrature error); per-band energy
  is rotation invariant; irradiance of non-negative radiance stays above the clamped-cosine
  kernel's ringing bound.
- Tetrahedra (tetrahedra.py): barycentrics sum to one and reconstruct the point; the walk agrees
  with scipy's Delaunay.find_simplex; interpolation reproduces affine fields exactly.
- Quantizers: RGB9E5 round-trip bound and per-channel monotonicity; 8-bit hemisphere direction
  codes' angular bound; BC1 two-colour and colour-line error bounds (decoded values may leave the
  block's [min, max] by more than the 565 rounding: the least-squares endpoint refit extrapolates when
  that lowers the block's squared error, so that is not a property of this encoder); the log codes of the
  form-factor compression (monotone, half a step in log space).
- Sky patch layouts (kernels/sky.py): uniform N, Tregenza, Reinhart MF:n tile the upper hemisphere
  (solid angles sum to 2 pi, positive, unit centres above the horizon, every direction in exactly
  one patch, which is within the patch's stated radius of its centre).

Sphere-map properties live in tests/test_sphere_maps.py; sampling maps in tests/test_sampling.py.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st
from scipy.spatial import Delaunay
from tolerances import (BARYCENTRIC, BC1_BOUND_SLACK, FLOAT32_ROUNDING, FLOAT32_STORAGE, FLOAT64_AMPLIFIED,
                        FLOAT64_ROUNDING, LOG_CODE_SLACK, ON_BOUNDARY, PALETTE_ROUNDING, QUANT565, QUOTED_6_DECIMALS,
                        SH_LOBE, SH_QUADRATURE)
from usdbake.processors.light_probes import tetrahedra
from usdbake.processors.radiosity import bc1, operator_codec
from usdbake.kernels import rgb9e5, sh, sky
from usdbake.kernels import direction24 as dir24

PROPERTY = settings(derandomize=True, max_examples=100, deadline=None)
"""Fixed examples (reproducible in CI), few enough that the whole file runs in seconds."""

SLOW_PROPERTY = settings(derandomize=True, max_examples=40, deadline=None)
"""For examples that build a Delaunay tetrahedralization or a large quadrature each."""

unit = st.floats(-1.0, 1.0, allow_nan=False)


def gauss_sphere(n_z: int, n_phi: int) -> tuple[np.ndarray, np.ndarray]:
    """Gauss-Legendre in z times uniform phi: exact for polynomials of degree < min(2 n_z, n_phi)."""
    nodes, weights = np.polynomial.legendre.leggauss(n_z)
    phi = (np.arange(n_phi) + 0.5) * 2 * np.pi / n_phi
    z, p = np.meshgrid(nodes, phi, indexing="ij")
    r = np.sqrt(1 - z * z)
    dirs = np.stack([r * np.cos(p), r * np.sin(p), z], axis=-1).reshape(-1, 3)
    return dirs, (weights[:, None] * np.full(n_phi, 2 * np.pi / n_phi)).reshape(-1)


EXACT_QUADRATURE = gauss_sphere(6, 12)
"""Exact for degree < 12: products of L2 basis functions are degree 4."""

FINE_QUADRATURE = gauss_sphere(48, 96)
"""For non-band-limited smooth lobes (see tolerances.SH_LOBE)."""


@st.composite
def unit_vectors(draw):
    v = np.array([draw(unit), draw(unit), draw(unit)])
    norm = np.linalg.norm(v)
    assume(norm > 0.1)  # away from 0 so normalizing is well conditioned
    return v / norm


@st.composite
def rotations(draw):
    """Uniformly parametrized rotations from a (normalized) quaternion."""
    q = np.array([draw(unit) for _ in range(4)])
    norm = np.linalg.norm(q)
    assume(norm > 0.1)
    w, x, y, z = q / norm
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ])


coefficients9 = st.lists(st.floats(-10.0, 10.0, allow_nan=False), min_size=9, max_size=9).map(np.array)


# ---------------------------------------------------------------------------
# L2 spherical harmonics

@PROPERTY
@given(coefficients9)
def test_projection_recovers_band_limited_coefficients(c):
    dirs, w = EXACT_QUADRATURE
    values = sh.sh_basis_np(dirs) @ c
    np.testing.assert_allclose(sh.project_np(dirs, values, w), c, rtol=0, atol=SH_QUADRATURE * (1 + np.abs(c).max()),
                               err_msg="orthonormal basis: projecting sum c_k Y_k must give c back")


@PROPERTY
@given(coefficients9, rotations())
def test_rotation_of_band_limited_function_is_exact(c, rotation):
    dirs, w = EXACT_QUADRATURE
    rotated = sh.project_np(dirs, sh.sh_basis_np(dirs @ rotation) @ c, w)  # g(w) = f(R^T w)
    np.testing.assert_allclose(sh.rotate_np(c, rotation), rotated, rtol=0, atol=SH_QUADRATURE * (1 + np.abs(c).max()),
                               err_msg="rotation matrix must map f's coefficients to those of f(R^T w)")


@SLOW_PROPERTY
@given(unit_vectors(), rotations(), st.floats(0.5, 20.0))
def test_rotating_projected_lobe_equals_projecting_rotated_lobe(axis, rotation, sharpness):
    dirs, w = FINE_QUADRATURE

    def lobe(a):
        return np.exp(sharpness * (dirs @ a - 1.0))

    projected = sh.project_np(dirs, lobe(axis), w)
    np.testing.assert_allclose(sh.rotate_np(projected, rotation), sh.project_np(dirs, lobe(rotation @ axis), w),
                               rtol=0, atol=SH_LOBE, err_msg="rotation must commute with projection")
    # Per-band energy is rotation invariant (each band is an irreducible representation).
    for band in range(3):
        rows = sh.BAND == band
        assert np.linalg.norm(sh.rotate_np(projected, rotation)[rows]) == pytest.approx(
            np.linalg.norm(projected[rows]), abs=SH_QUADRATURE), f"band {band} energy changed under rotation"


KERNEL_MIN = (math.pi / (4 * math.pi) * 1.0 + 2 * math.pi / 3 * 3 / (4 * math.pi) * (-8 / 15)
              + math.pi / 4 * 5 / (4 * math.pi) * 0.5 * (3 * (8 / 15) ** 2 - 1))
"""Minimum over n.w of the L2 clamped-cosine kernel sum_l A_l (2l+1)/(4 pi) P_l(n.w), at n.w = -8/15
(-0.0396): the L2 irradiance of non-negative radiance with total power Phi is >= KERNEL_MIN * Phi,
attained by a single delta light (Ramamoorthi & Hanrahan 2001 truncation; see tests/test_sh.py)."""


@SLOW_PROPERTY
@given(st.lists(st.tuples(unit_vectors(), st.floats(0.0, 1e3), st.integers(0, 50)), min_size=1, max_size=5),
       st.lists(unit_vectors(), min_size=12, max_size=12))
def test_irradiance_of_non_negative_radiance_is_above_the_ringing_bound(lobes, normals):
    dirs, w = EXACT_QUADRATURE  # any non-negative quadrature gives a non-negative (discrete) radiance
    radiance = sum(power * np.maximum(dirs @ a, 0.0) ** k for a, power, k in lobes)
    phi = float((radiance * w).sum())
    e = sh.evaluate_np(sh.irradiance_sh_np(sh.project_np(dirs, radiance, w))[:, None], np.array(normals))[:, 0]
    assert e.min() >= KERNEL_MIN * phi - FLOAT64_ROUNDING * (1 + phi), "L2 irradiance below the kernel's ringing bound"
    assert KERNEL_MIN == pytest.approx(-0.039583, abs=QUOTED_6_DECIMALS)


# ---------------------------------------------------------------------------
# Barycentrics and point location

@st.composite
def tetrahedron_and_points(draw):
    corners = np.array([[draw(st.floats(-10, 10)) for _ in range(3)] for _ in range(4)])
    edges = corners[1:] - corners[0]
    volume = abs(np.linalg.det(edges)) / 6
    longest = max(np.linalg.norm(corners[i] - corners[j]) for i in range(4) for j in range(i))
    assume(longest > 1e-3 and volume > 1e-3 * longest ** 3)  # not a sliver: condition number <~ 1e3
    offset = draw(st.sampled_from([0.0, 1e3, -1e5]))
    weights = np.array([[draw(st.floats(-0.5, 1.5)) for _ in range(4)] for _ in range(5)])
    weights /= np.where(np.abs(weights.sum(1, keepdims=True)) > 0.1, weights.sum(1, keepdims=True), 1.0)
    queries = weights @ corners
    return corners + offset, queries + offset


@PROPERTY
@given(tetrahedron_and_points())
def test_barycentrics_sum_to_one_and_reconstruct_the_point(data):
    corners, queries = data
    tetra = tetrahedra.tetrahedralize(corners)
    assert tetra.num_tets == 1
    b = tetrahedra.barycentric(tetra, np.zeros(len(queries), np.int64), queries)
    np.testing.assert_allclose(b.sum(axis=1), 1.0, rtol=0, atol=BARYCENTRIC, err_msg="partition of unity")
    scale = 1 + np.abs(corners).max()
    np.testing.assert_allclose(b @ tetra.points[tetra.tet_vertices[0]], queries, rtol=0, atol=BARYCENTRIC * scale,
                               err_msg="sum b_i v_i must reconstruct the query")


@st.composite
def point_clouds(draw):
    seed = draw(st.integers(0, 2**31 - 1))
    count = draw(st.integers(5, 60))
    scale = draw(st.sampled_from([1e-3, 1.0, 50.0]))
    offset = draw(st.sampled_from([0.0, 1e4]))
    rng = np.random.default_rng(seed)
    points = rng.random((count, 3)) * scale + offset
    queries = rng.random((40, 3)) * scale * 1.2 - 0.1 * scale + offset  # some outside the hull
    return points, queries


@SLOW_PROPERTY
@given(point_clouds())
def test_walk_agrees_with_scipy_find_simplex(data):
    points, queries = data
    tetra = tetrahedra.tetrahedralize(points)
    assume(not tetra.joggled)  # random points are in general position; joggled sets differ from scipy by design
    reference = Delaunay(points, qhull_options="Qbb Qc Qz Q12 Qt")
    expected = reference.find_simplex(queries)
    tet, bary, inside = tetrahedra.locate(tetra, queries)
    np.testing.assert_array_equal(inside, expected >= 0, err_msg="inside/outside the hull must agree with qhull")
    found = tet[inside]
    # Same simplex as scipy, unless the query lies on a face both tetrahedra share.
    same = np.all(np.sort(tetra.tet_vertices[found], axis=1) == np.sort(reference.simplices[expected[inside]], axis=1),
                  axis=1)
    on_face = bary[inside].min(axis=1) <= ON_BOUNDARY
    assert np.all(same | on_face), "walk ended in a different tetrahedron than scipy's find_simplex"
    assert np.all(bary[inside] >= -tetrahedra.BARY_TOLERANCE), "walk ended in a tetrahedron not containing the query"


@SLOW_PROPERTY
@given(point_clouds(), st.lists(st.floats(-5, 5), min_size=4, max_size=4))
def test_interpolation_reproduces_affine_fields(data, coefficients):
    points, queries = data
    tetra = tetrahedra.tetrahedralize(points)
    a, b = np.array(coefficients[:3]), coefficients[3]
    field = points @ a + b
    tet, bary, inside = tetrahedra.locate(tetra, queries)
    assume(inside.any())
    interpolated = (bary * field[tetra.tet_vertices[tet]]).sum(axis=1)
    scale = 1 + np.abs(points).max() * np.abs(a).sum() + abs(b)
    np.testing.assert_allclose(interpolated[inside], (queries @ a + b)[inside], rtol=0, atol=BARYCENTRIC * scale,
                               err_msg="linear interpolation must reproduce an affine field exactly")


# ---------------------------------------------------------------------------
# RGB9E5




@st.composite
def rgb9e5_inputs(draw):
    """Non-negative finite colours over every magnitude, half of them built from a shared exponent and
    per-channel mantissas plus an offset in (-1, 1) steps, so mantissa edges (0, 255, 511, the
    exponent bump) are hit as often as the middle of the range."""
    if draw(st.booleans()):
        rgb = np.array([draw(st.floats(0.0, 1.0)) for _ in range(3)])
        return np.minimum(rgb * 2.0 ** draw(st.floats(-30, 16)), rgb9e5.MAX_RGB9E5)
    exponent = draw(st.integers(0, rgb9e5.MAX_EXPONENT))
    step = 2.0 ** (exponent - rgb9e5.EXPONENT_BIAS - rgb9e5.MANTISSA_BITS)
    top = 2**rgb9e5.MANTISSA_BITS - 1
    mantissa = st.one_of(st.sampled_from([0, 1, top // 2, top // 2 + 1, top - 1, top]), st.integers(0, top))
    offset = st.one_of(st.sampled_from([-0.5, 0.0, 0.5, 0.4999, 0.5001]), st.floats(-1.0, 1.0))
    mantissas = np.array([draw(mantissa) for _ in range(3)], np.float64)
    offsets = np.array([draw(offset) for _ in range(3)])
    return np.clip((mantissas + offsets) * step, 0.0, rgb9e5.MAX_RGB9E5)


@PROPERTY
@given(rgb9e5_inputs())
def test_rgb9e5_round_trip_within_the_format_bound(rgb):
    decoded = rgb9e5.decode_rgb9e5(rgb9e5.encode_rgb9e5(rgb)).astype(np.float64)
    bound = max(rgb9e5.RELATIVE_ERROR * rgb.max(), rgb9e5.ABSOLUTE_ERROR)
    assert np.all(np.abs(decoded - rgb) <= bound), f"{rgb} -> {decoded}, bound {bound}"


@PROPERTY
@given(rgb9e5_inputs(), st.integers(0, 2), st.sampled_from([2.0**-12, 2.0**-9, 2.0**-6, 0.1, 1.0, 4.0]))
def test_rgb9e5_is_monotone_in_each_channel(rgb, channel, growth):
    """Raising one channel never lowers its decoded value (the others may coarsen: shared exponent)."""
    larger = rgb.copy()
    larger[channel] = min(rgb[channel] * (1 + growth) + growth * 2.0**-24, rgb9e5.MAX_RGB9E5)
    before = rgb9e5.decode_rgb9e5(rgb9e5.encode_rgb9e5(rgb))[channel]
    after = rgb9e5.decode_rgb9e5(rgb9e5.encode_rgb9e5(larger))[channel]
    assert after >= before, f"channel {channel}: {rgb} -> {before}, but {larger} -> {after}"


# ---------------------------------------------------------------------------
# 24-bit (8:8:8) hemisphere directions


@PROPERTY
@given(unit_vectors(), st.integers(0, 5))
def test_direction_code_angle_bound(direction, hemisphere):
    axis = dir24.AXES[hemisphere].astype(np.float64)
    if direction @ axis < 0:
        direction = direction - 2 * (direction @ axis) * axis  # reflect into the hemisphere
    decoded = dir24.decode_directions(dir24.encode_directions(direction[None], [hemisphere]))[0]
    angle = math.degrees(math.acos(min(1.0, float(decoded.astype(np.float64) @ direction))))
    assert angle <= dir24.MAX_ANGLE_ERROR_DEG, f"{direction} in hemisphere {hemisphere}: {angle:.2f} deg"
    assert float(decoded @ axis) >= dir24.MIN_AXIS_COSINE - FLOAT32_STORAGE, "decoded direction left its hemisphere"


# ---------------------------------------------------------------------------
# BC1

byte = st.floats(0.0, 255.0, allow_nan=False)
colour8 = st.lists(byte, min_size=3, max_size=3).map(np.array)


@PROPERTY
@given(colour8, colour8, st.lists(st.booleans(), min_size=16, max_size=16))
def test_bc1_two_colour_blocks_are_exact_up_to_565_rounding(a, b, mask):
    texels = np.where(np.array(mask)[:, None], a, b).reshape(4, 4, 3)
    decoded = bc1.decode_bc1(bc1.encode_bc1(texels), 4, 4).astype(np.float64)
    # The range fit puts the endpoints on the two colours; each texel can reach its own endpoint,
    # so the block's mean squared error is at most one endpoint's rounding (refinement only lowers it).
    mse = ((decoded - texels) ** 2).sum(-1).mean()
    assert mse <= (QUANT565 ** 2).sum() + BC1_BOUND_SLACK, f"two-colour block: mean squared error {mse:.2f}"


def segment_block(a, b, t):
    return (a[None] + np.array(t)[:, None] * (b - a)[None]).reshape(4, 4, 3)


def line_block_bound(a, b):
    """Mean squared error bound for texels on the segment a-b with both ends present: each texel is
    within |b - a| / 6 of one of the four ideal palette entries, which the decoder reproduces within
    PALETTE_ROUNDING; the least-squares refinement is kept only when it lowers the block's error."""
    return (np.linalg.norm(b - a) / 6 + PALETTE_ROUNDING) ** 2


@PROPERTY
@given(colour8, colour8, st.lists(st.floats(0.0, 1.0), min_size=14, max_size=14))
def test_bc1_blocks_on_a_line_are_within_the_palette_bound(a, b, t):
    texels = segment_block(a, b, [0.0, 1.0] + list(t))
    decoded = bc1.decode_bc1(bc1.encode_bc1(texels), 4, 4).astype(np.float64)
    mse = ((decoded - texels) ** 2).sum(-1).mean()
    assert mse <= line_block_bound(a, b) + BC1_BOUND_SLACK, \
        f"line block: mse {mse:.2f} > bound {line_block_bound(a, b):.2f}"


def test_bc1_colour_line_orthogonal_to_grey():
    """A red-green ramp (r + g + b constant): the principal axis must not start from grey."""
    x = np.linspace(0.0, 1.0, 16)
    a, b = np.array([255.0, 0.0, 128.0]), np.array([0.0, 255.0, 128.0])
    texels = segment_block(a, b, x)
    decoded = bc1.decode_bc1(bc1.encode_bc1(texels), 4, 4).astype(np.float64)
    mse = ((decoded - texels) ** 2).sum(-1).mean()
    assert mse <= line_block_bound(a, b), f"red-green ramp: rms {math.sqrt(mse):.1f} (bound {math.sqrt(line_block_bound(a, b)):.1f})"


# ---------------------------------------------------------------------------
# Log codes of the form-factor compression

@PROPERTY
@given(st.floats(-12, -1), st.floats(-3, 3),
       st.lists(st.floats(0.0, 1.0, allow_nan=False), min_size=1, max_size=50))
def test_log_codes_monotone_and_within_half_a_step(log10_floor, log10_vmax, fractions):
    vmax = 10.0 ** log10_vmax
    floor = vmax * 10.0 ** log10_floor
    values = np.sort(np.array(fractions) * vmax)
    codes, scale, offset = operator_codec.log_codes(values, floor, vmax)
    assert np.all(np.diff(codes) >= 0), "codes must be monotone in the value"
    byte_codes = np.rint(codes).astype(np.int64)
    decoded = operator_codec.code_lut(scale, offset, "log")[byte_codes].astype(np.float64)
    coded = values >= floor
    np.testing.assert_array_equal(decoded[~coded], 0.0, err_msg="values below the floor decode to 0")
    error = np.abs(np.log(decoded[coded]) - np.log(values[coded]))
    assert np.all(error <= scale * (0.5 + LOG_CODE_SLACK) + FLOAT32_ROUNDING), \
        f"log error {error.max()} > half step {scale / 2}"


# ---------------------------------------------------------------------------
# Sky patch layouts

layouts = st.one_of(
    st.integers(1, 65536).map(lambda n: ("uniform", n)),  # the processor's patch_count range
    st.just(("tregenza", 1)),
    st.integers(1, 16).map(lambda n: ("reinhart", n)),  # its subdivision range
)

# Directions on a shared patch edge (e.g. exactly south, on a ring boundary) belong to both closed patches;
# float azimuth wrapping decides them either way, so coverage is tested with the closed patches grown by
# ON_BOUNDARY and overlap with the open patches shrunk by it.


def containing_patches(patches: sky.SkyPatches, direction: np.ndarray, slack: float) -> np.ndarray:
    """Indices of patches whose (z, azimuth) bounds, grown by ``slack`` (shrunk if negative), contain an
    ENU direction; azimuth wraps around north."""
    z = direction[2]
    azimuth = math.atan2(direction[0], direction[1])  # from north towards east
    z_lo, z_hi, az_lo, az_hi = patches.patch_bounds.T
    in_z = (z >= z_lo - slack) & (z <= z_hi + slack)
    wrapped = (azimuth - az_lo + slack) % (2 * np.pi)
    in_az = wrapped <= (az_hi - az_lo) + 2 * slack
    return np.flatnonzero(in_z & in_az)


@PROPERTY
@given(layouts, st.lists(unit_vectors(), min_size=8, max_size=8))
def test_patch_layouts_tile_the_upper_hemisphere(layout, directions):
    name, n = layout
    patches = sky.patch_layout(name, count=n, subdivision=n)
    if name == "uniform":
        assert len(patches) == n
        np.testing.assert_allclose(patches.patch_solid_angles, 2 * np.pi / n, rtol=FLOAT64_AMPLIFIED,
                                   err_msg="equal solid angle")
    assert np.all(patches.patch_solid_angles > 0)
    assert patches.patch_solid_angles.sum() == pytest.approx(2 * np.pi, abs=FLOAT64_AMPLIFIED)
    np.testing.assert_allclose(np.linalg.norm(patches.patch_directions, axis=1), 1.0, rtol=0, atol=FLOAT64_ROUNDING)
    assert patches.patch_directions[:, 2].min() >= 0.0
    # The bounds tile the hemisphere: rings stack from the horizon to the zenith, each ring's azimuth
    # ranges are contiguous and close the circle, and each stated solid angle is its band's dz dphi
    # (Archimedes' hat-box theorem).
    z_lo, z_hi, az_lo, az_hi = patches.patch_bounds.T
    np.testing.assert_allclose(patches.patch_solid_angles, (z_hi - z_lo) * (az_hi - az_lo), rtol=FLOAT64_ROUNDING,
                               atol=0,
                               err_msg="solid angle of a z band x azimuth range must be dz dphi")
    rings = np.unique(patches.patch_bounds[:, :2], axis=0)
    assert rings[0, 0] == 0.0 and rings[-1, 1] == 1.0, "rings must span z from the horizon to the zenith"
    np.testing.assert_array_equal(rings[1:, 0], rings[:-1, 1], err_msg="rings must stack without gaps")
    for lo, hi in rings:
        ring = np.flatnonzero((z_lo == lo) & (z_hi == hi))
        order = ring[np.argsort(az_lo[ring])]
        np.testing.assert_allclose(az_lo[order[1:]], az_hi[order[:-1]], rtol=0, atol=FLOAT64_ROUNDING,
                                   err_msg="azimuth ranges in a ring must be contiguous")
        assert az_hi[order[-1]] - az_lo[order[0]] == pytest.approx(2 * np.pi, abs=FLOAT64_ROUNDING), "ring must close"
    for d in directions:
        d = d * np.sign(d[2]) if d[2] != 0 else d
        hits = containing_patches(patches, d, ON_BOUNDARY)
        assert len(hits) >= 1, f"{name} {n}: direction {d} lies in no patch"
        assert len(containing_patches(patches, d, -ON_BOUNDARY)) <= 1, f"{name} {n}: patches overlap at {d}"
        angle = math.acos(min(1.0, float(patches.patch_directions[hits[0]] @ d)))
        assert angle <= patches.patch_radius[hits[0]], "direction farther from its patch centre than the radius"
    # Each patch centre lies in its own patch.
    for k in range(0, len(patches), max(1, len(patches) // 16)):
        assert k in containing_patches(patches, patches.patch_directions[k], ON_BOUNDARY), \
            f"centre of patch {k} outside it"
