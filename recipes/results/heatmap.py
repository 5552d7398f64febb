"""The surprise heatmap: the VAE bonus at every agent position and direction of one
MiniGrid layout, drawn over the rendered grid.

The paper claims the KL bonus is highest in hallways, in sight of doors and near
the goal. This command shows it for a trained run: it places the agent on every
cell it can reach in one layout, facing each of the 4 directions, computes the raw
bonus (nats) of each observation with the run's checkpointed bonus transform, and
draws the per-cell maximum (or mean) over directions as a colour overlay on the
rendered grid, one panel per checkpoint (points of training)::

    python recipes/results/heatmap.py RUN_DIR_OR_CKPT [...] \\
        --layout-seed 0 --out docs/results/heatmaps/n3s4.png \\
        [--open-doors] [--reduce max|mean] [--directions] [--shared-scale] \\
        [--memory-steps K [K ...]]

A run directory (written by ``recipes/minigrid/main.py`` with ``bonus=vae``) is
read through its latest checkpoint, ``checkpoint.torchrl`` (a 0.2 run's
``checkpoint.pt`` is read too); to compare points of training, run with
``checkpoint.keep=true`` and pass the files it keeps under ``checkpoints/``. The env and the VAE are rebuilt from the checkpoint's config.

**Episodic bonus.** The elliptical bonus (``intrinsic.vae.variant=elliptical``)
of a state depends on the states before it in the episode: each cell is scored
as the next state of an episode that took the first ``K`` steps of the layout's
shortest solution (:func:`solution_memory`; ``K = 0``, the default, is an episode
starting there), one panel per checkpoint and ``K``, the memory's cells marked.

**Cells.** The agent is placed on the cells reachable from its start position by
walking over cells it can stand on (empty, floor, goal, open doors). Doors stay
as the layout generated them (closed, or locked), so the rooms beyond are out of
reach, unless ``--open-doors`` opens (and unlocks) every door first. Other cells
are NaN in :func:`bonus_grid` and left uncoloured in the picture. The
observations are the env's own (``gen_obs``), without the observation noise of
``env.stochasticity`` a run may have trained with.

**Categories.** Next to the PNG a CSV (same name, ``.csv``), also printed, holds
the mean bonus of the reachable cells of each category, a partition of them taken
in this order (a cell belongs to the first that fits):

- ``doorway``: a door cell, or a cell next to a door (4-neighbourhood);
- ``near_goal``: the goal cell, or a cell next to it;
- ``door_in_view``: some direction's observation shows a door (object id 4);
- ``other``: the rest.

and, for reference, ``all`` (every reachable cell) and two categories of single
observations (cell and direction): ``view_door`` (a door is in the agent's view)
and ``view_no_door``. Each row gives the count, ``mean_bonus`` (over the
observations of its cells, all 4 directions) and, for cells, ``mean_cell_max``
(the mean of each cell's maximum over directions, what the default picture
shows).

The picture and the means are one layout of one run: an anecdote, not a result.

**Over runs and layouts.** ``--summary`` draws no picture: it scores every
checkpoint on every layout of ``--layout-seeds``, divides each category's mean
bonus by the layout's mean over all its reachable observations (1.0: an average
observation; :func:`category_table`) and gives, per setting, the IQM over runs of
each run's mean over the layouts with a 95% bootstrap CI and how many runs put
the category above the average (:func:`summarize_categories`)::

    python recipes/results/heatmap.py --summary \\
        runs/a2c_minigrid/doorkey8x8/+setting=vae_literal,seed=* \\
        --layout-seeds 0 1 2 3 4 5 6 7 8 9 --open-doors \\
        --out docs/results/heatmaps/doorkey8x8_categories.csv

writes the summary there, beside it the rows per run and layout
(``doorkey8x8_categories_layouts.csv.xz``) and the summary formatted for the docs
(``doorkey8x8_categories_report.csv``, :func:`summary_report`).
``--from-layouts doorkey8x8_categories_layouts.csv.xz`` recomputes the summary and
its table from those rows alone (``make figures`` does it for every
``docs/results/heatmaps/*_layouts.csv.xz``).
"""

from __future__ import annotations

import argparse
import contextlib
import csv
import os
import sys
import warnings
from collections import deque
from collections.abc import Iterator, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch
from minigrid.core.constants import OBJECT_TO_IDX
from tensordict import TensorDict

# Run as a script: recipes/ holds the shared `common` and `results` packages.
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from common.errors import UserMistake, report_mistakes

__all__ = [
    "CATEGORIES",
    "NotAHeatmapRun",
    "UNMAPPED_VARIANTS",
    "bonus_grid",
    "category_means",
    "category_table",
    "cell_categories",
    "door_views",
    "load_bonus_transform",
    "main",
    "make_layout_env",
    "observation_bonus",
    "plot_heatmaps",
    "reachable_cells",
    "render_layout",
    "solution_memory",
    "summarize_categories",
    "summary_report",
]

CATEGORIES: tuple[str, ...] = ("doorway", "near_goal", "door_in_view", "other")
"""The cell categories of :func:`cell_categories`, in their order of precedence."""

UNMAPPED_VARIANTS: tuple[str, ...] = ("noveld",)
"""VAE variants without a map: their bonus pays a transition ``(s, s')``, not a state."""

_DOOR_ID = OBJECT_TO_IDX["door"]
# MiniGrid's directions: 0 right (+x), 1 down (+y), 2 left, 3 up.
_NEIGHBOURS = ((1, 0), (0, 1), (-1, 0), (0, -1))


# ---------------------------------------------------------------------- layout
def make_layout_env(env_name: str, layout_seed: int = 0):
    """``gym.make(env_name, render_mode="rgb_array")``, reset to one layout.

    Registers minigrid's envs and the paper's MultiRoom ids first
    (:func:`~torchrl_surprise.envs.register_minigrid_envs`).

    Examples:
        >>> env = make_layout_env("MiniGrid-MultiRoom-N3-S4-v0", layout_seed=0)
        >>> env.unwrapped.grid.width, env.unwrapped.grid.height
        (25, 25)
    """
    import gymnasium as gym

    from torchrl_surprise.envs import register_minigrid_envs

    register_minigrid_envs()
    env = gym.make(env_name, render_mode="rgb_array")
    env.reset(seed=layout_seed)
    return env


def _doors(base) -> list:
    grid = base.grid
    return [
        obj
        for obj in grid.grid
        if obj is not None and getattr(obj, "type", None) == "door"
    ]


@contextlib.contextmanager
def _layout(env, open_doors: bool) -> Iterator[Any]:
    """The unwrapped env, with doors opened if asked; restored on exit.

    Every function here moves the agent (and may open doors) to look at the
    layout: the caller's env must come back as it was.
    """
    base = env.unwrapped
    agent_pos, agent_dir = base.agent_pos, base.agent_dir
    doors = _doors(base)
    door_states = [(door.is_open, door.is_locked) for door in doors]
    try:
        if open_doors:
            for door in doors:
                door.is_open, door.is_locked = True, False
        yield base
    finally:
        base.agent_pos, base.agent_dir = agent_pos, agent_dir
        for door, (is_open, is_locked) in zip(doors, door_states):
            door.is_open, door.is_locked = is_open, is_locked


