"""Builders shared by the MiniGrid recipes (A2C, PPO): config checks, envs, the
rl-starter-files actor-critic, the bonus and its advantage, the collector.

Run support, not library core: it imports minigrid (through the env factory) and is
imported by the recipes only.
"""

from __future__ import annotations

import math

import torch
from tensordict.nn import TensorDictModule, TensorDictSequential
from torch import nn
from torch.distributions import Categorical
from torchrl.envs import Compose, RewardSum, StepCounter, TransformedEnv
from torchrl.envs.transforms import RNDTransform
from torchrl.modules import ActorValueOperator, ProbabilisticActor, ValueOperator
from torchrl.objectives.rnd import RNDLoss
from torchrl.objectives.value import GAE

from torchrl_surprise import (
    ICMLoss,
    ICMModel,
    ICMTransform,
    IntrinsicValueLoss,
    StateVAE,
    TwoStreamAdvantage,
    VAELoss,
    VAESurpriseTransform,
)
from torchrl_surprise.envs import make_minigrid_env
from torchrl_surprise.experiments import RESUME_MODES, ResumableCollector
from torchrl_surprise.transforms import (
    NORMALIZATIONS,
    PrecomputedBonusTransform,
    VAENegativeELBOTransform,
    VAEPosteriorShiftTransform,
    make_coef_schedule,
)
from torchrl_surprise.transforms.stochasticity import (
    STOCHASTICITY_LEVELS,
    StochasticityTransform,
)

__all__ = [
    "BONUSES",
    "VAE_VARIANTS",
    "MiniGridConvTrunk",
    "check_config",
    "init_rl_starter",
    "make_actor_critic",
    "make_advantage",
    "make_bonus",
    "make_collector",
    "make_env",
]

BONUSES = ("none", "vae", "icm", "rnd")

VAE_VARIANTS = {
    # the paper's bonus: KL(q(z|s) || N(0, I))
    "kl": VAESurpriseTransform,
    # novelty: -ELBO, how badly the VAE explains the state
    "neg_elbo": VAENegativeELBOTransform,
    # KL(q(z|s) || q_ref(z|s)): with the reference taken right before the VAE
    # trains on the rollout (info_gain) or every few updates (lagged_kl)
    "info_gain": VAEPosteriorShiftTransform,
    "lagged_kl": VAEPosteriorShiftTransform,
}
"""``intrinsic.vae.variant`` -> the transform that computes the VAE bonus."""
RND_KEY = "rnd_reward"


def check_config(cfg) -> None:
    """Fails early, naming the value, on a config the recipe cannot run."""
    variant = cfg.intrinsic.vae.get("variant", "kl")
    if variant not in VAE_VARIANTS:
        raise ValueError(
            f"intrinsic.vae.variant must be one of {tuple(VAE_VARIANTS)}, got "
            f"{variant!r}."
        )
    if cfg.bonus not in BONUSES:
        raise ValueError(f"bonus must be one of {BONUSES}, got {cfg.bonus!r}.")
    if cfg.intrinsic.normalization not in NORMALIZATIONS:
        raise ValueError(
            f"intrinsic.normalization must be one of {NORMALIZATIONS}, got "
            f"{cfg.intrinsic.normalization!r}."
        )
    if cfg.env.stochasticity not in STOCHASTICITY_LEVELS:
        raise ValueError(
            f"env.stochasticity must be one of {sorted(STOCHASTICITY_LEVELS)}, got "
            f"{cfg.env.stochasticity!r}."
        )
    if str(cfg.resume).lower() not in RESUME_MODES:
        raise ValueError(f"resume must be one of {RESUME_MODES}, got {cfg.resume!r}.")
    positive = {
        "env.num_envs": cfg.env.num_envs,
        "collector.total_frames": cfg.collector.total_frames,
        "collector.frames_per_env": cfg.collector.frames_per_env,
        "optim.lr": cfg.optim.lr,
        "intrinsic.lr": cfg.intrinsic.lr,
        "eval.interval_frames": cfg.eval.interval_frames,
        "eval.num_envs": cfg.eval.num_envs,
        "checkpoint.interval_frames": cfg.checkpoint.interval_frames,
        "logger.log_interval": cfg.logger.log_interval,
    }
    for name, value in positive.items():
        if not (isinstance(value, (int, float)) and value > 0):
            raise ValueError(f"{name} must be a positive number, got {value!r}.")
    if not 0.0 <= cfg.loss.gamma <= 1.0 or not 0.0 <= cfg.loss.gae_lambda <= 1.0:
        raise ValueError("loss.gamma and loss.gae_lambda must be in [0, 1].")
    if cfg.intrinsic.update_steps < 0 or cfg.intrinsic.warmup_frames < 0:
        raise ValueError("intrinsic.update_steps and warmup_frames must be >= 0.")
    if not math.isfinite(cfg.intrinsic.coef):
        raise ValueError(f"intrinsic.coef must be finite, got {cfg.intrinsic.coef}.")


