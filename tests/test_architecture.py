"""The import rule of docs/architecture.md, enforced: which package may import which.

    schemas   imports nothing of ours (any Python client can use it with msgspec alone)
    common    imports schemas
    robots    imports schemas (it builds models; it never runs a service)
    a service (sim, bridge, viz, ...) imports common, schemas, robots; never another service
    zensim    (the command line: cli, up, router, ...) may import anything

Every import statement in the product's folders is read (top level and inside functions), so a
lazy import cannot slip past the rule.
"""

from __future__ import annotations

import ast
import tomllib
from pathlib import Path

import pytest

from support import REPO

LIBRARIES = {"zensim.schemas", "zensim.common", "zensim.robots"}
"""Packages that are not services."""
ALLOWED = {
    "zensim.schemas": {"zensim.schemas"},
    "zensim.common": {"zensim.common", "zensim.schemas"},
    "zensim.robots": {"zensim.robots", "zensim.schemas"},
}


def package_dirs() -> dict[str, Path]:
    """Import root -> folder, from pyproject's package-dir (the one source of the mapping)."""
    mapping = tomllib.loads((REPO / "pyproject.toml").read_text())["tool"]["setuptools"]["package-dir"]
    return {package: REPO / folder for package, folder in mapping.items()}


def owner(module: str, packages: dict[str, Path]) -> str | None:
    """The top-level zensim package a module name belongs to (`zensim.sim.physics` -> `zensim.sim`)."""
    parts = module.split(".")
    for n in (2, 1):
        candidate = ".".join(parts[:n])
        if candidate in packages:
            return candidate
    return None


def imports_of(path: Path, package: str) -> set[str]:
    """Every zensim module a file imports, relative imports resolved."""
    found = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            found |= {alias.name for alias in node.names}
        elif isinstance(node, ast.ImportFrom):
            if node.level:  # relative: within the file's own package
                found.add(package)
            elif node.module:
                found.add(node.module)
    return {name for name in found if name == "zensim" or name.startswith("zensim.")}


def package_files() -> list[tuple[str, Path]]:
    packages = package_dirs()
    files = []
    for package, folder in packages.items():
        if package == "zensim":
            continue
        for path in sorted(folder.rglob("*.py")):
            sub = path.relative_to(folder).parts[:-1]
            if any(".".join((package, *sub[: i + 1])) in packages for i in range(len(sub))):
                continue  # belongs to a nested package listed on its own
            files.append((package, path))
    return files


@pytest.mark.parametrize("package, path", package_files(), ids=lambda v: str(v).removeprefix(str(REPO) + "/"))
def test_imports_follow_the_rule(package: str, path: Path) -> None:
    packages = package_dirs()
    services = {p for p in packages if p not in LIBRARIES and p != "zensim" and owner(p, packages) == p}
    for module in imports_of(path, package):
        target = owner(module, packages)
        assert target is not None and target != "zensim", f"{path.name} imports {module}: the command line package"
        if package in ALLOWED:
            assert target in ALLOWED[package], f"{package} ({path.name}) may not import {module}"
        elif package in services:
            assert target == package or target in LIBRARIES, f"service {package} ({path.name}) imports {module}"


def test_the_rule_sees_every_service() -> None:
    packages = package_dirs()
    services = {p for p in packages if p not in LIBRARIES and p != "zensim" and owner(p, packages) == p}
    assert {"zensim.sim", "zensim.bridge", "zensim.viz"} <= services
    assert len(package_files()) > 20


URDF_READERS = {"yourdfpy", "lxml", "xml.etree", "xml.etree.ElementTree", "xml.dom", "xml.sax", "defusedxml"}
"""Modules that can parse a URDF."""


def third_party_imports(path: Path) -> set[str]:
    found = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            found |= {alias.name for alias in node.names}
        elif isinstance(node, ast.ImportFrom) and not node.level and node.module:
            found.add(node.module)
    return found


def test_the_urdf_is_read_in_one_module() -> None:
    """robots/description.py is the URDF reader; derive.py (a developer tool) only copies XML elements."""
    readers = {path.relative_to(REPO).as_posix() for folder in ("services", "schemas", "robots", "zensim")
               for path in (REPO / folder).rglob("*.py") if third_party_imports(path) & URDF_READERS}
    assert readers == {"robots/description.py", "robots/unitree_g1/derive.py"}
