"""Run support shared by the recipes: seeding, checkpoints, episode stats, curves."""

from __future__ import annotations

import copyreg
import csv
import importlib
import logging
import multiprocessing
import os
import random
import shutil
import signal
import sys
import types
from collections import deque
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any, NoReturn

import numpy as np
import torch
import torch.utils.deterministic
from tensordict import TensorDictBase


def _pickle_module_by_name(module: types.ModuleType):
    return importlib.import_module, (module.__name__,)


# Hydra's joblib and submitit launchers send the task function to their workers
# with cloudpickle, which pickles a script's function by value together with the
# torch submodules its code names; torch.utils.deterministic is a ModuleType
# subclass that cloudpickle cannot pickle, so it is pickled by name instead.
copyreg.pickle(type(torch.utils.deterministic), _pickle_module_by_name)

__all__ = [
    "BONUS_SECTIONS",
    "RESUMABLE_CHANGES",
    "RESUME_MODES",
    "Checkpointer",
    "EpisodeStats",
    "Progress",
    "RNGState",
    "StopSignal",
    "config_differences",
    "unused_bonus_sections",
    "find_scalar_log",
    "plot_scalar_logs",
    "resume_command",
    "truncate_scalar_logs",
    "evaluate_episodes",
    "get_run_logger",
    "get_rng_state",
    "load_checkpoint",
    "prepare_run",
    "plot_learning_curves",
    "read_scalar_csv",
    "save_checkpoint",
    "seed_everything",
    "set_rng_state",
]


def seed_everything(seed: int) -> None:
    """Seeds Python, NumPy and torch (all the generators a recipe draws from).

    Examples:
        >>> seed_everything(0); a = torch.rand(1)
        >>> seed_everything(0); bool((a == torch.rand(1)).all())
        True
    """
    random.seed(seed)
    np.random.seed(seed)
    torch.manual_seed(seed)


def get_rng_state() -> dict[str, Any]:
    """The state of the Python, NumPy and torch generators, for a checkpoint."""
    return {
        "python": random.getstate(),
        "numpy": np.random.get_state(),
        "torch": torch.get_rng_state(),
    }


def set_rng_state(state: Mapping[str, Any]) -> None:
    """Restores what :func:`get_rng_state` returned.

    Examples:
        >>> state = get_rng_state(); a = torch.rand(2)
        >>> set_rng_state(state); bool((a == torch.rand(2)).all())
        True
    """
    random.setstate(state["python"])
    np.random.set_state(state["numpy"])
    torch.set_rng_state(state["torch"])


def save_checkpoint(path: str | os.PathLike, state: Mapping[str, Any]) -> None:
    """Writes ``state`` with ``torch.save`` atomically (a kill never leaves half a file).

    Examples:
        >>> import tempfile, os
        >>> path = os.path.join(tempfile.mkdtemp(), "ckpt.pt")
        >>> save_checkpoint(path, {"frames": 128})
        >>> load_checkpoint(path)["frames"]
        128
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".tmp")
    torch.save(dict(state), tmp)
    os.replace(tmp, path)


def load_checkpoint(path: str | os.PathLike) -> dict[str, Any]:
    """Loads a checkpoint written by :func:`save_checkpoint`."""
    # Checkpoints hold RNG states (tuples, NumPy arrays): not weights-only.
    return torch.load(path, weights_only=False)


RESUMABLE_CHANGES: tuple[str, ...] = (
    "resume",
    "torch_threads",
    "collector.total_frames",
    "eval",
    "logger",
    "checkpoint",
)
"""Config entries (and sections) that may change when a run resumes.

