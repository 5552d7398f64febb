"""Videos of a trained policy: episodes rendered by gymnasium, written as GIFs.

A recipe's envs do not render (rendering costs more than a MiniGrid step, and
MuJoCo needs an OpenGL context for it). A video is recorded on a copy of the
evaluation env that does: the same task built with ``render_mode="rgb_array"``
under the same TorchRL transforms as the recipe's env (cloned from an env that
the recipe built, so observations reach the policy exactly as in training and
the policy runs on it unchanged). One env, one episode after the other; after
the reset and after every step the gymnasium env's ``render()`` gives a frame.

* :func:`make_minigrid_video_env`, :func:`make_mujoco_video_env`: that env.
* :func:`record_episodes`: the frames of ``episodes`` episodes of a policy.
* :func:`write_gif`: the frames as a GIF (imageio), written whole or not at all.
* :func:`log_video`: the frames to a TorchRL logger that takes videos.
* :func:`save_video`: all of it for a run's end (``eval.video=true``):
  ``<run dir>/videos/episode_<frames>.gif``; a video that cannot be rendered or
  written is one :class:`VideoUnavailable` message. The recipes' own:
  :func:`record_minigrid_video`, :func:`record_mujoco_video` (with
  :func:`check_mujoco_rendering` at the run's start).

Why not TorchRL's ``VideoRecorder``: it records a pixel entry of the
tensordict, so the env would have to write every frame into its step outputs
(``PixelRenderTransform``), and it writes only through a logger, whose formats
are TensorBoard's, W&B's, MLflow's, or the CSV logger's ``.pt``, memmap and mp4
(the last through torchcodec): no GIF, which would then be written from the
recorder's frame buffer anyway. Here the frames go to a list, the GIF is
written by imageio (through Pillow), and the logger gets the same frames in the
layout ``log_video`` takes.

A GIF stores a frame that repeats the previous one once, with the two durations
summed (Pillow does; MiniGrid's ``pickup`` with nothing in front of the agent
changes nothing): a GIF of an episode of ``T`` steps plays ``T + 1`` frames of
``1 / fps`` seconds, the reset's and one per step, in fewer stored frames.

MuJoCo renders through OpenGL: without a display, ``MUJOCO_GL=egl`` (or
``osmesa``) in the environment before Python starts.
"""

from __future__ import annotations

import os
import warnings
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np
import torch
from torchrl.envs import EnvBase, TransformedEnv

from .errors import UserMistake
from .files import write_atomically, write_failure
from .minigrid import make_env

__all__ = [
    "DEFAULT_FPS",
    "VIDEO_DIR",
    "VideoFrames",
    "VideoUnavailable",
    "check_mujoco_rendering",
    "log_video",
    "make_minigrid_video_env",
    "make_mujoco_video_env",
    "record_episodes",
    "record_minigrid_video",
    "record_mujoco_video",
    "save_video",
    "video_path",
    "write_gif",
]

DEFAULT_FPS = 10
"""Frames per second of a video: one MiniGrid step every 0.1 s."""

VIDEO_DIR = "videos"
"""The folder of a run directory that holds its videos."""


class VideoFrames(NamedTuple):
    """The frames of the episodes :func:`record_episodes` ran, one after the other.

    Attributes:
        frames: ``uint8`` ``[T, H, W, 3]``: for each episode, the frame after its
            reset and one after each of its steps.
        steps: the number of steps of each episode; ``T = sum(steps) +
            len(steps)``.
        returns: the return of each episode (the env's reward, summed).
    """

    frames: np.ndarray
    steps: list[int]
    returns: list[float]


