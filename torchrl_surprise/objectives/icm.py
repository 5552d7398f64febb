"""ICM's forward and inverse losses (Pathak et al., 2017)."""

from __future__ import annotations

from dataclasses import dataclass

import torch
import torch.nn.functional as F
from tensordict import TensorDict, TensorDictBase
from tensordict.utils import NestedKey

from torchrl_surprise.modules.icm import ICMModel
from torchrl_surprise.objectives.common import BonusModelLoss, as_key_tuple

__all__ = ["ICMLoss"]


class ICMLoss(BonusModelLoss):
    """Forward and inverse losses of the Intrinsic Curiosity Module.

    ``loss_inverse = (1 - beta) * CE(g(phi(s), phi(s')), a)`` (MSE for continuous
    actions) trains the encoder and the inverse model;
    ``loss_forward = beta * 0.5 * ||f(phi(s), a) - phi(s')||^2`` trains the forward
    model only: features are detached in it, as otherwise the encoder can shrink
    its features to make the forward error (the bonus) vanish. ``beta = 0.2`` is
    the ICM paper's weighting.

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

    @dataclass
    class _AcceptedKeys:
        """Configurable tensordict keys.

        Attributes:
            observations (tuple of NestedKey): the observation keys of ``s``; the
                keys of ``s'`` are the same under ``"next"``.
            action (NestedKey): the action taken in ``s``.
        """

        observations: tuple[NestedKey, ...] = ("observation",)
        action: NestedKey = "action"

    default_keys = _AcceptedKeys
    tensor_keys: _AcceptedKeys
    out_keys = ["loss_forward", "loss_inverse", "forward_error", "inverse_error"]

    def __init__(self, icm: ICMModel, *, beta: float = 0.2, reduction: str = "mean"):
        if not 0.0 <= beta <= 1.0:
            raise ValueError(f"beta must be in [0, 1], got {beta}.")
        super().__init__(reduction)
        self.icm = icm
        self.beta = beta
        self.set_keys(observations=tuple(icm.in_keys))

    @property
    def in_keys(self) -> list[NestedKey]:
        """The keys the loss reads."""
        obs = list(self.tensor_keys.observations)
        nxt = [("next", *as_key_tuple(k)) for k in obs]
        return obs + nxt + [self.tensor_keys.action]

    def forward(self, tensordict: TensorDictBase = None, **kwargs) -> TensorDictBase:
        """Computes the losses on a batch (a TensorDict, or the keys as keywords)."""
        if tensordict is None:
            tensordict = TensorDict(kwargs)
        keys = self.tensor_keys.observations
        obs = self._read(tensordict, keys)
        next_obs = self._read(tensordict, [("next", *as_key_tuple(k)) for k in keys])
        (action,) = self._read(tensordict, [self.tensor_keys.action])
        phi, phi_next = self.icm.paired_features(obs, next_obs)
        inverse_out = self.icm.inverse_model(torch.cat([phi, phi_next], -1))
        encoded_action = self.icm.encode_action(action)
        if self.icm.discrete:
            # The class of each one-hot row: what icm.action_target returns,
            # without validating and encoding the action a second time.
            target = encoded_action.argmax(-1)
            inverse = F.cross_entropy(
                inverse_out.reshape(-1, inverse_out.shape[-1]),
                target.reshape(-1),
                reduction="none",
            ).reshape(target.shape)
        else:
            inverse = 0.5 * (inverse_out - encoded_action).pow(2).sum(-1)
        pred = self.icm.forward_model(torch.cat([phi.detach(), encoded_action], -1))
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
