"""Tests of the MiniGrid oracle: hand-built layouts with known answers, brute force,
and replays of the oracle's actions in the real paper tasks."""

from __future__ import annotations

import csv
import itertools

import gymnasium as gym
import numpy as np
import pytest
from minigrid.core.grid import Grid
from minigrid.core.mission import MissionSpace
from minigrid.core.world_object import Ball, Box, Door, Floor, Goal, Key, Lava, Wall
from minigrid.minigrid_env import MiniGridEnv

from torchrl_surprise.envs import MULTIROOM_N3_S4, MULTIROOM_N4_S4
from torchrl_surprise.envs.oracle import (
    ORACLE_CSV_COLUMNS,
    main,
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
        "X": lambda: Box("red"),
    }.get(char, lambda: None)()


class LayoutEnv(MiniGridEnv):
    """A MiniGridEnv whose grid is drawn as text, one character per cell.

    ``#`` wall, ``.`` empty, ``F`` floor, ``G`` goal, ``~`` lava, ``D`` closed yellow door, ``O``
    open yellow door, ``L`` / ``M`` locked yellow / blue door, ``K`` / ``k`` yellow /
    blue key, ``B`` ball, ``X`` box, and ``> v < ^`` the agent and its direction.
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
        self.grid = Grid(width, height)
        for y, row in enumerate(self.rows):
            for x, char in enumerate(row):
                if char in _AGENT_DIRS:
                    self.agent_pos = (x, y)
                    self.agent_dir = _AGENT_DIRS[char]
                elif (obj := _cell(char)) is not None:
                    self.put_obj(obj, x, y)
        self.mission = "reach the goal"


def _make(rows: list[str], max_steps: int = 100) -> LayoutEnv:
    env = LayoutEnv(rows, max_steps=max_steps)
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


def test_unsupported_objects_and_tasks_are_refused():
    with pytest.raises(ValueError, match="Box"):
        solve_minigrid(_make(["######", "#>X.G#", "######"]))
    env = gym.make("MiniGrid-Unlock-v0")  # overrides step(): success = door opened
    env.reset(seed=0)
    with pytest.raises(ValueError, match="overrides"):
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
        assert tuple(reader.fieldnames) == ORACLE_CSV_COLUMNS
        (written,) = list(reader)
    solutions = oracle_returns("MiniGrid-DoorKey-5x5-v0", range(4))
    mean = sum(s.episode_return for s in solutions) / 4
    assert float(written["mean_return"]) == pytest.approx(mean, abs=1e-4)
    assert rows == oracle_table(["MiniGrid-DoorKey-5x5-v0"], 4)
    assert rows[0]["max_steps"] == max(s.num_steps for s in solutions)
    # A return of 0.8 on a 250-step task: 1 - 0.9 * t / 250 = 0.8.
    assert rows[0]["return_at_0.8_steps"] == pytest.approx(250 * 0.2 / 0.9)
    assert _minigrid_return(return_to_steps(0.8, 250), 250) == pytest.approx(0.8)
