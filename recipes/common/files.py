"""Writes of a run's files that a full disk or a kill cannot leave half done.

A file is written beside its target and renamed over it (:func:`write_atomically`);
a failed write raises :class:`RunWriteError`, which names the file, the cause and
what is left as it was. Written here because neither TorchRL nor the standard
library has an atomic write that names its failure.
"""

from __future__ import annotations

import errno
import os
import shutil
import uuid
from pathlib import Path

from .errors import UserMistake

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


class RunWriteError(UserMistake, OSError):
    """A file of a run could not be written: the message names the file, the
    cause (``no space left on device``, ``permission denied``) and what is left as
    it was. ``errno`` is the cause's (``None`` when unknown).

    Examples:
        >>> err = write_failure(OSError(errno.ENOSPC, "No space"), Path("/r/x"))
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


def is_write_error(error: BaseException) -> bool:
    # torch.save reports a failed write as a RuntimeError of its zip writer
    # ("[enforce fail at inline_container.cc:672] . unexpected pos").
    if _errno_of(error) is not None:
        return True
    text = str(error)
    return isinstance(error, RuntimeError) and (
        "inline_container" in text or "PytorchStreamWriter" in text
    )


def free_bytes(path: Path) -> int | None:
    for folder in (path.parent, *path.parents):
        if folder.is_dir():
            try:
                return shutil.disk_usage(folder).free
            except OSError:
                return None
    return None


def write_failure(
    error: BaseException, path: Path, *, needed: int = 0, kept: str = ""
) -> RunWriteError:
    """The error to raise for a failed write of ``path``: its cause in words."""
    code = _errno_of(error)
    free = free_bytes(path)
    if code is None and free is not None and free < max(needed, _NEARLY_FULL):
        code = errno.ENOSPC  # torch's writer gives no errno
    if code is None:
        reason = f"the write failed ({type(error).__name__}: {error})"
    else:
        reason = _WRITE_ERRORS.get(code) or os.strerror(code).lower()
    message = f"could not write {path}: {reason}"
    if code in (errno.ENOSPC, errno.EDQUOT) and free is not None:
        message += f" ({free / 2**20:.1f} MiB free there"
        if needed:
            # a new file is written beside the one it replaces
            message += f"; the write needs about {needed / 2**20:.1f} MiB more"
        message += ")"
    message += ". No partial file is left behind."
    if kept:
        message += " " + kept
    if code in (errno.ENOSPC, errno.EDQUOT):
        message += " Free some space (or move the run directory), then resume."
    elif code in (errno.EACCES, errno.EPERM, errno.EROFS):
        message += " Make the run directory writable, then resume."
    return RunWriteError(code, message, str(path))


def remove_path(path: Path) -> None:
    try:
        if path.is_dir():
            shutil.rmtree(path, ignore_errors=True)
        else:
            path.unlink(missing_ok=True)
    except OSError:
        pass


def temporary_path(path: Path) -> Path:
    return path.with_name(f".{path.name}.{os.getpid()}-{uuid.uuid4().hex[:8]}.tmp")


def write_atomically(path: Path, data: str | bytes, *, kept: str = "") -> None:
    """Writes ``data`` to a temporary file beside ``path``, then renames it over
    ``path``: a failed write leaves ``path`` as it was and no temporary file, and
    raises :class:`RunWriteError`."""
    tmp = temporary_path(path)
    try:
        with open(tmp, "wb" if isinstance(data, bytes) else "w") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except OSError as err:
        raise write_failure(err, path, kept=kept) from err
    finally:
        remove_path(tmp)
