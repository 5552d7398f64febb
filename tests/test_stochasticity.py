"""Tests of StochasticityTransform on real MiniGrid envs (and TorchRL's mock envs)."""

from __future__ import annotations

import pytest
import torch
from tensordict import TensorDict, TensorDictBase
from torch import nn
from torchrl.data import LazyTensorStorage, ReplayBuffer, TensorDictReplayBuffer
from torchrl.envs import Compose, ParallelEnv, SerialEnv, TransformedEnv
from torchrl.envs.utils import check_env_specs
from torchrl.testing.mocking_classes import DiscreteActionVecMockEnv

from torchrl_surprise.envs import MULTIROOM_N3_S4, make_minigrid_env, make_mujoco_env
from torchrl_surprise.transforms.stochasticity import (
    AGENT_CELL,
    DEFAULT_NOISE_PATCH,
    STOCHASTICITY_LEVEL_NAMES,
    STOCHASTICITY_LEVELS,
    StochasticityTransform,
)

NUM_ENVS = 4
STEPS = 70  # crosses the 60-step N3S4 episode end
LEFT = 0


def _base(num_envs: int = NUM_ENVS, seed: int = 0, **kwargs):
    return make_minigrid_env(MULTIROOM_N3_S4, num_envs=num_envs, seed=seed, **kwargs)


def _env(transform: StochasticityTransform, num_envs: int = NUM_ENVS, **kwargs):
    return _base(num_envs, **kwargs).append_transform(transform)


def _replay_policy(actions: torch.Tensor):
    step = iter(range(actions.shape[0]))

    def policy(td: TensorDictBase) -> TensorDictBase:
        return td.set("action", actions[next(step)].clone())

    return policy


def _fixed_actions(steps: int = STEPS, num_envs: int = NUM_ENVS, seed: int = 0):
    return torch.randint(
        7, (steps, num_envs), generator=torch.Generator().manual_seed(seed)
    )


def _rollout(env, actions: torch.Tensor) -> TensorDictBase:
    td = env.rollout(
        actions.shape[0], policy=_replay_policy(actions), break_when_any_done=False
    )
    env.close()
    return td


def _patch_mask(patch=DEFAULT_NOISE_PATCH) -> torch.Tensor:
    mask = torch.zeros(7, 7, dtype=torch.bool)
    for x, y in patch:
        mask[x, y] = True
    return mask


def _parallel_factory():
    # Module-level, hence picklable for ParallelEnv's spawned workers.
    return _env(StochasticityTransform(0.5, 0.5, seed=0), num_envs=2)


# Levels --------------------------------------------------------------------------
def test_levels():
    assert len(STOCHASTICITY_LEVELS) >= 4
    assert STOCHASTICITY_LEVELS[0] == (0.0, 0.0)
    for level, (p, q) in STOCHASTICITY_LEVELS.items():
        t = StochasticityTransform.from_level(level)
        assert (t.action_noise, t.obs_noise) == (p, q)
    for name, level in STOCHASTICITY_LEVEL_NAMES.items():
        t = StochasticityTransform.from_level(name, seed=1)
        assert (t.action_noise, t.obs_noise) == STOCHASTICITY_LEVELS[level]
    # Levels grow in both knobs.
    levels = [STOCHASTICITY_LEVELS[k] for k in sorted(STOCHASTICITY_LEVELS)]
    assert levels == sorted(levels)
    assert AGENT_CELL not in DEFAULT_NOISE_PATCH


def test_level_zero_is_identity():
    actions = _fixed_actions()
    reference = _rollout(_base(), actions)
    transform = StochasticityTransform.from_level(0, seed=0)
    state = transform._generator.get_state()
    td = _rollout(_env(transform), actions)
    assert (td == reference).all()
    assert torch.equal(transform._generator.get_state(), state)  # drew nothing


# Action noise --------------------------------------------------------------------
def _turns(td: TensorDictBase) -> torch.Tensor:
    """Direction change of each step, in {-1, 0, 1, 2} (mod 4)."""
    return (td["next", "direction"] - td["direction"]) % 4


@pytest.mark.parametrize("categorical", [True, False])
def test_action_noise_changes_executed_actions_only(categorical):
    always_left = torch.full((STEPS, NUM_ENVS), LEFT)
    if not categorical:
        always_left = torch.nn.functional.one_hot(always_left, 7)
    kwargs = {"categorical_action_encoding": categorical}
    clean = _rollout(_base(**kwargs), always_left)
    noisy = _rollout(
        _env(StochasticityTransform(action_noise=1.0, seed=0), **kwargs), always_left
    )
    # The tensordict keeps the agent's action ...
    assert torch.equal(noisy["action"], always_left.transpose(0, 1))
    # ... but the env executed other ones: "left" always turns by -1 (3 mod 4), a
    # uniformly random action does so with probability 1/7 only.
    assert (_turns(clean) == 3).all()
    turns = _turns(noisy)
    left = (turns == 3).float().mean()
    right = (turns == 1).float().mean()
    assert 0.05 < left < 0.3 and 0.05 < right < 0.3
    assert (turns == 0).float().mean() > 0.5  # forward/pickup/drop/toggle/done


