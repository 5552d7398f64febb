"""Gymnasium MuJoCo environments for TorchRL, with float32 observations.

The paper's DDPG experiments used HalfCheetah, Hopper and Walker2d ``-v1`` (mujoco-py);
those ids are gone, so the ``-v5`` versions (official ``mujoco`` bindings) are used.
"""

from __future__ import annotations

import difflib
import functools
from typing import Any

import gymnasium as gym
from torchrl.envs import DoubleToFloat, EnvBase, TransformedEnv

from torchrl_surprise.envs.vector import SingleGymEnv, VectorGymWrapper

__all__ = ["PAPER_MUJOCO_IDS", "make_mujoco_env"]

PAPER_MUJOCO_IDS: tuple[str, ...] = ("HalfCheetah-v5", "Hopper-v5", "Walker2d-v5")
"""The paper's MuJoCo tasks (``-v1`` in the paper, ``-v5`` here)."""


def _mujoco_env_class() -> type:
    """Gymnasium's ``MujocoEnv``, or one error naming the extra that installs it.

    Gymnasium registers its MuJoCo ids without ``mujoco`` installed, and raises
    its own ``DependencyNotInstalled`` (not an ``ImportError``) on the first
    ``gym.make``; this module imports without ``mujoco`` and says what to install.
    """
    try:
        from gymnasium.envs.mujoco import MujocoEnv
    except (ImportError, gym.error.DependencyNotInstalled) as err:
        raise ModuleNotFoundError(
            "torchrl_surprise.envs.make_mujoco_env needs MuJoCo ('mujoco' and "
            "gymnasium's MuJoCo envs), which is not installed: "
            'pip install "torchrl_surprise[mujoco]".',
            name="mujoco",
        ) from err
    return MujocoEnv


def _known_mujoco_ids() -> list[str]:
    ids = []
    for env_id, spec in gym.registry.items():
        entry_point = spec.entry_point
        if isinstance(entry_point, str) and ".mujoco" in entry_point:
            ids.append(env_id)
    return sorted(ids)


def _check_mujoco_id(env_name: str) -> None:
    if env_name in gym.registry:
        return
    known = _known_mujoco_ids()
    close = difflib.get_close_matches(env_name, known, n=5, cutoff=0.6)
    suggestions = close if close else [i for i in known if i.endswith("-v5")][:8]
    raise ValueError(
        f"Unknown MuJoCo environment id {env_name!r}. "
        f"{'Did you mean' if close else 'Known ids include'}: {', '.join(suggestions)}."
    )


def _check_is_mujoco(env_name: str, env: gym.Env) -> None:
    if not isinstance(env.unwrapped, _mujoco_env_class()):
        raise ValueError(
            f"{env_name!r} is a registered gymnasium id but not a MuJoCo env "
            f"(got {type(env.unwrapped).__name__})."
        )


def _make_single_mujoco(env_name: str) -> gym.Env:
    """One headless MuJoCo env (module-level, hence picklable)."""
    env = gym.make(env_name)
    _check_is_mujoco(env_name, env)
    return env


def make_mujoco_env(
    env_name: str,
    num_envs: int = 1,
    seed: int | None = None,
    device: Any = "cpu",
) -> EnvBase:
    """Builds a gymnasium MuJoCo env for TorchRL with float32 observations.

    ``num_envs == 1`` gives a plain :class:`~torchrl.envs.GymEnv` (batch size
    ``[]``); ``num_envs > 1`` gives one in-process gymnasium ``SyncVectorEnv``
    wrapped by :class:`~torchrl.envs.GymWrapper` (batch size ``[num_envs]``), which
    was faster than a ``SerialEnv`` or ``ParallelEnv`` on 2 cores. The vector env's
    own auto-reset is disabled (``AutoresetMode.DISABLED``): TorchRL resets finished
    sub-envs through a reset mask, exactly as for its own batched envs, and both
    branches return the same entries (``SAME_STEP`` would add gymnasium's info
    entries, ``reward_ctrl``, ``x_position``, ..., to the vector env only). Both are
    followed by :class:`~torchrl.envs.DoubleToFloat`. No render mode is requested,
    so no OpenGL context is needed (headless).

    Args:
        env_name: any registered gymnasium MuJoCo id, e.g. ``"HalfCheetah-v5"``.
        num_envs: number of envs stepped together.
        seed: if given, ``env.set_seed(seed)`` is called (sub-env ``i`` of a vector
            env gets ``seed + i``).
        device: device of the output tensors.

    Returns:
        A TorchRL env whose ``"observation"`` entry is float32.

    Raises:
        ValueError: if ``env_name`` is not a registered MuJoCo id (the message lists
            close matches) or ``num_envs < 1``.
        ModuleNotFoundError: MuJoCo is not installed; the message gives the
            command that installs it, ``pip install "torchrl_surprise[mujoco]"``.

    Examples:
        >>> from torchrl_surprise.envs import make_mujoco_env
        >>> env = make_mujoco_env("HalfCheetah-v5", seed=0)
        >>> td = env.rollout(5)
        >>> td["next", "observation"].shape, td["next", "observation"].dtype
        (torch.Size([5, 17]), torch.float32)
        >>> env.close()
    """
    if not isinstance(num_envs, int) or num_envs < 1:
        raise ValueError(f"num_envs must be a positive int, got {num_envs!r}.")
    _mujoco_env_class()
    _check_mujoco_id(env_name)
    if num_envs == 1:
        base = SingleGymEnv(env_name, device=device)
        _check_is_mujoco(env_name, base.gym_env)
    else:
        env_fn = functools.partial(_make_single_mujoco, env_name)
        vec_env = gym.vector.SyncVectorEnv(
            [env_fn] * num_envs, autoreset_mode=gym.vector.AutoresetMode.DISABLED
        )
        base = VectorGymWrapper(vec_env, device=device)
    env = TransformedEnv(base, DoubleToFloat())
    if seed is not None:
        env.set_seed(seed)
    return env
