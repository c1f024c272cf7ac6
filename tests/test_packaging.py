"""Packaging: every package and data folder of the source tree is in pyproject.toml's setuptools
configuration (a folder left out is missing from wheels, and setuptools warns about it on install)."""
from __future__ import annotations

import tomllib
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


def test_every_package_and_data_folder_is_configured():
    tool = tomllib.loads((REPO / "pyproject.toml").read_text())["tool"]["setuptools"]
    listed = set(tool["packages"])
    for package, folder in tool["package-dir"].items():
        root = REPO / folder
        for d in [root, *(p for p in root.rglob("*") if p.is_dir())]:
            if "__pycache__" in d.parts or not any(f.is_file() and f.suffix != ".pyc" for f in d.iterdir()):
                continue
            name = ".".join([package, *d.relative_to(root).parts])
            if any(n == name or n.startswith(name + ".") for n in tool["package-dir"] if n != package):
                continue  # mapped to another folder
            assert name in listed, f"{d.relative_to(REPO)} holds files but {name} is not in [tool.setuptools] packages"
    for package, patterns in tool.get("package-data", {}).items():
        assert package in listed, f"package-data for unlisted package {package}"
        folder = REPO / tool["package-dir"].get(package, package.replace(".", "/"))
        assert all(any(folder.glob(p)) for p in patterns), f"{package}: {patterns} match no file"
