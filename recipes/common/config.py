"""The recipes' typed configs: one dataclass per config section, the schema of each
recipe's ``config.yaml``.

Each ``config.yaml`` starts its defaults with its schema (``minigrid_schema``,
``ddpg_mujoco_schema``), so Hydra refuses, while it composes the config and before
the script runs, a key that is not in the schema and a value of the wrong type
(``seed=abc``, ``env.num_envs=2.5``, ``loss.normalize_advantage=maybe``), naming
the setting by its full key. The values, and the reason for each, live in the yaml
files: every field here is ``MISSING``.

What a type cannot say is checked by :func:`validate_minigrid` and
:func:`validate_ddpg` before anything is built: every float is finite, each value
satisfies its field's ``rule`` (``optim.lr`` > 0), and the rules between settings
hold (``collector.workers`` divides ``env.num_envs``); each error names the setting
by its full key and what it expects. The objects the recipes build keep their own
checks. Importing this module stores the two schemas in Hydra's ConfigStore.

Examples:
    >>> from omegaconf import OmegaConf
    >>> cfg = OmegaConf.merge(OmegaConf.structured(LoggerConfig),
    ...                       {"backend": "csv", "project_name": "p",
    ...                        "log_interval": 0, "episode_window": 10})
    >>> check_settings(cfg, LoggerConfig, prefix="logger.")
    Traceback (most recent call last):
    ...
    ValueError: logger.log_interval must be an integer > 0, got 0.
    >>> OmegaConf.merge(cfg, {"log_interval": 2.5})
    Traceback (most recent call last):
    ...
    omegaconf.errors.ValidationError: Value '2.5' of type 'float' could not be converted to Integer
        full_key: log_interval
        object_type=LoggerConfig
"""

# No "from __future__ import annotations": a sweep sends this module by value to
# its workers (common.stopping.register_sweep_pickling), where string annotations
# could not be evaluated in a module they cannot import.
import dataclasses
import difflib
import functools
import math
import types
import typing
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, NamedTuple

from hydra.core.config_store import ConfigStore
from omegaconf import MISSING

from torchrl_surprise.envs.minigrid import MINIGRID_BACKENDS
from torchrl_surprise.transforms import NORMALIZATIONS, STOCHASTICITY_LEVELS
from torchrl_surprise.transforms.vae_surprise import GLOBAL_BONUSES, NOVELD_NOVELTIES

from .bonuses import bonus_choices
from .errors import ConfigError
from .rundir import RESUME_MODES

__all__ = [
    "ALGOS",
    "BONUS_AT",
    "DDPG_BONUSES",
    "DEVICES",
    "EXPLORATION_NOISES",
    "LOGGER_BACKENDS",
    "OPTIMIZERS",
    "VAE_VARIANTS",
    "CheckpointConfig",
    "DDPGConfig",
    "EvalConfig",
    "IntrinsicConfig",
    "LoggerConfig",
    "MiniGridConfig",
    "Rule",
    "VAEConfig",
    "check_settings",
    "one_of",
    "required",
    "validate_ddpg",
    "validate_minigrid",
]


# Choices are strings checked against these tuples (the field's rule), not enums:
# an enum-typed field would hand its members to what the recipe builds (a bonus
# transform's state_dict keeps its normalization), and so into checkpoints, which
# would then need this module to load.
DDPG_BONUSES: tuple[str, ...] = ("none", "vae")
"""``bonus`` of the DDPG recipe."""
ALGOS: tuple[str, ...] = ("a2c", "ppo")
"""``algo.name``: the MiniGrid recipe's learner."""
OPTIMIZERS: tuple[str, ...] = ("rmsprop", "adam")
"""``optim.name``: the MiniGrid actor-critic's optimiser."""
VAE_VARIANTS: tuple[str, ...] = (
    "kl",
    "neg_elbo",
    "info_gain",
    "lagged_kl",
    "elliptical",
    "noveld",
)
"""``intrinsic.vae.variant``: the keys of ``common.minigrid.VAE_VARIANTS``."""
BONUS_AT: tuple[str, ...] = ("sample", "collection")
"""``intrinsic.bonus_at`` of the DDPG recipe."""
EXPLORATION_NOISES: tuple[str, ...] = ("gaussian", "ou")
"""``exploration.noise`` of the DDPG recipe."""
LOGGER_BACKENDS: tuple[str, ...] = ("csv", "tensorboard", "wandb", "mlflow", "")
"""``logger.backend``; ``""`` logs nothing."""
DEVICES: tuple[str, ...] = ("cpu", "cuda", "auto")
"""``device`` of the MiniGrid recipe (auto: cuda when torch sees one, else cpu)."""
# and those the library owns, taken from it: NORMALIZATIONS, GLOBAL_BONUSES,
# NOVELD_NOVELTIES, MINIGRID_BACKENDS


