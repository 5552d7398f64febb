"""The surprise heatmap (recipes/results/heatmap.py) on one real layout.

MiniGrid-MultiRoom-N3-S4-v0, layout seed 0, with a small VAE built in-process;
the CLI reads a checkpoint the test writes in the recipe's format.
"""

from __future__ import annotations

import csv
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import torch
from tensordict import TensorDict

from results.heatmap import (
    CATEGORIES,
    NotAHeatmapRun,
    bonus_grid,
    category_means,
    category_table,
    cell_categories,
    door_views,
    load_bonus_transform,
    main,
    make_layout_env,
    reachable_cells,
    render_layout,
    solution_memory,
)
from torchrl_surprise import StateVAE, VAESurpriseTransform
from torchrl_surprise.transforms import (
    VAEEllipticalTransform,
    VAENovelDTransform,
    VAEPosteriorShiftTransform,
)

ENV = "MiniGrid-MultiRoom-N3-S4-v0"
VAE_CONFIG = {"latent_dim": 4, "hidden_dim": 16, "use_direction": True}


@pytest.fixture
def env():
    env = make_layout_env(ENV, layout_seed=0)
    yield env
    env.close()


def small_transform(cls=VAESurpriseTransform, **kwargs):
    return cls(StateVAE.for_minigrid(**VAE_CONFIG), **kwargs)


def agent_state(env):
    base = env.unwrapped
    doors = [
        (obj.is_open, obj.is_locked)
        for obj in base.grid.grid
        if obj is not None and obj.type == "door"
    ]
    return tuple(base.agent_pos), base.agent_dir, base.step_count, doors


@pytest.mark.parametrize("open_doors", [False, True])
def test_nan_exactly_where_the_agent_cannot_be(env, open_doors):
    grid = bonus_grid(small_transform(), env, open_doors=open_doors)
    base = env.unwrapped
    assert grid.shape == (base.grid.height, base.grid.width, 4)
    finite = np.isfinite(grid)
    # a cell is all finite or all NaN (4 directions)
    assert (finite.all(-1) == finite.any(-1)).all()
    reachable = reachable_cells(env, open_doors=open_doors)
    assert (finite.all(-1) == reachable).all()
    for y, x in np.argwhere(reachable):
        cell = base.grid.get(int(x), int(y))
        # (the doors are closed again once bonus_grid has returned)
        assert (
            cell is None or cell.can_overlap() or (open_doors and cell.type == "door")
        )
    for y in range(base.grid.height):
        for x in range(base.grid.width):
            cell = base.grid.get(x, y)
            if cell is not None and cell.type == "wall":
                assert not finite[y, x].any()
    x0, y0 = base.agent_pos
    assert finite[y0, x0].all()
    doors = [
        (x, y)
        for y in range(base.grid.height)
        for x in range(base.grid.width)
        if getattr(base.grid.get(x, y), "type", None) == "door"
    ]
    # closed doors cannot be stood on and wall the other rooms off
    assert all(finite[y, x].all() == open_doors for x, y in doors)
    closed = reachable_cells(env, open_doors=False)
    opened = reachable_cells(env, open_doors=True)
    assert (closed <= opened).all() and closed.sum() < opened.sum()
    assert any(
        getattr(base.grid.get(int(x), int(y)), "type", None) == "goal"
        for y, x in np.argwhere(opened)
    )


