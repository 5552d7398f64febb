"""The DDPG MuJoCo recipe, run end to end as a user runs it (tiny budgets), and its
pieces in-process: the replay-buffer bonus equals the env-path bonus."""

from __future__ import annotations

import os
import shlex
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import torch
from _recipe_run import (
    assert_resume_refused,
    differing_logs,
    kill_after_checkpoint,
    load_recipe_utils,
    wait_for_checkpoint,
)
from hydra import compose, initialize_config_dir
from PIL import Image

from common.checkpoint import load_checkpoint
from common.config import validate_ddpg
from common.scalar_logs import read_scalar_csv
from results import aggregate

RECIPE = Path(__file__).resolve().parents[1] / "recipes" / "ddpg_mujoco"
MAIN = RECIPE / "main.py"
FRAMES_PER_BATCH = 200
TINY = [
    "env.num_envs=2",
    f"collector.frames_per_batch={FRAMES_PER_BATCH}",
    "collector.init_random_frames=200",
    "replay_buffer.size=10000",
    "optim.batch_size=32",
    "optim.utd_ratio=0.1",  # 20 updates per batch
    "network.hidden_sizes=[32,32]",
    "intrinsic.vae.hidden_dim=32",
    "intrinsic.batch_size=32",
    "intrinsic.update_every=2",
    "intrinsic.warmup_frames=0",
    "eval.interval_frames=1000",
    "eval.episodes=1",
    "eval.num_envs=1",
    "checkpoint.interval_frames=400",
    "logger.log_interval=1",
]


utils = load_recipe_utils(RECIPE)


def make_cfg(*overrides: str):
    with initialize_config_dir(config_dir=str(RECIPE), version_base=None):
        return compose(config_name="config", overrides=list(overrides))


def recipe_cmd(run_dir: Path, *overrides: str) -> list[str]:
    return [sys.executable, str(MAIN), f"hydra.run.dir={run_dir}", *TINY, *overrides]


_started: list[subprocess.Popen] = []


@pytest.fixture(autouse=True)
def _no_run_left_behind():
    # A test that fails while its runs are going on kills them.
    yield
    while _started:
        proc = _started.pop()
        if proc.poll() is None:
            proc.kill()
            proc.wait()


