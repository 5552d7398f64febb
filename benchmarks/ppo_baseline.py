"""A hand-written PPO on envpool's MiniGrid: the speed anchor of the PPO recipe.

The shape of CleanRL's ``ppo_atari_envpool.py``: the hyperparameters in one
dataclass, envpool called directly, plain ``torch`` tensors from the env to the
optimiser (no TensorDict, no TorchRL object), the whole update visible in
:func:`ppo_update`. What it computes is the MiniGrid recipe's PPO
(``recipes/minigrid/main.py algo=ppo``), with its defaults:

* the env: ``env.name`` on envpool, 64 envs, one envpool thread, stepped as the
  recipe's env steps it (``torchrl_surprise.envs.EnvPoolMiniGridEnv``): finished
  envs reset explicitly (no autoreset step), MultiRoom layouts with a door on a
  room's corner drawn again, MiniGrid's float64 success reward and its
  ``terminated`` on a success at the time limit;
* the model: rl-starter-files' actor-critic as the recipe builds it
  (``common.minigrid.make_actor_critic``): 3 conv layers (16/32/64) on the 7x7x3
  ids fed as numbers, 64-unit policy and value heads, unit-norm rows for the
  linear layers;
* the update: 64 envs x 32 steps a batch, GAE (gamma 0.99, lambda 0.95) with
  bootstrapping on time limits, 4 epochs of shuffled minibatches of 256, the
  clipped ratio (0.2), the value loss clipped by the same epsilon around the
  collecting critic's value (squared error, weight 0.5), entropy 0.01, the
  advantage normalised per minibatch, gradient norm clipped at 0.5, Adam (lr
  1e-3, eps 1e-8);
* ``--bonus vae_noveld`` (the recipe's ``+setting=vae_noveld``): NovelD on the
  library's :class:`~torchrl_surprise.StateVAE` (its negative ELBO as the
  novelty, :class:`~torchrl_surprise.transforms.EpisodicVisits` for first
  visits), the bonus divided by the running std of its discounted return, a
  second value head for the non-episodic intrinsic return, ``A = A_ext + 0.1
  A_int``, and two steps of the library's :class:`~torchrl_surprise.VAELoss`
  with a fused Adam (lr 1e-3) on each batch's next states.

``tests/test_ppo_baseline.py`` checks these numbers against the recipe's
resolved config and the network against the recipe's, weight for weight.

What it leaves out of the recipe's loop: evaluation, checkpoints, the env's log
of actions for an exact resume, the checks for non-finite values after every
minibatch. The values are computed during the rollout, with the policy (as
CleanRL does), where the recipe runs its critic over the batch after it.

Usage::

    python benchmarks/ppo_baseline.py --frames 40960
    python benchmarks/ppo_baseline.py --frames 40960 --bonus vae_noveld

Prints one JSON line: frames, frames per CPU second of this process in the
training loop (``fps_cpu``, the recipe's ``time/fps_cpu``), frames per second,
the last update's losses.
"""

from __future__ import annotations

import argparse
import json
import time
from dataclasses import asdict, dataclass

import numpy as np
import torch
from torch import nn
from torch.distributions import Categorical

__all__ = [
    "ActorCritic",
    "Args",
    "MiniGridPool",
    "ReturnStd",
    "gae",
    "main",
    "noveld_bonus",
    "ppo_update",
    "train",
]

BONUSES = ("none", "vae_noveld")


