"""The hard-exploration suite's table: every task and setting, the issue's targets,
and the peers' published numbers beside ours.

Each task of the suite is an experiment aggregated on its own, at its own budget
(``recipes/results/aggregate.py runs/ppo_minigrid/suite_<task> --out
docs/results/suite_<task> --budget <its budget>``). This command reads those
experiments' ``summary.csv`` and ``probability_of_improvement.csv`` and a table of
published numbers, and writes the suite's tables::

    python recipes/results/suite.py docs/results/suite_keycorridor_s3r3 \\
        docs/results/suite_doorkey16x16_16x512 --published docs/results/suite_published.csv \\
        --out docs/results/suite

**Score.** A run's score is its final train return divided by the oracle's where
the task has an oracle (every task of the suite has one), else its final success
rate; a setting's score is the IQM over seeds with its 95% bootstrap CI (as
``aggregate.py`` computes them). A setting **solves** a task when its IQM is at
least 0.9 of the oracle's return (a success rate of 0.95 without an oracle);
its frames to solve are the median over seeds of the frames at which each seed's
moving return first reached 0.9 of the oracle's.

**Outputs** (in ``--out``):

- ``table.csv``: one row per task and setting: ``task, setting, budget, seeds``
  (those that reached the budget, in the score), ``metric, iqm, ci_low, ci_high,
  solved, seeds_reaching, seeds_logged, median_frames_to_solve`` (over every
  seed that logged, as ``aggregate.py``'s report counts them).
- ``wide.csv``: the table a report shows: a row per task, a column per setting
  holding ``IQM [CI] (seeds)``, and ``published``: the peers' published numbers
  for that task, each with its method, learner and budget.
- ``frames_to_solve.csv``: the same shape, the median frames to 0.9 of the
  oracle's return with the seeds that reached it.
- ``targets.csv``: per task, the issue's targets for two candidates: the best
  VAE-based setting (names starting with ``vae``, the untrained controls
  included) and the best trained VAE (not ``*_untrained``), each the highest
  IQM of its group among the settings with the most finished seeds, up to
  ``--min-seeds`` (a screening seed does not displace a full pass), so
  chosen on the data it is judged on; whether it solves
  the task; and against each peer (E3B at both widths, ``e3b`` and ``e3b_128``,
  and NovelD) the probability that it is better (from
  the task's ``probability_of_improvement.csv``) with a verdict: ``better`` (the
  CI above 0.5), ``worse`` (below), ``level`` (the CI holds 0.5) or ``too few
  seeds`` (either side under ``--min-seeds``, default :data:`MIN_SEEDS`, or in
  its place the task's own count where ``--task-min-seeds TASK=N`` names it: a
  task whose budget makes the full pass unaffordable runs fewer seeds, and says
  so; the same count decides which settings compete as candidates);
  then the same against the candidate's untrained control (the setting named
  ``<candidate>_untrained``: the same bonus on a VAE that never trains), which
  says whether the VAE's training earns its cost on the task.
- ``published.csv``: the published numbers, checked, copied as given.

The published table has the columns of :data:`PUBLISHED_COLUMNS`; ``task`` is
the env id without ``MiniGrid-`` and its version (``KeyCorridorS3R3``), as in
``wide.csv``; ``budget_frames`` is a number or ``not stated``.
"""

from __future__ import annotations

__all__ = [
    "CANDIDATES",
    "PUBLISHED_COLUMNS",
    "SuiteInputError",
    "read_experiments",
    "read_published",
    "short_task",
    "suite_table",
    "targets",
    "wide_tables",
    "write_suite",
]

import argparse
import shutil
import sys
from collections.abc import Mapping, Sequence
from functools import partial
from pathlib import Path

import pandas as pd

# Run as a script: recipes/ holds the shared `common` package.
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from common.labels import task_name  # noqa: E402

