"""Tests of the MiniGrid oracle: hand-built layouts with known answers, brute force,
and replays of the oracle's actions in the real paper tasks."""

from __future__ import annotations

import copy
import csv
import heapq
import itertools

import gymnasium as gym
import numpy as np
import pytest
from minigrid.core.constants import DIR_TO_VEC
from minigrid.core.grid import Grid
from minigrid.core.mission import MissionSpace
from minigrid.core.world_object import Ball, Box, Door, Floor, Goal, Key, Lava, Wall
from minigrid.envs.keycorridor import KeyCorridorEnv
from minigrid.minigrid_env import MiniGridEnv

from results.oracle import main  # the tables' command (recipes/results)
from torchrl_surprise.envs import MULTIROOM_N3_S4, MULTIROOM_N4_S4
from torchrl_surprise.envs.oracle import (
    NOISY_ORACLE_CSV_COLUMNS,
    ORACLE_CSV_COLUMNS,
    _noise_state_key,
    optimal_returns_under_action_noise,
    oracle_returns,
    oracle_table,
    return_to_steps,
    solve_minigrid,
)

LEFT, RIGHT, FORWARD, PICKUP, DROP, TOGGLE, DONE = range(7)
_AGENT_DIRS = {">": 0, "v": 1, "<": 2, "^": 3}


def _cell(char: str):
    """One layout character as a MiniGrid object (None for an empty cell)."""
    return {
        "#": lambda: Wall(),
        "G": lambda: Goal(),
        "~": lambda: Lava(),
        "F": lambda: Floor(),
        "D": lambda: Door("yellow"),  # closed
        "O": lambda: Door("yellow", is_open=True),
        "L": lambda: Door("yellow", is_locked=True),
        "M": lambda: Door("blue", is_locked=True),
        "K": lambda: Key("yellow"),
        "k": lambda: Key("blue"),
        "B": lambda: Ball("yellow"),
        "X": lambda: Box("red"),  # empty
        "Y": lambda: Box("grey", contains=Key("yellow")),
        "T": lambda: Ball("blue"),  # the object to pick up, in a pickup task
        "U": lambda: Ball("blue"),  # looks like T, is not the object to pick up
        "Z": lambda: Box("grey"),  # empty, looks like Y
    }.get(char, lambda: None)()


class LayoutEnv(MiniGridEnv):
    """A MiniGridEnv whose grid is drawn as text, one character per cell.

    ``#`` wall, ``.`` empty, ``F`` floor, ``G`` goal, ``~`` lava, ``D`` closed yellow door, ``O``
    open yellow door, ``L`` / ``M`` locked yellow / blue door, ``K`` / ``k`` yellow /
    blue key, ``B`` ball, ``X`` empty box, ``Y`` box holding a yellow key, ``Z``
    empty box looking like ``Y``, ``T`` blue ball (``U`` another), and ``> v < ^``
    the agent and its direction.
    """

    def __init__(self, rows: list[str], max_steps: int = 100, **kwargs):
        self.rows = rows
        super().__init__(
            mission_space=MissionSpace(mission_func=lambda: "reach the goal"),
            width=len(rows[0]),
            height=len(rows),
            max_steps=max_steps,
            see_through_walls=True,
            **kwargs,
        )

    def _gen_grid(self, width: int, height: int) -> None:
        _draw(self, self.rows)
        self.mission = "reach the goal"


def _draw(env: MiniGridEnv, rows: list[str]) -> None:
    """Sets ``env``'s grid, agent and (for ``T``) object to pick up from ``rows``."""
    env.grid = Grid(len(rows[0]), len(rows))
    for y, row in enumerate(rows):
        for x, char in enumerate(row):
            if char in _AGENT_DIRS:
                env.agent_pos = (x, y)
                env.agent_dir = _AGENT_DIRS[char]
            elif (obj := _cell(char)) is not None:
                env.put_obj(obj, x, y)
                if char == "T":
                    env.obj = obj


class PickupLayoutEnv(KeyCorridorEnv):
    """KeyCorridor's task on a grid drawn as text (as in :class:`LayoutEnv`): the
    episode succeeds when a pickup leaves the agent carrying ``T`` (``env.obj``).
    Only the layout is replaced; ``step`` is KeyCorridor's own."""

    def __init__(self, rows: list[str], max_steps: int = 100):
        self.rows = rows
        super().__init__(num_rows=1, room_size=3, max_steps=max_steps)

    def _gen_grid(self, width: int, height: int) -> None:
        _draw(self, self.rows)
        self.width, self.height = len(self.rows[0]), len(self.rows)
        self.mission = "pick up the blue ball"


def _make(rows: list[str], max_steps: int = 100) -> LayoutEnv:
    env = LayoutEnv(rows, max_steps=max_steps)
    env.reset(seed=0)
    return env


def _make_pickup(rows: list[str], max_steps: int = 100) -> PickupLayoutEnv:
    env = PickupLayoutEnv(rows, max_steps=max_steps)
    env.reset(seed=0)
    return env


