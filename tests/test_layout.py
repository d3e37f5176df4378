"""The package's layout stays easy to read: short functions, short modules, no private name
used outside its module, one installed top-level package (issue 14).

Run ``python tests/test_layout.py`` for the report these tests assert on.
"""

from __future__ import annotations

import ast
import sys
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "rangeslam"
MAX_FUNCTION_LINES = 80
MAX_MODULE_LINES = 800


def _modules() -> list[Path]:
    return sorted(PACKAGE.rglob("*.py"))


def _module_name(path: Path) -> str:
    return ".".join(path.relative_to(ROOT).with_suffix("").parts).removesuffix(".__init__")


def long_functions() -> list[tuple[int, str]]:
    """(lines, "module:function") of every function or method longer than MAX_FUNCTION_LINES."""
    out = []
    for path in _modules():
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef):
                n = node.end_lineno - node.lineno + 1
                if n > MAX_FUNCTION_LINES:
                    out.append((n, f"{_module_name(path)}:{node.name}"))
    return sorted(out, reverse=True)


def long_modules() -> list[tuple[int, str]]:
    """(lines, module) of every module longer than MAX_MODULE_LINES."""
    out = []
    for path in _modules():
        n = len(path.read_text().splitlines())
        if n > MAX_MODULE_LINES:
            out.append((n, _module_name(path)))
    return sorted(out, reverse=True)


def _is_private(name: str) -> bool:
    return name.startswith("_") and not name.startswith("__")


def private_crossings() -> list[str]:
    """Private names used outside the module that defines them: ``from m import _x``, and
    ``m._x`` where ``m`` is a module of the package imported by name."""
    out = []
    for path in _modules():
        here = _module_name(path)
        tree = ast.parse(path.read_text())
        package_modules = set()
        for node in ast.walk(tree):
            if isinstance(node, ast.ImportFrom):
                source = node.module or ""
                if node.level or source.startswith("rangeslam"):
                    for alias in node.names:
                        if _is_private(alias.name):
                            out.append(
                                f"{here}: from {'.' * node.level}{source} import {alias.name}"
                            )
                        package_modules.add(alias.asname or alias.name)
            elif isinstance(node, ast.Import):
                for alias in node.names:
                    if alias.name.startswith("rangeslam"):
                        package_modules.add(alias.asname or alias.name.split(".")[0])
        for node in ast.walk(tree):
            if (
                isinstance(node, ast.Attribute)
                and _is_private(node.attr)
                and isinstance(node.value, ast.Name)
                and node.value.id in package_modules
            ):
                out.append(f"{here}: {node.value.id}.{node.attr}")
    return out


def installed_packages() -> list[str]:
    config = tomllib.loads((ROOT / "pyproject.toml").read_text())
    return config["tool"]["hatch"]["build"]["targets"]["wheel"]["packages"]


def test_no_function_longer_than_the_limit():
    """Every function and method of the package fits on a screen (at most 80 lines)."""
    assert long_functions() == []


def test_no_module_longer_than_the_limit():
    """Every module of the package has at most 800 lines."""
    assert long_modules() == []


def test_no_private_name_crosses_a_module_boundary():
    """What two modules share is a public name; private names stay in their module."""
    assert private_crossings() == []


def test_one_installed_top_level_package():
    """pyproject.toml installs the one package ``rangeslam`` (baselines live inside it)."""
    assert installed_packages() == ["rangeslam"]


if __name__ == "__main__":
    for n, where in long_functions():
        print(f"function {n:4d} lines  {where}")
    for n, where in long_modules():
        print(f"module   {n:4d} lines  {where}")
    for line in private_crossings():
        print(f"private  {line}")
    print(f"installed packages: {installed_packages()}")
    sys.exit(0)
