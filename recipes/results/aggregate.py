"""Aggregates a sweep's runs: IQM with bootstrap CIs, thresholds, curves, profiles.

One command turns the run directories of one or more sweeps into the committed
results of an experiment::

    python recipes/results/aggregate.py runs/a2c_minigrid/n3s4 \\
        --out docs/results/n3s4 --oracle docs/results/oracle/oracle_returns.csv

and a second one regenerates every table and figure from the committed per-run
data alone, without the run directories::

    python recipes/results/aggregate.py \\
        --from-data docs/results/n3s4/runs.csv.xz --out docs/results/n3s4 \\
        --oracle docs/results/oracle/oracle_returns.csv

Given both, the run directories' runs are added to the committed data (a run of
the same task, setting and seed replaced by one that got at least as far, see
:func:`merge_run_data`): a sweep too long for one machine runs in parts, e.g.
``python recipes/ddpg_mujoco/main.py -m +experiment=figure3 seed=0`` here and
``seed=1`` elsewhere, each part aggregated into the same results::

    python recipes/results/aggregate.py runs/ddpg_mujoco/figure3 \\
        --from-data docs/results/figure3/runs.csv.xz --out docs/results/figure3

``--settings S [S ...]`` keeps only the runs of those settings, for instance a
study that compares new runs with one setting of committed results (written to
an ``--out`` other than the ``--from-data`` file's directory, whose runs it would
drop otherwise)::

    python recipes/results/aggregate.py runs/ppo_minigrid/transfer_n4s4 \\
        --from-data docs/results/ppo_n4s4/runs.csv.xz --settings vae_elliptical \\
        vae_elliptical_from_n3s4 vae_elliptical_from_n3s4_frozen \\
        vae_elliptical_untrained --out docs/results/ppo_transfer_n4s4

``--tasks T [T ...]`` does the same for tasks (env ids), ``--backends B [B ...]``
for the backends they ran on.

``--all docs/results`` does that for every experiment under ``docs/results`` (each
directory holding a ``runs.csv.xz``, at the budget its ``summary.csv`` was written
with); ``make figures`` runs it.

Other options: ``--budget FRAMES`` (the frame count at which final performance is
read; default: per task, the largest frame count that every run of the task
reached), ``--reps`` (bootstrap replications, default 2000), ``--seed`` (of the
bootstrap, default 0) and ``--max-points`` (points kept per run and metric in
``runs.csv.xz``, default 200).

**Runs.** A run directory is any directory under the given paths holding
``config_resolved.yaml`` (keys read: ``env.name``, ``seed``, ``bonus``,
``collector.total_frames``, ``env.backend`` and an optional top-level ``setting``). Its scalars are
the files of TorchRL's ``CSVLogger``, ``<run>/logs/<algo>/scalars/<group>/<name>.csv``
(rows ``step,value``, the step in environment frames). The **task** of a run is
the pair of its env id (``env.name``, the ``task`` column) and its **backend**
(``env.backend``, the ``backend`` column: ``gymnasium`` for minigrid's Python
envs and for a config without one, ``envpool`` for its C++ port, whose layouts
for a seed differ): a run on envpool is never pooled with minigrid's runs of the
env id, and is normalised by the oracle over envpool's layouts. Every table
below has the ``backend`` column right after ``task``; a text or a figure names
a task by its env id, followed by its backend in parentheses when that is not
gymnasium (:func:`task_name`). A run's **setting** is the config's ``setting``
when that is a non-empty string, else the Hydra overrides of
``.hydra/overrides.yaml`` minus ``seed``, ``env.name``, ``+experiment``,
``experiment_name``, ``resume``, ``resume_without_logs``, ``torch_threads``,
``hydra.*``, ``logger.*``, ``eval.*`` and ``checkpoint.*`` (they name the run or
change what it reports, not what it learns), sorted and joined with ``,`` (see
:func:`setting_label`), else the ``bonus``. A step logged twice (a resumed run)
keeps its last value; non-finite values (a moving mean before the first episode
ended) are dropped. A run that stopped early is kept up to where it
got and marked unfinished.

**Normalisation.** With ``--oracle`` (CSVs with columns ``env``, ``backend``
and ``mean_return``, such as ``recipes/results/oracle.py`` writes), the episode
returns of a task are divided by the oracle mean return of its env id on its
backend; tasks absent from the files (MuJoCo) stay unnormalised, which the
``normalized`` column and the command's output say. An input table (``runs.csv.xz``,
``runs_meta.csv`` or an oracle table) without a ``backend`` column is refused,
saying how to regenerate it.

**Outputs** (in ``--out``):

- ``runs.csv.xz``: the committed per-run data, an xz-compressed CSV
  ``task,backend,setting,seed,frames,metric,value`` (``xzcat``, ``pandas.read_csv`` and
  every CSV tool read it; xz keeps a study's curves at about a twentieth of the
  plain CSV, and its bytes depend on the data alone, so a regenerated file is
  the committed one) for the metrics of :data:`METRICS` a run logged, at most ``--max-points`` points
  per run and metric (evenly spaced by index, the last point always kept), raw
  (unnormalised) values. Everything below is computed from this file alone, so
  frame counts (first crossings) have the resolution of the kept points, about
  ``total_frames / max_points``.
- ``runs_meta.csv``: ``task,backend,setting,seed,total_frames,last_frame,finished,run_dir``.
  A run is finished when its ``status.json`` says so (the run writes it with each
  checkpoint: ``common.status.write_run_status``); a run directory without one
  (written before it existed) is finished when it logged its last point less
  than one logging period (the median gap between its logged steps) before
  ``collector.total_frames``: the recipes log every few updates, so the last
  logged step of a complete run falls short of the target by up to one period.
- ``summary.csv``: one row per task and setting: ``task, backend, setting, normalized,
  oracle_return, budget, seeds, seeds_unfinished, seeds_short_of_budget``; for each
  metric ``train_return``, ``train_success``, ``eval_return``, ``eval_success``
  the value at the last logged step at or before the budget, aggregated over seeds:
  ``<metric>_iqm, <metric>_ci_low, <metric>_ci_high`` (interquartile mean with a
  95% stratified-bootstrap CI, rliable), ``<metric>_mean, <metric>_seeds``; and for
  each fraction of :data:`FRACTIONS` of the oracle return (normalised tasks only)
  ``seeds_reaching_<f>`` and ``median_frames_to_<f>``: the median over seeds of the
  first frame at which the normalised ``train/episode_return`` reached ``f``,
  counting a seed that never did (up to the budget) as infinitely late, so it reads
  ``not reached`` when half the seeds or more never got there.
- ``final_scores.csv``: per run, the scores ``summary.csv`` aggregates: ``task,
  backend, setting, seed, metric, budget, frames, value``, each metric's value at its last
  logged step at or before the budget (``frames``), returns divided by the oracle's
  (:func:`final_scores`). A report quoting one seed's score reads it here.
- ``frames_to_threshold.csv``: per seed, ``task, backend, setting, seed, fraction,
  frames, searched_to``; ``frames`` is empty when the fraction was not reached by
  ``searched_to`` (the run's last frame or the budget, whichever is first).
- ``probability_of_improvement.csv``: per task and ordered pair of settings,
  ``task, backend, budget, setting_x, setting_y, seeds_x, seeds_y, probability,
  ci_low, ci_high``: P(a seed of X ends above a seed of Y) on the final (normalised)
  ``train/episode_return`` (rliable, Mann-Whitney U), with a 95% bootstrap CI.
- ``curves.png``: per task, the IQM over seeds of the (normalised)
  ``train/episode_return`` against frames with a 95% stratified-bootstrap band;
  each run is interpolated onto a common grid, never extrapolated, so a setting's
  curve stops where its shortest run stops. The dotted line marks the budget.
- ``performance_profiles.png``: per task, rliable's performance profiles (the
  fraction of runs whose final score exceeds tau) with 95% bootstrap bands.
- ``levels.png`` (only when some setting ran at a noise level other than 0, its
  label then ending in ``,env.stochasticity=L``): per task, the final return's IQM
  and CI against the noise level, one line per setting (Figure 2).

Every bootstrap is seeded by ``--seed`` and the name of what it estimates (a task
on another backend than gymnasium named by :func:`bootstrap_task_name`), so a
rerun writes identical CSVs, and adding a setting leaves the intervals of the
others unchanged (rliable 1.2 resamples with NumPy's global generator whatever its
``random_state``: each estimate seeds it, then restores its previous state). The IQM is the 25% trimmed
mean: the mean of the middle two of four seeds, the plain mean below four seeds.
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import textwrap
import warnings
import zlib
from collections.abc import Callable, Collection, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

# Run as a script: recipes/ holds the shared `common` package.
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
# the labels of a run, defined beside the run that writes them to status.json
# (names kept here for compatibility)
from common.labels import (  # noqa: F401
    _NOT_SETTING,
    _NOT_SETTING_SECTIONS,
    GYMNASIUM,
    LEVEL_KEY,
    add_label_keys,
    add_label_keys_argument,
    read_overrides,
    run_backend,
    setting_label,
    split_level,
    task_name,
)
from common.scalar_logs import read_scalar_csv
from common.status import read_run_status

__all__ = [
    "EPISODES_METRIC",
    "EPISODE_WINDOW",
    "FRACTIONS",
    "LEVEL_KEY",
    "METRICS",
    "TASK_KEYS",
    "RunInfo",
    "aggregate",
    "bootstrap_task_name",
    "extract_run_data",
    "final_scores",
    "find_runs",
    "frames_to_threshold",
    "improvement_probabilities",
    "iqm_interval",
    "keep_runs",
    "keep_settings",
    "main",
    "merge_run_data",
    "normalize_returns",
    "plot_curves",
    "plot_levels",
    "plot_profiles",
    "probability_of_improvement",
    "read_oracle",
    "report_table",
    "status_text",
    "runs_metadata",
    "runs_file",
    "setting_label",
    "split_level",
    "summarize",
    "task_name",
    "unfinished_runs",
    "write_runs_file",
]

#: The scalars read from each run, and the short names of their summary columns.
METRICS: dict[str, str] = {
    "train/episode_return": "train_return",
    "train/success_rate": "train_success",
    "eval/episode_return": "eval_return",
    "eval/success_rate": "eval_success",
}
#: Metrics divided by the oracle return of their task.
RETURN_METRICS: tuple[str, ...] = ("train/episode_return", "eval/episode_return")
#: The metric of final scores, curves, thresholds, profiles and improvements.
MAIN_METRIC = "train/episode_return"
#: Fractions of the oracle return whose first crossing is reported.
FRACTIONS: tuple[float, ...] = (0.5, 0.8, 0.9)
#: The cumulative count of finished episodes: a crossing counts only once the
#: moving window of the train return is full (see :func:`frames_to_threshold`).
EPISODES_METRIC = "train/episodes"
#: Episodes the train return's moving window holds (the recipes' default
#: ``logger.episode_window``).
EPISODE_WINDOW = 100

#: The columns that identify a task: its env id and the backend it ran on.
TASK_KEYS = ["task", "backend"]
_RUN_KEYS = [*TASK_KEYS, "setting", "seed"]
#: The name of the per-run data file an aggregation writes.
RUNS_FILE = "runs.csv.xz"
#: The names it is read under: the compressed file, or a plain CSV of earlier data.
RUNS_FILES = (RUNS_FILE, "runs.csv")
#: The figures :func:`aggregate` can draw.
FIGURES = ("curves.png", "performance_profiles.png", "levels.png")
#: The columns of ``runs.csv.xz``.
_DATA_COLUMNS = [*_RUN_KEYS, "frames", "metric", "value"]
#: The columns of ``runs_meta.csv``.
_META_COLUMNS = [*_RUN_KEYS, "total_frames", "last_frame", "finished", "run_dir"]
_NOT_REACHED = "not reached"


def _task_order(task: str, backend: str) -> tuple[str, bool, str]:
    # The tables' order of tasks: by env id, the env id on gymnasium before it on
    # another backend (those by name).
    return task, backend != GYMNASIUM, backend


def _gymnasium_first(column: pd.Series) -> pd.Series:
    # sort_values' key for _task_order: gymnasium, as "", sorts before any backend
    return column.where(column != GYMNASIUM, "") if column.name == "backend" else column


def _in_task_order(table: pd.DataFrame, by: Sequence[str] = TASK_KEYS) -> pd.DataFrame:
    """``table`` sorted by ``by`` (starting with :data:`TASK_KEYS`), its tasks in
    the tables' order (:func:`_task_order`); rows that tie keep their order."""
    table = table.sort_values(list(by), key=_gymnasium_first, kind="mergesort")
    return table.reset_index(drop=True)


