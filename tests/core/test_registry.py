"""The registry is complete and the built-ins follow one convention.

Every processor module of a technique package is named in core.registry.BUILTIN (a technique
nobody registered is dead code that no test bakes); every entry loads; a
processor ``name`` is its module's name and its class name is the CamelCase of
it; every parameter has one line of doc, since ``usdbake list`` and the docs
tables print it.
"""

from __future__ import annotations

import re

from repo_paths import REPO

import pytest

from usdbake.core import registry
from usdbake.core.processor import Processor

PROCESSORS_DIR = REPO / "processors"

ACRONYMS = {"ao": "AO"}
"""Name parts written in capitals in class names: instance_ao -> InstanceAO."""


def class_name(name: str) -> str:
    """The class name a processor ``name`` must have: ambient_occlusion -> AmbientOcclusion."""
    return "".join(ACRONYMS.get(part, part.capitalize()) for part in name.split("_"))


def test_class_name_convention():
    assert class_name("ambient_occlusion") == "AmbientOcclusion"
    assert class_name("instance_ao") == "InstanceAO"
    assert class_name("form_factors") == "FormFactors"


def test_every_processor_module_is_in_builtin():
    """Every module of a technique package that defines a Processor is listed, and only those."""
    modules = {f"{path.parent.name}.{path.stem}" for path in PROCESSORS_DIR.glob("*/*.py")
               if re.search(r"^class \w+\(Processor\):", path.read_text(), re.MULTILINE)}
    listed = {".".join(spec.partition(":")[0].split(".")[-2:]) for spec in registry.BUILTIN}
    assert modules - listed == set(), "add these modules to usdbake.core.registry.BUILTIN"
    assert listed - modules == set(), "BUILTIN names modules that processors/ does not hold"


def test_builtin_entries_are_unique_and_in_the_processors_package():
    assert len(set(registry.BUILTIN)) == len(registry.BUILTIN)
    for spec in registry.BUILTIN:
        module, _, attribute = spec.partition(":")
        assert module.startswith("usdbake.processors.") and attribute, spec


@pytest.mark.parametrize("spec", registry.BUILTIN)
def test_builtin_entry_loads_and_follows_the_convention(spec):
    cls = registry.load(spec)
    module, _, attribute = spec.partition(":")
    assert issubclass(cls, Processor) and cls.__module__ == module
    assert cls.name == module.rpartition(".")[2], "a processor's name is its module's name"
    assert attribute == class_name(cls.name), f"class {attribute} should be {class_name(cls.name)}"
    assert cls.summary.strip(), "usdbake list prints the summary"


@pytest.mark.parametrize("spec", registry.BUILTIN)
def test_every_param_has_a_doc(spec):
    cls = registry.load(spec)
    rows = cls.Params.describe()
    undocumented = [row["name"] for row in rows if not str(row["doc"]).strip()]
    assert undocumented == [], f"{cls.name}: params without a doc line"
    cls.Params()  # the defaults pass their own bounds


def test_builtin_names_are_unique():
    assert len(registry.builtin()) == len(registry.BUILTIN)