def _reachable(base) -> np.ndarray:
    grid = base.grid
    mask = np.zeros((grid.height, grid.width), dtype=bool)
    start = tuple(int(v) for v in base.agent_pos)
    queue = deque([start])
    mask[start[1], start[0]] = True
    while queue:
        x, y = queue.popleft()
        for dx, dy in _NEIGHBOURS:
            nx, ny = x + dx, y + dy
            if not (0 <= nx < grid.width and 0 <= ny < grid.height) or mask[ny, nx]:
                continue
            cell = grid.get(nx, ny)
            if cell is None or cell.can_overlap():
                mask[ny, nx] = True
                queue.append((nx, ny))
    return mask


def reachable_cells(env, *, open_doors: bool = False) -> np.ndarray:
    """The cells the agent can walk to from its position, ``bool [H, W]``.

    Walks over cells it can stand on (empty, floor, goal, open doors; with
    ``open_doors``, every door opened and unlocked first). Indexed ``[y, x]``.

    Examples:
        >>> env = make_layout_env("MiniGrid-MultiRoom-N3-S4-v0", layout_seed=0)
        >>> closed = reachable_cells(env)
        >>> opened = reachable_cells(env, open_doors=True)
        >>> bool(closed.sum() < opened.sum()), bool((closed <= opened).all())
        (True, True)
    """
    with _layout(env, open_doors) as base:
        return _reachable(base)


def _observations(base, mask: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The observation at each cell of ``mask`` (row-major) and direction 0-3."""
    images, directions = [], []
    for y, x in np.argwhere(mask):
        for direction in range(4):
            base.agent_pos, base.agent_dir = (int(x), int(y)), direction
            obs = base.gen_obs()
            images.append(obs["image"])
            directions.append(obs["direction"])
    if not images:
        return np.zeros((0, 7, 7, 3), np.uint8), np.zeros((0,), np.int64)
    return np.stack(images), np.asarray(directions, dtype=np.int64)


def render_layout(env, *, open_doors: bool = False, tile_size: int = 32) -> np.ndarray:
    """The RGB picture of the layout with the agent at its position, ``[H*t, W*t, 3]``.

    Examples:
        >>> env = make_layout_env("MiniGrid-DoorKey-5x5-v0", layout_seed=0)
        >>> render_layout(env, tile_size=8).shape
        (40, 40, 3)
    """
    with _layout(env, open_doors) as base:
        return base.grid.render(tile_size, base.agent_pos, base.agent_dir)


# ----------------------------------------------------------------------- bonus
def observation_bonus(
    transform,
    image: torch.Tensor | np.ndarray,
    direction: torch.Tensor | np.ndarray,
    memory: tuple[torch.Tensor | np.ndarray, torch.Tensor | np.ndarray] | None = None,
) -> torch.Tensor:
    """The raw bonus of a batch of MiniGrid observations, through the public path.

    Calls ``transform`` on transitions ``{"next": {"image", "direction",
    "reward"}}`` (one time step of ``N`` states) and reads its
    ``intrinsic_reward_key``: the bonus before normalisation, in nats for the VAE
    bonuses. The transform's statistics are frozen during the call (then
    unfrozen if they were not frozen), so they are not updated.

    An episodic bonus (:class:`~torchrl_surprise.transforms.VAEEllipticalTransform`)
    depends on the states seen before in the episode: ``memory`` gives them, and
    each of the ``N`` observations is scored as the next state of an episode that
    went through ``memory`` (the transform walks ``K + 1`` time steps of ``N``
    envs; its episodes start afresh before and after). Without ``memory``, the
    episode starts at the observation. A per-state bonus ignores ``memory``.

    Args:
        transform: a bonus transform (e.g. :class:`~torchrl_surprise.VAESurpriseTransform`).
        image: ``uint8 [N, 7, 7, 3]`` object, colour and state ids.
        direction: ``int [N]`` in ``{0, 1, 2, 3}``.
        memory: ``(images [K, 7, 7, 3], directions [K])``, the episode so far.

    Returns:
        ``float [N]``.

    Examples:
        >>> import torch
        >>> from torchrl_surprise import StateVAE, VAESurpriseTransform
        >>> vae = StateVAE.for_minigrid(latent_dim=4, hidden_dim=16)
        >>> t = VAESurpriseTransform(vae)
        >>> image = torch.ones(3, 7, 7, 3, dtype=torch.uint8)
        >>> bonus = observation_bonus(t, image, torch.tensor([0, 1, 2]))
        >>> torch.allclose(bonus, vae.kl(image, torch.tensor([0, 1, 2])))
        True
        >>> t.frozen
        False
    """
    image = torch.as_tensor(np.asarray(image), dtype=torch.uint8)
    direction = torch.as_tensor(np.asarray(direction), dtype=torch.int64)
    n = image.shape[0]
    image, direction = image.unsqueeze(0), direction.unsqueeze(0)
    if memory is not None:
        past_image = torch.as_tensor(np.asarray(memory[0]), dtype=torch.uint8)
        past_direction = torch.as_tensor(np.asarray(memory[1]), dtype=torch.int64)
        k = past_image.shape[0]
        image = torch.cat([past_image.unsqueeze(1).expand(k, n, -1, -1, -1), image])
        direction = torch.cat([past_direction.unsqueeze(1).expand(k, n), direction])
    steps = image.shape[0]
    # A leading time dimension: normalization="return_std" and the episodic
    # bonus need one (the raw bonus of a per-state bonus does not depend on it).
    td = TensorDict(
        {
            "next": {
                "image": image,
                "direction": direction,
                "reward": torch.zeros(steps, n, 1),
            }
        },
        batch_size=[steps, n],
        names=["time", None],
    )
    episodic = hasattr(transform, "reset_episodes")
    was_frozen = getattr(transform, "frozen", True)
    if hasattr(transform, "freeze"):
        transform.freeze()
    try:
        if episodic:
            transform.reset_episodes()
        out = transform(td)
    finally:
        if episodic:
            transform.reset_episodes()
        if not was_frozen:
            transform.unfreeze()
    key = getattr(transform, "intrinsic_reward_key", "intrinsic_reward")
    return out["next", key][-1].reshape(n).float()


def bonus_grid(transform, env, *, open_doors: bool = False, memory=None) -> np.ndarray:
    """The raw bonus with the agent at every reachable cell, facing each direction.

    Places the agent of ``env``'s current layout on every cell of
    :func:`reachable_cells`, in each direction, takes the observation
    (``gen_obs``) and computes all bonuses in one batch
    (:func:`observation_bonus`). The env's agent (and its doors) are left as
    they were.

    Args:
        transform: the bonus transform (its VAE reads ``"image"`` and, if it
            uses it, ``"direction"``).
        env: a MiniGrid env (gymnasium, wrapped or not), reset to a layout.
        open_doors (bool): open and unlock every door first.
        memory: the episode so far, for an episodic bonus
            (:func:`observation_bonus`; :func:`solution_memory` gives one).

    Returns:
        ``float [H, W, 4]`` indexed ``[y, x, direction]``; NaN where the agent
        cannot stand or cannot get to.

    Examples:
        >>> import numpy as np
        >>> from torchrl_surprise import StateVAE, VAESurpriseTransform
        >>> env = make_layout_env("MiniGrid-DoorKey-5x5-v0", layout_seed=0)
        >>> t = VAESurpriseTransform(StateVAE.for_minigrid(latent_dim=4, hidden_dim=16))
        >>> grid = bonus_grid(t, env)
        >>> grid.shape
        (5, 5, 4)
        >>> bool((np.isfinite(grid).all(-1) == reachable_cells(env)).all())
        True
    """
    with _layout(env, open_doors) as base:
        mask = _reachable(base)
        images, directions = _observations(base, mask)
    grid = np.full((*mask.shape, 4), np.nan)
    if len(images):
        bonus = observation_bonus(transform, images, directions, memory=memory)
        grid[mask] = bonus.numpy().reshape(-1, 4)
    return grid


def solution_memory(env, steps: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The first ``steps`` states of the layout's shortest solution, as an episode
    memory for an episodic bonus.

    Follows the oracle's shortest action sequence
    (:func:`~torchrl_surprise.envs.solve_minigrid`) from ``env``'s current state on
    a copy of the env, and collects the observation after each action (the states
    whose bonus an agent would have been paid, in order). ``env`` is not changed.

    Args:
        env: a MiniGrid env reset to a layout.
        steps (int): how many states (fewer if the solution is shorter).

    Returns:
        ``(images uint8 [K, 7, 7, 3], directions int [K], cells int [K, 2])``,
        the cells as ``(x, y)``.

    Examples:
        >>> env = make_layout_env("MiniGrid-DoorKey-5x5-v0", layout_seed=0)
        >>> images, directions, cells = solution_memory(env, 3)
        >>> images.shape, directions.shape, cells.shape
        ((3, 7, 7, 3), (3,), (3, 2))
    """
    import copy

    from torchrl_surprise.envs import solve_minigrid

    if steps < 0:
        raise ValueError(f"steps must be >= 0, got {steps}.")
    actions = solve_minigrid(env).actions[:steps]
    base = copy.deepcopy(env.unwrapped)
    images, directions, cells = [], [], []
    for action in actions:
        obs, *_ = base.step(action)
        images.append(obs["image"])
        directions.append(obs["direction"])
        cells.append(tuple(base.agent_pos))
    return (
        np.asarray(images, dtype=np.uint8).reshape(-1, 7, 7, 3),
        np.asarray(directions, dtype=np.int64),
        np.asarray(cells, dtype=np.int64).reshape(-1, 2),
    )


