"""Every tolerance of the test suite, each with the error it bounds (house style, point 9).

A tolerance is how far a computed value may be from the value the test expects: rounding of a
float format, the noise of a Monte Carlo estimate at the test's sample count, the step of a codec,
the truncation of a quadrature, or an accuracy figure a processor is held to (measured value
stated). Sample counts, seeds, sizes, expected values and exact checks stay in the tests, and so
do bounds a test derives line by line from its own grid or bins (test_sampling's ring_tol and
sector_tol) and qualitative thresholds (an effect is visible, a check is not vacuous).

Tests import what they use: ``from tolerances import FLOAT32_STORAGE, MC_SIGMAS``. Where a bound
depends on a test's own sample count, this module holds the dimensionless part (the number of
standard deviations, the flips per receiver, a quadrature's error coefficient) and the test
applies it to its count. tests/test_tolerances.py checks that every constant here has a reason and
is used.
"""

import numpy as np

# -- floating point: float64 -------------------------------------------------------------------

FLOAT64_CONSTANT = 1e-15
"""A closed-form constant evaluated in float64 by one sqrt and a division or two: within a few
ulps (eps = 2.2e-16) of the exact value."""

FLOAT64_ROUNDING = 1e-12
"""Float64 rounding of identities that hold exactly in real arithmetic, on values of order 1: a few
ulps (eps = 2.2e-16) per operation over up to ~1e3 operations or terms (quadrature-exact sums,
norms of unit vectors, ring areas, areas of refined meshes, push-pull copies and averages)."""

FLOAT64_AMPLIFIED = 1e-9
"""Float64 rounding amplified by the computation: sums of thousands of terms, differences of nearly
equal values, inverse trigonometry near +-1 (round trips through the sphere maps near the poles:
~1e3), coordinates far from the origin (1e6 units: eps x 1e6 = 2e-10). Still far below any real
error these tests look for."""

ON_BOUNDARY = 1e-9
"""Slack that decides "on a boundary" in float64 geometry of unit size: a point on an edge, a face,
the hull or a sky patch's border, a grid vertex exactly at a stated bound, a zero-area ear (signed
area in units of its polygon's area) or a zero-volume tetrahedron lands ~1e-15 off it after
rounding; within 1e-9 it counts as on it (closed patches grow by this, open ones shrink by it),
anything farther is a real separation."""

BARYCENTRIC = 1e-9
"""Float64 barycentrics (and the affine fields they interpolate) of points within a few
tetrahedron sizes of well-conditioned tetrahedra (condition number up to ~1e3, volume checked):
the solves lose at most ~1e4 ulps."""

FINITE_DIFFERENCE = 1e-6
"""Relative error of a float64 central-difference Jacobian with step 1e-6: truncation
O(step^2 f''') ~ 1e-12, cancellation ~ eps / step ~ 1e-10; margin for the steeper wedges of the
concentric map."""

# -- floating point: float32 -------------------------------------------------------------------

FLOAT32_UNIT_ROUNDOFF = 6e-8
"""Relative rounding of one float32 operation (2^-24 = 5.96e-8): a float32 sum of N terms is good
to N * FLOAT32_UNIT_ROUNDOFF relative."""

FLOAT32_ROUNDING = 1e-7
"""One float32 rounding of a value of order 1 (at most 6e-8): values that are exact (often exactly
0) in real arithmetic, computed by a few float32 operations on order-1 inputs; the float32 byte
LUT of the log codes."""

FLOAT32_STORAGE = 1e-6
"""A value of order 1 after float32 storage and a handful of float32 operations (spacing 6e-8 to
1.2e-7 near 1): points relative to the scene origin (so it holds however far the stage is from
(0, 0, 0), while float32 world coordinates at 1e6 would be off by 0.03), colours copied from
float32 or float64 sources, unit normals, areas, light parameters, form-factor row sums (shares of
rays, at most 1), relit or composited pixels."""

