"""A MiniGrid oracle: the shortest action sequence that solves an episode.

:func:`solve_minigrid` reads the full state of a reset MiniGrid env (the layout, the
agent's position and direction, what it carries, the doors' states, where the keys
and balls are) and runs a breadth-first search over abstract states with MiniGrid's
own action semantics (minigrid 3.2.0, ``MiniGridEnv.step``): the first goal reached
is reached by a shortest sequence, and its return is MiniGrid's
``1 - 0.9 * (step_count / max_steps)``, or 0 when no sequence of at most
``max_steps`` actions reaches a goal. The oracle sees the whole grid; the agent sees
a 7x7 egocentric view, so the agent's best achievable return is lower.

:func:`oracle_returns` solves an env id for a list of seeds, :func:`oracle_table`
summarises several ids (one row each, the columns of :data:`ORACLE_CSV_COLUMNS`),
and the command line writes that table as a CSV::

    python -m torchrl_surprise.envs.oracle \\
        --envs MiniGrid-MultiRoom-N3-S4-v0 MiniGrid-DoorKey-5x5-v0 --seeds 1000 \\
        --out docs/results/oracle/oracle_returns.csv

Layouts may hold walls, floors, doors (open, closed or locked), keys, balls, goals
and lava. Anything else (a box, whose toggle replaces it by its contents, or a
subclass with its own semantics) and envs that override ``step`` or ``_reward``
(Fetch, Unlock, DynamicObstacles, ...) are refused rather than solved wrongly.
"""

from __future__ import annotations

import argparse
import csv
import statistics
import sys
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import gymnasium as gym
from minigrid.core.actions import Actions
from minigrid.core.constants import DIR_TO_VEC
from minigrid.core.world_object import Ball, Door, Floor, Goal, Key, Lava, Wall
from minigrid.minigrid_env import MiniGridEnv

from torchrl_surprise.envs.minigrid import register_minigrid_envs

__all__ = [
    "ORACLE_CSV_COLUMNS",
    "OracleSolution",
    "format_oracle_table",
    "oracle_returns",
    "oracle_table",
    "return_to_steps",
    "solve_minigrid",
    "write_oracle_csv",
]

ORACLE_CSV_COLUMNS: tuple[str, ...] = (
    "env",
    "seeds",
    "mean_return",
    "std_return",
    "mean_steps",
    "min_steps",
    "max_steps",
    "max_episode_steps",
    "solved_fraction",
    "return_at_0.8_steps",
)
"""Columns of :func:`oracle_table` rows and of the CSV the command line writes.

``mean_return`` and ``std_return`` are over all seeds (an unsolved seed counts as 0,
as MiniGrid scores a timeout; the std is the population std); ``mean_steps``,
``min_steps`` and ``max_steps`` are the oracle's episode lengths over the solved
seeds; ``max_episode_steps`` is MiniGrid's ``max_steps`` for the id;
``return_at_0.8_steps`` is the episode length whose return is 0.8.
"""

# Cell kinds of the static layout. Keys and balls are not cell kinds: they move, so
# they live in the dynamic state; the cell under them is EMPTY (MiniGrid stores one
# object per cell, so a key never sits on a floor, door or goal).
_EMPTY, _WALL, _FLOOR, _GOAL, _LAVA, _DOOR = range(6)
# Door state bits, as MiniGrid's two booleans: a door built open and locked is
# passable and still needs the key to be toggled.
_OPEN, _LOCKED = 1, 2
_CARRIED = -1  # object location of the carried object
_NOTHING = -1  # carried-object index when the hands are empty

_LEFT, _RIGHT, _FORWARD = int(Actions.left), int(Actions.right), int(Actions.forward)
_PICKUP, _DROP, _TOGGLE = int(Actions.pickup), int(Actions.drop), int(Actions.toggle)
_STATIC_KIND = {Wall: _WALL, Floor: _FLOOR, Goal: _GOAL, Lava: _LAVA}
_MOVABLE = (Key, Ball)


