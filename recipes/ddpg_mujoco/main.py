"""DDPG with a surprise bonus on MuJoCo (the paper's Figure 3), in TorchRL.

For every collected batch of ``frames_per_batch`` transitions, in this order:

1. the collector steps ``num_envs`` envs with the actor plus exploration noise
   (uniform random actions for the first ``init_random_frames`` frames); the
   running observation statistics are updated with the batch's observations;
2. with ``intrinsic.bonus_at=collection`` the bonus of the batch is computed now
   (normalised observations, current VAE) and stored with it; the transitions go
   into a uniform replay buffer;
3. once ``init_random_frames`` frames are collected, ``utd_ratio * frames_per_batch``
   updates, each on a fresh minibatch:

   a. with ``intrinsic.bonus_at=sample`` (default) the minibatch's observations are
      normalised with the current statistics and its bonus is recomputed with the
      current VAE: ``r = r_ext + coef * normalize(KL(q(z|s') || N(0, I)))``, so the
      bonus of an old transition is never stale;
   b. one critic step (TorchRL's DDPGLoss, TD(0) target with the target critic,
      and the target actor with ``loss.delay_actor=true``), one actor step, then a
      Polyak update of the target networks (SoftUpdate);
   c. every ``intrinsic.update_every`` updates, one VAE step (VAELoss) on its own
      replay sample of normalised next observations.

Evaluation runs the actor without noise on the extrinsic reward only.

Run: ``python recipes/ddpg_mujoco/main.py bonus=vae env.name=HalfCheetah-v5``
Sweep: ``python recipes/ddpg_mujoco/main.py -m +experiment=figure3`` (rerun it to
resume: finished runs are skipped, killed ones continue).
Resume a killed run: ``... hydra.run.dir=<its run dir>`` (``resume=auto``, the
default, continues from the checkpoint; the resumed run logs exactly what the
uninterrupted run would have). Ctrl-C or SIGTERM saves a checkpoint and exits.
"""

from __future__ import annotations

import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any

# recipes/ holds what the recipes share (common) and the results tools (results).
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import hydra
import torch
import utils  # the builders beside this script
from utils import (
    OBS_KEY,
    ObservationNormalizer,
    ScalarMeans,
    make_bonus,
    make_collector,
    make_ddpg,
    make_env,
    make_replay_buffer,
    replay_keys,
)

from common.checkpoint import RunCounters
from common.config import validate_ddpg
from common.errors import report_mistakes
from common.evaluation import EVAL_SEED_OFFSET, EpisodeStats, evaluate
from common.run import TrainingRun
from common.stopping import register_sweep_pickling, sweep_requested
from common.video import check_mujoco_rendering, record_mujoco_video, video_path


@dataclass
class Training:
    """What a run is built of (:func:`build`) and what its loop (:func:`train`) uses."""

    eval_env: Any
    eval_seed: int
    actor: Any
    loss_module: Any
    target_updater: Any
    actor_optim: Any
    critic_optim: Any
    obs_norm: ObservationNormalizer
    bonus_transform: Any
    vae_loss: Any
    vae_optim: Any
    buffer: Any
    stored_keys: list
    stats: EpisodeStats
    pending: ScalarMeans
    progress: RunCounters
    collector: Any


@hydra.main(config_path=".", config_name="config", version_base=None)
@report_mistakes
def main(cfg) -> None:
    """The run, in the steps the module's docstring numbers: checks, build, the
    loop of batches and updates, the end (checkpoint, curve)."""
    validate_ddpg(cfg)
    # Seeds, resume checks, the checkpoint to resume from (common/rundir.py)
    run = TrainingRun(cfg, "ddpg")
    # a finished run writes the video (or curve) its end left missing
    video = [video_path(run.run_dir, run.done_frames)] if cfg.eval.video else []
    if run.nothing_to_do(outputs=video):
        return
    with run.starting():  # a mistake before the run starts leaves nothing behind
        if cfg.eval.video:
            # MuJoCo renders with OpenGL: refused now, not after the training
            check_mujoco_rendering(cfg.env.name)
        training = build(cfg, run)
    frames, updates, fps, ups = train(cfg, run, training)
    finish(cfg, run, training, frames, updates, fps, ups)


