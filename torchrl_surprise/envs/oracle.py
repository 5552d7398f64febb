"""A MiniGrid oracle: the shortest action sequence that solves an episode.

:func:`solve_minigrid` reads the full state of a reset MiniGrid env (the layout, the
agent's position and direction, what it carries, the doors' states, where the keys,
balls and boxes are and what the boxes hold) and runs an A* search over abstract
states with MiniGrid's own action semantics (minigrid 3.2.0, ``MiniGridEnv.step``):
the first success popped is reached by a shortest sequence (the search's lower bound
never overestimates, and it prunes only moves that no shortest sequence makes; see
:func:`solve_minigrid`), so the number of steps is optimal, not a bound. Its return is
MiniGrid's ``1 - 0.9 * (step_count / max_steps)``, or 0 when no sequence of at most
``max_steps`` actions succeeds. Success is reaching a goal (MultiRoom, DoorKey, ...)
or, in KeyCorridor and ObstructedMaze, a pickup that leaves the agent carrying the
task's object (``env.obj``). The oracle sees the whole grid; the agent sees a 7x7
egocentric view, so the agent's best achievable return is lower.

:func:`oracle_returns` solves an env id for a list of seeds, :func:`oracle_table`
summarises several ids (one row each, the columns of :data:`ORACLE_CSV_COLUMNS`);
the repository's ``recipes/results/oracle.py`` writes such tables as CSVs (the
committed ``docs/results/oracle/``).

Under action noise (an executed action replaced by a random one with probability
``p``, as :class:`~torchrl_surprise.transforms.StochasticityTransform` does) no
policy keeps the oracle's return; :func:`optimal_returns_under_action_noise` gives
the best expected return there, exactly, and :func:`noisy_oracle_table`
tabulates it.

Layouts may hold walls, floors, doors (open, closed or locked), keys, balls, boxes
(toggled, a box is replaced by what it holds), goals and lava. Anything else (a
subclass with its own semantics) and envs that override ``step`` or ``_reward`` in
another way (Fetch, Unlock, DynamicObstacles, ...) are refused rather than solved
wrongly. Over the hard-exploration suite (KeyCorridorS3R3/S4R3/S6R3,
DoorKey-16x16, MultiRoom-N6, ObstructedMaze-1Dlhb/2Dlhb) a layout takes from a
millisecond to about a second (``benchmarks/suite_oracle.py``).
"""

from __future__ import annotations

import copy
import heapq
import itertools
import statistics
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import Any

import gymnasium as gym
import numpy as np
from minigrid.core.actions import Actions
from minigrid.core.constants import DIR_TO_VEC
from minigrid.core.world_object import Ball, Box, Door, Floor, Goal, Key, Lava, Wall
from minigrid.envs.keycorridor import KeyCorridorEnv
from minigrid.envs.obstructedmaze import ObstructedMazeEnv
from minigrid.minigrid_env import MiniGridEnv

from torchrl_surprise.envs.minigrid_ids import register_minigrid_envs

