"""The catalogue, resources (issue 27): inputs that cost time or memory out of proportion to their size.

Each case bakes a stage through the command (``usdbake.cli.main.main``), checks that no input file changed
by a byte, and checks the result; complexity is asserted by counting work, never by timing. Timings are
printed (``pytest -s``) for the record. docs/reliability.md lists the cases.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from production_assets import add_floor, new_stage
from pxr import Gf, Usd, UsdGeom, Vt

from tolerances import FLOAT32_STORAGE
from usdbake.cli.main import main
from usdbake.kernels.tracer import Tracer
from usdbake.stages.extract import extract_scene

FAST = ["--set", "ambient_occlusion.samples=64"]
TRIANGLE_CM = np.array([[0, 100, 0], [0, 100, 100], [100, 100, 0]], np.float32)
"""One triangle a metre above the floor (Y-up, centimetres), facing up (+Y): open sky above it."""


class Baker:
    """Runs the command in-process and checks the inputs stay byte-identical."""

    def __init__(self, capsys):
        self.capsys = capsys

    def __call__(self, *argv, inputs=()) -> tuple[int, str, str]:
        files = [Path(p) for p in inputs]
        before = {p: p.read_bytes() for p in files}
        self.capsys.readouterr()
        code = main([str(a) for a in argv])
        captured = self.capsys.readouterr()
        for path in files:
            assert path.read_bytes() == before[path], f"{path} changed"
        return code, captured.out, captured.err


@pytest.fixture
def bake(capsys):
    return Baker(capsys)


@pytest.fixture
def cache(tmp_path) -> list[str]:
    """A result cache of the test's own: every bake computes (and its time is its own)."""
    return ["--cache", str(tmp_path / "cache")]