def door_views(env, *, open_doors: bool = False) -> np.ndarray:
    """Whether a door is in the agent's view, ``bool [H, W, 4]`` by ``[y, x, direction]``.

    True where the observation with the agent at that reachable cell and facing
    that way shows a door (object id 4, open or not, after occlusion); False
    elsewhere, unreachable cells included.

    Examples:
        >>> env = make_layout_env("MiniGrid-DoorKey-8x8-v0", layout_seed=0)
        >>> views = door_views(env)
        >>> views.shape
        (8, 8, 4)
        >>> bool(views.any() and not views.all(-1)[reachable_cells(env)].all())
        True
    """
    with _layout(env, open_doors) as base:
        mask = _reachable(base)
        images, _ = _observations(base, mask)
    views = np.zeros((*mask.shape, 4), dtype=bool)
    if len(images):
        views[mask] = (images[..., 0] == _DOOR_ID).reshape(-1, 4, 49).any(-1)
    return views


def cell_categories(env, *, open_doors: bool = False) -> dict[str, np.ndarray]:
    """Reachable cells by category, ``{name: bool [H, W]}`` for each of :data:`CATEGORIES`.

    The categories partition :func:`reachable_cells`; a cell belongs to the
    first that fits: ``doorway`` (a door, or next to one), ``near_goal`` (the
    goal, or next to it), ``door_in_view`` (a door is in the observation of
    one of its 4 directions, :func:`door_views`), ``other``.

    Examples:
        >>> env = make_layout_env("MiniGrid-MultiRoom-N3-S4-v0", layout_seed=0)
        >>> cats = cell_categories(env, open_doors=True)
        >>> list(cats)
        ['doorway', 'near_goal', 'door_in_view', 'other']
        >>> total = sum(mask.astype(int) for mask in cats.values())
        >>> bool((total == reachable_cells(env, open_doors=True)).all())
        True
    """
    with _layout(env, open_doors) as base:
        mask = _reachable(base)
    doors = _object_mask(env, "door")
    goals = _object_mask(env, "goal")
    sees_door = door_views(env, open_doors=open_doors).any(-1)
    remaining = mask.copy()
    categories = {}
    for name, candidates in (
        ("doorway", _with_neighbours(doors)),
        ("near_goal", _with_neighbours(goals)),
        ("door_in_view", sees_door),
        ("other", remaining),
    ):
        categories[name] = remaining & candidates
        remaining = remaining & ~candidates
    return categories


def _object_mask(env, kind: str) -> np.ndarray:
    grid = env.unwrapped.grid
    mask = np.zeros((grid.height, grid.width), dtype=bool)
    for x, y in _object_cells(env, kind):
        mask[y, x] = True
    return mask


def _object_cells(env, kind: str) -> list[tuple[int, int]]:
    grid = env.unwrapped.grid
    return [
        (x, y)
        for y in range(grid.height)
        for x in range(grid.width)
        if getattr(grid.get(x, y), "type", None) == kind
    ]


def _with_neighbours(mask: np.ndarray) -> np.ndarray:
    out = mask.copy()
    out[1:] |= mask[:-1]
    out[:-1] |= mask[1:]
    out[:, 1:] |= mask[:, :-1]
    out[:, :-1] |= mask[:, 1:]
    return out


def category_means(
    grid: np.ndarray, categories: Mapping[str, np.ndarray]
) -> dict[str, dict[str, Any]]:
    """Mean bonus of each category of cells (or of observations).

    Args:
        grid: ``[H, W, 4]`` bonus grid (:func:`bonus_grid`).
        categories: ``{name: mask}``; a ``[H, W]`` mask selects cells (all 4
            directions of each), a ``[H, W, 4]`` mask single observations.

    Returns:
        ``{name: {"unit", "count", "mean_bonus", "mean_cell_max"}}``: ``unit``
        is ``"cell"`` or ``"observation"`` and ``count`` how many;
        ``mean_bonus`` the mean over the selected observations;
        ``mean_cell_max`` (cells only) the mean of each cell's maximum over the
        4 directions, what the default picture shows. NaN when empty.

    Examples:
        >>> import numpy as np
        >>> grid = np.array([[[1.0, 3.0, 1.0, 3.0], [np.nan] * 4]])
        >>> cells = {"a": np.array([[True, False]])}
        >>> category_means(grid, cells)["a"]
        {'unit': 'cell', 'count': 1, 'mean_bonus': 2.0, 'mean_cell_max': 3.0}
        >>> views = {"b": np.array([[[False, True, False, True], [False] * 4]])}
        >>> category_means(grid, views)["b"]["mean_bonus"]
        3.0
    """
    nan = float("nan")
    out = {}
    for name, mask in categories.items():
        mask = np.asarray(mask, dtype=bool)
        values = grid[mask]
        count = int(mask.sum())
        if mask.ndim == grid.ndim:
            out[name] = {
                "unit": "observation",
                "count": count,
                "mean_bonus": float(values.mean()) if count else nan,
                "mean_cell_max": nan,
            }
        else:
            out[name] = {
                "unit": "cell",
                "count": count,
                "mean_bonus": float(values.mean()) if count else nan,
                "mean_cell_max": float(values.max(-1).mean()) if count else nan,
            }
    return out


