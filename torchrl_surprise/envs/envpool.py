"""MiniGrid on envpool's C++ backend, as a TorchRL env like the gymnasium one.

:class:`EnvPoolMiniGridEnv` steps ``num_envs`` MiniGrid envs in envpool
(``envpool.make(task, env_type="gymnasium", ...)``, ``pip install
"torchrl_surprise[envpool]"``) and writes exactly the entries, specs and dtypes of
:func:`~torchrl_surprise.envs.make_minigrid_env`'s gymnasium backend: ``image``
uint8 ``[B, 7, 7, 3]``, ``direction`` int64 ``[B]``, a categorical ``action``,
``("next", "reward")`` float32 ``[B, 1]``, ``done`` / ``terminated`` /
``truncated`` bool ``[B, 1]``. ``make_minigrid_env(..., backend="envpool")``
builds it.

What differs from envpool's own outputs, and why:

* **No autoreset.** envpool resets a finished env on the step *after* its last
  one. TorchRL resets finished envs itself (``env.rollout``, collectors), so
  :meth:`~EnvPoolMiniGridEnv._reset` resets exactly the envs of the ``_reset`` mask
  with envpool's ``reset(env_ids)``; the last observation of an episode is in
  ``("next", ...)``, the first of the next one at the root, with no spurious step.
  Stepping a finished env without resetting it is an error. (``reset(env_ids)``
  and stepping a finished env once to trigger the autoreset cost the same, one
  call into envpool; ``reset`` is also right for an env that is not finished.)
* **The reward of a success is MiniGrid's float64 value.** envpool computes
  ``1 - 0.9 * (step / max_steps)`` in float32 arithmetic, which differs from
  MiniGrid's float64 value rounded to float32 in the last bit for about 40% of
  ``(step, max_steps)`` pairs (e.g. step 19 of 60: 0.71500003 vs 0.71499997). A
  positive reward is recomputed from the episode's step and ``max_steps``.
* **A success on the last step is terminated.** envpool's gymnasium API reports
  ``terminated = done and not truncated`` with ``truncated = done and step >=
  max_steps``, so an episode that reaches the goal (or lava) on its last allowed
  step is ``terminated=False, truncated=True``; MiniGrid reports
  ``terminated=True, truncated=True``. On such steps, ``terminated`` is set where
  the reward is not zero or the agent stands on lava. A zero-reward failure on
  the very last step of the few tasks that have one (Memory, Fetch, GoToDoor,
  GoToObject, PutNear, RedBlueDoors, BabyAI) stays ``terminated=False``: the
  debug state does not say it.
* **MultiRoom layouts whose doors lead into a room's corner are drawn again.**
  envpool 1.2.5's MultiRoom generator places the next room with ``top_y =
  RandInt(y - size_y + 2, y + 1)`` (and likewise ``top_x``) for an entry door at
  ``y``, where minigrid draws from ``[y - size_y + 2, y)``: the room's top corner
  can fall on the door, which then opens onto two walls, and that room and every
  room after it, the goal's included, cannot be reached. With rooms of size 4
  that is one entry door in three: 61% of N3S4 layouts and 77% of N4S4 layouts
  are unsolvable (1000 seeds; minigrid: none). The env resets such envs again
  until their layout has none (``redraw_corner_doors``, on by default for the
  MultiRoom tasks); the oracle's mean return over the layouts drawn then matches
  minigrid's within its standard error (``benchmarks/envpool_oracle.py``).

The paper's tasks ``MiniGrid-MultiRoom-N3-S4-v0`` and ``-N4-S4-v0`` are envpool's
``MiniGrid-MultiRoom-N2-S4-v0`` with ``min_num_rooms = max_num_rooms = n``,
``max_room_size=4`` and ``max_episode_steps=20 * n``. Any envpool MiniGrid or
BabyAI task is reachable by its name. envpool generates its own layouts: the
same seed gives the same layouts in envpool, but not minigrid's.
:func:`minigrid_env_from_envpool_state` rebuilds an envpool state in a real
minigrid env (to compare them step for step, or to solve envpool's layouts with
:func:`~torchrl_surprise.envs.oracle.solve_minigrid`).

Exact resume: envpool's C++ state cannot be pickled, but envpool is deterministic
given its seed and the calls made to it. The env records, since its pool was
built, every reset (which envs) and every step (the actions, one byte per env);
:meth:`~EnvPoolMiniGridEnv.runtime_state` returns that log and
:meth:`~EnvPoolMiniGridEnv.load_runtime_state` rebuilds the pool from the seed
and replays it, after which the env steps exactly as the saved one would have
(the API of :class:`~torchrl_surprise.envs.vector.RuntimeStateMixin`, which
:class:`~torchrl_surprise.collectors.ResumableCollector` calls). The log grows by
``num_envs`` bytes per step and replaying costs a step per step;
:meth:`~EnvPoolMiniGridEnv.reseed` is a barrier that bounds both: it rebuilds the
pool from a new seed (all episodes in progress end; TorchRL must then reset the
env, e.g. ``collector.reset()``) and empties the log. Called at the same frames in
an uninterrupted run and in a resumed one (with :func:`barrier_seed`), both log
the same.

envpool is imported on first use, never when :mod:`torchrl_surprise.envs` is.
"""