#: The settings that are the library's VAE-based bonuses: names starting with it.
VAE_PREFIX = "vae"
#: The peers every VAE-based setting is judged against: E3B at the width of its own
#: code (1024) and at the width RLeXplore runs it on MiniGrid (128), and NovelD.
PEERS: tuple[str, ...] = ("e3b", "e3b_128", "noveld")
#: The plain learner.
PLAIN = "none"
#: A VAE-based setting's control, the same bonus on a VAE that never trains, is
#: named by this suffix (``vae_noveld`` -> ``vae_noveld_untrained``).
UNTRAINED = "_untrained"
#: Fraction of the oracle's return (or success rate without an oracle) that solves.
SOLVED_RETURN, SOLVED_SUCCESS = 0.9, 0.95
#: Seeds each side needs before ``targets.csv`` says better, level or worse: the
#: suite's pass of 5 seeds (``--min-seeds``; with 3 seeds a side, complete
#: separation has a bootstrap CI of [1, 1] and a one-sided rank test's p of 0.05).
MIN_SEEDS = 5
PUBLISHED_COLUMNS: tuple[str, ...] = (
    "task",
    "method",
    "learner",
    "metric",
    "value",
    "budget_frames",
    "seeds",
    "source",
)


class SuiteInputError(ValueError):
    """An experiment directory or the published table lacks what the suite needs."""


def short_task(task: str) -> str:
    """The env id as the suite's tables name it: without ``MiniGrid-`` and its
    version (a task comes from one backend: :func:`read_experiments`).

    Examples:
        >>> short_task("MiniGrid-KeyCorridorS3R3-v0")
        'KeyCorridorS3R3'
        >>> short_task("MiniGrid-ObstructedMaze-2Dlhb-v1")
        'ObstructedMaze-2Dlhb'
    """
    name = task.removeprefix("MiniGrid-")
    head, _, version = name.rpartition("-v")
    return head if head and version.isdigit() else name


_EXPERIMENT_FILE = (
    "each suite experiment is a directory written by recipes/results/aggregate.py "
    "(summary.csv, probability_of_improvement.csv)"
)


def _read_csv(path: Path, needed: Sequence[str], what: str) -> pd.DataFrame:
    if not path.is_file():
        raise SuiteInputError(f"{path} is missing: {what}")
    # Labels such as "none" are settings, not missing values.
    table = pd.read_csv(path, keep_default_na=False, na_values=[""])
    missing = [column for column in needed if column not in table.columns]
    if missing:
        raise SuiteInputError(f"{path} lacks the columns {missing}; expected {needed}")
    return table


_SUMMARY_COLUMNS = (
    "task",
    "backend",
    "setting",
    "normalized",
    "budget",
    "seeds",
    "train_return_iqm",
    "train_return_ci_low",
    "train_return_ci_high",
    "train_return_seeds",
    "train_success_iqm",
    "train_success_ci_low",
    "train_success_ci_high",
    "train_success_seeds",
    "seeds_reaching_0.9",
    "median_frames_to_0.9",
)
_POI_COLUMNS = (
    "task",
    "backend",
    "setting_x",
    "setting_y",
    "seeds_x",
    "seeds_y",
    "probability",
    "ci_low",
    "ci_high",
)


def read_experiments(
    dirs: Sequence[str | Path],
) -> tuple[pd.DataFrame, pd.DataFrame]:
    """The summaries and probabilities of improvement of the suite's experiments.

    Raises:
        SuiteInputError: a directory lacks either file or a column (``backend``
            included: a summary written before it is regenerated by
            ``aggregate.py``), or a task (by :func:`short_task`) comes from two
            directories, two env ids or two backends.
    """
    summaries, probabilities = [], []
    dirs = [Path(directory) for directory in dirs]
    twice = sorted({str(d) for d in dirs if dirs.count(d) > 1})
    if twice:
        raise SuiteInputError(f"an experiment directory is given twice: {twice}")
    for directory in dirs:
        summary = _read_csv(
            directory / "summary.csv", _SUMMARY_COLUMNS, _EXPERIMENT_FILE
        )
        summary["experiment"] = str(directory)
        summaries.append(summary)
        probabilities.append(
            _read_csv(
                directory / "probability_of_improvement.csv",
                _POI_COLUMNS,
                _EXPERIMENT_FILE,
            )
        )
    if not summaries:
        raise SuiteInputError("no experiment directory given")
    summary = pd.concat(summaries, ignore_index=True)
    # the tables name a task by short_task: one env id on one backend and one
    # experiment each
    sources = summary.assign(short=summary["task"].map(short_task))
    sources = sources[["short", "task", "backend", "experiment"]].drop_duplicates()
    shared = {
        short: sorted(
            f"{task_name(task, backend)} in {experiment}"
            for task, backend, experiment in pairs.values
        )
        for short, pairs in sources.groupby("short")[["task", "backend", "experiment"]]
        if len(pairs) > 1
    }
    if shared:
        raise SuiteInputError(
            "a task must come from one env id on one backend of one experiment; "
            f"these come from several: {shared}"
        )
    # an experiment of one setting has no comparison: its empty table adds nothing
    # (and pandas no longer wants all-NA frames in a concat)
    compared = [table for table in probabilities if not table.empty]
    return summary, pd.concat(compared or probabilities, ignore_index=True)


