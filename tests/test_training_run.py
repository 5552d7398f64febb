"""The run scaffolding the recipes share (common/run.py), without running a recipe."""

from __future__ import annotations

import copyreg
import subprocess
import sys
from pathlib import Path

import cloudpickle
import numpy as np
import pytest
import torch
import torch.utils.deterministic
from omegaconf import OmegaConf

from common.checkpoint import RunCounters, load_checkpoint
from common.evaluation import plot_learning_curves
from common.run import TrainingRun
from common.scalar_logs import read_scalar_csv
from common.stopping import register_sweep_pickling

RECIPES = Path(__file__).resolve().parents[1] / "recipes"


def test_importing_the_run_support_registers_no_pickling_hook():
    # A hook registered at import is a mechanism a reader cannot see: the recipe
    # calls register_sweep_pickling itself.
    code = (
        "import copyreg, sys, torch.utils.deterministic\n"
        f"sys.path.insert(0, {str(RECIPES)!r})\n"
        "import common.run, common.stopping, common.minigrid\n"
        "t = type(torch.utils.deterministic)\n"
        "assert t not in copyreg.dispatch_table, 'hook registered at import'\n"
        "common.stopping.register_sweep_pickling()\n"
        "assert t in copyreg.dispatch_table\n"
    )
    subprocess.run([sys.executable, "-c", code], check=True, timeout=120)


def test_a_task_function_naming_torch_utils_deterministic_pickles_for_a_sweep():
    def task(cfg):  # names torch, utils and deterministic, as the recipes' mains do
        return torch.nn.utils, cfg.eval.deterministic

    register_sweep_pickling()
    assert type(torch.utils.deterministic) in copyreg.dispatch_table
    restored = cloudpickle.loads(cloudpickle.dumps(task))
    cfg = OmegaConf.create({"eval": {"deterministic": True}})
    assert restored(cfg) == (torch.nn.utils, True)


def _cfg(total_frames: int, interval: int, keep: bool = False, backend: str = "csv"):
    return OmegaConf.create(
        {
            "seed": 0,
            "resume": "auto",
            "torch_threads": 1,
            "collector": {"total_frames": total_frames},
            "logger": {"backend": backend, "project_name": "p"},
            "checkpoint": {"interval_frames": interval, "keep": keep},
        }
    )


def _train(run_dir, total_frames: int, keep: bool = False, backend: str = "csv"):
    run = TrainingRun(_cfg(total_frames, 128, keep, backend), "demo", run_dir=run_dir)
    if run.nothing_to_do():
        return None
    counters = RunCounters(frames=0, next_ckpt=128)
    net = torch.nn.Linear(2, 1)
    run.restore({"progress": counters, "net": net})
    while counters.frames < total_frames:
        counters.frames += 64
        run.log({"train/draw": torch.rand(()).item()}, step=counters.frames)
        run.after_update()
    run.finish(f"{counters.frames} frames.", curves={"train/draw": "draw"})
    return run


def test_a_training_run_saves_periodically_keeps_and_resumes_where_it_stopped(
    tmp_path, capsys
):
    whole, parts = tmp_path / "whole", tmp_path / "parts"
    _train(whole, 512, keep=True)
    assert load_checkpoint(whole / "checkpoint.torchrl")["frames"] == 512
    kept = sorted(p.name for p in (whole / "checkpoints").iterdir())
    assert kept == [f"checkpoint-{n:012d}.torchrl" for n in (128, 256, 384, 512)]
    assert (whole / "learning_curve.png").exists()
    assert "Done: 512 frames." in capsys.readouterr().out
    # the same run in two parts: the second resumes from the first's checkpoint
    _train(parts, 256)
    _train(parts, 512)
    csv = "logs/demo/scalars/train/draw.csv"
    assert (whole / csv).read_bytes() == (parts / csv).read_bytes()
    steps, _ = read_scalar_csv(parts / csv)
    assert steps.tolist() == list(range(64, 513, 64))
    # a finished run has nothing to do
    assert _train(parts, 512) is None
    assert "Nothing to do: 512 frames already done" in capsys.readouterr().out


def test_a_run_logging_to_tensorboard_draws_its_curve_from_rows_cut_on_resume(
    tmp_path, capsys
):
    pytest.importorskip("tensorboard")
    run_dir = tmp_path / "run"
    _train(run_dir, 256, backend="tensorboard")
    assert list((run_dir / "logs" / "demo").glob("events.out.tfevents.*"))
    # killed after its checkpoint at 256: rows past it are logged again on resume
    csv = run_dir / "logs/demo/scalars/train/draw.csv"
    csv.write_text(csv.read_text() + "320,0.5\n")
    (run_dir / "learning_curve.png").unlink()
    _train(run_dir, 512, backend="tensorboard")
    out = capsys.readouterr().out
    assert f"Learning curve: {run_dir / 'learning_curve.png'}" in out
    assert (run_dir / "learning_curve.png").stat().st_size > 0
    steps, _ = read_scalar_csv(csv)
    assert steps.tolist() == list(range(64, 513, 64))
    assert not (run_dir / "logs/demo/scalars/train/draw.csv.tmp").exists()


def test_a_run_without_a_logger_says_why_it_has_no_curve(tmp_path, capsys):
    _train(tmp_path / "run", 128, backend="")
    out = capsys.readouterr().out
    assert "Learning curve: none (logger.backend='' logs no scalars)" in out
    assert not (tmp_path / "run" / "learning_curve.png").exists()


def test_the_curve_draws_the_optimum_as_a_dashed_line(tmp_path):
    from PIL import Image

    curves = {"vae": ([0, 64, 128], [0.0, 0.2, 0.5])}
    plain = plot_learning_curves(curves, tmp_path / "plain.png")
    lined = plot_learning_curves(
        curves, tmp_path / "lined.png", optimum=("oracle", 0.8)
    )
    plain, lined = (np.asarray(Image.open(p).convert("L")) for p in (plain, lined))
    assert plain.shape == lined.shape and (plain != lined).any()


def test_the_minigrid_oracle_gives_the_curve_its_optimum():
    from common.minigrid import oracle_optimum
    from torchrl_surprise.envs import oracle_returns

    label, value = oracle_optimum("MiniGrid-MultiRoom-N3-S4-v0", seed=10_000)
    solutions = oracle_returns("MiniGrid-MultiRoom-N3-S4-v0", range(10_000, 10_020))
    assert value == pytest.approx(np.mean([s.episode_return for s in solutions]))
    assert label == "oracle (mean of 20 layouts)"
    assert oracle_optimum("MiniGrid-MultiRoom-N3-S4-v0", 0, 1)[0].startswith("noise")
    # a task the oracle refuses (Fetch's reward is its own): no line
    assert oracle_optimum("MiniGrid-Fetch-5x5-N2-v0", seed=0) is None
