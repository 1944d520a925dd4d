"""Shared pytest setup for usdbake's tests."""

import sys
from pathlib import Path

# Tests run with --import-mode=importlib, which does not put tests/ on sys.path;
# plain helper modules here (stage_builders) are imported as top-level modules.
sys.path.insert(0, str(Path(__file__).parent))

import pytest  # noqa: E402  (after the path set-up, so the helper modules import)


@pytest.fixture
def stage_in(tmp_path):
    """A small stage with fake-processor receivers, written to tmp_path/in.usda; returns its path."""
    import fake_processors

    return fake_processors.write_stage(tmp_path / "in.usda")


@pytest.fixture
def cache(tmp_path):
    """A result-cache folder of the test's own."""
    return str(tmp_path / "cache")