@dataclass(frozen=True)
class OracleSolution:
    """The shortest solution of one MiniGrid episode, as found by :func:`solve_minigrid`.

    Attributes:
        actions: a shortest action sequence (MiniGrid action ints: left=0, right=1,
            forward=2, pickup=3, drop=4, toggle=5) whose last action reaches a goal;
            empty when the episode cannot be solved.
        num_steps: ``len(actions)``, 0 when unsolved.
        solved: whether a goal can be reached before MiniGrid truncates the episode.
        episode_return: the return MiniGrid pays for playing ``actions``:
            ``1 - 0.9 * (step_count / max_steps)`` with ``step_count`` the env's step
            count at the goal, and 0 when unsolved.
        max_steps: MiniGrid's ``max_steps`` of the episode.
    """

    actions: tuple[int, ...]
    num_steps: int
    solved: bool
    episode_return: float
    max_steps: int


@dataclass(frozen=True)
class _Layout:
    """The static part of a grid plus the initial dynamic state, as flat arrays."""

    width: int
    kinds: tuple[int, ...]  # per cell, one of the _EMPTY..._DOOR kinds
    door_index: tuple[int, ...]  # per cell, index into the doors (-1 if no door)
    door_colors: tuple[str, ...]
    object_is_key: tuple[bool, ...]
    object_colors: tuple[str, ...]
    # Initial dynamic state: agent cell and direction, carried object, doors, objects.
    start: tuple[int, int, int, tuple[int, ...], tuple[int, ...]]


def _read_layout(env: MiniGridEnv) -> _Layout:
    grid = env.grid
    width, height = grid.width, grid.height
    kinds = [_EMPTY] * (width * height)
    door_index = [-1] * (width * height)
    door_colors: list[str] = []
    door_states: list[int] = []
    movable: list[tuple[Any, int]] = []  # (object, cell or _CARRIED)
    for cell, obj in enumerate(grid.grid):
        if obj is None:
            continue
        # Exact classes only: a subclass may change can_overlap / toggle / ... and
        # the search would then be wrong without failing.
        cls = type(obj)
        if cls in _STATIC_KIND:
            kinds[cell] = _STATIC_KIND[cls]
        elif cls is Door:
            kinds[cell] = _DOOR
            door_index[cell] = len(door_colors)
            door_colors.append(obj.color)
            door_states.append(_OPEN * obj.is_open | _LOCKED * obj.is_locked)
        elif cls in _MOVABLE:
            movable.append((obj, cell))
        else:
            raise ValueError(
                f"solve_minigrid supports walls, floors, doors, keys, balls, goals and "
                f"lava; found {cls.__name__} at {(cell % width, cell // width)}"
            )
    carrying = _NOTHING
    if env.carrying is not None:
        if type(env.carrying) not in _MOVABLE:
            raise ValueError(
                f"solve_minigrid: the agent carries an unsupported "
                f"{type(env.carrying).__name__}"
            )
        carrying = len(movable)
        movable.append((env.carrying, _CARRIED))
    x, y = (int(v) for v in env.agent_pos)
    start = (
        y * width + x,
        int(env.agent_dir),
        carrying,
        tuple(door_states),
        tuple(cell for _, cell in movable),
    )
    return _Layout(
        width=width,
        kinds=tuple(kinds),
        door_index=tuple(door_index),
        door_colors=tuple(door_colors),
        object_is_key=tuple(type(obj) is Key for obj, _ in movable),
        object_colors=tuple(obj.color for obj, _ in movable),
        start=start,
    )


def _front_cells(width: int, height: int) -> list[tuple[int, ...]]:
    """Per cell, the cell in front for each direction, or -1 outside the grid."""
    fronts = []
    for cell in range(width * height):
        x, y = cell % width, cell // width
        row = []
        for dx, dy in DIR_TO_VEC:
            fx, fy = x + int(dx), y + int(dy)
            inside = 0 <= fx < width and 0 <= fy < height
            row.append(fy * width + fx if inside else -1)
        fronts.append(tuple(row))
    return fronts