def test_bonus_equals_the_bonus_of_the_placed_agent(env):
    transform = small_transform()
    grid = bonus_grid(transform, env, open_doors=True)
    # a fresh env of the same layout, the agent really put on a door cell
    fresh = make_layout_env(ENV, layout_seed=0)
    base = fresh.unwrapped
    x, y = next(
        (x, y)
        for y in range(base.grid.height)
        for x in range(base.grid.width)
        if getattr(base.grid.get(x, y), "type", None) == "door"
    )
    for obj in base.grid.grid:  # as bonus_grid(open_doors=True) sees the layout
        if obj is not None and obj.type == "door":
            obj.is_open = True
    values = []
    for direction in range(4):
        base.agent_pos, base.agent_dir = (x, y), direction
        obs = base.gen_obs()
        td = TensorDict(
            {
                "next": {
                    "image": torch.as_tensor(obs["image"]).unsqueeze(0),
                    "direction": torch.tensor([obs["direction"]]),
                    "reward": torch.zeros(1, 1),
                }
            },
            batch_size=[1],
        )
        values.append(transform(td)["next", "intrinsic_reward"].item())
    np.testing.assert_allclose(grid[y, x], values, rtol=1e-5, atol=1e-6)
    # the four directions see different things: the test checks something
    assert len(set(np.round(values, 6))) > 1
    fresh.close()


def test_leaves_env_and_transform_as_they_were(env):
    transform = small_transform(normalization="reward_std")
    before_env = agent_state(env)
    before_stats = {
        k: v.clone() for k, v in transform.state_dict().items() if torch.is_tensor(v)
    }
    for open_doors in (False, True):
        bonus_grid(transform, env, open_doors=open_doors)
        cell_categories(env, open_doors=open_doors)
        render_layout(env, open_doors=open_doors, tile_size=8)
    assert agent_state(env) == before_env
    assert not transform.frozen
    after = transform.state_dict()
    for key, value in before_stats.items():
        assert torch.equal(after[key], value), key


def test_categories_partition_the_reachable_cells(env):
    cats = cell_categories(env, open_doors=True)
    assert tuple(cats) == CATEGORIES
    reachable = reachable_cells(env, open_doors=True)
    for name in ("doorway", "near_goal", "door_in_view"):
        assert cats[name].any(), name
    stacked = np.stack(list(cats.values()))
    assert (stacked.sum(0) == reachable).all()  # disjoint, and cover them
    base = env.unwrapped

    def kinds_around(x, y):
        return {
            getattr(base.grid.get(x + dx, y + dy), "type", None)
            for dx, dy in ((0, 0), (1, 0), (-1, 0), (0, 1), (0, -1))
        }

    for y, x in np.argwhere(cats["doorway"]):
        assert "door" in kinds_around(int(x), int(y))
    for y, x in np.argwhere(cats["near_goal"]):
        assert "goal" in kinds_around(int(x), int(y))
    views = door_views(env, open_doors=True)
    assert views[cats["door_in_view"]].any(-1).all()
    assert not views[cats["other"]].any()
    assert not views[~reachable].any()
    means = category_means(bonus_grid(small_transform(), env, open_doors=True), cats)
    assert means["doorway"]["count"] == cats["doorway"].sum()
    assert np.isfinite(means["doorway"]["mean_bonus"])


def write_checkpoint(path, transform, *, bonus="vae", variant="kl", frames=1234):
    config = {
        "bonus": bonus,
        "env": {"name": ENV},
        "loss": {"gamma": 0.99},
        "intrinsic": {
            "normalization": transform.normalization,
            "clip": None,
            "vae": {**VAE_CONFIG, "variant": variant},
        },
    }
    torch.save(
        {"config": config, "frames": frames, "bonus_transform": transform.state_dict()},
        path,
    )