@dataclass
class Args:
    """The recipe's settings (``algo=ppo``; the bonus's with ``+setting=vae_noveld``)."""

    env_id: str = "MiniGrid-MultiRoom-N3-S4-v0"
    """``env.name``: the paper's N3S4 (envpool's MultiRoom-N2-S4 with 3 rooms)"""
    seed: int = 0
    total_frames: int = 40_960
    """``collector.total_frames``"""
    torch_threads: int = 1
    """``torch_threads``"""
    num_envs: int = 64
    """``env.num_envs``"""
    env_threads: int = 1
    """``env.num_threads``: envpool's threads"""
    num_steps: int = 32
    """``collector.frames_per_env``: steps per env per batch"""
    learning_rate: float = 1e-3
    """``optim.lr`` (Adam, ``optim.name``)"""
    adam_eps: float = 1e-8
    """``optim.eps``"""
    max_grad_norm: float = 0.5
    """``optim.max_grad_norm``"""
    gamma: float = 0.99
    """``loss.gamma``"""
    gae_lambda: float = 0.95
    """``loss.gae_lambda``"""
    ent_coef: float = 0.01
    """``loss.entropy_coef``"""
    vf_coef: float = 0.5
    """``loss.critic_coef``: the weight of the squared error (no extra 1/2)"""
    norm_adv: bool = True
    """``loss.normalize_advantage``: per minibatch"""
    clip_coef: float = 0.2
    """``loss.clip_epsilon``: the ratio's and the value's"""
    update_epochs: int = 4
    """``loss.epochs``"""
    minibatch_size: int = 256
    """``loss.minibatch_size``"""
    bonus: str = "none"
    """``none`` (``+setting=none``) or ``vae_noveld`` (``+setting=vae_noveld``)"""
    intrinsic_coef: float = 0.1
    """``intrinsic.coef``: A = A_ext + coef * A_int"""
    intrinsic_lr: float = 1e-3
    """``intrinsic.lr``: the VAE's Adam"""
    vae_update_steps: int = 2
    """``intrinsic.update_steps``: VAE steps on each batch"""
    vae_latent_dim: int = 32
    """``intrinsic.vae.latent_dim``"""
    vae_hidden_dim: int = 256
    """``intrinsic.vae.hidden_dim``"""
    vae_kl_weight: float = 1.0
    """``intrinsic.vae.kl_weight``"""
    noveld_alpha: float = 0.5
    """``intrinsic.vae.alpha``: NovelD's alpha"""

    @property
    def batch_size(self) -> int:
        return self.num_envs * self.num_steps


