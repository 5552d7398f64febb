"""Losses that train the bonus models (TorchRL ``LossModule`` conventions)."""

from torchrl_surprise.objectives.icm import ICMLoss
from torchrl_surprise.objectives.vae import VAELoss

__all__ = ["ICMLoss", "VAELoss"]