def test_cli_writes_png_and_csv(tmp_path, env, capsys):
    # A posterior-shift VAE whose reference differs: the reference must load too.
    transform = small_transform(VAEPosteriorShiftTransform, normalization="return_std")
    with torch.no_grad():
        transform.vae.head.bias.add_(0.3)
    run_dir = tmp_path / "run"
    run_dir.mkdir()
    write_checkpoint(run_dir / "checkpoint.pt", transform, variant="info_gain")
    other = tmp_path / "later.pt"
    write_checkpoint(other, transform, variant="info_gain", frames=5678)

    loaded, config, frames = load_bonus_transform(run_dir)
    assert type(loaded) is VAEPosteriorShiftTransform and frames == 1234
    assert config["env"]["name"] == ENV
    expected = bonus_grid(transform, env, open_doors=True)
    np.testing.assert_allclose(
        bonus_grid(loaded, env, open_doors=True), expected, rtol=1e-5, atol=1e-6
    )
    assert np.nanmax(expected) > 0

    out = tmp_path / "maps" / "n3s4.png"
    png = main(
        [str(run_dir), "--checkpoint", str(other), "--layout-seed", "0"]
        + ["--out", str(out), "--open-doors", "--directions"]
    )
    assert png == out and out.stat().st_size > 0
    with open(out.with_suffix(".csv")) as f:
        rows = list(csv.DictReader(f))
    assert [r["frames"] for r in rows].count("1234") == len(rows) // 2
    assert {r["category"] for r in rows} >= set(CATEGORIES)
    doorway = next(r for r in rows if r["category"] == "doorway")
    cats = cell_categories(env, open_doors=True)
    assert float(doorway["mean_bonus"]) == pytest.approx(
        float(np.mean(expected[cats["doorway"]])), rel=1e-5
    )
    printed = capsys.readouterr().out
    assert "doorway" in printed and str(out) in printed


def test_clear_errors(tmp_path):
    empty = tmp_path / "empty_run"
    empty.mkdir()
    with pytest.raises(FileNotFoundError, match="empty_run"):
        load_bonus_transform(empty)
    icm_run = tmp_path / "icm_run"
    icm_run.mkdir()
    write_checkpoint(icm_run / "checkpoint.pt", small_transform(), bonus="icm")
    with pytest.raises(ValueError, match="icm_run.*'icm', not 'vae'"):
        load_bonus_transform(icm_run)
    with pytest.raises(ValueError, match="icm_run"):
        main([str(icm_run), "--out", str(tmp_path / "x.png")])
    # NovelD on the VAE pays transitions: no map, said so before anything is drawn
    noveld_run = tmp_path / "noveld_run"
    noveld_run.mkdir()
    write_checkpoint(
        noveld_run / "checkpoint.pt",
        small_transform(VAENovelDTransform),
        variant="noveld",
    )
    with pytest.raises(ValueError, match="noveld_run.*'noveld' pays a transition"):
        main([str(noveld_run), "--out", str(tmp_path / "x.png")])
    with pytest.raises(ValueError, match="memory-steps must be >= 0"):
        run_dir = tmp_path / "kl_run"
        run_dir.mkdir()
        write_checkpoint(run_dir / "checkpoint.pt", small_transform())
        main(
            [
                str(run_dir),
                "--out",
                str(tmp_path / "x.png"),
                "--memory-steps",
                "0",
                "-1",
            ]
        )


def elliptical_by_hand(transform, images, directions, memory):
    # phi^T C^-1 phi, C = ridge I + the memory's phi phi^T
    vae = transform.vae
    with torch.no_grad():
        phi = vae.posterior(torch.as_tensor(images), torch.as_tensor(directions))[0]
        past = vae.posterior(torch.as_tensor(memory[0]), torch.as_tensor(memory[1]))[0]
    phi, past = phi.double(), past.double()
    cov = transform.ridge * torch.eye(phi.shape[-1], dtype=torch.float64)
    cov = cov + past.T @ past
    return (phi * torch.linalg.solve(cov, phi.T).T).sum(-1)


