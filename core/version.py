"""The installed usdbake's version, written into provenance and cache manifests."""

from importlib.metadata import PackageNotFoundError, version

try:
    __version__ = version("usdbake")
except PackageNotFoundError:  # running from a source tree that was never installed
    __version__ = "0.0.0+source"