def _groups(env, open_doors: bool) -> dict[str, np.ndarray]:
    """The categories of the CSV: :func:`cell_categories`, ``all`` and the views."""
    reachable = reachable_cells(env, open_doors=open_doors)
    views = door_views(env, open_doors=open_doors)
    return {
        **cell_categories(env, open_doors=open_doors),
        "all": reachable,
        # Per observation: sharper than door_in_view, which a cell has when
        # any one of its 4 directions sees a door (most cells of small rooms).
        "view_door": views,
        "view_no_door": reachable[..., None] & ~views,
    }


# ------------------------------------------------------------------ checkpoint
class NotAHeatmapRun(UserMistake, ValueError):
    """A run the surprise heatmap cannot draw: not a MiniGrid run, no VAE bonus,
    or a VAE variant without a map of cells; the message says which."""


def _check_heatmap_run(path: Path, config: Mapping[str, Any]) -> None:
    """Refuses a run whose checkpoint has no map of MiniGrid cells to draw."""
    from common.bonuses import VAE_VARIANTS

    env_name = str((config.get("env") or {}).get("name", ""))
    if not env_name.startswith("MiniGrid"):
        raise NotAHeatmapRun(
            f"{path} is a run of {env_name or 'an unknown env'}, not of the MiniGrid "
            "recipe: the surprise heatmap maps a MiniGrid maze's cells, for runs of "
            "recipes/minigrid/main.py with bonus=vae."
        )
    if config.get("bonus") != "vae":
        raise NotAHeatmapRun(
            f"{path}: this run's bonus is {config.get('bonus')!r}, not 'vae'; the "
            "surprise heatmap needs a run made with bonus=vae."
        )
    variant = config["intrinsic"]["vae"].get("variant", "kl")
    if variant not in VAE_VARIANTS:
        raise NotAHeatmapRun(
            f"{path}: unknown intrinsic.vae.variant {variant!r}; expected one of "
            f"{tuple(VAE_VARIANTS)}."
        )
    if variant in UNMAPPED_VARIANTS:
        raise NotAHeatmapRun(
            f"{path}: intrinsic.vae.variant {variant!r} pays a transition (s, s'), "
            "not a state, so it has no map of cells; the heatmap draws the "
            f"variants {tuple(v for v in VAE_VARIANTS if v not in UNMAPPED_VARIANTS)}."
        )


def load_bonus_transform(run_dir_or_ckpt: str | os.PathLike):
    """The VAE bonus transform of an A2C-MiniGrid run, as the recipe built it.

    Args:
        run_dir_or_ckpt: a run directory (its ``checkpoint.torchrl``, or a 0.2
            run's ``checkpoint.pt``, is read) or a checkpoint file (either).

    Returns:
        ``(transform, config, frames)``: the transform with the checkpoint's
        VAE (and reference copy, for the posterior-shift variants) and
        statistics, frozen; the run's resolved config (a dict); the frame count
        of the checkpoint.

    Raises:
        FileNotFoundError: no checkpoint there.
        NotAHeatmapRun: not a MiniGrid run, no VAE bonus, or a variant with no
            map (a ``ValueError``).
        ValueError: the checkpoint lacks the bonus.

    Examples:
        >>> import tempfile, os, torch
        >>> from torchrl_surprise import StateVAE, VAESurpriseTransform
        >>> vae = StateVAE.for_minigrid(latent_dim=4, hidden_dim=16)
        >>> config = {"bonus": "vae", "env": {"name": "MiniGrid-DoorKey-5x5-v0"},
        ...           "intrinsic": {"normalization": "none", "vae": {
        ...               "latent_dim": 4, "hidden_dim": 16, "use_direction": True}}}
        >>> with tempfile.TemporaryDirectory() as run_dir:
        ...     torch.save({"config": config, "frames": 128, "bonus_transform":
        ...                 VAESurpriseTransform(vae).state_dict()},
        ...                os.path.join(run_dir, "checkpoint.pt"))
        ...     transform, config, frames = load_bonus_transform(run_dir)
        >>> type(transform).__name__, frames, transform.frozen
        ('VAESurpriseTransform', 128, True)
    """
    from common.bonuses import VAE_VARIANTS, vae_variant_kwargs
    from common.checkpoint import find_checkpoint, load_checkpoint
    from torchrl_surprise import StateVAE

    path = Path(run_dir_or_ckpt)
    try:
        ckpt_path = find_checkpoint(path)
    except FileNotFoundError as err:
        raise FileNotFoundError(
            f"{err}. Pass a run directory of recipes/minigrid/main.py that has "
            "saved a checkpoint, or a checkpoint file."
        ) from None
    ckpt = load_checkpoint(ckpt_path)
    config = ckpt.get("config") if isinstance(ckpt, Mapping) else None
    if not isinstance(config, Mapping):
        raise NotAHeatmapRun(f"{ckpt_path}: not a recipe checkpoint (no 'config').")
    _check_heatmap_run(path, config)
    state = ckpt.get("bonus_transform")
    if state is None:
        raise ValueError(f"{ckpt_path}: the checkpoint holds no 'bonus_transform'.")
    icfg = config["intrinsic"]
    vcfg = icfg["vae"]
    variant = vcfg.get("variant", "kl")
    vae = StateVAE.for_minigrid(
        latent_dim=vcfg["latent_dim"],
        hidden_dim=vcfg["hidden_dim"],
        use_direction=vcfg["use_direction"],
    )
    # The settings a state_dict is tied to (normalisation statistics); the
    # coefficient and its schedule do not change the raw bonus.
    transform = VAE_VARIANTS[variant](
        vae,
        normalization=icfg.get("normalization", "none"),
        gamma=config.get("loss", {}).get("gamma", 0.99),
        clip=icfg.get("clip"),
        **vae_variant_kwargs(variant, vcfg),
    )
    transform.load_state_dict(state)
    transform.freeze()
    if hasattr(transform, "reset_episodes"):
        # the training envs' episodes in progress: the map starts its own
        transform.reset_episodes()
    frames = int(ckpt.get("frames", 0))
    return transform, dict(config), frames


# ------------------------------------------------------------ many runs, layouts
def _load_sources(sources: Sequence[str | os.PathLike], env_name: str | None):
    """``([(source, transform, config, frames)], env_name)``: one env for all."""
    loaded = [(str(src), *load_bonus_transform(src)) for src in sources]
    env_names = {config["env"]["name"] for _, _, config, _ in loaded}
    if env_name is None and len(env_names) > 1:
        raise ValueError(
            f"the checkpoints come from different envs {sorted(env_names)}: give "
            "those of one env, or pick the layouts' env (--env, env_name)."
        )
    return loaded, env_name or env_names.pop()


