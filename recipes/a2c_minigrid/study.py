"""Runs a named set of A2C settings, resumably, and summarises them.

Each setting is one run of ``main.py`` in ``<out>/<name>``. Rerunning the command
skips finished runs and resumes killed ones from their checkpoints, so a study
survives the machine being stopped. ``--report`` writes, for every finished run,
the frames at which the 100-episode mean extrinsic return first reached 0.5 and
0.8 (counted once 100 episodes have ended), a CSV of the curves and a figure.

    python recipes/a2c_minigrid/study.py --study n3s4 --out runs/study_n3s4 --jobs 2
    python recipes/a2c_minigrid/study.py --study n3s4 --out runs/study_n3s4 --report docs/results/n3s4
"""

from __future__ import annotations

import argparse
import csv
import os
import subprocess
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parents[1]))

from torchrl_surprise.experiments import (  # noqa: E402
    load_checkpoint,
    plot_learning_curves,
    read_scalar_csv,
)

N3S4 = "env.name=MiniGrid-MultiRoom-N3-S4-v0"
# The paper's literal form: one critic on r_ext + coef * r_int.
RAW = [
    "intrinsic.intrinsic_critic=false",
    "intrinsic.episodic=true",
    "intrinsic.normalization=none",
]
# RND's recipe: a second value head for non-episodic intrinsic returns, the bonus
# divided by the running std of its discounted return.
NONEPISODIC = [
    "intrinsic.intrinsic_critic=true",
    "intrinsic.episodic=false",
    "intrinsic.normalization=return_std",
    "intrinsic.coef=0.5",
]
STUDIES: dict[str, dict[str, list[str]]] = {
    # The A2C anchor: bonus=none must solve DoorKey-5x5 well under 300k frames.
    "anchor": {"none": ["env.name=MiniGrid-DoorKey-5x5-v0", "bonus=none"]},
    # MultiRoom-N4S4 (Figure 1, middle panel), the recipe's default bonus settings.
    "n4s4": {
        "vae": ["env.name=MiniGrid-MultiRoom-N4-S4-v0", "bonus=vae"],
        "icm": ["env.name=MiniGrid-MultiRoom-N4-S4-v0", "bonus=icm"],
        "none": ["env.name=MiniGrid-MultiRoom-N4-S4-v0", "bonus=none"],
    },
    # Figure 2: N3S4 with noise (torchrl_surprise.transforms.STOCHASTICITY_LEVELS),
    # the recipe's default bonus settings.
    "noise": {
        "vae_level2": [N3S4, "bonus=vae", "env.stochasticity=2"],
        "icm_level2": [N3S4, "bonus=icm", "env.stochasticity=2"],
        "vae_level3": [N3S4, "bonus=vae", "env.stochasticity=3"],
        "icm_level3": [N3S4, "bonus=icm", "env.stochasticity=3"],
    },
    # The paper's DoorKey-8x8 panel, with the recipe's default bonus settings.
    "doorkey8x8": {
        "vae": ["env.name=MiniGrid-DoorKey-8x8-v0", "bonus=vae"],
        "none": ["env.name=MiniGrid-DoorKey-8x8-v0", "bonus=none"],
    },
    # The settings tried on MultiRoom-N3S4, in the order of docs/report.rst.
    "n3s4": {
        "none": [N3S4, "bonus=none"],
        "vae_raw_c0.01": [N3S4, "bonus=vae", *RAW, "intrinsic.coef=0.01"],
        "vae_critic_nonepisodic": [N3S4, "bonus=vae", *NONEPISODIC],
        "vae_zscore_c0.01": [
            N3S4,
            "bonus=vae",
            *RAW,
            "intrinsic.normalization=zscore",
            "intrinsic.coef=0.01",
        ],
        "rnd_critic_nonepisodic": [N3S4, "bonus=rnd", *NONEPISODIC],
        "icm_critic_nonepisodic": [N3S4, "bonus=icm", *NONEPISODIC],
        "icm_raw_c0.01": [N3S4, "bonus=icm", *RAW, "intrinsic.coef=0.01"],
        "vae_raw_c0.001": [N3S4, "bonus=vae", *RAW, "intrinsic.coef=0.001"],
    },
}


def _alive(pid_file: Path) -> bool:
    try:
        os.kill(int(pid_file.read_text()), 0)
    except (FileNotFoundError, ValueError, ProcessLookupError):
        return False
    return True


def run_state(run_dir: Path, frames: int) -> str:
    if _alive(run_dir / "pid"):
        return "running"
    ckpt = run_dir / "checkpoint.pt"
    if not ckpt.exists():
        return "new"
    return "done" if load_checkpoint(ckpt)["frames"] >= frames else "partial"


