"""The renderer behind `usdbake preview` (outside every processor's cache key)."""