def test_elliptical_map_scores_each_cell_after_the_episode_memory(env):
    transform = small_transform(VAEEllipticalTransform)
    images, directions, cells = solution_memory(env, 6)
    assert len(images) == 6 and env_untouched(env)
    # the memory follows the oracle: each state is one step from the last
    steps = np.abs(np.diff(np.concatenate([[env.unwrapped.agent_pos], cells]), axis=0))
    assert (steps.sum(-1) <= 1).all()

    # doors as generated: the by-hand observations below see the same grid
    empty = bonus_grid(transform, env)
    after = bonus_grid(transform, env, memory=(images, directions))
    mask = np.isfinite(empty)
    assert (np.isfinite(after) == mask).all()
    # by hand on every reachable observation
    base = env.unwrapped
    ys, xs = np.nonzero(mask.any(-1))
    queries = []
    for x, y in zip(xs, ys):
        for d in range(4):
            base.agent_pos, base.agent_dir = (int(x), int(y)), d
            obs = base.gen_obs()
            queries.append((obs["image"], obs["direction"]))
    env.reset(seed=0)
    q_images = np.stack([q[0] for q in queries])
    q_dirs = np.array([q[1] for q in queries])
    no_memory = (images[:0], directions[:0])
    np.testing.assert_allclose(
        empty[ys, xs].reshape(-1),
        elliptical_by_hand(transform, q_images, q_dirs, no_memory).numpy(),
        rtol=1e-4,
    )
    np.testing.assert_allclose(
        after[ys, xs].reshape(-1),
        elliptical_by_hand(transform, q_images, q_dirs, (images, directions)).numpy(),
        rtol=1e-4,
    )
    # a state of the memory is worth less after it than at an episode's start
    seen = [(x, y, d) for (x, y), d in zip(cells, directions) if mask[y, x, d]]
    assert seen
    for x, y, d in seen:
        assert after[y, x, d] < empty[y, x, d]
    # the transform's own episodes are left empty
    assert transform.memory.inv_cov.numel() == 0


def env_untouched(env):
    base = env.unwrapped
    return base.step_count == 0


def test_cli_draws_an_elliptical_run_with_its_episode_memory(tmp_path, capsys):
    run_dir = tmp_path / "elliptical_run"
    run_dir.mkdir()
    transform = small_transform(VAEEllipticalTransform, normalization="return_std")
    write_checkpoint(run_dir / "checkpoint.pt", transform, variant="elliptical")
    loaded, _, _ = load_bonus_transform(run_dir)
    assert type(loaded) is VAEEllipticalTransform
    out = tmp_path / "ell.png"
    main([str(run_dir), "--out", str(out), "--open-doors", "--memory-steps", "0", "5"])
    assert out.stat().st_size > 0
    with open(out.with_suffix(".csv")) as f:
        rows = list(csv.DictReader(f))
    # one panel per memory length, the longer memory scoring lower on average
    by_steps = {
        r["memory_steps"]: float(r["mean_bonus"])
        for r in rows
        if r["category"] == "all"
    }
    assert set(by_steps) == {"0", "5"} and by_steps["5"] < by_steps["0"]
    assert "first 0/5 steps of the shortest solution" in capsys.readouterr().out


