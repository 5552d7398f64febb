"""The suite's table on two fake suite experiments aggregated by aggregate.py.

Both tasks ran on envpool (the ``backend`` column of every table). Task
``MiniGrid-KeyCorridorS3R3-v0`` (oracle 0.5, budget 1000 frames):
``vae_a`` ends every seed at 0.95 of the oracle, ``vae_u_untrained`` at 1.0,
``vae_b`` one seed at 0.95 and two at 0.5, ``vae_a_untrained`` (``vae_a``'s
control) at 0.5, ``e3b`` at 0.2, ``e3b_128`` at 0.97, ``none`` at 0, 3 seeds
each, and one screening seed of ``vae_s`` at 0.99, every run a straight ramp (so a seed's moving return crosses 0.9 of the
oracle at frames ``1000 * 0.9 / final``). Task
``MiniGrid-DoorKey-16x16-v0`` (no oracle: scored by its success rate,
budget 2000) has one seed of ``none``, ``vae_a`` (ending at a success rate of 0.5),
``vae_a_untrained`` (0.4) and ``noveld`` (at 0.6), and one of ``e3b`` killed at half
the budget.
"""

from __future__ import annotations

import re
from pathlib import Path

import pandas as pd
import pytest

from results.aggregate import main as aggregate_main
from results.suite import (
    MIN_SEEDS,
    SuiteInputError,
    main,
    read_published,
    short_task,
    write_suite,
)

S3R3, D16 = "MiniGrid-KeyCorridorS3R3-v0", "MiniGrid-DoorKey-16x16-v0"
BACKEND = "envpool"
ORACLE = {S3R3: 0.5}
FINALS = {
    S3R3: {
        "none": [0.0] * 3,
        "e3b": [0.2] * 3,
        "e3b_128": [0.97] * 3,
        "vae_a": [0.95] * 3,
        "vae_b": [0.95, 0.5, 0.5],
        "vae_u_untrained": [1.0] * 3,
        "vae_a_untrained": [0.5] * 3,
        "vae_s": [0.99],
    },
    D16: {
        "none": [0.0],
        "vae_a": [0.5],
        "vae_a_untrained": [0.4],
        "noveld": [0.6],
        "e3b": [0.3],
    },
}
#: Runs killed at half their budget: (task, setting).
KILLED = {(D16, "e3b")}
BUDGETS = {S3R3: 1000, D16: 2000}
PUBLISHED = """task,method,learner,metric,value,budget_frames,seeds,source
DoorKey-16x16,E3B,PPO,normalised score,0.98,not stated,,"RLeXplore README, figure"
DoorKey-16x16,RND,PPO,normalised score,0.02,not stated,,"RLeXplore README, figure"
DoorKey-16x16,RIDE,IMPALA,return,0.50,30000000,,"a paper, figure 3"
"""


