"""Run support shared by the recipes: seeding, checkpoints, episode stats, curves.

A recipe's ``main.py`` holds its algorithm; what every run does around it is
:class:`TrainingRun`: prepare the run directory (resume checks, seeds), restore a
checkpoint, log, show progress, save periodically and on a stop signal, and end
with a final checkpoint, a learning curve and a summary.

Checkpoints are TorchRL's (:mod:`torchrl.checkpoint`): a ``Checkpoint`` archive of
the run's components with the global generators (``GlobalRNGState``, CUDA's
included) and the frames and config in its manifest, kept copies through
``CheckpointRotation``. Two things stay here, because the library does not do them:

- the atomic write. ``Checkpoint.save`` over an existing file moves the old one
  aside, then the new one in: a kill between the two leaves no checkpoint. The run
  saves to a temporary file of its own and renames it over the previous one.
- the random generators restored last. ``Checkpoint.load`` restores components
  in name order; building a run draws random numbers, so they are loaded apart.

Measured on the recipes' states: a checkpoint costs 0.05-0.1 s against 0.01-0.02 s
for ``torch.save`` (small states; the default TensorDict payload, 0.35 s, is not
used), and 0.85 s against 0.31 s with a full 1M-transition replay buffer: a
fraction of a percent of a run between two checkpoints.
"""

from __future__ import annotations

import copyreg
import errno
import functools
import importlib
import json
import logging
import multiprocessing
import os
import random
import shutil
import signal
import socket
import sys
import time
import types
import uuid
import warnings
import zipfile
from collections import deque
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any, NamedTuple, NoReturn

import numpy as np
import torch
from tensordict import TensorDictBase
from torchrl.checkpoint import (
    Checkpoint,
    CheckpointRotation,
    GlobalRNGState,
    StateDictCheckpointAdapter,
)
from torchrl.record.loggers.mlflow import MLFlowLogger

from torchrl_surprise import collectors as _collectors

from .labels import run_labels

__all__ = [
    "BONUS_SECTIONS",
    "RESUMABLE_CHANGES",
    "DamagedCheckpoint",
    "DamagedLog",
    "RunWriteError",
    "STATUS_NAME",
    "RESUME_MODES",
    "CHECKPOINT_NAME",
    "KEPT_CHECKPOINTS",
    "LEGACY_CHECKPOINT_NAME",
    "LOCK_NAME",
    "RunDirInUse",
    "RunLock",
    "RunCheckpoint",
    "kept_checkpoints_warning",
    "EVAL_SEED_OFFSET",
    "EpisodeStats",
    "Evaluation",
    "RunCounters",
    "STOP_SIGNALS",
    "StopSignal",
    "TrainingRun",
    "config_differences",
    "unused_bonus_sections",
    "find_scalar_log",
    "plot_run_curves",
    "resume_command",
    "truncate_scalar_logs",
    "evaluate",
    "get_run_logger",
    "RESUMED_LOGGERS",
    "RunMLFlowLogger",
    "checkpoint_info",
    "find_checkpoint",
    "load_checkpoint",
    "read_run_status",
    "write_run_status",
    "prepare_run",
    "register_sweep_pickling",
    "plot_learning_curves",
    "read_scalar_csv",
    "seed_everything",
]


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


CHECKPOINT_NAME = "checkpoint.torchrl"
"""A run's latest checkpoint, ``<run dir>/checkpoint.torchrl``: a TorchRL checkpoint
archive (:class:`torchrl.checkpoint.Checkpoint`, ``format="archive"``)."""

LEGACY_CHECKPOINT_NAME = "checkpoint.pt"
"""The checkpoint of the recipes' 0.2 release, a ``torch.save`` of a dict; it is
still resumed and read, and removed once the run has saved its successor."""

KEPT_CHECKPOINTS = "checkpoints"
"""With ``checkpoint.keep``, every periodic checkpoint is kept in this folder of the
run directory (:class:`torchrl.checkpoint.CheckpointRotation`'s names,
``checkpoint-<frames, 12 digits>.torchrl``)."""


# The names of checkpoint files: the run's and the kept ones, and a 0.2 run's.
_CHECKPOINT_SUFFIXES = (".torchrl", ".pt")


def find_checkpoint(run_dir_or_file: str | os.PathLike) -> Path:
    """The checkpoint file of a run directory (its ``checkpoint.torchrl``, or a 0.2
    run's ``checkpoint.pt``), or the file itself.

    Raises:
        FileNotFoundError: a directory without either, or no such file.
        ValueError: a file that is neither a TorchRL checkpoint archive nor named
            as a checkpoint (``*.torchrl``, ``*.pt``): a sweep's
            ``multirun.yaml`` matched by ``<sweep>/*``, say.
    """
    path = Path(run_dir_or_file)
    if not path.is_dir():
        if not path.exists():
            raise FileNotFoundError(f"no checkpoint at {path}")
        if path.suffix not in _CHECKPOINT_SUFFIXES and not Checkpoint.is_checkpoint(
            path
        ):
            raise ValueError(
                f"{path} is not a checkpoint: expected a run directory or a "
                "checkpoint file (*.torchrl, or a 0.2 run's checkpoint.pt). A "
                "sweep folder's <sweep>/* also matches its multirun.yaml: name "
                "its runs with <sweep>/+setting=* (or the runs' own folders)."
            )
        return path
    for name in (CHECKPOINT_NAME, LEGACY_CHECKPOINT_NAME):
        if (path / name).exists():
            return path / name
    raise FileNotFoundError(
        f"no checkpoint in {path} (looked for {CHECKPOINT_NAME} and "
        f"{LEGACY_CHECKPOINT_NAME})"
    )


def _is_legacy(path: Path) -> bool:
    return not (path.is_dir() or Checkpoint.is_checkpoint(path))


def _load_legacy(path: Path) -> dict[str, Any]:
    # Pickled RNG states (tuples, NumPy arrays): not weights-only.
    try:
        state = torch.load(path, weights_only=False)
    except (FileNotFoundError, PermissionError):
        raise
    except Exception as err:  # EOFError, UnpicklingError, RuntimeError, EINVAL
        raise DamagedCheckpoint(path, err) from err
    rng = state.get("rng")
    if isinstance(rng, Mapping) and "torch" in rng:  # GlobalRNGState's names
        state["rng"] = {
            "python": rng["python"],
            "numpy": rng["numpy"],
            "torch_cpu": rng["torch"],
        }
    return state


class DamagedCheckpoint(ValueError):
    """A checkpoint file that cannot be read: empty, cut short, or overwritten.

    The message names the file, what is wrong with it, and what to do: use the
    newest earlier checkpoint that ``checkpoint.keep`` kept under
    ``<run dir>/checkpoints/`` (named, with its frames), or, on a resume
    (:meth:`for_resume`), start afresh in a new run directory.

    Attributes:
        path (Path): the damaged file.
        run_dir (Path | None): the run being resumed from it: the message then
            says how to go on with that run.
        earlier (Path | None): the newest readable checkpoint kept beside it.
        earlier_frames (int | None): the frames ``earlier`` holds.

    Examples:
        >>> import tempfile, os
        >>> path = os.path.join(tempfile.mkdtemp(), CHECKPOINT_NAME)
        >>> _ = open(path, "wb").close()
        >>> checkpoint_info(path)  # doctest: +ELLIPSIS
        Traceback (most recent call last):
        ...
        common.run.DamagedCheckpoint: .../checkpoint.torchrl is damaged: it is empty (0 bytes)...
    """

    def __init__(
        self,
        path: str | os.PathLike,
        error: BaseException,
        run_dir: str | os.PathLike | None = None,
    ):
        self.path = Path(path)
        self.error = error
        self.run_dir = None if run_dir is None else Path(run_dir)
        self.earlier, self.earlier_frames = _earlier_checkpoint(self.path)
        if self.run_dir is None:
            super().__init__(self._describe() + " " + self._use_earlier())
        else:
            super().__init__(
                f"Cannot resume {self.run_dir}: {self._describe()} "
                + " ".join(self._resume_advice())
            )

    def _describe(self) -> str:
        try:
            size = self.path.stat().st_size
            with open(self.path, "rb") as f:
                head = f.read(4)
        except OSError:
            size, head = None, b""
        if size == 0:
            what = "it is empty (0 bytes)"
        elif head == b"PK\x03\x04":
            what = f"it is cut short or overwritten in part ({size} bytes)"
        else:
            what = (
                "its bytes are neither a TorchRL checkpoint archive nor a "
                f"torch.save file ({size} bytes)"
            )
        cause = str(self.error).split(". ")[0].rstrip(".")  # torch's first sentence
        return (
            f"{self.path} is damaged: {what}; reading it failed with "
            f"{type(self.error).__name__}: {cause}. A full disk, a crash or "
            "an interrupted copy leaves such a file."
        )

    def _use_earlier(self) -> str:
        if self.earlier is None:
            return (
                "No earlier checkpoint is kept beside it (checkpoint.keep=true keeps "
                f"each one under <run dir>/{KEPT_CHECKPOINTS}/)."
            )
        return (
            f"An earlier checkpoint of the run is kept: {self.earlier} "
            f"({self.earlier_frames} frames); pass that file instead."
        )

    def for_resume(self, run_dir: str | os.PathLike) -> DamagedCheckpoint:
        """The same error, saying how to go on with the run in ``run_dir``."""
        return DamagedCheckpoint(self.path, self.error, run_dir=run_dir)

    def _resume_advice(self) -> list[str]:
        run_dir = self.run_dir
        advice = []
        if self.earlier is not None:
            advice.append(
                f"To resume from the kept {self.earlier} ({self.earlier_frames} "
                f"frames), put it in place of the damaged file: mv {self.path} "
                f"{self.path}.damaged && cp {self.earlier} {run_dir / CHECKPOINT_NAME}"
                "; then run the same command again."
            )
        else:
            advice.append(self._use_earlier())
        advice.append(
            f"To start afresh, move the run directory away (mv {run_dir} "
            f"{run_dir}.damaged) or pass another hydra.run.dir, with resume=false."
        )
        return advice


