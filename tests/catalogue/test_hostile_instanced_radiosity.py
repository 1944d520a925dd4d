"""The catalogue, resources (issue 27): radiosity on instanced layouts.

A 1,280-triangle prototype under 4 PointInstancers took 5.7 GB and 86 s in form_factors at 1,000 instances
(6,004 patches against a target of 2,000): every instance had patches of its own, so the dense n x n parts
grew with the square of the instance count. Instances receive no output of radiosity (they occlude and
reflect), so their triangles now share patches across instances (one voxel, one normal axis, one albedo
step) and the patch count follows ``target_patches``; receiver meshes keep patches of their own.

Bakes run through the command (``usdbake.cli.main.main``); the work is asserted by counting (patches,
form-factor rays), never by timing. Timings are printed (``pytest -s``); memory and seconds at 250 and
1,000 instances come from ``python -m usdbake.benchmarks.instanced_radiosity_memory`` (docs/radiosity.md).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
from pxr import Sdf, Usd, UsdGeom

from usdbake.benchmarks.instanced_radiosity_memory import write_layout
from usdbake.cli.main import main

TARGET = 150
FAST = ["--set", f"form_factors.target_patches={TARGET}", "--set", "form_factors.rays=64",
        "--set", "radiosity.gather_rays=16", "--set", "radiosity.light_samples=4",
        "--set", "radiosity.sky_samples=16", "--set", "radiosity.patch_points=4"]
PATCH_SLACK = 1.35
"""choose_voxel_size stops within a few refinements of the target: measured 0.98-1.05 x here."""


def bake(tmp_path: Path, source: Path, *args: str) -> Path:
    """Bake ``source`` with -p radiosity (cache of its own; the input must not change); the output layer."""
    out = tmp_path / f"{source.stem}.baked.usdc"
    before = source.read_bytes()
    code = main(["bake", str(source), "-o", str(out), "-p", "radiosity", "--json",
                 "--cache", str(tmp_path / f"cache-{source.stem}"), *FAST, *args])
    assert code == 0
    assert source.read_bytes() == before
    return out


def report(capsys) -> dict:
    return json.loads(capsys.readouterr().out)


def patch_count(out: Path) -> int:
    layer = Sdf.Layer.FindOrOpen(str(out))
    return len(layer.GetAttributeAtPath("/usdbake/RadiosityPatches.areas").default)


def step(data: dict, name: str) -> dict:
    return next(s for s in data["steps"] if s["processor"] == name)


def test_patches_and_form_factor_work_do_not_grow_with_the_instance_count(tmp_path, capsys):
    """64 and 512 instances of a 320-triangle sphere on one floor: the patch count keeps to the target at
    both (before: >= 6 a sphere, 3,000+ at 512), the form-factor rays follow the patches, and radiosity
    writes the floor only (instances get no primvars)."""
    rows = {}
    for count in (64, 512):
        source = tmp_path / f"layout_{count}.usda"
        triangles = write_layout(source, count, level=2)
        out = bake(tmp_path, source)
        data = report(capsys)
        rows[count] = {"patches": patch_count(out), "rays": step(data, "form_factors")["rays"],
                       "seconds": {s["processor"]: s["seconds"] for s in data["steps"]}, **triangles}
        stage = Usd.Stage.Open(str(out))
        written = [p.GetPath().pathString for p in stage.Traverse()
                   if UsdGeom.PrimvarsAPI(p).HasPrimvar("bake:irradianceIndirect")]
        assert written == ["/World/Floor"]
        indirect = np.array(UsdGeom.PrimvarsAPI(stage.GetPrimAtPath("/World/Floor"))
                            .GetPrimvar("bake:irradianceIndirect").Get())
        assert np.isfinite(indirect).all() and indirect.max() > 0  # light bounced off the spheres
    print(f"radiosity on instanced layouts, target_patches={TARGET}: {rows}")
    for row in rows.values():
        assert row["patches"] <= PATCH_SLACK * TARGET
    assert rows[512]["patches"] <= PATCH_SLACK * rows[64]["patches"]
    assert rows[512]["rays"] <= PATCH_SLACK * rows[64]["rays"]  # rays per patch x patches: no instance term


def test_a_radiosity_without_light_runs_no_form_factors_on_instances(tmp_path, capsys):
    """The issue's other half: a skipped processor still ran its dependencies (form_factors, 100 s and
    6.4 GB at 1,000 instances). Without a light radiosity does not apply, and form_factors, which only it
    needed, is skipped too: nothing is computed, the command says why and writes nothing (exit 2)."""
    source = tmp_path / "dark.usda"
    write_layout(source, 512, level=2, lights=False)
    before = source.read_bytes()
    out = tmp_path / "dark.baked.usdc"
    code = main(["bake", str(source), "-o", str(out), "-p", "radiosity", "--cache", str(tmp_path / "cache")])
    err = capsys.readouterr().err
    assert code == 2 and not out.exists() and source.read_bytes() == before
    assert "form_factors skipped (needed only by radiosity (skipped))" in err
    assert "radiosity skipped (not applicable: no lights" in err
