"""Shared pytest setup for usdbake's tests."""

import sys
from pathlib import Path

# Tests run with --import-mode=importlib, which does not put tests/ on sys.path;
# plain helper modules here (stage_builders) are imported as top-level modules.
sys.path.insert(0, str(Path(__file__).parent))
