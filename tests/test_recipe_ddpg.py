"""The DDPG MuJoCo recipe, run end to end as a user runs it (tiny budgets), and its
pieces in-process: the replay-buffer bonus equals the env-path bonus."""

from __future__ import annotations

import importlib.util
import subprocess
import sys
from pathlib import Path

import pytest
import torch
from _recipe_run import kill_after_checkpoint
from hydra import compose, initialize_config_dir
from tensordict import TensorDict

from torchrl_surprise.experiments import load_checkpoint, read_scalar_csv

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
    "eval.interval_frames=400",
    "eval.episodes=1",
    "eval.num_envs=1",
    "checkpoint.interval_frames=200",
    "logger.log_interval=1",
]


def _load_utils():
    # Loaded under its own name: the A2C recipe has a utils.py too.
    spec = importlib.util.spec_from_file_location(
        "ddpg_mujoco_utils", RECIPE / "utils.py"
    )
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


utils = _load_utils()


def make_cfg(*overrides: str):
    with initialize_config_dir(config_dir=str(RECIPE), version_base=None):
        return compose(config_name="config", overrides=list(overrides))


def run_recipe(run_dir: Path, *overrides: str, check: bool = True):
    cmd = [sys.executable, str(MAIN), f"hydra.run.dir={run_dir}", *TINY, *overrides]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
    if check and proc.returncode != 0:
        raise AssertionError(
            f"recipe failed:\n{proc.stdout[-3000:]}\n{proc.stderr[-3000:]}"
        )
    return proc


def scalars(run_dir: Path) -> Path:
    return run_dir / "logs" / "ddpg" / "scalars"


VAE_RUN = ["bonus=vae", "collector.total_frames=600", "seed=3"]


@pytest.fixture(scope="module")
def vae_run(tmp_path_factory):
    run_dir = tmp_path_factory.mktemp("ddpg") / "vae"
    proc = run_recipe(run_dir, *VAE_RUN)
    return run_dir, proc


def _check_run(run_dir: Path, proc, frames: int, bonus: str) -> None:
    assert "Learning curve:" in proc.stdout
    assert (run_dir / "learning_curve.png").stat().st_size > 0
    assert (run_dir / "config_resolved.yaml").exists()
    steps, fps = read_scalar_csv(scalars(run_dir) / "time" / "fps.csv")
    assert steps[-1] == frames and (fps > 0).all()
    _, ups = read_scalar_csv(scalars(run_dir) / "time" / "updates_per_s.csv")
    assert ups[-1] > 0
    for name in ("loss_value", "loss_actor"):
        _, loss = read_scalar_csv(scalars(run_dir) / "train" / f"{name}.csv")
        assert torch.isfinite(torch.as_tensor(loss)).all()
    _, ret = read_scalar_csv(scalars(run_dir) / "eval" / "episode_return.csv")
    assert torch.isfinite(torch.as_tensor(ret)).all()
    if bonus == "vae":
        for name in ("intrinsic_reward", "intrinsic_reward_normalized"):
            _, raw = read_scalar_csv(scalars(run_dir) / "train" / f"{name}.csv")
            assert torch.isfinite(torch.as_tensor(raw)).all()
        bonus_logs = {p.stem for p in (scalars(run_dir) / "bonus").iterdir()}
        assert {"loss_reconstruction", "loss_kl"} <= bonus_logs
    ckpt = load_checkpoint(run_dir / "checkpoint.pt")
    assert ckpt["frames"] == frames
    # No frame lost or stored twice: the buffer holds every collected transition.
    assert ckpt["replay_buffer"]["size"] == frames


def test_vae_runs_end_to_end_on_halfcheetah(vae_run):
    _check_run(*vae_run, frames=600, bonus="vae")


@pytest.mark.parametrize(
    "env_name, bonus, extra",
    [
        ("HalfCheetah-v5", "none", []),
        ("Hopper-v5", "vae", ["intrinsic.bonus_at=collection"]),
    ],
)
def test_recipe_runs_end_to_end(tmp_path, env_name, bonus, extra):
    run_dir = tmp_path / bonus
    args = [f"env.name={env_name}", f"bonus={bonus}", "collector.total_frames=600"]
    proc = run_recipe(run_dir, *args, *extra)
    _check_run(run_dir, proc, frames=600, bonus=bonus)
    if env_name == "Hopper-v5":  # random Hopper episodes end within 600 frames
        _, ret = read_scalar_csv(scalars(run_dir) / "train" / "episode_return.csv")
        assert torch.isfinite(torch.as_tensor(ret[-1]))