def test_action_noise_standalone_distribution():
    transform = StochasticityTransform(action_noise=0.5, num_actions=7, seed=0)
    agent = torch.full((20_000,), 3)
    td = TensorDict(action=agent.clone(), batch_size=[20_000])
    executed = transform.inv(td)["action"]
    assert torch.equal(td["action"], agent)  # inv works on a copy
    counts = torch.bincount(executed, minlength=7).float() / 20_000
    # Kept with probability 0.5 + 0.5 / 7, every other action 0.5 / 7.
    expected = torch.full((7,), 0.5 / 7)
    expected[3] += 0.5
    torch.testing.assert_close(counts, expected, atol=0.015, rtol=0)


def test_action_noise_one_hot_mock_env():
    env = TransformedEnv(
        DiscreteActionVecMockEnv(), StochasticityTransform(action_noise=1.0, seed=0)
    )
    check_env_specs(env)
    td = env.rollout(5)
    assert td["action"].shape == (5, 7)
    one_hot = TensorDict(action=torch.eye(7)[[2] * 1000], batch_size=[1000])
    executed = env.transform.inv(one_hot)["action"]
    assert executed.shape == (1000, 7) and (executed.sum(-1) == 1).all()
    assert (executed.argmax(-1) != 2).any()


# Observation noise ---------------------------------------------------------------
def test_obs_noise_changes_exactly_the_patch():
    actions = _fixed_actions()
    clean = _rollout(_base(), actions)
    noisy = _rollout(_env(StochasticityTransform(obs_noise=1.0, seed=0)), actions)
    patch = _patch_mask()
    for key in ("image", ("next", "image")):
        a, b = clean[key], noisy[key]  # [B, T, 7, 7, 3]
        # Outside the patch nothing changes, at step and at reset alike.
        assert torch.equal(a[..., ~patch, :], b[..., ~patch, :])
        # Inside it, every observation differs somewhere (27 random ids).
        changed = (a[..., patch, :] != b[..., patch, :]).flatten(-2).any(-1)
        assert changed.all()
        values = b[..., patch, :]
        assert values[..., 0].max() < 10 and values[..., 1].max() < 6
        assert values[..., 2].max() < 3
    # Dynamics untouched: same rewards and done flags.
    assert torch.equal(clean["next", "done"], noisy["next", "done"])
    assert torch.equal(clean["next", "direction"], noisy["next", "direction"])


def test_obs_noise_zero_never_changes_images():
    actions = _fixed_actions()
    clean = _rollout(_base(), actions)
    noisy = _rollout(
        _env(StochasticityTransform(action_noise=0.0, obs_noise=0.0, seed=0)), actions
    )
    assert torch.equal(clean["image"], noisy["image"])
    assert torch.equal(clean["next", "image"], noisy["next", "image"])


def test_obs_noise_rate_and_custom_patch():
    patch = [(5, 0), (6, 0)]
    transform = StochasticityTransform(obs_noise=0.3, patch=patch, seed=0)
    image = torch.ones(5000, 7, 7, 3, dtype=torch.uint8)
    out = transform(TensorDict(image=image.clone(), batch_size=[5000]))["image"]
    mask = _patch_mask(patch)
    assert torch.equal(out[:, ~mask], image[:, ~mask])
    shown = (out[:, mask] != 1).flatten(1).any(1).float().mean()
    assert 0.25 < shown < 0.35  # ~0.3, minus the rare draws equal to the image


def test_specs_unchanged_and_check_env_specs():
    base = _base()
    env = _env(StochasticityTransform.from_level(3, seed=0))
    check_env_specs(env)
    assert env.full_observation_spec == base.full_observation_spec
    assert env.full_action_spec == base.full_action_spec
    assert env.full_reward_spec == base.full_reward_spec
    assert env.full_done_spec == base.full_done_spec


# Reproducibility -----------------------------------------------------------------
def test_same_seed_same_noise():
    actions = _fixed_actions()

    def run(seed):
        return _rollout(_env(StochasticityTransform.from_level(3, seed=seed)), actions)

    first, second, other = run(1), run(1), run(2)
    assert (first == second).all()
    assert not torch.equal(first["next", "image"], other["next", "image"])