def _memories(env, memory_steps: Sequence[int]) -> list[tuple[int, Any, list]]:
    """``[(K, memory or None, cells)]``: the first ``K`` states of the layout's
    shortest solution for each of ``memory_steps`` (``K`` at most its length)."""
    if min(memory_steps) < 0:
        raise ValueError(f"--memory-steps must be >= 0, got {list(memory_steps)}.")
    # one search for the longest memory; each K takes its first K states
    images, directions, cells = solution_memory(env, max(memory_steps))
    memories = []
    for steps in memory_steps:
        k = min(steps, len(cells))
        memory = (images[:k], directions[:k]) if k else None
        memories.append((k, memory, [tuple(c) for c in cells[:k].tolist()]))
    return memories


def category_table(
    sources: Sequence[str | os.PathLike],
    layout_seeds: Sequence[int],
    *,
    env_name: str | None = None,
    open_doors: bool = False,
    memory_steps: Sequence[int] = (0,),
):
    """Each category's mean bonus, per run and layout, relative to the layout's mean.

    The bonus grids of :func:`bonus_grid` for every checkpoint of ``sources``
    on every layout of ``layout_seeds``, reduced by :func:`category_means`.
    ``relative`` divides a category's ``mean_bonus`` by the mean over all the
    layout's reachable observations (category ``all``): 1.0 is an average
    observation. It compares runs whose bonus scales differ (the KL grows as a
    VAE trains; the elliptical bonus has no unit), which
    :func:`summarize_categories` aggregates over.

    Args:
        sources: run directories or checkpoint files (:func:`load_bonus_transform`),
            all of one env unless ``env_name`` is given.
        layout_seeds: the layouts (``make_layout_env(env_name, seed)``).
        env_name: the MiniGrid env id (default: the checkpoints' ``env.name``).
        open_doors (bool): open and unlock every door first.
        memory_steps: for an episodic bonus, the episode memories
            (:func:`solution_memory` of each layout) to score the cells after.

    Returns:
        A :class:`pandas.DataFrame`, one row per run, layout, memory and category
        of :func:`category_means` (``all`` included): ``source, setting, seed,
        variant, frames, env, layout_seed, open_doors, memory_steps, category,
        unit, count, mean_bonus, relative``.

    Raises:
        ValueError: the checkpoints come from different envs and ``env_name``
            is not given; a negative memory length.

    Examples:
        >>> import tempfile, os, torch
        >>> from torchrl_surprise import StateVAE, VAESurpriseTransform
        >>> vae = StateVAE.for_minigrid(latent_dim=4, hidden_dim=16)
        >>> config = {"bonus": "vae", "seed": 0, "setting": "vae_literal",
        ...           "env": {"name": "MiniGrid-DoorKey-5x5-v0"},
        ...           "intrinsic": {"normalization": "none", "vae": {
        ...               "latent_dim": 4, "hidden_dim": 16, "use_direction": True}}}
        >>> with tempfile.TemporaryDirectory() as run_dir:
        ...     torch.save({"config": config, "frames": 128, "bonus_transform":
        ...                 VAESurpriseTransform(vae).state_dict()},
        ...                os.path.join(run_dir, "checkpoint.pt"))
        ...     table = category_table([run_dir], layout_seeds=[0, 1])
        >>> sorted(table["layout_seed"].unique().tolist())
        [0, 1]
        >>> table.loc[table["category"] == "all", "relative"].tolist()
        [1.0, 1.0]
    """
    import pandas as pd

    from results.aggregate import setting_label

    loaded, env_name = _load_sources(sources, env_name)
    labels = [
        {
            "source": src,
            "setting": setting_label(config, None),
            "seed": config.get("seed"),
            "variant": config["intrinsic"]["vae"].get("variant", "kl"),
            "frames": frames,
        }
        for src, _, config, frames in loaded
    ]
    rows = []
    for layout_seed in layout_seeds:
        env = make_layout_env(env_name, layout_seed)
        groups = _groups(env, open_doors)
        for steps, memory, _ in _memories(env, memory_steps):
            for (_, transform, _, _), label in zip(loaded, labels):
                grid = bonus_grid(transform, env, open_doors=open_doors, memory=memory)
                means = category_means(grid, groups)
                overall = means["all"]["mean_bonus"]
                for name, stats in means.items():
                    rows.append(
                        {
                            **label,
                            "env": env_name,
                            "layout_seed": layout_seed,
                            "open_doors": open_doors,
                            "memory_steps": steps,
                            "category": name,
                            "unit": stats["unit"],
                            "count": stats["count"],
                            "mean_bonus": stats["mean_bonus"],
                            "relative": stats["mean_bonus"] / overall
                            if overall
                            else float("nan"),
                        }
                    )
        env.close()
    return pd.DataFrame(rows)


def summarize_categories(table, *, reps: int = 2000, seed: int = 0):
    """Over runs: how a category's bonus compares with the layout's average.

    Each run's ``relative`` (:func:`category_table`) is averaged over the layouts
    where the category has cells; over the runs of a setting, the IQM of those
    means with a 95% stratified-bootstrap CI (rliable, as the sweeps' reports),
    and how many runs put the category above the average (> 1.0).

    Args:
        table: the output of :func:`category_table`.
        reps (int): bootstrap replications.
        seed (int): seed of the bootstrap (one stream per estimate).

    Returns:
        A :class:`pandas.DataFrame`, one row per ``env, setting, variant,
        frames, memory_steps, category`` (``all`` left out): ``runs, layouts,
        relative_iqm, relative_low, relative_high, runs_above_average,
        mean_bonus`` (the mean over runs and layouts, in the bonus's unit).

    Examples:
        >>> import pandas as pd
        >>> rows = [{"env": "E", "setting": "s", "variant": "kl", "frames": 128,
        ...          "memory_steps": 0,
        ...          "source": f"run{r}", "layout_seed": l, "category": "doorway",
        ...          "relative": 1.0 + r + l, "mean_bonus": 2.0}
        ...         for r in range(3) for l in range(2)]
        >>> row = summarize_categories(pd.DataFrame(rows), reps=100).iloc[0]
        >>> float(row["relative_iqm"]), int(row["runs_above_average"]), int(row["layouts"])
        (2.5, 3, 2)
    """
    import pandas as pd

    from results.aggregate import iqm_interval

    # checkpoints of one setting at other points of training are other rows
    keys = ["env", "setting", "variant", "frames", "memory_steps", "category"]
    table = table[table["category"] != "all"]
    per_run = (
        table.dropna(subset=["relative"])
        .groupby([*keys, "source"], sort=False)
        .agg(relative=("relative", "mean"), layouts=("layout_seed", "nunique"))
        .reset_index()
    )
    mean_bonus = table.groupby(keys, sort=False)["mean_bonus"].mean()
    rows = []
    for key, group in per_run.groupby(keys, sort=False):
        iqm, low, high = iqm_interval(
            group["relative"].to_numpy(), reps=reps, seed=seed, names=key
        )
        rows.append(
            {
                **dict(zip(keys, key)),
                "runs": len(group),
                "layouts": int(group["layouts"].max()),
                "relative_iqm": iqm,
                "relative_low": low,
                "relative_high": high,
                "runs_above_average": int((group["relative"] > 1.0).sum()),
                "mean_bonus": float(mean_bonus.loc[key]),
            }
        )
    return pd.DataFrame(rows)


