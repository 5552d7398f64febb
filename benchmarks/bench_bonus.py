"""Cost of the VAE and ICM bonuses on MiniGrid, against the A2C actor-critic.

On MiniGrid transitions of a random policy (16 envs; the first 8 steps of each
env are the A2C recipe's rollout, 128 states; all 64 steps make 1,024 states),
for each bonus model at the recipe's default sizes:

* ``bonus forward``: the computation at the heart of the bonus, without
  gradients: ``StateVAE.for_minigrid().kl(image, direction)`` of the next
  states (vae), ``ICMModel.for_minigrid().forward_error(s, a, s')`` (icm);
* ``transform forward``: ``VAESurpriseTransform`` / ``ICMTransform`` on the
  collected TensorDict (``normalization="zscore"``): reading and checking the
  observations, the bonus, normalisation and writing the rewards;
* ``train step``: one ``VAELoss`` / ``ICMLoss`` forward, backward and
  ``Adam(fused=True)`` step on the batch as collected (``[16, 8]``,
  ``[16, 64]``), as the recipe trains the bonus;

and, as baselines in the same process on the same states, the A2C
actor-critic of rl-starter-files (3 conv layers with 16/32/64 channels on the
7x7x3 grid, then 64-unit actor and critic heads):

* ``AC forward``: the forward pass (what acting costs per state);
* ``AC train step``: forward, backward and ``Adam`` step on a surrogate loss.

Per A2C update the recipe computes one bonus forward over the rollout and
``intrinsic.update_steps = 2`` train steps; the ``A2C update`` row adds them up
(``transform forward + 2 x train step``), in actor-critic train steps.

Each measurement is timeit-style: a warm-up, then ``--repeat`` repeats of a
number of calls chosen so one repeat lasts at least ``--min-time`` seconds; the
median repeat is reported. Repeats of the different measurements are
interleaved so that load changes on a shared machine hit them alike. Everything
runs with ``torch.set_num_threads(n)`` for each ``n`` of ``--threads`` (default
1, as the recipe runs); the load average is printed alongside, since more
threads than free cores makes small ops very slow (threads wait on each other
at every op).

Run: ``python benchmarks/bench_bonus.py`` (about a minute on 2 CPU cores).
"""

from __future__ import annotations

import argparse
import os
import statistics
import time
from collections.abc import Callable

import torch
from tensordict import TensorDictBase
from torch import nn
from torchrl.collectors import Collector

from torchrl_surprise import (
    ICMLoss,
    ICMModel,
    ICMTransform,
    StateVAE,
    VAELoss,
    VAESurpriseTransform,
)
from torchrl_surprise.envs import make_minigrid_env

ENV_NAME = "MiniGrid-MultiRoom-N3-S4-v0"
NUM_ENVS = 16
STEPS = 64
#: Steps per env of one A2C rollout (recipes/a2c_minigrid: 16 envs x 8 steps).
ROLLOUT_STEPS = 8
NUM_ACTIONS = 7
#: Bonus-model train steps per A2C update (``intrinsic.update_steps``).
UPDATE_STEPS = 2


