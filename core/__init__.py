"""The library's core: no pxr, no Warp kernels.

The Scene (struct of arrays + fingerprints), the processor contract (Params,
products, output records, Result, Context, Processor), the registry, the DAG
runner and its cache, and the errors that are the user's to fix. A technique
imports what it needs from here: ``from ..core import Processor, Params, param, ...``.
"""

from . import registry
from .errors import OutputError, StageError, UsageError
from .params import ParamError, Params, TextureTargetParams, param
from .processor import Context, Processor, Result
from .records import Attribute, Block, File, Output, Prim, Primvar, RefinedMesh, Relationship, Texture
from .scene import Scene

__all__ = ["Attribute", "Block", "Context", "File", "Output", "OutputError", "ParamError", "Params", "Prim", "Primvar", "Processor",
           "RefinedMesh", "Relationship", "Result", "Scene", "StageError", "Texture", "TextureTargetParams", "UsageError", "param", "registry"]
