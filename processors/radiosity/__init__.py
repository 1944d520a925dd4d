"""Form factors and radiosity: voxel-clustered patches, the multi-bounce form-factor operator
compressed (exact top values, log-quantized BC1 residual), relit by matrix-vector products.

One package per technique: its processors, and the kernels, geometry and formats only it
uses. It imports core/, kernels/, geometry/ and formats/, never another technique."""
