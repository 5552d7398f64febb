"""Run support shared by the recipes: seeding, checkpoints, episode stats, curves."""

from __future__ import annotations

import csv
import os
import random
from collections import deque
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch
from tensordict import TensorDictBase

__all__ = [
    "EpisodeStats",
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


def prepare_run(cfg, run_dir: str | os.PathLike) -> tuple[Path, dict[str, Any] | None]:
    """What every recipe does first: threads, seeds, resolved config, checkpoint.

    Sets ``torch.set_num_threads(cfg.torch_threads)``, seeds with ``cfg.seed``,
    writes ``config_resolved.yaml`` into ``run_dir`` and, with ``cfg.resume``,
    loads ``<run_dir>/checkpoint.pt`` (a clear error when there is none).

    Returns:
        ``(checkpoint_path, checkpoint or None)``.
    """
    from omegaconf import OmegaConf

    run_dir = Path(run_dir)
    ckpt_path = run_dir / "checkpoint.pt"
    torch.set_num_threads(cfg.torch_threads)
    seed_everything(cfg.seed)
    run_dir.mkdir(parents=True, exist_ok=True)
    (run_dir / "config_resolved.yaml").write_text(OmegaConf.to_yaml(cfg, resolve=True))
    if not cfg.resume:
        return ckpt_path, None
    if not ckpt_path.exists():
        raise FileNotFoundError(
            f"resume=true but there is no checkpoint at {ckpt_path}; pass the run "
            "directory of the run to resume as hydra.run.dir=<dir>."
        )
    return ckpt_path, load_checkpoint(ckpt_path)


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
