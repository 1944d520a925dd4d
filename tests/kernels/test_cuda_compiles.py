"""Every kernel that traces rays, and the radiosity relight (its CUDA form), compiles for CUDA (sm_86 PTX
through Warp's NVRTC), without a GPU, and computes as the CPU build does.

The ray core's native traversal has a scalar branch for CUDA (``#ifdef __CUDA_ARCH__``) that a CPU run
never compiles; ``--device cuda:0`` would meet an error there only on a machine with a GPU. Warp
compiles a module ahead of time for an architecture with the NVRTC it ships, driver or not, so the CUDA
side is checked here on every machine. Running it needs a GPU and is left to the benchmark.

NVRTC fuses a * b - c * d into one FMA unless a module says ``fuse_fp: False``; the CPU build fuses
nothing. Fused, the watertight test's edge functions of a packet lane of zeros (a point triangle at the
origin, as empty lanes were) are one rounding error each, all of one sign, and the lane is hit at the
origin's depth: the CUDA bakes' false occlusion and their reads at face -1 (issue 33). Empty lanes are
NaN now (``bvh_build.TriangleBvh``), and every module of the library turns fusion off, so CUDA rounds as
the CPU does: the ray core's PTX holds no fused multiply-add.
"""

import importlib
import re

import pytest
import warp as wp
from repo_paths import REPO

FAST = ["usdbake.kernels.tracer", "usdbake.processors.daylight.sun_visibility", "usdbake.processors.occlusion.ambient_occlusion",
        "usdbake.processors.daylight.patch_visibility", "usdbake.processors.radiosity.form_factors",
        "usdbake.processors.instancing.displacement_fields", "usdbake.preview.raycast", "usdbake.processors.radiosity.operator_relight"]
"""Modules of a few seconds each (measured 0.7-2 s)."""
HEAVY = ["usdbake.processors.radiosity.radiosity", "usdbake.processors.irradiance_grid.irradiance_grid", "usdbake.processors.instancing.instance_ao",
         "usdbake.processors.light_probes.capture"]
"""Modules of 5-12 s each: the slow run."""


def _check_compiles(name: str, folder) -> None:
    """The module's PTX exists and holds an entry point per kernel."""
    module = importlib.import_module(name)
    kernels = [k for k in vars(module).values() if isinstance(k, wp.Kernel) and k.module.name == name]
    paths = wp.compile_aot_module(module, arch=86, use_ptx=True, module_dir=str(folder))
    ptx = "".join(p.read_text() for p in paths)
    assert kernels and ptx.count(".entry") >= len(kernels)


@pytest.mark.parametrize("name", FAST)
def test_tracing_kernels_compile_for_cuda(name, tmp_path):
    _check_compiles(name, tmp_path)


@pytest.mark.slow
@pytest.mark.parametrize("name", HEAVY)
def test_heavy_tracing_kernels_compile_for_cuda(name, tmp_path):
    _check_compiles(name, tmp_path)


def test_the_ray_core_compiles_without_fused_multiply_adds(tmp_path):
    module = importlib.import_module("usdbake.kernels.tracer")
    paths = wp.compile_aot_module(module, arch=86, use_ptx=True, module_dir=str(tmp_path))
    ptx = "".join(p.read_text() for p in paths)
    assert "mul.rn.f32" in ptx and "fma.rn.f32" not in ptx


def test_every_warp_module_turns_floating_point_fusion_off():
    """A library module with Warp kernels or functions sets its options once, with fuse_fp off (CUDA then
    rounds every product and sum as the CPU does)."""
    def ours(path):  # the library and its benchmarks: not the tests, nor a virtual environment kept here
        parts = path.relative_to(REPO).parts
        return not any(part == "tests" or part.startswith(".") or part == "site-packages" for part in parts)

    modules = [path for path in REPO.rglob("*.py") if ours(path)
               and re.search(r"^@wp\.(kernel|func|func_native|struct)", path.read_text(), re.MULTILINE)]
    assert len(modules) > 20
    for path in modules:
        options = re.findall(r"wp\.set_module_options\((.*)\)", path.read_text())
        assert options == ['{"enable_backward": False, "fuse_fp": False}'], path.relative_to(REPO)