def _replay(env: gym.Env, actions, seed: int | None = None):
    """Plays ``actions``; returns (reward, terminated) of the last step, and checks
    that the episode neither ends early nor steps on lava on the way."""
    env.reset(seed=seed if seed is not None else 0)
    base = env.unwrapped
    reward, terminated = 0.0, False
    for i, action in enumerate(actions):
        _, reward, terminated, truncated, _ = env.step(action)
        last = i == len(actions) - 1
        assert not (terminated or truncated) or last, f"episode ended at step {i}"
        cell = base.grid.get(*base.agent_pos)
        assert cell is None or cell.type != "lava"
    return reward, terminated


def _minigrid_return(steps: int, max_steps: int) -> float:
    return 1 - 0.9 * (steps / max_steps)  # MiniGridEnv._reward, verbatim


# Hand-built layouts with known answers ----------------------------------------------
@pytest.mark.parametrize("k", [1, 3, 5])
def test_goal_k_cells_ahead_is_k_forwards(k):
    env = _make(["#" * (k + 3), "#>" + "." * (k - 1) + "G#", "#" * (k + 3)])
    solution = solve_minigrid(env)
    assert solution.actions == (FORWARD,) * k
    assert solution.num_steps == k and solution.solved
    assert solution.episode_return == _minigrid_return(k, 100)


def test_goal_behind_needs_two_turns():
    env = _make(["#####", "#G.>#", "#####"])
    solution = solve_minigrid(env)
    assert solution.num_steps == 4
    assert sorted(solution.actions[:2]) in ([LEFT, LEFT], [RIGHT, RIGHT])
    assert solution.actions[2:] == (FORWARD, FORWARD)


def test_closed_door_is_toggled():
    env = _make(["#######", "#>.D.G#", "#######"])
    solution = solve_minigrid(env)
    assert solution.actions == (FORWARD, TOGGLE, FORWARD, FORWARD, FORWARD)
    assert _replay(env, solution.actions) == (solution.episode_return, True)


def test_open_door_needs_no_toggle():
    env = _make(["#######", "#>.O.G#", "#######"])
    assert solve_minigrid(env).actions == (FORWARD,) * 4


def test_locked_door_needs_the_key_of_its_colour():
    env = _make(["#######", "#>KL.G#", "#######"])
    solution = solve_minigrid(env)
    assert solution.actions == (PICKUP, FORWARD, TOGGLE, FORWARD, FORWARD, FORWARD)
    assert _replay(env, solution.actions) == (solution.episode_return, True)


def test_locked_door_with_wrong_key_or_a_ball_is_unsolvable():
    for rows in (
        ["#######", "#>kL.G#", "#######"],
        ["#######", "#>BL.G#", "#######"],
        ["#######", "#>.L.G#", "#######"],
    ):
        solution = solve_minigrid(_make(rows))
        assert not solution.solved
        assert solution.actions == () and solution.episode_return == 0.0


def test_key_in_the_way_is_picked_up_and_carried():
    # The key opens nothing here, but it blocks the corridor: picking it up clears it.
    env = _make(["######", "#>K.G#", "######"])
    solution = solve_minigrid(env)
    assert PICKUP in solution.actions
    assert solution.actions == (PICKUP, FORWARD, FORWARD, FORWARD)
    assert _replay(env, solution.actions) == (solution.episode_return, True)


def test_two_locked_doors_need_a_key_swap():
    # Yellow key opens the first door; the blue key lies behind it, and the agent
    # must drop the yellow key to pick up the blue one.
    rows = [
        "#########",
        "#>KL.kMG#",
        "#...#####",
        "#########",
    ]
    env = _make(rows)
    solution = solve_minigrid(env)
    assert solution.solved
    assert solution.actions.count(PICKUP) == 2 and DROP in solution.actions
    assert _replay(env, solution.actions) == (solution.episode_return, True)


def test_unreachable_goal_is_unsolvable():
    env = _make(["#######", "#>..#G#", "#######"])
    solution = solve_minigrid(env)
    assert not solution.solved and solution.num_steps == 0
    assert solution.episode_return == 0.0


def test_lava_is_avoided():
    rows = [
        "#######",
        "#.....#",
        "#>.~.G#",
        "#.....#",
        "#######",
    ]
    env = _make(rows)
    solution = solve_minigrid(env)
    # 4 forwards through the lava would be shorter; around it: 6 forwards, 3 turns.
    assert solution.num_steps == 9
    assert _replay(env, solution.actions) == (solution.episode_return, True)


def test_lava_across_the_only_path_is_unsolvable():
    env = _make(["#######", "#>.~.G#", "#######"])
    assert not solve_minigrid(env).solved


def test_timeout_bound_is_exact():
    rows = ["#######", "#>.D.G#", "#######"]  # shortest solution: 5 steps
    at_limit = solve_minigrid(_make(rows, max_steps=5))
    assert at_limit.solved and at_limit.num_steps == 5
    # Reaching the goal on the last allowed step still pays, as in MiniGrid.
    assert at_limit.episode_return == _minigrid_return(5, 5)
    env = _make(rows, max_steps=5)
    assert _replay(env, at_limit.actions) == (at_limit.episode_return, True)
    too_short = solve_minigrid(_make(rows, max_steps=4))
    assert not too_short.solved and too_short.episode_return == 0.0


