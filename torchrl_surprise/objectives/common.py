"""What the bonus-model losses share: observation keys, reduction, input checks."""

from __future__ import annotations

import torch
from tensordict import TensorDictBase
from tensordict.utils import NestedKey, unravel_key
from torchrl.objectives.common import LossModule

__all__ = ["BonusModelLoss", "REDUCTIONS", "as_key_tuple"]

REDUCTIONS = ("mean", "sum", "none")


def as_key_tuple(key: NestedKey) -> tuple[str, ...]:
    """A nested key as a tuple: ``"obs"`` -> ``("obs",)``."""
    return (key,) if isinstance(key, str) else tuple(key)


class BonusModelLoss(LossModule):
    """The base of the bonus-model losses (:class:`VAELoss`, :class:`ICMLoss`).

    A ``LossModule`` whose ``observations`` key is a sequence of keys, with a
    ``reduction`` and input checks that name the missing key or the NaN.
    """

    def __init__(self, reduction: str):
        if reduction not in REDUCTIONS:
            raise ValueError(
                f"reduction must be one of {REDUCTIONS}, got {reduction!r}."
            )
        super().__init__()
        self.reduction = reduction

    def set_keys(self, **kwargs) -> None:
        """Sets tensordict keys; ``observations`` takes one key or a sequence."""
        if kwargs.get("observations") is not None:
            obs = kwargs["observations"]
            if isinstance(obs, str):
                obs = (obs,)
            kwargs["observations"] = tuple(unravel_key(k) for k in obs)
        super().set_keys(**kwargs)

    def _forward_value_estimator_keys(self, **kwargs) -> None:
        pass

    def _reduce(self, loss: torch.Tensor) -> torch.Tensor:
        if self.reduction == "mean":
            return loss.mean()
        if self.reduction == "sum":
            return loss.sum()
        return loss

    def _read(self, tensordict: TensorDictBase, keys) -> list[torch.Tensor]:
        values = []
        for key in keys:
            value = tensordict.get(key, None)
            if value is None:
                raise KeyError(
                    f"{type(self).__name__}: expected the key {key!r}; found "
                    f"{sorted(str(k) for k in tensordict.keys(True, True))}."
                )
            if value.dtype.is_floating_point and not torch.isfinite(value).all():
                raise ValueError(f"{type(self).__name__}: {key!r} contains NaN or inf.")
            values.append(value)
        return values