# ---------------------------------------------------------------------- figure
_OUTLINE_COLOURS = {"door": "tab:orange", "goal": "lime"}


def _layout_box(env) -> tuple[int, int, int, int]:
    """``(y0, y1, x0, x1)``: the bounding box of the layout's walls and objects.

    MultiRoom draws its rooms in a corner of a 25x25 grid; the rest is empty.
    """
    grid = env.unwrapped.grid
    filled = np.array(
        [
            [grid.get(x, y) is not None for x in range(grid.width)]
            for y in range(grid.height)
        ]
    )
    rows, cols = np.flatnonzero(filled.any(1)), np.flatnonzero(filled.any(0))
    if rows.size == 0:
        return 0, grid.height, 0, grid.width
    return int(rows[0]), int(rows[-1]) + 1, int(cols[0]), int(cols[-1]) + 1


def _triangles(grid: np.ndarray):
    """One triangle per finite ``[y, x, d]``: cell centre to the edge faced."""
    polygons, values = [], []
    for y, x, d in np.argwhere(np.isfinite(grid)):
        c = (x + 0.5, y + 0.5)
        edge = {
            0: ((x + 1, y), (x + 1, y + 1)),
            1: ((x, y + 1), (x + 1, y + 1)),
            2: ((x, y), (x, y + 1)),
            3: ((x, y), (x + 1, y)),
        }[int(d)]
        polygons.append((c, *edge))
        values.append(grid[y, x, d])
    return polygons, np.asarray(values)


def plot_heatmaps(
    grids: Sequence[np.ndarray],
    background: np.ndarray,
    out: str | os.PathLike,
    *,
    titles: Sequence[str],
    suptitle: str = "",
    reduce: str = "max",
    directions: bool = False,
    shared_scale: bool = False,
    outlines: Mapping[str, Sequence[tuple[int, int]]] | None = None,
    alpha: float = 0.7,
    unit: str = "nats",
    paths: Sequence[Sequence[tuple[int, int]]] | None = None,
) -> Path:
    """Draws one panel per bonus grid over the rendered layout; writes a PNG.

    Args:
        grids: ``[H, W, 4]`` bonus grids (:func:`bonus_grid`) of one layout.
        background: the rendered layout (:func:`render_layout`).
        out: the PNG path (its folder is created).
        titles: one title per panel.
        suptitle: the figure's title.
        reduce (str): ``"max"`` or ``"mean"`` over the 4 directions per cell.
        directions (bool): draw 4 triangles per cell, one per direction (the
            triangle pointing right is the agent facing right), instead of
            reducing.
        shared_scale (bool): one colour scale for all panels (default: each
            panel its own, as the bonus scale changes during training).
        outlines: cells ``(x, y)`` to outline, by what they hold (``"door"`` and
            ``"goal"`` have their own colours), so the overlay does not hide them.
        alpha (float): opacity of the overlay.
        unit (str): the bonus's unit, on the colour bars.
        paths: per panel, cells ``(x, y)`` to mark with a dot (an episode's
            memory, :func:`solution_memory`).

    Returns:
        The path written.

    Examples:
        >>> import numpy as np, tempfile, os
        >>> grid = np.full((3, 4, 4), np.nan)
        >>> grid[1, 1:3] = [[0.1, 0.2, 0.3, 0.4], [0.5, 0.6, 0.7, 0.8]]
        >>> background = np.zeros((3 * 8, 4 * 8, 3), np.uint8)
        >>> with tempfile.TemporaryDirectory() as tmp:
        ...     png = plot_heatmaps([grid], background, os.path.join(tmp, "h.png"),
        ...                         titles=["0 frames"], outlines={"goal": [(2, 1)]})
        ...     png.stat().st_size > 0
        True
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    if reduce not in ("max", "mean"):
        raise ValueError(f"reduce must be 'max' or 'mean', got {reduce!r}.")
    if len(titles) != len(grids):
        raise ValueError(f"{len(grids)} grids but {len(titles)} titles.")
    if paths is not None and len(paths) != len(grids):
        raise ValueError(f"{len(grids)} grids but {len(paths)} paths.")
    panels = [g if directions else _reduced(g, reduce) for g in grids]
    shared = _limits(np.concatenate([p.ravel() for p in panels])) if panels else None
    height, width = grids[0].shape[:2] if grids else background.shape[:2]
    fig, axes = plt.subplots(
        1,
        len(grids),
        figsize=(5.2 * len(grids), 4.6 * height / width + 0.8),
        squeeze=False,
    )
    for i, (ax, panel, title) in enumerate(zip(axes[0], panels, titles)):
        limits = shared if shared_scale else _limits(panel)
        artist = _draw_panel(ax, panel, background, limits, directions, alpha)
        for kind, cells in (outlines or {}).items():
            _outline(ax, cells, _OUTLINE_COLOURS.get(kind, "white"))
        for x, y in paths[i] if paths is not None else ():
            ax.plot(x + 0.5, y + 0.5, "o", color="red", markersize=5)
        ax.set_title(title, fontsize=10)
        label = "bonus per direction" if directions else f"{reduce} over directions"
        fig.colorbar(artist, ax=ax, fraction=0.046, pad=0.03).set_label(
            f"raw bonus ({unit}), {label}"
        )
    if suptitle:
        fig.suptitle(suptitle, fontsize=11)
    handles = _legend_handles(outlines, paths)
    if handles:
        fig.legend(handles=handles, loc="lower center", ncol=len(handles))
    fig.tight_layout(rect=(0, 0.05 if handles else 0, 1, 1))
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=110)
    plt.close(fig)
    return out


def _reduced(grid: np.ndarray, reduce: str) -> np.ndarray:
    """A ``[H, W, 4]`` grid's max or mean over directions (NaN where unreachable)."""
    if not np.isfinite(grid).any():
        return np.full(grid.shape[:2], np.nan)
    with warnings.catch_warnings():
        # unreachable cells are all-NaN: they stay NaN (uncoloured)
        warnings.simplefilter("ignore", RuntimeWarning)
        return np.nanmax(grid, -1) if reduce == "max" else np.nanmean(grid, -1)


def _limits(values: np.ndarray) -> tuple[float, float]:
    """The colour scale of the finite values (a non-empty range)."""
    finite = values[np.isfinite(values)]
    if finite.size == 0:
        return 0.0, 1.0
    low, high = float(finite.min()), float(finite.max())
    return low, (high if high > low else low + 1e-6)