def _earlier_checkpoint(path: Path) -> tuple[Path | None, int | None]:
    # The kept checkpoints of the run: <run dir>/checkpoints/ beside its latest
    # one, or the folder a kept one is in; the newest readable one, older than a
    # damaged kept one.
    kept = path.parent if path.parent.name == KEPT_CHECKPOINTS else None
    kept = kept or path.parent / KEPT_CHECKPOINTS
    if not kept.is_dir():
        return None, None
    for candidate in sorted(kept.glob("checkpoint-*.torchrl"), reverse=True):
        if candidate == path or (kept == path.parent and candidate.name > path.name):
            continue
        try:
            frames = Checkpoint.manifest(candidate)["metadata"].get("frames", 0)
            _verify_archive(candidate)
        except Exception:  # damaged as well: an older one
            continue
        return candidate, int(frames)
    return None, None


def _verify_archive(path: Path) -> None:
    # Every member's CRC: a checkpoint overwritten in part reads its manifest
    # but fails on the payload, after part of the run was restored.
    if path.is_dir():
        return
    try:
        with zipfile.ZipFile(path) as archive:
            bad = archive.testzip()
    except (zipfile.BadZipFile, EOFError, ValueError) as err:
        raise DamagedCheckpoint(path, err) from err
    if bad is not None:
        raise DamagedCheckpoint(path, zipfile.BadZipFile(f"bad CRC-32 for {bad}"))


_WRITE_ERRORS = {
    errno.ENOSPC: "no space left on device",
    errno.EDQUOT: "disk quota exceeded",
    errno.EACCES: "permission denied",
    errno.EPERM: "operation not permitted",
    errno.EROFS: "read-only file system",
    errno.EFBIG: "file too large",
}

#: Below this much free space, a write that torch reports without an errno
#: (``unexpected pos``, ``file write failed``) is put down to a full disk.
_NEARLY_FULL = 64 * 2**20


class RunWriteError(OSError):
    """A file of a run could not be written: the message names the file, the
    cause (``no space left on device``, ``permission denied``) and what is left as
    it was. ``errno`` is the cause's (``None`` when unknown).

    Examples:
        >>> err = _write_failure(OSError(errno.ENOSPC, "No space"), Path("/r/x"))
        >>> str(err).startswith("could not write /r/x: no space left on device")
        True
    """

    def __init__(self, code: int | None, message: str, filename: str):
        super().__init__(code, message, filename)
        self.message = message

    def __str__(self) -> str:
        return self.message


def _errno_of(error: BaseException) -> int | None:
    seen = set()
    while error is not None and id(error) not in seen:
        seen.add(id(error))
        if isinstance(error, OSError) and error.errno is not None:
            return error.errno
        error = error.__cause__ or error.__context__
    return None


def _is_write_error(error: BaseException) -> bool:
    # torch.save reports a failed write as a RuntimeError of its zip writer
    # ("[enforce fail at inline_container.cc:672] . unexpected pos").
    if _errno_of(error) is not None:
        return True
    text = str(error)
    return isinstance(error, RuntimeError) and (
        "inline_container" in text or "PytorchStreamWriter" in text
    )


def _free_bytes(path: Path) -> int | None:
    for folder in (path.parent, *path.parents):
        if folder.is_dir():
            try:
                return shutil.disk_usage(folder).free
            except OSError:
                return None
    return None


def _write_failure(
    error: BaseException, path: Path, *, needed: int = 0, kept: str = ""
) -> RunWriteError:
    """The error to raise for a failed write of ``path``: its cause in words."""
    code = _errno_of(error)
    free = _free_bytes(path)
    if code is None and free is not None and free < max(needed, _NEARLY_FULL):
        code = errno.ENOSPC  # torch's writer gives no errno
    if code is None:
        reason = f"the write failed ({type(error).__name__}: {error})"
    else:
        reason = _WRITE_ERRORS.get(code) or os.strerror(code).lower()
    message = f"could not write {path}: {reason}"
    if code in (errno.ENOSPC, errno.EDQUOT) and free is not None:
        message += f" ({free / 2**20:.1f} MiB free there)"
    message += ". No partial file is left behind."
    if kept:
        message += " " + kept
    if code in (errno.ENOSPC, errno.EDQUOT):
        message += " Free some space (or move the run directory), then resume."
    elif code in (errno.EACCES, errno.EPERM, errno.EROFS):
        message += " Make the run directory writable, then resume."
    return RunWriteError(code, message, str(path))


def _remove(path: Path) -> None:
    try:
        if path.is_dir():
            shutil.rmtree(path, ignore_errors=True)
        else:
            path.unlink(missing_ok=True)
    except OSError:
        pass


def _temporary(path: Path) -> Path:
    return path.with_name(f".{path.name}.{os.getpid()}-{uuid.uuid4().hex[:8]}.tmp")


def _write_atomically(path: Path, data: str | bytes, *, kept: str = "") -> None:
    """Writes ``data`` to a temporary file beside ``path``, then renames it over
    ``path``: a failed write leaves ``path`` as it was and no temporary file, and
    raises :class:`RunWriteError`."""
    tmp = _temporary(path)
    try:
        with open(tmp, "wb" if isinstance(data, bytes) else "w") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except OSError as err:
        raise _write_failure(err, path, kept=kept) from err
    finally:
        _remove(tmp)


def _remove_leftover_temporaries(run_dir: Path) -> None:
    # What a run killed while writing left: its checkpoint's, status's and
    # truncated logs' temporary files (the run owns its directory: RunLock).
    patterns = (
        ".checkpoint.*",
        "..checkpoint.*",
        f".{STATUS_NAME}.*",
        ".config_resolved.yaml.*",
    )
    for pattern in patterns:
        for path in run_dir.glob(pattern):
            _remove(path)
    for path in (run_dir / KEPT_CHECKPOINTS).glob(".checkpoint-*"):
        _remove(path)
    for path in (run_dir / "logs").glob("**/scalars/**/.*.csv.*"):
        _remove(path)


class DamagedLog(ValueError):
    """A scalar log with a line that is not a ``step,value`` row; the message
    names the file and the line.

    Examples:
        >>> import tempfile, os
        >>> path = os.path.join(tempfile.mkdtemp(), "x.csv")
        >>> _ = open(path, "w").write("64,0.5\\nline\\n128,0.25\\n")
        >>> read_scalar_csv(path)  # doctest: +ELLIPSIS
        Traceback (most recent call last):
        ...
        common.run.DamagedLog: .../x.csv, line 2: 'line' is not a 'step,value' row...
    """

    def __init__(self, path: str | os.PathLike, line_number: int, line: bytes):
        self.path = Path(path)
        self.line_number = line_number
        text = line.decode("utf-8", "replace").rstrip("\r\n")
        shown = repr(text if len(text) <= 60 else text[:60] + "...")
        super().__init__(
            f"{self.path}, line {line_number}: {shown} is not a 'step,value' row "
            "of TorchRL's CSVLogger: the file is damaged (a full disk, a crash or "
            "an edit). Delete or correct that line, then run again."
        )


def _scalar_row(
    path: str | os.PathLike, number: int, line: bytes, *, last: bool
) -> tuple[int, float] | None:
    # (step, value); None for a blank line, or for a last line cut short by a
    # write that was still going on or was interrupted (no newline yet).
    if not line.strip():
        return None
    fields = line.strip().split(b",")
    try:
        if len(fields) != 2:
            raise ValueError(fields)
        return int(float(fields[0])), float(fields[1])
    except (ValueError, OverflowError):
        if last and not line.endswith(b"\n"):
            return None
        raise DamagedLog(path, number, line) from None


STATUS_NAME = "status.json"
"""A run's own record of how far it got, ``<run dir>/status.json``
(:func:`write_run_status`), rewritten atomically with each checkpoint."""


def _scalar_logs(run_dir: Path) -> list[str]:
    logs = (run_dir / "logs").glob("*/scalars/**/*.csv")
    return sorted(p.relative_to(run_dir).as_posix() for p in logs)


