"""Builders shared by the MiniGrid recipes (A2C, PPO): envs, the
rl-starter-files actor-critic, the bonus and its advantage, the collector, and the
pieces of the training loop both recipes run alike (the bonus model's update, the
rollout metrics, the evaluation).

Run support, not library core: it imports minigrid (through the env factory) and is
imported by the recipes only.
"""

from __future__ import annotations

import functools
import os
from pathlib import Path

import torch
from omegaconf import OmegaConf
from tensordict.nn import TensorDictModule, TensorDictSequential
from torch import nn
from torch.distributions import Categorical
from torchrl.envs import Compose, RewardSum, StepCounter, TransformedEnv
from torchrl.modules import ActorValueOperator, ProbabilisticActor, ValueOperator
from torchrl.objectives.value import GAE

from common.bonuses import BONUSES
from common.checkpoint import DamagedCheckpoint, find_checkpoint, load_checkpoint
from common.errors import ConfigError
from common.labels import GYMNASIUM, split_level, task_name
from torchrl_surprise import (
    IntrinsicValueLoss,
    TwoStreamAdvantage,
)
from torchrl_surprise.collectors import (
    ResumableCollector,
    ResumableMultiSyncCollector,
)
from torchrl_surprise.envs import UnknownMiniGridTask, make_minigrid_env
from torchrl_surprise.transforms import (
    make_coef_schedule,
)
from torchrl_surprise.transforms.stochasticity import StochasticityTransform

__all__ = [
    "MiniGridConvTrunk",
    "bonus_update_steps",
    "committed_summary",
    "measured_comparison",
    "init_rl_starter",
    "load_bonus_model",
    "make_actor_critic",
    "inverse_head",
    "make_advantage",
    "make_bonus",
    "make_collector",
    "make_env",
    "oracle_optimum",
    "rollout_metrics",
    "shared_trunk",
    "train_bonus_model",
]


def make_env(env_cfg, num_envs: int, seed: int, bonus: str = "none", rnd=None):
    """MiniGrid as one batched TorchRL env, with noise, episode stats (and RND).

    Args:
        env_cfg: the config's ``env`` section (``name``, ``backend``,
            ``num_threads``, ``stochasticity``).
        num_envs (int): envs in the batch.
        seed (int): the envs' seed.
        bonus (str): ``"rnd"`` appends ``rnd`` (TorchRL's ``RNDTransform``).

    Raises:
        ConfigError: ``env.name`` is not a task of ``env.backend`` (the factory's
            message names the close ids).
    """
    try:
        env = make_minigrid_env(
            env_cfg.name,
            num_envs=num_envs,
            backend=env_cfg.backend,
            num_threads=env_cfg.num_threads,
        )
    except UnknownMiniGridTask as err:
        raise ConfigError(f"env.name={env_cfg.name}: {err}") from None
    transforms = []
    if env_cfg.stochasticity:
        # Transforms are not seeded by env.set_seed in TorchRL 0.14: seed it here.
        noise = StochasticityTransform.from_level(env_cfg.stochasticity, seed=seed + 1)
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


def make_actor_critic(
    action_spec, intrinsic_critic: bool, return_log_prob: bool = False
):
    """Shared conv trunk, a categorical policy head and one (or two) value heads.

    ``return_log_prob=True`` makes the policy write ``"action_log_prob"`` as it
    acts (PPO's ratio needs the log-probability under the collecting policy).
    """
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
        return_log_prob=return_log_prob,
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
    """The bonus ``bonus`` (a name in :data:`common.bonuses.BONUSES`, or
    ``"none"``): ``(batch transform, loss on the bonus model, env-side transform
    or None)``, all ``None`` for ``"none"``."""
    if bonus == "none":
        return None, None, None
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
    return BONUSES[bonus].build(cfg, action_spec, common)


