"""docs/install.rst says what pyproject.toml and constraints/ say: the core ranges,
every extra, and pins that are those of the constraint files."""

from __future__ import annotations

import re
from pathlib import Path

import tomllib

ROOT = Path(__file__).resolve().parents[1]
INSTALL = (ROOT / "docs" / "install.rst").read_text()
PROJECT = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]


def pins(path: Path) -> dict[str, str]:
    """``name -> version`` of a constraint file's ``name==version`` lines."""
    found = {}
    for line in path.read_text().splitlines():
        if "==" in line and not line.startswith("#"):
            name, version = line.split("==")
            found[name.strip().lower()] = version.strip()
    return found


def test_the_install_page_gives_each_core_range_and_names_each_extra():
    for requirement in PROJECT["dependencies"]:
        assert requirement in INSTALL, requirement
    for extra in PROJECT["optional-dependencies"]:
        assert f"``{extra}``" in INSTALL, extra


def test_every_version_the_install_page_pins_is_a_constraint_files():
    tested = pins(ROOT / "constraints" / "tested.txt")
    minimum = pins(ROOT / "constraints" / "minimum.txt")
    written = re.findall(r"([A-Za-z][\w.-]*)(?:\[\w+\])?==([\w.+]+)", INSTALL)
    assert written, "no pin on the page"
    for name, version in written:
        name = name.lower()
        if name == "torch-ac":  # the bench extra's own pin (pyproject.toml)
            assert f"torch-ac=={version}" in PROJECT["optional-dependencies"]["bench"]
            continue
        # pip freeze's torch==2.13.0+cpu is the constraint torch==2.13.0
        version = version.removesuffix("+cpu")
        assert version in (tested.get(name), minimum.get(name)), (
            f"{name}=={version}: not in constraints/"
        )
