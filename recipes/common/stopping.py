"""Stopping a run on a signal with a checkpoint, and how it comes back: the
resume command, submitit's requeue, the pickling a sweep's launcher needs."""

from __future__ import annotations

import copyreg
import functools
import importlib
import logging
import multiprocessing
import os
import re
import shlex
import signal
import sys
import types
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import NoReturn

from torchrl_surprise import collectors as _collectors

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


def exit_process(code: int) -> NoReturn:
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


def hydra_path_override(key: str, path: str | os.PathLike) -> str:
    """``key=path`` as one shell word that Hydra's override parser reads back as
    ``path``, whatever the path holds (spaces, quotes, non-ASCII letters).

    Examples:
        >>> hydra_path_override("hydra.run.dir", "runs/a_b-1.2")
        'hydra.run.dir=runs/a_b-1.2'
        >>> print(hydra_path_override("hydra.run.dir", "/tmp/sp ace/été"))
        'hydra.run.dir='"'"'/tmp/sp ace/été'"'"''
    """
    path = str(path)
    if re.fullmatch(r"[A-Za-z0-9_./:+-]+", path):
        return shlex.quote(f"{key}={path}")
    # A quoted Hydra value: a quote is escaped, and so are the backslashes before
    # a quote or the closing one (Hydra keeps any other backslash as it is).
    value = re.sub(r"(\\*)'", lambda m: m.group(1) * 2 + "\\'", path)
    value = "'" + re.sub(r"(\\+)$", lambda m: m.group(1) * 2, value) + "'"
    return shlex.quote(f"{key}={value}")


def resume_command(run_dir: str | os.PathLike) -> str:
    """The command line that resumes the current Hydra run in ``run_dir``, each
    word quoted for the shell (:func:`hydra_path_override` for the directory)."""
    try:
        from hydra.core.hydra_config import HydraConfig

        overrides = [
            o
            for o in HydraConfig.get().overrides.task
            if not o.startswith(("resume=", "hydra.run.dir="))
        ]
    except (ImportError, ValueError):
        overrides = []
    words = [shlex.quote(word) for word in (sys.argv[0], *overrides)]
    words += [hydra_path_override("hydra.run.dir", run_dir), "resume=true"]
    return "python " + " ".join(words)


def _pickle_module_by_name(module: types.ModuleType):
    return importlib.import_module, (module.__name__,)


def sweep_requested(argv: Sequence[str]) -> bool:
    """Whether a recipe's command line asks Hydra for a sweep (``-m``,
    ``--multirun`` or ``hydra.mode=MULTIRUN``): only then does a launcher pickle
    the recipe's task function (:func:`register_sweep_pickling`).

    Examples:
        >>> sweep_requested(["main.py", "-m", "seed=0,1"])
        True
        >>> sweep_requested(["main.py", "seed=0"])
        False
    """
    return any(
        arg in ("-m", "--multirun")
        or arg.replace(" ", "").lstrip("+") == "hydra.mode=MULTIRUN"
        for arg in argv[1:]
    )


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

    A recipe calls this once, before Hydra launches a sweep
    (:func:`sweep_requested`); a single run pickles nothing.

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


RECIPES_DIR = str(Path(__file__).resolve().parents[1])


def register_recipes_pickling() -> None:
    # A job requeued by submitit is pickled again in this process, where the
    # recipes' modules may have been imported by name since (sys.path holds the
    # recipes' folder, TrainingRun): pickled by reference, the job would not load
    # in the next process, which cannot import them. They go by value, as the
    # sweep's first pickling sent them (register_sweep_pickling).
    recipes = RECIPES_DIR + os.sep
    modules = [
        module
        for module in list(sys.modules.values())
        if (getattr(module, "__file__", None) or "").startswith(recipes)
    ]
    register_sweep_pickling(*modules)


def submitit_requeue(stop: StopSignal):
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


def stop_and_exit(
    stop: StopSignal, run_dir: str | os.PathLike, frames: int, close: Callable[[], None]
) -> NoReturn:
    """Ends a run on a stop request, its checkpoint saved at ``frames``: closes
    what it holds (``close``), says how it resumes and exits with status ``128 +
    signal`` (:func:`exit_process`); in a submitit job, on its preempt signal,
    submitit's handler requeues the job instead (:func:`submitit_requeue`)."""
    close()
    requeue = submitit_requeue(stop)
    then = (
        "submitit requeues the job, which resumes from it."
        if requeue is not None
        else f"Resume with: {resume_command(run_dir)}"
    )
    print(
        f"{stop.name}: stopped at {frames} frames, checkpoint saved. {then}", flush=True
    )
    if requeue is not None:
        # submitit's handler saves its job (the launcher's task with the same
        # arguments), requeues it and exits; the job comes back with resume=auto
        # and continues from the checkpoint just saved.
        register_recipes_pickling()
        stop.restore()
        requeue()
    exit_process(128 + stop.received)


def in_sweep() -> bool:
    try:
        from hydra.core.hydra_config import HydraConfig
        from hydra.types import RunMode

        return HydraConfig.get().mode == RunMode.MULTIRUN
    except (ImportError, ValueError):
        return False
