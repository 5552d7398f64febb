"""How far into a MiniGrid task a run's final policy gets: the share of its
episodes in which the agent carries a ball, a key or a box, opens a door, succeeds.

A return of 0 says a policy never finishes a task, not how close it came. On the
suite's object tasks (ObstructedMaze: move the ball that blocks the door, open the
box, take the key, unlock the door, fetch the ball behind it; KeyCorridor, DoorKey)
each step of the chain shows in the agent's own view, so the episodes of a final
policy say how far it gets. For each run (its checkpoint's policy, rebuilt as the
recipe built it), this command plays ``--envs`` envs of the run's task and backend
for ``--steps`` steps (actions sampled from the policy, as in training; envs seeded
``--seed``), and over the episodes that end within them writes one row per run:

- ``episodes``: how many ended (episodes still running at the last step are left
  out; ``--steps`` should hold a few of the task's ``max_steps``);
- ``carried_ball``, ``carried_key``, ``carried_box``: the share in which the agent
  held one at some step (MiniGrid draws the carried object in the agent's cell of
  its view);
- ``opened_door``: the share in which an open door came into view. The suite's
  tasks start with every door closed or locked, so an open door is one the agent
  opened;
- ``success``: the share that ended with a positive reward (MiniGrid rewards only
  reaching the goal).

Usage::

    python recipes/results/milestones.py runs/ppo_minigrid/suite_obstructedmaze_1dlhb/+setting=*,seed=* \\
        --out docs/results/milestones/obstructedmaze_1dlhb.csv
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path

import pandas as pd
import torch

# recipes/ holds what the recipes share (common), which rebuilds a run's policy
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

__all__ = [
    "COLUMNS",
    "MILESTONES",
    "episode_milestones",
    "load_policy",
    "policy_episodes",
    "run_milestones",
]

#: MiniGrid's object indices (``minigrid.core.constants.OBJECT_TO_IDX``) and its
#: door state for an open door (``STATE_TO_IDX["open"]``).
_DOOR, _KEY, _BALL, _BOX, _OPEN = 4, 5, 6, 7, 0

#: The milestones, in the order of the output's columns.
MILESTONES = ("carried_ball", "carried_key", "carried_box", "opened_door", "success")

#: Columns of the output, per run.
COLUMNS = ("run", "setting", "seed", "frames", "episodes", *MILESTONES)


def episode_milestones(
    image: torch.Tensor, reward: torch.Tensor, done: torch.Tensor
) -> pd.DataFrame:
    """One row per episode that ends within ``[envs, steps]`` observations, a
    column per milestone (:data:`MILESTONES`, booleans).

    Args:
        image: ``[envs, steps, 7, 7, 3]``, the egocentric views after each step
            (the ``("next", "image")`` of a rollout; the agent at ``(3, 6)``).
        reward: ``[envs, steps]``, the reward of each step.
        done: ``[envs, steps]``, whether the episode ended at that step.

    Examples:
        >>> image = torch.zeros(1, 4, 7, 7, 3, dtype=torch.uint8)
        >>> image[0, 1, 3, 6, 0] = 5  # carries a key at step 1
        >>> image[0, 3, 2, 2] = torch.tensor([4, 0, 0])  # an open door, step 3
        >>> done = torch.tensor([[False, True, False, True]])
        >>> reward = torch.tensor([[0.0, 0.0, 0.0, 0.5]])
        >>> episode_milestones(image, reward, done).astype(int).to_dict("list")
        ... # doctest: +NORMALIZE_WHITESPACE
        {'carried_ball': [0, 0], 'carried_key': [1, 0], 'carried_box': [0, 0],
         'opened_door': [0, 1], 'success': [0, 1]}
    """
    if image.dim() != 5 or image.shape[-3:] != (7, 7, 3):
        raise ValueError(
            "image must be [envs, steps, 7, 7, 3] (MiniGrid's egocentric view, "
            f"encoded), got {tuple(image.shape)}"
        )
    envs, steps = image.shape[:2]
    reward = reward.reshape(envs, steps)
    done = done.reshape(envs, steps).bool()
    carried = image[..., 3, 6, 0]
    seen = image.flatten(2, 3)  # [envs, steps, 49, 3]
    open_door = ((seen[..., 0] == _DOOR) & (seen[..., 2] == _OPEN)).any(-1)
    per_step = {
        "carried_ball": carried == _BALL,
        "carried_key": carried == _KEY,
        "carried_box": carried == _BOX,
        "opened_door": open_door,
        "success": reward > 0,
    }
    rows = []
    for env in range(envs):
        start = 0
        for end in done[env].nonzero().flatten().tolist():
            rows.append(
                {k: bool(v[env, start : end + 1].any()) for k, v in per_step.items()}
            )
            start = end + 1
    return pd.DataFrame(rows, columns=list(MILESTONES), dtype=bool)


def load_policy(run_dir: str | Path):
    """``(policy, config, frames)`` of a MiniGrid run's checkpoint: the recipe's
    actor (:func:`common.minigrid.make_actor_critic`) with the saved weights.

    Raises:
        FileNotFoundError: no checkpoint there.
        ValueError: the checkpoint is not a MiniGrid recipe's (no ``"model"``, or
            its config has no MiniGrid env).
    """
    from torchrl.data import Categorical

    from common.minigrid import make_actor_critic
    from common.run import find_checkpoint, load_checkpoint

    path = find_checkpoint(Path(run_dir))
    ckpt = load_checkpoint(path)
    config = ckpt.get("config") or {}
    env_name = (config.get("env") or {}).get("name", "")
    if "model" not in ckpt or not str(env_name).startswith("MiniGrid-"):
        raise ValueError(
            f"{path}: expected a MiniGrid recipe's checkpoint (a 'model' and a "
            f"MiniGrid env.name), got env.name {env_name!r} and components "
            f"{sorted(k for k in ckpt if k not in ('config', 'frames'))}"
        )
    # every MiniGrid env has the same 7 actions (left, right, forward, pickup,
    # drop, toggle, done)
    model, _ = make_actor_critic(Categorical(7), intrinsic_critic=False)
    model.load_state_dict(ckpt["model"])
    model.eval()
    return model.get_policy_operator(), config, ckpt.get("frames")


def policy_episodes(policy, config: dict, envs: int, steps: int, seed: int):
    """``(image, reward, done)`` of ``envs`` envs of the run's task and backend,
    ``steps`` steps of ``policy`` (sampled actions), each ``[envs, steps, ...]``."""
    from tensordict.nn import InteractionType, set_interaction_type

    from torchrl_surprise.envs import make_minigrid_env

    env_cfg = config["env"]
    env = make_minigrid_env(
        env_cfg["name"], num_envs=envs, backend=env_cfg.get("backend", "gymnasium")
    )
    env.set_seed(seed)
    torch.manual_seed(seed)
    with torch.no_grad(), set_interaction_type(InteractionType.RANDOM):
        rollout = env.rollout(steps, policy, break_when_any_done=False)
    env.close()
    return (
        rollout["next", "image"],
        rollout["next", "reward"].reshape(envs, steps),
        rollout["next", "done"].reshape(envs, steps),
    )


def run_milestones(run_dir: str | Path, loaded, episodes) -> dict:
    """One run's row of :data:`COLUMNS`: ``loaded`` from :func:`load_policy`, its
    ``episodes`` from :func:`policy_episodes`."""
    _, config, frames = loaded
    table = episode_milestones(*episodes)
    row = {
        "run": str(run_dir),
        "setting": config.get("setting") or "",
        "seed": config.get("seed"),
        "frames": frames,
        "episodes": len(table),
    }
    for name in MILESTONES:
        row[name] = round(float(table[name].mean()), 4) if len(table) else float("nan")
    return row


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python recipes/results/milestones.py",
        description=__doc__.split("\n\n", 1)[0],
    )
    parser.add_argument("runs", nargs="+", type=Path, help="run directories")
    parser.add_argument("--envs", type=int, default=16, help="envs of the rollout")
    parser.add_argument("--steps", type=int, default=1000, help="steps per env")
    parser.add_argument("--seed", type=int, default=0, help="seed of the rollout")
    parser.add_argument("--out", type=Path, help="CSV to write")
    args = parser.parse_args(argv)
    torch.set_num_threads(1)
    loaded = {}
    for run in args.runs:
        try:
            loaded[run] = load_policy(run)
        except (FileNotFoundError, ValueError) as error:
            parser.error(str(error))
    rows = []
    for run, (policy, config, _) in loaded.items():
        episodes = policy_episodes(policy, config, args.envs, args.steps, args.seed)
        rows.append(run_milestones(run, loaded[run], episodes))
    table = pd.DataFrame(rows, columns=list(COLUMNS))
    table = table.sort_values(["setting", "seed"], kind="stable")
    if args.out is not None:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        table.to_csv(args.out, index=False)
        print(f"wrote {args.out}")
    print(table.drop(columns="run").to_string(index=False))
    return 0


if __name__ == "__main__":
    sys.exit(main())
