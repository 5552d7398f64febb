"""Run support for the recipes: checkpoints, resume, episode statistics, sweeps.

This subpackage is the plumbing of a training run, not something composed into a
TorchRL pipeline: the core of :mod:`torchrl_surprise` (modules, transforms,
objectives, envs) never imports it, and it may import recipe tooling (OmegaConf,
matplotlib, rliable) where a function needs it.
"""

from torchrl_surprise.experiments.run import (
    EpisodeStats,
    evaluate_episodes,
    get_rng_state,
    get_run_logger,
    load_checkpoint,
    plot_learning_curves,
    prepare_run,
    read_scalar_csv,
    save_checkpoint,
    seed_everything,
    set_rng_state,
)

__all__ = [
    "EpisodeStats",
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
]
