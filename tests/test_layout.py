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


def test_importing_the_package_does_no_tensor_work_and_registers_nothing():
    # Every module of the package imported under a mode that records each torch
    # call (the libraries it builds on imported before), then gymnasium's registry
    # read: the paper's MultiRoom ids are registered on request only.
    modules = sorted(
        ".".join(path.relative_to(PACKAGE.parent).with_suffix("").parts)
        for path in PACKAGE.rglob("*.py")
        if path.name != "__init__.py"
    )
    code = f"""
import importlib, torch, torchrl, tensordict, gymnasium, minigrid, envpool
import torchrl.envs, torchrl.objectives, torchrl.collectors, torchrl.data
from torch.overrides import TorchFunctionMode

calls = []
class Record(TorchFunctionMode):
    def __torch_function__(self, func, types, args=(), kwargs=None):
        calls.append(getattr(func, "__name__", str(func)))
        return func(*args, **(kwargs or {{}}))

with Record():
    for name in ["torchrl_surprise", *{modules!r}]:
        importlib.import_module(name)
print(calls)
print("MiniGrid-MultiRoom-N3-S4-v0" in gymnasium.registry)
"""
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True
    ).stdout.splitlines()
    assert out == ["[]", "False"]


def _imported_modules(path: Path) -> set[str]:
    """The package's modules that ``path`` imports, anywhere in it."""
    package = ".".join(path.relative_to(PACKAGE.parent).with_suffix("").parts[:-1])
    found = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            found |= {alias.name for alias in node.names}
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                parts = package.split(".")[: len(package.split(".")) - node.level + 1]
                base = ".".join(parts + ([base] if base else []))
            found.add(base)
            found |= {f"{base}.{alias.name}" for alias in node.names}
    return {name for name in found if name.startswith("torchrl_surprise")}


def test_the_package_has_no_import_circle():
    # Between modules (a package's __init__, which gathers its modules, aside):
    # function-level imports count.
    modules = {
        ".".join(path.relative_to(PACKAGE.parent).with_suffix("").parts): path
        for path in PACKAGE.rglob("*.py")
        if path.name != "__init__.py"
    }
    graph = {
        name: _imported_modules(path) & set(modules) - {name}
        for name, path in modules.items()
    }
    circles = []

    def visit(name, trail):
        for nxt in sorted(graph[name]):
            if nxt in trail:
                circles.append(" -> ".join(trail[trail.index(nxt) :] + [nxt]))
            elif len(trail) < len(graph):
                visit(nxt, trail + [nxt])

    for name in sorted(graph):
        visit(name, [name])
    assert circles == []


def test_the_training_code_never_imports_the_results_tools():
    # The results tools consume the runs: one way only.
    recipes = PACKAGE.parent / "recipes"
    offenders = []
    for folder in ("common", "minigrid", "ddpg_mujoco"):
        for path in (recipes / folder).rglob("*.py"):
            for node in ast.walk(ast.parse(path.read_text())):
                names = []
                if isinstance(node, ast.Import):
                    names = [alias.name for alias in node.names]
                elif isinstance(node, ast.ImportFrom) and not node.level:
                    names = [node.module or ""]
                offenders += [
                    f"{path.relative_to(recipes)}: {name}"
                    for name in names
                    if name == "results" or name.startswith("results.")
                ]
    assert offenders == []
