"""Cost of the VAE surprise bonus on MiniGrid, against the A2C actor-critic.

Measures, per 1,000 MiniGrid states (a collector batch of 16 envs x 64 steps):

* ``KL forward``: ``StateVAE.for_minigrid().kl(image, direction)`` under
  ``torch.no_grad()``, the computation at the heart of the bonus;
* ``transform forward``: ``VAESurpriseTransform.forward`` on the collected
  TensorDict (reads ``("next", "image")``/``("next", "direction")``, writes the
  bonus, its normalised version, the extrinsic copy and the mixed reward);
* ``VAE train step``: one ``VAELoss`` forward, backward and ``Adam`` step;

and, as baselines in the same process on the same states, the A2C
actor-critic of rl-starter-files (3 conv layers with 16/32/64 channels on the
7x7x3 grid, then 64-unit actor and critic heads):

* ``AC forward``: the forward pass (what acting costs per state);
* ``AC train step``: forward, backward and ``Adam`` step on a surrogate loss.

Each measurement is timeit-style: a warm-up, then ``--repeat`` repeats of a
number of calls chosen so one repeat lasts at least ``--min-time`` seconds; the
median repeat is reported. Repeats of the different measurements are
interleaved so that load changes on a shared machine hit them alike. Everything
runs with ``torch.set_num_threads(n)`` for each ``n`` of ``--threads``; the
load average is printed alongside, since more threads than free cores makes
small ops very slow (threads wait on each other at every op).

Run: ``python benchmarks/bench_bonus.py`` (under a minute on 2 CPU cores).
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

from torchrl_surprise import StateVAE, VAELoss, VAESurpriseTransform
from torchrl_surprise.envs import make_minigrid_env

ENV_NAME = "MiniGrid-MultiRoom-N3-S4-v0"
NUM_ENVS = 16
STEPS = 64
NUM_ACTIONS = 7


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


def measure(batch: TensorDictBase, repeat: int, min_time: float) -> dict[str, float]:
    """Seconds per call of each measurement on ``batch``."""
    torch.manual_seed(0)
    vae = StateVAE.for_minigrid()
    surprise = VAESurpriseTransform(vae, coef=0.01, normalization="zscore")
    vae_loss = VAELoss(vae)
    vae_optim = torch.optim.Adam(vae_loss.parameters(), lr=1e-3)
    ac = MiniGridActorCritic()
    ac_optim = torch.optim.Adam(ac.parameters(), lr=1e-3)

    image = batch["next", "image"]
    direction = batch["next", "direction"]
    flat = batch.reshape(-1)

    def kl_forward():
        with torch.no_grad():
            return vae.kl(image, direction)

    def transform_forward():
        return surprise(batch)

    def vae_train_step():
        losses = vae_loss(flat)
        vae_optim.zero_grad()
        (losses["loss_reconstruction"] + losses["loss_kl"]).backward()
        vae_optim.step()

    def ac_forward():
        with torch.no_grad():
            return ac(image)

    def ac_train_step():
        logits, value = ac(image)
        # A stand-in for the A2C loss: same graph size, same backward cost.
        loss = logits.mean() + value.pow(2).mean()
        ac_optim.zero_grad()
        loss.backward()
        ac_optim.step()

    calls = {
        "KL forward": kl_forward,
        "transform forward (zscore)": transform_forward,
        "VAE train step (VAELoss+Adam)": vae_train_step,
        "AC forward [baseline]": ac_forward,
        "AC train step [baseline]": ac_train_step,
    }
    return time_calls(calls, repeat, min_time)


def _load() -> str:
    return " ".join(f"{x:.1f}" for x in os.getloadavg())


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--threads", type=int, nargs="+", default=[1, 2])
    parser.add_argument("--repeat", type=int, default=7)
    parser.add_argument("--min-time", type=float, default=0.05)
    args = parser.parse_args()

    batch = collect_batch()
    num_states = batch.numel()
    per_1k = 1000.0 / num_states
    print(
        f"torch {torch.__version__}; {ENV_NAME}; batch {list(batch.batch_size)} "
        f"= {num_states} transitions; StateVAE.for_minigrid() defaults; "
        f"median of {args.repeat} repeats"
    )
    print(f"{os.cpu_count()} CPUs, load average {_load()} before the measurements")
    header = (
        f"{'threads':>7}  {'measurement':<30} {'us / 1k states':>15} "
        f"{'x AC fwd':>9} {'x AC step':>10}"
    )
    print(header)
    print("-" * len(header))
    for threads in args.threads:
        torch.set_num_threads(threads)
        seconds = measure(batch, args.repeat, args.min_time)
        ac_fwd = seconds["AC forward [baseline]"]
        ac_step = seconds["AC train step [baseline]"]
        for name, value in seconds.items():
            step_ratio = f"{value / ac_step:10.2f}" if "step" in name else " " * 10
            print(
                f"{threads:>7}  {name:<30} {value * per_1k * 1e6:15.0f} "
                f"{value / ac_fwd:9.2f} {step_ratio}"
            )
    print(f"load average {_load()} after the measurements")
    print(
        "x AC fwd: cost / actor-critic forward on the same states; "
        "x AC step: cost / actor-critic train step (train steps only)."
    )


if __name__ == "__main__":
    main()
