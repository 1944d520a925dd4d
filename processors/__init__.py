"""The techniques, one module each and nothing else.

Each module reads top to bottom: the math (docstring with the paper's
equations), the Warp kernels, the compute functions, and the Processor class.
The registry lists them (usdbake.core.registry.BUILTIN); importing this
package imports none of them.
"""