def _render_source(env: EnvBase):
    """The gymnasium env under ``env`` whose ``render()`` gives its frames."""
    import gymnasium as gym

    base = env.base_env if isinstance(env, TransformedEnv) else env
    gym_env = getattr(base, "gym_env", None)
    if gym_env is None:
        raise TypeError(
            "a video is rendered by the gymnasium env under a TorchRL env built by "
            "torchrl_surprise.envs.make_minigrid_env(backend='gymnasium') or "
            f"make_mujoco_env; got a {type(base).__name__}, which cannot render "
            "(envpool's MiniGrid has no renderer). Build the video env with "
            "make_minigrid_video_env or make_mujoco_video_env."
        )
    if isinstance(gym_env, gym.vector.VectorEnv):
        gym_env = gym_env.envs[0]
    if gym_env.render_mode != "rgb_array":
        raise ValueError(
            f"the env renders with render_mode={gym_env.render_mode!r}; a video "
            "needs render_mode='rgb_array' (make_minigrid_video_env and "
            "make_mujoco_video_env build it so)."
        )
    return gym_env


class VideoUnavailable(UserMistake, RuntimeError):
    """A video that could not be recorded: frames that do not render (MuJoCo
    without a display or ``MUJOCO_GL``), a GIF that could not be written."""


def _render(gym_env) -> np.ndarray:
    try:
        with warnings.catch_warnings():
            # GLFW's own warnings of a missing display: the error below says it
            warnings.filterwarnings("ignore", module="glfw")
            frame = gym_env.render()
    except Exception as err:
        # mujoco.FatalError, PyOpenGL's errors, gymnasium's ValueError for a bad
        # MUJOCO_GL: no common type, one cause
        if not hasattr(gym_env.unwrapped, "mujoco_renderer"):
            raise
        raise VideoUnavailable(
            "MuJoCo could not render without a display (MUJOCO_GL="
            f"{os.environ.get('MUJOCO_GL') or '<unset>'}): set MUJOCO_GL=egl (or "
            "MUJOCO_GL=osmesa) in the environment before Python starts, e.g. "
            f"`MUJOCO_GL=egl python ...`. The error was: {err}"
        ) from err
    return np.ascontiguousarray(frame, dtype=np.uint8)


def _maze_box(gym_env, frame: np.ndarray) -> tuple[int, int, int, int] | None:
    """The pixels ``(top, bottom, left, right)`` of a MiniGrid frame that hold
    its maze: the cells with an object (walls, doors, ...) and the agent's; the
    rest of the grid is empty floor (MultiRoom lays 3 small rooms out in a
    25x25 grid). ``None`` for an env without a MiniGrid grid (MuJoCo)."""
    base = gym_env.unwrapped
    grid = getattr(base, "grid", None)
    if grid is None or not hasattr(base, "agent_pos"):
        return None
    cells = [
        (i, j)
        for j in range(grid.height)
        for i in range(grid.width)
        if grid.get(i, j) is not None
    ]
    cells.append(tuple(int(v) for v in base.agent_pos))
    tile = frame.shape[0] // grid.height
    columns, rows = zip(*cells)
    return (
        min(rows) * tile,
        (max(rows) + 1) * tile,
        min(columns) * tile,
        (max(columns) + 1) * tile,
    )


def _union(box, other):
    if box is None or other is None:
        return other if box is None else box
    return (
        min(box[0], other[0]),
        max(box[1], other[1]),
        min(box[2], other[2]),
        max(box[3], other[3]),
    )


