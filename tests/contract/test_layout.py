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



MAX_PARAMETERS = 8
# the functions allowed more, each argued in issue 58's note: SUMO's command line, Gymnasium's make()
# keywords, two training entry points, and the rollout's cluster-and-check step (its checks are one
# private object already; the loose keywords are what tests and the benchmark vary)
LONG_PARAMETER_LISTS = {"sim/session.py:SumoSession.__init__", "gym/env.py:ScenarioEnv.__init__",
                        "rollout/train.py:train_rollout", "prior/train.py:train_prior",
                        "rollout/sample.py:select_representatives"}


def _parameters(node: ast.FunctionDef | ast.AsyncFunctionDef) -> int:
    """Parameters as a caller sees them: ``self``/``cls`` out, keyword-only and ``*args``/``**kwargs`` in."""
    a = node.args
    names = [p.arg for p in (*a.posonlyargs, *a.args, *a.kwonlyargs)]
    return len(names) - (names[:1] in (["self"], ["cls"])) + (a.vararg is not None) + (a.kwarg is not None)


def test_no_function_over_8_parameters() -> None:
    """Long parameter lists become the settings objects they repeat (issue 58), but for the argued few."""
    long = {}
    for path in sorted((REPO / "coster_sumo").rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text())):
            children = node.body if isinstance(node, (ast.Module, ast.ClassDef)) else []
            for f in children:
                if isinstance(f, (ast.FunctionDef, ast.AsyncFunctionDef)) and _parameters(f) > MAX_PARAMETERS:
                    name = f"{node.name}.{f.name}" if isinstance(node, ast.ClassDef) else f.name
                    long[f"{path.relative_to(REPO / 'coster_sumo')}:{name}"] = _parameters(f)
    unargued = sorted(set(long) - LONG_PARAMETER_LISTS)
    assert not unargued, f"over {MAX_PARAMETERS} parameters: {unargued}"
    stale = sorted(LONG_PARAMETER_LISTS - set(long))
    assert not stale, f"no longer over {MAX_PARAMETERS} parameters, drop them from LONG_PARAMETER_LISTS: {stale}"
    assert len(LONG_PARAMETER_LISTS) <= 5, "issue 58: at most 5 functions with more than 8 parameters"


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
