"""The USD boundary: stage -> Scene, output records -> bake layer, the runner, the CLI and the hook.

Importing this package registers the usdbake schema plugin first, so our
prim types are known before any stage is opened in this process.
"""

from ..schemas import register as _register_schemas

_register_schemas()