def record_episodes(
    env: EnvBase,
    policy,
    episodes: int = 1,
    *,
    deterministic: bool = False,
    max_steps: int = 10_000,
    crop_to_maze: bool = True,
) -> VideoFrames:
    """Runs ``policy`` for ``episodes`` episodes of ``env``, rendering each step.

    Each episode starts with ``env.reset()`` and ends at its first done
    (terminated or truncated: MiniGrid's and MuJoCo's time limits end every
    episode) or after ``max_steps`` steps. The policy acts under
    ``torch.no_grad()`` with TorchRL's deterministic or random exploration type,
    as in the recipes' evaluation. Torch's random generators are restored after
    the episodes, so recording does not change what a run draws next.

    Args:
        env: one TorchRL env (batch size ``[]`` or ``[1]``) whose gymnasium env
            renders ``rgb_array`` frames (:func:`make_minigrid_video_env`,
            :func:`make_mujoco_video_env`).
        policy: a TorchRL policy for ``env``'s observations.
        episodes (int): how many episodes to record; > 0.
        deterministic (bool): ``ExplorationType.DETERMINISTIC`` (else
            ``RANDOM``: the policy is sampled).
        max_steps (int): the most steps of one episode.
        crop_to_maze (bool): on MiniGrid, crop the frames to the part of the
            grid that holds the maze of any of the episodes (MultiRoom's 3 rooms
            fill a few cells of its 25x25 grid); other envs' are not cropped.

    Returns:
        The frames, the steps and the return of each episode.

    Raises:
        ValueError: ``episodes`` or ``max_steps`` < 1, an env of more than one env,
            or one that does not render ``rgb_array`` frames.
        TypeError: an env with no gymnasium env to render (envpool).

    Examples:
        >>> env = make_minigrid_video_env("MiniGrid-Empty-5x5-v0", seed=0, tile_size=8)
        >>> video = record_episodes(env, env.rand_action, max_steps=5)
        >>> video.frames.shape, video.frames.dtype
        ((6, 40, 40, 3), dtype('uint8'))
        >>> video.steps
        [5]
    """
    from torchrl.envs.utils import ExplorationType, set_exploration_type, step_mdp

    if episodes < 1 or max_steps < 1:
        raise ValueError(
            f"episodes and max_steps must be >= 1, got {episodes} and {max_steps}."
        )
    if env.batch_size.numel() != 1:
        raise ValueError(
            f"a video is recorded on one env, got batch size {tuple(env.batch_size)}:"
            " build the env with num_envs=1."
        )
    source = _render_source(env)
    reward_key, done_key = env.reward_key, env.done_keys[0]
    mode = ExplorationType.DETERMINISTIC if deterministic else ExplorationType.RANDOM
    frames, steps, returns, box = [], [], [], None
    with (
        torch.random.fork_rng(devices=[]),
        torch.no_grad(),
        set_exploration_type(mode),
    ):
        for _ in range(episodes):
            td = env.reset()
            frames.append(_render(source))
            if crop_to_maze:
                box = _union(box, _maze_box(source, frames[-1]))
            total, done, count = 0.0, False, 0
            while not done and count < max_steps:
                td = env.step(policy(td))
                frames.append(_render(source))
                total += td["next", reward_key].sum().item()
                done = bool(td["next", done_key].any())
                td = step_mdp(td)
                count += 1
            steps.append(count)
            returns.append(total)
    frames = np.stack(frames)
    if box is not None:
        top, bottom, left, right = box
        frames = np.ascontiguousarray(frames[:, top:bottom, left:right])
    return VideoFrames(frames, steps, returns)


def write_gif(frames, path: str | os.PathLike, fps: int = DEFAULT_FPS) -> Path:
    """Writes ``frames`` as a GIF that loops, ``1 / fps`` seconds a frame.

    Encoded by imageio (its Pillow plugin) in memory, then written beside
    ``path`` and renamed over it: a write that fails (a full disk, no
    permission) leaves no partial GIF and raises
    :class:`~common.files.RunWriteError`, which names the file and the cause.
    GIF stores durations in hundredths of a second: ``fps`` is rounded to the
    nearest duration that GIF can store (10 fps: 0.1 s). A frame equal to the
    one before it is stored once with both durations (Pillow's GIF writer).

    Args:
        frames: ``uint8`` ``[T, H, W, 3]`` (numpy array or tensor), ``T >= 1``.
        path: the GIF's path; its folder is created.
        fps (int): frames per second; > 0.

    Returns:
        ``path``.

    Raises:
        ValueError: frames that are not ``uint8`` ``[T, H, W, 3]``, or ``fps <= 0``.
        RunWriteError: the file could not be written.

    Examples:
        >>> import tempfile
        >>> from PIL import Image
        >>> frames = np.zeros((3, 4, 4, 3), dtype=np.uint8)
        >>> frames[1, 0, 0] = 255
        >>> path = write_gif(frames, Path(tempfile.mkdtemp()) / "a.gif", fps=10)
        >>> Image.open(path).n_frames  # the third repeats none: all stored
        3
    """
    import imageio.v3 as iio

    frames = np.asarray(frames)
    if frames.dtype != np.uint8 or frames.ndim != 4 or frames.shape[-1] != 3:
        raise ValueError(
            "frames must be uint8 [T, H, W, 3] (RGB), got "
            f"{frames.dtype} {list(frames.shape)}."
        )
    if len(frames) == 0:
        raise ValueError("frames is empty: a GIF needs at least one frame.")
    if not fps > 0:
        raise ValueError(f"fps must be > 0, got {fps}.")
    # GIF's unit of time is 10 ms: a duration Pillow would round on writing.
    duration = max(10, round(100 / fps) * 10)
    data = iio.imwrite("<bytes>", frames, extension=".gif", duration=duration, loop=0)
    path = Path(path)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise write_failure(err, path) from err
    write_atomically(path, data)
    return path


