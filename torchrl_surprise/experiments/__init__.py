"""Run support for the recipes: checkpoints, resume, episode statistics, sweeps.

This subpackage is the plumbing of a training run, not something composed into a
TorchRL pipeline: the core of :mod:`torchrl_surprise` (modules, transforms,
objectives, envs) never imports it, and it may import recipe tooling (OmegaConf,
matplotlib, rliable) where a function needs it.

The aggregation of a sweep's runs (IQM, bootstrap CIs, thresholds, curves) is the
command ``python -m torchrl_surprise.experiments.aggregate``
(:mod:`torchrl_surprise.experiments.aggregate`).
"""

from torchrl_surprise.experiments.collector import (
    ResumableCollector,
    ResumableMultiSyncCollector,
    worker_seed,
)
from torchrl_surprise.experiments.run import (
    BONUS_SECTIONS,
    RESUMABLE_CHANGES,
    RESUME_MODES,
    Checkpointer,
    EpisodeStats,
    Progress,
    RNGState,
    StopSignal,
    config_differences,
    evaluate_episodes,
    find_scalar_log,
    get_rng_state,
    get_run_logger,
    load_checkpoint,
    plot_learning_curves,
    plot_scalar_logs,
    prepare_run,
    read_scalar_csv,
    resume_command,
    save_checkpoint,
    seed_everything,
    set_rng_state,
    truncate_scalar_logs,
    unused_bonus_sections,
)

__all__ = [
    "BONUS_SECTIONS",
    "RESUMABLE_CHANGES",
    "RESUME_MODES",
    "Checkpointer",
    "EpisodeStats",
    "Progress",
    "RNGState",
    "ResumableCollector",
    "ResumableMultiSyncCollector",
    "StopSignal",
    "config_differences",
    "unused_bonus_sections",
    "find_scalar_log",
    "plot_scalar_logs",
    "resume_command",
    "truncate_scalar_logs",
    "evaluate_episodes",
    "get_rng_state",
    "get_run_logger",
    "load_checkpoint",
    "plot_learning_curves",
    "prepare_run",
    "read_scalar_csv",
    "save_checkpoint",
    "seed_everything",
    "set_rng_state",
    "worker_seed",
]