def test_mid_episode_counts_steps_already_taken():
    env = _make(["#######", "#>.D.G#", "#######"], max_steps=20)
    env.step(LEFT)
    env.step(RIGHT)
    solution = solve_minigrid(env)
    assert solution.num_steps == 5
    assert solution.episode_return == _minigrid_return(2 + 5, 20)
    for action in solution.actions:
        _, reward, terminated, _, _ = env.step(action)
    assert terminated and reward == solution.episode_return


def test_solve_does_not_modify_the_env():
    env = _make(["#######", "#>KL.G#", "#######"])
    before = (env.agent_pos, env.agent_dir, env.step_count, env.grid.encode())
    solve_minigrid(env)
    assert env.carrying is None
    assert (env.agent_pos, env.agent_dir, env.step_count) == before[:3]
    np.testing.assert_array_equal(env.grid.encode(), before[3])


class _HeavyBall(Ball):
    """A ball subclass: it could change what pickup or toggle does."""


def test_unsupported_objects_and_tasks_are_refused():
    env = _make(["######", "#>..G#", "######"])
    env.grid.set(2, 1, _HeavyBall("red"))
    with pytest.raises(ValueError, match="_HeavyBall"):
        solve_minigrid(env)
    env = gym.make("MiniGrid-Unlock-v0")  # overrides step(): success = door opened
    env.reset(seed=0)
    with pytest.raises(ValueError, match="overrides"):
        solve_minigrid(env)
    env = _make_pickup(["######", "#>.T.#", "######"])
    env.grid.set(3, 1, None)  # the object to pick up is gone from the grid
    with pytest.raises(ValueError, match="not in the grid"):
        solve_minigrid(env)


@pytest.mark.parametrize(
    "rows",
    [
        ["#######", "#>.D.G#", "#######"],  # 5 steps: forward, toggle, 3 forwards
        ["######", "#>KLG#", "######"],  # 5 steps: pickup, forward, toggle, 2 fwd
    ],
)
def test_no_shorter_sequence_exists_brute_force(rows):
    env = _make(rows)
    solution = solve_minigrid(env)
    assert solution.num_steps == 5
    # Every sequence of 4 actions (all 7, done included) in the real env: none
    # reaches the goal at any step, so nothing shorter than 5 solves the episode.
    for actions in itertools.product(range(7), repeat=solution.num_steps - 1):
        env.reset(seed=0)
        for action in actions:
            _, reward, terminated, _, _ = env.step(action)
            assert not terminated, actions
    assert _replay(env, solution.actions) == (solution.episode_return, True)


def _reference_shortest_length(env: LayoutEnv, horizon: int) -> int | None:
    """Shortest solution length by a BFS whose transitions are the real env's step().

    Slow (it decodes the grid and calls step() per transition) but shares no code
    with the oracle: a state is MiniGrid's own grid encoding plus the agent.
    """
    width, height = env.grid.width, env.grid.height
    movable = {"key": Key, "ball": Ball}

    def snapshot():
        held = env.carrying
        return (
            tuple(int(v) for v in env.agent_pos),
            int(env.agent_dir),
            None if held is None else (held.type, held.color),
            env.grid.encode().tobytes(),
        )

    def restore(state):
        pos, direction, held, encoded = state
        grid = np.frombuffer(encoded, dtype=np.uint8).reshape(width, height, 3)
        env.grid, _ = Grid.decode(grid)
        env.agent_pos, env.agent_dir = pos, direction
        env.carrying = None if held is None else movable[held[0]](held[1])
        env.step_count = 0  # no truncation inside the reference search

    start = snapshot()
    seen, frontier = {start}, [start]
    for depth in range(1, horizon + 1):
        next_frontier = []
        for state in frontier:
            for action in range(7):
                restore(state)
                _, reward, terminated, _, _ = env.step(action)
                if terminated and reward > 0:
                    return depth
                successor = snapshot()
                if not terminated and successor not in seen:  # lava: a dead end
                    seen.add(successor)
                    next_frontier.append(successor)
        frontier = next_frontier
    return None


def _random_rows(rng: np.random.Generator, width: int, height: int) -> list[str]:
    """A random walled layout: floors, walls, lava, doors of each state, keys, balls."""
    chars = np.array(list(".F#~DOLMKkB"))
    weights = [0.4, 0.1, 0.12, 0.05, 0.07, 0.04, 0.06, 0.04, 0.05, 0.04, 0.03]
    inner = rng.choice(chars, size=(height - 2, width - 2), p=weights)
    # Agent in the first column, goal in the last: solutions are not trivial.
    inner[rng.integers(height - 2), 0] = rng.choice(list("><v^"))
    inner[rng.integers(height - 2), -1] = "G"
    wall = "#" * width
    return [wall] + ["#" + "".join(row) + "#" for row in inner] + [wall]


NUM_RANDOM_LAYOUTS = 20


def test_oracle_matches_a_bfs_over_the_real_step_on_random_layouts():
    rng = np.random.default_rng(0)
    solved = 0
    for _ in range(NUM_RANDOM_LAYOUTS):
        env = _make(_random_rows(rng, width=6, height=5), max_steps=25)
        solution = solve_minigrid(env)
        reference = _reference_shortest_length(env, horizon=25)
        assert solution.num_steps == (reference or 0), env.pprint_grid()
        solved += solution.solved
        if solution.solved:
            env.reset(seed=0)
            assert _replay(env, solution.actions) == (solution.episode_return, True)
    assert 10 <= solved < NUM_RANDOM_LAYOUTS  # both kinds of layouts were drawn


