"""The example scripts of the docs run, and do what the docs say."""

from __future__ import annotations

import importlib.util
import math
from pathlib import Path

import torch

EXAMPLES = Path(__file__).resolve().parents[1] / "docs" / "examples"


def load(name: str):
    spec = importlib.util.spec_from_file_location(name, EXAMPLES / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_two_stream_a2c_example_trains_a_users_pipeline():
    result = load("two_stream_a2c").main(frames=1024)
    assert result["episodes"] > 0
    assert 0.0 <= result["mean_return_last_100"] <= 1.0
    # The VAE trained between rollouts: the bonus it gives has moved.
    assert math.isfinite(result["mean_bonus_last"])
    assert result["mean_bonus_last"] != result["mean_bonus_first"]


def test_tutorial_trains_ppo_with_two_critics_and_plots_the_bonus(tmp_path):
    out = tmp_path / "figure" / "bonus.png"
    # 8 envs x 50 steps per update: 6 updates, 300 steps per env, past
    # DoorKey-5x5's 250-step time limit.
    result = load("tutorial_surprise").main(frames=2400, out=out)

    assert result["frames"] == [400, 800, 1200, 1600, 2000, 2400]
    assert len(result["returns"]) >= 8  # each env finished one at least
    assert all(0.0 <= r <= 1.0 for r in result["returns"])
    # The raw KL of each batch, finite and moved by the VAE updates between them.
    assert all(math.isfinite(b) and b >= 0.0 for b in result["bonus"])
    assert len(set(result["bonus"])) == len(result["bonus"])

    # Two streams: both advantages, both critics' targets, mixed with the
    # transform's coefficient, in the collector's [envs, time, 1] layout.
    batch = result["last_batch"]
    for key in ("advantage", "advantage_ext", "advantage_int", "value_target"):
        assert batch[key].shape == (8, 50, 1), key
    assert batch["value_target_int"].shape == (8, 50, 1)
    mixed = batch["advantage_ext"] + 0.5 * batch["advantage_int"]
    assert torch.allclose(batch["advantage"], mixed)
    # The bonus is written beside the task reward, not mixed into it.
    # (MiniGrid pays only on reaching the goal.)
    rewarded = batch["next", "reward"] != 0
    assert not (rewarded & ~batch["next", "terminated"]).any()

    # One episode scored by the VAE before and after training: same states,
    # different bonus.
    before, after = result["episode_bonus"].values()
    assert before.shape == after.shape and before.numel() > 0
    assert torch.isfinite(after).all() and not torch.allclose(before, after)

    assert out.stat().st_size > 0
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