def make_env(cfg, num_envs: int, seed: int, bonus: str = "none", rnd=None):
    """MiniGrid as one batched TorchRL env, with noise, episode stats (and RND)."""
    env = make_minigrid_env(cfg.env.name, num_envs=num_envs)
    transforms = []
    if cfg.env.stochasticity:
        # Transforms are not seeded by env.set_seed in TorchRL 0.14: seed it here.
        noise = StochasticityTransform.from_level(cfg.env.stochasticity, seed=seed + 1)
        transforms.append(noise)
    # RewardSum sees the env's reward: the extrinsic return is what is logged.
    transforms += [RewardSum(), StepCounter()]
    if bonus == "rnd":
        transforms.append(rnd)
    env = TransformedEnv(env, Compose(*transforms))
    env.set_seed(seed)
    return env


class MiniGridConvTrunk(nn.Module):
    """The image network of rl-starter-files' ACModel (ids fed as numbers)."""

    def __init__(self):
        super().__init__()
        self.net = nn.Sequential(
            nn.Conv2d(3, 16, (2, 2)),
            nn.ReLU(),
            nn.MaxPool2d((2, 2)),
            nn.Conv2d(16, 32, (2, 2)),
            nn.ReLU(),
            nn.Conv2d(32, 64, (2, 2)),
            nn.ReLU(),
            nn.Flatten(),
        )

    def forward(self, image: torch.Tensor) -> torch.Tensor:
        batch = image.shape[:-3]
        x = image.reshape(-1, *image.shape[-3:]).float().movedim(-1, -3)
        return self.net(x).reshape(*batch, -1)


def _mlp_head(out_features: int) -> nn.Module:
    return nn.Sequential(nn.Linear(64, 64), nn.Tanh(), nn.Linear(64, out_features))


def init_rl_starter(module: nn.Module) -> None:
    # rl-starter-files' init_params: unit-norm rows, zero bias, for Linear layers.
    if isinstance(module, nn.Linear):
        module.weight.data.normal_(0, 1)
        module.weight.data *= 1 / module.weight.data.pow(2).sum(1, keepdim=True).sqrt()
        module.bias.data.fill_(0)


def make_actor_critic(action_spec, intrinsic_critic: bool):
    """Shared conv trunk, a categorical policy head and one (or two) value heads."""
    num_actions = action_spec.space.n
    trunk = TensorDictModule(
        MiniGridConvTrunk(), in_keys=["image"], out_keys=["hidden"]
    )
    policy_head = ProbabilisticActor(
        TensorDictModule(
            _mlp_head(num_actions), in_keys=["hidden"], out_keys=["logits"]
        ),
        in_keys=["logits"],
        distribution_class=Categorical,
        spec=action_spec,
        return_log_prob=False,
    )
    value_head = ValueOperator(_mlp_head(1), in_keys=["hidden"])
    model = ActorValueOperator(trunk, policy_head, value_head)
    model.apply(init_rl_starter)
    intrinsic_value = None
    if intrinsic_critic:
        int_head = ValueOperator(
            _mlp_head(1), in_keys=["hidden"], out_keys=["state_value_int"]
        )
        int_head.apply(init_rl_starter)
        intrinsic_value = TensorDictSequential(trunk, int_head)
    return model, intrinsic_value


