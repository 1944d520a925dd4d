"""irradiance_grid: irradiance vectors against closed forms (uniform sky, a distant light, a shadow),
quantization (the paper's exactness along delta kept through 8-bit directions and RGB9E5), the
reconstruction formula, inside-geometry vertices, determinism across thread counts, degenerate
geometry, applies()/params, and an end-to-end bake through USD with its stream file."""

import math

import numpy as np
from lit_scenes import cube, make_lights, make_scene, merge, quad
from stage_builders import base_context
import pytest
from tolerances import (FLOAT32_ACCUMULATED, FLOAT32_LONG_CHAIN, FLOAT32_ROUNDING, FLOAT32_STORAGE, FLOAT64_ROUNDING,
                        GRID_BOUNCE_SHARE, MC_SIGMAS, ON_BOUNDARY)
from usdbake.processors.irradiance_grid.products import IrradianceGridProduct
from usdbake.kernels.direction24 import dequantize_vectors
from usdbake.processors.irradiance_grid import irradiance_grid as ig
from usdbake.processors.irradiance_grid.vector_grid import GridLayout, grid_bounds, grid_layout, reconstruct_irradiance
from usdbake.formats import streaming
from usdbake.core import Context, ParamError
from usdbake.kernels import direction24 as dir24
from usdbake.kernels.rgb9e5 import RELATIVE_ERROR
from usdbake.core.scene import LIGHT_DISK, LIGHT_DISTANT, LIGHT_DOME, LIGHT_SPHERE, Scene
from usdbake.kernels.tracer import Tracer


# -- scenes built without pxr -------------------------------------------------------------------












def far_speck():
    """A tiny triangle far away: a Tracer needs geometry, this one is (almost) never hit."""
    return quad([1e3, 1e3, 1e3], [1e-3, 0, 0], [0, 1e-3, 0])


def run(scene: Scene, threads: int | None = None, **params):
    tracer = Tracer.from_scene(scene, threads=threads)
    processor = ig.IrradianceGrid()
    return processor.run(Context(scene, processor.Params(**params), tracer)), tracer


# -- irradiance vectors ----------------------------------------------------------------------------


def test_uniform_sky_gives_pi_l_along_each_axis():
    """Unoccluded uniform radiance L: integral over hemisphere delta of L w dw = pi L delta."""
    dome = np.array([0.2, 0.5, 1.0])
    scene = make_scene(*far_speck(), lights=make_lights((LIGHT_DOME, dome, (0, 0, 0), (0, 0, -1), (0, 0))))
    rays = 16384
    vectors, back = ig.compute_irradiance_vectors(Tracer.from_scene(scene), scene, np.zeros((2, 3)), rays=rays,
                                                  seed=3)
    assert (back == 0).all()
    # i.i.d. std of one component of 4 pi L w 1[w.delta > 0] is at most 4 pi L / sqrt(3 N).
    tol = MC_SIGMAS * 4 * math.pi * dome.max() / math.sqrt(3 * rays)
    expected = math.pi * dome[None, :, None] * dir24.AXES[:, None, :]  # (6, 3 channels, 3)
    for v in vectors:
        np.testing.assert_allclose(v, expected, atol=tol)
    # Quantized: every direction decodes within the code's bound of its axis, and the paper's
    # guarantee M delta = c (d' . delta) = I . delta holds to RGB9E5 precision.
    directions, colors = ig.quantize_vectors(vectors)
    decoded = dequantize_vectors(directions, colors)
    along = np.einsum("vhci,hi->vhc", decoded, dir24.AXES)
    truth = np.einsum("vhci,hi->vhc", vectors, dir24.AXES)
    # RGB9E5 shares one exponent: the error bound is relative to the largest channel.
    bound = RELATIVE_ERROR * truth.max(axis=2, keepdims=True) * (1 + FLOAT32_ACCUMULATED)
    assert np.all(np.abs(along - truth) <= bound)


