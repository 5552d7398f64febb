"""The wheel installs like a library: into a fresh environment, with the core
requirements at their lower ends (constraints/minimum.txt) and no extra, a bonus
composes with a TorchRL mock env, and no env family or recipe tool comes with it."""

from __future__ import annotations

import subprocess
import sys
import tarfile
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
# What only an extra may bring (env families, recipe and results tooling).
NOT_IN_CORE = (
    "minigrid",
    "mujoco",
    "envpool",
    "hydra",
    "matplotlib",
    "pandas",
    "rliable",
)

PROBE = f"""
import importlib.util, sys
from torchrl.envs import TransformedEnv
from torchrl.envs.utils import check_env_specs
from torchrl.testing.mocking_classes import ContinuousActionVecMockEnv
import torchrl_surprise
import torchrl_surprise.envs
from torchrl_surprise import StateVAE, VAEEllipticalTransform, VAELoss

vae = StateVAE.for_vector(7, latent_dim=4, hidden_dim=16)
env = TransformedEnv(ContinuousActionVecMockEnv(), VAEEllipticalTransform(vae))
check_env_specs(env)
td = env.rollout(5)
assert td["next", "intrinsic_reward"].shape == (5, 1)
assert (td["next", "intrinsic_reward"] > 0).all()
VAELoss(vae)(td)["loss_kl"].backward()
for name in {NOT_IN_CORE!r}:
    assert name not in sys.modules, f"imported {{name}}"
    assert importlib.util.find_spec(name) is None, f"installed {{name}}"
try:
    torchrl_surprise.envs.make_minigrid_env
except ModuleNotFoundError as err:
    print("MISSING:", err)
print("VERSION:", torchrl_surprise.__version__)
"""


def version() -> str:
    init = (ROOT / "torchrl_surprise" / "__init__.py").read_text()
    return init.split('__version__ = "')[1].split('"')[0]


def run(*cmd, **kwargs) -> subprocess.CompletedProcess:
    proc = subprocess.run(cmd, capture_output=True, text=True, **kwargs)
    assert proc.returncode == 0, f"{' '.join(map(str, cmd))}:\n{proc.stderr[-3000:]}"
    return proc


@pytest.mark.slow
def test_the_wheel_installs_with_the_core_lower_ends_only(tmp_path):
    run(sys.executable, "-m", "pip", "wheel", "--no-deps", "-q", "-w", tmp_path, ROOT)
    (wheel,) = tmp_path.glob("torchrl_surprise-*.whl")
    venv = tmp_path / "venv"
    run(sys.executable, "-m", "venv", venv)
    python = venv / "bin" / "python"
    minimum = ROOT / "constraints" / "minimum.txt"
    # pytest: torchrl.testing (the mock envs) imports it; not a dependency of ours.
    run(
        python,
        "-m",
        "pip",
        "install",
        "-q",
        "-c",
        minimum,
        wheel,
        "pytest",
        timeout=900,
    )
    installed = run(python, "-m", "pip", "freeze").stdout.lower()
    for line in minimum.read_text().splitlines():
        if line and not line.startswith("#"):
            assert line.lower() in installed.replace("+cpu", ""), line
    out = run(python, "-c", PROBE, cwd=tmp_path).stdout
    # One source for the version: the package's __version__, read by setuptools.
    assert f"torchrl_surprise-{version()}-" in wheel.name
    assert f"VERSION: {version()}" in out
    assert 'pip install "torchrl_surprise[minigrid]"' in out


def test_the_sdist_is_the_library_with_its_license_and_no_license_warning(tmp_path):
    # setuptools' own PEP 517 backend (the one pyproject.toml names), no isolation:
    # offline, and its warnings reach this process
    log = []
    for kind in ("sdist", "wheel"):
        build = f"import sys, setuptools.build_meta as b; b.build_{kind}(sys.argv[1])"
        proc = run(sys.executable, "-c", build, tmp_path, cwd=ROOT)
        log += (proc.stdout + proc.stderr).lower().splitlines()
    warned = [line for line in log if "warn" in line and "licen" in line]
    assert not warned, warned
    (sdist,) = tmp_path.glob("torchrl_surprise-*.tar.gz")
    with tarfile.open(sdist) as tar:
        names = [n.split("/", 1)[1] for n in tar.getnames() if "/" in n]
        info = tar.extractfile(f"torchrl_surprise-{version()}/PKG-INFO").read()
    # the tests need the recipes and docs of a checkout: none is half shipped
    assert {n.split("/")[0] for n in names} == {
        "LICENSE",
        "MANIFEST.in",
        "PKG-INFO",
        "README.md",
        "pyproject.toml",
        "setup.cfg",
        "torchrl_surprise",
        "torchrl_surprise.egg-info",
    }
    (wheel,) = tmp_path.glob("torchrl_surprise-*.whl")
    with zipfile.ZipFile(wheel) as whl:
        metadata = whl.read(f"torchrl_surprise-{version()}.dist-info/METADATA")
        licenses = [n for n in whl.namelist() if "/licenses/" in n]
    for meta in (info.decode(), metadata.decode()):
        assert "License-Expression: MIT" in meta.splitlines()
        assert "License-File: LICENSE" in meta.splitlines()
        assert "Classifier: License ::" not in meta
    assert licenses == [f"torchrl_surprise-{version()}.dist-info/licenses/LICENSE"]
