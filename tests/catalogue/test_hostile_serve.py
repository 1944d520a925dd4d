"""Hostile cases for ``usdbake serve`` (issue 27, items 2 and 3): it hands out only the files the served bake
wrote, and one host cannot block it.

Files: a stream an input authors (the issue's ``@/etc/hostname@``), names in the provenance that leave the
folder, a sidecar replaced by a link (before start, and after start with the same bytes, so only the refusal
to follow links can stop it), a hard link and an edit in place. Load: the issue's 70 clients that ask for
``/stream?chunk=1024`` with a 1 KiB receive window and never read, and 100 connections that never finish
their request head, while a normal client asks for the manifest.
"""

from __future__ import annotations

import asyncio
import hashlib
import http.client
import json
import os
import socket
import threading
import time
from collections import defaultdict
from contextlib import ExitStack, contextmanager
from pathlib import Path

import pytest
from aiohttp import web
from pxr import Sdf, Vt

from repo_paths import SAMPLES
from usdbake.cli.main import main
from usdbake.core.errors import UsageError
from usdbake.stages.serve import FRAME, Limits, make_app

SECRET = b"SECRET-CONTENT"
GRID = ["-p", "irradiance_grid", "--set", "irradiance_grid.rays=16"]
FAST_AO = ["-p", "ambient_occlusion", "--set", "ambient_occlusion.samples=16"]


def bake(folder: Path, source: Path, *options) -> Path:
    out = folder / "out" / "baked.usdc"
    assert main(["bake", str(source), "-o", str(out), *options, "--cache", str(folder / "cache")]) == 0
    return out


def digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


@contextmanager
def serving(app: web.Application, limits: Limits = Limits()):
    """The app on a free loopback port in a thread of its own, with serve's header timeout; yields (port,
    runner, loop)."""
    loop = asyncio.new_event_loop()
    runner = web.AppRunner(app, keepalive_timeout=limits.header_timeout)
    loop.run_until_complete(runner.setup())
    site = web.TCPSite(runner, "127.0.0.1", 0)
    loop.run_until_complete(site.start())
    thread = threading.Thread(target=loop.run_forever, daemon=True)
    thread.start()
    try:
        yield site._server.sockets[0].getsockname()[1], runner, loop
    finally:
        loop.call_soon_threadsafe(loop.stop)
        thread.join(5)
        loop.run_until_complete(runner.cleanup())
        loop.close()


def get(port: int, path: str, *, source: str = "127.0.0.1", headers=None) -> tuple[int, bytes]:
    """(status, body) of GET ``path`` from the loopback address ``source``."""
    connection = http.client.HTTPConnection("127.0.0.1", port, timeout=30, source_address=(source, 0))
    try:
        connection.request("GET", path, headers=headers or {})
        response = connection.getresponse()
        return response.status, response.read()
    finally:
        connection.close()


def peeked_status(sock: socket.socket) -> bytes:
    """The status code a socket has received, left unread (b'' before the answer)."""
    try:
        head = sock.recv(12, socket.MSG_PEEK | socket.MSG_DONTWAIT)
    except BlockingIOError:
        return b""
    return head[9:12] if len(head) == 12 else b""


def hostile_input(folder: Path) -> tuple[Path, Path]:
    """cornell_box under a layer that authors streams on three meshes: the issue's /etc/hostname, a secret
    file of the test's own (absolute) and ``../secret.txt`` relative to the input. Returns (input, secret)."""
    secret = folder / "secret.txt"
    secret.write_bytes(SECRET)
    layer = Sdf.Layer.CreateNew(str(folder / "input.usda"))
    layer.subLayerPaths.append(str(SAMPLES / "cornell_box.usda"))
    for prim, value in (("Floor", "/etc/hostname"), ("Ceiling", str(secret)), ("BackWall", "../secret.txt")):
        spec = Sdf.CreatePrimInLayer(layer, f"/World/CornellBox/{prim}")
        Sdf.AttributeSpec(spec, "bake:pmStreamFile", Sdf.ValueTypeNames.Asset).default = Sdf.AssetPath(value)
    layer.Save()
    return folder / "input.usda", secret