class Rule(NamedTuple):
    """What a setting's value must satisfy beyond its type: ``expected`` is how an
    error says it, ``holds`` tests a value."""

    expected: str
    holds: Callable[[Any], bool]


POSITIVE = Rule("> 0", lambda v: v > 0)
NON_NEGATIVE = Rule(">= 0", lambda v: v >= 0)
UNIT_INTERVAL = Rule("in [0, 1]", lambda v: 0 <= v <= 1)
HALF_OPEN_UNIT = Rule("in (0, 1]", lambda v: 0 < v <= 1)


def one_of(choices) -> Rule:
    """A rule for a setting that takes one of ``choices``."""
    return Rule("one of " + ", ".join(repr(c) for c in choices), choices.__contains__)


class _Registered:
    """A rule for ``bonus``: one of the names registered when it is checked
    (:func:`common.bonuses.bonus_choices`), so a bonus registered after this
    module is imported is accepted."""

    @property
    def expected(self) -> str:
        return one_of(bonus_choices()).expected

    def holds(self, value) -> bool:
        return value in bonus_choices()


RESUME = Rule(
    "one of " + ", ".join(RESUME_MODES) + " (any case)",
    lambda v: str(v).lower() in RESUME_MODES,
)


def required(rule: Rule | None = None):
    """A field without a default (the yaml sets it), checked against ``rule``."""
    return field(default=MISSING, metadata={"rule": rule})


def section(schema):
    return field(default_factory=schema)


# Sections both recipes share.
@dataclass
class LoggerConfig:
    """``logger``: where metrics go, how often."""

    backend: str = required(one_of(LOGGER_BACKENDS))
    """TorchRL logger: csv, tensorboard, wandb, mlflow, or "" for none."""
    project_name: str = required()
    """W&B project (ignored by the other backends)."""
    log_interval: int = required(POSITIVE)
    """Updates (MiniGrid) or collected batches (DDPG) between two log lines; > 0."""
    episode_window: int = required(POSITIVE)
    """Finished episodes in the moving window of the logged return; > 0."""


@dataclass
class CheckpointConfig:
    """``checkpoint``: how often a run saves what it needs to resume."""

    interval_frames: int = required(POSITIVE)
    """Frames between two periodic checkpoints; > 0."""


@dataclass
class EvalConfig:
    """``eval``: the evaluation of the policy on extrinsic reward."""

    interval_frames: int = required(POSITIVE)
    """Training frames between two evaluations; > 0."""
    episodes: int = required(POSITIVE)
    """Episodes per evaluation; > 0."""
    num_envs: int = required(POSITIVE)
    """Evaluation envs stepped together; > 0."""


@dataclass
class VAEConfig:
    """``intrinsic.vae``: the state VAE whose surprise is the bonus."""

    latent_dim: int = required(POSITIVE)
    """Size of the latent z; > 0."""
    hidden_dim: int = required(POSITIVE)
    """Width of the encoder's and decoder's hidden layers; > 0."""
    kl_weight: float = required(NON_NEGATIVE)
    """Weight of the KL term in the VAE's loss (beta); >= 0."""


