"""The MiniGrid recipe's learners: A2C or PPO (``algo.name``), their losses,
optimisers and minibatches. The env, model, bonus and collector builders are in
:mod:`common.minigrid`."""

from __future__ import annotations

import torch
from tensordict import TensorDictBase
from tensordict.nn import InteractionType, TensorDictModuleBase
from tensordict.nn.probabilistic import interaction_type
from torch.distributions import Categorical
from torchrl.data import SamplerWithoutReplacement
from torchrl.envs.transforms import RewardClipping
from torchrl.objectives import A2CLoss, ClipPPOLoss

from common.checkpoint import DIVERGED_ADVICE
from common.errors import NonFiniteRun
from common.minigrid import make_advantage

__all__ = [
    "LOGGED_LOSSES",
    "SampledCategoricalPolicy",
    "make_loss",
    "Minibatches",
    "make_minibatches",
    "make_optimizer",
    "make_reward_clip",
    "minibatches",
    "resolve_device",
    "standardize_advantage",
]

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


def resolve_device(name: str) -> torch.device:
    """The device of the ``device`` setting: the policy, critics and bonus model's.

    ``cpu``; ``cuda`` (a CUDA device must be visible to torch, else a clear error);
    ``auto``: ``cuda`` when torch sees one, else ``cpu``. The envs stay on the CPU.

    Examples:
        >>> resolve_device("cpu")
        device(type='cpu')
        >>> resolve_device("auto") == torch.device(
        ...     "cuda" if torch.cuda.is_available() else "cpu")
        True
    """
    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    if name == "cuda" and not torch.cuda.is_available():
        build = (
            f"built with CUDA {torch.version.cuda}"
            if torch.version.cuda
            else "a CPU-only build"
        )
        raise RuntimeError(
            "device=cuda, but torch sees no CUDA device "
            f"(torch.cuda.is_available() is False; torch {torch.__version__} is "
            f"{build}): run with device=cpu, or device=auto to take a GPU only "
            "where there is one."
        )
    if name not in ("cpu", "cuda"):
        raise ValueError(f"device must be one of 'cpu', 'cuda', 'auto', got {name!r}.")
    return torch.device(name)


def make_reward_clip(cfg) -> RewardClipping | None:
    """TorchRL's ``RewardClipping`` of a batch's learner reward to
    ``[-loss.reward_clip, loss.reward_clip]`` (``None`` without it).

    It clips ``("next", "reward")``, what the (one) critic and GAE read: with one
    critic, the extrinsic reward plus the bonus, as E3B's code clips its total
    reward; the bonus transforms keep the task reward under
    ``"extrinsic_reward"``.

    Examples:
        >>> from omegaconf import OmegaConf
        >>> make_reward_clip(OmegaConf.create({"loss": {"reward_clip": None}})) is None
        True
        >>> clip = make_reward_clip(OmegaConf.create({"loss": {"reward_clip": 1.0}}))
        >>> from tensordict import TensorDict
        >>> td = TensorDict({"next": {"reward": torch.tensor([[2.5], [0.5]])}}, [2])
        >>> clip(td)["next", "reward"].flatten()
        tensor([1.0000, 0.5000])
    """
    bound = cfg.loss.get("reward_clip")
    if bound is None:
        return None
    return RewardClipping(-bound, bound, in_keys=[("next", "reward")])


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
        # The heads as they are, not functionalised: no parameter set is swapped
        # into them on every call (no target networks here); the same values.
        "functional": False,
    }
    if cfg.algo.name == "a2c":
        loss = A2CLoss(**heads)
    else:
        loss = ClipPPOLoss(
            **heads,
            clip_epsilon=cfg.loss.clip_epsilon,
            clip_value=True,
            normalize_advantage=bool(cfg.loss.normalize_advantage),
            log_explained_variance=False,  # not logged: not computed
        )
    advantage, value_loss = make_advantage(cfg, model, intrinsic_value, bonus_transform)
    return loss, advantage, value_loss