def finish(cfg, run: TrainingRun, t: Training, frames, updates, fps, ups) -> None:
    """The final checkpoint and learning curve, then the video."""
    stats = t.stats
    run.finish(
        f"{frames} frames, {updates} updates, {stats.episodes} episodes, last "
        f"{cfg.logger.episode_window}-episode mean return {stats.mean_return:.1f}, "
        f"{fps:.0f} frames/s, {ups:.0f} updates/s.",
        curves={
            "train/episode_return": "train (with noise)",
            "eval/episode_return": "eval (deterministic)",
        },
        title=f"{cfg.env.name}: DDPG + {cfg.bonus} (seed {cfg.seed})",
        ylabel="extrinsic episode return",
    )
    if cfg.eval.video:
        # The final actor, without noise, on the evaluation's first episodes, as
        # a GIF (and to a logger that shows videos)
        like = make_env(cfg.env, 1, seed=t.eval_seed)
        like.close()
        video = record_mujoco_video(
            cfg,
            t.actor,
            run.run_dir,
            frames,
            seed=t.eval_seed,
            like=like,
            logger=run.logger,
        )
        print(f"Video: {video}")


def build(cfg, run: TrainingRun) -> Training:
    """Envs, actor and critic, the bonus, the replay buffer and the collector, in
    the order they draw random numbers; then the checkpoint restored."""
    # Create envs, seeded with cfg.seed whatever the checkpoint: a resumed run
    # restores the episodes in progress from the collector's state instead.
    env = make_env(cfg.env, cfg.env.num_envs, seed=cfg.seed)
    eval_seed = cfg.seed + EVAL_SEED_OFFSET
    eval_env = make_env(cfg.env, cfg.eval.num_envs, seed=eval_seed)
    obs_dim = env.observation_spec[OBS_KEY].shape[-1]

    # Create the actor, critic and loss
    actor, policy, noise, loss_module, target_updater = make_ddpg(cfg, env)
    actor_optim = torch.optim.Adam(
        loss_module.actor_network_params.flatten_keys().values(),
        lr=cfg.optim.actor_lr,
        fused=True,  # the same Adam update in one kernel per parameter group
    )
    critic_optim = torch.optim.Adam(
        loss_module.value_network_params.flatten_keys().values(),
        lr=cfg.optim.critic_lr,
        fused=True,
    )
    obs_norm = ObservationNormalizer(obs_dim, clip=cfg.obs_norm.clip)

    # Create the bonus and the replay buffer
    bonus_transform, vae_loss = make_bonus(cfg, obs_dim)
    vae_optim = None
    if vae_loss is not None:
        vae_optim = torch.optim.Adam(
            vae_loss.parameters(), lr=cfg.intrinsic.lr, fused=True
        )
    t = Training(
        eval_env=eval_env,
        eval_seed=eval_seed,
        actor=actor,
        loss_module=loss_module,
        target_updater=target_updater,
        actor_optim=actor_optim,
        critic_optim=critic_optim,
        obs_norm=obs_norm,
        bonus_transform=bonus_transform,
        vae_loss=vae_loss,
        vae_optim=vae_optim,
        buffer=make_replay_buffer(cfg.replay_buffer.size),
        stored_keys=replay_keys(bonus_transform, cfg.intrinsic.bonus_at),
        stats=EpisodeStats(window=cfg.logger.episode_window),
        # Per-update scalars not yet logged (means over the updates between logs).
        pending=ScalarMeans(),
        progress=RunCounters(
            frames=0,
            updates=0,
            next_eval=cfg.eval.interval_frames,
            next_ckpt=cfg.checkpoint.interval_frames,
        ),
        # Create the collector: it holds the episodes in progress; it runs to
        # total_frames (and acts at random up to init_random_frames) from its own
        # saved frame count, so it is built for the whole run.
        collector=make_collector(env, policy, cfg),
    )
    # What a checkpoint holds, saved and loaded from this one mapping (with the
    # random generators, restored last); restored when resuming.
    run.restore(
        {
            "progress": t.progress,
            # actor, critic and the target networks
            "loss_module": loss_module,
            "target_updater": target_updater,
            "noise": noise,
            "actor_optim": actor_optim,
            "critic_optim": critic_optim,
            "obs_norm": obs_norm,
            # the VAE, the bonus statistics and the schedule's frame counter
            "bonus_transform": bonus_transform,
            "vae_optim": vae_optim,
            # TorchRL's state: storage, write cursor, sampler
            "replay_buffer": t.buffer,
            "collector": t.collector,
            "stats": t.stats,
            "pending_logs": t.pending,
        },
        on_exit=[t.collector.shutdown],
    )
    return t


def add_bonus_scalars(t: Training, next_td) -> None:
    """The raw bonus, and the normalised one that is mixed into the reward."""
    transform = t.bonus_transform
    t.pending.add("train/intrinsic_reward", next_td[transform.intrinsic_reward_key])
    if transform.normalized_reward_key is not None:
        t.pending.add(
            "train/intrinsic_reward_normalized",
            next_td[transform.normalized_reward_key],
        )