# Boxes, and tasks whose success is picking up env.obj ------------------------------
def test_box_hiding_the_key_is_toggled_first():
    env = _make(["#######", "#>YL.G#", "#######"])
    solution = solve_minigrid(env)
    # The box becomes its key, which opens the door; 7 steps, no other order works.
    assert solution.actions == (
        TOGGLE, PICKUP, FORWARD, TOGGLE, FORWARD, FORWARD, FORWARD
    )  # fmt: skip
    assert _replay(env, solution.actions) == (solution.episode_return, True)


def test_empty_box_in_the_way_is_removed_or_carried():
    env = _make(["######", "#>X.G#", "######"])
    solution = solve_minigrid(env)
    # Toggle it away or pick it up, then 3 forwards.
    assert solution.num_steps == 4 and solution.actions[0] in (TOGGLE, PICKUP)
    assert _replay(env, solution.actions) == (solution.episode_return, True)
    # A key inside a carried box does not open a door (and with no free cell to
    # drop the box on, it cannot be taken out); the bare key does.
    hidden = _make(["######", "#>L.G#", "######"])
    hidden.carrying = Box("grey", contains=Key("yellow"))
    assert not solve_minigrid(hidden).solved
    bare = _make(["######", "#>L.G#", "######"])
    bare.carrying = Key("yellow")
    assert solve_minigrid(bare).actions == (TOGGLE, FORWARD, FORWARD, FORWARD)


def test_pickup_task_hand_checked_corridor():
    # A one-row corridor: key, locked door, the ball. The key opens the door, then
    # must leave the hands (a pickup needs empty hands) without blocking the ball:
    # pickup, 2 forwards, toggle (4); turn back, drop on the key's old cell (7); turn
    # again, 2 forwards, pickup the ball (12). Dropping it anywhere else is longer.
    rows = ["########", "#>K.L.T#", "########"]
    env = _make_pickup(rows)
    solution = solve_minigrid(env)
    assert solution.num_steps == 12
    assert solution.actions[-1] == PICKUP and solution.actions.count(DROP) == 1
    assert solution.episode_return == _minigrid_return(12, 100)
    assert _reference_shortest_length_any(env, horizon=12) == 12
    assert _replay(env, solution.actions) == (solution.episode_return, True)
    # Walking into the ball's cell is impossible and no goal exists: only the
    # pickup ends the episode.
    assert not solve_minigrid(_make_pickup(["########", "#>k.L.T#", "########"])).solved


def test_pickup_task_ball_blocking_the_door_is_moved():
    # ObstructedMaze's obstacle: a ball in front of the door; pick it up, put it
    # aside, open the door, pick up the target behind it.
    rows = [
        "#######",
        "#...#.#",
        "#>.BDT#",
        "#...#.#",
        "#######",
    ]
    env = _make_pickup(rows)
    solution = solve_minigrid(env)
    reference = _reference_shortest_length_any(env, horizon=solution.num_steps)
    assert solution.num_steps == reference
    assert PICKUP in solution.actions[:-1] and DROP in solution.actions
    assert _replay(env, solution.actions) == (solution.episode_return, True)


def _describe(obj, target):
    """A hashable description of one grid cell's object (box contents included)."""
    if obj is None:
        return None
    return (
        type(obj).__name__,
        obj.color,
        getattr(obj, "is_open", None),
        getattr(obj, "is_locked", None),
        _describe(getattr(obj, "contains", None), target),
        obj is target,
    )


def _reference_shortest_length_any(env, horizon):
    """Shortest successful episode length by a BFS whose transitions are the real
    env's step(), for any MiniGrid task (boxes, and KeyCorridor's / ObstructedMaze's
    'pick up env.obj' included): a state is a deep copy of the grid, the carried
    object and the task's object, restored before each step. Shares no code with
    the oracle; slow, for small layouts."""
    base = env.unwrapped
    has_target = getattr(base, "obj", None) is not None

    def snapshot():
        target = base.obj if has_target else None
        key = (
            tuple(int(v) for v in base.agent_pos),
            int(base.agent_dir),
            _describe(base.carrying, target),
            tuple(_describe(obj, target) for obj in base.grid.grid),
        )
        world = copy.deepcopy((base.grid, base.carrying, target))
        return key, (key[0], key[1], world)

    def restore(saved):
        pos, direction, world = saved
        base.grid, base.carrying, obj = copy.deepcopy(world)
        base.agent_pos, base.agent_dir = pos, direction
        if has_target:
            base.obj = obj
        base.step_count = 0  # no truncation inside the reference search

    start_key, start = snapshot()
    seen, frontier = {start_key}, [start]
    for depth in range(1, horizon + 1):
        next_frontier = []
        for saved in frontier:
            for action in range(7):
                restore(saved)
                _, reward, terminated, _, _ = base.step(action)
                if terminated and reward > 0:
                    return depth
                key, successor = snapshot()
                if not terminated and key not in seen:  # lava: a dead end
                    seen.add(key)
                    next_frontier.append(successor)
        frontier = next_frontier
    return None