def start_recipe(run_dir: Path, *overrides: str) -> subprocess.Popen:
    proc = subprocess.Popen(
        recipe_cmd(run_dir, *overrides),
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    _started.append(proc)
    return proc


def finish(proc: subprocess.Popen, check: bool = True) -> subprocess.CompletedProcess:
    """Waits for a started run (runs overlap: start-up is most of a tiny run)."""
    out, err = proc.communicate(timeout=300)
    if check and proc.returncode != 0:
        raise AssertionError(f"recipe failed:\n{out[-3000:]}\n{err[-3000:]}")
    return subprocess.CompletedProcess(proc.args, proc.returncode, out, err)


def run_recipe(run_dir: Path, *overrides: str, check: bool = True):
    return finish(start_recipe(run_dir, *overrides), check=check)


def scalars(run_dir: Path) -> Path:
    return run_dir / "logs" / "ddpg" / "scalars"


def _check_finished_run(run_dir: Path, proc, frames: int, bonus: str) -> None:
    assert f"Done: {frames} frames" in proc.stdout
    assert (run_dir / "learning_curve.png").stat().st_size > 0
    assert (run_dir / "config_resolved.yaml").exists()
    _, fps = read_scalar_csv(scalars(run_dir) / "time" / "fps.csv")
    assert (fps > 0).all()
    for name in ("loss_value", "loss_actor"):
        _, loss = read_scalar_csv(scalars(run_dir) / "train" / f"{name}.csv")
        assert np.isfinite(loss).all()
    steps, ret = read_scalar_csv(scalars(run_dir) / "eval" / "episode_return.csv")
    assert steps[-1] == frames and np.isfinite(ret).all()
    if bonus == "vae":
        for name in ("intrinsic_reward", "intrinsic_reward_normalized"):
            _, raw = read_scalar_csv(scalars(run_dir) / "train" / f"{name}.csv")
            assert np.isfinite(raw).all()
        bonus_logs = {p.stem for p in (scalars(run_dir) / "bonus").iterdir()}
        assert {"loss_reconstruction", "loss_kl"} <= bonus_logs
    ckpt = load_checkpoint(run_dir / "checkpoint.torchrl")
    assert ckpt["frames"] == frames


@pytest.mark.parametrize(
    "bonus, overrides",
    [
        ("vae", []),  # HalfCheetah, the bonus recomputed on every replay sample
        # Hopper's episodes end (resets mid-batch), OU noise carries per-env state.
        ("none", ["env.name=Hopper-v5", "exploration.noise=ou"]),
    ],
    ids=["vae-sample-halfcheetah", "none-ou-hopper"],
)
def test_killed_and_resumed_run_logs_what_the_uninterrupted_run_logs(
    tmp_path, bonus, overrides
):
    run = [
        f"bonus={bonus}",
        *overrides,
        "collector.total_frames=2000",
        # A small buffer wraps after the kill: its write cursor must be restored.
        "replay_buffer.size=1000",
        # Checkpoints (every 2 batches) fall between log lines (batches 1, 3, ...):
        # the per-update scalars not yet logged must be restored.
        "logger.log_interval=2",
    ]
    whole = start_recipe(tmp_path / "whole", *run)
    killed_dir = tmp_path / "killed"
    killed = kill_after_checkpoint(
        recipe_cmd(killed_dir, *run), killed_dir / "checkpoint.torchrl", min_frames=400
    )
    assert 400 <= killed["frames"] < 2000, "the kill must land mid-run"
    _check_finished_run(tmp_path / "whole", finish(whole), 2000, bonus)
    # resume=auto (the default) continues from the checkpoint.
    resumed = run_recipe(killed_dir, *run)
    assert "Done: 2000 frames" in resumed.stdout
    # Every scalar file but time/*, byte for byte: same values, each step once.
    assert differing_logs(tmp_path / "whole", killed_dir) == []
    ckpt = load_checkpoint(killed_dir / "checkpoint.torchrl")
    # Updates start with the batch that reaches init_random_frames (the first).
    assert ckpt["progress"]["updates"] == 2000 // FRAMES_PER_BATCH * 20


def test_sigint_and_sigterm_save_a_checkpoint_and_exit_cleanly(tmp_path):
    signals = (signal.SIGINT, signal.SIGTERM)
    procs = [
        start_recipe(tmp_path / sig.name, "bonus=vae", "collector.total_frames=1000000")
        for sig in signals
    ]
    for sig, proc in zip(signals, procs):
        run_dir = tmp_path / sig.name
        wait_for_checkpoint(run_dir / "checkpoint.torchrl", min_frames=400)
        proc.send_signal(sig)
        out, err = proc.communicate(timeout=60)
        assert proc.returncode == 128 + sig, err[-2000:]
        assert "Traceback" not in err
        assert f"{sig.name}: stopped at" in out and "Resume with: " in out
        frames = load_checkpoint(run_dir / "checkpoint.torchrl")["frames"]
        steps, _ = read_scalar_csv(scalars(run_dir) / "train" / "updates.csv")
        assert steps[-1] == frames, "the checkpoint holds every logged step"
    # The printed command resumes the run (here with a shorter budget).
    command = shlex.split(out.split("Resume with: ")[1].splitlines()[0])
    assert command[0] == "python" and f"hydra.run.dir={run_dir}" in command
    target = f"collector.total_frames={frames + 2 * FRAMES_PER_BATCH}"
    command = [sys.executable] + [
        target if arg.startswith("collector.total_frames=") else arg
        for arg in command[1:]
    ]
    resumed = subprocess.run(command, capture_output=True, text=True, timeout=300)
    assert resumed.returncode == 0, resumed.stderr[-3000:]
    assert f"Done: {frames + 2 * FRAMES_PER_BATCH} frames" in resumed.stdout


def test_resume_refuses_a_changed_experiment(tmp_path):
    run_dir = tmp_path / "run"
    run_recipe(run_dir, "bonus=vae", "collector.total_frames=200")
    config = (run_dir / "config_resolved.yaml").read_text()
    ckpt_mtime = (run_dir / "checkpoint.torchrl").stat().st_mtime_ns
    changes = {
        "env.name=Walker2d-v5": "env.name: 'HalfCheetah-v5' -> 'Walker2d-v5'",
        "bonus=none": "bonus: 'vae' -> 'none'",
    }
    # Both at once (one process): the refusal names each.
    proc = run_recipe(run_dir, *changes, "collector.total_frames=400", check=False)
    assert_resume_refused(proc, *changes.values())
    assert (run_dir / "config_resolved.yaml").read_text() == config
    assert (run_dir / "checkpoint.torchrl").stat().st_mtime_ns == ckpt_mtime


def test_runs_without_a_logger(tmp_path):
    # The bonus stored at collection time, on Hopper: its only end-to-end run here.
    run_dir = tmp_path / "run"
    proc = run_recipe(
        run_dir,
        "logger.backend=",
        "env.name=Hopper-v5",
        "bonus=vae",
        "intrinsic.bonus_at=collection",
        "collector.total_frames=600",
    )
    assert (
        "Done: 600 frames" in proc.stdout
        and "Learning curve: none (logger.backend='' logs no scalars)" in proc.stdout
    )
    assert not (run_dir / "logs").exists()
    ckpt = load_checkpoint(run_dir / "checkpoint.torchrl")
    assert ckpt["frames"] == 600 and len(ckpt["stats"]["returns"]) > 0


@pytest.mark.parametrize(
    "launcher, seeds",
    # submitit_local is tested on the A2C recipe (tests/test_recipe_a2c.py).
    [("local", [0, 1])],
)
def test_sweep_runs_each_job_once_and_a_rerun_starts_no_new_work(
    tmp_path, launcher, seeds
):
    sweep = [
        sys.executable,
        str(MAIN),
        "-m",
        "+experiment=tiny",
        f"hydra/launcher={launcher}",
        f"hydra.sweep.dir={tmp_path}",
        "collector.total_frames=1000",  # tiny's 2 batches (not in the run names)
        "optim.utd_ratio=0.02",  # 10 updates per batch
    ]
    if seeds == [0]:
        sweep.append("seed=0")  # replaces the experiment's seeds
    first = subprocess.run(sweep, capture_output=True, text=True, timeout=600)
    assert first.returncode == 0, first.stderr[-3000:]
    ckpts = sorted(tmp_path.glob("*/checkpoint.torchrl"))
    assert [p.parent.name for p in ckpts] == [
        f"+setting={setting},optim.utd_ratio=0.02,seed={seed}"
        for setting in ("none", "vae")
        for seed in seeds
    ]
    assert all(load_checkpoint(p)["frames"] == 1000 for p in ckpts)
    mtimes = [p.stat().st_mtime_ns for p in ckpts]
    again = subprocess.run(sweep, capture_output=True, text=True, timeout=600)
    assert again.returncode == 0, again.stderr[-3000:]
    assert [p.stat().st_mtime_ns for p in ckpts] == mtimes
    if launcher != "local":
        return
    # The seeds are different runs.
    losses = [
        read_scalar_csv(scalars(ckpt.parent) / "train" / "loss_value.csv")[1]
        for ckpt in ckpts[2:]
    ]
    assert not np.array_equal(*losses)
    # The aggregation command summarises DDPG runs too (what report.py did).
    out = tmp_path / "results"
    assert aggregate.main([str(tmp_path), "--out", str(out), "--reps", "50"]) == 0
    summary = pd.read_csv(out / "summary.csv")
    assert sorted(summary["setting"]) == ["none", "vae"]
    assert (summary["seeds"] == 2).all() and summary["eval_return_iqm"].notna().all()


def test_replay_buffer_bonus_equals_env_bonus():
    torch.manual_seed(0)
    cfg = make_cfg(
        "bonus=vae", "intrinsic.warmup_frames=0", "intrinsic.vae.hidden_dim=32"
    )
    env = utils.make_env(cfg.env, 2, seed=0)
    obs_dim = env.observation_spec[utils.OBS_KEY].shape[-1]
    obs_norm = utils.ObservationNormalizer(obs_dim, clip=cfg.obs_norm.clip)
    warmup = env.rollout(100, break_when_any_done=False).reshape(-1)
    obs_norm.update(warmup["next", utils.OBS_KEY])
    transform, vae_loss = utils.make_bonus(cfg, obs_dim)
    optim = torch.optim.Adam(vae_loss.parameters(), lr=1e-2)
    for _ in range(3):  # weights away from their initialisation
        loss = vae_loss(obs_norm(warmup.clone()))
        optim.zero_grad()
        (loss["loss_reconstruction"] + loss["loss_kl"]).backward()
        optim.step()
    transform(obs_norm(warmup.clone()))  # some history in the bonus statistics
    transform.freeze()  # then both paths normalise the bonus alike

    # Env path: the same normaliser and transform inside the env.
    env.append_transform(obs_norm)
    env.append_transform(transform)
    rollout = env.rollout(50, break_when_any_done=False).reshape(-1)
    assert rollout["next", "intrinsic_reward"].std() > 0

    # Replay path: store what the recipe stores (extrinsic reward, raw observations).
    stored = rollout.select(*utils.replay_keys(transform, "sample"))
    stored["next", "reward"] = rollout["next", "extrinsic_reward"]
    buffer = utils.make_replay_buffer(1000)
    buffer.extend(stored)
    sample = buffer.sample(64)
    sample = transform(obs_norm(sample))
    expected = rollout[sample["index"]]
    for key in (
        "intrinsic_reward",
        "intrinsic_reward_normalized",
        "extrinsic_reward",
        "reward",
    ):
        torch.testing.assert_close(sample["next", key], expected["next", key])

    # The bonus follows the current VAE: one more VAE step changes it.
    before = sample["next", "intrinsic_reward"].clone()
    loss = vae_loss(obs_norm(warmup.clone()))
    optim.zero_grad()
    (loss["loss_reconstruction"] + loss["loss_kl"]).backward()
    optim.step()
    again = transform(obs_norm(sample.clone()))
    assert not torch.allclose(again["next", "intrinsic_reward"], before)
    env.close()


@pytest.mark.parametrize("delay_actor", [False, True])
def test_td_target_takes_its_next_action_from_the_actor_or_a_target_actor(
    delay_actor,
):
    torch.manual_seed(0)
    cfg = make_cfg(f"loss.delay_actor={delay_actor}", "network.hidden_sizes=[32,32]")
    env = utils.make_env(cfg.env, 2, seed=0)
    _, _, _, loss, target_updater = utils.make_ddpg(cfg, env)
    batch = env.rollout(20, break_when_any_done=False).reshape(-1)
    has_target = any("target_actor_network_params" in k for k in loss.state_dict())
    assert has_target == delay_actor  # and so it is checkpointed with the loss

    def critic_loss() -> torch.Tensor:
        with torch.no_grad():
            return loss.loss_value(batch.clone())[0]

    before = critic_loss()
    # The actor's weights (not its action-bound buffers) move; the critic and its
    # target do not.
    actor = loss.actor_network_params.flatten_keys()
    weights = [k for k, p in actor.items() if isinstance(p, torch.nn.Parameter)]
    assert weights
    with torch.no_grad():
        for key in weights:
            actor[key].add_(0.5)
    moved = critic_loss()
    if not delay_actor:
        assert not torch.allclose(moved, before)  # next action from the actor
        env.close()
        return
    torch.testing.assert_close(moved, before)  # from the target actor
    old_target = loss.target_actor_network_params.flatten_keys().clone()
    target_updater.step()  # Polyak: target <- (1 - tau) target + tau actor
    target = loss.target_actor_network_params.flatten_keys()
    tau = cfg.optim.tau
    for key in weights:
        expected = (1 - tau) * old_target[key] + tau * actor[key]
        torch.testing.assert_close(target[key], expected)
    assert not torch.allclose(critic_loss(), before)
    env.close()


def test_unknown_env_id_fails_clearly():
    cfg = make_cfg("env.name=HalfCheetah-v99")
    validate_ddpg(cfg)  # any id is a string: the env factory names it
    with pytest.raises(ValueError, match="HalfCheetah-v99"):
        utils.make_env(cfg.env, 1, seed=0)


def _run_with_env(run_dir: Path, env_vars: dict, *overrides: str):
    env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "MUJOCO_GL")}
    env.update(env_vars)
    return subprocess.run(
        recipe_cmd(run_dir, *overrides),
        capture_output=True,
        text=True,
        env=env,
        timeout=300,
    )


