"""Tutorial: the VAE surprise bonus in your own TorchRL PPO pipeline.

The env, the networks, the collector and the PPO loss are plain TorchRL; the
bonus comes from torchrl_surprise: ``VAESurpriseTransform`` (the KL bonus of a
collected batch), ``VAELoss`` (trains the same VAE), ``TwoStreamAdvantage`` and
``IntrinsicValueLoss`` (a second critic for the bonus). The script plots the bonus
as the VAE trains, and over the states of one episode. The walk-through is
``docs/tutorial.rst``.

Run: ``python docs/examples/tutorial_surprise.py --frames 20000 --out docs/results/tutorial/bonus.png``
"""

from __future__ import annotations

import argparse
import copy
from pathlib import Path

import torch
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from tensordict.nn import TensorDictModule, TensorDictSequential
from torch import nn
from torch.distributions import Categorical
from torchrl.collectors import Collector
from torchrl.envs import (
    Compose,
    DTypeCastTransform,
    ExplorationType,
    FlattenObservation,
    RewardSum,
    TransformedEnv,
    set_exploration_type,
)
from torchrl.modules import ActorValueOperator, ProbabilisticActor, ValueOperator
from torchrl.objectives import ClipPPOLoss

from torchrl_surprise import (
    IntrinsicValueLoss,
    StateVAE,
    TwoStreamAdvantage,
    VAELoss,
    VAESurpriseTransform,
)
from torchrl_surprise.envs import make_minigrid_env


def make_env(env_name: str, num_envs: int, seed: int) -> TransformedEnv:
    """MiniGrid as a batched TorchRL env, with a float view for the policy."""
    env = make_minigrid_env(env_name, num_envs=num_envs, seed=seed)
    return TransformedEnv(
        env,
        Compose(
            # "image" holds uint8 ids: the VAE embeds them as categories, the
            # policy reads a float copy of them as one flat vector.
            DTypeCastTransform(
                torch.uint8, torch.float32, in_keys=["image"], out_keys=["view"]
            ),
            FlattenObservation(-3, -1, in_keys=["view"]),
            RewardSum(),  # the task's return, before any bonus
        ),
    )


def make_actor_critic(num_actions: int):
    """A shared trunk, a policy, the extrinsic critic and the intrinsic critic."""
    trunk = TensorDictModule(
        nn.Sequential(nn.Linear(147, 64), nn.Tanh()), ["view"], ["hidden"]
    )
    policy_head = ProbabilisticActor(
        TensorDictModule(nn.Linear(64, num_actions), ["hidden"], ["logits"]),
        in_keys=["logits"],
        distribution_class=Categorical,
        return_log_prob=True,  # PPO's ratio needs the collecting policy's
    )
    model = ActorValueOperator(
        trunk, policy_head, ValueOperator(nn.Linear(64, 1), ["hidden"])
    )
    value_int = TensorDictSequential(
        trunk, ValueOperator(nn.Linear(64, 1), ["hidden"], ["state_value_int"])
    )
    return model.get_policy_operator(), model.get_value_operator(), value_int


def make_bonus(value, value_int):
    """The VAE, its bonus transform and loss, and the two-stream advantage."""
    vae = StateVAE.for_minigrid()  # reads "image" and "direction"
    # reward_key=None: the bonus is written beside the reward, not mixed into it;
    # the intrinsic critic learns its return instead.
    surprise = VAESurpriseTransform(
        vae, coef=0.5, normalization="return_std", reward_key=None
    )
    vae_loss = VAELoss(vae)  # the same VAE: training it changes the bonus
    advantage = TwoStreamAdvantage(
        value,
        value_int,
        intrinsic_reward_key=surprise.normalized_reward_key,
        coef=surprise.current_coef,
        episodic=False,  # novelty does not end with the episode
    )
    return surprise, vae_loss, advantage


def ppo_update(ppo, critic_int, optim, data, epochs=4, minibatch_size=128):
    """Clipped PPO on shuffled minibatches; the intrinsic critic trains beside."""
    flat = data.reshape(-1)
    for _ in range(epochs):
        for index in torch.randperm(flat.numel()).split(minibatch_size):
            batch = flat[index]
            losses = ppo(batch)
            loss = losses["loss_objective"] + losses["loss_critic"]
            loss = loss + losses["loss_entropy"] + critic_int(batch)["loss_critic_int"]
            optim.zero_grad()
            loss.backward()
            nn.utils.clip_grad_norm_(optim.param_groups[0]["params"], 0.5)
            optim.step()


