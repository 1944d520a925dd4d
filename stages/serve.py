"""``usdbake serve``: a baked stage's progressive streams over HTTP (aiohttp).

Pacanowski et al. 2008 stream a scene to a remote viewer that shows it after
the first packets and sharpens as the rest arrives. The bake writes the
streams beside the layer (``bake:pmStreamFile`` per mesh, the irradiance
grid's ``streamFile``, the daylight coefficients' ``streamFile`` on
``/usdbake/DaylightStream``); this server hands them out:

==================== ======================================================
route                what
==================== ======================================================
``GET /``            the viewer: a WebGL2 page (``viewer/``) that reads
                     ``/stream`` and draws the meshes lit by the grid as
                     they arrive, or the daylight faces relit for any date,
                     hour and sky
``GET /manifest``    JSON: the stage, each mesh stream (prim, url, bytes),
                     the grid stream, the daylight stream and the annual
                     overlay; a client reads it first
``GET /overlay``     annual_daylight's metrics on the daylight faces
                     (``annual_overlay``: read from the bake layer's own
                     primvars at start, served from memory)
``GET /files/NAME``  one stream file: one HTTP range (a client takes a
                     prefix, then the rest), a strong ETag (the file's
                     SHA-256) and If-None-Match
``GET /stream``      every stream in one response, interleaved: frames of
                     ``chunk`` bytes, always from the stream least far
                     along, so any prefix holds the same share of every mesh
                     and of the grid (``interleave``; the paper's server)
==================== ======================================================

**Which files.** Only what the served bake itself wrote: a stream attribute
counts only where the bake layer (the file served, not the input it
sublayers) authors it, and only when it names one of the layer's own
sidecars (``owned_sidecars``: recorded with a SHA-256, a usdbake sidecar name
directly in the layer's folder). Any other stream value on the stage (an
input's, ``../``, an absolute path, an unrecorded name) is left out with a
warning naming the prim, attribute and value. A request names a stream by
file name and is looked up in that table; the file is then opened inside the
folder (held open since start) by name with ``O_NOFOLLOW``, so a link is
never followed, and served only while it is a plain file with the bytes the
bake recorded (size and SHA-256, hashed again whenever its inode, size or
times change); anything else is 404. ``/stream`` sends the bytes read and
checked at start.

**What one client may hold** (``Limits``):

=================== ====== ======= ==============================================
name                type   default meaning
=================== ====== ======= ==============================================
``max_clients``     int    64      stream requests (``/files/``, ``/stream``) at
                                   once; more get 503 with Retry-After
``max_per_peer``    int    8       what one address may hold once half of
                                   ``max_clients`` are taken
``header_timeout``  float  10 s    a connection that has not sent a whole request
                                   head this long after it opened or after its
                                   last response is closed
``write_timeout``   float  10 s    a response whose client takes no bytes this
                                   long is cut off: its connection aborted, its
                                   slot freed
=================== ====== ======= ==============================================

Only the stream routes take a slot: the viewer, its script and the manifest
are answered from memory, a few KB that go into the socket at once, so no
client can hold them, and a viewer always gets its manifest. One address
takes any free slot while at least half are free, then at most
``max_per_peer``: however many requests one host sends, it holds at most half
the slots (or ``max_per_peer`` if more). Every response, error pages too, is
written under ``write_timeout``: a write waits only while the connection's
buffer is over its high-water mark (64 KiB), so a client that stops reading
gives its slot back within ``write_timeout`` (one that takes less than about
110 KiB in that time, 11 KB/s at the default, counts as stopped) and pins at
most about 192 KiB meanwhile (that 64 KiB, the up to 64 KiB aiohttp writes between two waits,
one write of at most ``WRITE_PIECE``). The header timeout is aiohttp's keep-alive
timer (``keepalive_timeout``), which runs from a connection's opening (aiohttp
3.14.4 and later) and after each response, and closes a connection still
waiting for a complete request when it fires; a request head is at most
aiohttp's default 8 KiB a line and 128 headers. Connections are not counted:
one that holds nothing is closed by these timeouts. A host with many
addresses is bounded only by ``max_clients`` and the timeouts. ``serve`` binds
127.0.0.1 unless told otherwise. Ctrl-C or SIGTERM stops the server after the
requests in flight (aiohttp's run_app).
"""

from __future__ import annotations

