"""A cornell_box baked with progressive_mesh and irradiance_grid, and a usdbake serve app on loopback:
shared by the server and browser-viewer tests."""

from __future__ import annotations

import asyncio
import threading
import urllib.error
import urllib.request
from contextlib import contextmanager
from pathlib import Path

from aiohttp import web

from repo_paths import SAMPLES


def bake_streams(folder: Path) -> Path:
    """The baked layer (small grid, 4-vertex mesh packets so even small meshes stream in several)."""
    from usdbake.cli.main import main

    out = folder / "cornell.usdc"
    code = main(["bake", str(SAMPLES / "cornell_box.usda"), "-o", str(out), "-p", "progressive_mesh",
                 "-p", "irradiance_grid", "--set", "irradiance_grid.vertices=500", "--set", "irradiance_grid.rays=16",
                 "--set", "progressive_mesh.packet_vertices=4", "--cache", str(folder / "cache")])
    assert code == 0
    return out


@contextmanager
def running(app: web.Application):
    """The app on a free loopback port in a thread of its own; yields its base URL."""
    loop = asyncio.new_event_loop()
    runner = web.AppRunner(app)
    loop.run_until_complete(runner.setup())
    site = web.TCPSite(runner, "127.0.0.1", 0)
    loop.run_until_complete(site.start())
    port = site._server.sockets[0].getsockname()[1]
    thread = threading.Thread(target=loop.run_forever, daemon=True)
    thread.start()
    try:
        yield f"http://127.0.0.1:{port}"
    finally:
        loop.call_soon_threadsafe(loop.stop)
        thread.join(5)
        loop.run_until_complete(runner.cleanup())
        loop.close()


def get(url: str, headers=None):
    """(status, headers, body) of a GET, error statuses included."""
    request = urllib.request.Request(url, headers=headers or {})
    try:
        with urllib.request.urlopen(request, timeout=10) as response:
            return response.status, response.headers, response.read()  # headers: case-insensitive
    except urllib.error.HTTPError as error:
        return error.code, error.headers, error.read()
