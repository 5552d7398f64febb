"""The VAE surprise bonus: ``KL(q(z|s') || N(0, I))`` of each next state."""

from __future__ import annotations

from collections.abc import Sequence

import torch
from tensordict import TensorDictBase
from tensordict.utils import NestedKey

from torchrl_surprise.modules.vae import StateVAE
from torchrl_surprise.transforms.base import IntrinsicRewardTransform

__all__ = ["VAESurpriseTransform"]


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
