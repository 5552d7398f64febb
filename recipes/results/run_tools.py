"""The command line the results tools that read runs' checkpoints share
(``latent_scale.py``, ``milestones.py``): run directories, a rollout's envs and
seed, the CSV to write and an earlier one to add to; each run loaded or the
command refused, naming why; the table written and printed."""

from __future__ import annotations

import argparse
import os
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import pandas as pd

__all__ = ["checkpoint_parser", "load_runs", "merge_earlier", "write_table"]


def checkpoint_parser(script: str, doc: str, *, envs: int) -> argparse.ArgumentParser:
    """The parser of ``recipes/results/<script>``: ``runs``, ``--envs`` (default
    ``envs``), ``--seed``, ``--out``, ``--from-data``; its description is
    ``doc``'s first paragraph.

    Examples:
        >>> parser = checkpoint_parser("tool.py", "Does X.\\n\\nMore.", envs=4)
        >>> args = parser.parse_args(["run_a", "--seed", "2"])
        >>> args.runs, args.envs, args.seed, args.out, args.from_data
        ([PosixPath('run_a')], 4, 2, None, None)
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
    parser.add_argument(
        "--from-data",
        type=Path,
        help=(
            "an earlier table of this tool (a committed CSV whose runs are no "
            "longer on disk): its rows are kept beside the runs given, a run "
            "given again replacing its row"
        ),
    )
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


def merge_earlier(
    parser: argparse.ArgumentParser, table: pd.DataFrame, earlier: Path | None
) -> pd.DataFrame:
    """``earlier``'s rows (when given), each run of ``table`` found there in its
    place, then ``table``'s other runs. A run is its ``run`` path, normalised
    (``runs/a`` and ``runs/./a`` are one run; a moved run is another). The
    earlier table's labels are read as written (a setting named ``NA`` stays
    one). An ``earlier`` that is missing, empty or has other columns than
    ``table`` ends the command with the parser's error (exit 2), naming them.

    Examples:
        >>> import tempfile
        >>> parser = checkpoint_parser("tool.py", "Does X.", envs=4)
        >>> old = pd.DataFrame({"run": ["runs/a", "runs/b"], "score": [0.5, 0.1]})
        >>> new = pd.DataFrame({"run": ["runs/c", "runs/./b"], "score": [0.9, 0.2]})
        >>> with tempfile.TemporaryDirectory() as folder:
        ...     old.to_csv(f"{folder}/old.csv", index=False)
        ...     merged = merge_earlier(parser, new, Path(f"{folder}/old.csv"))
        >>> merged.to_dict("list")
        {'run': ['runs/a', 'runs/./b', 'runs/c'], 'score': [0.5, 0.2, 0.9]}
    """
    if earlier is None:
        return table
    if not earlier.is_file():
        parser.error(f"--from-data {earlier} does not exist")
    labels = [c for c in ("run", "setting") if c in table.columns]
    try:
        old = pd.read_csv(
            earlier,
            dtype=dict.fromkeys(labels, str),
            keep_default_na=False,
            na_values={c: [""] for c in table.columns if c not in labels},
            float_precision="round_trip",
        )
    except pd.errors.EmptyDataError:
        parser.error(f"--from-data {earlier} is empty: give a table this tool wrote")
    if list(old.columns) != list(table.columns):
        parser.error(
            f"--from-data {earlier} has the columns {list(old.columns)}; this tool "
            f"writes {list(table.columns)}: give a table it wrote"
        )

    def run_of(paths: pd.Series) -> list[str]:
        return [os.path.normpath(str(path)) for path in paths]

    new = dict(zip(run_of(table["run"]), range(len(table))))
    rows = [
        table.iloc[[new[run]]] if run in new else old.iloc[[i]]
        for i, run in enumerate(run_of(old["run"]))
    ]
    kept = set(run_of(old["run"]))
    rows += [table.iloc[[i]] for run, i in new.items() if run not in kept]
    if not rows:
        return table
    return pd.concat(rows, ignore_index=True)


def write_table(table: pd.DataFrame, out: Path | None) -> None:
    """Writes ``table`` to ``out`` (when given) and prints it without its ``run``
    column."""
    if out is not None:
        out.parent.mkdir(parents=True, exist_ok=True)
        table.to_csv(out, index=False)
        print(f"wrote {out}")
    print(table.drop(columns="run").to_string(index=False))
