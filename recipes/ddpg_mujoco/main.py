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

import time
from pathlib import Path

import cloudpickle
import hydra
import numpy as np
import torch
import utils  # the builders beside this script
from hydra.core.hydra_config import HydraConfig
from hydra.types import RunMode
from omegaconf import OmegaConf
from tqdm import tqdm
from utils import (
    OBS_KEY,
    ObservationNormalizer,
    ScalarMeans,
    check_config,
    make_bonus,
    make_collector,
    make_ddpg,
    make_env,
    make_replay_buffer,
    replay_keys,
)

from common.run import (
    Checkpointer,
    EpisodeStats,
    Progress,
    RNGState,
    StopSignal,
    evaluate_episodes,
    find_scalar_log,
    get_run_logger,
    plot_learning_curves,
    prepare_run,
    read_scalar_csv,
)

# Sweep launchers pickle this script's task function for their worker processes,
# where the module beside the script is not importable (submitit, Ray): it travels
# by value instead.
cloudpickle.register_pickle_by_value(utils)

EVAL_SEED_OFFSET = 10_000


def evaluate(env, actor, episodes: int) -> float:
    """Mean extrinsic return of the noiseless actor over ``episodes`` episodes."""
    returns = evaluate_episodes(env, actor, episodes, seed=env.eval_seed, chunk=1000)
    return sum(returns) / max(len(returns), 1)


def plot_returns(log_dir: Path, path: Path, title: str) -> Path | None:
    """Train and evaluation returns, read back from the run's CSV logs."""
    curves = {}
    for name, label in (
        ("train/episode_return", "train (with noise)"),
        ("eval/episode_return", "eval (deterministic)"),
    ):
        try:
            steps, values = read_scalar_csv(find_scalar_log(log_dir, name))
        except FileNotFoundError:  # not logged (logger.backend=) or not yet
            continue
        finite = np.isfinite(values)  # NaN before the first episode ends
        curves[label] = (steps[finite], values[finite])
    if not curves:
        return None
    return plot_learning_curves(
        curves, path, title=title, ylabel="extrinsic episode return"
    )


@hydra.main(config_path=".", config_name="config", version_base=None)
def main(cfg) -> None:  # noqa: C901 (one readable loop, as TorchRL's recipes)
    check_config(cfg)
    run_dir = Path(HydraConfig.get().runtime.output_dir)
    ckpt_path, ckpt = prepare_run(cfg, run_dir)
    if ckpt and ckpt["frames"] >= cfg.collector.total_frames:
        # A finished run in a rerun sweep: nothing to build.
        print(f"Nothing to do: {ckpt['frames']} frames already done in {run_dir}.")
        return

    # ---- envs, models, losses, buffer -----------------------------------------
    # Seeded with cfg.seed whatever the checkpoint: a resumed run restores the
    # episodes in progress from the collector's state instead.
    env = make_env(cfg, cfg.env.num_envs, seed=cfg.seed)
    eval_env = make_env(cfg, cfg.eval.num_envs, seed=cfg.seed + EVAL_SEED_OFFSET)
    eval_env.eval_seed = cfg.seed + EVAL_SEED_OFFSET
    obs_dim = env.observation_spec[OBS_KEY].shape[-1]
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
    progress = Progress(
        frames=0,
        updates=0,
        next_eval=cfg.eval.interval_frames,
        next_ckpt=cfg.checkpoint.interval_frames,
    )
    # The collector holds the episodes in progress; it runs to total_frames (and
    # acts at random up to init_random_frames) from its own saved frame count, so
    # it is built for the whole run.
    collector = make_collector(env, policy, cfg)
    # What a checkpoint holds, saved and loaded from this one mapping (RNG last:
    # building the run above drew random numbers).
    checkpointer = Checkpointer(
        ckpt_path,
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
            "rng": RNGState(),
        },
        config=OmegaConf.to_container(cfg, resolve=True),
    )
    if ckpt:
        checkpointer.load(ckpt)
    frames, updates = progress.frames, progress.updates
    logger = get_run_logger(
        cfg.logger.backend, run_dir, "ddpg", cfg.logger.project_name
    )
    updates_per_batch = int(cfg.collector.frames_per_batch * cfg.optim.utd_ratio)
    stop = StopSignal()

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

    # ---- training loop ----------------------------------------------------------
    pbar = tqdm(
        total=cfg.collector.total_frames,
        initial=frames,
        unit="f",
        desc=cfg.bonus,
        # In a sweep, parallel bars garble each other: the logs hold the progress.
        disable=HydraConfig.get().mode == RunMode.MULTIRUN,
    )
    start, start_frames, start_updates = time.perf_counter(), frames, updates
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

        pbar.update(data.numel())
        elapsed = time.perf_counter() - start
        fps = (frames - start_frames) / elapsed
        ups = (updates - start_updates) / elapsed
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
            if logger is not None:
                for name, value in metrics.items():
                    logger.log_scalar(name, value, step=frames)
            pbar.set_postfix(
                fps=f"{fps:.0f}", ups=f"{ups:.0f}", ret=f"{stats.mean_return:.1f}"
            )

        progress.frames, progress.updates = frames, updates
        if frames >= progress.next_eval:
            progress.next_eval += cfg.eval.interval_frames
            ret = evaluate(eval_env, actor, cfg.eval.episodes)
            if logger is not None:
                logger.log_scalar("eval/episode_return", ret, step=frames)
        # Checkpoints at the end of an iteration only: updates done, logs written.
        if frames >= progress.next_ckpt:
            progress.next_ckpt += cfg.checkpoint.interval_frames
            checkpointer.save()
        stop.save_and_exit(
            checkpointer, frames, run_dir, pbar.close, collector.shutdown
        )
    stop.restore()
    pbar.close()
    checkpointer.save()
    collector.shutdown()

    curve = plot_returns(
        run_dir / "logs",
        run_dir / "learning_curve.png",
        title=f"{cfg.env.name}: DDPG + {cfg.bonus} (seed {cfg.seed})",
    )
    print(
        f"Done: {frames} frames, {updates} updates, {stats.episodes} episodes, last "
        f"{cfg.logger.episode_window}-episode mean return {stats.mean_return:.1f}, "
        f"{fps:.0f} frames/s, {ups:.0f} updates/s.\n"
        f"Learning curve: {curve}\nLogs: {run_dir / 'logs'}\nRun directory: {run_dir}"
    )


if __name__ == "__main__":
    main()
