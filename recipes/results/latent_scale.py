"""The elliptical VAE bonus's scale: how long a run's posterior means are, and how
heavy-tailed its bonus, on the episodes of a uniformly random policy.

The elliptical bonus ``phi^T C^-1 phi`` (``intrinsic.vae.variant=elliptical``) is
``|phi|^2 / ridge`` at an episode's first state and grows with the latent's scale
elsewhere against the fixed ridge; a trained VAE and its untrained control can
then differ in scale as much as in what they encode. For each run (its checkpoint,
as :func:`results.heatmap.load_bonus_transform` rebuilds its transform), this
command encodes the same episodes (``--envs`` envs of the run's task and backend,
``--steps`` steps of a uniformly random policy, seeded ``--seed``), walks the
episodic memory over them as a training batch does, and writes one row per run
(its ``global_bonus`` and ``unit_latent`` named; the bonus is the episodic term
alone, without a ``global_bonus="kl"`` run's KL factor):

- ``mean_sq_norm``, ``max_sq_norm``: ``|mu|^2`` of the posterior means;
- ``first``: the mean bonus of an episode's first bonus-bearing state (the memory
  is empty there); ``other_mean``, ``other_p99``, ``tail``: the other states'
  mean bonus, 99th percentile and their ratio; ``first_share``: the first
  states' share of all the bonus;
- the same with ``unit_`` in front, for the posterior means at unit length
  (``intrinsic.vae.unit_latent``).

Usage::

    python recipes/results/latent_scale.py runs/ppo_minigrid/suite_keycorridor_s3r3/+setting=vae_elliptical,seed=* \\
        runs/ppo_minigrid/suite_keycorridor_s3r3/+setting=vae_elliptical_untrained,seed=* \\
        --out docs/results/latent_scale/keycorridor_s3r3.csv

``--from-data <csv>`` adds the runs to a table this command wrote earlier: runs
no longer on disk keep their rows, a run given again (the same path) replaces its
own, in its place.
"""

from __future__ import annotations

import sys
from collections.abc import Sequence
from pathlib import Path

import pandas as pd
import torch

from torchrl_surprise.transforms import VAEEllipticalTransform

# Run as a script: recipes/ holds the shared `common` and `results` packages.
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

__all__ = ["COLUMNS", "bonus_stats", "load_elliptical", "random_episodes", "run_scale"]

#: Columns of the output, per run.
COLUMNS = (
    "run",
    "setting",
    "seed",
    "frames",
    "global_bonus",
    "unit_latent",
    "mean_sq_norm",
    "max_sq_norm",
    "first",
    "other_mean",
    "other_p99",
    "tail",
    "first_share",
    "unit_first",
    "unit_other_mean",
    "unit_other_p99",
    "unit_tail",
    "unit_first_share",
)


def random_episodes(env_name: str, backend: str, envs: int, steps: int, seed: int):
    """``(image, direction, done)`` of a uniformly random policy's steps, each
    ``[envs, steps, ...]``: the ``("next", ...)`` entries a collector's batch holds."""
    from torchrl_surprise.envs import make_minigrid_env

    env = make_minigrid_env(env_name, num_envs=envs, backend=backend)
    env.set_seed(seed)
    torch.manual_seed(seed)
    rollout = env.rollout(steps, break_when_any_done=False)
    env.close()
    return (
        rollout["next", "image"],
        rollout["next", "direction"],
        rollout["next", "done"].reshape(envs, steps),
    )


def bonus_stats(bonus: torch.Tensor, done: torch.Tensor) -> dict[str, float]:
    """Scale and tail of a ``[envs, steps]`` bonus whose episodes end at ``done``.

    Examples:
        >>> bonus = torch.tensor([[10.0, 1.0, 1.0, 10.0, 1.0]])
        >>> done = torch.tensor([[False, False, True, False, False]])
        >>> stats = bonus_stats(bonus, done)
        >>> stats["first"], stats["other_mean"], stats["first_share"]
        (10.0, 1.0, 0.8696)
    """
    first = torch.zeros_like(done)
    first[:, 0] = True
    first[:, 1:] = done[:, :-1]
    other = bonus[~first].double()
    p99 = float(other.quantile(0.99))
    mean = float(other.mean())
    return {
        "first": round(float(bonus[first].double().mean()), 4),
        "other_mean": round(mean, 4),
        "other_p99": round(p99, 4),
        "tail": round(p99 / mean, 2) if mean > 0 else float("nan"),
        "first_share": round(
            float(bonus[first].double().sum() / bonus.double().sum()), 4
        ),
    }


def load_elliptical(run_dir: str | Path):
    """``(transform, config, frames)`` of a run whose bonus is the elliptical one.

    Raises:
        ValueError: the run's VAE bonus is another variant (naming it).
    """
    from results.heatmap import load_bonus_transform

    transform, config, frames = load_bonus_transform(run_dir)
    if not isinstance(transform, VAEEllipticalTransform):
        raise ValueError(
            f"{run_dir}: intrinsic.vae.variant is "
            f"{config['intrinsic']['vae'].get('variant')!r}; the latent's scale is "
            "measured for the elliptical bonus (variant 'elliptical')"
        )
    return transform, config, frames


def run_scale(run_dir: str | Path, loaded, episodes) -> dict:
    """One run's row of :data:`COLUMNS`: ``loaded`` from :func:`load_elliptical`,
    on ``episodes`` (:func:`random_episodes`)."""
    transform, config, frames = loaded
    image, direction, done = episodes
    envs, steps = done.shape
    with torch.no_grad():
        loc, _ = transform.vae.posterior(
            image.reshape(envs * steps, *image.shape[2:]),
            direction.reshape(envs * steps, *direction.shape[2:]),
        )
    loc = loc.reshape(envs, steps, -1)
    row = {
        "run": str(run_dir),
        "setting": config.get("setting") or "",
        "seed": config.get("seed"),
        "frames": frames,
        "global_bonus": transform.global_bonus,
        "unit_latent": transform.unit_latent,
        "mean_sq_norm": round(float(loc.pow(2).sum(-1).mean()), 4),
        "max_sq_norm": round(float(loc.pow(2).sum(-1).max()), 4),
    }
    for prefix, phi in (
        ("", loc),
        ("unit_", torch.nn.functional.normalize(loc, dim=-1)),
    ):
        transform.memory.reset()
        bonus = transform.memory.walk(phi, done, 1)
        row.update({prefix + k: v for k, v in bonus_stats(bonus, done).items()})
    return row


def main(argv: Sequence[str] | None = None) -> int:
    from common.labels import run_backend
    from results.run_tools import (
        checkpoint_parser,
        load_runs,
        merge_earlier,
        write_table,
    )

    parser = checkpoint_parser("latent_scale.py", __doc__, envs=8)
    parser.add_argument("--steps", type=int, default=600, help="steps per env")
    args = parser.parse_args(argv)
    torch.set_num_threads(1)
    loaded = load_runs(parser, args.runs, load_elliptical)
    episodes = {}
    rows = []
    for run, (_, config, _) in loaded.items():
        env = (config["env"]["name"], run_backend(config))
        if env not in episodes:
            episodes[env] = random_episodes(*env, args.envs, args.steps, args.seed)
        rows.append(run_scale(run, loaded[run], episodes[env]))
    table = pd.DataFrame(rows, columns=list(COLUMNS))
    write_table(merge_earlier(parser, table, args.from_data), args.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
