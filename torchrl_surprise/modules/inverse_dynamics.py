"""An embedding trained by inverse dynamics: what ICM and E3B build on.

ICM (Pathak et al., 2017) adds a forward model on the embedding
(:class:`~torchrl_surprise.modules.ICMModel`); E3B (Henaff et al., 2022) computes
its elliptical bonus on it (:class:`~torchrl_surprise.modules.E3BModel`). Both
train it with :class:`~torchrl_surprise.objectives.InverseDynamicsLoss` (ICM's
inverse term).
"""

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

__all__ = ["InverseDynamicsModel", "PosteriorMean"]


class PosteriorMean(nn.Module):
    """The posterior mean of a :class:`~torchrl_surprise.modules.StateVAE` as an
    encoder: ``(*observations) -> loc``, ``out_features = vae.latent_dim``.

    It holds the VAE itself (not a copy): an
    :class:`InverseDynamicsModel` built on it trains the VAE's encoder, so that
    its latent keeps what the agent's actions control
    (:meth:`InverseDynamicsModel.on_vae`).

    Examples:
        >>> import torch
        >>> from torchrl_surprise.modules import StateVAE
        >>> vae = StateVAE.for_vector(obs_dim=3, latent_dim=2, hidden_dim=8)
        >>> encoder = PosteriorMean(vae)
        >>> obs = torch.randn(4, 3)
        >>> torch.equal(encoder(obs), vae.posterior(obs)[0])
        True
    """

    def __init__(self, vae: nn.Module):
        super().__init__()
        self.vae = vae
        self.out_features = vae.latent_dim

    def forward(self, *observations: torch.Tensor) -> torch.Tensor:
        return self.vae.posterior(*observations)[0]


class InverseDynamicsModel(nn.Module):
    """An embedding ``phi`` and an inverse model ``(phi(s), phi(s')) -> a``.

    Trained by :class:`~torchrl_surprise.objectives.InverseDynamicsLoss`, the
    embedding keeps what the agent's actions control and drops the rest (noise
    the agent cannot affect). :class:`~torchrl_surprise.modules.ICMModel` adds a
    forward model on it; :class:`~torchrl_surprise.modules.E3BModel` uses it as
    E3B's embedding.

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

    Examples:
        >>> import torch
        >>> model = InverseDynamicsModel.for_vector(
        ...     obs_dim=3, action_dim=4, embedding_dim=8, discrete=True)
        >>> s, s_next = torch.randn(5, 3), torch.randn(5, 3)
        >>> phi, phi_next = model.paired_features([s], [s_next])
        >>> model.inverse_model(torch.cat([phi, phi_next], -1)).shape
        torch.Size([5, 4])
        >>> model.embed(s).shape
        torch.Size([5, 8])
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

    @classmethod
    def for_minigrid(
        cls,
        num_actions: int = 7,
        embedding_dim: int = 256,
        hidden_dim: int = 256,
        use_direction: bool = True,
        onednn_linear: bool = False,
    ) -> InverseDynamicsModel:
        """On MiniGrid's symbolic grid (``"image"``, ``"direction"``).

        The encoder is :class:`~torchrl_surprise.modules.MiniGridEncoder`.

        Args:
            num_actions (int): number of discrete actions.
            embedding_dim (int): size of ``phi`` (the encoder's width).
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
    def on_vae(
        cls,
        vae: nn.Module,
        action_dim: int,
        discrete: bool = True,
        hidden_dim: int = 256,
        onednn_linear: bool = False,
    ) -> InverseDynamicsModel:
        """An inverse model on a VAE's posterior mean (:class:`PosteriorMean`).

        Trained beside the VAE's ELBO (``VAELoss(vae, inverse_dynamics=...)``),
        its loss shapes the latent towards what the agent controls; the VAE is
        shared, not copied, and the model reads the VAE's ``in_keys``.

        Args:
            vae (StateVAE): the VAE whose posterior mean is ``phi``.
            action_dim (int): number of discrete actions, or the action's size.
            discrete (bool): discrete actions.
            hidden_dim (int): width of the inverse model.
            onednn_linear (bool): run the inverse model on ``OneDNNLinear``.

        Examples:
            >>> from torchrl_surprise.modules import StateVAE
            >>> vae = StateVAE.for_minigrid(latent_dim=8, hidden_dim=32)
            >>> model = InverseDynamicsModel.on_vae(vae, action_dim=7)
            >>> model.in_keys, model.embedding_dim
            (['image', 'direction'], 8)
        """
        return cls(
            PosteriorMean(vae),
            action_dim,
            discrete=discrete,
            hidden_dim=hidden_dim,
            in_keys=vae.in_keys,
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
    ) -> InverseDynamicsModel:
        """On flat float observations (continuous actions by default).

        The encoder is :class:`~torchrl_surprise.modules.VectorEncoder`.

        Args:
            obs_dim (int): observation size.
            action_dim (int): action size, or number of discrete actions.
            embedding_dim (int): size of ``phi`` (the encoder's width).
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

    @property
    def embedding_dim(self) -> int:
        """The size of ``phi``."""
        return self.encoder.out_features

    def embed(self, *observations: torch.Tensor) -> torch.Tensor:
        """``phi(s)``, ``[..., embedding_dim]``, for the observation tensors of ``s``."""
        return self.encoder(*observations)

    def features(self, observations: Sequence[torch.Tensor]) -> torch.Tensor:
        """``phi(s)`` for the observation tensors of ``s`` (as a sequence)."""
        return self.encoder(*observations)

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
