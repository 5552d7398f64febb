"""Networks of the Intrinsic Curiosity Module (Pathak et al., 2017)."""

from __future__ import annotations

from collections.abc import Sequence

import torch
from tensordict.utils import NestedKey
from torch import nn

from torchrl_surprise.modules.inverse_dynamics import InverseDynamicsModel
from torchrl_surprise.modules.vae import linear_layer

__all__ = ["ICMModel"]


class ICMModel(InverseDynamicsModel):
    """Feature encoder ``phi``, inverse model and forward model of ICM.

    An :class:`~torchrl_surprise.modules.InverseDynamicsModel` (the encoder and
    the inverse model) with a forward model on its features:

    * ``phi(s)``: observation features (any encoder exposing ``out_features``).
    * inverse model: ``(phi(s), phi(s')) -> a`` (logits for discrete actions, a
      mean for continuous ones).
    * forward model: ``(phi(s), a) -> phi(s')``; its squared error is the bonus.

    Args:
        encoder (nn.Module): maps observations (in ``in_keys`` order) to features.
        action_dim (int): number of discrete actions, or the size of a continuous
            action.
        discrete (bool): discrete actions (integers or one-hot) or continuous.
        hidden_dim (int): width of the inverse and forward models.
        in_keys (sequence of NestedKey): observation keys the model reads.
        onednn_linear (bool): run the models' layers on
            :class:`~torchrl_surprise.modules.vae.OneDNNLinear`.

    Examples:
        >>> import torch
        >>> icm = ICMModel.for_minigrid(num_actions=7, hidden_dim=32)
        >>> image = torch.randint(0, 3, (4, 7, 7, 3), dtype=torch.uint8)
        >>> direction = torch.zeros(4, dtype=torch.long)
        >>> action = torch.randint(0, 7, (4,))
        >>> icm.forward_error((image, direction), action, (image, direction)).shape
        torch.Size([4])
    """

    def __init__(
        self,
        encoder: nn.Module,
        action_dim: int,
        discrete: bool = True,
        hidden_dim: int = 256,
        in_keys: Sequence[NestedKey] = ("observation",),
        onednn_linear: bool = False,
    ):
        super().__init__(
            encoder, action_dim, discrete, hidden_dim, in_keys, onednn_linear
        )
        feat = encoder.out_features
        self.forward_model = nn.Sequential(
            linear_layer(feat + action_dim, hidden_dim, onednn_linear),
            nn.ReLU(),
            linear_layer(hidden_dim, feat, onednn_linear),
        )

    @classmethod
    def for_minigrid(
        cls,
        num_actions: int = 7,
        hidden_dim: int = 256,
        use_direction: bool = True,
        onednn_linear: bool = False,
    ) -> ICMModel:
        """ICM on MiniGrid's symbolic grid (``"image"``, ``"direction"``).

        Args:
            num_actions (int): number of discrete actions.
            hidden_dim (int): width of the encoder and the models.
            use_direction (bool): also encode the direction.
            onednn_linear (bool): run the linear layers on ``OneDNNLinear``.
        """
        return super().for_minigrid(
            num_actions,
            embedding_dim=hidden_dim,
            hidden_dim=hidden_dim,
            use_direction=use_direction,
            onednn_linear=onednn_linear,
        )

    @classmethod
    def for_vector(
        cls,
        obs_dim: int,
        action_dim: int,
        hidden_dim: int = 256,
        onednn_linear: bool = False,
    ) -> ICMModel:
        """ICM on flat observations with continuous actions.

        Args:
            obs_dim (int): observation size.
            action_dim (int): action size.
            hidden_dim (int): width of the encoder and the models.
            onednn_linear (bool): run the linear layers on ``OneDNNLinear``.
        """
        return super().for_vector(
            obs_dim,
            action_dim,
            embedding_dim=hidden_dim,
            hidden_dim=hidden_dim,
            discrete=False,
            onednn_linear=onednn_linear,
        )

    def forward_error(
        self,
        observations: Sequence[torch.Tensor],
        action: torch.Tensor,
        next_observations: Sequence[torch.Tensor],
    ) -> torch.Tensor:
        """``0.5 * ||f(phi(s), a) - phi(s')||^2`` per transition, shape ``[...]``."""
        phi, phi_next = self.paired_features(observations, next_observations)
        pred = self.forward_model(torch.cat([phi, self.encode_action(action)], -1))
        return 0.5 * (pred - phi_next).pow(2).sum(-1)
