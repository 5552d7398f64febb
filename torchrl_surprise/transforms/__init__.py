"""Bonus transforms on one shared base, and the stochasticity transform."""

from torchrl_surprise.transforms.base import (
    NORMALIZATIONS,
    E3BRewardMoments,
    IntrinsicRewardTransform,
    LinearSchedule,
    WorkerCopyWarning,
    make_coef_schedule,
)
from torchrl_surprise.transforms.e3b import E3BTransform
from torchrl_surprise.transforms.episodic import (
    EllipticalEpisodicMemory,
    EpisodicMemory,
    EpisodicVisits,
)
from torchrl_surprise.transforms.icm import ICMTransform
from torchrl_surprise.transforms.noveld import NovelDTransform
from torchrl_surprise.transforms.precomputed import PrecomputedBonusTransform
from torchrl_surprise.transforms.stochasticity import (
    STOCHASTICITY_LEVELS,
    StochasticityTransform,
)
from torchrl_surprise.transforms.vae_surprise import (
    VAEEllipticalTransform,
    VAENegativeELBOTransform,
    VAENovelDTransform,
    VAEPosteriorShiftTransform,
    VAESurpriseTransform,
)

__all__ = [
    "E3BRewardMoments",
    "E3BTransform",
    "EllipticalEpisodicMemory",
    "EpisodicMemory",
    "EpisodicVisits",
    "ICMTransform",
    "IntrinsicRewardTransform",
    "LinearSchedule",
    "NORMALIZATIONS",
    "NovelDTransform",
    "PrecomputedBonusTransform",
    "STOCHASTICITY_LEVELS",
    "StochasticityTransform",
    "VAEEllipticalTransform",
    "VAENegativeELBOTransform",
    "VAENovelDTransform",
    "VAEPosteriorShiftTransform",
    "VAESurpriseTransform",
    "WorkerCopyWarning",
    "make_coef_schedule",
]