def _tasks(table: pd.DataFrame) -> list[tuple[str, str]]:
    """The tasks (env id, backend) of a table, in the tables' order."""
    pairs = table[TASK_KEYS].drop_duplicates().itertuples(index=False, name=None)
    return sorted(pairs, key=lambda pair: _task_order(*pair))


def bootstrap_task_name(task: str, backend: str) -> str:
    """The name of a task in the seed of its bootstraps (:func:`iqm_interval`'s
    ``names``): the env id, followed by ``@<backend>`` on another backend than
    gymnasium.

    It is the name committed studies' bootstraps were seeded with (their task
    column read so before it had a backend column), so their intervals are
    unchanged. A name for the seed only, never read back.

    Examples:
        >>> [bootstrap_task_name("MiniGrid-Empty-5x5-v0", backend)
        ...  for backend in ("gymnasium", "envpool")]
        ['MiniGrid-Empty-5x5-v0', 'MiniGrid-Empty-5x5-v0@envpool']
    """
    return task if backend == GYMNASIUM else f"{task}@{backend}"


@dataclass(frozen=True)
class RunInfo:
    """One run directory and what identifies it in a sweep.

    Attributes:
        path (Path): the run directory (it holds ``config_resolved.yaml``).
        task (str): the config's ``env.name``.
        backend (str): where it ran, the config's ``env.backend`` (:func:`run_backend`).
        setting (str): the label of the run's setting (:func:`setting_label`).
        seed (int): the config's ``seed``.
        total_frames (int | None): the config's ``collector.total_frames``.
        scalars_dir (Path | None): ``<path>/logs/<algo>/scalars``, or ``None``
            when the run has logged nothing yet.
    """

    path: Path
    task: str
    backend: str
    setting: str
    seed: int
    total_frames: int | None
    scalars_dir: Path | None


def _scalars_dir(run_dir: Path) -> Path | None:
    # The recipes name their logger folder after the algorithm (a2c, ddpg):
    # whichever single folder under logs/ holds scalars is the run's.
    found = sorted(p for p in (run_dir / "logs").glob("*/scalars") if p.is_dir())
    if len(found) > 1:
        names = ", ".join(p.parent.name for p in found)
        raise ValueError(
            f"{run_dir}: several loggers under logs/ ({names}); expected one"
        )
    return found[0] if found else None


def _read_run(run_dir: Path, label_keys: Sequence[str] = ()) -> RunInfo:
    from omegaconf import OmegaConf

    config = OmegaConf.to_container(OmegaConf.load(run_dir / "config_resolved.yaml"))
    overrides = read_overrides(run_dir)
    task = (config.get("env") or {}).get("name")
    seed = config.get("seed")
    if task is None or seed is None:
        raise ValueError(f"{run_dir}/config_resolved.yaml has no env.name or no seed")
    total_frames = (config.get("collector") or {}).get("total_frames")
    setting = add_label_keys(
        setting_label(config, overrides),
        config,
        label_keys,
        f"{run_dir}/config_resolved.yaml",
    )
    return RunInfo(
        path=run_dir,
        task=str(task),
        backend=run_backend(config),
        setting=setting,
        seed=int(seed),
        total_frames=None if total_frames is None else int(total_frames),
        scalars_dir=_scalars_dir(run_dir),
    )


def find_runs(
    paths: Sequence[str | os.PathLike], label_keys: Sequence[str] = ()
) -> list[RunInfo]:
    """The run directories under ``paths`` (searched recursively), sorted.

    Args:
        paths: sweep directories, run directories, or any folders above them.
        label_keys: dotted keys of the runs' resolved config whose values join
            each run's setting label as ``,key=value`` (e.g. ``env.num_envs``):
            runs of one named setting that differ in them (a sweep over a
            hyperparameter beside ``+setting=...``) are then told apart.

    Raises:
        FileNotFoundError: a path does not exist, or no run directory (a folder
            holding ``config_resolved.yaml``) is under any of them.
        ValueError: two run directories are the same task (env id and backend),
            setting and seed, or a run's config has no value for one of
            ``label_keys``.

    Examples:
        >>> import tempfile
        >>> find_runs([tempfile.mkdtemp()])
        Traceback (most recent call last):
        ...
        FileNotFoundError: no run directory (a folder with config_resolved.yaml) under ...
    """
    run_dirs: set[Path] = set()
    for path in map(Path, paths):
        if not path.exists():
            raise FileNotFoundError(f"{path} does not exist")
        run_dirs.update(p.parent for p in path.rglob("config_resolved.yaml"))
    if not run_dirs:
        raise FileNotFoundError(
            "no run directory (a folder with config_resolved.yaml) under "
            + ", ".join(str(p) for p in paths)
        )
    runs = sorted(
        (_read_run(d, label_keys) for d in run_dirs),
        key=lambda r: (*_task_order(r.task, r.backend), r.setting, r.seed),
    )
    seen: dict[tuple[str, str, str, int], Path] = {}
    for run in runs:
        key = (run.task, run.backend, run.setting, run.seed)
        if key in seen:
            raise ValueError(
                f"{seen[key]} and {run.path} are both task "
                f"{task_name(run.task, run.backend)}, setting "
                f"{run.setting}, seed {run.seed}: pass only one of them, or tell "
                "them apart with --label-keys KEY (a config key whose value "
                "differs between them, e.g. env.num_envs)"
            )
        seen[key] = run.path
    return runs


def _read_metrics(run: RunInfo) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    curves = {}
    if run.scalars_dir is None:
        return curves
    for metric in (*METRICS, EPISODES_METRIC):
        path = run.scalars_dir / f"{metric}.csv"
        if path.is_file():
            steps, values = read_scalar_csv(path)
            finite = np.isfinite(values)
            if finite.any():
                curves[metric] = (steps[finite], values[finite])
    return curves


def _downsample(n: int, max_points: int) -> np.ndarray:
    if n <= max_points:
        return np.arange(n)
    # Evenly spaced indices that always keep the first and the last point.
    return np.unique(np.linspace(0, n - 1, max_points).round().astype(np.int64))


def extract_run_data(runs: Sequence[RunInfo], max_points: int = 200) -> pd.DataFrame:
    """The long table of ``runs.csv.xz``: ``task,backend,setting,seed,frames,metric,value``.

    Reads the metrics of :data:`METRICS` and :data:`EPISODES_METRIC` that each
    run logged (a step logged twice
    keeps its last value, non-finite values are dropped) and keeps at most
    ``max_points`` points per run and metric, the last one always. Values are raw.

    Args:
        runs: from :func:`find_runs`.
        max_points (int): points kept per run and metric, at least 2.
    """
    if max_points < 2:
        raise ValueError(f"max_points={max_points}: keep at least the first and last")
    tables = []
    for run in runs:
        for metric, (steps, values) in _read_metrics(run).items():
            keep = _downsample(len(steps), max_points)
            tables.append(
                pd.DataFrame(
                    {
                        "task": run.task,
                        "backend": run.backend,
                        "setting": run.setting,
                        "seed": run.seed,
                        "frames": steps[keep],
                        "metric": metric,
                        "value": values[keep],
                    }
                )
            )
    columns = _DATA_COLUMNS
    if not tables:
        return pd.DataFrame(columns=columns)
    return pd.concat(tables, ignore_index=True)[columns]


