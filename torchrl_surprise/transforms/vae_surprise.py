"""The VAE surprise bonus: ``KL(q(z|s') || N(0, I))`` of each next state."""

from __future__ import annotations

import copy
from collections.abc import Sequence

import torch
from tensordict import TensorDictBase
from tensordict.utils import NestedKey, unravel_key

from torchrl_surprise.modules.vae import StateVAE, kl_to_standard_normal
from torchrl_surprise.transforms.base import IntrinsicRewardTransform
from torchrl_surprise.transforms.episodic import (
    EllipticalEpisodicMemory,
    checked_flag,
    embed_where,
)
from torchrl_surprise.transforms.noveld import NovelDTransform

__all__ = [
    "GLOBAL_BONUSES",
    "NOVELD_NOVELTIES",
    "VAEEllipticalTransform",
    "VAENegativeELBOTransform",
    "VAENovelDTransform",
    "VAEPosteriorShiftTransform",
    "VAESurpriseTransform",
]


class VAESurpriseTransform(IntrinsicRewardTransform):
    """Bayesian-surprise bonus: the KL between a state VAE's posterior and prior.

    ``r_int(s_{t+1}) = KL(q(z|s_{t+1}) || N(0, I))``, in closed form for the
    VAE's diagonal Gaussian posterior, computed with the current VAE and no
    gradients. The VAE is trained by :class:`~torchrl_surprise.VAELoss`, which
    holds the same instance. Keys, normalisation, the coefficient and mixing are
    those of :class:`~torchrl_surprise.transforms.IntrinsicRewardTransform`.

    Use it inside an env (``TransformedEnv(env, transform)``) to add the bonus at
    every step, or call it on a collected batch or a replay-buffer sample to
    (re)compute the bonus with the current VAE in one batched forward.

    Args:
        vae (StateVAE): the state VAE.
        in_keys (sequence of NestedKey, optional): observation keys, in the order
            the VAE takes them. Defaults to ``vae.in_keys``.
        **kwargs: see :class:`~torchrl_surprise.transforms.IntrinsicRewardTransform`.

    Examples:
        >>> import torch
        >>> from torchrl.envs import TransformedEnv
        >>> from torchrl.testing.mocking_classes import ContinuousActionVecMockEnv
        >>> from torchrl_surprise import StateVAE, VAESurpriseTransform
        >>> torch.manual_seed(0)  # doctest: +ELLIPSIS
        <torch._C.Generator object at ...>
        >>> base = ContinuousActionVecMockEnv()
        >>> obs_dim = base.observation_spec["observation"].shape[-1]
        >>> vae = StateVAE.for_vector(obs_dim, latent_dim=4, hidden_dim=32)
        >>> env = TransformedEnv(base, VAESurpriseTransform(vae, coef=0.1))
        >>> rollout = env.rollout(5)
        >>> rollout["next", "intrinsic_reward"].shape
        torch.Size([5, 1])
        >>> mixed = rollout["next", "extrinsic_reward"] + 0.1 * rollout["next", "intrinsic_reward"]
        >>> torch.allclose(rollout["next", "reward"], mixed)
        True
    """

    def __init__(
        self,
        vae: StateVAE,
        in_keys: Sequence[NestedKey] | None = None,
        **kwargs,
    ):
        if in_keys is None:
            in_keys = vae.in_keys
        super().__init__(in_keys, **kwargs)
        self.vae = vae

    def _compute_bonus(
        self, tensordict: TensorDictBase, next_tensordict: TensorDictBase
    ) -> torch.Tensor:
        observations = self._observations(next_tensordict, "the 'next' tensordict")
        return self.vae.kl(*observations)