@pytest.mark.slow
@pytest.mark.skipif(sys.platform != "linux", reason="no display on Linux only")
def test_eval_video_records_the_actor_or_is_refused_before_training(tmp_path):
    video = ("env.name=Hopper-v5", "collector.total_frames=400", "eval.video=true")
    # no display, no MUJOCO_GL: one message before anything runs, nothing left
    refused = _run_with_env(tmp_path / "refused", {}, *video)
    assert refused.returncode == 2, refused.stderr[-3000:]
    assert refused.stderr.strip().splitlines() == [
        line
        for line in refused.stderr.strip().splitlines()
        if line.startswith("Error:")
    ]
    assert "set MUJOCO_GL=egl" in refused.stderr and "Traceback" not in refused.stderr
    assert not (tmp_path / "refused").exists()
    run_dir = tmp_path / "egl"
    proc = _run_with_env(run_dir, {"MUJOCO_GL": "egl"}, *video)
    if proc.returncode == 2 and "MUJOCO_GL" in proc.stderr:
        pytest.skip(f"no headless OpenGL (EGL) here: {proc.stderr[-300:]}")
    gif = run_dir / "videos" / "episode_400.gif"
    assert proc.returncode == 0 and f"Video: {gif}" in proc.stdout, proc.stderr
    with Image.open(gif) as image:
        # a Hopper episode: at least a few steps before it falls, 240x240
        assert image.n_frames > 5 and image.size == (240, 240)
