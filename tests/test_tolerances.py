"""tests/tolerances.py holds every tolerance of the suite: each constant states its reason in a
docstring and is imported by at least one test, and the tolerances a test module still builds
itself (from its own sample counts) start from one of them."""

import ast
import re
from pathlib import Path

import pytest

TESTS = Path(__file__).parent
MODULE = TESTS / "tolerances.py"


def module_constants() -> list[tuple[str, ast.stmt | None]]:
    """(name, the statement right after its assignment) for each module-level constant."""
    body = ast.parse(MODULE.read_text()).body
    constants = []
    for index, node in enumerate(body):
        if isinstance(node, ast.Assign):
            targets = node.targets
        elif isinstance(node, ast.AnnAssign):
            targets = [node.target]
        else:
            continue
        following = body[index + 1] if index + 1 < len(body) else None
        constants += [(target.id, following) for target in targets if isinstance(target, ast.Name)]
    return constants


def other_test_files() -> list[Path]:
    return [path for path in sorted(TESTS.rglob("*.py")) if path not in (MODULE, Path(__file__))]


def imported_from_tolerances(tree: ast.Module) -> set[str]:
    return {alias.name for node in ast.walk(tree) if isinstance(node, ast.ImportFrom) and node.module == "tolerances"
            for alias in node.names}


def test_the_module_has_constants():
    assert len(module_constants()) > 20


@pytest.mark.parametrize("name, following", module_constants(), ids=[name for name, _ in module_constants()])
def test_every_tolerance_states_its_reason(name, following):
    assert isinstance(following, ast.Expr) and isinstance(following.value, ast.Constant) \
        and isinstance(following.value.value, str), f"{name} has no docstring (its reason) right after it"
    assert len(following.value.value.split()) >= 5, f"{name}: the reason is too short to say what error it bounds"


def test_every_tolerance_is_used_by_a_test():
    used = set().union(*(imported_from_tolerances(ast.parse(path.read_text())) for path in other_test_files()))
    unused = sorted({name for name, _ in module_constants()} - used)
    assert not unused, f"tolerances.py constants no test imports: {unused}"


def test_tolerances_built_in_test_modules_start_from_the_shared_ones():
    """A module-level *TOL* / *TOLERANCE* name outside tolerances.py is derived from a test's own sample
    count, so its value must use a constant from tolerances.py (no new bare literal)."""
    for path in other_test_files():
        tree = ast.parse(path.read_text())
        shared = imported_from_tolerances(tree)
        for node in tree.body:
            if not isinstance(node, ast.Assign):
                continue
            for target in node.targets:
                if isinstance(target, ast.Name) and re.search(r"TOL", target.id):
                    names = {n.id for n in ast.walk(node.value) if isinstance(n, ast.Name)}
                    assert names & shared, f"{path.relative_to(TESTS)}: {target.id} uses no constant of tolerances.py"
