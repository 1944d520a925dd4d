"""Delaunay tetrahedralization, barycentric walk and interpolation (processors/tetrahedra.py):
degenerate input (cospherical, coplanar, collinear, duplicates, too few, NaN), agreement of the walk
with scipy's find_simplex, linear precision, the hull, neighbours, and the blocked-edge rule."""

import numpy as np
import pytest
from scipy.spatial import ConvexHull, Delaunay

from tolerances import (BARYCENTRIC, FLOAT64_AMPLIFIED, FLOAT64_ROUNDING, JOGGLE_FIELD, JOGGLE_RECONSTRUCTION,
                        ON_BOUNDARY)
from usdbake.processors.light_probes import tetrahedra as T

CUBE = np.array([[i, j, k] for i in (0, 1) for j in (0, 1) for k in (0, 1)], float)
OCTAHEDRON = np.array([[0.5, 0.5, -0.5], [0.5, 0.5, 1.5], [-0.5, 0.5, 0.5], [1.5, 0.5, 0.5],
                       [0.5, -0.5, 0.5], [0.5, 1.5, 0.5]])


def volumes(tetra):
    return T._volumes(tetra.points, tetra.tet_vertices)


def check_structure(tetra):
    """Positively oriented, neighbours mutual and sharing the face opposite the vertex."""
    assert (volumes(tetra) >= -ON_BOUNDARY).all()
    tets, nbr = tetra.tet_vertices, tetra.tet_neighbors
    for t in range(tetra.num_tets):
        for k in range(4):
            n = nbr[t, k]
            if n < 0:
                continue
            face = set(tets[t]) - {tets[t, k]}
            assert face <= set(tets[n])
            assert t in nbr[n]


def hull_contains(points, queries):
    eq = ConvexHull(points).equations
    return (queries @ eq[:, :3].T + eq[:, 3] <= -ON_BOUNDARY).all(axis=1)


def test_random_points_structure_and_volume():
    points = np.random.default_rng(1).random((200, 3))  # fixed seed
    tetra = T.tetrahedralize(points)
    check_structure(tetra)
    assert not tetra.joggled
    assert volumes(tetra).sum() == pytest.approx(ConvexHull(points).volume, rel=FLOAT64_ROUNDING)


def test_cospherical_cube_and_octahedron():
    points = np.r_[CUBE, OCTAHEDRON]
    tetra = T.tetrahedralize(points)
    check_structure(tetra)
    assert volumes(tetra).sum() == pytest.approx(ConvexHull(points).volume, rel=FLOAT64_ROUNDING)
    queries = np.random.default_rng(2).uniform(-0.6, 1.6, (3000, 3))  # fixed seed
    tet, bary, inside = T.locate(tetra, queries)
    expected_inside = hull_contains(points, queries)
    np.testing.assert_array_equal(inside[expected_inside], True)
    outside = ~hull_contains(points, queries) & ~inside  # points within 1e-9 of the hull may go either way
    assert outside.sum() > 0.3 * len(queries)
    recon = np.einsum("nv,nvj->nj", bary, points[tetra.tet_vertices[tet]])
    np.testing.assert_allclose(recon[inside], queries[inside], atol=JOGGLE_RECONSTRUCTION)


def test_cube_corners_alone():
    tetra = T.tetrahedralize(CUBE)
    check_structure(tetra)
    assert volumes(tetra).sum() == pytest.approx(1.0, rel=FLOAT64_ROUNDING)


@pytest.mark.parametrize("points, word", [
    (np.c_[np.random.default_rng(3).random((20, 2)), np.zeros(20)], "coplanar"),
    (np.outer(np.arange(10.0), [1.0, 2.0, 3.0]), "collinear"),
    (CUBE[:3], "at least 4"),
    (np.repeat(CUBE[:1], 6, axis=0), "at least 4"),
])
def test_degenerate_input_raises_a_clear_error(points, word):
    with pytest.raises(T.DegenerateProbesError, match=word):
        T.tetrahedralize(points)


def test_non_finite_points_raise():
    points = np.r_[CUBE, [[np.nan, 0, 0]]]
    with pytest.raises(T.DegenerateProbesError, match="NaN"):
        T.tetrahedralize(points)


