"""Point location in probe clouds on the device (processors.light_probes.lookup) against scipy's Qhull and the
float64 walk of processors.light_probes.tetrahedra."""

import numpy as np
import pytest
import warp as wp
from scipy.spatial import Delaunay
from tolerances import FLOAT32_BARYCENTRIC

from usdbake.processors.light_probes import tetrahedra
from usdbake.processors.light_probes.lookup import ProbeLookup, TetMesh, locate_from


def per_probe_weights(tet_vertices: np.ndarray, tets: np.ndarray, bary: np.ndarray, probes: int) -> np.ndarray:
    """(N, P) weight of every probe: equal for two tetrahedra that share the face a point lies on."""
    weights = np.zeros((len(tets), probes))
    rows = np.repeat(np.arange(len(tets)), 4)
    np.add.at(weights, (rows, tet_vertices[tets].ravel()), np.asarray(bary, np.float64).ravel())
    return weights


@pytest.fixture(scope="module")
def cloud():
    rng = np.random.default_rng(21)  # fixed seed
    probes = rng.uniform(0.0, 10.0, (500, 3))
    return probes, tetrahedra.tetrahedralize(probes)


def test_lookups_equal_scipy_barycentrics(cloud):
    """Inside the hull, the probe weights are scipy's (find_simplex + its barycentric transform)."""
    probes, tetra = cloud
    rng = np.random.default_rng(22)  # fixed seed
    points = rng.uniform(0.0, 10.0, (20000, 3))
    delaunay = Delaunay(probes)
    simplex = delaunay.find_simplex(points)
    inside_scipy = simplex >= 0
    points = points[inside_scipy]
    simplex = simplex[inside_scipy]
    b = np.einsum("nij,nj->ni", delaunay.transform[simplex, :3], points - delaunay.transform[simplex, 3])
    scipy_bary = np.c_[b, 1.0 - b.sum(axis=1)]
    tets, bary, inside = ProbeLookup(tetra, threads=2).locate(points)
    assert inside.all()
    ours = per_probe_weights(tetra.tet_vertices, tets, bary, len(probes))
    theirs = per_probe_weights(delaunay.simplices, simplex, scipy_bary, len(probes))
    assert np.abs(ours - theirs).max() <= FLOAT32_BARYCENTRIC


def test_device_walk_ends_where_the_float64_walk_ends(cloud):
    probes, tetra = cloud
    points = np.random.default_rng(23).uniform(-2.0, 12.0, (5000, 3))  # fixed seed; some outside the hull
    tets, bary, inside = ProbeLookup(tetra).locate(points)
    ref_tet, ref_bary, ref_inside = tetrahedra.locate(tetra, points)
    np.testing.assert_array_equal(inside, ref_inside)
    ours = per_probe_weights(tetra.tet_vertices, tets[inside], bary[inside], len(probes))
    theirs = per_probe_weights(tetra.tet_vertices, ref_tet[inside], ref_bary[inside], len(probes))
    assert np.abs(ours - theirs).max() <= FLOAT32_BARYCENTRIC
    assert (tets[~inside] >= 0).all()  # outside: a boundary tetrahedron, never an invalid index


@wp.kernel
def _walk_from(mesh: TetMesh, points: wp.array(dtype=wp.vec3), start: int, tets: wp.array(dtype=int)):
    i = wp.tid()
    tets[i] = locate_from(mesh, points[i], start).tet


def test_walk_from_any_start_reaches_the_same_tetrahedron(cloud):
    """locate_from (what an engine calls with an object's cached tetrahedron) from a far start."""
    probes, tetra = cloud
    points = np.random.default_rng(24).uniform(2.0, 8.0, (2000, 3)).astype(np.float32)  # fixed seed
    lookup = ProbeLookup(tetra)
    expected, _, inside = lookup.locate(points)
    out = wp.zeros(len(points), dtype=int)
    wp.launch(_walk_from, dim=len(points), inputs=[lookup.mesh, wp.array(points, dtype=wp.vec3), 0, out])
    got = out.numpy()
    assert inside.all()
    # a point on a shared face may end in either tetrahedron: compare the probes' weights, not the index
    ours = per_probe_weights(tetra.tet_vertices, got, tetrahedra.barycentric(tetra, got, points), len(probes))
    theirs = per_probe_weights(tetra.tet_vertices, expected, tetrahedra.barycentric(tetra, expected, points),
                               len(probes))
    assert np.abs(ours - theirs).max() <= FLOAT32_BARYCENTRIC


def test_cospherical_probes_are_located_with_a_proper_tetrahedron():
    """Cube corners (Qhull joggles them): points inside the cube get weights that sum to 1 and
    reproduce the point (linear precision)."""
    corners = np.array([[x, y, z] for x in (0, 1) for y in (0, 1) for z in (0, 1)], np.float64)
    tetra = tetrahedra.tetrahedralize(corners)
    points = np.random.default_rng(25).uniform(0.05, 0.95, (1000, 3))  # fixed seed
    tets, bary, inside = ProbeLookup(tetra).locate(points)
    assert inside.all()
    rebuilt = np.einsum("nk,nkd->nd", bary.astype(np.float64), corners[tetra.tet_vertices[tets]])
    assert np.abs(rebuilt - points).max() <= FLOAT32_BARYCENTRIC
    assert np.abs(bary.sum(axis=1) - 1.0).max() <= FLOAT32_BARYCENTRIC
