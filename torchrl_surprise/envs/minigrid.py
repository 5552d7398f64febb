"""MiniGrid environments for TorchRL: the paper's MultiRoom tasks and a fast factory.

Two things live here:

* :func:`register_minigrid_envs` registers the MultiRoom variants used by the paper
  that minigrid does not register itself (``MiniGrid-MultiRoom-N3-S4-v0`` and
  ``MiniGrid-MultiRoom-N4-S4-v0``). :func:`make_minigrid_env` calls it (so does a
  worker process that builds its env through it); call it yourself before
  ``gymnasium.make`` of those ids. Importing the package registers nothing.
* :func:`make_minigrid_env` builds a batch of MiniGrid envs as one in-process
  gymnasium ``SyncVectorEnv`` wrapped once by TorchRL's
  :class:`~torchrl.envs.GymWrapper`. On 2 cores this was the fastest TorchRL setup
  measured: 1.2-1.7x a ``SerialEnv`` of single envs, about 0.55x a raw gymnasium
  loop (see ``benchmarks/bench_envs.py``). The mission string is dropped:
  TorchRL has no spec conversion for minigrid's ``MissionSpace``, and the mission of
  the tasks used here is constant.

Why the vector env's auto-reset is ``DISABLED`` and not ``SAME_STEP``: with
``SAME_STEP``, TorchRL 0.14.1 reads the true last observation of an episode from
gymnasium's ``info["final_obs"]``, but for dict observation spaces (MiniGrid's) it
files the whole dict under ``"observation"`` and then looks up ``"image"`` and
``"direction"``, finds nothing and writes zeros: every ``("next", "image")`` at an
episode end was an all-zero image (checked against a plain gymnasium loop). With
``DISABLED``, TorchRL resets finished sub-envs itself through gymnasium's
``reset_mask`` option, the last observations are right, no per-step info parsing is
needed, and throughput was the same or better (1.0-1.3x per CPU second). As with
any TorchRL env, a sub-env must be reset after it is done (``env.rollout`` and the
collectors do it).
"""

from __future__ import annotations

import functools
from typing import Any

import gymnasium as gym
import torch
from gymnasium.wrappers import FilterObservation
from minigrid.minigrid_env import MiniGridEnv
from tensordict import NestedKey
from torchrl.data import Categorical, Composite, OneHot
from torchrl.envs import EnvBase, Transform

from torchrl_surprise.envs.minigrid_ids import (
    MULTIROOM_N3_S4,
    MULTIROOM_N4_S4,
    PAPER_MULTIROOM_IDS,
    check_minigrid_id,
    register_minigrid_envs,
)
from torchrl_surprise.envs.vector import VectorGymWrapper

__all__ = [
    "MINIGRID_BACKENDS",
    "MINIGRID_OBS_KEYS",
    "MULTIROOM_N3_S4",
    "MULTIROOM_N4_S4",
    "PAPER_MULTIROOM_IDS",
    "make_minigrid_env",
    "register_minigrid_envs",
]

MINIGRID_OBS_KEYS: tuple[str, ...] = ("image", "direction")
"""Observation entries kept from MiniGrid's dict observation (the mission is dropped)."""


def _make_single_minigrid(
    env_name: str, env_kwargs: dict[str, Any] | None = None
) -> gym.Env:
    """One MiniGrid env with the mission dropped (module-level, hence picklable)."""
    register_minigrid_envs()  # in a worker process too
    env = gym.make(env_name, **(env_kwargs or {}))
    if not isinstance(env.unwrapped, MiniGridEnv):
        env.close()
        raise ValueError(
            f"{env_name!r} is a registered gymnasium id but not a MiniGrid env "
            f"(got {type(env.unwrapped).__name__})."
        )
    return FilterObservation(env, list(MINIGRID_OBS_KEYS))


class _OneHotAction(Transform):
    """Exposes a categorical action as one-hot (the base env keeps integer actions).

    GymWrapper's ``categorical_action_encoding=False`` would also turn the
    ``direction`` observation (a ``Discrete`` space) into one-hot; so the base env
    always uses integer encoding and only the action is converted here.
    """

    def __init__(self, action_key: NestedKey = "action") -> None:
        super().__init__(in_keys_inv=[action_key], out_keys_inv=[action_key])
        self.action_key = action_key

    def _inv_apply_transform(self, action: torch.Tensor) -> torch.Tensor:
        return action.argmax(-1)

    def transform_action_spec(self, action_spec: Composite) -> Composite:
        spec = action_spec[self.action_key]
        if not isinstance(spec, Categorical):
            raise TypeError(f"Expected a Categorical action spec, got {spec}.")
        n = int(spec.space.n)
        action_spec[self.action_key] = OneHot(
            n, shape=(*spec.shape, n), device=spec.device, dtype=torch.long
        )
        return action_spec


MINIGRID_BACKENDS: tuple[str, ...] = ("gymnasium", "envpool")
"""The backends of :func:`make_minigrid_env`."""


