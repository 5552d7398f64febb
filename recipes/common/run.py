"""What a recipe's run does around its algorithm: :class:`TrainingRun`.

A recipe's ``main.py`` holds its algorithm; :class:`TrainingRun` composes the run
directory (:mod:`common.rundir`), checkpoints (:mod:`common.checkpoint`), loggers
(:mod:`common.loggers`), stop signals (:mod:`common.stopping`) and the learning
curve (:mod:`common.evaluation`) around it.
"""

from __future__ import annotations

import contextlib
import os
import time
from collections.abc import Iterator, Mapping, Sequence
from pathlib import Path
from typing import Any

from tqdm import tqdm

from .checkpoint import RunCheckpoint, RunCounters, check_finite, load_resumed
from .errors import UserMistake
from .evaluation import CURVE_NAME, plot_run_curves, run_curve_text
from .loggers import LoggerState, RunLogs
from .rundir import RunDirClaim, write_run_record
from .stopping import StopSignal, in_sweep, stop_and_exit

__all__ = ["CURVE_NAME", "TrainingRun"]


class TrainingRun:
    """What a recipe's run does around its algorithm, in the order it meets it.

    1. ``TrainingRun(cfg, name)``: the run directory's lock and checks
       (:class:`~common.rundir.RunDirClaim`: threads, seeds, resume checks, the
       checkpoint to resume from); :meth:`nothing_to_do` says whether that
       checkpoint already holds the whole budget.
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
        self.cfg, self.name, self.run_dir = cfg, name, Path(run_dir)
        # this process owns the run directory until it ends
        self.dir = RunDirClaim(cfg, self.run_dir)
        self.logs: RunLogs | None = None
        self.counters: RunCounters | None = None
        self.progress_bar = None
        self._checkpoint: RunCheckpoint | None = None
        self._stop: StopSignal | None = None
        self._on_exit: Sequence[Any] = ()

    @contextlib.contextmanager
    def starting(self) -> Iterator[None]:
        """Where a recipe builds its run, up to :meth:`restore`: a user's mistake
        raised there (an unknown env, a model that does not fit a transfer)
        gives the run directory up (:meth:`RunDirClaim.abandon`) before it
        propagates, leaving nothing behind."""
        try:
            yield
        except UserMistake:
            self.dir.abandon()
            raise

    @property
    def resumed_from(self) -> dict[str, Any] | None:
        """What the checkpoint to resume from says (``None`` for a new run)."""
        return self.dir.resumed_from

    @property
    def done_frames(self) -> int:
        """The frames the checkpoint to resume from holds (0 for a new run)."""
        return self.dir.done_frames

    def nothing_to_do(self, outputs: Sequence[Path] = ()) -> bool:
        """Whether the checkpoint already holds ``collector.total_frames`` frames
        (a finished run in a rerun sweep) and the run's end left everything it
        writes (its learning curve when it logged scalars, and ``outputs``: the
        video a recipe records at its end), or another sweep runs this job,
        saying so (:meth:`RunDirClaim.finished`). A finished run missing one is
        resumed, trains no further, and its end writes what is missing."""
        total = self.cfg.collector.total_frames
        return self.dir.finished(total, outputs, curve=self.run_dir / CURVE_NAME)

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
        cfg, source = self.cfg, self.dir.source
        if "logger" in components:
            raise KeyError("'logger' is the run's own: the logger's state.")
        self.counters = components["progress"]
        saved = {**components, "logger": LoggerState(cfg.logger.backend)}
        self._checkpoint = RunCheckpoint.for_run(
            self.run_dir, saved, _resolved(cfg), cfg.checkpoint.get("keep", False)
        )
        if source is not None:
            load_resumed(source, saved)
        write_run_record(self.run_dir, cfg)  # the run starts: its record is ours
        self.logs = RunLogs(
            cfg.logger.backend,
            self.run_dir,
            self.name,
            cfg.logger.project_name,
            saved["logger"],
            # a fresh run has no events of a killed run to hide
            purge_after=None if source is None else self.counters.frames,
        )
        self._stop, self._on_exit = StopSignal(), tuple(on_exit)
        self.progress_bar = tqdm(
            total=cfg.collector.total_frames,
            initial=self.counters.frames,
            unit="f",
            desc=f"{self.name} {cfg.get('bonus', '')}".strip(),
            disable=in_sweep() if show_progress is None else not show_progress,
        )
        self.start_frames, self._start_time = self.counters.frames, time.perf_counter()

    def per_second(self, count: float) -> float:
        """``count`` (frames, updates done since :meth:`restore`) per second."""
        return count / (time.perf_counter() - self._start_time)

    def check_finite(self, frames: int, **values: Any) -> None:
        """Stops the run when a loss (a tensor) or a module's or optimiser's
        state holds a NaN or an infinity, naming the first such quantity; the
        last checkpoint, finite, stays the run's (:func:`check_finite`)."""
        check_finite(frames, self._checkpoint, **values)

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
        frames, cfg = self.counters.frames, self.cfg
        self.progress_bar.update(frames - self.progress_bar.n)
        self._checkpoint.save_every(
            cfg.checkpoint.interval_frames, cfg.collector.total_frames
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
        logs = self.run_dir / "logs"
        curve = plot_run_curves(
            logs,
            curves,
            self.run_dir / CURVE_NAME,
            title=title,
            ylabel=ylabel,
            optimum=optimum,
        )
        drawn = run_curve_text(curve, self.cfg.logger.backend, curves)
        print(
            f"Done: {summary}\nLearning curve: {drawn}\n"
            f"Logs: {logs}\nRun directory: {self.run_dir}"
        )
        self.dir.release()
        return curve


def _resolved(cfg) -> dict[str, Any]:
    from omegaconf import OmegaConf

    return OmegaConf.to_container(cfg, resolve=True)
