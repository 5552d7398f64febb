"""Runs that survive what users do to them: two processes on one run directory."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest
from omegaconf import OmegaConf

import common.rundir
from common.run import TrainingRun

RECIPES = Path(__file__).resolve().parents[1] / "recipes"

CFG = {
    "seed": 0,
    "resume": "auto",
    "torch_threads": 1,
    "collector": {"total_frames": 256},
    "logger": {"backend": "csv", "project_name": "p"},
    "checkpoint": {"interval_frames": 128},
}


def start_holder(run_dir: Path) -> subprocess.Popen:
    """Another process that starts a run in ``run_dir`` and stays there."""
    code = (
        f"import sys; sys.path.insert(0, {str(RECIPES)!r})\n"
        "from omegaconf import OmegaConf\n"
        "from common.run import TrainingRun\n"
        f"run = TrainingRun(OmegaConf.create({CFG!r}), 'demo', run_dir={str(run_dir)!r})\n"
        "print('started', flush=True)\n"
        "import time; time.sleep(600)\n"
    )
    proc = subprocess.Popen(
        [sys.executable, "-c", code], stdout=subprocess.PIPE, text=True
    )
    assert proc.stdout.readline().strip() == "started"
    return proc


def test_a_run_dir_is_owned_by_one_process_and_a_killed_owner_frees_it(tmp_path):
    holder = start_holder(tmp_path)
    try:
        with pytest.raises(RuntimeError) as err:
            TrainingRun(OmegaConf.create(CFG), "demo", run_dir=tmp_path)
        message = str(err.value)
        assert str(tmp_path) in message and f"process {holder.pid} on" in message
    finally:
        holder.kill()  # SIGKILL: no clean-up runs, the lock must not stay
        holder.wait()
    run = TrainingRun(OmegaConf.create(CFG), "demo", run_dir=tmp_path)
    assert not run.nothing_to_do()


def test_a_rerun_sweep_skips_the_job_another_sweep_is_running(
    tmp_path, monkeypatch, capsys
):
    holder = start_holder(tmp_path)
    try:
        monkeypatch.setattr(common.rundir, "in_sweep", lambda: True)
        run = TrainingRun(OmegaConf.create(CFG), "demo", run_dir=tmp_path)
        assert run.nothing_to_do()  # the job returns: exit status 0
        out = capsys.readouterr().out
        assert out.startswith("Skipped: ") and f"process {holder.pid}" in out
    finally:
        holder.kill()
        holder.wait()