# ---- the env --------------------------------------------------------------------
class MiniGridPool:
    """envpool's MiniGrid stepped as the recipe's env steps it, in numpy and torch.

    ``step`` returns the step's observations (an episode's last one where it
    ends), its reward and flags, and the observations the next step starts from
    (finished envs reset with ``reset(env_ids)``, as TorchRL's collector resets
    them). Episode returns are counted here (the recipe's ``RewardSum``).
    """

    def __init__(self, env_id: str, num_envs: int, seed: int, num_threads: int = 1):
        import envpool

        from torchrl_surprise.envs.envpool import envpool_minigrid_task

        task, kwargs = envpool_minigrid_task(env_id)
        self.pool = envpool.make(
            task,
            env_type="gymnasium",
            num_envs=num_envs,
            seed=seed,
            num_threads=num_threads,
            **kwargs,
        )
        self.num_envs = num_envs
        self.num_actions = int(self.pool.action_space.n)
        self.redraw = self.pool.config["env_name"] == "multi_room"
        self.episode_return = np.zeros(num_envs)
        self.returns: list[float] = []

    def reset(self) -> tuple[torch.Tensor, torch.Tensor]:
        ids = np.arange(self.num_envs, dtype=np.int32)
        obs, _ = self.pool.reset()
        return self._fresh(ids, obs)

    def _fresh(self, ids: np.ndarray, obs) -> tuple[torch.Tensor, torch.Tensor]:
        """First observations of ``ids``, corner-door layouts drawn again."""
        from torchrl_surprise.envs.envpool import _has_corner_door

        image = torch.from_numpy(obs["image"])
        direction = torch.from_numpy(obs["direction"]).to(torch.int64)
        rows = np.arange(len(ids))
        while self.redraw and len(rows):
            # the env's own layout check: the same task as the recipe's
            states = self.pool.debug_states(ids[rows].tolist())
            rows = rows[[_has_corner_door(s) for s in states]]
            if len(rows):
                again, _ = self.pool.reset(ids[rows])
                image[rows] = torch.from_numpy(again["image"])
                direction[rows] = torch.from_numpy(again["direction"]).to(torch.int64)
        return image, direction

    def step(self, action: torch.Tensor, image: torch.Tensor, direction: torch.Tensor):
        """One step of every env.

        Returns ``(next_image, next_direction, reward, terminated, truncated,
        image, direction)``: the step's observations, reward and flags (torch,
        ``[num_envs]``), then where the next step starts.
        """
        obs, reward, terminated, truncated, info = self.pool.step(
            action.numpy().astype(np.int32)
        )
        self._fix_last_steps(reward, terminated, truncated, info["elapsed_step"])
        next_image = torch.from_numpy(obs["image"])
        next_direction = torch.from_numpy(obs["direction"]).to(torch.int64)
        done = terminated | truncated
        self.episode_return += reward
        image, direction = next_image, next_direction
        if done.any():
            ids = np.flatnonzero(done).astype(np.int32)
            self.returns.extend(self.episode_return[ids].tolist())
            self.episode_return[ids] = 0.0
            first, _ = self.pool.reset(ids)
            first_image, first_direction = self._fresh(ids, first)
            image, direction = next_image.clone(), next_direction.clone()
            image[ids] = first_image
            direction[ids] = first_direction
        return (
            next_image,
            next_direction,
            torch.from_numpy(reward),
            torch.from_numpy(terminated),
            torch.from_numpy(truncated),
            image,
            direction,
        )

    def _fix_last_steps(self, reward, terminated, truncated, elapsed) -> None:
        """MiniGrid's float64 success reward; a success at the time limit is
        terminated (envpool's differ: ``torchrl_surprise/envs/envpool.py``)."""
        from torchrl_surprise.envs.envpool import _on_lava

        success = reward > 0
        rows = np.flatnonzero(success | (truncated & ~success))
        if not len(rows):
            return
        for row, state in zip(rows, self.pool.debug_states(rows.tolist())):
            if success[row]:
                reward[row] = 1 - 0.9 * (int(elapsed[row]) / int(state.max_steps))
            if truncated[row] and not terminated[row]:
                if reward[row] != 0 or _on_lava(state):
                    terminated[row] = True


# ---- the model ------------------------------------------------------------------
def _head(out_features: int) -> nn.Sequential:
    head = nn.Sequential(nn.Linear(64, 64), nn.Tanh(), nn.Linear(64, out_features))
    for layer in (head[0], head[2]):
        # rl-starter-files' init_params: unit-norm rows, zero bias
        layer.weight.data.normal_(0, 1)
        layer.weight.data /= layer.weight.data.pow(2).sum(1, keepdim=True).sqrt()
        layer.bias.data.zero_()
    return head


class ActorCritic(nn.Module):
    """rl-starter-files' actor-critic, as the recipe builds it; with
    ``intrinsic_critic`` a second value head on the same trunk."""

    def __init__(self, num_actions: int = 7, intrinsic_critic: bool = False):
        super().__init__()
        self.trunk = nn.Sequential(
            nn.Conv2d(3, 16, (2, 2)),
            nn.ReLU(),
            nn.MaxPool2d((2, 2)),
            nn.Conv2d(16, 32, (2, 2)),
            nn.ReLU(),
            nn.Conv2d(32, 64, (2, 2)),
            nn.ReLU(),
            nn.Flatten(),
        )
        self.actor = _head(num_actions)
        self.critic = _head(1)
        self.critic_int = _head(1) if intrinsic_critic else None

    def hidden(self, image: torch.Tensor) -> torch.Tensor:
        """``[B, 7, 7, 3]`` uint8 ids -> ``[B, 64]`` features."""
        return self.trunk(image.float().permute(0, 3, 1, 2))

    def values(self, hidden: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor | None]:
        value = self.critic(hidden).squeeze(-1)
        if self.critic_int is None:
            return value, None
        return value, self.critic_int(hidden).squeeze(-1)