def _draw_panel(ax, panel, background, limits, directions: bool, alpha: float):
    """One panel's overlay on the layout; returns the artist its colour bar reads."""
    import matplotlib
    from matplotlib.collections import PolyCollection
    from matplotlib.colors import Normalize

    # Transparent NaN: cells the agent cannot reach keep the rendering.
    cmap = matplotlib.colormaps["viridis"].with_extremes(bad=(0.0, 0.0, 0.0, 0.0))
    norm = Normalize(*limits)
    height, width = panel.shape[:2]
    ax.imshow(background, extent=(0, width, height, 0), interpolation="nearest")
    if directions:
        polygons, values = _triangles(panel)
        artist = PolyCollection(
            polygons, array=values, cmap=cmap, norm=norm, alpha=alpha
        )
        artist.set_edgecolor("none")
        ax.add_collection(artist)
    else:
        artist = ax.imshow(
            np.ma.masked_invalid(panel),
            extent=(0, width, height, 0),
            cmap=cmap,
            norm=norm,
            alpha=alpha,
            interpolation="nearest",
        )
    ax.set_xlim(0, width)
    ax.set_ylim(height, 0)
    ax.set_xticks([])
    ax.set_yticks([])
    return artist


def _outline(ax, cells, colour) -> None:
    from matplotlib.patches import Rectangle

    for x, y in cells:
        ax.add_patch(
            Rectangle(
                (x + 0.06, y + 0.06),
                0.88,
                0.88,
                fill=False,
                edgecolor=colour,
                linewidth=1.6,
            )
        )


def _legend_handles(outlines, paths) -> list:
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch

    handles = [
        Patch(fill=False, edgecolor=_OUTLINE_COLOURS.get(kind, "white"), label=kind)
        for kind, cells in (outlines or {}).items()
        if cells
    ]
    if paths is not None and any(paths):
        handles.append(
            Line2D([], [], marker="o", color="red", linestyle="", label="memory")
        )
    return handles


# ------------------------------------------------------------------------- CLI
def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="python recipes/results/heatmap.py",
        description=(
            "Draw the VAE surprise bonus at every reachable agent position and "
            "direction of one MiniGrid layout, one panel per checkpoint."
        ),
    )
    parser.add_argument(
        "runs",
        nargs="*",
        metavar="RUN_DIR_OR_CKPT",
        help="run directories (their latest checkpoint) or checkpoint files",
    )
    parser.add_argument(
        "--checkpoint",
        action="append",
        default=[],
        metavar="PATH",
        help="a checkpoint file (repeatable; added after the positional ones)",
    )
    parser.add_argument("--layout-seed", type=int, default=0)
    parser.add_argument(
        "--summary",
        action="store_true",
        help="no picture: each category's bonus relative to the layout's mean, "
        "per run and layout (--layout-seeds), aggregated over the runs (IQM, 95%% "
        "CI); --out is then the summary CSV, the per-layout rows go beside it",
    )
    parser.add_argument(
        "--layout-seeds",
        type=int,
        nargs="+",
        default=None,
        metavar="SEED",
        help="with --summary: the layouts (default: --layout-seed)",
    )
    parser.add_argument(
        "--env",
        default=None,
        help="MiniGrid env id (default: the checkpoints' env.name)",
    )
    parser.add_argument(
        "--out",
        default=None,
        help="the PNG; the CSV goes beside it (--summary: the summary CSV)",
    )
    parser.add_argument(
        "--from-layouts",
        type=Path,
        default=None,
        metavar="LAYOUTS_CSV",
        help="recompute a --summary from the rows per run and layout it wrote "
        "(no checkpoint needed); --out defaults to the summary beside them",
    )
    _add_drawing_arguments(parser)
    return parser


def _add_drawing_arguments(parser: argparse.ArgumentParser) -> None:
    """What the layout and the picture look like."""
    parser.add_argument(
        "--open-doors",
        action="store_true",
        help="open and unlock every door first, so the rooms beyond are reachable",
    )
    parser.add_argument("--reduce", choices=("max", "mean"), default="max")
    parser.add_argument(
        "--directions",
        action="store_true",
        help="draw 4 triangles per cell (one per direction) instead of reducing",
    )
    parser.add_argument(
        "--shared-scale",
        action="store_true",
        help="one colour scale for all panels",
    )
    parser.add_argument(
        "--memory-steps",
        type=int,
        nargs="+",
        default=[0],
        metavar="K",
        help="for an episodic bonus (intrinsic.vae.variant=elliptical): score each "
        "cell as the next state of an episode that took the first K steps of the "
        "layout's shortest solution (default 0: an episode that starts there); "
        "several values draw one panel per checkpoint and value",
    )
    parser.add_argument("--tile-size", type=int, default=32)


def _format(value: float) -> str:
    return "-" if not np.isfinite(value) else f"{value:.4g}"


def main(argv: Sequence[str] | None = None) -> Path:
    """The command: loads the checkpoints, computes the grids, writes PNG and CSV.

    Returns:
        The PNG's path (``--summary``: the summary CSV's).
    """
    args = _parser().parse_args(argv)
    sources = [*args.runs, *args.checkpoint]
    if args.from_layouts is not None:
        if sources:
            _parser().error("--from-layouts takes no run directory or checkpoint")
        return _summary_main(args, sources)
    if not sources:
        _parser().error("give at least one run directory or --checkpoint")
    if args.out is None:
        _parser().error("--out is required")
    if args.summary:
        return _summary_main(args, sources)
    if args.layout_seeds is not None:
        _parser().error("--layout-seeds goes with --summary (a picture is one layout)")
    return _picture_main(args, sources)


