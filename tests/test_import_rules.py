"""USD stays at the boundary: processors/ never imports pxr nor stages/; only
schemas/ and stages/ import pxr (house style 3, DESIGN 'Layout').

Imports are read with ast (relative imports resolved to absolute names), so a
rule broken in a function body or behind a branch is caught too; a subprocess
then checks the transitive import graph at run time.
"""

import ast
import subprocess
import sys
from pathlib import Path


ROOT = Path(__file__).resolve().parent.parent
PACKAGE = "usdbake"
PXR_ALLOWED = ("schemas", "stages")
"""Top-level folders that may import pxr."""


def package_files() -> list[Path]:
    """The package's modules: the root __init__.py and every .py under its subpackages."""
    files = [ROOT / "__init__.py"]
    for folder in ("processors", "stages", "schemas"):
        files += sorted((ROOT / folder).rglob("*.py"))
    return files


def module_parts(path: Path) -> list[str]:
    rel = path.relative_to(ROOT).with_suffix("")
    parts = [PACKAGE, *rel.parts]
    return parts[:-1] if parts[-1] == "__init__" else parts


def imported_names(path: Path, module: str | None = None) -> list[tuple[int, str]]:
    """(line, absolute module name) for every import statement in the file.

    ``module`` is the file's dotted name (default: from its place under ROOT).
    """
    tree = ast.parse(path.read_text(), filename=str(path))
    parts = module.split(".") if module else module_parts(path)
    package = parts if path.name == "__init__.py" else parts[:-1]
    found = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            found += [(node.lineno, alias.name) for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                anchor = package[: len(package) - (node.level - 1)]
                base = ".".join(anchor + ([node.module] if node.module else []))
            else:
                base = node.module or ""
            found.append((node.lineno, base))
            # `from . import stages` names a module through the alias.
            found += [(node.lineno, f"{base}.{alias.name}") for alias in node.names]
    return found


def violations(files, forbidden) -> list[str]:
    bad = []
    for path in files:
        for line, name in imported_names(path):
            if any(name == f or name.startswith(f + ".") for f in forbidden):
                bad.append(f"{path.relative_to(ROOT)}:{line} imports {name}")
    return bad


def test_package_files_are_found():
    names = {str(p.relative_to(ROOT)) for p in package_files()}
    assert {"processors/base.py", "processors/scene.py", "stages/pipeline.py", "schemas/__init__.py"} <= names


def test_resolver_sees_relative_and_aliased_imports(tmp_path):
    probe = tmp_path / "probe.py"
    probe.write_text("from ...stages import cli\nfrom ... import stages\nimport pxr.Usd\nfrom pxr import Sdf\n")
    names = {name for _, name in imported_names(probe, "usdbake.processors.kernels.probe")}
    assert {"usdbake.stages", "usdbake.stages.cli", "pxr.Usd", "pxr", "pxr.Sdf"} <= names
    assert violations_in(probe, "usdbake.processors.kernels.probe", ["pxr"]) == 2
    assert violations_in(probe, "usdbake.processors.kernels.probe", ["usdbake.stages"]) == 2


def violations_in(path, module, forbidden) -> int:
    return len({line for line, name in imported_names(path, module)
                if any(name == f or name.startswith(f + ".") for f in forbidden)})


def test_processors_never_import_pxr():
    files = sorted((ROOT / "processors").rglob("*.py"))
    assert violations(files, ["pxr"]) == []


def test_processors_never_import_stages_or_schemas():
    files = sorted((ROOT / "processors").rglob("*.py"))
    assert violations(files, [f"{PACKAGE}.stages", f"{PACKAGE}.schemas"]) == []


def test_builtin_processor_list_names_processor_modules_only():
    from usdbake import processors

    for name in processors.BUILTIN_MODULES:
        assert (ROOT / "processors" / f"{name}.py").exists(), name


def test_only_schemas_and_stages_import_pxr():
    outside = [p for p in package_files() if p.relative_to(ROOT).parts[0] not in PXR_ALLOWED]
    assert outside, "expected modules outside schemas/ and stages/"
    assert violations(outside, ["pxr"]) == []


def test_importing_processors_loads_no_pxr_of_its_own():
    """The parent package registers the schema plugin (so pxr is loaded by ``import usdbake``);
    importing the processors on top of it must add no pxr module and nothing from stages/."""
    code = (
        "import sys\n"
        "def usd():\n"
        "    return {m for m in sys.modules if m == 'pxr' or m.startswith(('pxr.', 'usdbake.stages'))}\n"
        "import usdbake\n"
        "before = usd()\n"
        "import usdbake.processors\n"
        "assert 'usdbake.processors.ambient_occlusion' in sys.modules\n"
        "print(sorted(usd() - before))\n"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip().splitlines()[-1] == "[]"
