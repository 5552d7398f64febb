"""A run directory: its owner (the lock), and the checks before a run starts or
resumes in it (seeds, a changed experiment, missing logs, a damaged checkpoint)."""

from __future__ import annotations

import os
import random
import shutil
import socket
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch

from .bonuses import BONUSES, bonus_sections
from .checkpoint import (
    CHECKPOINT_NAME,
    KEPT_CHECKPOINTS,
    DamagedCheckpoint,
    checkpoint_info,
    find_checkpoint,
    is_legacy,
    verify_archive,
)
from .errors import MissingRunFile, ResumeRefused, RunAlreadyThere, UserMistake
from .files import remove_path, write_atomically
from .scalar_logs import scalar_log_files, truncate_scalar_logs
from .status import STATUS_NAME, read_run_status
from .stopping import in_sweep


def seed_everything(seed: int) -> None:
    """Seeds Python, NumPy and torch (all the generators a recipe draws from).

    Examples:
        >>> seed_everything(0); a = torch.rand(1)
        >>> seed_everything(0); bool((a == torch.rand(1)).all())
        True
    """
    random.seed(seed)
    np.random.seed(seed)
    torch.manual_seed(seed)


def _remove_leftover_temporaries(run_dir: Path) -> None:
    # What a run killed while writing left: its checkpoint's, status's and
    # truncated logs' temporary files (the run owns its directory: RunLock).
    patterns = (
        ".checkpoint.*",
        "..checkpoint.*",
        f".{STATUS_NAME}.*",
        ".config_resolved.yaml.*",
        f"{HYDRA_RECORD}/.*.tmp",
    )
    for pattern in patterns:
        for path in run_dir.glob(pattern):
            remove_path(path)
    for path in (run_dir / KEPT_CHECKPOINTS).glob(".checkpoint-*"):
        remove_path(path)
    for path in (run_dir / "logs").glob("**/scalars/**/.*.csv.*"):
        remove_path(path)


def _missing_scalar_logs(
    run_dir: Path, info: Mapping[str, Any], backend: str
) -> list[str]:
    # The CSV logs a run resumed at info["frames"] with the CSV logger should
    # find, each with rows: those its status.json lists, or for a run without
    # one, any; none at all when it logged elsewhere until its checkpoint.
    if info["frames"] <= 0 or backend != "csv":
        return []
    saved = (info["config"].get("logger") or {}).get("backend")
    if saved != "csv":
        return [f"every CSV log (the run logged with logger.backend={saved!r})"]
    present = set(scalar_log_files(run_dir))
    try:
        status = read_run_status(run_dir)
    except ValueError:
        status = None
    if status is not None and isinstance(status.get("logs"), list):
        listed = sorted(status["logs"])
        return [
            name if name not in present else f"{name} (emptied)"
            for name in listed
            if name not in present or not (run_dir / name).read_bytes().strip()
        ]
    return [] if present else ["logs/*/scalars/*.csv (none left)"]


RESUMABLE_CHANGES: tuple[str, ...] = (
    "resume",
    "experiment_name",
    "torch_threads",
    "collector.total_frames",
    "eval",
    "logger",
    "checkpoint",
    "resume_without_logs",
)
"""Config entries (and sections) that may change when a run resumes.

They decide how long a run goes on, what it reports and where it is found
(``experiment_name``: a sweep's runs moved into the folder of an experiment
config renamed since resume there), not what it learns; any other difference
between the checkpoint's config and the resumed one is refused. Nor do they name
a sweep job's directory (each recipe's ``config.yaml`` lists them key by key in
``hydra.job.config.override_dirname.exclude_keys``), so a sweep rerun with them
changed finds its runs.
"""


RESUME_MODES: tuple[str, ...] = ("auto", "true", "false")
"""``resume``: ``auto`` continues from a checkpoint if there is one, else starts;
``true`` requires a checkpoint; ``false`` requires a run directory without one."""


def _resume_mode(value) -> str:
    mode = str(value).lower()
    if mode not in RESUME_MODES:
        raise ValueError(f"resume must be one of {RESUME_MODES}, got {value!r}.")
    return mode


