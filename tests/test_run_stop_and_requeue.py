"""Runs that survive a cluster: the signals that save and stop a run, submitit's
requeue after its time-limit warning, and the logger's run continued on resume."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import torch
from _recipe_run import wait_for_checkpoint
from omegaconf import OmegaConf
from tensorboard.backend.event_processing import event_file_loader
from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

from common.checkpoint import (
    CHECKPOINT_NAME,
    RunCheckpoint,
    RunCounters,
    checkpoint_info,
    load_checkpoint,
)
from common.loggers import RunMLFlowLogger, get_run_logger
from common.run import TrainingRun
from common.rundir import LOCK_NAME
from common.scalar_logs import read_scalar_csv
from common.stopping import StopSignal, submitit_requeue

RECIPES = Path(__file__).resolve().parents[1] / "recipes"
MAIN = RECIPES / "minigrid" / "main.py"
# 32 frames per update, each logged; no bonus: the cheapest run of the recipe
TINY = [
    "bonus=none",
    "env.name=MiniGrid-MultiRoom-N2-S4-v0",
    "env.num_envs=4",
    "collector.frames_per_env=8",
    "eval.interval_frames=256",
    "eval.episodes=2",
    "eval.num_envs=2",
    "checkpoint.interval_frames=128",
    "logger.log_interval=1",
]
REWARD_CSV = "logs/a2c/scalars/train/reward.csv"


def run_recipe(run_dir: Path, *overrides: str) -> subprocess.CompletedProcess:
    cmd = [sys.executable, str(MAIN), f"hydra.run.dir={run_dir}", *TINY, *overrides]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, f"{proc.stdout[-2000:]}\n{proc.stderr[-3000:]}"
    return proc


@pytest.mark.parametrize("sig", [signal.SIGUSR2, signal.SIGHUP])
def test_sigusr2_and_sighup_save_a_checkpoint_and_the_run_resumes(tmp_path, sig):
    # SIGUSR2: SLURM's warning before the time limit (submitit's --signal);
    # SIGHUP: the terminal the run was started from closed.
    run_dir = tmp_path / "run"
    cmd = [sys.executable, str(MAIN), f"hydra.run.dir={run_dir}", *TINY]
    proc = subprocess.Popen(
        [*cmd, "collector.total_frames=1000000"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        # the run starts with the signal's default action, as from a terminal,
        # also when the tests run under nohup (which ignores SIGHUP, and an
        # ignored SIGHUP stays ignored: the next test)
        preexec_fn=lambda: signal.signal(sig, signal.SIG_DFL),
    )
    try:
        wait_for_checkpoint(run_dir / CHECKPOINT_NAME, min_frames=128)
        proc.send_signal(sig)
        out, err = proc.communicate(timeout=120)
    finally:
        proc.kill()
    assert proc.returncode == 128 + sig, err[-3000:]
    assert "Traceback" not in err
    assert f"{sig.name}: stopped at" in out and "Resume with:" in out, out[-2000:]
    frames = load_checkpoint(run_dir / CHECKPOINT_NAME)["frames"]
    steps, _ = read_scalar_csv(run_dir / REWARD_CSV)
    assert steps[-1] == frames, "the stop saved a checkpoint at the last logged step"
    out = run_recipe(run_dir, f"collector.total_frames={frames + 64}").stdout
    assert f"Done: {frames + 64} frames" in out
    steps, _ = read_scalar_csv(run_dir / REWARD_CSV)
    assert steps.tolist() == list(range(32, frames + 65, 32))


def test_an_ignored_sighup_stays_ignored():
    # nohup: the run is meant to outlive its terminal
    previous = signal.signal(signal.SIGHUP, signal.SIG_IGN)
    try:
        stop = StopSignal()
        os.kill(os.getpid(), signal.SIGHUP)
        assert signal.getsignal(signal.SIGHUP) == signal.SIG_IGN and not stop
        stop.restore()
    finally:
        signal.signal(signal.SIGHUP, previous)


def test_a_sigterm_after_submitits_sigusr2_still_requeues(monkeypatch):
    # SLURM's SIGTERM can follow its SIGUSR2 before the update ends: the run
    # stops for the first signal and submitit's handler still requeues the job.
    requeued = []
    previous = signal.signal(signal.SIGUSR2, lambda *a: requeued.append(a[0]))
    try:
        stop = StopSignal()
        os.kill(os.getpid(), signal.SIGUSR2)
        os.kill(os.getpid(), signal.SIGTERM)
        stop.restore()
    finally:
        signal.signal(signal.SIGUSR2, previous)
    assert stop.received == signal.SIGUSR2 and stop.name == "SIGUSR2"
    assert stop.seen == [signal.SIGUSR2, signal.SIGTERM]
    monkeypatch.setenv("SUBMITIT_EXECUTOR", "slurm")
    requeue = submitit_requeue(stop)
    assert requeue is not None
    requeue()
    assert requeued == [signal.SIGUSR2]
    monkeypatch.delenv("SUBMITIT_EXECUTOR")
    assert submitit_requeue(stop) is None, "not a submitit job: no requeue"


def test_a_submitit_job_saves_on_sigusr2_is_requeued_and_resumes(tmp_path):
    # submitit_local runs a job the way SLURM does (submitit's SIGUSR2 handler,
    # the requeue); the SIGUSR2 is sent here rather than timeout_min - 30 s late.
    sweep_dir = tmp_path / "sweep"
    job_dir = sweep_dir / "job"
    sweep = [
        sys.executable,
        str(MAIN),
        "-m",
        "hydra/launcher=submitit_local",
        f"hydra.sweep.dir={sweep_dir}",
        "hydra.sweep.subdir=job",
        *TINY,
        "collector.total_frames=512",
    ]
    proc = subprocess.Popen(
        sweep, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
    )
    try:
        wait_for_checkpoint(job_dir / CHECKPOINT_NAME, min_frames=128, timeout=300)
        first_pid = int((job_dir / LOCK_NAME).read_text().split()[0])
        os.kill(first_pid, signal.SIGUSR2)
        out, err = proc.communicate(timeout=300)
    finally:
        proc.kill()
    assert proc.returncode == 0, err[-3000:]
    logs = sorted((sweep_dir / ".submitit").glob("*/*_log.*"))
    job_log = "\n".join(p.read_text() for p in logs)
    # the first attempt saved where it stopped, submitit requeued the job, the
    # second attempt resumed from that checkpoint and finished the budget
    stops = [line for line in job_log.splitlines() if "SIGUSR2: stopped at" in line]
    assert len(set(stops)) == 1, job_log[-3000:]
    assert stops[0].endswith("submitit requeues the job, which resumes from it.")
    assert "Requeued job" in job_log and "Done: 512 frames" in job_log
    assert int((job_dir / LOCK_NAME).read_text().split()[0]) != first_pid
    assert checkpoint_info(job_dir / CHECKPOINT_NAME)["frames"] == 512
    steps, _ = read_scalar_csv(job_dir / REWARD_CSV)
    assert steps.tolist() == list(range(32, 513, 32)), "each step logged once"


def event_steps(path: Path, tag: str) -> list[int]:
    """The steps of ``tag`` in one TensorBoard events file, as written."""
    return [
        e.step
        for e in event_file_loader.EventFileLoader(str(path)).Load()
        if any(v.tag == tag for v in e.summary.value)
    ]


def test_a_resumed_tensorboard_run_continues_its_events(tmp_path):
    run_dir = tmp_path / "run"
    events = run_dir / "logs" / "a2c"
    cmd = [sys.executable, str(MAIN), f"hydra.run.dir={run_dir}", *TINY]
    tb = ["logger.backend=tensorboard", "checkpoint.interval_frames=512"]
    proc = subprocess.Popen(
        [*cmd, *tb, "collector.total_frames=1000000"],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    try:
        # killed between two checkpoints, once it has logged past the first
        wait_for_checkpoint(run_dir / CHECKPOINT_NAME, min_frames=512)
        deadline = time.time() + 120
        while (
            max(
                event_steps(p, "train/reward")
                for p in events.glob("events.out.tfevents.*")
            )[-1]
            <= 512
        ):
            assert time.time() < deadline, "no step logged after the checkpoint"
            time.sleep(0.05)
    finally:
        proc.kill()
        proc.wait()
    assert checkpoint_info(run_dir / CHECKPOINT_NAME)["frames"] == 512
    run_recipe(run_dir, *tb, "collector.total_frames=768")
    # one run: one experiment directory, which both processes wrote to
    assert [p.name for p in (run_dir / "logs").iterdir()] == ["a2c"]
    written = sorted(
        s
        for p in events.glob("events.out.tfevents.*")
        for s in event_steps(p, "train/reward")
    )
    assert len(written) > len(set(written)), "the killed run logged past 512"
    # what TensorBoard shows: every step once, the killed run's extra ones hidden
    shown = EventAccumulator(str(events)).Reload().Scalars("train/reward")
    assert [e.step for e in shown] == list(range(32, 769, 32))
    assert load_checkpoint(run_dir / CHECKPOINT_NAME)["logger"]["backend"] == (
        "tensorboard"
    )


def _cfg(total_frames: int):
    return OmegaConf.create(
        {
            "seed": 0,
            "resume": "auto",
            "torch_threads": 1,
            "collector": {"total_frames": total_frames},
            "logger": {"backend": "csv", "project_name": "p"},
            "checkpoint": {"interval_frames": 128},
        }
    )


def _train(run_dir: Path, total_frames: int) -> TrainingRun:
    run = TrainingRun(_cfg(total_frames), "demo", run_dir=run_dir)
    counters = RunCounters(frames=0, next_ckpt=128)
    run.restore({"progress": counters}, show_progress=False)
    while counters.frames < total_frames:
        counters.frames += 64
        run.log({"train/x": float(counters.frames)}, step=counters.frames)
        run.after_update()
    run.finish(f"{counters.frames} frames.", curves={})
    return run


def test_the_logger_state_is_saved_and_a_resumed_run_continues_it(tmp_path):
    _train(tmp_path, 256)
    state = load_checkpoint(tmp_path / CHECKPOINT_NAME)["logger"]
    assert state["backend"] == "csv"
    # not the history of every scalar logged: it would grow with the run
    assert not state["state"]["local"]["scalars"]
    _train(tmp_path, 384)
    # the logger continued the first part's files, each step once
    steps, _ = read_scalar_csv(tmp_path / "logs" / "demo" / "scalars" / "train/x.csv")
    assert steps.tolist() == [64, 128, 192, 256, 320, 384]


def test_a_checkpoint_without_logger_state_still_resumes(tmp_path):
    # written before the checkpoint held the logger's state (and no logs: this
    # checkpoint was not written by a run)
    cfg = _cfg(256)
    cfg.resume_without_logs = True
    saved = OmegaConf.to_container(cfg, resolve=True)
    counters = RunCounters(frames=128, next_ckpt=256)
    net = torch.nn.Linear(2, 1)
    RunCheckpoint(
        tmp_path / CHECKPOINT_NAME, {"progress": counters, "net": net}, saved
    ).save()
    run = TrainingRun(cfg, "demo", run_dir=tmp_path)
    restored = RunCounters(frames=0, next_ckpt=128)
    run.restore({"progress": restored, "net": torch.nn.Linear(2, 1)})
    assert restored.frames == 128 and run.logger is not None
    restored.frames = 256
    run.after_update()
    assert load_checkpoint(tmp_path / CHECKPOINT_NAME)["logger"]["backend"] == "csv"
    run.finish("256 frames.", curves={})


def _stopped_and_resumed(run_dir, backend: str, env: dict) -> int:
    """Runs the recipe with ``logger.backend=backend``, stops it by SIGTERM after
    its first checkpoint, resumes it for 64 more frames; returns the frames it
    stopped at."""
    cmd = [sys.executable, str(MAIN), f"hydra.run.dir={run_dir}", *TINY]
    cmd.append(f"logger.backend={backend}")
    proc = subprocess.Popen(
        [*cmd, "collector.total_frames=1000000"],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
        env=env,
    )
    try:
        wait_for_checkpoint(run_dir / CHECKPOINT_NAME, min_frames=128)
        proc.send_signal(signal.SIGTERM)
        _, err = proc.communicate(timeout=120)
    finally:
        proc.kill()
    assert proc.returncode == 128 + signal.SIGTERM, err[-3000:]
    frames = checkpoint_info(run_dir / CHECKPOINT_NAME)["frames"]
    resumed = subprocess.run(
        [*cmd, f"collector.total_frames={frames + 64}"],
        capture_output=True,
        text=True,
        timeout=300,
        env=env,
    )
    assert resumed.returncode == 0, resumed.stderr[-3000:]
    return frames


def test_a_resumed_wandb_run_continues_the_same_run(tmp_path):
    pytest.importorskip("wandb")
    run_dir = tmp_path / "run"
    env = {**os.environ, "WANDB_MODE": "offline", "WANDB_SILENT": "true"}
    _stopped_and_resumed(run_dir, "wandb", env)
    # an offline W&B run is a directory offline-run-<time>-<run id>: both
    # processes logged to the one run id the checkpoint holds
    runs = sorted((run_dir / "logs" / "wandb").glob("offline-run-*"))
    ids = {p.name.rsplit("-", 1)[1] for p in runs}
    assert len(runs) == 2 and len(ids) == 1, [p.name for p in runs]
    saved = load_checkpoint(run_dir / CHECKPOINT_NAME)["logger"]["state"]
    assert ids == {saved["local"]["id"]}


def test_a_resumed_mlflow_run_continues_the_same_run(tmp_path):
    mlflow = pytest.importorskip("mlflow")
    run_dir = tmp_path / "run"
    env = {k: v for k, v in os.environ.items() if k != "MLFLOW_TRACKING_URI"}
    frames = _stopped_and_resumed(run_dir, "mlflow", env)
    # one run in the run's own SQLite store, holding both parts' steps
    client = mlflow.MlflowClient(f"sqlite:///{run_dir / 'logs' / 'mlflow.db'}")
    runs = [
        r
        for e in client.search_experiments()
        for r in client.search_runs([e.experiment_id])
    ]
    saved = load_checkpoint(run_dir / CHECKPOINT_NAME)["logger"]["state"]
    assert [r.info.run_id for r in runs] == [saved["local"]["run_id"]]
    steps = [
        m.step for m in client.get_metric_history(runs[0].info.run_id, "train/episodes")
    ]
    assert steps[0] <= 64 and steps[-1] == frames + 64, steps


def test_wandb_runs_one_after_another_in_a_process_each_log_to_their_own(
    tmp_path, monkeypatch
):
    # a sweep's worker (joblib's loky reuses processes) runs job after job: by
    # default W&B hands a second wandb.init in a process the first run
    pytest.importorskip("wandb")
    monkeypatch.setenv("WANDB_MODE", "offline")
    monkeypatch.setenv("WANDB_SILENT", "true")
    first = get_run_logger("wandb", tmp_path / "a", "exp", "p")
    first.log_scalar("train/x", 1.0, step=64)
    first_id = first.experiment.id
    second = get_run_logger("wandb", tmp_path / "b", "exp", "p")
    second.log_scalar("train/x", 2.0, step=64)
    assert second.experiment.id != first_id
    assert first.state_dict()["local"]["id"] == first_id
    second.experiment.finish()


@pytest.fixture
def mlflow_here(monkeypatch):
    """mlflow, with its process-wide tracking URI and active run put back after."""
    mlflow = pytest.importorskip("mlflow")
    from mlflow.tracking._tracking_service import utils as tracking_utils

    monkeypatch.delenv("MLFLOW_TRACKING_URI", raising=False)
    monkeypatch.setattr(tracking_utils, "_tracking_uri", tracking_utils._tracking_uri)
    yield mlflow
    while mlflow.active_run() is not None:
        mlflow.end_run()


def _mlflow_runs(mlflow, store):
    client = mlflow.MlflowClient(store)
    return client, {
        r.info.run_id: r
        for e in client.search_experiments()
        for r in client.search_runs([e.experiment_id])
    }


def test_an_mlflow_run_missing_from_the_store_is_refused_naming_it(
    tmp_path, mlflow_here
):
    uri = f"sqlite:///{tmp_path / 'other.db'}"
    with pytest.raises(ValueError, match="Cannot resume MLflow run 'a1b2c3'.*other.db"):
        RunMLFlowLogger("demo", uri, run_id="a1b2c3")


def test_mlflow_runs_one_after_another_in_a_process_each_log_to_their_own(
    tmp_path, mlflow_here, monkeypatch
):
    # a sweep's worker runs job after job in one process; with a shared store
    # (MLFLOW_TRACKING_URI) a resumed run sits in another experiment than the
    # last one logged to
    store = f"sqlite:///{tmp_path / 'shared.db'}"
    monkeypatch.setenv("MLFLOW_TRACKING_URI", store)
    first = get_run_logger("mlflow", tmp_path / "a", "exp_a", "p")
    first.log_scalar("train/x", 1.0, step=64)
    state = first.state_dict()
    first.end("KILLED")
    second = get_run_logger("mlflow", tmp_path / "b", "exp_b", "p")
    second.log_scalar("train/x", 2.0, step=64)  # never ended: a crashed job
    resumed = get_run_logger("mlflow", tmp_path / "a", "exp_a", "p", state_dict=state)
    resumed.log_scalar("train/x", 3.0, step=128)
    resumed.end()
    client, runs = _mlflow_runs(mlflow_here, store)
    assert resumed.run_id == first.run_id and len(runs) == 2
    history = client.get_metric_history(first.run_id, "train/x")
    assert [(m.step, m.value) for m in history] == [(64, 1.0), (128, 3.0)]
    assert [m.value for m in client.get_metric_history(second.run_id, "train/x")] == [
        2.0
    ]
    assert runs[first.run_id].info.status == "FINISHED"
    assert runs[second.run_id].info.status == "FAILED"


def test_an_mlflow_checkpoint_without_a_run_id_resumes_with_a_new_run(
    tmp_path, mlflow_here
):
    # the logger state of a checkpoint written before the run id was saved: the
    # experiment id of another store, the video counter
    old = {
        "exp_name": "demo",
        "log_dir": "x",
        "local": {"id": "7", "video_log_counter": 3},
    }
    logger = get_run_logger("mlflow", tmp_path, "demo", "p", state_dict=old)
    logger.log_scalar("train/x", 1.0, step=64)
    logger.end()
    client, runs = _mlflow_runs(
        mlflow_here, f"sqlite:///{tmp_path / 'logs' / 'mlflow.db'}"
    )
    assert list(runs) == [logger.run_id] and logger.video_log_counter == 3
    assert [m.value for m in client.get_metric_history(logger.run_id, "train/x")] == [
        1.0
    ]
