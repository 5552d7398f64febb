"""The MiniGrid recipe's bonuses, each declared once.

A bonus is one :class:`Bonus` in :data:`BONUSES`: its name (``bonus=<name>``), the
``intrinsic`` section that configures it, how its transform and loss (and, for
TorchRL's RND, a transform inside the env) are built from the config, and which
attribute of its transform holds the model that ``intrinsic.init_from`` loads.
The config's choices (:mod:`common.config`), :func:`common.minigrid.make_bonus`,
resume's rule for the sections a run does not read
(:func:`common.rundir.unused_bonus_sections`), the docs' list of bonuses and the
tests all read :data:`BONUSES`. Adding a bonus is its transform and loss plus one
:func:`register_bonus` call.

Examples:
    >>> sorted(BONUSES)
    ['e3b', 'icm', 'noveld', 'rnd', 'vae']
    >>> BONUSES["e3b"].section, BONUSES["e3b"].model_attr
    ('e3b', 'model')
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

from torch import nn
from torchrl.envs.transforms import RNDTransform
from torchrl.objectives.rnd import RNDLoss

from torchrl_surprise import (
    E3BModel,
    E3BTransform,
    ICMLoss,
    ICMModel,
    ICMTransform,
    InverseDynamicsLoss,
    NovelDTransform,
    RNDDistillationLoss,
    RNDModel,
    StateVAE,
    VAELoss,
    VAESurpriseTransform,
)
from torchrl_surprise.modules import InverseDynamicsModel
from torchrl_surprise.transforms import (
    PrecomputedBonusTransform,
    VAEEllipticalTransform,
    VAENegativeELBOTransform,
    VAENovelDTransform,
    VAEPosteriorShiftTransform,
)

__all__ = [
    "BONUSES",
    "RND_KEY",
    "VAE_VARIANTS",
    "Bonus",
    "bonus_choices",
    "bonus_sections",
    "register_bonus",
    "vae_variant_kwargs",
]


@dataclass(frozen=True)
class Bonus:
    """One bonus of the MiniGrid recipe.

    Attributes:
        name (str): ``bonus=<name>``.
        build (callable): ``build(cfg, action_spec, common)`` -> ``(transform,
            loss, env_side)``: the bonus transform applied to each collected
            batch, the ``LossModule`` that trains its model, and a transform to
            append to the training env (``None`` but for TorchRL's RND).
            ``common`` holds the keyword arguments every bonus transform takes
            from ``intrinsic.*`` (coefficient and schedule, normalisation,
            ``gamma``, ``clip``, ``reward_key``).
        section (str, optional): the ``intrinsic.<section>`` that configures it
            (``None``: none); a resumed run may change the other bonuses'.
        model_attr (str, optional): the transform's attribute holding the
            model that ``intrinsic.init_from`` starts from another run's
            (``None``: no transfer).
    """

    name: str
    build: Callable[[Any, Any, Mapping[str, Any]], tuple]
    section: str | None = None
    model_attr: str | None = None


BONUSES: dict[str, Bonus] = {}
"""Every bonus the recipe knows, by name (``"none"`` is no bonus)."""


def register_bonus(bonus: Bonus) -> Bonus:
    """Adds ``bonus`` to :data:`BONUSES`; a name already taken is refused."""
    if bonus.name == "none" or bonus.name in BONUSES:
        raise ValueError(f"a bonus named {bonus.name!r} is already registered.")
    BONUSES[bonus.name] = bonus
    return bonus


def bonus_choices() -> tuple[str, ...]:
    """The values ``bonus`` takes: ``"none"`` and every registered bonus."""
    return ("none", *BONUSES)


def bonus_sections() -> tuple[str, ...]:
    """The ``intrinsic`` sections that configure one bonus each."""
    return tuple(b.section for b in BONUSES.values() if b.section)


VAE_VARIANTS = {
    # the paper's bonus: KL(q(z|s) || N(0, I))
    "kl": VAESurpriseTransform,
    # novelty: -ELBO, how badly the VAE explains the state
    "neg_elbo": VAENegativeELBOTransform,
    # KL(q(z|s) || q_ref(z|s)): with the reference taken right before the VAE
    # trains on the rollout (info_gain) or every few updates (lagged_kl)
    "info_gain": VAEPosteriorShiftTransform,
    "lagged_kl": VAEPosteriorShiftTransform,
    # episodic novelty: E3B's elliptical bonus on the VAE's posterior mean
    "elliptical": VAEEllipticalTransform,
    # NovelD's novelty difference on first visits, the novelty the VAE's -ELBO
    "noveld": VAENovelDTransform,
}
"""``intrinsic.vae.variant`` -> the transform that computes the VAE bonus."""
RND_KEY = "rnd_reward"


def vae_variant_kwargs(variant: str, vae_cfg) -> dict:
    """The keyword arguments a VAE variant's transform takes beyond the common
    ones, read from the ``intrinsic.vae`` section of a config (a mapping).

    Examples:
        >>> vae_variant_kwargs("elliptical", {"ridge": 0.5})
        {'ridge': 0.5, 'global_bonus': 'none', 'unit_latent': False, 'start_in_memory': False}
        >>> vae_variant_kwargs("noveld", {"alpha": 0.25, "novelty": "kl"})
        {'alpha': 0.25, 'novelty': 'kl'}
        >>> vae_variant_kwargs("kl", {"ridge": 0.5})
        {}
    """
    if variant == "noveld":
        return {
            "alpha": vae_cfg.get("alpha", 0.5),
            "novelty": vae_cfg.get("novelty", "neg_elbo"),
        }
    if variant != "elliptical":
        return {}
    return {
        "ridge": vae_cfg.get("ridge", 0.1),
        "global_bonus": vae_cfg.get("global_bonus", "none"),
        "unit_latent": vae_cfg.get("unit_latent", False),
        "start_in_memory": vae_cfg.get("start_in_memory", False),
    }


def _build_vae(cfg, action_spec, common):
    vcfg = cfg.intrinsic.vae
    vae = StateVAE.for_minigrid(
        latent_dim=vcfg.latent_dim,
        hidden_dim=vcfg.hidden_dim,
        use_direction=vcfg.use_direction,
    )
    variant = vcfg.get("variant", "kl")
    transform = VAE_VARIANTS[variant](
        vae, **common, **vae_variant_kwargs(variant, vcfg)
    )
    inverse = {}
    if vcfg.get("inverse_weight", 0.0) > 0:
        inverse = dict(
            inverse_dynamics=InverseDynamicsModel.on_vae(
                vae, action_spec.space.n, hidden_dim=vcfg.hidden_dim
            ),
            inverse_weight=vcfg.inverse_weight,
        )
    return transform, VAELoss(vae, kl_weight=vcfg.kl_weight, **inverse), None


def _build_icm(cfg, action_spec, common):
    icfg = cfg.intrinsic.icm
    icm = ICMModel.for_minigrid(
        num_actions=action_spec.space.n, hidden_dim=icfg.hidden_dim
    )
    return ICMTransform(icm, **common), ICMLoss(icm, beta=icfg.beta), None


def _build_e3b(cfg, action_spec, common):
    ecfg = cfg.intrinsic.e3b
    model = E3BModel.for_minigrid(
        num_actions=action_spec.space.n,
        embedding_dim=ecfg.embedding_dim,
        hidden_dim=ecfg.hidden_dim,
    )
    transform = E3BTransform(
        model, ridge=ecfg.ridge, start_in_memory=ecfg.start_in_memory, **common
    )
    return transform, InverseDynamicsLoss(model), None


def _build_noveld(cfg, action_spec, common):
    ncfg = cfg.intrinsic.noveld
    rnd = RNDModel.for_minigrid(
        embedding_dim=ncfg.embedding_dim, hidden_dim=ncfg.hidden_dim
    )
    transform = NovelDTransform(rnd, alpha=ncfg.alpha, **common)
    return transform, RNDDistillationLoss(rnd), None


def _build_rnd(cfg, action_spec, common):
    width = cfg.intrinsic.rnd.hidden_dim

    def net():
        return nn.Sequential(
            nn.Flatten(-3),
            nn.Linear(7 * 7 * 3, width),
            nn.ReLU(),
            nn.Linear(width, width),
            nn.ReLU(),
            nn.Linear(width, width),
        )

    target, predictor = net(), net()
    # TorchRL's RNDTransform runs in the env (it has no batch path); its raw
    # error is then normalised and mixed by the same base as the other bonuses.
    env_side = RNDTransform(
        target, predictor, in_keys=["image"], out_keys=[RND_KEY], normalize_reward=False
    )
    transform = PrecomputedBonusTransform(RND_KEY, **common)
    update_fraction = cfg.intrinsic.rnd.update_fraction
    loss = RNDLoss(predictor, target, update_fraction=update_fraction)
    loss.set_keys(observation=("next", "image"))
    return transform, loss, env_side


# The paper's VAE (intrinsic.vae.variant chooses its bonus), ICM (Pathak et al.
# 2017), TorchRL's RND (Burda et al. 2019), E3B (Henaff et al. 2022), NovelD on
# RND (Zhang et al. 2021).
register_bonus(Bonus("vae", _build_vae, section="vae", model_attr="vae"))
register_bonus(Bonus("icm", _build_icm, section="icm", model_attr="icm"))
register_bonus(Bonus("rnd", _build_rnd, section="rnd"))
register_bonus(Bonus("e3b", _build_e3b, section="e3b", model_attr="model"))
register_bonus(Bonus("noveld", _build_noveld, section="noveld", model_attr="rnd"))