def test_single_distant_light_gives_vectors_along_the_light():
    """A zero-angle distant light of irradiance E from w: I_delta = E w in the three hemispheres
    containing w, zero in the others (no sampling involved: exact up to float32)."""
    w = np.array([0.48, 0.6, 0.64])
    w /= np.linalg.norm(w)
    e = np.array([3.0, 2.0, 1.0])
    scene = make_scene(*far_speck(), lights=make_lights((LIGHT_DISTANT, e, (0, 0, 0), -w, (0, 0))))
    vectors, _ = ig.compute_irradiance_vectors(Tracer.from_scene(scene), scene, np.zeros((1, 3)), rays=16)
    for h, axis in enumerate(dir24.AXES):
        expected = np.outer(e, w) if axis @ w > 0 else np.zeros((3, 3))
        np.testing.assert_allclose(vectors[0, h], expected, rtol=FLOAT32_ACCUMULATED, atol=FLOAT32_ACCUMULATED)
    directions, colors = ig.quantize_vectors(vectors)
    decoded = dequantize_vectors(directions, colors)[0]
    for h in (0, 2, 4):
        d = decoded[h].sum(axis=0)
        assert math.degrees(math.acos(min(1.0, d @ w / np.linalg.norm(d)))) <= dir24.MAX_ANGLE_ERROR_DEG
        np.testing.assert_allclose(decoded[h] @ dir24.AXES[h], e * (w @ dir24.AXES[h]),
                                   atol=RELATIVE_ERROR * e.max() * (w @ dir24.AXES[h]) * (1 + FLOAT32_ACCUMULATED))


def test_shadowed_distant_light_gives_nothing():
    w = np.array([0.0, 0.0, 1.0])
    blocker = quad([-5, -5, 1], [10, 0, 0], [0, 10, 0], flip=True)  # faces down, over the point
    scene = make_scene(*blocker, albedo=0.0, lights=make_lights((LIGHT_DISTANT, [1, 1, 1], (0, 0, 0), -w, (0, 0))))
    vectors, _ = ig.compute_irradiance_vectors(Tracer.from_scene(scene), scene, np.zeros((1, 3)), rays=64)
    np.testing.assert_array_equal(vectors, 0.0)


def test_indirect_only_drops_the_light_but_keeps_its_bounce():
    """Sun over a ground of albedo rho: with include_direct off, the +z vector vanishes and the -z
    vector holds the ground's reflected light, E(-z) = rho E_s cos(theta) (an infinite Lambertian
    plane of radiance rho E cos / pi under the point)."""
    w = np.array([0.0, 0.6, 0.8])
    ground = quad([-1e3, -1e3, 0], [2e3, 0, 0], [0, 2e3, 0])
    rho = 0.5
    scene = make_scene(*ground, albedo=rho, lights=make_lights((LIGHT_DISTANT, [2, 2, 2], (0, 0, 0), -w, (0, 0))))
    rays = 4096
    v_all, _ = ig.compute_irradiance_vectors(Tracer.from_scene(scene), scene, np.array([[0, 0, 1.0]]), rays=rays)
    v_ind, _ = ig.compute_irradiance_vectors(Tracer.from_scene(scene), scene, np.array([[0, 0, 1.0]]), rays=rays,
                                             include_direct=False)
    np.testing.assert_allclose(v_ind[0, 4], 0.0, atol=FLOAT32_ROUNDING)
    np.testing.assert_allclose(v_all[0, 4] @ [0, 0, 1], 2 * 0.8, rtol=FLOAT32_ACCUMULATED)
    radiance = rho * 2 * 0.8 / math.pi
    tol = MC_SIGMAS * 4 * math.pi * radiance / math.sqrt(3 * rays)
    np.testing.assert_allclose(-v_ind[0, 5] @ [0, 0, -1], -math.pi * radiance, atol=tol)
    np.testing.assert_allclose(v_ind[0, 5], v_all[0, 5], rtol=FLOAT32_ACCUMULATED)


# -- reconstruction ---------------------------------------------------------------------------------


def uniform_grid(radiance=1.0):
    layout = GridLayout(np.zeros(3), np.ones(3), (2, 2, 2))
    vectors = np.broadcast_to(math.pi * radiance * dir24.AXES[None, :, None, :], (8, 6, 3, 3)).copy()
    return layout, vectors


