"""The envpool MiniGrid backend is the same task as minigrid, behind the same API.

* Step for step: envpool's start states rebuilt in minigrid envs, then the same
  actions applied to both give the same observations, rewards and flags, across
  episode ends and TorchRL's partial resets.
* The oracle's mean return over envpool's layouts matches its mean over minigrid's.
* The TorchRL env has the gymnasium backend's specs and batch semantics; seeding,
  errors, and exact resume through the replay log.
"""

from __future__ import annotations

import functools
import statistics
import subprocess
import sys

import numpy as np
import pytest
import torch
from tensordict import TensorDictBase
from torchrl.collectors import Collector
from torchrl.envs.utils import check_env_specs

envpool = pytest.importorskip("envpool")

import gymnasium as gym  # noqa: E402
from minigrid.core.actions import Actions  # noqa: E402

from torchrl_surprise.envs.envpool import (  # noqa: E402
    ENVPOOL_PAPER_TASKS,
    EnvPoolMiniGridEnv,
    barrier_seed,
    envpool_minigrid_task,
    envpool_minigrid_tasks,
    minigrid_env_from_envpool_state,
)
from torchrl_surprise.envs.minigrid import (  # noqa: E402
    MULTIROOM_N3_S4,
    MULTIROOM_N4_S4,
    PAPER_MULTIROOM_IDS,
    make_minigrid_env,
)
from torchrl_surprise.envs.minigrid_ids import UnknownMiniGridTask  # noqa: E402
from torchrl_surprise.envs.oracle import oracle_returns, solve_minigrid  # noqa: E402

DOORKEY = "MiniGrid-DoorKey-8x8-v0"
KEYCORRIDOR = "MiniGrid-KeyCorridorS3R1-v0"
OBSTRUCTED = "MiniGrid-ObstructedMaze-1Dl-v0"
OBSTRUCTED_BOX = "MiniGrid-ObstructedMaze-1Dlhb-v0"  # key in a box, door blocked
GOAL_TASKS = (MULTIROOM_N3_S4, MULTIROOM_N4_S4, DOORKEY)

_DONE = int(Actions.done)  # a no-op in these tasks
_PICKUP, _DROP, _TOGGLE = int(Actions.pickup), int(Actions.drop), int(Actions.toggle)


# Step for step ------------------------------------------------------------------
class _Planner:
    """Per env and episode, a plan: random actions, the oracle's solution, or the
    oracle's solution padded with no-ops so that the goal is reached on the very
    last step the episode allows (where envpool's own flags differ from MiniGrid's).
    """

    MODES = ("oracle_last_step", "random", "oracle")

    def __init__(self, num_envs: int, solvable: bool, seed: int) -> None:
        self.rng = np.random.default_rng(seed)
        self.solvable = solvable
        self.episodes = [0] * num_envs
        self.plans: list[list[int]] = [[] for _ in range(num_envs)]

    def start(self, i: int, twin: gym.Env) -> str:
        mode = self.MODES[(i + self.episodes[i]) % 3] if self.solvable else "random"
        self.episodes[i] += 1
        self.plans[i] = []
        if mode != "random":
            solution = solve_minigrid(twin)
            assert solution.solved
            pad = solution.max_steps - solution.num_steps
            pad = pad if mode == "oracle_last_step" else 0
            self.plans[i] = [_DONE] * pad + list(solution.actions)
        return mode

    def action(self, i: int, twin: gym.Env) -> int:
        if self.plans[i]:
            return self.plans[i].pop(0)
        # Random, but more often picking up, opening and unboxing what is in
        # front: KeyCorridor and ObstructedMaze are won by picking up a ball
        # behind a locked door (about one episode in seven then succeeds).
        base = twin.unwrapped
        front = base.grid.get(*base.front_pos)
        if front is not None and front.can_pickup() and base.carrying is None:
            if self.rng.random() < 0.7:
                return _PICKUP
        if front is not None and front.type in ("door", "box"):
            if not (front.type == "door" and front.is_open) and self.rng.random() < 0.7:
                return _TOGGLE
        if base.carrying is not None and front is None and self.rng.random() < 0.1:
            return _DROP
        return int(self.rng.choice([0, 1, 2, 2, 2, 3, 4, 5, 6]))