class VAENegativeELBOTransform(VAESurpriseTransform):
    """Novelty as the VAE's negative ELBO: ``-log p(s|z=mu) + KL(q(z|s) || p(z))``.

    How badly the VAE explains a state: high for states it has rarely been
    trained on, falling as it learns them, like RND's prediction error. The
    paper's KL is the second term alone, which *rises* on trained states (it
    marks informative states, not new ones). The reconstruction term uses the
    posterior mean, so the bonus is deterministic.

    Examples:
        >>> import torch
        >>> from tensordict import TensorDict
        >>> from torchrl_surprise import StateVAE
        >>> vae = StateVAE.for_vector(3, latent_dim=2, hidden_dim=8)
        >>> t = VAENegativeELBOTransform(vae, in_keys=["observation"], coef=0.1)
        >>> td = TensorDict({"next": {"observation": torch.randn(4, 3),
        ...                           "reward": torch.zeros(4, 1)}}, [4])
        >>> t(td)["next", "intrinsic_reward"].shape
        torch.Size([4, 1])
    """

    def _compute_bonus(
        self, tensordict: TensorDictBase, next_tensordict: TensorDictBase
    ) -> torch.Tensor:
        observations = self._observations(next_tensordict, "the 'next' tensordict")
        return self.vae.novelty(*observations)


class VAEPosteriorShiftTransform(VAESurpriseTransform):
    """Surprise as the shift of a state's posterior: ``KL(q(z|s) || q_ref(z|s))``.

    ``q_ref`` is a frozen reference copy of the VAE, set by :meth:`snapshot`:

    * snapshot right before the VAE trains on a rollout and compute the bonus
      after that update: the bonus is the information gain of the update on
      each state, Bayesian surprise as Itti and Baldi define it (the paper's
      KL to the prior approximates it);
    * snapshot every few updates and compute the bonus as usual: the KL under a
      lagged copy of the VAE.

    Args:
        vae (StateVAE): the state VAE (trained by ``VAELoss``).
        **kwargs: see :class:`VAESurpriseTransform`.

    Examples:
        >>> import torch
        >>> from tensordict import TensorDict
        >>> from torchrl_surprise import StateVAE
        >>> vae = StateVAE.for_vector(3, latent_dim=2, hidden_dim=8)
        >>> t = VAEPosteriorShiftTransform(vae, in_keys=["observation"])
        >>> td = TensorDict({"next": {"observation": torch.randn(4, 3),
        ...                           "reward": torch.zeros(4, 1)}}, [4])
        >>> float(t(td)["next", "intrinsic_reward"].abs().max())  # same weights
        0.0
        >>> with torch.no_grad():
        ...     _ = vae.head.bias.add_(0.5)
        >>> bool((t(td)["next", "intrinsic_reward"] > 0).all())
        True
    """

    def __init__(self, vae: StateVAE, in_keys=None, **kwargs):
        super().__init__(vae, in_keys=in_keys, **kwargs)
        self.reference = copy.deepcopy(vae).requires_grad_(False)

    def snapshot(self) -> None:
        """Makes the reference the VAE as it is now."""
        self.reference.load_state_dict(self.vae.state_dict())

    def _compute_bonus(
        self, tensordict: TensorDictBase, next_tensordict: TensorDictBase
    ) -> torch.Tensor:
        observations = self._observations(next_tensordict, "the 'next' tensordict")
        loc, scale = self.vae.posterior(*observations)
        ref_loc, ref_scale = self.reference.posterior(*observations)
        var, ref_var = scale.pow(2), ref_scale.pow(2)
        kl = 0.5 * (
            (var + (loc - ref_loc).pow(2)) / ref_var - 1.0 + ref_var.log() - var.log()
        )
        return kl.sum(-1)


#: Accepted values of :class:`VAEEllipticalTransform`'s ``global_bonus``.
GLOBAL_BONUSES = ("none", "kl")
#: Accepted values of :class:`VAENovelDTransform`'s ``novelty``: the VAE's
#: negative ELBO, its KL.
NOVELD_NOVELTIES = ("neg_elbo", "kl")


