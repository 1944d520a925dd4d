"""Displacement fields and instance AO: presampled visibility around rigid prototypes, looked up
for the ambient occlusion of instanced and moving objects (Gaitatzes, Chrysanthou & Papaioannou).

One package per technique: its processors, and the kernels, geometry and formats only it
uses. It imports core/, kernels/, geometry/ and formats/, never another technique."""
