"""The oracle's return over envpool's layouts against minigrid's, one table.

For each task, the first layout of seeds ``0..n-1`` in both backends (envpool: one
pool of ``n`` envs seeded 0, whose env ``i`` is seeded ``i``; minigrid:
``reset(seed=i)``), each solved by :func:`~torchrl_surprise.envs.oracle.solve_minigrid`
(envpool's layouts rebuilt in minigrid by
:func:`~torchrl_surprise.envs.envpool.minigrid_env_from_envpool_state`). The
MultiRoom tasks are also measured without redrawing the layouts whose entry door
opens onto a room's corner (``redraw_corner_doors=False``, envpool's own
generator). ``z`` is the difference of the means over its standard error.

With ``--out FOLDER`` it also writes ``envpool_oracle_returns.csv`` there: the
rows of envpool's layouts (redrawn as the backend does), each task's env id with
``envpool`` in its ``backend`` column, which the aggregation reads as the oracle
of envpool runs' tasks (``recipes/results/aggregate.py``).

Usage::

    python benchmarks/envpool_oracle.py --seeds 1000 --out docs/results/oracle
"""

from __future__ import annotations

import argparse
import statistics
import sys
from pathlib import Path

import gymnasium as gym

from torchrl_surprise.envs import register_minigrid_envs
from torchrl_surprise.envs.envpool import (
    EnvPoolMiniGridEnv,
    minigrid_env_from_envpool_state,
)
from torchrl_surprise.envs.oracle import oracle_returns, oracle_row, solve_minigrid

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "recipes"))
from results.oracle import write_oracle_csv  # noqa: E402  (the tables' CSV writer)

TASKS = (
    "MiniGrid-MultiRoom-N3-S4-v0",
    "MiniGrid-MultiRoom-N4-S4-v0",
    "MiniGrid-DoorKey-8x8-v0",
)


def envpool_solutions(task: str, seeds: int, redraw: bool | None = None) -> list:
    """The oracle's solutions of envpool's first layouts of envs ``0..seeds-1``
    (``redraw``: the backend's ``redraw_corner_doors``; None: its default)."""
    env = EnvPoolMiniGridEnv(task, num_envs=seeds, seed=0, redraw_corner_doors=redraw)
    env.reset()
    states = env.debug_states()
    env.close()
    register_minigrid_envs()
    twin = gym.make(task)
    solutions = []
    for state in states:
        twin = minigrid_env_from_envpool_state(state, task, env=twin)
        solutions.append(solve_minigrid(twin))
    return solutions


def summary(solutions: list) -> tuple[float, float, float, float]:
    returns = [s.episode_return for s in solutions]
    n = len(returns)
    solved = [s.num_steps for s in solutions if s.solved]
    return (
        statistics.mean(returns),
        statistics.stdev(returns) / n**0.5,
        1 - len(solved) / n,
        statistics.mean(solved),
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=1000)
    parser.add_argument(
        "--out", type=Path, help="folder for envpool_oracle_returns.csv (optional)"
    )
    args = parser.parse_args()
    table = []
    header = (
        f"{'task':<30} {'layouts':<22} {'mean return':>12} {'s.e.':>7} "
        f"{'unsolvable':>10} {'mean steps':>10} {'z':>6}"
    )
    print(header)
    print("-" * len(header))
    for task in TASKS:
        ref = summary(oracle_returns(task, range(args.seeds)))
        rows = [("minigrid", ref)]
        solutions = envpool_solutions(task, args.seeds)
        table.append(oracle_row(task, solutions))
        rows.append(("envpool", summary(solutions)))
        if "MultiRoom" in task:
            raw = envpool_solutions(task, args.seeds, redraw=False)
            rows.append(("envpool, no redraw", summary(raw)))
        for name, (mean, se, unsolvable, steps) in rows:
            z = (
                (mean - ref[0]) / (se**2 + ref[1] ** 2) ** 0.5
                if name != "minigrid"
                else 0
            )
            print(
                f"{task:<30} {name:<22} {mean:>12.4f} {se:>7.4f} "
                f"{unsolvable:>10.1%} {steps:>10.2f} {z:>6.1f}"
            )
    if args.out is not None:
        path = args.out / "envpool_oracle_returns.csv"
        print(f"Wrote {write_oracle_csv(table, path, backend='envpool')}")


if __name__ == "__main__":
    main()