def inverse_head(bonus_loss) -> nn.Module | None:
    """The inverse model on the VAE's latent (``intrinsic.vae.inverse_weight > 0``),
    which a checkpoint holds beside the bonus transform (that holds the VAE);
    ``None`` for every other bonus."""
    inverse_loss = getattr(bonus_loss, "inverse_loss", None)
    return None if inverse_loss is None else inverse_loss.model.inverse_model


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
    # One critic with both value heads on the shared trunk: one pass of the trunk
    # over the batch's states and next states gives all four values.
    int_head = intrinsic_value.module[-1]
    both = TensorDictSequential(shared_trunk(model), model.get_value_head(), int_head)
    advantage = TwoStreamAdvantage(
        both,
        None,
        intrinsic_reward_key=bonus_transform.normalized_reward_key
        or bonus_transform.intrinsic_reward_key,
        # The transform's coefficient and schedule: coef means one thing.
        coef=bonus_transform.current_coef,
        gamma=cfg.loss.gamma,
        lmbda=cfg.loss.gae_lambda,
        episodic=cfg.intrinsic.episodic,
    )
    # The head only: it reads the trunk's features that the training loop computes
    # once, with gradients, for every loss (shared_trunk).
    value_loss = IntrinsicValueLoss(int_head, critic_coef=cfg.loss.critic_coef)
    return advantage, value_loss


def shared_trunk(model) -> TensorDictModule:
    """The actor-critic's trunk, to run once per update before the losses.

    The recipes' losses (TorchRL's ``A2CLoss`` / ``ClipPPOLoss`` and
    :class:`~torchrl_surprise.IntrinsicValueLoss`) are given the policy and value
    heads only, which read the trunk's ``"hidden"`` features from the batch: the
    training loop runs ``data = trunk(data)`` with gradients first, so the trunk
    runs once per update instead of once per head, and its gradient is the sum of
    the heads' as before. (The batch's ``"hidden"`` from the rollout was computed
    without gradients; the trunk call replaces it.)

    Examples:
        >>> from torchrl.data import Categorical
        >>> model, _ = make_actor_critic(Categorical(7), intrinsic_critic=False)
        >>> trunk = shared_trunk(model)
        >>> trunk.in_keys, trunk.out_keys
        (['image'], ['hidden'])
        >>> model.get_value_head().in_keys
        ['hidden']
    """
    return model.module[0]


def make_collector(env, policy, cfg, total_frames: int, device=None):
    """The collector of ``env.num_envs * collector.frames_per_env`` frames a batch.

    With ``collector.workers`` 1 (the default, and what a config without the entry
    gets): a :class:`~torchrl_surprise.collectors.ResumableCollector` stepping
    ``env`` in this process. With more, a
    :class:`~torchrl_surprise.collectors.ResumableMultiSyncCollector`: worker
    ``w`` builds ``env.num_envs / workers`` envs seeded from
    ``seed + w * env.num_envs / workers`` (the sub-envs get the seeds they get with
    one process), ``env`` only gave the specs and is closed. Either way the state
    holds the episodes in progress, so a resumed run continues exactly.

    With ``device`` (the ``device`` setting), the policy runs there and the batch is
    stored there, the envs step on the CPU (TorchRL moves each step's entries
    between them); with the CPU, no entry is copied.
    """
    workers = cfg.collector.get("workers", 1)
    devices = {}
    if device is not None:
        devices = dict(policy_device=device, env_device="cpu", storing_device=device)
    frames_per_batch = cfg.env.num_envs * cfg.collector.frames_per_env
    if workers == 1:
        # ResumableCollector: a TorchRL Collector whose state_dict also holds the
        # episodes in progress, so a resumed run continues exactly.
        return ResumableCollector(
            env,
            policy,
            frames_per_batch=frames_per_batch,
            total_frames=total_frames,
            auto_register_policy_transforms=False,
            **devices,
        )
    env.close()
    per_worker = cfg.env.num_envs // workers
    # The workers are spawned processes: the factories travel pickled, with the
    # env settings only (no Hydra interpolation to resolve there).
    env_cfg = OmegaConf.create(OmegaConf.to_container(cfg.env, resolve=True))
    factories = [
        functools.partial(make_env, env_cfg, per_worker, seed=cfg.seed + w * per_worker)
        for w in range(workers)
    ]
    return ResumableMultiSyncCollector(
        factories,
        policy,
        frames_per_batch=per_worker * cfg.collector.frames_per_env,
        total_frames=total_frames,
        seed=cfg.seed,
        auto_register_policy_transforms=False,
        **devices,
    )