import asyncio
import hashlib
import heapq
import json
import os
import stat
import struct
from collections import Counter
from collections.abc import Iterable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

from aiohttp import hdrs, web
from pxr import Sdf, Usd

from ..core.errors import UsageError
from .annual_overlay import ANNUAL_PRIM, annual_overlay
from .sidecars import owned_sidecars

GRID_PRIM = "/usdbake/IrradianceGrid"
DAYLIGHT_PRIM = "/usdbake/DaylightStream"
OVERLAY_URL = "/overlay"
MESH_STREAM_ATTRIBUTE = "bake:pmStreamFile"
FRAME = struct.Struct("<IIQ")
"""Frame header of ``/stream``: stream index (0: the manifest, 1.. the manifest's streams: meshes, then the
grid), payload length, offset of the payload in its stream."""
STREAM_CHUNK = 16 * 1024
WRITE_PIECE = 64 * 1024
"""Largest single write, whatever ``chunk`` a client asks for: it bounds what a stalled client pins (module
docstring)."""
VIEWER = Path(__file__).with_name("viewer")
"""The browser viewer (index.html and its scripts: WebGL2, written here) served at / ."""
VIEWER_SCRIPTS = ("viewer.js", "sky.js", "daylight.js", "camera.js", "controls.js")
"""The viewer's scripts, each served at /NAME: the stream reader and drawing, the sky models (the kernels'
sky, sun and luminous efficacy, ported), the daylight relighting, the orbit camera, the daylight controls."""


@dataclass(frozen=True)
class Limits:
    """What one client may hold of the server (module docstring, "What one client may hold")."""

    max_clients: int = 64
    """Stream requests (``/files/``, ``/stream``) handled at once; more get 503 with Retry-After."""
    max_per_peer: int = 8
    """Stream requests one address may hold once half of ``max_clients`` are taken."""
    header_timeout: float = 10.0
    """Seconds a connection gets to send a whole request head, from its opening or its last response."""
    write_timeout: float = 10.0
    """Seconds a response may wait for its client to take bytes before the connection is aborted."""

    def __post_init__(self):
        if self.max_clients < 1 or self.max_per_peer < 1:
            raise ValueError(f"max_clients {self.max_clients}, max_per_peer {self.max_per_peer}: at least 1")
        if not (self.header_timeout > 0 and self.write_timeout > 0):
            raise ValueError(f"timeouts {self.header_timeout}, {self.write_timeout}: positive seconds")


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


class BakeFolder:
    """The served bake's folder, held open from start: its stream files are opened inside it by name, a link
    never followed and a special file never read, and count only while they hold the bytes the bake
    recorded."""

    def __init__(self, folder: Path):
        self.descriptor = os.open(folder, os.O_RDONLY | os.O_DIRECTORY | os.O_CLOEXEC)
        self.expected: dict[str, tuple[int, str]] = {}
        """File name -> (size, SHA-256) of the bytes checked at start."""
        self.checked: dict[str, tuple] = {}
        """File name -> identity (device, inode, size, mtime, ctime) last found to hold those bytes."""

    def _open(self, name: str) -> tuple[int, os.stat_result] | None:
        try:
            fd = os.open(name, os.O_RDONLY | os.O_NOFOLLOW | os.O_NONBLOCK | os.O_CLOEXEC, dir_fd=self.descriptor)
        except OSError:  # missing, a link (ELOOP), unreadable
            return None
        status = os.fstat(fd)
        if not stat.S_ISREG(status.st_mode):
            os.close(fd)
            return None
        return fd, status

    @staticmethod
    def _identity(status: os.stat_result) -> tuple:
        return status.st_dev, status.st_ino, status.st_size, status.st_mtime_ns, status.st_ctime_ns

    def read(self, name: str, sha256: str) -> bytes | None:
        """The file's bytes when it is a plain file in the folder that hashes to ``sha256`` (at start)."""
        opened = self._open(name)
        if opened is None:
            return None
        fd, status = opened
        with open(fd, "rb") as file:
            data = file.read()
        if hashlib.sha256(data).hexdigest() != sha256:
            return None
        self.expected[name], self.checked[name] = (len(data), sha256), self._identity(status)
        return data

    def open(self, name: str) -> int | None:
        """A descriptor of the file (at request time) while it still holds the bytes checked at start; the
        caller closes it."""
        opened = self._open(name)
        if opened is None:
            return None
        fd, status = opened
        if self._identity(status) != self.checked[name]:  # replaced or touched since: hash it again
            size, sha256 = self.expected[name]
            with open(fd, "rb", closefd=False) as file:
                same = status.st_size == size and hashlib.file_digest(file, "sha256").hexdigest() == sha256
            if not same:
                os.close(fd)
                return None
            self.checked[name] = self._identity(status)
        return fd

    def close(self) -> None:
        os.close(self.descriptor)


