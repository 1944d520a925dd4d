"""The daylight family's texture target (issue 31): sky exposure per texel against Embree, daylight per texel
against Radiance, seams, untouched meshes, and its cost beside the vertex target.

Figures:
- sky exposure (sky_visibility's sum_j V_ij dw_j / pi, at the defaults: 256 uniform patches, 4 rays each) at
  1000 random texels whose centre lies inside their triangle, against Embree (embreex) tracing 16384 float64
  cosine-weighted rays per texel about the owning face's normal from the texel's point (origin 1e-5 of the scene
  diagonal along it), a ray counting when it escapes above the horizon; as ``rms_over_noise`` with the noise of
  two seeds of ours and the reference's own binomial variance; on the furnished room (bench_lightmaps' stage:
  open windows, ground and exterior skins ``bake:skip``, 32 texels/m) and on the plan benchmark's city (Y-up
  centimetres, 270k triangles, every mesh charted by xatlas, 1 texel/m);
- texel pairs across UV seams (different charts, one world point within a quarter texel, normals within
  cos 0.99): RMS exposure difference / their noise;
- the glazed furnished room (bench_daylight_bounces' stage, VLT 0.7, its own ground; ground and outer skin
  ``bake:skip``: they occlude and reflect but get no texels) under one uniform sky with 5 bounces, baked with
  ``target=both``: the irradiance lightmap read back from the files (bilinear, through the
  mesh's lightmap UVs) at the 150 random surface points of Radiance's cached rtrace -ab 6 reference, its median
  |relative error| beside the refined faces' of the same bake; the composed meshes of a ``target=texture`` bake
  byte-identical to the input's; the bake times, layer sizes and peak memory (each bake in a child process,
  VmHWM) of the vertex and texture targets;
- the LM-83 office (bench_daylight_bounces' stage) baked by ``annual_daylight`` with ``target=both``: mean
  occupied illuminance and daylight factor read from its lightmaps at the 170 floor sensors against Radiance's
  cached two-phase reference (rcontrib -ab 6), and sDA over the sensors, beside the refined faces' of the same
  bake.
Quick mode (the smoke run): the room's exposure at 8 texels/m with a 1024-ray reference when Embree is there.
"""

from __future__ import annotations

import json
import math
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from . import harness
from .bench_lightmaps import composed_meshes, embree_ao, has_embree, interior, prepared, room_scene, seam_pairs

NAME = "daylight_lightmaps"
DESCRIPTION = __doc__.split("\n\n", 1)[1].strip()
REFERENCE_RAYS = 16384
"""16x the ~1000 rays our exposure takes per texel (4 per patch, up to 256 patches above the face)."""
TEXELS_CHECKED = 1000
ROOM_CELL = 0.1
RGB_LUMINANCE = np.array([0.265, 0.670, 0.065])
"""Radiance's luminance weights (the reference's own)."""


def texel_exposure(scene, density: float, seeds=(0, 1)):
    """(page, [exposure of the page's texels per seed], seconds of the first) at sky_visibility's defaults."""
    from usdbake.geometry.mesh import receiver_prims
    from usdbake.kernels.sky import patch_layout
    from usdbake.kernels.tracer import Tracer
    from usdbake.processors.daylight.sky_visibility import compute_sky_visibility
    from usdbake.processors.daylight.texel_receivers import compute_texel_visibility

    tracer = Tracer.from_scene(scene)
    # the face product only gives the texels their patch layout and frame: one prim's faces keep it cheap
    sky, _ = compute_sky_visibility(tracer, scene, patches=patch_layout("uniform", count=256), adaptive=False,
                                    prims=receiver_prims(scene)[:1], max_face_area=0.0)
    layout, pages, _, _ = prepared(scene, density)
    page = max(pages, key=lambda p: len(p.texel))
    values, seconds = [], 0.0
    for seed in seeds:
        started = time.perf_counter()
        texels = compute_texel_visibility(tracer, scene, sky, layout, [page], samples=4, seed=seed, margin=16,
                                          denoise=False)
        seconds = seconds or time.perf_counter() - started
        values.append(texels.view.exposure.astype(np.float64))
    return page, values, seconds