def _is_true(value) -> bool:
    return str(value).strip().lower() in ("true", "1")


def suite_table(summary: pd.DataFrame) -> pd.DataFrame:
    """One row per task and setting: the score at the budget and frames to solve.

    Examples:
        >>> row = {"task": "MiniGrid-T-v0", "setting": "vae", "normalized": True,
        ...     "budget": 1000, "seeds": 5, "train_return_iqm": 0.95,
        ...     "train_return_ci_low": 0.9, "train_return_ci_high": 0.97,
        ...     "train_return_seeds": 5, "seeds_reaching_0.9": 4,
        ...     "median_frames_to_0.9": "700"}
        >>> suite_table(pd.DataFrame([row]))[["task", "iqm", "solved"]]
          task   iqm  solved
        0    T  0.95    True
    """
    rows = []
    for _, row in summary.iterrows():
        normalized = _is_true(row["normalized"])
        name = "train_return" if normalized else "train_success"
        iqm = pd.to_numeric(row[f"{name}_iqm"], errors="coerce")
        frames = pd.to_numeric(row.get("median_frames_to_0.9"), errors="coerce")
        seeds = pd.to_numeric(row.get(f"{name}_seeds"), errors="coerce")
        rows.append(
            {
                "task": short_task(row["task"]),
                "setting": row["setting"],
                "budget": int(row["budget"]),
                # the runs that reached the budget (those in the score)
                "seeds": 0 if pd.isna(seeds) else int(seeds),
                "metric": "return / oracle" if normalized else "success",
                "iqm": iqm,
                "ci_low": pd.to_numeric(row[f"{name}_ci_low"], errors="coerce"),
                "ci_high": pd.to_numeric(row[f"{name}_ci_high"], errors="coerce"),
                "solved": bool(
                    not pd.isna(iqm)
                    and iqm >= (SOLVED_RETURN if normalized else SOLVED_SUCCESS)
                ),
                "seeds_reaching": (
                    int(row["seeds_reaching_0.9"]) if normalized else pd.NA
                ),
                # the seeds counted for frames to solve: every seed that logged
                # (aggregate.py's report counts them so)
                "seeds_logged": int(row["seeds"]),
                "median_frames_to_solve": (
                    int(frames) if normalized and not pd.isna(frames) else pd.NA
                ),
            }
        )
    return pd.DataFrame(rows)


def read_published(path: str | Path) -> pd.DataFrame:
    """The published numbers, checked: every column of :data:`PUBLISHED_COLUMNS`,
    a source on every row, and a numeric value.

    Raises:
        SuiteInputError: naming the file, the row and what it lacks.
    """
    path = Path(path)
    table = _read_csv(
        path,
        PUBLISHED_COLUMNS,
        f"the published numbers are a CSV with the columns {list(PUBLISHED_COLUMNS)}",
    )
    for index, row in table.iterrows():
        line = index + 2  # the header is line 1
        for column in ("task", "method", "learner", "metric", "source"):
            if pd.isna(row[column]) or not str(row[column]).strip():
                raise SuiteInputError(
                    f"{path}, line {line}: a published number needs a {column}"
                )
        if pd.isna(pd.to_numeric(row["value"], errors="coerce")):
            raise SuiteInputError(
                f"{path}, line {line}: value {row['value']!r} is not a number"
            )
        budget = "" if pd.isna(row["budget_frames"]) else str(row["budget_frames"])
        if budget.strip() != "not stated" and not budget.strip().isdigit():
            raise SuiteInputError(
                f"{path}, line {line}: budget_frames {budget!r} is neither a frame "
                "count nor 'not stated'"
            )
    return table


