"""E3B's embedding: an encoder trained by inverse dynamics (Henaff et al. 2022)."""

from __future__ import annotations

from torchrl_surprise.modules.inverse_dynamics import InverseDynamicsModel

__all__ = ["E3BModel"]


class E3BModel(InverseDynamicsModel):
    """The embedding ``phi`` of E3B's elliptical bonus and its inverse model.

    ``phi(s)`` is the encoder's output; the inverse model predicts ``a_t`` from
    ``(phi(s_t), phi(s_{t+1}))`` and its loss
    (:class:`~torchrl_surprise.objectives.InverseDynamicsLoss`) is what trains
    ``phi``, so the embedding keeps what the agent controls.
    :class:`~torchrl_surprise.transforms.E3BTransform` computes the bonus on it
    (:meth:`~torchrl_surprise.modules.InverseDynamicsModel.embed`).

    The builders use the library's encoders (ICM's design: MiniGrid ids embedded
    per cell, an MLP for vectors), not E3B's convolutional network; the sizes
    are E3B's (see :meth:`for_minigrid`;
    :meth:`~torchrl_surprise.modules.InverseDynamicsModel.for_vector` for
    vectors).

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
        return super().for_minigrid(
            num_actions,
            embedding_dim=embedding_dim,
            hidden_dim=hidden_dim,
            use_direction=use_direction,
            onednn_linear=onednn_linear,
        )
