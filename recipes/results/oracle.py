"""The MiniGrid oracle's tables as CSVs: what the scores are divided by.

The oracle itself (the search, :func:`~torchrl_surprise.envs.oracle.solve_minigrid`,
and its summaries, :func:`~torchrl_surprise.envs.oracle.oracle_table`) is the
library's; this command writes its tables, as ``docs/results/oracle/`` holds them::

    python recipes/results/oracle.py --envs MiniGrid-MultiRoom-N3-S4-v0 \\
        MiniGrid-DoorKey-5x5-v0 --seeds 1000 --out docs/results/oracle/oracle_returns.csv
    python recipes/results/oracle.py --envs MiniGrid-MultiRoom-N3-S4-v0 \\
        --seeds 200 --action-noise 0.05 0.1 0.2 --out noisy_oracle.csv

(``--action-noise``: the best expected return when an executed action is replaced
by a random one with probability P,
:func:`~torchrl_surprise.envs.oracle.optimal_returns_under_action_noise`.)

Each table's second column, ``backend``, says whose layouts were solved:
``gymnasium`` (minigrid's Python envs, the layouts this command solves) or
``envpool`` (its C++ port's, ``benchmarks/envpool_oracle.py`` and
``benchmarks/suite_oracle.py``); ``recipes/results/aggregate.py`` reads the
oracle of a task by its env id and backend.
"""

from __future__ import annotations

import argparse
import csv
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from torchrl_surprise.envs.oracle import (
    NOISY_ORACLE_CSV_COLUMNS,
    ORACLE_CSV_COLUMNS,
    noisy_oracle_table,
    oracle_table,
)

__all__ = ["GYMNASIUM", "format_oracle_table", "main", "write_oracle_csv"]

#: The backend of minigrid's Python envs, whose layouts ``oracle_table`` solves
#: (``common.labels.GYMNASIUM``, the aggregation's name for it).
GYMNASIUM = "gymnasium"


def _format_value(value: Any) -> str:
    return f"{value:.4f}" if isinstance(value, float) else str(value)


def write_oracle_csv(
    rows: Sequence[dict[str, Any]],
    path: str | Path,
    columns: Sequence[str] = ORACLE_CSV_COLUMNS,
    *,
    backend: str = GYMNASIUM,
) -> Path:
    """Writes :func:`oracle_table` rows as a CSV (floats with 4 decimals), a
    ``backend`` column after ``env``.

    Args:
        rows: the rows, keyed by ``columns``.
        path: the CSV to write.
        columns: :data:`ORACLE_CSV_COLUMNS`, or :data:`NOISY_ORACLE_CSV_COLUMNS`
            for :func:`noisy_oracle_table` rows; ``env`` first.
        backend: whose layouts the rows solved, every row's ``backend``:
            ``gymnasium`` (minigrid's, :func:`oracle_table`'s) or ``envpool``.

    Returns:
        The path written (parent folders are created).

    Examples:
        >>> import tempfile
        >>> rows = oracle_table(["MiniGrid-DoorKey-5x5-v0"], 2)
        >>> with tempfile.TemporaryDirectory() as folder:
        ...     path = write_oracle_csv(rows, Path(folder) / "oracle.csv")
        ...     print(*path.read_text().splitlines()[:2], sep="\\n")
        env,backend,seeds,mean_return,std_return,mean_steps,min_steps,max_steps,max_episode_steps,solved_fraction,return_at_0.8_steps
        MiniGrid-DoorKey-5x5-v0,gymnasium,2,...
    """
    if not columns or columns[0] != "env":
        raise ValueError(f"the oracle's columns start with env, got {list(columns)}")
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open("w", newline="") as file:
        writer = csv.DictWriter(file, fieldnames=["env", "backend", *columns[1:]])
        writer.writeheader()
        for row in rows:
            cells = {key: _format_value(row[key]) for key in columns}
            writer.writerow({**cells, "backend": backend})
    return path


def format_oracle_table(
    rows: Sequence[dict[str, Any]], columns: Sequence[str] = ORACLE_CSV_COLUMNS
) -> str:
    """A fixed-width text table of :func:`oracle_table` rows, for a terminal.

    Examples:
        >>> rows = oracle_table(["MiniGrid-DoorKey-5x5-v0"], 2)
        >>> print(format_oracle_table(rows).splitlines()[0].split()[:3])
        ['env', 'seeds', 'mean_return']
    """
    cells = [list(columns)]
    cells += [[_format_value(row[key]) for key in columns] for row in rows]
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
        prog="python recipes/results/oracle.py",
        description="Shortest-solution (oracle) returns of MiniGrid tasks.",
    )
    parser.add_argument("--envs", nargs="+", required=True, help="MiniGrid ids")
    parser.add_argument(
        "--seeds", type=int, default=1000, help="seeds 0..N-1 per id (default 1000)"
    )
    parser.add_argument("--out", type=Path, default=None, help="CSV path to write")
    parser.add_argument(
        "--action-noise",
        type=float,
        nargs="+",
        default=None,
        metavar="P",
        help="instead, the best expected return when an action is replaced by a "
        "random one with probability P (one row per id and P; "
        "optimal_returns_under_action_noise)",
    )
    args = parser.parse_args(argv)
    if args.action_noise is None:
        rows, columns = oracle_table(args.envs, args.seeds), ORACLE_CSV_COLUMNS
    else:
        rows = noisy_oracle_table(args.envs, args.seeds, args.action_noise)
        columns = NOISY_ORACLE_CSV_COLUMNS
    print(format_oracle_table(rows, columns))
    if args.out is not None:
        print(f"wrote {write_oracle_csv(rows, args.out, columns)}")
    return rows


if __name__ == "__main__":
    main(sys.argv[1:])
