"""Environment factories (MiniGrid with the paper's MultiRoom tasks, MuJoCo), the
MiniGrid oracle, and gymnasium wrappers whose runtime state can be checkpointed.

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
from torchrl_surprise.envs.oracle import (
    OracleSolution,
    oracle_returns,
    oracle_table,
    solve_minigrid,
)
from torchrl_surprise.envs.vector import (
    RuntimeStateMixin,
    SingleGymEnv,
    VectorGymWrapper,
)

register_minigrid_envs()

__all__ = [
    "MINIGRID_OBS_KEYS",
    "MULTIROOM_N3_S4",
    "MULTIROOM_N4_S4",
    "PAPER_MUJOCO_IDS",
    "PAPER_MULTIROOM_IDS",
    "OracleSolution",
    "RuntimeStateMixin",
    "SingleGymEnv",
    "VectorGymWrapper",
    "make_minigrid_env",
    "make_mujoco_env",
    "oracle_returns",
    "oracle_table",
    "register_minigrid_envs",
    "solve_minigrid",
]
