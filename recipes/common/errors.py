"""A user's mistake is one message: what is wrong, where, what to do.

The errors a user can cause (a bad setting, an unknown env, a damaged file, a run
directory in use, a changed experiment on resume) are :class:`UserMistake`; a
recipe's ``main`` runs under :func:`report_mistakes`, which prints such an error's
message on stderr, with no traceback, and exits with status 2. Any other exception
is a bug and keeps its traceback; so does a mistake under ``HYDRA_FULL_ERROR=1``.
A collector worker that died (:class:`~torchrl_surprise.collectors.CollectorWorkerDied`:
killed, out of memory) is no mistake but no bug of the recipe either: it is one
message too, with the command that resumes the run, and exit status 1.
"""

from __future__ import annotations

import contextlib
import functools
import os
import sys
from collections.abc import Callable, Iterator
from pathlib import Path

from tqdm import tqdm

from torchrl_surprise.collectors import CollectorWorkerDied

from .stopping import in_sweep, resume_command

__all__ = [
    "ConfigError",
    "MISTAKE_EXIT_CODE",
    "MissingRunFile",
    "NonFiniteRun",
    "ResumeRefused",
    "RunAlreadyThere",
    "UserMistake",
    "report_mistakes",
]

MISTAKE_EXIT_CODE = 2
"""The exit status of a run refused for a user's mistake (a bug's is Python's 1)."""


class UserMistake(Exception):
    """Mixed into the errors a user causes and fixes: their message says what to do."""


class ConfigError(UserMistake, ValueError):
    """A setting the recipe cannot run with, named by its full key."""


class ResumeRefused(UserMistake, ValueError):
    """A run directory that cannot be resumed (or started) as asked."""


class MissingRunFile(UserMistake, FileNotFoundError):
    """A file a resume needs is not in the run directory (its checkpoint, its logs)."""


class RunAlreadyThere(UserMistake, FileExistsError):
    """``resume=false`` in a run directory that already holds a run."""


class NonFiniteRun(UserMistake, ArithmeticError):
    """The run went non-finite (a loss, a gradient, a parameter): it stops, and
    its last finite checkpoint stays as it was."""


def _hydra_run_dir() -> Path | None:
    try:
        from hydra.core.hydra_config import HydraConfig

        return Path(HydraConfig.get().runtime.output_dir)
    except (ImportError, ValueError):
        return None


def _print_error(message: str) -> None:
    # on a line of its own, a progress bar cleared first
    with tqdm.external_write_mode(file=sys.stderr):
        print(f"Error: {message}", file=sys.stderr, flush=True)


@contextlib.contextmanager
def _reporting() -> Iterator[None]:
    try:
        yield
    except CollectorWorkerDied as err:
        if os.environ.get("HYDRA_FULL_ERROR") == "1":
            raise
        run_dir = _hydra_run_dir()
        resume = f" Resume with: {resume_command(run_dir)}" if run_dir else ""
        _print_error(f"{err}{resume}")
        if in_sweep():
            raise  # Hydra marks this job failed (a rerun of the sweep resumes it)
        raise SystemExit(1) from None
    except UserMistake as err:
        if os.environ.get("HYDRA_FULL_ERROR") == "1":
            raise
        run_dir = _hydra_run_dir()
        if run_dir is not None and run_dir.is_dir() and not any(run_dir.iterdir()):
            try:
                run_dir.rmdir()  # made by Hydra for this launch, which never started
            except OSError:
                pass  # another launch wrote there since
        _print_error(str(err))
        if in_sweep():
            raise  # Hydra marks this job failed; the sweep's other jobs go on
        raise SystemExit(MISTAKE_EXIT_CODE) from None


def report_mistakes(main: Callable) -> Callable:
    """Decorates a recipe's ``main``: a :class:`UserMistake` is printed as one
    ``Error: ...`` line on stderr and the process exits with
    :data:`MISTAKE_EXIT_CODE` (in a sweep, the error goes on to Hydra, which marks
    the job failed and runs the others); the empty run directory Hydra made for
    a launch refused before it started is removed.

    Examples:
        >>> @report_mistakes
        ... def main():
        ...     raise ConfigError("optim.lr must be a finite number > 0, got inf.")
        >>> import contextlib, io
        >>> err = io.StringIO()
        >>> with contextlib.redirect_stderr(err):
        ...     try:
        ...         main()
        ...     except SystemExit as exit:
        ...         code = exit.code
        >>> code, err.getvalue()
        (2, 'Error: optim.lr must be a finite number > 0, got inf.\\n')
    """

    @functools.wraps(main)
    def reported(*args, **kwargs):
        with _reporting():
            return main(*args, **kwargs)

    return reported
