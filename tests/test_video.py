"""Videos of a policy (recipes/common/video.py): real MiniGrid episodes as GIFs, the
envpool backend, the logger hand-off, MuJoCo where it renders, and the recipe's
``eval.video=true`` end to end."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest
import torch
from hydra import compose, initialize_config_dir
from PIL import Image, ImageSequence
from test_recipe_a2c import run_recipe
from torchrl.envs.utils import step_mdp

from common.minigrid import make_actor_critic, make_env
from common.video import (
    log_video,
    make_minigrid_video_env,
    record_episodes,
    record_minigrid_video,
    write_gif,
)
from torchrl_surprise.envs import make_minigrid_env

RECIPES = Path(__file__).resolve().parents[1] / "recipes"
TASK = "MiniGrid-MultiRoom-N3-S4-v0"  # the recipe's default task: 60-step episodes
SEED = 10_000


def minigrid_config(*overrides: str):
    with initialize_config_dir(config_dir=str(RECIPES / "minigrid"), version_base=None):
        return compose("config", overrides=[f"env.name={TASK}", *overrides])


def random_policy(env):
    """The recipe's actor-critic, randomly initialised: its policy operator."""
    torch.manual_seed(0)
    model, _ = make_actor_critic(env.action_spec, intrinsic_critic=False)
    return model.get_policy_operator()


def read_gif(path: Path) -> tuple[list[np.ndarray], list[int]]:
    """The stored frames of a GIF (RGB) and the duration of each, in ms."""
    frames, durations = [], []
    with Image.open(path) as gif:
        for frame in ImageSequence.Iterator(gif):
            durations.append(frame.info["duration"])
            frames.append(np.asarray(frame.convert("RGB")))
    return frames, durations


def without_repeats(frames: np.ndarray) -> list[np.ndarray]:
    return [frames[0]] + [b for a, b in zip(frames, frames[1:]) if not (a == b).all()]


def test_a_gif_holds_every_frame_of_a_real_minigrid_episode(tmp_path):
    cfg = minigrid_config()
    env = make_minigrid_video_env(TASK, SEED, like=make_env(cfg.env, 1, seed=SEED))
    policy = random_policy(env)
    video = record_episodes(env, policy)
    minigrid = env.base_env.gym_env.envs[0].unwrapped
    # one episode, to its end: minigrid's own step counter says how long it was
    (steps,) = video.steps
    assert steps == minigrid.step_count
    assert steps == minigrid.max_steps or video.returns[0] > 0, "the episode ended"
    # the reset's frame, then one per step: minigrid's render, cropped to the maze
    assert video.frames.shape[0] == steps + 1 and video.frames.shape[-1] == 3
    assert video.frames.dtype == np.uint8

    path = write_gif(video.frames, tmp_path / "videos" / "episode.gif", fps=10)
    stored, durations = read_gif(path)
    # It plays steps + 1 frames of 0.1 s; a frame that repeats the one before it
    # (an action that changes nothing) is stored once with both durations.
    assert sum(durations) == (steps + 1) * 100
    expected = without_repeats(video.frames)
    assert len(stored) == len(expected)
    assert all((a == b).all() for a, b in zip(stored, expected)), "lossless"
    # the agent moves: the episode is more than one picture
    assert len(stored) > 1 and not (stored[0] == stored[-1]).all()
    env.close()


WALL = np.array([100, 100, 100], np.uint8)  # minigrid's grey, a wall's colour


def test_a_multiroom_video_is_its_maze_not_the_whole_grid():
    # MultiRoom-N3S4 lays 3 rooms of at most 4x4 out in a 25x25 grid: the rest is
    # empty floor, which the GIF leaves out
    def record(crop):
        env = make_minigrid_video_env(TASK, SEED, tile_size=8)
        torch.manual_seed(0)
        video = record_episodes(env, env.rand_action, max_steps=3, crop_to_maze=crop)
        env.close()
        return video.frames

    cropped, whole = record(True), record(False)
    assert whole.shape == (4, 25 * 8, 25 * 8, 3)
    height, width = cropped.shape[1:3]
    assert height % 8 == width % 8 == 0 and height * width < whole[0].size / 3 / 4
    # the crop is a part of the whole frame that holds every wall of the maze
    offsets = [
        (r, c)
        for r in range(0, 25 * 8 - height + 1, 8)
        for c in range(0, 25 * 8 - width + 1, 8)
        if (whole[:, r : r + height, c : c + width] == cropped).all()
    ]
    assert len(offsets) == 1
    walls = (whole[0] == WALL).all(-1).sum()
    assert walls > 0 and (cropped[0] == WALL).all(-1).sum() == walls


def test_a_gif_write_that_fails_names_the_file_and_leaves_nothing(
    tmp_path, monkeypatch
):
    import errno

    import common.files
    from common.errors import UserMistake

    frames = np.zeros((2, 8, 8, 3), np.uint8)
    path = tmp_path / "videos" / "episode_64.gif"

    def full_disk(fd):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(common.files.os, "fsync", full_disk)
    with pytest.raises(UserMistake, match="no space left on device") as err:
        write_gif(frames, path)
    assert str(path) in str(err.value) and "No partial file" in str(err.value)
    assert list(path.parent.iterdir()) == []