def bonus_update_steps(cfg, iteration: int) -> int:
    """The bonus model's gradient steps after rollout ``iteration`` (from 0).

    ``intrinsic.update_steps`` on every ``intrinsic.update_every``-th rollout
    (absent from older configs: 1, every rollout), the first included; none on the
    others and none at all for a transferred model kept frozen
    (``intrinsic.finetune: false``). The count depends on the rollout's index only,
    so a resumed run trains on the same rollouts as the uninterrupted one.

    Examples:
        >>> from omegaconf import OmegaConf
        >>> cfg = OmegaConf.create({"intrinsic": {"update_steps": 2,
        ...     "update_every": 4, "finetune": True}})
        >>> [bonus_update_steps(cfg, i) for i in range(6)]
        [2, 0, 0, 0, 2, 0]
    """
    icfg = cfg.intrinsic
    if not icfg.finetune or iteration % icfg.get("update_every", 1):
        return 0
    return icfg.update_steps


def train_bonus_model(
    bonus_loss, optim, data, steps: int, env_side=None, batch_size: int | None = None
):
    """``steps`` gradient steps of the bonus model on the states of ``data``.

    Each step minimises the sum of the ``loss_*`` entries of ``bonus_loss(data)``,
    or with ``batch_size`` of ``bonus_loss`` on that many of the batch's
    transitions, drawn without replacement (torch's global generator, which the
    checkpoint holds) for each step. With RND (``env_side``, TorchRL's
    ``RNDTransform``), ``RNDLoss`` normalises the states with the env-side
    transform's running statistics.

    Returns:
        The loss TensorDict of the last step (``None`` without a bonus model or
        when ``steps`` is 0).
    """
    if bonus_loss is None:
        return None
    if env_side is not None:
        bonus_loss.obs_rms = env_side.obs_rms
    bonus_td = None
    flat = data.reshape(-1)
    for _ in range(steps):
        if batch_size is not None and batch_size < flat.numel():
            data = flat[torch.randperm(flat.numel(), device=flat.device)[:batch_size]]
        bonus_td = bonus_loss(data)
        bonus_total = sum(v for k, v in bonus_td.items() if k.startswith("loss_"))
        optim.zero_grad()
        bonus_total.backward()
        optim.step()
    return bonus_td


def rollout_metrics(stats, data, bonus_transform=None, bonus_td=None) -> dict:
    """What both recipes log about a collected batch, by metric name.

    The episode statistics (extrinsic return, success rate, length, episode count),
    the mean reward of the batch, and with a bonus its raw and normalised mean, the
    current coefficient and the bonus model's losses (``bonus/*``).
    """
    metrics = {
        "train/episode_return": stats.mean_return,
        "train/success_rate": stats.success_rate,
        "train/episode_length": stats.mean_length,
        "train/episodes": stats.episodes,
        "train/reward": data["next", "reward"].mean().item(),
    }
    if bonus_transform is not None:
        next_td = data["next"]
        metrics["train/intrinsic_reward"] = (
            next_td[bonus_transform.intrinsic_reward_key].mean().item()
        )
        if bonus_transform.normalized_reward_key is not None:
            metrics["train/intrinsic_reward_normalized"] = (
                next_td[bonus_transform.normalized_reward_key].mean().item()
            )
        metrics["train/intrinsic_coef"] = bonus_transform.current_coef()
    if bonus_td is not None:
        for key, value in bonus_td.items():
            metrics[f"bonus/{key}"] = value.mean().item()
    return metrics


