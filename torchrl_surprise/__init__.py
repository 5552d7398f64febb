"""torchrl_surprise: VAE Bayesian-surprise exploration for TorchRL.

The intrinsic reward of a state is ``KL(q(z|s) || N(0, I))`` under a VAE trained on
visited states; the agent trains on ``r_ext + beta * r_int``.
"""

from torchrl_surprise.modules import ICMModel, StateVAE
from torchrl_surprise.objectives import (
    ICMLoss,
    IntrinsicValueLoss,
    TwoStreamAdvantage,
    VAELoss,
)
from torchrl_surprise.transforms import (
    ICMTransform,
    IntrinsicRewardTransform,
    LinearSchedule,
    VAESurpriseTransform,
)

__version__ = "0.1.0"

__all__ = [
    "ICMLoss",
    "ICMModel",
    "ICMTransform",
    "IntrinsicRewardTransform",
    "IntrinsicValueLoss",
    "LinearSchedule",
    "StateVAE",
    "TwoStreamAdvantage",
    "VAELoss",
    "VAESurpriseTransform",
]
