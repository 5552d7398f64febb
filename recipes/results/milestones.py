"""How far into a MiniGrid task a run's final policy gets: the share of its
episodes in which the agent moves a ball, carries a key or a box, brings a key to
its locked door, opens or unlocks a door, succeeds.

A return of 0 says a policy never finishes a task, not how close it came. On the
suite's object tasks (ObstructedMaze: move the ball that blocks the door, open the
box, take the key, unlock the door, fetch the ball behind it; KeyCorridor, DoorKey)
each step of the chain shows in the agent's own view, so the episodes of a final
policy say how far it gets. For each run (its checkpoint's policy, rebuilt as the
recipe built it), this command plays ``--envs`` envs of the run's task and backend
(actions sampled from the policy, as in training; envs seeded ``--seed``) until
each has ended ``--episodes`` episodes (``episodes x max_steps`` steps: an episode
lasts at most the task's ``max_steps``), and over the first ``--episodes`` of each
env (not the episodes that end first, which would favour short, successful ones)
writes one row per run:

- ``episodes``: how many were scored (``envs x episodes``);
- ``carried_ball``, ``carried_key``, ``carried_box``: the share in which the agent
  held one at a step that was not the episode's rewarded last step (MiniGrid draws
  the carried object in the agent's cell of its view; on KeyCorridor and
  ObstructedMaze, picking up the target ball is the success itself, so
  ``carried_ball`` is another ball: ObstructedMaze's blocking ball moved). A box
  is opened by a toggle, not carried: carrying one is a detour;
- ``saw_locked_door_with_key``, ``faced_locked_door_with_key``: the share in
  which the agent, holding a key, had a locked door of the key's colour in view,
  or in the cell in front of it (where a toggle unlocks it): they tell a policy
  that never brings the key back to its door from one that reaches it and does
  not unlock it;
- ``opened_door``: the share in which an open door came into view (the suite's
  tasks start with every door closed or locked, so it is one the agent opened;
  on KeyCorridor, MultiRoom and ObstructedMaze-2Dlhb some doors are unlocked);
- ``unlocked_door``: the share in which the agent unlocked a door (a toggle
  with a locked door in front of it, open after it);
- ``success``: the share that ended with a positive reward (the task solved);

and, beside them, ``toggle_prob_at_door``: the policy's probability of the toggle
action at the steps where the agent holds a key facing a locked door of its
colour (where a toggle unlocks it), averaged over those steps (empty when there
are none): how readily a policy that brings the key to its door tries it there.
It reads the view before each step (where the action is chosen), the milestones
the view after it, so an episode that first faces the door at its last step
counts as ``faced_locked_door_with_key`` and adds no step here.

With ``--toggles``, the table is instead where the policy would toggle: for
each context of :data:`TOGGLE_CONTEXTS` (the cell in front of the agent, in the
view before the step), the number of scored steps in it (``steps_<context>``) and
the policy's mean probability of the toggle action over them
(``toggle_<context>``, empty without steps; a uniform policy's is 1/7): anywhere,
holding a key at its locked door, at a locked door without its key (where a
toggle does nothing), at a closed door, at a box (a toggle opens it). They tell a
policy that rules out toggling everywhere from one that rules it out at locked
doors only.

A run trained with ``env.stochasticity`` is refused: its noise is not replayed.
A run is a run directory (its latest checkpoint) or one checkpoint file: a run
made with ``checkpoint.keep=true`` keeps each periodic one as
``<run>/checkpoints/checkpoint-<frames>.torchrl``, so passing them all gives the
milestones at points of training (the ``frames`` column tells them apart).

Usage::

    python recipes/results/milestones.py runs/ppo_minigrid/suite_obstructedmaze_1dlhb/+setting=*,seed=* \\
        --out docs/results/milestones/obstructedmaze_1dlhb.csv
    python recipes/results/milestones.py "runs/ppo_minigrid/suite_obstructedmaze_2dlhb/+setting=vae_noveld,seed=0"/checkpoints/*.torchrl
    python recipes/results/milestones.py runs/ppo_minigrid/suite_obstructedmaze_1dlhb/+setting=*,seed=* --toggles
    python recipes/results/milestones.py <new runs> --from-data <its committed csv> --out <its committed csv>

``--from-data`` adds the runs to a table this command wrote earlier (of the same
kind: milestones or ``--toggles``): runs no longer on disk keep their rows, a
run given again (the same path) replaces its own.
``--label-keys KEY [KEY ...]`` adds each dotted config key's value to the
runs' setting labels (``noveld,loss.entropy_coef=0.03``), as ``aggregate.py``'s
does, for a sweep of one named setting over a hyperparameter.
"""