def runs_metadata(runs: Sequence[RunInfo]) -> pd.DataFrame:
    """The table of ``runs_meta.csv``: one row per run, with its completion.

    Columns ``task, backend, setting, seed, total_frames, last_frame, finished,
    run_dir``.
    ``last_frame`` is the last step any metric logged. A run is finished when its
    ``status.json`` says so (``common.status.read_run_status``; its budget is then
    ``total_frames``); without one (a run of an earlier release), when
    ``last_frame`` is less than one logging period (the median gap between its
    logged steps) before ``total_frames``. Unknown values are empty.
    """
    rows = []
    for run in runs:
        steps = np.unique(
            np.concatenate([s for s, _ in _read_metrics(run).values()] or [[]])
        )
        last = int(steps[-1]) if len(steps) else None
        total_frames = run.total_frames
        finished = None
        try:
            status = read_run_status(run.path)
        except ValueError as err:
            warnings.warn(
                f"{err}; finished or not is guessed from the logs", stacklevel=2
            )
            status = None
        if status is not None:
            finished = bool(status["finished"])
            total_frames = status.get("total_frames", total_frames)
        elif last is not None and total_frames is not None:
            period = float(np.median(np.diff(steps))) if len(steps) > 1 else 0.0
            finished = total_frames - last < max(period, 1.0)
        rows.append(
            {
                "task": run.task,
                "backend": run.backend,
                "setting": run.setting,
                "seed": run.seed,
                "total_frames": total_frames,
                "last_frame": last,
                "finished": finished,
                "run_dir": str(run.path),
            }
        )
    meta = pd.DataFrame(rows)
    for column in ("total_frames", "last_frame"):
        meta[column] = meta[column].astype("Int64")
    return meta


def merge_run_data(
    earlier: pd.DataFrame,
    earlier_meta: pd.DataFrame | None,
    data: pd.DataFrame,
    meta: pd.DataFrame,
    *,
    source: str = "the earlier data",
) -> tuple[pd.DataFrame, pd.DataFrame]:
    """Adds runs to data written before: a sweep continued elsewhere or later.

    A sweep too long for one machine or one session runs in parts (a subset of
    its jobs, e.g. ``seed=0`` on the command line); each part's run directories
    are aggregated together with the ``runs.csv.xz`` (and ``runs_meta.csv``) the
    earlier parts left. A run of ``data`` (same task, setting and seed) replaces
    the earlier one when it got at least as far; one that got less far is
    refused, so that nothing already computed is lost.

    Args:
        earlier (pd.DataFrame): a ``runs.csv.xz`` table, as :func:`extract_run_data`
            writes it.
        earlier_meta (pd.DataFrame | None): its ``runs_meta.csv`` table, or
            ``None`` when it has none (its runs are then listed with their last
            logged frame only).
        data (pd.DataFrame): the new runs' table (:func:`extract_run_data`).
        meta (pd.DataFrame): the new runs' :func:`runs_metadata`.
        source (str): how to name ``earlier`` in an error.

    Returns:
        The merged data and metadata tables, sorted by task (env id, then
        backend: gymnasium first), setting and seed.

    Raises:
        ValueError: a new run got less far than the same run in ``earlier``.

    Examples:
        >>> import pandas as pd
        >>> def run(seed, last):
        ...     return pd.DataFrame({"task": "T", "backend": "envpool", "setting": "s",
        ...         "seed": seed, "frames": [0, last], "metric": "train/episode_return",
        ...         "value": [0.0, 1.0]})
        >>> def meta(seed, last):
        ...     return pd.DataFrame({"task": ["T"], "backend": ["envpool"],
        ...         "setting": ["s"], "seed": [seed], "total_frames": [100],
        ...         "last_frame": [last], "finished": [True], "run_dir": [f"runs/{seed}"]})
        >>> merged, merged_meta = merge_run_data(run(0, 100), meta(0, 100),
        ...                                      run(1, 100), meta(1, 100))
        >>> merged_meta["seed"].tolist()
        [0, 1]
        >>> merge_run_data(merged, merged_meta, run(1, 50), meta(1, 50))
        Traceback (most recent call last):
        ...
        ValueError: task T (envpool), setting s, seed 1: runs/1 reached frame 50, the earlier data 100: ...
    """
    columns = _DATA_COLUMNS
    for name, table in (("earlier", earlier), ("data", data)):
        missing = sorted(set(columns) - set(table.columns))
        if missing:
            raise ValueError(f"{name} has no column {', '.join(missing)}")
    if earlier_meta is None:
        earlier_meta = meta_of_data(earlier, source)[meta.columns]
    old_reach = earlier.groupby(_RUN_KEYS)["frames"].max()
    new_reach = data.groupby(_RUN_KEYS)["frames"].max()
    run_dirs = meta.set_index(_RUN_KEYS)["run_dir"]
    replaced = run_dirs.index
    for key in replaced.intersection(old_reach.index):
        # a run directory that logged nothing yet reached no frame at all
        reached = new_reach.get(key, -1)
        if reached < old_reach[key]:
            task, backend, setting, seed = key
            raise ValueError(
                f"task {task_name(task, backend)}, setting {setting}, seed {seed}: "
                f"{run_dirs[key]} reached frame {reached}, {source} "
                f"{old_reach[key]}: it would replace a longer run; aggregate "
                "without that run directory"
            )

    def kept(table: pd.DataFrame) -> pd.DataFrame:
        return table[~table.set_index(_RUN_KEYS).index.isin(replaced)]

    def merged(old: pd.DataFrame, new: pd.DataFrame) -> pd.DataFrame:
        table = pd.concat([kept(old), new], ignore_index=True)
        # stable: each run's rows keep their order
        return _in_task_order(table, _RUN_KEYS)

    merged_meta = merged(earlier_meta, meta)
    for column in ("total_frames", "last_frame"):
        merged_meta[column] = merged_meta[column].astype("Int64")
    return merged(earlier, data)[columns], merged_meta


def keep_settings(
    data: pd.DataFrame, meta: pd.DataFrame | None, settings: Sequence[str]
) -> tuple[pd.DataFrame, pd.DataFrame | None]:
    """The runs of ``settings`` only: :func:`keep_runs` with ``settings`` alone.

    Examples:
        >>> data = pd.DataFrame({"task": "T", "backend": "gymnasium",
        ...     "setting": ["a", "b", "c"], "seed": 0, "frames": 128, "metric": "m",
        ...     "value": 1.0})
        >>> keep_settings(data, None, ["a", "c"])[0]["setting"].tolist()
        ['a', 'c']
    """
    return keep_runs(data, meta, settings=settings)


def keep_runs(
    data: pd.DataFrame,
    meta: pd.DataFrame | None,
    *,
    settings: Sequence[str] | None = None,
    tasks: Sequence[str] | None = None,
    backends: Sequence[str] | None = None,
) -> tuple[pd.DataFrame, pd.DataFrame | None]:
    """The runs of some settings and tasks, in ``runs.csv.xz`` data and its metadata.

    Args:
        data: ``runs.csv.xz`` data (columns ``task``, ``backend``, ``setting``, ...).
        meta: its ``runs_meta.csv``, or None.
        settings: keep only these settings (None: all).
        tasks: keep only these env ids, on every backend (None: all).
        backends: keep only the runs on these backends (None: all).

    Raises:
        ValueError: a setting, env id or backend has no run, naming those there are.

    Examples:
        >>> data = pd.DataFrame({"task": ["A", "A", "B"],
        ...     "backend": ["gymnasium", "envpool", "envpool"],
        ...     "setting": ["a", "b", "a"], "seed": 0, "frames": 128, "metric": "m",
        ...     "value": 1.0})
        >>> keep_runs(data, None, settings=["a"], tasks=["B"])[0].shape[0]
        1
        >>> keep_runs(data, None, backends=["envpool"])[0]["task"].tolist()
        ['A', 'B']
        >>> keep_runs(data, None, settings=["d"])
        Traceback (most recent call last):
        ...
        ValueError: no runs of the settings ['d']; the data has ['a', 'b'].
    """
    selected = (("setting", settings), ("task", tasks), ("backend", backends))
    for column, values in selected:
        if values is None:
            continue
        present = set(data[column])
        missing = [v for v in values if v not in present]
        if missing:
            raise ValueError(
                f"no runs of the {column}s {missing}; the data has {sorted(present)}."
            )
        data = data[data[column].isin(values)].reset_index(drop=True)
        if meta is not None:
            meta = meta[meta[column].isin(values)].reset_index(drop=True)
    return data, meta


def _require_backend(
    table: pd.DataFrame, path: str | os.PathLike, expected: str, regenerate: str
) -> None:
    """Refuses an input table without a ``backend`` column, saying what is
    expected and how to regenerate it."""
    if "backend" not in table.columns:
        raise ValueError(
            f"{path} has no backend column: expected the columns {expected}, a "
            "task's env id and the backend it ran on (gymnasium: minigrid's Python "
            "envs; envpool: its C++ port) each in its own column. It was written "
            f"before the backend column existed: regenerate it with {regenerate}."
        )


_ORACLE_COLUMNS = "env,backend,mean_return,..."
_ORACLE_REGENERATE = (
    "recipes/results/oracle.py (minigrid's layouts), benchmarks/envpool_oracle.py "
    "or benchmarks/suite_oracle.py (envpool's)"
)


def read_oracle(*paths: str | os.PathLike) -> dict[tuple[str, str], float]:
    """The oracle mean return of each task, (env id, backend), from CSVs with
    ``env,backend,mean_return``.

    Several tables are merged (minigrid's layouts, envpool's, the suite's); a task
    in two of them is refused, and so is a table without a ``backend`` column.

    Examples:
        >>> import tempfile
        >>> path = Path(tempfile.mkdtemp()) / "oracle.csv"
        >>> _ = path.write_text("env,backend,mean_return\\nA,gymnasium,0.8\\nA,envpool,0.7\\n")
        >>> read_oracle(path)
        {('A', 'gymnasium'): 0.8, ('A', 'envpool'): 0.7}
    """
    oracle: dict[tuple[str, str], float] = {}
    source: dict[tuple[str, str], int] = {}  # the position in ``paths`` of its table
    for position, path in enumerate(paths):
        table = pd.read_csv(path, dtype={"env": str, "backend": str})
        _require_backend(table, path, _ORACLE_COLUMNS, _ORACLE_REGENERATE)
        missing = {"env", "mean_return"} - set(table.columns)
        if missing:
            raise ValueError(f"{path} has no column {', '.join(sorted(missing))}")
        for env, backend, value in zip(
            table["env"], table["backend"], table["mean_return"]
        ):
            task = (str(env), str(backend))
            if task in oracle:
                where = "twice" if source[task] == position else "in another table too"
                raise ValueError(
                    f"{path}: the oracle of {task_name(*task)} is {where} (one row "
                    "per env id and backend: a table of several action noises is "
                    "one --oracle file per noise)"
                )
            oracle[task] = float(value)
            source[task] = position
    return oracle


