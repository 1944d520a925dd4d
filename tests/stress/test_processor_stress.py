"""Every registered processor on hostile geometry: finite outputs, values in range, clean errors,
and the same results for a scene moved far from the origin or shrunk to millimetres.

The hostile stage (stage_builders_stress.hostile_lit_stage) holds zero-area and
sliver triangles, duplicate vertices, non-planar and concave polygons,
coincident coplanar faces (z-fighting), a 2e4-unit triangle next to 1e-6-unit
ones, a DistantLight, a DomeLight and a PointInstancer with four instances.
"""

from __future__ import annotations


import numpy as np
import pytest
import usdbake
from pxr import Gf, Sdf, Usd, UsdGeom
from stress.stage_builders_stress import FAST_PARAMS, fast_params, hostile_lit_stage, small_lit_stage, walk_values
from tolerances import FLOAT32_ACCUMULATED, FLOAT32_LONG_CHAIN, FLOAT32_STORAGE, PROCESSOR_RAY_FLIPS
from usdbake.processors.light_probes.products import ProbeCloud
from usdbake.processors.radiosity.products import FormFactorProduct
from usdbake import core
from usdbake.processors.radiosity.operator_codec import decompress_operator
from usdbake.processors.radiosity.sky_guide import guided_ray_split
from usdbake.kernels.sh import sh_basis_np
from usdbake.core.errors import StageError
from usdbake.stages.extract import extract_scene
from usdbake.stages.hook import last_report
from usdbake.core.pipeline import Pipeline
from usdbake.core.runtime import Runtime
from usdbake.kernels.tracer import Tracer

PROCESSORS = sorted(name for name, cls in core.registry.registry().items()
                    if cls.__module__.startswith("usdbake.processors."))

UNIT_INTERVAL = ("primvars:bake:ao", "primvars:bake:aoFace", "primvars:bake:skyExposure")
"""Visibility-like outputs: a share of rays or of the sky, in [0, 1]."""

NON_NEGATIVE = ("primvars:bake:irradianceDirect", "primvars:bake:irradianceIndirect",
                "primvars:bake:irradianceGrid", "primvars:bake:daylight", "areas", "albedo",
                "bake:field:radius")
"""Irradiance, areas and albedo: sums and integrals of non-negative terms."""

SH_L2_IRRADIANCE_MIN = -19.0 / 120.0
"""Least value of the L2 (order 2) irradiance of ANY non-negative radiance, relative to its mean over
the sphere: a delta light gives E(x) = W/4 (3/8 + 2x + 15/8 x^2), x = cos(angle) (Ramamoorthi &
Hanrahan's A_0 = pi, A_1 = 2 pi / 3, A_2 = pi / 4); its minimum at x = -8/15 is -0.0396 W and its
mean over the sphere is W / 4, so the ratio is -19/120 = -0.15833. A Monte Carlo projection is a
non-negative sum of deltas, so the bound holds for it too: min_n E(n) >= -19/120 * mean E, with
mean E = c_00 * Y_00. With the sun alone the probes reach it (measured min E / mean E = -0.1583332
on both stages; 18% of the sampled normals negative)."""


def authored_values(stage: Usd.Stage, layer: Sdf.Layer) -> dict[str, list]:
    """{attribute path: [value at each authored time sample, or the default]} for every attribute spec
    in ``layer``, read through the composed ``stage``."""
    paths: list[Sdf.Path] = []
    layer.Traverse(Sdf.Path.absoluteRootPath,
                   lambda path: paths.append(path) if path.IsPropertyPath() and
                   isinstance(layer.GetPropertyAtPath(path), Sdf.AttributeSpec) else None)
    values = {}
    for path in paths:
        attribute = stage.GetAttributeAtPath(path)
        assert attribute, f"{path} authored in the bake layer but not on the stage"
        times = attribute.GetTimeSamples()
        values[str(path)] = [attribute.Get(t) for t in times] if times else [attribute.Get()]
    return values


