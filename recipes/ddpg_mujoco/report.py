"""Summarises DDPG runs: evaluation returns per run, a CSV and a figure.

    python recipes/ddpg_mujoco/report.py runs/ddpg_halfcheetah/none runs/ddpg_halfcheetah/vae --out docs/results/ddpg_halfcheetah

Each run directory is one run of ``main.py`` (``hydra.run.dir=<dir>``); its name
labels the run. Only what the runs logged is read.
"""

from __future__ import annotations

import argparse
import csv
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from torchrl_surprise.experiments import plot_learning_curves, read_scalar_csv  # noqa: E402


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("runs", nargs="+", type=Path)
    parser.add_argument("--out", type=Path, required=True)
    args = parser.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    rows, curves = [], {}
    for run in args.runs:
        scalars = run / "logs" / "ddpg" / "scalars"
        steps, returns = read_scalar_csv(scalars / "eval" / "episode_return.csv")
        _, fps = read_scalar_csv(scalars / "time" / "fps.csv")
        _, ups = read_scalar_csv(scalars / "time" / "updates_per_s.csv")
        curves[run.name] = (steps, returns)
        rows.append(
            {
                "run": run.name,
                "frames": int(steps[-1]),
                "eval_return_last": round(float(returns[-1]), 1),
                "eval_return_best": round(float(returns.max()), 1),
                "eval_returns": " ".join(
                    f"{int(s)}:{r:.0f}" for s, r in zip(steps, returns)
                ),
                "frames_per_s": round(float(fps[len(fps) // 2 :].mean()), 1),
                "updates_per_s": round(float(ups[len(ups) // 2 :].mean()), 1),
            }
        )
    with open(args.out / "summary.csv", "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    with open(args.out / "curves.csv", "w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow(["run", "frames", "eval_return"])
        for name, (steps, returns) in curves.items():
            writer.writerows(
                [name, int(s), round(float(r), 2)] for s, r in zip(steps, returns)
            )
    plot_learning_curves(
        curves,
        args.out / "curves.png",
        title="deterministic evaluation return (extrinsic)",
    )
    for row in rows:
        print(row)


if __name__ == "__main__":
    main()