def random_normals(n, seed):
    d = np.random.default_rng(seed).normal(size=(n, 3))  # fixed seed
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def test_axis_aligned_normals_read_the_quantized_grid_exactly():
    """Paper 3.3: c = I . delta / (d' . delta) keeps I . delta through quantization, so a surface facing an
    axis reads the 42-byte grid as the float one, to RGB9E5 precision (relative to the largest channel)."""
    rng = np.random.default_rng(5)  # fixed seed: arbitrary light
    layout = GridLayout(np.zeros(3), np.ones(3), (2, 2, 2))
    w = rng.normal(size=(8, 6, 3, 3))
    axes = dir24.AXES[None, :, None, :].astype(np.float64)
    w += (np.abs(np.einsum("vhci,hi->vhc", w, dir24.AXES))[..., None] + 0.1) * axes  # into each hemisphere
    vectors = (w * rng.random((8, 6, 3, 1)) * 10).astype(np.float32)
    decoded = dequantize_vectors(*ig.quantize_vectors(vectors))
    points = rng.random((200, 3))
    normals = dir24.AXES[rng.integers(0, 6, len(points))]
    exact = reconstruct_irradiance(layout, vectors, points, normals, normal_offset=0.0)
    quantized = reconstruct_irradiance(layout, decoded, points, normals, normal_offset=0.0)
    bound = RELATIVE_ERROR * np.abs(vectors).max() * np.sqrt(3) * (1 + FLOAT32_ACCUMULATED)
    assert np.abs(quantized - exact).max() <= bound
    off_axis = reconstruct_irradiance(layout, decoded, points, random_normals(len(points), 6), normal_offset=0.0)
    assert np.isfinite(off_axis).all()


def test_paper_reconstruction_closed_form_for_a_uniform_sky():
    """Paper 3.2: I_n = sum_a I_a n_a^2, E = I_n . n; with I_a = pi L delta_a, E = pi L sum |n_a|^3:
    exact along the axes, pi L / sqrt(3) on the diagonals."""
    layout, vectors = uniform_grid()
    n = random_normals(500, 1)
    points = np.random.default_rng(2).random((500, 3))
    e = reconstruct_irradiance(layout, vectors, points, n, normal_offset=0.0)
    np.testing.assert_allclose(e, np.repeat((math.pi * (np.abs(n) ** 3).sum(axis=1))[:, None], 3, 1),
                               rtol=FLOAT32_ACCUMULATED)
    axes = reconstruct_irradiance(layout, vectors, np.full((6, 3), 0.5), dir24.AXES, normal_offset=0.0)
    np.testing.assert_allclose(axes, math.pi, rtol=FLOAT32_ACCUMULATED)
    normalized = reconstruct_irradiance(layout, vectors, points, n, normal_offset=0.0, reconstruction="normalized")
    np.testing.assert_allclose(normalized, math.pi, rtol=FLOAT32_ACCUMULATED)


def test_reconstruction_is_trilinear_and_zero_normals_give_zero():
    layout = GridLayout(np.zeros(3), np.full(3, 2.0), (2, 2, 2))
    coords = streaming.grid_coords(layout.resolution).astype(np.float64)
    value = 1.0 + coords @ [1.0, 2.0, 3.0]  # linear in the vertex coordinates
    vectors = np.zeros((8, 6, 3, 3))
    vectors[:, 4, :, 2] = value[:, None]  # +z hemisphere, along +z
    points = np.random.default_rng(3).random((50, 3)) * 2.0
    e = reconstruct_irradiance(layout, vectors, points, np.tile([0, 0, 1.0], (50, 1)), normal_offset=0.0)
    np.testing.assert_allclose(e[:, 0], 1.0 + points / 2.0 @ [1.0, 2.0, 3.0], rtol=FLOAT32_ACCUMULATED)
    zero = reconstruct_irradiance(layout, vectors, points[:2], np.array([[0, 0, 0], [np.nan, 0, 0]]))
    np.testing.assert_array_equal(zero, 0.0)
    with pytest.raises(ValueError):
        reconstruct_irradiance(layout, vectors, points, points, reconstruction="bogus")


