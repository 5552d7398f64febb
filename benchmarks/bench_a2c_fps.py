"""Frames/s of the A2C MiniGrid recipe with and without the bonus, as a ratio.

Runs ``recipes/a2c_minigrid/main.py`` for a short budget per bonus, interleaved
(none, vae, none, vae, ...) so that both see the same machine load, and prints
the median frames/s of each and their ratio against ``bonus=none``.

    python benchmarks/bench_a2c_fps.py --frames 30000 --repeats 2 --bonuses none vae icm rnd
"""

from __future__ import annotations

import argparse
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from torchrl_surprise.experiments import read_scalar_csv  # noqa: E402


def run(bonus: str, frames: int, env: str, out: Path) -> float:
    run_dir = out / f"{bonus}_{len(list(out.iterdir()))}"
    subprocess.run(
        [
            sys.executable,
            str(ROOT / "recipes" / "a2c_minigrid" / "main.py"),
            f"bonus={bonus}",
            f"env.name={env}",
            f"collector.total_frames={frames}",
            f"eval.interval_frames={10 * frames}",
            f"checkpoint.interval_frames={10 * frames}",
            f"hydra.run.dir={run_dir}",
        ],
        check=True,
        capture_output=True,
    )
    _, fps = read_scalar_csv(run_dir / "logs" / "a2c" / "scalars" / "time" / "fps.csv")
    return float(fps[-1])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--frames", type=int, default=30_000)
    parser.add_argument("--repeats", type=int, default=2)
    parser.add_argument("--env", default="MiniGrid-MultiRoom-N3-S4-v0")
    parser.add_argument("--bonuses", nargs="+", default=["none", "vae"])
    args = parser.parse_args()
    results: dict[str, list[float]] = {b: [] for b in args.bonuses}
    with tempfile.TemporaryDirectory() as tmp:
        for _ in range(args.repeats):
            for bonus in args.bonuses:
                results[bonus].append(run(bonus, args.frames, args.env, Path(tmp)))
    base = statistics.median(results[args.bonuses[0]])
    print(f"{args.env}, {args.frames} frames per run, {args.repeats} repeats")
    print(f"{'bonus':<8}{'frames/s (median)':>20}{'ratio':>10}")
    for bonus, values in results.items():
        med = statistics.median(values)
        print(f"{bonus:<8}{med:>20.0f}{med / base:>10.2f}")


if __name__ == "__main__":
    main()
