"""How far into a task a policy gets: milestones read from MiniGrid's own views."""

from __future__ import annotations

import gymnasium as gym
import pandas as pd
import pytest
import torch
from torchrl.data import Categorical

from common.minigrid import make_actor_critic
from results.milestones import MILESTONES, episode_milestones, main
from torchrl_surprise.envs.oracle import solve_minigrid


def _played(env_id: str, seed: int, actions=None):
    """``(image, reward, done)`` of one episode of ``env_id`` (``[1, steps, ...]``),
    playing the oracle's shortest solution (or ``actions``)."""
    env = gym.make(env_id)
    env.reset(seed=seed)
    if actions is None:
        actions = solve_minigrid(env.unwrapped).actions
    images, rewards, dones = [], [], []
    for action in actions:
        obs, reward, terminated, truncated, _ = env.step(action)
        images.append(torch.as_tensor(obs["image"]))
        rewards.append(float(reward))
        dones.append(terminated or truncated)
    env.close()
    return (
        torch.stack(images)[None],
        torch.tensor(rewards)[None],
        torch.tensor(dones)[None],
    )


@pytest.mark.parametrize(
    "env_id, reached",
    [
        # move the ball off the door, open the box, take its key, unlock, fetch
        ("MiniGrid-ObstructedMaze-1Dlhb-v0", {"carried_ball", "carried_key"}),
        ("MiniGrid-DoorKey-5x5-v0", {"carried_key"}),
    ],
)
def test_the_oracles_solution_reaches_every_milestone_on_its_way(env_id, reached):
    table = episode_milestones(*_played(env_id, seed=1))
    assert len(table) == 1
    row = table.iloc[0]
    expected = reached | {"opened_door", "success"}
    assert {name for name in MILESTONES if row[name]} == expected


def test_an_episode_that_has_not_ended_is_left_out_and_each_episode_starts_afresh():
    # the solution's first half (the key taken, the door still locked), then the
    # episode ends, then a second episode begins and does not end
    image, reward, done = _played("MiniGrid-DoorKey-5x5-v0", seed=1)
    steps = image.shape[1]
    cut = torch.cat([image, image[:, :2]], 1)
    ended = torch.zeros(1, steps + 2, dtype=torch.bool)
    ended[0, steps - 1] = True
    table = episode_milestones(cut, torch.cat([reward, reward[:, :2]], 1), ended)
    assert len(table) == 1 and bool(table.iloc[0]["success"])
    nothing = episode_milestones(
        image, torch.zeros_like(reward), torch.zeros_like(done)
    )
    assert nothing.empty and list(nothing.columns) == list(MILESTONES)


def test_a_view_of_the_wrong_shape_is_refused_naming_the_expected_one():
    with pytest.raises(ValueError, match=r"\[envs, steps, 7, 7, 3\].*\(2, 7, 7, 3\)"):
        episode_milestones(torch.zeros(2, 7, 7, 3), torch.zeros(2), torch.zeros(2))


def _checkpoint(run_dir, env_name: str, backend: str = "gymnasium"):
    torch.manual_seed(0)
    model, _ = make_actor_critic(Categorical(7), intrinsic_critic=False)
    config = {
        "setting": "demo",
        "seed": 4,
        "env": {"name": env_name, "backend": backend},
    }
    run_dir.mkdir()
    torch.save(
        {"config": config, "frames": 512, "model": model.state_dict()},
        run_dir / "checkpoint.pt",
    )


def test_a_runs_policy_is_played_and_its_episodes_counted(tmp_path):
    _checkpoint(tmp_path / "run", "MiniGrid-DoorKey-5x5-v0")
    out = tmp_path / "milestones.csv"
    argv = [str(tmp_path / "run"), "--envs", "2", "--steps", "260", "--out", str(out)]
    assert main(argv) == 0
    table = pd.read_csv(out)
    row = table.iloc[0]
    assert (row["setting"], row["seed"], row["frames"]) == ("demo", 4, 512)
    # DoorKey-5x5 truncates at 250 steps: each env ends at least one episode
    assert row["episodes"] >= 2
    assert all(0.0 <= row[name] <= 1.0 for name in MILESTONES)
    # seeded: the same rollout again
    assert main([*argv[:-1], str(tmp_path / "again.csv")]) == 0
    pd.testing.assert_frame_equal(table, pd.read_csv(tmp_path / "again.csv"))


def test_a_run_that_is_not_a_minigrid_policy_is_refused(tmp_path, capsys):
    _checkpoint(tmp_path / "run", "HalfCheetah-v5")
    with pytest.raises(SystemExit) as exit_:
        main([str(tmp_path / "run")])
    assert exit_.value.code == 2
    assert "expected a MiniGrid recipe's checkpoint" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main([str(tmp_path / "nowhere")])