class VAEEllipticalTransform(VAESurpriseTransform):
    """Episodic novelty in the VAE's latent space: E3B's elliptical bonus.

    With ``phi(s)`` the posterior mean of a state and ``C = ridge * I + sum
    phi phi^T`` over the states seen so far in the episode,

    ``r_int(s_{t+1}) = phi(s_{t+1})^T C^{-1} phi(s_{t+1})``

    (then ``s_{t+1}`` joins ``C``): high for a state unlike every state of the
    episode so far, whatever the VAE thinks of it globally (Henaff et al. 2022,
    "Exploration via Elliptical Episodic Bonuses", with the VAE's encoder in
    place of their inverse-dynamics embedding). ``global_bonus="kl"`` multiplies
    it by the paper's KL, the product of a global and an episodic term as in
    NovelD and E3B's follow-ups. ``unit_latent=True`` takes ``phi`` as the
    posterior mean divided by its norm: the bonus then measures how far a state's
    direction in the latent is from the episode's so far, whatever the latent's
    scale (at most ``1 / ridge``, reached by an episode's first state). A trained
    VAE's posterior means are several times longer than an untrained encoder's,
    and their bonus heavy-tailed (``docs/results.rst``, "The elliptical bonus's
    scale"); unit length makes the two compare on what they encode alone.

    The bonus depends on the order of states within each episode, so the
    transform keeps one inverse matrix per env in ``memory``, an
    :class:`~torchrl_surprise.transforms.EllipticalEpisodicMemory` (the one
    :class:`~torchrl_surprise.transforms.E3BTransform` uses; saved by
    ``state_dict``, so a resumed run continues its episodes). In an env
    (``_step``) it advances one step of every env and restarts an env's memory
    when it is done or reset; on a batch (``forward``) it walks the dimension
    named ``"time"`` (or ``time_dim``) and restarts after each ``done``. A batch
    that is not time-ordered (a replay-buffer sample) is refused. Call
    :meth:`reset_episodes` before recomputing the bonus of a batch already seen.

    Args:
        vae (StateVAE): the state VAE (trained by ``VAELoss``).
        ridge (float): ``lambda`` of ``C``'s ``lambda * I`` (E3B: 0.1).
        global_bonus (str): ``"none"`` (the elliptical term alone) or ``"kl"``.
        unit_latent (bool): ``phi`` is the posterior mean at unit length (the
            global KL, with ``global_bonus="kl"``, reads the posterior as it is).
        start_in_memory (bool): an episode's first state joins ``C`` before
            the first bonus, as in E3B's code
            (:class:`~torchrl_surprise.transforms.E3BTransform`); ``False``
            (the default, every committed result): ``C`` starts from
            ``ridge * I``.
        done_key (NestedKey): the ``"next"`` entry that ends an episode.
        **kwargs: see :class:`VAESurpriseTransform`.

    Examples:
        >>> import torch
        >>> from tensordict import TensorDict
        >>> from torchrl_surprise import StateVAE
        >>> vae = StateVAE.for_vector(3, latent_dim=2, hidden_dim=8)
        >>> t = VAEEllipticalTransform(vae, in_keys=["observation"])
        >>> same = torch.ones(1, 4, 3)  # one env, one state seen four times
        >>> td = TensorDict({"next": {"observation": same,
        ...                           "reward": torch.zeros(1, 4, 1),
        ...                           "done": torch.zeros(1, 4, 1, dtype=torch.bool)}},
        ...                 [1, 4], names=[None, "time"])
        >>> bonus = t(td)["next", "intrinsic_reward"][0, :, 0]
        >>> bool((bonus[1:] < bonus[:-1]).all())  # less novel each time
        True
    """

    def __init__(
        self,
        vae: StateVAE,
        in_keys=None,
        *,
        ridge: float = 0.1,
        global_bonus: str = "none",
        unit_latent: bool = False,
        start_in_memory: bool = False,
        done_key: NestedKey = "done",
        **kwargs,
    ):
        if global_bonus not in GLOBAL_BONUSES:
            raise ValueError(
                f"global_bonus must be one of {GLOBAL_BONUSES}, got {global_bonus!r}."
            )
        checked_flag("unit_latent", unit_latent)
        checked_flag("start_in_memory", start_in_memory)
        memory = EllipticalEpisodicMemory(vae.latent_dim, ridge)
        super().__init__(vae, in_keys=in_keys, **kwargs)
        self.memory = memory
        self.ridge = memory.ridge
        self.global_bonus = global_bonus
        self.unit_latent = unit_latent
        self.start_in_memory = start_in_memory
        self.done_key = unravel_key(done_key)

    def reset_episodes(self) -> None:
        """Forgets every episode in progress (their next states start afresh)."""
        self.memory.reset()

    def _reset(self, tensordict, tensordict_reset):
        self.memory.reset_from(tensordict)
        return tensordict_reset

    def _posterior(self, next_tensordict: TensorDictBase):
        observations = self._observations(next_tensordict, "the 'next' tensordict")
        return self.vae.posterior(*observations)

    def _features(self, loc: torch.Tensor) -> torch.Tensor:
        """``phi``: the posterior mean, at unit length with ``unit_latent``."""
        return torch.nn.functional.normalize(loc, dim=-1) if self.unit_latent else loc

    def _with_global(self, bonus, loc, scale) -> torch.Tensor:
        bonus = bonus.to(loc.dtype)
        if self.global_bonus == "kl":
            bonus = bonus * kl_to_standard_normal(loc, scale)
        return bonus

    def _starts(self, tensordict: TensorDictBase, mask: torch.Tensor):
        """``phi`` of the states that begin an episode (``mask``), or ``None``
        when they do not join the memory."""
        if not self.start_in_memory:
            return None
        observations = self._observations(tensordict, "the root tensordict")

        def embed(*obs):
            return self._features(self.vae.posterior(*obs)[0])

        return embed_where(embed, observations, mask, self.vae.latent_dim)

    def _compute_bonus(
        self, tensordict: TensorDictBase, next_tensordict: TensorDictBase
    ) -> torch.Tensor:
        # The env path: one step of every env.
        done = self._episode_ends(next_tensordict, self.done_key)
        loc, scale = self._posterior(next_tensordict)
        start = self._starts(tensordict, self.memory.pending(loc.shape[:-1]))
        bonus = self.memory.step(self._features(loc), done, start)
        return self._with_global(bonus, loc, scale)

    def _compute_batch_bonus(
        self,
        tensordict: TensorDictBase,
        next_tensordict: TensorDictBase,
        time_dim: int | None,
    ) -> torch.Tensor:
        time_dim = self._require_time_dim(time_dim)
        done = self._episode_ends(next_tensordict, self.done_key)
        loc, scale = self._posterior(next_tensordict)
        if done is None:
            done = torch.zeros(loc.shape[:-1], dtype=torch.bool, device=loc.device)
        start = self._starts(tensordict, self.memory.pending_starts(done, time_dim))
        bonus = self.memory.walk(self._features(loc), done, time_dim, start)
        return self._with_global(bonus, loc, scale)

    def _load_from_state_dict(self, state_dict, prefix, *args, **kwargs):
        # Checkpoints written before the memory was a submodule keep it here.
        old = state_dict.pop(prefix + "_inv_cov", None)
        if old is not None:
            state_dict[prefix + "memory.inv_cov"] = old
        super()._load_from_state_dict(state_dict, prefix, *args, **kwargs)


