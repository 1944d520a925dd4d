"""Shared pytest setup for usdbake's tests."""

import sys
from pathlib import Path

# Tests run with --import-mode=importlib, which does not put tests/ on sys.path;
# plain helper modules here (stage_builders) are imported as top-level modules.
sys.path.insert(0, str(Path(__file__).parent))

import pytest  # noqa: E402  (after the path set-up, so the helper modules import)
from hypothesis import settings  # noqa: E402

# Property tests draw the same examples on every run (a fixed seed, no example database): a red CI run
# can be rerun as it was, and a green one does not turn red by the luck of the draw.
settings.register_profile("usdbake", derandomize=True, database=None)
settings.load_profile("usdbake")


@pytest.fixture
def stage_in(tmp_path):
    """A small stage with fake-processor receivers, written to tmp_path/in.usda; returns its path."""
    import fake_processors

    return fake_processors.write_stage(tmp_path / "in.usda")


def _forbidden(*args, **kwargs):
    raise AssertionError("compute started before the input was checked")


@pytest.fixture
def no_compute(monkeypatch):
    """Fail the test if any processor runs: a bad input must be refused before."""
    from usdbake.core import registry

    for processor in registry.registry().values():
        monkeypatch.setattr(processor, "run", _forbidden)


@pytest.fixture
def no_read(monkeypatch, no_compute):
    """Also fail it if the stage is read into a Scene, by the command or the hook."""
    from usdbake.stages import bake_file, extract  # bake_file (the command's and the hook's) binds it at import

    for module in (extract, bake_file):
        monkeypatch.setattr(module, "extract_scene", _forbidden)


@pytest.fixture
def cache(tmp_path):
    """A result-cache folder of the test's own."""
    return str(tmp_path / "cache")
