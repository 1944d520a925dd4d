"""Hostile inputs (issue 27): a huge dome texture, PointInstancer arrays of the wrong length, scenes at
extreme scales, transforms that overflow.

Each case goes through the command. A refusal is one line on stderr (``usdbake: error: ...``), exit 2,
raised while the stage is read, before any BVH is built or processor runs (``no_trace`` makes either
fail the test). A case usdbake bakes is checked against an answer that does not come from the case
itself: the unscaled scene, or OpenUSD's documented meaning.
"""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest
from pxr import Gf, Sdf, Usd, UsdGeom, UsdLux, Vt

from stage_builders import add_mesh, new_stage
from tolerances import FLOAT32_STORAGE, MEAN_FLIP_SHIFT, SINGLE_RAY_FLIP
from usdbake.cli.main import main

SAMPLES = Path(__file__).resolve().parents[2] / "samples"
AO = ["-p", "ambient_occlusion", "--set", "ambient_occlusion.samples=64", "--force"]
"""--force: each case computes (no result of an earlier run is reused from the cache)."""
INSTANCES = 16


def run_cli(capsys, *argv):
    capsys.readouterr()
    code = main([str(a) for a in argv])
    captured = capsys.readouterr()
    return code, captured.out, captured.err


def assert_refused(code, err, expected: str):
    """Exit 2 and one line on stderr, 'usdbake: error: <expected>', after the progress display's
    'reading stage' (the stage is being read when the problem is found)."""
    assert "Traceback" not in err
    lines = err.strip().splitlines()
    assert lines[-1] == f"usdbake: error: {expected}", err
    assert all(line.startswith("reading stage") for line in lines[:-1]), err
    assert code == 2


@pytest.fixture
def no_trace(monkeypatch, no_compute):
    """Also fail the test if a BVH is built: the refusal comes while the stage is read."""
    from usdbake.kernels import tracer

    def forbidden(*args, **kwargs):
        raise AssertionError("a BVH was built before the input was checked")

    monkeypatch.setattr(tracer.Tracer, "__init__", forbidden)


# ---------------------------------------------------------------------------
# PointInstancer arrays


def pawns(tmp_path, **arrays) -> Path:
    """/World/Pawns: 16 instances of a small box on a floor, with ``arrays`` authored over the defaults
    (a value of None blocks the attribute; (time, value) pairs author time samples)."""
    stage = new_stage()
    add_mesh(stage, "/World/Floor", [(-20, 0, -20), (40, 0, -20), (40, 0, 20), (-20, 0, 20)], [4], [0, 3, 2, 1])
    instancer = UsdGeom.PointInstancer.Define(stage, "/World/Pawns")
    add_mesh(stage, "/World/Pawns/Protos/Box", [(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0)], [4], [0, 1, 2, 3])
    instancer.CreatePrototypesRel().SetTargets(["/World/Pawns/Protos/Box"])
    instancer.CreateProtoIndicesAttr([0] * INSTANCES)
    instancer.CreatePositionsAttr([(2.0 * i, 0.0, 0.0) for i in range(INSTANCES)])
    for name, value in arrays.items():
        attribute = instancer.GetPrim().GetAttribute(name) or getattr(
            instancer, f"Create{name[0].upper()}{name[1:]}Attr")()
        if isinstance(value, dict):
            for time, sample in value.items():
                attribute.Set(sample, time)
        else:
            attribute.Set(value)
    path = tmp_path / "pawns.usda"
    stage.GetRootLayer().Export(str(path))
    return path


def quats(count: int) -> Vt.QuathArray:
    return Vt.QuathArray([Gf.Quath(1, 0, 0, 0)] * count)