class VAENovelDTransform(NovelDTransform):
    """NovelD on the VAE: the gain in its negative ELBO (or KL), paid on first visits.

    ``r_int(s, s') = max(novelty(s') - alpha * novelty(s), 0) * 1[s' is visited
    for the first time in this episode]``

    with ``novelty`` the VAE's negative ELBO (:meth:`StateVAE.novelty
    <torchrl_surprise.modules.StateVAE.novelty>`, the bonus of
    :class:`VAENegativeELBOTransform`) in place of NovelD's RND error. The
    VAE, trained by :class:`~torchrl_surprise.VAELoss` on the states the agent
    visits, explains its familiar states better than new ones, so the
    difference pays crossing into the part of the world it has not learned
    yet. A VAE that never trains gives every state about the same novelty: the
    bonus is then close to ``(1 - alpha)`` times a constant on first visits, an
    episodic count, which is the control for what the VAE's training buys.

    With ``novelty="kl"`` the novelty is the paper's surprise, ``KL(q(z|s) ||
    N(0, I))`` (:meth:`StateVAE.kl <torchrl_surprise.modules.StateVAE.kl>`), in
    place of the negative ELBO: the gain is then in how much the VAE encodes,
    not in how badly it reconstructs, which a view it cannot reconstruct (a
    noisy TV's cells) keeps high however often it is seen.

    Everything else is :class:`~torchrl_surprise.transforms.NovelDTransform`'s:
    ``alpha``, the first-visit indicator on ``visit_keys``, the per-env sets in
    ``visits`` (saved by ``state_dict``), the env path and the time-ordered
    batch path, :meth:`reset_episodes`. The VAE is held as ``vae``.

    Args:
        vae (StateVAE): the state VAE (trained by ``VAELoss``).
        in_keys (sequence of NestedKey, optional): observation keys, in the order
            the VAE takes them. Defaults to ``vae.in_keys``.

    Keyword Args:
        novelty (str): ``"neg_elbo"`` (default: the VAE's negative ELBO) or
            ``"kl"`` (its posterior's KL to the prior).
        **kwargs: see :class:`~torchrl_surprise.transforms.NovelDTransform`.

    Examples:
        >>> import torch
        >>> from tensordict import TensorDict
        >>> from torchrl_surprise import StateVAE
        >>> torch.manual_seed(0)  # doctest: +ELLIPSIS
        <torch._C.Generator object at ...>
        >>> vae = StateVAE.for_vector(3, latent_dim=2, hidden_dim=8)
        >>> t = VAENovelDTransform(vae, in_keys=["observation"], coef=0.1)
        >>> obs = torch.randn(1, 3, 3)  # one env: s0, s1, s0 again
        >>> obs[0, 2] = obs[0, 0]
        >>> td = TensorDict({"observation": obs[:, :-1],
        ...                  "next": {"observation": obs[:, 1:],
        ...                           "reward": torch.zeros(1, 2, 1),
        ...                           "done": torch.zeros(1, 2, 1, dtype=torch.bool)}},
        ...                 [1, 2], names=[None, "time"])
        >>> bonus = t(td)["next", "intrinsic_reward"][0, :, 0]
        >>> bool(bonus[0] > 0), float(bonus[1])  # s1 is new; s0 was seen
        (True, 0.0)
        >>> kl = VAENovelDTransform(vae, in_keys=["observation"], novelty="kl")
        >>> torch.allclose(kl.novelty(obs), vae.kl(obs))
        True
    """

    model_attr = "vae"

    def __init__(
        self,
        vae: StateVAE,
        in_keys: Sequence[NestedKey] | None = None,
        *,
        novelty: str = "neg_elbo",
        **kwargs,
    ):
        if novelty not in NOVELD_NOVELTIES:
            raise ValueError(
                f"{type(self).__name__}: novelty must be one of "
                f"{NOVELD_NOVELTIES}, got {novelty!r}."
            )
        super().__init__(vae, in_keys, **kwargs)
        self.novelty_kind = novelty

    def novelty(self, *observations: torch.Tensor) -> torch.Tensor:
        """``novelty(s)`` per state, ``[...]``: the VAE's negative ELBO, or its
        KL with ``novelty="kl"``."""
        if self.novelty_kind == "kl":
            return self.vae.kl(*observations)
        return self.vae.novelty(*observations)
