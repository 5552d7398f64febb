"""What the recipes share: run scaffolding and the MiniGrid builders.

Not part of the ``torchrl_surprise`` wheel: it is the plumbing of the recipes in
this directory (checkpoints and resume, signals, episode statistics, loggers and
learning curves in :mod:`common.run`; the MiniGrid recipe's env, model, bonus and
collector builders in :mod:`common.minigrid`). The recipes put ``recipes/`` on
``sys.path`` and import it as ``common``.
"""
