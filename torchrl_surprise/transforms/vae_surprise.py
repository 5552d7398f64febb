"""The VAE surprise bonus: ``KL(q(z|s') || N(0, I))`` of each next state."""

from __future__ import annotations

import copy
from collections.abc import Sequence

import torch
from tensordict import TensorDictBase
from tensordict.utils import NestedKey

from torchrl_surprise.modules.vae import StateVAE, kl_to_standard_normal
from torchrl_surprise.transforms.base import IntrinsicRewardTransform

__all__ = [
    "VAENegativeELBOTransform",
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
        loc, scale = self.vae.posterior(*observations)
        nll = -self.vae.decoder.log_prob(loc, *observations)
        return nll + kl_to_standard_normal(loc, scale)


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
