"""The MiniGrid recipes with ``collector.workers=2`` (TorchRL's MultiSyncCollector),
run as a user runs them (tiny budgets), and the workers' config checks."""

from __future__ import annotations

import functools
import os
import signal
import socket
import subprocess
import sys
from pathlib import Path

import pytest
import torch
from _recipe_run import (
    differing_logs,
    kill_after_checkpoint,
    shared_run,
    wait_for_checkpoint,
)
from hydra import compose, initialize_config_dir
from omegaconf import OmegaConf

from common.checkpoint import load_checkpoint
from common.config import validate_minigrid
from common.minigrid import (
    make_actor_critic,
    make_collector,
    make_env,
)
from common.scalar_logs import read_scalar_csv
from torchrl_surprise.collectors import ResumableCollector

RECIPES = Path(__file__).resolve().parents[1] / "recipes"
A2C = RECIPES / "minigrid"
# 2 workers x 2 envs x 8 steps = 32 frames per update.
TINY = [
    "env.name=MiniGrid-MultiRoom-N3-S4-v0",
    "env.num_envs=4",
    "collector.frames_per_env=8",
    "eval.interval_frames=256",
    "eval.episodes=4",
    "eval.num_envs=2",
    "checkpoint.interval_frames=128",
    "logger.log_interval=1",
]
RUN = ["bonus=vae", "collector.workers=2", "collector.total_frames=1024", "seed=3"]


def run_recipe(recipe: Path, run_dir: Path, *overrides: str, check: bool = True):
    cmd = [sys.executable, str(recipe / "main.py"), f"hydra.run.dir={run_dir}"]
    proc = subprocess.run(
        [*cmd, *TINY, *overrides], capture_output=True, text=True, timeout=300
    )
    if check and proc.returncode != 0:
        raise AssertionError(
            f"recipe failed:\n{proc.stdout[-3000:]}\n{proc.stderr[-3000:]}"
        )
    return proc


@pytest.fixture(scope="module")
def a2c_run(tmp_path_factory) -> Path:
    """One uninterrupted A2C run with two workers: the reference of the tests."""
    make = lambda run_dir: run_recipe(A2C, run_dir, *RUN)  # noqa: E731
    return shared_run(tmp_path_factory, "workers_a2c", make).path


def test_a2c_with_two_workers_learns_from_every_batch(a2c_run):
    scalars = a2c_run / "logs" / "a2c" / "scalars"
    # Each update gets one batch of 32 frames, 16 from each worker.
    steps, grad_norm = read_scalar_csv(scalars / "train" / "grad_norm.csv")
    assert list(steps) == list(range(32, 1025, 32))
    assert torch.isfinite(torch.as_tensor(grad_norm)).all() and (grad_norm > 0).all()
    _, raw = read_scalar_csv(scalars / "train" / "intrinsic_reward.csv")
    assert (raw > 0).all(), "the VAE bonus of every batch"
    _, episodes = read_scalar_csv(scalars / "train" / "episodes.csv")
    assert episodes[-1] > 0
    steps, _ = read_scalar_csv(scalars / "eval" / "episode_return.csv")
    assert list(steps) == [256, 512, 768, 1024]
    ckpt = load_checkpoint(a2c_run / "checkpoint.torchrl")
    assert ckpt["frames"] == 1024 and ckpt["collector"]["frames"] == 1024
    assert {"worker0", "worker1"} <= set(ckpt["collector"])


def test_same_seed_and_workers_give_the_same_logs(tmp_path, a2c_run):
    run_recipe(A2C, tmp_path / "again", *RUN)
    assert differing_logs(a2c_run, tmp_path / "again") == []