def test_set_seed_and_global_seed():
    transform = StochasticityTransform(0.5, 0.5, num_actions=7, seed=0)
    td = TensorDict(
        image=torch.zeros(64, 7, 7, 3, dtype=torch.uint8),
        action=torch.zeros(64, dtype=torch.long),
        batch_size=[64],
    )

    def draw():
        return transform(td.clone())["image"], transform.inv(td)["action"]

    transform.set_seed(5)
    first = draw()
    transform.set_seed(5)
    second = draw()
    assert all(torch.equal(a, b) for a, b in zip(first, second))
    # seed=None draws the seed from torch's global RNG.
    torch.manual_seed(0)
    a = StochasticityTransform(0.5, 0.5, num_actions=7)
    torch.manual_seed(0)
    b = StochasticityTransform(0.5, 0.5, num_actions=7)
    assert a.seed == b.seed
    # clone() keeps the generator state but not the object.
    c = a.clone()
    assert c._generator is not a._generator
    assert torch.equal(c._generator.get_state(), a._generator.get_state())


# Validation ----------------------------------------------------------------------
@pytest.mark.parametrize(
    "kwargs,error",
    [
        ({"action_noise": -0.1}, ValueError),
        ({"action_noise": 1.5}, ValueError),
        ({"obs_noise": 2}, ValueError),
        ({"obs_noise": "0.1"}, TypeError),
        ({"action_noise": True}, TypeError),
        ({"patch": [(7, 0)]}, ValueError),
        ({"patch": [(0, -1)]}, ValueError),
        ({"patch": []}, ValueError),
        ({"patch": [(0, 0, 0)]}, ValueError),
        ({"patch": [(0, 0), (0, 0)]}, ValueError),
        ({"patch": [(4, 4)], "view_size": 3}, ValueError),
        ({"num_actions": 0}, ValueError),
    ],
)
def test_invalid_arguments(kwargs, error):
    with pytest.raises(error):
        StochasticityTransform(**kwargs)


def test_invalid_use():
    with pytest.raises(ValueError, match="Unknown stochasticity level"):
        StochasticityTransform.from_level(4)
    with pytest.raises(ValueError, match="Unknown stochasticity level"):
        StochasticityTransform.from_level("extreme")
    transform = StochasticityTransform(0.5, 0.5)
    with pytest.raises(ValueError, match="action_noise"):
        transform.action_noise = 1.1
    with pytest.raises(RuntimeError, match="num_actions"):
        transform.inv(
            TensorDict(action=torch.zeros(3, dtype=torch.long), batch_size=[3])
        )
    small = TensorDict(image=torch.zeros(2, 3, 3, 3, dtype=torch.uint8), batch_size=[2])
    with pytest.raises(ValueError, match="does not fit"):
        StochasticityTransform(obs_noise=1.0, patch=[(5, 5)])(small)
    mujoco = make_mujoco_env("HalfCheetah-v5").append_transform(
        StochasticityTransform(action_noise=0.5)
    )
    with pytest.raises(TypeError, match="discrete action"):
        mujoco.rand_step(mujoco.reset())
    mujoco.close()


# TorchRL's transform contract -------------------------------------------------------
def test_any_batch_shape_serial_env():
    serial = SerialEnv(2, lambda: _base(num_envs=3))
    env = TransformedEnv(serial, StochasticityTransform(0.5, 0.5, seed=0))
    check_env_specs(env)
    td = env.rollout(STEPS, break_when_any_done=False)
    assert td.batch_size == (2, 3, STEPS)
    env.close()


def test_inside_serial_env_workers():
    env = SerialEnv(2, _parallel_factory)
    check_env_specs(env)
    assert env.rollout(5).batch_size == (2, 2, 5)
    env.close()


@pytest.mark.slow
def test_inside_parallel_env_workers():
    env = ParallelEnv(2, _parallel_factory)
    try:
        check_env_specs(env)
        assert env.rollout(5).batch_size == (2, 2, 5)
    finally:
        env.close()


def test_compose_and_sequential():
    env = _base().append_transform(
        Compose(StochasticityTransform(0.5, 0.5, seed=0), StochasticityTransform(0.1))
    )
    check_env_specs(env)
    env.close()
    image = torch.zeros(2, 3, 7, 7, 3, dtype=torch.uint8)
    td = TensorDict(image=image, batch_size=[2, 3])
    module = nn.Sequential(StochasticityTransform(obs_noise=1.0, seed=0), nn.Identity())
    out = module(td.clone())
    assert out["image"].shape == image.shape
    assert (out["image"][..., _patch_mask(), :] != 0).any()


@pytest.mark.parametrize("rb_cls", [ReplayBuffer, TensorDictReplayBuffer])
def test_replay_buffer(rb_cls):
    rb = rb_cls(storage=LazyTensorStorage(16), batch_size=8)
    rb.append_transform(StochasticityTransform(obs_noise=1.0, seed=0))
    data = TensorDict(
        image=torch.zeros(16, 7, 7, 3, dtype=torch.uint8),
        action=torch.zeros(16, dtype=torch.long),
        batch_size=[16],
    )
    rb.extend(data)
    sample = rb.sample()
    assert sample["image"].shape == (8, 7, 7, 3)
    assert (sample["image"][:, _patch_mask()] != 0).any()
    assert (sample["image"][:, ~_patch_mask()] == 0).all()