def test_duplicates_are_never_referenced():
    rng = np.random.default_rng(4)  # fixed seed
    points = rng.random((50, 3))
    with_dupes = np.r_[points, points[:10], points[5:15] + 1e-14]
    tetra = T.tetrahedralize(with_dupes)
    check_structure(tetra)
    assert tetra.tet_vertices.max() < 50
    assert volumes(tetra).sum() == pytest.approx(ConvexHull(points).volume, rel=FLOAT64_ROUNDING)


def test_walk_agrees_with_scipy_find_simplex():
    rng = np.random.default_rng(5)  # fixed seed
    points = rng.random((300, 3))
    tetra = T.tetrahedralize(points)
    reference = Delaunay(points)
    queries = rng.uniform(0.05, 0.95, (1500, 3))
    expected = reference.find_simplex(queries)
    for start in (None, 0):  # from the nearest centroid, and the paper's walk from one start tetrahedron
        tet, bary, inside = T.locate(tetra, queries, start=start)
        found = expected >= 0
        np.testing.assert_array_equal(inside, found)
        mine = np.sort(tetra.tet_vertices[tet[found]], axis=1)
        theirs = np.sort(reference.simplices[expected[found]], axis=1)
        np.testing.assert_array_equal(mine, theirs)
        assert (bary[found] >= -BARYCENTRIC).all()


def test_walk_from_every_start_finds_the_same_tetrahedron():
    rng = np.random.default_rng(6)  # fixed seed
    points = rng.random((60, 3))
    tetra = T.tetrahedralize(points)
    query = np.array([[0.5, 0.45, 0.52]])
    results = {tuple(sorted(tetra.tet_vertices[T.locate(tetra, query, start=s)[0][0]]))
               for s in range(tetra.num_tets)}
    assert len(results) == 1


def test_brute_force_fallback_when_steps_run_out():
    points = np.random.default_rng(7).random((100, 3))  # fixed seed
    tetra = T.tetrahedralize(points)
    queries = np.random.default_rng(8).uniform(0.2, 0.8, (200, 3))
    walked = T.locate(tetra, queries, start=0)
    forced = T.locate(tetra, queries, start=0, max_steps=1)
    inside = walked[2]
    np.testing.assert_allclose(forced[1][inside], walked[1][inside], atol=BARYCENTRIC)


def test_interpolation_reproduces_a_linear_field_exactly():
    rng = np.random.default_rng(9)  # fixed seed
    points = rng.random((150, 3)) * [3.0, 1.0, 2.0] + [10.0, -5.0, 0.0]
    a, b = rng.normal(size=(3, 4)), rng.normal(size=4)
    values = points @ a + b
    tetra = T.tetrahedralize(points)
    queries = points.min(axis=0) + rng.random((2000, 3)) * (points.max(axis=0) - points.min(axis=0))
    tet, bary, inside = T.locate(tetra, queries)
    interpolated = np.einsum("nv,nvc->nc", bary, values[tetra.tet_vertices[tet]])
    np.testing.assert_allclose(interpolated[inside], queries[inside] @ a + b, atol=BARYCENTRIC)
    # and at the probes themselves the weights pick the probe
    tet, bary, inside = T.locate(tetra, points)
    picked = np.einsum("nv,nvc->nc", bary, values[tetra.tet_vertices[tet]])
    np.testing.assert_allclose(picked, values, atol=BARYCENTRIC)


def test_outside_queries_clamp_to_the_boundary():
    points = np.r_[CUBE, [[0.5, 0.5, 0.5]]]
    tetra = T.tetrahedralize(points)
    queries = np.array([[0.5, 0.5, 3.0], [-2.0, 0.3, 0.4], [0.9, 5.0, 0.1]])
    tet, bary, inside = T.locate(tetra, queries)
    assert not inside.any()
    assert (tetra.tet_neighbors[tet] < 0).any(axis=1).all()  # walks end on the hull
    w = T.clamp_weights(bary)
    assert (w >= 0).all()
    np.testing.assert_allclose(w.sum(axis=1), 1.0)
    # A query straight above the top face blends only top-face probes.
    top = points[tetra.tet_vertices[tet[0]]][:, 2] == 1.0
    assert w[0][~top].sum() == 0.0


