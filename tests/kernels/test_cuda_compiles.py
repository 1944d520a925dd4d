"""Every kernel that traces rays, and the radiosity relight (its CUDA form), compiles for CUDA (sm_86 PTX
through Warp's NVRTC), without a GPU.

The ray core's native traversal has a scalar branch for CUDA (``#ifdef __CUDA_ARCH__``) that a CPU run
never compiles; ``--device cuda:0`` would meet an error there only on a machine with a GPU. Warp
compiles a module ahead of time for an architecture with the NVRTC it ships, driver or not, so the CUDA
side is checked here on every machine. Running it needs a GPU and is left to the benchmark.
"""

import importlib

import pytest
import warp as wp

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