# ---- advantages and the bonus -----------------------------------------------------
def gae(reward, value, next_value, terminated, done, gamma: float, lam: float):
    """GAE over ``[T, N]``: ``terminated`` stops the bootstrap, ``done`` the trace
    (TorchRL's ``GAE``). Returns ``(advantage, value_target)``."""
    advantage = torch.zeros_like(reward)
    last = torch.zeros_like(reward[0])
    bootstrap = gamma * (~terminated).float()
    trace = gamma * lam * (~done).float()
    for t in reversed(range(reward.shape[0])):
        delta = reward[t] + bootstrap[t] * next_value[t] - value[t]
        last = delta + trace[t] * last
        advantage[t] = last
    return advantage, advantage + value


class ReturnStd:
    """The bonus over the running std of its discounted return, non-episodic
    (``intrinsic.normalization=return_std``; RND's normalisation)."""

    def __init__(self, num_envs: int, gamma: float):
        self.gamma = gamma
        self.acc = torch.zeros(num_envs)
        self.mean, self.var, self.count = torch.zeros(()), torch.ones(()), 1e-4

    def __call__(self, bonus: torch.Tensor) -> torch.Tensor:
        returns = torch.empty_like(bonus)
        for t in range(bonus.shape[0]):
            self.acc = self.acc * self.gamma + bonus[t]
            returns[t] = self.acc
        batch_mean, batch_var, n = (
            returns.mean(),
            returns.var(unbiased=False),
            bonus.numel(),
        )
        delta, total = batch_mean - self.mean, self.count + n
        m2 = self.var * self.count + batch_var * n + delta**2 * self.count * n / total
        self.mean = self.mean + delta * n / total
        self.var, self.count = m2 / total, total
        return bonus / self.var.clamp_min(1e-8).sqrt()


def noveld_bonus(
    vae, visits, image, direction, next_image, next_direction, done, alpha
):
    """NovelD on the VAE, ``[T, N]``: ``max(novelty(s') - alpha novelty(s), 0)``
    on first visits of the episode, the novelty the VAE's negative ELBO."""
    with torch.no_grad():
        novelty, next_novelty = vae.novelty(
            torch.stack([image, next_image]), torch.stack([direction, next_direction])
        ).unbind(0)
    gain = (next_novelty - alpha * novelty).clamp_min(0.0)
    first = visits.walk([image, direction], [next_image, next_direction], done, 0)
    return gain * first.to(gain.dtype)


# ---- the loop -------------------------------------------------------------------
@dataclass
class Rollout:
    """One batch, ``[T, N]`` (time first, as CleanRL stores it)."""

    image: torch.Tensor
    direction: torch.Tensor
    next_image: torch.Tensor
    next_direction: torch.Tensor
    action: torch.Tensor
    logprob: torch.Tensor
    reward: torch.Tensor
    terminated: torch.Tensor
    done: torch.Tensor
    value: torch.Tensor
    value_int: torch.Tensor | None


def collect(args: Args, envs: MiniGridPool, agent: ActorCritic, image, direction):
    """``num_steps`` steps of every env; returns the batch and where it stopped."""
    T, N = args.num_steps, args.num_envs
    empty = torch.empty
    two = args.bonus != "none"
    b = Rollout(
        image=empty((T, N, 7, 7, 3), dtype=torch.uint8),
        direction=empty((T, N), dtype=torch.int64),
        next_image=empty((T, N, 7, 7, 3), dtype=torch.uint8),
        next_direction=empty((T, N), dtype=torch.int64),
        action=empty((T, N), dtype=torch.int64),
        logprob=empty((T, N)),
        reward=empty((T, N)),
        terminated=empty((T, N), dtype=torch.bool),
        done=empty((T, N), dtype=torch.bool),
        value=empty((T, N)),
        value_int=empty((T, N)) if two else None,
    )
    for t in range(T):
        b.image[t], b.direction[t] = image, direction
        with torch.no_grad():
            hidden = agent.hidden(image)
            dist = Categorical(logits=agent.actor(hidden), validate_args=False)
            action = dist.sample()
            b.logprob[t] = dist.log_prob(action)
            value, value_int = agent.values(hidden)
        b.action[t], b.value[t] = action, value
        if two:
            b.value_int[t] = value_int
        out = envs.step(action, image, direction)
        b.next_image[t], b.next_direction[t], b.reward[t] = out[:3]
        b.terminated[t] = out[3]
        b.done[t] = out[3] | out[4]
        image, direction = out[5], out[6]
    return b, image, direction


