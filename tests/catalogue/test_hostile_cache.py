"""The catalogue's hostile cache cases (issue 27, item 7): the cache is an optimisation, never a way to fail.

A cache entry hand-edited (a typo, one prim's values on another prim, an 8-value constant primvar),
or a cache that cannot be written (a full disk, ``ulimit -f``): each bake goes through the command,
exits 0 with exactly one ``warning: usdbake cache: ...`` line, and authors the values a fresh bake
authors. A read-only shared cache folder is read and warns once (the last case).
"""

from __future__ import annotations

import errno
import hashlib
import io
import json
import os
import resource
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from pxr import Gf, Usd, UsdGeom, Vt

from production_assets import instanced_board, new_stage
from read_only import ReadOnly
from usdbake import core
from usdbake.cli.main import main
from usdbake.core.cache import entry_sha256

FAST = ["--set", "ambient_occlusion.samples=64"]

CUBE = [(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0), (0, 0, 1), (1, 0, 1), (1, 1, 1), (0, 1, 1)]
CUBE_FACES = [0, 3, 2, 1, 4, 5, 6, 7, 0, 1, 5, 4, 2, 3, 7, 6, 1, 2, 6, 5, 0, 4, 7, 3]  # outward quads


def floor_and_cube(folder: Path, *, cells: int = 1) -> Path:
    """A floor of cells x cells quads ((cells + 1)^2 points: 4 for one cell) and a welded 8-point cube on it."""
    path = folder / f"floor_and_cube_{cells}.usda"
    stage = new_stage(path)
    edge = np.linspace(-200.0, 200.0, cells + 1)
    floor = UsdGeom.Mesh.Define(stage, "/World/Floor")
    floor.CreatePointsAttr(Vt.Vec3fArray([Gf.Vec3f(float(x), 0.0, float(z)) for z in edge for x in edge]))
    corner = np.arange(cells)[:, None] * (cells + 1) + np.arange(cells)[None, :]
    quads = np.stack([corner, corner + cells + 1, corner + cells + 2, corner + 1], axis=-1).reshape(-1)
    floor.CreateFaceVertexCountsAttr([4] * cells * cells)
    floor.CreateFaceVertexIndicesAttr(Vt.IntArray(quads.tolist()))
    cube = UsdGeom.Mesh.Define(stage, "/World/Cube")
    cube.CreatePointsAttr(Vt.Vec3fArray([Gf.Vec3f(100.0 * x - 50.0, 100.0 * y, 100.0 * z - 50.0) for x, y, z in CUBE]))
    cube.CreateFaceVertexCountsAttr([4] * 6)
    cube.CreateFaceVertexIndicesAttr(CUBE_FACES)
    stage.Save()
    return path


def bake(*argv) -> tuple[int, list[str], dict]:
    """(exit code, the cache's warning lines, {processor: action}) of ``usdbake bake ... --json``, in
    process; the command prints each warning as one ``warning: ...`` line on stderr."""
    stdout, stderr = io.StringIO(), io.StringIO()
    real = sys.stdout, sys.stderr
    sys.stdout, sys.stderr = stdout, stderr
    try:
        code = main([str(a) for a in (*argv, "--json", *FAST)])
    finally:
        sys.stdout, sys.stderr = real
    report = json.loads(stdout.getvalue()) if code == 0 else {"steps": []}
    lines = [line.removeprefix("warning: ") for line in stderr.getvalue().splitlines()
             if line.startswith("warning: usdbake cache:")]
    return code, lines, {step["processor"]: step["action"] for step in report["steps"]}


def baked_values(path: Path) -> dict[str, tuple[str, np.ndarray]]:
    """{prim: (interpolation, values)} of every primvars:bake:ao a layer's stage holds."""
    stage = Usd.Stage.Open(str(path))
    found = {}
    for prim in stage.Traverse():
        primvar = UsdGeom.PrimvarsAPI(prim).GetPrimvar("bake:ao")
        if primvar and primvar.HasAuthoredValue():
            found[str(prim.GetPath())] = (primvar.GetInterpolation(), np.asarray(primvar.Get()))
    return found


def assert_same_bake(path: Path, reference: Path) -> None:
    got, expected = baked_values(path), baked_values(reference)
    assert got.keys() == expected.keys() and got
    for prim, (interpolation, values) in expected.items():
        assert got[prim][0] == interpolation, prim
        np.testing.assert_array_equal(got[prim][1], values, err_msg=prim)  # fixed seed: the same bits


