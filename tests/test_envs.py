"""Integration tests of the env factories on real MiniGrid and MuJoCo envs."""

from __future__ import annotations

import functools
import pickle
import subprocess
import sys

import gymnasium as gym
import pytest
import torch
from gymnasium.wrappers import FilterObservation
from minigrid.envs import MultiRoomEnv
from tensordict import TensorDictBase
from torchrl.collectors import Collector
from torchrl.envs import SerialEnv
from torchrl.envs.utils import check_env_specs

from torchrl_surprise.envs import (
    MULTIROOM_N3_S4,
    MULTIROOM_N4_S4,
    PAPER_MULTIROOM_IDS,
    make_minigrid_env,
    make_mujoco_env,
    register_minigrid_envs,
)

N3S4_MAX_STEPS = 60


def _fixed_actions(num_envs: int, steps: int, n: int = 7, seed: int = 0):
    gen = torch.Generator().manual_seed(seed)
    return torch.randint(n, (steps, num_envs), generator=gen)


def _replay_policy(actions: torch.Tensor):
    """A policy that plays a fixed [T, B] action sequence (one row per call)."""
    step = iter(range(actions.shape[0]))

    def policy(td: TensorDictBase) -> TensorDictBase:
        return td.set("action", actions[next(step)].clone())

    return policy


# Registration ------------------------------------------------------------------
@pytest.mark.parametrize("env_id,num_rooms", sorted(PAPER_MULTIROOM_IDS.items()))
def test_paper_multiroom_registered(env_id, num_rooms):
    assert env_id in register_minigrid_envs()
    assert env_id in gym.registry
    env = gym.make(env_id)
    inner = env.unwrapped
    assert isinstance(inner, MultiRoomEnv)
    assert inner.minNumRooms == inner.maxNumRooms == num_rooms
    assert inner.maxRoomSize == 4
    assert inner.max_steps == 20 * num_rooms
    for seed in range(3):
        env.reset(seed=seed)
        assert len(inner.rooms) == num_rooms
        # Room sizes include their walls, as in minigrid's maxRoomSize.
        assert all(max(room.size) <= 4 for room in inner.rooms)
    env.close()


def test_registration_is_idempotent():
    register_minigrid_envs()
    before = gym.registry[MULTIROOM_N3_S4]
    assert register_minigrid_envs() == [MULTIROOM_N3_S4, MULTIROOM_N4_S4]
    assert register_minigrid_envs() == [MULTIROOM_N3_S4, MULTIROOM_N4_S4]
    assert gym.registry[MULTIROOM_N3_S4] is before


def test_factory_unpickles_in_fresh_process():
    # What a spawned worker does: unpickle the factory (importing this package,
    # which registers the ids) and build the env.
    factory = functools.partial(make_minigrid_env, MULTIROOM_N4_S4, num_envs=2, seed=0)
    code = (
        "import pickle, sys\n"
        "env = pickle.loads(sys.stdin.buffer.read())()\n"
        "print(tuple(env.reset()['image'].shape))\n"
    )
    out = subprocess.run(
        [sys.executable, "-c", code],
        input=pickle.dumps(factory),
        capture_output=True,
        timeout=120,
        check=True,
    )
    assert out.stdout.decode().strip().splitlines()[-1] == "(2, 7, 7, 3)"


# make_minigrid_env ---------------------------------------------------------------
@pytest.mark.parametrize("categorical", [True, False])
def test_minigrid_specs(categorical):
    env = make_minigrid_env(
        MULTIROOM_N3_S4, num_envs=3, seed=0, categorical_action_encoding=categorical
    )
    check_env_specs(env)
    assert env.batch_size == torch.Size([3])
    assert set(env.observation_spec.keys()) == {"image", "direction"}
    td = env.rand_step(env.reset())
    assert td["image"].shape == (3, 7, 7, 3) and td["image"].dtype == torch.uint8
    assert td["direction"].shape == (3,) and not td["direction"].is_floating_point()
    assert td["next", "reward"].shape == (3, 1)
    for key in ("done", "terminated", "truncated"):
        assert td["next", key].shape == (3, 1) and td["next", key].dtype == torch.bool
    if categorical:
        assert td["action"].shape == (3,)
    else:
        assert td["action"].shape == (3, 7) and (td["action"].sum(-1) == 1).all()
    env.close()


