"""Random network distillation's networks (Burda et al. 2019), as NovelD uses them."""

from __future__ import annotations

from collections.abc import Sequence

import torch
from tensordict.utils import NestedKey, unravel_key
from torch import nn

from torchrl_surprise.modules.vae import MiniGridEncoder, VectorEncoder

__all__ = ["RNDModel"]


class _EncoderHead(nn.Module):
    """An encoder of observation tensors followed by a linear head."""

    def __init__(self, encoder: nn.Module, out_features: int):
        super().__init__()
        self.encoder = encoder
        self.head = nn.Linear(encoder.out_features, out_features)
        self.out_features = out_features

    def forward(self, *observations: torch.Tensor) -> torch.Tensor:
        return self.head(self.encoder(*observations))


class RNDModel(nn.Module):
    """A fixed random target network and a predictor trained to match it.

    ``novelty(s) = ||predictor(s) - target(s)||_2``: high on states the
    predictor has rarely been trained on (NovelD's novelty, the L2 norm of RND's
    error). The target's parameters never train (``requires_grad=False``);
    :class:`~torchrl_surprise.objectives.RNDDistillationLoss` trains the
    predictor. Both networks read the observation tensors in ``in_keys`` order,
    so MiniGrid's ``image`` and ``direction`` go in together.

    Args:
        target (nn.Module): the random network, ``(*observations) -> [..., d]``.
        predictor (nn.Module): the trained network, same signature and size.
        in_keys (sequence of NestedKey): observation keys the networks read.

    Examples:
        >>> import torch
        >>> rnd = RNDModel.for_minigrid(embedding_dim=8, hidden_dim=16)
        >>> image = torch.randint(0, 3, (4, 7, 7, 3), dtype=torch.uint8)
        >>> rnd.novelty(image, torch.zeros(4, dtype=torch.long)).shape
        torch.Size([4])
        >>> any(p.requires_grad for p in rnd.target.parameters())
        False
    """

    def __init__(
        self,
        target: nn.Module,
        predictor: nn.Module,
        in_keys: Sequence[NestedKey] = ("observation",),
    ):
        super().__init__()
        if isinstance(in_keys, str):
            in_keys = [in_keys]
        self.in_keys = [unravel_key(key) for key in in_keys]
        self.target = target.requires_grad_(False)
        self.predictor = predictor

    @classmethod
    def _with_encoders(cls, make_encoder, embedding_dim: int, in_keys) -> RNDModel:
        target = _EncoderHead(make_encoder(), embedding_dim)
        # Same architecture, its own random initialisation.
        predictor = _EncoderHead(make_encoder(), embedding_dim)
        return cls(target, predictor, in_keys=in_keys)

    @classmethod
    def for_minigrid(
        cls, embedding_dim: int = 128, hidden_dim: int = 256, use_direction: bool = True
    ) -> RNDModel:
        """RND on MiniGrid's symbolic grid (``"image"``, ``"direction"``).

        Each network is :class:`~torchrl_surprise.modules.MiniGridEncoder` and a
        linear head to ``embedding_dim`` (NovelD's MiniGrid embedding is 128).

        Args:
            embedding_dim (int): size of the networks' output.
            hidden_dim (int): width of the encoders.
            use_direction (bool): also read the direction.
        """
        return cls._with_encoders(
            lambda: MiniGridEncoder(hidden_dim=hidden_dim, use_direction=use_direction),
            embedding_dim,
            ["image", "direction"] if use_direction else ["image"],
        )

    @classmethod
    def for_vector(
        cls, obs_dim: int, embedding_dim: int = 128, hidden_dim: int = 256
    ) -> RNDModel:
        """RND on flat float observations.

        Args:
            obs_dim (int): observation size.
            embedding_dim (int): size of the networks' output.
            hidden_dim (int): width of the encoders.
        """
        return cls._with_encoders(
            lambda: VectorEncoder(obs_dim, hidden_dim=hidden_dim),
            embedding_dim,
            ["observation"],
        )

    def errors(self, *observations: torch.Tensor) -> torch.Tensor:
        """``predictor(s) - target(s)``, ``[..., d]`` (the target detached)."""
        with torch.no_grad():
            target = self.target(*observations)
        return self.predictor(*observations) - target

    def novelty(self, *observations: torch.Tensor) -> torch.Tensor:
        """``||predictor(s) - target(s)||_2`` per state, ``[...]``."""
        return self.errors(*observations).norm(dim=-1)