def _picture_main(args, sources: Sequence[str]) -> Path:
    """One layout's heatmap per checkpoint (and memory), its PNG and CSV."""
    loaded, env_name = _load_sources(sources, args.env)
    env = make_layout_env(env_name, args.layout_seed)
    memories = _memories(env, args.memory_steps)  # (steps, memory or None, cells)
    variants = [
        config["intrinsic"]["vae"].get("variant", "kl") for *_, config, _ in loaded
    ]
    panels = [
        (*checkpoint, variant, memory)
        for checkpoint, variant in zip(loaded, variants)
        for memory in memories
    ]
    grids, titles, rows = _panel_grids(args, env, env_name, panels, len(memories))
    suptitle, unit = _picture_labels(args, env_name, variants, memories)
    png = _draw_picture(args, env, grids, titles, suptitle, unit, panels, memories)
    csv_path = png.with_suffix(".csv")
    with open(csv_path, "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    _print_rows(rows, suptitle, unit)
    print(f"Heatmap: {png}\nCategory means: {csv_path}")
    return png


def _panel_grids(args, env, env_name: str, panels, n_memories: int):
    """Each panel's bonus grid, its title, and its rows of category means."""
    groups = _groups(env, args.open_doors)
    one_variant = len({panel[4] for panel in panels}) == 1
    grids, titles, rows = [], [], []
    for src, transform, _, frames, variant, (steps, memory, _) in panels:
        grid = bonus_grid(transform, env, open_doors=args.open_doors, memory=memory)
        grids.append(grid)
        title = f"{frames:,} frames" if one_variant else f"{variant}, {frames:,} frames"
        if n_memories > 1:
            title += f", memory {steps} steps"
        titles.append(title)
        for name, stats in category_means(grid, groups).items():
            rows.append(
                {
                    "checkpoint": str(src),
                    "frames": frames,
                    "variant": variant,
                    "env": env_name,
                    "layout_seed": args.layout_seed,
                    "open_doors": args.open_doors,
                    "memory_steps": steps,
                    "category": name,
                    **stats,
                }
            )
    return grids, titles, rows


def _picture_labels(args, env_name: str, variants, memories) -> tuple[str, str]:
    """The figure's title and the bonus's unit."""
    one_variant = len(set(variants)) == 1
    doors = "doors open" if args.open_doors else "doors as generated"
    if any(v == "elliptical" for v in variants):
        lengths = "/".join(str(m[0]) for m in memories)
        doors += (
            f", episode memory: the first {lengths} steps of the shortest solution"
            if any(m[0] for m in memories)
            else ", empty episode memory"
        )
    bonus = f"VAE bonus {variants[0]}, " if one_variant else ""
    over = "per direction" if args.directions else args.reduce + " over directions"
    suptitle = f"{env_name}, layout seed {args.layout_seed}\n{bonus}{doors}, {over}"
    unit = "nats"
    if "elliptical" in variants:
        # phi^T C^-1 phi has no unit (times the KL's nats with global_bonus="kl")
        unit = "phi'C^-1 phi" if one_variant else "nats; elliptical: phi'C^-1 phi"
    return suptitle, unit


def _draw_picture(args, env, grids, titles, suptitle, unit, panels, memories) -> Path:
    """The heatmaps over the layout's part of the grid (:func:`plot_heatmaps`)."""
    background = render_layout(
        env, open_doors=args.open_doors, tile_size=args.tile_size
    )
    y0, y1, x0, x1 = _layout_box(env)
    t = args.tile_size
    outlines = {
        kind: [(x - x0, y - y0) for x, y in _object_cells(env, kind)]
        for kind in ("door", "goal")
    }
    has_memory = any(m[0] for m in memories)
    return plot_heatmaps(
        [grid[y0:y1, x0:x1] for grid in grids],
        background[y0 * t : y1 * t, x0 * t : x1 * t],
        args.out,
        titles=titles,
        suptitle=suptitle,
        reduce=args.reduce,
        directions=args.directions,
        shared_scale=args.shared_scale,
        outlines=outlines,
        unit=unit,
        paths=[[(x - x0, y - y0) for x, y in p[-1][2]] for p in panels]
        if has_memory
        else None,
    )


def _print_rows(rows, suptitle: str, unit: str) -> None:
    print(
        suptitle.replace("\n", ", ")
        + f": mean raw bonus ({unit}) by category of cells (max: mean of each cell's "
        "max over directions) and of observations"
    )
    print(
        f"{'checkpoint':<36} {'frames':>8} {'category':<15} {'unit':<11} "
        f"{'count':>5} {'mean':>8} {'max':>8}"
    )
    for row in rows:
        print(
            f"{row['checkpoint'][-36:]:<36} {row['frames']:>8} "
            f"{row['category']:<15} {row['unit']:<11} {row['count']:>5} "
            f"{_format(row['mean_bonus']):>8} {_format(row['mean_cell_max']):>8}"
        )


def summary_report(summary):
    """The summary of :func:`summarize_categories` as the docs show it.

    One row per setting, point of training, memory and category:
    ``relative to the average, IQM [95% CI]`` formatted, and ``runs above
    average`` as ``k of n``.

    Examples:
        >>> import pandas as pd
        >>> summary = pd.DataFrame([{"env": "E", "setting": "s", "variant": "kl",
        ...     "frames": 128, "memory_steps": 0, "category": "doorway", "runs": 5,
        ...     "layouts": 10, "relative_iqm": 1.234, "relative_low": 1.1,
        ...     "relative_high": 1.3, "runs_above_average": 4, "mean_bonus": 2.0}])
        >>> summary_report(summary).iloc[0, [0, 3, 4, 5]].tolist()
        ['s', 'doorway', '1.23 [1.10, 1.30]', '4 of 5']
    """
    import pandas as pd

    return pd.DataFrame(
        {
            "setting": summary["setting"],
            "frames": summary["frames"],
            "memory steps": summary["memory_steps"],
            "category": summary["category"],
            "bonus over the layout's mean, IQM [95% CI]": [
                f"{r.relative_iqm:.2f} [{r.relative_low:.2f}, {r.relative_high:.2f}]"
                for r in summary.itertuples()
            ],
            "runs above the mean": [
                f"{r.runs_above_average} of {r.runs}" for r in summary.itertuples()
            ],
        }
    )


#: The per-layout rows' file, xz-compressed as aggregate.py's runs.csv.xz; a
#: plain ``_layouts.csv`` of earlier data is read as well.
_LAYOUTS_SUFFIX = "_layouts.csv.xz"
_LAYOUTS_SUFFIXES = (_LAYOUTS_SUFFIX, "_layouts.csv")


def _summary_main(args, sources: Sequence[str]) -> Path:
    import pandas as pd

    if args.from_layouts is not None:
        layouts_path = args.from_layouts
        if not layouts_path.is_file():
            raise FileNotFoundError(f"{layouts_path} does not exist")
        table = pd.read_csv(layouts_path, float_precision="round_trip")
        name = layouts_path.name
        default = next(
            (name[: -len(end)] for end in _LAYOUTS_SUFFIXES if name.endswith(end)),
            None,
        )
        if args.out is None and default is None:
            raise ValueError(
                f"{layouts_path}: give --out (the name does not end in {_LAYOUTS_SUFFIX})"
            )
        out = Path(args.out) if args.out else layouts_path.with_name(default + ".csv")
    else:
        table = category_table(
            sources,
            args.layout_seeds or [args.layout_seed],
            env_name=args.env,
            open_doors=args.open_doors,
            memory_steps=args.memory_steps,
        )
        out = Path(args.out)
        layouts_path = out.with_name(out.stem + _LAYOUTS_SUFFIX)
    summary = summarize_categories(table)
    out.parent.mkdir(parents=True, exist_ok=True)
    report_path = out.with_name(out.stem + "_report.csv")
    if args.from_layouts is None:
        xz = {"method": "xz", "preset": 9}
        table.to_csv(layouts_path, index=False, compression=xz)
    summary.to_csv(out, index=False)
    summary_report(summary).to_csv(report_path, index=False)
    doors = "doors open" if table["open_doors"].all() else "doors as generated"
    print(
        f"{table['env'].iloc[0]}, layouts {sorted(set(table['layout_seed']))}, "
        f"{doors}: each category's mean bonus over the layout's mean (1.0: "
        "average), IQM [95% CI] over runs"
    )
    print(
        f"{'setting':<24} {'frames':>8} {'memory':>6} {'category':<15} {'runs':>4} "
        f"{'relative':>22} {'above 1':>7}"
    )
    for row in summary.itertuples():
        interval = (
            f"{row.relative_iqm:.2f} [{row.relative_low:.2f}, {row.relative_high:.2f}]"
        )
        print(
            f"{row.setting[:24]:<24} {row.frames:>8} {row.memory_steps:>6} "
            f"{row.category:<15} "
            f"{row.runs:>4} {interval:>22} {row.runs_above_average:>7}"
        )
    print(
        f"Summary: {out}\nFor the docs: {report_path}\nPer run and layout: {layouts_path}"
    )
    return out


if __name__ == "__main__":
    # a run the heatmap cannot draw is one line, not a traceback
    report_mistakes(main)()
