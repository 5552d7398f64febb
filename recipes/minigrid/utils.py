"""The MiniGrid recipe's learners: A2C or PPO (``algo.name``), their losses,
optimisers and minibatches. The env, model, bonus and collector builders are in
:mod:`common.minigrid`."""

from __future__ import annotations

import torch
from tensordict import TensorDictBase
from torchrl.data import LazyTensorStorage, ReplayBuffer, SamplerWithoutReplacement
from torchrl.objectives import A2CLoss, ClipPPOLoss

from common.minigrid import make_advantage

# What the losses return that is logged (means over an update's minibatches).
LOGGED_LOSSES = {
    "a2c": ("loss_objective", "loss_critic", "loss_entropy", "entropy"),
    "ppo": (
        "loss_objective",
        "loss_critic",
        "loss_entropy",
        "entropy",
        "clip_fraction",
        "kl_approx",
    ),
}


def make_loss(cfg, model, intrinsic_value, bonus_transform):
    """TorchRL's A2CLoss or ClipPPOLoss, and the advantage (GAE, or two streams).

    A2C is torch-ac's A2C: one step on the whole batch. PPO is torch-ac's PPO (what
    rl-starter-files runs): clipped ratio, the value update clipped by the same
    epsilon around the collecting critic's value, squared error, the advantages of
    each minibatch normalised with ``loss.normalize_advantage`` (as
    Stable-Baselines3 and CleanRL do).

    Returns ``(loss, advantage, intrinsic_value_loss or None)``.
    """
    # The heads: the training loop runs the shared trunk once before the losses
    # (shared_trunk; TorchRL's single call of a common module).
    heads = {
        "actor_network": model.get_policy_head(),
        "critic_network": model.get_value_head(),
        "entropy_coeff": cfg.loss.entropy_coef,
        "critic_coeff": cfg.loss.critic_coef,
        "loss_critic_type": "l2",
    }
    if cfg.algo.name == "a2c":
        loss = A2CLoss(**heads)
    else:
        loss = ClipPPOLoss(
            **heads,
            clip_epsilon=cfg.loss.clip_epsilon,
            clip_value=True,
            normalize_advantage=bool(cfg.loss.normalize_advantage),
        )
    advantage, value_loss = make_advantage(cfg, model, intrinsic_value, bonus_transform)
    return loss, advantage, value_loss


def make_optimizer(cfg, params) -> torch.optim.Optimizer:
    """RMSprop (A2C, rl-starter-files) or Adam (PPO), as ``optim.name`` says."""
    if cfg.optim.name == "rmsprop":
        return torch.optim.RMSprop(
            params, lr=cfg.optim.lr, alpha=cfg.optim.alpha, eps=cfg.optim.eps
        )
    return torch.optim.Adam(params, lr=cfg.optim.lr, eps=cfg.optim.eps)


def make_minibatch_buffer(cfg) -> ReplayBuffer | None:
    """PPO's collected batch, iterated in shuffled minibatches (one epoch per pass).

    Its sampler draws the next permutation as an epoch ends: a checkpoint holds it.
    ``None`` for A2C, which takes one step on the whole batch.
    """
    if cfg.algo.name == "a2c":
        return None
    return ReplayBuffer(
        storage=LazyTensorStorage(cfg.env.num_envs * cfg.collector.frames_per_env),
        sampler=SamplerWithoutReplacement(),
        batch_size=cfg.loss.minibatch_size,
    )


def minibatches(data: TensorDictBase, buffer: ReplayBuffer | None, epochs: int):
    """The batches of one update: the whole batch (A2C), or ``epochs`` passes of
    shuffled minibatches (PPO)."""
    if buffer is None:
        yield data
        return
    buffer.extend(data.reshape(-1))
    for _ in range(epochs):
        yield from buffer


def standardize_advantage(data: TensorDictBase, key="advantage") -> TensorDictBase:
    """Centres and scales the batch's advantages to mean 0 and std 1, in place.

    A2C's ``loss.normalize_advantage``: what ``ClipPPOLoss(normalize_advantage=True)``
    does to each minibatch (and Stable-Baselines3's A2C option), which TorchRL's
    ``A2CLoss`` has no argument for; the same floor on the std as TorchRL's.
    """
    advantage = data[key]
    scale = advantage.std().clamp_min(torch.finfo(torch.float).resolution)
    data[key] = (advantage - advantage.mean()) / scale
    return data