def _random_pickup_rows(rng: np.random.Generator, width: int, height: int) -> list[str]:
    """A random walled layout for the pickup task: the ball ``T`` in the last
    column, doors, keys, balls and boxes (empty or hiding a key) between."""
    chars = np.array(list(".#DLKkBXY"))
    weights = [0.45, 0.12, 0.06, 0.08, 0.06, 0.04, 0.07, 0.05, 0.07]
    inner = rng.choice(chars, size=(height - 2, width - 2), p=weights)
    inner[rng.integers(height - 2), 0] = rng.choice(list("><v^"))
    inner[rng.integers(height - 2), -1] = "T"
    wall = "#" * width
    return [wall] + ["#" + "".join(row) + "#" for row in inner] + [wall]


NUM_RANDOM_PICKUP_LAYOUTS = 12


def test_oracle_matches_a_bfs_over_the_real_step_on_random_pickup_layouts():
    rng = np.random.default_rng(2)
    solved = 0
    for _ in range(NUM_RANDOM_PICKUP_LAYOUTS):
        env = _make_pickup(_random_pickup_rows(rng, width=6, height=4), max_steps=16)
        solution = solve_minigrid(env)
        # No shorter solution (and none at all within max_steps when unsolved).
        horizon = solution.num_steps if solution.solved else 16
        reference = _reference_shortest_length_any(env, horizon=horizon)
        assert solution.num_steps == (reference or 0), env.pprint_grid()
        solved += solution.solved
        if solution.solved:
            assert _replay(env, solution.actions) == (solution.episode_return, True)
    assert 3 <= solved < NUM_RANDOM_PICKUP_LAYOUTS  # both kinds of layouts were drawn


# The paper's tasks in the real gymnasium envs ---------------------------------------
@pytest.mark.parametrize(
    "env_id,seeds",
    [
        (MULTIROOM_N3_S4, range(5)),
        (MULTIROOM_N4_S4, range(5)),
        ("MiniGrid-DoorKey-8x8-v0", range(5)),
        ("MiniGrid-DoorKey-5x5-v0", range(3)),
    ],
)
def test_replay_in_real_env_reaches_goal_with_oracle_return(env_id, seeds):
    env = gym.make(env_id)
    solutions = oracle_returns(env_id, seeds)
    for seed, solution in zip(seeds, solutions):
        assert solution.solved
        reward, terminated = _replay(env, solution.actions, seed=seed)
        assert terminated
        assert reward == solution.episode_return
        assert reward == _minigrid_return(solution.num_steps, solution.max_steps)
    if "DoorKey" in env_id:
        for solution in solutions:  # a locked door: pick up the key, then toggle
            assert solution.actions.index(PICKUP) < solution.actions.index(TOGGLE)
    else:
        assert all(TOGGLE in s.actions for s in solutions)  # closed doors


def test_oracle_table_and_cli(tmp_path, capsys):
    out = tmp_path / "oracle" / "oracle_returns.csv"
    rows = main(
        ["--envs", "MiniGrid-DoorKey-5x5-v0", "--seeds", "4", "--out", str(out)]
    )
    assert "MiniGrid-DoorKey-5x5-v0" in capsys.readouterr().out
    with out.open() as file:
        reader = csv.DictReader(file)
        # the backend whose layouts were solved, after the env id: minigrid's
        assert tuple(reader.fieldnames) == ("env", "backend", *ORACLE_CSV_COLUMNS[1:])
        (written,) = list(reader)
    assert (written["env"], written["backend"]) == (
        "MiniGrid-DoorKey-5x5-v0",
        "gymnasium",
    )
    solutions = oracle_returns("MiniGrid-DoorKey-5x5-v0", range(4))
    mean = sum(s.episode_return for s in solutions) / 4
    assert float(written["mean_return"]) == pytest.approx(mean, abs=1e-4)
    assert rows == oracle_table(["MiniGrid-DoorKey-5x5-v0"], 4)
    assert rows[0]["max_steps"] == max(s.num_steps for s in solutions)
    # A return of 0.8 on a 250-step task: 1 - 0.9 * t / 250 = 0.8.
    assert rows[0]["return_at_0.8_steps"] == pytest.approx(250 * 0.2 / 0.9)
    assert _minigrid_return(return_to_steps(0.8, 250), 250) == pytest.approx(0.8)


def test_a_table_of_envpools_layouts_is_read_as_the_oracle_of_envpool_runs(tmp_path):
    # the writer's backend column is what the aggregation keys the oracle by:
    # (env id, backend), the env id never suffixed
    from results.aggregate import read_oracle
    from results.oracle import write_oracle_csv

    rows = oracle_table(["MiniGrid-DoorKey-5x5-v0"], 2)
    minigrid = write_oracle_csv(rows, tmp_path / "minigrid.csv")
    envpool = write_oracle_csv(
        [{**rows[0], "mean_return": 0.5}], tmp_path / "envpool.csv", backend="envpool"
    )
    assert read_oracle(minigrid, envpool) == {
        ("MiniGrid-DoorKey-5x5-v0", "gymnasium"): round(rows[0]["mean_return"], 4),
        ("MiniGrid-DoorKey-5x5-v0", "envpool"): 0.5,
    }
    with pytest.raises(ValueError, match="start with env"):
        write_oracle_csv(rows, tmp_path / "x.csv", ("seeds", "env"))