def _assert_twin_obs(twin: gym.Env, td: TensorDictBase, i: int) -> None:
    obs = twin.unwrapped.gen_obs()
    assert torch.equal(td["image"][i], torch.as_tensor(obs["image"]))
    assert int(td["direction"][i]) == obs["direction"]


def _step_for_step(task: str, num_envs: int, steps: int, seed: int) -> dict:
    """Runs the envpool backend and minigrid twins side by side; counts events."""
    env = make_minigrid_env(task, num_envs=num_envs, seed=seed, backend="envpool")
    base = env
    td = env.reset()
    twins = base.minigrid_envs()
    planner = _Planner(num_envs, solvable=task in GOAL_TASKS, seed=seed)
    for i, twin in enumerate(twins):
        _assert_twin_obs(twin, td, i)
        planner.start(i, twin)
    counts = dict.fromkeys(
        ("steps", "episodes", "successes", "truncated", "last_step_successes"), 0
    )
    for _ in range(steps):
        actions = [planner.action(i, twins[i]) for i in range(num_envs)]
        td["action"] = torch.tensor(actions)
        td, td_next = env.step_and_maybe_reset(td)
        nxt = td["next"]
        for i, twin in enumerate(twins):
            obs, reward, terminated, truncated, _ = twin.step(actions[i])
            assert torch.equal(nxt["image"][i], torch.as_tensor(obs["image"]))
            assert int(nxt["direction"][i]) == obs["direction"]
            # Bit-equal float32 rewards: what the gymnasium backend writes.
            assert nxt["reward"][i].item() == np.float32(reward), (task, i)
            assert bool(nxt["terminated"][i]) == terminated, (task, i)
            assert bool(nxt["truncated"][i]) == truncated, (task, i)
            assert bool(nxt["done"][i]) == (terminated or truncated)
            counts["steps"] += 1
            if terminated or truncated:
                counts["episodes"] += 1
                counts["successes"] += reward > 0
                counts["truncated"] += truncated
                counts["last_step_successes"] += terminated and truncated
                # The partial reset: env i starts a new episode, the others go on.
                twins[i] = base.minigrid_envs([i])[0]
                _assert_twin_obs(twins[i], td_next, i)
                planner.start(i, twins[i])
        td = td_next
    env.close()
    return counts


@pytest.mark.parametrize(
    "task,steps,successes",
    [
        (MULTIROOM_N3_S4, 400, True),
        (MULTIROOM_N4_S4, 400, True),
        (DOORKEY, 1400, True),
        (KEYCORRIDOR, 1500, True),
        (OBSTRUCTED, 1500, True),
        (OBSTRUCTED_BOX, 700, False),  # boxes opened, never won at random
    ],
)
def test_step_for_step_same_as_minigrid(task, steps, successes):
    counts = _step_for_step(task, num_envs=4, steps=steps, seed=3)
    # The run crossed episode ends of every kind it can produce.
    assert counts["episodes"] >= 4 and counts["truncated"] >= 1
    assert (counts["successes"] >= 1) == successes
    if task in GOAL_TASKS:
        # The goal reached on the very last step: terminated and truncated.
        assert counts["last_step_successes"] >= 1


def test_envpool_raw_flags_and_reward_differ_where_corrected():
    """What the backend corrects: envpool's own outputs at a last-step success."""
    task, kwargs = envpool_minigrid_task(MULTIROOM_N3_S4)
    pool = envpool.make(task, env_type="gymnasium", num_envs=1, seed=0, **kwargs)
    pool.reset()
    twin = minigrid_env_from_envpool_state(pool.debug_states([0])[0], MULTIROOM_N3_S4)
    solution = solve_minigrid(twin)
    plan = [_DONE] * (60 - solution.num_steps) + list(solution.actions)
    for action in plan:
        _, reward, terminated, truncated, _ = pool.step(np.array([action]))
    # envpool: terminated = done & ~truncated, and its reward in float32 arithmetic.
    assert (bool(terminated[0]), bool(truncated[0])) == (False, True)
    assert reward[0] == np.float32(1) - np.float32(0.9) * np.float32(60 / 60)
    for action in plan:
        _, _, twin_terminated, twin_truncated, _ = twin.step(action)
    assert (twin_terminated, twin_truncated) == (True, True)
    # The float32 arithmetic differs from MiniGrid's float64 in the last bit,
    # e.g. at step 19 of 60.
    assert np.float32(1 - 0.9 * (19 / 60)) != np.float32(1) - np.float32(
        0.9
    ) * np.float32(19) / np.float32(60)


