"""The A2C recipe's loss; the MiniGrid builders are shared with the PPO recipe
(:mod:`torchrl_surprise.experiments.minigrid`)."""

from __future__ import annotations

from torchrl.objectives import A2CLoss

from torchrl_surprise.experiments.minigrid import (  # noqa: F401 (the recipe's builders)
    check_config,
    make_actor_critic,
    make_advantage,
    make_bonus,
    make_collector,
    make_env,
)


def make_a2c(cfg, model, intrinsic_value, bonus_transform):
    """TorchRL's A2CLoss and the advantage (GAE, or two streams with two critics).

    Returns ``(loss, advantage, intrinsic_value_loss or None)``.
    """
    loss = A2CLoss(
        actor_network=model.get_policy_operator(),
        critic_network=model.get_value_operator(),
        entropy_coeff=cfg.loss.entropy_coef,
        critic_coeff=cfg.loss.critic_coef,
        loss_critic_type="l2",
    )
    advantage, value_loss = make_advantage(cfg, model, intrinsic_value, bonus_transform)
    return loss, advantage, value_loss
