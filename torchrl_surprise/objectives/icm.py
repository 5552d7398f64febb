"""ICM's forward and inverse losses (Pathak et al., 2017)."""

from __future__ import annotations

import torch
from tensordict import TensorDict, TensorDictBase
from torch import nn

from torchrl_surprise.modules.icm import ICMModel
from torchrl_surprise.objectives.inverse_dynamics import InverseDynamicsLoss

__all__ = ["ICMLoss"]


class ICMLoss(InverseDynamicsLoss):
    """Forward and inverse losses of the Intrinsic Curiosity Module.

    ``loss_inverse = (1 - beta) * CE(g(phi(s), phi(s')), a)`` (MSE for continuous
    actions; :class:`~torchrl_surprise.objectives.InverseDynamicsLoss`'s loss)
    trains the encoder and the inverse model;
    ``loss_forward = beta * 0.5 * ||f(phi(s), a) - phi(s')||^2`` trains the forward
    model only: features are detached in it, as otherwise the encoder can shrink
    its features to make the forward error (the bonus) vanish. ``beta = 0.2`` is
    the ICM paper's weighting.

    The networks are the loss's ``model`` (also ``icm``), so its ``state_dict``
    keys start with ``model.``; one saved with the former ``icm.`` keys still
    loads.

    Args:
        icm (ICMModel): the ICM networks, shared with
            :class:`~torchrl_surprise.ICMTransform`.

    Keyword Args:
        beta (float): weight of the forward loss against the inverse loss.
        reduction (str): ``"mean"``, ``"sum"`` or ``"none"``.

    Examples:
        >>> import torch
        >>> from tensordict import TensorDict
        >>> from torchrl_surprise import ICMLoss
        >>> from torchrl_surprise.modules import ICMModel
        >>> icm = ICMModel.for_vector(obs_dim=3, action_dim=2, hidden_dim=16)
        >>> batch = TensorDict(
        ...     {"observation": torch.randn(8, 3), "action": torch.randn(8, 2),
        ...      "next": {"observation": torch.randn(8, 3)}}, [8])
        >>> out = ICMLoss(icm)(batch)
        >>> (out["loss_forward"] + out["loss_inverse"]).backward()
    """

    out_keys = ["loss_forward", "loss_inverse", "forward_error", "inverse_error"]

    def __init__(self, icm: ICMModel, *, beta: float = 0.2, reduction: str = "mean"):
        if not 0.0 <= beta <= 1.0:
            raise ValueError(f"beta must be in [0, 1], got {beta}.")
        if not isinstance(getattr(icm, "forward_model", None), nn.Module):
            raise TypeError(
                f"ICMLoss: expected an ICMModel (inverse dynamics and a "
                f"forward_model), got {type(icm).__name__}; InverseDynamicsLoss "
                "trains a model without a forward model."
            )
        super().__init__(icm, reduction=reduction)
        self.beta = beta

    @property
    def icm(self) -> ICMModel:
        """The ICM networks (the same module as :attr:`model`)."""
        return self.model

    def _load_from_state_dict(self, state_dict, prefix, *args, **kwargs):
        # Until 0.2 the networks were registered as ``icm``: rename their keys.
        old = prefix + "icm."
        for key in [k for k in state_dict if k.startswith(old)]:
            state_dict[prefix + "model." + key[len(old) :]] = state_dict.pop(key)
        super()._load_from_state_dict(state_dict, prefix, *args, **kwargs)

    def forward(self, tensordict: TensorDictBase = None, **kwargs) -> TensorDictBase:
        """Computes the losses on a batch (a TensorDict, or the keys as keywords)."""
        if tensordict is None:
            tensordict = TensorDict(kwargs)
        phi, phi_next, encoded_action, inverse = self._inverse_terms(tensordict)
        pred = self.model.forward_model(torch.cat([phi.detach(), encoded_action], -1))
        forward = 0.5 * (pred - phi_next.detach()).pow(2).sum(-1)
        return TensorDict(
            {
                "loss_forward": self._reduce(self.beta * forward),
                "loss_inverse": self._reduce((1 - self.beta) * inverse),
                "forward_error": forward.detach().mean(),
                "inverse_error": inverse.detach().mean(),
            },
            batch_size=[],
        )
