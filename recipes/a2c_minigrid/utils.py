"""The A2C recipe's loss; the MiniGrid builders are shared with the PPO recipe
(:mod:`torchrl_surprise.experiments.minigrid`)."""

from __future__ import annotations

import torch
from tensordict import TensorDictBase
from torchrl.objectives import A2CLoss

from torchrl_surprise.experiments.minigrid import (  # noqa: F401 (the recipe's builders)
    check_config,
    make_actor_critic,
    make_advantage,
    make_bonus,
    make_collector,
    make_env,
    shared_trunk,
)


def make_a2c(cfg, model, intrinsic_value, bonus_transform):
    """TorchRL's A2CLoss and the advantage (GAE, or two streams with two critics).

    Returns ``(loss, advantage, intrinsic_value_loss or None)``.
    """
    loss = A2CLoss(
        # The heads: the training loop runs the shared trunk once before the
        # losses (shared_trunk; TorchRL's single call of a common module).
        actor_network=model.get_policy_head(),
        critic_network=model.get_value_head(),
        entropy_coeff=cfg.loss.entropy_coef,
        critic_coeff=cfg.loss.critic_coef,
        loss_critic_type="l2",
    )
    advantage, value_loss = make_advantage(cfg, model, intrinsic_value, bonus_transform)
    return loss, advantage, value_loss


def standardize_advantage(data: TensorDictBase, key="advantage") -> TensorDictBase:
    """Centres and scales the batch's advantages to mean 0 and std 1, in place.

    ``loss.normalize_advantage``: what ``ClipPPOLoss(normalize_advantage=True)``
    does to each minibatch (and Stable-Baselines3's A2C option), which TorchRL's
    ``A2CLoss`` has no argument for; the same floor on the std as TorchRL's.
    """
    advantage = data[key]
    scale = advantage.std().clamp_min(torch.finfo(torch.float).resolution)
    data[key] = (advantage - advantage.mean()) / scale
    return data
