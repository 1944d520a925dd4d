"""Shared Warp functions (@wp.func) used by several processors."""
