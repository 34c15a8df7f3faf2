"""Packaging: every package folder of the repository is in ``pyproject.toml``'s hand-kept list."""

from __future__ import annotations

import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def test_every_package_folder_is_packaged():
    setuptools = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]
    found = set()
    for name, folder in setuptools["package-dir"].items():
        for init in (ROOT / folder).rglob("__init__.py"):
            rel = init.parent.relative_to(ROOT / folder)
            found.add(".".join([name, *rel.parts]))
    assert found, "no package folder found: is package-dir right?"
    assert found == set(setuptools["packages"]), (
        f"not packaged: {sorted(found - set(setuptools['packages']))}; "
        f"listed without a folder: {sorted(set(setuptools['packages']) - found)}")