FLOAT32_BARYCENTRIC = 1e-3
"""Float32 barycentrics of a point in a probe tetrahedron against float64 (scipy, the numpy walk): the
3x3 inverse edge matrix in float32 times (p - v0) loses ~eps x its condition number, which reaches the
hundreds for the slivers of random Delaunay clouds (measured 1.7e-4 over 20,000 points in 1,024
random probes)."""

POLYNOMIAL_SIN_COS = 3e-7
"""kernels.sampling.sin_cos (Cody-Waite reduction, Cephes polynomials) against float64 for |x| < 100:
a few ulps of 1.2e-7 (measured 9.1e-8 over 1M random arguments)."""

FLOAT32_WARP_MATH = 2e-6
"""Warp float32 against the float64 numpy twins for sin/cos/sqrt of order-1 values (SH basis values
up to ~1.1): ~10 ulps of 1.2e-7."""

FLOAT32_ACCUMULATED = 1e-5
"""Float32 rounding accumulated over tens to hundreds of operations or terms on values up to ~10:
ray/triangle hit distances and barycentrics on unit-sized geometry, world positions within ~10
units of the origin (float32 points after float64 transforms), sums of a few hundred float32
terms, bounds exact in real arithmetic (a sum or mean of [0, 1] terms), results that differ only
in summation order."""

FLOAT32_WARP_MAPS = 2e-5
"""Warp float32 against numpy float64 for the sphere and hemisphere maps on unit-sized values:
float32 trigonometry (~1e-7) amplified by the maps' slopes."""

FLOAT32_LONG_CHAIN = 1e-4
"""Float32 rounding through a long chain, relative to the largest value: sums of thousands of
terms, values of order 10 to 100 stored in float32, float32 decodes against float64 references
(camera rays, relit operators, row sums rescaled by the codec), a rescaled scene whose float32 hit
points move by an ulp."""

# -- Monte Carlo and grazing rays --------------------------------------------------------------

MC_SIGMAS = 4.0
"""Monte Carlo tolerances are MC_SIGMAS standard deviations of the i.i.d. estimator at the test's
sample count (stratified or jittered sampling never has more variance): ~6e-5 two-sided
false-failure rate per check, and the seeds are fixed anyway."""

GRAZING_RAY_FLIPS = 2.0
"""Rays per receiver that may flip between hit and miss when a scene is rescaled or moved: same
seeds and receivers, so only float32 rounding differs, and it decides rays that graze an edge.
The tolerance on a visibility mean is GRAZING_RAY_FLIPS / samples."""

STRESS_RAY_FLIPS = 3.0
"""As GRAZING_RAY_FLIPS, for the stress suite's box on a floor authored 1e5 units away (or moved
there by a double-precision xformOp, or scaled by 1e3): a few flips per vertex."""

FAR_POINTS_FLIP_FACTOR = 4.0
"""Points authored at 1e6 units are themselves float32 (ulp 0.06 there): the geometry moves, not
only the rays, so STRESS_RAY_FLIPS grows by this factor."""

PROCESSOR_RAY_FLIPS = 4.0
"""Rays of 64 per value that may flip when every processor runs on a translated or rescaled stage,
relative to the largest value of the output (for radiosity's indirect light: what one final-gather
ray carries; measured: one gather ray at a box corner, 0.0245 = 0.5 pi / 64)."""

CELL_BORDER_FLIPS = 1e-3
"""Share of displacement-field lookups that land in a neighbouring cell when the affine map of a
ray into prototype space rounds differently (float32, at cell borders only)."""

INSTANCE_TRANSFORM_FLIPS = 1e-3
"""Share of rays whose closest triangle differs between a two-level (instanced) and a flattened trace
of the same scene: moving a ray into an instance's space rounds (float32), so a ray through a shared
edge may take the neighbouring triangle (measured: 0 of 20,000)."""

CHI2_SIGNIFICANCE = 1e-3
"""p-value below which a chi-square test rejects equal cell probabilities (false-failure rate 1e-3
per test; the seed is fixed anyway)."""

SINGLE_RAY_FLIP = 1.0
"""Rays per vertex that may flip between hit and miss where only float32 rounding differs and at most
one was measured to: the Cornell box rescaled by 1e-12 or 1e12 (64 rays), instances folded into one
prototype against a field shared by them (256 rays). The tolerance is SINGLE_RAY_FLIP / rays."""

