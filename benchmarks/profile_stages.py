"""Where a frame's time goes: the recipes' training loops under py-spy, per stage.

Each recipe runs in a subprocess under ``py-spy record`` (sampling, raw stacks).
Every sample taken inside the training loop is attributed to the stage of the
loop line it is under (the innermost frame of the recipe's ``main``: the stages
are regions of ``main.py`` that start at the marker lines below), and then, by
its innermost Python frame, to a kind of work:

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

# (marker substring, stage): a stage runs from its marker line to the next marker.
MINIGRID_STAGES = [
    ("for data in collector:", "collection (collector: env + policy)"),
    ("frames += data.numel()", "bookkeeping (episode stats)"),
    ('if variant == "info_gain":', "bonus model training"),
    ("# Step 2:", "bonus forward"),
    ("data = advantage(data)", "advantage (GAE)"),
    ("# Step 4:", "update (loss + backward + optimiser)"),
    ("# Step 5:", "bonus model training"),
    ("# Logging", "logging, eval, checkpoint"),
]
DDPG_STAGES = [
    ("for data in collector:", "collection (collector: env + actor)"),
    ("frames += data.numel()", "bookkeeping (stats, obs statistics)"),
    ("buffer.extend(", "replay buffer extend"),
    ("sample = sample_uniform(", "replay buffer sample"),
    ("sample = buffer.sample(", "replay buffer sample"),  # before DDPGUpdate
    ("if bonus_at_sample:", "bonus on the sample"),
    ("loss_value = ddpg.critic_loss(", "critic loss + backward + Adam"),
    ("loss_actor = ddpg.actor_loss(", "actor loss + backward + Adam"),
    ("ddpg.update_target()", "soft target update"),
    # the loop as it was before DDPGUpdate (to profile older commits alike)
    ("loss_value, _ = loss_module.loss_value(", "critic loss + backward + Adam"),
    ("loss_actor, _ = loss_module.loss_actor(", "actor loss + backward + Adam"),
    ("target_updater.step()", "soft target update"),
    ("updates += 1", "per-update scalars"),
    ("if vae_loss is not None and updates", "VAE step"),
    ("pbar.update(", "logging, eval, checkpoint"),
]
# the end of the training loop (the MiniGrid recipe, then the DDPG one)
LOOP_ENDS = ("run.finish(", "stop.restore()")

PROFILES = {
    # the recipe's defaults (the elliptical VAE bonus) on the envpool backend
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


@dataclass
class StageMap:
    lines: dict[int, str]

    @classmethod
    def from_source(cls, main: Path, markers: list[tuple[str, str]]) -> StageMap:
        source = main.read_text().splitlines()
        starts: list[tuple[int, str]] = []
        for marker, stage in markers:
            for number, line in enumerate(source, start=1):
                if marker in line:
                    starts.append((number, stage))
                    break
        starts.sort()
        end = next(
            (
                n
                for n, line in enumerate(source, start=1)
                if any(end in line for end in LOOP_ENDS)
            ),
            len(source),
        )
        lines: dict[int, str] = {}
        for (start, stage), nxt in zip(starts, [*starts[1:], (end, "")]):
            for number in range(start, nxt[0]):
                lines[number] = stage
        return cls(lines)


def attribute(raw: Path, main: Path, stage_map: StageMap):
    """Samples per (stage, kind), for samples inside the training loop."""
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
        # The innermost frame of the recipe's main() (hydra calls it from <module>).
        idx = max(
            (i for i, f in enumerate(frames) if f.startswith("main ") and needle in f),
            default=None,
        )
        if idx is None:
            continue
        lineno = int(frames[idx].rsplit(":", 1)[1].rstrip(")"))
        stage = stage_map.lines.get(lineno)
        if stage is None:
            continue  # set-up or wrap-up, outside the timed loop
        counts[stage][kind_of(frames[-1]) if idx < len(frames) - 1 else "other"] += int(
            n
        )
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