from __future__ import annotations

import difflib
import functools
from types import SimpleNamespace
from typing import Any

import gymnasium as gym
import numpy as np
import torch
from tensordict import TensorDict, TensorDictBase
from torchrl.data import (
    Categorical,
    Composite,
    Unbounded,
    UnboundedDiscrete,
)
from torchrl.envs import EnvBase

from torchrl_surprise.envs.minigrid_ids import (
    UnknownMiniGridTask,
    register_minigrid_envs,
)

__all__ = [
    "ENVPOOL_PAPER_TASKS",
    "EnvPoolMiniGridEnv",
    "barrier_seed",
    "envpool_minigrid_task",
    "envpool_minigrid_tasks",
    "minigrid_env_from_envpool_state",
]

_INSTALL_HINT = 'pip install "torchrl_surprise[envpool]"'

ENVPOOL_PAPER_TASKS: dict[str, tuple[str, dict[str, int]]] = {
    f"MiniGrid-MultiRoom-N{n}-S4-v0": (
        "MiniGrid-MultiRoom-N2-S4-v0",
        {
            "min_num_rooms": n,
            "max_num_rooms": n,
            "max_room_size": 4,
            "max_episode_steps": 20 * n,
        },
    )
    for n in (3, 4)
}
"""The paper's MultiRoom ids, as an envpool task and its ``envpool.make`` kwargs."""

_SEED_BOUND = 2**31  # envpool seeds env i with seed + i, an int32
_NOT_STEPPED = 255  # action byte of an env left out of a partial step
_WALL, _DOOR, _LAVA = 2, 4, 9  # minigrid's object indices
_MAX_REDRAWS = 1000
_LOG_CHUNK = 4096  # rows of the action log allocated at once


def _import_envpool():
    try:
        import envpool
    except ModuleNotFoundError as err:
        raise ModuleNotFoundError(
            f"The envpool MiniGrid backend needs envpool, which is not installed: "
            f"{_INSTALL_HINT}.",
            name="envpool",
        ) from err
    return envpool


@functools.cache
def envpool_minigrid_tasks() -> tuple[str, ...]:
    """The MiniGrid and BabyAI task names the envpool backend accepts.

    envpool's own ``MiniGrid-*`` and ``BabyAI-*`` tasks, and the paper's ids of
    :data:`ENVPOOL_PAPER_TASKS`.

    Examples:
        >>> tasks = envpool_minigrid_tasks()
        >>> "MiniGrid-DoorKey-8x8-v0" in tasks, "MiniGrid-MultiRoom-N3-S4-v0" in tasks
        (True, True)
    """
    envpool = _import_envpool()
    native = [
        name
        for name in envpool.list_all_envs()
        if name.startswith("MiniGrid-") or name.startswith("BabyAI-")
    ]
    return tuple(sorted({*native, *ENVPOOL_PAPER_TASKS}))


def envpool_minigrid_task(env_name: str) -> tuple[str, dict[str, Any]]:
    """The envpool task and ``envpool.make`` kwargs of a MiniGrid id.

    Args:
        env_name: a name of :func:`envpool_minigrid_tasks`.

    Returns:
        ``(task, kwargs)``: the paper's ids map to envpool's MultiRoom-N2-S4 with
        their number of rooms and time limit; any other name maps to itself.

    Raises:
        ValueError: ``env_name`` is not an envpool MiniGrid task; the message lists
            close matches.

    Examples:
        >>> envpool_minigrid_task("MiniGrid-MultiRoom-N4-S4-v0")[1]["max_episode_steps"]
        80
        >>> envpool_minigrid_task("MiniGrid-DoorKey-8x8-v0")
        ('MiniGrid-DoorKey-8x8-v0', {})
    """
    if env_name in ENVPOOL_PAPER_TASKS:
        task, kwargs = ENVPOOL_PAPER_TASKS[env_name]
        return task, dict(kwargs)
    known = envpool_minigrid_tasks()
    if env_name in known:
        return env_name, {}
    close = difflib.get_close_matches(env_name, known, n=5, cutoff=0.6)
    register_minigrid_envs()
    # A task of minigrid's Python envs only: its backend runs it, a close envpool
    # id would be another task.
    python_only = (
        f"{env_name!r} is a task of minigrid's Python envs: run it with "
        "backend='gymnasium'. "
        if env_name in gym.registry
        else ""
    )
    raise UnknownMiniGridTask(
        f"envpool has no MiniGrid task {env_name!r}. "
        + python_only
        + (f"Close matches: {', '.join(close)}. " if close else "")
        + f"It has {len(known)} MiniGrid/BabyAI tasks, e.g. "
        f"{', '.join(known[:3])}; see envpool_minigrid_tasks()."
    )