__all__ = [
    "NOISY_ORACLE_CSV_COLUMNS",
    "ORACLE_CSV_COLUMNS",
    "OracleSolution",
    "oracle_returns",
    "oracle_row",
    "noisy_oracle_table",
    "optimal_returns_under_action_noise",
    "oracle_table",
    "return_to_steps",
    "solve_minigrid",
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

NOISY_ORACLE_CSV_COLUMNS: tuple[str, ...] = (
    "env",
    "action_noise",
    "seeds",
    "mean_return",
    "std_return",
    "noise_free_return",
    "fraction_of_noise_free",
)
"""Columns of :func:`noisy_oracle_table` rows and of the CSV the command line
writes with ``--action-noise``: ``env`` and ``mean_return`` are what
``recipes/results/aggregate.py --oracle`` reads (one ``p`` per file there)."""

# Cell kinds of the static layout. Keys, balls and boxes are not cell kinds: they move
# (and a toggled box vanishes), so they live in the dynamic state; the cell under them
# is EMPTY (MiniGrid stores one object per cell, so a key never sits on a door).
_EMPTY, _WALL, _FLOOR, _GOAL, _LAVA, _DOOR = range(6)
# Door state bits, as MiniGrid's two booleans: a door built open and locked is
# passable and still needs the key to be toggled.
_OPEN, _LOCKED = 1, 2
# Object locations that are not a cell: carried, inside a box, or gone (a toggled box).
_CARRIED, _IN_BOX, _GONE = -1, -2, -3
_NOTHING = -1  # carried-object index when the hands are empty (and "no object")
_KEY, _BALL, _BOX = range(3)

_LEFT, _RIGHT, _FORWARD = int(Actions.left), int(Actions.right), int(Actions.forward)
_PICKUP, _DROP, _TOGGLE = int(Actions.pickup), int(Actions.drop), int(Actions.toggle)
_STATIC_KIND = {Wall: _WALL, Floor: _FLOOR, Goal: _GOAL, Lava: _LAVA}
_MOVABLE = {Key: _KEY, Ball: _BALL, Box: _BOX}
# step() overrides that add one rule to MiniGridEnv.step: a pickup action that leaves
# the agent carrying ``env.obj`` ends the episode with ``_reward()``.
_PICKUP_TASK_STEPS = (KeyCorridorEnv.step, ObstructedMazeEnv.step)
_UNREACHABLE = 1 << 30
# Ends of an episode in optimal_returns_under_action_noise's transition table.
_NOISE_SUCCESS, _NOISE_FAILURE = -1, -2


@dataclass(frozen=True)
class OracleSolution:
    """The shortest solution of one MiniGrid episode, as found by :func:`solve_minigrid`.

    Attributes:
        actions: a shortest action sequence (MiniGrid action ints: left=0, right=1,
            forward=2, pickup=3, drop=4, toggle=5) whose last action ends the
            episode with success (reaching a goal, or picking up the task's object
            in KeyCorridor and ObstructedMaze); empty when the episode cannot be
            solved.
        num_steps: ``len(actions)``, 0 when unsolved.
        solved: whether the task can be solved before MiniGrid truncates the episode.
        episode_return: the return MiniGrid pays for playing ``actions``:
            ``1 - 0.9 * (step_count / max_steps)`` with ``step_count`` the env's step
            count at success, and 0 when unsolved.
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
    door_cells: tuple[int, ...]
    door_colors: tuple[str, ...]
    object_kinds: tuple[int, ...]  # per object, _KEY, _BALL or _BOX
    object_colors: tuple[str, ...]
    box_contents: tuple[int, ...]  # per object, the object inside it (or _NOTHING)
    target: int  # the object whose pickup ends the episode (or _NOTHING)
    # Initial dynamic state: agent cell and direction, carried object, doors,
    # objects' locations, and the object that may not be picked up next (_NOTHING).
    start: tuple[int, int, int, tuple[int, ...], tuple[int, ...], int]


def _read_layout(env: MiniGridEnv, target: Any) -> _Layout:
    grid = env.grid
    width = grid.width
    kinds = [_EMPTY] * (width * grid.height)
    door_index = [-1] * (width * grid.height)
    door_cells: list[int] = []
    door_colors: list[str] = []
    door_states: list[int] = []
    objects: list[Any] = []
    locations: list[int] = []
    contents: list[int] = []

    def add_object(obj: Any, location: int, where: str) -> int:
        # Exact classes only: a subclass may change can_pickup / toggle / ... and
        # the search would then be wrong without failing.
        if type(obj) not in _MOVABLE:
            raise ValueError(
                f"solve_minigrid supports walls, floors, doors, keys, balls, boxes, "
                f"goals and lava; found {type(obj).__name__} {where}"
            )
        index = len(objects)
        objects.append(obj)
        locations.append(location)
        contents.append(_NOTHING)
        if type(obj) is Box and obj.contains is not None:
            contents[index] = add_object(obj.contains, _IN_BOX, f"in a box {where}")
        return index

    for cell, obj in enumerate(grid.grid):
        if obj is None:
            continue
        cls = type(obj)
        if cls in _STATIC_KIND:
            kinds[cell] = _STATIC_KIND[cls]
        elif cls is Door:
            kinds[cell] = _DOOR
            door_index[cell] = len(door_colors)
            door_cells.append(cell)
            door_colors.append(obj.color)
            door_states.append(_OPEN * obj.is_open | _LOCKED * obj.is_locked)
        else:
            add_object(obj, cell, f"at {(cell % width, cell // width)}")
    carrying = _NOTHING
    if env.carrying is not None:
        carrying = add_object(env.carrying, _CARRIED, "in the agent's hands")
    target_index = _NOTHING
    if target is not None:
        found = [i for i, obj in enumerate(objects) if obj is target]
        if not found:
            raise ValueError(
                f"solve_minigrid: the object to pick up ({target.color} {target.type}, "
                "env.obj) is not in the grid"
            )
        (target_index,) = found
    x, y = (int(v) for v in env.agent_pos)
    start = (
        y * width + x,
        int(env.agent_dir),
        carrying,
        tuple(door_states),
        tuple(locations),
        _NOTHING,
    )
    return _Layout(
        width=width,
        kinds=tuple(kinds),
        door_index=tuple(door_index),
        door_cells=tuple(door_cells),
        door_colors=tuple(door_colors),
        object_kinds=tuple(_MOVABLE[type(obj)] for obj in objects),
        object_colors=tuple(obj.color for obj in objects),
        box_contents=tuple(contents),
        target=target_index,
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


class _LowerBound:
    """An admissible estimate of the steps left to success (A*'s heuristic).

    Distances are counted on a relaxed grid: every cell but walls and lava is
    passable (doors, objects and boxes included), so a distance in cells is at most
    the number of forwards the agent needs. While a locked, closed door separates
    the agent from its goal (or object), some such door must be unlocked, with a key
    of its colour: the agent goes next to the key (or the box hiding it), picks it
    up, goes next to the door, toggles it, then reaches the goal; each leg is
    bounded below by its relaxed distance.
    """

    def __init__(self, layout: _Layout, fronts: list[tuple[int, ...]]) -> None:
        self.layout = layout
        self.width = layout.width
        kinds = layout.kinds
        self.neighbours = [
            tuple(f for f in fronts[c] if f >= 0 and kinds[f] not in (_WALL, _LAVA))
            for c in range(len(kinds))
        ]
        self.goals = tuple(c for c, kind in enumerate(kinds) if kind == _GOAL)
        self._distances: dict[Any, list[int]] = {}
        self._regions: dict[tuple[int, ...], list[int]] = {}

    def distances(self, sources: Any) -> list[int]:
        """Relaxed distance in cells from each cell to the nearest of ``sources``."""
        cached = self._distances.get(sources)
        if cached is not None:
            return cached
        starts = (sources,) if isinstance(sources, int) else sources
        distance = [_UNREACHABLE] * len(self.neighbours)
        frontier = list(starts)
        for cell in frontier:
            distance[cell] = 0
        depth = 0
        while frontier:
            depth += 1
            next_frontier = []
            for cell in frontier:
                for other in self.neighbours[cell]:
                    if distance[other] == _UNREACHABLE:
                        distance[other] = depth
                        next_frontier.append(other)
            frontier = next_frontier
        self._distances[sources] = distance
        return distance

    def regions(self, doors: tuple[int, ...]) -> list[int]:
        """Connected components of the relaxed grid minus locked, closed doors."""
        cached = self._regions.get(doors)
        if cached is None:
            cells = self.layout.door_cells
            blocked = {cells[i] for i, state in enumerate(doors) if state == _LOCKED}
            cached = self._regions[doors] = self._components(blocked)
        return cached

    def _components(self, blocked: set[int]) -> list[int]:
        labels = [-1] * len(self.neighbours)
        for seed in range(len(labels)):
            if labels[seed] >= 0 or self.layout.kinds[seed] in (_WALL, _LAVA):
                continue
            labels[seed] = seed
            if seed in blocked:
                continue
            stack = [seed]
            while stack:
                cell = stack.pop()
                for other in self.neighbours[cell]:
                    if labels[other] < 0 and other not in blocked:
                        labels[other] = seed
                        stack.append(other)
        return labels

    def _finish_cells(self, objects: tuple[int, ...], pos: int) -> tuple[int, ...]:
        if self.layout.target == _NOTHING:
            return self.goals
        return (self._where(self.layout.target, objects, pos)[0],)

    def solvable(self, state: tuple) -> bool:
        """False when a locked door with no key of its colour anywhere (keys are
        never destroyed, boxes release theirs) separates the agent from its goal
        or object: the search would otherwise explore every state in vain."""
        pos, _, _, doors, objects, _ = state
        layout = self.layout
        key_colours = {
            colour
            for kind, colour in zip(layout.object_kinds, layout.object_colors)
            if kind == _KEY
        }
        blocked = {
            layout.door_cells[i]
            for i, door_state in enumerate(doors)
            if door_state == _LOCKED and layout.door_colors[i] not in key_colours
        }
        labels = self._components(blocked)
        return any(
            labels[cell] == labels[pos] for cell in self._finish_cells(objects, pos)
        )

    def _where(
        self, index: int, objects: tuple[int, ...], pos: int
    ) -> tuple[int, int, bool]:
        """(cell, boxes, carried): the cell of an object or of the outermost box
        around it (the agent's cell if that box is carried), how many boxes must be
        toggled to free it, and whether the agent carries it (inside its boxes)."""
        contents = self.layout.box_contents
        boxes = 0
        while objects[index] == _IN_BOX:
            index = contents.index(index)
            boxes += 1
        if objects[index] == _CARRIED:
            return pos, boxes, True
        return objects[index], boxes, False

    def _aligned(self, pos: int, direction: int, cells: tuple[int, ...]) -> bool:
        """Whether one of ``cells`` lies straight ahead (else a turn is needed)."""
        x, y = pos % self.width, pos // self.width
        dx, dy = (int(v) for v in DIR_TO_VEC[direction])
        for cell in cells:
            cx, cy = cell % self.width, cell // self.width
            if (dx and cy == y and (cx - x) * dx > 0) or (
                dy and cx == x and (cy - y) * dy > 0
            ):
                return True
        return False

    def __call__(self, state: tuple) -> int:
        pos, direction, carrying, doors, objects, _ = state
        layout = self.layout
        target = layout.target
        if target == _NOTHING:
            if not self.goals:
                return _UNREACHABLE
            finish_cells, finish = self.goals, self.distances(self.goals)
            cost = finish[pos] + (not self._aligned(pos, direction, self.goals))
            after_door_drop = 0
        else:
            target_cell, boxes, carried = self._where(target, objects, pos)
            finish_cells = (target_cell,)
            finish = self.distances(target_cell)
            # Walk next to the object (turning unless it is straight ahead), empty
            # the hands (dropping a box that hides it), toggle the boxes around it,
            # pick it up.
            cost = (
                max(finish[pos] - 1, 0)
                + (not carried and not self._aligned(pos, direction, finish_cells))
                + (carrying != _NOTHING)
                + boxes
                + 1
            )
            after_door_drop = 1  # the key used on a door must be dropped
        if cost >= _UNREACHABLE:
            return _UNREACHABLE
        labels = self.regions(doors)
        if any(labels[cell] == labels[pos] for cell in finish_cells):
            return cost
        # A locked, closed door is in the way: unlock one.
        best = _UNREACHABLE
        door_colors, door_cells = layout.door_colors, layout.door_cells
        kinds, colors = layout.object_kinds, layout.object_colors
        for door, door_state in enumerate(doors):
            if door_state != _LOCKED:
                continue
            door_cell = door_cells[door]
            to_door = self.distances(door_cell)
            rest = (
                max(finish[door_cell] - 1, 0)
                if target == _NOTHING
                else max(finish[door_cell] - 2, 0) + after_door_drop + 1
            )
            for key, location in enumerate(objects):
                if (
                    kinds[key] != _KEY
                    or colors[key] != door_colors[door]
                    or location == _GONE
                ):
                    continue
                if location == _CARRIED:
                    legs = max(to_door[pos] - 1, 0) + 1
                else:
                    source, boxes, carried = self._where(key, objects, pos)
                    from_source = self.distances(source)
                    # A key in a carried box appears next to the agent, not on it.
                    margin = 3 if carried else 2
                    legs = (
                        max(from_source[pos] - 1, 0)
                        + (carrying != _NOTHING)  # drop what the hands hold
                        + boxes
                        + 1  # pickup
                        + max(from_source[door_cell] - margin, 0)
                        + 1  # toggle
                    )
                best = min(best, legs + rest)
        return best


class _Moves:
    """The moves ``MiniGridEnv.step`` (and the pickup tasks' step) makes from a
    state of one layout, less those no shortest sequence makes (each is proved
    so in ``solve_minigrid``'s docstring): no-ops, closing a door, picking up
    again the object just dropped, and a drop after which no other object can
    be picked up."""

    def __init__(self, layout: _Layout, fronts):
        self.layout = layout
        self.fronts = fronts

    def another_pickup_possible(
        self, pos: int, doors: tuple[int, ...], objects: tuple[int, ...], dropped: int
    ) -> bool:
        """With empty hands, until the next pickup only unlocked doors and boxes
        can change: flood the cells reachable that way (box cells count as
        passable) and look for an object other than ``dropped`` (or a box's
        contents) next to them."""
        layout, fronts = self.layout, self.fronts
        kinds, door_index = layout.kinds, layout.door_index
        seen = {pos}
        stack = [pos]
        while stack:
            cell = stack.pop()
            for other in fronts[cell]:
                if other < 0 or other in seen:
                    continue
                kind = kinds[other]
                if other in objects:
                    held = objects.index(other)
                    if held != dropped or layout.box_contents[held] != _NOTHING:
                        return True
                    if layout.object_kinds[held] != _BOX:
                        continue
                elif kind == _DOOR:
                    if doors[door_index[other]] == _LOCKED:
                        continue
                elif kind not in (_EMPTY, _FLOOR):
                    continue
                seen.add(other)
                stack.append(other)
        return False

    def __call__(self, state: tuple) -> tuple[int | None, list[tuple[int, tuple]]]:
        """``(the action that succeeds from state or None, [(action, next state)])``."""
        layout = self.layout
        kinds, door_index = layout.kinds, layout.door_index
        pos, direction, carrying, doors, objects, forbidden = state
        front = self.fronts[pos][direction]
        if front < 0:
            # MiniGrid's step() reads the front cell before any action, and
            # asserts on a cell outside the grid: every action fails here.
            return None, []
        successors = [
            (_LEFT, (pos, (direction - 1) % 4, carrying, doors, objects, forbidden)),
            (_RIGHT, (pos, (direction + 1) % 4, carrying, doors, objects, forbidden)),
        ]
        kind = kinds[front]
        occupant = objects.index(front) if front in objects else _NOTHING
        success = None
        if kind == _GOAL:
            success = _FORWARD
        elif (
            kind == _FLOOR
            or (kind == _EMPTY and occupant == _NOTHING)
            or (kind == _DOOR and doors[door_index[front]] & _OPEN)
        ):
            successors.append(
                (_FORWARD, (front, direction, carrying, doors, objects, forbidden))
            )
        # Lava ends the episode with return 0: a dead end, never expanded.
        if occupant != _NOTHING and carrying == _NOTHING and occupant != forbidden:
            if occupant == layout.target:
                success = _PICKUP
            else:
                moved = objects[:occupant] + (_CARRIED,) + objects[occupant + 1 :]
                successors.append(
                    (_PICKUP, (pos, direction, occupant, doors, moved, _NOTHING))
                )
        if carrying != _NOTHING and kind == _EMPTY and occupant == _NOTHING:
            moved = objects[:carrying] + (front,) + objects[carrying + 1 :]
            if self.another_pickup_possible(pos, doors, moved, carrying):
                successors.append(
                    (_DROP, (pos, direction, _NOTHING, doors, moved, carrying))
                )
        toggled = self._toggle(state, front, kind, occupant)
        if toggled is not None:
            successors.append((_TOGGLE, toggled))
        return success, successors

    def _toggle(self, state: tuple, front: int, kind: int, occupant: int):
        """The state after a toggle of the cell in front, or None if it changes
        nothing (opened doors are never closed)."""
        layout = self.layout
        pos, direction, carrying, doors, objects, forbidden = state
        if kind == _DOOR:
            door = layout.door_index[front]
            door_state = doors[door]
            if door_state == 0:  # closed: open it
                door_state = _OPEN
            elif (
                door_state & _LOCKED
                and carrying != _NOTHING
                and layout.object_kinds[carrying] == _KEY
                and layout.object_colors[carrying] == layout.door_colors[door]
            ):
                door_state = _OPEN
            if door_state == doors[door]:
                return None
            toggled = doors[:door] + (door_state,) + doors[door + 1 :]
            return (pos, direction, carrying, toggled, objects, forbidden)
        if occupant != _NOTHING and layout.object_kinds[occupant] == _BOX:
            # Toggling a box replaces it by its contents (possibly nothing).
            inside = layout.box_contents[occupant]
            moved = list(objects)
            moved[occupant] = _GONE
            if inside != _NOTHING:
                moved[inside] = front
            return (pos, direction, carrying, doors, tuple(moved), forbidden)
        return None


def _shortest_actions(layout: _Layout, horizon: int) -> tuple[int, ...] | None:
    """A* search over :class:`_Moves`; the actions of a shortest successful
    sequence, or None."""
    fronts = _front_cells(layout.width, len(layout.kinds) // layout.width)
    lower_bound = _LowerBound(layout, fronts)
    moves = _Moves(layout, fronts)
    start = layout.start
    if start[2] != _NOTHING and start[2] == layout.target:
        return (_PICKUP,)  # already holding the object: any pickup action succeeds
    best_cost = {start: 0}
    parents: dict[tuple, tuple[tuple, int] | None] = {start: None}
    done = ("done",)  # the success pseudo-state
    tie = itertools.count()
    start_bound = lower_bound(start)
    if start_bound > horizon or not lower_bound.solvable(start):
        return None
    queue = [(start_bound, 0, next(tie), start)]
    while queue:
        _, negative_cost, _, state = heapq.heappop(queue)
        if state is done:
            return _trace(parents, done)
        cost = -negative_cost
        if cost > best_cost[state]:
            continue  # a stale entry: reached more cheaply since
        success, successors = moves(state)
        if success is not None:
            if cost + 1 <= horizon and cost + 1 < best_cost.get(done, _UNREACHABLE):
                best_cost[done] = cost + 1
                parents[done] = (state, success)
                heapq.heappush(queue, (cost + 1, -(cost + 1), next(tie), done))
            continue
        successor_cost = cost + 1
        for action, successor in successors:
            if successor_cost >= best_cost.get(successor, _UNREACHABLE):
                continue
            bound = lower_bound(successor)
            if successor_cost + bound > horizon:
                continue
            best_cost[successor] = successor_cost
            parents[successor] = (state, action)
            heapq.heappush(
                queue,
                (successor_cost + bound, -successor_cost, next(tie), successor),
            )
    return None


def _trace(parents: dict[tuple, tuple[tuple, int] | None], state: tuple) -> tuple:
    actions = []
    link = parents[state]
    while link is not None:
        state, action = link
        actions.append(action)
        link = parents[state]
    return tuple(reversed(actions))


def _check_semantics(env: MiniGridEnv) -> Any:
    """The object whose pickup ends the episode (None for goal tasks), or raises."""
    cls = type(env)
    if cls._reward is MiniGridEnv._reward:
        if cls.step is MiniGridEnv.step:
            return None
        if cls.step in _PICKUP_TASK_STEPS:
            if getattr(env, "obj", None) is None:
                raise ValueError(f"solve_minigrid: {cls.__name__} has no env.obj")
            return env.obj
    raise ValueError(
        f"solve_minigrid: {cls.__name__} overrides MiniGridEnv.step or _reward; its "
        "task is neither 'reach the goal' nor 'pick up env.obj' (KeyCorridor, "
        "ObstructedMaze), and the oracle would be wrong"
    )


def _reset_minigrid(env: gym.Env, caller: str) -> tuple[MiniGridEnv, Any]:
    """The unwrapped MiniGrid env, reset, and its task's object to pick up (None
    for goal tasks), or raises naming ``caller``."""
    base = env.unwrapped
    if not isinstance(base, MiniGridEnv):
        raise TypeError(f"{caller} needs a MiniGridEnv, got {type(base)}")
    if base.grid is None or base.agent_pos is None:
        raise ValueError(f"{caller}: reset the env first")
    return base, _check_semantics(base)


def _each_layout(env_id: str, seeds: Iterable[int], solve, **make_kwargs) -> list:
    """``solve(env)`` of ``gym.make(env_id)`` after ``reset(seed=s)``, per seed."""
    register_minigrid_envs()
    env = gym.make(env_id, **make_kwargs)
    try:
        results = []
        for seed in seeds:
            env.reset(seed=int(seed))
            results.append(solve(env))
        return results
    finally:
        env.close()


def solve_minigrid(env: gym.Env) -> OracleSolution:
    """Finds a shortest action sequence that solves the episode, by A* search.

    The search starts from the env's current state (normally right after
    ``reset(seed=...)``; mid-episode, the steps already taken count towards
    ``max_steps`` and the return, as they do in MiniGrid) and does not modify the
    env. States are (agent cell, direction, carried object, door states, key, ball
    and box locations, the object just dropped); transitions are those of
    ``MiniGridEnv.step``, plus KeyCorridor's and ObstructedMaze's rule that a pickup
    of ``env.obj`` succeeds. Reaching lava ends the episode with return 0, so lava
    cells are avoided.

    The search skips moves that no shortest sequence makes, so what it returns is
    optimal: (1) no-ops (a blocked forward, ``done``, ...). (2) Closing a door: the
    same sequence without that toggle (and without later toggles and forwards that
    only undo it) still succeeds, one step sooner; nothing needs a door closed.
    (3) Picking up again the object just dropped, before any other pickup: removing
    the drop and that pickup leaves a valid sequence (with empty hands between them
    the agent toggled only unlocked doors and boxes, which carrying does not
    change), two steps shorter. (4) A drop after which no object but the dropped one
    can be picked up: a drop never followed by a pickup can be removed, and by (3)
    the next pickup is of another object, which must then be reachable through the
    cells that empty hands can clear (open or unlocked doors, boxes). The A*
    estimate is the relaxed distance (walls and lava only) to the goal or the
    object, plus the turn, drop and pickup it needs, and, while a locked door
    separates them, the legs to a key of that door's colour and to the door; it
    never overestimates, and states are re-expanded when reached more cheaply.

    Args:
        env: a MiniGrid env, possibly wrapped (``gym.make`` output); its
            ``unwrapped`` env is read.

    Returns:
        The shortest solution, or an unsolved one (no actions, return 0) when the
        task cannot be solved within the ``max_steps - step_count`` steps left.

    Raises:
        ValueError: the grid holds an object this search does not model, the env
            overrides ``step`` or ``_reward`` with another task, or its ``env.obj``
            is not in the grid.

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
    base, target = _reset_minigrid(env, "solve_minigrid")
    max_steps = int(base.max_steps)
    step_count = int(base.step_count)
    actions = _shortest_actions(_read_layout(base, target), max_steps - step_count)
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
    return _each_layout(env_id, seeds, solve_minigrid, **make_kwargs)


def _describe(obj: Any) -> tuple | None:
    """An object's encoding with what it holds, boxes in boxes included."""
    if obj is None:
        return None
    return (obj.encode(), _describe(getattr(obj, "contains", None)))


def _noise_state_key(env: MiniGridEnv, pickup_task: bool) -> tuple:
    """A hashable full state of ``env``: what its ``step`` reads and changes.

    ``Grid.encode`` holds every cell's object, colour and door state; added are
    what the boxes hold (not encoded; boxes can be carried and swapped) and, in a
    pickup task, where the object to pick up is (its success compares objects,
    not their looks): two states differ wherever one of these does.
    """
    contents, target = [], None
    for i, obj in enumerate(env.grid.grid):
        if isinstance(obj, Box):
            contents.append((i, _describe(obj.contains)))
        if pickup_task and obj is env.obj:
            target = i
    if pickup_task and env.carrying is env.obj:
        target = _CARRIED
    return (
        tuple(int(x) for x in env.agent_pos),
        int(env.agent_dir),
        _describe(env.carrying),
        tuple(contents),
        target,
        env.grid.encode().tobytes(),
    )


def optimal_returns_under_action_noise(
    env: gym.Env, action_noise: Sequence[float], *, max_states: int = 100_000
) -> list[float]:
    """The best expected return from the env's state when actions are noisy.

    With probability ``p`` the env executes, instead of the chosen action, one
    drawn uniformly from all of its actions (possibly the same one): the action
    noise of :class:`~torchrl_surprise.transforms.StochasticityTransform`. No
    policy, however well it knows the maze, keeps the noise-free oracle's
    return (:func:`solve_minigrid`) then; this is what the best policy that sees
    the whole state gets on average, the return that is achievable under the
    noise.

    It is computed exactly, not sampled: the states reachable from the env's
    current one are enumerated by stepping copies of it with every action
    (MiniGrid's own ``step``), and the best expected return is the backward
    recursion over the steps left before ``max_steps``, with MiniGrid's return
    ``1 - 0.9 * step_count / max_steps`` at success, 0 at a timeout or in lava.
    For each step count and state the best action maximises ``(1 - p)`` times
    its own value plus ``p`` times the mean over all actions. At ``p = 0`` it is
    the noise-free oracle's return. The env is not modified.

    Args:
        env: a MiniGrid env (possibly wrapped; its ``unwrapped`` env is read),
            reset (or mid-episode: the steps taken count, as in MiniGrid).
        action_noise: the probabilities ``p``, each in ``[0, 1]``; the states
            are enumerated once for all of them.

    Keyword Args:
        max_states (int): refuse a layout with more reachable states than
            this (the enumeration's memory and time grow with it).

    Returns:
        The best expected return for each ``p``, in order.

    Raises:
        ValueError: a ``p`` outside ``[0, 1]``, more than ``max_states``
            reachable states, or an env whose task :func:`solve_minigrid`
            refuses.
        TypeError: the env is not a MiniGrid env.

    Examples:
        >>> import gymnasium as gym
        >>> env = gym.make("MiniGrid-DoorKey-5x5-v0")
        >>> _ = env.reset(seed=0)
        >>> free, noisy = optimal_returns_under_action_noise(env, [0.0, 0.2])
        >>> free == solve_minigrid(env).episode_return
        True
        >>> round(noisy, 4)
        0.9484
    """
    levels = [float(p) for p in action_noise]
    bad = [p for p in levels if not 0.0 <= p <= 1.0]
    if bad:
        raise ValueError(f"action_noise: each p must be in [0, 1], got {bad}")
    base, target = _reset_minigrid(env, "optimal_returns_under_action_noise")
    pickup_task = target is not None
    num_actions = int(base.action_space.n)
    max_steps, start_count = int(base.max_steps), int(base.step_count)
    # Enumerate the reachable states: successors[s][a] is a state's index, or
    # _NOISE_SUCCESS / _NOISE_FAILURE when the action ends the episode.
    root = copy.deepcopy(base)
    index = {_noise_state_key(root, pickup_task): 0}
    states, successors = [root], []
    while len(successors) < len(states):
        state = states[len(successors)]
        states[len(successors)] = None  # expanded: only its index is kept
        row = []
        for action in range(num_actions):
            child = copy.deepcopy(state)
            child.step_count = 0  # the recursion counts steps, not the copies
            _, reward, terminated, _, _ = child.step(action)
            if terminated:
                row.append(_NOISE_SUCCESS if reward > 0 else _NOISE_FAILURE)
                continue
            key = _noise_state_key(child, pickup_task)
            if key not in index:
                if len(states) == max_states:
                    raise ValueError(
                        f"optimal_returns_under_action_noise: more than "
                        f"max_states={max_states} states are reachable in this "
                        f"{type(base).__name__} layout; pass a larger max_states"
                    )
                index[key] = len(states)
                states.append(child)
            row.append(index[key])
        successors.append(row)
    count = len(states)
    table = np.array(successors, dtype=np.int64)
    # Two extra entries of the value vector: success (its return at that step)
    # and failure (0).
    table[table == _NOISE_SUCCESS] = count
    table[table == _NOISE_FAILURE] = count + 1
    results = []
    for p in levels:
        value = np.zeros(count + 2)  # no step left: a timeout, return 0
        for left in range(1, max_steps - start_count + 1):
            step_count = max_steps - left + 1  # MiniGrid's count after this step
            value[count] = 1 - 0.9 * (step_count / max_steps)
            value[count + 1] = 0.0
            q = value[table]
            value[:count] = (1 - p) * q.max(axis=1) + p * q.mean(axis=1)
        results.append(float(value[0]))
    return results


def noisy_oracle_table(
    env_ids: Sequence[str], num_seeds: int, action_noise: Sequence[float]
) -> list[dict[str, Any]]:
    """What is achievable under action noise: one row per env id and ``p``.

    For seeds ``0 .. num_seeds - 1`` each layout's best expected return under
    each ``p`` (:func:`optimal_returns_under_action_noise`), summarised as
    :data:`NOISY_ORACLE_CSV_COLUMNS`: ``mean_return`` over the layouts (the
    normaliser for runs at that noise), ``noise_free_return`` the same
    layouts' noise-free oracle return and ``fraction_of_noise_free`` their
    ratio.

    Examples:
        >>> rows = noisy_oracle_table(["MiniGrid-DoorKey-5x5-v0"], 2, [0.2])
        >>> row = rows[0]
        >>> row["env"], row["action_noise"], row["seeds"]
        ('MiniGrid-DoorKey-5x5-v0', 0.2, 2)
        >>> 0.9 < row["fraction_of_noise_free"] < 1.0
        True
    """
    levels = [float(p) for p in action_noise]
    rows = []
    for env_id in env_ids:
        returns = _each_layout(
            env_id,
            range(num_seeds),
            lambda env: optimal_returns_under_action_noise(env, [0.0, *levels]),
        )
        free = statistics.fmean(r[0] for r in returns)
        for i, p in enumerate(levels, start=1):
            noisy = [r[i] for r in returns]
            rows.append(
                {
                    "env": env_id,
                    "action_noise": p,
                    "seeds": num_seeds,
                    "mean_return": statistics.fmean(noisy),
                    "std_return": statistics.pstdev(noisy),
                    "noise_free_return": free,
                    "fraction_of_noise_free": statistics.fmean(noisy) / free,
                }
            )
    return rows


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


def oracle_row(env_id: str, solutions: Sequence[OracleSolution]) -> dict[str, Any]:
    """The summary row (:data:`ORACLE_CSV_COLUMNS`) of one task's solutions.

    Args:
        env_id: the task's id, written in the ``env`` column.
        solutions: one :class:`OracleSolution` per episode (from :func:`oracle_returns`,
            or from layouts of another backend solved by :func:`solve_minigrid`), all
            with the same ``max_steps``.

    Examples:
        >>> solutions = oracle_returns("MiniGrid-DoorKey-5x5-v0", range(3))
        >>> row = oracle_row("MiniGrid-DoorKey-5x5-v0", solutions)
        >>> row["seeds"], row["min_steps"], row["max_steps"], row["solved_fraction"]
        (3, 7, 13, 1.0)
    """
    returns = [s.episode_return for s in solutions]
    steps = [s.num_steps for s in solutions if s.solved]
    max_steps = {s.max_steps for s in solutions}
    # The tasks fix max_steps per id; a mix would make the 0.8-return length
    # meaningless.
    if len(max_steps) != 1:
        raise ValueError(f"oracle_row: {env_id} mixes max_steps {sorted(max_steps)}")
    (max_episode_steps,) = max_steps
    return {
        "env": env_id,
        "seeds": len(solutions),
        "mean_return": statistics.fmean(returns),
        "std_return": statistics.pstdev(returns),
        "mean_steps": statistics.fmean(steps) if steps else float("nan"),
        "min_steps": min(steps, default=0),
        "max_steps": max(steps, default=0),
        "max_episode_steps": max_episode_steps,
        "solved_fraction": len(steps) / len(solutions),
        "return_at_0.8_steps": return_to_steps(0.8, max_episode_steps),
    }


def oracle_table(env_ids: Sequence[str], num_seeds: int) -> list[dict[str, Any]]:
    """One summary row per env id over seeds ``0 .. num_seeds - 1``.

    Args:
        env_ids: gymnasium MiniGrid ids.
        num_seeds: the number of seeds per id.

    Returns:
        Rows keyed by :data:`ORACLE_CSV_COLUMNS` (see :func:`oracle_row`).

    Examples:
        >>> (row,) = oracle_table(["MiniGrid-DoorKey-5x5-v0"], 3)
        >>> row["env"], row["seeds"], row["min_steps"], row["max_steps"]
        ('MiniGrid-DoorKey-5x5-v0', 3, 7, 13)
        >>> row["max_episode_steps"], round(row["return_at_0.8_steps"], 2)
        (250, 55.56)
    """
    return [
        oracle_row(env_id, oracle_returns(env_id, range(num_seeds)))
        for env_id in env_ids
    ]