They decide how long a run goes on and what it reports, not what it learns; any
other difference between the checkpoint's config and the resumed one is refused.
"""

RESUME_MODES: tuple[str, ...] = ("auto", "true", "false")
"""``resume``: ``auto`` continues from a checkpoint if there is one, else starts;
``true`` requires a checkpoint; ``false`` requires a run directory without one."""


def _resume_mode(value) -> str:
    mode = str(value).lower()
    if mode not in RESUME_MODES:
        raise ValueError(f"resume must be one of {RESUME_MODES}, got {value!r}.")
    return mode


def _flatten(config: Mapping[str, Any], prefix: str = "") -> dict[str, Any]:
    flat: dict[str, Any] = {}
    for key, value in config.items():
        name = f"{prefix}{key}"
        if isinstance(value, Mapping):
            flat.update(_flatten(value, name + "."))
        else:
            flat[name] = value
    return flat


BONUS_SECTIONS: tuple[str, ...] = ("vae", "icm", "rnd")
"""The sections under ``intrinsic`` that configure one bonus each."""


def unused_bonus_sections(config: Mapping[str, Any]) -> tuple[str, ...]:
    """The config sections a run with this config does not read: the whole
    ``intrinsic`` section when ``bonus`` is ``"none"``, else the ``intrinsic.<name>``
    sections of the other bonuses. A changed default there cannot change the run,
    so resuming it is safe.

    Examples:
        >>> unused_bonus_sections({"bonus": "icm", "intrinsic": {"vae": {}, "icm": {}}})
        ('intrinsic.vae',)
        >>> unused_bonus_sections({"bonus": "none", "intrinsic": {"coef": 0.5}})
        ('intrinsic',)
    """
    bonus = config.get("bonus")
    intrinsic = config.get("intrinsic")
    if bonus is None or not isinstance(intrinsic, Mapping):
        return ()
    if bonus == "none":
        return ("intrinsic",)
    return tuple(
        f"intrinsic.{name}"
        for name, value in intrinsic.items()
        if name in BONUS_SECTIONS and name != bonus and isinstance(value, Mapping)
    )


def config_differences(
    saved: Mapping[str, Any],
    current: Mapping[str, Any],
    allowed: Sequence[str] = RESUMABLE_CHANGES,
) -> list[str]:
    """The settings that differ between two configs, outside ``allowed``.

    A setting absent from ``saved`` is one that a newer version of the recipe
    added after the checkpoint was written; its default is meant to keep the old
    behaviour, so it is not counted (a setting that was removed is).

    Args:
        saved: the config a checkpoint was written under (nested mapping).
        current: the config of the run that would resume it.
        allowed: entries or whole sections (``"logger"``) that may differ.

    Returns:
        ``"name: saved -> current"`` for each differing setting, sorted.

    Examples:
        >>> config_differences({"env": {"name": "A"}, "logger": {"backend": "csv"}},
        ...                    {"env": {"name": "B"}, "logger": {"backend": ""}})
        ["env.name: 'A' -> 'B'"]
        >>> config_differences({"a": 1}, {"a": 1, "new": 2})
        []
    """
    old, new = _flatten(saved), _flatten(current)
    diffs = []
    for name in sorted(old):
        if any(name == a or name.startswith(a + ".") for a in allowed):
            continue
        before, after = old[name], new.get(name, "<absent>")
        if before != after:
            diffs.append(f"{name}: {before!r} -> {after!r}")
    return diffs


def truncate_scalar_logs(log_dir: str | os.PathLike, max_step: int) -> int:
    """Drops the rows of TorchRL ``CSVLogger`` scalar files logged after ``max_step``.

    A run killed after its checkpoint has logged steps that its resumed run logs
    again; cutting them at the checkpoint keeps each step logged once.

    Returns:
        The number of rows removed.
    """
    removed = 0
    for path in sorted(Path(log_dir).glob("**/scalars/**/*.csv")):
        rows = path.read_text().splitlines(keepends=True)
        kept = [
            r for r in rows if r.strip() and int(float(r.split(",")[0])) <= max_step
        ]
        if len(kept) != len(rows):
            removed += len(rows) - len(kept)
            tmp = path.with_name(path.name + ".tmp")
            tmp.write_text("".join(kept))
            os.replace(tmp, path)
    return removed


def prepare_run(cfg, run_dir: str | os.PathLike) -> tuple[Path, dict[str, Any] | None]:
    """What every recipe does first: threads, seeds, resume checks, resolved config.

    Sets ``torch.set_num_threads(cfg.torch_threads)`` and seeds with ``cfg.seed``.
    With ``cfg.resume`` ``auto`` (or ``true``) and a ``<run_dir>/checkpoint.pt``,
    loads it, refuses it if the experiment changed (:func:`config_differences`,
    naming each setting; the sections of bonuses the run does not use, from
    :func:`unused_bonus_sections`, may change), and cuts the CSV logs at the checkpoint's frame so each
    step stays logged once; without a checkpoint the run starts at frame 0, and the
    rows a run killed before its first checkpoint left in ``<run_dir>/logs`` go. ``resume=false`` refuses a directory that already holds
    a checkpoint, so that nothing computed is overwritten. Writes
    ``config_resolved.yaml`` once the checks pass.

    Returns:
        ``(checkpoint_path, checkpoint or None)``.
    """
    from omegaconf import OmegaConf

    run_dir = Path(run_dir)
    ckpt_path = run_dir / "checkpoint.pt"
    mode = _resume_mode(cfg.resume)
    torch.set_num_threads(cfg.torch_threads)
    seed_everything(cfg.seed)
    config = OmegaConf.to_container(cfg, resolve=True)
    ckpt = None
    if ckpt_path.exists():
        if mode == "false":
            raise FileExistsError(
                f"{run_dir} already holds a checkpoint: pass resume=auto to continue "
                "it, or another hydra.run.dir to start a new run."
            )
        ckpt = load_checkpoint(ckpt_path)
        diffs = config_differences(
            ckpt["config"],
            config,
            allowed=RESUMABLE_CHANGES + unused_bonus_sections(ckpt["config"]),
        )
        if diffs:
            raise ValueError(
                f"Cannot resume {run_dir}: the experiment changed ("
                + "; ".join(diffs)
                + "). Only these settings may change on resume: "
                + ", ".join(RESUMABLE_CHANGES)
                + ". Start a new run directory for a new experiment."
            )
        truncate_scalar_logs(run_dir / "logs", ckpt["frames"])
    elif mode == "true":
        raise FileNotFoundError(
            f"resume=true but there is no checkpoint at {ckpt_path}; pass the run "
            "directory of the run to resume as hydra.run.dir=<dir>."
        )
    else:
        # A run killed before its first checkpoint left rows that this run, which
        # starts from frame 0 with the same seed, logs again: drop them.
        truncate_scalar_logs(run_dir / "logs", -1)
    run_dir.mkdir(parents=True, exist_ok=True)
    (run_dir / "config_resolved.yaml").write_text(OmegaConf.to_yaml(config))
    return ckpt_path, ckpt


class Progress:
    """Counters of a run (frames, and the next frame to evaluate or checkpoint at).

    Examples:
        >>> p = Progress(frames=0, next_eval=100)
        >>> p.frames += 64
        >>> Progress(frames=0, next_eval=0).load_state_dict(p.state_dict())
    """

    def __init__(self, **counters: int):
        self.__dict__.update(counters)

    def state_dict(self) -> dict[str, int]:
        return dict(self.__dict__)

    def load_state_dict(self, state: Mapping[str, int]) -> None:
        self.__dict__.update(state)


class RNGState:
    """The Python, NumPy and torch generators as a checkpointable object."""

    def state_dict(self) -> dict[str, Any]:
        return get_rng_state()

    def load_state_dict(self, state: Mapping[str, Any]) -> None:
        set_rng_state(state)


class Checkpointer:
    """One mapping of what a run saves, used both to save and to load.

    Every value is an object with ``state_dict()`` / ``load_state_dict()``
    (modules, optimisers, transforms, collectors, :class:`Progress`,
    :class:`RNGState`); ``None`` entries are skipped. Loading follows the mapping's
    order, so put :class:`RNGState` last: building the run consumed random numbers.

    Args:
        path: the checkpoint file (written atomically).
        components: name -> object.
        config: the resolved run config, saved with the state so that a resume
            can refuse a changed experiment (:func:`prepare_run`).
        keep_dir: where :meth:`save_every` also keeps each periodic checkpoint,
            as ``checkpoint_<frames>.pt`` (points of training, for instance for
            the surprise heatmap); ``None`` (default) keeps only the latest.

    Examples:
        >>> import tempfile, os
        >>> net = torch.nn.Linear(2, 2); progress = Progress(frames=128)
        >>> path = os.path.join(tempfile.mkdtemp(), "ckpt.pt")
        >>> Checkpointer(path, {"net": net, "progress": progress}, config={}).save()
        >>> other = Progress(frames=0)
        >>> Checkpointer(path, {"net": torch.nn.Linear(2, 2), "progress": other},
        ...              config={}).load(load_checkpoint(path))
        >>> other.frames
        128
        >>> keep = os.path.join(os.path.dirname(path), "checkpoints")
        >>> progress.next_ckpt = 100
        >>> Checkpointer(path, {"progress": progress}, config={},
        ...              keep_dir=keep).save_every(100)
        >>> os.listdir(keep), progress.next_ckpt
        (['checkpoint_128.pt'], 200)
    """

    def __init__(
        self,
        path: str | os.PathLike,
        components: Mapping[str, Any],
        config: Mapping[str, Any],
        keep_dir: str | os.PathLike | None = None,
    ):
        self.path = Path(path)
        self.components = {k: v for k, v in components.items() if v is not None}
        self.config = config
        self.keep_dir = None if keep_dir is None else Path(keep_dir)

    def save(self) -> None:
        state = {name: obj.state_dict() for name, obj in self.components.items()}
        state["config"] = self.config
        # The frame count sits at the top level for tools that only read that.
        progress = self.components.get("progress")
        if progress is not None:
            state["frames"] = progress.frames
        save_checkpoint(self.path, state)

    def save_every(self, interval_frames: int) -> None:
        """Saves when the run's :class:`Progress` has passed ``next_ckpt`` frames,
        and moves ``next_ckpt`` on by ``interval_frames``."""
        progress = self.components["progress"]
        if progress.frames >= progress.next_ckpt:
            progress.next_ckpt += interval_frames
            self.save()
            if self.keep_dir is not None:
                # the same bytes: a copy of the file save() has just written
                self.keep_dir.mkdir(parents=True, exist_ok=True)
                kept = self.keep_dir / f"checkpoint_{progress.frames}.pt"
                shutil.copyfile(self.path, kept.with_name(kept.name + ".tmp"))
                os.replace(kept.with_name(kept.name + ".tmp"), kept)

    def load(self, state: Mapping[str, Any]) -> None:
        missing = [name for name in self.components if name not in state]
        if missing:
            raise KeyError(
                f"{self.path} holds no {missing}: it was written by another "
                "version of this recipe, or for another experiment."
            )
        for name, obj in self.components.items():
            obj.load_state_dict(state[name])


class StopSignal:
    """Turns SIGINT and SIGTERM into a request to stop after the current update.

    A training loop checks it once per iteration; when set, it saves a checkpoint
    and exits (a cluster scheduler sends SIGTERM before preemption; Ctrl-C sends
    SIGINT). A second SIGINT interrupts at once.

    Examples:
        >>> import os, signal
        >>> stop = StopSignal()
        >>> os.kill(os.getpid(), signal.SIGTERM)
        >>> bool(stop), stop.name
        (True, 'SIGTERM')
        >>> stop.restore()
    """

    def __init__(self, signals: Sequence[int] = (signal.SIGINT, signal.SIGTERM)):
        self.received: int | None = None
        self._previous = {sig: signal.signal(sig, self._handle) for sig in signals}

    def _handle(self, signum, frame) -> None:
        if self.received == signal.SIGINT and signum == signal.SIGINT:
            raise KeyboardInterrupt
        self.received = signum

    def __bool__(self) -> bool:
        return self.received is not None

    @property
    def name(self) -> str:
        return signal.Signals(self.received).name if self.received else ""

    def save_and_exit(
        self, checkpointer: Checkpointer, frames: int, run_dir, *closers
    ) -> None:
        """If a signal came: save, run ``closers`` (progress bar, collector), print
        one line on how to resume, and exit with status ``128 + signal``.

        In a launcher's worker process (the local joblib launcher), the exit is
        immediate (:func:`os._exit`), so that the worker starts no queued job."""
        if not self:
            return
        checkpointer.save()
        for close in closers:
            close()
        print(
            f"{self.name}: stopped at {frames} frames, checkpoint saved. "
            f"Resume with: {resume_command(run_dir)}"
        )
        _exit_process(128 + self.received)

    def restore(self) -> None:
        """Puts back the handlers that were installed before."""
        for sig, handler in self._previous.items():
            signal.signal(sig, handler)


def _exit_process(code: int) -> NoReturn:
    """Exits with ``code``, also from a launcher's worker process.

    In the main process this is :func:`sys.exit`. A worker of a process pool (the
    local joblib launcher's loky workers) catches :class:`SystemExit` as a job's
    error and goes on to the sweep's next job, even after the process that
    launched the sweep died of the same signal; so a worker flushes its output
    and ends at once with :func:`os._exit`. Files the run writes (checkpoints,
    CSV logs) are closed or flushed before this is called.
    """
    if multiprocessing.parent_process() is None:
        sys.exit(code)
    for stream in (sys.stdout, sys.stderr):
        stream.flush()
    logging.shutdown()
    os._exit(code)


def resume_command(run_dir: str | os.PathLike) -> str:
    """The command line that resumes the current Hydra run in ``run_dir``."""
    try:
        from hydra.core.hydra_config import HydraConfig

        overrides = [
            o
            for o in HydraConfig.get().overrides.task
            if not o.startswith(("resume=", "hydra.run.dir="))
        ]
    except (ImportError, ValueError):
        overrides = []
    args = [sys.argv[0], *overrides, f"hydra.run.dir={run_dir}", "resume=true"]
    return "python " + " ".join(args)


class EpisodeStats:
    """Finished-episode statistics from collected batches, with a moving window.

    Reads the episode return summed by TorchRL's ``RewardSum`` (extrinsic reward
    when the bonus is mixed in after collection) and the length from
    ``StepCounter``, at the transitions where ``("next", "done")`` is set.

    Args:
        window (int): number of recent episodes the moving mean covers.
        return_key (NestedKey): the episode-return key under ``"next"``.
        length_key (NestedKey): the episode step-count key under ``"next"``.
        success_threshold (float): an episode counts as a success when its
            return exceeds this (MiniGrid pays a positive reward only on success).

    Examples:
        >>> from tensordict import TensorDict
        >>> batch = TensorDict({"next": {
        ...     "done": torch.tensor([[False], [True]]),
        ...     "episode_reward": torch.tensor([[0.0], [0.9]]),
        ...     "step_count": torch.tensor([[1], [2]])}}, [2])
        >>> stats = EpisodeStats(window=10)
        >>> stats.update(batch)
        1
        >>> round(stats.mean_return, 3), stats.success_rate
        (0.9, 1.0)
    """

    def __init__(
        self,
        window: int = 100,
        return_key="episode_reward",
        length_key="step_count",
        success_threshold: float = 0.0,
    ):
        self.returns: deque[float] = deque(maxlen=window)
        self.lengths: deque[int] = deque(maxlen=window)
        self.return_key = return_key
        self.length_key = length_key
        self.success_threshold = success_threshold
        self.episodes = 0

    def update(self, batch: TensorDictBase) -> int:
        """Adds the episodes that end in ``batch``; returns how many ended."""
        done = batch.get(("next", "done")).reshape(-1)
        if not done.any():
            return 0
        returns = batch.get(("next", self.return_key)).reshape(-1)[done]
        lengths = batch.get(("next", self.length_key)).reshape(-1)[done]
        self.returns.extend(returns.tolist())
        self.lengths.extend(lengths.tolist())
        self.episodes += int(done.sum())
        return int(done.sum())

    @property
    def mean_return(self) -> float:
        return float(np.mean(self.returns)) if self.returns else float("nan")

    @property
    def mean_length(self) -> float:
        return float(np.mean(self.lengths)) if self.lengths else float("nan")

    @property
    def success_rate(self) -> float:
        if not self.returns:
            return float("nan")
        return float(np.mean([r > self.success_threshold for r in self.returns]))

    def state_dict(self) -> dict[str, Any]:
        return {
            "returns": list(self.returns),
            "lengths": list(self.lengths),
            "episodes": self.episodes,
        }

    def load_state_dict(self, state: Mapping[str, Any]) -> None:
        self.returns.clear()
        self.returns.extend(state["returns"])
        self.lengths.clear()
        self.lengths.extend(state["lengths"])
        self.episodes = state["episodes"]


def get_run_logger(
    backend: str, run_dir: str | os.PathLike, experiment_name: str, project: str
):
    """A TorchRL logger writing under ``<run_dir>/logs`` (``None`` for ``""``).

    Args:
        backend (str): ``"csv"``, ``"tensorboard"``, ``"wandb"``, ``"mlflow"`` or ``""``.
        run_dir: the run directory.
        experiment_name (str): the experiment's name (its folder for CSV).
        project (str): the W&B project (ignored by the other backends).
    """
    from torchrl.record.loggers import get_logger

    extra = {"project": project} if backend == "wandb" else {}
    return get_logger(
        backend,
        logger_name=str(Path(run_dir) / "logs"),
        experiment_name=experiment_name,
        **extra,
    )


def evaluate_episodes(
    env,
    policy,
    episodes: int,
    *,
    seed: int,
    deterministic: bool = True,
    chunk: int = 256,
    max_chunks: int = 100,
) -> list[float]:
    """Returns of the first ``episodes`` episodes that end, under ``torch.no_grad()``.

    The env is reseeded with ``seed`` first, so every evaluation sees the same
    episodes. It must sum the episode return under ``("next", "episode_reward")``
    (TorchRL's ``RewardSum``, placed before any bonus so the return is extrinsic).

    Args:
        env: a (batched) TorchRL env.
        policy: the policy to evaluate.
        episodes (int): how many finished episodes to return.
        seed (int): the evaluation seed.
        deterministic (bool): ``ExplorationType.DETERMINISTIC`` or ``RANDOM``.
        chunk (int): steps per rollout call; ``max_chunks`` bounds the total.
    """
    from torchrl.envs.utils import ExplorationType, set_exploration_type, step_mdp

    env.set_seed(seed)
    mode = ExplorationType.DETERMINISTIC if deterministic else ExplorationType.RANDOM
    returns: list[float] = []
    state = env.reset()
    with torch.no_grad(), set_exploration_type(mode):
        for _ in range(max_chunks):
            rollout = env.rollout(
                chunk,
                policy,
                auto_reset=False,
                tensordict=state,
                break_when_any_done=False,
            )
            done = rollout["next", "done"].squeeze(-1)
            returns += rollout["next", "episode_reward"].squeeze(-1)[done].tolist()
            state = step_mdp(rollout[..., -1])
            if len(returns) >= episodes:
                break
    return returns[:episodes]


def read_scalar_csv(path: str | os.PathLike) -> tuple[np.ndarray, np.ndarray]:
    """Reads one scalar file of TorchRL's ``CSVLogger`` (rows ``step,value``).

    When a resumed run logged a step again, the last value of that step is kept.
    """
    values: dict[int, float] = {}
    with open(path) as f:
        for row in csv.reader(f):
            if len(row) >= 2:
                values[int(float(row[0]))] = float(row[1])
    steps = np.array(sorted(values), dtype=np.int64)
    return steps, np.array([values[s] for s in steps], dtype=np.float64)


def plot_learning_curves(
    curves: Mapping[str, tuple[Sequence[float], Sequence[float]]],
    path: str | os.PathLike,
    *,
    title: str = "",
    xlabel: str = "frames",
    ylabel: str = "return",
) -> Path:
    """Plots named ``(x, y)`` curves into a PNG with matplotlib's Agg backend.

    Examples:
        >>> import tempfile, os
        >>> out = plot_learning_curves({"a": ([0, 1], [0.0, 1.0])},
        ...                            os.path.join(tempfile.mkdtemp(), "c.png"))
        >>> out.exists()
        True
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 4))
    for name, (x, y) in curves.items():
        ax.plot(x, y, label=name, marker="." if len(x) < 50 else None)
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    if title:
        ax.set_title(title)
    if len(curves) > 1:
        ax.legend()
    ax.grid(alpha=0.3)
    fig.tight_layout()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path


def find_scalar_log(log_dir: str | os.PathLike, name: str) -> Path:
    """The CSV file of scalar ``name`` (e.g. ``"train/episode_return"``) under a run's
    ``logs`` directory, whatever the experiment folder TorchRL's ``CSVLogger`` made."""
    matches = sorted(Path(log_dir).glob(f"*/scalars/{name}.csv"))
    if not matches:
        raise FileNotFoundError(f"no scalar log {name!r} under {log_dir}")
    return matches[0]


def plot_scalar_logs(
    log_dir: str | os.PathLike,
    name: str,
    path: str | os.PathLike,
    *,
    label: str = "",
    title: str = "",
    ylabel: str = "",
) -> Path | None:
    """Plots one logged scalar against frames, read back from the run's CSV logs.

    Returns ``None`` (and draws nothing) when the run logged no such scalar, for
    instance with ``logger.backend=`` (no logger).
    """
    try:
        steps, values = read_scalar_csv(find_scalar_log(log_dir, name))
    except FileNotFoundError:
        return None
    return plot_learning_curves(
        {label or name: (steps, values)},
        path,
        title=title,
        ylabel=ylabel or name,
    )
