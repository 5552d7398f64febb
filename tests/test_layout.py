"""The library/recipe boundary: what ``import torchrl_surprise`` pulls in."""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[1] / "torchrl_surprise"


def test_the_core_imports_no_env_package_and_no_recipe_tooling():
    # One interpreter checks every module; a failure names each one imported.
    modules = ["minigrid", "hydra", "omegaconf", "matplotlib", "pandas", "rliable"]
    code = (
        "import sys, torchrl_surprise, torchrl_surprise.modules, "
        "torchrl_surprise.transforms, torchrl_surprise.objectives; "
        f"print(*[m for m in {modules!r} + ['common', 'results'] if m in sys.modules])"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True
    ).stdout.split()
    assert out == [], f"import torchrl_surprise imported {out}"


def test_no_module_imports_private_names_of_another():
    offenders = []
    for path in PACKAGE.rglob("*.py"):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ImportFrom) and (node.module or "").startswith(
                "torchrl_surprise"
            ):
                offenders += [
                    f"{path.relative_to(PACKAGE)}: {node.module}.{alias.name}"
                    for alias in node.names
                    if alias.name.startswith("_")
                ]
    assert offenders == []


def test_env_families_are_imported_on_first_use_only():
    code = (
        "import sys, torchrl_surprise.envs as envs; "
        "print(sorted(m for m in sys.modules if m.startswith('torchrl_surprise.envs.'))); "
        "envs.make_minigrid_env; "
        "print('torchrl_surprise.envs.minigrid' in sys.modules, "
        "'torchrl_surprise.envs.mujoco' in sys.modules)"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True
    ).stdout.splitlines()
    assert out == ["['torchrl_surprise.envs.vector']", "True False"]


def test_a_missing_env_family_names_its_extra():
    # minigrid made unimportable, as in an install without the extra.
    code = (
        "import sys; sys.modules['minigrid'] = None; "
        "import torchrl_surprise.envs as envs; envs.make_minigrid_env"
    )
    result = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True
    )
    assert result.returncode != 0
    assert 'pip install "torchrl_surprise[minigrid]"' in result.stderr
