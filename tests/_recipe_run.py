"""Running a recipe as a user does, for the recipe tests."""

from __future__ import annotations

import importlib.util
import os
import shutil
import signal
import subprocess
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from filelock import FileLock

from common.checkpoint import checkpoint_info, load_checkpoint


def load_recipe_utils(recipe_dir: Path):
    """A recipe's ``utils.py``, loaded under its own name: every recipe has one."""
    spec = importlib.util.spec_from_file_location(
        f"{recipe_dir.name}_utils", recipe_dir / "utils.py"
    )
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def run_sweep(
    main: Path, sweep_dir: Path, subdir: str, *overrides: str
) -> subprocess.CompletedProcess:
    """Runs the recipe ``main`` as a sweep (``-m``) over ``overrides``, its jobs one
    after the other in one process (``hydra.launcher.n_jobs=1``: joblib runs them
    in the sweep's process; a recipe's start-up is most of a tiny run's time), each
    in ``<sweep_dir>/<subdir>`` (an interpolation: ``${bonus}``; a boolean reads
    ``True`` or ``False``). Hydra's sweeper keeps the order of each list.

    Raises:
        AssertionError: the sweep failed (its output's end is in the message).
    """
    cmd = [
        sys.executable,
        str(main),
        "-m",
        f"hydra.sweep.dir={sweep_dir}",
        f"hydra.sweep.subdir={subdir}",
        "hydra.launcher.n_jobs=1",
        *overrides,
    ]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=600)
    if proc.returncode != 0:
        raise AssertionError(
            f"the sweep failed:\n{proc.stdout[-2000:]}\n{proc.stderr[-3000:]}"
        )
    return proc


def run_results_script(name: str, *args: str, cwd: Path) -> None:
    """Runs ``recipes/results/<name>`` as the docs do: a script in a fresh process,
    with nothing of ``recipes/`` importable but what it puts on ``sys.path``."""
    script = Path(__file__).resolve().parents[1] / "recipes" / "results" / name
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    done = subprocess.run(
        [sys.executable, str(script), *args],
        capture_output=True,
        text=True,
        env=env,
        cwd=cwd,
        timeout=300,
    )
    assert done.returncode == 0, done.stderr[-2000:]


def assert_resume_refused(proc: subprocess.CompletedProcess, *changes: str) -> None:
    """``proc`` refused to resume a changed experiment, naming each of ``changes``."""
    assert proc.returncode != 0 and "the experiment changed" in proc.stderr, (
        proc.stderr[-3000:]
    )
    missing = [change for change in changes if change not in proc.stderr]
    assert not missing, f"the refusal does not name {missing}:\n{proc.stderr[-3000:]}"


def wait_for_checkpoint(ckpt_path: Path, min_frames: int, timeout: float = 120):
    """Waits until the checkpoint at ``ckpt_path`` holds at least ``min_frames``."""
    deadline = time.time() + timeout
    while time.time() < deadline:
        try:
            # the manifest only: cheap enough to poll
            if checkpoint_info(ckpt_path)["frames"] >= min_frames:
                return
        except FileNotFoundError:
            pass  # not written yet
        time.sleep(0.05)
    raise TimeoutError(f"no checkpoint with {min_frames} frames at {ckpt_path}")


def kill_after_checkpoint(cmd: list[str], ckpt_path: Path, min_frames: int) -> dict:
    """Starts ``cmd``, SIGKILLs it once its checkpoint holds ``min_frames``.

    Returns the checkpoint the killed run left behind.
    """
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        wait_for_checkpoint(ckpt_path, min_frames)
    finally:
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait()
    return load_checkpoint(ckpt_path)


def differing_logs(run_a: Path, run_b: Path) -> list[str]:
    """The CSV scalar logs (all but wall-clock ``time/*``) that differ between runs."""
    files = {
        p.relative_to(run).as_posix()
        for run in (run_a, run_b)
        for p in (run / "logs").glob("**/scalars/**/*.csv")
    }
    files = {f for f in files if "/scalars/time/" not in f}
    assert files, f"no scalar logs under {run_a} or {run_b}"
    return sorted(
        f
        for f in files
        if not ((run_a / f).exists() and (run_b / f).exists())
        or (run_a / f).read_bytes() != (run_b / f).read_bytes()
    )


@dataclass(frozen=True)
class SharedRun:
    """A finished run that several tests read (and none changes): its directory
    and what it printed."""

    path: Path
    stdout: str


def shared_run(
    tmp_path_factory, name: str, make: Callable[[Path], subprocess.CompletedProcess]
) -> SharedRun:
    """The run ``make(run_dir)`` makes, made once per test session: the pytest-xdist
    workers share it through a lock in their common temporary folder (each worker
    would otherwise make its own copy of a module-scoped fixture)."""
    root = tmp_path_factory.getbasetemp()
    if os.environ.get("PYTEST_XDIST_WORKER"):
        root = root.parent  # common to the workers of this session
    run_dir = root / "shared_runs" / name
    run_dir.parent.mkdir(parents=True, exist_ok=True)
    done = run_dir.with_name(f"{name}.stdout")
    with FileLock(f"{run_dir}.lock"):
        if not done.exists():
            if run_dir.exists():  # left by a make that failed
                shutil.rmtree(run_dir)
            done.write_text(make(run_dir).stdout)
    return SharedRun(run_dir, done.read_text())