MEAN_FLIP_SHIFT = 1e-3
"""Shift of the mean AO over all of the Cornell box's vertices when grazing rays flip on a rescaled stage:
each flip moves one vertex by 1/64, so this bounds the flipping vertices to under one in 16 (a
systematic change of the trace would move every vertex)."""

# -- quadrature and deterministic grids --------------------------------------------------------

MIDPOINT_MOMENT_FACTOR = 2.0
"""Midpoint rule on a side-n grid of [0, 1)^2: polynomial moments of the sampling maps are off by
O(h^2); the tolerance is MIDPOINT_MOMENT_FACTOR / n^2 (measured exactly 1 / n^2 for E[r^2])."""

MIDPOINT_RIM_FACTOR = 1.0
"""E[z] = E[sqrt(1 - r^2)] has a square-root singularity at the disk's rim, so the midpoint rule
converges only as h^1.5 there: tolerance MIDPOINT_RIM_FACTOR * n^-1.5 (measured ~0.5 n^-1.5)."""

GRID_MINIMUM = 1e-9
"""Minimum of a smooth kernel found on a 200001-point grid of [-1, 1]: the grid misses the true
minimum by at most f'' h^2 / 8 ~ 1e-11 (h = 1e-5)."""

FIBONACCI_MEAN = 2e-3
"""Largest coordinate of the mean of 1000 Fibonacci-sphere directions: the spiral is balanced up to
its O(1/N) discrepancy."""

GROUND_QUADRATURE = 1e-4
"""Gauss-Legendre x uniform quadrature (400 x 800) of a lit ground square whose edges cut the grid:
error below 1e-4 of the irradiance."""

# -- codecs and quantization -------------------------------------------------------------------

UINT8_HALF_STEP = 0.5 / 255
"""Rounding of a [0, 1] value to an 8-bit code: half a step."""

UINT8_CODE_STEP = 1.0
"""One 8-bit code step, in code units: a mean of 8-bit codes rounded to a code once more."""

ROUNDING_MEAN_SHARE = 0.6
"""Rounding errors spread evenly over a step have mean |error| = half_step / 2; their mean must stay
below ROUNDING_MEAN_SHARE * half_step (a systematic offset would reach half_step)."""

QUANT565 = np.array([255 / 62 + 0.5, 255 / 126 + 0.5, 255 / 62 + 0.5])
"""BC1: per-channel error of an endpoint, in 8-bit steps: half a 5/6-bit level (255/31/2, 255/63/2)
plus the byte rounding of the expansion (0.5)."""

PALETTE_ROUNDING = np.linalg.norm(QUANT565 + 0.5)
"""BC1: Euclidean distance of a decoded palette entry from its ideal position: endpoint rounding
(QUANT565) plus the byte rounding of the interpolated entries (0.5)."""

BC1_BOUND_SLACK = 1e-3
"""Slack on BC1's squared-error bounds (8-bit units squared, bounds of ~50 and up): blocks that meet
a bound exactly, up to float64 rounding of the mean squared error."""

BC1_LINE_RMS = 3.0
"""BC1 RMS (8-bit steps) for texels on the 4 palette positions of a line in RGB: only the rounding
of the endpoints to 5/6 bits remains, at most half a 5-bit step (4.1) per channel, ~2.4 RMS."""

LOG_CODE_SLACK = 2e-5
"""Log codes of the form-factor compression are stored as float32 (up to 255: 1.5e-5 absolute)
before rounding to a byte, so a code may sit that much beyond half a step."""

VIRIDIS_TOLERANCE = 3.0 / 255.0
"""VIRIDIS is 33 knots of matplotlib's table linearly interpolated: measured max deviation 2.5/255."""

# -- geometry: meshes, tetrahedra, sphere maps, displacement fields ----------------------------

T_JUNCTION_ENDPOINT = 1e-6
"""A vertex whose parameter along an edge is within 1e-6 of either end is that end, not a
T-junction in the edge's interior (float64 parameters of midpoints are exact to ~1e-16)."""