def as_float_array(value) -> np.ndarray | None:
    """The value as a float array, or None when it is not numeric float data (tokens, assets, ints)."""
    if value is None or isinstance(value, (str, bool, int, Sdf.AssetPath)):
        return None
    try:
        array = np.asarray(value)
    except (TypeError, ValueError):
        return None
    return array if array.dtype.kind == "f" else None


def walk_arrays(value, where: str):
    """(where, array) for every float numpy array reachable from a product or record."""
    for key, leaf in walk_values(value, where):
        if isinstance(leaf, np.ndarray) and leaf.dtype.kind == "f":
            yield key, leaf


def test_every_builtin_processor_is_stressed():
    """Every built-in processor joins the stress and determinism tests (FAST_PARAMS only speeds some up)."""
    assert set(core.registry.builtin()) == set(PROCESSORS) and set(FAST_PARAMS) <= set(PROCESSORS)


@pytest.fixture(scope="module")
def hostile_scene():
    return extract_scene(hostile_lit_stage())


@pytest.mark.parametrize("name", PROCESSORS)
def test_hostile_stage_bakes_finite_values_in_range(name, tmp_path):
    stage = hostile_lit_stage()
    layer = usdbake.bake(stage, processors=[name], params=fast_params(name), cache_dir=str(tmp_path))
    report = {r["processor"]: r for r in last_report(layer)}
    assert report[name]["action"] == "run", f"{name} did not run: {report[name]['reason']}"
    values = authored_values(stage, layer)
    assert values, f"{name} authored nothing"
    checked = 0
    for path, samples in values.items():
        prop = path.rsplit(".", 1)[-1]
        for value in samples:
            array = as_float_array(value)
            if array is None:
                continue
            checked += 1
            assert np.isfinite(array).all(), f"{path}: {np.count_nonzero(~np.isfinite(array))} non-finite values"
            if prop in UNIT_INTERVAL:
                assert array.min() >= 0 and array.max() <= 1 + FLOAT32_ACCUMULATED, \
                    f"{path} outside [0, 1]: {array.min()} .. {array.max()}"
            if prop in NON_NEGATIVE:
                scale = max(1.0, float(np.abs(array).max()))
                assert array.min() >= -FLOAT32_ACCUMULATED * scale, f"{path} negative: {array.min()}"
        if prop == "primvars:bake:pmRank":
            # integer outputs: a stream order must be a permutation, and every vertex collapses onto one
            # streamed before it (or -1), or the client rebuilding a level of detail reads garbage.
            prim = path.rsplit(".", 1)[0]
            rank = np.asarray(samples[0])
            target = np.asarray(stage.GetAttributeAtPath(f"{prim}.primvars:bake:pmCollapseTo").Get())
            n = len(stage.GetAttributeAtPath(f"{prim}.points").Get())
            assert np.array_equal(np.sort(rank), np.arange(n)), f"{path} is not a permutation"
            assert ((target >= -1) & (target < n)).all(), path
            ok = target >= 0
            assert (rank[target[ok]] < rank[ok]).all(), f"{path}: collapse onto a later vertex"
            checked += 1
        if prop == "primvars:bake:skyVisibility":
            prim = path.rsplit(".", 1)[0]
            scale = stage.GetAttributeAtPath(f"{prim}.bake:sky:visibilityScale").Get()
            dequantized = np.asarray(samples[0], np.float64) * scale
            assert dequantized.min() >= 0 and dequantized.max() <= 1 + FLOAT32_ACCUMULATED, path
            checked += 1
    assert checked, f"{name}: no float data among {sorted(values)}"


@pytest.mark.parametrize("name", PROCESSORS)
def test_hostile_stage_products_are_finite(name, hostile_scene):
    """Every float array in every step's products and output records (kernel outputs handed downstream)."""
    steps = Pipeline.build([name], fast_params(name), runtime=Runtime(Tracer.from_scene)).run(hostile_scene)
    for step in steps:
        assert step.action == "run", f"{step.name}: {step.reason}"
        for where, array in walk_arrays({"products": step.result.products,
                                         "outputs": list(step.result.outputs)},
                                        step.name):
            assert np.isfinite(array).all(), f"{where}: {np.count_nonzero(~np.isfinite(array))} non-finite"