@torch.no_grad()
def next_values(agent: ActorCritic, b: Rollout, image: torch.Tensor):
    """``V(s_{t+1})`` of each step: the next step's value, or at an episode's end
    the value of its last observation (bootstrapped where it is truncated)."""
    last, last_int = agent.values(agent.hidden(image))
    value = torch.cat([b.value[1:], last[None]])
    value_int = (
        None if b.value_int is None else torch.cat([b.value_int[1:], last_int[None]])
    )
    ended = b.done.nonzero(as_tuple=True)
    if len(ended[0]):
        final, final_int = agent.values(agent.hidden(b.next_image[ended]))
        value[ended] = final
        if value_int is not None:
            value_int[ended] = final_int
    return value, value_int


def ppo_update(
    args: Args, agent, optimizer, params, b: Rollout, advantage, target, target_int
):
    """``update_epochs`` passes of shuffled minibatches; the last one's losses."""
    flat = lambda x: x.reshape(args.batch_size, *x.shape[2:])  # noqa: E731
    image, action, logprob = flat(b.image), flat(b.action), flat(b.logprob)
    advantage, target, old_value = flat(advantage), flat(target), flat(b.value)
    if target_int is not None:
        target_int = flat(target_int)
    eps = torch.finfo(torch.float).resolution
    for _ in range(args.update_epochs):
        order = torch.randperm(args.batch_size)
        for start in range(0, args.batch_size, args.minibatch_size):
            mb = order[start : start + args.minibatch_size]
            hidden = agent.hidden(image[mb])
            dist = Categorical(logits=agent.actor(hidden), validate_args=False)
            ratio = (dist.log_prob(action[mb]) - logprob[mb]).exp()
            mb_adv = advantage[mb]
            if args.norm_adv:
                mb_adv = (mb_adv - mb_adv.mean()) / mb_adv.std().clamp_min(eps)
            clipped = ratio.clamp(1 - args.clip_coef, 1 + args.clip_coef)
            pg_loss = -torch.min(ratio * mb_adv, clipped * mb_adv).mean()
            value, value_int = agent.values(hidden)
            v_clipped = old_value[mb] + (value - old_value[mb]).clamp(
                -args.clip_coef, args.clip_coef
            )
            v_loss = (
                args.vf_coef
                * torch.max(
                    (value - target[mb]) ** 2, (v_clipped - target[mb]) ** 2
                ).mean()
            )
            entropy = dist.entropy().mean()
            loss = pg_loss + v_loss - args.ent_coef * entropy
            if value_int is not None:
                loss = loss + args.vf_coef * ((value_int - target_int[mb]) ** 2).mean()
            optimizer.zero_grad()
            loss.backward()
            nn.utils.clip_grad_norm_(params, args.max_grad_norm)
            optimizer.step()
    return {
        "loss": loss.item(),
        "loss_objective": pg_loss.item(),
        "loss_critic": v_loss.item(),
        "entropy": entropy.item(),
    }


def train_vae(args: Args, vae_loss, vae_optimizer, b: Rollout) -> float:
    """``vae_update_steps`` steps of the library's ``VAELoss`` on the batch's
    next states (the recipe's ``train_bonus_model``)."""
    total = torch.zeros(())
    for _ in range(args.vae_update_steps):
        out = vae_loss(next={"image": b.next_image, "direction": b.next_direction})
        total = out["loss_reconstruction"] + out["loss_kl"]
        vae_optimizer.zero_grad()
        total.backward()
        vae_optimizer.step()
    return total.item()


