"""Networks: the state VAE, observation encoders and the ICM networks."""

from torchrl_surprise.modules.icm import ICMModel
from torchrl_surprise.modules.vae import (
    GaussianVectorDecoder,
    MiniGridDecoder,
    MiniGridEncoder,
    StateVAE,
    VectorEncoder,
    kl_to_standard_normal,
)

__all__ = [
    "GaussianVectorDecoder",
    "ICMModel",
    "MiniGridDecoder",
    "MiniGridEncoder",
    "StateVAE",
    "VectorEncoder",
    "kl_to_standard_normal",
]