@dataclass
class IntrinsicConfig:
    """``intrinsic``: the bonus, ``r = r_ext + coef * normalize(r_int)``, and its
    model's training."""

    coef: float = required()
    """Weight of the normalised bonus in the reward (or the advantage); finite."""
    coef_end: float | None = required()
    """Value coef anneals to, linearly over anneal_frames; null keeps coef."""
    anneal_frames: int = required(NON_NEGATIVE)
    """Frames over which coef anneals to coef_end; >= 0."""
    warmup_frames: int = required(NON_NEGATIVE)
    """Frames during which the bonus model trains but the bonus weighs 0; >= 0."""
    normalization: str = required(one_of(NORMALIZATIONS))
    """How the bonus is normalised before it is weighted (NORMALIZATIONS)."""
    clip: float | None = required(POSITIVE)
    """Bound on the normalised bonus, [-clip, clip]; > 0, or null for none."""
    update_every: int = required(POSITIVE)
    """Bonus-model training on every update_every-th update (MiniGrid) or DDPG
    update (DDPG); > 0."""
    lr: float = required(POSITIVE)
    """Adam learning rate of the bonus model; > 0."""


# The MiniGrid recipe (recipes/minigrid/config.yaml).
@dataclass
class AlgoConfig:
    """``algo`` (algo/*.yaml)."""

    name: str = required(one_of(ALGOS))
    """The learner: a2c or ppo."""


@dataclass
class MiniGridEnvConfig:
    """``env`` of the MiniGrid recipe."""

    name: str = required()
    """A MiniGrid env id, e.g. MiniGrid-MultiRoom-N3-S4-v0."""
    num_envs: int = required(POSITIVE)
    """Training envs stepped together; > 0."""
    backend: str = required(one_of(MINIGRID_BACKENDS))
    """gymnasium (minigrid's Python envs) or envpool (its C++ port)."""
    num_threads: int = required(POSITIVE)
    """envpool's threads (envpool only); > 0."""
    stochasticity: int = required(one_of(tuple(STOCHASTICITY_LEVELS)))
    """Level of STOCHASTICITY_LEVELS (0: the deterministic env)."""


@dataclass
class MiniGridCollectorConfig:
    """``collector`` of the MiniGrid recipe."""

    total_frames: int = required(POSITIVE)
    """The run's budget of env frames, over all envs; > 0."""
    frames_per_env: int = required(POSITIVE)
    """Steps per env per update; > 0."""
    workers: int = required(POSITIVE)
    """Processes stepping env.num_envs / workers envs each; > 0, divides
    env.num_envs, 1 with bonus=rnd."""


@dataclass
class MiniGridOptimConfig:
    """``optim``: the actor-critic's optimiser."""

    name: str = required(one_of(OPTIMIZERS))
    """rmsprop or adam."""
    lr: float = required(POSITIVE)
    """Learning rate; > 0."""
    alpha: float = required(UNIT_INTERVAL)
    """RMSprop's smoothing constant (unused by Adam); in [0, 1]."""
    eps: float = required(POSITIVE)
    """Term added to the denominator of the step; > 0 (0 divides by zero where a
    parameter's gradients have all been 0, and the run goes non-finite)."""
    max_grad_norm: float = required(POSITIVE)
    """Bound on the norm of the gradients of each step; > 0."""


@dataclass
class MiniGridLossConfig:
    """``loss``: the A2C or PPO objective and its advantages."""

    gamma: float = required(UNIT_INTERVAL)
    """Discount; in [0, 1]."""
    gae_lambda: float = required(UNIT_INTERVAL)
    """GAE's lambda; in [0, 1]."""
    entropy_coef: float = required(NON_NEGATIVE)
    """Weight of the entropy bonus; >= 0."""
    critic_coef: float = required(NON_NEGATIVE)
    """Weight of the critic's squared error; >= 0."""
    normalize_advantage: bool = required()
    """Centre and scale the advantages (A2C: of the batch; PPO: of each minibatch)."""
    clip_epsilon: float = required(POSITIVE)
    """PPO's clipping of the ratio and of the value update; > 0."""
    epochs: int = required(POSITIVE)
    """PPO's passes over each collected batch; > 0."""
    minibatch_size: int = required(POSITIVE)
    """PPO's minibatch, in transitions; > 0 and at most env.num_envs *
    collector.frames_per_env."""
    reward_clip: float | None = required(POSITIVE)
    """Bound on the reward the critic learns from (the mixed reward with one
    critic), [-reward_clip, reward_clip]; > 0, or null for none."""