def _oracle_returns(
    data: pd.DataFrame, oracle: Mapping[tuple[str, str], float]
) -> pd.Series:
    """The oracle mean return of each row's task (NaN where it has none)."""
    tasks = zip(data["task"], data["backend"])
    return pd.Series([oracle.get(t, np.nan) for t in tasks], index=data.index)


def normalize_returns(
    data: pd.DataFrame, oracle: Mapping[tuple[str, str], float]
) -> pd.DataFrame:
    """A copy of ``data`` with the returns of oracle tasks divided by the oracle's.

    Only the rows of :data:`RETURN_METRICS` whose task (env id, backend) is in
    ``oracle`` change.

    Examples:
        >>> data = pd.DataFrame({"task": ["A", "A", "A", "B"],
        ...     "backend": ["gymnasium", "gymnasium", "envpool", "gymnasium"],
        ...     "metric": ["train/episode_return", "train/success_rate",
        ...                "train/episode_return", "train/episode_return"],
        ...     "value": [0.4, 0.5, 0.4, 7.0]})
        >>> oracle = {("A", "gymnasium"): 0.8, ("A", "envpool"): 0.5}
        >>> normalize_returns(data, oracle)["value"].tolist()
        [0.5, 0.5, 0.8, 7.0]
    """
    data = data.copy()
    oracle_return = _oracle_returns(data, oracle)
    rows = data["metric"].isin(RETURN_METRICS) & oracle_return.notna()
    data.loc[rows, "value"] = data.loc[rows, "value"] / oracle_return[rows]
    return data


def _budgets(data: pd.DataFrame, budget: int | None) -> dict[tuple[str, str], int]:
    if budget is not None:
        return {task: int(budget) for task in _tasks(data)}
    budgets = {}
    for task, rows in data.groupby(TASK_KEYS):
        main = rows[rows["metric"] == MAIN_METRIC]
        # Runs that logged no train return: the frames all of them logged anything at.
        last = (
            (main if len(main) else rows).groupby(["setting", "seed"])["frames"].max()
        )
        budgets[task] = int(last.min())
    return budgets


def _per_task(data: pd.DataFrame, values: Mapping[tuple[str, str], int]) -> pd.Series:
    """Each row's value of its task (env id, backend) in ``values``."""
    tasks = zip(data["task"], data["backend"])
    return pd.Series([values[task] for task in tasks], index=data.index, dtype="int64")


def _median_gap(frames: pd.Series) -> float:
    steps = np.unique(frames.to_numpy())
    return float(np.median(np.diff(steps))) if len(steps) > 1 else 0.0


def final_scores(
    data: pd.DataFrame,
    oracle: Mapping[tuple[str, str], float] | None = None,
    budget: int | None = None,
) -> pd.DataFrame:
    """Each run's value of each metric at the last logged step at or before the budget.

    Runs that stopped more than one logging period short of the budget are left
    out (they have no value at the budget).

    Args:
        data: the table of :func:`extract_run_data` (raw values).
        oracle: task (env id, backend) to oracle mean return; its tasks' returns
            are normalised.
        budget: frames; ``None``: per task, the largest frame count that all of its
            runs reached in ``train/episode_return``.

    Returns:
        ``task, backend, setting, seed, metric, budget, frames, value``
        (``frames``: the step the value was logged at).

    Examples:
        >>> data = pd.DataFrame({"task": "A", "backend": "gymnasium", "setting": "s",
        ...     "seed": [0, 0, 1], "frames": [10, 20, 10],
        ...     "metric": "train/episode_return", "value": [0.2, 0.4, 0.6]})
        >>> oracle = {("A", "gymnasium"): 0.8}
        >>> final_scores(data, oracle)[["seed", "budget", "frames", "value"]]
           seed  budget  frames  value
        0     0      10      10   0.25
        1     1      10      10   0.75
    """
    if oracle:
        data = normalize_returns(data, oracle)
    budgets = _budgets(data, budget)
    data = data.assign(budget=_per_task(data, budgets))
    # A run that stopped short of the budget (by more than one logging period)
    # has no value at the budget: it is left out, not read at an earlier frame.
    reached = data.groupby(_RUN_KEYS)["frames"].agg(["max", _median_gap])
    reached = reached["max"] + reached["_median_gap"]
    run_index = pd.MultiIndex.from_frame(data[_RUN_KEYS])
    data = data[reached.reindex(run_index).to_numpy() >= data["budget"].to_numpy()]
    data = data[data["frames"] <= data["budget"]]
    last = data.groupby([*_RUN_KEYS, "metric"])["frames"].idxmax()
    columns = [*_RUN_KEYS, "metric", "budget", "frames", "value"]
    return _in_task_order(data.loc[last.values, columns])


def _bootstrap_seed(seed: int, *names: object) -> np.ndarray:
    # One stream per estimate, named by what it estimates: an estimate does not
    # depend on which other settings or tasks are aggregated with it.
    name = zlib.crc32("\x1f".join(map(str, names)).encode())
    return np.random.SeedSequence([seed, name]).generate_state(4)


