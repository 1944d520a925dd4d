"""Ambient occlusion: cosine-weighted hemisphere ray casts per vertex (and per instance).

One package per technique: its processors, and the kernels, geometry and formats only it
uses. It imports core/, kernels/, geometry/ and formats/, never another technique."""
