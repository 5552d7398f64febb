"""RND's distillation loss on the library's observation keys (Burda et al. 2019)."""

from __future__ import annotations

from dataclasses import dataclass

from tensordict import TensorDict, TensorDictBase
from tensordict.utils import NestedKey

from torchrl_surprise.modules.rnd import RNDModel
from torchrl_surprise.objectives.common import BonusModelLoss, as_key_tuple

__all__ = ["RNDDistillationLoss"]


class RNDDistillationLoss(BonusModelLoss):
    """The predictor's squared error against the fixed random target.

    ``loss_predictor = mean over the embedding of (predictor(s) - target(s))^2``
    on the next states of a batch, as TorchRL's
    :class:`~torchrl.objectives.RNDLoss`, but on an
    :class:`~torchrl_surprise.modules.RNDModel` that reads several observation
    keys (MiniGrid's ``image`` and ``direction``), where TorchRL's reads one.
    Only the predictor trains. It is the loss of
    :class:`~torchrl_surprise.transforms.NovelDTransform`'s novelty.

    Args:
        rnd (RNDModel): the target and predictor networks.

    Keyword Args:
        reduction (str): ``"mean"``, ``"sum"`` or ``"none"`` (keeps the batch).

    Examples:
        >>> import torch
        >>> from tensordict import TensorDict
        >>> from torchrl_surprise.modules import RNDModel
        >>> rnd = RNDModel.for_vector(obs_dim=3, embedding_dim=8, hidden_dim=16)
        >>> batch = TensorDict({"next": {"observation": torch.randn(8, 3)}}, [8])
        >>> out = RNDDistillationLoss(rnd)(batch)
        >>> sorted(out.keys())
        ['loss_predictor', 'novelty']
        >>> out["loss_predictor"].backward()
    """

    @dataclass
    class _AcceptedKeys:
        """Configurable tensordict keys.

        Attributes:
            observations (tuple of NestedKey): the states the predictor is
                trained on, in the order the networks take them. Defaults to
                ``("next", key)`` for each of ``rnd.in_keys``.
        """

        observations: tuple[NestedKey, ...] = (("next", "observation"),)

    default_keys = _AcceptedKeys
    tensor_keys: _AcceptedKeys
    out_keys = ["loss_predictor", "novelty"]

    def __init__(self, rnd: RNDModel, *, reduction: str = "mean"):
        super().__init__(reduction)
        self.rnd = rnd
        self.set_keys(
            observations=tuple(("next", *as_key_tuple(k)) for k in rnd.in_keys)
        )

    @property
    def in_keys(self) -> list[NestedKey]:
        """The keys the loss reads."""
        return list(self.tensor_keys.observations)

    def forward(self, tensordict: TensorDictBase = None, **kwargs) -> TensorDictBase:
        """Computes the loss on a batch (a TensorDict, or the keys as keywords)."""
        if tensordict is None:
            tensordict = TensorDict(kwargs)
        observations = self._read(tensordict, self.tensor_keys.observations)
        errors = self.rnd.errors(*observations)
        return TensorDict(
            {
                "loss_predictor": self._reduce(errors.pow(2).mean(-1)),
                "novelty": errors.detach().norm(dim=-1).mean(),
            },
            batch_size=[],
        )
