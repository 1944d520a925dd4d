"""``usdbake serve``: a baked stage's progressive-mesh and irradiance-grid streams over HTTP (stages.serve)."""

from __future__ import annotations

from rich.console import Console

from ..core.errors import UsageError
from .console import EXIT_OK


def add_parser(commands) -> None:
    serve = commands.add_parser("serve", help="serve a baked stage's progressive mesh and irradiance-grid streams "
                                "over HTTP (range requests, ETags)")
    serve.add_argument("input", help="a baked stage (usdbake bake -p progressive_mesh and/or -p irradiance_grid)")
    serve.add_argument("--host", default="127.0.0.1", help="address to listen on (default: this machine only)")
    serve.add_argument("--port", type=int, default=8642)
    serve.add_argument("--max-clients", type=int, default=64, help="stream requests handled at once; more get 503")
    serve.add_argument("--max-per-peer", type=int, default=8, help="stream requests one address may hold once half "
                       "of --max-clients are taken")


def cmd_serve(args, console: Console) -> int:
    from ..stages.serve import Limits, serve

    if args.max_clients < 1:
        raise UsageError(f"--max-clients {args.max_clients}: at least 1")
    if not 0 <= args.port <= 65535:
        raise UsageError(f"--port {args.port}: not a TCP port (0..65535)")
    if args.max_per_peer < 1:
        raise UsageError(f"--max-per-peer {args.max_per_peer}: at least 1")
    serve(args.input, host=args.host, port=args.port,
          limits=Limits(max_clients=args.max_clients, max_per_peer=args.max_per_peer),
          log=lambda line: console.print(line, highlight=False))
    return EXIT_OK
