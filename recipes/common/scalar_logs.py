"""The scalar logs of TorchRL's ``CSVLogger``: read, cut at a checkpoint, found."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from .errors import UserMistake
from .files import write_atomically

__all__ = [
    "DamagedLog",
    "ScalarCSVWriter",
    "find_scalar_log",
    "read_scalar_csv",
    "scalar_log_files",
    "truncate_scalar_logs",
]


class DamagedLog(UserMistake, ValueError):
    """A scalar log with a line that is not a ``step,value`` row; the message
    names the file and the line.

    Examples:
        >>> import tempfile, os
        >>> path = os.path.join(tempfile.mkdtemp(), "x.csv")
        >>> _ = open(path, "w").write("64,0.5\\nline\\n128,0.25\\n")
        >>> read_scalar_csv(path)  # doctest: +ELLIPSIS
        Traceback (most recent call last):
        ...
        common.scalar_logs.DamagedLog: .../x.csv, line 2: 'line' is not a 'step,value' row...
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


def scalar_log_files(run_dir: Path) -> list[str]:
    logs = (run_dir / "logs").glob("*/scalars/**/*.csv")
    return sorted(p.relative_to(run_dir).as_posix() for p in logs)


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
            write_atomically(path, b"".join(kept), kept=f"{path} is left as it was.")
    return removed


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


def find_scalar_log(log_dir: str | os.PathLike, name: str) -> Path:
    """The CSV file of scalar ``name`` (e.g. ``"train/episode_return"``) under a run's
    ``logs`` directory, whatever the experiment folder TorchRL's ``CSVLogger`` made."""
    matches = sorted(Path(log_dir).glob(f"*/scalars/{name}.csv"))
    if not matches:
        raise FileNotFoundError(f"no scalar log {name!r} under {log_dir}")
    return matches[0]


class ScalarCSVWriter:
    """Writes scalars as TorchRL's ``CSVLogger`` does, one ``step,value`` row each.

    A run that logs to TensorBoard, W&B or MLflow keeps its scalars here as well,
    under ``<run dir>/logs/<experiment>/scalars/<name>.csv``: its learning curve
    is drawn from them (:func:`common.evaluation.plot_run_curves`), and a resume
    cuts them at the checkpoint as it cuts a CSV run's (:func:`truncate_scalar_logs`).
    Each row is flushed when written: what a checkpoint follows is on disk.
    Written here rather than as a second ``CSVLogger``, whose experiment keeps
    every scalar it logged in memory for the length of the run.

    Args:
        log_dir: the experiment's folder, ``<run dir>/logs/<experiment>``.

    Examples:
        >>> import tempfile
        >>> log_dir = Path(tempfile.mkdtemp()) / "demo"
        >>> with ScalarCSVWriter(log_dir) as writer:
        ...     writer.add_scalar("train/x", 0.5, step=64)
        >>> read_scalar_csv(find_scalar_log(log_dir.parent, "train/x"))
        (array([64]), array([0.5]))
    """

    def __init__(self, log_dir: str | os.PathLike):
        self.log_dir = Path(log_dir)
        self._files: dict[str, object] = {}

    def add_scalar(self, name: str, value: float, step: int) -> None:
        """Appends the row ``step,value`` to ``scalars/<name>.csv``."""
        file = self._files.get(name)
        if file is None:
            path = self.log_dir / "scalars" / f"{name}.csv"
            path.parent.mkdir(parents=True, exist_ok=True)
            file = self._files[name] = path.open("a")
        file.write(f"{int(step)},{float(value)}\n")
        file.flush()

    def close(self) -> None:
        """Closes the files (a later :meth:`add_scalar` opens them again)."""
        for file in self._files.values():
            file.close()
        self._files.clear()

    def __enter__(self) -> ScalarCSVWriter:
        return self

    def __exit__(self, *exc) -> None:
        self.close()