def _interval_estimate(
    scores: np.ndarray | list[np.ndarray],
    func: Callable[..., np.ndarray],
    reps: int,
    seed: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    from rliable import library as rly

    # rliable 1.2 resamples with np.random.choice, the global generator, whatever
    # ``random_state`` says: seed the global one for this estimate, then restore it.
    saved = np.random.get_state()
    np.random.seed(seed)
    try:
        with warnings.catch_warnings():
            # arch deprecates the ``random_state`` that rliable passes on.
            warnings.simplefilter("ignore", FutureWarning)
            points, intervals = rly.get_interval_estimates(
                {"x": scores},
                func,
                reps=reps,
                random_state=np.random.RandomState(seed),
            )
    finally:
        np.random.set_state(saved)
    return np.asarray(points["x"]), np.asarray(intervals["x"])


def _iqm(scores: np.ndarray) -> np.ndarray:
    from rliable import metrics

    return np.array([metrics.aggregate_iqm(scores)])


def iqm_interval(
    scores: Sequence[float] | np.ndarray,
    *,
    reps: int = 2000,
    seed: int = 0,
    names: Sequence[object] = (),
) -> tuple[float, float, float]:
    """The IQM of per-run scores with its 95% stratified-bootstrap CI (rliable).

    How the reports state a result over seeds. The bootstrap draws from one
    stream per estimate, named by ``names`` (what it estimates) and ``seed``, so
    an estimate does not depend on what else is aggregated beside it.

    Args:
        scores: one score per run.
        reps (int): bootstrap replications.
        seed (int): seed of the bootstrap.
        names: what is estimated (e.g. task, setting, metric).

    Returns:
        ``(iqm, low, high)``.

    Examples:
        >>> iqm, low, high = iqm_interval([0.1, 0.5, 0.6, 0.7, 0.9], reps=200,
        ...                               names=("task", "setting"))
        >>> round(iqm, 2), bool(0.1 <= low <= iqm <= high <= 0.9)
        (0.6, True)
        >>> iqm_interval([0.1, 0.5, 0.6, 0.7, 0.9], reps=200, names=("task", "setting"))[1] == low
        True
    """
    values = np.asarray(scores, dtype=float)[:, None]
    point, interval = _interval_estimate(
        values, _iqm, reps, _bootstrap_seed(seed, *names)
    )
    return float(point[0]), float(interval[0, 0]), float(interval[1, 0])


def _iqm_per_column(scores: np.ndarray) -> np.ndarray:
    # rliable's aggregate_iqm at every frame of a (runs x 1 x frames) array at
    # once: a 25% trimmed mean over runs.
    from scipy.stats import trim_mean

    return trim_mean(scores[:, 0, :], proportiontocut=0.25, axis=0)


def frames_to_threshold(
    data: pd.DataFrame,
    oracle: Mapping[tuple[str, str], float],
    budget: int | None = None,
    fractions: Sequence[float] = FRACTIONS,
    window: int = EPISODE_WINDOW,
) -> pd.DataFrame:
    """Per seed, the first frame at which the normalised train return reached each fraction.

    Only tasks (env id, backend) in ``oracle`` are covered, and only steps up to
    the budget (as in :func:`final_scores`) are searched. Where the run logged its episode count
    (:data:`EPISODES_METRIC`), a step counts only once ``window`` episodes have
    ended: before that the moving mean holds the few episodes that ended first,
    the short, successful ones when failures run to a long time limit.

    Returns:
        ``task, backend, setting, seed, fraction, frames, searched_to``;
        ``frames`` is ``<NA>`` (censored) when the fraction was not reached by
        ``searched_to``.

    Examples:
        >>> data = pd.DataFrame({"task": "A", "backend": "envpool", "setting": "s",
        ...     "seed": 0, "frames": [10, 20, 30], "metric": "train/episode_return",
        ...     "value": [0.1, 0.45, 0.6]})
        >>> table = frames_to_threshold(data, {("A", "envpool"): 0.5},
        ...                             fractions=[0.8, 1.5])
        >>> table[["task", "backend", "fraction", "frames", "searched_to"]]
          task  backend  fraction  frames  searched_to
        0    A  envpool       0.8      20           30
        1    A  envpool       1.5    <NA>           30
    """
    budgets = _budgets(data, budget)
    episodes = {
        key: run.sort_values("frames")
        for key, run in data[data["metric"] == EPISODES_METRIC].groupby(_RUN_KEYS)
    }
    data = data[(data["metric"] == MAIN_METRIC) & _oracle_returns(data, oracle).notna()]
    data = normalize_returns(data, oracle)
    rows = []
    for (task, backend, setting, seed), run in data.groupby(_RUN_KEYS, sort=True):
        run = run[run["frames"] <= budgets[task, backend]].sort_values("frames")
        searched_to = int(run["frames"].iloc[-1]) if len(run) else None
        counts = episodes.get((task, backend, setting, seed))
        full = np.ones(len(run), dtype=bool)
        if counts is not None and len(run):
            # the count logged at or before each step (0 before the first)
            ended = pd.merge_asof(
                run[["frames"]],
                counts[["frames", "value"]].rename(columns={"value": "ended"}),
                on="frames",
            )["ended"].fillna(0)
            full = ended.to_numpy() >= window
        for fraction in fractions:
            reached = run["frames"][(run["value"] >= fraction).to_numpy() & full]
            rows.append(
                {
                    "task": task,
                    "backend": backend,
                    "setting": setting,
                    "seed": seed,
                    "fraction": fraction,
                    "frames": int(reached.iloc[0]) if len(reached) else None,
                    "searched_to": searched_to,
                }
            )
    table = pd.DataFrame(
        rows, columns=[*_RUN_KEYS, "fraction", "frames", "searched_to"]
    )
    for column in ("frames", "searched_to"):
        table[column] = table[column].astype("Int64")
    return _in_task_order(table)


def _median_frames(frames: pd.Series) -> int | str:
    # A seed that never reached the threshold counts as infinitely late, so the
    # median is "not reached" when half the seeds or more never got there.
    median = np.median(frames.astype("float64").fillna(np.inf).to_numpy())
    return _NOT_REACHED if not np.isfinite(median) else int(round(median))


def _rows_of(table: pd.DataFrame, task: str, backend: str, setting: str) -> pd.Series:
    """Which rows of ``table`` are the runs of one setting of one task."""
    return (
        (table["task"] == task)
        & (table["backend"] == backend)
        & (table["setting"] == setting)
    )


def _final_columns(
    name: str, scores: np.ndarray, reps: int, seed: int, names: Sequence[object]
) -> dict[str, object]:
    """``summary.csv``'s columns of one metric (short name ``name``) from its
    final ``scores`` over seeds, the bootstrap named by ``names``."""
    iqm = low = high = mean = None
    if len(scores):
        iqm, low, high = iqm_interval(scores, reps=reps, seed=seed, names=names)
        mean = scores.mean()
    return {
        f"{name}_iqm": iqm,
        f"{name}_ci_low": low,
        f"{name}_ci_high": high,
        f"{name}_mean": mean,
        f"{name}_seeds": len(scores),
    }


def summarize(
    data: pd.DataFrame,
    oracle: Mapping[tuple[str, str], float] | None = None,
    budget: int | None = None,
    reps: int = 2000,
    seed: int = 0,
    meta: pd.DataFrame | None = None,
    fractions: Sequence[float] = FRACTIONS,
) -> pd.DataFrame:
    """One row per task and setting with final performance and frames to thresholds.

    See the module's description of ``summary.csv`` for the columns.

    Args:
        data: the table of :func:`extract_run_data` (raw values).
        oracle: task (env id, backend) to oracle mean return (tasks absent stay
            unnormalised).
        budget: frames at which final performance is read (see :func:`final_scores`).
        reps (int): bootstrap replications of the 95% CIs.
        seed (int): seed of the bootstrap.
        meta: the table of :func:`runs_metadata`, for ``seeds_unfinished``.
        fractions: fractions of the oracle return for the threshold columns.

    Examples:
        >>> data = pd.DataFrame({"task": "A", "backend": "gymnasium", "setting": "s",
        ...     "seed": [0, 1, 2, 3], "frames": 100, "metric": "train/episode_return",
        ...     "value": [0.0, 0.4, 0.6, 2.0]})
        >>> row = summarize(data, reps=100).iloc[0]
        >>> float(row["train_return_iqm"]), float(row["train_return_mean"])
        (0.5, 0.75)
    """
    oracle = dict(oracle or {})
    finals = final_scores(data, oracle, budget)
    budgets = _budgets(data, budget)
    thresholds = frames_to_threshold(data, oracle, budget, fractions)
    last = data[data["metric"] == MAIN_METRIC].groupby(_RUN_KEYS)["frames"].max()
    last = last.reset_index()
    keys = [*TASK_KEYS, "setting"]
    short_of_budget = (
        (last["frames"] < _per_task(last, budgets))
        .groupby([last[k] for k in keys])
        .sum()
    )
    rows = []
    for (task, backend, setting), runs in data.groupby(keys, sort=True):
        normalized = (task, backend) in oracle
        row = {
            "task": task,
            "backend": backend,
            "setting": setting,
            "normalized": normalized,
            "oracle_return": oracle.get((task, backend)),
            "budget": budgets[task, backend],
            "seeds": runs["seed"].nunique(),
            "seeds_unfinished": None,
            "seeds_short_of_budget": int(
                short_of_budget.get((task, backend, setting), 0)
            ),
        }
        if meta is not None:
            runs_meta = meta[_rows_of(meta, task, backend, setting)]
            row["seeds_unfinished"] = len(unfinished_runs(runs_meta))
        scores = finals[_rows_of(finals, task, backend, setting)]
        for metric, name in METRICS.items():
            values = scores.loc[scores["metric"] == metric, "value"].to_numpy()
            names = ("final", bootstrap_task_name(task, backend), setting, metric)
            row.update(_final_columns(name, values, reps, seed, names))
        crossings = thresholds[_rows_of(thresholds, task, backend, setting)]
        for fraction in fractions:
            at = crossings.loc[crossings["fraction"] == fraction, "frames"]
            row[f"seeds_reaching_{fraction}"] = (
                int(at.notna().sum()) if normalized else None
            )
            row[f"median_frames_to_{fraction}"] = (
                _median_frames(at) if normalized and len(at) else None
            )
        rows.append(row)
    summary = pd.DataFrame(rows)
    for column in summary.columns:
        if column == "seeds_unfinished" or column.startswith("seeds_reaching_"):
            summary[column] = summary[column].astype("Int64")
        elif column.startswith("median_frames_to_"):
            # frame counts, "not reached" or None (unnormalised): kept as they
            # are, whatever the other rows hold (no 8500 -> 8500.0)
            summary[column] = pd.Series(
                [row[column] for row in rows], index=summary.index, dtype=object
            )
    return _in_task_order(summary.round(4))


def probability_of_improvement(scores_x: np.ndarray, scores_y: np.ndarray) -> float:
    """P(X > Y) + P(X = Y) / 2 for a run of X and a run of Y drawn at random, per
    task (a column), averaged over tasks: rliable's
    ``metrics.probability_of_improvement``, the same numbers.

    rliable counts through SciPy's Mann-Whitney U test, about a millisecond a
    call, and a bootstrap calls it 2,000 times for each pair of settings; this
    counts the pairs at once in NumPy (the U statistic is that count).

    Examples:
        >>> probability_of_improvement(np.array([[1.0], [2.0]]), np.array([[0.0], [2.0]]))
        0.625
    """
    x, y = np.asarray(scores_x)[:, None, :], np.asarray(scores_y)[None, :, :]
    # runs of X x runs of Y x tasks; compared, not subtracted (no overflow, and
    # inf ties with inf); a task with a NaN score is NaN, as in rliable
    wins = (x > y).sum(axis=(0, 1)) + 0.5 * (x == y).sum(axis=(0, 1))
    unknown = np.isnan(x).any(axis=(0, 1)) | np.isnan(y).any(axis=(0, 1))
    per_task = np.where(unknown, np.nan, wins / (x.shape[0] * y.shape[1]))
    return float(np.mean(per_task))


def improvement_probabilities(
    data: pd.DataFrame,
    oracle: Mapping[tuple[str, str], float] | None = None,
    budget: int | None = None,
    reps: int = 2000,
    seed: int = 0,
) -> pd.DataFrame:
    """Per task, P(setting X beats setting Y) for every ordered pair of settings.

    The probability that a seed of X ends above a seed of Y on the final
    (normalised) ``train/episode_return`` (:func:`probability_of_improvement`,
    rliable's), with a 95% stratified-bootstrap CI (rliable's).

    Returns:
        ``task, backend, budget, setting_x, setting_y, seeds_x, seeds_y,
        probability, ci_low, ci_high``; no rows for a task with one setting.

    Examples:
        >>> data = pd.DataFrame({"task": "A", "backend": "gymnasium",
        ...     "setting": ["x", "x", "y", "y"], "seed": [0, 1, 0, 1], "frames": 10,
        ...     "metric": "train/episode_return", "value": [1.0, 2.0, 0.0, 0.5]})
        >>> improvement_probabilities(data, reps=50)[["setting_x", "probability"]]
          setting_x  probability
        0         x          1.0
        1         y          0.0
    """
    finals = final_scores(data, oracle, budget)
    finals = finals[finals["metric"] == MAIN_METRIC]
    rows = []
    for (task, backend), task_finals in finals.groupby(TASK_KEYS, sort=True):
        by_setting = {
            s: g["value"].to_numpy()[:, None]
            for s, g in task_finals.groupby("setting", sort=True)
        }
        for x, scores_x in by_setting.items():
            for y, scores_y in by_setting.items():
                if x == y:
                    continue
                name = bootstrap_task_name(task, backend)
                stream = _bootstrap_seed(seed, "improvement", name, x, y)
                point, interval = _interval_estimate(
                    [scores_x, scores_y],
                    probability_of_improvement,
                    reps,
                    stream,
                )
                rows.append(
                    {
                        "task": task,
                        "backend": backend,
                        "budget": int(task_finals["budget"].iloc[0]),
                        "setting_x": x,
                        "setting_y": y,
                        "seeds_x": len(scores_x),
                        "seeds_y": len(scores_y),
                        "probability": float(point),
                        "ci_low": float(np.ravel(interval)[0]),
                        "ci_high": float(np.ravel(interval)[1]),
                    }
                )
    columns = [*TASK_KEYS, "budget", "setting_x", "setting_y", "seeds_x", "seeds_y"]
    table = pd.DataFrame(rows, columns=[*columns, "probability", "ci_low", "ci_high"])
    return _in_task_order(table.round(4))


def _figure(n_panels: int, width: float = 5.0, height: float = 3.6):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    ncols = min(3, max(n_panels, 1))
    nrows = math.ceil(max(n_panels, 1) / ncols)
    fig, axes = plt.subplots(
        nrows, ncols, figsize=(width * ncols, height * nrows), squeeze=False
    )
    for ax in axes.flat[n_panels:]:
        ax.set_visible(False)
    return fig, list(axes.flat[:n_panels])


def _setting_colors(settings: Sequence[str]) -> dict[str, tuple]:
    # One colour per setting across every panel and both figures.
    import matplotlib

    cmap = matplotlib.colormaps["tab10" if len(settings) <= 10 else "tab20"]
    return {s: cmap(i % cmap.N) for i, s in enumerate(sorted(settings))}


def _save(fig, path: Path, title: str) -> Path:
    import matplotlib.pyplot as plt

    handles = {}
    for ax in fig.axes:
        for handle, label in zip(*ax.get_legend_handles_labels()):
            handles.setdefault(label, handle)
    # Up to 3 legend columns, fewer where the labels would not fit the figure's
    # width (a one-panel figure with long setting names).
    ncol = min(3, len(handles))
    while handles:
        legend = fig.legend(
            list(handles.values()),
            list(handles),
            loc="lower center",
            bbox_to_anchor=(0.5, 0.0),
            ncol=ncol,
            fontsize="small",
            frameon=False,
        )
        width = legend.get_window_extent(fig.canvas.get_renderer()).width
        if ncol == 1 or width <= fig.bbox.width:
            break
        legend.remove()
        ncol -= 1
    # The legend's rows (about 0.2 inch each) and each title line past the
    # first (about 0.19 inch) add to the figure's height, not take from the panels.
    rows = math.ceil(len(handles) / ncol) if handles else 0
    # Wrapped to the figure's width (about 11 characters an inch at this size):
    # a one-panel figure is too narrow for the title on one line.
    lines = textwrap.wrap(title, width=max(20, int(fig.get_figwidth() * 11)))
    fig.suptitle("\n".join(lines), fontsize="medium")
    height = fig.get_figheight() + 0.19 * (len(lines) - 1) + 0.2 * rows
    fig.set_figheight(height)
    # tight_layout leaves room for the suptitle itself: the rect's top stays 1
    fig.tight_layout(rect=(0, (0.2 * rows + 0.05) / height, 1, 1))
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def _score_label(normalized: bool) -> str:
    return "return / oracle return" if normalized else "return (no oracle: raw)"


def plot_curves(
    data: pd.DataFrame,
    path: str | os.PathLike,
    oracle: Mapping[tuple[str, str], float] | None = None,
    budget: int | None = None,
    reps: int = 2000,
    seed: int = 0,
    grid_points: int = 101,
) -> Path:
    """Per task, the IQM over seeds of the train return against frames, 95% CI band.

    Each run's (normalised) ``train/episode_return`` is interpolated onto a grid
    of ``grid_points`` frames from 0 to the task's last frame, never past the
    run's own first or last point; a setting's curve covers the grid points where
    all its seeds have data. The band is rliable's stratified bootstrap over seeds.
    """
    oracle = dict(oracle or {})
    data = normalize_returns(data[data["metric"] == MAIN_METRIC], oracle)
    budgets = _budgets(data, budget)
    tasks = _tasks(data)
    colors = _setting_colors(data["setting"].unique())
    fig, axes = _figure(len(tasks))
    for ax, (task, backend) in zip(axes, tasks):
        task_data = data[(data["task"] == task) & (data["backend"] == backend)]
        grid = np.linspace(0, task_data["frames"].max(), grid_points)
        for setting, runs in task_data.groupby("setting", sort=True):
            curves = np.stack(
                [
                    np.interp(
                        grid, run["frames"], run["value"], left=np.nan, right=np.nan
                    )
                    for _, run in runs.sort_values("frames").groupby("seed")
                ]
            )
            covered = np.isfinite(curves).all(axis=0)
            if not covered.any():
                continue
            name = bootstrap_task_name(task, backend)
            stream = _bootstrap_seed(seed, "curve", name, setting)
            point, interval = _interval_estimate(
                curves[:, None, covered], _iqm_per_column, reps, stream
            )
            label = f"{setting} ({len(curves)} seed{'' if len(curves) == 1 else 's'})"
            ax.plot(grid[covered], point, color=colors[setting], label=label)
            ax.fill_between(
                grid[covered],
                interval[0],
                interval[1],
                color=colors[setting],
                alpha=0.2,
            )
        ax.axvline(budgets[task, backend], color="grey", linestyle=":", linewidth=1)
        ax.set_title(task_name(task, backend), fontsize="medium")
        ax.set_xlabel("frames")
        ax.set_ylabel(_score_label((task, backend) in oracle))
        ax.grid(True, alpha=0.2)
    title = (
        "train episode return: IQM over seeds (mean below 4 seeds), "
        "95% stratified-bootstrap CI (rliable); dotted: budget"
    )
    return _save(fig, Path(path), title)


def plot_levels(summary: pd.DataFrame, path: str | os.PathLike) -> Path | None:
    """Per task, the final return (IQM, 95% CI) against the noise level (Figure 2).

    One line per base setting that has runs at a noise level other than 0
    (:func:`split_level`), from ``summary.csv``'s ``train_return`` columns; level 0
    is the base setting's own row. Returns ``None`` (and writes nothing) when no
    setting names a level.
    """
    base, level = (
        zip(*map(split_level, summary["setting"])) if len(summary) else ((), ())
    )
    rows = summary.assign(base=list(base), level=list(level))
    noisy = set(rows.loc[rows["level"] > 0, "base"])
    rows = rows[rows["base"].isin(noisy)]
    if rows.empty:
        return None
    tasks = _tasks(rows)
    colors = _setting_colors(sorted(noisy))
    fig, axes = _figure(len(tasks))
    for ax, (task, backend) in zip(axes, tasks):
        task_rows = rows[(rows["task"] == task) & (rows["backend"] == backend)]
        for base, points in task_rows.groupby("base", sort=True):
            points = points.sort_values("level")
            iqm = points["train_return_iqm"].to_numpy(float)
            low = points["train_return_ci_low"].to_numpy(float)
            high = points["train_return_ci_high"].to_numpy(float)
            seeds = points["seeds"].min()
            ax.errorbar(
                points["level"],
                iqm,
                yerr=[iqm - low, high - iqm],
                color=colors[base],
                marker="o",
                capsize=3,
                label=f"{base} ({seeds}+ seeds)",
            )
        ax.set_xticks(sorted(task_rows["level"].unique()))
        ax.set_title(task_name(task, backend), fontsize="medium")
        ax.set_xlabel(f"noise level ({LEVEL_KEY})")
        ax.set_ylabel(_score_label(bool(task_rows["normalized"].any())))
        ax.grid(True, alpha=0.2)
    budget = ", ".join(str(int(b)) for b in sorted(rows["budget"].unique()))
    title = (
        f"train episode return at {budget} frames against the noise level: IQM "
        "over seeds, 95% stratified-bootstrap CI (rliable)"
    )
    return _save(fig, Path(path), title)


def _score_distribution(scores: np.ndarray, taus: np.ndarray) -> np.ndarray:
    # rliable's ``score_distributions`` (the fraction of runs scoring above tau),
    # vectorised over tau.
    return (scores.reshape(-1, 1) > taus.reshape(1, -1)).mean(axis=0)


def plot_profiles(
    data: pd.DataFrame,
    path: str | os.PathLike,
    oracle: Mapping[tuple[str, str], float] | None = None,
    budget: int | None = None,
    reps: int = 2000,
    seed: int = 0,
) -> Path:
    """Per task, rliable performance profiles of the final (normalised) train return.

    A profile is the fraction of a setting's runs whose final score exceeds tau,
    with a 95% stratified-bootstrap band, drawn by rliable's
    ``plot_utils.plot_performance_profiles``.
    """
    from rliable import plot_utils

    oracle = dict(oracle or {})
    finals = final_scores(data, oracle, budget)
    finals = finals[finals["metric"] == MAIN_METRIC]
    tasks = _tasks(finals)
    colors = _setting_colors(finals["setting"].unique())
    fig, axes = _figure(len(tasks))
    for ax, (task, backend) in zip(axes, tasks):
        task_finals = finals[(finals["task"] == task) & (finals["backend"] == backend)]
        normalized = (task, backend) in oracle
        low, high = task_finals["value"].min(), task_finals["value"].max()
        if normalized:
            low, high = min(0.0, low), max(1.0, high)
        else:
            # Start below the lowest score so that the profile starts at 1.
            pad = 0.05 * (high - low) if high > low else 1.0
            low, high = low - pad, high + pad
        taus = np.linspace(low, high, 101)
        profiles, cis = {}, {}
        for setting, group in task_finals.groupby("setting", sort=True):
            # rly.create_performance_profile computes this same profile but takes
            # no random_state; the seeded bootstrap keeps the figure reproducible.
            name = bootstrap_task_name(task, backend)
            stream = _bootstrap_seed(seed, "profile", name, setting)
            profiles[setting], cis[setting] = _interval_estimate(
                group["value"].to_numpy()[:, None],
                lambda s, taus=taus: _score_distribution(s, taus),
                reps,
                stream,
            )
        plot_utils.plot_performance_profiles(
            profiles,
            taus,
            performance_profile_cis=cis,
            ax=ax,
            colors={s: colors[s] for s in profiles},
            xlabel=f"final {_score_label(normalized)} (tau)",
            ylabel="fraction of runs > tau",
            labelsize="medium",
            ticklabelsize="small",
        )
        budget_frames = int(task_finals["budget"].iloc[0])
        ax.set_title(
            f"{task_name(task, backend)} at {budget_frames} frames", fontsize="medium"
        )
    title = "performance profiles of the final train episode return, 95% bootstrap CI"
    return _save(fig, Path(path), title)


def write_runs_file(data: pd.DataFrame, path: Path) -> Path:
    """Writes per-run data as ``runs.csv.xz`` does: six significant digits, xz.

    The file's bytes depend on the data alone (xz stores no time or name), so
    rewriting the same data leaves a committed file unchanged.

    Args:
        data: a table of :data:`_DATA_COLUMNS`, as :func:`extract_run_data` returns.
        path: the file; a name ending in ``.xz`` is compressed, any other is not.

    Returns:
        ``path``.
    """
    compression = {"method": "xz", "preset": 9} if str(path).endswith(".xz") else None
    data.to_csv(path, index=False, float_format="%.6g", compression=compression)
    return Path(path)


def runs_file(directory: Path) -> Path | None:
    """The per-run data file of a results directory (:data:`RUNS_FILES`), or None."""
    for name in RUNS_FILES:
        if (Path(directory) / name).is_file():
            return Path(directory) / name
    return None


def _regenerate_runs(path: Path) -> str:
    return (
        "recipes/results/aggregate.py from the run directories it was aggregated "
        f"from (python recipes/results/aggregate.py RUN_DIR ... --out {path.parent})"
    )


def _read_runs_csv(path: Path) -> pd.DataFrame:
    # Labels such as "none" or "NA" are settings, not missing values; the
    # compression follows the file's name (runs.csv.xz or a plain runs.csv).
    data = pd.read_csv(
        path,
        dtype={"task": str, "backend": str, "setting": str, "metric": str},
        keep_default_na=False,
        float_precision="round_trip",
    )
    _require_backend(data, path, ",".join(_DATA_COLUMNS), _regenerate_runs(path))
    return data


def _read_meta_beside(runs_csv: Path) -> pd.DataFrame | None:
    # runs_meta.csv is written beside runs.csv; data from before it existed has none
    meta_csv = runs_csv.with_name("runs_meta.csv")
    return _read_meta_csv(meta_csv) if meta_csv.is_file() else None


def meta_of_data(data: pd.DataFrame, source: str) -> pd.DataFrame:
    """A ``runs_meta.csv`` table for data that came without one: each run with
    its last logged frame, its budget and completion unknown, ``source`` as its
    run directory."""
    reach = data.groupby(_RUN_KEYS, as_index=False)["frames"].max()
    unknown = [pd.NA] * len(reach)
    return reach.rename(columns={"frames": "last_frame"}).assign(
        total_frames=pd.array(unknown, dtype="Int64"),
        finished=pd.array(unknown, dtype="boolean"),
        run_dir=source,
    )[_META_COLUMNS]


def _read_meta_csv(path: Path) -> pd.DataFrame:
    meta = pd.read_csv(
        path,
        dtype={"task": str, "backend": str, "setting": str, "run_dir": str},
        keep_default_na=False,
        na_values={"total_frames": [""], "last_frame": [""]},
    )
    _require_backend(meta, path, ",".join(_META_COLUMNS), _regenerate_runs(path))
    return meta


def _interval(row: pd.Series, name: str) -> str:
    iqm = row.get(f"{name}_iqm")
    if iqm is None or pd.isna(iqm):
        return ""
    return f"{iqm:.2f} [{row[f'{name}_ci_low']:.2f}, {row[f'{name}_ci_high']:.2f}]"


def _frames_to(row: pd.Series, fraction: float) -> str:
    median = row.get(f"median_frames_to_{fraction}")
    if median is None or (not isinstance(median, str) and pd.isna(median)):
        return ""
    reached = int(row[f"seeds_reaching_{fraction}"])
    try:
        median = f"{float(median) / 1000:.0f}k"
    except ValueError:
        pass  # "not reached"
    return f"{median} ({reached}/{int(row['seeds'])})"


def unfinished_runs(meta: pd.DataFrame) -> pd.DataFrame:
    """The rows of a ``runs_meta.csv`` table whose run had not reached its budget.

    A run is unfinished only where its metadata says so: runs merged from data
    without a ``runs_meta.csv`` have no completion recorded (an empty cell), and
    the column reads back as bools or as strings.

    Examples:
        >>> meta = pd.DataFrame({"seed": [0, 1, 2], "finished": [True, False, ""]})
        >>> unfinished_runs(meta)["seed"].tolist()
        [1]
    """
    if "finished" not in meta:
        return meta.iloc[:0]
    return meta[meta["finished"].astype(str) == "False"]


def status_text(
    summary: pd.DataFrame,
    meta: pd.DataFrame | None,
    scores: pd.DataFrame | None = None,
) -> str:
    """One paragraph (reStructuredText) on what the tables cover: seeds per
    setting and the runs that had not reached their own ``total_frames`` when
    aggregated.

    Such a run is either short of the aggregation's budget, and left out of the
    final scores, or past it (a budget below the runs' own, or a run extended
    beyond it), and in them, read at the budget. ``scores`` (the table of
    :func:`final_scores`, required when ``meta`` holds such runs) says which, so
    the text follows the scores' own rule. Where the summary covers several
    tasks, each setting is named with its task (:func:`task_name`).

    Examples:
        >>> summary = pd.DataFrame({"task": ["A", "A"],
        ...     "backend": ["gymnasium", "envpool"], "setting": "s", "seeds": [3, 1]})
        >>> print(status_text(summary, None), end="")
        Seeds that reached the budget, per setting: A s 3, A (envpool) s 1.
        >>> summary = pd.DataFrame({"task": "A", "backend": "gymnasium",
        ...     "setting": ["s", "t"], "seeds": 1, "train_return_seeds": [0, 1]})
        >>> meta = pd.DataFrame({"task": "A", "backend": "gymnasium",
        ...     "setting": ["s", "t"], "seed": 0, "total_frames": 10000,
        ...     "last_frame": [4000, 6000], "finished": False})
        >>> scores = pd.DataFrame({"task": ["A"], "backend": ["gymnasium"],
        ...     "setting": ["t"], "seed": [0]})
        >>> print(status_text(summary, meta, scores), end="")
        ... # doctest: +NORMALIZE_WHITESPACE
        Seeds that reached the budget, per setting: s 0, t 1. Unfinished when
        aggregated: s seed 0 (4k of 10k frames); final scores leave them out
        (curves show them up to where they got), and rerunning the sweep command
        completes them. Past the budget, not yet at their own total_frames (in the
        final scores, read at the budget): t seed 0 (6k of 10k frames).
    """
    several = len(summary[TASK_KEYS].drop_duplicates()) > 1

    def name(row) -> str:
        task = task_name(row["task"], row["backend"])
        return f"{task} {row['setting']}" if several else str(row["setting"])

    def listed(runs: pd.DataFrame) -> str:
        return ", ".join(
            f"{name(r._asdict())} seed {r.seed} ({int(r.last_frame) // 1000}k of "
            f"{int(r.total_frames) // 1000}k frames)"
            for r in runs.itertuples()
        )

    counts = ", ".join(
        f"{name(row)} {int(row.get('train_return_seeds', row['seeds']))}"
        for _, row in summary.iterrows()
    )
    text = f"Seeds that reached the budget, per setting: {counts}."
    late = None if meta is None else unfinished_runs(meta)
    if late is None or not len(late):
        return text + "\n"
    if scores is None:
        raise ValueError(
            "status_text needs the final scores (final_scores' table) to say which "
            "unfinished runs they hold"
        )
    scored = pd.MultiIndex.from_frame(scores[_RUN_KEYS].drop_duplicates())
    past = pd.MultiIndex.from_frame(late[_RUN_KEYS]).isin(scored)
    short, beyond = late[~past], late[past]
    if len(short):
        text += (
            f" Unfinished when aggregated: {listed(short)}; final scores leave them "
            "out (curves show them up to where they got), and rerunning the sweep "
            "command completes them."
        )
    if len(beyond):
        text += (
            " Past the budget, not yet at their own total_frames (in the final "
            f"scores, read at the budget): {listed(beyond)}."
        )
    return text + "\n"


def report_table(summary: pd.DataFrame) -> pd.DataFrame:
    """The summary in the columns a report shows: IQM [95% CI] and frames to
    thresholds (median over seeds, with how many seeds reached it).

    Examples:
        >>> row = {"task": "T", "backend": "gymnasium", "setting": "s", "seeds": 4,
        ...        "budget": 1000, "normalized": True, "train_return_iqm": 0.5,
        ...        "train_return_ci_low": 0.4, "train_return_ci_high": 0.6,
        ...        "median_frames_to_0.5": 800.0, "seeds_reaching_0.5": 3}
        >>> report_table(pd.DataFrame([row])).iloc[0]["return / oracle"]
        '0.50 [0.40, 0.60]'
    """
    rows = []
    for _, row in summary.iterrows():
        ret = "return / oracle" if row.get("normalized", False) else "return"
        out = {
            "task": row["task"].removeprefix("MiniGrid-"),
            "backend": row["backend"],
            "setting": row["setting"],
            # the runs that reached the budget (those in the final scores)
            "seeds": int(row.get("train_return_seeds", row["seeds"])),
            "frames": f"{int(row['budget']) / 1000:.0f}k",
            ret: _interval(row, "train_return"),
            "success": _interval(row, "train_success"),
            f"eval {ret}": _interval(row, "eval_return"),
        }
        for fraction in FRACTIONS:
            out[f"frames to {fraction}"] = _frames_to(row, fraction)
        rows.append(out)
    return pd.DataFrame(rows)


def aggregate(
    data: pd.DataFrame,
    out: str | os.PathLike,
    *,
    oracle: Mapping[tuple[str, str], float] | None = None,
    budget: int | None = None,
    reps: int = 2000,
    seed: int = 0,
    meta: pd.DataFrame | None = None,
    figures: Collection[str] | None = None,
) -> dict[str, Path]:
    """Writes every table and figure computed from the per-run data into ``out``.

    ``summary.csv``, ``report.csv`` (its short form, for reports),
    ``final_scores.csv`` (the per-run scores it aggregates),
    ``frames_to_threshold.csv``, ``probability_of_improvement.csv``,
    ``curves.png`` and ``performance_profiles.png`` (see the module description),
    and ``levels.png`` when settings were run at several noise levels.
    ``figures`` names the figures to draw (None: all of :data:`FIGURES`).

    Returns:
        The path of each output, by file name.
    """
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    oracle = dict(oracle or {})
    tables = {
        "summary.csv": summarize(data, oracle, budget, reps, seed, meta),
        "final_scores.csv": final_scores(data, oracle, budget),
        "frames_to_threshold.csv": frames_to_threshold(data, oracle, budget),
        "probability_of_improvement.csv": improvement_probabilities(
            data, oracle, budget, reps, seed
        ),
    }
    tables["report.csv"] = report_table(tables["summary.csv"])
    status = status_text(tables["summary.csv"], meta, tables["final_scores.csv"])
    (out / "status.rst").write_text(status)
    paths = {}
    for name, table in tables.items():
        paths[name] = out / name
        table.to_csv(paths[name], index=False)
    figures = FIGURES if figures is None else set(figures)
    if "curves.png" in figures:
        paths["curves.png"] = plot_curves(
            data, out / "curves.png", oracle, budget, reps, seed
        )
    if "performance_profiles.png" in figures:
        paths["performance_profiles.png"] = plot_profiles(
            data, out / "performance_profiles.png", oracle, budget, reps, seed
        )
    if "levels.png" in figures:
        levels = plot_levels(tables["summary.csv"], out / "levels.png")
        if levels is not None:
            paths["levels.png"] = levels
    return paths


ORACLE_DIR = Path("docs/results/oracle")
"""The oracle tables: ``oracle_returns.csv`` (``recipes/results/oracle.py``,
minigrid's layouts), ``envpool_oracle_returns.csv``
(``benchmarks/envpool_oracle.py``, envpool's layouts) and the suite's
(``benchmarks/suite_oracle.py``)."""


def default_oracle_tables() -> list[Path]:
    """Every ``*oracle_returns*.csv`` of :data:`ORACLE_DIR` (from the repository
    root), sorted."""
    return sorted(ORACLE_DIR.glob("*oracle_returns*.csv"))


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="python recipes/results/aggregate.py",
        description="Aggregates a sweep's runs into tables and figures "
        "(IQM with bootstrap CIs, frames to thresholds, curves, profiles).",
    )
    parser.add_argument("runs", nargs="*", type=Path, help="sweep or run directories")
    parser.add_argument(
        "--from-data",
        type=Path,
        help="a runs.csv.xz (or runs.csv) written before: recompute everything from it alone, or "
        "with run directories, add their runs to it (merge_run_data)",
    )
    parser.add_argument(
        "--all",
        type=Path,
        metavar="RESULTS_DIR",
        help="regenerate every experiment under RESULTS_DIR (each <dir>/runs.csv.xz, "
        "at the budget of its summary.csv) from its committed data",
    )
    parser.add_argument("--out", type=Path, help="output directory")
    parser.add_argument(
        "--settings",
        nargs="+",
        metavar="SETTING",
        help="keep only the runs of these settings",
    )
    parser.add_argument(
        "--tasks",
        nargs="+",
        metavar="TASK",
        help="keep only the runs of these tasks (env ids, on every backend)",
    )
    parser.add_argument(
        "--backends",
        nargs="+",
        metavar="BACKEND",
        help="keep only the runs on these backends (gymnasium, envpool)",
    )
    add_label_keys_argument(
        parser,
        " (--settings then names the labels with them); with run directories",
    )
    parser.add_argument("--budget", type=int, help="frames of final performance")
    parser.add_argument(
        "--oracle",
        type=Path,
        nargs="+",
        default=None,
        help="CSVs with env,backend,mean_return (default: the committed oracle tables, "
        f"{ORACLE_DIR}/*oracle_returns*.csv, when run from the repository root); "
        "'none' to skip",
    )
    parser.add_argument("--reps", type=int, default=2000, help="bootstrap replications")
    parser.add_argument("--seed", type=int, default=0, help="seed of the bootstrap")
    parser.add_argument(
        "--max-points", type=int, default=200, help="points per run and metric kept"
    )
    parser.add_argument(
        "--figures",
        nargs="*",
        choices=FIGURES,
        default=None,
        metavar="FIGURE",
        help=f"draw only these figures ({', '.join(FIGURES)}; default: all, "
        "--all: those the directory holds); --figures alone draws none",
    )
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """The command line (see the module description); returns the exit status."""
    parser = _parser()
    args = parser.parse_args(argv)
    if args.label_keys and not args.runs:
        parser.error(
            "--label-keys labels the runs of run directories: give them (the "
            "labels of --from-data and --all are those their data holds)"
        )
    if args.all is not None:
        if args.runs or args.from_data is not None or args.out is not None:
            parser.error("--all takes no run directories, --from-data or --out")
        return _regenerate_all(parser, args)
    if not args.runs and args.from_data is None:
        parser.error("give run directories, --from-data RUNS_CSV, or both")
    if args.out is None:
        parser.error("--out is required with run directories or --from-data")
    try:
        tables = default_oracle_tables() if args.oracle is None else args.oracle
        use_oracle = [str(t) for t in tables] != ["none"]
        oracle = read_oracle(*tables) if use_oracle else {}
        if args.from_data is not None and not args.from_data.is_file():
            raise FileNotFoundError(f"{args.from_data} does not exist")
        runs_csv = _runs_data_file(args)
        # Both modes compute from the file just written or given, so the tables
        # of a rerun from the committed data are the same bytes.
        data = _read_runs_csv(runs_csv)
        meta = _read_meta_beside(runs_csv)
    except (FileNotFoundError, ValueError) as error:
        parser.error(str(error))
    if data.empty:
        parser.error(f"{runs_csv}: the runs logged none of {', '.join(METRICS)}")
    paths = aggregate(
        data,
        args.out,
        oracle=oracle,
        budget=args.budget,
        reps=args.reps,
        seed=args.seed,
        meta=meta,
        figures=args.figures,
    )
    _report(data, meta, oracle, [runs_csv, *paths.values()])
    return 0


