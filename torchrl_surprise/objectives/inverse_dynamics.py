"""The inverse-dynamics loss: what trains ICM's and E3B's embeddings.

ICM (Pathak et al., 2017) weighs it against a forward loss
(:class:`~torchrl_surprise.objectives.ICMLoss`); E3B (Henaff et al., 2022) trains
its embedding with it alone.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
import torch.nn.functional as F
from tensordict import TensorDict, TensorDictBase
from tensordict.utils import NestedKey

from torchrl_surprise.modules.inverse_dynamics import InverseDynamicsModel
from torchrl_surprise.objectives.common import BonusModelLoss, as_key_tuple

__all__ = ["InverseDynamicsLoss"]


class InverseDynamicsLoss(BonusModelLoss):
    """Predict the action ``a_t`` from ``(phi(s_t), phi(s_{t+1}))``.

    ``loss_inverse`` is the cross-entropy of the inverse model's logits against
    the action taken (discrete actions) or half its squared error (continuous
    ones). It trains the embedding and the inverse model of an
    :class:`~torchrl_surprise.modules.InverseDynamicsModel`: E3B's
    :class:`~torchrl_surprise.modules.E3BModel`, whose embedding
    :class:`~torchrl_surprise.transforms.E3BTransform` computes the bonus on.
    E3B trains it with a learning rate of ``1e-4``.
    :class:`~torchrl_surprise.objectives.ICMLoss` adds ICM's forward loss to it.

    Args:
        model (InverseDynamicsModel): the embedding and inverse model.

    Keyword Args:
        reduction (str): ``"mean"``, ``"sum"`` or ``"none"`` (keeps the batch).

    Examples:
        >>> import torch
        >>> from tensordict import TensorDict
        >>> from torchrl_surprise.modules import E3BModel
        >>> model = E3BModel.for_vector(obs_dim=3, action_dim=2, embedding_dim=8)
        >>> batch = TensorDict(
        ...     {"observation": torch.randn(8, 3), "action": torch.randn(8, 2),
        ...      "next": {"observation": torch.randn(8, 3)}}, [8])
        >>> out = InverseDynamicsLoss(model)(batch)
        >>> sorted(out.keys())
        ['inverse_error', 'loss_inverse']
        >>> out["loss_inverse"].backward()
    """

    @dataclass
    class _AcceptedKeys:
        """Configurable tensordict keys.

        Attributes:
            observations (tuple of NestedKey): the observation keys of ``s_t``;
                those of ``s_{t+1}`` are the same under ``"next"``.
            action (NestedKey): the action taken in ``s_t``.
        """

        observations: tuple[NestedKey, ...] = ("observation",)
        action: NestedKey = "action"

    default_keys = _AcceptedKeys
    tensor_keys: _AcceptedKeys
    out_keys = ["loss_inverse", "inverse_error"]

    def __init__(self, model: InverseDynamicsModel, *, reduction: str = "mean"):
        super().__init__(reduction)
        self.model = model
        self.set_keys(observations=tuple(model.in_keys))

    @property
    def in_keys(self) -> list[NestedKey]:
        """The keys the loss reads."""
        obs = list(self.tensor_keys.observations)
        nxt = [("next", *as_key_tuple(k)) for k in obs]
        return obs + nxt + [self.tensor_keys.action]

    def _inverse_terms(
        self, tensordict: TensorDictBase
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
        """``(phi(s), phi(s'), encoded action, inverse error per transition)``."""
        keys = self.tensor_keys.observations
        obs = self._read(tensordict, keys)
        next_obs = self._read(tensordict, [("next", *as_key_tuple(k)) for k in keys])
        (action,) = self._read(tensordict, [self.tensor_keys.action])
        phi, phi_next = self.model.paired_features(obs, next_obs)
        out = self.model.inverse_model(torch.cat([phi, phi_next], -1))
        encoded = self.model.encode_action(action)
        if self.model.discrete:
            # The class of each one-hot row: what model.action_target returns,
            # without validating and encoding the action a second time.
            target = encoded.argmax(-1)
            error = F.cross_entropy(
                out.reshape(-1, out.shape[-1]), target.reshape(-1), reduction="none"
            ).reshape(target.shape)
        else:
            error = 0.5 * (out - encoded).pow(2).sum(-1)
        return phi, phi_next, encoded, error

    def forward(self, tensordict: TensorDictBase = None, **kwargs) -> TensorDictBase:
        """Computes the loss on a batch (a TensorDict, or the keys as keywords)."""
        if tensordict is None:
            tensordict = TensorDict(kwargs)
        *_, error = self._inverse_terms(tensordict)
        return TensorDict(
            {
                "loss_inverse": self._reduce(error),
                "inverse_error": error.detach().mean(),
            },
            batch_size=[],
        )