def test_streams_an_input_authors_are_never_served(tmp_path):
    source, secret = hostile_input(tmp_path)
    warnings: list[str] = []
    ao_only = bake(tmp_path / "ao", source, *FAST_AO)
    with pytest.raises(UsageError, match="no streams to serve"):
        make_app(str(ao_only), log=warnings.append)
    assert any("/World/CornellBox/Floor.bake:pmStreamFile = '/etc/hostname'" in line for line in warnings)

    warnings.clear()
    baked = bake(tmp_path / "ao_grid", source, *FAST_AO, *GRID, "--set", "irradiance_grid.vertices=300")
    app = make_app(str(baked), log=warnings.append)
    for prim, value in (("Floor", "/etc/hostname"), ("Ceiling", str(secret)), ("BackWall", "../secret.txt")):
        assert sum(f"/World/CornellBox/{prim}.bake:pmStreamFile = {value!r}: not a stream file" in line
                   for line in warnings) == 1, warnings
    with serving(app) as (port, _, _):
        status, body = get(port, "/manifest")
        assert status == 200 and b"hostname" not in body and b"secret" not in body
        manifest = json.loads(body)
        assert manifest["meshes"] == [] and manifest["grid"]["url"].startswith("/files/baked_")
        for attack in ("/files/hostname", "/files/secret.txt", "/files/..%2Fsecret.txt", "/files/%2Fetc%2Fhostname",
                       "/files/" + str(secret).replace("/", "%2F"), "/" + str(secret).lstrip("/")):
            status, body = get(port, attack)
            assert status == 404 and SECRET not in body, attack
        status, stream = get(port, "/stream")
        assert status == 200 and SECRET not in stream


def test_provenance_names_outside_the_folder_or_not_ours_are_left_out(tmp_path):
    """A bake layer edited to record '../secret.bin', an absolute path and a user file in the folder as
    sidecars (with their right digests) and to point mesh streams at them."""
    baked = bake(tmp_path, SAMPLES / "cornell_box.usda", "-p", "progressive_mesh", *GRID,
                 "--set", "irradiance_grid.vertices=300")
    outside, elsewhere, notes = tmp_path / "secret.bin", tmp_path / "else" / "secret.bin", baked.parent / "notes.bin"
    elsewhere.parent.mkdir()
    for path in (outside, elsewhere, notes):
        path.write_bytes(SECRET)
    layer = Sdf.Layer.FindOrOpen(str(baked))
    data = dict(layer.customLayerData)
    provenance = dict(data["usdbake"])
    names = ["../secret.bin", str(elsewhere), "./notes.bin"]
    data["usdbake"] = {**provenance, "sidecars": Vt.StringArray([*provenance["sidecars"], *names]),
                       "sidecarDigests": Vt.StringArray([*provenance["sidecarDigests"], *[digest(outside)] * 3])}
    layer.customLayerData = data
    meshes = ["/World/CornellBox/Floor", "/World/CornellBox/Ceiling", "/World/CornellBox/BackWall"]
    for prim, name in zip(meshes, names):
        layer.GetAttributeAtPath(f"{prim}.bake:pmStreamFile").default = Sdf.AssetPath(name)
    layer.Save()

    warnings: list[str] = []
    with serving(make_app(str(baked), log=warnings.append)) as (port, _, _):
        status, body = get(port, "/manifest")
        listed = {mesh["prim"] for mesh in json.loads(body)["meshes"]}
        assert status == 200 and listed and not listed & set(meshes)
        for prim, name in zip(meshes, names):
            assert any(f"{prim}.bake:pmStreamFile = {name!r}: not a stream file" in line for line in warnings)
        for attack in ("/files/secret.bin", "/files/notes.bin", "/files/..%2Fsecret.bin"):
            status, body = get(port, attack)
            assert status == 404 and SECRET not in body, attack
        status, stream = get(port, "/stream")
        assert status == 200 and SECRET not in stream


