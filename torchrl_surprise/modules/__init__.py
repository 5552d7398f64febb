"""Networks: the state VAE, observation encoders, and the ICM, E3B and RND networks."""

from torchrl_surprise.modules.e3b import E3BModel
from torchrl_surprise.modules.icm import ICMModel
from torchrl_surprise.modules.inverse_dynamics import (
    InverseDynamicsModel,
    PosteriorMean,
)
from torchrl_surprise.modules.rnd import RNDModel
from torchrl_surprise.modules.vae import (
    GaussianVectorDecoder,
    MiniGridDecoder,
    MiniGridEncoder,
    StateVAE,
    VectorEncoder,
    kl_to_standard_normal,
)

__all__ = [
    "E3BModel",
    "GaussianVectorDecoder",
    "ICMModel",
    "InverseDynamicsModel",
    "MiniGridDecoder",
    "MiniGridEncoder",
    "PosteriorMean",
    "RNDModel",
    "StateVAE",
    "VectorEncoder",
    "kl_to_standard_normal",
]