def _frames(frames) -> str:
    if pd.isna(frames):
        return "not stated"
    frames = int(frames)
    if frames >= 1_000_000:
        return f"{frames / 1e6:.2f}".rstrip("0").rstrip(".") + "M"
    return f"{frames / 1000:.0f}k"


def _published_cell(rows: pd.DataFrame) -> str:
    """``method value, ... (learner, metric, budget)``, a group per source setup."""
    cells = []
    for (learner, metric, budget), group in rows.groupby(
        ["learner", "metric", "budget_frames"], sort=False
    ):
        budget = str(budget).strip()
        budget = budget if budget == "not stated" else _frames(budget)
        values = ", ".join(
            f"{row['method']} {float(row['value']):.2f}" for _, row in group.iterrows()
        )
        cells.append(f"{values} ({learner}, {metric}, budget {budget})")
    return "; ".join(cells)


def _order(settings: Sequence[str]) -> list[str]:
    """The plain learner first, then the peers, then the rest alphabetically."""
    first = [s for s in (PLAIN, *PEERS) if s in settings]
    return first + sorted(s for s in settings if s not in first)


def wide_tables(
    table: pd.DataFrame, published: pd.DataFrame | None = None
) -> tuple[pd.DataFrame, pd.DataFrame]:
    """The report's two tables: scores and frames to solve, a row per task."""
    settings = _order(table["setting"].unique())
    scores, frames = [], []
    for task, rows in table.groupby("task", sort=False):
        rows = rows.set_index("setting")
        budget = _frames(rows["budget"].iloc[0])
        score = {"task": task, "budget": budget}
        solve = {"task": task, "budget": budget}
        for setting in settings:
            if setting not in rows.index:
                score[setting] = solve[setting] = ""
                continue
            row = rows.loc[setting]
            score[setting] = _score(rows, setting)
            if pd.isna(row["seeds_reaching"]) or not row["seeds_logged"]:
                solve[setting] = ""
            elif pd.isna(row["median_frames_to_solve"]):
                # aggregate.py's median is "not reached" once half the seeds miss
                solve[setting] = (
                    f"not reached ({row['seeds_reaching']}/{row['seeds_logged']})"
                )
            else:
                solve[setting] = (
                    f"{_frames(row['median_frames_to_solve'])} "
                    f"({row['seeds_reaching']}/{row['seeds_logged']})"
                )
        if published is not None:
            score["published"] = _published_cell(published[published["task"] == task])
        scores.append(score)
        frames.append(solve)
    return pd.DataFrame(scores), pd.DataFrame(frames)


_NO_VERDICT = {"probability": pd.NA, "ci": "", "verdict": "not run"}


def _verdict(
    poi: pd.DataFrame, task: str, best: str, peer: str, min_seeds: int
) -> dict:
    rows = poi[
        (poi["task"] == task) & (poi["setting_x"] == best) & (poi["setting_y"] == peer)
    ]
    if rows.empty:
        return dict(_NO_VERDICT)
    row = rows.iloc[0]
    ci = f"[{row['ci_low']:.2f}, {row['ci_high']:.2f}]"
    if min(int(row["seeds_x"]), int(row["seeds_y"])) < min_seeds:
        verdict = f"too few seeds ({int(row['seeds_x'])} vs {int(row['seeds_y'])})"
    elif row["ci_low"] > 0.5:
        verdict = "better"
    elif row["ci_high"] < 0.5:
        verdict = "worse"
    else:
        verdict = "level"
    return {
        "probability": round(float(row["probability"]), 2),
        "ci": ci,
        "verdict": verdict,
    }