def test_summary_over_runs_and_layouts(tmp_path, capsys):
    # Two runs (two different VAEs) on two layouts: the per-layout rows are the
    # grids' category means, relative to the layout's mean, and the summary
    # aggregates each run's mean over the layouts.
    runs = []
    for i in range(2):
        transform = small_transform()
        with torch.no_grad():
            transform.vae.head.bias.add_(0.5 * i)
        run_dir = tmp_path / f"run{i}"
        run_dir.mkdir()
        write_checkpoint(run_dir / "checkpoint.pt", transform)
        runs.append((run_dir, transform))
    # another point of training of the first run: a row of its own
    later = tmp_path / "run0_later.pt"
    write_checkpoint(later, runs[0][1], frames=5678)
    out = tmp_path / "summary" / "n3s4_categories.csv"
    path = main(
        [str(r) for r, _ in runs]
        + ["--checkpoint", str(later), "--summary", "--layout-seeds", "0", "1"]
        + ["--open-doors", "--out", str(out)]
    )
    assert path == out
    layouts = pd.read_csv(out.with_name("n3s4_categories_layouts.csv.xz"))
    assert sorted(layouts["layout_seed"].unique()) == [0, 1]
    per_run = {}
    for run_dir, transform in runs:
        means = []
        for layout_seed in (0, 1):
            env = make_layout_env(ENV, layout_seed=layout_seed)
            grid = bonus_grid(transform, env, open_doors=True)
            doorway = grid[cell_categories(env, open_doors=True)["doorway"]]
            row = layouts[
                (layouts["source"] == str(run_dir))
                & (layouts["layout_seed"] == layout_seed)
                & (layouts["category"] == "doorway")
            ].iloc[0]
            assert row["mean_bonus"] == pytest.approx(float(doorway.mean()), rel=1e-5)
            expected = (
                doorway.mean() / grid[reachable_cells(env, open_doors=True)].mean()
            )
            assert row["relative"] == pytest.approx(float(expected), rel=1e-5)
            means.append(expected)
            env.close()
        per_run[run_dir] = np.mean(means)
    summary = pd.read_csv(out)
    assert "all" not in set(summary["category"])
    doorways = summary[summary["category"] == "doorway"].set_index("frames")
    assert doorways.loc[5678, "runs"] == 1
    assert doorways.loc[5678, "relative_iqm"] == pytest.approx(per_run[runs[0][0]])
    doorway = doorways.loc[1234]
    assert doorway["runs"] == 2 and doorway["layouts"] == 2
    # the IQM of two runs is their mean
    assert doorway["relative_iqm"] == pytest.approx(np.mean(list(per_run.values())))
    assert (
        doorway["relative_low"] <= doorway["relative_iqm"] <= doorway["relative_high"]
    )
    assert doorway["runs_above_average"] == sum(v > 1 for v in per_run.values())
    report = pd.read_csv(out.with_name("n3s4_categories_report.csv"))
    assert len(report) == len(summary)
    assert f"{doorway['runs_above_average']} of 2" in set(report.iloc[:, -1])
    # the same summary and table from the rows per run and layout alone
    layouts_csv = out.with_name("n3s4_categories_layouts.csv.xz")
    again = tmp_path / "again"
    again.mkdir()
    copied = again / layouts_csv.name
    copied.write_bytes(layouts_csv.read_bytes())
    assert main(["--from-layouts", str(copied)]) == again / out.name
    for name in (out.name, "n3s4_categories_report.csv"):
        assert (again / name).read_bytes() == (out.parent / name).read_bytes(), name
    printed = capsys.readouterr().out
    assert "doorway" in printed and str(out) in printed


def test_summary_refuses_mixed_envs_and_layouts_without_summary(tmp_path):
    transform = small_transform()
    first, second = tmp_path / "a.pt", tmp_path / "b.pt"
    write_checkpoint(first, transform)
    write_checkpoint(second, transform)
    state = torch.load(second, weights_only=False)
    state["config"]["env"]["name"] = "MiniGrid-DoorKey-5x5-v0"
    torch.save(state, second)
    with pytest.raises(ValueError, match="different envs.*DoorKey-5x5.*N3-S4"):
        category_table([first, second], [0])
    with pytest.raises(SystemExit):
        main([str(first), "--layout-seeds", "0", "1", "--out", str(tmp_path / "x.png")])
    with pytest.raises(FileNotFoundError, match="nowhere_layouts.csv"):
        main(["--from-layouts", str(tmp_path / "nowhere_layouts.csv")])


def test_a_ddpg_run_is_refused_in_one_line_naming_the_minigrid_recipe(tmp_path):
    # a DDPG run with the VAE bonus: its VAE has no use_direction, no maze
    transform = small_transform()
    config = {
        "bonus": "vae",
        "env": {"name": "Hopper-v5"},
        "intrinsic": {"normalization": "none", "vae": {"latent_dim": 4}},
    }
    torch.save(
        {"config": config, "frames": 600, "bonus_transform": transform.state_dict()},
        tmp_path / "checkpoint.pt",
    )
    with pytest.raises(NotAHeatmapRun, match="heatmap maps a MiniGrid maze"):
        load_bonus_transform(tmp_path)
    script = Path(__file__).resolve().parents[1] / "recipes" / "results" / "heatmap.py"
    proc = subprocess.run(
        [sys.executable, str(script), str(tmp_path), "--out", str(tmp_path / "h")],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert proc.returncode == 2
    (line,) = proc.stderr.strip().splitlines()
    assert line.startswith(f"Error: {tmp_path} is a run of Hopper-v5, not of the")
    assert "recipes/minigrid/main.py with bonus=vae" in line