def train(cfg, run: TrainingRun, t: Training) -> tuple[int, int, float, float]:
    """Steps 1-3 for every batch; returns frames, updates, frames/s, updates/s."""
    frames, updates = t.progress.frames, t.progress.updates
    start_updates = updates
    fps = ups = 0.0
    at_collection = t.bonus_transform is not None and (
        cfg.intrinsic.bonus_at == "collection"
    )
    for data in t.collector:
        frames += data.numel()
        iteration = frames // cfg.collector.frames_per_batch - 1
        t.stats.update(data)
        t.obs_norm.update(data["next", OBS_KEY])
        if at_collection:
            with torch.no_grad():
                t.bonus_transform.set_frames(frames)
                data = t.bonus_transform(t.obs_norm(data))
            add_bonus_scalars(t, data["next"])
        t.buffer.extend(data.select(*t.stored_keys).reshape(-1))
        if frames >= cfg.collector.init_random_frames:
            updates = update(cfg, t, frames, updates)
            run.check_finite(frames, loss_module=t.loss_module)

        # Logging
        fps = run.per_second(frames - run.start_frames)
        ups = run.per_second(updates - start_updates)
        if iteration % cfg.logger.log_interval == 0:
            log_batch(cfg, run, t, frames, updates, fps, ups)

        # Evaluation: the actor without noise, on the extrinsic reward
        t.progress.frames, t.progress.updates = frames, updates
        if frames >= t.progress.next_eval:
            t.progress.next_eval += cfg.eval.interval_frames
            result = evaluate(
                t.eval_env, t.actor, cfg.eval.episodes, seed=t.eval_seed, chunk=1000
            )
            run.log({"eval/episode_return": result.mean_return}, step=frames)
        # Progress, periodic checkpoint, stop on a signal (common/run.py)
        run.after_update()
    return frames, updates, fps, ups


def update(cfg, t: Training, frames: int, updates: int) -> int:
    """Step 3: ``utd_ratio * frames_per_batch`` updates, each on a fresh
    minibatch (its bonus recomputed with ``intrinsic.bonus_at=sample``); the VAE
    every ``intrinsic.update_every`` updates. Returns the updates done in all."""
    at_sample = t.bonus_transform is not None and cfg.intrinsic.bonus_at == "sample"
    for _ in range(int(cfg.collector.frames_per_batch * cfg.optim.utd_ratio)):
        sample = t.buffer.sample(cfg.optim.batch_size)
        if at_sample:
            with torch.no_grad():
                t.bonus_transform.set_frames(frames)
                sample = t.bonus_transform(t.obs_norm(sample))
            add_bonus_scalars(t, sample["next"])
        loss_value, _ = t.loss_module.loss_value(sample)
        t.critic_optim.zero_grad()
        loss_value.backward()
        t.critic_optim.step()
        loss_actor, _ = t.loss_module.loss_actor(sample)
        t.actor_optim.zero_grad()
        loss_actor.backward()
        t.actor_optim.step()
        t.target_updater.step()
        updates += 1
        t.pending.add("train/loss_value", loss_value)
        t.pending.add("train/loss_actor", loss_actor)
        t.pending.add("train/reward", sample["next", "reward"])

        if t.vae_loss is not None and updates % cfg.intrinsic.update_every == 0:
            vae_batch = t.obs_norm(t.buffer.sample(cfg.intrinsic.batch_size))
            vae_td = t.vae_loss(vae_batch)
            vae_total = vae_td["loss_reconstruction"] + vae_td["loss_kl"]
            t.vae_optim.zero_grad()
            vae_total.backward()
            t.vae_optim.step()
            for key, value in vae_td.items():
                t.pending.add(f"bonus/{key}", value)
    return updates


def log_batch(cfg, run, t: Training, frames, updates, fps, ups) -> None:
    """One log line: episode statistics, speed, and the means of the updates'
    scalars since the last one."""
    metrics = {
        "train/episode_return": t.stats.mean_return,
        "train/episode_length": t.stats.mean_length,
        "train/episodes": t.stats.episodes,
        "train/updates": updates,
        "time/fps": fps,
        "time/updates_per_s": ups,
    }
    if t.bonus_transform is not None:
        metrics["train/intrinsic_coef"] = t.bonus_transform.current_coef()
    metrics.update(t.pending.pop_means())
    run.log(metrics, step=frames)
    run.progress_bar.set_postfix(
        fps=f"{fps:.0f}", ups=f"{ups:.0f}", ret=f"{t.stats.mean_return:.1f}"
    )


if __name__ == "__main__":
    if sweep_requested(sys.argv):
        # Sweep launchers pickle the task function for their worker processes,
        # where the module beside the script is not importable (submitit, Ray).
        register_sweep_pickling(utils)
    main()
