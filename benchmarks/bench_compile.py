"""``torch.compile`` of the MiniGrid actor-critic on this CPU, against eager, and
PPO's Adam step fused against the recipe's ``foreach``.

The policy's forward on 64 observations (collection, no gradients) and the
trunk's and policy head's forward and backward on a minibatch of 256 (the
update), each in CPU microseconds per call after warm-up, one torch thread as
the recipes run; the first call's compile time is reported apart. Then one Adam
step over the actor-critic's parameters (PPO takes one a minibatch), with
``foreach=True`` (the recipe's) and with ``fused=True``, interleaved.

    python benchmarks/bench_compile.py
"""

from __future__ import annotations

import functools
import sys
import time
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "recipes"))

from torchrl.data import Categorical as CategoricalSpec  # noqa: E402

from common.minigrid import make_actor_critic  # noqa: E402


def observations(n: int) -> torch.Tensor:
    """MiniGrid images: object, colour and state ids in range."""
    return torch.stack(
        [
            torch.randint(0, 11, (n, 7, 7)),
            torch.randint(0, 6, (n, 7, 7)),
            torch.randint(0, 3, (n, 7, 7)),
        ],
        -1,
    )


def per_call(fn, calls: int, warmup: int = 10) -> float:
    """CPU microseconds of one call of ``fn``."""
    for _ in range(warmup):
        fn()
    start = time.process_time()
    for _ in range(calls):
        fn()
    return (time.process_time() - start) / calls * 1e6


def main() -> None:
    torch.set_num_threads(1)
    torch.manual_seed(0)
    model, _ = make_actor_critic(CategoricalSpec(7), intrinsic_critic=False)
    trunk = model.get_policy_operator().module[0].module
    head = model.get_policy_operator().module[1].module
    small, batch = observations(64), observations(256)

    def forward(t, h):
        with torch.no_grad():
            return h(t(small))

    def update(t, h):
        h(t(batch)).logsumexp(-1).mean().backward()

    for name, step, calls in (
        ("policy forward, 64 obs", forward, 400),
        ("forward + backward, 256", update, 200),
    ):
        eager = per_call(functools.partial(step, trunk, head), calls)
        t, h = torch.compile(trunk, dynamic=False), torch.compile(head, dynamic=False)
        start = time.time()
        step(t, h)
        compile_s = time.time() - start
        compiled = per_call(functools.partial(step, t, h), calls)
        print(
            f"{name}: eager {eager:,.0f} us, compiled {compiled:,.0f} us "
            f"(eager / compiled {eager / compiled:.2f}x), first call {compile_s:.1f} s"
        )
    params = list(model.parameters())
    for param in params:
        param.grad = torch.randn_like(param)
    steps = {
        kind: torch.optim.Adam(params, lr=1e-4, **{kind: True}).step
        for kind in ("foreach", "fused")
    }
    times = {kind: [] for kind in steps}
    for _ in range(3):  # interleaved rounds
        for kind, step in steps.items():
            times[kind].append(per_call(step, 500))
    foreach, fused = (sorted(times[k])[1] for k in ("foreach", "fused"))
    print(
        f"Adam step, {len(params)} tensors: foreach {foreach:,.0f} us, fused "
        f"{fused:,.0f} us (foreach / fused {foreach / fused:.2f}x; median of 3 rounds)"
    )


if __name__ == "__main__":
    main()
