"""The farm tests start Dask LocalClusters, whose nannies write Dask's worker settings (OMP_NUM_THREADS=1,
MALLOC_TRIM_THRESHOLD_, ...) into this process's environment; put it back so later tests' subprocesses
do not inherit them."""

import os

import pytest


@pytest.fixture(autouse=True, scope="module")
def restore_environment():
    saved = dict(os.environ)
    yield
    os.environ.clear()
    os.environ.update(saved)