def test_lava_on_last_step_is_terminated():
    """Walking into lava on the last allowed step: terminated and truncated."""
    env = EnvPoolMiniGridEnv("MiniGrid-LavaGapS5-v0", num_envs=1, seed=0)
    td = env.reset()
    twin = env.minigrid_envs()[0]
    base = twin.unwrapped
    # Find a lava cell next to a free one and walk the agent there in the twin's
    # plan: the oracle avoids lava, so search a path into it by hand.
    lava = [
        (x, y)
        for x in range(base.width)
        for y in range(base.height)
        if base.grid.get(x, y) is not None and base.grid.get(x, y).type == "lava"
    ]
    path = _path_into(base, set(lava))
    assert path is not None
    plan = [_DONE] * (base.max_steps - len(path)) + path
    for action in plan:
        td["action"] = torch.tensor([action])
        td = env.step(td)
        obs, reward, terminated, truncated, _ = twin.step(action)
        assert bool(td["next", "terminated"]) == terminated
        assert bool(td["next", "truncated"]) == truncated
        td = env.step_mdp(td)
    assert terminated and truncated
    env.close()


def _path_into(base, targets: set) -> list[int] | None:
    """Breadth-first search of turns and forwards that step onto a target cell."""
    from collections import deque

    from minigrid.core.constants import DIR_TO_VEC

    start = (tuple(base.agent_pos), base.agent_dir)
    seen = {start: []}
    queue = deque([start])
    while queue:
        (pos, d) = state = queue.popleft()
        path = seen[state]
        fx, fy = pos[0] + DIR_TO_VEC[d][0], pos[1] + DIR_TO_VEC[d][1]
        if (fx, fy) in targets:
            return path + [int(Actions.forward)]
        cell = base.grid.get(fx, fy)
        nexts = [
            ((pos, (d - 1) % 4), Actions.left),
            ((pos, (d + 1) % 4), Actions.right),
        ]
        if cell is None or cell.type == "floor":
            nexts.append((((fx, fy), d), Actions.forward))
        for nxt, action in nexts:
            if nxt not in seen:
                seen[nxt] = path + [int(action)]
                queue.append(nxt)
    return None


# The same task distribution -----------------------------------------------------
def envpool_oracle_returns(
    task: str, num_layouts: int, seed: int = 0, **kwargs
) -> list[float]:
    """The oracle's return on envpool's first layout of envs 0..n-1 (seeds s..s+n-1)."""
    env = EnvPoolMiniGridEnv(task, num_envs=num_layouts, seed=seed)
    env.reset()
    twin = gym.make(task)
    returns = []
    for state in env.debug_states():
        twin = minigrid_env_from_envpool_state(state, task, env=twin)
        returns.append(solve_minigrid(twin).episode_return)
    env.close()
    return returns


@pytest.mark.parametrize("task", GOAL_TASKS)
def test_oracle_return_matches_minigrid_layouts(task):
    n = 300
    ours = envpool_oracle_returns(task, n, seed=10_000)
    theirs = [s.episode_return for s in oracle_returns(task, range(n))]
    se = (statistics.variance(ours) / n + statistics.variance(theirs) / n) ** 0.5
    # Every layout is solvable, as in minigrid.
    assert min(ours) > 0 and min(theirs) > 0
    assert abs(statistics.mean(ours) - statistics.mean(theirs)) < 3 * se


