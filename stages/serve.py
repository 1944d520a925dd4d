"""``usdbake serve``: a baked stage's progressive streams over HTTP (aiohttp).

Pacanowski et al. 2008 stream a scene to a remote viewer that shows it after
the first packets and sharpens as the rest arrives. The bake writes the
streams beside the layer (``bake:pmStreamFile`` per mesh, the irradiance
grid's ``streamFile``); this server hands them out:

==================== ======================================================
route                what
==================== ======================================================
``GET /``            the viewer: a WebGL2 page (``viewer/``) that reads
                     ``/stream`` and draws the meshes lit by the grid as
                     they arrive
``GET /manifest``    JSON: the stage, each mesh stream (prim, url, bytes)
                     and the grid stream; a client reads it first
``GET /files/NAME``  one stream file: HTTP range requests (a client takes a
                     prefix, then the rest), ETag / If-None-Match (aiohttp's
                     FileResponse)
``GET /stream``      every stream in one response, interleaved: frames of
                     ``chunk`` bytes, always from the stream least far
                     along, so any prefix holds the same share of every mesh
                     and of the grid (``interleave``; the paper's server)
==================== ======================================================

Only the files the stage's bake names are served, looked up by name in a
table built at start (no path from a request ever reaches the file system);
anything else is 404. At most ``max_clients`` requests are handled at once;
the others get 503 with Retry-After. Ctrl-C or SIGTERM stops the server
after the requests in flight (aiohttp's run_app).
"""

from __future__ import annotations

import asyncio
import heapq
import json
import struct
from pathlib import Path

from aiohttp import web
from pxr import Usd

from ..core.errors import UsageError

GRID_PRIM = "/usdbake/IrradianceGrid"
MESH_STREAM_ATTRIBUTE = "bake:pmStreamFile"
FRAME = struct.Struct("<IIQ")
"""Frame header of ``/stream``: stream index (0: the manifest, 1.. the manifest's streams: meshes, then the
grid), payload length, offset of the payload in its stream."""
STREAM_CHUNK = 16 * 1024
VIEWER = Path(__file__).with_name("viewer")
"""The browser viewer (index.html, viewer.js: WebGL2, written here) served at / ."""


def interleave(sizes: list[int], chunk: int) -> list[tuple[int, int, int]]:
    """(stream, offset, length) of every frame: a chunk at a time from the stream with the smallest share
    sent so far (ties: the lower index), so after any frame each stream is within one chunk of the same
    share of its bytes."""
    heap = [(0.0, i) for i, size in enumerate(sizes) if size > 0]
    heapq.heapify(heap)
    sent = [0] * len(sizes)
    frames = []
    while heap:
        _, i = heapq.heappop(heap)
        length = min(chunk, sizes[i] - sent[i])
        frames.append((i, sent[i], length))
        sent[i] += length
        if sent[i] < sizes[i]:
            heapq.heappush(heap, (sent[i] / sizes[i], i))
    return frames


def stage_streams(path: str) -> dict:
    """{'stage', 'meshes': [{'prim', 'name', 'file'}], 'grid': {'name', 'file'} | None} of a baked stage:
    every stream file its bake names, resolved to an existing file."""
    stage = Usd.Stage.Open(path)
    if stage is None:
        raise UsageError(f"{path}: cannot open the stage")

    def resolved(attribute, prim_path: str) -> Path:
        asset = attribute.Get()
        file = Path(asset.resolvedPath) if asset is not None and asset.resolvedPath else None
        if file is None or not file.is_file():
            raise UsageError(f"{prim_path}.{attribute.GetName()}: {asset.path if asset else ''!r} is not a file "
                             f"beside the bake; bake the stage again")
        return file

    meshes = []
    for prim in stage.Traverse():
        attribute = prim.GetAttribute(MESH_STREAM_ATTRIBUTE)
        if attribute and attribute.HasAuthoredValue():
            file = resolved(attribute, str(prim.GetPath()))
            meshes.append({"prim": str(prim.GetPath()), "name": file.name, "file": file})
    grid_prim = stage.GetPrimAtPath(GRID_PRIM)
    grid = None
    if grid_prim and grid_prim.GetAttribute("streamFile").HasAuthoredValue():
        file = resolved(grid_prim.GetAttribute("streamFile"), GRID_PRIM)
        grid = {"name": file.name, "file": file}
    if not meshes and grid is None:
        raise UsageError(f"{path}: no streams to serve: bake it with -p progressive_mesh and/or -p irradiance_grid")
    return {"stage": Path(path).name, "meshes": meshes, "grid": grid}