@dataclass
class Bonus:
    """NovelD on the VAE: the library's modules, its loss, the normalisation."""

    vae: nn.Module
    loss: nn.Module
    optimizer: torch.optim.Optimizer
    visits: nn.Module
    normalize: ReturnStd


def make_bonus(args: Args) -> Bonus | None:
    if args.bonus not in BONUSES:
        raise ValueError(f"bonus must be one of {BONUSES}, got {args.bonus!r}.")
    if args.bonus == "none":
        return None
    from torchrl_surprise import StateVAE, VAELoss
    from torchrl_surprise.transforms import EpisodicVisits

    vae = StateVAE.for_minigrid(
        latent_dim=args.vae_latent_dim, hidden_dim=args.vae_hidden_dim
    )
    loss = VAELoss(vae, kl_weight=args.vae_kl_weight)
    optimizer = torch.optim.Adam(vae.parameters(), lr=args.intrinsic_lr, fused=True)
    normalize = ReturnStd(args.num_envs, args.gamma)
    return Bonus(vae, loss, optimizer, EpisodicVisits(), normalize)


def advantages(args: Args, agent, bonus: Bonus | None, b: Rollout, image):
    """GAE on the env reward; with the bonus, ``+ coef *`` GAE on the normalised
    bonus with the intrinsic critic, across episode ends. Returns
    ``(advantage, value_target, intrinsic value_target or None)``."""
    next_value, next_value_int = next_values(agent, b, image)
    lam = args.gae_lambda
    advantage, target = gae(
        b.reward, b.value, next_value, b.terminated, b.done, args.gamma, lam
    )
    if bonus is None:
        return advantage, target, None
    raw = noveld_bonus(
        bonus.vae,
        bonus.visits,
        b.image,
        b.direction,
        b.next_image,
        b.next_direction,
        b.done,
        args.noveld_alpha,
    )
    normalized = bonus.normalize(raw)
    never = torch.zeros_like(b.done)
    advantage_int, target_int = gae(
        normalized, b.value_int, next_value_int, never, never, args.gamma, lam
    )
    return advantage + args.intrinsic_coef * advantage_int, target, target_int


def train(args: Args) -> dict:
    """The run; returns frames, frames per CPU second and per second of the loop,
    and the last update's losses."""
    torch.set_num_threads(args.torch_threads)
    torch.manual_seed(args.seed)
    envs = MiniGridPool(args.env_id, args.num_envs, args.seed, args.env_threads)
    agent = ActorCritic(envs.num_actions, intrinsic_critic=args.bonus != "none")
    params = list(agent.parameters())
    optimizer = torch.optim.Adam(
        params, lr=args.learning_rate, eps=args.adam_eps, foreach=True
    )
    bonus = make_bonus(args)
    image, direction = envs.reset()
    updates = max(-(-args.total_frames // args.batch_size), 1)
    cpu, wall = time.process_time(), time.perf_counter()
    for _ in range(updates):
        b, image, direction = collect(args, envs, agent, image, direction)
        advantage, target, target_int = advantages(args, agent, bonus, b, image)
        logs = ppo_update(
            args, agent, optimizer, params, b, advantage, target, target_int
        )
        if bonus is not None:
            logs["loss_vae"] = train_vae(args, bonus.loss, bonus.optimizer, b)
    cpu, wall = time.process_time() - cpu, time.perf_counter() - wall
    frames = updates * args.batch_size
    return {
        "frames": frames,
        "fps_cpu": frames / cpu,
        "fps": frames / wall,
        "episodes": len(envs.returns),
        "mean_return": float(np.mean(envs.returns)) if envs.returns else 0.0,
        **logs,
    }


def main(argv: list[str] | None = None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=Args.total_frames)
    parser.add_argument("--bonus", choices=BONUSES, default="none")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--env", default=Args.env_id)
    cli = parser.parse_args(argv)
    args = Args(env_id=cli.env, seed=cli.seed, total_frames=cli.frames, bonus=cli.bonus)
    result = {"args": asdict(args), **train(args)}
    print(json.dumps(result))
    return result


if __name__ == "__main__":
    main()
