"""Builders for the DDPG MuJoCo recipe: envs, actor and critic, loss, buffer, bonus."""

from __future__ import annotations

import torch
from tensordict import TensorDictBase
from tensordict.nn import TensorDictModule, TensorDictSequential
from torchrl.data import Composite, LazyTensorStorage, TensorDictReplayBuffer, Unbounded
from torchrl.envs import Compose, InitTracker, RewardSum, StepCounter
from torchrl.envs.transforms import Transform
from torchrl.envs.transforms.rnd import RunningMeanStd
from torchrl.modules import (
    MLP,
    AdditiveGaussianModule,
    OrnsteinUhlenbeckProcessModule,
    TanhModule,
    ValueOperator,
)
from torchrl.objectives import DDPGLoss, SoftUpdate

from torchrl_surprise import StateVAE, VAELoss, VAESurpriseTransform
from torchrl_surprise.collectors import ResumableCollector
from torchrl_surprise.envs import make_mujoco_env
from torchrl_surprise.modules.vae import OneDNNLinear
from torchrl_surprise.transforms import make_coef_schedule

OBS_KEY = "observation"
OBS_NORM_KEY = "observation_norm"

#: What a transition keeps in the replay buffer (the bonus keys are added when
#: the bonus is stored at collection time). The normalised observation is not
#: stored: it is recomputed on every sample with the current statistics.
REPLAY_KEYS = (
    OBS_KEY,
    "action",
    ("next", OBS_KEY),
    ("next", "reward"),
    ("next", "done"),
    ("next", "terminated"),
)


def make_env(env_cfg, num_envs: int, seed: int):
    """A gymnasium MuJoCo env in TorchRL with extrinsic episode statistics, from
    the config's ``env`` section (``name``)."""
    env = make_mujoco_env(env_cfg.name, num_envs=num_envs)
    # RewardSum sees the env's reward: the bonus is mixed in later, on batches, so
    # the logged episode return is the task's. InitTracker resets the OU noise.
    env.append_transform(Compose(InitTracker(), RewardSum(), StepCounter()))
    env.set_seed(seed)
    return env


class ObservationNormalizer(Transform):
    """Writes ``clip((obs - mean) / std)`` under its own key, at the root and in "next".

    The running statistics (TorchRL's ``RunningMeanStd``, in ``state_dict``) change
    only through :meth:`update`, which the training loop calls on each collected
    batch. Reading never changes them, so an env step and a replay-buffer sample
    with the same statistics give the same normalised observation.

    Args:
        obs_dim (int): size of the flat observation.
        in_key (NestedKey): the raw observation.
        out_key (NestedKey): where the normalised copy is written.
        clip (float, optional): clip the normalised values to ``[-clip, clip]``.

    Examples:
        >>> from tensordict import TensorDict
        >>> norm = ObservationNormalizer(3)
        >>> norm.update(torch.randn(100, 3) * 4 + 2)
        >>> td = TensorDict({"observation": torch.zeros(5, 3),
        ...                  "next": {"observation": torch.ones(5, 3)}}, [5])
        >>> td = norm(td)
        >>> td["next", "observation_norm"].shape
        torch.Size([5, 3])
    """

    def __init__(
        self,
        obs_dim: int,
        in_key=OBS_KEY,
        out_key=OBS_NORM_KEY,
        clip: float | None = 5.0,
    ):
        super().__init__(in_keys=[in_key], out_keys=[out_key])
        self.rms = RunningMeanStd(shape=(obs_dim,))
        self.clip = clip

    @torch.no_grad()
    def update(self, observations: torch.Tensor) -> None:
        if not torch.isfinite(observations).all():
            raise ValueError(
                "ObservationNormalizer: the collected observations contain NaN or inf."
            )
        self.rms.update(observations)

    def _apply_transform(self, obs: torch.Tensor) -> torch.Tensor:
        out = self.rms.normalize(obs)
        if self.clip is not None:
            out = out.clamp(-self.clip, self.clip)
        return out

    def _reset(self, tensordict, tensordict_reset):
        return self._call(tensordict_reset)

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        self._call(tensordict)
        next_tensordict = tensordict.get("next", None)
        if next_tensordict is not None:
            self._call(next_tensordict)
        return tensordict

    def transform_observation_spec(self, observation_spec: Composite) -> Composite:
        for in_key, out_key in zip(self.in_keys, self.out_keys):
            ref = observation_spec[in_key]
            observation_spec[out_key] = Unbounded(
                shape=ref.shape, device=ref.device, dtype=torch.float32
            )
        return observation_spec