def exposure_accuracy(label: str, scene, density: float, rays: int, seed: int) -> dict:
    """Sky exposure at interior texels against Embree, and across seams (module docstring); without Embree (a
    bench extra, ".[bench]") the texel count, time, noise and seams only."""
    page, (ours, other), seconds = texel_exposure(scene, density)
    candidates = interior(page)
    chosen = np.random.default_rng(seed).choice(candidates, min(TEXELS_CHECKED, len(candidates)), replace=False)
    noise = math.sqrt(np.mean((ours[chosen] - other[chosen]) ** 2) / 2)
    figures = {f"{label}_texels": int(len(page.texel)), f"{label}_exposure_seconds": round(seconds, 2),
               f"{label}_exposure_noise": round(noise, 5)}
    pairs = seam_pairs(page, density)
    if len(pairs):
        difference = math.sqrt(np.mean((ours[pairs[:, 0]] - ours[pairs[:, 1]]) ** 2))
        pair_noise = math.sqrt(np.mean((ours[pairs].ravel() - other[pairs].ravel()) ** 2) / 2)
        figures[f"{label}_seam_pairs"] = int(len(pairs))
        figures[f"{label}_seam_rms_over_pair_noise"] = round(difference / (math.sqrt(2) * pair_noise), 3)
    if not has_embree():
        return figures
    faces = scene.tri_normals[page.triangle[chosen]]
    reference = harness.cached_reference(
        f"daylight_lightmap_exposure_{label}", {"rays": rays, "texels": len(chosen), "density": density,
                                                 "seed": seed, "triangles": scene.num_triangles, "version": 1},
        lambda: {"exposure": embree_ao(scene, page.points[chosen], faces, faces, rays, seed=seed + 1,
                                       up=scene.up_vector)})["exposure"]
    rms = math.sqrt(np.mean((ours[chosen] - reference) ** 2))
    allowed = math.sqrt(noise ** 2 + float(np.mean(reference * (1 - reference))) / rays)
    figures.update({f"{label}_exposure_rms": round(rms, 5),
                    f"{label}_exposure_bias": round(float(np.mean(ours[chosen] - reference)), 5),
                    f"{label}_exposure_rms_over_noise": round(rms / allowed, 3)})
    return figures


def city_scene():
    from pxr import Usd

    from usdbake.stages.extract import extract_scene

    from .city_stage import cached_stage

    return extract_scene(Usd.Stage.Open(str(cached_stage(270_000))))


BACKDROPS = ("/World/Ground", "/World/Room/Exterior")
"""The glazed room's 200 m ground and outer skin: ``bake:skip`` for the texture target (they occlude and reflect
but get no texels; at 32 texels/m the ground alone would be a 4096^2 page, which the bake refuses)."""


def skip_backdrops(stage) -> None:
    from pxr import Sdf

    for path in BACKDROPS:
        stage.GetPrimAtPath(path).CreateAttribute("bake:skip", Sdf.ValueTypeNames.Bool).Set(True)


