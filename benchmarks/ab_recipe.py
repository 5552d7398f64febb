"""A/B of the MiniGrid recipe at two revisions: the median per-round ratio of
frames per CPU second, each run's own logged ``time/fps_cpu`` (its loop, not its
start-up), interleaved (A, B, B, A, ...) so that a shared machine's load moves
both alike.

    python benchmarks/ab_recipe.py --a HEAD~1 --b HEAD --rounds 4 -- \\
        algo=ppo bonus=none collector.total_frames=40960

``--a`` and ``--b`` are git revisions (checked out in temporary worktrees) or
``.`` for the working tree; everything after ``--`` is the recipe's command line
(evaluation and periodic checkpoints are pushed past the budget), and
``--b-extra`` adds overrides to B's runs only (a setting A's code has not got). Prints each
round and the median ratio B / A with the load average.
"""

from __future__ import annotations

import argparse
import csv
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
from collections.abc import Sequence
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def checkout(rev: str, into: Path) -> Path:
    """The tree at ``rev`` (a temporary git worktree at ``into``), or this one
    for ``.``."""
    if rev == ".":
        return ROOT
    path = into
    subprocess.run(
        ["git", "-C", str(ROOT), "worktree", "add", "--detach", str(path), rev],
        check=True,
        capture_output=True,
    )
    return path


def fps_cpu(tree: Path, args: Sequence[str], out: Path) -> float:
    """One recipe run in ``tree``; its last logged frames per CPU second."""
    shutil.rmtree(out, ignore_errors=True)
    env = dict(os.environ, PYTHONPATH=str(tree))
    command = [
        sys.executable,
        "recipes/minigrid/main.py",
        *args,
        f"hydra.run.dir={out}",
    ]
    command += [
        "eval.interval_frames=1000000000",
        "checkpoint.interval_frames=1000000000",
    ]
    subprocess.run(command, cwd=tree, env=env, check=True, capture_output=True)
    log = next(out.glob("logs/*/scalars/time/fps_cpu.csv"))
    with open(log) as f:
        return float(list(csv.reader(f))[-1][-1])


def main(argv: Sequence[str] | None = None) -> float:
    parser = argparse.ArgumentParser(prog="python benchmarks/ab_recipe.py")
    parser.add_argument("--a", required=True, help="git revision, or . (this tree)")
    parser.add_argument("--b", default=".", help="git revision, or . (default)")
    parser.add_argument("--rounds", type=int, default=4)
    parser.add_argument(
        "--b-extra",
        nargs="+",
        default=[],
        metavar="OVERRIDE",
        help="B's runs only (put the recipe's overrides after --)",
    )
    parser.add_argument("recipe_args", nargs="*", help="the recipe's overrides")
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        trees = {}
        try:
            trees = {"A": checkout(args.a, tmp / "tree_a")}
            trees["B"] = checkout(args.b, tmp / "tree_b")
            ratios = []
            for r in range(args.rounds):
                order = "AB" if r % 2 == 0 else "BA"
                extra = {"A": [], "B": args.b_extra}
                fps = {
                    k: fps_cpu(trees[k], [*args.recipe_args, *extra[k]], tmp / k)
                    for k in order
                }
                ratios.append(fps["B"] / fps["A"])
                print(
                    f"round {r + 1}: A {fps['A']:,.0f}  B {fps['B']:,.0f}  "
                    f"B/A {ratios[-1]:.3f}  (load {os.getloadavg()[0]:.1f})",
                    flush=True,
                )
        finally:
            for tree in trees.values():
                if tree != ROOT:
                    subprocess.run(
                        [
                            "git",
                            "-C",
                            str(ROOT),
                            "worktree",
                            "remove",
                            "--force",
                            str(tree),
                        ],
                        capture_output=True,
                    )
    median = statistics.median(ratios)
    print(f"B / A, median of {args.rounds} rounds: {median:.3f}")
    return median


if __name__ == "__main__":
    main()