def test_form_factor_rows_sum_to_at_most_one(hostile_scene):
    """F_ij = share of patch i's rays landing on patch j: a row is at most 1 (each ray hits one patch or
    escapes). The multi-bounce operator M = sum_{h<=k} (F rho)^h is non-negative with row sums at most
    sum_{h<=k} rho_max^h (|F rho|_inf <= rho_max, submultiplicative); decoded with row correction, the
    same bound up to float32 rounding."""
    steps = Pipeline.build(["form_factors"], fast_params("form_factors"),
                           runtime=Runtime(Tracer.from_scene)).run(hostile_scene)
    product = steps[-1].result.products[FormFactorProduct]
    checks = product.checks
    assert checks["row_sum_min"] >= 0
    assert checks["row_sum_max"] <= 1 + FLOAT32_ACCUMULATED, checks
    assert checks["row_sum_max"] > 0.1, "no patch sees another: the check would be vacuous"
    operator = decompress_operator(product.operator).astype(np.float64)
    assert np.isfinite(operator).all()
    rho = float(np.max(product.patches.patch_albedo))
    assert 0 <= rho < 1
    bound = sum(rho ** h for h in range(1, product.bounces + 1)) if not product.infinite else rho / (1 - rho)
    rows = operator.sum(axis=2)
    # BC1 codes are rescaled per row to the exact row sum, so a row's decoded sum is its exact sum (float32).
    assert rows.max() <= bound * (1 + FLOAT32_LONG_CHAIN), (rows.max(), bound)
    assert operator.min() >= -FLOAT32_STORAGE * max(1.0, operator.max())


@pytest.mark.parametrize("lights", ["sun and dome", "sun only"])
def test_light_probe_sh_irradiance_is_non_negative(lights, hostile_scene):
    """SH irradiance evaluated at random normals is above the L2 ringing bound for non-negative lighting."""
    scene = hostile_scene
    if lights == "sun only":
        stage = hostile_lit_stage()
        stage.RemovePrim("/World/Sky")
        scene = extract_scene(stage)
    steps = Pipeline.build(["light_probes"], fast_params("light_probes"), runtime=Runtime(Tracer.from_scene)).run(scene)
    cloud = steps[-1].result.products[ProbeCloud]
    sh = cloud.probe_sh.astype(np.float64)  # (P, 9, 3) irradiance SH
    assert len(sh) >= 4 and np.isfinite(sh).all()
    normals = np.random.default_rng(3).normal(size=(4096, 3))
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    irradiance = np.einsum("nk,pkc->pnc", sh_basis_np(normals), sh)  # (P, N, 3)
    mean = sh[:, 0, :] * sh_basis_np(normals[:1])[0, 0]  # (P, 3): mean over the sphere = c_00 Y_00
    assert (mean >= -FLOAT32_ACCUMULATED * np.abs(mean).max()).all(), "negative mean irradiance"
    assert mean.max() > 0, "no probe receives light: the check would be vacuous"
    floor = SH_L2_IRRADIANCE_MIN * mean[:, None, :] - FLOAT32_ACCUMULATED * np.abs(mean).max()
    worst = (irradiance - floor).min()
    assert worst >= 0, f"SH irradiance below the L2 bound for non-negative radiance by {-worst}"


@pytest.mark.parametrize("name", PROCESSORS)
def test_nan_point_is_a_clean_stage_error(name, tmp_path):
    stage = hostile_lit_stage()
    mesh = UsdGeom.Mesh(stage.GetPrimAtPath("/World/box"))
    points = list(mesh.GetPointsAttr().Get())
    points[5] = Gf.Vec3f(float("nan"), 0.0, 0.0)
    mesh.GetPointsAttr().Set(points)
    with pytest.raises(StageError, match=r"/World/box\.points: point 5"):
        usdbake.bake(stage, processors=[name], params=fast_params(name), cache_dir=str(tmp_path))
    assert not stage.GetSessionLayer().subLayerPaths, "a failed bake must author nothing"


