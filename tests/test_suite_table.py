"""The suite's table on two fake suite experiments aggregated by aggregate.py.

Task ``MiniGrid-KeyCorridorS3R3-v0@envpool`` (oracle 0.5, budget 1000 frames):
``vae_a`` ends every seed at 0.95 of the oracle, ``vae_b`` at 0.5, ``e3b`` at 0.2,
``none`` at 0, 3 seeds each, every run a straight ramp (so a seed's moving return
crosses 0.9 of the oracle at frames ``1000 * 0.9 / final``). Task
``MiniGrid-DoorKey-16x16-v0@envpool`` (no oracle: scored by its success rate,
budget 2000) has one seed of ``none``, ``vae_a`` (ending at a success rate of 0.5)
and ``noveld`` (at 0.6).
"""

from __future__ import annotations

from pathlib import Path

import pandas as pd
import pytest

from results.aggregate import main as aggregate_main
from results.suite import SuiteInputError, main, read_published, short_task, write_suite

S3R3, D16 = "MiniGrid-KeyCorridorS3R3-v0@envpool", "MiniGrid-DoorKey-16x16-v0@envpool"
ORACLE = {S3R3: 0.5}
FINALS = {
    S3R3: {
        "none": [0.0] * 3,
        "e3b": [0.2] * 3,
        "vae_a": [0.95] * 3,
        "vae_b": [0.5] * 3,
    },
    D16: {"none": [0.0], "vae_a": [0.5], "noveld": [0.6]},
}
BUDGETS = {S3R3: 1000, D16: 2000}
PUBLISHED = """task,method,learner,metric,value,budget_frames,seeds,source
DoorKey-16x16,E3B,PPO,normalised score,0.98,not stated,,"RLeXplore README, figure"
DoorKey-16x16,RND,PPO,normalised score,0.02,not stated,,"RLeXplore README, figure"
DoorKey-16x16,RIDE,IMPALA,return,0.5,30000000,,"a paper, figure 3"
"""


