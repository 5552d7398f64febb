"""What identifies a run in a sweep: its task (an env id and the backend it ran
on), its setting and its seed.

The run writes them to its ``status.json`` (:func:`common.status.write_run_status`)
and the aggregation groups runs by them (``results.aggregate``): one definition,
light enough for the training process (no pandas).
"""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

__all__ = [
    "GYMNASIUM",
    "LEVEL_KEY",
    "split_level",
    "add_label_keys",
    "add_label_keys_argument",
    "read_overrides",
    "run_backend",
    "run_labels",
    "setting_label",
    "task_name",
]

#: The override that names a run's noise level in its setting label.
LEVEL_KEY = "env.stochasticity"
# Overrides that name the run (which seed, which task, which sweep) or how it ran
# (Hydra, threads, the device), not what was trained: they are left out of a
# setting's label.
_NOT_SETTING = {
    "seed",
    "device",
    "env.name",
    "env.backend",
    "experiment",
    "experiment_name",
    "resume",
    "resume_without_logs",
    "torch_threads",
}
# Sections whose overrides change what a run reports or how it saves (they may
# change on resume, common.rundir.RESUMABLE_CHANGES), not what it learns.
_NOT_SETTING_SECTIONS = ("hydra", "logger", "eval", "checkpoint")

#: The backend of minigrid's Python envs (and of MuJoCo's gymnasium envs).
GYMNASIUM = "gymnasium"


def run_backend(config: Mapping) -> str:
    """Where a run stepped its env: the config's ``env.backend``.

    envpool's MiniGrid is the same task with its own layouts for a seed, so its
    runs are never pooled with minigrid's runs of the env id: a task is the pair
    (env id, backend), normalised by the oracle over that backend's layouts.

    Examples:
        >>> run_backend({"env": {"name": "MiniGrid-DoorKey-8x8-v0", "backend": "envpool"}})
        'envpool'
        >>> run_backend({"env": {"name": "MiniGrid-DoorKey-8x8-v0"}})
        'gymnasium'
    """
    backend = (config.get("env") or {}).get("backend")
    # A config written before env.backend existed: its run used minigrid's Python
    # envs (MuJoCo's recipe has no other backend).
    return GYMNASIUM if backend is None else str(backend)


def task_name(task: str, backend: str) -> str:
    """How a text or a figure names a task: the env id, followed by its backend
    in parentheses when that is not :data:`GYMNASIUM`.

    Examples:
        >>> task_name("MiniGrid-DoorKey-8x8-v0", "gymnasium")
        'MiniGrid-DoorKey-8x8-v0'
        >>> task_name("MiniGrid-DoorKey-8x8-v0", "envpool")
        'MiniGrid-DoorKey-8x8-v0 (envpool)'
    """
    return task if backend == GYMNASIUM else f"{task} ({backend})"


def setting_label(config: Mapping, overrides: Sequence[str] | None) -> str:
    """The label of a run's setting: what tells it apart from the other runs.

    The config's top-level ``setting`` when it is a non-empty string (followed by
    ``,env.stochasticity=L`` for a run at a noise level ``L`` other than 0: the
    same setting at another level is another point of Figure 2); else the
    Hydra overrides minus those naming the run or how it ran (``seed``,
    ``env.name``, ``+experiment``, ``experiment_name``, ``resume``, ``resume_without_logs``,
    ``torch_threads``, ``device``, ``hydra.*``) and those of what it reports or how
    it saves (``logger.*``, ``eval.*``, ``checkpoint.*``), sorted and joined with
    ``,``; else the config's ``bonus``.

    Args:
        config (Mapping): the run's resolved config.
        overrides (Sequence[str] | None): the strings of ``.hydra/overrides.yaml``,
            or ``None`` when the run has none.

    Examples:
        >>> setting_label({"bonus": "vae"}, ["seed=1", "intrinsic.coef=0.1",
        ...     "bonus=vae", "+experiment=n3s4", "hydra.run.dir=x", "resume=true"])
        'bonus=vae,intrinsic.coef=0.1'
        >>> setting_label({"bonus": "vae"}, ["seed=1", "env.name=MiniGrid-Empty-5x5-v0"])
        'vae'
        >>> setting_label({"bonus": "vae"}, ["logger.backend=csv", "eval.episodes=5",
        ...     "checkpoint.keep=true", "torch_threads=2"])
        'vae'
        >>> setting_label({"bonus": "vae"}, ["device=cuda", "bonus=vae"])
        'bonus=vae'
        >>> setting_label({"bonus": "vae", "setting": "vae_zscore"}, ["bonus=vae"])
        'vae_zscore'
        >>> setting_label({"setting": "icm", "env": {"stochasticity": 2}}, None)
        'icm,env.stochasticity=2'
    """
    setting = config.get("setting")
    if isinstance(setting, str) and setting:
        level = (config.get("env") or {}).get("stochasticity") or 0
        return f"{setting},{LEVEL_KEY}={level}" if level else setting
    kept = []
    for override in overrides or ():
        key = override.split("=", 1)[0].lstrip("+~")
        section = key.split(".", 1)[0].split("/", 1)[0]
        if key in _NOT_SETTING or section in _NOT_SETTING_SECTIONS:
            continue
        kept.append(override)
    if kept:
        return ",".join(sorted(kept))
    return str(config.get("bonus", "default"))