def _flatten(config: Mapping[str, Any], prefix: str = "") -> dict[str, Any]:
    flat: dict[str, Any] = {}
    for key, value in config.items():
        name = f"{prefix}{key}"
        if isinstance(value, Mapping):
            flat.update(_flatten(value, name + "."))
        else:
            flat[name] = value
    return flat


def unused_bonus_sections(config: Mapping[str, Any]) -> tuple[str, ...]:
    """The config sections a run with this config does not read: the whole
    ``intrinsic`` section when ``bonus`` is ``"none"``, else the ``intrinsic.<name>``
    sections of the other bonuses (:func:`common.bonuses.bonus_sections`). A
    changed default there cannot change the run, so resuming it is safe.

    Examples:
        >>> unused_bonus_sections({"bonus": "icm", "intrinsic": {"vae": {}, "icm": {}}})
        ('intrinsic.vae',)
        >>> unused_bonus_sections({"bonus": "none", "intrinsic": {"coef": 0.5}})
        ('intrinsic',)
    """
    bonus = config.get("bonus")
    intrinsic = config.get("intrinsic")
    if bonus is None or not isinstance(intrinsic, Mapping):
        return ()
    if bonus == "none":
        return ("intrinsic",)
    own = BONUSES[bonus].section if bonus in BONUSES else bonus
    return tuple(
        f"intrinsic.{name}"
        for name, value in intrinsic.items()
        if name in bonus_sections() and name != own and isinstance(value, Mapping)
    )


FORMER_BEHAVIOUR: dict[str, Any] = {
    # E3B's first state of an episode joins its memory by default since 0.2.0
    "intrinsic.e3b.start_in_memory": False,
}
"""Settings added with a default that changes what a run computes, each with the
value that keeps the behaviour of a checkpoint written before it existed."""


def config_differences(
    saved: Mapping[str, Any],
    current: Mapping[str, Any],
    allowed: Sequence[str] = RESUMABLE_CHANGES,
) -> list[str]:
    """The settings that differ between two configs, outside ``allowed``.

    A setting absent from ``saved`` is one that a newer version of the recipe
    added after the checkpoint was written; its default is meant to keep the old
    behaviour, so it is not counted (a setting that was removed is), unless its
    default does not (:data:`FORMER_BEHAVIOUR`): then it is compared with the
    value that gives the old behaviour.

    Args:
        saved: the config a checkpoint was written under (nested mapping).
        current: the config of the run that would resume it.
        allowed: entries or whole sections (``"logger"``) that may differ.

    Returns:
        ``"name: saved -> current"`` for each differing setting, sorted.

    Examples:
        >>> config_differences({"env": {"name": "A"}, "logger": {"backend": "csv"}},
        ...                    {"env": {"name": "B"}, "logger": {"backend": ""}})
        ["env.name: 'A' -> 'B'"]
        >>> config_differences({"a": 1}, {"a": 1, "new": 2})
        []
    """
    old, new = _flatten(saved), _flatten(current)
    for name, former in FORMER_BEHAVIOUR.items():
        section = name.rsplit(".", 1)[0] + "."
        if name not in old and any(key.startswith(section) for key in old):
            old[name] = former
    diffs = []
    for name in sorted(old):
        if any(name == a or name.startswith(a + ".") for a in allowed):
            continue
        before, after = old[name], new.get(name, "<absent>")
        if before != after:
            diffs.append(f"{name}: {before!r} -> {after!r}")
    return diffs


