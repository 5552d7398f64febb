"""The aggregation command on a fake sweep whose every number is known by hand.

Task ``MiniGrid-Fake-v0`` (oracle mean return 0.8) has two settings from Hydra
overrides, 4 seeds each, logged every 1000 frames up to 10000. The ``vae`` seeds
ramp linearly to normalised final returns 1.3, 0.55, 0.75 and 0.25; the ``none``
seeds stay at 0 (seed 0 logged step 5000 twice, first 0.5 then 0). Task
``HalfCheetah-v5`` has no oracle return: a setting named in the config and one
labelled by its bonus (no overrides file), 2 seeds each, one of them killed at
6000 of 10000 frames.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import yaml

from results.aggregate import (
    _figure,
    _save,
    extract_run_data,
    find_runs,
    main,
    merge_run_data,
    probability_of_improvement,
    read_oracle,
    runs_metadata,
    setting_label,
    status_text,
)

MINIGRID, CHEETAH = "MiniGrid-Fake-v0", "HalfCheetah-v5"
ORACLE_RETURN = 0.8
#: Normalised final train return of each seed of the vae setting.
VAE_FINALS = [1.3, 0.55, 0.75, 0.25]
STEPS = list(range(0, 10001, 1000))
REPS = 50


def write_run(
    run_dir: Path,
    config: dict,
    overrides: list[str] | None,
    scalars: dict[str, list[tuple[int, float]]],
    algo: str = "a2c",
) -> None:
    """A run directory as the recipes leave it: config, overrides, CSVLogger files."""
    run_dir.mkdir(parents=True)
    (run_dir / "config_resolved.yaml").write_text(yaml.safe_dump(config))
    if overrides is not None:
        (run_dir / ".hydra").mkdir()
        (run_dir / ".hydra" / "overrides.yaml").write_text(yaml.safe_dump(overrides))
    for name, rows in scalars.items():
        path = run_dir / "logs" / algo / "scalars" / f"{name}.csv"
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text("".join(f"{step},{value}\n" for step, value in rows))


def minigrid_run(root: Path, bonus: str, seed: int, final: float) -> None:
    raw = [(s, final * ORACLE_RETURN * s / 10000) for s in STEPS]
    if bonus == "none" and seed == 0:
        # A resumed run logged step 5000 again: the second value is the one kept.
        raw.insert(5, (5000, 0.5))
    overrides = [f"bonus={bonus}", f"seed={seed}", f"env.name={MINIGRID}"]
    overrides += ["+experiment=fake", "hydra.job.chdir=false"]
    if bonus == "vae":
        overrides.append("intrinsic.coef=0.1")
    config = {
        "seed": seed,
        "bonus": bonus,
        "env": {"name": MINIGRID},
        "collector": {"total_frames": 10000},
    }
    write_run(
        root / ",".join(overrides[:3]),
        config,
        overrides,
        {
            # The moving mean is NaN until an episode ends: dropped.
            "train/episode_return": [(0, float("nan")), *raw[1:]],
            "train/success_rate": [(s, float(v > 0)) for s, v in raw],
            "eval/episode_return": [(s, v) for s, v in raw if s % 5000 == 0],
        },
    )


def cheetah_run(root: Path, setting: str | None, seed: int, last: int) -> None:
    config = {
        "seed": seed,
        "bonus": "none" if setting is None else "vae",
        "env": {"name": CHEETAH},
        "collector": {"total_frames": 10000},
    }
    if setting is not None:
        config["setting"] = setting
    rows = [(s, 100.0 * (seed + 1) * s / 1000) for s in STEPS if s <= last]
    write_run(
        root / f"{setting}_{seed}",
        config,
        None if setting is None else ["bonus=vae", f"seed={seed}"],
        {"train/episode_return": rows, "eval/episode_return": rows[::5]},
        algo="ddpg",
    )


@pytest.fixture(scope="module")
def sweep(tmp_path_factory) -> dict[str, Path]:
    root = tmp_path_factory.mktemp("aggregate")
    for seed, final in enumerate(VAE_FINALS):
        minigrid_run(root / "runs" / "minigrid", "vae", seed, final)
        minigrid_run(root / "runs" / "minigrid", "none", seed, 0.0)
    for seed in (0, 1):
        cheetah_run(
            root / "runs" / "cheetah", "cheetah_vae", seed, 6000 if seed else 10000
        )
        cheetah_run(root / "runs" / "cheetah", None, seed, 10000)
    oracle = root / "oracle_returns.csv"
    pd.DataFrame(
        {
            "env": [MINIGRID, "MiniGrid-Other-v0"],
            "backend": "gymnasium",
            "seeds": 10,
            "mean_return": [0.8, 0.5],
        }
    ).to_csv(oracle, index=False)
    out = root / "results"
    argv = [str(root / "runs" / "minigrid"), str(root / "runs" / "cheetah")]
    assert (
        main([*argv, "--out", str(out), "--oracle", str(oracle), "--reps", str(REPS)])
        == 0
    )
    return {"root": root, "out": out, "oracle": oracle}


def read(out: Path, name: str) -> pd.DataFrame:
    return pd.read_csv(out / name, keep_default_na=False, na_values=[""])


def summary_row(out: Path, task: str, setting: str) -> pd.Series:
    summary = read(out, "summary.csv")
    rows = summary[(summary["task"] == task) & (summary["setting"] == setting)]
    assert len(rows) == 1
    return rows.iloc[0]


def test_setting_labels(sweep):
    summary = read(sweep["out"], "summary.csv")
    assert list(zip(summary["task"], summary["setting"], summary["seeds"])) == [
        (CHEETAH, "cheetah_vae", 2),
        (CHEETAH, "none", 2),
        (MINIGRID, "bonus=none", 4),
        (MINIGRID, "bonus=vae,intrinsic.coef=0.1", 4),
    ]
    assert setting_label({"bonus": "icm", "setting": ""}, ["seed=3"]) == "icm"


def test_final_iqm_is_the_mean_of_the_middle_two_normalised_seeds(sweep):
    row = summary_row(sweep["out"], MINIGRID, "bonus=vae,intrinsic.coef=0.1")
    middle = sorted(VAE_FINALS)[1:3]
    assert row["train_return_iqm"] == pytest.approx(np.mean(middle), abs=1e-4)
    assert row["train_return_mean"] == pytest.approx(np.mean(VAE_FINALS), abs=1e-4)
    assert (
        row["train_return_ci_low"]
        <= row["train_return_iqm"]
        <= row["train_return_ci_high"]
    )
    assert row["train_return_seeds"] == 4
    assert row["budget"] == 10000
    # Success is not normalised; the eval return is, at its own last step <= budget.
    assert row["train_success_iqm"] == pytest.approx(1.0)
    assert row["eval_return_iqm"] == pytest.approx(np.mean(middle), abs=1e-4)
    assert pd.isna(row["eval_success_iqm"]) and row["eval_success_seeds"] == 0


def test_final_scores_are_the_per_seed_values_the_summary_aggregates(sweep):
    finals = read(sweep["out"], "final_scores.csv")
    train = finals[finals["metric"] == "train/episode_return"]
    vae = train[train["setting"] == "bonus=vae,intrinsic.coef=0.1"]
    # one row per seed, normalised, read at the budget
    assert list(vae["seed"]) == [0, 1, 2, 3]
    assert list(vae["value"]) == pytest.approx(VAE_FINALS)
    assert (vae["frames"] == 10000).all() and (vae["budget"] == 10000).all()
    # HalfCheetah's budget is its shortest run's 6000 frames: seed 0 ran on to
    # 10000 and is read at 6000, unnormalised (100 and 200 per 1000 frames)
    cheetah = train[train["setting"] == "cheetah_vae"]
    assert list(cheetah["frames"]) == [6000, 6000]
    assert list(cheetah["value"]) == pytest.approx([600.0, 1200.0])
    row = summary_row(sweep["out"], MINIGRID, "bonus=vae,intrinsic.coef=0.1")
    assert row["train_return_seeds"] == len(vae)
    assert row["train_return_mean"] == pytest.approx(vae["value"].mean(), abs=1e-4)


def test_oracle_normalises_only_the_tasks_it_knows(sweep):
    row = summary_row(sweep["out"], MINIGRID, "bonus=vae,intrinsic.coef=0.1")
    assert bool(row["normalized"]) and row["oracle_return"] == ORACLE_RETURN
    runs = read(sweep["out"], "runs.csv.xz")
    raw = runs[
        (runs["task"] == MINIGRID)
        & (runs["seed"] == 0)
        & runs["setting"].str.startswith("bonus=vae")
        & (runs["metric"] == "train/episode_return")
    ]
    # runs.csv keeps raw returns: 1.3 of an oracle return of 0.8.
    assert raw["value"].iloc[-1] == pytest.approx(1.3 * ORACLE_RETURN)
    cheetah = summary_row(sweep["out"], CHEETAH, "none")
    assert not bool(cheetah["normalized"]) and pd.isna(cheetah["oracle_return"])
    # Seeds 0 and 1 reach 100 and 200 per 1000 frames; the budget is 6000 frames.
    assert cheetah["train_return_mean"] == pytest.approx(900.0)
    assert pd.isna(cheetah["median_frames_to_0.5"])


def test_frames_to_threshold_per_seed_and_censoring(sweep):
    table = read(sweep["out"], "frames_to_threshold.csv")
    vae = table[table["setting"].str.startswith("bonus=vae")]
    at = {(s, f): v for s, f, v in zip(vae["seed"], vae["fraction"], vae["frames"])}
    assert at[0, 0.5] == 4000 and at[0, 0.8] == 7000 and at[0, 0.9] == 7000
    assert at[1, 0.5] == 10000 and at[2, 0.5] == 7000
    assert all(pd.isna(at[s, f]) for s, f in [(1, 0.8), (2, 0.8), (3, 0.5), (3, 0.9)])
    assert set(table["task"]) == {MINIGRID}  # no oracle, no threshold
    assert (table["searched_to"] == 10000).all()

    row = summary_row(sweep["out"], MINIGRID, "bonus=vae,intrinsic.coef=0.1")
    # 0.5: 4000, 7000, 10000 and one never: the median of the middle two.
    assert row["seeds_reaching_0.5"] == 3 and row["median_frames_to_0.5"] == "8500"
    # 0.8: one seed of four: the median is not reached.
    assert (
        row["seeds_reaching_0.8"] == 1 and row["median_frames_to_0.8"] == "not reached"
    )


def test_a_step_logged_twice_keeps_its_last_value(sweep):
    runs = read(sweep["out"], "runs.csv.xz")
    mine = runs[
        (runs["setting"] == "bonus=none")
        & (runs["seed"] == 0)
        & (runs["metric"] == "train/episode_return")
    ]
    assert mine["frames"].tolist() == STEPS[1:]  # NaN at step 0 dropped, 5000 once
    assert mine.loc[mine["frames"] == 5000, "value"].tolist() == [0.0]
    row = summary_row(sweep["out"], MINIGRID, "bonus=none")
    assert row["seeds_reaching_0.5"] == 0


def test_an_unfinished_run_is_marked_and_sets_the_budget(sweep):
    meta = read(sweep["out"], "runs_meta.csv")
    cheetah = meta[meta["task"] == CHEETAH].set_index(["setting", "seed"])
    assert cheetah.loc[("cheetah_vae", 1), "last_frame"] == 6000
    assert not cheetah.loc[("cheetah_vae", 1), "finished"]
    assert cheetah["finished"].sum() == 3 and meta["finished"].sum() == 11
    assert summary_row(sweep["out"], CHEETAH, "cheetah_vae")["seeds_unfinished"] == 1
    assert summary_row(sweep["out"], CHEETAH, "none")["budget"] == 6000


def test_probability_of_improvement(sweep):
    table = read(sweep["out"], "probability_of_improvement.csv")
    assert len(table) == 4  # two ordered pairs per task
    vae_over_none = table[table["setting_x"].str.startswith("bonus=vae")].iloc[0]
    assert vae_over_none["probability"] == pytest.approx(1.0)  # every vae seed > 0
    assert vae_over_none["seeds_x"] == vae_over_none["seeds_y"] == 4


def test_probability_of_improvement_is_rliables_to_the_bit():
    from rliable import metrics

    rng = np.random.default_rng(0)
    for runs_x, runs_y, tasks in [(5, 5, 1), (3, 7, 1), (4, 2, 3), (1, 1, 1)]:
        for _ in range(50):
            # few distinct values: ties within and across settings, and resamples
            # that are the same array (rliable's 0.5 without a test)
            x = rng.integers(0, 3, (runs_x, tasks)) / 2
            y = rng.integers(0, 3, (runs_y, tasks)) / 2
            for a, b in [(x, y), (x, x)]:
                expected = metrics.probability_of_improvement(a, b)
                assert probability_of_improvement(a, b) == expected
    # scores rliable takes that a subtraction would get wrong
    inf, nan = np.inf, np.nan
    for a, b in [
        (np.array([[inf], [1.0]]), np.array([[inf], [0.0]])),
        (np.array([[nan], [1.0]]), np.array([[0.0], [2.0]])),
        (np.array([[0], [255]], np.uint8), np.array([[1], [3]], np.uint8)),
    ]:
        expected = metrics.probability_of_improvement(a, b)
        np.testing.assert_equal(probability_of_improvement(a, b), expected)


def test_from_data_regenerates_identical_tables(sweep, tmp_path):
    out = sweep["out"]
    argv = ["--from-data", str(out / "runs.csv.xz"), "--out", str(tmp_path)]
    np.random.seed(123)
    expected = np.random.rand()
    np.random.seed(123)
    assert main([*argv, "--oracle", str(sweep["oracle"]), "--reps", str(REPS)]) == 0
    # The bootstraps seed NumPy's global generator and give it back untouched.
    assert np.random.rand() == expected
    for name in (
        "summary.csv",
        "final_scores.csv",
        "frames_to_threshold.csv",
        "probability_of_improvement.csv",
    ):
        assert (tmp_path / name).read_bytes() == (out / name).read_bytes(), name
    for name in ("curves.png", "performance_profiles.png"):
        assert (out / name).stat().st_size > 0 and (tmp_path / name).stat().st_size > 0


def test_a_sweep_aggregated_in_parts_equals_it_aggregated_at_once(sweep, tmp_path):
    # part 1 (the MiniGrid runs) committed; part 2 (the HalfCheetah runs) added to
    # it later: the same runs.csv, metadata and tables as the whole sweep at once
    runs, oracle = sweep["root"] / "runs", ["--oracle", str(sweep["oracle"])]
    common = [*oracle, "--reps", str(REPS)]
    part = tmp_path / "part"
    assert main([str(runs / "minigrid"), "--out", str(part), *common]) == 0
    assert set(read(part, "summary.csv")["task"]) == {MINIGRID}
    whole = tmp_path / "whole"
    argv = [str(runs / "cheetah"), "--from-data", str(part / "runs.csv.xz")]
    assert main([*argv, "--out", str(whole), *common]) == 0
    for name in ("runs.csv.xz", "runs_meta.csv", "summary.csv", "report.csv"):
        assert (whole / name).read_bytes() == (sweep["out"] / name).read_bytes(), name
    # in place, and again: a rerun replaces each run by itself
    for _ in range(2):
        argv = [str(runs / "cheetah"), "--from-data", str(part / "runs.csv.xz")]
        assert main([*argv, "--out", str(part), *common]) == 0
        assert (part / "runs.csv.xz").read_bytes() == (
            whole / "runs.csv.xz"
        ).read_bytes()


def test_earlier_data_without_its_runs_meta_merges_and_reads_as_finished(
    sweep, tmp_path
):
    # a runs.csv copied away from its runs_meta.csv (or written before it existed):
    # its runs have no completion recorded, so none is reported as unfinished; the
    # new part's unfinished run (cheetah_vae seed 1) still is, as with full metadata
    runs, oracle = sweep["root"] / "runs", ["--oracle", str(sweep["oracle"])]
    common = [*oracle, "--reps", str(REPS)]
    part = tmp_path / "part"
    assert main([str(runs / "minigrid"), "--out", str(part), *common]) == 0
    (part / "runs_meta.csv").unlink()
    out = tmp_path / "out"
    argv = [str(runs / "cheetah"), "--from-data", str(part / "runs.csv.xz")]
    assert main([*argv, "--out", str(out), *common]) == 0
    assert (out / "runs.csv.xz").read_bytes() == (
        sweep["out"] / "runs.csv.xz"
    ).read_bytes()
    status = (out / "status.rst").read_text()
    assert status == (sweep["out"] / "status.rst").read_text()
    # the sweep covers two tasks, so each setting is named with its task; the
    # budget (none given: the frames every run of the task reached) is 6k, so the
    # run is unfinished and in the scores
    assert (
        "Past the budget, not yet at their own total_frames (in the final scores, "
        f"read at the budget): {CHEETAH} cheetah_vae seed 1 (6k of 10k" in status
    )
    assert f"{CHEETAH} cheetah_vae 2, {CHEETAH} none 2, {MINIGRID} " in status
    assert "bonus=" not in status.split("Past the budget")[1]
    meta = read(out, "runs_meta.csv")
    assert meta[meta["task"] == MINIGRID]["total_frames"].isna().all()


def test_a_run_unfinished_but_past_the_budget_is_scored_and_said_so(sweep, tmp_path):
    # cheetah_vae seed 1 stopped at 6k of its 10k frames: at a budget of 5k it is
    # past the budget (a study aggregated at a budget below its runs' own, or runs
    # extended beyond it), so its score counts and the status does not say it is
    # left out
    runs = sweep["root"] / "runs" / "cheetah"
    out = tmp_path / "out"
    argv = [str(runs), "--out", str(out), "--budget", "5000", "--reps", str(REPS)]
    assert main(argv) == 0
    status = (out / "status.rst").read_text()
    assert "leave them out" not in status
    assert (
        "Past the budget, not yet at their own total_frames (in the final scores, "
        "read at the budget): cheetah_vae seed 1 (6k of 10k frames)." in status
    )
    scores = read(out, "final_scores.csv")
    returns = scores[scores["metric"] == "train/episode_return"]
    vae = returns[returns["setting"] == "cheetah_vae"]
    assert sorted(vae["seed"]) == [0, 1]
    assert (vae["frames"] <= 5000).all()
    assert status.startswith("Seeds that reached the budget, per setting: ")
    assert "cheetah_vae 2, none 2." in status


def test_the_status_of_unfinished_runs_needs_the_scores_that_hold_them(sweep):
    # which unfinished runs are in the scores is final_scores' rule, not a second
    # one: without its table the status refuses to guess
    summary, meta = (
        read(sweep["out"], "summary.csv"),
        read(sweep["out"], "runs_meta.csv"),
    )
    with pytest.raises(ValueError, match="needs the final scores"):
        status_text(summary, meta)
    scores = read(sweep["out"], "final_scores.csv")
    assert (
        status_text(summary, meta, scores) == (sweep["out"] / "status.rst").read_text()
    )


def test_settings_keeps_only_the_runs_of_those_settings(sweep, tmp_path):
    runs, data = sweep["root"] / "runs", sweep["out"] / "runs.csv.xz"
    common = ["--oracle", str(sweep["oracle"]), "--reps", str(REPS)]
    vae = "bonus=vae,intrinsic.coef=0.1"  # the MiniGrid runs' label
    some = [vae, "cheetah_vae"]
    # new runs added to committed data, then only two settings kept
    out = tmp_path / "some"
    argv = [str(runs / "cheetah"), "--from-data", str(data), "--settings", *some]
    assert main([*argv, "--out", str(out), *common]) == 0
    full = read(sweep["out"], "runs.csv.xz")
    expected = full[full["setting"].isin(some)].reset_index(drop=True)
    pd.testing.assert_frame_equal(read(out, "runs.csv.xz"), expected)
    assert set(read(out, "runs_meta.csv")["setting"]) == set(some)
    assert set(read(out, "summary.csv")["setting"]) == set(some)

    # a setting's row does not depend on the settings left out, to the byte
    # (frame counts stay integers beside an unnormalised task's empty cells)
    def line(results):
        text = (results / "summary.csv").read_text().splitlines()
        return [row for row in text if row.startswith(f'{MINIGRID},gymnasium,"{vae}"')]

    assert len(line(out)) == 1 and line(out) == line(sweep["out"])
    # from the committed data alone
    alone = tmp_path / "alone"
    argv = ["--from-data", str(data), "--settings", "none", "--out", str(alone)]
    assert main([*argv, *common]) == 0
    assert set(read(alone, "runs.csv.xz")["setting"]) == {"none"}


def test_settings_selects_from_a_data_file_copied_away_from_its_meta(
    sweep, tmp_path, capsys
):
    # `git show REV:.../runs.csv.xz > old.csv.xz` leaves runs_meta.csv behind
    copy = tmp_path / "old.csv.xz"
    copy.write_bytes((sweep["out"] / "runs.csv.xz").read_bytes())
    common = ["--oracle", str(sweep["oracle"]), "--reps", str(REPS)]
    out = tmp_path / "none"
    argv = ["--from-data", str(copy), "--settings", "none", "--out", str(out)]
    assert main([*argv, *common]) == 0
    assert f"no runs_meta.csv beside {copy}" in capsys.readouterr().err
    meta = read(out, "runs_meta.csv")
    full = read(sweep["out"], "runs_meta.csv")
    expected = full[full["setting"] == "none"]
    assert sorted(meta["seed"]) == sorted(expected["seed"])
    # each run's last logged frame; its budget and completion unknown
    assert list(meta["last_frame"]) == list(expected["last_frame"])
    assert meta["finished"].isna().all() and set(meta["run_dir"]) == {str(copy)}


def test_tasks_keeps_only_the_runs_of_those_tasks(sweep, tmp_path):
    data = sweep["out"] / "runs.csv.xz"
    common = ["--oracle", str(sweep["oracle"]), "--reps", str(REPS)]
    out = tmp_path / "cheetah"
    argv = ["--from-data", str(data), "--tasks", CHEETAH, "--settings", "none"]
    assert main([*argv, "--out", str(out), *common]) == 0
    full = read(sweep["out"], "runs.csv.xz")
    keep = (full["task"] == CHEETAH) & (full["setting"] == "none")
    expected = full[keep].reset_index(drop=True)
    # (the selected returns happen to be whole numbers: read back as integers)
    pd.testing.assert_frame_equal(read(out, "runs.csv.xz"), expected, check_dtype=False)
    assert set(read(out, "runs_meta.csv")["task"]) == {CHEETAH}
    assert set(read(out, "summary.csv")["task"]) == {CHEETAH}


@pytest.mark.parametrize(
    "option, kept, absent, present",
    [
        ("--settings", "bonus=vae,intrinsic.coef=0.1", "rnd", "cheetah_vae"),
        ("--tasks", CHEETAH, "Ant-v5", CHEETAH),
    ],
)
def test_a_selection_in_place_or_without_runs_is_refused(
    sweep, tmp_path, capsys, option, kept, absent, present
):
    data = sweep["out"] / "runs.csv.xz"
    common = ["--oracle", str(sweep["oracle"]), "--reps", str(REPS)]
    # in place it would drop committed runs: refused, the file untouched
    before = data.read_bytes()
    argv = ["--from-data", str(data), option, kept, "--out", str(sweep["out"])]
    with pytest.raises(SystemExit):
        main([*argv, *common])
    assert f"{option} would drop runs" in capsys.readouterr().err
    assert data.read_bytes() == before
    # a selection without runs is named, with those there are; nothing written
    argv = ["--from-data", str(data), option, absent, "--out", str(tmp_path / "x")]
    with pytest.raises(SystemExit):
        main([*argv, *common])
    err = capsys.readouterr().err
    assert f"['{absent}']" in err and f"'{present}'" in err
    assert not (tmp_path / "x").exists()


def test_adding_a_shorter_run_than_the_committed_one_is_refused(
    sweep, tmp_path, capsys
):
    out = tmp_path / "out"
    out.mkdir()
    for name in ("runs.csv.xz", "runs_meta.csv"):
        (out / name).write_bytes((sweep["out"] / name).read_bytes())
    before = (out / "runs.csv.xz").read_bytes()
    # seed 0 of cheetah_vae again, killed at 4000 frames where the data has 10000
    cheetah_run(tmp_path / "again", "cheetah_vae", 0, 4000)
    argv = [str(tmp_path / "again"), "--from-data", str(out / "runs.csv.xz")]
    with pytest.raises(SystemExit):
        main([*argv, "--out", str(out), "--oracle", "none", "--reps", str(REPS)])
    err = capsys.readouterr().err
    assert "seed 0" in err and "cheetah_vae_0" in err and "reached frame 4000" in err
    assert "10000" in err and "longer run" in err
    assert (out / "runs.csv.xz").read_bytes() == before
    # the same run further on replaces it; every other run is kept
    cheetah_run(tmp_path / "further", "cheetah_vae", 1, 10000)
    argv = [str(tmp_path / "further"), "--from-data", str(out / "runs.csv.xz")]
    assert main([*argv, "--out", str(out), "--oracle", "none", "--reps", "10"]) == 0
    meta = read(out, "runs_meta.csv").set_index(["task", "setting", "seed"])
    assert len(meta) == 12 and meta.loc[(CHEETAH, "cheetah_vae", 1), "finished"]
    assert meta.loc[(CHEETAH, "cheetah_vae", 1), "last_frame"] == 10000


def test_data_without_metadata_keeps_its_runs_by_their_last_frame(sweep):
    runs = find_runs([sweep["root"] / "runs" / "minigrid"])
    earlier = extract_run_data(runs[:3])
    data, meta = extract_run_data(runs[2:]), runs_metadata(runs[2:])
    merged, merged_meta = merge_run_data(earlier, None, data, meta, source="old.csv")
    assert merged.equals(extract_run_data(runs))
    assert len(merged_meta) == len(runs)
    # the two runs known only from the data: their last frame, their source
    old = merged_meta.iloc[:2]
    assert (old["last_frame"] == 10000).all() and (old["run_dir"] == "old.csv").all()
    assert old["total_frames"].isna().all() and old["finished"].isna().all()
    new = merged_meta.iloc[2:].reset_index(drop=True)
    assert new.to_csv(index=False) == meta.to_csv(index=False)


def test_a_run_short_of_the_budget_is_left_out_of_final_scores(sweep, tmp_path):
    argv = [str(sweep["root"] / "runs" / "cheetah"), "--out", str(tmp_path)]
    assert main([*argv, "--budget", "8500", "--reps", str(REPS)]) == 0
    row = summary_row(tmp_path, CHEETAH, "cheetah_vae")
    assert row["budget"] == 8500 and row["seeds_short_of_budget"] == 1
    # Seed 0 at its last point before the budget, 8000 frames (800); seed 1
    # stopped at 6000 frames, more than a logging period short: left out.
    assert row["train_return_mean"] == pytest.approx(800.0)
    assert row["train_return_seeds"] == 1


def test_extract_keeps_at_most_max_points_and_the_last(sweep):
    runs = find_runs([sweep["root"] / "runs" / "minigrid"])
    data = extract_run_data(runs, max_points=4)
    counts = data.groupby(["setting", "seed", "metric"])["frames"].agg(["size", "max"])
    assert counts["size"].max() == 4 and (counts["max"] == 10000).all()


def test_no_run_directory_is_a_clear_error(tmp_path, capsys):
    empty = tmp_path / "empty_sweep"
    empty.mkdir()
    with pytest.raises(SystemExit):
        main([str(empty), "--out", str(tmp_path / "out")])
    assert "no run directory" in capsys.readouterr().err
    with pytest.raises(FileNotFoundError, match="empty_sweep"):
        find_runs([empty])
    with pytest.raises(SystemExit):
        main([str(tmp_path / "missing"), "--out", str(tmp_path / "out")])
    assert str(tmp_path / "missing") in capsys.readouterr().err


def test_a_threshold_counts_only_once_the_episode_window_is_full():
    from results.aggregate import frames_to_threshold

    # The first episodes to end are the short successes (return 0.8 at 1000
    # frames), the time-outs end later and pull the mean down; the 100-episode
    # window fills at 3000 frames, where the return is 0.5 of the oracle's.
    rows = [(1000, 0.8, 10), (2000, 0.2, 60), (3000, 0.5, 120), (4000, 0.9, 200)]
    run = {"task": "A", "backend": "gymnasium", "setting": "s", "seed": 0}
    data = pd.DataFrame(
        [
            {**run, "frames": f, "metric": "train/episode_return", "value": v}
            for f, v, _ in rows
        ]
        + [
            {**run, "frames": f, "metric": "train/episodes", "value": n}
            for f, _, n in rows
        ]
    )
    oracle = {("A", "gymnasium"): 1.0}
    table = frames_to_threshold(data, oracle, fractions=[0.5, 0.8])
    assert table["frames"].tolist() == [3000, 4000]
    # A run that logged no episode count is read as before.
    plain = data[data["metric"] == "train/episode_return"]
    table = frames_to_threshold(plain, oracle, fractions=[0.5, 0.8])
    assert table["frames"].tolist() == [1000, 1000]


_SUMMARY_HEADER = (
    "task,backend,setting,oracle_return,budget,seeds,train_return_iqm,"
    "train_return_ci_low,train_return_ci_high\n"
)


def _committed(
    tmp_path,
    name,
    recipe,
    rows,
    task="MiniGrid-MultiRoom-N3-S4-v0",
    backend="gymnasium",
):
    # a committed experiment: its summary rows (setting, IQM) and its runs' recipe
    (tmp_path / name).mkdir()
    (tmp_path / name / "summary.csv").write_text(
        _SUMMARY_HEADER
        + "".join(
            f'{task},{backend},"{s}",0.8,500000,5,{v},{v - 0.1},{v + 0.05}\n'
            for s, v in rows
        )
    )
    (tmp_path / name / "runs_meta.csv").write_text(
        f'run_dir\n"runs/{recipe}/{name}/+setting={rows[0][0]},seed=0"\n'
    )


def test_a_run_is_shown_beside_the_plain_learner_and_the_best_setting(tmp_path):
    from common.minigrid import measured_comparison

    task = "MiniGrid-MultiRoom-N3-S4-v0"
    _committed(tmp_path, "a_small", "a2c_minigrid", [("icm", 0.36)])
    _committed(
        tmp_path,
        "b_main",
        "a2c_minigrid",
        [("none", 0.0), ("vae_elliptical", 0.94), ("icm", 0.36)],
    )
    _committed(tmp_path, "c_ppo", "ppo_minigrid", [("none", 0.99), ("rnd", 1.0)])
    lines = measured_comparison(
        task, "gymnasium", 500_000, tmp_path, "a2c_minigrid", run_return=0.76
    ).splitlines()
    # one summary, the one with the most settings of the run's own learner
    assert "b_main" in lines[0] and "return / oracle" in lines[0]
    assert lines[1].split() == ["this", "run", "0.95"]  # 0.76 / 0.8
    assert lines[2].split()[:4] == ["none", "(plain", "learner)", "0.00"]
    assert lines[3].split()[:3] == ["vae_elliptical", "(best)", "0.94"]
    assert "[0.84, 0.99], 5 seeds" in lines[3]
    assert len(lines) == 4
    ppo = measured_comparison(
        task, "gymnasium", 500_000, tmp_path, "ppo_minigrid"
    ).splitlines()
    assert "c_ppo" in ppo[0] and ppo[2].split()[:3] == ["rnd", "(best)", "1.00"]
    # a setting without a score (an unfinished seed) is left out, and the best
    # is another setting than the plain learner
    _committed(
        tmp_path,
        "d_more",
        "a2c_minigrid",
        [("none", 0.0), ("rnd", 0.3), ("icm", 0.2), ("e3b", 0.1)],
    )
    summary = tmp_path / "d_more" / "summary.csv"
    summary.write_text(
        summary.read_text() + f'{task},gymnasium,"vae",0.8,500000,1,,,\n'
    )
    lines = measured_comparison(
        task, "gymnasium", 500_000, tmp_path, "a2c_minigrid"
    ).splitlines()
    assert "d_more" in lines[0] and lines[2].split()[:2] == ["rnd", "(best)"]
    _committed(
        tmp_path,
        "e_plain",
        "a2c_minigrid",
        [("none", 0.5), ("x", 0.1), ("y", 0.1), ("z", 0.1), ("w", 0.1), ("v", 0.1)],
    )
    lines = measured_comparison(
        task, "gymnasium", 500_000, tmp_path, "a2c_minigrid"
    ).splitlines()
    assert "e_plain" in lines[0] and lines[2].split()[1] == "(best)"  # not none
    # another budget, another noise level, a task not measured: nothing
    on = (task, "gymnasium")
    assert measured_comparison(*on, 1_000_000, tmp_path, "a2c_minigrid") == ""
    assert measured_comparison(*on, 500_000, tmp_path, "a2c_minigrid", 2) == ""
    empty = ("MiniGrid-Empty-5x5-v0", "gymnasium")
    assert measured_comparison(*empty, 500_000, tmp_path, "a2c") == ""


def test_a_run_is_compared_at_its_noise_level_and_on_its_backend_first(tmp_path):
    from common.minigrid import measured_comparison

    task = "MiniGrid-MultiRoom-N3-S4-v0"
    _committed(
        tmp_path,
        "noise",
        "a2c_minigrid",
        [
            ("icm", 0.34),
            ("icm,env.stochasticity=2", 0.27),
            ("none,env.stochasticity=2", 0.0),
        ],
    )
    level2 = measured_comparison(
        task, "gymnasium", 500_000, tmp_path, "a2c_minigrid", 2
    )
    assert "none,env.stochasticity=2 (plain learner)" in level2
    assert "icm,env.stochasticity=2 (best)" in level2 and "0.34" not in level2

    def on_envpool() -> str:
        return measured_comparison(task, "envpool", 500_000, tmp_path, "a2c_minigrid")

    # a run on envpool: envpool's layouts' results, else minigrid's envs'
    assert on_envpool().startswith(f"Measured on {task} at") and "noise" in on_envpool()
    _committed(tmp_path, "pool", "a2c_minigrid", [("vae", 0.93)], backend="envpool")
    assert on_envpool().startswith(f"Measured on {task} (envpool) at")
    assert "pool" in on_envpool()
    # the summary's task and backend columns pick the rows, not the env id alone:
    # a run on minigrid's envs is never shown envpool's results
    gymnasium = measured_comparison(
        task, "gymnasium", 500_000, tmp_path, "a2c_minigrid"
    )
    assert "pool" not in gymnasium.splitlines()[0] and "(envpool)" not in gymnasium
    # the plain learner measured on minigrid's envs beats no plain learner on envpool
    _committed(tmp_path, "main", "a2c_minigrid", [("none", 0.0), ("vae", 0.9)])
    assert on_envpool().startswith(f"Measured on {task} at") and "main" in on_envpool()
    assert "none (plain learner)" in on_envpool()
    (tmp_path / "main" / "runs_meta.csv").unlink()
    # an experiment whose runs' recipe is unknown (no runs_meta.csv) is not shown
    (tmp_path / "pool" / "runs_meta.csv").unlink()
    assert "(envpool)" not in on_envpool().splitlines()[0]


def test_all_regenerates_every_experiment_of_a_results_dir(sweep, tmp_path):
    import shutil

    # two experiments: the sweep's, and the same data aggregated at a budget
    results = tmp_path / "results"
    shutil.copytree(sweep["out"], results / "a")
    b = results / "nested" / "b"
    b.mkdir(parents=True)
    for name in ("runs.csv.xz", "runs_meta.csv"):
        shutil.copy(results / "a" / name, b / name)
    oracle = ["--oracle", str(sweep["oracle"]), "--reps", str(REPS)]
    args = ["--from-data", str(b / "runs.csv.xz"), *oracle, "--budget", "600"]
    assert main([*args, "--out", str(b)]) == 0
    tables = ("summary.csv", "probability_of_improvement.csv", "report.csv")
    expected = {p: p.read_bytes() for p in results.glob("**/*.csv") if p.name in tables}
    for path in expected:
        if path.name != "summary.csv":  # it holds the budget to use
            path.write_text("stale")
        else:
            os.utime(path, (0, 0))
    assert main(["--all", str(results), *oracle]) == 0
    assert all(p.stat().st_mtime > 0 for p in expected)
    for path, content in expected.items():
        assert path.read_bytes() == content, path
    assert set(pd.read_csv(results / "nested" / "b" / "summary.csv")["budget"]) == {600}


def test_the_data_is_an_xz_csv_and_earlier_plain_data_is_read_and_replaced(
    sweep, tmp_path
):
    import lzma
    import shutil

    xz = (sweep["out"] / "runs.csv.xz").read_bytes()
    plain = lzma.decompress(xz)  # a CSV any tool reads, compressed
    assert plain.startswith(b"task,backend,setting,seed,frames,metric,value\n")
    assert len(xz) < len(plain) / 5
    # data committed before as a plain runs.csv: read, and its directory's data
    # rewritten as the compressed file with the same bytes inside
    study = tmp_path / "study"
    study.mkdir()
    (study / "runs.csv").write_bytes(plain)
    shutil.copy(sweep["out"] / "runs_meta.csv", study / "runs_meta.csv")
    common = ["--oracle", str(sweep["oracle"]), "--reps", str(REPS)]
    argv = ["--from-data", str(study / "runs.csv"), "--tasks"]
    assert (
        main(
            [*argv, *sorted(set(read(sweep["out"], "summary.csv")["task"]))]
            + ["--out", str(tmp_path / "copy"), *common]
        )
        == 0
    )
    assert (tmp_path / "copy" / "runs.csv.xz").read_bytes() == xz
    runs = sweep["root"] / "runs"
    argv = [str(runs / "minigrid"), "--from-data", str(study / "runs.csv")]
    assert main([*argv, "--out", str(study), *common]) == 0
    assert not (study / "runs.csv").exists()
    assert (study / "runs.csv.xz").is_file()


def test_all_redraws_only_the_figures_a_study_holds(sweep, tmp_path):
    import shutil

    study = tmp_path / "results" / "study"
    shutil.copytree(sweep["out"], study)
    (study / "performance_profiles.png").unlink()
    os.utime(study / "curves.png", (0, 0))
    argv = ["--all", str(tmp_path / "results"), "--oracle", str(sweep["oracle"])]
    assert main([*argv, "--reps", str(REPS)]) == 0
    assert (study / "curves.png").stat().st_mtime > 0  # redrawn
    assert not (study / "performance_profiles.png").exists()  # a figure no page shows
    # --all with --figures draws those
    argv = ["--all", str(tmp_path / "results"), "--oracle", str(sweep["oracle"])]
    assert (
        main([*argv, "--reps", str(REPS), "--figures", "performance_profiles.png"]) == 0
    )
    assert (study / "performance_profiles.png").is_file()
    # a single study draws every figure unless told otherwise
    out = tmp_path / "one"
    argv = ["--from-data", str(study / "runs.csv.xz"), "--out", str(out)]
    common = ["--oracle", str(sweep["oracle"]), "--reps", str(REPS)]
    assert main([*argv, *common]) == 0
    assert (out / "performance_profiles.png").is_file()
    assert main([*argv, *common, "--out", str(tmp_path / "none"), "--figures"]) == 0
    assert not list((tmp_path / "none").glob("*.png"))


def test_all_refuses_a_dir_without_data_and_mixed_arguments(tmp_path, capsys):
    with pytest.raises(SystemExit):
        main(["--all", str(tmp_path)])
    assert "no runs.csv" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["--all", str(tmp_path), "--out", str(tmp_path)])
    assert "--all takes no" in capsys.readouterr().err


def test_a_setting_at_several_noise_levels_gets_one_label_per_level_and_a_figure(
    sweep, tmp_path
):
    # the same setting (config label) at levels 0 and 2, 4 seeds each: one label
    # per level, and levels.png with one line from the two summary rows
    for level, final in [(0, 0.9), (2, 0.3)]:
        for seed in range(4):
            config = {
                "seed": seed,
                "bonus": "vae",
                "setting": "vae_ell",
                "env": {"name": MINIGRID, "stochasticity": level},
                "collector": {"total_frames": 10000},
            }
            rows = [(s, final * ORACLE_RETURN * s / 10000) for s in STEPS[1:]]
            write_run(
                tmp_path / "runs" / f"{level}_{seed}",
                config,
                None,
                {"train/episode_return": rows},
            )
    runs = find_runs([tmp_path / "runs"])
    assert sorted({r.setting for r in runs}) == [
        "vae_ell",
        "vae_ell,env.stochasticity=2",
    ]
    out = tmp_path / "out"
    argv = [str(tmp_path / "runs"), "--out", str(out), "--reps", str(REPS)]
    assert main([*argv, "--oracle", str(sweep["oracle"])]) == 0
    assert summary_row(out, MINIGRID, "vae_ell,env.stochasticity=2")[
        "train_return_iqm"
    ] == pytest.approx(0.3)
    assert (out / "levels.png").stat().st_size > 0
    # a results dir without levels has no such figure
    assert not (sweep["out"] / "levels.png").exists()


@pytest.mark.parametrize("n_panels", [1, 3])
def test_the_legend_fits_the_figure_and_clears_the_panels(tmp_path, n_panels):
    # a one-panel figure with four long setting names (a single-task transfer
    # sweep) would cut a 3-column legend at both edges: fewer columns, and the
    # figure grows by the rows this adds, so the legend stays below the x labels
    fig, axes = _figure(n_panels)
    names = [f"vae_elliptical_from_n3s4_frozen_{i} (5 seeds)" for i in range(4)]
    for ax in axes:
        for name in names:
            ax.plot([0, 1], [0, 1], label=name)
        ax.set_xlabel("frames")
    _save(fig, tmp_path / "f.png", "a title " * 20)
    assert (tmp_path / "f.png").stat().st_size > 0
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    renderer = FigureCanvasAgg(fig).get_renderer()  # the closed figure's own is gone
    (legend,) = fig.legends
    box = legend.get_window_extent(renderer)
    assert [t.get_text() for t in legend.get_texts()] == names
    assert 0 <= box.x0 and box.x1 <= fig.bbox.width
    assert box.y0 >= 0
    for ax in axes:
        assert box.y1 <= ax.get_tightbbox(renderer).y0 + 1


def _short_run(root: Path, seed: int, overrides: list[str], status: dict | None):
    # a 1,024-frame run whose log_interval let it log one row, at 128 frames
    config = {
        "seed": seed,
        "bonus": "vae",
        "env": {"name": MINIGRID},
        "collector": {"total_frames": 1024},
    }
    run_dir = root / f"run_{seed}"
    write_run(
        run_dir,
        config,
        ["bonus=vae", f"seed={seed}", *overrides],
        {"train/episode_return": [(128, 0.5)]},
    )
    if status is not None:
        (run_dir / "status.json").write_text(json.dumps(status))
    return run_dir


def test_a_run_is_finished_when_its_status_says_so(tmp_path, capsys):
    done = {"frames": 1024, "total_frames": 1024, "finished": True}
    _short_run(tmp_path / "runs", 0, [], done)
    _short_run(tmp_path / "runs", 1, [], {**done, "frames": 512, "finished": False})
    _short_run(tmp_path / "runs", 2, [], None)  # an older run dir: the guess
    meta = runs_metadata(find_runs([tmp_path / "runs"]))
    assert meta["finished"].tolist() == [True, False, False]
    main([str(tmp_path / "runs"), "--out", str(tmp_path / "out"), "--oracle", "none"])
    out = capsys.readouterr().out
    assert "Unfinished: MiniGrid-Fake-v0 bonus=vae seed 1 (128 of 1024" in out
    assert "seed 0" not in out  # finished: its status says so


def test_overrides_of_what_a_run_reports_do_not_split_its_setting(tmp_path):
    # seed 1 was started, then resumed with other logger, eval and checkpoint
    # settings: its overrides.yaml holds them, its setting is seed 0's
    _short_run(tmp_path / "runs", 0, ["intrinsic.coef=0.1"], None)
    reported = ["logger.backend=tensorboard", "eval.interval_frames=64"]
    reported += ["checkpoint.keep=true", "checkpoint.interval_frames=128"]
    reported += ["torch_threads=2", "resume=true", "resume_without_logs=true"]
    _short_run(tmp_path / "runs", 1, ["intrinsic.coef=0.1", *reported], None)
    runs = find_runs([tmp_path / "runs"])
    assert [r.setting for r in runs] == ["bonus=vae,intrinsic.coef=0.1"] * 2


def test_a_damaged_log_line_is_named(tmp_path, capsys):
    run_dir = _short_run(tmp_path / "runs", 0, [], None)
    log = run_dir / "logs" / "a2c" / "scalars" / "train" / "episode_return.csv"
    log.write_text("64,0.25\nline\n128,0.5\n")
    with pytest.raises(SystemExit):
        main([str(run_dir), "--out", str(tmp_path / "out"), "--oracle", "none"])
    assert f"{log}, line 2: 'line' is not a 'step,value' row" in capsys.readouterr().err


def test_one_env_id_on_two_backends_is_two_tasks_each_normalised_by_its_oracle(
    tmp_path, monkeypatch, capsys
):
    # the same env id on both backends: two tasks, the backend column telling them
    # apart, each normalised by its own oracle row
    for backend, final in (("gymnasium", 0.4), ("envpool", 0.6)):
        for seed in (0, 1):
            config = {
                "seed": seed,
                "bonus": "vae",
                "setting": "vae",
                "env": {"name": MINIGRID, "backend": backend},
                "collector": {"total_frames": 10000},
            }
            rows = [(s, final * s / 10000) for s in STEPS]
            write_run(
                tmp_path / "runs" / f"{backend}_{seed}",
                config,
                [f"seed={seed}", f"env.backend={backend}"],
                {"train/episode_return": rows, "eval/episode_return": rows},
            )
    minigrid_oracle, envpool_oracle = tmp_path / "a.csv", tmp_path / "b.csv"
    pd.DataFrame(
        {"env": [MINIGRID], "backend": ["gymnasium"], "mean_return": [0.8]}
    ).to_csv(minigrid_oracle, index=False)
    pd.DataFrame(
        {"env": [MINIGRID], "backend": ["envpool"], "mean_return": [0.6]}
    ).to_csv(envpool_oracle, index=False)
    titles = []

    def save(fig, path, title):  # the figures' panel titles, instead of the files
        titles.append([ax.get_title() for ax in fig.axes if ax.get_visible()])
        return path

    monkeypatch.setattr("results.aggregate._save", save)
    out = tmp_path / "out"
    argv = [str(tmp_path / "runs"), "--out", str(out), "--reps", str(REPS)]
    assert main([*argv, "--oracle", str(minigrid_oracle), str(envpool_oracle)]) == 0
    assert f"{MINIGRID} (envpool)  vae: 2 seeds" in capsys.readouterr().out
    summary = read(out, "summary.csv").set_index(["task", "backend"])
    # the env id alone in the task column, gymnasium's row first
    assert summary.index.tolist() == [(MINIGRID, "gymnasium"), (MINIGRID, "envpool")]
    assert summary.loc[(MINIGRID, "gymnasium"), "oracle_return"] == pytest.approx(0.8)
    assert summary.loc[(MINIGRID, "gymnasium"), "train_return_mean"] == 0.5
    assert summary.loc[(MINIGRID, "envpool"), "oracle_return"] == pytest.approx(0.6)
    assert summary.loc[(MINIGRID, "envpool"), "train_return_mean"] == 1.0
    # every table has the backend column right after the task
    for name in (
        "runs.csv.xz",
        "runs_meta.csv",
        "summary.csv",
        "final_scores.csv",
        "frames_to_threshold.csv",
        "probability_of_improvement.csv",
        "report.csv",
    ):
        table = read(out, name)
        assert table.columns[:2].tolist() == ["task", "backend"], name
        if len(table):  # one setting per task: no probability of improvement
            assert table["backend"].unique().tolist() == ["gymnasium", "envpool"]
    assert read(out, "report.csv")["task"].unique().tolist() == ["Fake-v0"]
    status = (out / "status.rst").read_text()
    assert f"setting: {MINIGRID} vae 2, {MINIGRID} (envpool) vae 2." in status
    # a panel names the env id, and the backend where it is not gymnasium
    assert titles[0] == [MINIGRID, f"{MINIGRID} (envpool)"]
    assert titles[1] == [
        f"{MINIGRID} at 10000 frames",
        f"{MINIGRID} (envpool) at 10000 frames",
    ]
    # one task in two oracle tables is ambiguous: refused, naming the table
    with pytest.raises(ValueError, match="another table"):
        read_oracle(minigrid_oracle, minigrid_oracle)
    # and twice in one table (several action noises of one task): refused too
    pd.DataFrame(
        {"env": [MINIGRID] * 2, "backend": "gymnasium", "mean_return": [0.8, 0.7]}
    ).to_csv(minigrid_oracle, index=False)
    with pytest.raises(ValueError, match="is twice .* one --oracle file per noise"):
        read_oracle(minigrid_oracle)


def test_a_table_without_a_backend_column_is_refused_saying_how_to_regenerate(
    sweep, tmp_path, capsys
):
    # tables written before the backend column existed: refused, not guessed at
    out = tmp_path / "old"
    out.mkdir()
    data = read(sweep["out"], "runs.csv.xz")
    data.drop(columns="backend").to_csv(out / "runs.csv.xz", index=False)
    common = ["--out", str(tmp_path / "new"), "--oracle", str(sweep["oracle"])]
    with pytest.raises(SystemExit):
        main(["--from-data", str(out / "runs.csv.xz"), *common])
    err = capsys.readouterr().err
    expected = "task,backend,setting,seed,frames,metric,value"
    assert (
        f"{out / 'runs.csv.xz'} has no backend column: expected the columns {expected}"
        in err
    )
    assert (
        "regenerate it with recipes/results/aggregate.py from the run directories"
        in err
    )
    # its runs_meta.csv too, beside data that has the column
    data.to_csv(out / "runs.csv.xz", index=False)
    meta = read(sweep["out"], "runs_meta.csv").drop(columns="backend")
    meta.to_csv(out / "runs_meta.csv", index=False)
    with pytest.raises(SystemExit):
        main(["--from-data", str(out / "runs.csv.xz"), *common])
    assert f"{out / 'runs_meta.csv'} has no backend column" in capsys.readouterr().err
    # and an oracle table
    legacy = tmp_path / "oracle.csv"
    pd.DataFrame({"env": [MINIGRID], "mean_return": [0.8]}).to_csv(legacy, index=False)
    with pytest.raises(ValueError) as refused:
        read_oracle(legacy)
    message = str(refused.value)
    assert (
        "has no backend column: expected the columns env,backend,mean_return" in message
    )
    assert "recipes/results/oracle.py" in message
    assert not (tmp_path / "new" / "summary.csv").exists()


def test_label_keys_tell_apart_runs_of_one_setting(tmp_path, capsys):
    # A sweep over a hyperparameter beside a named setting: the setting's label
    # alone cannot tell its runs apart; --label-keys adds the key's value.
    for num_envs, final in ((16, 1.0), (64, 0.0)):
        config = {
            "seed": 0,
            "bonus": "vae",
            "setting": "noveld",
            "env": {"name": MINIGRID, "num_envs": num_envs},
            "collector": {"total_frames": 10000},
        }
        raw = [(s, final * ORACLE_RETURN * s / 10000) for s in STEPS]
        write_run(
            tmp_path / "runs" / f"noveld_{num_envs}",
            config,
            ["+setting=noveld", "seed=0", f"env.num_envs={num_envs}"],
            {"train/episode_return": raw[1:]},
        )
    argv = [str(tmp_path / "runs"), "--oracle", "none", "--reps", str(REPS)]
    with pytest.raises(SystemExit):
        main([*argv, "--out", str(tmp_path / "out")])
    assert "tell them apart with --label-keys" in capsys.readouterr().err
    out = tmp_path / "split"
    assert main([*argv, "--out", str(out), "--label-keys", "env.num_envs"]) == 0
    summary = read(out, "summary.csv").set_index("setting")
    assert sorted(summary.index) == ["noveld,env.num_envs=16", "noveld,env.num_envs=64"]
    assert summary.loc["noveld,env.num_envs=16", "train_return_mean"] == pytest.approx(
        ORACLE_RETURN
    )
    assert summary.loc["noveld,env.num_envs=64", "train_return_mean"] == 0.0
    with pytest.raises(ValueError, match="no 'collector.frames_per_env'"):
        find_runs([tmp_path / "runs"], ["collector.frames_per_env"])
    with pytest.raises(ValueError, match="'env' is a dict, not a value"):
        find_runs([tmp_path / "runs"], ["env"])
    # a key the label already holds is not added twice
    runs = find_runs([tmp_path / "runs"], ["env.num_envs", "env.num_envs"])
    assert [run.setting for run in runs] == [
        "noveld,env.num_envs=16",
        "noveld,env.num_envs=64",
    ]
    # labels come from run directories: not with --from-data alone
    with pytest.raises(SystemExit):
        main(
            [
                "--from-data",
                str(out / "runs.csv.xz"),
                "--out",
                str(tmp_path / "x"),
                "--label-keys",
                "env.num_envs",
            ]
        )
    assert "--label-keys labels the runs of run directories" in capsys.readouterr().err


def test_a_committed_study_regenerates_byte_for_byte_from_its_data(tmp_path):
    # What `make figures` does for every study, for one small one: its committed
    # tables are what its committed data gives (2 settings x 2 seeds, with
    # bootstrapped intervals and probabilities of improvement).
    root = Path(__file__).resolve().parents[1] / "docs" / "results"
    study = root / "e3b_128_lr_doorkey16x16"
    budget = pd.read_csv(study / "summary.csv")["budget"].unique()
    assert len(budget) == 1
    oracle = sorted(str(p) for p in (root / "oracle").glob("*oracle_returns*.csv"))
    argv = ["--from-data", str(study / "runs.csv.xz"), "--out", str(tmp_path)]
    argv += ["--budget", str(int(budget[0])), "--oracle", *oracle, "--figures"]
    assert main(argv) == 0
    for name in (
        "summary.csv",
        "report.csv",
        "final_scores.csv",
        "frames_to_threshold.csv",
        "probability_of_improvement.csv",
        "status.rst",
    ):
        assert (tmp_path / name).read_bytes() == (study / name).read_bytes(), (
            f"docs/results/{study.name}/{name} is stale: run `make figures`"
        )