@pytest.mark.parametrize(
    "env_id,num_actions",
    [
        (MULTIROOM_N3_S4, 7),  # all envs truncate together at 60 steps
        ("MiniGrid-Empty-5x5-v0", 3),  # goals reached at different steps
    ],
)
def test_minigrid_rollout_matches_gymnasium_across_resets(env_id, num_actions):
    """Each sub-env equals a plain gymnasium env seeded ``seed + i``, episode ends included."""
    num_envs, steps, seed = 3, 2 * N3S4_MAX_STEPS + 10, 5
    actions = _fixed_actions(num_envs, steps, n=num_actions)
    env = make_minigrid_env(env_id, num_envs=num_envs, seed=seed)
    td = env.rollout(steps, policy=_replay_policy(actions), break_when_any_done=False)
    env.close()
    assert td.batch_size == (num_envs, steps)
    done = td["next", "done"].squeeze(-1)
    assert done.any(1).all()  # every env crossed an episode end
    if num_actions == 3:  # some env reset while others did not
        assert (done.any(0) & ~done.all(0)).any()

    for i in range(num_envs):
        raw = FilterObservation(gym.make(env_id), ["image", "direction"])
        raw.reset(seed=seed + i)
        obs, _ = raw.reset()  # rollout() resets once more, without a seed
        for t in range(steps):
            assert torch.equal(td["image"][i, t], torch.as_tensor(obs["image"]))
            obs_next, reward, terminated, truncated, _ = raw.step(int(actions[t, i]))
            nxt = td["next"][i, t]
            assert torch.equal(nxt["image"], torch.as_tensor(obs_next["image"]))
            assert int(nxt["direction"]) == obs_next["direction"]
            assert float(nxt["reward"]) == pytest.approx(reward)
            assert bool(nxt["terminated"]) == terminated
            assert bool(nxt["truncated"]) == truncated
            assert bool(nxt["done"]) == (terminated or truncated)
            obs = raw.reset()[0] if terminated or truncated else obs_next
        raw.close()


def test_minigrid_inside_serial_env():
    factory = functools.partial(
        make_minigrid_env, "MiniGrid-Empty-5x5-v0", num_envs=3, seed=0
    )
    env = SerialEnv(2, factory)
    check_env_specs(env)
    td = env.rollout(150, break_when_any_done=False)
    env.close()
    assert td.batch_size == (2, 3, 150)
    assert td["next", "done"].shape == (2, 3, 150, 1)
    assert td["next", "done"].any()


def test_minigrid_truncates_at_max_steps():
    env = make_minigrid_env(MULTIROOM_N3_S4, num_envs=2, seed=1)
    # Turning left forever never ends an episode early.
    td = env.rollout(
        2 * N3S4_MAX_STEPS,
        policy=lambda td: td.set("action", torch.zeros(2, dtype=torch.long)),
        break_when_any_done=False,
    )
    env.close()
    truncated = td["next", "truncated"].squeeze(-1)
    expected = torch.zeros_like(truncated)
    expected[:, N3S4_MAX_STEPS - 1 :: N3S4_MAX_STEPS] = True
    assert torch.equal(truncated, expected)
    assert not td["next", "terminated"].any()


def test_minigrid_same_seed_same_observations():
    actions = _fixed_actions(4, 70, seed=3)

    def run(seed):
        env = make_minigrid_env(MULTIROOM_N3_S4, num_envs=4, seed=seed)
        td = env.rollout(70, policy=_replay_policy(actions), break_when_any_done=False)
        env.close()
        return td

    first, second, other = run(11), run(11), run(12)
    assert torch.equal(first["image"], second["image"])
    assert torch.equal(first["next", "image"], second["next", "image"])
    assert torch.equal(first["next", "done"], second["next", "done"])
    assert not torch.equal(first["image"], other["image"])


def test_minigrid_set_seed_resets_deterministically():
    env = make_minigrid_env("MiniGrid-DoorKey-8x8-v0", num_envs=2)
    env.set_seed(7)
    first = env.reset()["image"].clone()
    env.set_seed(7)
    assert torch.equal(env.reset()["image"], first)
    env.close()


def test_minigrid_env_kwargs():
    env = make_minigrid_env(
        MULTIROOM_N3_S4, num_envs=2, seed=0, env_kwargs={"max_steps": 5}
    )
    td = env.rollout(
        5,
        policy=lambda td: td.set("action", torch.zeros(2, dtype=torch.long)),
        break_when_any_done=False,
    )
    env.close()
    assert td["next", "truncated"][:, -1].all() and not td["next", "done"][:, :-1].any()


def test_minigrid_unknown_id():
    with pytest.raises(ValueError, match="MiniGrid-MultiRom-N3-S4-v0") as err:
        make_minigrid_env("MiniGrid-MultiRom-N3-S4-v0", num_envs=1)
    assert MULTIROOM_N3_S4 in str(err.value)
    with pytest.raises(ValueError, match="Unknown MiniGrid environment id 'Nope-v0'"):
        make_minigrid_env("Nope-v0", num_envs=1)
    with pytest.raises(ValueError, match="not a MiniGrid env"):
        make_minigrid_env("CartPole-v1", num_envs=1)
    with pytest.raises(ValueError, match="num_envs"):
        make_minigrid_env(MULTIROOM_N3_S4, num_envs=0)