def prepare_run(cfg, run_dir: str | os.PathLike) -> tuple[Path, dict[str, Any] | None]:
    """What every recipe does first: threads, seeds, resume checks, resolved config.

    Sets ``torch.set_num_threads(cfg.torch_threads)`` and seeds with ``cfg.seed``.
    With ``cfg.resume`` ``auto`` (or ``true``) and a checkpoint in ``run_dir``
    (:func:`find_checkpoint`), reads its manifest, refuses it if the experiment
    changed (:func:`config_differences`, naming each setting; the sections of
    bonuses the run does not use, from :func:`unused_bonus_sections`, may change),
    and cuts the CSV logs at the checkpoint's frame so each step stays logged
    once; without a checkpoint the run starts at frame 0, and the rows a run
    killed before its first checkpoint left in ``<run_dir>/logs`` go.
    ``resume=false`` refuses a directory that already holds a checkpoint, so that
    nothing computed is overwritten. The run's record (``config_resolved.yaml``,
    Hydra's ``.hydra/``) is written when the run starts (:func:`write_run_record`),
    not here: a run with nothing to do keeps the record it ran with.

    A resume also refuses a damaged checkpoint (:class:`DamagedCheckpoint`,
    naming the earlier one ``checkpoint.keep`` kept), a damaged scalar log
    (:class:`DamagedLog`, naming the line), and a run whose scalar logs are gone
    (those its ``status.json`` lists, or all of them): it would go on with a
    learning curve missing everything before the checkpoint. Set
    ``resume_without_logs=true`` to go on all the same. The temporary files of a
    write that a kill interrupted are removed.

    Returns:
        ``(checkpoint to resume from, its checkpoint_info)``, or
        ``(<run_dir>/checkpoint.torchrl, None)`` for a new run.
    """
    from omegaconf import OmegaConf

    run_dir = Path(run_dir)
    mode = _resume_mode(cfg.resume)
    torch.set_num_threads(cfg.torch_threads)
    seed_everything(cfg.seed)
    config = OmegaConf.to_container(cfg, resolve=True)
    info = None
    if run_dir.is_dir():
        _remove_leftover_temporaries(run_dir)
    try:
        ckpt_path = find_checkpoint(run_dir) if run_dir.is_dir() else None
    except FileNotFoundError:
        ckpt_path = None
    if ckpt_path is not None:
        if mode == "false":
            raise RunAlreadyThere(
                f"{run_dir} already holds a checkpoint: pass resume=auto to continue "
                "it, or another hydra.run.dir to start a new run."
            )
        try:
            info = checkpoint_info(ckpt_path)
            if not is_legacy(ckpt_path):
                verify_archive(ckpt_path)
        except DamagedCheckpoint as err:
            raise err.for_resume(run_dir) from err.error
        diffs = config_differences(
            info["config"],
            config,
            allowed=RESUMABLE_CHANGES + unused_bonus_sections(info["config"]),
        )
        if diffs:
            raise ResumeRefused(
                f"Cannot resume {run_dir}: the experiment changed ("
                + "; ".join(diffs)
                + "). Only these settings may change on resume: "
                + ", ".join(RESUMABLE_CHANGES)
                + ". Start a new run directory for a new experiment."
            )
        backend = (cfg.get("logger") or {}).get("backend")
        missing = _missing_scalar_logs(run_dir, info, backend)
        if missing and not cfg.get("resume_without_logs", False):
            raise MissingRunFile(
                f"Cannot resume {run_dir}: its checkpoint is at {info['frames']} "
                "frames but scalar logs it wrote before are missing: "
                + ", ".join(missing)
                + ". Resumed, its learning curve and aggregated results would "
                "lack everything before that frame. Put the logs back; or start "
                f"afresh (move {run_dir} away, or another hydra.run.dir, with "
                "resume=false); or pass resume_without_logs=true to go on "
                "without the early curve."
            )
        truncate_scalar_logs(run_dir / "logs", info["frames"])
    elif mode == "true":
        raise MissingRunFile(
            f"resume=true but there is no checkpoint in {run_dir}; pass the run "
            "directory of the run to resume as hydra.run.dir=<dir>."
        )
    else:
        # A run killed before its first checkpoint left rows that this run, which
        # starts from frame 0 with the same seed, logs again: drop them.
        truncate_scalar_logs(run_dir / "logs", -1)
        ckpt_path = run_dir / CHECKPOINT_NAME
    run_dir.mkdir(parents=True, exist_ok=True)
    return ckpt_path, info


LOCK_NAME = "run.lock"
"""The lock file of a run directory: ``<pid> <host>`` of the process that owns it."""


class RunDirInUse(UserMistake, RuntimeError):
    """Another live process owns the run directory (:class:`RunLock`)."""


