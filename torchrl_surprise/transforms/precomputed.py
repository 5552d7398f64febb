"""Normalise and mix a bonus that another component already wrote."""

from __future__ import annotations

import torch
from tensordict import TensorDictBase
from tensordict.utils import NestedKey

from torchrl_surprise.transforms.base import IntrinsicRewardTransform

__all__ = ["PrecomputedBonusTransform"]


class PrecomputedBonusTransform(IntrinsicRewardTransform):
    """Gives a bonus computed elsewhere the base's normalisation, coef and mixing.

    The bonus is read from ``("next", bonus_key)``, for instance what TorchRL's
    :class:`~torchrl.envs.transforms.RNDTransform` writes in an env (it has no
    batch path and does not mix rewards itself).

    Args:
        bonus_key (NestedKey): where the raw bonus already is, in ``"next"``.
        **kwargs: see :class:`~torchrl_surprise.transforms.IntrinsicRewardTransform`.

    Examples:
        >>> import torch
        >>> from tensordict import TensorDict
        >>> batch = TensorDict({"next": {"reward": torch.zeros(3, 1),
        ...                              "rnd_reward": torch.ones(3, 1)}}, [3])
        >>> out = PrecomputedBonusTransform("rnd_reward", coef=0.5)(batch)
        >>> out["next", "reward"].squeeze(-1)
        tensor([0.5000, 0.5000, 0.5000])
    """

    def __init__(self, bonus_key: NestedKey, **kwargs):
        super().__init__([bonus_key], **kwargs)

    def _compute_bonus(
        self, tensordict: TensorDictBase, next_tensordict: TensorDictBase
    ) -> torch.Tensor:
        (bonus,) = self._observations(next_tensordict, "the 'next' tensordict")
        batch_size = next_tensordict.batch_size
        bonus = self._per_transition(self.in_keys[0], bonus, batch_size)
        return bonus.reshape(batch_size).float()