@dataclass
class MiniGridVAEConfig(VAEConfig):
    """``intrinsic.vae`` of the MiniGrid recipe: the VAE and which of its bonuses."""

    variant: str = required(one_of(VAE_VARIANTS))
    """kl, neg_elbo, info_gain, lagged_kl, elliptical or noveld (docs in config.yaml)."""
    lag_updates: int = required(POSITIVE)
    """lagged_kl: updates between two refreshes of the reference copy; > 0."""
    ridge: float = required(POSITIVE)
    """elliptical: the ridge lambda of C = lambda I + sum phi phi^T; > 0."""
    global_bonus: str = required(one_of(GLOBAL_BONUSES))
    """elliptical: none, or kl to multiply the episodic bonus by the KL."""
    unit_latent: bool = required()
    """elliptical: the episodic term reads the posterior mean at unit length."""
    start_in_memory: bool = required()
    """elliptical: an episode's first state joins C before the first bonus."""
    alpha: float = required(NON_NEGATIVE)
    """noveld: weight of novelty(s) in max(novelty(s') - alpha novelty(s), 0); >= 0."""
    novelty: str = required(one_of(NOVELD_NOVELTIES))
    """noveld: the VAE's novelty, neg_elbo (its negative ELBO) or kl (its KL)."""
    use_direction: bool = required()
    """The VAE reads the agent's direction as well as the image."""
    inverse_weight: float = required(NON_NEGATIVE)
    """Weight of an inverse-dynamics loss on the posterior mean beside the ELBO
    (0: none); >= 0."""


@dataclass
class ICMConfig:
    """``intrinsic.icm``: the intrinsic curiosity module."""

    hidden_dim: int = required(POSITIVE)
    """Width of the forward and inverse models; > 0."""
    beta: float = required(UNIT_INTERVAL)
    """Weight of the forward loss against the inverse loss; in [0, 1]."""


@dataclass
class RNDConfig:
    """``intrinsic.rnd``: random network distillation."""

    hidden_dim: int = required(POSITIVE)
    """Width of the target and predictor networks; > 0."""
    update_fraction: float = required(HALF_OPEN_UNIT)
    """Fraction of the states the predictor trains on; in (0, 1]."""


@dataclass
class E3BConfig:
    """``intrinsic.e3b``: E3B's elliptical bonus on an inverse-dynamics embedding."""

    embedding_dim: int = required(POSITIVE)
    """Size of the embedding phi the bonus is computed on; > 0."""
    hidden_dim: int = required(POSITIVE)
    """Width of the inverse-dynamics head; > 0."""
    ridge: float = required(POSITIVE)
    """The ridge lambda of C = lambda I + sum phi phi^T; > 0."""
    start_in_memory: bool = required()
    """An episode's first state joins C before the first bonus (E3B's code)."""


@dataclass
class NovelDConfig:
    """``intrinsic.noveld``: NovelD's novelty difference on RND, first visits."""

    alpha: float = required(NON_NEGATIVE)
    """Weight of novelty(s) in max(novelty(s') - alpha novelty(s), 0); >= 0."""
    embedding_dim: int = required(POSITIVE)
    """Output size of RND's target and predictor; > 0."""
    hidden_dim: int = required(POSITIVE)
    """Width of RND's encoders; > 0."""


@dataclass
class MiniGridIntrinsicConfig(IntrinsicConfig):
    """``intrinsic`` of the MiniGrid recipe."""

    intrinsic_critic: bool = required()
    """A second value head learns the intrinsic return (A_ext + coef * A_int)."""
    episodic: bool = required()
    """Intrinsic returns stop at episode ends."""
    init_from: str | None = required()
    """A run dir or checkpoint whose bonus model this run starts from (not rnd)."""
    finetune: bool = required()
    """With init_from: keep training the bonus model (false: frozen)."""
    update_steps: int = required(NON_NEGATIVE)
    """Bonus-model gradient steps per training update; >= 0."""
    batch_size: int | None = required(POSITIVE)
    """Transitions per bonus-model step, drawn at random from the batch; null: all."""
    vae: MiniGridVAEConfig = section(MiniGridVAEConfig)
    icm: ICMConfig = section(ICMConfig)
    rnd: RNDConfig = section(RNDConfig)
    e3b: E3BConfig = section(E3BConfig)
    noveld: NovelDConfig = section(NovelDConfig)