@pytest.fixture
def cached(tmp_path):
    """Bake ``source`` once into a fresh cache and once more into a reference without it; returns
    (cache folder, its one manifest, the reference output)."""
    def make(source: Path) -> tuple[Path, Path, Path]:
        cache_dir, reference = tmp_path / "cache", tmp_path / "reference.usda"
        code, warned, actions = bake("bake", source, "-o", tmp_path / "first.usda", "--cache", cache_dir)
        assert (code, warned, actions) == (0, [], {"ambient_occlusion": "run"})
        assert bake("bake", source, "-o", reference, "--cache", tmp_path / "fresh")[:2] == (0, [])
        (manifest,) = cache_dir.glob("*.json")
        return cache_dir, manifest, reference
    return make


def record_of(content: dict, prim: str, interpolation: str) -> dict:
    """The tree node of the output record of ``prim`` with ``interpolation``."""
    (node,) = [r for r in content["tree"]["fields"]["outputs"]
               if r["fields"]["prim"] == prim and r["fields"].get("interpolation") == interpolation]
    return node["fields"]


def plant(manifest: Path, prim: str, interpolation: str, values: np.ndarray) -> None:
    """Give the record of ``prim`` these values, and seal the entry as the cache would (arrays file named
    and hashed by content, manifest hash recomputed): only the check against the scene can refuse it."""
    content = json.loads(manifest.read_text())
    old = manifest.with_name(f"{manifest.stem}.{content['arrays_sha256'][:16]}.npz")
    with np.load(old) as npz:
        arrays = {name: npz[name] for name in npz.files}
    record = record_of(content, prim, interpolation)
    record["values"] = {"$": "array", "name": "planted", "dtype": values.dtype.str, "shape": list(values.shape),
                        "readonly": False}
    arrays["planted"] = values
    buffer = io.BytesIO()
    np.savez(buffer, **arrays)
    content["arrays_sha256"] = hashlib.sha256(buffer.getvalue()).hexdigest()
    manifest.with_name(f"{manifest.stem}.{content['arrays_sha256'][:16]}.npz").write_bytes(buffer.getvalue())
    content["sha256"] = entry_sha256(content)
    manifest.write_text(json.dumps(content))


def recomputed(manifest: Path, why: str) -> str:
    return f"usdbake cache: {manifest}: {why}; recomputing"


# ---------------------------------------------------------------------------
# Entries that are not what the cache wrote


def test_a_one_character_typo_in_a_manifest_is_recomputed(cached, tmp_path):
    """'float' -> 'flaot' in one record's type: it used to crash the writer (TypeError from Sdf)."""
    source = floor_and_cube(tmp_path)
    cache_dir, manifest, reference = cached(source)
    text = manifest.read_text()
    manifest.write_text(text.replace('"type_name":"float"', '"type_name":"flaot"', 1))
    out = tmp_path / "out.usda"
    assert bake("bake", source, "-o", out, "--cache", cache_dir) == (
        0, [recomputed(manifest, "entry hash mismatch (the manifest was edited)")], {"ambient_occlusion": "run"})
    assert_same_bake(out, reference)
    assert bake("bake", source, "-o", out, "--cache", cache_dir) == (0, [], {"ambient_occlusion": "cached"})


def test_one_prims_values_on_anothers_points_are_recomputed(cached, tmp_path):
    """The Cube's 8 AO values on the Floor's 4 points, the entry resealed: the scene refuses it."""
    source = floor_and_cube(tmp_path)
    cache_dir, manifest, reference = cached(source)
    cube = baked_values(reference)["/World/Cube"][1].astype(np.float32)
    assert len(cube) == 8
    plant(manifest, "/World/Floor", "vertex", cube)
    out = tmp_path / "out.usda"
    assert bake("bake", source, "-o", out, "--cache", cache_dir) == (
        0, [recomputed(manifest, "does not fit the scene (/World/Floor: 8 vertex values for 4 points)")],
        {"ambient_occlusion": "run"})
    assert_same_bake(out, reference)
    assert bake("bake", source, "-o", out, "--cache", cache_dir) == (0, [], {"ambient_occlusion": "cached"})


def test_an_eight_value_constant_primvar_is_recomputed(cached, tmp_path):
    """A native instance's per-instance AO (constant: one value) given 8 values."""
    source = instanced_board(tmp_path)
    cache_dir, manifest, reference = cached(source)
    assert baked_values(reference)["/World/Pawns/Pawn_0"][0] == "constant"
    plant(manifest, "/World/Pawns/Pawn_0", "constant", np.full(8, 0.5, np.float32))
    out = tmp_path / "out.usda"
    assert bake("bake", source, "-o", out, "--cache", cache_dir) == (
        0, [recomputed(manifest, "does not fit the scene (/World/Pawns/Pawn_0: 8 constant values, not one element)")],
        {"ambient_occlusion": "run"})
    assert_same_bake(out, reference)