def write_run_status(
    run_dir: str | os.PathLike,
    config: Mapping[str, Any],
    frames: int,
    labels: Mapping[str, Any] | None = None,
) -> Path:
    """Writes ``<run_dir>/status.json`` atomically: how far the run got.

    Keys: ``task`` (``env.name``, ``<env id>@envpool`` on envpool), ``seed``,
    ``setting`` (the labels the aggregation gives the run: ``labels``, else
    :func:`common.labels.run_labels` of ``config`` and the run's overrides), ``frames``
    (done, as in the checkpoint), ``total_frames`` (the budget,
    ``collector.total_frames``), ``finished`` (``frames >= total_frames``),
    ``logs`` (the scalar logs written so far, relative to the run directory:
    a resume refuses to go on without them) and ``updated`` (UTC time).

    Examples:
        >>> import tempfile
        >>> run_dir = tempfile.mkdtemp()
        >>> config = {"env": {"name": "MiniGrid-Empty-5x5-v0"}, "seed": 0,
        ...           "bonus": "vae", "collector": {"total_frames": 1024}}
        >>> _ = write_run_status(run_dir, config, frames=1024)
        >>> status = read_run_status(run_dir)
        >>> status["finished"], status["frames"], status["setting"]
        (True, 1024, 'vae')
    """
    run_dir = Path(run_dir)
    if labels is None:
        labels = run_labels(config, run_dir)
    total = (config.get("collector") or {}).get("total_frames")
    status = {
        "task": labels["task"],
        "seed": labels["seed"],
        "setting": labels["setting"],
        "frames": int(frames),
        "total_frames": None if total is None else int(total),
        "finished": total is not None and int(frames) >= int(total),
        "logs": _scalar_logs(run_dir),
        "updated": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
    }
    path = run_dir / STATUS_NAME
    _write_atomically(
        path,
        json.dumps(status, indent=1) + "\n",
        kept="The previous status.json is left as it was.",
    )
    return path


def read_run_status(run_dir: str | os.PathLike) -> dict[str, Any] | None:
    """The run's ``status.json`` (:func:`write_run_status`), or ``None`` for a run
    directory without one (written before it existed).

    Raises:
        ValueError: the file is not the JSON object it should be (named).
    """
    path = Path(run_dir) / STATUS_NAME
    try:
        status = json.loads(path.read_bytes())
    except FileNotFoundError:
        return None
    except ValueError as err:
        raise ValueError(f"{path} is damaged ({err}); delete it") from None
    if not isinstance(status, dict) or not {"frames", "finished"} <= set(status):
        raise ValueError(f"{path} is damaged (no frames or finished); delete it")
    return status


def _missing_scalar_logs(run_dir: Path, info: Mapping[str, Any]) -> list[str]:
    # The CSV logs a run resumed at info["frames"] should find: those its
    # status.json lists, or for a run without one, any.
    logger = info["config"].get("logger") or {}
    if info["frames"] <= 0 or logger.get("backend") != "csv":
        return []
    present = set(_scalar_logs(run_dir))
    try:
        status = read_run_status(run_dir)
    except ValueError:
        status = None
    if status is not None and isinstance(status.get("logs"), list):
        return sorted(set(status["logs"]) - present)
    return [] if present else ["logs/*/scalars/*.csv (none left)"]


def checkpoint_info(path: str | os.PathLike) -> dict[str, Any]:
    """What a checkpoint says of its run without loading its state: ``frames``
    and the resolved ``config`` (the manifest's metadata).

    Raises:
        DamagedCheckpoint: the file cannot be read (empty, cut short, garbage).

    Examples:
        >>> import tempfile, os
        >>> counters = RunCounters(frames=128)
        >>> path = os.path.join(tempfile.mkdtemp(), CHECKPOINT_NAME)
        >>> RunCheckpoint(path, {"progress": counters}, config={"seed": 0}).save()
        >>> checkpoint_info(path)
        {'config': {'seed': 0}, 'frames': 128}
    """
    path = Path(path)
    if _is_legacy(path):
        state = _load_legacy(path)
        return {"config": state.get("config", {}), "frames": state.get("frames", 0)}
    metadata = Checkpoint.manifest(path)["metadata"]
    return {"config": metadata.get("config", {}), "frames": metadata.get("frames", 0)}


class _SavedState:
    """Receives one component's state dict when a checkpoint is read as a dict."""

    def __init__(self):
        self.state = None

    def state_dict(self):
        return self.state

    def load_state_dict(self, state) -> None:
        self.state = state


def load_checkpoint(path: str | os.PathLike) -> dict[str, Any]:
    """Every state a checkpoint holds, by component name, with its ``frames`` and
    ``config``: for tools that read a run (the heatmap, transfer, tests), not for
    resuming it (:meth:`TrainingRun.restore`). Reads both formats
    (:data:`CHECKPOINT_NAME`, :data:`LEGACY_CHECKPOINT_NAME`); a file that
    cannot be read raises :class:`DamagedCheckpoint`, which names it and the
    earlier checkpoint kept beside it.

    Examples:
        >>> import tempfile, os
        >>> net, counters = torch.nn.Linear(2, 2), RunCounters(frames=128)
        >>> path = os.path.join(tempfile.mkdtemp(), CHECKPOINT_NAME)
        >>> RunCheckpoint(path, {"net": net, "progress": counters}, config={}).save()
        >>> state = load_checkpoint(path)
        >>> state["frames"], sorted(state["net"]), state["progress"]
        (128, ['bias', 'weight'], {'frames': 128})
    """
    path = Path(path)
    if _is_legacy(path):
        return _load_legacy(path)
    _verify_archive(path)
    manifest = Checkpoint.manifest(path)
    holders = {name: _SavedState() for name in manifest["components"]}
    _reader(holders).load(path, tensor_load_kwargs=_UNPICKLE)
    state = {name: holder.state for name, holder in holders.items()}
    state.update(checkpoint_info(path))
    return state


def _reader(components: Mapping[str, Any]) -> Checkpoint:
    # Each state dict is one torch.save payload in the archive: 3 to 7 times
    # cheaper to write than the default TensorDict payload for the recipes' many
    # small states. It is read with pickle (_UNPICKLE): the collectors' states
    # hold TensorDicts and the episode state of envs, which weights-only loading
    # refuses; so a checkpoint is trusted as the 0.2 torch.save one was.
    checkpoint = Checkpoint(format="archive")
    for name, obj in components.items():
        checkpoint.register(
            name, obj, adapter=StateDictCheckpointAdapter(payload_format="torch")
        )
    return checkpoint


_UNPICKLE = {"weights_only": False}


def kept_checkpoints_warning(
    path: str | os.PathLike, to_come: int, interval_frames: int
) -> str | None:
    """What to say when ``to_come`` more checkpoints of the size of the kept one
    at ``path`` would not fit in the space free on its disk; ``None`` when they
    fit (or the free space cannot be read).

    ``checkpoint.keep=true`` keeps every periodic checkpoint, and a checkpoint
    can be large (E3B's keeps one inverse covariance per env: 568 MB at 64
    envs); the run says so at its first kept checkpoint rather than at a full
    disk.

    Examples:
        >>> import tempfile, os
        >>> path = os.path.join(tempfile.mkdtemp(), "checkpoint-000000000128.torchrl")
        >>> with open(path, "wb") as f:
        ...     _ = f.write(b"0" * 1024)
        >>> kept_checkpoints_warning(path, to_come=3, interval_frames=128) is None
        True
    """
    path = Path(path)
    size = path.stat().st_size
    needed = size * max(to_come, 0)
    free = _free_bytes(path)
    if free is None or needed <= free:
        return None
    return (
        f"checkpoint.keep=true keeps a checkpoint of {size / 2**20:.1f} MiB every "
        f"{interval_frames} frames in {path.parent}: the {to_come} still to come "
        f"need about {needed / 2**30:.2f} GiB, and {free / 2**30:.2f} GiB is free "
        "there. The run goes on and, if the disk fills, stops with an error naming "
        "the file (it resumes from its last checkpoint once there is room). Free "
        "some space, or rerun with checkpoint.keep=false or a larger "
        "checkpoint.interval_frames."
    )


