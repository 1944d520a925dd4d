"""Irradiance vector grids and progressive meshes: six irradiance vectors per grid vertex,
quantized and streamed progressively with push-pull hole filling (Pacanowski et al.).

One package per technique: its processors, and the kernels, geometry and formats only it
uses. It imports core/, kernels/, geometry/ and formats/, never another technique."""