def make_ddpg(cfg, env):
    """Actor (MLP + tanh to the action bounds), critic Q(s, a), loss, target updater.

    The MLPs' linear layers are :class:`~torchrl_surprise.modules.vae.OneDNNLinear`
    (TorchRL's ``MLP(layer_class=...)``; ``nn.Linear``'s parameters, initialisation
    and state_dict): their 256x256 products run on oneDNN, faster than MKL on one
    CPU thread (docs/speed.rst).

    Returns ``(actor, exploration_policy, noise_module, loss, target_updater)``.
    """
    action_spec = env.action_spec_unbatched
    obs_dim = env.observation_spec[OBS_KEY].shape[-1]
    act_dim = action_spec.shape[-1]
    hidden = list(cfg.network.hidden_sizes)
    actor = TensorDictSequential(
        TensorDictModule(
            MLP(
                in_features=obs_dim,
                out_features=act_dim,
                num_cells=hidden,
                activation_class=torch.nn.ReLU,
                layer_class=OneDNNLinear,
            ),
            in_keys=[OBS_KEY],
            out_keys=["param"],
        ),
        TanhModule(in_keys=["param"], out_keys=["action"], spec=action_spec),
    )
    critic = ValueOperator(
        MLP(
            in_features=obs_dim + act_dim,
            out_features=1,
            num_cells=hidden,
            activation_class=torch.nn.ReLU,
            layer_class=OneDNNLinear,
        ),
        in_keys=[OBS_KEY, "action"],
    )
    ecfg = cfg.exploration
    if ecfg.noise == "gaussian":
        # Constant sigma: a + N(0, std^2) projected onto the bounds; std is
        # gaussian_std times each dimension's half range (OurDDPG: 0.1 * max_action).
        noise = AdditiveGaussianModule(
            spec=action_spec,
            sigma_init=1.0,
            sigma_end=1.0,
            mean=0.0,
            std=1.0,
            safe=False,  # it projects onto the spec itself
        )
        half_range = (action_spec.space.high - action_spec.space.low) / 2
        noise.std = float(ecfg.gaussian_std) * half_range.float()
    else:
        noise = OrnsteinUhlenbeckProcessModule(
            spec=action_spec,
            eps_init=1.0,
            eps_end=1.0,
            theta=float(ecfg.ou_theta),
            sigma=float(ecfg.ou_sigma),
            dt=float(ecfg.ou_dt),
        )
    policy = TensorDictSequential(actor, noise)
    loss = DDPGLoss(
        actor,
        critic,
        loss_function="l2",
        delay_actor=cfg.loss.delay_actor,
        delay_value=True,
    )
    loss.make_value_estimator(gamma=cfg.optim.gamma)
    target_updater = SoftUpdate(loss, tau=cfg.optim.tau)
    return actor, policy, noise, loss, target_updater


def make_bonus(cfg, obs_dim: int):
    """The VAE bonus on normalised observations: ``(transform, vae_loss)`` or Nones."""
    if cfg.bonus == "none":
        return None, None
    icfg = cfg.intrinsic
    schedule = make_coef_schedule(
        icfg.coef, icfg.coef_end, icfg.anneal_frames, icfg.warmup_frames
    )
    vae = StateVAE.for_vector(
        obs_dim,
        latent_dim=icfg.vae.latent_dim,
        hidden_dim=icfg.vae.hidden_dim,
        in_keys=[OBS_NORM_KEY],
    )
    transform = VAESurpriseTransform(
        vae,
        # Replay samples are not new frames: the loop drives the counter.
        count_frames=False,
        coef=icfg.coef,
        coef_schedule=schedule,
        normalization=icfg.normalization,
        gamma=cfg.optim.gamma,
        clip=icfg.clip,
    )
    loss = VAELoss(vae, kl_weight=icfg.vae.kl_weight)
    return transform, loss


def replay_keys(bonus_transform, bonus_at: str) -> list:
    """The keys a transition keeps in the buffer (plus the bonus when stored)."""
    keys = list(REPLAY_KEYS)
    if bonus_transform is not None and bonus_at == "collection":
        keys += [("next", key) for key in _bonus_keys(bonus_transform)]
    return keys


def _bonus_keys(transform) -> list:
    keys = [transform.intrinsic_reward_key, transform.extrinsic_reward_key]
    if transform.normalized_reward_key is not None:
        keys.append(transform.normalized_reward_key)
    return keys


def make_replay_buffer(size: int) -> TensorDictReplayBuffer:
    """Uniform replay over a preallocated tensor storage (sampled with replacement).

    TorchRL's ``state_dict()`` of the buffer holds the storage (all ``size`` slots,
    filled or not), the write cursor and the sampler: a checkpoint saves it whole.
    """
    return TensorDictReplayBuffer(storage=LazyTensorStorage(int(size)))


class ScalarMeans:
    """Per-update scalars gathered between two log lines, logged as their means.

    It is part of a checkpoint: a run stopped between two log lines and resumed
    logs the same means as the uninterrupted run.

    Examples:
        >>> means = ScalarMeans()
        >>> means.add("train/loss", torch.tensor(1.0))
        >>> means.add("train/loss", torch.tensor(2.0))
        >>> restored = ScalarMeans()
        >>> restored.load_state_dict(means.state_dict())
        >>> restored.pop_means()
        {'train/loss': 1.5}
        >>> restored.pop_means()
        {}
    """

    def __init__(self):
        self.values: dict[str, list[torch.Tensor]] = {}

    def add(self, name: str, value: torch.Tensor) -> None:
        self.values.setdefault(name, []).append(value.detach().mean())

    def pop_means(self) -> dict[str, float]:
        """The mean of each scalar since the last call; then starts afresh."""
        means = {k: torch.stack(v).mean().item() for k, v in self.values.items()}
        self.values.clear()
        return means

    def state_dict(self) -> dict[str, torch.Tensor]:
        return {k: torch.stack(v) for k, v in self.values.items()}

    def load_state_dict(self, state) -> None:
        self.values = {k: list(v.unbind(0)) for k, v in state.items()}


def make_collector(env, policy, cfg):
    """The collector of the whole run, random actions for ``init_random_frames``.

    A :class:`~torchrl_surprise.collectors.ResumableCollector`: its state holds the
    episodes in progress (MuJoCo simulator states included) and its frame count, so
    a resumed run continues them, and the random phase, where they were.
    """
    return ResumableCollector(
        env,
        policy,
        frames_per_batch=cfg.collector.frames_per_batch,
        total_frames=cfg.collector.total_frames,
        init_random_frames=cfg.collector.init_random_frames,
        auto_register_policy_transforms=False,
    )