def log_video(
    logger,
    frames,
    *,
    step: int,
    fps: int = DEFAULT_FPS,
    name: str = "eval/video",
) -> bool:
    """Hands ``frames`` to a TorchRL logger's ``log_video``, if it takes videos.

    TensorBoard, W&B and MLflow show a video with the run's scalars; TorchRL's
    ``CSVLogger`` would save the raw frames as a tensor file, many times the
    size of the GIF beside it, so it is not given the video. A logger that fails
    on it (TensorBoard without moviepy) leaves a warning: the GIF is the video.

    Args:
        logger: a :class:`~torchrl.record.loggers.Logger`, or ``None``.
        frames: ``uint8`` ``[T, H, W, 3]``.
        step (int): the step to log the video at (the run's frames).
        fps (int): frames per second.
        name (str): the video's name in the logger.

    Returns:
        Whether the logger took the video.

    Examples:
        >>> import tempfile
        >>> from torchrl.record.loggers import CSVLogger
        >>> logger = CSVLogger("demo", log_dir=tempfile.mkdtemp())
        >>> log_video(logger, np.zeros((2, 4, 4, 3), np.uint8), step=0)
        False
    """
    from torchrl.record.loggers import CSVLogger

    if logger is None or isinstance(logger, CSVLogger):
        return False
    # [T, H, W, 3] -> [1, T, 3, H, W], the layout every log_video takes
    video = torch.as_tensor(np.asarray(frames)).permute(0, 3, 1, 2).unsqueeze(0)
    try:
        logger.log_video(name, video, step=step, fps=fps)
    except Exception as err:  # TorchRL's loggers raise a bare Exception for these
        warnings.warn(
            f"{type(logger).__name__} did not take the video ({err}); the GIF "
            "holds it.",
            stacklevel=2,
        )
        return False
    return True


def _with_transforms_of(base: EnvBase, like: EnvBase | None, seed: int) -> EnvBase:
    """``base`` under copies of ``like``'s transforms, seeded with ``seed``."""
    env = base
    if isinstance(like, TransformedEnv):
        env = TransformedEnv(base, like.transform.clone())
    env.set_seed(seed)
    return env


