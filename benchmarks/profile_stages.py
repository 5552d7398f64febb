"""Where a frame's time goes: the recipes' training loops under py-spy, per stage.

Each recipe runs in a subprocess under ``py-spy record`` (sampling, raw stacks).
Every sample taken inside the training loop is attributed to a stage by the
innermost frame of the recipe's ``main.py`` that has one (the stages are that
file's functions of the loop's steps, or regions of a function that start at
the marker lines below; a marker that is gone is an error), and then, by its
innermost Python frame, to a kind of work:

* ``env``: gymnasium, MiniGrid or MuJoCo code (the simulation itself);
* ``torch ops``: torch operators (``torch.nn`` layers and functional, autograd,
  optimizers, distributions, our networks' layers in
  ``torchrl_surprise.modules``): the arithmetic, including its C++ dispatch;
* ``tensordict/torchrl``: TensorDict and TorchRL Python code (keys, specs,
  checks, copies, wrappers);
* ``other``: the rest (``nn.Module.__call__`` glue, numpy, our code, Python).

Usage (py-spy is a profiling tool, not a dependency: ``pip install py-spy``)::

    python benchmarks/profile_stages.py [--only a2c-none ddpg-none] [--rate 100]

Writes ``docs/results/bench_profile.txt`` (``--out``).
"""

from __future__ import annotations

import argparse
import ast
import collections
import os
import shutil
import subprocess
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
MINIGRID = ROOT / "recipes" / "minigrid" / "main.py"
DDPG = ROOT / "recipes" / "ddpg_mujoco" / "main.py"

# (function of the recipe's main.py, marker substring or None, stage): a function
# given with None is that stage from its first line; a marker's stage runs from
# its line to the next marker of the same function, or the function's end.
MINIGRID_STAGES = [
    ("train", "for data in t.collector:", "collection (collector: env + policy)"),
    ("train", "frames += data.numel()", "bookkeeping (episode stats)"),
    ("train", 'if variant == "info_gain":', "bonus model training"),
    ("train", "data = bonus_and_advantage(", "bonus forward"),
    ("train", "# Logging", "logging, eval, checkpoint"),
    ("bonus_and_advantage", None, "bonus forward"),
    ("bonus_and_advantage", "if t.reward_clip is not None:", "advantage (GAE)"),
    ("learner_update", None, "update (loss + backward + optimiser)"),
    ("train_bonus", None, "bonus model training"),
    ("maybe_evaluate", None, "logging, eval, checkpoint"),
]
DDPG_STAGES = [
    ("train", "for data in t.collector:", "collection (collector: env + actor)"),
    ("train", "frames += data.numel()", "bookkeeping (stats, obs statistics)"),
    ("train", "if at_collection:", "bonus at collection"),
    ("train", "t.buffer.extend(", "replay buffer extend"),
    ("train", "if frames >= cfg.collector.init_random_frames:", "divergence check"),
    ("train", "# Logging", "logging, eval, checkpoint"),
    ("update", "sample = t.buffer.sample(", "replay buffer sample"),
    ("update", "if at_sample:", "bonus on the sample"),
    (
        "update",
        "loss_value, _ = t.loss_module.loss_value(",
        "critic loss + backward + Adam",
    ),
    (
        "update",
        "loss_actor, _ = t.loss_module.loss_actor(",
        "actor loss + backward + Adam",
    ),
    ("update", "t.target_updater.step()", "soft target update"),
    ("update", "updates += 1", "per-update scalars"),
    ("update", "if t.vae_loss is not None and updates", "VAE step"),
    ("log_batch", None, "logging, eval, checkpoint"),
]

