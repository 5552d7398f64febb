"""E3B's embedding: an encoder trained by inverse dynamics (Henaff et al. 2022)."""

from __future__ import annotations

import torch

from torchrl_surprise.modules.icm import InverseDynamicsModel
from torchrl_surprise.modules.vae import MiniGridEncoder, VectorEncoder

__all__ = ["E3BModel"]


class E3BModel(InverseDynamicsModel):
    """The embedding ``phi`` of E3B's elliptical bonus and its inverse model.

    ``phi(s)`` is the encoder's output; the inverse model predicts ``a_t`` from
    ``(phi(s_t), phi(s_{t+1}))`` and its loss
    (:class:`~torchrl_surprise.objectives.InverseDynamicsLoss`) is what trains
    ``phi``, so the embedding keeps what the agent controls.
    :class:`~torchrl_surprise.transforms.E3BTransform` computes the bonus on it.

    The builders use the library's encoders (ICM's design: MiniGrid ids embedded
    per cell, an MLP for vectors), not E3B's convolutional network; the sizes
    are E3B's (see :meth:`for_minigrid`).

    Args:
        encoder (nn.Module): maps observations (in ``in_keys`` order) to the
            embedding; must expose ``out_features``.
        action_dim (int): number of discrete actions, or the size of a continuous
            action.
        discrete (bool): discrete actions (integers or one-hot) or continuous.
        hidden_dim (int): width of the inverse model.
        in_keys (sequence of NestedKey): observation keys the model reads.
        onednn_linear (bool): run the layers on ``OneDNNLinear``.

    Examples:
        >>> import torch
        >>> model = E3BModel.for_minigrid(num_actions=7, embedding_dim=16)
        >>> image = torch.randint(0, 3, (4, 7, 7, 3), dtype=torch.uint8)
        >>> model.embed(image, torch.zeros(4, dtype=torch.long)).shape
        torch.Size([4, 16])
    """

    @property
    def embedding_dim(self) -> int:
        """The size of ``phi``."""
        return self.encoder.out_features

    def embed(self, *observations: torch.Tensor) -> torch.Tensor:
        """``phi(s)``, ``[..., embedding_dim]``, for the observation tensors of ``s``."""
        return self.encoder(*observations)

    @classmethod
    def for_minigrid(
        cls,
        num_actions: int = 7,
        embedding_dim: int = 1024,
        hidden_dim: int = 256,
        use_direction: bool = True,
        onednn_linear: bool = False,
    ) -> E3BModel:
        """E3B on MiniGrid's symbolic grid (``"image"``, ``"direction"``).

        From E3B (paper and released code, ``--hidden_dim 1024``): a 1024-wide
        embedding. E3B's other settings belong to the transform and the
        optimiser: ``ridge=0.1`` (:class:`~torchrl_surprise.transforms.E3BTransform`'s
        default) and a learning rate of ``1e-4`` for this model. The encoder is
        :class:`~torchrl_surprise.modules.MiniGridEncoder` (as ICM's), the
        inverse model's width ``hidden_dim`` is ICM's default.

        Args:
            num_actions (int): number of discrete actions.
            embedding_dim (int): size of ``phi``.
            hidden_dim (int): width of the inverse model.
            use_direction (bool): also encode the direction.
            onednn_linear (bool): run the linear layers on ``OneDNNLinear``.
        """
        return cls(
            MiniGridEncoder(
                hidden_dim=embedding_dim,
                use_direction=use_direction,
                onednn_linear=onednn_linear,
            ),
            num_actions,
            discrete=True,
            hidden_dim=hidden_dim,
            in_keys=["image", "direction"] if use_direction else ["image"],
            onednn_linear=onednn_linear,
        )

    @classmethod
    def for_vector(
        cls,
        obs_dim: int,
        action_dim: int,
        embedding_dim: int = 256,
        hidden_dim: int = 256,
        discrete: bool = False,
        onednn_linear: bool = False,
    ) -> E3BModel:
        """E3B on flat float observations (continuous actions by default).

        Args:
            obs_dim (int): observation size.
            action_dim (int): action size, or number of discrete actions.
            embedding_dim (int): size of ``phi``.
            hidden_dim (int): width of the inverse model.
            discrete (bool): discrete actions.
            onednn_linear (bool): run the linear layers on ``OneDNNLinear``.
        """
        return cls(
            VectorEncoder(
                obs_dim, hidden_dim=embedding_dim, onednn_linear=onednn_linear
            ),
            action_dim,
            discrete=discrete,
            hidden_dim=hidden_dim,
            onednn_linear=onednn_linear,
        )
