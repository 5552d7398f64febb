"""Negative ELBO of the state VAE, as a TorchRL loss module."""

from __future__ import annotations

from dataclasses import dataclass

import torch
from tensordict import TensorDict, TensorDictBase
from tensordict.utils import NestedKey, unravel_key
from torchrl.objectives.common import LossModule

from torchrl_surprise.modules.vae import StateVAE, kl_to_standard_normal

__all__ = ["VAELoss"]


def _read(loss: LossModule, tensordict: TensorDictBase, keys) -> list[torch.Tensor]:
    values = []
    for key in keys:
        value = tensordict.get(key, None)
        if value is None:
            raise KeyError(
                f"{type(loss).__name__}: expected the key {key!r}; found "
                f"{sorted(str(k) for k in tensordict.keys(True, True))}."
            )
        if value.dtype.is_floating_point and not torch.isfinite(value).all():
            raise ValueError(f"{type(loss).__name__}: {key!r} contains NaN or inf.")
        values.append(value)
    return values


class VAELoss(LossModule):
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
        if reduction not in ("mean", "sum", "none"):
            raise ValueError(f"reduction must be mean, sum or none, got {reduction!r}.")
        super().__init__()
        self.vae = vae
        self.kl_weight = kl_weight
        self.reduction = reduction
        self.set_keys(observations=tuple(("next", *_as_tuple(k)) for k in vae.in_keys))

    def set_keys(self, **kwargs) -> None:
        """Sets tensordict keys; ``observations`` takes one key or a sequence."""
        if "observations" in kwargs and kwargs["observations"] is not None:
            obs = kwargs["observations"]
            if isinstance(obs, str):
                obs = (obs,)
            kwargs["observations"] = tuple(unravel_key(k) for k in obs)
        super().set_keys(**kwargs)

    def _forward_value_estimator_keys(self, **kwargs) -> None:
        pass

    @property
    def in_keys(self) -> list[NestedKey]:
        """The keys the loss reads."""
        return list(self.tensor_keys.observations)

    def forward(self, tensordict: TensorDictBase = None, **kwargs) -> TensorDictBase:
        """Computes the losses on a batch (a TensorDict, or the keys as keywords)."""
        if tensordict is None:
            tensordict = TensorDict(kwargs)
        observations = _read(self, tensordict, self.tensor_keys.observations)
        loc, scale, _, log_likelihood = self.vae(*observations)
        kl = kl_to_standard_normal(loc, scale)
        nll = -log_likelihood
        loss_kl = self._reduce_loss(self.kl_weight * kl, tensordict)
        loss_rec = self._reduce_loss(nll, tensordict)
        return TensorDict(
            {
                "loss_reconstruction": loss_rec,
                "loss_kl": loss_kl,
                "kl": kl.detach().mean(),
                "reconstruction_nll": nll.detach().mean(),
            },
            batch_size=[],
        )

    def _reduce_loss(self, loss: torch.Tensor, tensordict: TensorDictBase):
        if self.reduction == "mean":
            return loss.mean()
        if self.reduction == "sum":
            return loss.sum()
        return loss


def _as_tuple(key: NestedKey) -> tuple[str, ...]:
    return (key,) if isinstance(key, str) else tuple(key)
