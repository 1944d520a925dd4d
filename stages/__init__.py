"""The USD boundary: stage -> Scene (extract, triangulate, materials), output records -> bake layer,
the Python hook, inspect, and the baked data the previewer reads back.

Only this package and usdbake.schemas import pxr. The schema plugin is
registered by ``import usdbake`` (the package root), before any of this runs.
"""