TRIANGULATION_AREA = 1e-6
"""Triangle areas are summed in float64 from float64 corners; 1e-6 leaves room for the rotation
into 3D and back, far below any missing or overlapping triangle."""

JOGGLE_RECONSTRUCTION = 1e-6
"""Cospherical input is joggled by 1e-6 diagonals (tetrahedra.JOGGLE_RELATIVE): barycentrics of
the joggled slivers rebuild a query to about that."""

JOGGLE_FIELD = 1e-5
"""A linear field interpolated on a joggled (flat-tetrahedra) lattice: the 1e-6 joggle times the
field's gradient (normal coefficients, up to ~3 per axis) and the lattice size."""

MALLEY_ROUNDTRIP = 1e-7
"""Float64 round trip square -> cosine hemisphere -> square: z = sqrt(1 - r^2) and its inverse
amplify rounding near the rim (squares within 1e-6 of the border)."""

CELL_SPACING_RATIO = 1.4
"""Largest / smallest nearest-neighbour distance of the octahedral equal-area cell centres at any
resolution (documented: 1.34)."""

WRAP_NEIGHBOUR_SPACING = 1.6
"""Neighbours across the octahedral map's folded border are at most this many times the largest
in-row spacing apart on the sphere (they are adjacent, not across the map)."""

ICOSPHERE_SAGITTA = 2e-4
"""Relative bounding-sphere excess of an icosphere of level 5: its chords' sagitta, ~1.2e-4 of the
radius."""

FIELD_GRAZING_ERROR = 0.003
"""Displacement-field distances beyond the quantization's half step: the chord sagitta (~2e-4) of
the tessellated sphere seen at grazing incidence (cosine >= 0.09)."""

BOUNDING_SPHERE_SLACK = 1e-3
"""The bounding sphere of an icosphere (vertices on the sphere) exceeds its radius by at most the
bounding-sphere construction's slack."""

# -- spherical harmonics -----------------------------------------------------------------------

SH_QUADRATURE = 1e-11
"""Float64 sums over 72 exact quadrature nodes of SH values up to ~30: a few hundred ulps."""

SH_LOBE = 1e-9
"""A von Mises-Fisher lobe exp(k (w.a - 1)) is not band-limited but smooth (analytic): with k <= 20
the 48 x 96 product quadrature projects it to ~1e-13 (measured 4e-14 against a 96 x 192 one),
whatever its axis; the rotated and unrotated projections each carry that error. (A clamped cosine
lobe has a kink at its horizon that this quadrature resolves only to ~2e-4 when the kink lies along
a z ring.)"""

SH_ROTATION = 1e-10
"""Float64 rotation of L2 SH coefficients: the 9 x 9 matrix's entries are degree-2 polynomials of
the rotation's, applied to coefficients of size ~3 and compared with a 288-node projection."""

SH_L2_TRUNCATION = 0.01
"""L2 truncation of the irradiance of max(w.z, 0): pi/4 + pi/3 + 5 pi/64 is 0.8 % below the exact
2 pi / 3 (Ramamoorthi & Hanrahan)."""

DERING_STRENGTH = 1e-3
"""The window strength ``dering`` finds on its 512 directions against DERING_NON_NEGATIVE (quoted to 4
decimals, from a search over all directions): the directions may straddle the dip's minimum, so the
found strength is a little lower (measured 0.09309 against 0.0933)."""

LEAST_SQUARES_RIDGE = 1e-6
"""A float64 least-squares gradient with a ridge of 1e-9 of its normal matrix's trace (light_probes
ascent): the ridge shrinks the solution by ~1e-9 x trace / smallest eigenvalue, up to ~1e-6 for the
flat neighbourhoods of a random cloud; a linear field's gradient comes back to that."""

# -- published and quoted reference values -----------------------------------------------------

QUOTED_6_DECIMALS = 1e-6
"""A reference value quoted to 6 decimals (-0.039583, 0.488603) is good to 5e-7."""