@dataclass
class MiniGridEvalConfig(EvalConfig):
    """``eval`` of the MiniGrid recipe."""

    deterministic: bool = required()
    """Greedy actions (false: the policy is sampled)."""
    video: bool = required()
    """Record the final policy's episodes as a GIF (``common.video``)."""
    video_episodes: int = required(POSITIVE)
    """Episodes in that GIF; > 0."""


@dataclass
class MiniGridCheckpointConfig(CheckpointConfig):
    """``checkpoint`` of the MiniGrid recipe."""

    keep: bool = required()
    """Keep every periodic checkpoint under checkpoints/ (false: the latest only)."""


@dataclass
class MiniGridConfig:
    """The MiniGrid recipe's config (``minigrid_schema``)."""

    seed: int = required(NON_NEGATIVE)
    """Seed of every generator of the run; >= 0 (NumPy's seeds are)."""
    bonus: str = required(_Registered())
    """none, vae, icm, rnd, e3b or noveld."""
    resume: str = required(RESUME)
    """auto, true or false (common.rundir.RESUME_MODES)."""
    resume_without_logs: bool = required()
    """Resume a run whose scalar logs are gone (false: refused, naming them)."""
    setting: str = required()
    """Label of this run's settings in aggregated reports."""
    experiment_name: str = required()
    """Name of the sweep's directory, runs/<algo>_minigrid/<name>/."""
    torch_threads: int = required(POSITIVE)
    """torch.set_num_threads; > 0."""
    device: str = required(one_of(DEVICES))
    """Where the policy, critics and bonus model run: cpu, cuda or auto (cuda when
    torch sees one, else cpu); the envs stay on the CPU."""
    algo: AlgoConfig = section(AlgoConfig)
    env: MiniGridEnvConfig = section(MiniGridEnvConfig)
    collector: MiniGridCollectorConfig = section(MiniGridCollectorConfig)
    optim: MiniGridOptimConfig = section(MiniGridOptimConfig)
    loss: MiniGridLossConfig = section(MiniGridLossConfig)
    intrinsic: MiniGridIntrinsicConfig = section(MiniGridIntrinsicConfig)
    eval: MiniGridEvalConfig = section(MiniGridEvalConfig)
    logger: LoggerConfig = section(LoggerConfig)
    checkpoint: MiniGridCheckpointConfig = section(MiniGridCheckpointConfig)


# The DDPG recipe (recipes/ddpg_mujoco/config.yaml).
@dataclass
class DDPGEvalConfig(EvalConfig):
    """``eval`` of the DDPG recipe."""

    video: bool = required()
    """Record the final actor's episodes as a GIF (``common.video``); MuJoCo
    renders with OpenGL: without a display, MUJOCO_GL=egl."""
    video_episodes: int = required(POSITIVE)
    """Episodes in that GIF; > 0."""


@dataclass
class DDPGEnvConfig:
    """``env`` of the DDPG recipe."""

    name: str = required()
    """A gymnasium MuJoCo id, e.g. HalfCheetah-v5."""
    num_envs: int = required(POSITIVE)
    """Envs of one in-process vector env; > 0, divides collector.frames_per_batch."""


@dataclass
class DDPGCollectorConfig:
    """``collector`` of the DDPG recipe."""

    total_frames: int = required(POSITIVE)
    """The run's budget of env frames; > 0, a multiple of frames_per_batch."""
    frames_per_batch: int = required(POSITIVE)
    """Frames collected between two blocks of updates; > 0."""
    init_random_frames: int = required(NON_NEGATIVE)
    """Frames of uniform random actions first; >= 0, a multiple of
    frames_per_batch."""