def test_sunlit_ground_end_to_end_matches_the_closed_form():
    """A ground plane (z = 0) under a zero-angle sun of irradiance E_s from w: the grid's +z vectors
    above the ground hold E_s w, so the ground reads E = E_s cos(theta) (RGB9E5 precision)."""
    w = np.array([0.3, 0.0, 0.9539392])
    ground_p, ground_t = quad([-2, -2, 0], [4, 0, 0], [0, 4, 0])
    scene = make_scene(ground_p, ground_t, albedo=0.3,
                       lights=make_lights((LIGHT_DISTANT, [4, 4, 4], (0, 0, 0), -w, (0, 0))))
    result, _ = run(scene, vertices=200, rays=16)
    grid = result.products[IrradianceGridProduct]
    assert grid.vertex_valid.all()
    (primvar,) = [r for r in result.outputs if getattr(r, "name", "") == "bake:irradianceGrid"]
    assert primvar.interpolation == "vertex" and primvar.type_name == "color3f"
    np.testing.assert_allclose(primvar.values, 4 * w[2], rtol=RELATIVE_ERROR * (1 + FLOAT32_ACCUMULATED))


# -- grid, inside geometry, determinism, degenerate input ------------------------------------------


def test_grid_layout_bounds_and_target_count():
    layout = grid_layout(np.array([0, 0, 0.0]), np.array([10, 5, 2.0]), vertices=20000)
    assert 10000 <= layout.count <= 20000
    lo = layout.grid_origin
    hi = lo + (np.asarray(layout.resolution) - 1) * layout.cell_size
    h = layout.cell_size[0]
    # Outer vertices lie between h/4 and 3h/4 outside the bounds.
    assert np.all(-lo >= h / 4 - ON_BOUNDARY) and np.all(-lo <= 3 * h / 4 + ON_BOUNDARY)
    assert np.all(hi - [10, 5, 2] >= h / 4 - ON_BOUNDARY)
    fixed = grid_layout(np.zeros(3), np.ones(3), cell_size=0.25)
    assert fixed.resolution == (6, 6, 6)
    flat = grid_layout(np.zeros(3), np.array([1.0, 1.0, 0.0]), vertices=100)
    assert flat.resolution[2] == 2 and flat.count <= 100
    with pytest.raises(ValueError, match="cell_size"):
        grid_layout(np.zeros(3), np.full(3, 1e4), cell_size=1e-3)


def test_vertices_inside_closed_geometry_are_flagged_and_filled():
    room = cube([-3, -3, -3], [3, 3, 3], inward=True)
    block = cube([-1, -1, -1], [1, 1, 1])  # closed, faces outward
    points, tris = merge([room, block])
    scene = make_scene(points, tris, albedo=0.5,
                       lights=make_lights((LIGHT_SPHERE, [50, 50, 50], (2, 2, 2), (0, 0, -1), (0.2, 0))))
    result, _ = run(scene, cell_size=0.5, rays=64)
    grid = result.products[IrradianceGridProduct]
    positions = grid.layout.positions()
    inside_block = (np.abs(positions) < 0.99).all(axis=1)
    outside_room = (np.abs(positions) > 3.01).any(axis=1)
    free = ~inside_block & ~outside_room & ((np.abs(np.abs(positions) - 1) > 0.01).any(axis=1))
    assert not grid.vertex_valid[inside_block].any()
    # Outside the inward-facing room, fewer than half of the rays meet its back faces: valid (and dark).
    assert grid.vertex_valid[outside_room].mean() > 0.9
    assert grid.vertex_valid[free & (np.abs(positions) > 1.01).any(axis=1) & (np.abs(positions) < 2.99).all(axis=1)
                             ].all()
    decoded = dequantize_vectors(grid.directions, grid.colors)
    assert np.isfinite(decoded).all()
    # Filled vertices lie within the range of the computed ones (push-pull is a convex fill).
    valid = decoded[grid.vertex_valid]
    assert decoded.max() <= valid.max() * (1 + 2 * RELATIVE_ERROR) + FLOAT32_STORAGE
    assert any("inside geometry" in m for m in result.messages)


