"""The A2C MiniGrid recipe, run end to end as a user runs it (tiny budgets)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest
import torch
from _recipe_run import kill_after_checkpoint

from torchrl_surprise.experiments import load_checkpoint, read_scalar_csv

MAIN = Path(__file__).resolve().parents[1] / "recipes" / "a2c_minigrid" / "main.py"
TINY = [
    "env.name=MiniGrid-MultiRoom-N3-S4-v0",
    "env.num_envs=4",
    "collector.frames_per_env=8",
    "eval.interval_frames=256",
    "eval.episodes=4",
    "eval.num_envs=2",
    "checkpoint.interval_frames=128",
    "logger.log_interval=1",
]


def run_recipe(run_dir: Path, *overrides: str, check: bool = True):
    cmd = [sys.executable, str(MAIN), f"hydra.run.dir={run_dir}", *TINY, *overrides]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
    if check and proc.returncode != 0:
        raise AssertionError(
            f"recipe failed:\n{proc.stdout[-3000:]}\n{proc.stderr[-3000:]}"
        )
    return proc


@pytest.mark.parametrize("bonus", ["none", "vae", "icm", "rnd"])
def test_every_bonus_runs_end_to_end(tmp_path, bonus):
    run_dir = tmp_path / bonus
    proc = run_recipe(run_dir, f"bonus={bonus}", "collector.total_frames=512")
    assert "Learning curve:" in proc.stdout
    assert (run_dir / "learning_curve.png").stat().st_size > 0
    assert (run_dir / "config_resolved.yaml").exists()
    scalars = run_dir / "logs" / "a2c" / "scalars"
    steps, fps = read_scalar_csv(scalars / "time" / "fps.csv")
    assert steps[-1] == 512 and (fps > 0).all()
    assert (scalars / "eval" / "episode_return.csv").exists()
    if bonus != "none":
        _, raw = read_scalar_csv(scalars / "train" / "intrinsic_reward.csv")
        assert torch.isfinite(torch.as_tensor(raw)).all()
        assert list((scalars / "bonus").iterdir()), "bonus-model losses are logged"
    ckpt = load_checkpoint(run_dir / "checkpoint.pt")
    assert ckpt["frames"] == 512


def test_same_seed_same_curve(tmp_path):
    args = ["bonus=vae", "collector.total_frames=384", "seed=3"]
    run_recipe(tmp_path / "a", *args)
    run_recipe(tmp_path / "b", *args)
    run_recipe(tmp_path / "c", *args[:-1], "seed=4")
    losses = {}
    for name in "abc":
        path = (
            tmp_path / name / "logs" / "a2c" / "scalars" / "train" / "loss_critic.csv"
        )
        losses[name] = read_scalar_csv(path)[1]
    assert (losses["a"] == losses["b"]).all()
    assert not (losses["a"] == losses["c"]).all()


def test_resume_after_kill_continues_the_frame_count(tmp_path):
    run_dir = tmp_path / "run"
    cmd = [
        sys.executable,
        str(MAIN),
        f"hydra.run.dir={run_dir}",
        *TINY,
        "bonus=vae",
        "collector.total_frames=1000000",
    ]
    ckpt_path = run_dir / "checkpoint.pt"
    killed = kill_after_checkpoint(cmd, ckpt_path, min_frames=256)
    killed_at = killed["frames"]
    assert killed_at >= 256
    target = killed_at + 4 * 32  # four more rollouts of 4 envs x 8 frames
    out = run_recipe(
        run_dir, "bonus=vae", "resume=true", f"collector.total_frames={target}"
    )
    ckpt = load_checkpoint(ckpt_path)
    assert ckpt["frames"] == target
    assert f"Done: {target} frames" in out.stdout
    steps, _ = read_scalar_csv(
        run_dir / "logs" / "a2c" / "scalars" / "time" / "fps.csv"
    )
    assert steps[-1] == target


@pytest.mark.parametrize(
    "override, message",
    [
        ("bonus=banana", "bonus must be one of"),
        ("env.name=MiniGrid-NoSuchEnv-v0", "MiniGrid-NoSuchEnv-v0"),
        ("intrinsic.normalization=median", "intrinsic.normalization must be one of"),
        ("collector.total_frames=-5", "collector.total_frames must be a positive"),
        ("resume=true", "no checkpoint"),
    ],
)
def test_bad_config_fails_clearly(tmp_path, override, message):
    proc = run_recipe(tmp_path / "bad", override, check=False)
    assert proc.returncode != 0
    assert message in proc.stdout + proc.stderr