from __future__ import annotations

import math
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import NamedTuple

import pandas as pd
import torch
from minigrid.core.actions import Actions
from minigrid.core.constants import OBJECT_TO_IDX, STATE_TO_IDX

# recipes/ holds what the recipes share (common), which rebuilds a run's policy
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

__all__ = [
    "COLUMNS",
    "MILESTONES",
    "TOGGLE_COLUMNS",
    "TOGGLE_CONTEXTS",
    "Episodes",
    "episode_milestones",
    "load_policy",
    "max_steps",
    "policy_episodes",
    "run_milestones",
    "run_toggles",
    "toggle_contexts",
    "toggle_probability_at_door",
]

_DOOR, _KEY, _BALL, _BOX = (OBJECT_TO_IDX[k] for k in ("door", "key", "ball", "box"))
_OPEN, _CLOSED, _LOCKED = (STATE_TO_IDX[k] for k in ("open", "closed", "locked"))
#: The agent's cell of its 7x7 view ([x, y]) and the cell in front of it.
_AGENT, _FRONT = (3, 6), (3, 5)

#: The milestones, in the order of the output's columns.
MILESTONES = (
    "carried_ball",
    "carried_key",
    "carried_box",
    "saw_locked_door_with_key",
    "faced_locked_door_with_key",
    "opened_door",
    "unlocked_door",
    "success",
)

#: Columns of the output, per run.
COLUMNS = (
    "run",
    "setting",
    "seed",
    "frames",
    "episodes",
    *MILESTONES,
    "toggle_prob_at_door",
)


#: Where ``--toggles`` reads the policy's toggle probability: the cell in front
#: of the agent (and what it holds) in the view before the step.
TOGGLE_CONTEXTS = (
    "anywhere",
    "key_at_its_door",
    "locked_door_without_its_key",
    "closed_door",
    "box",
)

#: Columns of ``--toggles``' output, per run.
TOGGLE_COLUMNS = (
    "run",
    "setting",
    "seed",
    "frames",
    "episodes",
    *(f"steps_{context}" for context in TOGGLE_CONTEXTS),
    *(f"toggle_{context}" for context in TOGGLE_CONTEXTS),
)


class Episodes(NamedTuple):
    """Steps of ``envs`` envs, each ``[envs, steps, ...]``: the views before
    (``image``) and after (``next_image``) each step, its ``reward``, ``done`` and
    ``action``, and the policy's ``logits`` at each step (when played by one)."""

    image: torch.Tensor
    next_image: torch.Tensor
    reward: torch.Tensor
    done: torch.Tensor
    action: torch.Tensor
    logits: torch.Tensor | None = None


def _locked_door(cells: torch.Tensor) -> torch.Tensor:
    # cells ([..., 3], encoded) that are a locked door
    return (cells[..., 0] == _DOOR) & (cells[..., 2] == _LOCKED)


def _locked_door_of(cells: torch.Tensor, colour: torch.Tensor) -> torch.Tensor:
    # cells ([..., 3], encoded) that are a locked door of ``colour`` (a key opens
    # the door of its colour; ObstructedMaze-2Dlhb has two)
    return _locked_door(cells) & (cells[..., 1] == colour)