def test_determinism_across_thread_counts():
    """Over 2 * MIN_CHUNK vertices so the launch is really split across threads."""
    room = cube([-3, -3, -3], [3, 3, 3], inward=True)
    scene = make_scene(*room, lights=make_lights((LIGHT_SPHERE, [20, 20, 20], (1, 1, 1), (0, 0, -1), (0.2, 0))))
    one, _ = run(scene, threads=1, vertices=12000, rays=4)
    two, _ = run(scene, threads=2, vertices=12000, rays=4)
    a, b = one.products[IrradianceGridProduct], two.products[IrradianceGridProduct]
    assert a.layout.count > 8192
    np.testing.assert_array_equal(a.directions, b.directions)
    np.testing.assert_array_equal(a.colors, b.colors)


def test_degenerate_geometry_gives_finite_outputs():
    """Zero-area and collinear triangles, a huge-coordinate offset, one flat triangle."""
    points = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [2, 2, 2], [2, 2, 2], [2, 2, 2], [0, 0, 0], [1, 1, 1],
                       [2, 2, 2]], np.float32) + 1e6
    tris = np.array([[0, 1, 2], [3, 4, 5], [6, 7, 8]], np.int32)
    scene = make_scene(points - 1e6, tris, emission=np.array([[1, 1, 1], [5, 5, 5], [0, 0, 0]], np.float32),
                       lights=make_lights((LIGHT_DOME, [1, 1, 1], (0, 0, 0), (0, 0, -1), (0, 0))))
    result, _ = run(scene, vertices=64, rays=16)
    for record in result.outputs:
        values = getattr(record, "values", getattr(record, "value", None))
        if isinstance(values, np.ndarray) and values.dtype.kind == "f":
            assert np.isfinite(values).all(), record.name
    grid = result.products[IrradianceGridProduct]
    assert np.isfinite(dequantize_vectors(grid.directions, grid.colors)).all()


def test_applies_and_params():
    points, tris = quad([0, 0, 0], [1, 0, 0], [0, 1, 0])
    ok, reason = ig.IrradianceGrid().applies(base_context(make_scene(points, tris)))
    assert not ok and "no lights" in reason
    dark = make_scene(points, tris, lights=make_lights((LIGHT_DOME, [0, 0, 0], (0, 0, 0), (0, 0, -1), (0, 0))))
    assert not ig.IrradianceGrid().applies(base_context(dark))[0]
    emissive = make_scene(points, tris, emission=np.ones((2, 3), np.float32))
    assert ig.IrradianceGrid().applies(base_context(emissive))[0]
    for bad in ({"rays": 0}, {"vertices": 2}, {"cell_size": -1.0}, {"normal_offset": -0.1},
                {"reconstruction": "cubic"}):
        with pytest.raises(ParamError):
            ig.IrradianceGrid.Params(**bad)


# -- end to end through USD ------------------------------------------------------------------------


def test_end_to_end_small_stage(tmp_path):
    from lit_scenes import lamp_room_file
    from pxr import Usd
    from usdbake.cli.main import main
    from usdbake.preview.compose import grid_spheres

    source = lamp_room_file(tmp_path)
    out = tmp_path / "room_grid.usdc"
    code = main(["bake", str(source), "-o", str(out), "-p", "irradiance_grid", "--cache", str(tmp_path / "cache"),
                 "--set", "irradiance_grid.vertices=400", "--set", "irradiance_grid.rays=16"])
    assert code == 0
    baked = Usd.Stage.Open(str(out))
    prim = baked.GetPrimAtPath(ig.GRID_PRIM)
    assert prim and prim.GetTypeName() == "IrradianceVectorGrid"
    get = lambda name: prim.GetAttribute(name).Get()
    resolution = tuple(get("resolution"))
    count = int(np.prod(resolution))
    assert 8 < count <= 400 and get("vectorsPerVertex") == 6
    assert len(get("directions")) == 6 * 3 * count and len(get("colorsRGB9E5")) == 6 * count  # 42 bytes a vertex
    valid = np.asarray(get("bake:vertexValid"), bool)
    # The stream file: the valid vertices in progressive order, same codes as the prim's arrays.
    stream_path = tmp_path / get("streamFile").path
    stream = streaming.decode_stream(stream_path.read_bytes())
    assert stream.resolution == resolution and len(stream.vertex_index) == valid.sum()
    order = streaming.progressive_order(resolution)
    np.testing.assert_array_equal(stream.vertex_index, order[valid[order]])
    np.testing.assert_array_equal(stream.colors.ravel(),
                                  np.asarray(get("colorsRGB9E5")).reshape(-1, 6)[stream.vertex_index].ravel())
    np.testing.assert_array_equal(stream.directions,
                                  np.asarray(get("directions")).reshape(-1, 6, 3)[stream.vertex_index])
    np.testing.assert_allclose(stream.grid_origin, np.asarray(get("gridOrigin")), rtol=FLOAT32_STORAGE)
    # The mesh primvar and the preview's reading of the grid.
    primvar = baked.GetPrimAtPath("/World/Room").GetAttribute("primvars:bake:irradianceGrid")
    values = np.asarray(primvar.Get())
    room_points = baked.GetPrimAtPath("/World/Room").GetAttribute("points").Get()
    assert values.shape == (len(room_points), 3) and np.isfinite(values).all() and values.max() > 0
    from usdbake.stages.extract import extract_scene

    scene = extract_scene(baked)
    spheres = grid_spheres(baked, scene, None)  # centres in the scene frame (relative to scene.origin)
    assert spheres is not None and len(spheres.centers) == count
    np.testing.assert_allclose(spheres.centers.min(axis=0) + scene.origin, np.asarray(get("gridOrigin")),
                               atol=FLOAT32_LONG_CHAIN)