class MiniGridActorCritic(nn.Module):
    """rl-starter-files' ``ACModel`` (no memory, no text) on the 7x7x3 grid."""

    def __init__(self, num_actions: int = NUM_ACTIONS):
        super().__init__()
        self.image_conv = nn.Sequential(
            nn.Conv2d(3, 16, (2, 2)),
            nn.ReLU(),
            nn.MaxPool2d((2, 2)),
            nn.Conv2d(16, 32, (2, 2)),
            nn.ReLU(),
            nn.Conv2d(32, 64, (2, 2)),
            nn.ReLU(),
        )
        self.actor = nn.Sequential(
            nn.Linear(64, 64), nn.Tanh(), nn.Linear(64, num_actions)
        )
        self.critic = nn.Sequential(nn.Linear(64, 64), nn.Tanh(), nn.Linear(64, 1))

    def forward(self, image: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        batch = image.shape[:-3]
        x = image.reshape(-1, *image.shape[-3:]).permute(0, 3, 1, 2).float()
        features = self.image_conv(x).flatten(1)
        logits = self.actor(features).log_softmax(-1)
        value = self.critic(features)
        return logits.reshape(*batch, -1), value.reshape(*batch, 1)


def collect_batch(seed: int = 0) -> TensorDictBase:
    """One collector batch of random-policy MiniGrid transitions, ``[16, 64]``."""
    env = make_minigrid_env(ENV_NAME, num_envs=NUM_ENVS, seed=seed)
    collector = Collector(
        env,
        policy=None,
        frames_per_batch=NUM_ENVS * STEPS,
        total_frames=NUM_ENVS * STEPS,
    )
    try:
        batch = next(iter(collector))
    finally:
        collector.shutdown()
    return batch


def _calls_per_repeat(fn: Callable[[], object], min_time: float) -> int:
    """Warms ``fn`` up, then doubles the number of calls until they last ``min_time``."""
    for _ in range(3):
        fn()
    number = 1
    while True:
        start = time.perf_counter()
        for _ in range(number):
            fn()
        if time.perf_counter() - start >= min_time:
            return number
        number *= 2


def time_calls(
    calls: dict[str, Callable[[], object]], repeat: int, min_time: float
) -> dict[str, float]:
    """Median seconds per call of each callable, timeit-style.

    The repeats of the different callables are interleaved (one repeat of each,
    in turn), so that a change in the load of a shared machine affects all of
    them alike and the ratios stay meaningful.
    """
    numbers = {name: _calls_per_repeat(fn, min_time) for name, fn in calls.items()}
    times: dict[str, list[float]] = {name: [] for name in calls}
    for _ in range(repeat):
        for name, fn in calls.items():
            number = numbers[name]
            start = time.perf_counter()
            for _ in range(number):
                fn()
            times[name].append((time.perf_counter() - start) / number)
    return {name: statistics.median(values) for name, values in times.items()}


def _train_step(loss_module, optim: torch.optim.Optimizer, batch: TensorDictBase):
    def step():
        losses = loss_module(batch)
        optim.zero_grad()
        sum(v for k, v in losses.items() if k.startswith("loss_")).backward()
        optim.step()

    return step


def make_calls(batch: TensorDictBase) -> dict[tuple[str, str], Callable[[], object]]:
    """The measured callables on ``batch``, keyed by ``(bonus, measurement)``."""
    torch.manual_seed(0)
    obs = (batch["image"], batch["direction"])
    next_obs = (batch["next", "image"], batch["next", "direction"])
    action = batch["action"]
    vae_batch, icm_batch = batch.clone(), batch.clone()

    # The recipe's models and optimiser (recipes/a2c_minigrid: make_bonus, main).
    vae = StateVAE.for_minigrid()
    vae_transform = VAESurpriseTransform(vae, coef=0.01, normalization="zscore")
    vae_loss = VAELoss(vae)
    vae_optim = torch.optim.Adam(vae_loss.parameters(), lr=1e-3, fused=True)
    icm = ICMModel.for_minigrid(num_actions=NUM_ACTIONS)
    icm_transform = ICMTransform(icm, coef=0.01, normalization="zscore")
    icm_loss = ICMLoss(icm)
    icm_optim = torch.optim.Adam(icm_loss.parameters(), lr=1e-3, fused=True)
    ac = MiniGridActorCritic()
    ac_optim = torch.optim.Adam(ac.parameters(), lr=1e-3)

    def vae_forward():
        with torch.no_grad():
            return vae.kl(*next_obs)

    def icm_forward():
        with torch.no_grad():
            return icm.forward_error(obs, action, next_obs)

    def ac_forward():
        with torch.no_grad():
            return ac(batch["image"])

    def ac_train_step():
        logits, value = ac(batch["image"])
        # A stand-in for the A2C loss: same graph size, same backward cost.
        loss = logits.mean() + value.pow(2).mean()
        ac_optim.zero_grad()
        loss.backward()
        ac_optim.step()

    return {
        ("vae", "bonus forward (KL)"): vae_forward,
        # Each transform on its own copy: it writes its reward keys in place.
        ("vae", "transform forward"): lambda: vae_transform(vae_batch),
        ("vae", "train step"): _train_step(vae_loss, vae_optim, batch),
        ("icm", "bonus forward"): icm_forward,
        ("icm", "transform forward"): lambda: icm_transform(icm_batch),
        ("icm", "train step"): _train_step(icm_loss, icm_optim, batch),
        ("ac", "AC forward [baseline]"): ac_forward,
        ("ac", "AC train step [baseline]"): ac_train_step,
    }


def _load() -> str:
    return " ".join(f"{x:.1f}" for x in os.getloadavg())


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--threads",
        type=int,
        nargs="+",
        default=[1],
        help="torch thread counts to measure with (the recipe uses 1), e.g. 1 2",
    )
    parser.add_argument("--repeat", type=int, default=7)
    parser.add_argument("--min-time", type=float, default=0.05)
    args = parser.parse_args()

    collected = collect_batch()
    batches = {
        "rollout": collected[:, :ROLLOUT_STEPS].contiguous(),
        "collector": collected,
    }
    print(
        f"torch {torch.__version__}; {ENV_NAME}; random policy; rollout = "
        f"{NUM_ENVS} envs x {ROLLOUT_STEPS} steps (the A2C recipe's), collector = "
        f"{NUM_ENVS} x {STEPS}; recipe default sizes; median of {args.repeat} "
        "repeats"
    )
    print(f"{os.cpu_count()} CPUs, load average {_load()} before the measurements")
    header = (
        f"{'threads':>7} {'states':>6}  {'bonus':<5} {'measurement':<26} "
        f"{'us / call':>10} {'x AC fwd':>9} {'x AC step':>10}"
    )
    print(header)
    print("-" * len(header))
    for threads in args.threads:
        torch.set_num_threads(threads)
        for batch in batches.values():
            seconds = time_calls(make_calls(batch), args.repeat, args.min_time)
            ac_fwd = seconds["ac", "AC forward [baseline]"]
            ac_step = seconds["ac", "AC train step [baseline]"]
            rows = []
            for bonus in ("vae", "icm"):
                rows += [
                    (key, value) for key, value in seconds.items() if key[0] == bonus
                ]
                update = seconds[bonus, "transform forward"]
                update += UPDATE_STEPS * seconds[bonus, "train step"]
                rows.append(((bonus, f"A2C update (1 + {UPDATE_STEPS} steps)"), update))
            rows += [(key, value) for key, value in seconds.items() if key[0] == "ac"]
            for (bonus, name), value in rows:
                if "step" in name or "update" in name:
                    step_ratio = f"{value / ac_step:10.2f}"
                else:
                    step_ratio = " " * 10
                print(
                    f"{threads:>7} {batch.numel():>6}  {bonus:<5} {name:<26} "
                    f"{value * 1e6:10.0f} {value / ac_fwd:9.2f} {step_ratio}"
                )
    print(f"load average {_load()} after the measurements")
    print(
        "x AC fwd: cost / actor-critic forward on the same states; x AC step: "
        "cost / actor-critic train step (train steps and updates only). "
        f"A2C update: transform forward + {UPDATE_STEPS} train steps."
    )


if __name__ == "__main__":
    main()