def make_optimizer(cfg, params) -> torch.optim.Optimizer:
    """RMSprop (A2C, rl-starter-files) or Adam (PPO), as ``optim.name`` says.

    ``foreach``: one multi-tensor kernel per operation over all the parameters
    instead of a Python loop over them (torch picks it on GPUs only); the same
    values, bit for bit, on the CPU.
    """
    if cfg.optim.name == "rmsprop":
        return torch.optim.RMSprop(
            params,
            lr=cfg.optim.lr,
            alpha=cfg.optim.alpha,
            eps=cfg.optim.eps,
            foreach=True,
        )
    return torch.optim.Adam(params, lr=cfg.optim.lr, eps=cfg.optim.eps, foreach=True)


class Minibatches:
    """PPO's epochs of shuffled minibatches over the collected batch.

    The order is drawn by TorchRL's ``SamplerWithoutReplacement``, called on the
    flat batch itself: the same permutations from the same random draws as a
    ``ReplayBuffer`` of that sampler (it draws the next epoch's order as an epoch
    ends, and its state, saved in the checkpoint, is the same), without copying
    the batch into a storage and indexing it back out of it on every minibatch.
    A minibatch holds what the update reads: the batch less its next states
    (the advantages and value targets are computed already) and the collector's
    bookkeeping, which every minibatch would otherwise index too.

    Examples:
        >>> import torch
        >>> from tensordict import TensorDict
        >>> data = TensorDict({"x": torch.arange(8).reshape(2, 4)}, batch_size=[2, 4])
        >>> batches = list(Minibatches(4)(data, epochs=2))
        >>> [b.batch_size for b in batches]
        [torch.Size([4]), torch.Size([4]), torch.Size([4]), torch.Size([4])]
        >>> sorted(torch.cat([b["x"] for b in batches[:2]]).tolist())
        [0, 1, 2, 3, 4, 5, 6, 7]
    """

    def __init__(self, size: int):
        self.size = size
        self.sampler = SamplerWithoutReplacement()

    #: What a minibatch leaves out.
    UNUSED = ("next", "collector")

    def __call__(self, data: TensorDictBase, epochs: int):
        flat = data.exclude(*self.UNUSED).reshape(-1)
        for _ in range(epochs):
            self.sampler.ran_out = False
            while not self.sampler.ran_out:
                index, _ = self.sampler.sample(flat, self.size)
                yield flat[index]


def make_minibatches(cfg) -> Minibatches | None:
    """PPO's minibatches (:class:`Minibatches`); ``None`` for A2C, which takes
    one step on the whole batch."""
    if cfg.algo.name == "a2c":
        return None
    return Minibatches(cfg.loss.minibatch_size)


def minibatches(data: TensorDictBase, batches: Minibatches | None, epochs: int):
    """The batches of one update: the whole batch (A2C), or ``epochs`` passes of
    shuffled minibatches (PPO)."""
    if batches is None:
        yield data
        return
    yield from batches(data, epochs)


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


def _on(tensor: torch.Tensor, device: torch.device) -> bool:
    # "cuda" names the current CUDA device; a tensor's device has its index
    return tensor.device.type == device.type and (
        device.index is None or tensor.device.index == device.index
    )