def make_minigrid_env(
    env_name: str,
    num_envs: int = 16,
    seed: int | None = None,
    device: Any = "cpu",
    categorical_action_encoding: bool = True,
    env_kwargs: dict[str, Any] | None = None,
    backend: str = "gymnasium",
    num_threads: int = 1,
) -> EnvBase:
    """Builds ``num_envs`` MiniGrid envs as one batched TorchRL env.

    With ``backend="envpool"`` the envs are envpool's C++ MiniGrid
    (:class:`~torchrl_surprise.envs.envpool.EnvPoolMiniGridEnv`, ``pip install
    "torchrl_surprise[envpool]"``): the same entries, specs and batch semantics,
    several times the steps per CPU second (``benchmarks/bench_envpool.py``), but
    envpool's own layouts (the same seed gives the same layouts within a backend,
    not across them) and exact resume through a replay log rather than pickled
    envs. What is below describes the gymnasium backend, the default.

    The envs run in-process in a gymnasium ``SyncVectorEnv`` whose own auto-reset is
    disabled, wrapped once by TorchRL's ``GymWrapper``: TorchRL resets finished
    sub-envs (``env.rollout``, collectors), so the last observation of an episode is
    in ``("next", ...)`` and the first one of the next episode at the root after
    ``step_mdp``, as for any TorchRL env (see the module docstring for why not
    ``SAME_STEP``). The mission string is dropped.

    Output entries, with ``B = num_envs``:

    * ``"image"``: ``uint8`` ``[B, 7, 7, 3]``, the egocentric view as
      (object, colour, state) ids. ``image[b, x, y]`` is column ``x`` (left to
      right) and row ``y`` (far to near) of the view; the agent is at ``x=3, y=6``.
    * ``"direction"``: ``int64`` ``[B]`` in ``{0, 1, 2, 3}``.
    * ``"action"``: ``int64`` ``[B]`` (or one-hot ``[B, n]`` if
      ``categorical_action_encoding=False``); ``("next", "reward")`` float32
      ``[B, 1]``; ``done``, ``terminated``, ``truncated`` bool ``[B, 1]``.

    Args:
        env_name: any registered MiniGrid id, e.g. ``"MiniGrid-DoorKey-8x8-v0"`` or
            the paper's ``"MiniGrid-MultiRoom-N3-S4-v0"``.
        num_envs: number of envs stepped together (the env's batch size).
        seed: if given, ``env.set_seed(seed)`` is called: sub-env ``i`` is seeded
            with ``seed + i`` and later resets are deterministic.
        device: device of the output tensors.
        categorical_action_encoding: integer actions if ``True``, else one-hot.
        env_kwargs: extra keyword arguments for ``gymnasium.make`` (e.g.
            ``{"max_steps": 100}``), or for ``envpool.make`` with the envpool
            backend (e.g. ``{"max_episode_steps": 100}``).
        backend: ``"gymnasium"`` (minigrid's Python envs) or ``"envpool"``.
        num_threads: envpool's worker threads (envpool backend only).

    Returns:
        A TorchRL env with batch size ``[num_envs]``.

    Raises:
        ValueError: if ``env_name`` is not a registered MiniGrid id (the message
            lists close matches), ``num_envs < 1`` or ``backend`` is unknown.
        ModuleNotFoundError: ``backend="envpool"`` without envpool installed.

    Examples:
        >>> from torchrl_surprise.envs import make_minigrid_env
        >>> env = make_minigrid_env("MiniGrid-MultiRoom-N3-S4-v0", num_envs=4, seed=0)
        >>> env.batch_size
        torch.Size([4])
        >>> td = env.rollout(100, break_when_any_done=False)
        >>> td["image"].shape, td["image"].dtype
        (torch.Size([4, 100, 7, 7, 3]), torch.uint8)
        >>> bool(td["next", "truncated"].any())  # 60-step episodes were auto-reset
        True
        >>> env.close()
    """
    if backend not in MINIGRID_BACKENDS:
        raise ValueError(
            f"backend must be one of {MINIGRID_BACKENDS}, got {backend!r}."
        )
    if not isinstance(num_envs, int) or num_envs < 1:
        raise ValueError(f"num_envs must be a positive int, got {num_envs!r}.")
    if backend == "envpool":
        # Imported here: the envpool backend is an extra of its own.
        from torchrl_surprise.envs.envpool import EnvPoolMiniGridEnv

        env = EnvPoolMiniGridEnv(
            env_name,
            num_envs=num_envs,
            seed=seed,
            num_threads=num_threads,
            device=device,
            env_kwargs=env_kwargs,
        )
        if not categorical_action_encoding:
            env = env.append_transform(_OneHotAction())
        return env
    register_minigrid_envs()
    check_minigrid_id(env_name)
    env_fn = functools.partial(_make_single_minigrid, env_name, env_kwargs)
    vec_env = gym.vector.SyncVectorEnv(
        [env_fn] * num_envs, autoreset_mode=gym.vector.AutoresetMode.DISABLED
    )
    env = VectorGymWrapper(vec_env, device=device, categorical_action_encoding=True)
    if not categorical_action_encoding:
        env = env.append_transform(_OneHotAction())
    if seed is not None:
        env.set_seed(seed)
    return env
