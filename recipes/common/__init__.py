"""What the recipes share: run scaffolding, typed configs, the MiniGrid builders.

Not part of the ``torchrl_surprise`` wheel: it is the plumbing of the recipes in
this directory (checkpoints, the run directory's lock and resume checks, signals,
episode statistics, loggers and learning curves, one module each, composed by
:class:`common.run.TrainingRun`; the bonus registry in :mod:`common.bonuses`; the
MiniGrid recipe's env, model, bonus and collector builders in
:mod:`common.minigrid`; the config schemas and their validation in
:mod:`common.config`). The recipes put ``recipes/`` on ``sys.path``
and import it as ``common``.
"""

# Stores the recipes' config schemas in Hydra's ConfigStore, where each config.yaml's
# defaults find them (minigrid_schema, ddpg_mujoco_schema).
from . import config  # noqa: F401