def make_minigrid_video_env(
    env_name: str,
    seed: int,
    *,
    like: EnvBase | None = None,
    tile_size: int = 16,
    env_kwargs: dict[str, Any] | None = None,
) -> EnvBase:
    """One MiniGrid env of ``env_name`` that renders, for :func:`record_episodes`.

    Its base is :func:`~torchrl_surprise.envs.make_minigrid_env`'s gymnasium env
    with ``render_mode="rgb_array"``: minigrid's own frames, the whole grid with
    the agent's view highlighted, ``tile_size`` pixels a cell. Over it, copies of
    the transforms of ``like``, an env the recipe built for the task (its noise,
    its episode statistics), so the policy reads what it reads in training.
    ``like`` may run on either backend: envpool's MiniGrid, which cannot render,
    is the same task with the same observations (tests/test_envpool.py), so a
    policy trained on it is recorded on minigrid's (whose layout for a seed is
    not envpool's).

    Args:
        env_name (str): a MiniGrid id.
        seed (int): the env's seed (the evaluation's, to see its first episode).
        like: an env whose transforms are copied; ``None``: no transforms.
        tile_size (int): pixels per grid cell (MultiRoom's 25x25 grid: 400x400,
            which :func:`record_episodes` crops to the maze).
        env_kwargs: more keyword arguments for ``gymnasium.make``.

    Returns:
        A TorchRL env of batch size ``[1]``.

    Examples:
        >>> env = make_minigrid_video_env("MiniGrid-DoorKey-5x5-v0", seed=0)
        >>> env.batch_size
        torch.Size([1])
        >>> video = record_episodes(env, env.rand_action, max_steps=3)
        >>> video.frames.shape
        (4, 80, 80, 3)
    """
    from torchrl_surprise.envs import make_minigrid_env

    kwargs = {**(env_kwargs or {}), "render_mode": "rgb_array", "tile_size": tile_size}
    base = make_minigrid_env(env_name, num_envs=1, env_kwargs=kwargs)
    return _with_transforms_of(base, like, seed)


def make_mujoco_video_env(
    env_name: str,
    seed: int,
    *,
    like: EnvBase | None = None,
    width: int = 240,
    height: int = 240,
) -> EnvBase:
    """One MuJoCo env of ``env_name`` that renders, for :func:`record_episodes`.

    Gymnasium's env with ``render_mode="rgb_array"`` (``width`` x ``height``
    frames, ~170 MB in memory for a 1,000-step episode at 240x240), wrapped as
    :func:`~torchrl_surprise.envs.make_mujoco_env` wraps it, under copies of the
    transforms of ``like`` (the recipe's env: float32 observations, episode
    statistics), or of ``make_mujoco_env``'s own without ``like``. Rendering
    needs OpenGL: without a display, set ``MUJOCO_GL=egl`` (or ``osmesa``)
    before Python starts; the first frame fails otherwise, naming it.

    Args:
        env_name (str): a gymnasium MuJoCo id, e.g. ``"HalfCheetah-v5"``.
        seed (int): the env's seed.
        like: an env whose transforms are copied (default: ``make_mujoco_env``'s).
        width (int): frame width in pixels.
        height (int): frame height in pixels.

    Returns:
        A TorchRL env of batch size ``[]``.
    """
    from torchrl_surprise.envs import make_mujoco_env
    from torchrl_surprise.envs.vector import SingleGymEnv

    if like is None:
        like = make_mujoco_env(env_name)
        like.close()
    base = SingleGymEnv(env_name, render_mode="rgb_array", width=width, height=height)
    return _with_transforms_of(base, like, seed)


def video_path(run_dir: str | os.PathLike, frames: int) -> Path:
    """Where a run's video of its policy after ``frames`` frames goes.

    Examples:
        >>> video_path("run", 1024).as_posix()
        'run/videos/episode_1024.gif'
    """
    return Path(run_dir) / VIDEO_DIR / f"episode_{frames}.gif"


def save_video(
    env: EnvBase,
    policy,
    run_dir: str | os.PathLike,
    frames: int,
    *,
    episodes: int,
    deterministic: bool,
    logger=None,
    fps: int = DEFAULT_FPS,
) -> Path:
    """A run's video: :func:`record_episodes` on ``env`` (closed after), the GIF
    at :func:`video_path`, the frames to ``logger`` (:func:`log_video`).

    Raises:
        VideoUnavailable: the frames could not be rendered, or the GIF written
            (a full disk, no permission); the message says that the run itself
            is saved and that rerunning its command writes the video.
    """
    path = video_path(run_dir, frames)
    try:
        try:
            video = record_episodes(env, policy, episodes, deterministic=deterministic)
        finally:
            env.close()
        write_gif(video.frames, path, fps)
    except UserMistake as err:
        raise VideoUnavailable(
            f"The run is finished and saved, but not its video ({path}): {err} "
            "Once that is fixed, run the same command again: a finished run "
            "writes the video (and learning curve) it lacks."
        ) from err
    log_video(logger, video.frames, step=frames, fps=fps)
    return path