@pytest.mark.parametrize("arrays, expected", [
    ({"orientations": quats(3)}, "/World/Pawns.orientations: 3 values for 16 positions (one per instance, or none)"),
    ({"scales": [(1, 1, 1)] * 3}, "/World/Pawns.scales: 3 values for 16 positions (one per instance, or none)"),
    ({"positions": [(0, 0, 0)] * 3}, "/World/Pawns.positions: 3 values for 16 protoIndices (one per instance)"),
    ({"orientations": {1.0: quats(16), 2.0: quats(3)}, "positions": {1.0: [(2.0 * i, 0, 0) for i in range(16)]}},
     "/World/Pawns.orientations: 3 values for 16 positions at time 2 (one per instance, or none)"),
    ({"protoIndices": [0] * 15 + [2]}, "/World/Pawns.protoIndices: index 2 at instance 15, but prototypes has "
                                       "1 target (0..0)"),
    ({"scales": [(1, 1, 1)] * 15 + [(float("nan"), 1, 1)]},
     "/World/Pawns.scales: value 15 is (nan, 1.0, 1.0) (1 non-finite values)"),
    ({"ids": Vt.Int64Array(list(range(3))), "invisibleIds": Vt.Int64Array([1])},
     "/World/Pawns.ids: 3 values for 16 protoIndices (invisibleIds and inactiveIds name instances by id: one id "
     "per instance)"),
], ids=["short-orientations", "short-scales", "short-positions", "short-orientations-at-a-time-sample",
        "protoIndex-out-of-range", "nan-scale", "ids-for-masking"])
def test_instancer_arrays_of_the_wrong_length_are_refused_before_compute(capsys, tmp_path, no_trace, arrays,
                                                                        expected):
    """OpenUSD warns about short orientations or scales and then reads past their end (AO differed run
    to run); usdbake names the attribute and both lengths."""
    source = pawns(tmp_path, **arrays)
    code, _, err = run_cli(capsys, "bake", source, "-o", tmp_path / "out.usda", *AO)
    assert_refused(code, err, expected)
    assert not (tmp_path / "out.usda").exists()


def instance_ao(layer_path: Path) -> np.ndarray:
    layer = Sdf.Layer.FindOrOpen(str(layer_path))
    return np.array(layer.GetAttributeAtPath("/World/Pawns.primvars:bake:ao").default)


def test_velocities_of_the_wrong_length_are_ignored_as_openusd_does(capsys, tmp_path):
    """OpenUSD's meaning: velocities of the wrong length are dropped with a warning and the instances
    placed as if they were zero. usdbake says so and bakes what a stage without them bakes."""
    short = pawns(tmp_path, velocities=[(1, 0, 0)] * 3)
    code, _, err = run_cli(capsys, "bake", short, "-o", tmp_path / "short.usda", *AO)
    assert code == 0, err
    assert ("warning: /World/Pawns.velocities: 3 values for 16 positions; ignored, as OpenUSD does (the "
            "instances are placed as if every value were zero)") in " ".join(err.split())
    (tmp_path / "plain").mkdir()
    plain = pawns(tmp_path / "plain")
    assert run_cli(capsys, "bake", plain, "-o", tmp_path / "plain.usda", *AO)[0] == 0
    np.testing.assert_array_equal(instance_ao(tmp_path / "short.usda"), instance_ao(tmp_path / "plain.usda"))


# ---------------------------------------------------------------------------
# Extreme scales and transforms


def scaled_cornell_box(folder: Path, scale: float) -> Path:
    """samples/cornell_box.usda under a uniform xformOp:scale on /World, in a layer of its own."""
    folder.mkdir(parents=True, exist_ok=True)
    layer = Sdf.Layer.CreateNew(str(folder / "scaled.usda"))
    layer.subLayerPaths.append(str(SAMPLES / "cornell_box.usda"))
    stage = Usd.Stage.Open(layer)
    UsdGeom.Xformable(stage.GetPrimAtPath("/World")).AddScaleOp(UsdGeom.XformOp.PrecisionDouble, "bakeTest").Set(
        Gf.Vec3d(scale, scale, scale))
    layer.Save()
    return folder / "scaled.usda"


def cornell_ao(capsys, folder: Path, scale: float) -> dict[str, np.ndarray]:
    source = scaled_cornell_box(folder, scale)
    code, _, err = run_cli(capsys, "bake", source, "-o", folder / "out.usda", *AO)
    assert code == 0, err
    layer = Sdf.Layer.FindOrOpen(str(folder / "out.usda"))
    meshes = ["Floor", "Ceiling", "BackWall", "RightWall", "LeftWall", "ShortBlock", "TallBlock"]
    return {m: np.array(layer.GetAttributeAtPath(f"/World/CornellBox/{m}.primvars:bake:ao").default) for m in meshes}