def load_bonus_model(
    transform, bonus: str, source: str | os.PathLike, inverse_head=None
) -> int:
    """Starts a bonus model from another run's (transfer), without its statistics.

    Args:
        transform: the bonus transform of this run.
        bonus (str): a bonus whose registry entry names its model
            (:attr:`common.bonuses.Bonus.model_attr`).
        source: a run directory or its checkpoint file.
        inverse_head: this run's inverse model on the VAE's latent
            (:func:`inverse_head`, ``intrinsic.vae.inverse_weight > 0``), started
            from the source run's when that run trained one (else it starts
            afresh, and this says so).

    Returns:
        The number of frames the source run had trained for.
    """
    transferable = [name for name, b in BONUSES.items() if b.model_attr]
    if bonus not in transferable:
        raise ValueError(
            f"intrinsic.init_from supports bonus {', '.join(transferable)}, "
            f"not {bonus!r}."
        )
    try:
        path = find_checkpoint(source)
    except FileNotFoundError as err:
        raise FileNotFoundError(f"intrinsic.init_from: {err}.") from None
    try:
        ckpt = load_checkpoint(path)
    except DamagedCheckpoint as err:
        raise ValueError(f"intrinsic.init_from: {err}") from err
    source_bonus = ckpt.get("config", {}).get("bonus")
    if source_bonus != bonus:
        raise ValueError(
            f"intrinsic.init_from: {path} was trained with bonus={source_bonus!r}, "
            f"this run has bonus={bonus!r}."
        )
    prefix = BONUSES[bonus].model_attr + "."
    weights = {
        k[len(prefix) :]: v
        for k, v in ckpt["bonus_transform"].items()
        if k.startswith(prefix)
    }
    model = getattr(transform, BONUSES[bonus].model_attr)
    try:
        model.load_state_dict(weights)
    except RuntimeError as err:
        raise ValueError(
            f"intrinsic.init_from: the model in {path} does not fit this run's "
            f"(sizes in intrinsic.{bonus}.* must match the source run's): {err}"
        ) from err
    if inverse_head is not None:
        if "bonus_inverse_head" in ckpt:
            inverse_head.load_state_dict(ckpt["bonus_inverse_head"])
        else:
            print(
                f"intrinsic.init_from: {path} trained no inverse model on the VAE's "
                "latent; this run's starts afresh."
            )
    return int(ckpt.get("frames", 0))


ORACLE_LAYOUTS = 20
"""The layouts :func:`oracle_optimum` solves: its line is their mean return."""


def oracle_optimum(env_name: str, seed: int, stochasticity: int = 0):
    """The oracle's mean return on ``env_name``, ``(label, value)``, for the
    learning curve's dashed line; ``None`` for a task the oracle does not solve.

    :func:`torchrl_surprise.envs.oracle_returns` on :data:`ORACLE_LAYOUTS` layouts
    of minigrid's envs from ``seed`` on (the evaluation's seeds): the best return
    of an agent that sees the whole grid, the return the results pages divide by
    (``oracle_return``). envpool's layouts of the same task have the same mean
    within a percent (docs/results/oracle). Under ``env.stochasticity`` no agent
    reaches it: the line is then labelled noise-free.

    Examples:
        >>> label, value = oracle_optimum("MiniGrid-DoorKey-5x5-v0", seed=0)
        >>> label, round(value, 2)
        ('oracle (mean of 20 layouts)', 0.96)
    """
    import gymnasium as gym

    from torchrl_surprise.envs import oracle_returns

    try:
        solutions = oracle_returns(env_name, range(seed, seed + ORACLE_LAYOUTS))
    except (TypeError, ValueError, gym.error.Error):
        # not a goal or pickup task the oracle solves (Fetch, ...), or no minigrid
        # env of that id
        return None
    value = sum(s.episode_return for s in solutions) / len(solutions)
    label = f"oracle (mean of {ORACLE_LAYOUTS} layouts)"
    if stochasticity:
        label = f"noise-free {label}"
    return label, value


