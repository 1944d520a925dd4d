"""The house plan, as imports: each folder of the package imports only the folders below it.

    cli, preview           -> stages, processors (via the registry), core, kernels, geometry
                              (preview also formats: the stream client decodes the served streams)
    stages (+ schemas)     -> core                 USD lives here and in schemas/ only
    processors             -> core, kernels, geometry, formats; never each other
    kernels, geometry, formats -> core
    core                   -> nothing of ours (one lazy import: the runner builds the shared BVH)

Imports are read with ast (relative imports resolved to absolute names), so a
rule broken in a function body or behind a branch is caught too; a subprocess
then checks the transitive import graph at run time.
"""

from repo_paths import REPO
import ast
import subprocess
import sys
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
    "stages": ("core", "schemas"),
    "preview": ("core", "kernels", "geometry", "stages", "formats"),
    "farm": ("core", "stages"),
    "cli": ("core", "stages", "preview", "farm", "benchmarks"),
}
"""Folder -> the other folders of the package it may import."""

LAZY_EXCEPTIONS = {("core/pipeline.py", "usdbake.kernels.tracer"), ("stages/sky_dome.py", "usdbake.kernels.sky"),
                   ("stages/sky_dome.py", "usdbake.kernels.solar"), ("stages/sky_dome.py", "usdbake.formats.weather"),
                   ("farm/chunks.py", "usdbake.kernels.tracer")}
"""The runner's factory of the shared BVH imports the tracer when a processor first asks for it; ``usdbake
sky`` evaluates the sky models and the sun position (numpy) when it writes a sky as UsdLux lights, and
reads a weather file's hour when asked for one; a Dask worker builds its BVH of a scene on its first chunk."""

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
                if not any(str(path.relative_to(ROOT)) == file and name.startswith(module)
                           for file, module in LAZY_EXCEPTIONS):
                    bad.append(f"{path.relative_to(ROOT)}:{line} imports {name}")
    return bad


def violations_in(path, module, forbidden) -> int:
    return len({line for line, name in imported_names(path, module)
                if any(name == f or name.startswith(f + ".") for f in forbidden)})


def test_resolver_sees_relative_and_aliased_imports(tmp_path):
    probe = tmp_path / "probe.py"
    probe.write_text("from ..stages import extract\nfrom .. import stages\nimport pxr.Usd\nfrom pxr import Sdf\n")
    names = {name for _, name in imported_names(probe, "usdbake.kernels.probe")}
    assert {"usdbake.stages", "usdbake.stages.extract", "pxr.Usd", "pxr", "pxr.Sdf"} <= names
    assert violations_in(probe, "usdbake.kernels.probe", ["pxr"]) == 2
    assert violations_in(probe, "usdbake.kernels.probe", ["usdbake.stages"]) == 2


def test_every_folder_has_a_rule():
    folders = {p.name for p in ROOT.iterdir() if (p / "__init__.py").exists()}
    assert folders - {"tests", "samples", "benchmarks"} == set(MAY_IMPORT)


def test_each_folder_imports_only_the_folders_below_it():
    for folder, allowed in MAY_IMPORT.items():
        forbidden = [f"{PACKAGE}.{other}" for other in (*FOLDERS, "benchmarks")
                     if other != folder and other not in allowed]
        assert violations(package_files((folder,)), forbidden) == [], folder


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