def test_ao_of_a_scaled_scene_is_the_unscaled_scenes(capsys, tmp_path):
    """The issue's case: 1e12 gave AO = 1 everywhere (the watertight test's t, a product of three
    coordinates, overflowed float32). Scaled by 1e-12 and 1e12 the Cornell box bakes the AO it bakes
    unscaled; by 2^-40 and 2^39, where the stored points scale exactly, bit for bit."""
    reference = cornell_ao(capsys, tmp_path / "unit", 1.0)
    assert 0.05 < np.mean(np.concatenate(list(reference.values()))) < 0.9  # occluded, not the AO = 1 failure
    for scale in (2.0 ** -40, 2.0 ** 39):  # 8.7e-10 and 5.3e14 units across
        scaled = cornell_ao(capsys, tmp_path / f"exact{scale:g}", scale)
        for mesh, values in reference.items():
            np.testing.assert_array_equal(scaled[mesh], values, err_msg=f"{mesh} at {scale:g}")
    for scale in (1e-12, 1e12):
        scaled = cornell_ao(capsys, tmp_path / f"decimal{scale:g}", scale)
        for mesh, values in reference.items():
            # Points rounded at another scale can flip a grazing ray: at most one of 64 per vertex here.
            np.testing.assert_allclose(scaled[mesh], values, atol=SINGLE_RAY_FLIP / 64 + FLOAT32_STORAGE,
                                       err_msg=f"{mesh} at {scale:g}")
            assert abs(scaled[mesh].mean() - values.mean()) < MEAN_FLIP_SHIFT


@pytest.mark.parametrize("scale, diagonal", [(1e15, "9.607e+17"), (1e-30, "9.607e-28")])
def test_a_scene_float32_cannot_hold_is_refused_naming_its_extent(capsys, tmp_path, no_trace, scale, diagonal):
    """1e15 and 1e-30 baked AO = 1 with exit 0 (and 'no sky-visible faces' at 1e-30)."""
    source = scaled_cornell_box(tmp_path, scale)
    code, _, err = run_cli(capsys, "bake", source, "-o", tmp_path / "out.usda", *AO)
    assert_refused(code, err, f"scaled.usda: the geometry spans {diagonal} stage units (bounding-box diagonal); "
                              f"usdbake computes in float32 and bakes extents from 1e-12 to 1e+15: scale the stage "
                              f"(an xformOp:scale on its root prim, and metersPerUnit to match)")


@pytest.mark.parametrize("scale, problem", [
    ((float("inf"), 1.0, 1.0), "its world transform holds a non-finite value (an xformOp of the prim or of a parent "
                               "is inf or nan)"),
    ((1e300, 1e300, 1e300), "point 0 overflows to (inf, 0.0, 0.0) in world space (3 such points): its transform, "
                            "or a parent's, scales it past float64"),
], ids=["inf", "overflow"])
def test_a_transform_that_is_not_finite_is_refused(capsys, tmp_path, no_trace, scale, problem):
    stage = new_stage()
    add_mesh(stage, "/World/Floor", [(0, 0, 0), (1, 0, 0), (1, 0, 1), (0, 0, 1)], [4], [0, 3, 2, 1])
    xform = UsdGeom.Xform.Define(stage, "/World/Big")
    xform.AddScaleOp(UsdGeom.XformOp.PrecisionDouble).Set(Gf.Vec3d(*scale))
    add_mesh(stage, "/World/Big/Tri", [(1e30, 0, 0), (0, 1e30, 0), (0, 0, 1e30)], [3], [0, 1, 2])
    stage.GetRootLayer().Export(str(tmp_path / "big.usda"))
    code, _, err = run_cli(capsys, "bake", tmp_path / "big.usda", "-o", tmp_path / "out.usda", *AO)
    assert_refused(code, err, f"/World/Big/Tri: {problem}")


def numeric_values(layer: Sdf.Layer) -> dict[str, np.ndarray]:
    """Every attribute value in ``layer`` that is an array of numbers, by attribute path."""
    found = {}

    def visit(path):
        if path.IsPropertyPath():
            value = layer.GetAttributeAtPath(path).default if layer.GetAttributeAtPath(path) else None
            try:
                array = np.asarray(value, np.float64)
            except (TypeError, ValueError):
                return
            if array.size and array.dtype == np.float64:
                found[str(path)] = array

    layer.Traverse(Sdf.Path.absoluteRootPath, visit)
    return found