def test_a_run_whose_video_cannot_be_written_says_it_is_saved_and_how_to_finish(
    tmp_path, monkeypatch
):
    import errno

    import common.files
    from common.video import VideoUnavailable, save_video

    env = make_minigrid_video_env("MiniGrid-Empty-5x5-v0", seed=0, tile_size=8)

    def full_disk(fd):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(common.files.os, "fsync", full_disk)
    with pytest.raises(VideoUnavailable) as err:
        save_video(env, env.rand_action, tmp_path, 64, episodes=1, deterministic=False)
    message = str(err.value)
    assert "The run is finished and saved, but not its video" in message
    assert "no space left on device" in message and "run the same command" in message
    assert list((tmp_path / "videos").iterdir()) == []


def test_the_video_env_gives_the_policy_the_training_envs_observations():
    # with the noisy TV on: the recipe's transforms are the video env's; on
    # minigrid's envs, whose layouts the video env draws (envpool's: the next test)
    cfg = minigrid_config("env.stochasticity=2", "env.backend=gymnasium")
    train = make_env(cfg.env, 1, seed=SEED)
    video_env = make_minigrid_video_env(TASK, SEED, like=train)
    assert video_env.observation_spec == train.observation_spec
    assert [type(t) for t in video_env.transform] == [type(t) for t in train.transform]
    a, b = train.reset(), video_env.reset()
    assert (a["image"] == b["image"]).all() and (a["direction"] == b["direction"]).all()
    for action in torch.randint(7, (20, 1), generator=torch.Generator().manual_seed(0)):
        a = train.step(a.set("action", action))
        b = video_env.step(b.set("action", action.clone()))
        assert (a["next", "image"] == b["next", "image"]).all()
        a, b = step_mdp(a), step_mdp(b)


def test_several_episodes_follow_each_other_and_the_run_draws_the_same(tmp_path):
    env = make_minigrid_video_env("MiniGrid-Empty-5x5-v0", seed=0, tile_size=8)
    policy = random_policy(env)
    torch.manual_seed(1)
    before = torch.random.get_rng_state()
    video = record_episodes(env, policy, episodes=2, max_steps=7)
    assert torch.equal(torch.random.get_rng_state(), before), "torch's RNG untouched"
    assert len(video.steps) == 2 and all(1 <= s <= 7 for s in video.steps)
    assert len(video.frames) == sum(video.steps) + 2
    # the second episode starts from its reset's frame (Empty-5x5's is always
    # the same: the agent in the top-left corner, facing right)
    assert (video.frames[video.steps[0] + 1] == video.frames[0]).all()


def test_envpool_cannot_render_and_the_recipe_records_on_minigrid(tmp_path):
    pytest.importorskip("envpool")
    pool = make_minigrid_env(TASK, num_envs=1, backend="envpool")
    with pytest.raises(TypeError, match="envpool's MiniGrid has no renderer"):
        record_episodes(pool, pool.rand_action)
    pool.close()
    # the recipe's video of a run trained on envpool: the same task on minigrid's
    cfg = minigrid_config("env.backend=envpool", "eval.video_episodes=1")
    env = make_minigrid_env(TASK, num_envs=1)
    path = record_minigrid_video(
        cfg, random_policy(env), tmp_path, frames=1234, seed=SEED
    )
    assert path == tmp_path / "videos" / "episode_1234.gif"
    stored, durations = read_gif(path)
    # the maze of a layout of minigrid's, not its whole 25x25 grid of 16 pixels
    assert stored[0].shape[0] < 400 and stored[0].shape[1] < 400
    assert sum(durations) >= 2 * 100


def test_the_logger_gets_the_frames_when_it_takes_videos(tmp_path):
    from torchrl.record.loggers import CSVLogger

    class VideoLogger:
        def __init__(self):
            self.calls = []

        def log_video(self, name, video, step=None, **kwargs):
            self.calls.append((name, video, step, kwargs))

    frames = np.random.default_rng(0).integers(0, 256, (5, 6, 8, 3), dtype=np.uint8)
    logger = VideoLogger()
    assert log_video(logger, frames, step=512, fps=10)
    ((name, video, step, kwargs),) = logger.calls
    assert (name, step, kwargs) == ("eval/video", 512, {"fps": 10})
    # ((N), T, C, H, W), what TorchRL's loggers take
    assert video.shape == (1, 5, 3, 6, 8) and video.dtype == torch.uint8
    assert torch.equal(video[0].permute(0, 2, 3, 1), torch.as_tensor(frames))
    # CSV would write the raw frames as a tensor file: it is not given the video
    csv = CSVLogger("run", log_dir=str(tmp_path))
    assert not log_video(csv, frames, step=512)
    assert not list(tmp_path.glob("**/videos/*"))

    class NoVideoLogger:
        def log_video(self, name, video, step=None, **kwargs):
            raise Exception("moviepy not found")  # TorchRL's TensorBoard logger's

    with pytest.warns(UserWarning, match="moviepy not found"):
        assert not log_video(NoVideoLogger(), frames, step=0)