def _runs_data_file(args) -> Path:
    """The per-run data file the tables are computed from: ``--from-data`` as
    given, or the runs (merged into it, selected) written to ``--out``."""
    selected = {"--settings": args.settings, "--tasks": args.tasks}
    selected["--backends"] = args.backends
    selecting = any(values is not None for values in selected.values())
    if not args.runs and not selecting:
        return args.from_data
    earlier_meta = _read_meta_beside(args.from_data) if args.from_data else None
    if args.from_data is not None and earlier_meta is None:
        # a table copied away from its runs_meta.csv (git show REV:... > x.csv.xz)
        print(
            f"Warning: no runs_meta.csv beside {args.from_data}: its runs keep "
            "their last logged frame, and their budget, completion and run "
            "directory are written as unknown. Copy its runs_meta.csv beside it "
            "to keep them.",
            file=sys.stderr,
        )
    if not args.runs:
        data = _read_runs_csv(args.from_data)
        meta = earlier_meta
        if meta is None:
            meta = meta_of_data(data, str(args.from_data))
    else:
        runs = find_runs(args.runs, args.label_keys)
        data = extract_run_data(runs, args.max_points)
        meta = runs_metadata(runs)
        if args.from_data is not None:
            data, meta = merge_run_data(
                _read_runs_csv(args.from_data),
                earlier_meta,
                data,
                meta,
                source=str(args.from_data),
            )
    if selecting:
        data, meta = keep_runs(
            data, meta, settings=args.settings, tasks=args.tasks, backends=args.backends
        )
        from_dir = args.from_data and args.from_data.resolve().parent
        if from_dir == args.out.resolve():
            option = next(o for o, values in selected.items() if values is not None)
            raise ValueError(
                f"{option} would drop runs from {args.from_data}: write "
                "the selection to another --out."
            )
    args.out.mkdir(parents=True, exist_ok=True)
    runs_csv = args.out / RUNS_FILE
    write_runs_file(data, runs_csv)
    stale = args.out / "runs.csv"
    if args.from_data is not None and stale.resolve() == args.from_data.resolve():
        stale.unlink()  # earlier data, now in the compressed file just written
    meta.to_csv(args.out / "runs_meta.csv", index=False)
    return runs_csv


