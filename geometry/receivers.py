"""Whether a scene has prims to receive baked values: the applicability test of per-receiver processors."""

from __future__ import annotations

from ..core.scene import Scene
from .mesh import receiver_prims

NO_RECEIVERS = "no writable meshes (all instanced, bake:skip or empty)"
"""Why a processor that writes to receiver meshes does not apply."""


def missing_receivers(scene: Scene) -> str:
    """NO_RECEIVERS when the scene has no receiver prims (``receiver_prims``), else ''.

    Meant for ``Processor.applies``: ``reason = missing_receivers(scene); return not reason, reason``.
    """
    return NO_RECEIVERS if len(receiver_prims(scene)) == 0 else ""
