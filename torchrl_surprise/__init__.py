"""torchrl_surprise: exploration bonuses for TorchRL.

A bonus is a TorchRL ``Transform`` (it writes the intrinsic reward and the mixed
reward ``r_ext + coef * r_int``, inside an env or on a collected batch) paired with
a ``LossModule`` that trains its model. The paper's bonus is the VAE surprise,
``KL(q(z|s) || N(0, I))`` under a VAE trained on visited states; the one that
explores best in our measurements is its episodic form,
:class:`VAEEllipticalTransform`, with its intrinsic return learned by a second
critic (:class:`TwoStreamAdvantage`).

Env factories live in :mod:`torchrl_surprise.envs` (MiniGrid, MuJoCo: each needs
its extra), the resumable collectors in :mod:`torchrl_surprise.collectors`.
"""

from torchrl_surprise.modules import E3BModel, ICMModel, RNDModel, StateVAE
from torchrl_surprise.objectives import (
    ICMLoss,
    IntrinsicValueLoss,
    InverseDynamicsLoss,
    RNDDistillationLoss,
    TwoStreamAdvantage,
    VAELoss,
)
from torchrl_surprise.transforms import (
    E3BTransform,
    ICMTransform,
    IntrinsicRewardTransform,
    LinearSchedule,
    NovelDTransform,
    VAEEllipticalTransform,
    VAESurpriseTransform,
)

__version__ = "0.2.0"

__all__ = [
    "E3BModel",
    "E3BTransform",
    "ICMLoss",
    "ICMModel",
    "ICMTransform",
    "IntrinsicRewardTransform",
    "IntrinsicValueLoss",
    "InverseDynamicsLoss",
    "LinearSchedule",
    "NovelDTransform",
    "RNDDistillationLoss",
    "RNDModel",
    "StateVAE",
    "TwoStreamAdvantage",
    "VAEEllipticalTransform",
    "VAELoss",
    "VAESurpriseTransform",
]