# ---------------------------------------------------------------------------
# Translated and scaled scenes

TRANSLATE = (1e6, -1e6, 1e5)
SCALE = 1e-3


def bake_outputs(name: str, stage: Usd.Stage, tmp_path, props: tuple[str, ...]) -> dict[str, np.ndarray]:
    layer = usdbake.bake(stage, processors=[name], params=TRANSFORM_PARAMS[name], cache_dir=str(tmp_path))
    out = {}
    for prim in ("/World/floor", "/World/box"):
        for prop in props:
            attribute = stage.GetAttributeAtPath(f"{prim}.{prop}")
            if attribute and attribute.HasAuthoredValue():
                times = attribute.GetTimeSamples()
                value = [attribute.Get(t) for t in times] if times else [attribute.Get()]
                out[f"{prim}.{prop}"] = np.asarray(value, np.float64)
    assert out, f"{name} wrote none of {props}"
    assert layer is not None
    return out


TRANSFORM_SAMPLES = 64
TRANSFORM_PARAMS = {
    "ambient_occlusion": {"ambient_occlusion": {"samples": TRANSFORM_SAMPLES}},
    "instance_ao": {"displacement_fields": {"positional_samples": 64, "direction_map_size": 8, "force": "Crate"},
                    "instance_ao": {"samples": TRANSFORM_SAMPLES}},
    "sky_visibility": {"sky_visibility": {"patch_count": 16, "samples": 4, "max_level": 2}},
    "daylight": {"sky_visibility": {"patch_count": 16, "samples": 4, "max_level": 2},
                 "daylight": {"sun_samples": 16}},
    "radiosity": {"form_factors": {"target_patches": 48, "rays": 64},
                  "radiosity": {"light_samples": 16, "sky_samples": TRANSFORM_SAMPLES, "patch_points": 4,
                                "gather_rays": TRANSFORM_SAMPLES}},
    "irradiance_grid": {"irradiance_grid": {"vertices": 512, "rays": TRANSFORM_SAMPLES}},
}
TRANSFORM_OUTPUTS = {
    "ambient_occlusion": ("primvars:bake:ao",),
    "instance_ao": ("primvars:bake:ao",),
    "sky_visibility": ("primvars:bake:skyExposure",),
    "daylight": ("primvars:bake:daylight",),
    "radiosity": ("primvars:bake:irradianceDirect", "primvars:bake:irradianceIndirect"),
    "irradiance_grid": ("primvars:bake:irradianceGrid",),
}
RAY_FLIP_TOLERANCE = PROCESSOR_RAY_FLIPS / TRANSFORM_SAMPLES
"""Same seeds, same receivers: only float32 rounding of the recentred / rescaled geometry differs, so a
ray grazing an edge can flip between hit and miss (see PROCESSOR_RAY_FLIPS), relative to the largest
value of the output (for irradiance: the share of a full unoccluded sky/sun). For radiosity's indirect
light the unit is what one final-gather ray can carry, albedo_max * E_direct_max (measured under
scaling: one gather ray flips at a box corner touching the floor, 0.0245 = 0.5 * pi / 64, which is 56%
of the box's own largest indirect value but 1/64 of this unit; k-nearest-patch ties on the regular floor
grid move a floor vertex by 0.0093, also inside it)."""


@pytest.fixture(scope="module")
def reference_outputs(tmp_path_factory):
    return {name: bake_outputs(name, small_lit_stage(), tmp_path_factory.mktemp(name), props)
            for name, props in TRANSFORM_OUTPUTS.items()}


