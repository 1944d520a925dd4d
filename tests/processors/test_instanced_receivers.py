"""Instanced receivers get AO where USD can hold it (issue: real assets, item 3).

The reference is the flattened twin of the same board (``production_assets.instanced_board``
with ``instanced=False``): the same pawns as ordinary prims, baked per vertex. An instance's
mean is the area-weighted mean of its surface's per-vertex AO, as ``processors/occlusion/instances.py``
defines it, recomputed here from the twin's Scene.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from pxr import Usd, UsdGeom

import usdbake
from production_assets import instanced_board
from usdbake.core.errors import UsageError
from usdbake.stages.extract import extract_scene
from usdbake.stages.hook import last_report

from tolerances import INSTANCE_MEAN_AO, INSTANCE_VERTEX_AO

SAMPLES = 256


def bake(path, deinstance=False, **ao_params):
    stage = Usd.Stage.Open(str(path))
    layer = usdbake.bake(stage, ["ambient_occlusion"], {"ambient_occlusion": {"samples": SAMPLES, **ao_params}},
                         cache_dir=None, deinstance=deinstance)
    return stage, layer


def ao(stage, path) -> np.ndarray:
    return np.asarray(UsdGeom.PrimvarsAPI(stage.GetPrimAtPath(path)).GetPrimvar("bake:ao").Get())


def flat_instance_means(tmp_path) -> dict[str, float]:
    """Area-weighted mean AO of each pawn of the flattened twin, by the pawn's prim path."""
    stage, _ = bake(instanced_board(tmp_path, instanced=False))
    scene = extract_scene(stage)
    means = {}
    for root in [f"/World/Pawns/Pawn_{k}" for k in range(4)] + [f"/World/Row/Pawn_{k}" for k in range(4)]:
        total = weight = 0.0
        for prim, path in enumerate(scene.prim_paths):
            if path.startswith(root + "/"):
                values = ao(stage, path)
                tris = scene.tri_prim == prim
                local = scene.tri_vertices[tris] - scene.prim_point_start[prim]
                total += float((values[local].mean(axis=1) * scene.tri_areas[tris]).sum())
                weight += float(scene.tri_areas[tris].sum())
        means[root] = total / weight
    return means


def test_native_instances_and_point_instancer_rows_get_their_mean(tmp_path):
    expected = flat_instance_means(tmp_path)
    stage, layer = bake(instanced_board(tmp_path))
    for k in range(4):
        root = f"/World/Pawns/Pawn_{k}"
        primvar = UsdGeom.PrimvarsAPI(stage.GetPrimAtPath(root)).GetPrimvar("bake:ao")
        assert primvar.GetInterpolation() == "constant"
        assert abs(float(primvar.Get()[0]) - expected[root]) < INSTANCE_MEAN_AO
        user = stage.GetPrimAtPath(root).GetAttribute("userProperties:bake:ao")  # what Blender 5 imports
        assert user.IsCustom() and user.Get() == float(primvar.Get()[0])
    row = UsdGeom.PrimvarsAPI(stage.GetPrimAtPath("/World/Row")).GetPrimvar("bake:ao")
    assert row.GetInterpolation() == "vertex" and len(row.Get()) == 4  # one per instance
    np.testing.assert_allclose(row.Get(), [expected[f"/World/Row/Pawn_{k}"] for k in range(4)],
                               atol=INSTANCE_MEAN_AO)
    messages = last_report(layer)[0]["messages"]
    assert any("4 native instances: per-instance mean AO" in m for m in messages)
    assert any(m.startswith("/World/Row: per-instance mean AO of its 4 instances") for m in messages)
    # the meshes a renderer draws inherit the instance's value
    proxy = stage.GetPrimAtPath("/World/Pawns/Pawn_0/Base")
    inherited = UsdGeom.PrimvarsAPI(proxy).FindPrimvarWithInheritance("bake:ao")
    assert inherited and inherited.GetInterpolation() == "constant"


def test_deinstancing_gives_per_vertex_ao_like_the_flattened_twin(tmp_path):
    flat, _ = bake(instanced_board(tmp_path, instanced=False))
    stage, layer = bake(instanced_board(tmp_path), deinstance=True)
    for k in range(4):
        root = f"/World/Pawns/Pawn_{k}"
        assert not stage.GetPrimAtPath(root).IsInstanceable()
        for part in ("Base", "Head"):
            values, reference = ao(stage, f"{root}/{part}"), ao(flat, f"{root}/{part}")
            assert len(values) == len(reference) == 24
            assert abs(values.mean() - reference.mean()) < INSTANCE_MEAN_AO
            assert np.abs(np.sort(values) - np.sort(reference)).max() < INSTANCE_VERTEX_AO
    assert UsdGeom.PrimvarsAPI(stage.GetPrimAtPath("/World/Row")).GetPrimvar("bake:ao").HasValue()


def test_a_scene_made_only_of_instances_is_baked(tmp_path):
    stage, layer = bake(instanced_board(tmp_path, floor=False, name="only_instances.usda"))
    assert last_report(layer)[0]["action"] == "run"
    assert UsdGeom.PrimvarsAPI(stage.GetPrimAtPath("/World/Pawns/Pawn_0")).GetPrimvar("bake:ao").HasValue()


def test_instances_skip_keeps_them_out(tmp_path):
    with pytest.raises(UsageError, match="nothing to bake"):
        bake(instanced_board(tmp_path, floor=False, name="only_instances.usda"), instances="skip")


# ---------------------------------------------------------------------------
# Native instances are instances for displacement_fields and instance_ao too

FIELD_PARAMS = {"force": "Pawn", "positional_samples": 1089, "direction_map_size": 16}


def test_native_and_point_instanced_copies_of_one_asset_share_one_field(tmp_path):
    stage = Usd.Stage.Open(str(instanced_board(tmp_path)))
    layer = usdbake.bake(stage, ["displacement_fields"], {"displacement_fields": FIELD_PARAMS})
    messages = last_report(layer)[0]["messages"]
    assert "/World/Row/Prototypes/Pawn: shares the field of /Assets/Pawn (same shape)" in messages
    files = set()
    for path in [f"/World/Pawns/Pawn_{k}" for k in range(4)] + ["/World/Row/Prototypes/Pawn"]:
        prim = stage.GetPrimAtPath(path)
        assert prim.HasAPI("DisplacementFieldAPI") if hasattr(prim, "HasAPI") else True
        files.add(prim.GetAttribute("bake:field:file").Get().resolvedPath)
    assert len(files) == 1 and all(Path(f).is_file() for f in files)  # one texture for the 8 pawns


def test_instance_ao_reads_native_instances_through_their_field(tmp_path):
    stage = Usd.Stage.Open(str(instanced_board(tmp_path)))
    exact, _ = bake(instanced_board(tmp_path, name="exact.usda"))
    usdbake.bake(stage, ["instance_ao"], {"displacement_fields": FIELD_PARAMS,
                                          "instance_ao": {"samples": SAMPLES, "instances": True}})
    for k in range(4):
        root = f"/World/Pawns/Pawn_{k}"
        value = UsdGeom.PrimvarsAPI(stage.GetPrimAtPath(root)).GetPrimvar("bake:ao")
        assert value.GetInterpolation() == "constant"
        reference = ao(exact, root)[0]
        assert abs(float(value.Get()[0]) - reference) < INSTANCE_MEAN_AO
    np.testing.assert_allclose(ao(stage, "/World/Row"), ao(exact, "/World/Row"), atol=INSTANCE_MEAN_AO)