QUOTED_4_DECIMALS = 5e-5
"""A reference value quoted to 4 decimals (Perez et al.'s Table 1 coefficients) is good to 5e-5."""

SRGB_MATRIX_DIGITS = 1e-3
"""IEC 61966-2-1 prints the sRGB -> XYZ matrix to 4 decimals: taking our RGB (from the exact inverse) back
through it moves luminance and chromaticity coordinates by ~1e-4 relative (measured 6e-5 on Preetham skies),
1e-3 with margin."""

KASTEN_PLANE_PARALLEL = 0.005
"""Kasten's (1966) air mass times cos(zenith) against the plane-parallel atmosphere's 1, up to 60
degrees from the zenith: the curvature term makes it 0.9964 at 60 degrees."""

CATALOG_FORM_FACTOR = 1e-4
"""Howell's catalog quotes view factors to 5 decimals (0.19982, 0.20004): our closed forms must
agree within 1e-4."""

SPA_TOL_DEG = 0.02
"""The NOAA solar algorithm claims ~0.0167 deg over 1800-2100; the SPA example is a published value
to 1e-5 deg."""

ISSUE_TOL_DEG = 0.1
"""The issue's requirement for solar angles' agreement with an independent implementation."""

DECLINATION_DEG = 0.01
"""Solar declination at a solstice or equinox given to the minute: the published obliquity is
23.436 deg and the declination changes by < 0.0003 deg per minute near the equinox."""

NOON_AZIMUTH_DEG = 1.0
"""Azimuth of the sun at the minute of least zenith angle: one-minute steps move the sun by
~0.25 deg."""

LUMINANCE_WEIGHTS = 0.02
"""Relative gap between sRGB luminance weights applied to our RGB and Preetham's CIE Y: 2 %."""

ACES_WHITE = 0.01
"""The fitted ACES tone curve approaches 1 for bright input: within 0.01 of it at 20 x exposure."""

# -- accuracy figures: sky_visibility and daylight ---------------------------------------------

SKY_PATCH_INTEGRATION = 0.01
"""Relative error of integrating a smooth sky over 256 patches (patch-mean radiance x patch-mean
cosine)."""

SKY_PATCH_STRATIFICATION = 5e-3
"""Irradiance of an open plane under a uniform sky from 16 stratified samples per patch: each
patch's mean cosine is off by at most dz / 8, and the errors average out over 256 patches."""

PEREZ_PATCH_AVERAGING = 0.03
"""Patch averaging of the Perez sky, smooth but peaked around the sun (circumsolar): a few percent
of the diffuse horizontal irradiance."""

PEREZ_NORMALISATION = 3e-4
"""The Perez sky is scaled to its diffuse horizontal irradiance by a 90 x 180 midpoint rule
(kernels.sky): a 200 x 400 Gauss-Legendre integral of the scaled sky gives back the DHI to the first
rule's error, measured up to 5.6e-5 relative on five skies."""

SKY_MATRIX_NORMALISATION = 1e-3
"""The annual sky matrix scales each hour's Perez sky by a 45 x 90 quadrature (sky_matrix.NORMALIZATION_GRID),
the per-hour model by a 90 x 180 one: the two horizontal integrals agree within 0.1 %."""

SPLIT_FACE_EXPOSURE = 0.02
"""Mean sky exposure of a floor under a wall, split into faces of 1e-3 diagonal^2 and traced with 4
samples per patch of 256, against the mean of 2048 points at 4096 rays each: the patch discretization
and sampling leave ~1 % (measured 0.1108 against 0.1107; unsplit 0.1003)."""

EXPOSURE_COMPARISON_SLACK = 0.01
"""Relative slack when one exposure estimate must come closer to the reference than another: the
4-samples-per-patch noise of a floor's mean exposure, so that equal estimates do not fail by chance."""

SUN_PENUMBRA_SHARE = 1e-2
"""Share of a face inside the 0.53 deg sun's penumbra band behind a roof edge (~1 % of its area),
added to the Monte Carlo tolerance of sun visibility."""

