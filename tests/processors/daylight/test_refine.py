"""Conforming refinement: watertight stays watertight, no T-junctions, area and winding preserved,
marked triangles quartered, closure stays local, welded seams refined crack-free."""

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from tolerances import FLOAT64_AMPLIFIED, FLOAT64_ROUNDING, ON_BOUNDARY, T_JUNCTION_ENDPOINT
from usdbake.processors.daylight.refine import boundary_edges, is_watertight, refine, weld_points


def cube() -> tuple[np.ndarray, np.ndarray]:
    """Unit cube, 12 triangles with outward winding and shared vertices (watertight)."""
    points = np.array([[x, y, z] for x in (0, 1) for y in (0, 1) for z in (0, 1)], float)
    quads = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    triangles = [t for q in quads for t in ((q[0], q[1], q[2]), (q[0], q[2], q[3]))]
    return points, np.array(triangles)


def grid(n: int) -> tuple[np.ndarray, np.ndarray]:
    """n x n quads of the unit square, two right triangles each (the case where red refinement spreads)."""
    xs = np.linspace(0, 1, n + 1)
    points = np.array([[x, y, 0.0] for y in xs for x in xs])
    triangles = []
    for j in range(n):
        for i in range(n):
            a = j * (n + 1) + i
            triangles += [(a, a + 1, a + n + 2), (a, a + n + 2, a + n + 1)]
    return points, np.array(triangles)


def normals_areas(points, triangles):
    c = points[triangles]
    cross = np.cross(c[:, 1] - c[:, 0], c[:, 2] - c[:, 0])
    double = np.linalg.norm(cross, axis=1)
    return cross / np.maximum(double, 1e-300)[:, None], double / 2


def t_junctions(points, triangles) -> int:
    """Vertices lying strictly inside an edge of some triangle (brute force)."""
    edges = np.concatenate([triangles[:, [0, 1]], triangles[:, [1, 2]], triangles[:, [2, 0]]])
    a, b = points[edges[:, 0]], points[edges[:, 1]]
    used = np.unique(triangles)
    p = points[used]
    ab = b - a
    t = np.einsum("pk,ek->pe", p, ab) - np.einsum("ek,ek->e", a, ab)[None, :]
    t = t / np.einsum("ek,ek->e", ab, ab)[None, :]
    closest = a[None] + t[..., None] * ab[None]
    distance = np.linalg.norm(closest - p[:, None], axis=2)
    inside = (t > T_JUNCTION_ENDPOINT) & (t < 1 - T_JUNCTION_ENDPOINT) & (distance < ON_BOUNDARY)
    return int(inside.sum())


@settings(max_examples=15, deadline=None)
@given(st.integers(0, 2 ** 31 - 1), st.floats(0.05, 0.5))
def test_watertight_cube_stays_watertight_and_conforming(seed, fraction):
    points, triangles = cube()
    weld = np.arange(len(points))
    rng = np.random.default_rng(seed)
    total_area = normals_areas(points, triangles)[1].sum()
    for _ in range(3):
        marked = rng.random(len(triangles)) < fraction
        result = refine(points, triangles, marked, weld=weld)
        normals_before = normals_areas(points, triangles)[0]
        points, triangles, weld = result.points, result.triangles, result.weld
        normals, areas = normals_areas(points, triangles)
        assert is_watertight(triangles, weld)
        np.testing.assert_allclose(areas.sum(), total_area, rtol=FLOAT64_ROUNDING)
        np.testing.assert_allclose(normals, normals_before[result.parent], atol=FLOAT64_ROUNDING)  # winding kept
    assert t_junctions(points, triangles) == 0


def test_marked_triangles_are_quartered_and_closure_is_local():
    points, triangles = grid(16)
    marked = np.zeros(len(triangles), bool)
    marked[[100, 101]] = True
    areas = normals_areas(points, triangles)[1]
    result = refine(points, triangles, marked)
    new_areas = normals_areas(result.points, result.triangles)[1]
    for t in (100, 101):
        children = result.parent == t
        assert children.sum() == 4
        np.testing.assert_allclose(new_areas[children], areas[t] / 4, rtol=FLOAT64_ROUNDING)
    touched = np.unique(result.parent[result.changed])
    # Longest-edge closure reaches only a neighbourhood, not the grid (red-green closure would spread over it).
    assert len(touched) <= 12, touched
    assert t_junctions(result.points, result.triangles) == 0
    # The square's outline is unchanged: every boundary vertex lies on the unit square's border.
    outline = result.points[np.unique(boundary_edges(result.triangles, np.arange(len(result.points))))]
    on_border = np.isclose(outline[:, 0], 0) | np.isclose(outline[:, 0], 1) | np.isclose(outline[:, 1], 0) | \
        np.isclose(outline[:, 1], 1)
    assert on_border.all()


def test_repeated_refinement_along_a_line_has_no_t_junctions_and_bounded_angles():
    points, triangles = grid(4)
    for _ in range(4):
        centroid = points[triangles].mean(axis=1)
        marked = np.abs(centroid[:, 0] - 0.37 - 0.2 * centroid[:, 1]) < 0.05
        result = refine(points, triangles, marked)
        points, triangles = result.points, result.triangles
    assert t_junctions(points, triangles) == 0
    c = points[triangles]
    angles = []
    for k in range(3):
        u = c[:, (k + 1) % 3] - c[:, k]
        v = c[:, (k + 2) % 3] - c[:, k]
        cos = np.einsum("tk,tk->t", u, v) / np.linalg.norm(u, axis=1) / np.linalg.norm(v, axis=1)
        angles.append(np.degrees(np.arccos(np.clip(cos, -1, 1))))
    # Rivara: longest-edge bisection keeps the smallest angle >= half the initial smallest angle (45 deg here).
    assert np.min(angles) >= 45.0 / 2 - FLOAT64_AMPLIFIED


def test_split_seams_are_refined_crack_free():
    """A box authored with separate vertices per face (faceted): welding by position keeps it crack-free."""
    points, triangles = cube()
    split_points = points[triangles.ravel()]          # every triangle its own three vertices
    split_triangles = np.arange(len(split_points)).reshape(-1, 3)
    weld = weld_points(split_points)
    assert is_watertight(split_triangles, weld)
    marked = np.zeros(len(split_triangles), bool)
    marked[0] = True
    result = refine(split_points, split_triangles, marked, weld=weld)
    assert is_watertight(result.triangles, result.weld)
    assert t_junctions(result.points, result.triangles) == 0
    # Midpoints on a seam are coincident but distinct vertices (the authored seam stays a seam).
    assert len(result.points) > len(np.unique(result.points, axis=0))


def test_nothing_marked_is_a_no_op_and_degenerate_input_is_finite():
    points, triangles = cube()
    result = refine(points, triangles, np.zeros(len(triangles), bool))
    assert np.array_equal(result.triangles, triangles) and not result.changed.any()
    degenerate = np.array([[0, 0, 0], [1, 0, 0], [2, 0, 0], [0, 1, 0]], float)
    tris = np.array([[0, 1, 2], [0, 2, 3]])
    result = refine(degenerate, tris, np.array([True, True]))
    assert np.isfinite(result.points).all()
    assert t_junctions(result.points, result.triangles[normals_areas(result.points, result.triangles)[1] > 0]) == 0
