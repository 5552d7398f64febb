"""A user's own TorchRL pipeline with the VAE surprise bonus and two critics.

Everything here is plain TorchRL (a ``Collector``, ``A2CLoss``, the user's own
actor-critic) plus three pieces of torchrl_surprise:

* ``VAESurpriseTransform`` computes the bonus of a collected batch in one pass
  (the VAE as it was during the rollout) and normalises it;
* ``TwoStreamAdvantage`` gives ``A = A_ext + coef * A_int`` from an episodic
  extrinsic critic and a non-episodic intrinsic critic;
* ``VAELoss`` and ``IntrinsicValueLoss`` train the VAE and the intrinsic critic.

Run: ``python docs/examples/two_stream_a2c.py --frames 20000``.
"""

from __future__ import annotations

import argparse

import torch
from tensordict.nn import TensorDictModule, TensorDictSequential
from torch import nn
from torch.distributions import Categorical
from torchrl.collectors import Collector
from torchrl.envs import Compose, RewardSum, TransformedEnv
from torchrl.modules import ProbabilisticActor, ValueOperator
from torchrl.objectives import A2CLoss

from torchrl_surprise import (
    IntrinsicValueLoss,
    StateVAE,
    TwoStreamAdvantage,
    VAELoss,
    VAESurpriseTransform,
)
from torchrl_surprise.envs import make_minigrid_env


class AsFloat(nn.Module):
    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return x.float()


def make_actor_critic(num_actions: int):
    """A small MLP trunk on the 7x7x3 view, a policy and two value heads."""
    trunk = TensorDictModule(
        # MiniGrid's view holds uint8 ids: fed as numbers, as rl-starter-files does
        nn.Sequential(AsFloat(), nn.Flatten(-3), nn.Linear(147, 64), nn.Tanh()),
        in_keys=["image"],
        out_keys=["hidden"],
    )
    policy = ProbabilisticActor(
        TensorDictSequential(
            trunk, TensorDictModule(nn.Linear(64, num_actions), ["hidden"], ["logits"])
        ),
        in_keys=["logits"],
        distribution_class=Categorical,
        return_log_prob=True,
    )
    value = TensorDictSequential(trunk, ValueOperator(nn.Linear(64, 1), ["hidden"]))
    value_int = TensorDictSequential(
        trunk, ValueOperator(nn.Linear(64, 1), ["hidden"], ["state_value_int"])
    )
    return policy, value, value_int


def main(frames: int = 20_000, env_name: str = "MiniGrid-MultiRoom-N3-S4-v0") -> dict:
    torch.manual_seed(0)
    env = make_minigrid_env(env_name, num_envs=16, seed=0)
    # The episode return is summed before any bonus: it is the task's return.
    env = TransformedEnv(env, Compose(RewardSum()))
    policy, value, value_int = make_actor_critic(env.action_spec.space.n)

    vae = StateVAE.for_minigrid()
    # reward_key=None: the transform writes the bonus but does not mix it into
    # the reward; the two-stream advantage mixes advantages instead.
    surprise = VAESurpriseTransform(
        vae, coef=0.5, normalization="return_std", reward_key=None
    )
    advantage = TwoStreamAdvantage(
        value,
        value_int,
        intrinsic_reward_key=surprise.normalized_reward_key,
        coef=surprise.current_coef,  # one coefficient, the transform's
    )
    a2c = A2CLoss(policy, value, entropy_coeff=0.01, critic_coeff=0.5)
    critic_int = IntrinsicValueLoss(value_int, critic_coef=0.5)
    vae_loss = VAELoss(vae)
    # The shared trunk's parameters once each, in a fixed order (a set's order
    # changes from run to run, and with it the optimiser's arithmetic).
    params = list(
        dict.fromkeys(p for m in (policy, value, value_int) for p in m.parameters())
    )
    optim = torch.optim.RMSprop(params, lr=1e-3, alpha=0.99, eps=1e-8)
    vae_optim = torch.optim.Adam(vae.parameters(), lr=1e-3)

    collector = Collector(
        env,
        policy,
        frames_per_batch=128,
        total_frames=frames,
        auto_register_policy_transforms=False,
    )
    returns, bonus = [], []
    for data in collector:
        with torch.no_grad():
            data = surprise(data)  # bonus of the whole rollout, current VAE
            data = advantage(data)  # A_ext + coef * A_int, and both targets
        losses = a2c(data)
        loss = losses["loss_objective"] + losses["loss_critic"] + losses["loss_entropy"]
        loss = loss + critic_int(data)["loss_critic_int"]
        optim.zero_grad()
        loss.backward()
        nn.utils.clip_grad_norm_(params, 0.5)
        optim.step()
        # Algorithm 1: then the VAE trains on this rollout's states.
        vae_td = vae_loss(data)
        vae_optim.zero_grad()
        (vae_td["loss_reconstruction"] + vae_td["loss_kl"]).backward()
        vae_optim.step()

        done = data["next", "done"].squeeze(-1)
        returns += data["next", "episode_reward"].squeeze(-1)[done].tolist()
        bonus.append(data["next", "intrinsic_reward"].mean().item())
    collector.shutdown()
    result = {
        "episodes": len(returns),
        "mean_return_last_100": sum(returns[-100:]) / max(len(returns[-100:]), 1),
        "mean_bonus_first": bonus[0],
        "mean_bonus_last": bonus[-1],
    }
    print(result)
    return result


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=20_000)
    parser.add_argument("--env", default="MiniGrid-MultiRoom-N3-S4-v0")
    args = parser.parse_args()
    main(args.frames, args.env)