# The hard-exploration suite's tasks --------------------------------------------------
SUITE_SEEDS = [
    ("MiniGrid-KeyCorridorS3R3-v0", (0, 1, 2)),
    ("MiniGrid-KeyCorridorS4R3-v0", (0, 1)),
    ("MiniGrid-KeyCorridorS6R3-v0", (0, 1)),
    ("MiniGrid-DoorKey-16x16-v0", (0, 1)),
    ("MiniGrid-MultiRoom-N6-v0", (0, 1)),
    ("MiniGrid-ObstructedMaze-1Dlhb-v0", (0, 4)),
    ("MiniGrid-ObstructedMaze-2Dlhb-v0", (2, 4)),
]


@pytest.mark.parametrize("env_id,seeds", SUITE_SEEDS)
def test_suite_replay_in_real_env_succeeds_with_oracle_return(env_id, seeds):
    env = gym.make(env_id)
    pickup_task = "KeyCorridor" in env_id or "ObstructedMaze" in env_id
    for seed, solution in zip(seeds, oracle_returns(env_id, seeds)):
        assert solution.solved
        reward, terminated = _replay(env, solution.actions, seed=seed)
        assert terminated and reward > 0
        assert reward == solution.episode_return
        assert reward == _minigrid_return(solution.num_steps, solution.max_steps)
        if pickup_task:  # success is the pickup of env.obj, with empty hands first
            assert solution.actions[-1] == PICKUP
            assert env.unwrapped.carrying is env.unwrapped.obj
        if "ObstructedMaze" in env_id:  # the key is in a box, the door blocked
            assert TOGGLE in solution.actions and DROP in solution.actions


def test_obstructed_maze_v0_layout_without_its_key_is_unsolvable():
    # ObstructedMaze-2Dlhb-v0 seed 7: a blocking ball was placed over the box that
    # held the purple key (minigrid's v1 fixes this), and the blue ball is behind
    # the purple door. The oracle says so at once instead of searching every state.
    env = gym.make("MiniGrid-ObstructedMaze-2Dlhb-v0")
    env.reset(seed=7)
    grid = env.unwrapped.grid.grid
    keys = [o.contains for o in grid if o is not None and o.type == "box"]
    assert [k.color for k in keys] == ["blue"]  # the only key; none is purple
    solution = solve_minigrid(env)
    assert not solution.solved and solution.episode_return == 0.0
    v1 = gym.make("MiniGrid-ObstructedMaze-2Dlhb-v1")
    v1.reset(seed=7)
    assert solve_minigrid(v1).solved


def _walk_to(env: gym.Env, wanted) -> list[int]:
    """Plays a shortest walk to a pose facing a cell whose object satisfies
    ``wanted``; returns its actions. Dijkstra over (position, direction) on the
    current grid: turns and forwards cost 1, a closed unlocked door 2 (toggle, then
    forward); objects are obstacles. Shares no code with the oracle."""
    base = env.unwrapped
    start = (tuple(int(v) for v in base.agent_pos), int(base.agent_dir))
    queue, seen, tie = [(0, 0, start, ())], set(), itertools.count()
    while queue:
        cost, _, (pos, direction), actions = heapq.heappop(queue)
        if (pos, direction) in seen:
            continue
        seen.add((pos, direction))
        dx, dy = (int(v) for v in DIR_TO_VEC[direction])
        front = (pos[0] + dx, pos[1] + dy)
        cell = base.grid.get(*front)
        if wanted(cell):
            for action in actions:
                _, _, terminated, _, _ = env.step(action)
                assert not terminated
            return list(actions)
        moves = [(1, (pos, (direction - 1) % 4), (LEFT,))]
        moves.append((1, (pos, (direction + 1) % 4), (RIGHT,)))
        if cell is None or (cell.can_overlap() and cell.type != "lava"):
            if cell is None or cell.type != "goal":
                moves.append((1, (front, direction), (FORWARD,)))
        elif cell.type == "door" and not cell.is_locked:
            moves.append((2, (front, direction), (TOGGLE, FORWARD)))
        for step_cost, successor, more in moves:
            if successor not in seen:
                item = (cost + step_cost, next(tie), successor, actions + more)
                heapq.heappush(queue, item)
    raise AssertionError("no walk reaches the wanted cell")


