"""The techniques, one package each: its processors and the kernels, geometry and formats only it uses.

==================== ==========================================================
package              processors
==================== ==========================================================
``occlusion``        ambient_occlusion
``daylight``         sky_visibility, daylight, annual_daylight
``instancing``       displacement_fields, instance_ao
``radiosity``        form_factors, radiosity
``irradiance_grid``  irradiance_grid, progressive_mesh
``light_probes``     light_probes
==================== ==========================================================

A processor module reads top to bottom: the math (docstring with the paper's
equations), the Warp kernels, the compute functions, and the Processor class.
A technique package imports core/ and what two or more techniques share
(kernels/, geometry/, formats/), never another technique. The registry lists
the processors (usdbake.core.registry.BUILTIN); importing this package imports
none of them.
"""
