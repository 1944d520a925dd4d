"""processors.instancing.field_kernels on its own, without the processors that build and read fields:

- the codes of ``encode_field`` (uint8 and bit1) against a plain loop over the rays, edge distances included;
- the atlas layout tile by tile and its exact inverse;
- the Warp layout and lookup functions from kernels of this file: positional samples against the float64
  twin of the octahedral grid, texel directions against the concentric map's height, nearest cells and
  bilinear corners against their definitions, code_hits at its bounds;
- ``field_visibility`` on synthetic fields with closed-form answers: a uniform field seen through a scaled,
  moved instance (the occluder's world distance), and a field with one hit texel found by the ray built
  from that texel's own sample and direction (the layout's inverse);
- ``FieldSet``'s packing of several fields.

End-to-end AO through real fields is tested in test_instance_ao.py and test_displacement_fields.py.
"""

from __future__ import annotations

import numpy as np
import pytest
import warp as wp
from kernel_twins import concentric_disk_np, grid_cell_centers_np
from tolerances import FLOAT32_STORAGE, FLOAT32_WARP_MAPS
from usdbake.processors.instancing import field_kernels as fk
from usdbake.processors.instancing.products import DisplacementField

wp.set_module_options({"enable_backward": False})


# -- codes and atlas ------------------------------------------------------------------------------