#: The candidates ``targets.csv`` judges per task: a label and which settings
#: compete (the best IQM among those with enough seeds is the candidate).
CANDIDATES: tuple[tuple[str, str], ...] = (
    ("best VAE-based", "any setting named vae*, the untrained controls included"),
    ("best trained VAE", "the vae* settings whose VAE trains (not *_untrained)"),
)


def _candidates(scored: pd.DataFrame, min_seeds: int) -> dict[str, str]:
    vae = scored[scored.index.str.startswith(VAE_PREFIX)]
    trained = vae[~vae.index.str.endswith(UNTRAINED)]

    def best(group: pd.DataFrame) -> str:
        if not len(group):
            return ""
        enough = group["seeds"] >= min(min_seeds, group["seeds"].max())
        return group[enough]["iqm"].idxmax()

    return {label: best(group) for (label, _), group in zip(CANDIDATES, (vae, trained))}


def _check_task_min_seeds(
    table: pd.DataFrame, task_min_seeds: Mapping[str, int]
) -> None:
    tasks = sorted(table["task"].unique())
    for task, seeds in task_min_seeds.items():
        if task not in tasks:
            raise SuiteInputError(
                f"a seed count is given for task {task!r}, which no experiment "
                f"holds; expected one of {tasks}"
            )
        if isinstance(seeds, bool) or not isinstance(seeds, int) or seeds < 1:
            raise SuiteInputError(
                f"the seed count of task {task!r} must be an integer of at least "
                f"1, got {seeds!r}"
            )


def targets(
    table: pd.DataFrame,
    probabilities: pd.DataFrame,
    min_seeds: int = MIN_SEEDS,
    task_min_seeds: Mapping[str, int] | None = None,
) -> pd.DataFrame:
    """Per task and candidate (:data:`CANDIDATES`): its setting and score, whether
    it solves the task, the plain learner's score, and how the candidate compares
    with each peer (see the module's description).

    A verdict needs ``min_seeds`` finished seeds on both sides (the task's own
    count where ``task_min_seeds`` names it, by its short name as in
    :func:`short_task`), and an oracle: the probabilities of improvement compare
    returns, which are the score only where they are normalised by the oracle's.
    """
    task_min_seeds = dict(task_min_seeds or {})
    _check_task_min_seeds(table, task_min_seeds)
    poi = probabilities.assign(task=probabilities["task"].map(short_task))
    rows = []
    for task, rows_of_task in table.groupby("task", sort=False):
        needed = task_min_seeds.get(task, min_seeds)
        ran = rows_of_task.set_index("setting")
        scored = ran.dropna(subset=["iqm"])
        normalized = bool((rows_of_task["metric"] == "return / oracle").all())
        for label, best in _candidates(scored, needed).items():
            out = {"task": task, "candidate": label, "setting": best}
            out["score"] = _score(ran, best) if best else ""
            if not best:
                out["solves"] = ""
            else:
                seeds = int(scored.loc[best, "seeds"])
                out["solves"] = "yes" if scored.loc[best, "solved"] else "no"
                if seeds < needed:
                    out["solves"] += f" (too few seeds: {seeds})"
            out["plain"] = _score(ran, PLAIN)
            compare = partial(
                _compare, ran, scored, poi, task, best, needed, normalized
            )
            for peer in PEERS:
                out[peer] = _score(ran, peer)
                out[f"vs_{peer}"], out[f"vs_{peer}_verdict"] = compare(peer)
            # against the same bonus on a VAE that never trains
            if not best or best.endswith(UNTRAINED):
                control, untrained = "", ""
                vs_control = ("", "is an untrained control" if best else "not run")
            else:
                control = best + UNTRAINED
                untrained, vs_control = _score(ran, control), compare(control)
            out["untrained_control"], out["untrained"] = control, untrained
            out["vs_untrained"], out["vs_untrained_verdict"] = vs_control
            rows.append(out)
    return pd.DataFrame(rows)


