"""The oracle's return on the hard-exploration suite, over minigrid's and envpool's layouts.

For each task, the first layout of seeds ``0..n-1`` in both backends (minigrid:
``reset(seed=i)``; envpool: one pool of ``n`` envs seeded 0, whose env ``i`` is
seeded ``i``, rebuilt in minigrid by
:func:`~torchrl_surprise.envs.envpool.minigrid_env_from_envpool_state`), each solved
by :func:`~torchrl_surprise.envs.oracle.solve_minigrid` (a shortest solution, so the
return is the best achievable with the whole grid in view). Prints the mean return
with its standard error (population std / sqrt(n)), the mean and largest number of
steps and the seconds per layout, and writes one CSV per backend with the columns of
:data:`~torchrl_surprise.envs.oracle.ORACLE_CSV_COLUMNS` and a ``backend`` column
(``gymnasium`` for minigrid's layouts, ``envpool`` for envpool's: the backends of
the runs' configs, by which ``recipes/results/aggregate.py`` tells their tasks
apart); its ``--oracle`` reads both tables.

Usage::

    python benchmarks/suite_oracle.py --seeds 200 --out docs/results/oracle
"""

from __future__ import annotations

import argparse
import time
import warnings
from pathlib import Path

from envpool_oracle import envpool_solutions  # benchmarks/, beside this script

# recipes/results, which importing envpool_oracle put on sys.path
from results.oracle import format_oracle_table, write_oracle_csv
from torchrl_surprise.envs.oracle import oracle_returns, oracle_row

#: The ``backend`` column of each backend's table: the runs' ``env.backend``.
WRITTEN_BACKEND = {"minigrid": "gymnasium", "envpool": "envpool"}

TASKS = (
    "MiniGrid-KeyCorridorS3R3-v0",
    "MiniGrid-KeyCorridorS4R3-v0",
    "MiniGrid-KeyCorridorS6R3-v0",
    "MiniGrid-DoorKey-16x16-v0",
    "MiniGrid-MultiRoom-N6-v0",
    "MiniGrid-ObstructedMaze-1Dlhb-v0",
    "MiniGrid-ObstructedMaze-2Dlhb-v0",
    "MiniGrid-ObstructedMaze-2Dlhb-v1",
)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=200)
    parser.add_argument("--tasks", nargs="+", default=list(TASKS))
    parser.add_argument(
        "--backends", nargs="+", default=["minigrid", "envpool"],
        choices=["minigrid", "envpool"],
    )  # fmt: skip
    parser.add_argument(
        "--out", type=Path, default=None,
        help="folder for suite_oracle_returns[_envpool].csv",
    )  # fmt: skip
    args = parser.parse_args()
    warnings.filterwarnings("ignore", message=".*is out of date.*")
    header = (
        f"{'task':<34} {'backend':<9} {'n':>4} {'mean return':>11} {'s.e.':>7} "
        f"{'solved':>7} {'mean steps':>10} {'max steps':>9} {'s/layout':>8}"
    )
    print(header)
    print("-" * len(header))
    tables: dict[str, list] = {backend: [] for backend in args.backends}
    for task in args.tasks:
        for backend in args.backends:
            start = time.perf_counter()
            if backend == "minigrid":
                solutions = oracle_returns(task, range(args.seeds))
            else:
                solutions = envpool_solutions(task, args.seeds)
            seconds = (time.perf_counter() - start) / args.seeds
            row = oracle_row(task, solutions)
            tables[backend].append(row)
            se = row["std_return"] / row["seeds"] ** 0.5
            print(
                f"{task:<34} {backend:<9} {row['seeds']:>4} "
                f"{row['mean_return']:>11.4f} {se:>7.4f} "
                f"{row['solved_fraction']:>7.1%} {row['mean_steps']:>10.2f} "
                f"{row['max_steps']:>9} {seconds:>8.3f}",
                flush=True,
            )
    for backend, rows in tables.items():
        print(f"\n{backend}:\n{format_oracle_table(rows)}")
        if args.out is not None:
            suffix = "" if backend == "minigrid" else f"_{backend}"
            path = args.out / f"suite_oracle_returns{suffix}.csv"
            written = write_oracle_csv(rows, path, backend=WRITTEN_BACKEND[backend])
            print(f"wrote {written}")


if __name__ == "__main__":
    main()