SKY_VISIBILITY_RMS = 0.02
"""The issue's accuracy figure: area-weighted relative RMS of sky exposure at default settings
against a 4096-ray brute-force reference, on the window room."""

# -- accuracy figures: ambient_occlusion and instance_ao ---------------------------------------

AO_ISSUE_RELATIVE = 0.01
"""The issue asks for AO within 1 % of closed forms; the Monte Carlo tolerance must be tighter."""

AO_RMS_FIGURE = 0.02
"""The issue's figure: RMS AO difference of instance_ao from ambient_occlusion with 8-bit
4225 x 32x32 displacement fields."""

SYNTHETIC_RMS = 0.03
"""instance_ao on small synthetic scenes at 1089 x 16x16 fields (kept cheap for the default test
run); measured 0.019."""

RAY_MISMATCH = 0.06
"""Rays aimed at a dumbbell, 1089 x 16x16 nearest lookups that disagree with exact casts (rays
within a cell of a silhouette); measured 0.050."""

INSIDE_RMS = 0.05
"""Receiver points inside an instance's bounding sphere, 4225 x 32x32 fields: measured 0.038 (0.077
at 1089 x 16x16, 0.028 at 16641 x 32x32): the first-hit-only lookup behind the origin converges
slowly."""

SHARED_FIELD_RMS = 0.01
"""instance_ao on a floor through one field shared by a prototype and its turned and noisy copies, against
fields built for each copy (1089 x 16x16, 256 rays): the turned copy's own field samples the shape on
a grid turned against the shared one, so rays near silhouettes flip; measured 0.0052 RMS (0.039 max)."""

INSTANCE_MEAN_TOL = 0.01
"""Per-instance mean AO (self occlusion traced, mutual occlusion through 1089 x 16x16 fields)
against the exact AO at the same points (other rays: the exact run sees the instances as
receivers); measured <= 0.0013."""

AO_RMS_BOUND = 0.05
"""Benchmark AO (in [0, 1]) at the default 256 rays against a 16x-ray reference: the Monte Carlo
standard error of one vertex is at most 0.5 / sqrt(256) = 0.031 (Bernoulli visibility), so an RMS
above 0.05 means the estimator is biased, not noisy (measured 0.006)."""

# -- accuracy figures: radiosity and form_factors ----------------------------------------------

DIRECT_TOLERANCE = 0.01
"""Relative error of stratified light sampling with 1024 samples on smooth unoccluded integrands."""

DISTANT_CONE = 1e-3
"""Relative error of 1024 stratified samples of a distant light's 10 deg cone: the cosine varies by
0.4 % across it."""

BAKED_UNIFORM_SKY = 0.1
"""Irradiance read back from a small bake (64 capture rays per probe and grid vertex, 64 dome samples per
radiosity vertex) under a uniform dome against the exact pi L of an unoccluded upward face: stratified
Monte Carlo noise of 64 rays plus the L2 truncation of the probes (< 1 %); measured 0.6 to 3.8 %."""

GRID_BOUNCE_SHARE = 0.2
"""An irradiance grid with k bounces, its mean indirect light on the walls of a closed lit room as a share
of a k-bounce path tracer's, against the same share at one bounce: each pass reflects light read from
the previous grid, which carries the grid's own shortfall along (measured 0.90 at 2 bounces and 0.84 at
3; on the Cornell box 0.97 and 0.94). A bounce term off by a factor of 2 or pi would leave this band."""

SUN_TABLE_BLEND = 0.03
"""Relative difference of the sunlight on a plane beside a 0.5 m wall, the sun's visibility blended
bilinearly from a 4 x 3.75 degree grid of declination and hour angle, against 256 shadow rays per face
toward the exact sun. Measured over 200 random daytime hours of a year: above 15 degrees of altitude
median 0.17 %, 90th percentile 0.7 %, max 2.2 % (the shadow's length is convex in the altitude, and
blending across the moment its edge reaches the plane's edge); below 15 degrees up to 10 %."""

RADIOSITY_PATH_TRACED = 0.15
"""Relative RMS of radiosity's vertex indirect light (300 patches, 256 form-factor rays) against a
2048-path tracer; the benchmark reports finer settings."""