def make_bonus(cfg, action_spec, bonus: str):
    """The bonus: (batch transform, loss on the bonus model, env-side transform)."""
    icfg = cfg.intrinsic
    schedule = make_coef_schedule(
        icfg.coef, icfg.coef_end, icfg.anneal_frames, icfg.warmup_frames
    )
    common = dict(
        coef=icfg.coef,
        coef_schedule=schedule,
        normalization=icfg.normalization,
        gamma=cfg.loss.gamma,
        clip=icfg.clip,
        # With a separate intrinsic critic the reward stays extrinsic.
        reward_key=None if icfg.intrinsic_critic else "reward",
    )
    env_side = None
    if bonus == "vae":
        vae = StateVAE.for_minigrid(
            latent_dim=icfg.vae.latent_dim,
            hidden_dim=icfg.vae.hidden_dim,
            use_direction=icfg.vae.use_direction,
        )
        transform = VAE_VARIANTS[icfg.vae.get("variant", "kl")](vae, **common)
        loss = VAELoss(vae, kl_weight=icfg.vae.kl_weight)
    elif bonus == "icm":
        icm = ICMModel.for_minigrid(
            num_actions=action_spec.space.n, hidden_dim=icfg.icm.hidden_dim
        )
        transform = ICMTransform(icm, **common)
        loss = ICMLoss(icm, beta=icfg.icm.beta)
    elif bonus == "rnd":

        def net():
            return nn.Sequential(
                nn.Flatten(-3),
                nn.Linear(7 * 7 * 3, icfg.rnd.hidden_dim),
                nn.ReLU(),
                nn.Linear(icfg.rnd.hidden_dim, icfg.rnd.hidden_dim),
                nn.ReLU(),
                nn.Linear(icfg.rnd.hidden_dim, icfg.rnd.hidden_dim),
            )

        target, predictor = net(), net()
        # TorchRL's RNDTransform runs in the env (it has no batch path); its raw
        # error is then normalised and mixed by the same base as the other bonuses.
        env_side = RNDTransform(
            target,
            predictor,
            in_keys=["image"],
            out_keys=[RND_KEY],
            normalize_reward=False,
        )
        transform = PrecomputedBonusTransform(RND_KEY, **common)
        loss = RNDLoss(predictor, target, update_fraction=icfg.rnd.update_fraction)
        loss.set_keys(observation=("next", "image"))
    else:
        return None, None, None
    return transform, loss, env_side


def make_advantage(cfg, model, intrinsic_value, bonus_transform):
    """The advantage: GAE on the (mixed) reward, or two streams with two critics.

    Returns ``(advantage module, IntrinsicValueLoss or None)``.
    """
    if intrinsic_value is None:
        # One critic, on the env reward or on the transform's mixed reward.
        advantage = GAE(
            gamma=cfg.loss.gamma,
            lmbda=cfg.loss.gae_lambda,
            value_network=model.get_value_operator(),
            average_gae=False,
        )
        return advantage, None
    advantage = TwoStreamAdvantage(
        model.get_value_operator(),
        intrinsic_value,
        intrinsic_reward_key=bonus_transform.normalized_reward_key
        or bonus_transform.intrinsic_reward_key,
        # The transform's coefficient and schedule: coef means one thing.
        coef=bonus_transform.current_coef,
        gamma=cfg.loss.gamma,
        lmbda=cfg.loss.gae_lambda,
        episodic=cfg.intrinsic.episodic,
    )
    value_loss = IntrinsicValueLoss(intrinsic_value, critic_coef=cfg.loss.critic_coef)
    return advantage, value_loss


def make_collector(env, policy, cfg, total_frames: int):
    frames_per_batch = cfg.env.num_envs * cfg.collector.frames_per_env
    # ResumableCollector: a TorchRL Collector whose state_dict also holds the
    # episodes in progress, so a resumed run continues exactly.
    return ResumableCollector(
        env,
        policy,
        frames_per_batch=frames_per_batch,
        total_frames=total_frames,
        auto_register_policy_transforms=False,
    )