def _key_at_its_door(view: torch.Tensor) -> torch.Tensor:
    # [envs, steps]: the agent holds a key and the cell in front of it is a locked
    # door of the key's colour, where a toggle unlocks it
    held, front = view[..., _AGENT[0], _AGENT[1], :], view[..., _FRONT[0], _FRONT[1], :]
    return (held[..., 0] == _KEY) & _locked_door_of(front, held[..., 1])


def _checked_views(*views: torch.Tensor) -> tuple[torch.Tensor, ...]:
    # the views, each MiniGrid's encoded egocentric one: [envs, steps, 7, 7, 3]
    for view in views:
        if view.dim() != 5 or tuple(view.shape[-3:]) != (7, 7, 3):
            raise ValueError(
                "views must be [envs, steps, 7, 7, 3] (MiniGrid's egocentric view, "
                f"encoded), got {tuple(view.shape)}"
            )
    return views


def _scored_episodes(done: torch.Tensor, per_env: int | None) -> list[tuple]:
    # (env, first step, last step) of each env's first ``per_env`` ended episodes
    # (all ended ones without it); an env that ended fewer is refused
    episodes = []
    for env in range(done.shape[0]):
        ends = done[env].nonzero().flatten().tolist()
        if per_env is not None:
            if len(ends) < per_env:
                raise ValueError(
                    f"env {env} ended {len(ends)} episodes in {done.shape[-1]} "
                    f"steps, expected at least {per_env}"
                )
            ends = ends[:per_env]
        starts = [0, *(end + 1 for end in ends[:-1])]
        episodes += [(env, start, end) for start, end in zip(starts, ends)]
    return episodes


def episode_milestones(episodes: Episodes, per_env: int | None = None) -> pd.DataFrame:
    """One row per episode that ends within the steps, a column per milestone
    (:data:`MILESTONES`, booleans); with ``per_env``, each env's first ``per_env``
    episodes only.

    Raises:
        ValueError: a view is not MiniGrid's encoded 7x7 one, or an env ended fewer
            than ``per_env`` episodes.

    Examples:
        >>> image = torch.ones(1, 4, 7, 7, 3, dtype=torch.uint8)
        >>> after = image.clone()
        >>> after[0, 1, 3, 6, 0] = 5  # carries a key after step 1
        >>> after[0, 3, 2, 2] = torch.tensor([4, 0, 0])  # an open door, step 3
        >>> done = torch.tensor([[False, True, False, True]])
        >>> reward = torch.tensor([[0.0, 0.0, 0.0, 0.5]])
        >>> steps = Episodes(image, after, reward, done, torch.zeros(1, 4))
        >>> episode_milestones(steps).astype(int).to_dict("list")
        ... # doctest: +NORMALIZE_WHITESPACE
        {'carried_ball': [0, 0], 'carried_key': [1, 0], 'carried_box': [0, 0],
         'saw_locked_door_with_key': [0, 0], 'faced_locked_door_with_key': [0, 0],
         'opened_door': [0, 1], 'unlocked_door': [0, 0], 'success': [0, 1]}
    """
    image, after = _checked_views(episodes.image, episodes.next_image)
    envs, steps = after.shape[:2]
    reward = episodes.reward.reshape(envs, steps)
    done = episodes.done.reshape(envs, steps).bool()
    success = reward > 0
    # the rewarded pickup of the target ball ends the episode carrying it
    carried = after[..., _AGENT[0], _AGENT[1], 0].masked_fill(success, 0)
    seen = after.flatten(2, 3)  # [envs, steps, 49, 3]
    front, front_after = (
        image[..., _FRONT[0], _FRONT[1], :],
        after[..., _FRONT[0], _FRONT[1], :],
    )
    key_colour = after[..., _AGENT[0], _AGENT[1], 1]
    locked = _locked_door_of(seen, key_colour[..., None])  # of the key's colour
    per_step = {
        "carried_ball": carried == _BALL,
        "carried_key": carried == _KEY,
        "carried_box": carried == _BOX,
        "saw_locked_door_with_key": (carried == _KEY) & locked.any(-1),
        "faced_locked_door_with_key": (carried == _KEY) & _key_at_its_door(after),
        "opened_door": ((seen[..., 0] == _DOOR) & (seen[..., 2] == _OPEN)).any(-1),
        # the toggle action only: a turn from a locked door to an open one (in a
        # cell between two doors, as ObstructedMaze-2Dlhb has) also changes the
        # cell in front from locked to open
        "unlocked_door": _locked_door(front)
        & (episodes.action == int(Actions.toggle))
        & (front_after[..., 0] == _DOOR)
        & (front_after[..., 2] == _OPEN),
        "success": success,
    }
    rows = [
        {k: bool(v[env, start : end + 1].any()) for k, v in per_step.items()}
        for env, start, end in _scored_episodes(done, per_env)
    ]
    return pd.DataFrame(rows, columns=list(MILESTONES), dtype=bool)


