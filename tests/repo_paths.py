"""Where the repository's own files are, for tests in any folder under tests/."""

from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
"""The repository root (the usdbake package)."""

SAMPLES = REPO / "samples"
