"""Pure-compute processors (no pxr): the Scene, the Tracer, and one module per technique."""

from importlib import import_module

# Built-in processors register themselves when their module is imported.
BUILTIN_MODULES = ("ambient_occlusion", "displacement_fields", "instance_ao", "form_factors", "radiosity", "sky_visibility", "daylight", "light_probes", "irradiance_grid", "progressive_mesh",)

for _module in BUILTIN_MODULES:
    import_module(f"{__name__}.{_module}")