CLOSED_BOX_ESCAPES = 1e-3
"""Share of a patch's form-factor rays that may escape a closed box (through its shared edges):
rows sum to 1 above this (measured: exactly 1)."""

RECIPROCITY_FACE_SUMS = 0.03
"""Reciprocity A_i F_ij = A_j F_ji of face-to-face sums of form factors in a box at 4096 rays: Monte
Carlo noise of the sums, relative."""

RECIPROCITY_FLOOR = 1e-4
"""Absolute floor of the reciprocity check for face pairs that exchange (almost) nothing."""

BOUNCE_ENERGY = 0.03
"""Indirect power of a closed box after k bounces against P0 (rho + ... + rho^k), relative: Monte
Carlo noise of the 4096-ray form factors."""

RELIGHT_TOLERANCE = 0.03
"""Relative RMS of compressed vs dense indirect light on a small, noisy (256-ray) box: BC1
per-entry errors of ~10 % average out over the ~1000 columns of a row; the benchmark reports the
figure."""

# -- preview -----------------------------------------------------------------------------------

PIXEL_TOLERANCE = 1.0
"""A projected point and the centroid of the pixels a small quad covers agree within one pixel: the
centroid of a 3 x 3-ish pixel blob is quantized to pixel centres."""

EDGE_BAND = 0.02
"""Stage units either side of the shared edge where a float32 ray may land on either face."""

FRAME_EDGE_PX = 1e-6
"""Pixels: corners the auto camera frames exactly at the image border project onto it up to
float64 rounding of the projection (coordinates up to 800 px, boxes 1e-2 to 50 units)."""

CONTRAST_MARGIN = 0.1
"""Linear luminance gap between AO ~0.9 and AO ~0.2 pixels: through ACES at EV 0 (albedo 0.8) it is
~0.4, through viridis ~0.35; 0.1 still fails any renderer that swapped or flattened the two."""

INSTANCE_MEAN_AO = 0.02
"""Per-instance mean AO (in [0, 1]) of 256-ray vertex AO against the flattened twin's: a mean over
~48 vertices has a sampling error of about 0.031 / sqrt(48) = 0.005, so 0.02 is four standard errors."""

INSTANCE_VERTEX_AO = 0.1
"""One vertex's 256-ray AO against the same vertex of the flattened twin (sorted, so matched by rank):
two independent estimates differ by at most ~3 x sqrt(2) x 0.031 = 0.13 at worst; 0.1 holds for the
ranks of 24 vertices whose visibility is far from 1/2 (measured max 0.04)."""

TREGENZA_PATCH_INTEGRATION = 0.02
"""Relative error of the horizontal integral of one hour's Perez sky over the 145 Tregenza patches as
sum of patch-mean radiance x patch-mean cosine x solid angle (the product of means stands for the mean of
the product over 12-degree bands): measured up to 1.0% on the Greensboro TMY3 hours."""

# -- photometry: luminous efficacy of daylight ------------------------------------------------------

EFFICACY_NOMINAL = 0.05
"""Relative gap between the Greensboro TMY3 file's own median efficacies (its illuminance over its
irradiance, daylight hours over 50 W/m^2) and the 100 lm/W beam and 120 lm/W diffuse issue 29 quotes:
measured 100.0 and 116.6 lm/W (0 % and -2.8 %)."""

EFFICACY_FILE_CONVENTION = 0.01
"""Our Perez efficacies with the precipitable-water term off (W = 0, which is how the NSRDB computed the
Greensboro file's illuminance columns) over the file's illuminance / irradiance, per hour: median
measured 0.9996 beam (10th-90th percentile 0.997-1.002: the file rounds illuminance to 100 lux) and
1.0075 diffuse (the file takes diffuse as global efficacy, eqn 6, minus the beam; we use eqn 7)."""

EFFICACY_MEDIAN_MATCH = 0.05
"""Our median efficacy against the file's median over the same hours, in the file's convention (W = 0):
measured -0.1 % beam (99.9 against 100.0 lm/W), +2.1 % diffuse (119.1 against 116.6); 5 % is the
issue's bound."""