def _staged_plan(env: gym.Env, seed: int) -> tuple[list[int], float, bool]:
    """A feasible, not necessarily shortest, plan in the real env: fetch the key of
    the locked door (if any) and open it, then for KeyCorridor drop the key behind
    the door and pick up the object, else walk into the goal."""
    env.reset(seed=seed)
    base = env.unwrapped
    plan: list[int] = []
    reward, terminated = 0.0, False

    def play(actions):
        nonlocal reward, terminated
        for action in actions:
            _, reward, terminated, _, _ = env.step(action)
            plan.append(action)

    if any(o is not None and o.type == "key" for o in base.grid.grid):
        plan += _walk_to(env, lambda c: c is not None and c.type == "key")
        play([PICKUP])
        locked = [o for o in base.grid.grid if o is not None and o.type == "door"]
        locked = [o for o in locked if o.is_locked]
        plan += _walk_to(env, lambda c: any(c is door for door in locked))
        play([TOGGLE, FORWARD])
    if getattr(base, "obj", None) is not None:
        play([LEFT, LEFT, DROP, LEFT, LEFT])  # on the cell just left, behind
        plan += _walk_to(env, lambda c: c is base.obj)
        play([PICKUP])
    else:
        plan += _walk_to(env, lambda c: c is not None and c.type == "goal")
        play([FORWARD])
    return plan, reward, terminated


@pytest.mark.parametrize(
    "env_id,seeds",
    [
        ("MiniGrid-KeyCorridorS3R3-v0", range(4)),
        ("MiniGrid-KeyCorridorS6R3-v0", range(2)),
        ("MiniGrid-DoorKey-16x16-v0", range(2)),
        ("MiniGrid-MultiRoom-N6-v0", range(2)),
    ],
)
def test_oracle_is_never_beaten_by_a_staged_plan(env_id, seeds):
    env = gym.make(env_id)
    shorter = 0
    for seed, solution in zip(seeds, oracle_returns(env_id, seeds)):
        plan, reward, terminated = _staged_plan(env, seed)
        assert terminated and reward == _minigrid_return(
            len(plan), solution.max_steps
        )  # the plan is feasible in the real env
        assert solution.num_steps <= len(plan)
        assert solution.episode_return >= reward
        shorter += solution.num_steps < len(plan)
    if "KeyCorridor" in env_id:
        assert shorter  # the staged drop is not always the best place for the key


@pytest.mark.parametrize(
    "env_id", ["MiniGrid-KeyCorridorS3R3-v0", "MiniGrid-ObstructedMaze-1Dlhb-v0"]
)
def test_envpool_layouts_rebuilt_in_minigrid_are_solved(env_id):
    pytest.importorskip("envpool")
    from torchrl_surprise.envs.envpool import (
        EnvPoolMiniGridEnv,
        minigrid_env_from_envpool_state,
    )

    pool = EnvPoolMiniGridEnv(env_id, num_envs=2, seed=0)
    pool.reset()
    states = pool.debug_states()
    pool.close()
    for state in states:
        twin = minigrid_env_from_envpool_state(state, env_id)
        solution = solve_minigrid(twin)
        assert solution.solved and solution.actions[-1] == PICKUP
        for action in solution.actions:
            _, reward, terminated, _, _ = twin.step(action)
        assert terminated and reward == solution.episode_return


# What is achievable under action noise ---------------------------------------------
def test_action_noise_optimum_hand_computed():
    # The goal one step ahead, 2 steps allowed. The agent goes forward; the env
    # executes it with probability q = 1 - p + p / 7. Otherwise a random turn
    # (2 of 7) leaves no way to the goal in the step left, and a no-op (pickup,
    # drop, toggle, done: 4 of 7) leaves it facing the goal for its last step.
    p = 0.2
    env = _make(["####", "#>G#", "####"], max_steps=2)
    q = 1 - p + p / 7
    first, last = _minigrid_return(1, 2), _minigrid_return(2, 2)
    expected = q * first + p * 4 / 7 * q * last
    (noisy,) = optimal_returns_under_action_noise(env, [p])
    assert noisy == pytest.approx(expected, abs=1e-12)
    # Every action random (p = 1): the mean over actions, no choice left.
    (random,) = optimal_returns_under_action_noise(env, [1.0])
    assert random == pytest.approx(first / 7 + 4 / 7 / 7 * last, abs=1e-12)
    # Mid-episode the steps taken count: after a no-op, the same two steps pay
    # what steps 2 and 3 of 3 pay.
    env = _make(["####", "#>G#", "####"], max_steps=3)
    env.step(DONE)
    first, last = _minigrid_return(2, 3), _minigrid_return(3, 3)
    (noisy,) = optimal_returns_under_action_noise(env, [p])
    assert noisy == pytest.approx(q * first + p * 4 / 7 * q * last, abs=1e-12)
    (free,) = optimal_returns_under_action_noise(env, [0.0])
    assert free == solve_minigrid(env).episode_return == first


def test_action_noise_states_differ_in_what_boxes_hold_and_which_object_is_the_target():
    # Two grey boxes, one holding the key: swapped, the grid encodes the same.
    env = _make(["#######", "#>ZY.G#", "#######"])
    key = _noise_state_key(env, pickup_task=False)
    left, right = env.grid.get(2, 1), env.grid.get(3, 1)
    env.grid.set(2, 1, right)
    env.grid.set(3, 1, left)
    assert env.grid.encode().tobytes() == key[-1]
    assert _noise_state_key(env, pickup_task=False) != key
    # A pickup task's target and a ball that looks the same, swapped.
    env = _make_pickup(["######", "#>TU.#", "######"])
    key = _noise_state_key(env, pickup_task=True)
    target, twin = env.grid.get(2, 1), env.grid.get(3, 1)
    env.grid.set(2, 1, twin)
    env.grid.set(3, 1, target)
    assert _noise_state_key(env, pickup_task=True) != key


