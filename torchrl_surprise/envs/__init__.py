"""Environment factories: MiniGrid (with the paper's MultiRoom tasks) and MuJoCo.

Importing this package registers ``MiniGrid-MultiRoom-N3-S4-v0`` and
``MiniGrid-MultiRoom-N4-S4-v0`` with gymnasium.
"""

from torchrl_surprise.envs.minigrid import (
    MINIGRID_OBS_KEYS,
    MULTIROOM_N3_S4,
    MULTIROOM_N4_S4,
    PAPER_MULTIROOM_IDS,
    make_minigrid_env,
    register_minigrid_envs,
)
from torchrl_surprise.envs.mujoco import PAPER_MUJOCO_IDS, make_mujoco_env

register_minigrid_envs()

__all__ = [
    "MINIGRID_OBS_KEYS",
    "MULTIROOM_N3_S4",
    "MULTIROOM_N4_S4",
    "PAPER_MUJOCO_IDS",
    "PAPER_MULTIROOM_IDS",
    "make_minigrid_env",
    "make_mujoco_env",
    "register_minigrid_envs",
]