def bounded_requests(limit: int):
    """Middleware: at most ``limit`` requests in the handlers at once; the others get 503 with Retry-After."""
    slots = asyncio.Semaphore(limit)

    @web.middleware
    async def bounded(request: web.Request, handler):
        if slots.locked():
            raise web.HTTPServiceUnavailable(headers={"Retry-After": "1"}, text="too many clients; retry")
        async with slots:
            return await handler(request)

    return bounded


def make_app(path: str, *, max_clients: int = 64) -> web.Application:
    """The aiohttp application serving ``path``'s streams (module docstring)."""
    streams = stage_streams(path)
    ordered = streams["meshes"] + ([streams["grid"]] if streams["grid"] else [])  # /stream's numbering
    files = {stream["name"]: stream["file"] for stream in ordered}
    contents = [stream["file"].read_bytes() for stream in ordered]  # read once: /stream sends them to every client

    def entry(stream: dict, data: bytes) -> dict:
        return {"url": f"/files/{stream['name']}", "bytes": len(data)}

    manifest = {
        "stage": streams["stage"],
        "meshes": [{"prim": m["prim"], **entry(m, data)} for m, data in zip(streams["meshes"], contents)],
        "grid": entry(streams["grid"], contents[-1]) if streams["grid"] else None,
    }
    header = json.dumps(manifest).encode()
    page, script = (VIEWER / "index.html").read_text(), (VIEWER / "viewer.js").read_text()

    async def index(request: web.Request) -> web.Response:
        return web.Response(content_type="text/html", text=page)

    async def viewer_script(request: web.Request) -> web.Response:
        return web.Response(content_type="text/javascript", text=script)

    async def manifest_route(request: web.Request) -> web.Response:
        response = web.Response(text=json.dumps(manifest), content_type="application/json")
        response.enable_compression()
        return response

    async def stream_route(request: web.Request) -> web.StreamResponse:
        try:
            chunk = int(request.query.get("chunk", STREAM_CHUNK))
        except ValueError:
            raise web.HTTPBadRequest(text="chunk must be an integer") from None
        if not 1024 <= chunk <= 1 << 24:
            raise web.HTTPBadRequest(text="chunk must be within 1024..16777216 bytes")
        response = web.StreamResponse(headers={"Content-Type": "application/octet-stream"})
        await response.prepare(request)
        await response.write(FRAME.pack(0, len(header), 0) + header)
        for index, offset, length in interleave([len(c) for c in contents], chunk):
            await response.write(FRAME.pack(index + 1, length, offset) + contents[index][offset:offset + length])
        await response.write_eof()
        return response

    async def file_route(request: web.Request) -> web.StreamResponse:
        file = files.get(request.match_info["name"])
        if file is None:
            raise web.HTTPNotFound(text="not a stream of this stage")
        return web.FileResponse(file, headers={"Content-Type": "application/octet-stream"})

    app = web.Application(middlewares=[bounded_requests(max_clients)])
    app.router.add_get("/", index)
    app.router.add_get("/viewer.js", viewer_script)
    app.router.add_get("/manifest", manifest_route)
    app.router.add_get("/files/{name}", file_route)
    app.router.add_get("/stream", stream_route)
    return app


def serve(path: str, *, host: str = "127.0.0.1", port: int = 8642, max_clients: int = 64, log=print) -> None:
    """Serve until interrupted (Ctrl-C / SIGTERM): the requests in flight finish, then it stops."""
    app = make_app(path, max_clients=max_clients)
    web.run_app(app, host=host, port=port, print=lambda line: log(line.strip()) if line.strip() else None)