def test_killed_and_resumed_run_with_workers_logs_what_the_uninterrupted_run_logs(
    tmp_path, a2c_run
):
    killed_dir = tmp_path / "killed"
    cmd = [sys.executable, str(A2C / "main.py"), f"hydra.run.dir={killed_dir}"]
    killed = kill_after_checkpoint(
        [*cmd, *TINY, *RUN], killed_dir / "checkpoint.torchrl", min_frames=256
    )
    assert 256 <= killed["frames"] < 1024, "the kill must land mid-run"
    run_recipe(A2C, killed_dir, *RUN)
    assert differing_logs(a2c_run, killed_dir) == []
    # Another number of workers is another experiment: refused, not half-loaded.
    proc = run_recipe(
        A2C, killed_dir, *RUN, "collector.workers=1", "resume=true", check=False
    )
    assert proc.returncode != 0
    assert "collector.workers: 2 -> 1" in proc.stderr


def test_sigusr2_to_the_whole_job_saves_the_workers_state_and_resumes(tmp_path):
    # SLURM signals every process of the job step: the workers as well as the
    # main process, which must still reach them to save the collector's state.
    run_dir = tmp_path / "run"
    cmd = [sys.executable, str(A2C / "main.py"), f"hydra.run.dir={run_dir}"]
    workers = ["bonus=none", "collector.workers=2"]
    proc = subprocess.Popen(
        [*cmd, *TINY, *workers, "collector.total_frames=1000000"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        start_new_session=True,
    )
    try:
        wait_for_checkpoint(run_dir / "checkpoint.torchrl", min_frames=128)
        os.killpg(proc.pid, signal.SIGUSR2)
        out, err = proc.communicate(timeout=120)
    finally:
        proc.kill()
    assert proc.returncode == 128 + signal.SIGUSR2, err[-3000:]
    assert "SIGUSR2: stopped at" in out, out[-2000:]
    frames = load_checkpoint(run_dir / "checkpoint.torchrl")["frames"]
    proc = run_recipe(A2C, run_dir, *workers, f"collector.total_frames={frames + 32}")
    assert f"Done: {frames + 32} frames" in proc.stdout


def test_ppo_with_two_workers(tmp_path):
    run_dir = tmp_path / "ppo"
    overrides = ["collector.frames_per_env=32", "loss.minibatch_size=64"]
    run_recipe(
        RECIPES / "minigrid",
        run_dir,
        "algo=ppo",
        *overrides,
        "loss.epochs=2",
        "bonus=vae",
        "collector.workers=2",
        "collector.total_frames=256",
    )
    scalars = run_dir / "logs" / "ppo" / "scalars"
    steps, kl = read_scalar_csv(scalars / "train" / "kl_approx.csv")
    assert list(steps) == [128, 256] and torch.isfinite(torch.as_tensor(kl)).all()
    assert load_checkpoint(run_dir / "checkpoint.torchrl")["frames"] == 256


def _config(*overrides: str):
    with initialize_config_dir(config_dir=str(A2C), version_base=None):
        return compose(config_name="config", overrides=[*TINY, *overrides])


@pytest.mark.parametrize(
    "overrides, message",
    [
        (["collector.workers=3"], r"env.num_envs \(4\) must be a multiple of"),
        (["collector.workers=0"], "collector.workers must be an integer > 0, got 0"),
        (
            ["collector.workers=2", "bonus=rnd"],
            "Run bonus=rnd with collector.workers=1",
        ),
    ],
    ids=["divisor", "zero", "rnd"],
)
def test_bad_workers_are_refused_before_anything_runs(overrides, message):
    with pytest.raises(ValueError, match=message):
        validate_minigrid(_config(*overrides))


def test_a_config_without_workers_collects_in_one_process():
    # Runs started from a config written before collector.workers existed (an
    # untyped copy: the schema has the key).
    cfg = OmegaConf.create(OmegaConf.to_container(_config()))
    del cfg.collector.workers
    env = make_env(cfg.env, cfg.env.num_envs, seed=0)
    model, _ = make_actor_critic(env.action_spec, intrinsic_critic=False)
    collector = make_collector(env, model.get_policy_operator(), cfg, total_frames=64)
    assert type(collector) is ResumableCollector
    collector.shutdown()


def test_every_batch_is_collected_with_the_weights_of_the_last_update():
    # Algorithm 1's order: the update between two batches is what the workers'
    # policy samples the next batch with.
    cfg = _config("collector.workers=2")
    env = make_env(cfg.env, cfg.env.num_envs, seed=0)
    model, _ = make_actor_critic(env.action_spec, intrinsic_critic=False)
    policy = model.get_policy_operator()
    collector = make_collector(env, policy, cfg, total_frames=32 * 4)
    try:
        for i, batch in enumerate(collector):
            assert batch.shape == (4, 8)
            if i == 0:
                assert batch["action"].unique().numel() > 1
            else:
                assert (batch["action"] == 2).all()
            with torch.no_grad():  # the "update": always action 2 from now on
                last = list(policy.parameters())[-1]
                last.zero_()
                last[2] = 100.0
    finally:
        collector.shutdown()


def _free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("", 0))
        return sock.getsockname()[1]


