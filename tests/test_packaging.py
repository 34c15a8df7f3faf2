"""Packaging: every package folder of the repository is in ``pyproject.toml``'s hand-kept list."""

from __future__ import annotations

import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
SETUPTOOLS = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]


def _folder(package: str) -> Path:
    """The folder of ``package`` by ``package-dir`` (the longest mapped prefix)."""
    mapped = max((name for name in SETUPTOOLS["package-dir"] if package == name or package.startswith(name + ".")),
                 key=len)
    rest = package[len(mapped):].lstrip(".")
    return ROOT / SETUPTOOLS["package-dir"][mapped] / Path(*rest.split(".") if rest else ())


def test_every_package_folder_is_packaged():
    found = set()
    for name, folder in SETUPTOOLS["package-dir"].items():
        for init in (ROOT / folder).rglob("__init__.py"):
            rel = init.parent.relative_to(ROOT / folder)
            found.add(".".join([name, *rel.parts]))
    assert found, "no package folder found: is package-dir right?"
    # Data-only packages (no __init__.py): folders of package data, listed so that setuptools does not warn
    # "Package ... is absent from the `packages` configuration" on every install.
    data_only = {p for p in SETUPTOOLS["packages"] if not (_folder(p) / "__init__.py").exists()}
    assert found == set(SETUPTOOLS["packages"]) - data_only, (
        f"not packaged: {sorted(found - set(SETUPTOOLS['packages']))}; "
        f"listed without a folder: {sorted(set(SETUPTOOLS['packages']) - data_only - found)}")
    for p in data_only:
        assert _folder(p).is_dir() and p in SETUPTOOLS["package-data"], f"{p}: a data package needs its folder " \
            "and its package-data entry"


def test_every_folder_of_package_data_is_a_listed_package():
    """A package's data in a subfolder that is not itself listed makes setuptools warn on every install."""
    for package in SETUPTOOLS["packages"]:
        folder = _folder(package)
        for sub in folder.iterdir():
            if sub.is_dir() and sub.name != "__pycache__" and any(f.is_file() for f in sub.rglob("*")):
                assert f"{package}.{sub.name}" in SETUPTOOLS["packages"], (
                    f"{sub.relative_to(ROOT)} holds files but {package}.{sub.name} is not in pyproject.toml's "
                    "packages")