def test_emissive_geometry_is_seen_only_without_usdlux_lights():
    """An emissive ceiling (radiance 1, a 2 km square 1 m up, facing down) over the point: with no
    UsdLux light the +z vector is ~ pi L z (the ceiling fills the upper hemisphere up to a ~0.1%
    sliver); with a UsdLux light in the stage the ceiling's emission is not counted again (a lamp
    modelled as both would count twice), only the light itself."""
    ceiling = quad([-1e3, -1e3, 1], [2e3, 0, 0], [0, 2e3, 0], flip=True)
    emission = np.ones((2, 3), np.float32)
    rays = 4096
    tol = MC_SIGMAS * 4 * math.pi / math.sqrt(3 * rays)
    alone = make_scene(*ceiling, albedo=0.0, emission=emission)
    vectors, _ = ig.compute_irradiance_vectors(Tracer.from_scene(alone), alone, np.zeros((1, 3)), rays=rays)
    np.testing.assert_allclose(vectors[0, 4], math.pi * np.tile([0, 0, 1.0], (3, 1)), atol=tol)
    np.testing.assert_allclose(vectors[0, 5], 0.0, atol=FLOAT32_ROUNDING)
    lit = make_scene(*ceiling, albedo=0.0, emission=emission,
                     lights=make_lights((LIGHT_DISTANT, [1, 1, 1], (0, 0, 0), (0, 0, 1), (0, 0))))
    vectors, _ = ig.compute_irradiance_vectors(Tracer.from_scene(lit), lit, np.zeros((1, 3)), rays=rays)
    np.testing.assert_allclose(vectors[0, 4], 0.0, atol=FLOAT32_ROUNDING)  # the sun (from below) is not in +z
    np.testing.assert_allclose(vectors[0, 5], np.tile([0, 0, -1.0], (3, 1)), rtol=FLOAT32_ACCUMULATED)


def test_grid_function_matches_the_numpy_reconstruction():
    """kernels/grid_irradiance.grid_irradiance (wp.func) is reconstruct_irradiance's paper formula."""
    import warp as wp

    from usdbake.processors.irradiance_grid.grid_irradiance import GridVectors, grid_irradiance, grid_vectors

    @wp.kernel
    def read(grid: GridVectors, p: wp.array(dtype=wp.vec3), n: wp.array(dtype=wp.vec3), out: wp.array(dtype=wp.vec3)):
        i = wp.tid()
        out[i] = grid_irradiance(grid, p[i], n[i])

    rng = np.random.default_rng(8)  # fixed seed: arbitrary vectors, points in and around the grid
    layout = GridLayout(np.array([-1.0, 0.5, 2.0]), np.array([0.5, 0.5, 0.5]), (4, 3, 5))
    vectors = rng.normal(size=(layout.count, 6, 3, 3)).astype(np.float32)
    points = (layout.grid_origin - 0.2 + rng.random((400, 3)) * 2.8).astype(np.float32)
    normals = random_normals(400, 9).astype(np.float32)
    out = wp.zeros(400, dtype=wp.vec3, device="cpu")
    wp.launch(read, 400, [grid_vectors(vectors, layout.resolution, layout.grid_origin, layout.cell_size, "cpu"),
                          wp.array(points, dtype=wp.vec3, device="cpu"), wp.array(normals, dtype=wp.vec3, device="cpu"),
                          out], device="cpu")
    expected = reconstruct_irradiance(layout, vectors, points, normals, normal_offset=0.0)
    np.testing.assert_allclose(out.numpy(), expected, atol=FLOAT32_ACCUMULATED * np.abs(vectors).max())


