"""The run's TorchRL logger, and its resume from the state a checkpoint holds."""

from __future__ import annotations

import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from torchrl.record.loggers.mlflow import MLFlowLogger

from .scalar_logs import ScalarCSVWriter


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


class LoggerState:
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


def end_logger_run(logger, status: str) -> None:
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


class RunLogs:
    """Where a run's scalars go: its TorchRL logger (:func:`get_run_logger`) and,
    when that logger is not CSV's, a CSV copy of each scalar
    (:class:`~common.scalar_logs.ScalarCSVWriter`), which the learning curve is
    drawn from whatever the logger.

    Args:
        backend (str): ``logger.backend`` (``""``: no logger, no scalars).
        run_dir: the run directory (logs under ``<run_dir>/logs``).
        name (str): the logger's experiment (the learner).
        project (str): the W&B project.
        state (LoggerState): the logger's state the checkpoint holds; the logger
            is attached to it, so the next checkpoint saves it.
        purge_after: the frames of the checkpoint a run resumes from
            (:func:`get_run_logger`), ``None`` for a fresh run.

    Examples:
        >>> import tempfile
        >>> run_dir = Path(tempfile.mkdtemp())
        >>> logs = RunLogs("csv", run_dir, "demo", "p", LoggerState("csv"))
        >>> logs.log({"train/x": 1.0}, step=64)
        >>> logs.close("FINISHED")
        >>> (run_dir / "logs/demo/scalars/train/x.csv").read_text()
        '64,1.0\\n'
    """

    def __init__(
        self,
        backend: str,
        run_dir: str | os.PathLike,
        name: str,
        project: str,
        state: LoggerState,
        purge_after: int | None = None,
    ):
        self.logger = get_run_logger(
            backend,
            run_dir,
            name,
            project,
            state_dict=state.saved_for(backend),
            purge_after=purge_after,
        )
        state.logger = self.logger
        # CSV's own rows are the logger's; no rows without a logger
        self._copy = (
            ScalarCSVWriter(Path(run_dir) / "logs" / name)
            if backend not in ("csv", "")
            else None
        )

    def log(self, metrics: Mapping[str, float], step: int) -> None:
        """Logs each scalar of ``metrics`` at ``step``."""
        if self.logger is not None:
            for name, value in metrics.items():
                self.logger.log_scalar(name, value, step=step)
        if self._copy is not None:
            for name, value in metrics.items():
                self._copy.add_scalar(name, value, step)

    def close(self, status: str) -> None:
        """Ends the logger's run with ``status`` (``"FINISHED"``, ``"KILLED"``:
        :func:`end_logger_run`) and closes the CSV copy."""
        end_logger_run(self.logger, status)
        if self._copy is not None:
            self._copy.close()