def _runs_csv(path: Path, task: str) -> None:
    budget = BUDGETS[task]
    oracle = ORACLE.get(task, 1.0)
    rows = [
        {
            "task": task,
            "backend": BACKEND,
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
        if (task, setting) not in KILLED or frames <= budget // 2
    ]
    path.parent.mkdir(parents=True)
    pd.DataFrame(rows).to_csv(path, index=False)


@pytest.fixture(scope="module")
def suite(tmp_path_factory) -> dict[str, Path]:
    root = tmp_path_factory.mktemp("suite")
    oracle = root / "oracle.csv"
    pd.DataFrame(
        {
            "env": list(ORACLE),
            "backend": BACKEND,
            "seeds": 10,
            "mean_return": list(ORACLE.values()),
        }
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
    argv = [*map(str, dirs), "--published", str(published), "--out", str(out)]
    assert main([*argv, "--min-seeds", "3"]) == 0
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
    assert solved == [
        ("KeyCorridorS3R3", "e3b_128"),
        ("KeyCorridorS3R3", "vae_a"),
        ("KeyCorridorS3R3", "vae_s"),
        ("KeyCorridorS3R3", "vae_u_untrained"),
    ]
    # a straight ramp to 0.95 crosses 0.9 at 1000 * 0.9 / 0.95 = 947 frames; the
    # first logged step at or past it is 1000
    assert table.loc[("KeyCorridorS3R3", "vae_a"), "median_frames_to_solve"] == 1000
    assert table.loc[("KeyCorridorS3R3", "vae_a"), "seeds_reaching"] == 3
    frames = read(suite["out"], "frames_to_solve.csv").set_index("task")
    assert frames.loc["KeyCorridorS3R3", "vae_a"] == "1k (3/3)"
    assert frames.loc["KeyCorridorS3R3", "e3b"] == "not reached (0/3)"
    # one seed of three got there: the median is not reached, the count says 1
    assert frames.loc["KeyCorridorS3R3", "vae_b"] == "not reached (1/3)"
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
        "e3b_128",
        "noveld",
        "vae_a",
        "vae_a_untrained",
        "vae_b",
        "vae_s",
        "vae_u_untrained",
        "published",
    ]
    assert wide.loc["DoorKey-16x16", "e3b"] == "no finished seed"
    assert wide.loc["KeyCorridorS3R3", "vae_a"] == "0.95 [0.95, 0.95] (3)"
    assert wide.loc["KeyCorridorS3R3", "budget"] == "1k"
    # a setting a task did not run is an empty cell, not a zero
    assert pd.isna(wide.loc["KeyCorridorS3R3", "noveld"])
    assert wide.loc["DoorKey-16x16", "published"] == (
        "E3B 0.98, RND 0.02 (PPO, normalised score, budget not stated); "
        "RIDE 0.50 (IMPALA, return, budget 30M)"
    )
    assert pd.isna(wide.loc["KeyCorridorS3R3", "published"])


def _targets(out: Path) -> pd.DataFrame:
    return read(out, "targets.csv").set_index(["task", "candidate"])


def test_targets_judge_the_best_vae_setting_and_the_best_trained_one(suite):
    targets = _targets(suite["out"])
    any_vae = targets.loc[("KeyCorridorS3R3", "best VAE-based")]
    trained = targets.loc[("KeyCorridorS3R3", "best trained VAE")]
    # the untrained control is VAE-based; the trained candidate leaves it out;
    # vae_s's one screening seed (0.99) does not displace vae_a's three (0.95)
    assert (any_vae["setting"], trained["setting"]) == ("vae_u_untrained", "vae_a")
    assert trained["solves"] == "yes"
    assert trained["score"] == "0.95 [0.95, 0.95] (3)"
    assert trained["plain"] == "0.00 [0.00, 0.00] (3)"
    # every vae_a seed beats every e3b seed: probability 1 with its CI
    assert trained["vs_e3b"] == "1.00 [1.00, 1.00]"
    assert trained["vs_e3b_verdict"] == "better"
    # E3B at its other width is a peer of its own: every seed of it beats vae_a's
    assert trained["e3b_128"] == "0.97 [0.97, 0.97] (3)"
    assert trained["vs_e3b_128"] == "0.00 [0.00, 0.00]"
    assert trained["vs_e3b_128_verdict"] == "worse"
    assert trained["noveld"] == "not run"
    assert trained["vs_noveld_verdict"] == "not run"
    # whether the VAE's training earns its cost: vae_a against vae_a_untrained
    assert trained["untrained_control"] == "vae_a_untrained"
    assert trained["untrained"] == "0.50 [0.50, 0.50] (3)"
    assert trained["vs_untrained"] == "1.00 [1.00, 1.00]"
    assert trained["vs_untrained_verdict"] == "better"
    # an untrained setting is its own control; vae_u has no trained twin run
    assert pd.isna(any_vae["untrained_control"])
    assert any_vae["vs_untrained_verdict"] == "is an untrained control"


def test_a_task_without_an_oracle_or_seeds_enough_gets_no_verdict(suite):
    d16 = _targets(suite["out"]).loc[("DoorKey-16x16", "best trained VAE")]
    assert d16["solves"] == "no (too few seeds: 1)"
    assert d16["vs_noveld"] == "0.00 [0.00, 0.00]"
    # its score is the success rate, the probabilities compare returns
    assert d16["vs_noveld_verdict"] == "no verdict: no oracle"
    assert d16["e3b"] == d16["vs_e3b_verdict"] == "no finished seed"
    assert d16["untrained_control"] == "vae_a_untrained"
    assert d16["untrained"] == "0.40 [0.40, 0.40] (1)"  # its success rate
    assert d16["vs_untrained_verdict"] == "no verdict: no oracle"


def test_fewer_seeds_than_asked_for_are_too_few(suite, tmp_path):
    write_suite(suite["dirs"], tmp_path)  # the default: 5 seeds a side
    trained = _targets(tmp_path).loc[("KeyCorridorS3R3", "best trained VAE")]
    assert trained["vs_e3b_verdict"] == "too few seeds (3 vs 3)"
    assert trained["solves"] == "yes (too few seeds: 3)"


def test_a_task_given_its_own_seed_count_is_judged_at_it(suite, tmp_path):
    # the default asks 5 seeds a side; KeyCorridorS3R3 is given 3, as a task whose
    # budget makes 5 unaffordable is
    out = tmp_path / "out"
    argv = [*map(str, suite["dirs"]), "--out", str(out)]
    assert main([*argv, "--task-min-seeds", "KeyCorridorS3R3=3"]) == 0
    targets = _targets(out)
    trained = targets.loc[("KeyCorridorS3R3", "best trained VAE")]
    assert trained["solves"] == "yes"
    assert trained["vs_e3b_verdict"] == "better"
    assert trained["vs_untrained_verdict"] == "better"
    # the task's count replaces the default either way: asking 4 of it where the
    # default is 3 makes its 3 seeds too few again
    raised = tmp_path / "raised"
    argv_raised = [*map(str, suite["dirs"]), "--out", str(raised), "--min-seeds", "3"]
    assert main([*argv_raised, "--task-min-seeds", "KeyCorridorS3R3=4"]) == 0
    trained_4 = _targets(raised).loc[("KeyCorridorS3R3", "best trained VAE")]
    assert trained_4["solves"] == "yes (too few seeds: 3)"
    assert trained_4["vs_e3b_verdict"] == "too few seeds (3 vs 3)"
    # the same through the function, the same table as --min-seeds 3 gives here
    write_suite(suite["dirs"], tmp_path / "api", task_min_seeds={"KeyCorridorS3R3": 3})
    assert (tmp_path / "api" / "targets.csv").read_text() == (
        out / "targets.csv"
    ).read_text()
    s3r3 = _targets(suite["out"]).loc["KeyCorridorS3R3"]
    pd.testing.assert_frame_equal(targets.loc["KeyCorridorS3R3"], s3r3)


@pytest.mark.parametrize(
    "item, expected",
    [
        ("KeyCoridorS3R3=3", "which no experiment holds; expected one of"),
        ("KeyCorridorS3R3", "expects TASK=N with N at least 1"),
        ("KeyCorridorS3R3=0", "expects TASK=N with N at least 1"),
        ("KeyCorridorS3R3=\u00b3", "expects TASK=N with N at least 1"),
    ],
)
def test_a_wrong_task_seed_count_is_refused_with_what_was_expected(
    suite, tmp_path, capsys, item, expected
):
    argv = [*map(str, suite["dirs"]), "--out", str(tmp_path / "out")]
    with pytest.raises(SystemExit) as raised:
        main([*argv, "--task-min-seeds", item])
    assert raised.value.code == 2
    assert expected in capsys.readouterr().err
    assert not (tmp_path / "out" / "targets.csv").exists()


def test_level_and_worse_verdicts_follow_the_interval(suite, tmp_path):
    # the best trained setting (vae_a) against e3b, with the CI moved by hand
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
        write_suite([directory], tmp_path / "out", min_seeds=3)
        targets = _targets(tmp_path / "out")
        assert (
            targets.loc[("KeyCorridorS3R3", "best trained VAE"), "vs_e3b_verdict"]
            == verdict
        )


def test_regenerating_from_the_same_experiments_gives_the_same_tables(suite, tmp_path):
    write_suite(suite["dirs"], tmp_path / "again", suite["published"], min_seeds=3)
    assert (tmp_path / "again" / "published.csv").read_bytes() == suite[
        "published"
    ].read_bytes()
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
    # the same env id on the other backend: one name in the tables, two tasks
    summary = read(copy, "summary.csv")
    summary["backend"] = "gymnasium"
    summary.to_csv(copy / "summary.csv", index=False)
    with pytest.raises(SuiteInputError, match=r"S3R3-v0 \(envpool\) in .*S3R3-v0 in"):
        write_suite([suite["dirs"][0], copy], tmp_path / "out")
    # a summary without the backend column is refused, naming what is expected
    summary.drop(columns="backend").to_csv(copy / "summary.csv", index=False)
    with pytest.raises(SuiteInputError, match="lacks the columns \\['backend'\\]"):
        write_suite([copy], tmp_path / "out")


def test_a_directory_without_a_summary_is_named(tmp_path, capsys):
    with pytest.raises(SystemExit) as raised:
        main([str(tmp_path), "--out", str(tmp_path / "out")])
    assert raised.value.code == 2
    assert f"{tmp_path / 'summary.csv'} is missing" in capsys.readouterr().err


def test_a_missing_published_table_says_what_it_should_be(suite, tmp_path):
    with pytest.raises(SuiteInputError, match="missing: the published numbers are a"):
        write_suite(suite["dirs"], tmp_path, tmp_path / "nowhere.csv")


@pytest.mark.parametrize(
    "row, message",
    [
        (
            "DoorKey-16x16,E3B,PPO,score,0.98,not stated,,",
            "line 2: a published number needs a source",
        ),
        ("DoorKey-16x16,E3B,,score,0.98,not stated,,src", "needs a learner"),
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
    # runs set aside: KeyCorridorS3R3 at 16 x 128, DoorKey-16x16 at 64 x 32)
    root = Path(__file__).resolve().parents[1] / "docs" / "results"
    dirs = sorted(
        path.parent
        for path in root.glob("suite_*/summary.csv")
        if not path.parent.name.endswith(("_16x128", "_64x32"))
    )
    assert dirs, "no committed suite experiment"
    # the tasks its figures target gives their own seed count (a 3-seed full pass)
    makefile = (root.parents[1] / "Makefile").read_text()
    figures = re.search(r"^figures:.*?(?=^\S)", makefile, re.M | re.S)
    assert figures and "suite.py" in figures.group(), "no suite.py in make figures"
    assert "--min-seeds" not in figures.group(), "make figures sets --min-seeds"
    counts = re.findall(r"--task-min-seeds[ =](\S+)=(\d+)", figures.group())
    task_min_seeds = {task: int(seeds) for task, seeds in counts}
    write_suite(dirs, tmp_path, root / "suite_published.csv", MIN_SEEDS, task_min_seeds)
    for name in ("table.csv", "wide.csv", "frames_to_solve.csv", "targets.csv"):
        assert (tmp_path / name).read_text() == (root / "suite" / name).read_text(), (
            f"docs/results/suite/{name} is stale: run `make figures`"
        )
