"""Checkpoints of a run: TorchRL's format, the atomic write, damage named.

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

import os
import shlex
import sys
import warnings
import zipfile
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import torch
from torchrl.checkpoint import (
    Checkpoint,
    CheckpointRotation,
    GlobalRNGState,
    StateDictCheckpointAdapter,
)

from .errors import NonFiniteRun, UserMistake
from .files import (
    free_bytes,
    is_write_error,
    remove_path,
    temporary_path,
    write_failure,
)
from .labels import run_labels
from .status import write_run_status

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


def is_legacy(path: Path) -> bool:
    return not (path.is_dir() or Checkpoint.is_checkpoint(path))


def load_legacy(path: Path) -> dict[str, Any]:
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


class DamagedCheckpoint(UserMistake, ValueError):
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
        common.checkpoint.DamagedCheckpoint: .../checkpoint.torchrl is damaged: it is empty (0 bytes)...
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
        # every path shell-quoted: the commands are pasted as they are
        run_dir, damaged = self.run_dir, shlex.quote(str(self.path))
        advice = []
        if self.earlier is not None:
            earlier = shlex.quote(str(self.earlier))
            target = shlex.quote(str(run_dir / CHECKPOINT_NAME))
            aside = shlex.quote(f"{self.path}.damaged")
            advice.append(
                f"To resume from the kept {self.earlier} ({self.earlier_frames} "
                f"frames), put it in place of the damaged file: mv {damaged} "
                f"{aside} && cp {earlier} {target}; then run the same command again."
            )
        else:
            advice.append(self._use_earlier())
        moved = shlex.quote(f"{run_dir}.damaged")
        advice.append(
            f"To start afresh, move the run directory away (mv "
            f"{shlex.quote(str(run_dir))} {moved}) or pass another hydra.run.dir, "
            "with resume=false."
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
            verify_archive(candidate)
        except Exception:  # damaged as well: an older one
            continue
        return candidate, int(frames)
    return None, None


def verify_archive(path: Path) -> None:
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
    if is_legacy(path):
        state = load_legacy(path)
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
    if is_legacy(path):
        return load_legacy(path)
    verify_archive(path)
    manifest = Checkpoint.manifest(path)
    holders = {name: _SavedState() for name in manifest["components"]}
    checkpoint_of(holders).load(path, tensor_load_kwargs=UNPICKLE)
    state = {name: holder.state for name, holder in holders.items()}
    state.update(checkpoint_info(path))
    return state


def checkpoint_of(components: Mapping[str, Any]) -> Checkpoint:
    # Each state dict is one torch.save payload in the archive: 3 to 7 times
    # cheaper to write than the default TensorDict payload for the recipes' many
    # small states. It is read with pickle (UNPICKLE): the collectors' states
    # hold TensorDicts and the episode state of envs, which weights-only loading
    # refuses; so a checkpoint is trusted as the 0.2 torch.save one was.
    checkpoint = Checkpoint(format="archive")
    for name, obj in components.items():
        checkpoint.register(
            name, obj, adapter=StateDictCheckpointAdapter(payload_format="torch")
        )
    return checkpoint


UNPICKLE = {"weights_only": False}


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
    free = free_bytes(path)
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


DIVERGED_ADVICE = (
    "Start a new run with other settings (a smaller learning rate or "
    "intrinsic.coef), or look for what the last update read."
)
"""What a run that went non-finite is told to do."""


def first_non_finite(components: Mapping[str, Any]) -> str | None:
    """``"<component>: <entry>"`` of the first floating-point tensor holding a NaN
    or an infinity in the state of the modules and optimisers among
    ``components`` (``None`` when all are finite). Other components (collectors,
    buffers, counters) hold what the envs gave, not what training computed.

    Examples:
        >>> net = torch.nn.Linear(2, 1)
        >>> first_non_finite({"model": net}) is None
        True
        >>> with torch.no_grad():
        ...     net.bias.fill_(float("nan"))
        Parameter containing:
        tensor([nan], requires_grad=True)
        >>> first_non_finite({"model": net})
        'model: bias'
    """

    def walk(value, path):
        if isinstance(value, torch.Tensor):
            if value.is_floating_point() and not torch.isfinite(value).all():
                return path
        elif isinstance(value, Mapping):
            for key, item in value.items():
                found = walk(item, f"{path}.{key}" if path else str(key))
                if found is not None:
                    return found
        elif isinstance(value, (list, tuple)):
            for index, item in enumerate(value):
                found = walk(item, f"{path}[{index}]")
                if found is not None:
                    return found
        return None

    for name, obj in components.items():
        if isinstance(obj, (torch.nn.Module, torch.optim.Optimizer)):
            found = walk(obj.state_dict(), "")
            if found is not None:
                return f"{name}: {found}"
    return None


def check_finite(
    frames: int, checkpoint: RunCheckpoint | None = None, **values: Any
) -> None:
    """Stops a run when one of ``values`` (a loss tensor, or a module or an
    optimiser, whose state is read) holds a NaN or an infinity, naming the first
    such quantity (:class:`NonFiniteRun`); the run's last checkpoint, finite,
    stays its own.

    Examples:
        >>> check_finite(64, loss=torch.tensor(1.0))
        >>> check_finite(64, loss=torch.tensor(float("inf")))
        Traceback (most recent call last):
        ...
        common.errors.NonFiniteRun: loss is not finite at 64 frames: ...
    """
    for name, value in values.items():
        if isinstance(value, torch.Tensor):
            where = None if torch.isfinite(value).all() else name
        else:
            where = first_non_finite({name: value})
        if where is not None:
            kept = "" if checkpoint is None else checkpoint.left_as_it_was() + " "
            raise NonFiniteRun(
                f"{where} is not finite at {frames} frames: the run diverged and "
                f"stops. {kept}{DIVERGED_ADVICE}"
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
        self._checkpoint = checkpoint_of({**self.components, "rng": GlobalRNGState()})
        self._kept = (
            None
            if keep_dir is None
            else CheckpointRotation(keep_dir, keep_last=sys.maxsize)
        )
        self._space_checked = False

    @classmethod
    def for_run(
        cls,
        run_dir: str | os.PathLike,
        components: Mapping[str, Any],
        config: Mapping[str, Any],
        keep: bool = False,
    ) -> RunCheckpoint:
        """The checkpoint of the run in ``run_dir``: ``checkpoint.torchrl``, each
        periodic one also kept under ``checkpoints/`` with ``keep``, and
        ``status.json`` rewritten with each save."""
        run_dir = Path(run_dir)
        return cls(
            run_dir / CHECKPOINT_NAME,
            components,
            config=config,
            keep_dir=run_dir / KEPT_CHECKPOINTS if keep else None,
            status=True,
        )

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
        and the cause (``no space left on device``, ``permission denied``).

        A module or optimiser whose state holds a NaN or an infinity is never
        saved (:func:`first_non_finite`): :class:`NonFiniteRun` names it, and
        the previous checkpoint stays the run's."""
        where = first_non_finite(self.components)
        if where is not None:
            raise NonFiniteRun(
                f"{where} is not finite at {self._metadata()['frames']} frames: the "
                f"run diverged and stops, saving nothing. {self.left_as_it_was()} "
                f"{DIVERGED_ADVICE}"
            )
        tmp = temporary_path(self.path)
        try:
            self._checkpoint.save(tmp, metadata=self._metadata())
            os.replace(tmp, self.path)
        except Exception as err:
            if not is_write_error(err):
                raise
            size = self.path.stat().st_size if self.path.exists() else 0
            raise write_failure(
                err, self.path, needed=size, kept=self.left_as_it_was()
            ) from err
        finally:
            remove_path(tmp)
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

    def left_as_it_was(self) -> str:
        """What a failed save leaves: the previous checkpoint, or none."""
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
                    if not is_write_error(err):
                        raise
                    raise write_failure(
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
        if is_legacy(path):
            state = load_legacy(path)
            saved = set(state)
        else:
            state = None
            verify_archive(path)
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
            self._checkpoint.load(path, components=names, tensor_load_kwargs=UNPICKLE)


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


def holds_component(path: Path, name: str) -> bool:
    # a checkpoint of the previous format never holds the logger's state
    return not is_legacy(path) and name in Checkpoint.manifest(path)["components"]


def load_resumed(source: Path, components: Mapping[str, Any]) -> None:
    """Loads the checkpoint at ``source``, the one a run resumes from, into
    ``components``; a checkpoint written before the logger's state was saved
    (``"logger"``) loads without it, and the resumed logger starts afresh."""
    if not holds_component(source, "logger"):
        components = {k: v for k, v in components.items() if k != "logger"}
    RunCheckpoint(source, components, config={}).load(source)
