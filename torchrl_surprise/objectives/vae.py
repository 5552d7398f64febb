"""Negative ELBO of the state VAE, as a TorchRL loss module."""

from __future__ import annotations

from dataclasses import dataclass

from tensordict import TensorDict, TensorDictBase
from tensordict.utils import NestedKey

from torchrl_surprise.modules.vae import StateVAE, kl_to_standard_normal
from torchrl_surprise.objectives.common import BonusModelLoss, as_key_tuple

__all__ = ["VAELoss"]


class VAELoss(BonusModelLoss):
    """Negative ELBO of a :class:`~torchrl_surprise.modules.StateVAE`.

    ``loss_reconstruction = -E_q[log p(s|z)]`` (one reparameterised sample) and
    ``loss_kl = kl_weight * KL(q(z|s) || N(0, I))``; their sum is the negative
    ELBO (``kl_weight=1``) or a beta-VAE objective. Share the ``vae`` instance
    with :class:`~torchrl_surprise.VAESurpriseTransform` so that training the
    loss changes the bonus.

    Args:
        vae (StateVAE): the VAE to train.

    Keyword Args:
        kl_weight (float): weight of the KL term.
        reduction (str): ``"mean"``, ``"sum"`` or ``"none"`` (keeps the batch).

    Examples:
        >>> import torch
        >>> from tensordict import TensorDict
        >>> from torchrl_surprise import StateVAE, VAELoss
        >>> vae = StateVAE.for_vector(obs_dim=3, latent_dim=2, hidden_dim=16)
        >>> loss = VAELoss(vae)
        >>> batch = TensorDict({"next": {"observation": torch.randn(8, 3)}}, [8])
        >>> out = loss(batch)
        >>> sorted(out.keys())
        ['kl', 'loss_kl', 'loss_reconstruction', 'reconstruction_nll']
        >>> (out["loss_reconstruction"] + out["loss_kl"]).backward()
    """

    @dataclass
    class _AcceptedKeys:
        """Configurable tensordict keys.

        Attributes:
            observations (tuple of NestedKey): the states the VAE is trained on,
                in the order the VAE takes them. Defaults to ``("next", key)`` for
                each of ``vae.in_keys``: the states whose bonus the transform
                computes.
        """

        observations: tuple[NestedKey, ...] = (("next", "observation"),)

    default_keys = _AcceptedKeys
    tensor_keys: _AcceptedKeys
    out_keys = ["loss_reconstruction", "loss_kl", "kl", "reconstruction_nll"]

    def __init__(
        self,
        vae: StateVAE,
        *,
        kl_weight: float = 1.0,
        reduction: str = "mean",
    ):
        super().__init__(reduction)
        self.vae = vae
        self.kl_weight = kl_weight
        self.set_keys(
            observations=tuple(("next", *as_key_tuple(k)) for k in vae.in_keys)
        )

    @property
    def in_keys(self) -> list[NestedKey]:
        """The keys the loss reads."""
        return list(self.tensor_keys.observations)

    def forward(self, tensordict: TensorDictBase = None, **kwargs) -> TensorDictBase:
        """Computes the losses on a batch (a TensorDict, or the keys as keywords)."""
        if tensordict is None:
            tensordict = TensorDict(kwargs)
        observations = self._read(tensordict, self.tensor_keys.observations)
        loc, scale, _, log_likelihood = self.vae(*observations)
        kl = kl_to_standard_normal(loc, scale)
        nll = -log_likelihood
        loss_kl = self._reduce(self.kl_weight * kl)
        loss_rec = self._reduce(nll)
        return TensorDict(
            {
                "loss_reconstruction": loss_rec,
                "loss_kl": loss_kl,
                "kl": kl.detach().mean(),
                "reconstruction_nll": nll.detach().mean(),
            },
            batch_size=[],
        )