class RunCheckpoint:
    """One mapping of what a run saves, used both to save and to load, written as a
    TorchRL checkpoint (:class:`torchrl.checkpoint.Checkpoint`).

    Every value is an object with ``state_dict()`` / ``load_state_dict()``
    (modules, optimisers, transforms, collectors, :class:`RunCounters`); ``None``
    entries are skipped. The process's random generators (Python, NumPy, torch,
    CUDA: :class:`torchrl.checkpoint.GlobalRNGState`) are saved as ``"rng"`` and
    restored after everything else: building the run consumed random numbers.

    Args:
        path: the checkpoint file (``<run dir>/checkpoint.torchrl``).
        components: name -> object; ``"progress"`` is the run's
            :class:`RunCounters` (its ``frames`` go into the manifest).
        config: the resolved run config, saved in the manifest's metadata so
            that a resume can refuse a changed experiment (:func:`prepare_run`).
        keep_dir: where :meth:`save_every` also keeps each periodic checkpoint
            (:class:`torchrl.checkpoint.CheckpointRotation`, all kept); ``None``
            (default) keeps only the latest.
        status (bool | Mapping): also rewrite ``status.json`` beside the
            checkpoint with each save (:func:`write_run_status`; a run's, not a
            tool's); a mapping gives the run's labels (``task``, ``seed``,
            ``setting``: :func:`common.labels.run_labels`), else they are
            computed here, once.

    Examples:
        >>> import tempfile, os
        >>> net = torch.nn.Linear(2, 2); progress = RunCounters(frames=128)
        >>> path = os.path.join(tempfile.mkdtemp(), CHECKPOINT_NAME)
        >>> RunCheckpoint(path, {"net": net, "progress": progress}, config={}).save()
        >>> other = RunCounters(frames=0)
        >>> RunCheckpoint(path, {"net": torch.nn.Linear(2, 2), "progress": other},
        ...               config={}).load(path)
        >>> other.frames
        128
        >>> keep = os.path.join(os.path.dirname(path), KEPT_CHECKPOINTS)
        >>> progress.next_ckpt = 100
        >>> RunCheckpoint(path, {"progress": progress}, config={},
        ...               keep_dir=keep).save_every(100)
        >>> os.listdir(keep), progress.next_ckpt
        (['checkpoint-000000000128.torchrl'], 200)
    """

    def __init__(
        self,
        path: str | os.PathLike,
        components: Mapping[str, Any],
        config: Mapping[str, Any],
        keep_dir: str | os.PathLike | None = None,
        status: bool | Mapping[str, Any] = False,
    ):
        self.path = Path(path)
        self.status = bool(status)
        self._labels = (
            dict(status)
            if isinstance(status, Mapping)
            else run_labels(config, self.path.parent)
            if status
            else None
        )
        self.components = {k: v for k, v in components.items() if v is not None}
        if "rng" in self.components:
            raise KeyError("'rng' is the checkpoint's own: the global generators.")
        self.config = config
        self._checkpoint = _reader({**self.components, "rng": GlobalRNGState()})
        self._kept = (
            None
            if keep_dir is None
            else CheckpointRotation(keep_dir, keep_last=sys.maxsize)
        )
        self._space_checked = False

    def _metadata(self) -> dict[str, Any]:
        # The frame count and config sit in the manifest, readable without
        # loading the state (checkpoint_info).
        progress = self.components.get("progress")
        frames = 0 if progress is None else progress.frames
        return {"frames": frames, "config": self.config}

    def save(self) -> None:
        """Writes the checkpoint atomically: to a temporary file of its own, then
        renamed over the previous one, which a failed write leaves intact, with
        no temporary file; it raises :class:`RunWriteError`, which names the file
        and the cause (``no space left on device``, ``permission denied``)."""
        tmp = _temporary(self.path)
        try:
            self._checkpoint.save(tmp, metadata=self._metadata())
            os.replace(tmp, self.path)
        except Exception as err:
            if not _is_write_error(err):
                raise
            size = self.path.stat().st_size if self.path.exists() else 0
            raise _write_failure(
                err, self.path, needed=size, kept=self._left_as_it_was()
            ) from err
        finally:
            _remove(tmp)
        legacy = self.path.with_name(LEGACY_CHECKPOINT_NAME)
        if self.path.name == CHECKPOINT_NAME and legacy.exists():
            legacy.unlink()  # superseded by the checkpoint just written
        if self.status:
            write_run_status(
                self.path.parent,
                self.config,
                self._metadata()["frames"],
                labels=self._labels,
            )

    def _left_as_it_was(self) -> str:
        for previous in (self.path, self.path.with_name(LEGACY_CHECKPOINT_NAME)):
            if previous.exists():
                return f"The previous checkpoint, {previous}, is left as it was."
        return "The run has no earlier checkpoint."

    def save_every(self, interval_frames: int, total_frames: int | None = None) -> None:
        """Saves when the run's :class:`RunCounters` has passed ``next_ckpt``
        frames, and moves ``next_ckpt`` on by ``interval_frames``.

        With a ``keep_dir`` and ``total_frames``, the first checkpoint kept in
        this process also warns when the checkpoints still to come, at its size,
        would not fit in the space free there (:func:`kept_checkpoints_warning`):
        the run goes on, and stops with a :class:`RunWriteError` if the disk
        fills."""
        progress = self.components["progress"]
        if progress.frames >= progress.next_ckpt:
            progress.next_ckpt += interval_frames
            self.save()
            if self._kept is not None:
                kept = Path(self._kept.directory)
                path = kept / f"checkpoint-{progress.frames:012d}.torchrl"
                try:
                    self._kept.save(
                        self._checkpoint,
                        step=progress.frames,
                        metadata=self._metadata(),
                    )
                except Exception as err:
                    if not _is_write_error(err):
                        raise
                    raise _write_failure(
                        err,
                        path,
                        kept=f"The run's checkpoint, {self.path}, was written.",
                    ) from err
                if total_frames is not None and not self._space_checked:
                    self._space_checked = True
                    message = kept_checkpoints_warning(
                        path,
                        to_come=(total_frames - progress.frames) // interval_frames,
                        interval_frames=interval_frames,
                    )
                    if message is not None:
                        warnings.warn(message, UserWarning, stacklevel=2)

    def load(self, path: str | os.PathLike) -> None:
        """Restores every component from the checkpoint at ``path`` (either format),
        the random generators last."""
        path = Path(path)
        if _is_legacy(path):
            state = _load_legacy(path)
            saved = set(state)
        else:
            state = None
            _verify_archive(path)
            saved = set(Checkpoint.manifest(path)["components"])
        missing = [name for name in self.components if name not in saved]
        if missing:
            raise KeyError(
                f"{path} holds no {missing}: it was written by another "
                "version of this recipe, or for another experiment."
            )
        if state is not None:
            for name, obj in self.components.items():
                obj.load_state_dict(state[name])
            if "rng" in state:
                GlobalRNGState().load_state_dict(state["rng"])
            return
        for names in (list(self.components), ["rng"]):
            self._checkpoint.load(path, components=names, tensor_load_kwargs=_UNPICKLE)


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


BONUS_SECTIONS: tuple[str, ...] = ("vae", "icm", "rnd")
"""The sections under ``intrinsic`` that configure one bonus each."""


def unused_bonus_sections(config: Mapping[str, Any]) -> tuple[str, ...]:
    """The config sections a run with this config does not read: the whole
    ``intrinsic`` section when ``bonus`` is ``"none"``, else the ``intrinsic.<name>``
    sections of the other bonuses. A changed default there cannot change the run,
    so resuming it is safe.

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
    return tuple(
        f"intrinsic.{name}"
        for name, value in intrinsic.items()
        if name in BONUS_SECTIONS and name != bonus and isinstance(value, Mapping)
    )


def config_differences(
    saved: Mapping[str, Any],
    current: Mapping[str, Any],
    allowed: Sequence[str] = RESUMABLE_CHANGES,
) -> list[str]:
    """The settings that differ between two configs, outside ``allowed``.

    A setting absent from ``saved`` is one that a newer version of the recipe
    added after the checkpoint was written; its default is meant to keep the old
    behaviour, so it is not counted (a setting that was removed is).

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
    diffs = []
    for name in sorted(old):
        if any(name == a or name.startswith(a + ".") for a in allowed):
            continue
        before, after = old[name], new.get(name, "<absent>")
        if before != after:
            diffs.append(f"{name}: {before!r} -> {after!r}")
    return diffs