@pytest.fixture(scope="module")
def lit_room():
    """A closed 2 m room of six grey prims with a disk light under the ceiling, and 300 points on its walls."""
    from patch_scenes import box_parts
    from patch_scenes import make_scene as make_parts_scene

    light = (LIGHT_DISK, [10, 9, 8], [1, 1, 1.9], [0, 0, -1], [0.3, 0.3])
    scene = make_parts_scene(box_parts(size=2.0, grid=2), albedo=(0.6, 0.5, 0.4), lights=make_lights(light))
    rng = np.random.default_rng(4)  # fixed seed: points on the walls
    areas = scene.tri_areas.astype(np.float64)
    pick = rng.choice(len(areas), 300, p=areas / areas.sum())
    r1, r2 = np.sqrt(rng.random(300))[:, None], rng.random(300)[:, None]
    c = scene.points[scene.tri_vertices[pick]].astype(np.float64)
    points = (c[:, 0] * (1 - r1) + c[:, 1] * r1 * (1 - r2) + c[:, 2] * r1 * r2).astype(np.float32)
    return scene, Tracer.from_scene(scene), points, scene.tri_normals[pick]


def test_more_bounces_carry_the_light_a_path_tracer_sees(lit_room):
    """Indirect light at points on the walls of a closed lit room: each bounce adds light, and the k-bounce
    grid's mean, as a share of a k-bounce path tracer's, stays near the one-bounce grid's share (the passes
    that reflect the previous grid's light neither drop nor double it)."""
    from usdbake.benchmarks.references import path_traced_indirect

    scene, tracer, points, normals = lit_room
    layout = grid_layout(scene.points.min(0), scene.points.max(0), vertices=1500)
    means, shares = [], []
    for bounces in (1, 2, 3):
        grid = ig.bake_grid(tracer, scene, layout, rays=256, include_direct=False, bounces=bounces)
        estimate = reconstruct_irradiance(layout, grid.vectors, points, normals)
        reference = path_traced_indirect(tracer, scene, points, normals, paths=2048, bounces=bounces)
        means.append(float(estimate.mean()))
        shares.append(float(estimate.mean() / reference.mean()))
    assert means[0] < means[1] < means[2]
    assert all(abs(share / shares[0] - 1.0) <= GRID_BOUNCE_SHARE for share in shares[1:]), shares