def _scored_steps(episodes: Episodes, per_env: int | None) -> torch.Tensor:
    # [envs, steps]: the steps of each env's first ``per_env`` ended episodes
    envs, steps = episodes.image.shape[:2]
    done = episodes.done.reshape(envs, steps).bool()
    scored = torch.zeros_like(done)
    for env, start, end in _scored_episodes(done, per_env):
        scored[env, start : end + 1] = True
    return scored


def _toggle_probability(episodes: Episodes) -> torch.Tensor:
    # [envs, steps]: the policy's probability of the toggle action at each step
    if episodes.logits is None:
        raise ValueError("expected the policy's logits at each step, got none")
    return episodes.logits.float().softmax(-1)[..., int(Actions.toggle)]


def toggle_contexts(
    episodes: Episodes, per_env: int | None = None
) -> dict[str, tuple[int, float]]:
    """For each context of :data:`TOGGLE_CONTEXTS`, ``(steps, probability)``: how
    many steps of each env's first ``per_env`` ended episodes (all ended ones
    without it) are in it, and the policy's mean probability of the toggle action
    over them (NaN without steps). A context is read from the view before the
    step: the cell in front of the agent and what the agent holds.

    Raises:
        ValueError: the episodes carry no ``logits``, a view is not MiniGrid's
            encoded 7x7 one, or an env ended fewer than ``per_env`` episodes.

    Examples:
        >>> image = torch.zeros(1, 3, 7, 7, 3, dtype=torch.uint8)
        >>> image[0, 0, 3, 5] = torch.tensor([4, 4, 2])  # a locked yellow door
        >>> image[0, 1, 3, 5] = torch.tensor([7, 1, 0])  # a box
        >>> image[0, 2, 3, 6] = torch.tensor([5, 4, 0])  # holds a yellow key...
        >>> image[0, 2, 3, 5] = torch.tensor([4, 4, 2])  # ...at its door
        >>> logits = torch.zeros(1, 3, 7)  # uniform: 1/7 everywhere
        >>> done = torch.tensor([[False, False, True]])
        >>> steps = Episodes(image, image, torch.zeros(1, 3), done, torch.zeros(1, 3),
        ...                  logits)
        >>> {k: (n, round(p, 4)) for k, (n, p) in toggle_contexts(steps).items()}
        ... # doctest: +NORMALIZE_WHITESPACE
        {'anywhere': (3, 0.1429), 'key_at_its_door': (1, 0.1429),
         'locked_door_without_its_key': (1, 0.1429), 'closed_door': (0, nan),
         'box': (1, 0.1429)}
    """
    (image,) = _checked_views(episodes.image)
    toggle = _toggle_probability(episodes)
    scored = _scored_steps(episodes, per_env)
    front = image[..., _FRONT[0], _FRONT[1], :]
    at_door = _key_at_its_door(image)
    masks = {
        "anywhere": torch.ones_like(scored),
        "key_at_its_door": at_door,
        "locked_door_without_its_key": _locked_door(front) & ~at_door,
        "closed_door": (front[..., 0] == _DOOR) & (front[..., 2] == _CLOSED),
        "box": front[..., 0] == _BOX,
    }
    result = {}
    for context in TOGGLE_CONTEXTS:
        mask = masks[context] & scored
        steps = int(mask.sum())
        result[context] = (steps, float(toggle[mask].mean()) if steps else math.nan)
    return result