def add_triangles(stage: Usd.Stage, path: str, points: np.ndarray) -> UsdGeom.Mesh:
    """A mesh of unwelded triangles: points 3k, 3k + 1, 3k + 2 make triangle k."""
    mesh = UsdGeom.Mesh.Define(stage, path)
    mesh.CreatePointsAttr(Vt.Vec3fArray.FromNumpy(np.ascontiguousarray(points, np.float32)))
    mesh.CreateFaceVertexCountsAttr(Vt.IntArray.FromNumpy(np.full(len(points) // 3, 3, np.int32)))
    mesh.CreateFaceVertexIndicesAttr(Vt.IntArray.FromNumpy(np.arange(len(points), dtype=np.int32)))
    return mesh


def triangles_stage(folder: Path, name: str, points: np.ndarray) -> Path:
    path = folder / name
    stage = new_stage(path)
    add_floor(stage, "/World/Floor")
    add_triangles(stage, "/World/Triangles", points)
    stage.Save()
    return path


def ao_of(out: Path, prim: str) -> np.ndarray:
    stage = Usd.Stage.Open(str(out))  # held while its prim is read
    return np.array(UsdGeom.PrimvarsAPI(stage.GetPrimAtPath(prim)).GetPrimvar("bake:ao").Get())


def bake_seconds(out_text: str) -> float:
    return next(step["seconds"] for step in json.loads(out_text)["steps"] if step["processor"] == "ambient_occlusion")


# ---------------------------------------------------------------------------
# Coincident vertices: stacked copies of one triangle


def test_stacked_copies_of_a_triangle_cost_what_distinct_triangles_cost(bake, cache, tmp_path):
    """10,000 copies of one triangle (30,000 points at 3 positions) against 10,000 distinct ones. Before,
    the ray-origin rule visited every copy from each of the 30,000 vertices (measured 9.5 s here, 91 s at
    90,000 points, against 0.7 s and 2.4 s for distinct triangles). Now the tracer holds one copy (counted: the work of the origin rule is the lanes near a vertex),
    and the AO is that of one triangle: 1 on the copies, finite everywhere."""
    copies = 10_000
    stacked = triangles_stage(tmp_path, "stacked.usda", np.tile(TRIANGLE_CM, (copies, 1)))
    rng = np.random.default_rng(27)  # fixed seed: a reproducible scatter over the floor
    spots = np.repeat(rng.uniform([-180, 20, -180], [180, 150, 180], (copies, 3)), 3, axis=0)
    distinct = triangles_stage(tmp_path, "distinct.usda", spots + 0.1 * np.tile(TRIANGLE_CM, (copies, 1)))
    seconds = {}
    for source in (stacked, distinct):
        out = tmp_path / f"{source.stem}.baked.usdc"
        code, out_text, err = bake("bake", source, "-o", out, "--json", *FAST, *cache, inputs=[source])
        assert code == 0, err
        seconds[source.stem] = bake_seconds(out_text)
        ao = ao_of(out, "/World/Triangles")
        assert ao.shape == (3 * copies,) and np.isfinite(ao).all() and ((ao >= 0) & (ao <= 1)).all()
    print(f"ambient_occlusion on {3 * copies} points, 64 rays: {seconds} (s)")
    np.testing.assert_array_equal(ao_of(tmp_path / "stacked.baked.usdc", "/World/Triangles"), 1.0)
    assert (ao_of(tmp_path / "stacked.baked.usdc", "/World/Floor") < 1).any()  # the copies shade the floor
    lanes = Tracer.from_scene(extract_scene(Usd.Stage.Open(str(stacked)))).arrays.packet_triangle
    assert int((lanes >= 0).sum()) == 1 + 2  # one copy and the floor's two triangles are traced


def test_coincident_points_and_zero_area_faces_give_finite_ao(bake, cache, tmp_path):
    """30,000 points all at one place (10,000 zero-area triangles) beside a floor: no normal, so AO 1, no NaN."""
    source = triangles_stage(tmp_path, "coincident.usda", np.full((30_000, 3), 50.0, np.float32))
    out = tmp_path / "out.usdc"
    code, _, err = bake("bake", source, "-o", out, *FAST, *cache, inputs=[source])
    assert code == 0, err
    np.testing.assert_array_equal(ao_of(out, "/World/Triangles"), 1.0)
    assert np.isfinite(ao_of(out, "/World/Floor")).all()


def test_nan_points_are_refused_before_compute(bake, tmp_path):
    points = np.tile(TRIANGLE_CM, (4, 1))
    points[7, 1] = np.nan
    source = triangles_stage(tmp_path, "nan.usda", points)
    out = tmp_path / "out.usdc"
    code, _, err = bake("bake", source, "-o", out, *FAST, inputs=[source])
    assert code == 2 and not out.exists()
    assert err.strip().splitlines()[-1] == ("usdbake: error: /World/Triangles.points: point 7 is (0.0, nan, 100.0) "
                                            "(1 non-finite points); fix or remove them")


# ---------------------------------------------------------------------------
# One displacement field for copies of a prototype that differ by a rigid motion or rounding


def lopsided_points() -> tuple[np.ndarray, np.ndarray]:
    """A bent, asymmetric blob 60 cm across: (P, 3) float64 points, (T, 3) triangles."""
    from instanced_scenes import icosphere

    points, triangles = icosphere(2)
    points = points * [30.0, 18.0, 12.0]
    points[:, 0] += 0.04 * np.maximum(points[:, 1], 0) ** 2
    return points, triangles


def add_instancer(stage, path: str, points: np.ndarray, triangles: np.ndarray, positions, orientation=None):
    """A PointInstancer with one mesh prototype defined under it, ``points`` in the prototype's own frame."""
    instancer = UsdGeom.PointInstancer.Define(stage, path)
    mesh = UsdGeom.Mesh.Define(stage, f"{path}/Prototypes/Blob")
    mesh.CreatePointsAttr(Vt.Vec3fArray.FromNumpy(np.ascontiguousarray(points, np.float32)))
    mesh.CreateFaceVertexCountsAttr(Vt.IntArray.FromNumpy(np.full(len(triangles), 3, np.int32)))
    mesh.CreateFaceVertexIndicesAttr(Vt.IntArray.FromNumpy(np.ascontiguousarray(triangles, np.int32).ravel()))
    instancer.CreatePrototypesRel().SetTargets([mesh.GetPath()])
    instancer.CreateProtoIndicesAttr([0] * len(positions))
    instancer.CreatePositionsAttr([Gf.Vec3f(*p) for p in positions])
    if orientation is not None:
        instancer.CreateOrientationsAttr([orientation] * len(positions))


def test_turned_and_rounded_copies_of_a_prototype_share_one_field(bake, cache, tmp_path):
    """Three PointInstancers of one blob: as authored; authored a second time turned 90 degrees about +Y and
    moved 20 cm (its instances turned back); a third time with 1e-6 relative noise. Before, the turned copy
    got a field of its own (the key compared points on a grid); now one is built, named by all three, the
    turned one with its orientation."""
    points, triangles = lopsided_points()
    turn = Gf.Rotation(Gf.Vec3d(0, 1, 0), 90.0)
    rotation = np.array(Gf.Matrix4d().SetRotate(turn).ExtractRotationMatrix())  # row vectors: v @ rotation
    turned = points @ rotation + [20.0, 0.0, 0.0]
    rng = np.random.default_rng(6)  # fixed seed: reproducible noise
    noisy = points + rng.normal(size=points.shape) * 1e-6 * np.ptp(points, axis=0).max()
    source = tmp_path / "blobs.usda"
    stage = new_stage(source)
    add_floor(stage, "/World/Floor")
    row = lambda z: [(-120.0 + 80.0 * k, 20.0, z) for k in range(4)]  # noqa: E731
    add_instancer(stage, "/World/A", points, triangles, row(-100.0))
    add_instancer(stage, "/World/B", turned, triangles, row(0.0), Gf.Quath(turn.GetInverse().GetQuat()))
    add_instancer(stage, "/World/C", noisy, triangles, row(100.0))
    stage.Save()
    out = tmp_path / "out.usda"
    code, out_text, err = bake("bake", source, "-o", out, "--json", "-p", "instance_ao",
                               "--set", "instance_ao.samples=16", "--set", "displacement_fields.min_instances=1",
                               "--set", "displacement_fields.positional_samples=64",
                               "--set", "displacement_fields.direction_map_size=8", *cache, inputs=[source])
    assert code == 0, err
    steps = {step["processor"]: step for step in json.loads(out_text)["steps"]}
    assert steps["displacement_fields"]["rays"] == 64 * 8 * 8  # one field built
    assert "/World/B/Prototypes/Blob: shares the field of /World/A/Prototypes/Blob (same shape, rotated 90 " \
           "degrees, moved 20)" in steps["displacement_fields"]["messages"]
    baked = Usd.Stage.Open(str(out))
    prims = {name: baked.GetPrimAtPath(f"/World/{name}/Prototypes/Blob") for name in "ABC"}
    files = {prim.GetAttribute("bake:field:file").Get().resolvedPath for prim in prims.values()}
    assert len(files) == 1 and Path(files.pop()).is_file()
    orientation = prims["B"].GetAttribute("bake:field:orientation").Get()
    np.testing.assert_allclose([orientation.GetReal(), *orientation.GetImaginary()],
                               [np.sqrt(0.5), 0.0, np.sqrt(0.5), 0.0], atol=FLOAT32_STORAGE)  # cos 45 in float32
    assert not prims["A"].GetAttribute("bake:field:orientation").HasAuthoredValue()
    assert not prims["C"].GetAttribute("bake:field:orientation").HasAuthoredValue()
    ao = ao_of(out, "/World/Floor")
    assert np.isfinite(ao).all() and ((ao >= 0) & (ao <= 1)).all()