def radiance_figures() -> dict:
    """The glazed room's irradiance lightmap against Radiance at its 150 reference points, beside the faces'."""
    import usdbake

    from .daylight_references import furnished_reference
    from .furnished_daylight_room import furnished_daylight_room
    from .stage_readback import sample_baked, sample_lightmap

    scene = furnished_daylight_room()
    reference = furnished_reference(scene)
    skip_backdrops(scene.stage)  # after the reference: Radiance sees every surface, as the bake does
    params = {"daylight": {"sky": "uniform", "uniform_radiance": float(reference["sky_radiance"]), "sun": False}}
    figures = {}
    with tempfile.TemporaryDirectory() as folder:
        started = time.perf_counter()
        usdbake.bake(scene.stage, processors=["daylight"], params=params, target="both", texture_dir=folder)
        figures["room_both_seconds"] = round(time.perf_counter() - started, 2)
        theirs = reference["irradiance"] @ RGB_LUMINANCE
        faces = sample_baked(scene.stage, "bake:daylightIrradiance", reference["points"], reference["normals"])
        texels = sample_lightmap(scene.stage, "daylightIrradiance", reference["points"], reference["normals"],
                                 prims=reference["prims"])
        for label, ours in (("faces", faces @ RGB_LUMINANCE), ("texels", texels @ RGB_LUMINANCE)):
            error = (ours - theirs) / np.maximum(theirs, 1e-9)
            figures[f"room_{label}_points"] = int(np.isfinite(error).sum())
            figures[f"room_{label}_median_abs_error"] = round(float(np.nanmedian(np.abs(error))), 4)
            figures[f"room_{label}_bias"] = round(float(np.nanmedian(error)), 4)
    return figures


def office_annual_figures() -> dict:
    """The LM-83 office's annual metrics from its lightmaps against Radiance's two-phase reference at the 170
    floor sensors, beside the refined faces' of the same ``target=both`` bake (Greensboro TMY3, occupied 8-18 h)."""
    import usdbake

    from .bench_annual_daylight import tmy3
    from .daylight_references import office_reference
    from .daylight_scenes import lm83_office
    from .radiance_sky import cie_overcast_sky
    from .stage_readback import sample_baked, sample_lightmap

    scene = lm83_office()
    reference = office_reference(scene)
    hours = reference["times"]
    hour = (hours - hours.astype("datetime64[D]")).astype(np.float64) / 60.0
    hourly = reference["illuminance"][(hour >= 8.0) & (hour < 18.0)]
    overcast, horizontal = cie_overcast_sky(4, ground_reflectance=0.2)
    theirs = {"meanIlluminance": hourly.mean(axis=0),
              "daylightFactor": 100.0 * np.einsum("spc,p->sc", reference["dc"], overcast) @ RGB_LUMINANCE
              / horizontal}
    figures = {"office_sda_radiance": round(float(((hourly >= 300).mean(axis=0) >= 0.5).mean()), 4)}
    with tempfile.TemporaryDirectory() as folder:
        started = time.perf_counter()
        usdbake.bake(scene.stage, processors=["annual_daylight"], target="both", texture_dir=folder,
                     params={"annual_daylight": {"weather": str(tmy3()), "sensor_prims": "Floor"}})
        figures["office_both_seconds"] = round(time.perf_counter() - started, 2)
        prims = list(scene.sensor_prims)
        for name in ("meanIlluminance", "daylightFactor", "daylightAutonomy"):
            at = {"faces": sample_baked(scene.stage, f"bake:{name}", scene.sensor_points, scene.sensor_normals)[:, 0],
                  "texels": sample_lightmap(scene.stage, name, scene.sensor_points, scene.sensor_normals,
                                            prims=prims)[:, 0]}
            for label, ours in at.items():
                if name == "daylightAutonomy":
                    figures[f"office_{label}_sda"] = round(float((ours >= 0.5).mean()), 4)
                    continue
                error = (ours - theirs[name]) / np.maximum(theirs[name], 1e-9)
                short = "mean_illuminance" if name == "meanIlluminance" else "df"
                figures[f"office_{label}_{short}_median_abs_error"] = round(float(np.nanmedian(np.abs(error))), 4)
                figures[f"office_{label}_{short}_bias"] = round(float(np.nanmedian(error)), 4)
    return figures