def test_a_point_instancer_short_of_instances_is_recomputed(cached, tmp_path):
    """A PointInstancer's per-instance AO (vertex: one value per authored instance) one value short."""
    source = instanced_board(tmp_path)
    cache_dir, manifest, reference = cached(source)
    assert baked_values(reference)["/World/Row"][1].shape == (4,)
    plant(manifest, "/World/Row", "vertex", np.full(3, 0.5, np.float32))
    out = tmp_path / "out.usda"
    assert bake("bake", source, "-o", out, "--cache", cache_dir) == (
        0, [recomputed(manifest, "does not fit the scene (/World/Row: 3 vertex values for 4 instances)")],
        {"ambient_occlusion": "run"})
    assert_same_bake(out, reference)


# ---------------------------------------------------------------------------
# A cache that cannot be written


def unwritable(cache_dir: Path, strerror: str) -> str:
    return f"usdbake cache: cannot write in {cache_dir} ({strerror}); results of this run are not cached"


class FullDisk(io.FileIO):
    """A file on a disk with 100 bytes free: the write that passes them raises ENOSPC."""

    def write(self, data) -> int:
        if self.tell() + len(data) > 100:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        return super().write(data)


def test_a_full_cache_disk_warns_once_and_the_bake_completes(tmp_path, monkeypatch):
    source = floor_and_cube(tmp_path)
    reference, out, cache_dir = tmp_path / "reference.usda", tmp_path / "out.usda", tmp_path / "cache"
    assert bake("bake", source, "-o", reference, "--cache", tmp_path / "fresh")[:2] == (0, [])
    real_open = open
    monkeypatch.setattr(core.cache, "open", lambda path, mode="r", *args, **kwargs: FullDisk(path, "w")
                        if "w" in mode else real_open(path, mode, *args, **kwargs), raising=False)
    assert bake("bake", source, "-o", out, "--cache", cache_dir) == (
        0, [unwritable(cache_dir, "No space left on device")], {"ambient_occlusion": "run"})
    assert_same_bake(out, reference)
    assert list(cache_dir.iterdir()) == []  # the partial arrays file was removed


FILE_SIZE_LIMITED = """
import resource, sys
resource.setrlimit(resource.RLIMIT_FSIZE, ({limit}, resource.getrlimit(resource.RLIMIT_FSIZE)[1]))
from usdbake.cli.main import main
sys.exit(main({argv!r}))
"""


@pytest.mark.skipif(not hasattr(resource, "RLIMIT_FSIZE"), reason="no file size limit on this platform")
def test_a_file_size_limit_warns_once_and_the_bake_completes(tmp_path):
    """``ulimit -f``, for real: Python ignores SIGXFSZ, so a write past the limit is OSError EFBIG. The
    limit sits between the bake layer's size and the cache entry's, so only the cache cannot be written."""
    source = floor_and_cube(tmp_path, cells=60)  # 3721 floor points: the entry holds them twice, the layer once
    reference, out, cache_dir = tmp_path / "reference.usdc", tmp_path / "out.usdc", tmp_path / "cache"
    assert bake("bake", source, "-o", reference, "--cache", tmp_path / "fresh")[:2] == (0, [])
    (entry,) = (tmp_path / "fresh").glob("*.npz")
    limit = (reference.stat().st_size + entry.stat().st_size) // 2
    assert reference.stat().st_size < limit < entry.stat().st_size
    argv = ["bake", str(source), "-o", str(out), "--cache", str(cache_dir), *FAST]
    done = subprocess.run([sys.executable, "-c", FILE_SIZE_LIMITED.format(limit=limit, argv=argv)],
                          capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    assert "Traceback" not in done.stderr
    assert done.stderr.count("usdbake cache:") == 1
    assert f"warning: {unwritable(cache_dir, os.strerror(errno.EFBIG))}\n" in done.stderr
    assert_same_bake(out, reference)
    assert not [path for path in cache_dir.iterdir() if path.suffix in (".json", ".npz")]


def test_a_read_only_cache_folder_is_read_and_the_bake_warns_once(tmp_path):
    """A shared cache others fill and this user may only read: served, and a new entry warns once."""
    source = floor_and_cube(tmp_path)
    cache_dir, reference, out = tmp_path / "cache", tmp_path / "reference.usda", tmp_path / "out.usda"
    assert bake("bake", source, "-o", reference, "--cache", cache_dir)[:2] == (0, [])
    locker = ReadOnly(cache_dir)
    try:
        strerror = locker.lock()
        assert bake("bake", source, "-o", out, "--cache", cache_dir) == (0, [], {"ambient_occlusion": "cached"})
        assert bake("bake", source, "-o", out, "--cache", cache_dir, "--set", "ambient_occlusion.seed=1") == (
            0, [unwritable(cache_dir, strerror)], {"ambient_occlusion": "run"})
    finally:
        locker.unlock()