def test_without_a_probe_volume_the_grid_leaves_the_backdrop_out():
    """The same room on its 200 m ground without a probe volume: the grid spans the room grown by
    RECEIVER_MARGIN of its diagonal (not the lawn, whose 2.5 m cells would light the room from outside), and
    the result names the backdrop it left out."""
    from stage_builders import add_mesh, new_stage
    from pxr import UsdLux
    from usdbake.processors.irradiance_grid.vector_grid import RECEIVER_MARGIN
    from usdbake.stages.extract import extract_scene

    stage = new_stage(up_axis="Z")
    add_mesh(stage, "/World/Ground", [(-100, -100, 0), (100, -100, 0), (100, 100, 0), (-100, 100, 0)], [4],
             [0, 1, 2, 3])
    box = [(x, y, z) for z in (0, 3) for y in (-2, 2) for x in (-2, 2)]
    add_mesh(stage, "/World/Room", box, [4] * 6, [0, 2, 3, 1, 4, 5, 7, 6, 0, 1, 5, 4, 2, 6, 7, 3, 0, 4, 6, 2,
                                                 1, 3, 7, 5])
    UsdLux.DomeLight.Define(stage, "/World/Sky").CreateIntensityAttr(1.0)
    scene = extract_scene(stage)
    margin = RECEIVER_MARGIN * np.linalg.norm([4.0, 4.0, 3.0])
    lo, hi = grid_bounds(scene)
    expected_lo = np.maximum(np.array([-2.0, -2.0, 0.0]) - margin, scene.bounds[0] + scene.origin)
    np.testing.assert_allclose(lo + scene.origin, expected_lo, atol=FLOAT32_ROUNDING * 100)
    np.testing.assert_allclose(hi + scene.origin, np.minimum(np.array([2.0, 2.0, 3.0]) + margin,
                                                          scene.bounds[1] + scene.origin), atol=FLOAT32_ROUNDING * 100)
    result, _ = run(scene, vertices=1000, rays=16)
    assert result.stats["backdrops_left_out"] == 1.0
    assert any(m.startswith("grid placed around the receivers, leaving out the backdrop(s) /World/Ground")
               for m in result.messages), result.messages
    np.testing.assert_allclose(result.products[IrradianceGridProduct].layout.cell_size,
                               grid_layout(lo, hi, vertices=1000).cell_size)


def test_the_grid_goes_where_the_probe_volume_is():
    """A 4 x 4 x 3 m room on a 200 m ground plane: with a ProbeVolumeAPI cube around the room the grid lies
    over the room (its cells 0.3 m, not 8 m); an extentless volume is refused naming the prim."""
    from pxr import Gf, UsdGeom, UsdLux

    from stage_builders import add_mesh, new_stage
    from usdbake.core.errors import StageError
    from usdbake.stages.extract import extract_scene

    stage = new_stage(up_axis="Z")
    add_mesh(stage, "/World/Ground", [(-100, -100, 0), (100, -100, 0), (100, 100, 0), (-100, 100, 0)], [4],
             [0, 1, 2, 3])
    box = [(x, y, z) for z in (0, 3) for y in (-2, 2) for x in (-2, 2)]
    add_mesh(stage, "/World/Room", box, [4] * 6, [0, 2, 3, 1, 4, 5, 7, 6, 0, 1, 5, 4, 2, 6, 7, 3, 0, 4, 6, 2,
                                                 1, 3, 7, 5])
    UsdLux.DomeLight.Define(stage, "/World/Sky").CreateIntensityAttr(1.0)
    whole = grid_layout(*extract_scene(stage).bounds, vertices=1000)  # the whole stage, lawn included
    cube = UsdGeom.Cube.Define(stage, "/World/RoomVolume")
    UsdGeom.Xformable(cube).AddTranslateOp().Set(Gf.Vec3d(0, 0, 1.5))
    UsdGeom.Xformable(cube).AddScaleOp().Set(Gf.Vec3f(2, 2, 1.5))
    cube.GetPrim().ApplyAPI("ProbeVolumeAPI")
    cube.CreateVisibilityAttr(UsdGeom.Tokens.invisible)  # a volume, not a wall: it still counts
    scene = extract_scene(stage)
    assert len(scene.prim_paths) == 2  # the cube is no receiver
    np.testing.assert_allclose(scene.probe_volumes[0] + scene.origin, [[-2, -2, 0], [2, 2, 3]], atol=FLOAT64_ROUNDING)
    result, _ = run(scene, vertices=1000, rays=16)
    layout = result.products[IrradianceGridProduct].layout
    world_lo = layout.grid_origin + scene.origin
    world_hi = world_lo + (np.array(layout.resolution) - 1) * layout.cell_size
    assert (world_lo >= [-2, -2, 0] - layout.cell_size).all() and (world_hi <= [2, 2, 3] + layout.cell_size).all()
    assert layout.cell_size[0] < 0.1 * whole.cell_size[0]
    assert any("1 probe volume(s)" in m for m in result.messages)
    UsdGeom.Xform.Define(stage, "/World/Empty").GetPrim().ApplyAPI("ProbeVolumeAPI")
    with pytest.raises(StageError, match="/World/Empty.ProbeVolumeAPI: the probe volume has no extent"):
        extract_scene(stage)