@pytest.mark.parametrize(
    "env_id,seeds",
    [(MULTIROOM_N3_S4, range(2)), ("MiniGrid-DoorKey-5x5-v0", range(2))],
)
def test_action_noise_optimum_without_noise_is_the_oracle(env_id, seeds):
    env = gym.make(env_id)
    for seed in seeds:
        env.reset(seed=seed)
        free, mild, most = optimal_returns_under_action_noise(env, [0.0, 0.05, 0.2])
        assert free == pytest.approx(solve_minigrid(env).episode_return, abs=1e-12)
        assert free > mild > most > 0  # more noise, less achievable


@pytest.mark.parametrize(
    "rows,make",
    [
        (["#######", "#.....#", "#>.~.G#", "#.....#", "#######"], _make),  # lava
        (["#######", "#>YL.G#", "#######"], _make),  # a box holding the key
        (["######", "#>.T.#", "######"], _make_pickup),  # a pickup task
    ],
)
def test_action_noise_optimum_without_noise_on_hand_layouts(rows, make):
    env = make(rows)
    (free,) = optimal_returns_under_action_noise(env, [0.0])
    assert free == pytest.approx(solve_minigrid(env).episode_return, abs=1e-12)


def test_action_noise_optimum_matches_noisy_episodes_in_the_real_env():
    # One corridor through a closed door: replanning the oracle's shortest path
    # after every step is the best policy here, so its return over noisy
    # episodes of the real env (each executed action replaced by a random one
    # with probability p, as StochasticityTransform does) estimates the optimum.
    rows, p, episodes = ["#######", "#>.D.G#", "#######"], 0.3, 400
    (optimum,) = optimal_returns_under_action_noise(_make(rows, max_steps=20), [p])
    rng = np.random.default_rng(0)
    returns = []
    for _ in range(episodes):
        env = _make(rows, max_steps=20)
        reward, done = 0.0, False
        while not done:
            action = solve_minigrid(env).actions[0]
            if rng.random() < p:
                action = int(rng.integers(7))
            _, reward, terminated, truncated, _ = env.step(action)
            done = terminated or truncated
        returns.append(reward)
    error = np.std(returns) / np.sqrt(episodes)
    assert abs(np.mean(returns) - optimum) < 4 * error


def test_action_noise_optimum_leaves_the_env_and_refuses_bad_input():
    env = _make(["#######", "#>KL.G#", "#######"])
    before = (env.agent_pos, env.agent_dir, env.step_count, env.grid.encode())
    optimal_returns_under_action_noise(env, [0.1])
    assert env.carrying is None
    assert (env.agent_pos, env.agent_dir, env.step_count) == before[:3]
    np.testing.assert_array_equal(env.grid.encode(), before[3])
    with pytest.raises(ValueError, match=r"in \[0, 1\]"):
        optimal_returns_under_action_noise(env, [0.1, 1.5])
    with pytest.raises(ValueError, match="max_states=3"):
        optimal_returns_under_action_noise(env, [0.1], max_states=3)
    unlock = gym.make("MiniGrid-Unlock-v0")
    unlock.reset(seed=0)
    with pytest.raises(ValueError, match="overrides"):
        optimal_returns_under_action_noise(unlock, [0.1])
    with pytest.raises(ValueError, match="reset the env first"):
        optimal_returns_under_action_noise(gym.make("MiniGrid-DoorKey-5x5-v0"), [0.1])


def test_noisy_oracle_table_and_cli(tmp_path, capsys):
    out = tmp_path / "noisy.csv"
    argv = ["--envs", "MiniGrid-DoorKey-5x5-v0", "--seeds", "2", "--out", str(out)]
    rows = main([*argv, "--action-noise", "0.1", "0.2"])
    assert "fraction_of_noise_free" in capsys.readouterr().out
    with out.open() as file:
        reader = csv.DictReader(file)
        columns = ("env", "backend", *NOISY_ORACLE_CSV_COLUMNS[1:])
        assert tuple(reader.fieldnames) == columns
        written = list(reader)
    assert {row["backend"] for row in written} == {"gymnasium"}
    assert [float(row["action_noise"]) for row in written] == [0.1, 0.2]
    env = gym.make("MiniGrid-DoorKey-5x5-v0")
    per_seed = []
    for seed in range(2):
        env.reset(seed=seed)
        per_seed.append(optimal_returns_under_action_noise(env, [0.0, 0.2]))
    free, noisy = np.mean(per_seed, axis=0)
    assert rows[1]["mean_return"] == pytest.approx(noisy, abs=1e-12)
    assert rows[1]["noise_free_return"] == pytest.approx(free, abs=1e-12)
    assert float(written[1]["mean_return"]) == pytest.approx(noisy, abs=1e-4)
    assert rows[1]["fraction_of_noise_free"] == pytest.approx(noisy / free)
    # Each row's noise-free return is the oracle's, averaged over the same seeds.
    oracle = oracle_returns("MiniGrid-DoorKey-5x5-v0", range(2))
    assert free == pytest.approx(np.mean([s.episode_return for s in oracle]))
