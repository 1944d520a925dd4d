"""usdbake serve under load on loopback: concurrent clients streaming one baked stage."""

from __future__ import annotations

import asyncio
import json
import os
import socket
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import numpy as np

from . import harness

NAME = "serve"
DESCRIPTION = (
    "`usdbake serve` in its own process on loopback, serving a stage baked with `progressive_mesh` and "
    "`irradiance_grid` and `daylight_stream` (atrium; cornell_box for --quick). Clients are aiohttp sessions in one asyncio loop of "
    "the benchmark process, two loads one after the other. Range requests: each client reads the manifest, "
    "then takes every stream in 64 KiB range requests, round-robin over the streams. Interleaved: each client "
    "makes one GET /stream (16 KiB frames, the stream least far along first). First lit frame: the first chunk of "
    "every stream received (every mesh has its coarsest level and its collapse table, the grid its first "
    "vertices) and the daylight stream up to its first packet of faces (the viewer relights from there); full scene: every byte. Per-request latency over all clients; server memory: the server "
    "process's peak resident set (VmHWM). The issue's figure: 50 concurrent clients, bounded memory.")
CHUNK = 64 * 1024
CLIENTS = 50


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _bake(sample: str, folder: str) -> Path:
    from usdbake.cli.main import main

    out = Path(folder) / f"{sample}.baked.usdc"
    code = main(["bake", str(harness.SAMPLES / f"{sample}.usda"), "-o", str(out), "-p", "progressive_mesh",
                 "-p", "irradiance_grid", "-p", "daylight_stream", "--set", "irradiance_grid.rays=64",
                 "--cache", str(Path(folder) / "cache")])
    if code != 0:
        raise RuntimeError(f"baking {sample} for the serve benchmark failed ({code})")
    return out


def _lit_bytes(manifest: dict, daylight_lit: int) -> list[tuple[str, int, int]]:
    """(url, bytes, bytes for a first lit frame) of every stream in ``/stream``'s order."""
    streams = [(m["url"], m["bytes"], 1) for m in manifest["meshes"]]
    streams += [(manifest["grid"]["url"], manifest["grid"]["bytes"], 1)] if manifest["grid"] else []
    daylight = manifest.get("daylight")
    return streams + ([(daylight["url"], daylight["bytes"], daylight_lit)] if daylight else [])


def _daylight_lit(baked: Path) -> int:
    """Bytes of the daylight stream up to its first FACES section (0 without one)."""
    from usdbake.formats.daylight_stream import FACES, section_ends

    files = list(baked.parent.glob(f"{baked.stem}_daylight_*.bin"))
    return next((end for kind, end in section_ends(files[0].read_bytes()) if kind == FACES), 0) if files else 0


async def _client(session, base: str, latencies: list, daylight_lit: int) -> tuple[float, float, int]:
    started = time.perf_counter()
    async with session.get(f"{base}/manifest") as response:
        manifest = await response.json()
    streams = _lit_bytes(manifest, daylight_lit)
    offsets = [0] * len(streams)
    first_lit, received = None, 0
    while any(offset < size for offset, (_, size, _) in zip(offsets, streams)):
        for i, (url, size, _) in enumerate(streams):
            if offsets[i] >= size:
                continue
            end = min(size, offsets[i] + CHUNK)
            asked = time.perf_counter()
            async with session.get(base + url, headers={"Range": f"bytes={offsets[i]}-{end - 1}"}) as response:
                if response.status not in (200, 206):
                    raise RuntimeError(f"{url}: HTTP {response.status}")
                received += len(await response.read())
            latencies.append(time.perf_counter() - asked)
            offsets[i] = end
        if first_lit is None and all(offset >= min(size, lit) for offset, (_, size, lit) in zip(offsets, streams)):
            first_lit = time.perf_counter() - started
    return first_lit, time.perf_counter() - started, received


async def _interleaved_client(session, base: str, daylight_lit: int) -> tuple[float, float, int]:
    """One GET /stream: first lit frame when every stream has its first frame (the daylight stream its first
    faces), full scene at the end."""
    from usdbake.stages.serve import FRAME, STREAM_CHUNK

    started = time.perf_counter()
    first_lit, received = None, 0
    async with session.get(f"{base}/stream?chunk={STREAM_CHUNK}") as response:
        _, length, _ = FRAME.unpack(await response.content.readexactly(FRAME.size))
        manifest = json.loads(await response.content.readexactly(length))
        streams = _lit_bytes(manifest, daylight_lit)
        held = [0] * len(streams)
        while True:
            try:
                index, length, _ = FRAME.unpack(await response.content.readexactly(FRAME.size))
            except asyncio.IncompleteReadError:
                break
            received += len(await response.content.readexactly(length))
            held[index - 1] += length
            if first_lit is None and all(h >= min(size, lit) for h, (_, size, lit) in zip(held, streams)):
                first_lit = time.perf_counter() - started
    return first_lit, time.perf_counter() - started, received


