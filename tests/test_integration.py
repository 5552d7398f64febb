"""The bonus transforms on real MiniGrid and MuJoCo envs (integration)."""

from __future__ import annotations

import pytest
import torch
from torchrl.envs import TransformedEnv
from torchrl.envs.utils import check_env_specs

from torchrl_surprise import ICMModel, ICMTransform, StateVAE, VAESurpriseTransform
from torchrl_surprise.envs import make_minigrid_env, make_mujoco_env


def _env_path_equals_batch_path(env, transform):
    rollout = env.rollout(30, break_when_any_done=False)
    assert torch.isfinite(rollout["next", "intrinsic_reward"]).all()
    assert (rollout["next", "intrinsic_reward"] >= 0).all()
    expected = (
        rollout["next", "extrinsic_reward"] + 0.1 * rollout["next", "intrinsic_reward"]
    )
    torch.testing.assert_close(rollout["next", "reward"], expected)
    recomputed = transform(rollout.clone())
    for key in ("intrinsic_reward", "extrinsic_reward", "reward"):
        torch.testing.assert_close(recomputed["next", key], rollout["next", key])


@pytest.mark.parametrize("bonus", ["vae", "icm"])
def test_bonus_on_real_minigrid_env(bonus):
    base = make_minigrid_env("MiniGrid-MultiRoom-N3-S4-v0", num_envs=3, seed=0)
    if bonus == "vae":
        transform = VAESurpriseTransform(StateVAE.for_minigrid(hidden_dim=32), coef=0.1)
    else:
        icm = ICMModel.for_minigrid(num_actions=base.action_spec.space.n, hidden_dim=32)
        transform = ICMTransform(icm, coef=0.1)
    env = TransformedEnv(base, transform)
    check_env_specs(env)
    _env_path_equals_batch_path(env, transform)
    env.close()


def test_vae_bonus_on_real_mujoco_env():
    base = make_mujoco_env("HalfCheetah-v5", num_envs=2, seed=0)
    obs_dim = base.observation_spec["observation"].shape[-1]
    transform = VAESurpriseTransform(
        StateVAE.for_vector(obs_dim, hidden_dim=32), coef=0.1
    )
    env = TransformedEnv(base, transform)
    check_env_specs(env)
    _env_path_equals_batch_path(env, transform)
    env.close()


def test_minigrid_env_without_the_expected_observation_fails_clearly():
    base = make_minigrid_env("MiniGrid-DoorKey-5x5-v0", num_envs=2, seed=0)
    vae = StateVAE.for_vector(obs_dim=4, hidden_dim=8)  # reads "observation"
    with pytest.raises(KeyError, match="observation"):
        TransformedEnv(base, VAESurpriseTransform(vae)).rollout(2)
