"""Negative ELBO of the state VAE, as a TorchRL loss module."""

from __future__ import annotations

from dataclasses import dataclass

from tensordict import TensorDict, TensorDictBase
from tensordict.utils import NestedKey

from torchrl_surprise.modules.inverse_dynamics import InverseDynamicsModel
from torchrl_surprise.modules.vae import StateVAE, kl_to_standard_normal
from torchrl_surprise.objectives.common import BonusModelLoss, as_key_tuple
from torchrl_surprise.objectives.inverse_dynamics import InverseDynamicsLoss

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
        inverse_dynamics (InverseDynamicsModel, optional): an inverse model on
            this VAE's posterior mean (:meth:`InverseDynamicsModel.on_vae`). Its
            :class:`InverseDynamicsLoss`, times ``inverse_weight``, is added as
            ``loss_inverse``: the latent then keeps what the agent's actions
            control, where the ELBO alone keeps everything it can reconstruct
            (noise the agent cannot affect included). The loss then also reads
            ``s_t`` and the action.
        inverse_weight (float): weight of ``loss_inverse``.
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

        With an inverse-dynamics term on the latent:

        >>> from torchrl_surprise.modules import InverseDynamicsModel
        >>> inverse = InverseDynamicsModel.on_vae(vae, action_dim=4)
        >>> loss = VAELoss(vae, inverse_dynamics=inverse, inverse_weight=0.5)
        >>> batch["observation"] = torch.randn(8, 3)
        >>> batch["action"] = torch.randint(0, 4, (8,))
        >>> sorted(loss(batch).keys())
        ['inverse_error', 'kl', 'loss_inverse', 'loss_kl', 'loss_reconstruction', 'reconstruction_nll']
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
        inverse_dynamics: InverseDynamicsModel | None = None,
        inverse_weight: float = 1.0,
        reduction: str = "mean",
    ):
        super().__init__(reduction)
        self.vae = vae
        self.kl_weight = kl_weight
        self.set_keys(
            observations=tuple(("next", *as_key_tuple(k)) for k in vae.in_keys)
        )
        self.inverse_loss = None
        self.inverse_weight = float(inverse_weight)
        if inverse_dynamics is not None:
            if not self.inverse_weight > 0:
                raise ValueError(
                    f"VAELoss: inverse_weight must be > 0 with inverse_dynamics, got "
                    f"{inverse_weight}."
                )
            encoder = getattr(inverse_dynamics, "encoder", None)
            if getattr(encoder, "vae", None) is not vae:
                raise ValueError(
                    "VAELoss: inverse_dynamics must read this VAE's posterior "
                    "mean (InverseDynamicsModel.on_vae(vae, ...)); got a model "
                    f"with encoder {type(encoder).__name__}."
                )
            self.inverse_loss = InverseDynamicsLoss(
                inverse_dynamics, reduction=reduction
            )

    @property
    def in_keys(self) -> list[NestedKey]:
        """The keys the loss reads."""
        keys = list(self.tensor_keys.observations)
        if self.inverse_loss is not None:
            keys += [k for k in self.inverse_loss.in_keys if k not in keys]
        return keys

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
        out = TensorDict(
            {
                "loss_reconstruction": loss_rec,
                "loss_kl": loss_kl,
                "kl": kl.detach().mean(),
                "reconstruction_nll": nll.detach().mean(),
            },
            batch_size=[],
        )
        if self.inverse_loss is not None:
            inverse = self.inverse_loss(tensordict)
            out["loss_inverse"] = self.inverse_weight * inverse["loss_inverse"]
            out["inverse_error"] = inverse["inverse_error"]
        return out