def test_a_sidecar_replaced_by_a_link_or_other_bytes_is_not_served(tmp_path):
    """Links carry the very bytes the bake wrote, so the digest alone would pass them: the refusal to follow
    links is what stops them. Before start the link is left out; after start every swap is a 404 at
    request time, and the bake's own bytes put back (a new file) are served again."""
    baked = bake(tmp_path, SAMPLES / "cornell_box.usda", "-p", "progressive_mesh", *GRID,
                 "--set", "irradiance_grid.vertices=300")
    sidecars = sorted(baked.parent.glob("baked_*.bin"), key=lambda path: path.stat().st_size, reverse=True)
    early, swapped, hard, edited = sidecars[:4]
    copies = {}
    for path in (early, swapped, hard, edited):
        copies[path] = tmp_path / f"copy_{path.name}"
        copies[path].write_bytes(path.read_bytes())
    early.unlink()
    early.symlink_to(copies[early])
    warnings: list[str] = []
    app = make_app(str(baked), log=warnings.append)
    assert any(f"= './{early.name}': missing, a link" in line for line in warnings), warnings
    with serving(app) as (port, _, _):
        status, body = get(port, "/manifest")
        assert early.name not in body.decode()
        assert get(port, f"/files/{early.name}")[0] == 404
        for path in (swapped, hard, edited):
            assert get(port, f"/files/{path.name}") == (200, copies[path].read_bytes())
        secret = tmp_path / "secret.bin"
        secret.write_bytes(SECRET)
        swapped.unlink()
        swapped.symlink_to(copies[swapped])  # the same bytes, through a link
        hard.unlink()
        os.link(secret, hard)  # a hard link to a file that is not the bake's
        edited.write_bytes(b"x" * edited.stat().st_size)  # same size, other bytes, same inode
        for path in (swapped, hard, edited):
            status, body = get(port, f"/files/{path.name}", headers={"Range": "bytes=0-3"})
            assert status == 404 and SECRET not in body, path.name
        status, stream = get(port, "/stream")  # the bytes read and checked at start
        assert status == 200 and copies[swapped].read_bytes()[:64] in stream and SECRET not in stream
        swapped.unlink()
        swapped.write_bytes(copies[swapped].read_bytes())  # the bake's bytes again, a new file
        assert get(port, f"/files/{swapped.name}") == (200, copies[swapped].read_bytes())


def closed_by_server(sock: socket.socket) -> bool:
    """Whether the server has closed this connection (it sends nothing else to these)."""
    try:
        return sock.recv(1, socket.MSG_DONTWAIT) == b""
    except BlockingIOError:
        return False
    except ConnectionError:
        return True


def drained(sock: socket.socket) -> int:
    """Bytes left to read on a connection until the server's end or reset."""
    received = 0
    try:
        while chunk := sock.recv(1 << 16):
            received += len(chunk)
    except ConnectionResetError:
        pass
    return received


def streams_of(body: bytes) -> dict[int, bytes]:
    """A /stream body reassembled: stream index -> its bytes (0: the manifest)."""
    parts, at = defaultdict(bytearray), 0
    while at < len(body):
        index, length, offset = FRAME.unpack_from(body, at)
        assert offset == len(parts[index])
        parts[index] += body[at + FRAME.size:at + FRAME.size + length]
        at += FRAME.size + length
    return {index: bytes(part) for index, part in parts.items()}