def truncate_scalar_logs(log_dir: str | os.PathLike, max_step: int) -> int:
    """Drops the rows of TorchRL ``CSVLogger`` scalar files logged after ``max_step``.

    A run killed after its checkpoint has logged steps that its resumed run logs
    again; cutting them at the checkpoint keeps each step logged once. A last
    line that a write left unfinished (no newline) goes as well; any other line
    that is not ``step,value`` raises :class:`DamagedLog` naming it. Each file is
    rewritten atomically (a failed write raises :class:`RunWriteError` and leaves
    it as it was, with no temporary file).

    Returns:
        The number of rows removed.
    """
    removed = 0
    for path in sorted(Path(log_dir).glob("**/scalars/**/*.csv")):
        rows = path.read_bytes().splitlines(keepends=True)
        kept = []
        for number, row in enumerate(rows, 1):
            if max_step < 0:
                break  # a run that starts afresh: every row goes
            parsed = _scalar_row(path, number, row, last=number == len(rows))
            if parsed is not None and parsed[0] <= max_step:
                kept.append(row if row.endswith(b"\n") else row + b"\n")
        if kept != rows:
            removed += len(rows) - len(kept)
            _write_atomically(path, b"".join(kept), kept=f"{path} is left as it was.")
    return removed


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
    nothing computed is overwritten. Writes ``config_resolved.yaml`` once the
    checks pass.

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
            raise FileExistsError(
                f"{run_dir} already holds a checkpoint: pass resume=auto to continue "
                "it, or another hydra.run.dir to start a new run."
            )
        try:
            info = checkpoint_info(ckpt_path)
            if not _is_legacy(ckpt_path):
                _verify_archive(ckpt_path)
        except DamagedCheckpoint as err:
            raise err.for_resume(run_dir) from err.error
        diffs = config_differences(
            info["config"],
            config,
            allowed=RESUMABLE_CHANGES + unused_bonus_sections(info["config"]),
        )
        if diffs:
            raise ValueError(
                f"Cannot resume {run_dir}: the experiment changed ("
                + "; ".join(diffs)
                + "). Only these settings may change on resume: "
                + ", ".join(RESUMABLE_CHANGES)
                + ". Start a new run directory for a new experiment."
            )
        missing = _missing_scalar_logs(run_dir, info)
        if missing and not cfg.get("resume_without_logs", False):
            raise FileNotFoundError(
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
        raise FileNotFoundError(
            f"resume=true but there is no checkpoint in {run_dir}; pass the run "
            "directory of the run to resume as hydra.run.dir=<dir>."
        )
    else:
        # A run killed before its first checkpoint left rows that this run, which
        # starts from frame 0 with the same seed, logs again: drop them.
        truncate_scalar_logs(run_dir / "logs", -1)
        ckpt_path = run_dir / CHECKPOINT_NAME
    run_dir.mkdir(parents=True, exist_ok=True)
    _write_atomically(run_dir / "config_resolved.yaml", OmegaConf.to_yaml(config))
    return ckpt_path, info


class RunCounters:
    """The counters a run checkpoints: frames done, and the frame of the next
    evaluation or checkpoint (``next_eval``, ``next_ckpt``), or any other.

    Examples:
        >>> counters = RunCounters(frames=0, next_ckpt=100)
        >>> counters.frames += 64
        >>> other = RunCounters(frames=0, next_ckpt=0)
        >>> other.load_state_dict(counters.state_dict()); other.frames
        64
    """

    def __init__(self, **counters: int):
        self.__dict__.update(counters)

    def state_dict(self) -> dict[str, int]:
        return dict(self.__dict__)

    def load_state_dict(self, state: Mapping[str, int]) -> None:
        self.__dict__.update(state)


STOP_SIGNALS = _collectors.STOP_SIGNALS
"""The signals that stop a run with a checkpoint (:class:`StopSignal`): Ctrl-C, a
scheduler's SIGTERM, SIGUSR2 (what submitit asks SLURM to send ``signal_delay_s``,
120 s, before the time limit) and SIGHUP (the terminal closed; not when ignored, as
under ``nohup``). The library's tuple
(:data:`torchrl_surprise.collectors.STOP_SIGNALS`), which the collector's worker
processes ignore."""


class StopSignal:
    """Turns the :data:`STOP_SIGNALS` into a request to stop after the current update.

    A training loop checks it once per iteration; when set, it saves a checkpoint
    and exits (:meth:`TrainingRun.after_update`): Ctrl-C sends SIGINT, a cluster
    scheduler SIGTERM before preemption, submitit SIGUSR2 before the time limit,
    a closed terminal SIGHUP. The first signal is the one the run stops for
    (:attr:`received`, :attr:`name`); every one is recorded (:attr:`seen`), so a
    scheduler's SIGTERM after submitit's SIGUSR2 still lets submitit requeue the
    job. A second SIGINT interrupts at once. A SIGHUP that is ignored (``nohup``)
    stays ignored. The handlers found in place are kept (:meth:`previous`,
    :meth:`restore`): submitit's own for SIGUSR2 requeues its job once the run has
    saved (:meth:`TrainingRun.after_update`).

    Examples:
        >>> import os, signal
        >>> stop = StopSignal()
        >>> os.kill(os.getpid(), signal.SIGUSR2)
        >>> os.kill(os.getpid(), signal.SIGTERM)
        >>> bool(stop), stop.name, [signal.Signals(s).name for s in stop.seen]
        (True, 'SIGUSR2', ['SIGUSR2', 'SIGTERM'])
        >>> stop.restore()
    """

    def __init__(self, signals: Sequence[int] = STOP_SIGNALS):
        self.received: int | None = None
        """The first stop signal received (``None`` before any)."""
        self.seen: list[int] = []
        """Every stop signal received, in order."""
        self._previous = {}
        for sig in signals:
            if sig == signal.SIGHUP and signal.getsignal(sig) == signal.SIG_IGN:
                continue  # nohup: the run is meant to outlive its terminal
            self._previous[sig] = signal.signal(sig, self._handle)

    def _handle(self, signum, frame) -> None:
        if signum == signal.SIGINT and signal.SIGINT in self.seen:
            raise KeyboardInterrupt
        self.seen.append(signum)
        if self.received is None:
            self.received = signum

    def __bool__(self) -> bool:
        return self.received is not None

    @property
    def name(self) -> str:
        return signal.Signals(self.received).name if self.received else ""

    def previous(self, sig: int):
        """The handler that ``sig`` had before (``None`` if it was not taken)."""
        return self._previous.get(sig)

    def restore(self) -> None:
        """Puts back the handlers that were installed before."""
        for sig, handler in self._previous.items():
            signal.signal(sig, handler)


def _exit_process(code: int) -> NoReturn:
    """Exits with ``code``, also from a launcher's worker process.

    In the main process this is :func:`sys.exit`. A worker of a process pool (the
    local joblib launcher's loky workers) catches :class:`SystemExit` as a job's
    error and goes on to the sweep's next job, even after the process that
    launched the sweep died of the same signal; so a worker flushes its output
    and ends at once with :func:`os._exit`. Files the run writes (checkpoints,
    CSV logs) are closed or flushed before this is called.
    """
    if multiprocessing.parent_process() is None:
        sys.exit(code)
    for stream in (sys.stdout, sys.stderr):
        stream.flush()
    logging.shutdown()
    os._exit(code)


def resume_command(run_dir: str | os.PathLike) -> str:
    """The command line that resumes the current Hydra run in ``run_dir``."""
    try:
        from hydra.core.hydra_config import HydraConfig

        overrides = [
            o
            for o in HydraConfig.get().overrides.task
            if not o.startswith(("resume=", "hydra.run.dir="))
        ]
    except (ImportError, ValueError):
        overrides = []
    args = [sys.argv[0], *overrides, f"hydra.run.dir={run_dir}", "resume=true"]
    return "python " + " ".join(args)


def _pickle_module_by_name(module: types.ModuleType):
    return importlib.import_module, (module.__name__,)


def register_sweep_pickling(*modules: types.ModuleType) -> None:
    """Lets Hydra's sweep launchers send a recipe's task function to their workers.

    The joblib, submitit and Ray launchers pickle the task function with
    cloudpickle, which pickles a script's function by value together with what
    its code names:

    - ``modules`` (the recipe's ``utils``, ``common``) travel by value as well
      (``cloudpickle.register_pickle_by_value``): the workers cannot import them;
    - the torch submodules the code names, among them ``torch.utils.deterministic``
      (a ``ModuleType`` subclass cloudpickle cannot pickle), are pickled by name:
      a ``copyreg`` entry for that type, for the whole process.

    A recipe calls this once, at import, before Hydra launches anything.

    Examples:
        >>> import cloudpickle, torch.utils.deterministic
        >>> register_sweep_pickling()
        >>> cloudpickle.loads(cloudpickle.dumps(torch.utils.deterministic)).__name__
        'torch.utils.deterministic'
    """
    import cloudpickle
    import torch.utils.deterministic

    for module in modules:
        cloudpickle.register_pickle_by_value(module)
    copyreg.pickle(type(torch.utils.deterministic), _pickle_module_by_name)


LOCK_NAME = "run.lock"
"""The lock file of a run directory: ``<pid> <host>`` of the process that owns it."""


class RunDirInUse(RuntimeError):
    """Another live process owns the run directory (:class:`RunLock`)."""


class RunLock:
    """Makes one process at a time the owner of a run directory.

    An exclusive ``fcntl.flock`` on ``<run_dir>/run.lock``, which holds the owner's
    pid and host. The kernel releases the lock when its process ends, however it
    ends (a SIGKILL, a node's crash), so a dead run never leaves the directory
    stuck; the pid and host in the file only name the owner in the message.

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
        >>> lock.release()
    """

    def __init__(self, run_dir: str | os.PathLike):
        import fcntl

        self.path = Path(run_dir) / LOCK_NAME
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._fd = None
        self._fd = os.open(self.path, os.O_RDWR | os.O_CREAT, 0o644)
        try:
            fcntl.flock(self._fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = self.holder()
            self.release()
            raise RunDirInUse(
                f"{self.path.parent} is in use by {holder}: one process at a time "
                "runs in a run directory. Wait for that run to end (or stop it), or "
                "pass another hydra.run.dir."
            ) from None
        os.ftruncate(self._fd, 0)
        os.pwrite(self._fd, f"{os.getpid()} {socket.gethostname()}\n".encode(), 0)

    def holder(self) -> str:
        """``"process <pid> on <host>"``, as the lock file says."""
        try:
            pid, host = self.path.read_text().split()[:2]
        except (OSError, ValueError):
            return "another process"
        return f"process {pid} on {host}"

    def release(self) -> None:
        """Releases the lock (the process's end does it as well)."""
        if self._fd is not None:
            os.close(self._fd)
            self._fd = None

    __del__ = release


_RECIPES_DIR = str(Path(__file__).resolve().parents[1])


class TrainingRun:
    """What a recipe's run does around its algorithm, in the order it meets it.

    1. ``TrainingRun(cfg, name)``: :func:`prepare_run` (threads, seeds, resume
       checks, the checkpoint to resume from); :meth:`nothing_to_do` says
       whether that checkpoint already holds the whole budget.
    2. :meth:`restore` with what a checkpoint holds, once the run is built: loads
       the checkpoint into it, opens the logger (:attr:`logger`; a resumed run
       continues its logger's run from the state the checkpoint holds as
       ``"logger"``, :func:`get_run_logger`), shows a progress bar
       (:attr:`progress_bar`) and turns the :data:`STOP_SIGNALS` into a request
       to stop (:class:`StopSignal`).
    3. :meth:`after_update` once per collected batch, after its evaluation: the
       progress bar, the periodic checkpoint every ``checkpoint.interval_frames``
       (kept under ``checkpoints/`` with ``checkpoint.keep``), and on a stop
       request a checkpoint, one line on how to resume and the exit; in a
       submitit job, on its SIGUSR2, submitit's handler requeues the job instead.
    4. :meth:`finish`: the final checkpoint, the learning curve read back from the
       logs, and the summary.

    Args:
        cfg: the run's Hydra config (``seed``, ``resume``, ``torch_threads``,
            ``collector.total_frames``, ``logger.*``, ``checkpoint.*``).
        name (str): the learner (``"a2c"``, ``"ddpg"``): the logger's experiment.
        run_dir: the run directory; default: Hydra's output directory.

    Examples:
        >>> import tempfile
        >>> from omegaconf import OmegaConf
        >>> cfg = OmegaConf.create({"seed": 0, "resume": "auto", "torch_threads": 1,
        ...     "collector": {"total_frames": 256},
        ...     "logger": {"backend": "csv", "project_name": "p"},
        ...     "checkpoint": {"interval_frames": 128}})
        >>> run_dir = tempfile.mkdtemp()
        >>> run = TrainingRun(cfg, "demo", run_dir=run_dir)
        >>> counters = RunCounters(frames=0, next_ckpt=128)
        >>> run.restore({"progress": counters}, show_progress=False)
        >>> for _ in range(2):
        ...     counters.frames += 128
        ...     run.log({"train/x": 1.0}, step=counters.frames)
        ...     run.after_update()
        >>> run.finish("256 frames.", curves={"train/x": "x"})  # doctest: +ELLIPSIS
        Done: 256 frames.
        Learning curve: ...learning_curve.png
        ...
        >>> TrainingRun(cfg, "demo", run_dir=run_dir).nothing_to_do()  # doctest: +ELLIPSIS
        Nothing to do: 256 frames already done in ...
        True
    """

    def __init__(self, cfg, name: str, run_dir: str | os.PathLike | None = None):
        if _RECIPES_DIR not in sys.path:
            # A sweep's worker process (submitit, Ray) gets this code by value
            # but not the recipes' folder on its path, where the results tools
            # the run reads at its end live.
            sys.path.insert(0, _RECIPES_DIR)
        if run_dir is None:
            from hydra.core.hydra_config import HydraConfig

            run_dir = HydraConfig.get().runtime.output_dir
        self.cfg = cfg
        self.name = name
        self.run_dir = Path(run_dir)
        self.resumed_from = None
        self._skipped = ""
        try:
            # this process owns the run directory until it ends
            self._lock = RunLock(self.run_dir)
        except RunDirInUse as err:
            if not _in_sweep():
                raise
            # a rerun sweep leaves the job another sweep is running to it
            self._skipped = f"Skipped: {err}"
            return
        # the checkpoint to resume from (None: a new run) and what it says
        try:
            source, self.resumed_from = prepare_run(cfg, self.run_dir)
        except BaseException:
            self._lock.release()  # refused: the directory is free again
            raise
        self._source = source if self.resumed_from else None
        self.logger = None
        self.progress_bar = None
        self.counters: RunCounters | None = None
        self._checkpoint: RunCheckpoint | None = None
        self._stop: StopSignal | None = None
        self._on_exit: Sequence[Any] = ()

    def nothing_to_do(self) -> bool:
        """Whether the checkpoint already holds ``collector.total_frames`` frames
        (a finished run in a rerun sweep), or another sweep runs this job, saying
        so."""
        if self._skipped:
            print(self._skipped)
            return True
        frames = 0 if self.resumed_from is None else self.resumed_from["frames"]
        if frames < self.cfg.collector.total_frames:
            return False
        self._lock.release()
        print(f"Nothing to do: {frames} frames already done in {self.run_dir}.")
        return True

    def restore(
        self,
        components: Mapping[str, Any],
        *,
        on_exit: Sequence[Any] = (),
        show_progress: bool | None = None,
    ) -> None:
        """Loads the checkpoint (if resuming) into ``components`` and starts the loop.

        Args:
            components: what a checkpoint holds, name -> object with
                ``state_dict()`` / ``load_state_dict()`` (:class:`RunCheckpoint`,
                which adds the random generators); ``"progress"`` is the run's
                :class:`RunCounters` (``frames``, ``next_ckpt``).
            on_exit: callables run before the process exits on a stop request,
                and at :meth:`finish` (the collector's ``shutdown``).
            show_progress: draw a progress bar; default: unless in a sweep
                (parallel bars garble each other; the logs hold the progress).
        """
        cfg = self.cfg
        self.counters = components["progress"]
        if "logger" in components:
            raise KeyError("'logger' is the run's own: the logger's state.")
        logger_state = _LoggerState(cfg.logger.backend)
        saved = {**components, "logger": logger_state}
        config = _resolved(cfg)
        self._checkpoint = RunCheckpoint(
            self.run_dir / CHECKPOINT_NAME,
            saved,
            config=config,
            keep_dir=self.run_dir / KEPT_CHECKPOINTS
            if cfg.checkpoint.get("keep", False)
            else None,
            # what identifies the run in status.json: computed once
            status=run_labels(config, self.run_dir),
        )
        if self._source is not None:
            if not _holds_component(self._source, "logger"):
                # written before the logger's state was saved: resumed without it
                saved = components
            RunCheckpoint(self._source, saved, config={}).load(self._source)
        self.logger = get_run_logger(
            cfg.logger.backend,
            self.run_dir,
            self.name,
            cfg.logger.project_name,
            state_dict=logger_state.saved_for(cfg.logger.backend),
            # a fresh run has no events of a killed run to hide
            purge_after=self.counters.frames if self._source is not None else None,
        )
        logger_state.logger = self.logger
        self._stop = StopSignal()
        self._on_exit = tuple(on_exit)
        if show_progress is None:
            show_progress = not _in_sweep()
        from tqdm import tqdm

        self.progress_bar = tqdm(
            total=cfg.collector.total_frames,
            initial=self.counters.frames,
            unit="f",
            desc=f"{self.name} {cfg.get('bonus', '')}".strip(),
            disable=not show_progress,
        )
        self.start_frames = self.counters.frames
        self._start_time = time.perf_counter()

    def per_second(self, count: float) -> float:
        """``count`` (frames, updates done since :meth:`restore`) per second."""
        return count / (time.perf_counter() - self._start_time)

    def log(self, metrics: Mapping[str, float], step: int) -> None:
        """Logs each scalar of ``metrics`` at ``step`` (nothing without a logger)."""
        if self.logger is not None:
            for name, value in metrics.items():
                self.logger.log_scalar(name, value, step=step)

    def after_update(self) -> None:
        """The end of an iteration (updates done, logs written): progress, the
        periodic checkpoint, and on a stop request save, say how to resume, exit
        with status ``128 + signal`` (:func:`_exit_process`)."""
        frames = self.counters.frames
        self.progress_bar.update(frames - self.progress_bar.n)
        self._checkpoint.save_every(
            self.cfg.checkpoint.interval_frames, self.cfg.collector.total_frames
        )
        if not self._stop:
            return
        self._checkpoint.save()
        _end_logger_run(self.logger, "KILLED")
        self.progress_bar.close()
        for close in self._on_exit:
            close()
        requeue = _submitit_requeue(self._stop)
        then = (
            "submitit requeues the job, which resumes from it."
            if requeue is not None
            else f"Resume with: {resume_command(self.run_dir)}"
        )
        print(
            f"{self._stop.name}: stopped at {frames} frames, checkpoint saved. {then}",
            flush=True,
        )
        if requeue is not None:
            # submitit's handler saves its job (the launcher's task with the same
            # arguments), requeues it and exits; the job comes back with
            # resume=auto and continues from the checkpoint just saved.
            _register_recipes_pickling()
            self._stop.restore()
            requeue()
        _exit_process(128 + self._stop.received)

    def finish(
        self,
        summary: str,
        *,
        curves: Mapping[str, str],
        title: str = "",
        ylabel: str = "",
    ) -> Path | None:
        """The final checkpoint, the learning curve and the summary.

        Args:
            summary: what the run reached (printed after ``Done: ``).
            curves: logged scalar -> label, drawn into ``learning_curve.png``
                (:func:`plot_run_curves`).

        Returns:
            The learning curve's path (``None`` when nothing was logged).
        """
        self._stop.restore()
        self.progress_bar.close()
        self._checkpoint.save()
        _end_logger_run(self.logger, "FINISHED")
        for close in self._on_exit:
            close()
        curve = plot_run_curves(
            self.run_dir / "logs",
            curves,
            self.run_dir / "learning_curve.png",
            title=title,
            ylabel=ylabel,
        )
        print(
            f"Done: {summary}\nLearning curve: {curve}\n"
            f"Logs: {self.run_dir / 'logs'}\nRun directory: {self.run_dir}"
        )
        self._lock.release()
        return curve


def _register_recipes_pickling() -> None:
    # A job requeued by submitit is pickled again in this process, where the
    # recipes' modules may have been imported by name since (sys.path holds the
    # recipes' folder, TrainingRun): pickled by reference, the job would not load
    # in the next process, which cannot import them. They go by value, as the
    # sweep's first pickling sent them (register_sweep_pickling).
    recipes = _RECIPES_DIR + os.sep
    modules = [
        module
        for module in list(sys.modules.values())
        if (getattr(module, "__file__", None) or "").startswith(recipes)
    ]
    register_sweep_pickling(*modules)


def _submitit_requeue(stop: StopSignal):
    """Submitit's handler of its preempt signal (``SUBMITIT_PREEMPT_SIGNAL``,
    SIGUSR2), called with that signal, when this process is a submitit job
    (``SUBMITIT_EXECUTOR``) and the signal is among those received (a scheduler's
    SIGTERM may follow it): the handler requeues the job (``max_num_timeout``
    times at most) and exits. ``None`` otherwise."""
    if not os.environ.get("SUBMITIT_EXECUTOR"):
        return None
    name = "SIG" + os.environ.get("SUBMITIT_PREEMPT_SIGNAL", "USR2")
    preempt = getattr(signal, name, None)
    if preempt is None or preempt not in stop.seen:
        return None
    handler = stop.previous(preempt)
    return functools.partial(handler, preempt, None) if callable(handler) else None


def _in_sweep() -> bool:
    try:
        from hydra.core.hydra_config import HydraConfig
        from hydra.types import RunMode

        return HydraConfig.get().mode == RunMode.MULTIRUN
    except (ImportError, ValueError):
        return False


def _resolved(cfg) -> dict[str, Any]:
    from omegaconf import OmegaConf

    return OmegaConf.to_container(cfg, resolve=True)


class EpisodeStats:
    """Finished-episode statistics from collected batches, with a moving window.

    Reads the episode return summed by TorchRL's ``RewardSum`` (extrinsic reward
    when the bonus is mixed in after collection) and the length from
    ``StepCounter``, at the transitions where ``("next", "done")`` is set.

    Args:
        window (int): number of recent episodes the moving mean covers.
        return_key (NestedKey): the episode-return key under ``"next"``.
        length_key (NestedKey): the episode step-count key under ``"next"``.
        success_threshold (float): an episode counts as a success when its
            return exceeds this (MiniGrid pays a positive reward only on success).

    Examples:
        >>> from tensordict import TensorDict
        >>> batch = TensorDict({"next": {
        ...     "done": torch.tensor([[False], [True]]),
        ...     "episode_reward": torch.tensor([[0.0], [0.9]]),
        ...     "step_count": torch.tensor([[1], [2]])}}, [2])
        >>> stats = EpisodeStats(window=10)
        >>> stats.update(batch)
        1
        >>> round(stats.mean_return, 3), stats.success_rate
        (0.9, 1.0)
    """

    def __init__(
        self,
        window: int = 100,
        return_key="episode_reward",
        length_key="step_count",
        success_threshold: float = 0.0,
    ):
        self.returns: deque[float] = deque(maxlen=window)
        self.lengths: deque[int] = deque(maxlen=window)
        self.return_key = return_key
        self.length_key = length_key
        self.success_threshold = success_threshold
        self.episodes = 0

    def update(self, batch: TensorDictBase) -> int:
        """Adds the episodes that end in ``batch``; returns how many ended."""
        done = batch.get(("next", "done")).reshape(-1)
        if not done.any():
            return 0
        returns = batch.get(("next", self.return_key)).reshape(-1)[done]
        lengths = batch.get(("next", self.length_key)).reshape(-1)[done]
        self.returns.extend(returns.tolist())
        self.lengths.extend(lengths.tolist())
        self.episodes += int(done.sum())
        return int(done.sum())

    @property
    def mean_return(self) -> float:
        return float(np.mean(self.returns)) if self.returns else float("nan")

    @property
    def mean_length(self) -> float:
        return float(np.mean(self.lengths)) if self.lengths else float("nan")

    @property
    def success_rate(self) -> float:
        if not self.returns:
            return float("nan")
        return float(np.mean([r > self.success_threshold for r in self.returns]))

    def state_dict(self) -> dict[str, Any]:
        return {
            "returns": list(self.returns),
            "lengths": list(self.lengths),
            "episodes": self.episodes,
        }

    def load_state_dict(self, state: Mapping[str, Any]) -> None:
        self.returns.clear()
        self.returns.extend(state["returns"])
        self.lengths.clear()
        self.lengths.extend(state["lengths"])
        self.episodes = state["episodes"]


def _holds_component(path: Path, name: str) -> bool:
    # a checkpoint of the previous format never holds the logger's state
    return not _is_legacy(path) and name in Checkpoint.manifest(path)["components"]


def _without_csv_history(backend: str, state: Mapping[str, Any]) -> dict[str, Any]:
    """``state``, a logger's ``state_dict()``, without TorchRL's CSV logger's
    history of every ``(step, value)`` logged (``local.scalars``), which would make
    each checkpoint grow with the run: the recipes always log with a ``step``, so
    a resumed CSV logger does not need it; its counters stay. Other backends'
    states are returned as they are.

    Examples:
        >>> state = {"exp_name": "a2c", "local": {"scalars": {"x": [(64, 1.0)]},
        ...          "videos_counter": {}, "text_counter": {}}}
        >>> _without_csv_history("csv", state)["local"]
        {'scalars': {}, 'videos_counter': {}, 'text_counter': {}}
    """
    local = state.get("local")
    if backend != "csv" or not isinstance(local, Mapping):
        return dict(state)
    return {**state, "local": {**local, "scalars": {}}}


class _LoggerState:
    """The checkpoint's ``"logger"``: the backend and TorchRL's
    ``Logger.state_dict()`` of the run's logger (W&B's run id, the CSV logger's
    counters; not the CSV logger's history of scalars, :func:`_without_csv_history`),
    which a resumed run opens its logger with (:func:`get_run_logger`). Saving it
    flushes the logger: what was logged up to a checkpoint is on disk."""

    def __init__(self, backend: str):
        self.backend = backend
        self.logger = None
        self.saved: Mapping[str, Any] | None = None

    def state_dict(self) -> dict[str, Any]:
        state: dict[str, Any] = {"backend": self.backend}
        if self.logger is not None:
            state["state"] = _without_csv_history(
                self.backend, self.logger.state_dict()
            )
        return state

    def load_state_dict(self, state: Mapping[str, Any]) -> None:
        self.saved = state

    def saved_for(self, backend: str) -> Mapping[str, Any] | None:
        """The saved logger state, if it is ``backend``'s (the backend may change
        on resume)."""
        if not self.saved or self.saved.get("backend") != backend:
            return None
        state = self.saved.get("state")
        # a checkpoint written before the history was left out still holds it
        return None if state is None else _without_csv_history(backend, state)


RESUMED_LOGGERS: tuple[str, ...] = ("csv", "tensorboard", "wandb", "mlflow")
"""The backends whose run a resumed run continues from the logger state in its
checkpoint: the same W&B run (its id, ``resume="must"``), the same TensorBoard and
CSV directories with their counters (TorchRL's ``get_logger(..., state_dict=)``),
the same MLflow run (its run id, :class:`RunMLFlowLogger`)."""

MLFLOW_DB = "mlflow.db"
"""The SQLite store an MLflow run writes under ``<run_dir>/logs`` when the
``MLFLOW_TRACKING_URI`` environment variable does not name another store."""


class RunMLFlowLogger(MLFlowLogger):
    """TorchRL's ``MLFlowLogger``, whose run a resumed run continues.

    TorchRL's logger starts a new MLflow run each time it is built; this one, given
    the ``run_id`` saved in the checkpoint (its ``state_dict()["local"]["run_id"]``),
    reopens that run (``mlflow.start_run(run_id=...)``), so a run killed and
    resumed is one MLflow run. :func:`get_run_logger` builds it for
    ``logger.backend=mlflow``.

    Args:
        exp_name (str): the MLflow experiment.
        tracking_uri (str): the MLflow store (a database or server URI).

    Keyword Args:
        run_id (str, optional): the run to continue; a new run when ``None``.
        **kwargs: see TorchRL's ``MLFlowLogger``.
    """

    def __init__(self, exp_name, tracking_uri, *, run_id=None, **kwargs):
        self._resume_run_id = run_id
        super().__init__(exp_name, tracking_uri, **kwargs)

    def _create_experiment(self):
        import mlflow

        if mlflow.active_run() is not None:
            # an earlier run of this process (a sweep's worker runs job after job)
            # that neither finished nor stopped (TrainingRun ends those): it failed
            mlflow.end_run("FAILED")
        if self._resume_run_id is None:
            return super()._create_experiment()
        try:
            run = mlflow.get_run(self._resume_run_id)
        except mlflow.exceptions.MlflowException as err:
            if err.error_code != "RESOURCE_DOES_NOT_EXIST":
                raise
            raise ValueError(
                f"Cannot resume MLflow run {self._resume_run_id!r} (saved in the "
                f"checkpoint) from the store {mlflow.get_tracking_uri()!r}: {err}. "
                "A run resumes in the store it started in: set MLFLOW_TRACKING_URI "
                f"to it, or unset it for the run's logs/{MLFLOW_DB}."
            ) from None
        self.id = run.info.experiment_id
        # start_run(run_id=) refuses a run outside the active experiment
        mlflow.set_experiment(experiment_id=self.id)
        return mlflow.start_run(run_id=self._resume_run_id)

    @property
    def run_id(self) -> str:
        """The MLflow run's id."""
        return self.experiment.info.run_id

    def _active(self) -> bool:
        """Whether this run is MLflow's active run (not ended)."""
        import mlflow

        active = mlflow.active_run()
        return active is not None and active.info.run_id == self.run_id

    def end(self, status: str = "FINISHED") -> None:
        """Ends the MLflow run with ``status`` (``"FINISHED"``; ``"KILLED"`` for
        a run stopped to resume later), if it is still the active run."""
        import mlflow

        if self._active():
            mlflow.end_run(status)

    def log_video(self, name: str, video, **kwargs) -> None:
        """TorchRL's ``log_video``, to this run even once it has ended (the
        recipes record the final policy's video after the run finished)."""
        import mlflow

        if self._active():
            return super().log_video(name, video, **kwargs)
        with mlflow.start_run(run_id=self.run_id):
            return super().log_video(name, video, **kwargs)

    def _checkpoint_state(self) -> dict[str, Any]:
        return {**super()._checkpoint_state(), "run_id": self.run_id}

    def _load_checkpoint_state(self, state_dict: Mapping[str, Any]) -> None:
        # The experiment's id is this store's (_create_experiment): a checkpoint
        # written before the run id was saved holds another store's.
        state = {k: v for k, v in state_dict.items() if k not in ("id", "run_id")}
        super()._load_checkpoint_state(state)


def _end_logger_run(logger, status: str) -> None:
    """Ends the logger's run where the backend keeps one open per process
    (MLflow's active run): the next job of a sweep's worker starts its own."""
    if isinstance(logger, RunMLFlowLogger):
        logger.end(status)


def get_run_logger(
    backend: str,
    run_dir: str | os.PathLike,
    experiment_name: str,
    project: str,
    *,
    state_dict: Mapping[str, Any] | None = None,
    purge_after: int | None = None,
):
    """A TorchRL logger writing under ``<run_dir>/logs`` (``None`` for ``""``).

    Args:
        backend (str): ``"csv"``, ``"tensorboard"``, ``"wandb"``, ``"mlflow"`` or ``""``.
        run_dir: the run directory.
        experiment_name (str): the experiment's name (its folder for CSV and
            TensorBoard).
        project (str): the W&B project (ignored by the other backends).
        state_dict: the logger's ``state_dict()`` saved in the checkpoint of the
            run being resumed: its run continues (:data:`RESUMED_LOGGERS`; ignored
            for the others). The directory is ``run_dir``'s, wherever the run was
            written.
        purge_after: the step (frames) of the checkpoint a run resumes from:
            TensorBoard hides the events that a run killed after it logged past it
            (``SummaryWriter``'s ``purge_step``); the CSV rows are cut by
            :func:`prepare_run`.

    Examples:
        >>> import tempfile
        >>> run_dir = tempfile.mkdtemp()
        >>> logger = get_run_logger("csv", run_dir, "demo", "p")
        >>> logger.log_scalar("train/x", 1.0, step=64)
        >>> state = logger.state_dict()
        >>> resumed = get_run_logger("csv", run_dir, "demo", "p", state_dict=state)
        >>> resumed.experiment.scalars["train/x"]
        [(64, 1.0)]
    """
    from torchrl.record.loggers import get_logger

    logs = str(Path(run_dir) / "logs")
    if backend == "mlflow":
        return _mlflow_run_logger(Path(logs), experiment_name, state_dict)
    kwargs: dict[str, Any] = {}
    if backend == "wandb":
        # reinit=True ("finish_previous"): a sweep's worker runs job after job in
        # one process, where W&B would hand the next job the previous job's run
        kwargs["wandb_kwargs"] = {"project": project, "reinit": True}
    if state_dict is not None and backend in RESUMED_LOGGERS:
        kwargs["state_dict"] = {
            **state_dict,
            "log_dir": logs,
            "exp_name": experiment_name,
        }
    logger = get_logger(
        backend, logger_name=logs, experiment_name=experiment_name, **kwargs
    )
    if backend == "tensorboard" and purge_after is not None:
        from tensorboard.compat.proto.event_pb2 import Event, SessionLog

        writer = logger.experiment._get_file_writer()
        start = SessionLog(status=SessionLog.START)
        writer.add_event(Event(step=purge_after + 1, session_log=start))
        writer.flush()
    return logger


def _mlflow_run_logger(logs: Path, experiment_name: str, state_dict):
    """The MLflow logger of :func:`get_run_logger`: a new run, or the saved one."""
    logs.mkdir(parents=True, exist_ok=True)
    local = (state_dict or {}).get("local") or {}
    uri = os.environ.get("MLFLOW_TRACKING_URI")
    # the run's own store keeps its artifacts beside it; a named store, its own
    artifacts = None if uri else (logs / "mlflow-artifacts").resolve().as_uri()
    logger = RunMLFlowLogger(
        experiment_name,
        uri or f"sqlite:///{(logs / MLFLOW_DB).resolve()}",
        run_id=local.get("run_id"),
        artifact_location=artifacts,
    )
    if state_dict is not None:
        logger.load_state_dict(state_dict)
    return logger


EVAL_SEED_OFFSET = 10_000
"""The evaluation envs are seeded ``seed + EVAL_SEED_OFFSET``: other episodes than
the training envs' with the same ``seed``."""


class Evaluation(NamedTuple):
    """The extrinsic returns of the episodes an evaluation ran.

    Examples:
        >>> result = Evaluation([0.0, 0.5, 1.0, 0.0])
        >>> result.mean_return, result.success_rate
        (0.375, 0.5)
    """

    returns: list[float]

    @property
    def mean_return(self) -> float:
        """The mean return (0 when no episode ended)."""
        return sum(self.returns) / max(len(self.returns), 1)

    @property
    def success_rate(self) -> float:
        """The fraction of episodes with a positive return (MiniGrid pays a
        positive reward only on success)."""
        return sum(r > 0 for r in self.returns) / max(len(self.returns), 1)


def evaluate(
    env,
    policy,
    episodes: int,
    *,
    seed: int,
    deterministic: bool = True,
    chunk: int = 256,
    max_chunks: int = 100,
) -> Evaluation:
    """Runs ``policy`` until ``episodes`` episodes end, under ``torch.no_grad()``.

    The env is reseeded with ``seed`` first, so every evaluation sees the same
    episodes. It must sum the episode return under ``("next", "episode_reward")``
    (TorchRL's ``RewardSum``, placed before any bonus so the return is extrinsic).

    Args:
        env: a (batched) TorchRL env.
        policy: the policy to evaluate.
        episodes (int): how many finished episodes to return.
        seed (int): the evaluation seed (the run's ``seed + EVAL_SEED_OFFSET``).
        deterministic (bool): ``ExplorationType.DETERMINISTIC`` or ``RANDOM``.
        chunk (int): steps per rollout call; ``max_chunks`` bounds the total.

    Returns:
        The returns of the first ``episodes`` episodes that ended.
    """
    from torchrl.envs.utils import ExplorationType, set_exploration_type, step_mdp

    env.set_seed(seed)
    mode = ExplorationType.DETERMINISTIC if deterministic else ExplorationType.RANDOM
    returns: list[float] = []
    state = env.reset()
    with torch.no_grad(), set_exploration_type(mode):
        for _ in range(max_chunks):
            rollout = env.rollout(
                chunk,
                policy,
                auto_reset=False,
                tensordict=state,
                break_when_any_done=False,
            )
            done = rollout["next", "done"].squeeze(-1)
            returns += rollout["next", "episode_reward"].squeeze(-1)[done].tolist()
            state = step_mdp(rollout[..., -1])
            if len(returns) >= episodes:
                break
    return Evaluation(returns[:episodes])


def read_scalar_csv(path: str | os.PathLike) -> tuple[np.ndarray, np.ndarray]:
    """Reads one scalar file of TorchRL's ``CSVLogger`` (rows ``step,value``).

    When a resumed run logged a step again, the last value of that step is kept.
    A last line still being written (no newline yet) is skipped.

    Raises:
        DamagedLog: a line is not ``step,value``; it names the file and line.
    """
    values: dict[int, float] = {}
    rows = Path(path).read_bytes().splitlines(keepends=True)
    for number, row in enumerate(rows, 1):
        parsed = _scalar_row(path, number, row, last=number == len(rows))
        if parsed is not None:
            values[parsed[0]] = parsed[1]
    steps = np.array(sorted(values), dtype=np.int64)
    return steps, np.array([values[s] for s in steps], dtype=np.float64)


def plot_learning_curves(
    curves: Mapping[str, tuple[Sequence[float], Sequence[float]]],
    path: str | os.PathLike,
    *,
    title: str = "",
    xlabel: str = "frames",
    ylabel: str = "return",
) -> Path:
    """Plots named ``(x, y)`` curves into a PNG with matplotlib's Agg backend.

    Examples:
        >>> import tempfile, os
        >>> out = plot_learning_curves({"a": ([0, 1], [0.0, 1.0])},
        ...                            os.path.join(tempfile.mkdtemp(), "c.png"))
        >>> out.exists()
        True
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 4))
    for name, (x, y) in curves.items():
        ax.plot(x, y, label=name, marker="." if len(x) < 50 else None)
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    if title:
        ax.set_title(title)
    if len(curves) > 1:
        ax.legend()
    ax.grid(alpha=0.3)
    fig.tight_layout()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path


def find_scalar_log(log_dir: str | os.PathLike, name: str) -> Path:
    """The CSV file of scalar ``name`` (e.g. ``"train/episode_return"``) under a run's
    ``logs`` directory, whatever the experiment folder TorchRL's ``CSVLogger`` made."""
    matches = sorted(Path(log_dir).glob(f"*/scalars/{name}.csv"))
    if not matches:
        raise FileNotFoundError(f"no scalar log {name!r} under {log_dir}")
    return matches[0]


def plot_run_curves(
    log_dir: str | os.PathLike,
    curves: Mapping[str, str],
    path: str | os.PathLike,
    *,
    title: str = "",
    ylabel: str = "",
) -> Path | None:
    """Plots logged scalars against frames, read back from the run's CSV logs.

    Args:
        log_dir: the run's ``logs`` directory.
        curves: scalar name (``"train/episode_return"``) -> its label.
        path: the PNG to write.

    Returns:
        ``path``, or ``None`` (nothing drawn) when the run logged none of the
        scalars, for instance with ``logger.backend=`` (no logger). Points with
        no value yet (NaN before the first episode ends) are left out.
    """
    data = {}
    for name, label in curves.items():
        try:
            steps, values = read_scalar_csv(find_scalar_log(log_dir, name))
        except FileNotFoundError:
            continue
        finite = np.isfinite(values)
        data[label] = (steps[finite], values[finite])
    if not data:
        return None
    return plot_learning_curves(data, path, title=title, ylabel=ylabel)
