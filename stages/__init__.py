"""The USD boundary: stage -> Scene, output records -> bake layer, the runner, the CLI and the hook.

Only this package and usdbake.schemas import pxr. The schema plugin is
registered by ``import usdbake`` (the package root), before any of this runs.
"""