@dataclass
class ReplayBufferConfig:
    """``replay_buffer``."""

    size: int = required(POSITIVE)
    """Transitions the buffer holds; > 0."""


@dataclass
class DDPGOptimConfig:
    """``optim``: DDPG's updates."""

    batch_size: int = required(POSITIVE)
    """Transitions per update; > 0."""
    utd_ratio: float = required(POSITIVE)
    """Updates per collected frame; > 0."""
    actor_lr: float = required(POSITIVE)
    """Adam learning rate of the actor; > 0."""
    critic_lr: float = required(POSITIVE)
    """Adam learning rate of the critic; > 0."""
    gamma: float = required(UNIT_INTERVAL)
    """Discount; in [0, 1]."""
    tau: float = required(HALF_OPEN_UNIT)
    """Polyak rate of the target networks; in (0, 1]."""


@dataclass
class DDPGLossConfig:
    """``loss``: TorchRL's DDPGLoss."""

    delay_actor: bool = required()
    """The TD target's next action from a target actor (false: from the actor)."""


@dataclass
class NetworkConfig:
    """``network``: actor and critic MLPs."""

    hidden_sizes: list[int] = required(POSITIVE)
    """Width of each hidden layer; each > 0."""


@dataclass
class ExplorationConfig:
    """``exploration``: the noise added to the actor's actions."""

    noise: str = required(one_of(EXPLORATION_NOISES))
    """gaussian or ou."""
    gaussian_std: float = required(NON_NEGATIVE)
    """Std of the Gaussian noise, in half ranges of the action; >= 0."""
    ou_theta: float = required(NON_NEGATIVE)
    """Ornstein-Uhlenbeck mean reversion; >= 0."""
    ou_sigma: float = required(NON_NEGATIVE)
    """Ornstein-Uhlenbeck scale; >= 0."""
    ou_dt: float = required(POSITIVE)
    """Ornstein-Uhlenbeck time step; > 0."""


@dataclass
class ObsNormConfig:
    """``obs_norm``: the running normalisation of the VAE's observations."""

    clip: float | None = required(POSITIVE)
    """Bound on the normalised observation; > 0, or null for none."""


@dataclass
class DDPGIntrinsicConfig(IntrinsicConfig):
    """``intrinsic`` of the DDPG recipe."""

    bonus_at: str = required(one_of(BONUS_AT))
    """sample (recomputed on each replay sample) or collection (stored)."""
    batch_size: int = required(POSITIVE)
    """The VAE's minibatch, its own sample from the buffer; > 0."""
    vae: VAEConfig = section(VAEConfig)


@dataclass
class DDPGConfig:
    """The DDPG recipe's config (``ddpg_mujoco_schema``)."""

    seed: int = required(NON_NEGATIVE)
    """Seed of every generator of the run; >= 0 (NumPy's seeds are)."""
    bonus: str = required(one_of(DDPG_BONUSES))
    """none or vae."""
    resume: str = required(RESUME)
    """auto, true or false (common.rundir.RESUME_MODES)."""
    resume_without_logs: bool = required()
    """Resume a run whose scalar logs are gone (false: refused, naming them)."""
    setting: str = required()
    """Label of this run's settings in aggregated reports."""
    experiment_name: str = required()
    """Name of the sweep's directory, runs/ddpg_mujoco/<name>/."""
    torch_threads: int = required(POSITIVE)
    """torch.set_num_threads; > 0."""
    env: DDPGEnvConfig = section(DDPGEnvConfig)
    collector: DDPGCollectorConfig = section(DDPGCollectorConfig)
    replay_buffer: ReplayBufferConfig = section(ReplayBufferConfig)
    optim: DDPGOptimConfig = section(DDPGOptimConfig)
    loss: DDPGLossConfig = section(DDPGLossConfig)
    network: NetworkConfig = section(NetworkConfig)
    exploration: ExplorationConfig = section(ExplorationConfig)
    obs_norm: ObsNormConfig = section(ObsNormConfig)
    intrinsic: DDPGIntrinsicConfig = section(DDPGIntrinsicConfig)
    eval: DDPGEvalConfig = section(DDPGEvalConfig)
    logger: LoggerConfig = section(LoggerConfig)
    checkpoint: CheckpointConfig = section(CheckpointConfig)