def barrier_seed(seed: int, frames: int) -> int:
    """The seed of the pool rebuilt at a checkpoint barrier after ``frames`` frames.

    Drawn from ``numpy.random.SeedSequence([seed, frames])``, so the uninterrupted
    run and a resumed one rebuild the same pool at the same frame.

    Examples:
        >>> barrier_seed(0, 1000) == barrier_seed(0, 1000) != barrier_seed(0, 2000)
        True
    """
    state = np.random.SeedSequence([int(seed), int(frames)]).generate_state(1)[0]
    return int(state) % (_SEED_BOUND // 2)


class EnvPoolMiniGridEnv(EnvBase):
    """``num_envs`` MiniGrid envs stepped by envpool, as one batched TorchRL env.

    The entries, specs and batch semantics are those of
    :func:`~torchrl_surprise.envs.make_minigrid_env`'s gymnasium backend (see the
    module docstring for where envpool's outputs are corrected to match
    MiniGrid's). Actions are integers; ``make_minigrid_env(...,
    backend="envpool", categorical_action_encoding=False)`` adds the one-hot
    conversion the gymnasium backend uses. The mission is dropped.

    Sub-env ``i`` is envpool's env ``i`` of a pool seeded ``seed``, which envpool
    seeds with ``seed + i`` (so sub-env ``i`` of seed ``s`` lays out the same
    episodes as sub-env 0 of seed ``s + i``). :meth:`set_seed` rebuilds the pool.

    Args:
        env_name: a name of :func:`envpool_minigrid_tasks`, e.g.
            ``"MiniGrid-DoorKey-8x8-v0"`` or the paper's
            ``"MiniGrid-MultiRoom-N3-S4-v0"``.
        num_envs: number of envs stepped together (the batch size).
        seed: the pool's seed, in ``[0, 2**31 - num_envs)``; if ``None``, drawn
            from torch's global generator.
        num_threads: envpool's worker threads (1 was the fastest on 2 cores; see
            ``benchmarks/bench_envpool.py``).
        device: device of the output tensors.
        env_kwargs: extra ``envpool.make`` kwargs (e.g. ``{"max_episode_steps":
            100}``); they override the paper tasks' kwargs.
        redraw_corner_doors: reset again an env whose new layout has a door on a
            room's corner (module docstring); by default, for the MultiRoom tasks.

    Raises:
        ModuleNotFoundError: envpool is not installed (the message names the extra).
        ValueError: an unknown task (with close matches), ``num_envs < 1``,
            ``num_threads < 1`` or a seed out of range.

    Examples:
        >>> env = EnvPoolMiniGridEnv("MiniGrid-MultiRoom-N3-S4-v0", num_envs=4, seed=0)
        >>> td = env.rollout(100, break_when_any_done=False)
        >>> td["image"].shape, td["image"].dtype, td["direction"].dtype
        (torch.Size([4, 100, 7, 7, 3]), torch.uint8, torch.int64)
        >>> bool(td["next", "truncated"].any())  # 60-step episodes, reset by rollout
        True
        >>> env.close()
    """

    def __init__(
        self,
        env_name: str,
        num_envs: int = 16,
        seed: int | None = None,
        num_threads: int = 1,
        device: Any = "cpu",
        env_kwargs: dict[str, Any] | None = None,
        redraw_corner_doors: bool | None = None,
    ) -> None:
        if not isinstance(num_envs, int) or num_envs < 1:
            raise ValueError(f"num_envs must be a positive int, got {num_envs!r}.")
        if not isinstance(num_threads, int) or num_threads < 1:
            raise ValueError(
                f"num_threads must be a positive int, got {num_threads!r}."
            )
        task, kwargs = envpool_minigrid_task(env_name)
        kwargs.update(env_kwargs or {})
        super().__init__(device=device, batch_size=torch.Size([num_envs]))
        self.env_name = env_name
        self.num_envs = num_envs
        self.num_threads = num_threads
        self._task = task
        self._task_kwargs = kwargs
        self._pool = None
        if seed is None:
            seed = int(torch.randint(_SEED_BOUND - num_envs, ()).item())
        self._build_pool(seed)
        if redraw_corner_doors is None:
            redraw_corner_doors = self._pool.config["env_name"] == "multi_room"
        self.redraw_corner_doors = bool(redraw_corner_doors)
        self._make_specs()

    # The pool ------------------------------------------------------------------
    def _build_pool(self, seed: int) -> None:
        seed = int(seed)
        if not 0 <= seed < _SEED_BOUND - self.num_envs:
            raise ValueError(
                f"seed must be in [0, {_SEED_BOUND - self.num_envs}) (envpool seeds "
                f"env i with seed + i, an int32), got {seed}."
            )
        envpool = _import_envpool()
        if self._pool is not None:
            self._pool.close()
        self._pool = envpool.make(
            self._task,
            env_type="gymnasium",
            num_envs=self.num_envs,
            seed=seed,
            num_threads=self.num_threads,
            **self._task_kwargs,
        )
        self._seed = seed
        n = self.num_envs
        # What changes at each step lives in a plain namespace: setting an
        # attribute of the env itself goes through nn.Module.__setattr__.
        self._rt = SimpleNamespace(
            # Envs that ended an episode and must be reset before their next
            # step; a new pool's envs have not been reset yet.
            needs_reset=np.ones(n, dtype=bool),
            elapsed=np.zeros(n, dtype=np.int64),
            last_obs=None,  # (image, direction) of every env
            # Replay log since the pool was built: action rows (one byte per
            # env, _NOT_STEPPED for an env left out) and resets as (rows before,
            # env ids).
            log_chunks=[],
            log_rows=0,
            log_resets=[],
        )
        self._all_ids = np.arange(n, dtype=np.int32)

    @property
    def pool(self) -> Any:
        """The envpool ``gymnasium`` env behind this env."""
        return self._pool

    @property
    def seed(self) -> int:
        """The seed the current pool was built with."""
        return self._seed

    def _make_specs(self) -> None:
        space = self._pool.observation_space
        view = tuple(space["image"].shape)
        n_dirs = int(space["direction"].n)
        b = self.batch_size
        self.observation_spec = Composite(
            direction=Categorical(n_dirs, shape=b, dtype=torch.int64),
            image=UnboundedDiscrete(shape=(*b, *view), dtype=torch.uint8),
            shape=b,
        )
        self._num_actions = int(self._pool.action_space.n)
        self.action_spec = Categorical(self._num_actions, shape=b, dtype=torch.int64)
        self.reward_spec = Unbounded(shape=(*b, 1), dtype=torch.float32)
        self.done_spec = Composite(
            done=Categorical(2, shape=(*b, 1), dtype=torch.bool),
            terminated=Categorical(2, shape=(*b, 1), dtype=torch.bool),
            truncated=Categorical(2, shape=(*b, 1), dtype=torch.bool),
            shape=b,
        )

    # Log ------------------------------------------------------------------------
    def _log_step(self, actions: np.ndarray, ids: np.ndarray | None) -> None:
        row = self._rt.log_rows % _LOG_CHUNK
        if row == 0:
            self._rt.log_chunks.append(
                np.full((_LOG_CHUNK, self.num_envs), _NOT_STEPPED, dtype=np.uint8)
            )
        target = self._rt.log_chunks[-1][row]
        if ids is None:
            target[:] = actions
        else:
            target[ids] = actions
        self._rt.log_rows += 1

    # TorchRL API ----------------------------------------------------------------
    def _step(self, tensordict: TensorDictBase) -> TensorDictBase:
        action = tensordict.get("action")
        actions = action.numpy(force=True).astype(np.int32, copy=False)
        partial = tensordict.get("_step", None)
        ids = None
        if partial is not None and not bool(partial.all()):
            ids = self._all_ids[partial.view(-1).numpy(force=True)]
            actions = actions[ids]
        stepped = self._all_ids if ids is None else ids
        if self._rt.needs_reset[stepped].any():
            pending = stepped[self._rt.needs_reset[stepped]].tolist()
            raise RuntimeError(
                f"envs {pending} of {self.env_name!r} ended an episode and were not "
                "reset: reset them first (env.reset with a '_reset' mask; "
                "env.rollout and the collectors do it)."
            )
        if ((actions < 0) | (actions >= self._num_actions)).any():
            raise ValueError(
                f"actions must be in [0, {self._num_actions}), got {actions.tolist()}."
            )
        obs, reward, terminated, truncated, info = self._pool.step(actions, ids)
        self._log_step(actions, ids)
        elapsed = info["elapsed_step"]
        self._fix_last_steps(reward, terminated, truncated, elapsed, stepped)
        done = terminated | truncated
        image = torch.from_numpy(obs["image"])
        direction = torch.from_numpy(obs["direction"]).to(torch.int64)
        if ids is None:
            self._rt.elapsed[:] = elapsed
            self._rt.needs_reset[:] = done
            self._rt.last_obs = (image, direction)
            reward_t = torch.from_numpy(reward)
            out_done = torch.from_numpy(done)
            out_term = torch.from_numpy(terminated)
            out_trunc = torch.from_numpy(truncated)
        else:
            self._rt.elapsed[ids] = elapsed
            self._rt.needs_reset[ids] = done
            last_image, last_direction = self._rt.last_obs
            image = _scatter(last_image, ids, image)
            direction = _scatter(last_direction, ids, direction)
            # Envs left out of the step keep their observation, reward 0 and done
            # flags (they are done: env.rollout leaves out finished envs).
            self._rt.last_obs = (image, direction)
            reward_t = _scatter(torch.zeros(self.num_envs), ids, reward)
            left_out = np.ones(self.num_envs, dtype=bool)
            left_out[ids] = False
            prev = tensordict.get("done", None)
            prev_term = tensordict.get("terminated", None)
            prev_trunc = tensordict.get("truncated", None)
            out_done = _scatter(_or_false(prev, self.num_envs), ids, done)
            out_term = _scatter(_or_false(prev_term, self.num_envs), ids, terminated)
            out_trunc = _scatter(_or_false(prev_trunc, self.num_envs), ids, truncated)
        shape = (self.num_envs, 1)
        # Shapes and dtypes are right by construction: skip the checks.
        next_td = TensorDict._new_unsafe(
            {
                "image": image,
                "direction": direction,
                "reward": reward_t.view(shape),
                "done": out_done.view(shape),
                "terminated": out_term.view(shape),
                "truncated": out_trunc.view(shape),
            },
            batch_size=self.batch_size,
        )
        if self.device is not None and self.device != torch.device("cpu"):
            next_td = next_td.to(self.device)
        return next_td

    def _fix_last_steps(
        self,
        reward: np.ndarray,
        terminated: np.ndarray,
        truncated: np.ndarray,
        elapsed: np.ndarray,
        ids: np.ndarray,
    ) -> None:
        """MiniGrid's reward and flags where envpool's differ (module docstring).

        Works in place on envpool's output arrays, on the rare steps that end an
        episode with a success or on the time limit.
        """
        success = reward > 0
        ambiguous = truncated & ~success
        if not (success.any() or ambiguous.any()):
            return
        rows = np.flatnonzero(success | ambiguous)
        states = self._pool.debug_states(ids[rows].tolist())
        for row, state in zip(rows, states):
            if success[row]:
                # MiniGridEnv._reward, in float64 as MiniGrid computes it.
                reward[row] = 1 - 0.9 * (int(elapsed[row]) / int(state.max_steps))
            if truncated[row] and not terminated[row]:
                if reward[row] != 0 or _on_lava(state):
                    terminated[row] = True

    def _reset(self, tensordict: TensorDictBase | None = None, **kwargs: Any):
        mask = None if tensordict is None else tensordict.get("_reset", None)
        if mask is not None:
            mask = mask.reshape(self.num_envs).numpy(force=True)
        if mask is None or mask.all() or self._rt.last_obs is None:
            ids = self._all_ids
            obs, _ = self._pool.reset()
        else:
            ids = self._all_ids[mask]
            obs, _ = self._pool.reset(ids) if len(ids) else (None, None)
        if obs is not None:
            image_rows = torch.from_numpy(obs["image"])
            direction_rows = torch.from_numpy(obs["direction"]).to(torch.int64)
            if self.redraw_corner_doors:
                self._redraw_corner_doors(ids, image_rows, direction_rows)
        if len(ids) == self.num_envs:
            image, direction = image_rows, direction_rows
        else:
            image, direction = self._rt.last_obs
            if len(ids):
                image = _scatter(image, ids, image_rows)
                direction = _scatter(direction, ids, direction_rows)
        if len(ids):
            self._rt.log_resets.append((self._rt.log_rows, ids.copy()))
        self._rt.needs_reset[ids] = False
        self._rt.elapsed[ids] = 0
        self._rt.last_obs = (image, direction)
        false = torch.zeros(self.num_envs, 1, dtype=torch.bool)
        out = TensorDict(
            {
                "image": image,
                "direction": direction,
                "done": false,
                "terminated": false.clone(),
                "truncated": false.clone(),
            },
            batch_size=self.batch_size,
        )
        if self.device is not None and self.device != torch.device("cpu"):
            out = out.to(self.device)
        return out

    def _redraw_corner_doors(
        self, ids: np.ndarray, image: torch.Tensor, direction: torch.Tensor
    ) -> None:
        """Resets again, until none is left, the envs whose layout has a corner door.

        ``image`` and ``direction`` (rows of ``ids``) get the new first observations.
        """
        rows = np.arange(len(ids))
        for _ in range(_MAX_REDRAWS):
            states = self._pool.debug_states(ids[rows].tolist())
            rows = rows[[_has_corner_door(state) for state in states]]
            if not len(rows):
                return
            obs, _ = self._pool.reset(ids[rows])
            index = torch.from_numpy(rows)
            image[index] = torch.from_numpy(obs["image"])
            direction[index] = torch.from_numpy(obs["direction"]).to(torch.int64)
        raise RuntimeError(
            f"envs {ids[rows].tolist()} drew a MultiRoom layout with a door on a "
            f"room's corner {_MAX_REDRAWS} times in a row."
        )

    def _set_seed(self, seed: int | None) -> None:
        if seed is None:
            seed = int(torch.randint(_SEED_BOUND - self.num_envs, ()).item())
        self._build_pool(seed)

    def reseed(self, seed: int) -> None:
        """Rebuilds the pool from ``seed``: every episode in progress ends.

        A checkpoint barrier (module docstring): the replay log is emptied, and
        the env must be reset before its next step (``env.reset()``, or
        ``collector.reset()`` for a collector's env). Use :func:`barrier_seed`
        for a seed that depends only on the run's seed and frame count.

        Examples:
            >>> env = EnvPoolMiniGridEnv("MiniGrid-DoorKey-5x5-v0", num_envs=2, seed=0)
            >>> _ = env.rollout(10)
            >>> env.reseed(barrier_seed(0, 20))
            >>> env.runtime_state()["steps"]
            0
        """
        self._build_pool(seed)

    def close(self, *, raise_if_closed: bool = True) -> None:
        if self._pool is not None:
            self._pool.close()
            self._pool = None
        super().close(raise_if_closed=raise_if_closed)

    # Exact resume ----------------------------------------------------------------
    def runtime_state(self) -> dict[str, Any]:
        """What rebuilds this env exactly: its seed and the calls since.

        Returns:
            A dict of plain Python and numpy values (``env_name``, ``num_envs``,
            ``task_kwargs``, ``seed``, ``steps``, ``actions`` as a uint8 array
            ``[steps, num_envs]`` with 255 for an env left out of a step, and
            ``resets`` as ``(steps before, env ids)`` pairs).

        Examples:
            >>> env = EnvPoolMiniGridEnv("MiniGrid-DoorKey-5x5-v0", num_envs=2, seed=3)
            >>> turn = lambda td: td.set("action", torch.zeros(2, dtype=torch.long))
            >>> _ = env.rollout(30, policy=turn)
            >>> state = env.runtime_state()
            >>> state["steps"], state["actions"].shape
            (30, (30, 2))
            >>> other = EnvPoolMiniGridEnv("MiniGrid-DoorKey-5x5-v0", num_envs=2)
            >>> other.load_runtime_state(state)
            >>> forward = TensorDict(action=torch.full((2,), 2), batch_size=[2])
            >>> torch.equal(env.step(forward.clone())["next", "image"],
            ...             other.step(forward.clone())["next", "image"])
            True
        """
        if self._rt.log_rows:
            actions = np.concatenate(self._rt.log_chunks)[: self._rt.log_rows].copy()
        else:
            actions = np.zeros((0, self.num_envs), dtype=np.uint8)
        return {
            "env_name": self.env_name,
            "num_envs": self.num_envs,
            "task_kwargs": dict(self._task_kwargs),
            "seed": self._seed,
            "steps": self._rt.log_rows,
            "actions": actions,
            "resets": [(t, ids.copy()) for t, ids in self._rt.log_resets],
        }

    def load_runtime_state(self, state: dict[str, Any]) -> None:
        """Rebuilds the pool from the saved seed and replays the saved calls.

        Raises:
            ValueError: the state is of another task, ``num_envs`` or kwargs.
        """
        for key, mine in (
            ("env_name", self.env_name),
            ("num_envs", self.num_envs),
            ("task_kwargs", self._task_kwargs),
        ):
            if state[key] != mine:
                raise ValueError(
                    f"the saved envpool state has {key}={state[key]!r}, this env "
                    f"has {mine!r}: build it with the same arguments."
                )
        self._build_pool(state["seed"])
        actions = np.asarray(state["actions"], dtype=np.uint8)
        resets = list(state["resets"])
        r = 0
        for t in range(int(state["steps"]) + 1):
            while r < len(resets) and resets[r][0] == t:
                ids = np.asarray(resets[r][1], dtype=np.int32)
                self._replay_reset(ids)
                r += 1
            if t < len(actions):
                self._replay_step(actions[t])
        if r != len(resets):
            raise ValueError("the saved envpool state's resets are out of order.")

    def _replay_reset(self, ids: np.ndarray) -> None:
        mask = torch.zeros(self.num_envs, 1, dtype=torch.bool)
        mask[torch.from_numpy(ids.astype(np.int64))] = True
        self._reset(TensorDict({"_reset": mask}, batch_size=self.batch_size))

    def _replay_step(self, row: np.ndarray) -> None:
        stepped = row != _NOT_STEPPED
        action = torch.from_numpy(np.where(stepped, row, 0).astype(np.int64))
        td = TensorDict({"action": action}, batch_size=self.batch_size)
        if not stepped.all():
            td.set("_step", torch.from_numpy(stepped))
        self._step(td)

    # Inspection ------------------------------------------------------------------
    def debug_states(self, env_ids: list[int] | None = None) -> list[Any]:
        """envpool's full states of ``env_ids`` (all envs by default).

        Each has ``grid`` (``width * height * 3`` minigrid-encoded cells, x-major),
        ``agent_pos``, ``agent_dir``, the carried object, ``max_steps``,
        ``goal_pos``, ... (envpool's ``debug_states``).
        """
        ids = self._all_ids.tolist() if env_ids is None else list(env_ids)
        return self._pool.debug_states(ids)

    def elapsed_steps(self) -> np.ndarray:
        """Steps taken in each env's current episode."""
        return self._rt.elapsed.copy()

    def minigrid_envs(self, env_ids: list[int] | None = None) -> list[Any]:
        """The current state of ``env_ids`` rebuilt in minigrid envs.

        See :func:`minigrid_env_from_envpool_state`; each env's step count is its
        episode's step count here.

        Examples:
            >>> from torchrl_surprise.envs.oracle import solve_minigrid
            >>> env = EnvPoolMiniGridEnv("MiniGrid-DoorKey-5x5-v0", num_envs=2, seed=0)
            >>> _ = env.reset()
            >>> [solve_minigrid(e).solved for e in env.minigrid_envs()]
            [True, True]
        """
        ids = self._all_ids.tolist() if env_ids is None else list(env_ids)
        return [
            minigrid_env_from_envpool_state(
                state, self.env_name, step_count=int(self._rt.elapsed[i])
            )
            for i, state in zip(ids, self.debug_states(ids))
        ]


def _scatter(base: torch.Tensor, ids: np.ndarray, values: Any) -> torch.Tensor:
    out = base.clone()
    out[torch.from_numpy(np.asarray(ids, dtype=np.int64))] = torch.as_tensor(
        values, dtype=base.dtype
    )
    return out


def _or_false(value: torch.Tensor | None, n: int) -> torch.Tensor:
    if value is None:
        return torch.zeros(n, dtype=torch.bool)
    return value.reshape(n).cpu()


def _has_corner_door(state: Any) -> bool:
    """Whether a door has no two opposite cells that are not walls (a dead end)."""
    width, height = int(state.width), int(state.height)
    kinds = np.asarray(state.grid, dtype=np.uint8).reshape(width, height, 3)[..., 0]
    for x, y in zip(*np.nonzero(kinds == _DOOR)):
        across = 0 < x < width - 1 and _WALL not in (kinds[x - 1, y], kinds[x + 1, y])
        along = 0 < y < height - 1 and _WALL not in (kinds[x, y - 1], kinds[x, y + 1])
        if not (across or along):
            return True
    return False


def _on_lava(state: Any) -> bool:
    x, y = (int(v) for v in state.agent_pos)
    grid = np.asarray(state.grid, dtype=np.uint8).reshape(state.width, state.height, 3)
    return bool(grid[x, y, 0] == _LAVA)


# Rebuilding envpool states in minigrid ---------------------------------------------
_TYPE_NAMES = (
    "unseen",
    "empty",
    "wall",
    "floor",
    "door",
    "key",
    "ball",
    "box",
    "goal",
    "lava",
    "agent",
)
_COLOR_NAMES = ("red", "green", "blue", "purple", "yellow", "grey")
# envpool's env_name -> the attribute its minigrid class reads in step(): the
# target object at target_pos (the agent wins by picking it up).
_TARGET_OBJECT_TASKS = frozenset(
    {
        "unlock_pickup",
        "blocked_unlock_pickup",
        "key_corridor",
        "obstructed_maze_1dlhb",
        "obstructed_maze_full",
        "obstructed_maze_full_v1",
    }
)
_REFUSED_TASKS = {
    "dynamic_obstacles": "its obstacles move at random in step()",
}


def _decode(type_idx: int, color_idx: int, state: int) -> Any:
    from minigrid.core.world_object import WorldObj

    return WorldObj.decode(int(type_idx), int(color_idx), int(state))


def _rebuild_grid(state: Any) -> Any:
    from minigrid.core.grid import Grid

    width, height = int(state.width), int(state.height)
    cells = np.asarray(state.grid, dtype=np.uint8).reshape(width, height, 3)
    contains = np.asarray(state.grid_contains, dtype=np.uint8).reshape(width, height, 3)
    grid = Grid(width, height)
    for x in range(width):
        for y in range(height):
            obj = _decode(*cells[x, y])
            if obj is not None:
                inner = _decode(*contains[x, y])
                if inner is not None:
                    obj.contains = inner
                obj.init_pos = (x, y)
                obj.cur_pos = (x, y)
            grid.set(x, y, obj)
    return grid


def _rebuild_carrying(state: Any) -> Any:
    if not state.has_carrying:
        return None
    obj = _decode(state.carrying_type, state.carrying_color, state.carrying_state)
    if state.carrying_has_contains:
        inner = _decode(
            state.carrying_contains_type,
            state.carrying_contains_color,
            state.carrying_contains_state,
        )
        if inner is not None:
            obj.contains = inner
    obj.init_pos = None
    obj.cur_pos = np.array([-1, -1])
    return obj


def _find(grid: Any, kind: str, color: str | None = None) -> Any:
    for obj in grid.grid:
        if obj is not None and obj.type == kind and color in (None, obj.color):
            return obj
    return None


def minigrid_env_from_envpool_state(
    state: Any, env_name: str, *, step_count: int = 0, env: Any = None
) -> Any:
    """A minigrid env in the state of an envpool MiniGrid env.

    Builds ``gymnasium.make(env_name)`` (the paper's ids are registered first),
    resets it, then overwrites its grid (``minigrid.core.grid.Grid.decode`` of
    envpool's cells, box contents included), size, agent position and direction,
    carried object, mission, ``step_count`` and ``max_steps``, and the attributes
    the task's ``step`` reads (the object to pick up in KeyCorridor, UnlockPickup
    and ObstructedMaze, the door in Unlock, the targets of Fetch, GoToDoor,
    GoToObject, PutNear, Memory, the doors of RedBlueDoors). Stepping it then
    does what envpool does (``tests/test_envpool.py`` checks it step for step),
    and :func:`~torchrl_surprise.envs.oracle.solve_minigrid` solves it.

    The grid takes envpool's size, which is not always minigrid's: envpool lays
    ObstructedMaze-1Dl/1Dlh/1Dlhb out on 16x16 (3x3 rooms, only two of them
    used), minigrid on 11x6.

    Args:
        state: one entry of envpool's ``debug_states`` (or
            :meth:`EnvPoolMiniGridEnv.debug_states`).
        env_name: the MiniGrid id of the task, as given to
            :class:`EnvPoolMiniGridEnv`.
        step_count: steps already taken in the episode (0 at its start).
        env: a ``gymnasium.make(env_name)`` env to overwrite in place (rebuilding
            many states is then faster); a new one if ``None``.

    Returns:
        The ``gymnasium.make`` env (wrappers included), ready to ``step``.

    Raises:
        ValueError: a task whose state cannot be rebuilt (Dynamic-Obstacles: its
            obstacles move at random), or a state of another task.

    Examples:
        >>> import envpool
        >>> pool = envpool.make("MiniGrid-DoorKey-8x8-v0", env_type="gymnasium",
        ...                     num_envs=1, seed=0)
        >>> obs, _ = pool.reset()
        >>> env = minigrid_env_from_envpool_state(
        ...     pool.debug_states([0])[0], "MiniGrid-DoorKey-8x8-v0")
        >>> bool((env.unwrapped.gen_obs()["image"] == obs["image"][0]).all())
        True
    """

    # minigrid's ids and the paper's MultiRoom ids, in gymnasium's registry
    register_minigrid_envs()
    name = str(state.env_name)
    if name in _REFUSED_TASKS:
        raise ValueError(
            f"an envpool {name!r} state cannot be rebuilt in minigrid: "
            f"{_REFUSED_TASKS[name]}."
        )
    if env is None:
        env = gym.make(env_name)
    # A reset first: the wrappers' flags and the task's own attributes exist.
    env.reset(seed=0)
    base = env.unwrapped
    if int(state.max_steps) <= 0:
        raise ValueError(f"the envpool state has max_steps={state.max_steps}.")
    base.grid = _rebuild_grid(state)
    base.width, base.height = base.grid.width, base.grid.height
    base.agent_pos = tuple(int(v) for v in state.agent_pos)
    base.agent_dir = int(state.agent_dir)
    base.carrying = _rebuild_carrying(state)
    base.mission = str(state.mission)
    base.step_count = int(step_count)
    base.max_steps = int(state.max_steps)
    _set_task_attributes(base, state, name)
    return env


def _set_task_attributes(base: Any, state: Any, name: str) -> None:
    grid = base.grid
    target_pos = tuple(int(v) for v in state.target_pos)
    target_type = _TYPE_NAMES[int(state.target_type)]
    target_color = _COLOR_NAMES[int(state.target_color)]
    if name in _TARGET_OBJECT_TASKS:
        obj = grid.get(*target_pos) if min(target_pos) >= 0 else None
        carried = base.carrying
        if obj is None and carried is not None:
            if carried.type == target_type and carried.color == target_color:
                obj = carried
        base.obj = obj
    elif name == "unlock":
        base.door = _find(grid, "door")
    elif name == "fetch":
        base.targetType, base.targetColor = target_type, target_color
    elif name == "goto_door":
        base.target_pos, base.target_color = target_pos, target_color
    elif name == "goto_object":
        base.targetType, base.target_color = target_type, target_color
        base.target_pos = target_pos
    elif name == "put_near":
        base.move_type = _TYPE_NAMES[int(state.move_type)]
        base.moveColor = _COLOR_NAMES[int(state.move_color)]
        base.move_pos = tuple(int(v) for v in state.move_pos)
        base.target_type, base.target_color = target_type, target_color
        base.target_pos = target_pos
    elif name == "red_blue_door":
        base.red_door = _find(grid, "door", "red")
        base.blue_door = _find(grid, "door", "blue")
    elif name == "memory":
        base.success_pos = tuple(int(v) for v in state.success_pos)
        base.failure_pos = tuple(int(v) for v in state.failure_pos)
