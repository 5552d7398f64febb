"""What a recipe's run does around its algorithm: :class:`TrainingRun`.

A recipe's ``main.py`` holds its algorithm; :class:`TrainingRun` composes the run
directory (:mod:`common.rundir`), checkpoints (:mod:`common.checkpoint`), loggers
(:mod:`common.loggers`), stop signals (:mod:`common.stopping`) and the learning
curve (:mod:`common.evaluation`) around it.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import time
from collections.abc import Iterator, Mapping, Sequence
from pathlib import Path
from typing import Any

import torch

from .checkpoint import (
    CHECKPOINT_NAME,
    DIVERGED_ADVICE,
    KEPT_CHECKPOINTS,
    RunCheckpoint,
    RunCounters,
    first_non_finite,
    load_resumed,
)
from .errors import NonFiniteRun, UserMistake
from .evaluation import plot_run_curves, run_curve_text
from .labels import run_labels
from .loggers import LoggerState, RunLogs
from .rundir import (
    LOCK_NAME,
    RunDirInUse,
    RunLock,
    prepare_run,
    write_run_record,
)
from .scalar_logs import scalar_log_files
from .stopping import StopSignal, in_sweep, stop_and_exit

__all__ = ["CURVE_NAME", "TrainingRun"]

CURVE_NAME = "learning_curve.png"
"""The learning curve a run draws when it ends, in its run directory."""


class TrainingRun:
    """What a recipe's run does around its algorithm, in the order it meets it.

    1. ``TrainingRun(cfg, name)``: :func:`prepare_run` (threads, seeds, resume
       checks, the checkpoint to resume from); :meth:`nothing_to_do` says
       whether that checkpoint already holds the whole budget.
    2. :meth:`restore` with what a checkpoint holds, once the run is built: loads
       the checkpoint into it, opens the logger (:attr:`logger`; a resumed run
       continues its logger's run from the state the checkpoint holds as
       ``"logger"``, :class:`RunLogs`), shows a progress bar
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
            if not in_sweep():
                raise
            # a rerun sweep leaves the job another sweep is running to it
            self._skipped = f"Skipped: {err}"
            return
        # made for this launch (Hydra makes it empty; the lock file is ours):
        # abandon() removes it
        self._fresh = {p.name for p in self.run_dir.iterdir()} <= {LOCK_NAME}
        # the checkpoint to resume from (None: a new run) and what it says
        try:
            source, self.resumed_from = prepare_run(cfg, self.run_dir)
        except BaseException:
            self.abandon()  # refused: the directory is as it was, and free
            raise
        self._source = source if self.resumed_from else None
        self.logs: RunLogs | None = None
        self.progress_bar = None
        self.counters: RunCounters | None = None
        self._checkpoint: RunCheckpoint | None = None
        self._stop: StopSignal | None = None
        self._on_exit: Sequence[Any] = ()

    def abandon(self) -> None:
        """Gives the run directory up before the run started (:meth:`restore`),
        for a launch refused on a mistake: the lock is released and a directory
        this launch made (absent or empty before it) is removed with what was
        written in it, so a refused launch leaves nothing behind."""
        if self._fresh and self.run_dir.is_dir():
            # removed while the lock is held: no other launch has the directory
            shutil.rmtree(self.run_dir, ignore_errors=True)
        self._lock.release()

    @contextlib.contextmanager
    def starting(self) -> Iterator[None]:
        """Where a recipe builds its run, up to :meth:`restore`: a user's mistake
        raised there (an unknown env, a model that does not fit a transfer)
        gives the run directory up (:meth:`abandon`) before it propagates."""
        try:
            yield
        except UserMistake:
            self.abandon()
            raise

    @property
    def done_frames(self) -> int:
        """The frames the checkpoint to resume from holds (0 for a new run)."""
        return 0 if self.resumed_from is None else int(self.resumed_from["frames"])

    def nothing_to_do(self, outputs: Sequence[Path] = ()) -> bool:
        """Whether the checkpoint already holds ``collector.total_frames`` frames
        (a finished run in a rerun sweep) and the run's end left everything it
        writes, or another sweep runs this job, saying so.

        A finished run whose end is missing something (its learning curve when it
        logged scalars, one of ``outputs``: the video a recipe records at its
        end) has something to do: it is resumed, trains no further, and its end
        writes what is missing.

        Args:
            outputs: the files the recipe's end writes, besides the curve.
        """
        if self._skipped:
            print(self._skipped)
            return True
        frames = self.done_frames
        if frames < self.cfg.collector.total_frames:
            return False
        missing = [Path(p) for p in outputs if not Path(p).exists()]
        curve = self.run_dir / CURVE_NAME
        if not curve.exists() and scalar_log_files(self.run_dir):
            missing.insert(0, curve)
        if missing:
            print(
                f"Finished at {frames} frames; writing what its end left missing: "
                + ", ".join(str(p) for p in missing)
            )
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
        logger_state = LoggerState(cfg.logger.backend)
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
            load_resumed(self._source, saved)
        # the run starts: its record (resolved config, Hydra's) is this launch's
        write_run_record(self.run_dir, cfg)
        self.logs = RunLogs(
            cfg.logger.backend,
            self.run_dir,
            self.name,
            cfg.logger.project_name,
            logger_state,
            # a fresh run has no events of a killed run to hide
            purge_after=self.counters.frames if self._source is not None else None,
        )
        self._stop = StopSignal()
        self._on_exit = tuple(on_exit)
        if show_progress is None:
            show_progress = not in_sweep()
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

    def check_finite(self, frames: int, **values: Any) -> None:
        """Stops the run when a loss (a tensor) or a module's or optimiser's
        state holds a NaN or an infinity, naming the first such quantity; the
        last checkpoint, finite, stays the run's (:class:`NonFiniteRun`).

        Examples:
            >>> import torch
            >>> run = TrainingRun.__new__(TrainingRun)
            >>> run.run_dir = "run"
            >>> run.check_finite(64, loss=torch.tensor(1.0))
            >>> run.check_finite(64, loss=torch.tensor(float("inf")))
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
                kept = (
                    self._checkpoint.left_as_it_was()
                    if getattr(self, "_checkpoint", None) is not None
                    else ""
                )
                raise NonFiniteRun(
                    f"{where} is not finite at {frames} frames: the run diverged "
                    f"and stops. {kept} {DIVERGED_ADVICE}".replace("  ", " ")
                )

    @property
    def logger(self):
        """The run's TorchRL logger (``None`` before :meth:`restore`, or with
        ``logger.backend=''``)."""
        return None if self.logs is None else self.logs.logger

    def log(self, metrics: Mapping[str, float], step: int) -> None:
        """Logs each scalar of ``metrics`` at ``step`` (:class:`RunLogs`)."""
        self.logs.log(metrics, step)

    def after_update(self) -> None:
        """The end of an iteration (updates done, logs written): progress, the
        periodic checkpoint, and on a stop request save, say how to resume, exit
        with status ``128 + signal`` (:func:`stop_and_exit`)."""
        frames = self.counters.frames
        self.progress_bar.update(frames - self.progress_bar.n)
        self._checkpoint.save_every(
            self.cfg.checkpoint.interval_frames, self.cfg.collector.total_frames
        )
        if self._stop:
            self._checkpoint.save()
            stop_and_exit(
                self._stop, self.run_dir, frames, lambda: self._close("KILLED")
            )

    def _close(self, status: str) -> None:
        # what the run holds open: its logs, its progress bar, the recipe's
        # (the collector's shutdown)
        self.logs.close(status)
        self.progress_bar.close()
        for close in self._on_exit:
            close()

    def finish(
        self,
        summary: str,
        *,
        curves: Mapping[str, str],
        title: str = "",
        ylabel: str = "",
        optimum: tuple[str, float] | None = None,
    ) -> Path | None:
        """The final checkpoint, the learning curve and the summary.

        Args:
            summary: what the run reached (printed after ``Done: ``).
            curves: logged scalar -> label, drawn into ``learning_curve.png``
                (:func:`plot_run_curves`) whatever the logger (none without one).
            optimum: ``(label, value)``, the task's best return, drawn as a
                dashed line (the MiniGrid oracle's); ``None``: no line.

        Returns:
            The learning curve's path (``None`` when nothing was logged).
        """
        self._stop.restore()
        self._checkpoint.save()
        self._close("FINISHED")
        curve = plot_run_curves(
            self.run_dir / "logs",
            curves,
            self.run_dir / CURVE_NAME,
            title=title,
            ylabel=ylabel,
            optimum=optimum,
        )
        drawn = run_curve_text(curve, self.cfg.logger.backend, curves)
        print(
            f"Done: {summary}\nLearning curve: {drawn}\n"
            f"Logs: {self.run_dir / 'logs'}\nRun directory: {self.run_dir}"
        )
        self._lock.release()
        return curve


def _resolved(cfg) -> dict[str, Any]:
    from omegaconf import OmegaConf

    return OmegaConf.to_container(cfg, resolve=True)
