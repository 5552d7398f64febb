"""Step throughput of MiniGrid through TorchRL: our factory vs the alternatives.

Compares, with random actions, in one process:

* ``make_minigrid_env(num_envs=N)``: gymnasium ``SyncVectorEnv`` (auto-reset
  disabled, TorchRL resets) wrapped once by ``GymWrapper``;
* the same with ``AutoresetMode.SAME_STEP`` (see
  ``torchrl_surprise/envs/minigrid.py`` for why the factory does not use it);
* TorchRL ``SerialEnv(N)`` of single ``GymWrapper`` envs (mission dropped);
* a raw gymnasium loop over one env (the ceiling).

Usage::

    python benchmarks/bench_envs.py [--env MiniGrid-DoorKey-8x8-v0] [--num-envs 8]
        [--steps 4000] [--repeats 3]

Keep it short on a shared machine: the defaults take about 20 s.
"""

from __future__ import annotations

import argparse
import functools
import statistics
import time
from collections.abc import Callable

import gymnasium as gym
import torch
from gymnasium.wrappers import FilterObservation
from torchrl.envs import EnvBase, GymWrapper, SerialEnv

from torchrl_surprise.envs import MINIGRID_OBS_KEYS, make_minigrid_env
from torchrl_surprise.envs.minigrid import _make_single_minigrid

__all__ = ["main"]


def _single_gym_wrapper(env_name: str) -> EnvBase:
    env = FilterObservation(gym.make(env_name), list(MINIGRID_OBS_KEYS))
    return GymWrapper(env, categorical_action_encoding=True)


def _same_step_vector_env(env_name: str, num_envs: int) -> EnvBase:
    env_fn = functools.partial(_make_single_minigrid, env_name, None)
    vec_env = gym.vector.SyncVectorEnv(
        [env_fn] * num_envs, autoreset_mode=gym.vector.AutoresetMode.SAME_STEP
    )
    return GymWrapper(vec_env, categorical_action_encoding=True)


def _torchrl_steps_per_s(env: EnvBase, steps: int) -> tuple[float, float]:
    """Random-action rollout of ``steps`` total env steps (all sub-envs counted).

    Returns:
        Steps per second of wall-clock time and of this process's CPU time.
    """
    num_envs = max(env.batch_size.numel(), 1)
    env.rollout(20, break_when_any_done=False)  # warm-up
    horizon = max(steps // num_envs, 1)
    wall, cpu = time.perf_counter(), time.process_time()
    env.rollout(horizon, break_when_any_done=False)
    wall, cpu = time.perf_counter() - wall, time.process_time() - cpu
    return horizon * num_envs / wall, horizon * num_envs / cpu


def _raw_steps_per_s(env_name: str, steps: int) -> tuple[float, float]:
    env = gym.make(env_name)
    env.reset(seed=0)
    env.action_space.seed(0)
    wall, cpu = time.perf_counter(), time.process_time()
    for _ in range(steps):
        _, _, terminated, truncated, _ = env.step(env.action_space.sample())
        if terminated or truncated:
            env.reset()
    wall, cpu = time.perf_counter() - wall, time.process_time() - cpu
    env.close()
    return steps / wall, steps / cpu


def main(argv: list[str] | None = None) -> dict[str, float]:
    """Runs the benchmark and prints steps/s and ratios.

    Args:
        argv: command-line arguments (``None`` reads ``sys.argv``).

    Returns:
        Median wall-clock steps/s of each setup, by name.
    """
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--env", default="MiniGrid-DoorKey-8x8-v0")
    parser.add_argument("--num-envs", type=int, default=8)
    parser.add_argument("--steps", type=int, default=4000)
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args(argv)
    torch.set_num_threads(1)
    n = args.num_envs

    envs: dict[str, Callable[[], EnvBase]] = {
        f"make_minigrid_env(num_envs={n})": lambda: make_minigrid_env(
            args.env, num_envs=n, seed=0
        ),
        f"GymWrapper(SyncVectorEnv({n}), SAME_STEP)": lambda: _same_step_vector_env(
            args.env, n
        ),
        f"SerialEnv({n}) of GymWrapper (no mission)": lambda: SerialEnv(
            n, functools.partial(_single_gym_wrapper, args.env)
        ),
    }
    built = {name: build() for name, build in envs.items()}
    measures: dict[str, Callable[[], tuple[float, float]]] = {
        name: functools.partial(_torchrl_steps_per_s, env, args.steps)
        for name, env in built.items()
    }
    measures["raw gymnasium loop, 1 env"] = functools.partial(
        _raw_steps_per_s, args.env, args.steps
    )
    # Round-robin over the setups, so that load changes on a shared machine hit
    # them all alike; report the median of each.
    samples: dict[str, list[tuple[float, float]]] = {name: [] for name in measures}
    for _ in range(args.repeats):
        for name, measure in measures.items():
            samples[name].append(measure())
    for env in built.values():
        env.close()
    wall = {k: statistics.median(v[0] for v in vs) for k, vs in samples.items()}
    cpu = {k: statistics.median(v[1] for v in vs) for k, vs in samples.items()}

    ours = f"make_minigrid_env(num_envs={n})"
    print(f"{args.env}: random actions, {args.steps} steps, median of {args.repeats}")
    # CPU time of this process is less sensitive to other work on a shared machine.
    print(
        f"{'setup':<46}{'steps/s':>9}{'ours/this':>11}"
        f"{'steps/CPU-s':>13}{'ours/this':>11}"
    )
    for name in wall:
        print(
            f"{name:<46}{wall[name]:>9,.0f}{wall[ours] / wall[name]:>11.2f}"
            f"{cpu[name]:>13,.0f}{cpu[ours] / cpu[name]:>11.2f}"
        )
    return wall


if __name__ == "__main__":
    main()
