"""The package stays walkable: no module over 500 lines, no function over 80 (README, Layout).

Counted as an editor counts them: a module's lines, and a function from its ``def`` line to its last
line, docstring included. A module or function that grows past the limit is split along its seams
(the steps it does), not given a higher limit here.
"""

from __future__ import annotations

import ast
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
PACKAGE = [REPO / "coster_sumo", REPO / "converters"]
MAX_MODULE_LINES = 500
MAX_FUNCTION_LINES = 80


def _sources() -> list[Path]:
    return sorted(p for root in PACKAGE for p in root.rglob("*.py"))


def test_no_module_over_500_lines() -> None:
    sizes = {str(p.relative_to(REPO)): len(p.read_text().splitlines()) for p in _sources()}
    long = {name: n for name, n in sizes.items() if n > MAX_MODULE_LINES}
    assert not long, f"modules over {MAX_MODULE_LINES} lines: {long}"


def test_no_function_over_80_lines() -> None:
    long = {}
    for path in _sources():
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                n = (node.end_lineno or node.lineno) - node.lineno + 1
                if n > MAX_FUNCTION_LINES:
                    long[f"{path.relative_to(REPO)}:{node.lineno}:{node.name}"] = n
    assert not long, f"functions over {MAX_FUNCTION_LINES} lines: {long}"



def test_package_root_holds_at_most_five_modules() -> None:
    """The floors are folders (README, Layout): the root keeps the entry points, the API and the errors."""
    root = sorted(p.stem for p in (REPO / "coster_sumo").glob("*.py"))
    assert len(root) <= 5, f"modules at coster_sumo/'s root: {root}"


def test_every_package_is_installed() -> None:
    """pyproject.toml lists the packages one by one: a new folder missing there would not be in the wheel."""
    import tomllib

    listed = set(tomllib.loads((REPO / "pyproject.toml").read_text())["tool"]["setuptools"]["packages"])
    found = {".".join(p.parent.relative_to(REPO).parts) for p in (REPO / "coster_sumo").rglob("__init__.py")}
    assert found <= listed, f"packages not in pyproject.toml: {sorted(found - listed)}"