@dataclass(frozen=True)
class Stream:
    """One stream file the server hands out."""

    prim: str
    """The prim whose attribute names it (``GRID_PRIM`` for the grid)."""
    name: str
    """Its file name in the bake's folder: ``/files/NAME``."""
    sha256: str
    """Hex SHA-256 the bake recorded; the ETag of ``/files/NAME``."""
    data: bytes
    """Its bytes, read and checked at start: what ``/stream`` sends."""


@dataclass(frozen=True)
class BakeStreams:
    """What ``make_app`` serves: the streams that passed ``stage_streams``' checks, and their folder."""

    stage: str
    """The bake layer's file name."""
    folder: BakeFolder
    meshes: list[Stream]
    grid: Stream | None
    daylight: Stream | None = None
    """The daylight coefficients (formats/daylight_stream.py), when the bake ran daylight_stream."""
    overlay: bytes | None = None
    """annual_daylight's metrics on the daylight stream's faces (``annual_overlay``), when both ran."""

    def files(self) -> list[Stream]:
        """The stream files (``/files/NAME``): the meshes, the grid, the daylight stream."""
        return self.meshes + [s for s in (self.grid, self.daylight) if s is not None]

    def ordered(self) -> list[Stream]:
        """``/stream``'s numbering (1..): the files, then the overlay (from memory, no file)."""
        return self.files() + ([Stream(ANNUAL_PRIM, OVERLAY_URL, "", self.overlay)] if self.overlay else [])


def stage_streams(path: str, *, log=print) -> BakeStreams:
    """The streams the bake layer at ``path`` authors itself that name a sidecar it owns and that still hold
    its recorded bytes; every other stream attribute on the stage is left out with a warning through
    ``log``."""
    stage = Usd.Stage.Open(path)
    if stage is None:
        raise UsageError(f"{path}: cannot open the stage")
    layer = stage.GetRootLayer()
    folder = Path(layer.realPath).resolve().parent
    owned = owned_sidecars(layer)
    files = BakeFolder(folder)

    def accepted(attribute: Usd.Attribute) -> Stream | None:
        spec = layer.GetAttributeAtPath(attribute.GetPath())
        asset = spec.default if spec is not None else None  # the bake layer's own opinion, never an input's
        named = Path(os.path.normpath(folder / asset.path)) if isinstance(asset, Sdf.AssetPath) and asset.path else None
        value = attribute.Get()
        shown = value.path if isinstance(value, Sdf.AssetPath) else value
        if named not in owned:
            log(f"warning: {attribute.GetPath()} = {shown!r}: not a stream file this bake wrote in its folder; "
                f"not served")
            return None
        data = files.read(named.name, owned[named])
        if data is None:
            log(f"warning: {attribute.GetPath()} = {shown!r}: missing, a link, or not the bytes the bake recorded; "
                f"not served (bake the stage again)")
            return None
        return Stream(str(attribute.GetPrim().GetPath()), named.name, owned[named], data)

    def authored(prim: Usd.Prim, name: str) -> Usd.Attribute | None:
        attribute = prim.GetAttribute(name) if prim else None
        return attribute if attribute and attribute.HasAuthoredValue() else None

    mesh_attributes = [a for a in (authored(prim, MESH_STREAM_ATTRIBUTE) for prim in stage.Traverse()) if a]
    meshes = [stream for stream in map(accepted, mesh_attributes) if stream]
    grid_attribute = authored(stage.GetPrimAtPath(GRID_PRIM), "streamFile")
    grid = accepted(grid_attribute) if grid_attribute else None
    daylight_attribute = authored(stage.GetPrimAtPath(DAYLIGHT_PRIM), "streamFile")
    daylight = accepted(daylight_attribute) if daylight_attribute else None
    if not meshes and grid is None and daylight is None:
        files.close()
        raise UsageError(f"{path}: no streams to serve: bake it with -p progressive_mesh, -p irradiance_grid "
                         f"and/or -p daylight_stream")
    overlay = annual_overlay(stage, layer, daylight.data) if daylight else None
    return BakeStreams(Path(path).name, files, meshes, grid, daylight, overlay)