EFFICACY_PRECIPITABLE_WATER = 0.12
"""Our efficacies with each hour's dew point (gendaymtx -O0) against the file's, which leave out the b W
term (W 0.3-6 cm at Greensboro, |b| up to 5.8 lm/W per cm): medians measured -6.5 % beam (93.5 against
100.0 lm/W) and +10.2 % diffuse (128.5 against 116.6), median per-hour ratios 0.956 and 1.072."""

PEREZ_EFFICACY_ANNUAL = 0.05
"""Mean global horizontal illuminance of a year (Greensboro TMY3, every hour) from the Perez efficacies with
gendaymtx's default 11 degC dew point (as from a .wea file) against the file's own illuminance columns:
measured +1.8 % (the two models differ hour by hour, by the precipitable-water term, see above)."""

# -- glazing ---------------------------------------------------------------------------------------

RADIANCE_GLASS_DIGITS = 1e-7
"""Relative difference of the glass falloff (processors.daylight.glazing) from Radiance's transmissivity
formula as glass.c prints it, with its 10-digit constants: their rounding (~5e-11) is divided by the
formula's small denominator 0.0036 Tn after a cancellation; measured 3.4e-8 at Tn = 0.6 (and 5e-6 at
Tn = 0.05, which the tests do not compare)."""

GRID_WALL_OFFSET = 0.08
"""The grid read on the walls is the light 0.25 to 0.75 cells inside the box (the first vertex layer in front of
the wall), which near a concave edge also holds the light falling on the strip of side wall the read point has
behind it: measured +9% of the mean one-bounce light with 10 cells over the 2 m box, +5% with 14 (first order
in the cell size; brute-force E at the wall agrees with the analytic mean to 0.1%). Bounds each partial sum
from above and below; a double-counted pass adds 100% of a bounce, a pass that reads outside vertices loses
30% (the old read) or gains far more (a sky-lit outside)."""

GRID_LIMIT_SHARE = 0.10
"""Five bounces of albedo 0.5 carry 1 - 0.5^6 = 98.4% of the converged light; the issue asks for 10%."""

INTEGRATING_SPHERE = 0.05
"""Area-averaged irradiance inside a unit box with a 0.2 x 0.2 skylight after 10 bounces against the
integrating-sphere value E_dir / (1 - rho (1 - f)) (issue 29's 5%; a box mixes light less evenly than a
sphere): measured 0.999 of it at rho 0.5 (64 gather rays per face)."""

# -- test references: quadratures of patch integrals ----------------------------------------------

PATCH_MIDPOINT_RULE = 1e-5
"""A 200 x 200 midpoint rule in (z, azimuth) of a sky patch's mean cosine against its closed form
(test_patch_visibility): the rule's error is O(h^2) except in the zenith cap, where r = sqrt(1 - z^2)
has an infinite slope and it converges as h^1.5; measured 4.1e-7 on Tregenza's and 64 uniform patches."""

# Daylight in the browser (issue 32)
JAVASCRIPT_PORT = 1e-6
"""stages/viewer/sky.js against the kernels it ports, both float64: measured 4e-14 where Python stays float64
and 6-8e-8 where Python rounds its result to float32 (sky weights, sun patch weights, ground radiance)."""
JAVASCRIPT_PORT_ABSOLUTE = 1e-9
"""The same, as a share of the largest value compared: patches near the horizon and below it hold values far
smaller than the sky's brightest, where a relative bound alone says nothing."""
BROWSER_FLOAT32 = 1e-4
"""The viewer's relight shader against numpy relighting the same decoded stream: float32 sums over 256
patches in another order, plus the browser's V + D stored as one float32 sum; measured 2e-6 to 4e-7."""
INDIRECT_CODE_RELIGHT = 0.01
"""A lit face's irradiance relit from the stream (D through its 8-bit square-root codes) against the library
with float32 D: measured worst 0.75 % over a year of skies on a skylit box, 0.77 % on a 112k-face room."""