def test_same_seed_same_losses(tmp_path, vae_run):
    run_recipe(tmp_path / "b", *VAE_RUN)
    run_recipe(tmp_path / "c", *VAE_RUN[:-1], "seed=4")
    losses = {}
    for name, run_dir in (
        ("a", vae_run[0]),
        ("b", tmp_path / "b"),
        ("c", tmp_path / "c"),
    ):
        path = scalars(run_dir) / "train" / "loss_value.csv"
        losses[name] = read_scalar_csv(path)[1]
    assert (losses["a"] == losses["b"]).all()
    assert not (losses["a"] == losses["c"]).all()


def test_resume_after_kill_continues_the_frame_count(tmp_path):
    run_dir = tmp_path / "run"
    cmd = [
        sys.executable,
        str(MAIN),
        f"hydra.run.dir={run_dir}",
        *TINY,
        "bonus=vae",
        "collector.total_frames=1000000",
    ]
    ckpt_path = run_dir / "checkpoint.pt"
    killed = kill_after_checkpoint(cmd, ckpt_path, min_frames=400)
    killed_at = killed["frames"]
    assert killed_at >= 400
    target = killed_at + 2 * FRAMES_PER_BATCH
    out = run_recipe(
        run_dir, "bonus=vae", "resume=true", f"collector.total_frames={target}"
    )
    ckpt = load_checkpoint(ckpt_path)
    assert ckpt["frames"] == target
    assert ckpt["replay_buffer"]["size"] == target
    assert ckpt["updates"] == killed["updates"] + 2 * 20
    assert f"Done: {target} frames" in out.stdout
    steps, _ = read_scalar_csv(scalars(run_dir) / "time" / "fps.csv")
    assert steps[-1] == target


def test_replay_buffer_bonus_equals_env_bonus():
    torch.manual_seed(0)
    cfg = make_cfg(
        "bonus=vae", "intrinsic.warmup_frames=0", "intrinsic.vae.hidden_dim=32"
    )
    env = utils.make_env(cfg, 2, seed=0)
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


def test_replay_buffer_state_round_trip():
    buffer = utils.make_replay_buffer(8)
    data = {"observation": torch.arange(10.0)[:, None]}
    buffer.extend(TensorDict(data, [10]))  # wraps: slots 0-1 overwritten
    state = utils.replay_buffer_state(buffer)
    assert state["size"] == 8
    other = utils.make_replay_buffer(8)
    utils.load_replay_buffer_state(other, state)
    assert len(other) == 8 and other._writer._cursor == buffer._writer._cursor
    other.extend(TensorDict({"observation": torch.tensor([[10.0]])}, [1]))
    assert other.storage.get(torch.tensor([2]))["observation"].item() == 10.0


@pytest.mark.parametrize(
    "override, message",
    [
        ("bonus=banana", "bonus must be one of"),
        ("intrinsic.bonus_at=never", "intrinsic.bonus_at must be one of"),
        ("intrinsic.normalization=median", "intrinsic.normalization must be one of"),
        ("intrinsic.normalization=return_std", "return_std needs whole trajectories"),
        ("exploration.noise=pink", "exploration.noise must be one of"),
        ("collector.total_frames=-5", "collector.total_frames must be a positive"),
        ("collector.total_frames=1500", "must be a multiple of"),
        ("optim.batch_size=0", "optim.batch_size must be a positive"),
        ("env.num_envs=3", "must be a multiple of env.num_envs"),
    ],
)
def test_bad_config_fails_clearly(override, message):
    with pytest.raises(ValueError, match=message):
        utils.check_config(make_cfg(override))


def test_unknown_env_id_fails_clearly():
    cfg = make_cfg("env.name=HalfCheetah-v99")
    utils.check_config(cfg)
    with pytest.raises(ValueError, match="HalfCheetah-v99"):
        utils.make_env(cfg, 1, seed=0)


def test_resume_without_checkpoint_fails_clearly_from_the_command_line(tmp_path):
    proc = run_recipe(tmp_path / "bad", "resume=true", check=False)
    assert proc.returncode != 0
    assert "no checkpoint" in proc.stdout + proc.stderr