async def _load(base: str, clients: int, interleaved: bool, daylight_lit: int) -> tuple[list, list]:
    import aiohttp

    latencies: list = []
    connector = aiohttp.TCPConnector(limit=0)
    async with aiohttp.ClientSession(connector=connector) as session:
        tasks = [_interleaved_client(session, base, daylight_lit) if interleaved
                 else _client(session, base, latencies, daylight_lit)
                 for _ in range(clients)]
        results = await asyncio.gather(*tasks)
    return results, latencies


def _figures(mode: str, results: list, latencies: list, wall: float) -> dict:
    first_lit = np.array([r[0] for r in results])
    full = np.array([r[1] for r in results])
    row = {"mode": mode, "bytes_per_client": results[0][2],
           "first_lit_s_median": round(float(np.median(first_lit)), 3),
           "first_lit_s_max": round(float(first_lit.max()), 3),
           "full_scene_s_median": round(float(np.median(full)), 3), "full_scene_s_max": round(float(full.max()), 3),
           "throughput_mb_s": round(sum(r[2] for r in results) / 2 ** 20 / wall, 1)}
    if latencies:
        lat = np.array(latencies) * 1000
        row.update({"requests": len(latencies), "request_ms_p50": round(float(np.percentile(lat, 50)), 2),
                    "request_ms_p99": round(float(np.percentile(lat, 99)), 2)})
    return row


def _server_peak_mb(pid: int) -> float:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmHWM:"):
            return int(line.split()[1]) / 1024.0
    return float("nan")


@contextmanager
def serve_process(baked: Path) -> Iterator[tuple[str, int]]:
    """``usdbake serve baked`` in its own process on a free loopback port: yields (base URL, pid)."""
    port = _free_port()
    server = subprocess.Popen(
        [sys.executable, "-c", "import sys; from usdbake.cli.main import main; sys.exit(main(sys.argv[1:]))",
         "serve", str(baked), "--port", str(port), "--max-clients", "256"],
        stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, env={**os.environ, "PYTHONUNBUFFERED": "1"})
    try:
        deadline = time.time() + 60
        while True:
            try:
                with socket.create_connection(("127.0.0.1", port), timeout=1):
                    break
            except OSError:
                if server.poll() is not None or time.time() > deadline:
                    raise RuntimeError(f"usdbake serve did not start: {server.stderr.read().decode()[-2000:]}")
                time.sleep(0.2)
        yield f"http://127.0.0.1:{port}", server.pid
    finally:
        server.terminate()
        server.wait(10)


def run(quick: bool = False) -> dict:
    sample = "cornell_box" if quick else "atrium"
    clients = 10 if quick else CLIENTS
    with tempfile.TemporaryDirectory() as folder:
        baked = _bake(sample, folder)
        daylight_lit = _daylight_lit(baked)
        with serve_process(baked) as (base, pid):
            idle_mb = _server_peak_mb(pid)
            rows = []
            for mode in ("range requests", "interleaved /stream"):
                started = time.perf_counter()
                results, latencies = asyncio.run(_load(base, clients, mode != "range requests", daylight_lit))
                wall = time.perf_counter() - started
                rows.append(_figures(mode, results, latencies, wall))
            peak_mb = _server_peak_mb(pid)
    figures = {"sample": sample, "clients": clients, "bytes_per_client": rows[0]["bytes_per_client"],
               "server_peak_mb_idle": round(idle_mb, 1), "server_peak_mb_loaded": round(peak_mb, 1)}
    for row in rows:
        key = "range" if row["mode"] == "range requests" else "interleaved"
        figures.update({f"{key}_{name}": value for name, value in row.items() if name not in ("mode", "bytes_per_client")})
    table = harness.markdown_table(rows, list(rows[0]))
    table += f"\n\nServer peak resident memory: {idle_mb:.1f} MB idle, {peak_mb:.1f} MB after both loads."
    return harness.result(NAME, description=DESCRIPTION, settings={"quick": quick, "chunk": CHUNK},
                          points=[{"label": f"{clients} clients, {row['mode']}", "seconds": row["full_scene_s_max"],
                                   "error": 0.0, "default": row["mode"] != "range requests"} for row in rows],
                          figures=figures, table=table, knob="clients", error_label="-")
