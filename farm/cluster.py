"""Connecting to a Dask scheduler: the address from --scheduler or DASK_SCHEDULER_ADDRESS, one clear
line (a UsageError, exit 2) when Dask is missing or the scheduler cannot be reached, before any work."""

from __future__ import annotations

import os

from ..core.errors import UsageError

INSTALL_HINT = "pip install -e \".[distributed]\" (or pip install \"dask[distributed]\")"
CONNECT_TIMEOUT = 10.0
"""Seconds to wait for the scheduler before giving up (a firewall drops packets rather than refusing)."""


def scheduler_address(given: str | None) -> str | None:
    """--scheduler, else $DASK_SCHEDULER_ADDRESS, else None (bake here)."""
    return given or os.environ.get("DASK_SCHEDULER_ADDRESS") or None


def require_dask(what: str) -> None:
    """UsageError naming how to install Dask when it is missing."""
    try:
        import distributed  # noqa: F401  (imported only to check it is there)
    except ImportError:
        raise UsageError(f"{what} needs Dask, which is not installed: {INSTALL_HINT}") from None


def connect(address: str, *, timeout: float | None = None):
    """A ``distributed.Client`` connected to ``address`` (waiting ``timeout`` s, default CONNECT_TIMEOUT);
    UsageError in one line if it cannot be."""
    require_dask(f"--scheduler {address}")
    from distributed import Client

    try:
        return Client(address, timeout=timeout or CONNECT_TIMEOUT, set_as_default=False)
    except (OSError, TimeoutError, ValueError) as error:
        reason = " ".join(str(error).split()) or type(error).__name__
        if len(reason) > 160:
            reason = reason[:157] + "..."
        raise UsageError(f"--scheduler {address}: cannot reach the Dask scheduler ({reason})") from None


def worker_count(client) -> int:
    """Workers the scheduler knows now (at least 1, so chunk sizes stay defined while workers join)."""
    return max(1, len(client.scheduler_info(n_workers=-1).get("workers", {})))


WORKER_THREADS_VARIABLE = "USDBAKE_WORKER_THREADS"
"""Set by the local pool's initializer: a pool worker's share of the cores."""


def worker_threads() -> int | None:
    """Ray threads for work in a worker process: the Dask worker's thread count, else a pool worker's
    share of the cores, else None (every core); so 2 workers x 1 thread on 2 cores run 2 ray threads, not 4."""
    try:
        from distributed import get_worker

        return get_worker().state.nthreads
    except (ImportError, ValueError, AttributeError):
        share = os.environ.get(WORKER_THREADS_VARIABLE)
        return int(share) if share else None