def read_overrides(run_dir: str | os.PathLike) -> list[str] | None:
    """The Hydra overrides of the run in ``run_dir`` (``.hydra/overrides.yaml``),
    or ``None`` when it has none (not started by Hydra).

    Examples:
        >>> import tempfile
        >>> read_overrides(tempfile.mkdtemp()) is None
        True
    """
    path = Path(run_dir) / ".hydra" / "overrides.yaml"
    if not path.is_file():
        return None
    from omegaconf import OmegaConf

    return [str(o) for o in OmegaConf.load(path)]


def run_labels(config: Mapping, run_dir: str | os.PathLike) -> dict[str, Any]:
    """What identifies the run in ``run_dir`` with config ``config``: its
    ``task`` (``env.name``, the env id), ``backend`` (:func:`run_backend`),
    ``seed`` and ``setting`` (:func:`setting_label` of its overrides,
    :func:`read_overrides`).

    Examples:
        >>> import tempfile
        >>> config = {"env": {"name": "MiniGrid-Empty-5x5-v0", "backend": "envpool"},
        ...           "seed": 3, "bonus": "vae"}
        >>> run_labels(config, tempfile.mkdtemp())
        {'task': 'MiniGrid-Empty-5x5-v0', 'backend': 'envpool', 'seed': 3, 'setting': 'vae'}
    """
    return {
        "task": str((config.get("env") or {}).get("name")),
        "backend": run_backend(config),
        "seed": config.get("seed"),
        "setting": setting_label(config, read_overrides(run_dir)),
    }


def add_label_keys(
    setting: str, config: Mapping, keys: Sequence[str], source: str
) -> str:
    """``setting`` followed by ``,KEY=value`` for each dotted key of ``keys``
    whose entry it does not already hold, the value read from the run's resolved
    ``config``: what ``--label-keys`` adds so that runs of one named setting
    that differ in a hyperparameter are told apart.

    Args:
        setting (str): the run's label (:func:`setting_label`).
        config (Mapping): the run's resolved config.
        keys (Sequence[str]): dotted keys of single values (``env.num_envs``).
        source (str): where ``config`` was read, named in an error.

    Raises:
        ValueError: ``config`` has no such key, or its value is a dict or a
            list, not a single value.

    Examples:
        >>> config = {"setting": "noveld", "loss": {"entropy_coef": 0.03}}
        >>> add_label_keys("noveld", config, ["loss.entropy_coef"], "run/config")
        'noveld,loss.entropy_coef=0.03'
        >>> add_label_keys("noveld,loss.entropy_coef=0.03", config,
        ...                ["loss.entropy_coef"], "run/config")
        'noveld,loss.entropy_coef=0.03'
    """
    hint = "--label-keys takes dotted keys of the runs' resolved config"
    for key in keys:
        value: Any = config
        for part in key.split("."):
            if not isinstance(value, Mapping) or part not in value:
                raise ValueError(f"{source} has no {key!r} ({hint}, e.g. env.num_envs)")
            value = value[part]
        if isinstance(value, (Mapping, list, tuple)):
            kind = "dict" if isinstance(value, Mapping) else "list"
            raise ValueError(
                f"{source}: {key!r} is a {kind}, not a value (--label-keys "
                "takes keys of single values, e.g. env.num_envs)"
            )
        entry = f"{key}={value}"
        if entry not in setting.split(","):  # a label of overrides may hold it
            setting += f",{entry}"
    return setting


def add_label_keys_argument(parser, note: str = "") -> None:
    """Adds ``--label-keys KEY [KEY ...]`` (``args.label_keys``, default ``()``)
    to the ``argparse`` parser of a tool that labels runs, the keys for
    :func:`add_label_keys`; ``note`` ends its help.

    Examples:
        >>> import argparse
        >>> parser = argparse.ArgumentParser()
        >>> add_label_keys_argument(parser)
        >>> parser.parse_args(["--label-keys", "env.num_envs"]).label_keys
        ['env.num_envs']
        >>> parser.parse_args([]).label_keys
        ()
    """
    parser.add_argument(
        "--label-keys",
        nargs="+",
        default=(),
        metavar="KEY",
        help="dotted config keys whose values join each run's setting label "
        "(',KEY=value'), to tell apart runs of one setting that differ in them" + note,
    )


def split_level(setting: str) -> tuple[str, int]:
    """A setting label's base setting and noise level (0 when it names none).

    The level is the label's ``env.stochasticity=L`` entry wherever it stands (a
    label made of overrides sorts it among them).

    Examples:
        >>> split_level("icm,env.stochasticity=2"), split_level("icm")
        (('icm', 2), ('icm', 0))
        >>> split_level("bonus=vae,env.stochasticity=3,intrinsic.coef=0.1")
        ('bonus=vae,intrinsic.coef=0.1', 3)
    """
    entries = setting.split(",")
    prefix = f"{LEVEL_KEY}="
    levels = [e for e in entries if e.startswith(prefix)]
    if not levels:
        return setting, 0
    base = ",".join(e for e in entries if not e.startswith(prefix))
    return base, int(levels[0][len(prefix) :])