def test_encode_field_codes_against_a_plain_loop():
    rng = np.random.default_rng(4)  # fixed seed
    distances = rng.uniform(0, 1.4, (6, 8, 8)).astype(np.float32)
    distances[0] = 2.0  # a sample that sees nothing
    distances[1, 0, :4] = [0.0, 1.0, np.nextafter(np.float32(1.0), np.float32(2.0)), 1.5]  # edges
    codes, means = fk.encode_field(distances, "uint8")
    bits, bit_means = fk.encode_field(distances, "bit1")
    assert codes.dtype == bits.dtype == means.dtype == np.uint8
    assert codes.shape == (6, 8, 8) and bits.shape == (6, 8)
    np.testing.assert_array_equal(means, bit_means)
    for k in range(6):
        hits = []
        for b in range(8):
            for a in range(8):
                t = float(distances[k, b, a])
                expected = int(np.floor(t * 254 + 0.5)) if t <= 1.0 else 255
                assert codes[k, b, a] == expected, (k, b, a, t)
                texel = 8 * b + a
                assert (bits[k, texel // 8] >> (texel % 8)) & 1 == (t <= 1.0)
                if t <= 1.0:
                    hits.append(t)
        expected_mean = round(float(np.mean(hits)) * 254) if hits else 255
        assert abs(int(means[k]) - expected_mean) <= (0 if not hits else 1)  # round-half ties may differ
    np.testing.assert_array_equal(codes[1, 0, :4], [0, 254, 255, 255])
    assert means[0] == fk.MISS_CODE
    with pytest.raises(ValueError, match="unknown encoding 'bit8'"):
        fk.encode_field(distances, "bit8")


def make_field(side, map_size, encoding, texels, means, **kwargs):
    return DisplacementField(prototype="/P", center=kwargs.pop("center", np.zeros(3)), radius=kwargs.pop("radius", 1.0),
                             side=side, map_size=map_size, encoding=encoding, texels=texels, mean_codes=means, **kwargs)


@pytest.mark.parametrize("encoding", ["uint8", "bit1"])
def test_atlas_tiles_sit_where_the_layout_says_and_come_back_exactly(encoding):
    rng = np.random.default_rng(9)  # fixed seed
    n, m = 3, 16
    if encoding == "uint8":
        texels = rng.integers(0, 256, (n * n, m, m)).astype(np.uint8)
    else:
        texels = rng.integers(0, 256, (n * n, m * m // 8)).astype(np.uint8)
    means = rng.integers(0, 256, n * n).astype(np.uint8)
    atlas = fk.field_atlas(make_field(n, m, encoding, texels, means))
    if encoding == "uint8":
        assert atlas.shape == (n * m, n * m)
        for k in range(n * n):
            row, col = divmod(k, n)
            np.testing.assert_array_equal(atlas[row * m:(row + 1) * m, col * m:(col + 1) * m], texels[k])
    else:
        w = m // 8
        assert atlas.shape == (n * m + n, n * w)
        for k in range(n * n):
            row, col = divmod(k, n)
            np.testing.assert_array_equal(atlas[row * m:(row + 1) * m, col * w:(col + 1) * w].ravel(), texels[k])
        np.testing.assert_array_equal(atlas[n * m:, :n].ravel(), means)
    back, back_means = fk.field_from_atlas(np.dstack([atlas] * 3), side=n, map_size=m, encoding=encoding)  # RGB image
    np.testing.assert_array_equal(back, texels)
    np.testing.assert_array_equal(back_means, means if encoding == "bit1" else np.zeros(0))


# -- Warp layout functions ------------------------------------------------------------------------


@wp.kernel
def layout_kernel(side: int, map_size: int, samples: wp.array(dtype=wp.vec3), texel_z: wp.array(dtype=float)):
    k = wp.tid()
    s = fk.positional_sample(k, side)
    samples[k] = s
    frame = fk.tangent_frame(-s)
    for b in range(map_size):
        for a in range(map_size):
            texel_z[(k * map_size + b) * map_size + a] = wp.dot(fk.texel_direction(frame, a, b, map_size), -s)


def test_positional_samples_and_texel_directions_follow_the_layout():
    side, m = 5, 4
    samples = wp.zeros(side * side, dtype=wp.vec3)
    z = wp.zeros(side * side * m * m, dtype=float)
    wp.launch(layout_kernel, side * side, [side, m, samples, z])
    np.testing.assert_allclose(samples.numpy(), grid_cell_centers_np(side), atol=FLOAT32_WARP_MAPS)
    # Texel (a, b): the cosine-weighted map at the texel centre, z = sqrt(1 - r^2) of its concentric disk point.
    centres = (np.arange(m) + 0.5) / m
    u, v = np.meshgrid(centres, centres)  # u along columns (a), v along rows (b)
    disk = concentric_disk_np(u.ravel(), v.ravel())
    expected = np.sqrt(1 - (disk ** 2).sum(axis=1))
    np.testing.assert_allclose(z.numpy().reshape(side * side, m * m), np.tile(expected, (side * side, 1)),
                               atol=FLOAT32_WARP_MAPS)


@wp.kernel
def cell_kernel(us: wp.array(dtype=wp.vec2), n: int, nearest: wp.array(dtype=int), corners: wp.array(dtype=wp.vec3)):
    i = wp.tid()
    nearest[i] = fk.nearest_cell(us[i][0], n)
    for c in range(4):
        a, b, w = fk.bilinear_corner(us[i], n, c)
        corners[4 * i + c] = wp.vec3(float(a), float(b), w)


def test_nearest_cell_and_bilinear_corners_against_their_definitions():
    n = 4
    rng = np.random.default_rng(12)  # fixed seed
    uv = np.vstack([[[0.0, 0.0], [1.0, 1.0], [0.5, 0.125], [0.25 - 1e-7, 0.999]], rng.uniform(0, 1, (200, 2))])
    nearest = wp.zeros(len(uv), dtype=int)
    corners = wp.zeros(4 * len(uv), dtype=wp.vec3)
    wp.launch(cell_kernel, len(uv), [wp.array(uv.astype(np.float32), dtype=wp.vec2), n, nearest, corners])
    expected = np.minimum(np.floor(uv[:, 0].astype(np.float32).astype(np.float64) * n), n - 1).astype(int)
    np.testing.assert_array_equal(nearest.numpy(), expected)
    assert nearest.numpy()[:4].tolist() == [0, 3, 2, 0]
    c = corners.numpy().reshape(-1, 4, 3).astype(np.float64)
    col, row, w = c[..., 0], c[..., 1], c[..., 2]
    np.testing.assert_allclose(w.sum(axis=1), 1.0, atol=FLOAT32_STORAGE)
    assert (w >= -FLOAT32_STORAGE).all()
    # Column step first, then row; the four are the cells around uv, which their centres reproduce (bilinear
    # weights interpolate linear functions exactly).
    np.testing.assert_array_equal(col[:, 1] - col[:, 0], 1)
    np.testing.assert_array_equal(row[:, 2] - row[:, 0], 1)
    np.testing.assert_allclose((w * (col + 0.5) / n).sum(axis=1), uv[:, 0], atol=FLOAT32_STORAGE)
    np.testing.assert_allclose((w * (row + 0.5) / n).sum(axis=1), uv[:, 1], atol=FLOAT32_STORAGE)
    assert col.min() == -1 and col.max() == n  # one step outside at the borders, for the caller to handle


@wp.kernel
def code_hits_kernel(codes: wp.array(dtype=int), t_entry: wp.array(dtype=float), max_distance: float,
                     out: wp.array(dtype=float)):
    i = wp.tid()
    out[i] = fk.code_hits(codes[i], t_entry[i], 0.5, 4.0, max_distance)


def test_code_hits_bounds():
    # diameter 4 prototype units at scale 0.5: a code is t_entry + code / 254 * 2 world units; one step 2/254.
    step = 2.0 / 254
    cases = [(255, 0.0, 0.0), (0, 1.0, 1.0), (254, 1.0, 1.0), (254, 1.01, 0.0), (127, 2.0, 1.0),
             (0, -0.5 * step, 1.0), (0, -2 * step, 0.0)]
    codes, entries, expected = (np.array(x) for x in zip(*cases))
    out = wp.zeros(len(cases), dtype=float)
    wp.launch(code_hits_kernel, len(cases), [wp.array(codes.astype(np.int32), dtype=int),
                                             wp.array(entries.astype(np.float32), dtype=float), 3.0, out])
    np.testing.assert_array_equal(out.numpy(), expected)


# -- field_visibility -----------------------------------------------------------------------------


@wp.kernel
def visibility_kernel(fields: fk.FieldArrays, origins: wp.array(dtype=wp.vec3), directions: wp.array(dtype=wp.vec3),
                      max_distance: wp.array(dtype=float), inverse_linear: wp.mat33, inverse_offset: wp.vec3,
                      interpolate: int, out: wp.array(dtype=float)):
    i = wp.tid()
    out[i] = fk.field_visibility(origins[i], directions[i], max_distance[i], inverse_linear, inverse_offset,
                                 fields, 0, interpolate)


def visibility(field, origins, directions, max_distance, *, scale=1.0, offset=(0, 0, 0), mode="nearest"):
    """V of rays through one instance of ``field``: world = scale * prototype + offset."""
    fs = fk.FieldSet([field], "cpu")
    n = len(origins)
    out = wp.zeros(n, dtype=float)
    inverse_linear = wp.mat33(*(np.eye(3) / scale).ravel().tolist())
    inverse_offset = wp.vec3(*(-np.asarray(offset, np.float64) / scale).tolist())
    wp.launch(visibility_kernel, n, [fs.arrays, wp.array(np.float32(origins), dtype=wp.vec3),
                                     wp.array(np.float32(directions), dtype=wp.vec3),
                                     wp.array(np.float32(np.broadcast_to(max_distance, n)), dtype=float),
                                     inverse_linear, inverse_offset, fk.INTERPOLATION_MODES[mode], out])
    return out.numpy()


def uniform_field(code, encoding, side=4, m=8):
    distances = np.full((side * side, m, m), code / 254.0, np.float32)
    texels, means = fk.encode_field(distances, encoding)
    return make_field(side, m, encoding, texels, means)


@pytest.mark.parametrize("encoding", ["uint8", "bit1"])
@pytest.mark.parametrize("mode", ["nearest", "quadrilinear"])
def test_uniform_field_through_a_scaled_moved_instance(encoding, mode):
    # Unit sphere at the prototype origin; every stored ray hits at t / 2R = 0.5 (code 127), one prototype
    # unit past the entry. The instance is scaled by 2 and moved to x = 10: the ray from the world origin
    # along +x enters at 8 and meets the stored hit at 8 + 2 * 1 = 10 world units.
    field = uniform_field(127, encoding)
    origins = np.zeros((6, 3))
    directions = np.array([[1, 0, 0]] * 4 + [[0, 1, 0], [-1, 0, 0]], np.float64)
    max_distance = np.array([10.5, 9.5, 7.9, 100.0, 100.0, 100.0])
    v = visibility(field, origins, directions, max_distance, scale=2.0, offset=(10, 0, 0), mode=mode)
    # Occluded within reach; not when the hit lies beyond max_distance, or the sphere does; rays that miss
    # the sphere (+y) or meet it behind the origin (-x) see through.
    np.testing.assert_array_equal(v, [0.0, 1.0, 1.0, 0.0, 1.0, 1.0])
    # A field of misses never occludes.
    assert (visibility(uniform_field(255, encoding), origins, directions, 100.0, scale=2.0, offset=(10, 0, 0),
                       mode=mode) == 1.0).all()


@wp.kernel
def texel_ray_kernel(side: int, map_size: int, k: int, a: int, b: int, origin: wp.array(dtype=wp.vec3),
                     direction: wp.array(dtype=wp.vec3)):
    s = fk.positional_sample(k, side)
    d = fk.texel_direction(fk.tangent_frame(-s), a, b, map_size)
    origin[0] = s - d * 0.25  # outside the unit sphere, entering it at s_k
    direction[0] = d


def test_one_hit_texel_is_found_by_its_own_sample_and_direction():
    side, m, k, a, b = 6, 8, 14, 5, 2
    distances = np.full((side * side, m, m), 2.0, np.float32)  # all misses...
    distances[k, b, a] = 0.0  # ...but texel (a, b) of sample k, a hit right at the entry point
    texels, means = fk.encode_field(distances, "uint8")
    field = make_field(side, m, "uint8", texels, means)
    rays = []
    for texel in [(a, b), (a + 1, b), (a, b - 1)]:  # the texel and two neighbours
        origin, direction = wp.zeros(1, dtype=wp.vec3), wp.zeros(1, dtype=wp.vec3)
        wp.launch(texel_ray_kernel, 1, [side, m, k, texel[0], texel[1], origin, direction])
        rays.append((origin.numpy()[0], direction.numpy()[0]))
    origins, directions = (np.array(x) for x in zip(*rays))
    np.testing.assert_array_equal(visibility(field, origins, directions, 10.0), [0.0, 1.0, 1.0])


def test_field_set_packs_several_fields():
    one = uniform_field(10, "uint8", side=2, m=8)
    two = uniform_field(20, "bit1", side=3, m=16)
    short_means = make_field(2, 8, "bit1", np.zeros((4, 8), np.uint8), np.zeros(0, np.uint8), radius=2.5,
                             center=np.array([1.0, 2.0, 3.0]))
    fs = fk.FieldSet([one, two, short_means], "cpu")
    arrays = fs.arrays
    np.testing.assert_array_equal(arrays.field_offset.numpy(), [0, 4 * 64, 4 * 64 + 9 * 32])
    np.testing.assert_array_equal(arrays.field_mean_offset.numpy(), [0, 4, 13])
    np.testing.assert_array_equal(arrays.field_bits.numpy(), [0, 1, 1])
    np.testing.assert_array_equal(arrays.field_side.numpy(), [2, 3, 2])
    np.testing.assert_array_equal(arrays.field_map_size.numpy(), [8, 16, 8])
    np.testing.assert_allclose(arrays.field_radius.numpy(), [1.0, 1.0, 2.5])
    np.testing.assert_allclose(arrays.field_center.numpy()[2], [1, 2, 3])
    texels = arrays.texels.numpy()
    assert len(texels) == 4 * 64 + 9 * 32 + 4 * 8 and (texels[:256] == 10).all()
    means = arrays.means.numpy()
    np.testing.assert_array_equal(means, [10] * 4 + [20] * 9 + [fk.MISS_CODE] * 4)  # missing means: misses
    empty = fk.FieldSet([], "cpu").arrays
    assert len(empty.field_side.numpy()) == 1 and len(empty.texels.numpy()) == 1