def _report(data, meta, oracle, written) -> None:
    """What an aggregation prints: seeds per setting, what it could not
    normalise, the runs unfinished or not logging yet, the files written."""
    counts = data.groupby([*TASK_KEYS, "setting"])["seed"].nunique()
    for (task, backend, setting), seeds in counts.items():
        print(f"{task_name(task, backend)}  {setting}: {seeds} seeds")
    raw = [task_name(*task) for task in _tasks(data) if task not in oracle]
    if raw:
        print("Not normalised (no oracle return): " + ", ".join(raw))
    if meta is not None:
        for _, run in unfinished_runs(meta).iterrows():
            task = task_name(run["task"], run["backend"])
            print(
                f"Unfinished: {task} {run['setting']} seed {run['seed']} "
                f"({int(run['last_frame'])} of {int(run['total_frames'])} frames)"
            )
        for _, run in meta[meta["last_frame"].isna()].iterrows():
            print(f"No scalars logged yet, left out: {run['run_dir']}")
    print("Wrote " + ", ".join(str(p) for p in written))


def _regenerate_all(parser: argparse.ArgumentParser, args) -> int:
    """``--all``: every study under the directory, recomputed in place."""
    found = sorted(
        path
        for path in map(runs_file, {p.parent for p in args.all.glob("**/runs.csv*")})
        if path is not None
    )
    if not found:
        parser.error(f"no {RUNS_FILE} (or runs.csv) under {args.all}")
    for runs_csv in found:
        argv = ["--from-data", str(runs_csv), "--out", str(runs_csv.parent)]
        summary = runs_csv.with_name("summary.csv")
        if summary.is_file():
            # one budget for every task: the one the experiment was aggregated at
            table = pd.read_csv(summary)
            if "budget" not in table.columns:
                parser.error(f"{summary} has no budget column")
            budgets = table["budget"].dropna().unique()
            if len(budgets) == 1:
                argv += ["--budget", str(int(budgets[0]))]
        if args.oracle is not None:
            argv += ["--oracle", *map(str, args.oracle)]
        argv += ["--reps", str(args.reps), "--seed", str(args.seed)]
        # the figures asked for, else those the directory holds (a figure no
        # page shows is not redrawn)
        held = [n for n in FIGURES if (runs_csv.parent / n).is_file()]
        argv += ["--figures", *(held if args.figures is None else args.figures)]
        print(f"== {runs_csv.parent}", flush=True)
        main(argv)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
