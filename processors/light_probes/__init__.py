"""Light-probe clouds: placement, L2 spherical-harmonic capture, tetrahedral interpolation
and leak fixing by ray casts (Sukys; Cupisz).

One package per technique: its processors, and the kernels, geometry and formats only it
uses. It imports core/, kernels/, geometry/ and formats/, never another technique."""