class RunLock:
    """Makes one process at a time the owner of a run directory.

    An exclusive ``fcntl.flock`` on the run directory itself, and a ``lockf`` on
    ``<run_dir>/run.lock`` (NFS has no ``flock`` on directories across machines;
    its file locks go through the server), which holds the owner's pid and host
    to name it in the message that refuses another process. The kernel releases the lock when its process ends, however
    it ends (a SIGKILL, a node's crash), so a dead run never leaves the directory
    stuck, and deleting ``run.lock`` (the usual reflex for a "stale lock")
    releases nothing. Written here rather than with ``filelock``, which locks a
    file: delete that file and a second process takes a lock of its own.

    Args:
        run_dir: the run directory (created if absent).

    Raises:
        RunDirInUse: another process holds the lock; the message names the
            directory and that process.

    Examples:
        >>> import tempfile
        >>> run_dir = tempfile.mkdtemp()
        >>> lock = RunLock(run_dir)
        >>> lock.holder() == f"process {os.getpid()} on {socket.gethostname()}"
        True
        >>> os.remove(os.path.join(run_dir, LOCK_NAME))  # still held
        >>> RunLock(run_dir)  # doctest: +ELLIPSIS
        Traceback (most recent call last):
        ...
        common.rundir.RunDirInUse: ... is in use by another process: ...
        >>> lock.release()
    """

    def __init__(self, run_dir: str | os.PathLike):
        import fcntl

        self.path = Path(run_dir) / LOCK_NAME
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._fd = self._file = None
        self._fd = os.open(self.path.parent, os.O_RDONLY)
        try:
            fcntl.flock(self._fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            self._file = os.open(self.path, os.O_RDWR | os.O_CREAT, 0o644)
            fcntl.lockf(self._file, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:  # held (BlockingIOError, EACCES), or no lock here (ENOLCK)
            holder = self.holder()
            self.release()
            raise RunDirInUse(
                f"{self.path.parent} is in use by {holder}: one process at a time "
                "runs in a run directory. Wait for that run to end (or stop it), or "
                "pass another hydra.run.dir."
            ) from None
        # in place: the lock is on this file
        os.ftruncate(self._file, 0)
        os.pwrite(self._file, f"{os.getpid()} {socket.gethostname()}\n".encode(), 0)

    def holder(self) -> str:
        """``"process <pid> on <host>"``, as the lock file says."""
        try:
            pid, host = self.path.read_text().split()[:2]
        except (OSError, ValueError):
            return "another process"
        return f"process {pid} on {host}"

    def release(self) -> None:
        """Releases the lock (the process's end does it as well)."""
        for name in ("_file", "_fd"):
            fd = getattr(self, name, None)
            if fd is not None:
                os.close(fd)
                setattr(self, name, None)

    __del__ = release


class RunDirClaim:
    """A launch's hold on its run directory, from its checks to the run's end.

    Takes the directory's :class:`RunLock`, then :func:`prepare_run` (threads,
    seeds, resume checks, the checkpoint to resume from). In a sweep, a job whose
    directory another process holds is skipped (:attr:`skipped`): a rerun sweep
    leaves it to the sweep running it. A refused launch gives the directory up
    as it found it (:meth:`abandon`).

    Args:
        cfg: the run's config (``seed``, ``resume``, ``torch_threads``, ...).
        run_dir: the run directory.

    Raises:
        RunDirInUse: another process holds the directory, outside a sweep.

    Examples:
        >>> import tempfile
        >>> from omegaconf import OmegaConf
        >>> cfg = OmegaConf.create({"seed": 0, "resume": "auto", "torch_threads": 1})
        >>> claim = RunDirClaim(cfg, tempfile.mkdtemp())
        >>> claim.source is None, claim.done_frames
        (True, 0)
        >>> claim.finished(256, [])
        False
        >>> claim.abandon(); claim.path.exists()  # made for this launch: removed
        False
    """

    def __init__(self, cfg, run_dir: str | os.PathLike):
        self.path = Path(run_dir)
        self.skipped = ""
        self.source = self.resumed_from = None
        self._lock: RunLock | None = None
        self._fresh = False
        try:
            self._lock = RunLock(self.path)
        except RunDirInUse as err:
            if not in_sweep():
                raise
            self.skipped = f"Skipped: {err}"
            return
        # made for this launch (Hydra makes it empty; the lock file is ours)
        self._fresh = {p.name for p in self.path.iterdir()} <= {LOCK_NAME}
        try:
            source, self.resumed_from = prepare_run(cfg, self.path)
        except BaseException:
            self.abandon()  # refused: the directory is as it was, and free
            raise
        self.source = source if self.resumed_from else None

    @property
    def done_frames(self) -> int:
        """The frames the checkpoint to resume from holds (0 for a new run)."""
        return 0 if self.resumed_from is None else int(self.resumed_from["frames"])

    def finished(
        self,
        total_frames: int,
        outputs: Sequence[Path],
        curve: str | os.PathLike | None = None,
    ) -> bool:
        """Whether there is nothing left to do, saying so: another sweep runs the
        job (:attr:`skipped`), or the checkpoint holds ``total_frames`` and
        each of ``outputs`` (what the run's end writes) exists, and ``curve``
        too when the run logged scalars. A finished run missing one of them has
        its end to write: ``False``, naming them."""
        if self.skipped:
            print(self.skipped)
            return True
        frames = self.done_frames
        if frames < total_frames:
            return False
        missing = [Path(p) for p in outputs if not Path(p).exists()]
        if curve is not None and not Path(curve).exists():
            if scalar_log_files(self.path):  # a run without scalars draws none
                missing.insert(0, Path(curve))
        if missing:
            print(
                f"Finished at {frames} frames; writing what its end left missing: "
                + ", ".join(str(p) for p in missing)
            )
            return False
        self.release()
        print(f"Nothing to do: {frames} frames already done in {self.path}.")
        return True

    def abandon(self) -> None:
        """Gives the directory up before the run started, for a launch refused on
        a mistake: a directory this launch made (absent or empty before it) is
        removed with what was written in it, and the lock is released."""
        if self._fresh and self.path.is_dir():
            # removed while the lock is held: no other launch has the directory
            shutil.rmtree(self.path, ignore_errors=True)
        self.release()

    def release(self) -> None:
        """Releases the directory's lock (the process's end does it as well)."""
        if self._lock is not None:
            self._lock.release()


HYDRA_RECORD = ".hydra"
"""Hydra's record of a run in its directory (``config.yaml``, ``hydra.yaml``,
``overrides.yaml``, what Hydra writes with ``hydra.output_subdir=.hydra``)."""


def write_run_record(run_dir: str | os.PathLike, cfg) -> None:
    """Writes the run's record as it starts: ``config_resolved.yaml`` (the
    resolved config) and Hydra's ``.hydra/`` (:func:`write_hydra_record`)."""
    from omegaconf import OmegaConf

    config = OmegaConf.to_container(cfg, resolve=True)
    path = Path(run_dir) / "config_resolved.yaml"
    write_atomically(path, OmegaConf.to_yaml(config))
    write_hydra_record(run_dir, cfg)


def write_hydra_record(run_dir: str | os.PathLike, cfg) -> Path | None:
    """Writes Hydra's record of the current Hydra run into ``<run_dir>/.hydra``.

    The recipes set ``hydra.output_subdir: null``: Hydra would write it when a
    launch starts, before the run directory's lock is taken, so a launch refused
    there (the directory in use, a changed experiment) would rewrite the running
    run's record. The run writes it once it holds the lock and its checks passed
    (:meth:`common.run.TrainingRun.restore`). Nothing outside a Hydra app.

    Returns:
        The folder written, or ``None`` outside a Hydra app.
    """
    from omegaconf import OmegaConf

    try:
        from hydra.core.hydra_config import HydraConfig

        hydra_cfg = HydraConfig.get()
    except (ImportError, ValueError):
        return None
    folder = Path(run_dir) / HYDRA_RECORD
    folder.mkdir(parents=True, exist_ok=True)
    records = {
        "config.yaml": OmegaConf.to_yaml(cfg),
        "hydra.yaml": OmegaConf.to_yaml(OmegaConf.create({"hydra": hydra_cfg})),
        "overrides.yaml": OmegaConf.to_yaml(list(hydra_cfg.overrides.task)),
    }
    for name, text in records.items():
        write_atomically(folder / name, text)
    return folder