class Slots:
    """Stream slots (module docstring): at most ``max_clients`` taken, and once half are taken, at most
    ``max_per_peer`` by one address."""

    def __init__(self, limits: Limits):
        self.limits = limits
        self.taken: Counter = Counter()
        """Address -> slots it holds."""

    @contextmanager
    def hold(self, peer: str | None) -> Iterator[None]:
        """A slot for ``peer`` while the block runs; 503 with Retry-After when there is none for it."""
        total = self.taken.total()
        if total >= self.limits.max_clients or (
                self.taken[peer] >= self.limits.max_per_peer and 2 * total >= self.limits.max_clients):
            raise web.HTTPServiceUnavailable(headers={"Retry-After": "1"}, text="too many clients; retry")
        self.taken[peer] += 1
        try:
            yield
        finally:
            self.taken[peer] -= 1
            if not self.taken[peer]:
                del self.taken[peer]


async def send(request: web.BaseRequest, response: web.StreamResponse, chunks: Iterable = (), *,
               timeout: float) -> web.StreamResponse:
    """Prepare ``response``, write ``chunks`` (bytes-like) and end it, the deadline ``timeout`` s ahead of
    each step: a write waits only while the connection's buffer is over aiohttp's high-water mark, so a
    client that takes no bytes for that long is cut off (its connection aborted, the rest unwritten). A
    client that goes away ends it the same way. A response already ended is left as it is."""
    loop = asyncio.get_running_loop()
    if request.method == hdrs.METH_HEAD:
        chunks = ()  # the head only
    try:
        async with asyncio.timeout(timeout) as deadline:
            await response.prepare(request)
            for chunk in chunks:
                await response.write(chunk)
                deadline.reschedule(loop.time() + timeout)
            await response.write_eof()
    except (TimeoutError, ConnectionError):
        if request.transport is not None:
            request.transport.abort()
    return response


def written_in_time(timeout: float):
    """Middleware: every response, error pages too, written by ``send`` under the write timeout."""

    @web.middleware
    async def written(request: web.Request, handler):
        try:
            response = await handler(request)
        except web.HTTPException as error:  # an aiohttp Response: written here, raised for aiohttp's bookkeeping
            await send(request, error, timeout=timeout)
            raise
        return await send(request, response, timeout=timeout)

    return written


def frame(index: int, offset: int, payload: memoryview) -> Iterator[bytes | memoryview]:
    """One ``/stream`` frame as writes of at most ``WRITE_PIECE`` bytes (a small frame: one write)."""
    head = FRAME.pack(index, len(payload), offset)
    if len(payload) <= WRITE_PIECE:
        yield head + payload
        return
    yield head
    yield from (payload[at:at + WRITE_PIECE] for at in range(0, len(payload), WRITE_PIECE))


def byte_range(request: web.Request, size: int, etag: str) -> tuple[web.StreamResponse, int, int]:
    """The response head for what a request asks of a ``size``-byte file with strong ETag ``etag`` (304 on
    If-None-Match; one range, 206, or 416 when unsatisfiable) and the span [start, stop) to send."""
    headers = {"Content-Type": "application/octet-stream", "ETag": f'"{etag}"', "Accept-Ranges": "bytes"}
    if any(tag.value in (etag, "*") for tag in request.if_none_match or ()):
        raise web.HTTPNotModified(headers={"ETag": headers["ETag"]})
    start, stop, status = 0, size, 200
    if hdrs.RANGE in request.headers:
        try:
            start, stop, _ = request.http_range.indices(size)
        except ValueError:  # malformed, several ranges, start after end
            start = stop = 0
        if start >= stop:
            raise web.HTTPRequestRangeNotSatisfiable(headers={"Content-Range": f"bytes */{size}"})
        headers["Content-Range"], status = f"bytes {start}-{stop - 1}/{size}", 206
    response = web.StreamResponse(status=status, headers=headers)
    response.content_length = stop - start
    return response, start, stop