@torch.no_grad()
def bonus_over_episode(env, policy, vaes: dict) -> dict:
    """The raw bonus of each state of one episode, under each VAE given."""
    with set_exploration_type(ExplorationType.RANDOM):
        episode = env.rollout(10_000, policy)  # stops at the episode's end
    return {
        name: VAESurpriseTransform(vae, reward_key=None)(episode.clone())[
            "next", "intrinsic_reward"
        ].flatten()
        for name, vae in vaes.items()
    }


def plot_bonus(result: dict, out: str | Path) -> None:
    """Mean bonus per update against frames; the bonus over one episode."""
    fig = Figure(figsize=(10, 3.6), layout="constrained")
    FigureCanvasAgg(fig)
    left, right = fig.subplots(1, 2)
    left.plot(result["frames"], result["bonus"], marker=".")
    left.set(xlabel="frames", ylabel="mean KL bonus of the batch (nats)")
    left.set_title("The bonus as the VAE trains")
    for name, bonus in result["episode_bonus"].items():
        right.plot(bonus, label=f"{name} VAE")
    right.set(xlabel="step of the episode", ylabel="KL bonus (nats)")
    right.set_title("One episode, scored by the VAE before and after")
    right.legend()
    Path(out).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=120)


def main(
    frames: int = 20_000,
    out: str | Path | None = None,
    env_name: str = "MiniGrid-DoorKey-5x5-v0",
    seed: int = 0,
) -> dict:
    """Trains for ``frames`` frames and plots the bonus to ``out``, if given.

    Returns a dict: ``"frames"`` and ``"bonus"`` (the mean raw KL of each
    update's batch), ``"returns"`` (the task return of each finished episode),
    ``"last_batch"`` (with both advantages) and ``"episode_bonus"`` (the bonus
    of one episode's states under the untrained and the trained VAE).
    """
    torch.manual_seed(seed)
    env = make_env(env_name, num_envs=8, seed=seed)
    policy, value, value_int = make_actor_critic(env.action_spec.space.n)
    surprise, vae_loss, advantage = make_bonus(value, value_int)
    untrained_vae = copy.deepcopy(vae_loss.vae)
    ppo = ClipPPOLoss(policy, value, entropy_coeff=0.01, critic_coeff=0.5)
    critic_int = IntrinsicValueLoss(value_int, critic_coef=0.5)
    # The trunk is in all three: each parameter once, in a fixed order.
    params = dict.fromkeys(
        p for m in (policy, value, value_int) for p in m.parameters()
    )
    optim = torch.optim.Adam(list(params), lr=1e-3)
    vae_optim = torch.optim.Adam(vae_loss.parameters(), lr=1e-3)
    collector = Collector(
        env,
        policy,
        frames_per_batch=8 * 50,
        total_frames=frames,
        auto_register_policy_transforms=False,
    )

    result = {"frames": [], "bonus": [], "returns": []}
    seen = 0
    for data in collector:
        with torch.no_grad():
            data = surprise(data)  # the bonus of each next state, current VAE
            data = advantage(data)  # A_ext + coef * A_int, and both critics' targets
        ppo_update(ppo, critic_int, optim, data)
        # Then the VAE learns this rollout's states, in minibatches of 128.
        flat = data.reshape(-1)
        for index in torch.randperm(flat.numel()).split(128):
            vae_td = vae_loss(flat[index])
            vae_optim.zero_grad()
            (vae_td["loss_reconstruction"] + vae_td["loss_kl"]).backward()
            vae_optim.step()

        seen += data.numel()
        done = data["next", "done"].squeeze(-1)
        result["returns"] += data["next", "episode_reward"].squeeze(-1)[done].tolist()
        result["frames"].append(seen)
        result["bonus"].append(data["next", "intrinsic_reward"].mean().item())
    collector.shutdown()

    result["last_batch"] = data
    result["episode_bonus"] = bonus_over_episode(
        make_env(env_name, num_envs=1, seed=seed + 1),
        policy,
        {"untrained": untrained_vae, "trained": vae_loss.vae},
    )
    if out is not None:
        plot_bonus(result, out)
    returns = result["returns"]
    print(
        f"{len(returns)} episodes, mean return {sum(returns) / max(len(returns), 1):.3f}; "
        f"mean bonus {result['bonus'][0]:.3f} -> {result['bonus'][-1]:.3f} nats"
    )
    return result


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=20_000)
    parser.add_argument("--out", help="where to save the figure (PNG)")
    parser.add_argument("--env", default="MiniGrid-DoorKey-5x5-v0")
    args = parser.parse_args()
    main(args.frames, args.out, args.env)