def toggle_probability_at_door(episodes: Episodes, per_env: int | None = None) -> float:
    """The policy's mean probability of the toggle action over the steps at which
    the agent holds a key facing a locked door of its colour (NaN when there are
    none), in each env's first ``per_env`` ended episodes (all ended ones without
    it).

    Raises:
        ValueError: the episodes carry no ``logits``, or an env ended fewer than
            ``per_env`` episodes.

    Examples:
        >>> image = torch.zeros(1, 2, 7, 7, 3, dtype=torch.uint8)
        >>> image[0, :, 3, 6] = torch.tensor([5, 4, 0])  # holds a yellow key
        >>> image[0, 1, 3, 5] = torch.tensor([4, 4, 2])  # then faces its locked door
        >>> logits = torch.zeros(1, 2, 7)
        >>> logits[0, 1, 5] = 1.0  # toggle: e / (e + 6)
        >>> done = torch.tensor([[False, True]])
        >>> steps = Episodes(image, image, torch.zeros(1, 2), done, torch.zeros(1, 2),
        ...                  logits)
        >>> round(toggle_probability_at_door(steps), 4)
        0.3118
    """
    return toggle_contexts(episodes, per_env)["key_at_its_door"][1]


def load_policy(run_dir: str | Path):
    """``(policy, config, frames)`` of a MiniGrid run's checkpoint: the recipe's
    actor (:func:`common.minigrid.make_actor_critic`) with the saved weights.

    Raises:
        FileNotFoundError: no checkpoint there.
        ValueError: the checkpoint is not a MiniGrid recipe's (no ``"model"``, or
            its config has no MiniGrid env).
    """
    from torchrl.data import Categorical

    from common.checkpoint import find_checkpoint, load_checkpoint
    from common.minigrid import make_actor_critic

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
    if config["env"].get("stochasticity"):
        raise ValueError(
            f"{path}: the run was trained with env.stochasticity="
            f"{config['env']['stochasticity']}; milestones are read on the task "
            "without noise (expected env.stochasticity 0)"
        )
    # every MiniGrid env has the same 7 actions (left, right, forward, pickup,
    # drop, toggle, done)
    model, _ = make_actor_critic(Categorical(7), intrinsic_critic=False)
    model.load_state_dict(ckpt["model"])
    model.eval()
    return model.get_policy_operator(), config, ckpt.get("frames")


def max_steps(env_name: str) -> int:
    """The task's ``max_steps`` (minigrid's; envpool's tasks keep it)."""
    import gymnasium as gym

    from torchrl_surprise.envs import register_minigrid_envs

    register_minigrid_envs()
    env = gym.make(env_name)
    try:
        return int(env.unwrapped.max_steps)
    finally:
        env.close()


def policy_episodes(policy, config: dict, envs: int, steps: int, seed: int) -> Episodes:
    """:class:`Episodes` of ``envs`` envs of the run's task and backend, ``steps``
    steps of ``policy`` with sampled actions (as the training collector's)."""
    from tensordict.nn import InteractionType, set_interaction_type

    from common.labels import run_backend
    from torchrl_surprise.envs import make_minigrid_env

    env = make_minigrid_env(
        config["env"]["name"], num_envs=envs, backend=run_backend(config)
    )
    env.set_seed(seed)
    torch.manual_seed(seed)
    with torch.no_grad(), set_interaction_type(InteractionType.RANDOM):
        rollout = env.rollout(steps, policy, break_when_any_done=False)
    env.close()
    return Episodes(
        rollout["image"],
        rollout["next", "image"],
        rollout["next", "reward"].reshape(envs, steps),
        rollout["next", "done"].reshape(envs, steps),
        rollout["action"].reshape(envs, steps),
        rollout["logits"].reshape(envs, steps, -1),
    )