def test_torchrl_distributed_collector_runs_here_in_algorithm_1_order():
    # The configuration docs/recipes.rst gives for more than one machine, on local
    # processes (launcher="mp"): synchronous, the weights sent before each batch.
    from torchrl.collectors.distributed import DistributedCollector

    cfg = _config()
    env = make_env(cfg.env, 2, seed=0)
    model, _ = make_actor_critic(env.action_spec, intrinsic_critic=False)
    policy = model.get_policy_operator()
    nodes, envs_per_node = 2, 2
    collector = DistributedCollector(
        [
            functools.partial(make_env, cfg.env, envs_per_node, seed=i * envs_per_node)
            for i in range(nodes)
        ],
        policy,
        frames_per_batch=nodes * envs_per_node * 8,
        total_frames=nodes * envs_per_node * 8 * 3,
        sync=True,
        update_after_each_batch=True,
        launcher="mp",
        tcp_port=_free_port(),
        collector_kwargs={"auto_register_policy_transforms": False},
    )
    try:
        for i, batch in enumerate(collector):
            assert batch.shape == (nodes, envs_per_node, 8)
            actions = batch["action"]
            assert (actions == 2).all() if i else actions.unique().numel() > 1
            with torch.no_grad():  # the "update": always action 2 from now on
                last = list(policy.parameters())[-1]
                last.zero_()
                last[2] = 100.0
    finally:
        collector.shutdown()


def test_a_worker_that_dies_is_named_with_how_it_ended_and_what_to_do():
    from torchrl.envs.utils import RandomPolicy

    from torchrl_surprise.collectors import (
        CollectorWorkerDied,
        ResumableMultiSyncCollector,
    )
    from torchrl_surprise.envs import make_minigrid_env

    task = "MiniGrid-Empty-5x5-v0"
    factories = [
        functools.partial(make_minigrid_env, task, num_envs=1, seed=w) for w in range(2)
    ]
    spec = make_minigrid_env(task, num_envs=1).action_spec
    collector = ResumableMultiSyncCollector(
        factories, RandomPolicy(spec), frames_per_batch=4, total_frames=64, seed=0
    )
    try:
        batches = iter(collector)
        next(batches)
        worker = collector.procs[1]
        os.kill(worker.pid, signal.SIGKILL)  # as the out-of-memory killer does
        worker.join()
        with pytest.raises(CollectorWorkerDied) as err:
            next(batches)
    finally:
        collector.shutdown(raise_on_error=False)
    assert (err.value.worker, err.value.pid, err.value.exitcode) == (
        1,
        worker.pid,
        -signal.SIGKILL,
    )
    message = str(err.value)
    assert f"collector worker 1 (process {worker.pid}) died" in message
    assert (
        "killed by SIGKILL" in message and "resumes from its last checkpoint" in message
    )


def test_a_recipe_whose_worker_died_ends_with_one_line_and_the_resume_command(
    capsys,
):
    from common.errors import report_mistakes
    from torchrl_surprise.collectors import CollectorWorkerDied

    @report_mistakes
    def main():
        raise CollectorWorkerDied(0, 4242, 3)

    with pytest.raises(SystemExit) as exit:
        main()
    assert exit.value.code == 1
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert line.startswith("Error: collector worker 0 (process 4242) died")
    assert "exited with code 3" in line
