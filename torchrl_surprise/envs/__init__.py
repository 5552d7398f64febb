"""Environment factories, the MiniGrid oracle, and gymnasium wrappers whose runtime
state can be checkpointed.

Each env family is an extra, imported on first use of its names, so that
``import torchrl_surprise.envs`` needs neither minigrid nor mujoco:

* MiniGrid (``pip install "torchrl_surprise[minigrid]"``): :func:`make_minigrid_env`
  (the paper's ``MiniGrid-MultiRoom-N3-S4-v0`` and ``-N4-S4-v0`` included; it
  registers them with gymnasium, as :func:`register_minigrid_envs` does),
  the oracle :func:`solve_minigrid` and what is achievable under action noise,
  :func:`optimal_returns_under_action_noise`;
* MuJoCo (``pip install "torchrl_surprise[mujoco]"``): :func:`make_mujoco_env`.

Examples:
    >>> from torchrl_surprise.envs import PAPER_MUJOCO_IDS, make_minigrid_env
    >>> make_minigrid_env.__module__  # imported on this first use
    'torchrl_surprise.envs.minigrid'
    >>> PAPER_MUJOCO_IDS
    ('HalfCheetah-v5', 'Hopper-v5', 'Walker2d-v5')
"""

from __future__ import annotations

import importlib
from typing import Any

from torchrl_surprise.envs.vector import (
    RuntimeStateMixin,
    SingleGymEnv,
    VectorGymWrapper,
)

# name -> (module, the extra that installs what the module needs)
_LAZY = {
    "MINIGRID_OBS_KEYS": ("minigrid", "minigrid"),
    "MULTIROOM_N3_S4": ("minigrid_ids", "minigrid"),
    "MULTIROOM_N4_S4": ("minigrid_ids", "minigrid"),
    "PAPER_MULTIROOM_IDS": ("minigrid_ids", "minigrid"),
    "make_minigrid_env": ("minigrid", "minigrid"),
    "MINIGRID_BACKENDS": ("minigrid", "minigrid"),
    "EnvPoolMiniGridEnv": ("envpool", "envpool"),
    "minigrid_env_from_envpool_state": ("envpool", "envpool"),
    "envpool_minigrid_tasks": ("envpool", "envpool"),
    "envpool_minigrid_task": ("envpool", "envpool"),
    "barrier_seed": ("envpool", "envpool"),
    "ENVPOOL_PAPER_TASKS": ("envpool", "envpool"),
    "register_minigrid_envs": ("minigrid_ids", "minigrid"),
    "UnknownMiniGridTask": ("minigrid_ids", "minigrid"),
    "OracleSolution": ("oracle", "minigrid"),
    "oracle_returns": ("oracle", "minigrid"),
    "oracle_table": ("oracle", "minigrid"),
    "solve_minigrid": ("oracle", "minigrid"),
    "optimal_returns_under_action_noise": ("oracle", "minigrid"),
    "noisy_oracle_table": ("oracle", "minigrid"),
    "PAPER_MUJOCO_IDS": ("mujoco", "mujoco"),
    "make_mujoco_env": ("mujoco", "mujoco"),
}


def __getattr__(name: str) -> Any:
    if name not in _LAZY:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    module, extra = _LAZY[name]
    try:
        value = getattr(importlib.import_module(f"{__name__}.{module}"), name)
    except ModuleNotFoundError as err:
        raise ModuleNotFoundError(
            f"torchrl_surprise.envs.{name} needs {err.name!r}, which is not "
            f'installed: pip install "torchrl_surprise[{extra}]".',
            name=err.name,
        ) from err
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(__all__)


__all__ = [
    "ENVPOOL_PAPER_TASKS",
    "EnvPoolMiniGridEnv",
    "MINIGRID_BACKENDS",
    "MINIGRID_OBS_KEYS",
    "MULTIROOM_N3_S4",
    "MULTIROOM_N4_S4",
    "PAPER_MUJOCO_IDS",
    "PAPER_MULTIROOM_IDS",
    "OracleSolution",
    "RuntimeStateMixin",
    "SingleGymEnv",
    "VectorGymWrapper",
    "barrier_seed",
    "envpool_minigrid_task",
    "envpool_minigrid_tasks",
    "make_minigrid_env",
    "minigrid_env_from_envpool_state",
    "make_mujoco_env",
    "noisy_oracle_table",
    "optimal_returns_under_action_noise",
    "oracle_returns",
    "oracle_table",
    "register_minigrid_envs",
    "solve_minigrid",
    "UnknownMiniGridTask",
]