def test_rebuilt_env_is_solved_by_oracle_and_replays_on_envpool():
    """The oracle's solution of a rebuilt layout solves the envpool env itself."""
    env = EnvPoolMiniGridEnv(DOORKEY, num_envs=2, seed=5)
    td = env.reset()
    solutions = [solve_minigrid(twin) for twin in env.minigrid_envs()]
    ends: list[list[int]] = [[], []]
    for t in range(max(s.num_steps for s in solutions)):
        actions = [s.actions[t] if t < s.num_steps else _DONE for s in solutions]
        td, td_next = env.step_and_maybe_reset(td.set("action", torch.tensor(actions)))
        for i, s in enumerate(solutions):
            if td["next", "done"][i]:
                ends[i].append(t)
                assert bool(td["next", "terminated"][i])
                assert td["next", "reward"][i].item() == np.float32(s.episode_return)
        td = td_next
    assert ends == [[s.num_steps - 1] for s in solutions]


@pytest.mark.parametrize("task", [MULTIROOM_N3_S4, MULTIROOM_N4_S4])
def test_multiroom_corner_doors_are_redrawn(task):
    """envpool's MultiRoom puts some entry doors on a room's corner: unsolvable."""

    def layouts(redraw):
        env = EnvPoolMiniGridEnv(task, 100, seed=0, redraw_corner_doors=redraw)
        env.reset()
        twins = env.minigrid_envs()
        env.close()
        return twins

    raw = layouts(False)
    unsolvable = [t for t in raw if not solve_minigrid(t).solved]
    assert len(unsolvable) >= 40  # 61% (N3S4) and 77% (N4S4) over 1000 seeds
    for twin in unsolvable:
        base = twin.unwrapped
        corner_doors = [
            (x, y)
            for x in range(base.width)
            for y in range(base.height)
            if (o := base.grid.get(x, y)) is not None
            and o.type == "door"
            and _opens_onto_walls(base, x, y)
        ]
        assert corner_doors, "an unsolvable layout without a door on a corner"
    assert all(solve_minigrid(t).solved for t in layouts(None))


def _opens_onto_walls(base, x, y) -> bool:
    """A door with a wall on at least one side in both directions: no way through."""

    def wall(dx, dy):
        cell = base.grid.get(x + dx, y + dy)
        return cell is not None and cell.type == "wall"

    return (wall(1, 0) or wall(-1, 0)) and (wall(0, 1) or wall(0, -1))


def test_rebuild_refuses_dynamic_obstacles():
    pool = envpool.make(
        "MiniGrid-Dynamic-Obstacles-5x5-v0", env_type="gymnasium", num_envs=1, seed=0
    )
    pool.reset()
    with pytest.raises(ValueError, match="move at random"):
        minigrid_env_from_envpool_state(
            pool.debug_states([0])[0], "MiniGrid-Dynamic-Obstacles-5x5-v0"
        )


def test_obstructed_maze_grid_is_envpools_size():
    env = EnvPoolMiniGridEnv(OBSTRUCTED, num_envs=1, seed=0)
    env.reset()
    twin = env.minigrid_envs()[0].unwrapped
    assert (twin.width, twin.height) == (16, 16)
    assert (
        gym.make(OBSTRUCTED).unwrapped.width,
        gym.make(OBSTRUCTED).unwrapped.height,
    ) == (11, 6)


# The TorchRL env ----------------------------------------------------------------
@pytest.mark.parametrize("categorical", [True, False])
@pytest.mark.parametrize("task", [MULTIROOM_N3_S4, DOORKEY])
def test_specs_equal_gymnasium_backend(task, categorical):
    kwargs = dict(num_envs=3, seed=0, categorical_action_encoding=categorical)
    ours = make_minigrid_env(task, backend="envpool", **kwargs)
    theirs = make_minigrid_env(task, backend="gymnasium", **kwargs)
    check_env_specs(ours)
    check_env_specs(theirs)
    assert ours.observation_spec == theirs.observation_spec
    assert ours.full_action_spec == theirs.full_action_spec
    assert ours.full_reward_spec == theirs.full_reward_spec
    assert ours.full_done_spec == theirs.full_done_spec
    assert ours.full_state_spec == theirs.full_state_spec
    a, b = ours.rollout(5), theirs.rollout(5)
    assert set(a.keys(True, True)) == set(b.keys(True, True))
    for key in a.keys(True, True):
        assert (a[key].shape, a[key].dtype) == (b[key].shape, b[key].dtype), key
    ours.close()
    theirs.close()