def test_edge_list_and_masks():
    tetra = T.tetrahedralize(np.r_[CUBE, [[0.5, 0.5, 0.5]]])
    edges, index = T.edge_list(tetra.tet_vertices)
    assert (edges[:, 0] < edges[:, 1]).all()
    assert len(np.unique(edges, axis=0)) == len(edges)
    for t in range(tetra.num_tets):
        for e, (a, b) in enumerate(T.TET_EDGES):
            assert set(edges[index[t, e]]) == {tetra.tet_vertices[t, a], tetra.tet_vertices[t, b]}
    blocked = np.zeros(len(edges), bool)
    blocked[index[0, 4]] = True
    masks = T.edge_masks(index, blocked)
    assert masks[0] & (1 << 4)
    assert (masks[index[:, 4] != index[0, 4]] & (1 << 4) == 0).all()


def test_leak_weights_cut_vertices_behind_blocked_edges():
    weights = np.array([[0.4, 0.3, 0.2, 0.1], [0.1, 0.2, 0.3, 0.4], [0.4, 0.3, 0.2, 0.1]])
    edge_01 = 1 << T.TET_EDGES.index((0, 1))
    edge_23 = 1 << T.TET_EDGES.index((2, 3))
    out = T.leak_weights(weights, np.array([edge_01, edge_01, edge_23]))
    np.testing.assert_allclose(out[0], np.array([0.4, 0.0, 0.2, 0.1]) / 0.7)  # vertex 0 dominates: 1 is cut
    np.testing.assert_allclose(out[1], weights[1])  # vertex 3 dominates: edge 0-1 does not touch it
    np.testing.assert_allclose(out[2], weights[2])
    # Two sides: {0, 1} and {2, 3}; the heavier side wins even though vertex 2 is the single heaviest.
    across = sum(1 << T.TET_EDGES.index(edge) for edge in ((0, 2), (0, 3), (1, 2), (1, 3)))
    np.testing.assert_allclose(T.leak_weights(np.array([[0.3, 0.3, 0.35, 0.05]]), np.array([across])),
                               [[0.5, 0.5, 0.0, 0.0]])
    everything = sum(1 << e for e in range(6))
    np.testing.assert_allclose(T.leak_weights(weights, np.full(3, everything)),
                               np.eye(4)[[0, 3, 0]])


def test_from_arrays_round_trip():
    points = np.random.default_rng(10).random((40, 3))  # fixed seed
    tetra = T.tetrahedralize(points)
    again = T.from_arrays(points, tetra.tet_vertices.ravel(), tetra.tet_neighbors.ravel())
    queries = np.random.default_rng(11).uniform(0.1, 0.9, (300, 3))
    a, b = T.locate(tetra, queries), T.locate(again, queries)
    np.testing.assert_array_equal(a[0], b[0])
    np.testing.assert_allclose(a[1], b[1], atol=BARYCENTRIC)
    with pytest.raises(ValueError, match="outside"):
        T.from_arrays(points, np.array([0, 1, 2, 99]), np.array([-1, -1, -1, -1]))


def test_regular_grid_vertices_and_linear_field():
    """A 4 x 3 x 3 lattice (coplanar layers, cospherical cells: flat tetrahedra everywhere): every
    vertex interpolates to itself and a linear field is reproduced (up to the 1e-6 joggle)."""
    axes = [np.arange(4.0), np.arange(3.0), np.arange(3.0)]
    points = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
    tetra = T.tetrahedralize(points)
    check_structure(tetra)
    assert tetra.joggled and tetra.tet_flat is not None
    assert volumes(tetra).sum() == pytest.approx(3.0 * 2.0 * 2.0, rel=FLOAT64_AMPLIFIED)
    rng = np.random.default_rng(12)  # fixed seed
    a, b = rng.normal(size=(3, 2)), rng.normal(size=2)
    values = points @ a + b
    for queries, tol in ((points, BARYCENTRIC), (rng.random((1000, 3)) * [3, 2, 2], JOGGLE_FIELD)):
        tet, bary, inside = T.locate(tetra, queries)
        interior = ((queries > 1e-3) & (queries < [3 - 1e-3, 2 - 1e-3, 2 - 1e-3])).all(axis=1)
        assert inside[interior].all()  # on the hull the joggle may put a point 1e-6 outside: clamped
        assert not tetra.tet_flat[tet].any()
        got = np.einsum("nv,nvc->nc", T.clamp_weights(bary), values[tetra.tet_vertices[tet]])
        np.testing.assert_allclose(got, queries @ a + b, atol=tol)