def make_app(path: str, *, limits: Limits = Limits(), log=print) -> web.Application:
    """The aiohttp application serving ``path``'s streams (module docstring). Its header timeout is the
    runner's: pass ``keepalive_timeout=limits.header_timeout`` to ``web.AppRunner`` or ``web.run_app``."""
    streams = stage_streams(path, log=log)
    ordered = streams.ordered()
    by_name = {stream.name: stream for stream in streams.files()}

    def entry(stream: Stream) -> dict:
        return {"url": f"/files/{stream.name}", "bytes": len(stream.data)}

    manifest = {"stage": streams.stage, "meshes": [{"prim": m.prim, **entry(m)} for m in streams.meshes],
                "grid": entry(streams.grid) if streams.grid else None,
                "daylight": entry(streams.daylight) if streams.daylight else None,
                "overlay": {"url": OVERLAY_URL, "bytes": len(streams.overlay)} if streams.overlay else None}
    header = json.dumps(manifest).encode()
    page = (VIEWER / "index.html").read_text()
    scripts = {name: (VIEWER / name).read_text() for name in VIEWER_SCRIPTS}
    slots = Slots(limits)

    async def index(request: web.Request) -> web.Response:
        return web.Response(content_type="text/html", text=page)

    async def viewer_script(request: web.Request) -> web.Response:
        return web.Response(content_type="text/javascript", text=scripts[request.path.lstrip("/")])

    async def overlay_route(request: web.Request) -> web.Response:
        if streams.overlay is None:
            raise web.HTTPNotFound(text="no annual_daylight results on this bake's daylight faces")
        return web.Response(body=streams.overlay, content_type="application/octet-stream")

    async def manifest_route(request: web.Request) -> web.Response:
        response = web.Response(text=json.dumps(manifest), content_type="application/json")
        response.enable_compression()
        return response

    def frames(chunk: int) -> Iterator[bytes | memoryview]:
        yield from frame(0, 0, memoryview(header))
        for index, offset, length in interleave([len(s.data) for s in ordered], chunk):
            yield from frame(index + 1, offset, memoryview(ordered[index].data)[offset:offset + length])

    async def stream_route(request: web.Request) -> web.StreamResponse:
        try:
            chunk = int(request.query.get("chunk", STREAM_CHUNK))
        except ValueError:
            raise web.HTTPBadRequest(text="chunk must be an integer") from None
        if not 1024 <= chunk <= 1 << 24:
            raise web.HTTPBadRequest(text="chunk must be within 1024..16777216 bytes")
        with slots.hold(request.remote):
            response = web.StreamResponse(headers={"Content-Type": "application/octet-stream"})
            return await send(request, response, frames(chunk), timeout=limits.write_timeout)

    async def file_route(request: web.Request) -> web.StreamResponse:
        stream = by_name.get(request.match_info["name"])
        if stream is None:
            raise web.HTTPNotFound(text="not a stream of this stage")
        with slots.hold(request.remote):
            fd = await asyncio.to_thread(streams.folder.open, stream.name)
            if fd is None:
                raise web.HTTPNotFound(text="no longer the file the bake wrote")
            try:
                response, start, stop = byte_range(request, len(stream.data), stream.sha256)
                pieces = (os.pread(fd, min(WRITE_PIECE, stop - at), at) for at in range(start, stop, WRITE_PIECE))
                return await send(request, response, pieces, timeout=limits.write_timeout)
            finally:
                os.close(fd)

    async def close_folder(app: web.Application) -> None:
        streams.folder.close()

    app = web.Application(middlewares=[written_in_time(limits.write_timeout)])
    app.router.add_get("/", index)
    for name in VIEWER_SCRIPTS:
        app.router.add_get(f"/{name}", viewer_script)
    app.router.add_get("/manifest", manifest_route)
    app.router.add_get(OVERLAY_URL, overlay_route)
    app.router.add_get("/files/{name}", file_route)
    app.router.add_get("/stream", stream_route)
    app.on_cleanup.append(close_folder)
    return app


def serve(path: str, *, host: str = "127.0.0.1", port: int = 8642, limits: Limits = Limits(), log=print) -> None:
    """Serve until interrupted (Ctrl-C / SIGTERM): the requests in flight finish, then it stops."""
    app = make_app(path, limits=limits, log=log)
    web.run_app(app, host=host, port=port, keepalive_timeout=limits.header_timeout,
                print=lambda line: log(line.strip()) if line.strip() else None)
