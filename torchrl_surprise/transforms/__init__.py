"""Bonus transforms on one shared base, and the stochasticity transform."""

from torchrl_surprise.transforms.base import (
    NORMALIZATIONS,
    IntrinsicRewardTransform,
    LinearSchedule,
    WorkerCopyWarning,
    make_coef_schedule,
)
from torchrl_surprise.transforms.episodic import (
    EllipticalEpisodicMemory,
    EpisodicVisits,
)
from torchrl_surprise.transforms.icm import ICMTransform
from torchrl_surprise.transforms.precomputed import PrecomputedBonusTransform
from torchrl_surprise.transforms.stochasticity import (
    STOCHASTICITY_LEVELS,
    StochasticityTransform,
)
from torchrl_surprise.transforms.vae_surprise import (
    VAEEllipticalTransform,
    VAENegativeELBOTransform,
    VAEPosteriorShiftTransform,
    VAESurpriseTransform,
)

__all__ = [
    "EllipticalEpisodicMemory",
    "EpisodicVisits",
    "ICMTransform",
    "IntrinsicRewardTransform",
    "LinearSchedule",
    "NORMALIZATIONS",
    "PrecomputedBonusTransform",
    "STOCHASTICITY_LEVELS",
    "StochasticityTransform",
    "VAEEllipticalTransform",
    "VAENegativeELBOTransform",
    "VAEPosteriorShiftTransform",
    "VAESurpriseTransform",
    "WorkerCopyWarning",
    "make_coef_schedule",
]
