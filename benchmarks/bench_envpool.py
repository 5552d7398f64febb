"""Steps per CPU second of the MiniGrid backends, as ratios to a raw gymnasium loop.

For each task, in one process and interleaved over rounds (so that all setups see
the same machine load): a raw gymnasium loop of one env (random actions, reset at
episode ends), ``make_minigrid_env(16, backend="gymnasium")`` and
``make_minigrid_env(16, backend="envpool")`` with 1 and 2 threads (both through
``env.rollout`` with random actions, TorchRL resetting finished envs), and, as
the ceiling, envpool's own loop of 16 envs on 1 thread (its autoreset, no TorchRL). Steps are
env steps (16 per batched step). CPU time is ``time.process_time`` (all threads
of this process), wall time ``time.perf_counter``; the table shows the medians
over rounds and the ratios of the medians to the raw loop's.

Usage::

    python benchmarks/bench_envpool.py --rounds 3 --steps 20000
"""

from __future__ import annotations

import argparse
import os
import statistics
import time
from collections.abc import Callable

import gymnasium as gym
import numpy as np
import torch

from torchrl_surprise.envs.minigrid import make_minigrid_env, register_minigrid_envs

TASKS = ("MiniGrid-DoorKey-8x8-v0", "MiniGrid-MultiRoom-N3-S4-v0")
NUM_ENVS = 16


def raw_loop(task: str, steps: int) -> Callable[[], int]:
    register_minigrid_envs()
    env = gym.make(task)
    env.reset(seed=0)
    rng = np.random.default_rng(0)

    def run() -> int:
        for action in rng.integers(7, size=steps):
            _, _, terminated, truncated, _ = env.step(int(action))
            if terminated or truncated:
                env.reset()
        return steps

    return run


def raw_envpool(task: str, steps: int) -> Callable[[], int]:
    """envpool's own loop (its autoreset), the ceiling of the TorchRL env."""
    import envpool

    from torchrl_surprise.envs.envpool import envpool_minigrid_task

    name, kwargs = envpool_minigrid_task(task)
    pool = envpool.make(
        name, env_type="gymnasium", num_envs=NUM_ENVS, seed=0, num_threads=1, **kwargs
    )
    pool.reset()
    rng = np.random.default_rng(0)
    batched_steps = max(1, steps // NUM_ENVS)

    def run() -> int:
        for actions in rng.integers(7, size=(batched_steps, NUM_ENVS)):
            pool.step(actions)
        return batched_steps * NUM_ENVS

    return run


def torchrl_rollout(task: str, steps: int, **kwargs) -> Callable[[], int]:
    env = make_minigrid_env(task, num_envs=NUM_ENVS, seed=0, **kwargs)
    batched_steps = max(1, steps // NUM_ENVS)

    def run() -> int:
        env.rollout(batched_steps, break_when_any_done=False)
        return batched_steps * NUM_ENVS

    return run


def measure(run: Callable[[], int]) -> tuple[float, float]:
    cpu, wall = time.process_time(), time.perf_counter()
    steps = run()
    return (
        steps / (time.process_time() - cpu),
        steps / (time.perf_counter() - wall),
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--steps", type=int, default=20000, help="env steps per run")
    args = parser.parse_args()
    torch.manual_seed(0)
    torch.set_num_threads(1)
    print(f"load average {os.getloadavg()[0]:.2f}, {os.cpu_count()} cores")
    header = (
        f"{'task':<30} {'setup':<26} {'steps/CPU s':>12} {'x raw':>6} "
        f"{'steps/wall s':>13} {'x raw':>6}"
    )
    print(header)
    print("-" * len(header))
    for task in TASKS:
        setups = {
            "raw gymnasium, 1 env": raw_loop(task, args.steps // 4),
            f"gymnasium, {NUM_ENVS} envs": torchrl_rollout(task, args.steps // 2),
            f"raw envpool, {NUM_ENVS} envs": raw_envpool(task, args.steps * 2),
            f"envpool, {NUM_ENVS} envs, 1 thread": torchrl_rollout(
                task, args.steps, backend="envpool", num_threads=1
            ),
            f"envpool, {NUM_ENVS} envs, 2 threads": torchrl_rollout(
                task, args.steps, backend="envpool", num_threads=2
            ),
        }
        for run in setups.values():  # warm-up
            run()
        results: dict[str, list[tuple[float, float]]] = {name: [] for name in setups}
        for r in range(args.rounds):
            names = list(setups) if r % 2 == 0 else list(reversed(setups))
            for name in names:
                results[name].append(measure(setups[name]))
        cpu_ref = statistics.median(c for c, _ in results["raw gymnasium, 1 env"])
        wall_ref = statistics.median(w for _, w in results["raw gymnasium, 1 env"])
        for name, values in results.items():
            cpu = statistics.median(c for c, _ in values)
            wall = statistics.median(w for _, w in values)
            print(
                f"{task:<30} {name:<26} {cpu:>12,.0f} {cpu / cpu_ref:>6.2f} "
                f"{wall:>13,.0f} {wall / wall_ref:>6.2f}"
            )


if __name__ == "__main__":
    main()
