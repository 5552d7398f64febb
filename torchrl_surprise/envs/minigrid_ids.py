"""The MiniGrid ids of the paper's tasks, registered with gymnasium on request.

Kept apart from the env factories (:mod:`torchrl_surprise.envs.minigrid`,
:mod:`torchrl_surprise.envs.envpool`), which both read it: it needs gymnasium and
minigrid only, and importing it registers nothing.
"""

from __future__ import annotations

import difflib

import gymnasium as gym

__all__ = [
    "UnknownMiniGridTask",
    "MULTIROOM_N3_S4",
    "MULTIROOM_N4_S4",
    "PAPER_MULTIROOM_IDS",
    "check_minigrid_id",
    "register_minigrid_envs",
]


class UnknownMiniGridTask(ValueError):
    """An env id the MiniGrid backend asked for does not have (the message names
    the closest ones)."""


MULTIROOM_N3_S4 = "MiniGrid-MultiRoom-N3-S4-v0"
"""MultiRoom with exactly 3 rooms of size at most 4 (max_steps 60)."""

MULTIROOM_N4_S4 = "MiniGrid-MultiRoom-N4-S4-v0"
"""MultiRoom with exactly 4 rooms of size at most 4 (max_steps 80)."""

PAPER_MULTIROOM_IDS: dict[str, int] = {MULTIROOM_N3_S4: 3, MULTIROOM_N4_S4: 4}
"""The paper's MultiRoom ids, mapped to their number of rooms."""

_MAX_ROOM_SIZE = 4
_STEPS_PER_ROOM = 20  # minigrid's own default for MultiRoomEnv: max_steps = 20 * rooms


def register_minigrid_envs() -> list[str]:
    """Registers the paper's MultiRoom tasks with gymnasium, once.

    ``MiniGrid-MultiRoom-N{n}-S4-v0`` is ``minigrid.envs.MultiRoomEnv`` with
    ``minNumRooms=maxNumRooms=n``, ``maxRoomSize=4`` and ``max_steps=20 * n``, for
    n in (3, 4). Calling this again is a no-op: ids already in the registry are left
    alone.

    Returns:
        The registered ids (whether registered by this call or before).

    Examples:
        >>> import gymnasium as gym
        >>> from torchrl_surprise.envs import register_minigrid_envs
        >>> register_minigrid_envs()
        ['MiniGrid-MultiRoom-N3-S4-v0', 'MiniGrid-MultiRoom-N4-S4-v0']
        >>> gym.spec("MiniGrid-MultiRoom-N3-S4-v0").kwargs["max_steps"]
        60
    """
    import minigrid  # noqa: F401  (registers minigrid's own MiniGrid-* ids)

    for env_id, num_rooms in PAPER_MULTIROOM_IDS.items():
        if env_id in gym.registry:
            continue
        gym.register(
            id=env_id,
            entry_point="minigrid.envs:MultiRoomEnv",
            kwargs={
                "minNumRooms": num_rooms,
                "maxNumRooms": num_rooms,
                "maxRoomSize": _MAX_ROOM_SIZE,
                "max_steps": _STEPS_PER_ROOM * num_rooms,
            },
        )
    return list(PAPER_MULTIROOM_IDS)


def known_minigrid_ids() -> list[str]:
    return sorted(
        env_id
        for env_id in gym.registry
        if env_id.startswith("MiniGrid-") or env_id.startswith("BabyAI-")
    )


def check_minigrid_id(env_name: str) -> None:
    if env_name in gym.registry:
        return
    known = known_minigrid_ids()
    close = difflib.get_close_matches(env_name, known, n=5, cutoff=0.6)
    suggestions = close if close else known[:5]
    raise UnknownMiniGridTask(
        f"Unknown MiniGrid environment id {env_name!r}. "
        f"{'Did you mean' if close else 'Known ids include'}: "
        f"{', '.join(suggestions)} ({len(known)} MiniGrid/BabyAI ids are registered)."
    )
