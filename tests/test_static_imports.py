"""Static tools see the code: a type checker run from the checkout resolves every `zensim.*` module.

The folders map onto `zensim.*` (pyproject's package-dir); the default editable install does that with an
import hook no static tool follows, so IDEs and checkers saw nothing. scripts/test makes a strict editable
install instead (docs/architecture.md): this test is what an IDE does, asked of mypy.
"""

from __future__ import annotations

import subprocess
import sys
import tomllib
from pathlib import Path

from support import REPO


def product_modules() -> list[str]:
    """Every module of the product by its import name, read from the folders pyproject maps."""
    mapping = tomllib.loads((REPO / "pyproject.toml").read_text())["tool"]["setuptools"]["package-dir"]
    modules = set()
    for package, folder in mapping.items():
        for path in (REPO / folder).rglob("*.py"):
            parts = path.relative_to(REPO / folder).with_suffix("").parts
            if parts[-1] == "__init__":
                parts = parts[:-1]
            modules.add(".".join((package, *parts)))
    return sorted(modules)


def test_mypy_run_from_the_checkout_resolves_every_zensim_module(tmp_path: Path) -> None:
    modules = product_modules()
    assert {"zensim.sim.physics", "zensim.robots.unitree_g1.derive", "zensim.robots.unitree_g1.policy.convert",
            "zensim.schemas.generate", "zensim.common.wire"} <= set(modules)
    client = tmp_path / "ide_client.py"
    client.write_text("".join(f"import {module}\n" for module in modules))
    # As an editor does: the checkout is the working directory, the project's venv the interpreter.
    result = subprocess.run([sys.executable, "-m", "mypy", "--follow-imports=silent", "--cache-dir", str(tmp_path / "cache"),
                             str(client)], cwd=REPO, capture_output=True, text=True, timeout=600)
    assert result.returncode == 0, result.stdout + result.stderr
    assert "Success" in result.stdout