def test_bad_input_is_refused_naming_what_is_expected(tmp_path):
    with pytest.raises(ValueError, match=r"uint8 \[T, H, W, 3\]"):
        write_gif(np.zeros((2, 4, 4, 3), np.float32), tmp_path / "a.gif")
    with pytest.raises(ValueError, match=r"uint8 \[T, H, W, 3\]"):
        write_gif(np.zeros((4, 4, 3), np.uint8), tmp_path / "a.gif")
    with pytest.raises(ValueError, match="fps must be > 0"):
        write_gif(np.zeros((2, 4, 4, 3), np.uint8), tmp_path / "a.gif", fps=0)
    two = make_minigrid_env("MiniGrid-Empty-5x5-v0", num_envs=2)
    with pytest.raises(ValueError, match="num_envs=1"):
        record_episodes(two, two.rand_action)
    silent = make_minigrid_env("MiniGrid-Empty-5x5-v0", num_envs=1)
    with pytest.raises(ValueError, match="render_mode='rgb_array'"):
        record_episodes(silent, silent.rand_action)
    with pytest.raises(ValueError, match="episodes and max_steps must be >= 1"):
        record_episodes(silent, silent.rand_action, episodes=0)


# MuJoCo picks its OpenGL backend from MUJOCO_GL when it is imported: each case runs
# in a fresh interpreter with its own environment.
MUJOCO_SCRIPT = textwrap.dedent(
    """
    import sys
    from common.video import make_mujoco_video_env, record_episodes, write_gif
    env = make_mujoco_video_env("HalfCheetah-v5", seed=0, width=64, height=48)
    video = record_episodes(env, env.rand_action, max_steps=5)
    path = write_gif(video.frames, sys.argv[1])
    print(video.steps, video.frames.shape, len(set(f.tobytes() for f in video.frames)))
    """
)


def run_mujoco(gif: Path, **env_vars: str | None) -> subprocess.CompletedProcess:
    pytest.importorskip("mujoco")
    env = dict(os.environ, PYTHONPATH=str(RECIPES))
    for name, value in env_vars.items():
        env.pop(name, None)
        if value is not None:
            env[name] = value
    return subprocess.run(
        [sys.executable, "-c", MUJOCO_SCRIPT, str(gif)],
        capture_output=True,
        text=True,
        env=env,
        timeout=300,
    )


@pytest.mark.slow
def test_a_mujoco_episode_renders_headless_with_egl(tmp_path):
    gif = tmp_path / "cheetah.gif"
    proc = run_mujoco(gif, MUJOCO_GL="egl", DISPLAY=None)
    if proc.returncode != 0:
        if "MUJOCO_GL" in proc.stderr:
            pytest.skip(f"no headless OpenGL (EGL) here: {proc.stderr[-300:]}")
        raise AssertionError(proc.stderr[-3000:])
    # 5 steps: 6 frames, 64x48, the cheetah moves
    assert proc.stdout.split("\n")[0] == "[5] (6, 48, 64, 3) 6"
    stored, durations = read_gif(gif)
    assert stored[0].shape == (48, 64, 3) and sum(durations) == 6 * 100


@pytest.mark.slow
@pytest.mark.skipif(sys.platform != "linux", reason="no display on Linux only")
def test_mujoco_without_a_display_or_mujoco_gl_names_mujoco_gl(tmp_path):
    proc = run_mujoco(
        tmp_path / "x.gif", MUJOCO_GL=None, DISPLAY=None, WAYLAND_DISPLAY=None
    )
    assert proc.returncode != 0
    assert "VideoUnavailable: MuJoCo could not render without a display" in proc.stderr
    assert "set MUJOCO_GL=egl (or MUJOCO_GL=osmesa)" in proc.stderr


@pytest.mark.slow
def test_the_recipe_with_eval_video_prints_the_gifs_path(tmp_path):
    run_dir = tmp_path / "run"
    proc = run_recipe(
        run_dir, "bonus=none", "collector.total_frames=256", "eval.video=true"
    )
    gif = run_dir / "videos" / "episode_256.gif"
    assert f"Video: {gif}" in proc.stdout.splitlines()
    stored, durations = read_gif(gif)
    assert len(stored) > 1 and sum(durations) >= 2 * 100


@pytest.mark.slow
def test_a_finished_run_missing_its_curve_and_video_writes_them_on_rerun(tmp_path):
    run_dir = tmp_path / "run"
    run = ("bonus=none", "collector.total_frames=128", "eval.video=true")
    run_recipe(run_dir, *run)
    gif, curve = run_dir / "videos" / "episode_128.gif", run_dir / "learning_curve.png"
    assert gif.exists() and curve.exists()
    gif.unlink()
    curve.unlink()
    proc = run_recipe(run_dir, *run)
    assert f"writing what its end left missing: {curve}, {gif}" in proc.stdout
    assert f"Video: {gif}" in proc.stdout and gif.exists() and curve.exists()
    assert "Nothing to do: 128 frames" in run_recipe(run_dir, *run).stdout