@pytest.mark.parametrize("processor", ["ambient_occlusion", "sky_visibility", "irradiance_grid"])
def test_degenerate_triangles_bake_finite_values(capsys, tmp_path, processor):
    """Zero-area triangles, a sliver, two stacked copies of a face and a face of 1e-30 units, all below an
    ordinary quad: every value written is finite, and the quad sees the whole sky (AO exactly 1)."""
    stage = new_stage()
    add_mesh(stage, "/World/Floor", [(-5, 0, -5), (5, 0, -5), (5, 0, 5), (-5, 0, 5)], [4], [0, 3, 2, 1])
    add_mesh(stage, "/World/Top", [(0, 1, 0), (0, 1, 1), (1, 1, 1), (1, 1, 0)], [4], [0, 1, 2, 3])
    add_mesh(stage, "/World/Degenerate", [(3, .5, 0), (4, .5, 0), (5, .5, 0), (3, .5, 0)], [3, 3], [0, 1, 2, 0, 3, 1])
    add_mesh(stage, "/World/Sliver", [(-3, .5, 0), (-2, .5, 0), (-2.5, .5, 1e-7)], [3], [0, 1, 2])
    add_mesh(stage, "/World/Copies", [(2, .5, 2), (2, .5, 3), (3, .5, 2)] * 2, [3, 3], [0, 1, 2, 3, 4, 5])
    add_mesh(stage, "/World/Tiny", [(-4, .5, -4), (-4, .5, -4 + 1e-30), (-4 + 1e-30, .5, -4)], [3], [0, 1, 2])
    UsdLux.DomeLight.Define(stage, "/World/Sky").CreateIntensityAttr(1.0)
    stage.GetRootLayer().Export(str(tmp_path / "degenerate.usda"))
    code, _, err = run_cli(capsys, "bake", tmp_path / "degenerate.usda", "-o", tmp_path / "out.usda", "-p",
                           processor, "--force")
    assert code == 0, err
    layer = Sdf.Layer.FindOrOpen(str(tmp_path / "out.usda"))
    values = numeric_values(layer)
    written = [path for path in values if ":bake:" in path]
    assert written
    for path in written:
        assert np.isfinite(values[path]).all(), path
    if processor == "ambient_occlusion":
        np.testing.assert_array_equal(values["/World/Top.primvars:bake:ao"], 1.0)


# ---------------------------------------------------------------------------
# A huge dome texture


ISSUE_PNG = 10000
"""The issue's texture: 10000 x 10000 texels (a 285 KB PNG); read whole as float64 it cost 10 GB."""

MEMORY_LIMIT = 1536 * 2 ** 20
"""Peak resident memory allowed to a bake of the Cornell box with that texture: the bake without a dome
texture peaks near 0.55 GB here; one whole float64 copy of the texture alone is 2.4 GB."""


@pytest.mark.slow
@pytest.mark.parametrize("processor", ["ambient_occlusion", "irradiance_grid"])
def test_a_small_png_of_ten_thousand_texels_square_does_not_exhaust_memory(tmp_path, processor):
    """The issue's case, in a child process whose peak resident memory is measured (ru_maxrss): an
    ambient-occlusion bake never reads the texels, a bake that uses light reads them in strips into a
    1024 x 512 float32 map."""
    script = textwrap.dedent(f"""
        import resource, sys
        import numpy as np, OpenImageIO as oiio
        from pxr import Sdf, Usd, UsdLux
        n = {ISSUE_PNG}
        out = oiio.ImageOutput.create("sky.png")
        out.open("sky.png", oiio.ImageSpec(n, n, 3, oiio.UINT8))
        for first in range(0, n, 500):
            rows = np.linspace(255, 40, n).astype(np.uint8)[first:first + 500]
            out.write_scanlines(first, first + len(rows), 0, np.ascontiguousarray(
                np.broadcast_to(rows[:, None, None], (len(rows), n, 3))))
        out.close()
        layer = Sdf.Layer.CreateNew("dome.usda")
        layer.subLayerPaths.append({str(SAMPLES / "cornell_box.usda")!r})
        stage = Usd.Stage.Open(layer)
        dome = UsdLux.DomeLight.Define(stage, "/World/Sky")
        dome.CreateTextureFileAttr("./sky.png")
        layer.Save()
        from usdbake.cli.main import main
        code = main(["bake", "dome.usda", "-o", "out.usda", "-p", {processor!r}, "--force"])
        print("maxrss", resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024)
        sys.exit(code)
    """)
    result = subprocess.run([sys.executable, "-c", script], cwd=tmp_path, capture_output=True, text=True,
                            env={**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)}, timeout=600)
    assert result.returncode == 0, result.stderr
    peak = int(result.stdout.split("maxrss")[-1])
    assert peak < MEMORY_LIMIT, f"{peak / 2 ** 30:.2f} GB"
