"""The PPO recipe's loss, minibatch buffer and config checks; the MiniGrid builders
are shared with the A2C recipe (:mod:`torchrl_surprise.experiments.minigrid`)."""

from __future__ import annotations

from torchrl.data import LazyTensorStorage, ReplayBuffer, SamplerWithoutReplacement
from torchrl.objectives import ClipPPOLoss

from torchrl_surprise.experiments.minigrid import (  # noqa: F401 (the recipe's builders)
    EVAL_SEED_OFFSET,
    bonus_update_steps,
    evaluate,
    load_bonus_model,
    make_actor_critic,
    make_advantage,
    make_bonus,
    make_collector,
    make_env,
    rollout_metrics,
    shared_trunk,
    train_bonus_model,
)
from torchrl_surprise.experiments.minigrid import check_config as check_common


def check_config(cfg) -> None:
    """The MiniGrid recipes' checks, and PPO's epochs and minibatches."""
    check_common(cfg)
    batch = cfg.env.num_envs * cfg.collector.frames_per_env
    if not (isinstance(cfg.loss.epochs, int) and cfg.loss.epochs > 0):
        raise ValueError(
            f"loss.epochs must be a positive integer, got {cfg.loss.epochs!r}."
        )
    size = cfg.loss.minibatch_size
    if not (isinstance(size, int) and 0 < size <= batch):
        raise ValueError(
            f"loss.minibatch_size must be an integer in [1, {batch}] (env.num_envs * "
            f"collector.frames_per_env, the collected batch), got {size!r}."
        )
    if not cfg.loss.clip_epsilon > 0:
        raise ValueError(
            f"loss.clip_epsilon must be > 0, got {cfg.loss.clip_epsilon!r}."
        )


def make_ppo(cfg, model, intrinsic_value, bonus_transform):
    """TorchRL's ClipPPOLoss and the advantage (GAE, or two streams with two critics).

    The loss is torch-ac's PPO (what rl-starter-files runs): clipped ratio, the
    value update clipped by the same epsilon around the collecting critic's value,
    squared error, no advantage normalisation unless ``loss.normalize_advantage``
    (per minibatch, as Stable-Baselines3 and CleanRL do).

    Returns ``(loss, advantage, intrinsic_value_loss or None)``.
    """
    loss = ClipPPOLoss(
        # The heads: the training loop runs the shared trunk once before the
        # losses (shared_trunk; TorchRL's single call of a common module).
        actor_network=model.get_policy_head(),
        critic_network=model.get_value_head(),
        clip_epsilon=cfg.loss.clip_epsilon,
        entropy_coeff=cfg.loss.entropy_coef,
        critic_coeff=cfg.loss.critic_coef,
        loss_critic_type="l2",
        clip_value=True,
        normalize_advantage=bool(cfg.loss.get("normalize_advantage", False)),
    )
    advantage, value_loss = make_advantage(cfg, model, intrinsic_value, bonus_transform)
    return loss, advantage, value_loss


def make_minibatch_buffer(cfg) -> ReplayBuffer:
    """The collected batch, iterated in shuffled minibatches (one epoch per pass).

    Its sampler draws the next permutation as an epoch ends: a checkpoint holds it.
    """
    return ReplayBuffer(
        storage=LazyTensorStorage(cfg.env.num_envs * cfg.collector.frames_per_env),
        sampler=SamplerWithoutReplacement(),
        batch_size=cfg.loss.minibatch_size,
    )
