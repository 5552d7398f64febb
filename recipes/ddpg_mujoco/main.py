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
from pathlib import Path

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
from common.evaluation import EVAL_SEED_OFFSET, EpisodeStats, evaluate
from common.run import TrainingRun
from common.stopping import register_sweep_pickling, sweep_requested


@hydra.main(config_path=".", config_name="config", version_base=None)
def main(cfg) -> None:  # noqa: C901 (one readable loop, as TorchRL's recipes)
    validate_ddpg(cfg)
    # Seeds, resume checks, the checkpoint to resume from (common/run.py)
    run = TrainingRun(cfg, "ddpg")
    if run.nothing_to_do():
        return

    # Create envs, seeded with cfg.seed whatever the checkpoint: a resumed run
    # restores the episodes in progress from the collector's state instead.
    env = make_env(cfg, cfg.env.num_envs, seed=cfg.seed)
    eval_seed = cfg.seed + EVAL_SEED_OFFSET
    eval_env = make_env(cfg, cfg.eval.num_envs, seed=eval_seed)
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
    bonus_at_sample = bonus_transform is not None and cfg.intrinsic.bonus_at == "sample"
    bonus_at_collection = (
        bonus_transform is not None and cfg.intrinsic.bonus_at == "collection"
    )
    buffer = make_replay_buffer(cfg.replay_buffer.size)
    stored_keys = replay_keys(bonus_transform, cfg.intrinsic.bonus_at)

    stats = EpisodeStats(window=cfg.logger.episode_window)
    # Per-update scalars not yet logged (means over the updates between log lines).
    pending = ScalarMeans()
    progress = RunCounters(
        frames=0,
        updates=0,
        next_eval=cfg.eval.interval_frames,
        next_ckpt=cfg.checkpoint.interval_frames,
    )
    # Create the collector: it holds the episodes in progress; it runs to total_frames (and
    # acts at random up to init_random_frames) from its own saved frame count, so
    # it is built for the whole run.
    collector = make_collector(env, policy, cfg)
    # What a checkpoint holds, saved and loaded from this one mapping (with the
    # random generators, restored last); restored when resuming.
    run.restore(
        {
            "progress": progress,
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
            "replay_buffer": buffer,
            "collector": collector,
            "stats": stats,
            "pending_logs": pending,
        },
        on_exit=[collector.shutdown],
    )
    frames, updates = progress.frames, progress.updates
    updates_per_batch = int(cfg.collector.frames_per_batch * cfg.optim.utd_ratio)

    def add_bonus_scalars(next_td) -> None:
        # The raw bonus, and the normalised one that is mixed into the reward.
        pending.add(
            "train/intrinsic_reward", next_td[bonus_transform.intrinsic_reward_key]
        )
        if bonus_transform.normalized_reward_key is not None:
            pending.add(
                "train/intrinsic_reward_normalized",
                next_td[bonus_transform.normalized_reward_key],
            )

    # Main loop
    start_updates = updates
    for data in collector:
        frames += data.numel()
        iteration = frames // cfg.collector.frames_per_batch - 1
        stats.update(data)
        obs_norm.update(data["next", OBS_KEY])
        if bonus_at_collection:
            with torch.no_grad():
                bonus_transform.set_frames(frames)
                data = bonus_transform(obs_norm(data))
            add_bonus_scalars(data["next"])
        buffer.extend(data.select(*stored_keys).reshape(-1))

        if frames >= cfg.collector.init_random_frames:
            for _ in range(updates_per_batch):
                sample = buffer.sample(cfg.optim.batch_size)
                if bonus_at_sample:
                    with torch.no_grad():
                        bonus_transform.set_frames(frames)
                        sample = bonus_transform(obs_norm(sample))
                    add_bonus_scalars(sample["next"])
                loss_value, _ = loss_module.loss_value(sample)
                critic_optim.zero_grad()
                loss_value.backward()
                critic_optim.step()
                loss_actor, _ = loss_module.loss_actor(sample)
                actor_optim.zero_grad()
                loss_actor.backward()
                actor_optim.step()
                target_updater.step()
                updates += 1
                pending.add("train/loss_value", loss_value)
                pending.add("train/loss_actor", loss_actor)
                pending.add("train/reward", sample["next", "reward"])

                if vae_loss is not None and updates % cfg.intrinsic.update_every == 0:
                    vae_batch = obs_norm(buffer.sample(cfg.intrinsic.batch_size))
                    vae_td = vae_loss(vae_batch)
                    vae_total = vae_td["loss_reconstruction"] + vae_td["loss_kl"]
                    vae_optim.zero_grad()
                    vae_total.backward()
                    vae_optim.step()
                    for key, value in vae_td.items():
                        pending.add(f"bonus/{key}", value)

        # Logging
        fps = run.per_second(frames - run.start_frames)
        ups = run.per_second(updates - start_updates)
        if iteration % cfg.logger.log_interval == 0:
            metrics = {
                "train/episode_return": stats.mean_return,
                "train/episode_length": stats.mean_length,
                "train/episodes": stats.episodes,
                "train/updates": updates,
                "time/fps": fps,
                "time/updates_per_s": ups,
            }
            if bonus_transform is not None:
                metrics["train/intrinsic_coef"] = bonus_transform.current_coef()
            metrics.update(pending.pop_means())
            run.log(metrics, step=frames)
            run.progress_bar.set_postfix(
                fps=f"{fps:.0f}", ups=f"{ups:.0f}", ret=f"{stats.mean_return:.1f}"
            )

        # Evaluation: the actor without noise, on the extrinsic reward
        progress.frames, progress.updates = frames, updates
        if frames >= progress.next_eval:
            progress.next_eval += cfg.eval.interval_frames
            result = evaluate(
                eval_env, actor, cfg.eval.episodes, seed=eval_seed, chunk=1000
            )
            run.log({"eval/episode_return": result.mean_return}, step=frames)
        # Progress, periodic checkpoint, stop on a signal (common/run.py)
        run.after_update()

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


if __name__ == "__main__":
    if sweep_requested(sys.argv):
        # Sweep launchers pickle the task function for their worker processes,
        # where the module beside the script is not importable (submitit, Ray).
        register_sweep_pickling(utils)
    main()
