"""The command line the results tools that read runs' checkpoints share
(``latent_scale.py``, ``milestones.py``): run directories, a rollout's envs and
seed, the CSV to write; each run loaded or the command refused, naming why; the
table written and printed."""

from __future__ import annotations

import argparse
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import pandas as pd

__all__ = ["checkpoint_parser", "load_runs", "write_table"]


def checkpoint_parser(script: str, doc: str, *, envs: int) -> argparse.ArgumentParser:
    """The parser of ``recipes/results/<script>``: ``runs``, ``--envs`` (default
    ``envs``), ``--seed``, ``--out``; its description is ``doc``'s first paragraph.

    Examples:
        >>> parser = checkpoint_parser("tool.py", "Does X.\\n\\nMore.", envs=4)
        >>> args = parser.parse_args(["run_a", "--seed", "2"])
        >>> args.runs, args.envs, args.seed, args.out
        ([PosixPath('run_a')], 4, 2, None)
    """
    parser = argparse.ArgumentParser(
        prog=f"python recipes/results/{script}",
        description=doc.split("\n\n", 1)[0],
    )
    parser.add_argument(
        "runs", nargs="+", type=Path, help="run directories or checkpoint files"
    )
    parser.add_argument("--envs", type=int, default=envs, help="envs of the rollout")
    parser.add_argument("--seed", type=int, default=0, help="seed of the rollout")
    parser.add_argument("--out", type=Path, help="CSV to write")
    return parser


def load_runs(
    parser: argparse.ArgumentParser,
    runs: Sequence[Path],
    load: Callable[[Path], Any],
) -> dict[Path, Any]:
    """``load(run)`` for each run; a run without a checkpoint, or one ``load``
    refuses (``ValueError``), ends the command with the parser's error (exit 2)."""
    loaded = {}
    for run in runs:
        try:
            loaded[run] = load(run)
        except (FileNotFoundError, ValueError) as error:
            parser.error(str(error))
    return loaded


def write_table(table: pd.DataFrame, out: Path | None) -> None:
    """Writes ``table`` to ``out`` (when given) and prints it without its ``run``
    column."""
    if out is not None:
        out.parent.mkdir(parents=True, exist_ok=True)
        table.to_csv(out, index=False)
        print(f"wrote {out}")
    print(table.drop(columns="run").to_string(index=False))