def test_one_host_with_stalled_readers_and_slow_headers_does_not_block_a_normal_client(tmp_path):
    """The issue's load, timeouts shortened to 2 s so the test sees them expire. 70 clients from 127.0.0.1
    ask for /stream with a 1 KiB receive window (and a 536-byte MSS, as over a real network: on loopback
    the kernel would otherwise take 1.7 MB of a stalled connection) and never read; 100 connections from
    127.0.0.1 send a header line every 0.5 s and never finish. Meanwhile a client from the same address
    asks for the manifest every 0.1 s, and one from 127.0.0.2 takes the whole /stream."""
    baked = bake(tmp_path, SAMPLES / "cornell_box.usda", "-p", "progressive_mesh", *GRID,
                 "--set", "irradiance_grid.vertices=10000")  # a 420 KB grid: a stalled /stream blocks
    limits = Limits(header_timeout=2.0, write_timeout=2.0)
    grid = next(baked.parent.glob("baked_usdbake_irradiance_grid_*.bin"))
    with serving(make_app(str(baked), limits=limits), limits) as (port, runner, loop), ExitStack() as sockets:
        def connect(*, stalled: bool) -> socket.socket:
            sock = sockets.enter_context(socket.socket())
            if stalled:
                sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1024)
                sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_MAXSEG, 536)
            sock.connect(("127.0.0.1", port))
            return sock

        def buffered() -> int:
            """Bytes the server holds in its connections' write buffers."""
            async def total():
                return sum(h.transport.get_write_buffer_size() for h in runner.server.connections if h.transport)
            return asyncio.run_coroutine_threadsafe(total(), loop).result(10)

        started = time.monotonic()
        stalled = [connect(stalled=True) for _ in range(70)]
        for sock in stalled:
            sock.sendall(b"GET /stream?chunk=1024 HTTP/1.1\r\nHost: usdbake\r\n\r\n")
        slow = {}  # socket -> when it opened
        for _ in range(100):
            sock = connect(stalled=False)
            slow[sock] = time.monotonic()
            sock.sendall(b"GET /manifest HTTP/1.1\r\nHost: usdbake\r\n")
        while b"" in (answered := [peeked_status(sock) for sock in stalled]) and time.monotonic() - started < 20:
            time.sleep(0.05)
        # One address holds at most half the 64 slots; the rest of its requests are refused at once.
        assert (answered.count(b"200"), answered.count(b"503")) == (32, 38)
        assert get(port, f"/files/{grid.name}")[0] == 503  # a 33rd stream for this address

        latencies, closed, freed_after, peak_buffered, trickled = [], {}, None, 0, 0.0
        deadline = started + max(limits.header_timeout, limits.write_timeout) + 10
        while (len(closed) < len(slow) or freed_after is None) and time.monotonic() < deadline:
            asked = time.monotonic()
            status, body = get(port, "/manifest")  # from 127.0.0.1, like the attackers
            latencies.append(time.monotonic() - asked)
            assert status == 200 and b'"grid"' in body
            peak_buffered = max(peak_buffered, buffered())
            if time.monotonic() - trickled > 0.5:
                trickled = time.monotonic()
                for sock in set(slow) - set(closed):
                    if closed_by_server(sock):
                        closed[sock] = time.monotonic() - slow[sock]
                    else:
                        sock.sendall(b"X-Slow: 1\r\n")
            if freed_after is None and get(port, f"/files/{grid.name}")[0] == 200:
                freed_after = time.monotonic() - started
            time.sleep(0.1)

        status, body = get(port, "/stream", source="127.0.0.2")  # another host, while the load lasts
        streams = streams_of(body)
        manifest = json.loads(streams[0])
        assert status == 200 and streams[len(manifest["meshes"]) + 1] == grid.read_bytes()
        cut = [drained(sock) for sock, answer in zip(stalled, answered) if answer == b"200"]

    worst = max(latencies)
    print(f"\nnormal client, {len(latencies)} manifests under load: worst {worst * 1000:.1f} ms, "
          f"median {sorted(latencies)[len(latencies) // 2] * 1000:.1f} ms; stalled slots free again after "
          f"{freed_after:.1f} s; slow-header connections closed {min(closed.values()):.1f}.."
          f"{max(closed.values()):.1f} s after opening; server write buffers at most {peak_buffered / 1024:.0f} KiB")
    # Every manifest asked for under the load was answered (200, above); the latency is a figure, printed,
    # not asserted: a busy CI machine must not fail a correct server (docs/streaming.md has the measurements).
    # The stalled readers were cut off mid-stream and their slots came back before the loop's deadline
    # (the timeouts plus 10 s): without the write timeout they would hold them as long as they stall.
    assert freed_after is not None
    assert len(cut) == 32 and max(cut) < grid.stat().st_size
    # Every slow-header connection was closed by the header timeout before that deadline, not held.
    assert len(closed) == 100
    # What a stalled reader pins: at most about 192 KiB (stages/serve.py); 32 of them.
    assert peak_buffered <= 32 * 192 * 1024
