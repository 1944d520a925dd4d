"""farm.cluster on its own: where the scheduler address comes from, the one-line UsageErrors for a
missing Dask or an unreachable scheduler (reason on one line, cut at 160 characters), and the worker and
thread counts against an in-process Dask LocalCluster whose sizes are set here.

The command's refusal of an unreachable scheduler before any work is tested in tests/farm/test_batch.py.
"""

from __future__ import annotations

import socket
import sys

import pytest
from usdbake.core.errors import UsageError
from usdbake.farm import cluster

distributed = pytest.importorskip("distributed")


@pytest.fixture(scope="module")
def local_client():
    """Two in-process workers of two threads each (no nannies: starts in about a second)."""
    with distributed.LocalCluster(n_workers=2, threads_per_worker=2, processes=False, dashboard_address=":0") as lc:
        with distributed.Client(lc) as client:
            yield client


def test_scheduler_address_prefers_the_option_then_the_environment(monkeypatch):
    monkeypatch.delenv("DASK_SCHEDULER_ADDRESS", raising=False)
    assert cluster.scheduler_address(None) is None
    assert cluster.scheduler_address("") is None
    assert cluster.scheduler_address("tcp://a:8786") == "tcp://a:8786"
    monkeypatch.setenv("DASK_SCHEDULER_ADDRESS", "tcp://env:8786")
    assert cluster.scheduler_address(None) == "tcp://env:8786"
    assert cluster.scheduler_address("") == "tcp://env:8786"  # an empty option is no option
    assert cluster.scheduler_address("tcp://a:8786") == "tcp://a:8786"
    monkeypatch.setenv("DASK_SCHEDULER_ADDRESS", "")
    assert cluster.scheduler_address(None) is None


def test_missing_dask_is_a_usage_error_naming_the_install(monkeypatch):
    cluster.require_dask("--scheduler x")  # installed here: nothing raised
    monkeypatch.setitem(sys.modules, "distributed", None)  # what `import distributed` meets when it is absent
    with pytest.raises(UsageError) as raised:
        cluster.require_dask("bake_many")
    message = str(raised.value)
    assert message.startswith("bake_many needs Dask") and cluster.INSTALL_HINT in message and "\n" not in message
    with pytest.raises(UsageError, match="^--scheduler tcp://x:1 needs Dask"):
        cluster.connect("tcp://x:1")


def closed_port() -> int:
    """A local TCP port nothing listens on (bound, then released)."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_an_unreachable_scheduler_is_one_usage_error_line():
    address = f"tcp://127.0.0.1:{closed_port()}"
    with pytest.raises(UsageError) as raised:
        cluster.connect(address, timeout=0.5)
    message = str(raised.value)
    assert message.startswith(f"--scheduler {address}: cannot reach the Dask scheduler (")
    assert "\n" not in message and message.endswith(")")


def test_a_long_reason_is_cut_to_160_characters():
    # A port Dask cannot parse: the reason quotes it, 300 characters of it (no network involved).
    address = "tcp://localhost:" + "p" * 300
    with pytest.raises(UsageError) as raised:
        cluster.connect(address, timeout=0.5)
    message = str(raised.value)
    reason = message[message.index("scheduler (") + len("scheduler ("):-1]
    assert len(reason) == 160 and reason.endswith("p...") and "\n" not in message


def test_worker_count_and_threads_inside_and_outside_a_worker(local_client, monkeypatch):
    assert cluster.worker_count(local_client) == 2
    with cluster.connect(local_client.scheduler.address, timeout=5.0) as connected:  # a reachable scheduler
        assert cluster.worker_count(connected) == 2
        assert distributed.default_client() is local_client  # connect() does not become the default
    # Inside a Dask worker: its thread count, whatever the pool variable says.
    assert set(local_client.gather(local_client.map(lambda _: cluster.worker_threads(), range(4)))) == {2}
    monkeypatch.delenv(cluster.WORKER_THREADS_VARIABLE, raising=False)
    assert cluster.worker_threads() is None  # here, in no worker: every core
    monkeypatch.setenv(cluster.WORKER_THREADS_VARIABLE, "3")
    assert cluster.worker_threads() == 3
    monkeypatch.setenv(cluster.WORKER_THREADS_VARIABLE, "")
    assert cluster.worker_threads() is None


def test_worker_count_is_at_least_one_while_workers_join():
    with distributed.LocalCluster(n_workers=0, processes=False, dashboard_address=":0") as lc:
        with distributed.Client(lc) as client:
            assert cluster.worker_count(client) == 1