PROFILES = {
    # the recipes' defaults on the envpool backend (A2C: the elliptical VAE
    # bonus; PPO: NovelD on the VAE), and each learner without a bonus
    "a2c-envpool": (
        MINIGRID,
        MINIGRID_STAGES,
        ["algo=a2c", "env.backend=envpool", "collector.total_frames=40000"],
    ),
    "ppo-envpool": (
        MINIGRID,
        MINIGRID_STAGES,
        ["algo=ppo", "env.backend=envpool", "collector.total_frames=40960"],
    ),
    "ppo-none-envpool": (
        MINIGRID,
        MINIGRID_STAGES,
        [
            "algo=ppo",
            "bonus=none",
            "env.backend=envpool",
            "collector.total_frames=40960",
        ],
    ),
    # the suite's peers (docs/results.rst, "The hard-exploration suite")
    "ppo-e3b-envpool": (
        MINIGRID,
        MINIGRID_STAGES,
        [
            "algo=ppo",
            "+setting=e3b",
            "env.backend=envpool",
            "env.name=MiniGrid-KeyCorridorS3R3-v0",
            "collector.total_frames=40960",
        ],
    ),
    "ppo-noveld-envpool": (
        MINIGRID,
        MINIGRID_STAGES,
        [
            "algo=ppo",
            "+setting=noveld",
            "env.backend=envpool",
            "env.name=MiniGrid-KeyCorridorS3R3-v0",
            "collector.total_frames=40960",
        ],
    ),
    "a2c-none-envpool": (
        MINIGRID,
        MINIGRID_STAGES,
        [
            "algo=a2c",
            "bonus=none",
            "env.backend=envpool",
            "collector.total_frames=40000",
        ],
    ),
    "a2c": (MINIGRID, MINIGRID_STAGES, ["algo=a2c", "collector.total_frames=30000"]),
    "ddpg-none": (
        DDPG,
        DDPG_STAGES,
        [
            "bonus=none",
            "env.name=Hopper-v5",
            "collector.total_frames=3000",
            "collector.init_random_frames=1000",
        ],
    ),
    "ddpg-vae": (
        DDPG,
        DDPG_STAGES,
        [
            "bonus=vae",
            "env.name=Hopper-v5",
            "collector.total_frames=3000",
            "collector.init_random_frames=1000",
        ],
    ),
}

KINDS = ("env", "torch ops", "tensordict/torchrl", "other")


def kind_of(frame: str) -> str:
    path = frame[frame.rfind("(") + 1 :]
    if any(s in path for s in ("/gymnasium/", "/minigrid/", "/mujoco/", "/envpool/")):
        return "env"
    if any(s in path for s in ("tensordict/", "torchrl/")):
        return "tensordict/torchrl"
    if "torchrl_surprise/modules/" in path:
        return "torch ops"  # our networks' layers (OneDNNLinear, ...)
    if "torch/" in path and not any(
        s in path
        for s in ("torch/nn/modules/module.py", "torch/utils/", "torch/_jit_internal")
    ):
        return "torch ops"
    return "other"


class MissingMarker(ValueError):
    """A stage's marker is no longer in the recipe's ``main.py``."""


@dataclass
class StageMap:
    """``(function, line) -> stage`` over a recipe's ``main.py``."""

    lines: dict[tuple[str, int], str]

    @classmethod
    def from_source(
        cls, main: Path, markers: list[tuple[str, str | None, str]]
    ) -> StageMap:
        text = main.read_text()
        source = text.splitlines()
        spans = {
            node.name: (node.lineno, node.end_lineno)
            for node in ast.walk(ast.parse(text))
            if isinstance(node, ast.FunctionDef)
        }
        starts: dict[str, list[tuple[int, str]]] = collections.defaultdict(list)
        for function, marker, stage in markers:
            if function not in spans:
                raise MissingMarker(f"{main} has no function {function}()")
            first, last = spans[function]
            if marker is None:
                starts[function].append((first, stage))
                continue
            number = next(
                (n for n in range(first, last + 1) if marker in source[n - 1]), None
            )
            if number is None:
                raise MissingMarker(f"{main}: {function}() has no line {marker!r}")
            starts[function].append((number, stage))
        lines: dict[tuple[str, int], str] = {}
        for function, marks in starts.items():
            marks.sort()
            last = spans[function][1]
            for (start, stage), nxt in zip(marks, [*marks[1:], (last + 1, "")]):
                for number in range(start, nxt[0]):
                    lines[function, number] = stage
        return cls(lines)


