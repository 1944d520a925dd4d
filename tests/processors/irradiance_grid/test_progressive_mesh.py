"""progressive_mesh: the order is a permutation with collapses onto lower ranks, the full level
is the original mesh, a flat grid keeps its area and its 4 corners, a sphere's error shrinks as
points arrive, degenerate input is harmless, and a bake through USD writes the primvars."""

from repo_paths import SAMPLES
import numpy as np
import pytest
from tolerances import FLOAT32_STORAGE, FLOAT64_ROUNDING
from usdbake.processors.irradiance_grid import progressive_mesh as pm


def grid(n):
    x, y = np.meshgrid(np.arange(n), np.arange(n))
    points = np.c_[x.ravel(), y.ravel(), np.zeros(n * n)].astype(np.float64)
    tris = []
    for j in range(n - 1):
        for i in range(n - 1):
            a = j * n + i
            tris += [[a, a + 1, a + n + 1], [a, a + n + 1, a + n]]
    return points, np.array(tris)


def sphere(rings=12, segments=24):
    theta = np.linspace(0, np.pi, rings + 1)[1:-1]
    phi = np.linspace(0, 2 * np.pi, segments, endpoint=False)
    t, f = np.meshgrid(theta, phi, indexing="ij")
    points = np.c_[np.sin(t).ravel() * np.cos(f).ravel(), np.sin(t).ravel() * np.sin(f).ravel(), np.cos(t).ravel()]
    points = np.vstack([[0, 0, 1], points, [0, 0, -1]])
    tris = []
    for s in range(segments):
        tris.append([0, 1 + s, 1 + (s + 1) % segments])
        last = 1 + (rings - 2) * segments
        tris.append([len(points) - 1, last + (s + 1) % segments, last + s])
    for r in range(rings - 2):
        for s in range(segments):
            a, b = 1 + r * segments + s, 1 + r * segments + (s + 1) % segments
            tris += [[a, a + segments, b], [b, a + segments, b + segments]]
    return points, np.array(tris)


def area(points, faces):
    p = points[faces]
    return 0.5 * np.linalg.norm(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), axis=1).sum()


def check_order(rank, collapse_to):
    np.testing.assert_array_equal(np.sort(rank), np.arange(len(rank)))
    collapsed = np.flatnonzero(collapse_to >= 0)
    assert (rank[collapse_to[collapsed]] < rank[collapsed]).all()


def test_flat_grid_keeps_area_and_corners():
    points, tris = grid(10)
    rank, collapse_to = pm.progressive_order(points, tris)
    check_order(rank, collapse_to)
    np.testing.assert_array_equal(pm.lod_faces(tris, rank, collapse_to, len(points)), tris)
    for k in (4, 5, 10, 30, 60, 100):
        np.testing.assert_allclose(area(points, pm.lod_faces(tris, rank, collapse_to, k)), 81.0, rtol=FLOAT64_ROUNDING)
    corners = {(0.0, 0.0), (9.0, 0.0), (0.0, 9.0), (9.0, 9.0)}
    assert {tuple(points[v, :2]) for v in np.argsort(rank)[:4]} == corners


def test_sphere_error_shrinks_as_points_arrive():
    points, tris = sphere()
    rank, collapse_to = pm.progressive_order(points, tris)
    check_order(rank, collapse_to)
    full = area(points, tris)
    deficits = [full - area(points, pm.lod_faces(tris, rank, collapse_to, k)) for k in (12, 40, 120, len(points))]
    # Inscribed meshes: fewer points, less area; the full level is the original.
    assert deficits[0] > deficits[1] > deficits[2] > deficits[3] == 0.0
    assert deficits[1] < 0.25 * full


def test_degenerate_input_is_harmless():
    points = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0], [5, 5, 5], [np.nan, 0, 0]], np.float64)
    tris = np.array([[0, 1, 2], [1, 3, 2], [0, 0, 1], [2, 2, 2], [1, 1, 3]])
    rank, collapse_to = pm.progressive_order(points, tris)
    check_order(rank, collapse_to)
    assert collapse_to[4] == -1 and collapse_to[5] == -1  # isolated points collapse onto nothing
    for k in range(len(points) + 1):
        faces = pm.lod_faces(tris, rank, collapse_to, k)
        assert (faces >= 0).all() and (faces < len(points)).all()


def test_end_to_end_cornell_box(tmp_path):
    from pxr import Usd, UsdGeom
    from usdbake.cli.main import main

    sample = SAMPLES / "cornell_box.usda"
    out = tmp_path / "cornell_pm.usdc"
    assert main(["bake", str(sample), "-o", str(out), "-p", "progressive_mesh", "--cache", str(tmp_path / "c")]) == 0
    stage = Usd.Stage.Open(str(out))
    mesh = stage.GetPrimAtPath("/World/CornellBox/TallBlock")
    rank = np.asarray(mesh.GetAttribute("primvars:bake:pmRank").Get())
    collapse_to = np.asarray(mesh.GetAttribute("primvars:bake:pmCollapseTo").Get())
    assert len(rank) == len(mesh.GetAttribute("points").Get())
    check_order(rank, collapse_to)
    assert mesh.GetAttribute("primvars:bake:pmRank").GetMetadata("interpolation") == "vertex"
    # The stream file beside the layer: the whole stream is the mesh, world space, vertices in rank order.
    from usdbake.formats.mesh_stream import decode_mesh_stream

    stream = decode_mesh_stream((tmp_path / mesh.GetAttribute("bake:pmStreamFile").Get().path).read_bytes())
    points = np.asarray(mesh.GetAttribute("points").Get(), np.float64)
    world = np.asarray(UsdGeom.Xformable(mesh).ComputeLocalToWorldTransform(Usd.TimeCode.Default()))
    expected = (np.c_[points, np.ones(len(points))] @ world)[:, :3][np.argsort(rank)]
    np.testing.assert_allclose(stream.positions, expected, atol=FLOAT32_STORAGE * np.abs(expected).max())
    assert len(stream.faces) == stream.total_faces > 0 and stream.faces.max() < len(rank)


def test_params():
    from usdbake.core import ParamError

    with pytest.raises(ParamError):
        pm.ProgressiveMesh.Params(max_points=0)