def measured_comparison(
    task: str,
    backend: str,
    frames: int,
    results_dir: str | os.PathLike,
    recipe: str,
    stochasticity: int = 0,
    run_return: float | None = None,
) -> str:
    """A run's closing lines: the run beside the plain learner and the best
    setting measured on its task (env id ``task`` on ``backend``), from one
    committed summary; ``""`` if none.

    The summary is :func:`committed_summary`'s; scores are its IQM [95% CI]
    over seeds of the final return over the oracle's (raw where it has no oracle),
    and ``run_return`` (this run's final 100-episode mean) on the same scale.

    Examples:
        >>> measured_comparison("MiniGrid-DoorKey-5x5-v0", "envpool", 123, ".",
        ...                     "a2c_minigrid")
        ''
    """
    found = committed_summary(task, backend, frames, results_dir, recipe, stochasticity)
    if found is None:
        return ""
    path, rows = found
    oracle = float(rows[0]["oracle_return"] or "nan")
    scale = "return / oracle" if oracle == oracle else "return"
    # the run's task, or minigrid's envs' of its id
    measured = task_name(rows[0]["task"], rows[0]["backend"])
    if path.is_relative_to(Path.cwd()):
        path = path.relative_to(Path.cwd())
    lines = [
        f"Measured on {measured} at {frames} frames ({path}; {scale}, IQM [95% CI]):"
    ]
    if run_return is not None:
        score = run_return / oracle if oracle == oracle else run_return
        lines.append(f"  {'this run':<34} {score:.2f}")

    def score(row) -> float:
        value = float(row["train_return_iqm"] or "nan")
        return value if value == value else float("-inf")  # no score: last

    scored = [r for r in rows if score(r) > float("-inf")]
    plain = [r for r in scored if split_level(r["setting"])[0] == "none"]
    others = [r for r in scored if r not in plain]
    shown = [(r, "plain learner") for r in plain]
    if others:
        shown.append((max(others, key=score), "best"))
    for row, role in shown:
        lines.append(
            f"  {row['setting'] + ' (' + role + ')':<34} "
            f"{float(row['train_return_iqm']):.2f} "
            f"[{float(row['train_return_ci_low']):.2f}, "
            f"{float(row['train_return_ci_high']):.2f}], {row['seeds']} seeds"
        )
    return "\n".join(lines)


def committed_summary(
    task: str,
    backend: str,
    frames: int,
    results_dir: str | os.PathLike,
    recipe: str,
    stochasticity: int = 0,
) -> tuple[Path, list[dict]] | None:
    """The committed ``summary.csv`` that measured ``task`` on ``backend`` at
    ``frames``, and its rows.

    Among the experiments under ``results_dir`` whose runs all came from
    ``runs/<recipe>/`` (their ``runs_meta.csv``: the run's own learner), the rows
    whose ``task`` and ``backend`` columns are the run's, at a budget within 1%
    of ``frames`` and at the noise level ``stochasticity``; a run on another
    backend than gymnasium (envpool) is also shown minigrid's envs' rows of the
    same env id. Of those, the experiment that measured the
    plain learner, then the run's own backend, then the most settings, the first
    by name among equals. ``None`` when nothing was measured.
    """
    import csv

    def rows_of(path: Path, on: str) -> list[dict]:
        meta = path.parent / "runs_meta.csv"
        if not meta.exists():
            return []
        with open(meta) as f:
            run_dirs = [Path(row["run_dir"]).parts for row in csv.DictReader(f)]
        if not run_dirs or any(p[:2] != ("runs", recipe) for p in run_dirs):
            return []
        with open(path) as f:
            return [
                row
                for row in csv.DictReader(f)
                if row.get("task") == task
                and row.get("backend") == on
                and row.get("budget")
                and abs(float(row["budget"]) - frames) <= 0.01 * frames
                and split_level(row["setting"])[1] == stochasticity
            ]

    def rank(item):
        own, path, rows = item
        plain = any(split_level(r["setting"])[0] == "none" for r in rows)
        return plain, own, len(rows)

    summaries = sorted(Path(results_dir).glob("*/summary.csv"))
    backends = dict.fromkeys([backend, GYMNASIUM])
    found = [
        (on == backend, path, rows_of(path, on))
        for on in backends
        for path in summaries
    ]
    found = [item for item in found if item[2]]
    if not found:
        return None
    _, path, rows = max(found, key=rank)  # the first of equals: max keeps it
    return path, rows