def attribute(raw: Path, main: Path, stage_map: StageMap):
    """Samples per (stage, kind), for samples inside the training loop: each is
    the stage of the innermost frame of the recipe's ``main.py`` that has one."""
    counts: dict[str, collections.Counter] = collections.defaultdict(
        collections.Counter
    )
    total = 0
    needle = f"({main}:"
    for line in raw.read_text().splitlines():
        stack, _, n = line.rpartition(" ")
        if not n.isdigit():
            continue
        frames = stack.split(";")
        found = None
        for idx in range(len(frames) - 1, -1, -1):
            frame = frames[idx]
            if needle not in frame:
                continue
            function = frame.split(" ", 1)[0]
            lineno = int(frame.rsplit(":", 1)[1].rstrip(")"))
            stage = stage_map.lines.get((function, lineno))
            if stage is not None:
                found = idx, stage
                break
        if found is None:
            continue  # set-up or wrap-up, outside the timed loop
        idx, stage = found
        kind = kind_of(frames[-1]) if idx < len(frames) - 1 else "other"
        counts[stage][kind] += int(n)
        total += int(n)
    return counts, total


def profile(name: str, rate: int, tmp: Path) -> str:
    main, markers, overrides = PROFILES[name]
    raw = tmp / f"{name}.txt"
    run_dir = tmp / name
    cmd = [
        shutil.which("py-spy") or str(Path(sys.executable).with_name("py-spy")),
        "record",
        "--format",
        "raw",
        "--rate",
        str(rate),
        "--nonblocking",
        "--full-filenames",
        "-o",
        str(raw),
        "--",
        sys.executable,
        str(main),
        *overrides,
        "eval.interval_frames=10000000",
        "checkpoint.interval_frames=10000000",
        f"hydra.run.dir={run_dir}",
    ]
    load = os.getloadavg()
    subprocess.run(cmd, check=True, cwd=ROOT, capture_output=True)
    counts, total = attribute(raw, main, StageMap.from_source(main, markers))
    header = (
        f"{name}: {' '.join(overrides)}; {total} samples in the loop at {rate}/s, "
        f"load {load[0]:.2f}"
    )
    lines = [
        header,
        f"  {'stage':<38}{'share':>7}   " + "".join(f"{k:>20}" for k in KINDS),
    ]
    order = sorted(counts, key=lambda s: -sum(counts[s].values()))
    for stage in order:
        c = counts[stage]
        n = sum(c.values())
        kinds = "".join(f"{100 * c[k] / total:>19.1f}%" for k in KINDS)
        lines.append(f"  {stage:<38}{100 * n / total:>6.1f}%   {kinds}")
    all_kinds = collections.Counter()
    for c in counts.values():
        all_kinds.update(c)
    lines.append(
        f"  {'all':<38}{100.0:>6.1f}%   "
        + "".join(f"{100 * all_kinds[k] / total:>19.1f}%" for k in KINDS)
    )
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--only", nargs="+", choices=list(PROFILES))
    parser.add_argument("--rate", type=int, default=100, help="samples per second")
    parser.add_argument("--out", default=str(ROOT / "docs/results/bench_profile.txt"))
    args = parser.parse_args(argv)
    if shutil.which("py-spy") is None and not (
        Path(sys.executable).with_name("py-spy").exists()
    ):
        sys.exit("py-spy is not installed: pip install py-spy")
    blocks = [
        "Share of the training loop's samples per stage (rows) and kind of work "
        "(columns, shares of the whole loop); py-spy, Python stacks."
    ]
    with tempfile.TemporaryDirectory() as tmp:
        for name in args.only or PROFILES:
            print(f"profiling {name} ...", flush=True)
            blocks.append(profile(name, args.rate, Path(tmp)))
            print(blocks[-1], flush=True)
    Path(args.out).write_text("\n\n".join(blocks) + "\n")
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