class SampledCategoricalPolicy(TensorDictModuleBase):
    """The actor-critic's policy in one call, for collection and evaluation.

    The policy operator of :func:`common.minigrid.make_actor_critic` (trunk, policy
    head, ``ProbabilisticActor`` over a ``Categorical``) runs as three TensorDict
    modules and a distribution module per env step: at 16 envs a step, their
    reading, checking and writing of entries cost about as much as the arithmetic.
    This module runs the same layers on the tensors and samples from the same
    ``Categorical`` (the same generator draws: ``torch.multinomial`` on the same
    probabilities), and writes the same entries (``"hidden"``, ``"logits"``,
    ``"action"`` and, with ``return_log_prob``, ``"action_log_prob"``): a run logs
    the same numbers. Under an exploration type other than ``RANDOM`` (a greedy
    evaluation), and for a policy whose actor is not that one, it hands the
    call to ``policy`` itself.

    Its ``state_dict`` is ``policy``'s (a collector's checkpoint holds the same keys).
    With ``device``, observations on another device (the envs' CPU, in evaluation
    and videos) are moved to it and the entries written come back to theirs; the
    collector hands it observations on ``device`` already.

    Args:
        policy: ``model.get_policy_operator()`` of ``make_actor_critic``.
        device: where ``policy``'s parameters are (``None``: wherever the
            observations are).

    Examples:
        >>> import torch
        >>> from tensordict import TensorDict
        >>> from torchrl.data import Categorical as CategoricalSpec
        >>> from torchrl.envs.utils import ExplorationType, set_exploration_type
        >>> from common.minigrid import make_actor_critic
        >>> model, _ = make_actor_critic(CategoricalSpec(7), intrinsic_critic=False)
        >>> policy = model.get_policy_operator()
        >>> fast = SampledCategoricalPolicy(policy)
        >>> obs = TensorDict(image=torch.randint(0, 9, (4, 7, 7, 3)), batch_size=[4])
        >>> with set_exploration_type(ExplorationType.RANDOM):
        ...     _ = torch.manual_seed(0)
        ...     a = fast(obs.clone())["action"]
        ...     _ = torch.manual_seed(0)
        ...     b = policy(obs.clone())["action"]
        >>> torch.equal(a, b)
        True
    """

    def __init__(self, policy, device: torch.device | str | None = None):
        super().__init__()
        trunk, head, sampler = policy.module
        self.policy = policy
        self.device = None if device is None else torch.device(device)
        self.in_keys = list(policy.in_keys)
        self.out_keys = list(policy.out_keys)
        # the plain layers and the keys between them
        self._trunk, self._head = trunk.module, head.module
        (self._image_key,), (self._hidden_key,) = trunk.in_keys, trunk.out_keys
        (self._logits_key,) = head.out_keys
        self._action_key = sampler.dist_sample_keys[0]
        self._log_prob_key = sampler.log_prob_key if sampler.return_log_prob else None
        self._fast = (
            head.in_keys == trunk.out_keys
            and list(sampler.in_keys) == [self._logits_key]
            and sampler.distribution_class is Categorical
            and not sampler.distribution_kwargs
            and sampler.num_samples is None
            and len(sampler.dist_sample_keys) == 1
        )

    def state_dict(self, *args, **kwargs):
        return self.policy.state_dict(*args, **kwargs)

    def load_state_dict(self, state_dict, *args, **kwargs):
        return self.policy.load_state_dict(state_dict, *args, **kwargs)

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        image = tensordict.get(self._image_key)
        if self.device is not None and not _on(image, self.device):
            out = self(tensordict.select(*self.in_keys).to(self.device))
            out = out.select(*self.out_keys).to(image.device)
            tensordict.update(out)
            return tensordict
        if not self._fast or interaction_type() is not InteractionType.RANDOM:
            return self.policy(tensordict)
        hidden = self._trunk(image)
        logits = self._head(hidden)
        # What ProbabilisticTensorDictModule does under RANDOM: Categorical(logits)
        # (its argument checks change no value), sample(), log_prob(action).
        dist = Categorical(logits=logits, validate_args=False)
        try:
            action = dist.sample()
        except RuntimeError as err:  # torch.multinomial's check of the probabilities
            if not torch.isfinite(logits).all():
                raise NonFiniteRun(
                    "the policy's logits are not finite: the run diverged and "
                    "stops; its last checkpoint, if it saved one, is finite. "
                    + DIVERGED_ADVICE
                ) from err
            raise
        tensordict.set(self._hidden_key, hidden)
        tensordict.set(self._logits_key, logits)
        tensordict.set(self._action_key, action)
        if self._log_prob_key is not None:
            tensordict.set(self._log_prob_key, dist.log_prob(action))
        return tensordict