def compare(reference, moved):
    assert reference.keys() == moved.keys()
    for key, ref in reference.items():
        got = moved[key]
        assert np.isfinite(got).all(), key
        scale = max(float(np.abs(ref).max()), 1e-12)
        if key.endswith("irradianceIndirect"):
            albedo = float(extract_scene(small_lit_stage()).tri_albedo.max())
            direct = max(float(np.abs(v).max()) for k, v in reference.items() if k.endswith("irradianceDirect"))
            scale = albedo * direct
        # sky_visibility / daylight: the refined mesh must have the same faces (measured: 1012 floor faces
        # at the origin, translated and scaled; refinement decisions are scale-free and recentred).
        assert got.shape == ref.shape, f"{key}: {got.shape} != {ref.shape} (refinement differs)"
        tolerance = RAY_FLIP_TOLERANCE
        if key.endswith("irradianceDirect"):  # a flipped sky ray weighs pi L / n_c: n_c the cosine rays
            tolerance = PROCESSOR_RAY_FLIPS / guided_ray_split(TRANSFORM_SAMPLES)[1] ** 2
        np.testing.assert_allclose(got, ref, rtol=0, atol=tolerance * scale, err_msg=key)


@pytest.mark.parametrize("name", sorted(TRANSFORM_OUTPUTS))
def test_translated_scene_matches(name, reference_outputs, tmp_path):
    """/World moved to (1e6, -1e6, 1e5) by a double-precision translate: float32 world positions there are
    only good to 0.06 (half an ulp at 1e6), so this fails unless extraction composes the transforms and
    recentres in double precision before handing float32 to the kernels (points, lights, instances)."""
    stage = small_lit_stage(translate=TRANSLATE)
    compare(reference_outputs[name], bake_outputs(name, stage, tmp_path, TRANSFORM_OUTPUTS[name]))


@pytest.mark.parametrize("name", sorted(TRANSFORM_OUTPUTS))
def test_scaled_scene_matches(name, reference_outputs, tmp_path):
    """/World scaled by 1e-3: ray offsets, refinement thresholds and grid cells must scale with the scene.
    Lights are a DistantLight and a DomeLight, whose irradiance does not depend on the scene's size."""
    stage = small_lit_stage(scale=SCALE)
    compare(reference_outputs[name], bake_outputs(name, stage, tmp_path, TRANSFORM_OUTPUTS[name]))


@pytest.mark.parametrize("name", ["ambient_occlusion", "radiosity", "daylight"])
def test_hostile_stage_bakes_finite_lightmaps_in_range(name, tmp_path):
    """The texture target on the hostile stage (slivers, zero-area faces, far-off and tiny geometry): every
    lightmap it writes is readable, finite and in range (AO in [0, 1], irradiance non-negative)."""
    import OpenImageIO as oiio

    stage = hostile_lit_stage()
    textured = "sky_visibility" if name == "daylight" else name  # daylight's texels are sky_visibility's
    params = {**fast_params(name), textured: {**fast_params(name).get(textured, {}), "texel_density": 4.0,
                                              "max_texture_size": 256}}
    layer = usdbake.bake(stage, processors=[name], params=params, cache_dir=str(tmp_path), target="texture",
                         texture_dir=str(tmp_path))
    files = [attribute for prim in stage.Traverse() for attribute in prim.GetAttributes()
             if attribute.GetName().startswith("bake:lightmap:") and attribute.GetName().endswith(":file")]
    assert files, f"{name} wrote no lightmap"
    for attribute in files:
        pixels = oiio.ImageBuf(attribute.Get().resolvedPath).get_pixels(oiio.FLOAT)
        assert pixels is not None and np.isfinite(pixels).all(), attribute.GetPath()
        assert pixels.min() >= 0, attribute.GetPath()
        if ":ao:" in attribute.GetName() or ":skyExposure:" in attribute.GetName():
            assert pixels.max() <= 1, attribute.GetPath()
    assert {r["processor"]: r for r in last_report(layer)}[name]["action"] == "run"