def record_minigrid_video(
    cfg,
    policy,
    run_dir: str | os.PathLike,
    frames: int,
    *,
    seed: int,
    logger=None,
    fps: int = DEFAULT_FPS,
) -> Path:
    """The MiniGrid recipe's video: ``eval.video_episodes`` episodes of ``policy``.

    Recorded on :func:`make_minigrid_video_env` with the transforms of the
    recipe's env (``common.minigrid.make_env``: ``env.stochasticity``'s noise
    included), sampled or greedy as ``eval.deterministic`` says; written to
    ``<run_dir>/videos/episode_<frames>.gif`` and handed to ``logger``
    (:func:`save_video`) at step ``frames``.

    Args:
        cfg: the recipe's config (``env.*``, ``eval.deterministic``,
            ``eval.video_episodes``).
        policy: the policy operator of the actor-critic.
        run_dir: the run directory.
        frames (int): the training frames the policy had: the GIF's name.
        seed (int): the env's seed (the run's evaluation seed).
        logger: the run's TorchRL logger, or ``None``.
        fps (int): frames per second.

    Returns:
        The GIF's path.
    """
    from omegaconf import OmegaConf

    # The transforms only: the rendering env is minigrid's whatever the backend.
    env_cfg = OmegaConf.to_container(cfg.env, resolve=True)
    like = make_env(OmegaConf.create({**env_cfg, "backend": "gymnasium"}), 1, seed)
    like.close()
    env = make_minigrid_video_env(cfg.env.name, seed, like=like)
    return save_video(
        env,
        policy,
        run_dir,
        frames,
        episodes=cfg.eval.video_episodes,
        deterministic=cfg.eval.deterministic,
        logger=logger,
        fps=fps,
    )


def check_mujoco_rendering(env_name: str) -> None:
    """Renders one frame of ``env_name``, so that a run asked for a video
    (``eval.video=true``) fails at its start, not at its end, where MuJoCo
    cannot render (no display and no ``MUJOCO_GL=egl``).

    Raises:
        VideoUnavailable: MuJoCo cannot render here; the message says what to set.
    """
    env = make_mujoco_video_env(env_name, seed=0, width=16, height=16)
    try:
        env.reset()
        _render(_render_source(env))
    finally:
        env.close()


def record_mujoco_video(
    cfg,
    policy,
    run_dir: str | os.PathLike,
    frames: int,
    *,
    seed: int,
    like: EnvBase,
    logger=None,
) -> Path:
    """The DDPG recipe's video: ``eval.video_episodes`` episodes of its actor.

    Recorded on :func:`make_mujoco_video_env` under the transforms of ``like``
    (an env the recipe built, ``num_envs=1``), the actor without exploration
    noise, as the evaluation runs it; written to
    ``<run_dir>/videos/episode_<frames>.gif`` at MuJoCo's frame rate (the env's
    ``render_fps``: real time) and handed to ``logger`` (:func:`save_video`).

    Args:
        cfg: the recipe's config (``env.name``, ``eval.video_episodes``).
        policy: the actor (deterministic: it adds no noise).
        run_dir: the run directory.
        frames (int): the training frames the policy had: the GIF's name.
        seed (int): the env's seed (the run's evaluation seed).
        like: an env of the recipe whose transforms the video env copies.
        logger: the run's TorchRL logger, or ``None``.

    Returns:
        The GIF's path.
    """
    env = make_mujoco_video_env(cfg.env.name, seed, like=like)
    # real time, up to 50 frames a second: a viewer shows a GIF frame of less
    # than 20 ms for 100 ms
    fps = min(int(_render_source(env).metadata.get("render_fps", DEFAULT_FPS)), 50)
    return save_video(
        env,
        policy,
        run_dir,
        frames,
        episodes=cfg.eval.video_episodes,
        deterministic=True,
        logger=logger,
        fps=fps,
    )