def _shortest_actions(layout: _Layout, horizon: int) -> tuple[int, ...] | None:
    """Breadth-first search; the actions of a shortest path to a goal, or None.

    Only actions that change the state are expanded (a blocked forward, a pickup
    with full hands, ``done``, ... are no-ops in MiniGrid and never shorten a path).
    """
    width = layout.width
    kinds, door_index = layout.kinds, layout.door_index
    door_colors = layout.door_colors
    object_is_key, object_colors = layout.object_is_key, layout.object_colors
    fronts = _front_cells(width, len(kinds) // width)

    start = layout.start
    parents: dict[tuple, tuple[tuple, int] | None] = {start: None}
    frontier = [start]
    for _ in range(horizon):
        next_frontier = []
        for state in frontier:
            pos, direction, carrying, doors, objects = state
            front = fronts[pos][direction]
            if front < 0:
                # MiniGrid's step() reads the front cell before any action, and
                # asserts on a cell outside the grid: every action fails here.
                continue
            successors = [
                (_LEFT, (pos, (direction - 1) % 4, carrying, doors, objects)),
                (_RIGHT, (pos, (direction + 1) % 4, carrying, doors, objects)),
            ]
            kind = kinds[front]
            occupied = front in objects
            if kind == _GOAL:
                return _trace(parents, state) + (_FORWARD,)
            if (
                kind == _FLOOR
                or (kind == _EMPTY and not occupied)
                or (kind == _DOOR and doors[door_index[front]] & _OPEN)
            ):
                successors.append(
                    (_FORWARD, (front, direction, carrying, doors, objects))
                )
            # Lava ends the episode with return 0: a dead end, never expanded.
            if occupied and carrying == _NOTHING:
                picked = objects.index(front)
                moved = objects[:picked] + (_CARRIED,) + objects[picked + 1 :]
                successors.append((_PICKUP, (pos, direction, picked, doors, moved)))
            if carrying != _NOTHING and kind == _EMPTY and not occupied:
                moved = objects[:carrying] + (front,) + objects[carrying + 1 :]
                successors.append((_DROP, (pos, direction, _NOTHING, doors, moved)))
            if kind == _DOOR:
                door = door_index[front]
                door_state = doors[door]
                if not door_state & _LOCKED:
                    door_state ^= _OPEN
                elif (
                    carrying != _NOTHING
                    and object_is_key[carrying]
                    and object_colors[carrying] == door_colors[door]
                ):
                    door_state = _OPEN
                if door_state != doors[door]:
                    toggled = doors[:door] + (door_state,) + doors[door + 1 :]
                    successors.append(
                        (_TOGGLE, (pos, direction, carrying, toggled, objects))
                    )
            for action, successor in successors:
                if successor not in parents:
                    parents[successor] = (state, action)
                    next_frontier.append(successor)
        if not next_frontier:
            return None
        frontier = next_frontier
    return None


def _trace(parents: dict[tuple, tuple[tuple, int] | None], state: tuple) -> tuple:
    actions = []
    link = parents[state]
    while link is not None:
        state, action = link
        actions.append(action)
        link = parents[state]
    return tuple(reversed(actions))


def _check_semantics(env: MiniGridEnv) -> None:
    cls = type(env)
    if cls.step is not MiniGridEnv.step or cls._reward is not MiniGridEnv._reward:
        raise ValueError(
            f"solve_minigrid: {cls.__name__} overrides MiniGridEnv.step or _reward; "
            "its task differs from 'reach the goal', and the oracle would be wrong"
        )


def solve_minigrid(env: gym.Env) -> OracleSolution:
    """Finds a shortest action sequence that reaches a goal, by breadth-first search.

    The search starts from the env's current state (normally right after
    ``reset(seed=...)``; mid-episode, the steps already taken count towards
    ``max_steps`` and the return, as they do in MiniGrid) and does not modify the
    env. States are (agent cell, direction, carried object, door states, key and
    ball positions); transitions are those of ``MiniGridEnv.step``. Reaching lava
    ends the episode with return 0, so lava cells are avoided.

    Args:
        env: a MiniGrid env, possibly wrapped (``gym.make`` output); its
            ``unwrapped`` env is read.

    Returns:
        The shortest solution, or an unsolved one (no actions, return 0) when no
        goal can be reached within the ``max_steps - step_count`` steps left.

    Raises:
        ValueError: the grid holds an object this search does not model (a box), or
            the env overrides ``step`` or ``_reward``.

    Examples:
        >>> import gymnasium as gym
        >>> env = gym.make("MiniGrid-DoorKey-5x5-v0")
        >>> _ = env.reset(seed=0)
        >>> solution = solve_minigrid(env)
        >>> solution.num_steps, solution.max_steps, solution.solved
        (11, 250, True)
        >>> solution.episode_return == 1 - 0.9 * (11 / 250)
        True
        >>> for action in solution.actions:
        ...     _, reward, terminated, truncated, _ = env.step(action)
        >>> terminated, reward == solution.episode_return
        (True, True)
    """
    base = env.unwrapped
    if not isinstance(base, MiniGridEnv):
        raise TypeError(f"solve_minigrid needs a MiniGridEnv, got {type(base)}")
    if base.grid is None or base.agent_pos is None:
        raise ValueError("solve_minigrid: reset the env first")
    _check_semantics(base)
    max_steps = int(base.max_steps)
    step_count = int(base.step_count)
    actions = _shortest_actions(_read_layout(base), max_steps - step_count)
    if actions is None:
        return OracleSolution((), 0, False, 0.0, max_steps)
    # The same expression as MiniGridEnv._reward, so the floats are equal.
    episode_return = 1 - 0.9 * ((step_count + len(actions)) / max_steps)
    return OracleSolution(actions, len(actions), True, episode_return, max_steps)


def oracle_returns(
    env_id: str, seeds: Iterable[int], **make_kwargs: Any
) -> list[OracleSolution]:
    """Solves ``gym.make(env_id)`` after ``reset(seed=s)`` for each seed.

    The paper's MultiRoom ids (``MiniGrid-MultiRoom-N3-S4-v0``, ...) are registered
    first, so any id of :mod:`torchrl_surprise.envs` works.

    Args:
        env_id: a gymnasium MiniGrid id.
        seeds: the ``reset`` seeds, one episode each.
        **make_kwargs: passed to ``gym.make``.

    Returns:
        One :class:`OracleSolution` per seed, in the order of ``seeds``.

    Examples:
        >>> solutions = oracle_returns("MiniGrid-DoorKey-5x5-v0", range(3))
        >>> [s.num_steps for s in solutions]
        [11, 7, 13]
    """
    register_minigrid_envs()
    env = gym.make(env_id, **make_kwargs)
    try:
        solutions = []
        for seed in seeds:
            env.reset(seed=int(seed))
            solutions.append(solve_minigrid(env))
        return solutions
    finally:
        env.close()


def return_to_steps(episode_return: float, max_steps: int) -> float:
    """The episode length at which MiniGrid pays ``episode_return``.

    Inverts ``return = 1 - 0.9 * steps / max_steps``; the result is fractional in
    general (a return of exactly 0.8 may not be reachable).

    Examples:
        >>> round(return_to_steps(0.8, 60), 2)  # MultiRoom-N3-S4
        13.33
        >>> round(return_to_steps(0.1, 60), 2)  # the last step before the timeout
        60.0
    """
    return (1 - episode_return) * max_steps / 0.9


def oracle_table(env_ids: Sequence[str], num_seeds: int) -> list[dict[str, Any]]:
    """One summary row per env id over seeds ``0 .. num_seeds - 1``.

    Args:
        env_ids: gymnasium MiniGrid ids.
        num_seeds: the number of seeds per id.

    Returns:
        Rows keyed by :data:`ORACLE_CSV_COLUMNS`.

    Examples:
        >>> (row,) = oracle_table(["MiniGrid-DoorKey-5x5-v0"], 3)
        >>> row["env"], row["seeds"], row["min_steps"], row["max_steps"]
        ('MiniGrid-DoorKey-5x5-v0', 3, 7, 13)
        >>> row["max_episode_steps"], round(row["return_at_0.8_steps"], 2)
        (250, 55.56)
    """
    rows = []
    for env_id in env_ids:
        solutions = oracle_returns(env_id, range(num_seeds))
        returns = [s.episode_return for s in solutions]
        steps = [s.num_steps for s in solutions if s.solved]
        # MultiRoom and DoorKey fix max_steps per id; a mix would make the
        # 0.8-return length meaningless.
        (max_episode_steps,) = {s.max_steps for s in solutions}
        rows.append(
            {
                "env": env_id,
                "seeds": num_seeds,
                "mean_return": statistics.fmean(returns),
                "std_return": statistics.pstdev(returns),
                "mean_steps": statistics.fmean(steps) if steps else float("nan"),
                "min_steps": min(steps, default=0),
                "max_steps": max(steps, default=0),
                "max_episode_steps": max_episode_steps,
                "solved_fraction": len(steps) / num_seeds,
                "return_at_0.8_steps": return_to_steps(0.8, max_episode_steps),
            }
        )
    return rows


def _format_value(value: Any) -> str:
    return f"{value:.4f}" if isinstance(value, float) else str(value)


def write_oracle_csv(rows: Sequence[dict[str, Any]], path: str | Path) -> Path:
    """Writes :func:`oracle_table` rows as a CSV (floats with 4 decimals).

    Returns:
        The path written (parent folders are created).

    Examples:
        >>> import tempfile
        >>> rows = oracle_table(["MiniGrid-DoorKey-5x5-v0"], 2)
        >>> with tempfile.TemporaryDirectory() as folder:
        ...     path = write_oracle_csv(rows, Path(folder) / "oracle.csv")
        ...     print(path.read_text().splitlines()[0])
        env,seeds,mean_return,std_return,mean_steps,min_steps,max_steps,max_episode_steps,solved_fraction,return_at_0.8_steps
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open("w", newline="") as file:
        writer = csv.DictWriter(file, fieldnames=ORACLE_CSV_COLUMNS)
        writer.writeheader()
        for row in rows:
            writer.writerow(
                {key: _format_value(row[key]) for key in ORACLE_CSV_COLUMNS}
            )
    return path


def format_oracle_table(rows: Sequence[dict[str, Any]]) -> str:
    """A fixed-width text table of :func:`oracle_table` rows, for a terminal.

    Examples:
        >>> rows = oracle_table(["MiniGrid-DoorKey-5x5-v0"], 2)
        >>> print(format_oracle_table(rows).splitlines()[0].split()[:3])
        ['env', 'seeds', 'mean_return']
    """
    cells = [list(ORACLE_CSV_COLUMNS)]
    cells += [[_format_value(row[key]) for key in ORACLE_CSV_COLUMNS] for row in rows]
    widths = [max(len(line[i]) for line in cells) for i in range(len(cells[0]))]
    lines = [
        "  ".join(
            text.ljust(width) if i == 0 else text.rjust(width)
            for i, (text, width) in enumerate(zip(line, widths))
        )
        for line in cells
    ]
    return "\n".join(lines)


def main(argv: Sequence[str] | None = None) -> list[dict[str, Any]]:
    """Command line: solve each id for seeds ``0 .. N-1``, print and write the table."""
    parser = argparse.ArgumentParser(
        prog="python -m torchrl_surprise.envs.oracle",
        description="Shortest-solution (oracle) returns of MiniGrid tasks.",
    )
    parser.add_argument("--envs", nargs="+", required=True, help="MiniGrid ids")
    parser.add_argument(
        "--seeds", type=int, default=1000, help="seeds 0..N-1 per id (default 1000)"
    )
    parser.add_argument("--out", type=Path, default=None, help="CSV path to write")
    args = parser.parse_args(argv)
    rows = oracle_table(args.envs, args.seeds)
    print(format_oracle_table(rows))
    if args.out is not None:
        print(f"wrote {write_oracle_csv(rows, args.out)}")
    return rows


if __name__ == "__main__":
    main(sys.argv[1:])
