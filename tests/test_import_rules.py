"""The house plan, as imports: each folder of the package imports only the folders below it, and no module
imports itself back through others.

    usdbake (the package root), cli, benchmarks   the top: the root's bake() and bake_many() call stages and
                                                  farm, its irradiance_at() stages and the techniques' own
                                                  lookups; nothing imports the root, cli or benchmarks
                                                  (benchmarks import anything, ``usdbake bench`` runs them)
    farm, preview          -> stages, kernels, core (preview also geometry and formats)
    stages (+ schemas)     -> kernels, formats, core     USD lives here and in schemas/ only
    processors             -> kernels, geometry, formats, core; never each other (core's registry reaches
                              them by name, never by an import statement)
    kernels, geometry, formats -> core
    core                   -> nothing of ours

Imports are read with ast (relative imports resolved to absolute names), so a rule broken in a function body
or behind a branch is caught too, and no import is excepted; a subprocess then checks that importing the
processors loads no pxr.
"""

from repo_paths import REPO
import ast
import subprocess
import sys
from graphlib import CycleError, TopologicalSorter
from pathlib import Path

import pytest

ROOT = REPO
PACKAGE = "usdbake"
FOLDERS = ("core", "kernels", "geometry", "formats", "processors", "stages", "schemas", "preview", "farm", "cli")

MAY_IMPORT = {
    "core": (),
    "kernels": ("core",),
    "geometry": ("core",),
    "formats": ("core",),
    "processors": ("core", "kernels", "geometry", "formats"),
    "schemas": (),
    "stages": ("core", "kernels", "formats", "schemas"),
    "preview": ("core", "kernels", "geometry", "formats", "stages"),
    "farm": ("core", "kernels", "stages"),
    "cli": ("core", "kernels", "stages", "preview", "farm"),
    PACKAGE: ("core", "kernels", "schemas", "stages", "farm", "processors"),
    "benchmarks": (*FOLDERS, PACKAGE),
}
"""Layer (a folder, or ``usdbake``: the package root's ``__init__.py``) -> the other layers it may import."""

PXR_ALLOWED = ("schemas", "stages")
"""Folders that may import pxr."""


def package_files(folders=FOLDERS) -> list[Path]:
    files = [ROOT / "__init__.py"] if folders == FOLDERS else []
    for folder in folders:
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


def all_modules() -> dict[str, Path]:
    """Dotted name -> file of every module of the package, the root and benchmarks/ included."""
    files = [ROOT / "__init__.py"]
    for folder in (*FOLDERS, "benchmarks"):
        files += sorted((ROOT / folder).rglob("*.py"))
    return {".".join(module_parts(path)): path for path in files}


