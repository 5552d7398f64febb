"""Losses that train the bonus models (TorchRL ``LossModule`` conventions), and the
two-stream advantage that lets a bonus drive exploration."""

from torchrl_surprise.objectives.icm import ICMLoss
from torchrl_surprise.objectives.inverse_dynamics import InverseDynamicsLoss
from torchrl_surprise.objectives.rnd import RNDDistillationLoss
from torchrl_surprise.objectives.two_stream import (
    IntrinsicValueLoss,
    TwoStreamAdvantage,
)
from torchrl_surprise.objectives.vae import VAELoss

__all__ = [
    "ICMLoss",
    "IntrinsicValueLoss",
    "InverseDynamicsLoss",
    "RNDDistillationLoss",
    "TwoStreamAdvantage",
    "VAELoss",
]
