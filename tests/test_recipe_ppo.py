"""The PPO MiniGrid recipe, run end to end as a user runs it (tiny budgets), and a bad
config refused from the command line (the in-process checks: test_configs.py)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest
import torch
from _recipe_run import (
    SharedRun,
    differing_logs,
    kill_after_checkpoint,
    run_sweep,
    shared_run,
)

from common.checkpoint import load_checkpoint
from common.scalar_logs import read_scalar_csv

RECIPE = Path(__file__).resolve().parents[1] / "recipes" / "minigrid"
MAIN = RECIPE / "main.py"
# 4 envs x 32 frames = 128 per update, 2 epochs of 2 minibatches of 64.
TINY = [
    "algo=ppo",
    "env.name=MiniGrid-MultiRoom-N3-S4-v0",
    "env.num_envs=4",
    "collector.frames_per_env=32",
    "loss.epochs=2",
    "loss.minibatch_size=64",
    "eval.interval_frames=256",
    "eval.episodes=4",
    "eval.num_envs=2",
    "checkpoint.interval_frames=128",
]
# The seed and kill/resume tests run on the envpool backend (the A2C recipe's run on
# minigrid's): a resumed envpool run logs what the uninterrupted one logs too.
VAE_RUN = ["bonus=vae", "collector.total_frames=1024", "seed=3", "env.backend=envpool"]


def run_recipe(run_dir: Path, *overrides: str, check: bool = True):
    cmd = [sys.executable, str(MAIN), f"hydra.run.dir={run_dir}", *TINY, *overrides]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
    if check and proc.returncode != 0:
        raise AssertionError(
            f"recipe failed:\n{proc.stdout[-3000:]}\n{proc.stderr[-3000:]}"
        )
    return proc


@pytest.fixture(scope="module")
def vae_run(tmp_path_factory) -> Path:
    """One uninterrupted run, the reference of the seed and resume tests."""
    make = lambda run_dir: run_recipe(run_dir, *VAE_RUN)  # noqa: E731
    return shared_run(tmp_path_factory, "ppo_vae", make).path


BONUSES = ["none", "vae", "icm", "rnd", "e3b", "noveld"]


@pytest.fixture(scope="module")
def every_bonus(tmp_path_factory) -> SharedRun:
    """A sweep over every bonus, its runs in ``<sweep>/<bonus>``: one process runs
    them one after the other (start-up is most of a tiny run's time)."""

    def make(sweep_dir: Path) -> subprocess.CompletedProcess:
        bonuses = f"bonus={','.join(BONUSES)}"
        return run_sweep(
            MAIN, sweep_dir, "${bonus}", *TINY, bonuses, "collector.total_frames=256"
        )

    return shared_run(tmp_path_factory, "ppo_every_bonus", make)


@pytest.mark.parametrize("bonus", BONUSES)
def test_every_bonus_runs_end_to_end(every_bonus, bonus):
    run_dir = every_bonus.path / bonus
    assert f"Learning curve: {run_dir / 'learning_curve.png'}" in every_bonus.stdout
    assert (run_dir / "learning_curve.png").stat().st_size > 0
    scalars = run_dir / "logs" / "ppo" / "scalars"
    steps, fps = read_scalar_csv(scalars / "time" / "fps.csv")
    assert list(steps) == [128, 256] and (fps > 0).all()
    for name in ("loss_objective", "loss_critic", "clip_fraction", "kl_approx"):
        _, values = read_scalar_csv(scalars / "train" / f"{name}.csv")
        assert torch.isfinite(torch.as_tensor(values)).all(), name
    assert (scalars / "eval" / "episode_return.csv").exists()
    if bonus != "none":
        _, raw = read_scalar_csv(scalars / "train" / "intrinsic_reward.csv")
        assert torch.isfinite(torch.as_tensor(raw)).all()
        assert (scalars / "train" / "loss_critic_int.csv").exists()
        assert list((scalars / "bonus").iterdir()), "bonus-model losses are logged"
    assert load_checkpoint(run_dir / "checkpoint.torchrl")["frames"] == 256


def test_same_seed_same_logs_another_seed_differs(tmp_path, vae_run):
    # Again as the second job of a sweep: the first job (another seed) leaves
    # nothing to it that would change what it logs.
    seeds = [*(a for a in VAE_RUN if not a.startswith("seed=")), "seed=4,3"]
    run_sweep(MAIN, tmp_path, "${seed}", *TINY, *seeds)
    assert differing_logs(vae_run, tmp_path / "3") == []
    assert "logs/ppo/scalars/train/loss_critic.csv" in differing_logs(
        vae_run, tmp_path / "4"
    )


def test_killed_and_resumed_run_logs_what_the_uninterrupted_run_logs(tmp_path, vae_run):
    killed_dir = tmp_path / "killed"
    cmd = [sys.executable, str(MAIN), f"hydra.run.dir={killed_dir}", *TINY, *VAE_RUN]
    killed = kill_after_checkpoint(
        cmd, killed_dir / "checkpoint.torchrl", min_frames=256
    )
    assert 256 <= killed["frames"] < 1024, "the kill must land mid-run"
    run_recipe(killed_dir, *VAE_RUN)
    assert differing_logs(vae_run, killed_dir) == []


def test_bad_config_fails_clearly_on_the_command_line(tmp_path):
    proc = run_recipe(tmp_path / "bad", "loss.minibatch_size=1000", check=False)
    assert proc.returncode != 0
    assert "loss.minibatch_size must be an integer in [1, 128]" in proc.stderr
    assert not (tmp_path / "bad" / "checkpoint.torchrl").exists()


def test_the_bonus_model_trains_on_batch_size_transitions_drawn_each_step():
    # intrinsic.batch_size: each bonus-model step sees that many of the batch's
    # transitions, a new draw each step; null: the whole batch, every step.
    import torch
    from tensordict import TensorDict

    from common.minigrid import train_bonus_model

    seen = []

    class Loss(torch.nn.Module):
        def __init__(self):
            super().__init__()
            self.w = torch.nn.Parameter(torch.zeros(()))

        def forward(self, td):
            seen.append(td["i"].flatten().tolist())
            return TensorDict({"loss_x": (self.w - td["i"].float().mean()) ** 2})

    loss = Loss()
    optim = torch.optim.SGD(loss.parameters(), lr=0.1)
    data = TensorDict({"i": torch.arange(32).reshape(4, 8)}, batch_size=[4, 8])
    torch.manual_seed(0)
    train_bonus_model(loss, optim, data, steps=3, batch_size=8)
    assert [len(s) for s in seen] == [8, 8, 8]
    assert all(len(set(s)) == 8 for s in seen)  # without replacement
    assert seen[0] != seen[1] != seen[2]  # a new draw each step
    assert loss.w.item() != 0.0  # and it trained
    seen.clear()
    train_bonus_model(loss, optim, data, steps=2)
    assert [sorted(s) for s in seen] == [list(range(32))] * 2