def test_minigrid_collector_random_policy():
    factory = functools.partial(make_minigrid_env, MULTIROOM_N3_S4, num_envs=4, seed=0)
    pickle.dumps(factory)  # worker processes need a picklable factory
    collector = Collector(factory, policy=None, frames_per_batch=128, total_frames=256)
    batches = list(collector)
    collector.shutdown()
    assert len(batches) == 2
    for batch in batches:
        assert batch.numel() == 128
        assert batch.batch_size == (4, 32)
        assert batch["image"].dtype == torch.uint8
        assert batch["action"].shape == (4, 32)
        assert ((batch["action"] >= 0) & (batch["action"] < 7)).all()
    done = torch.cat([b["next", "done"] for b in batches], 1).squeeze(-1)
    # 64 random steps per env, 60-step episodes: every env ended one, and the
    # collector's trajectory ids advanced there.
    assert done.any(1).all()
    traj_ids = torch.cat([b["collector", "traj_ids"] for b in batches], 1)
    assert (traj_ids[:, -1] > traj_ids[:, 0]).all()


# make_mujoco_env ----------------------------------------------------------------
def test_mujoco_single_env_specs():
    env = make_mujoco_env("HalfCheetah-v5", seed=0)
    check_env_specs(env)
    assert env.batch_size == torch.Size([])
    td = env.rollout(4)
    assert td["observation"].shape == (4, 17)
    assert td["observation"].dtype == torch.float32
    assert td["next", "observation"].dtype == torch.float32
    assert td["action"].shape == (4, 6)
    env.close()


def test_mujoco_vector_env_specs():
    env = make_mujoco_env("Hopper-v5", num_envs=3, seed=0)
    check_env_specs(env)
    single = make_mujoco_env("Hopper-v5")
    assert set(env.observation_spec.keys()) == set(single.observation_spec.keys())
    assert set(env.full_done_spec.keys()) == set(single.full_done_spec.keys())
    single.close()
    env.close()


def test_mujoco_vector_rollout_matches_gymnasium_across_resets():
    num_envs, steps, seed = 2, 120, 0
    actions = torch.rand(steps, num_envs, 3, generator=torch.Generator().manual_seed(0))
    actions = actions * 2 - 1
    env = make_mujoco_env("Hopper-v5", num_envs=num_envs, seed=seed)
    td = env.rollout(steps, policy=_replay_policy(actions), break_when_any_done=False)
    env.close()
    assert td.batch_size == (num_envs, steps)
    assert td["next", "observation"].dtype == torch.float32
    # Random actions make Hopper fall within a few dozen steps.
    assert td["next", "done"].any(1).all()
    for i in range(num_envs):
        raw = gym.make("Hopper-v5")
        raw.reset(seed=seed + i)
        obs, _ = raw.reset()
        for t in range(steps):
            torch.testing.assert_close(
                td["observation"][i, t], torch.as_tensor(obs, dtype=torch.float32)
            )
            obs_next, _, terminated, truncated, _ = raw.step(actions[t, i].numpy())
            torch.testing.assert_close(
                td["next", "observation"][i, t],
                torch.as_tensor(obs_next, dtype=torch.float32),
            )
            assert bool(td["next", "terminated"][i, t]) == terminated
            assert bool(td["next", "done"][i, t]) == (terminated or truncated)
            obs = raw.reset()[0] if terminated or truncated else obs_next
        raw.close()


def test_mujoco_same_seed_same_observations():
    def run(seed):
        env = make_mujoco_env("HalfCheetah-v5", num_envs=2, seed=seed)
        torch.manual_seed(0)
        td = env.rollout(10)
        env.close()
        return td["next", "observation"]

    assert torch.equal(run(3), run(3))
    assert not torch.equal(run(3), run(4))


def test_mujoco_unknown_id():
    with pytest.raises(ValueError, match="HalfCheeta-v5") as err:
        make_mujoco_env("HalfCheeta-v5")
    assert "HalfCheetah-v5" in str(err.value)
    with pytest.raises(ValueError, match="not a MuJoCo env"):
        make_mujoco_env("CartPole-v1")
    with pytest.raises(ValueError, match="num_envs"):
        make_mujoco_env("HalfCheetah-v5", num_envs=0)


def test_mujoco_not_installed_names_the_extra_that_installs_it(monkeypatch):
    # As without the [mujoco] extra: `import mujoco` fails, so gymnasium's MuJoCo
    # package raises its own DependencyNotInstalled when (re)imported.
    monkeypatch.setitem(sys.modules, "mujoco", None)
    for name in list(sys.modules):
        if name.startswith("gymnasium.envs.mujoco"):
            monkeypatch.delitem(sys.modules, name)
    with pytest.raises(ModuleNotFoundError) as err:
        make_mujoco_env("HalfCheetah-v5")
    assert 'pip install "torchrl_surprise[mujoco]"' in str(err.value)
    assert err.value.name == "mujoco"
