"""Networks of the Intrinsic Curiosity Module (Pathak et al., 2017)."""

from __future__ import annotations

from collections.abc import Sequence

import torch
from tensordict.utils import NestedKey, unravel_key
from torch import nn

from torchrl_surprise.modules.vae import (
    MiniGridEncoder,
    VectorEncoder,
    linear_layer,
)

__all__ = ["ICMModel", "InverseDynamicsModel"]


class InverseDynamicsModel(nn.Module):
    """An embedding ``phi`` and an inverse model ``(phi(s), phi(s')) -> a``.

    Trained by :class:`~torchrl_surprise.objectives.InverseDynamicsLoss`, the
    embedding keeps what the agent's actions control and drops the rest (noise
    the agent cannot affect). :class:`ICMModel` adds a forward model on it;
    :class:`~torchrl_surprise.modules.E3BModel` uses it as E3B's embedding.

    Args:
        encoder (nn.Module): maps observations (in ``in_keys`` order) to features;
            must expose ``out_features``.
        action_dim (int): number of discrete actions, or the size of a continuous
            action.
        discrete (bool): discrete actions (integers or one-hot) or continuous.
        hidden_dim (int): width of the inverse model.
        in_keys (sequence of NestedKey): observation keys the model reads.
        onednn_linear (bool): run the model's layers on
            :class:`~torchrl_surprise.modules.vae.OneDNNLinear`.
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
        super().__init__()
        if isinstance(in_keys, str):
            in_keys = [in_keys]
        self.in_keys = [unravel_key(key) for key in in_keys]
        self.encoder = encoder
        self.action_dim = action_dim
        self.discrete = discrete
        feat = encoder.out_features
        self.inverse_model = nn.Sequential(
            linear_layer(2 * feat, hidden_dim, onednn_linear),
            nn.ReLU(),
            linear_layer(hidden_dim, action_dim, onednn_linear),
        )

    def encode_action(self, action: torch.Tensor) -> torch.Tensor:
        """One-hot (discrete: from integers or one-hot) or float (continuous)."""
        if not self.discrete:
            if action.shape[-1] != self.action_dim:
                raise ValueError(
                    f"action: expected trailing size {self.action_dim}, got "
                    f"{tuple(action.shape)}."
                )
            return action.float()
        if action.dtype.is_floating_point or action.dtype == torch.bool:
            if action.shape[-1] != self.action_dim:
                raise ValueError(
                    f"action: expected integer actions or one-hot of size "
                    f"{self.action_dim}, got {tuple(action.shape)} ({action.dtype})."
                )
            return action.float()
        if action.shape and action.shape[-1] == 1:
            action = action.squeeze(-1)
        if action.numel():
            # One reduction for both bounds; F.one_hot would check them again.
            low, high = torch.aminmax(action)
            if low.item() < 0 or high.item() >= self.action_dim:
                raise ValueError(
                    f"action: expected integers in [0, {self.action_dim})."
                )
        one_hot = action.new_zeros(*action.shape, self.action_dim, dtype=torch.float)
        return one_hot.scatter_(-1, action.long().unsqueeze(-1), 1.0)

    def action_target(self, action: torch.Tensor) -> torch.Tensor:
        """Integer class targets (discrete) or float targets (continuous)."""
        if self.discrete:
            return self.encode_action(action).argmax(-1)
        return action.float()

    def features(self, observations: Sequence[torch.Tensor]) -> torch.Tensor:
        """``phi(s)`` for the observation tensors of ``s``."""
        return self.encoder(*observations)

    def paired_features(
        self,
        observations: Sequence[torch.Tensor],
        next_observations: Sequence[torch.Tensor],
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """``(phi(s), phi(s'))``, in one encoder pass when their shapes match.

        Every layer of the encoder maps each state on its own, so stacking
        ``s`` and ``s'`` into one batch gives the same features as two calls, at
        the fixed cost (kernel launches, input checks, the embedding's
        backward) of one.
        """
        if len(observations) == len(next_observations) and all(
            o.shape == n.shape and o.dtype == n.dtype
            for o, n in zip(observations, next_observations, strict=True)
        ):
            stacked = [
                torch.stack([o, n]) for o, n in zip(observations, next_observations)
            ]
            phi, phi_next = self.encoder(*stacked).unbind(0)
            return phi, phi_next
        return self.features(observations), self.features(next_observations)


class ICMModel(InverseDynamicsModel):
    """Feature encoder ``phi``, inverse model and forward model of ICM.

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
        return cls(
            MiniGridEncoder(
                hidden_dim=hidden_dim,
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
        return cls(
            VectorEncoder(obs_dim, hidden_dim=hidden_dim, onednn_linear=onednn_linear),
            action_dim,
            discrete=False,
            hidden_dim=hidden_dim,
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