def _check_value(
    key: str, value: Any, kind: type, rule: Rule | None, optional: bool
) -> None:
    if isinstance(value, str) or kind is str:
        # Strings and enum choices: their type was enforced as the config composed.
        if rule is not None and not rule.holds(value):
            raise ValueError(f"{key} must be {rule.expected}, got {value!r}.")
        return
    if rule is not None and rule.expected.startswith("one of"):
        expected = rule.expected
    else:
        expected = "an integer" if kind is int else "a finite number"
        expected += "" if rule is None else f" {rule.expected}"
    expected += " or null" if optional else ""
    finite = kind is not float or math.isfinite(value)
    if not finite or (rule is not None and not rule.holds(value)):
        raise ValueError(f"{key} must be {expected}, got {value!r}.")


def check_settings(cfg, schema: type, prefix: str = "") -> None:
    """Checks each value of ``cfg`` against its field of ``schema``: floats are
    finite, and each value satisfies its field's :class:`Rule`.

    Types are not checked here: a config composed on its schema has them. A key
    the schema does not have (added with ``+``, a misspelt name) is refused.

    Args:
        cfg: a config composed on ``schema`` (a ``DictConfig``, or a section).
        schema: the dataclass of ``cfg``.
        prefix: the full key of ``cfg`` followed by a dot (``""`` at the root).

    Raises:
        ValueError: naming the first setting that breaks its rule, with its full
            key, what it expects and the value given.
    """
    hints = typing.get_type_hints(schema)
    fields = dataclasses.fields(schema)
    known = [f.name for f in fields]
    for key in cfg:
        if key not in known:
            # added with "+" (Hydra's own hint for a key it does not know)
            close = difflib.get_close_matches(str(key), known, n=1)
            hint = f" (did you mean {prefix}{close[0]}?)" if close else ""
            raise ValueError(
                f"{prefix}{key} is not a setting of this recipe{hint}. The settings "
                f"{'of ' + prefix.rstrip('.') if prefix else 'at the top'} are: "
                f"{', '.join(known)}."
            )
    for f in fields:
        key = f"{prefix}{f.name}"
        kind, value = hints[f.name], cfg[f.name]
        if dataclasses.is_dataclass(kind):
            check_settings(value, kind, prefix=f"{key}.")
            continue
        optional = typing.get_origin(kind) in (typing.Union, types.UnionType)
        if optional:
            if value is None:
                continue  # null: "none", as its field says
            kind = next(a for a in typing.get_args(kind) if a is not type(None))
        rule = f.metadata.get("rule")
        if typing.get_origin(kind) is list:
            (item_kind,) = typing.get_args(kind)
            for i, item in enumerate(value):
                _check_value(f"{key}[{i}]", item, item_kind, rule, False)
            continue
        _check_value(key, value, kind, rule, optional)


def _refusing(validate):
    """``validate`` with its ``ValueError`` raised as a :class:`ConfigError`, the
    user's mistake (:func:`common.errors.report_mistakes` prints it alone)."""

    @functools.wraps(validate)
    def checked(cfg) -> None:
        try:
            validate(cfg)
        except ValueError as err:
            raise ConfigError(str(err)) from None

    return checked