def imported_modules(path: Path, modules, module: str | None = None) -> dict[str, int]:
    """{module of the package: first line} for each import statement in the file, ``module`` (default: from
    its place under ROOT) itself left out. ``from P import name`` imports the module P.name when there is
    one, else P; a name of ours that is not a module is its longest dotted prefix that is."""
    def resolve(name: str) -> str | None:
        parts = name.split(".")
        while parts and ".".join(parts) not in modules:
            parts.pop()
        return ".".join(parts) or None

    tree = ast.parse(path.read_text(), filename=str(path))
    parts = module.split(".") if module else module_parts(path)
    package = parts if path.name == "__init__.py" else parts[:-1]
    found: dict[str, int] = {}
    for node in ast.walk(tree):
        targets = []
        if isinstance(node, ast.Import):
            targets = [resolve(alias.name) for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = ".".join(package[: len(package) - (node.level - 1)] + ([node.module] if node.module else [])) \
                if node.level else node.module or ""
            targets = [f"{base}.{alias.name}" if f"{base}.{alias.name}" in modules else resolve(base)
                       for alias in node.names]
        for target in targets:
            if target and target.startswith(PACKAGE) and target != ".".join(parts):
                found[target] = min(found.get(target, node.lineno), node.lineno)
    return found


def import_graph() -> dict[str, dict[str, int]]:
    """Module -> {module it imports: line}, over the whole package."""
    modules = all_modules()
    return {name: imported_modules(path, modules) for name, path in modules.items()}


def layer(module: str) -> str:
    """The folder a module lives in, or PACKAGE for the package root."""
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else PACKAGE


def violations_in(path, module, forbidden) -> int:
    return len({line for line, name in imported_names(path, module)
                if any(name == f or name.startswith(f + ".") for f in forbidden)})


def upward(graph: dict[str, dict[str, int]]) -> list[str]:
    """'module:line imports target' for each import of a layer that MAY_IMPORT does not put below."""
    return [f"{module}:{line} imports {target}" for module, imports in graph.items()
            for target, line in imports.items()
            if layer(target) != layer(module) and layer(target) not in MAY_IMPORT[layer(module)]]


def circle(graph: dict[str, dict[str, int]]) -> str:
    """One circle of imports ('a -> b -> a'), or '' when there is none."""
    try:
        list(TopologicalSorter({module: set(imports) for module, imports in graph.items()}).static_order())
    except CycleError as error:
        return " -> ".join(error.args[1])
    return ""


def test_resolver_sees_relative_and_aliased_imports(tmp_path):
    probe = tmp_path / "probe.py"
    probe.write_text("from ..stages import extract\nfrom .. import stages\nimport pxr.Usd\nfrom pxr import Sdf\n")
    names = {name for _, name in imported_names(probe, "usdbake.kernels.probe")}
    assert {"usdbake.stages", "usdbake.stages.extract", "pxr.Usd", "pxr", "pxr.Sdf"} <= names
    assert violations_in(probe, "usdbake.kernels.probe", ["pxr"]) == 2
    assert violations_in(probe, "usdbake.kernels.probe", ["usdbake.stages"]) == 2


def test_every_folder_has_a_rule():
    folders = {p.name for p in ROOT.iterdir() if (p / "__init__.py").exists()}
    assert folders - {"tests", "samples"} == set(MAY_IMPORT) - {PACKAGE}


def test_the_rules_are_layers():
    """MAY_IMPORT orders the layers: no two of them may import each other, even through a third."""
    try:
        list(TopologicalSorter(MAY_IMPORT).static_order())
    except CycleError as error:
        pytest.fail(f"layers that may import each other: {' -> '.join(error.args[1])}")


def test_nothing_imports_upward():
    """Every import statement of every module (the root and benchmarks/ included) names a module of its own
    layer or of one MAY_IMPORT puts below it; nothing is excepted."""
    assert upward(import_graph()) == []


def test_no_circles():
    """No module imports itself back through others, benchmarks/ included."""
    assert circle(import_graph()) == ""


def test_the_checks_see_upward_imports_and_circles(tmp_path):
    modules = {"usdbake", "usdbake.core", "usdbake.core.a", "usdbake.core.b", "usdbake.kernels", "usdbake.kernels.k"}
    probe = tmp_path / "probe.py"
    probe.write_text("def late():\n    from ..kernels import k\n    from . import b\nfrom .. import __version__\n")
    graph = {"usdbake.core.a": imported_modules(probe, modules, "usdbake.core.a")}
    assert graph["usdbake.core.a"] == {"usdbake.kernels.k": 2, "usdbake.core.b": 3, "usdbake": 4}
    assert sorted(upward(graph)) == ["usdbake.core.a:2 imports usdbake.kernels.k",
                                     "usdbake.core.a:4 imports usdbake"]
    assert circle(graph) == ""
    assert set(circle({**graph, "usdbake.core.b": {"usdbake.core.a": 1}}).split(" -> ")) == {"usdbake.core.a",
                                                                                            "usdbake.core.b"}


TECHNIQUES = sorted(p.name for p in (ROOT / "processors").iterdir() if (p / "__init__.py").exists())
"""The technique packages under processors/."""


def test_processors_are_technique_packages():
    assert TECHNIQUES and [p.name for p in (ROOT / "processors").glob("*.py")] == ["__init__.py"]


@pytest.mark.parametrize("technique", TECHNIQUES)
def test_a_technique_never_imports_another(technique):
    others = [f"{PACKAGE}.processors.{other}" for other in TECHNIQUES if other != technique]
    assert violations(sorted((ROOT / "processors" / technique).rglob("*.py")), others) == []


def test_shared_folders_hold_what_two_or_more_techniques_use():
    """A module of kernels/, geometry/ or formats/ that one technique alone imports belongs in its package
    (a module only kernels/ itself imports, the ray core's, reaches every technique through the tracer)."""
    users: dict[str, set[str]] = {}
    for technique in TECHNIQUES:
        for path in (ROOT / "processors" / technique).rglob("*.py"):
            for _, name in imported_names(path):
                users.setdefault(name, set()).add(technique)
    outside = [p for p in package_files() if p.relative_to(ROOT).parts[0] != "processors"]
    used_elsewhere = {name for path in outside for _, name in imported_names(path)}
    single = []
    for folder in ("kernels", "geometry", "formats"):
        for path in sorted((ROOT / folder).glob("*.py")):
            name = ".".join(module_parts(path))
            if path.stem != "__init__" and len(users.get(name, ())) == 1 and name not in used_elsewhere:
                single.append(f"{name}: only {users[name].pop()}")
    assert single == []


def test_only_schemas_and_stages_import_pxr():
    outside = [p for p in package_files() if p.relative_to(ROOT).parts[0] not in PXR_ALLOWED]
    assert outside, "expected modules outside schemas/ and stages/"
    assert violations(outside, ["pxr"]) == []


def test_importing_the_processors_loads_no_pxr_of_their_own():
    """The parent package registers the schema plugin (so pxr is loaded by ``import usdbake``);
    importing every processor on top of it must add no pxr module and nothing from stages/."""
    code = (
        "import sys\n"
        "def usd():\n"
        "    return {m for m in sys.modules if m == 'pxr' or m.startswith(('pxr.', 'usdbake.stages'))}\n"
        "import usdbake\n"
        "before = usd()\n"
        "from usdbake.core import registry\n"
        "registry.builtin()\n"
        "assert 'usdbake.processors.occlusion.ambient_occlusion' in sys.modules\n"
        "print(sorted(usd() - before))\n"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip().splitlines()[-1] == "[]"