def _run_row(run_dir: str | Path, loaded, episodes: int) -> dict:
    # the columns every row starts with: the run, its labels, frames, episodes
    from common.labels import run_labels

    _, config, frames = loaded
    labels = run_labels(config, run_dir)
    return {
        "run": str(run_dir),
        "setting": labels["setting"],
        "seed": labels["seed"],
        "frames": frames,
        "episodes": episodes,
    }


def run_milestones(
    run_dir: str | Path, loaded, episodes: Episodes, per_env: int
) -> dict:
    """One run's row of :data:`COLUMNS`: ``loaded`` from :func:`load_policy`, its
    ``episodes`` from :func:`policy_episodes`, each env's first ``per_env``."""
    table = episode_milestones(episodes, per_env)
    row = _run_row(run_dir, loaded, len(table))
    for name in MILESTONES:
        row[name] = round(float(table[name].mean()), 4)
    row["toggle_prob_at_door"] = round(toggle_probability_at_door(episodes, per_env), 4)
    return row


def run_toggles(run_dir: str | Path, loaded, episodes: Episodes, per_env: int) -> dict:
    """One run's row of :data:`TOGGLE_COLUMNS` (``--toggles``): the arguments of
    :func:`run_milestones`."""
    contexts = toggle_contexts(episodes, per_env)
    # each env's first per_env episodes (toggle_contexts refuses an env with fewer)
    row = _run_row(run_dir, loaded, episodes.image.shape[0] * per_env)
    for context, (steps, _) in contexts.items():
        row[f"steps_{context}"] = steps
    for context, (_, probability) in contexts.items():
        row[f"toggle_{context}"] = round(probability, 4)
    return row


def main(argv: Sequence[str] | None = None) -> int:
    from common.labels import add_label_keys, add_label_keys_argument
    from results.run_tools import (
        checkpoint_parser,
        load_runs,
        merge_earlier,
        write_table,
    )

    parser = checkpoint_parser("milestones.py", __doc__, envs=32)
    parser.add_argument(
        "--episodes", type=int, default=2, help="episodes scored per env"
    )
    parser.add_argument(
        "--toggles",
        action="store_true",
        help="write where the policy would toggle (TOGGLE_COLUMNS), not milestones",
    )
    add_label_keys_argument(parser)
    args = parser.parse_args(argv)
    row_of, columns = (
        (run_toggles, TOGGLE_COLUMNS) if args.toggles else (run_milestones, COLUMNS)
    )
    torch.set_num_threads(1)
    loaded = load_runs(parser, args.runs, load_policy)
    for run, (_, config, _) in loaded.items():  # before the long part: refused early
        try:
            add_label_keys("", config, args.label_keys, f"{run}'s checkpoint config")
        except ValueError as err:
            parser.error(str(err))
    rows = []
    for run, (policy, config, _) in loaded.items():
        steps = args.episodes * max_steps(config["env"]["name"])
        episodes = policy_episodes(policy, config, args.envs, steps, args.seed)
        row = row_of(run, loaded[run], episodes, args.episodes)
        row["setting"] = add_label_keys(row["setting"], config, args.label_keys, "")
        rows.append(row)
    table = merge_earlier(
        parser, pd.DataFrame(rows, columns=list(columns)), args.from_data
    )
    # a run's points of training (kept checkpoints) in the order of their frames
    order = ["setting", "seed", "frames", "run"]
    write_table(table.sort_values(order, kind="stable"), args.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
