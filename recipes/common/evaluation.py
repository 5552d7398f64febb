"""Episode statistics, the evaluation of a policy, and the learning curve."""

from __future__ import annotations

import os
from collections import deque
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np
import torch
from tensordict import TensorDictBase

from .scalar_logs import find_scalar_log, read_scalar_csv

__all__ = [
    "CURVE_NAME",
    "EVAL_SEED_OFFSET",
    "EpisodeStats",
    "Evaluation",
    "evaluate",
    "plot_learning_curves",
    "plot_run_curves",
    "run_curve_text",
]

CURVE_NAME = "learning_curve.png"
"""The learning curve a run draws when it ends, in its run directory."""


class EpisodeStats:
    """Finished-episode statistics from collected batches, with a moving window.

    Reads the episode return summed by TorchRL's ``RewardSum`` (extrinsic reward
    when the bonus is mixed in after collection) and the length from
    ``StepCounter``, at the transitions where ``("next", "done")`` is set.
    Written here because TorchRL reads finished episodes batch by batch (its
    sota scripts log the mean of ``episode_reward[done]``), with no window that
    spans batches and resumes from a checkpoint.

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


EVAL_SEED_OFFSET = 10_000
"""The evaluation envs are seeded ``seed + EVAL_SEED_OFFSET``: other episodes than
the training envs' with the same ``seed``."""


class Evaluation(NamedTuple):
    """The extrinsic returns of the episodes an evaluation ran.

    Examples:
        >>> result = Evaluation([0.0, 0.5, 1.0, 0.0])
        >>> result.mean_return, result.success_rate
        (0.375, 0.5)
    """

    returns: list[float]

    @property
    def mean_return(self) -> float:
        """The mean return (0 when no episode ended)."""
        return sum(self.returns) / max(len(self.returns), 1)

    @property
    def success_rate(self) -> float:
        """The fraction of episodes with a positive return (MiniGrid pays a
        positive reward only on success)."""
        return sum(r > 0 for r in self.returns) / max(len(self.returns), 1)


def evaluate(
    env,
    policy,
    episodes: int,
    *,
    seed: int,
    deterministic: bool = True,
    chunk: int = 256,
    max_chunks: int = 100,
) -> Evaluation:
    """Runs ``policy`` until ``episodes`` episodes end, under ``torch.no_grad()``.

    The env is reseeded with ``seed`` first, so every evaluation sees the same
    episodes. It must sum the episode return under ``("next", "episode_reward")``
    (TorchRL's ``RewardSum``, placed before any bonus so the return is extrinsic).

    Args:
        env: a (batched) TorchRL env.
        policy: the policy to evaluate.
        episodes (int): how many finished episodes to return.
        seed (int): the evaluation seed (the run's ``seed + EVAL_SEED_OFFSET``).
        deterministic (bool): ``ExplorationType.DETERMINISTIC`` or ``RANDOM``.
        chunk (int): steps per rollout call; ``max_chunks`` bounds the total.

    Returns:
        The returns of the first ``episodes`` episodes that ended.
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
    return Evaluation(returns[:episodes])


def plot_learning_curves(
    curves: Mapping[str, tuple[Sequence[float], Sequence[float]]],
    path: str | os.PathLike,
    *,
    title: str = "",
    xlabel: str = "frames",
    ylabel: str = "return",
    optimum: tuple[str, float] | None = None,
) -> Path:
    """Plots named ``(x, y)`` curves into a PNG with matplotlib's Agg backend.

    ``optimum``, ``(label, value)``: a dashed horizontal line at ``value``, the
    best return of the task (the MiniGrid oracle's), named in the legend.

    Examples:
        >>> import tempfile, os
        >>> out = plot_learning_curves({"a": ([0, 1], [0.0, 1.0])},
        ...                            os.path.join(tempfile.mkdtemp(), "c.png"),
        ...                            optimum=("oracle", 0.8))
        >>> out.exists()
        True
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 4))
    for name, (x, y) in curves.items():
        ax.plot(x, y, label=name, marker="." if len(x) < 50 else None)
    if optimum is not None:
        ax.axhline(optimum[1], color="0.3", linestyle="--", label=optimum[0])
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    if title:
        ax.set_title(title)
    if len(curves) + (optimum is not None) > 1:
        ax.legend()
    ax.grid(alpha=0.3)
    fig.tight_layout()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path


def plot_run_curves(
    log_dir: str | os.PathLike,
    curves: Mapping[str, str],
    path: str | os.PathLike,
    *,
    title: str = "",
    ylabel: str = "",
    optimum: tuple[str, float] | None = None,
) -> Path | None:
    """Plots logged scalars against frames, read back from the run's CSV logs.

    Every backend but ``logger.backend=`` (none) leaves them: TorchRL's
    ``CSVLogger``, or the copy :class:`common.scalar_logs.ScalarCSVWriter` keeps
    beside TensorBoard, W&B and MLflow.

    Args:
        log_dir: the run's ``logs`` directory.
        curves: scalar name (``"train/episode_return"``) -> its label.
        path: the PNG to write.
        optimum: ``(label, value)``, a dashed line (:func:`plot_learning_curves`).

    Returns:
        ``path``, or ``None`` (nothing drawn) when the run logged none of the
        scalars, for instance with ``logger.backend=`` (no logger). Points with
        no value yet (NaN before the first episode ends) are left out.
    """
    data = {}
    for name, label in curves.items():
        try:
            steps, values = read_scalar_csv(find_scalar_log(log_dir, name))
        except FileNotFoundError:
            continue
        finite = np.isfinite(values)
        data[label] = (steps[finite], values[finite])
    if not data:
        return None
    return plot_learning_curves(data, path, title=title, ylabel=ylabel, optimum=optimum)


def run_curve_text(curve: Path | None, backend: str, curves: Mapping[str, str]) -> str:
    """What a run's end says of its learning curve: its path, or why none was
    drawn (:func:`plot_run_curves` gave ``None``).

    Examples:
        >>> run_curve_text(None, "", {"train/x": "x"})
        "none (logger.backend='' logs no scalars)"
        >>> run_curve_text(None, "csv", {"train/x": "x"})
        'none (no finite value of train/x was logged)'
    """
    if curve is not None:
        return str(curve)
    if backend == "":
        return "none (logger.backend='' logs no scalars)"
    return f"none (no finite value of {', '.join(curves) or 'any scalar'} was logged)"