def _runs_csv(path: Path, task: str) -> None:
    budget = BUDGETS[task]
    oracle = ORACLE.get(task, 1.0)
    rows = [
        {
            "task": task,
            "setting": setting,
            "seed": seed,
            "frames": frames,
            "metric": metric,
            "value": final
            * (oracle if metric.endswith("return") else 1.0)
            * frames
            / budget,
        }
        for setting, finals in FINALS[task].items()
        for seed, final in enumerate(finals)
        for frames in range(budget // 10, budget + 1, budget // 10)
        for metric in ("train/episode_return", "train/success_rate")
    ]
    path.parent.mkdir(parents=True)
    pd.DataFrame(rows).to_csv(path, index=False)


@pytest.fixture(scope="module")
def suite(tmp_path_factory) -> dict[str, Path]:
    root = tmp_path_factory.mktemp("suite")
    oracle = root / "oracle.csv"
    pd.DataFrame(
        {"env": list(ORACLE), "seeds": 10, "mean_return": list(ORACLE.values())}
    ).to_csv(oracle, index=False)
    dirs = []
    for task in (S3R3, D16):
        directory = root / short_task(task)
        _runs_csv(directory / "runs.csv", task)
        argv = ["--from-data", str(directory / "runs.csv"), "--out", str(directory)]
        argv += [
            "--oracle",
            str(oracle),
            "--budget",
            str(BUDGETS[task]),
            "--reps",
            "50",
        ]
        assert aggregate_main(argv) == 0
        dirs.append(directory)
    published = root / "published.csv"
    published.write_text(PUBLISHED)
    out = root / "suite"
    assert (
        main([*map(str, dirs), "--published", str(published), "--out", str(out)]) == 0
    )
    return {"root": root, "dirs": dirs, "out": out, "published": published}


def read(out: Path, name: str) -> pd.DataFrame:
    return pd.read_csv(out / name, keep_default_na=False, na_values=[""])


def test_each_task_is_scored_at_its_own_budget_against_its_oracle(suite):
    table = read(suite["out"], "table.csv").set_index(["task", "setting"])
    assert table.loc[("KeyCorridorS3R3", "vae_a"), "budget"] == 1000
    assert table.loc[("DoorKey-16x16", "vae_a"), "budget"] == 2000
    assert table.loc[("KeyCorridorS3R3", "vae_a"), "iqm"] == pytest.approx(0.95)
    assert table.loc[("KeyCorridorS3R3", "e3b"), "iqm"] == pytest.approx(0.2)
    assert table.loc[("DoorKey-16x16", "noveld"), "iqm"] == pytest.approx(0.6)
    metric = table["metric"].groupby("task").unique()
    assert metric.to_dict() == {
        "DoorKey-16x16": ["success"],
        "KeyCorridorS3R3": ["return / oracle"],
    }


def test_a_setting_solves_a_task_at_0_9_of_the_oracle_with_its_frames(suite):
    table = read(suite["out"], "table.csv").set_index(["task", "setting"])
    solved = table[table["solved"]].index.tolist()
    assert solved == [("KeyCorridorS3R3", "vae_a")]
    # a straight ramp to 0.95 crosses 0.9 at 1000 * 0.9 / 0.95 = 947 frames; the
    # first logged step at or past it is 1000
    assert table.loc[("KeyCorridorS3R3", "vae_a"), "median_frames_to_solve"] == 1000
    assert table.loc[("KeyCorridorS3R3", "vae_a"), "seeds_reaching"] == 3
    frames = read(suite["out"], "frames_to_solve.csv").set_index("task")
    assert frames.loc["KeyCorridorS3R3", "vae_a"] == "1k (3/3)"
    assert frames.loc["KeyCorridorS3R3", "e3b"] == "not reached (0/3)"
    # without an oracle there are no frames to 0.9 of its return
    assert pd.isna(frames.loc["DoorKey-16x16", "noveld"])


def test_the_wide_table_puts_the_plain_learner_and_peers_first_and_published_beside(
    suite,
):
    wide = read(suite["out"], "wide.csv").set_index("task")
    assert wide.columns.tolist() == [
        "budget",
        "none",
        "e3b",
        "noveld",
        "vae_a",
        "vae_b",
        "published",
    ]
    assert wide.loc["KeyCorridorS3R3", "vae_a"] == "0.95 [0.95, 0.95] (3)"
    assert wide.loc["KeyCorridorS3R3", "budget"] == "1k"
    # a setting a task did not run is an empty cell, not a zero
    assert pd.isna(wide.loc["KeyCorridorS3R3", "noveld"])
    assert wide.loc["DoorKey-16x16", "published"] == (
        "E3B 0.98, RND 0.02 (PPO, normalised score, budget not stated); "
        "RIDE 0.50 (IMPALA, return, budget 30M)"
    )
    assert pd.isna(wide.loc["KeyCorridorS3R3", "published"])


def test_targets_judge_the_best_vae_setting_against_each_peer(suite):
    targets = read(suite["out"], "targets.csv").set_index("task")
    s3r3 = targets.loc["KeyCorridorS3R3"]
    assert s3r3["best_vae"] == "vae_a"
    assert bool(s3r3["best_vae_solves"])
    assert s3r3["plain"] == "0.00 [0.00, 0.00] (3)"
    # every vae_a seed beats every e3b seed: probability 1 with its CI
    assert s3r3["vs_e3b"] == 1.0
    assert s3r3["vs_e3b_verdict"] == "better"
    assert s3r3["noveld"] == "not run"
    assert s3r3["vs_noveld_verdict"] == "not run"
    d16 = targets.loc["DoorKey-16x16"]
    assert not bool(d16["best_vae_solves"])
    assert d16["vs_noveld"] == 0.0
    # one seed a side is a screening, not a comparison
    assert d16["vs_noveld_verdict"] == "too few seeds (1 vs 1)"


def test_level_and_worse_verdicts_follow_the_interval(suite, tmp_path):
    # vae_b (0.5) against e3b (0.2) with the CI moved by hand
    directory = tmp_path / "s3r3"
    directory.mkdir()
    source = suite["dirs"][0]
    (directory / "summary.csv").write_text((source / "summary.csv").read_text())
    poi = read(source, "probability_of_improvement.csv")
    mask = (poi["setting_x"] == "vae_a") & (poi["setting_y"] == "e3b")
    for (low, high), verdict in (((0.3, 0.7), "level"), ((0.1, 0.4), "worse")):
        poi.loc[mask, ["probability", "ci_low", "ci_high"]] = [
            (low + high) / 2,
            low,
            high,
        ]
        poi.to_csv(directory / "probability_of_improvement.csv", index=False)
        write_suite([directory], tmp_path / "out")
        targets = read(tmp_path / "out", "targets.csv").set_index("task")
        assert targets.loc["KeyCorridorS3R3", "vs_e3b_verdict"] == verdict


def test_regenerating_from_the_same_experiments_gives_the_same_tables(suite, tmp_path):
    write_suite(suite["dirs"], tmp_path / "again", suite["published"])
    for name in ("table.csv", "wide.csv", "frames_to_solve.csv", "targets.csv"):
        assert (tmp_path / "again" / name).read_text() == (
            suite["out"] / name
        ).read_text()


def test_a_task_from_two_experiments_is_refused(suite, tmp_path):
    copy = tmp_path / "copy"
    copy.mkdir()
    for name in ("summary.csv", "probability_of_improvement.csv"):
        (copy / name).write_text((suite["dirs"][0] / name).read_text())
    with pytest.raises(SuiteInputError, match="several.*KeyCorridorS3R3"):
        write_suite([suite["dirs"][0], copy], tmp_path / "out")
    with pytest.raises(SuiteInputError, match="given twice"):
        write_suite([suite["dirs"][0], suite["dirs"][0]], tmp_path / "out")


def test_a_directory_without_a_summary_is_named(tmp_path, capsys):
    with pytest.raises(SystemExit) as raised:
        main([str(tmp_path), "--out", str(tmp_path / "out")])
    assert raised.value.code == 2
    assert f"{tmp_path / 'summary.csv'} is missing" in capsys.readouterr().err


@pytest.mark.parametrize(
    "row, message",
    [
        (
            "DoorKey-16x16,E3B,PPO,score,0.98,not stated,,",
            "line 2: a published number needs a source",
        ),
        (
            "DoorKey-16x16,E3B,PPO,score,~0.98,not stated,,src",
            "value '~0.98' is not a number",
        ),
        ("DoorKey-16x16,E3B,PPO,score,0.98,2M,,src", "budget_frames '2M' is neither"),
    ],
)
def test_a_published_row_without_a_source_a_number_or_a_budget_is_named(
    tmp_path, row, message
):
    path = tmp_path / "published.csv"
    path.write_text(PUBLISHED.splitlines()[0] + "\n" + row + "\n")
    with pytest.raises(SuiteInputError, match=message):
        read_published(path)


def test_a_published_table_without_a_column_names_it(tmp_path):
    path = tmp_path / "published.csv"
    path.write_text("task,method,value\nDoorKey-16x16,E3B,0.98\n")
    with pytest.raises(SuiteInputError, match="lacks the columns.*learner"):
        read_published(path)


def test_the_committed_suite_table_is_what_make_figures_writes(tmp_path):
    # the experiments `make figures` reads (SUITE_DIRS: the suite's tasks, not the
    # KeyCorridorS3R3 runs set aside at 16 x 128)
    root = Path(__file__).resolve().parents[1] / "docs" / "results"
    dirs = sorted(
        path.parent
        for path in root.glob("suite_*/summary.csv")
        if not path.parent.name.endswith("_16x128")
    )
    assert dirs, "no committed suite experiment"
    write_suite(dirs, tmp_path, root / "suite_published.csv")
    for name in ("table.csv", "wide.csv", "frames_to_solve.csv", "targets.csv"):
        assert (tmp_path / name).read_text() == (root / "suite" / name).read_text(), (
            f"docs/results/suite/{name} is stale: run `make figures`"
        )