def _compare(
    ran: pd.DataFrame,
    scored: pd.DataFrame,
    poi: pd.DataFrame,
    task: str,
    best: str,
    min_seeds: int,
    normalized: bool,
    other: str,
) -> tuple[str, str]:
    """The candidate ``best`` against the setting ``other``: the probability of
    improvement with its CI, and the verdict."""
    if not best or other not in scored.index:
        verdict = dict(_NO_VERDICT)
        if other in ran.index:
            verdict["verdict"] = "no finished seed"
    else:
        verdict = _verdict(poi, task, best, other, min_seeds)
        if not normalized:
            verdict["verdict"] = "no verdict: no oracle"
    probability = verdict["probability"]
    cell = "" if pd.isna(probability) else f"{probability:.2f} {verdict['ci']}"
    return cell, verdict["verdict"]


def _score(ran: pd.DataFrame, setting: str) -> str:
    if setting not in ran.index:
        return "not run"
    row = ran.loc[setting]
    if pd.isna(row["iqm"]):
        return "no finished seed"
    return (
        f"{row['iqm']:.2f} [{row['ci_low']:.2f}, {row['ci_high']:.2f}] ({row['seeds']})"
    )


def write_suite(
    dirs: Sequence[str | Path],
    out: str | Path,
    published: str | Path | None = None,
    min_seeds: int = MIN_SEEDS,
    task_min_seeds: Mapping[str, int] | None = None,
) -> dict[str, Path]:
    """Writes the suite's tables (see the module's description) into ``out``;
    ``min_seeds`` and ``task_min_seeds`` as in :func:`targets`."""
    summary, probabilities = read_experiments(dirs)
    table = suite_table(summary)
    published_table = read_published(published) if published else None
    if published_table is not None:
        unknown = sorted(set(published_table["task"]) - set(table["task"]))
        if unknown:
            # a task of the published table that no experiment ran: kept in
            # published.csv, absent from wide.csv
            print(
                f"published numbers for tasks without runs: {unknown}", file=sys.stderr
            )
    scores, frames = wide_tables(table, published_table)
    tables = {
        "table.csv": table,
        "wide.csv": scores,
        "frames_to_solve.csv": frames,
        "targets.csv": targets(table, probabilities, min_seeds, task_min_seeds),
    }
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    paths = {}
    for name, frame in tables.items():
        paths[name] = out / name
        frame.to_csv(paths[name], index=False)
    if published is not None:
        # as given, byte for byte (checked above)
        paths["published.csv"] = out / "published.csv"
        shutil.copyfile(published, paths["published.csv"])
    return paths


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python recipes/results/suite.py",
        description=__doc__.split("\n\n", 1)[0],
    )
    parser.add_argument(
        "experiments",
        nargs="+",
        type=Path,
        help="the suite's experiment directories, each written by aggregate.py",
    )
    parser.add_argument("--out", type=Path, required=True, help="output directory")
    parser.add_argument(
        "--published", type=Path, help="the peers' published numbers (CSV)"
    )
    parser.add_argument(
        "--min-seeds",
        type=int,
        default=MIN_SEEDS,
        help="finished seeds each side needs for a verdict in targets.csv",
    )
    parser.add_argument(
        "--task-min-seeds",
        action="append",
        default=[],
        metavar="TASK=N",
        help="a task's own --min-seeds (TASK as in wide.csv: KeyCorridorS6R3=3); "
        "repeat for each such task",
    )
    args = parser.parse_args(argv)
    if args.min_seeds < 1:
        parser.error(f"--min-seeds must be at least 1, got {args.min_seeds}")
    task_min_seeds = {}
    for item in args.task_min_seeds:
        task, _, seeds = item.partition("=")
        if not task or not seeds.isdecimal() or int(seeds) < 1:
            parser.error(
                f"--task-min-seeds expects TASK=N with N at least 1 "
                f"(KeyCorridorS6R3=3), got {item!r}"
            )
        if task in task_min_seeds:
            parser.error(f"--task-min-seeds gives {task!r} twice")
        task_min_seeds[task] = int(seeds)
    try:
        paths = write_suite(
            args.experiments,
            args.out,
            args.published,
            args.min_seeds,
            task_min_seeds,
        )
    except SuiteInputError as error:
        parser.error(str(error))
    print("\n".join(f"wrote {path}" for path in paths.values()))
    return 0


if __name__ == "__main__":
    sys.exit(main())