@_refusing
def validate_minigrid(cfg) -> None:
    """Refuses a MiniGrid config the recipe cannot run, before anything is built.

    The settings' ranges (:func:`check_settings` over :class:`MiniGridConfig`),
    then the rules between settings.

    Raises:
        ConfigError: a ``ValueError`` naming the setting by its full key and the
            value expected.
    """
    check_settings(cfg, MiniGridConfig)
    workers, num_envs = cfg.collector.workers, cfg.env.num_envs
    if num_envs % workers:
        raise ValueError(
            f"env.num_envs ({num_envs}) must be a multiple of collector.workers "
            f"({workers}): each worker process steps env.num_envs / "
            "collector.workers envs. Change one of them."
        )
    if workers > 1 and cfg.bonus == "rnd":
        raise ValueError(
            "bonus=rnd runs TorchRL's RNDTransform inside the env, so with "
            f"collector.workers={workers} each worker process would compute the bonus "
            "with its own stale copy of the RND predictor and its statistics. Run "
            "bonus=rnd with collector.workers=1 (the other bonuses are computed on "
            "the collected batch in the main process and work with any number of "
            "workers)."
        )
    if workers > 1 and cfg.device != "cpu":
        # auto included, whatever this machine has: a config valid here is valid
        # on the cluster's GPU nodes too.
        raise ValueError(
            f"device={cfg.device} with collector.workers={workers}: the worker "
            "processes' policy would sample from the CUDA generator (device=auto "
            "picks cuda wherever torch sees a GPU), which the checkpoint does not "
            "save, so a resumed run would not continue the uninterrupted one. Run "
            f"device=cpu with collector.workers={workers}, or device=cuda with "
            "collector.workers=1."
        )
    variant = cfg.intrinsic.vae.variant
    update_every = cfg.intrinsic.update_every
    if (
        cfg.bonus == "vae"
        and variant in ("info_gain", "lagged_kl")
        and update_every != 1
    ):
        # info_gain: the change that training on a rollout makes to its states'
        # posterior; lagged_kl: the copy is refreshed right after a training step,
        # so with sparse steps it would mostly equal the VAE (a bonus of 0).
        raise ValueError(
            f"intrinsic.vae.variant={variant} compares the VAE with itself before "
            "its last updates, so it trains on every rollout: set "
            f"intrinsic.update_every=1 (got {update_every})."
        )
    if cfg.intrinsic.init_from and cfg.bonus in ("none", "rnd"):
        raise ValueError(
            "intrinsic.init_from starts the bonus model from another run's: bonus "
            f"must be vae, icm, e3b or noveld with it, got bonus={cfg.bonus}."
        )
    if cfg.algo.name == "ppo":
        batch = num_envs * cfg.collector.frames_per_env
        size = cfg.loss.minibatch_size
        if size > batch:
            raise ValueError(
                f"loss.minibatch_size must be an integer in [1, {batch}] "
                "(env.num_envs * collector.frames_per_env, the collected batch), "
                f"got {size}."
            )


@_refusing
def validate_ddpg(cfg) -> None:
    """Refuses a DDPG config the recipe cannot run, before anything is built.

    The settings' ranges (:func:`check_settings` over :class:`DDPGConfig`), then
    the rules between settings.

    Raises:
        ConfigError: a ``ValueError`` naming the setting by its full key and the
            value expected.
    """
    check_settings(cfg, DDPGConfig)
    intrinsic, collector = cfg.intrinsic, cfg.collector
    if intrinsic.normalization == "e3b_std":
        raise ValueError(
            "intrinsic.normalization=e3b_std is E3B's statistic over batches of 8 "
            "trajectories of an on-policy learner: DDPG's replay samples have none. "
            "Pick reward_std, zscore, return_std or none."
        )
    if intrinsic.normalization == "return_std" and intrinsic.bonus_at == "sample":
        raise ValueError(
            "intrinsic.normalization=return_std needs whole trajectories (a time "
            "dimension) and replay samples are single transitions: use it with "
            "intrinsic.bonus_at=collection, or pick reward_std / zscore / none."
        )
    if collector.frames_per_batch % cfg.env.num_envs:
        raise ValueError(
            f"collector.frames_per_batch ({collector.frames_per_batch}) must be a "
            f"multiple of env.num_envs ({cfg.env.num_envs})."
        )
    # Whole batches only: a resumed run then stops exactly at total_frames.
    for name in ("total_frames", "init_random_frames"):
        if collector[name] % collector.frames_per_batch:
            raise ValueError(
                f"collector.{name} ({collector[name]}) must be a multiple of "
                f"collector.frames_per_batch ({collector.frames_per_batch})."
            )


_store = ConfigStore.instance()
_store.store(name="minigrid_schema", node=MiniGridConfig)
_store.store(name="ddpg_mujoco_schema", node=DDPGConfig)