def launch(name: str, overrides: list[str], out: Path, frames: int, seed: int):
    run_dir = out / name
    state = run_state(run_dir, frames)
    if state in ("done", "running"):
        return None
    args = [
        sys.executable,
        str(HERE / "main.py"),
        *overrides,
        f"collector.total_frames={frames}",
        f"seed={seed}",
        f"hydra.run.dir={run_dir}",
        "eval.interval_frames=100000",
        f"resume={'true' if state == 'partial' else 'false'}",
    ]
    run_dir.mkdir(parents=True, exist_ok=True)
    log = open(run_dir / "stdout.log", "a")
    print(f"[study] {name}: {state} -> running", flush=True)
    proc = subprocess.Popen(args, stdout=log, stderr=subprocess.STDOUT)
    (run_dir / "pid").write_text(str(proc.pid))
    return proc


def first_reached(steps, values, threshold: float) -> int | None:
    for step, value in zip(steps, values):
        if value >= threshold:
            return int(step)
    return None


def report(settings: dict[str, list[str]], out: Path, dest: Path, frames: int) -> None:
    dest.mkdir(parents=True, exist_ok=True)
    curves, rows = {}, []
    for name in settings:
        path = out / name / "logs" / "a2c" / "scalars" / "train" / "episode_return.csv"
        if not path.exists():
            continue
        # Only points where the 100-episode window is full: a mean over the
        # first few episodes says little.
        ep_steps, episodes = read_scalar_csv(path.parent / "episodes.csv")
        full = set(ep_steps[episodes >= 100].tolist())
        steps, values = read_scalar_csv(path)
        ok = [s in full for s in steps.tolist()]
        steps, values = steps[ok], values[ok]
        curves[name] = (steps, values)
        succ_steps, success = read_scalar_csv(path.parent / "success_rate.csv")
        ok = [s in full for s in succ_steps.tolist()]
        succ_steps, success = succ_steps[ok], success[ok]
        fps_steps, fps = read_scalar_csv(path.parents[1] / "time" / "fps.csv")
        diagnostics = {}
        for key in (
            "intrinsic_reward",
            "intrinsic_reward_normalized",
            "episode_length",
        ):
            file = path.parent / f"{key}.csv"
            values_k = read_scalar_csv(file)[1] if file.exists() else []
            values_k = [v for v in values_k if v == v]
            # Mean over the first and the last 10 log points (raw KL drift etc.).
            diagnostics[key] = (
                f"{sum(values_k[:10]) / 10:.3g} -> {sum(values_k[-10:]) / 10:.3g}"
                if len(values_k) >= 20
                else ""
            )
        rows.append(
            {
                "setting": name,
                "frames": int(steps[-1]) if len(steps) else 0,
                "final_return": round(float(values[-1]), 3) if len(values) else "",
                "best_return": round(float(values.max()), 3) if len(values) else "",
                "frames_to_0.5": first_reached(steps, values, 0.5) or "not reached",
                "frames_to_0.8": first_reached(steps, values, 0.8) or "not reached",
                "final_success": round(float(success[-1]), 2) if len(success) else "",
                "success_0.8_at": first_reached(succ_steps, success, 0.8)
                or "not reached",
                "intrinsic_raw": diagnostics["intrinsic_reward"],
                "intrinsic_normalized": diagnostics["intrinsic_reward_normalized"],
                "episode_length": diagnostics["episode_length"],
                "fps": int(fps[len(fps) // 2 :].mean()) if len(fps) else "",
            }
        )
    with open(dest / "summary.csv", "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    with open(dest / "curves.csv", "w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow(["setting", "frames", "mean_return_100_episodes"])
        for name, (steps, values) in curves.items():
            writer.writerows(
                [name, int(s), round(float(v), 4)] for s, v in zip(steps, values)
            )
    plot_learning_curves(
        curves,
        dest / "curves.png",
        title=f"{out.name}: 100-episode mean extrinsic return",
    )
    for row in rows:
        print(row)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--study", default="n3s4", choices=sorted(STUDIES))
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--frames", type=int, default=1_000_000)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--jobs", type=int, default=2, help="runs at once (2 cores)")
    parser.add_argument("--only", nargs="*", help="a subset of the study's settings")
    parser.add_argument("--report", type=Path, help="write the summary here instead")
    args = parser.parse_args()
    settings = STUDIES[args.study]
    if args.only:
        unknown = set(args.only) - set(settings)
        if unknown:
            parser.error(
                f"unknown settings {sorted(unknown)}; known: {sorted(settings)}"
            )
        settings = {k: v for k, v in settings.items() if k in args.only}
    if args.report:
        report(settings, args.out, args.report, args.frames)
        return
    queue = list(settings.items())
    running: list[subprocess.Popen] = []
    while queue or running:
        running = [p for p in running if p.poll() is None]
        # Runs started by an earlier (killed) driver still hold a core.
        elsewhere = sum(
            run_state(args.out / name, args.frames) == "running" for name in settings
        ) - len(running)
        while queue and len(running) + elsewhere < args.jobs:
            name, overrides = queue.pop(0)
            proc = launch(name, overrides, args.out, args.frames, args.seed)
            if proc is not None:
                running.append(proc)
        time.sleep(2)


if __name__ == "__main__":
    main()