def target_bake(target: str) -> dict:
    """The glazed room's daylight bake (uniform sky) at ``target``, in this process: seconds, bake layer size,
    whether the composed meshes stayed identical, and the process's peak resident memory (VmHWM, MB)."""
    import usdbake
    from pxr import Usd

    from .furnished_daylight_room import room_stage

    stage = room_stage(cell=ROOM_CELL)
    skip_backdrops(stage)
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "room.usda"
        stage.GetRootLayer().Export(str(path))
        stage = Usd.Stage.Open(str(path))
        before = composed_meshes(stage)
        started = time.perf_counter()
        layer = usdbake.bake(stage, processors=["daylight"], params={"daylight": {"sky": "uniform", "sun": False}},
                             target=target, texture_dir=folder)
        seconds = time.perf_counter() - started
        status = Path("/proc/self/status").read_text()
        peak = int(status.split("VmHWM:")[1].split()[0]) / 1024
        return {"seconds": round(seconds, 2), "layer_kb": round(len(layer.ExportToString()) / 1024, 1),
                "meshes_identical": int(composed_meshes(stage) == before), "peak_mb": round(peak, 1)}


def texture_only_figures() -> dict:
    """``target_bake`` for the vertex and the texture target, each in a child process (its own peak memory)."""
    figures = {}
    for target in ("vertex", "texture"):
        code = ("import json\nfrom usdbake.benchmarks.bench_daylight_lightmaps import target_bake\n"
                f"print(json.dumps(target_bake({target!r})))\n")
        output = subprocess.run([sys.executable, "-c", code], check=True, capture_output=True, text=True).stdout
        data = json.loads(output.strip().splitlines()[-1])
        figures.update({f"room_{target}_seconds": data["seconds"], f"room_{target}_layer_kb": data["layer_kb"],
                        f"room_{target}_peak_mb": data["peak_mb"]})
        if target == "texture":
            figures["meshes_identical"] = data["meshes_identical"]
    return figures


def run(quick: bool = False) -> dict:
    figures: dict = {}
    _, room = room_scene(ROOM_CELL)
    figures.update(exposure_accuracy("room", room, 8.0 if quick else 32.0, 1024 if quick else REFERENCE_RAYS,
                                     seed=41))
    rows = [{"label": "room exposure", "seconds": figures["room_exposure_seconds"],
             "error": figures["room_exposure_rms"], "default": True}] if "room_exposure_rms" in figures else []
    if quick:
        return harness.result(NAME, description=DESCRIPTION, settings={"quick": True, "embree": has_embree()},
                              points=rows, figures=figures, knob="defaults", error_label="sky exposure RMS vs Embree")
    figures.update(exposure_accuracy("city", city_scene(), 1.0, REFERENCE_RAYS, seed=43))
    from . import radiance_binaries

    if radiance_binaries.radiance_available():
        figures.update(radiance_figures())
        figures.update(office_annual_figures())
    figures.update(texture_only_figures())
    table = harness.markdown_table([figures], [c for c in (
        "room_texels", "room_exposure_rms", "room_exposure_noise", "room_exposure_bias",
        "room_exposure_rms_over_noise", "room_seam_rms_over_pair_noise", "city_texels", "city_exposure_rms",
        "city_exposure_rms_over_noise", "city_seam_rms_over_pair_noise") if c in figures])
    table += "\n\n" + harness.markdown_table([figures], [c for c in (
        "room_faces_median_abs_error", "room_texels_median_abs_error", "room_faces_bias", "room_texels_bias",
        "room_both_seconds", "room_vertex_seconds", "room_texture_seconds", "room_vertex_peak_mb",
        "room_texture_peak_mb", "meshes_identical") if c in figures])
    table += "\n\n" + harness.markdown_table([figures], [c for c in (
        "office_faces_mean_illuminance_median_abs_error", "office_texels_mean_illuminance_median_abs_error",
        "office_faces_df_median_abs_error", "office_texels_df_median_abs_error", "office_faces_sda",
        "office_texels_sda", "office_sda_radiance", "office_both_seconds") if c in figures])
    return harness.result(NAME, description=DESCRIPTION, settings={"reference_rays": REFERENCE_RAYS,
                                                                   "texels_checked": TEXELS_CHECKED},
                          points=rows, figures=figures, table=table, knob="defaults",
                          error_label="sky exposure RMS vs Embree at interior texels")