def test_paper_tasks_are_the_minigrid_registrations():
    for env_id, num_rooms in PAPER_MULTIROOM_IDS.items():
        task, kwargs = ENVPOOL_PAPER_TASKS[env_id]
        spec = gym.spec(env_id).kwargs
        assert task == "MiniGrid-MultiRoom-N2-S4-v0"
        assert kwargs == {
            "min_num_rooms": spec["minNumRooms"],
            "max_num_rooms": spec["maxNumRooms"],
            "max_room_size": spec["maxRoomSize"],
            "max_episode_steps": spec["max_steps"],
        }
        env = EnvPoolMiniGridEnv(env_id, num_envs=8, seed=0)
        env.reset()
        for state in env.debug_states():
            assert state.max_steps == 20 * num_rooms
            twin = minigrid_env_from_envpool_state(state, env_id).unwrapped
            doors = [o for o in twin.grid.grid if o is not None and o.type == "door"]
            assert len(doors) == num_rooms - 1
        env.close()


def test_every_envpool_minigrid_task_reachable_by_name():
    tasks = envpool_minigrid_tasks()
    assert {MULTIROOM_N3_S4, MULTIROOM_N4_S4, DOORKEY, KEYCORRIDOR, OBSTRUCTED} <= set(
        tasks
    )
    assert len([t for t in tasks if t.startswith("MiniGrid-")]) >= 80
    for task in tasks[:: max(1, len(tasks) // 12)]:
        env = make_minigrid_env(task, num_envs=2, seed=0, backend="envpool")
        assert env.rand_step(env.reset())["next", "image"].shape == (2, 7, 7, 3)
        env.close()


def test_rollout_partial_resets_match_stepwise_reference():
    """env.rollout's partial resets: each env's episodes are its own, in order."""
    num_envs, steps = 3, 150
    actions = torch.randint(
        3, (steps, num_envs), generator=torch.Generator().manual_seed(0)
    )
    step = iter(range(steps))
    env = make_minigrid_env(
        "MiniGrid-Empty-5x5-v0", num_envs, seed=4, backend="envpool"
    )
    td = env.rollout(
        steps,
        policy=lambda td: td.set("action", actions[next(step)].clone()),
        break_when_any_done=False,
    )
    done = td["next", "done"].squeeze(-1)
    assert done.any(1).all() and (done.any(0) & ~done.all(0)).any()
    # Reference: one envpool env per sub-env, seed 4 + i, reset by hand.
    for i in range(num_envs):
        ref = envpool.make(
            "MiniGrid-Empty-5x5-v0", env_type="gymnasium", num_envs=1, seed=4 + i
        )
        obs, _ = ref.reset()
        for t in range(steps):
            assert torch.equal(td["image"][i, t], torch.as_tensor(obs["image"][0]))
            obs, reward, term, trunc, _ = ref.step(actions[t, i].numpy()[None])
            assert torch.equal(
                td["next", "image"][i, t], torch.as_tensor(obs["image"][0])
            )
            assert bool(td["next", "done"][i, t]) == bool(term[0] or trunc[0])
            if term[0] or trunc[0]:
                obs, _ = ref.reset()


def test_rollout_break_when_all_done_steps_only_running_envs():
    """Finished envs are left out of the step (envpool's step(actions, env_ids))."""
    env = EnvPoolMiniGridEnv("MiniGrid-Empty-5x5-v0", num_envs=3, seed=0)
    td = env.rollout(400, break_when_all_done=True)
    done = td["next", "done"].squeeze(-1)
    first_end = done.float().argmax(1)
    assert done.any(1).all() and len(set(first_end.tolist())) > 1
    assert td.shape[1] == first_end.max() + 1
    for i, end in enumerate(first_end.tolist()):
        assert done[i, end:].all() and not done[i, :end].any()


def test_stepping_a_finished_env_is_an_error():
    env = EnvPoolMiniGridEnv(MULTIROOM_N3_S4, num_envs=2, seed=0)
    td = env.reset()
    turn = torch.zeros(2, dtype=torch.long)
    for _ in range(60):
        td = env.step_mdp(env.step(td.set("action", turn)))
    with pytest.raises(RuntimeError, match=r"envs \[0, 1\] .* were not reset"):
        env.step(td.set("action", turn))
    with pytest.raises(ValueError, match=r"actions must be in \[0, 7\)"):
        env.step(env.reset().set("action", torch.full((2,), 7)))


def test_collector_random_policy():
    factory = functools.partial(
        make_minigrid_env, MULTIROOM_N3_S4, num_envs=4, seed=0, backend="envpool"
    )
    collector = Collector(factory, policy=None, frames_per_batch=128, total_frames=512)
    batches = list(collector)
    collector.shutdown()
    done = torch.cat([b["next", "done"] for b in batches], 1).squeeze(-1)
    assert done.any(1).all()
    traj_ids = torch.cat([b["collector", "traj_ids"] for b in batches], 1)
    assert (traj_ids[:, -1] > traj_ids[:, 0]).all()
    # After an episode end, the next step starts from the reset observation.
    images = torch.cat([b["image"] for b in batches], 1)
    next_images = torch.cat([b["next", "image"] for b in batches], 1)
    cont = ~done[:, :-1]
    assert torch.equal(images[:, 1:][cont], next_images[:, :-1][cont])


def test_same_seed_same_layouts():
    def first_grids(seed, num_envs=4):
        env = EnvPoolMiniGridEnv(MULTIROOM_N4_S4, num_envs=num_envs, seed=seed)
        env.reset()
        grids = [tuple(s.grid) for s in env.debug_states()]
        env.close()
        return grids

    assert first_grids(7) == first_grids(7)
    assert first_grids(7) != first_grids(8)
    # Sub-env i of seed s is sub-env 0 of seed s + i, as for the gymnasium backend.
    assert first_grids(7)[2] == first_grids(9, num_envs=1)[0]


def test_set_seed_rebuilds_the_pool():
    env = EnvPoolMiniGridEnv(DOORKEY, num_envs=2, seed=1)
    first = env.reset()["image"].clone()
    env.rollout(20)
    env.set_seed(1)
    assert env.seed == 1
    assert torch.equal(env.reset()["image"], first)


def test_errors():
    with pytest.raises(ValueError, match="MiniGrid-DoorKey-8x8-v0") as err:
        make_minigrid_env("MiniGrid-DoorKye-8x8-v0", backend="envpool")
    assert "envpool has no MiniGrid task 'MiniGrid-DoorKye-8x8-v0'" in str(err.value)
    assert "backend='gymnasium'" not in str(err.value)  # no such task anywhere
    # minigrid's -v1 MultiRoom: the backend that runs it is named before the
    # close envpool id (-v0 is another task)
    with pytest.raises(UnknownMiniGridTask) as err:
        make_minigrid_env("MiniGrid-MultiRoom-N4-S5-v1", backend="envpool")
    message = str(err.value)
    assert message.index("backend='gymnasium'") < message.index("N4-S5-v0")
    with pytest.raises(ValueError, match="backend must be one of"):
        make_minigrid_env(DOORKEY, backend="jax")
    with pytest.raises(ValueError, match="num_threads"):
        EnvPoolMiniGridEnv(DOORKEY, num_threads=0)
    with pytest.raises(ValueError, match="seed must be in"):
        EnvPoolMiniGridEnv(DOORKEY, num_envs=2, seed=2**31 - 1)


def test_missing_envpool_names_the_extra():
    code = (
        "import sys; sys.modules['envpool'] = None\n"
        "import torchrl_surprise, torchrl_surprise.envs\n"
        "from torchrl_surprise.envs import make_minigrid_env\n"
        "try:\n"
        "    make_minigrid_env('MiniGrid-DoorKey-8x8-v0', backend='envpool')\n"
        "except ModuleNotFoundError as err:\n"
        "    print(err)\n"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=120
    )
    assert 'pip install "torchrl_surprise[envpool]"' in out.stdout, out.stderr


def test_package_import_does_not_import_envpool():
    code = (
        "import sys, torchrl_surprise, torchrl_surprise.envs\n"
        "from torchrl_surprise.envs import make_minigrid_env\n"
        "make_minigrid_env('MiniGrid-Empty-5x5-v0', num_envs=1)\n"
        "print('envpool' in sys.modules)\n"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=120
    )
    assert out.stdout.strip().splitlines()[-1] == "False", out.stderr


# Exact resume ----------------------------------------------------------------------
def test_runtime_state_replays_to_the_same_future():
    num_envs = 3
    gen = torch.Generator().manual_seed(0)
    actions = torch.randint(7, (300, num_envs), generator=gen)

    def run(env, td, rows):
        out = []
        for t in rows:
            td, td_next = env.step_and_maybe_reset(td.set("action", actions[t].clone()))
            out.append(td["next"].clone())
            td = td_next
        return td, torch.stack(out, 1)

    env = EnvPoolMiniGridEnv(MULTIROOM_N3_S4, num_envs=num_envs, seed=2)
    td, _ = run(env, env.reset(), range(130))  # episode ends and partial resets
    state = env.runtime_state()
    carrier = td.clone()
    _, expected = run(env, td, range(130, 300))

    resumed = EnvPoolMiniGridEnv(MULTIROOM_N3_S4, num_envs=num_envs, seed=99)
    resumed.reset()
    resumed.load_runtime_state(state)
    assert resumed.runtime_state()["steps"] == state["steps"] == 130
    _, got = run(resumed, carrier, range(130, 300))
    assert torch.equal(got["image"], expected["image"])
    assert torch.equal(got["reward"], expected["reward"])
    assert torch.equal(got["done"], expected["done"])
    with pytest.raises(ValueError, match="num_envs=3"):
        EnvPoolMiniGridEnv(MULTIROOM_N3_S4, num_envs=2).load_runtime_state(state)


def test_reseed_barrier_same_in_uninterrupted_and_resumed_run():
    """A checkpoint barrier: both runs rebuild the pool from (seed, frames)."""

    def after_barrier(env):
        env.reseed(barrier_seed(0, 100))
        assert env.runtime_state()["steps"] == 0
        torch.manual_seed(1)
        return env.rollout(40)["next", "image"]

    uninterrupted = EnvPoolMiniGridEnv(DOORKEY, num_envs=2, seed=0)
    uninterrupted.rollout(50)
    resumed = EnvPoolMiniGridEnv(DOORKEY, num_envs=2, seed=0)
    assert torch.equal(after_barrier(uninterrupted), after_barrier(resumed))


def test_resumable_collector_continues_exactly():
    """torchrl_surprise's ResumableCollector saves and replays the envpool env."""
    from torchrl.envs.utils import RandomPolicy

    from torchrl_surprise.collectors import ResumableCollector

    def collector(state=None):
        env = make_minigrid_env(
            MULTIROOM_N3_S4, num_envs=4, seed=0, backend="envpool", num_threads=1
        )
        c = ResumableCollector(
            env, RandomPolicy(env.action_spec), frames_per_batch=128, total_frames=1024
        )
        if state is not None:
            c.load_state_dict(state)
        return c

    torch.manual_seed(0)
    first = collector()
    it = iter(first)
    for _ in range(3):  # 96 steps per env: episode ends and partial resets
        next(it)
    saved, rng = first.state_dict(), torch.get_rng_state()
    expected = [next(it) for _ in range(2)]
    resumed = collector(saved)
    torch.set_rng_state(rng)
    it = iter(resumed)
    for batch, want in zip([next(it) for _ in range(2)], expected):
        for key in ("image", ("next", "image"), ("next", "reward"), ("next", "done")):
            assert torch.equal(batch[key], want[key]), key
    assert torch.cat([b["next", "done"] for b in expected], 1).any()
