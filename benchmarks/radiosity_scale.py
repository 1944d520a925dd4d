"""Radiosity at scale: precompute, memory and relight at 2k-16k patches, compressed vs dense (issue 17).

Not a ``bench_`` module (minutes per size, and the smoke run's CPU meets no GPU):
``python -m usdbake.benchmarks.radiosity_scale OUT.json [target_patches ...]``, on the device named by
$USDBAKE_DEVICE (default cuda:0 where Warp sees one, else cpu). Per patch count on atrium: the
precompute (form factors traced on the device; operator products, reordering and BC1 on the CPU), its
parts and the growth of peak memory, the run-time form the default memory budget picks and the one a
1 GB budget picks, then y = M x timed (best of ROUNDS, device synchronized) four ways:

- the compressed kernel on the device (``OperatorRelighter``, the thesis' in-kernel decode);
- the same product as a dense float32 Warp kernel on the device (bench_radiosity's baseline);
- cuBLAS through torch on the dense operator, on CUDA where torch is installed;
- numpy BLAS on the host's cores (what the CPU relight does when the operator fits).

Results are written after every patch count, so a run stopped by a time limit keeps what it measured.
"""

from __future__ import annotations

import json
import os
import sys
import time

import numpy as np
import warp as wp

from . import harness
from .bench_radiosity import relight_dense_kernel
from usdbake import init_warp
from usdbake.processors.radiosity.operator_relight import COMPRESSED, OperatorRelighter, dense_nbytes, relight_form
from usdbake.kernels.tracer import Tracer
from usdbake.processors.radiosity import form_factors as ff

ROUNDS = 30


def best_seconds(function, rounds: int, sync) -> float:
    function()
    sync()
    best = float("inf")
    for _ in range(rounds):
        started = time.perf_counter()
        function()
        sync()
        best = min(best, time.perf_counter() - started)
    return best


def measure(scene, device: str, target: int) -> dict:
    tracer = Tracer.from_scene(scene, device=device)
    params = ff.FormFactors.Params(target_patches=target)
    with harness.measure() as m:
        product, dense = ff.precompute(tracer, scene, params)
    op, operator, seconds = product.operator, dense["operator"], dense["seconds"]
    n = op.size
    rng = np.random.default_rng(3)
    x = rng.uniform(0, 1, (n, 3)).astype(np.float32)
    sync = lambda: wp.synchronize_device(device)  # noqa: E731
    relighter = OperatorRelighter(op, device=device, form=COMPRESSED)
    y_compressed = relighter.apply(x)
    row = {"patches": n, "precompute_s": sum(seconds.values()), **{f"{k}_s": v for k, v in seconds.items()},
           "dense_mb": dense_nbytes(n) / 2**20, "compressed_runtime_mb": relighter.nbytes / 2**20,
           "stored_mb": op.nbytes / 2**20, "precompute_peak_mb": m.peak_mb,
           "default_form": relight_form(n, device), "form_at_1gb": relight_form(n, device, 2**30)}
    row["compressed_ms"] = 1e3 * best_seconds(relighter.apply_stored, ROUNDS, sync)
    dense_host = np.ascontiguousarray(np.moveaxis(operator, 0, -1))  # (n, n, 3)
    y_dense = np.einsum("cij,jc->ic", operator, x)
    row["compressed_vs_dense"] = harness.relative_rms(y_compressed, y_dense)
    matrix = wp.array(dense_host, dtype=wp.vec3, device=device)
    x_wp, y_wp = wp.array(x, dtype=wp.vec3, device=device), wp.zeros(n, dtype=wp.vec3, device=device)
    row["dense_warp_ms"] = 1e3 * best_seconds(
        lambda: wp.launch(relight_dense_kernel, dim=n, inputs=[0, matrix, x_wp, y_wp], device=device), ROUNDS, sync)
    del matrix
    try:
        import torch

        if not wp.get_device(device).is_cuda:
            raise ImportError("cuBLAS only on CUDA")
        m_t = torch.from_numpy(np.ascontiguousarray(operator)).to("cuda")  # (3, n, n)
        x_t = torch.from_numpy(np.ascontiguousarray(x.T[:, :, None])).to("cuda")
        row["dense_cublas_ms"] = 1e3 * best_seconds(lambda: torch.bmm(m_t, x_t), ROUNDS, torch.cuda.synchronize)
        del m_t, x_t
        torch.cuda.empty_cache()
    except ImportError:
        row["dense_cublas_ms"] = None
    m_rgb = np.ascontiguousarray(operator)
    x_cols = np.ascontiguousarray(x.T[:, :, None])
    row["dense_numpy_host_ms"] = 1e3 * best_seconds(lambda: np.matmul(m_rgb, x_cols), 5, lambda: None)
    row["compressed_vs_dense_warp"] = row["dense_warp_ms"] / row["compressed_ms"]
    return row


def main(argv: list[str]) -> None:
    out = argv[0]
    targets = [int(t) for t in argv[1:]] or [2000, 5000, 10000, 16000]
    init_warp("cuda:0")
    device = os.environ.get("USDBAKE_DEVICE") or ("cuda:0" if wp.is_cuda_available() else "cpu")
    scene = harness.load_scene("atrium")
    report = {"device": wp.get_device(device).name, "host_cores": os.cpu_count(), "rows": []}
    for target in targets:
        started = time.perf_counter()
        report["rows"].append(measure(scene, device, target))
        report["rows"][-1]["wall_s"] = time.perf_counter() - started
        print(json.dumps(report["rows"][-1]), flush=True)
        with open(out, "w") as handle:
            json.dump(report, handle, indent=1)


if __name__ == "__main__":
    main(sys.argv[1:])
