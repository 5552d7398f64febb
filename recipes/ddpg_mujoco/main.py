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
   b. one critic step (TorchRL's DDPGLoss, TD(0) target with the target critic),
      one actor step, then a Polyak update of the target critic (SoftUpdate);
   c. every ``intrinsic.update_every`` updates, one VAE step (VAELoss) on its own
      replay sample of normalised next observations.

Evaluation runs the actor without noise on the extrinsic reward only.

Run: ``python recipes/ddpg_mujoco/main.py bonus=vae env.name=HalfCheetah-v5``
Resume a killed run: ``... hydra.run.dir=<its run dir> resume=true``.
"""

from __future__ import annotations

import time
from pathlib import Path

import hydra
import torch
from hydra.core.hydra_config import HydraConfig
from tqdm import tqdm
from utils import (
    OBS_KEY,
    ObservationNormalizer,
    check_config,
    load_replay_buffer_state,
    make_bonus,
    make_collector,
    make_ddpg,
    make_env,
    make_replay_buffer,
    replay_buffer_state,
    replay_keys,
)

from torchrl_surprise.experiments import (
    EpisodeStats,
    evaluate_episodes,
    get_rng_state,
    get_run_logger,
    plot_learning_curves,
    prepare_run,
    save_checkpoint,
    set_rng_state,
)

EVAL_SEED_OFFSET = 10_000


def evaluate(env, actor, episodes: int) -> float:
    """Mean extrinsic return of the noiseless actor over ``episodes`` episodes."""
    returns = evaluate_episodes(env, actor, episodes, seed=env.eval_seed, chunk=1000)
    return sum(returns) / max(len(returns), 1)


def _mean(values: list[torch.Tensor]) -> float:
    return torch.stack(values).mean().item() if values else float("nan")


@hydra.main(config_path=".", config_name="config", version_base=None)
def main(cfg) -> None:  # noqa: C901 (one readable loop, as TorchRL's recipes)
    check_config(cfg)
    run_dir = Path(HydraConfig.get().runtime.output_dir)
    ckpt_path, ckpt = prepare_run(cfg, run_dir)
    frames = ckpt["frames"] if ckpt else 0
    updates = ckpt["updates"] if ckpt else 0

    # ---- envs, models, losses, buffer -----------------------------------------
    env = make_env(cfg, cfg.env.num_envs, seed=cfg.seed + frames)
    eval_env = make_env(cfg, cfg.eval.num_envs, seed=cfg.seed + EVAL_SEED_OFFSET)
    eval_env.eval_seed = cfg.seed + EVAL_SEED_OFFSET
    obs_dim = env.observation_spec[OBS_KEY].shape[-1]
    actor, policy, noise, loss_module, target_updater = make_ddpg(cfg, env)
    actor_optim = torch.optim.Adam(
        loss_module.actor_network_params.flatten_keys().values(),
        lr=cfg.optim.actor_lr,
    )
    critic_optim = torch.optim.Adam(
        loss_module.value_network_params.flatten_keys().values(),
        lr=cfg.optim.critic_lr,
    )
    obs_norm = ObservationNormalizer(obs_dim, clip=cfg.obs_norm.clip)
    bonus_transform, vae_loss = make_bonus(cfg, obs_dim)
    vae_optim = None
    if vae_loss is not None:
        vae_optim = torch.optim.Adam(vae_loss.parameters(), lr=cfg.intrinsic.lr)
    bonus_at_sample = bonus_transform is not None and cfg.intrinsic.bonus_at == "sample"
    bonus_at_collection = (
        bonus_transform is not None and cfg.intrinsic.bonus_at == "collection"
    )
    buffer = make_replay_buffer(cfg.replay_buffer.size)
    stored_keys = replay_keys(bonus_transform, cfg.intrinsic.bonus_at)

    stats = EpisodeStats(window=cfg.logger.episode_window)
    history: dict[str, list] = {
        "frames": [],
        "return": [],
        "eval_frames": [],
        "eval_return": [],
    }
    next_eval = cfg.eval.interval_frames
    next_ckpt = cfg.checkpoint.interval_frames
    if ckpt:
        loss_module.load_state_dict(ckpt["loss_module"])
        noise.load_state_dict(ckpt["noise"])
        actor_optim.load_state_dict(ckpt["actor_optim"])
        critic_optim.load_state_dict(ckpt["critic_optim"])
        obs_norm.load_state_dict(ckpt["obs_norm"])
        if bonus_transform is not None:
            bonus_transform.load_state_dict(ckpt["bonus_transform"])
            vae_optim.load_state_dict(ckpt["vae_optim"])
        load_replay_buffer_state(buffer, ckpt["replay_buffer"])
        stats.load_state_dict(ckpt["stats"])
        history = ckpt["history"]
        next_eval, next_ckpt = ckpt["next_eval"], ckpt["next_ckpt"]
        set_rng_state(ckpt["rng"])

    def checkpoint() -> None:
        save_checkpoint(
            ckpt_path,
            {
                "frames": frames,
                "updates": updates,
                # actor, critic and the target critic
                "loss_module": loss_module.state_dict(),
                "noise": noise.state_dict(),
                "actor_optim": actor_optim.state_dict(),
                "critic_optim": critic_optim.state_dict(),
                "obs_norm": obs_norm.state_dict(),
                # the VAE, the bonus statistics and the schedule's frame counter
                "bonus_transform": None
                if bonus_transform is None
                else bonus_transform.state_dict(),
                "vae_optim": None if vae_optim is None else vae_optim.state_dict(),
                "replay_buffer": replay_buffer_state(buffer),
                "stats": stats.state_dict(),
                "history": history,
                "next_eval": next_eval,
                "next_ckpt": next_ckpt,
                "rng": get_rng_state(),
            },
        )

    logger = get_run_logger(
        cfg.logger.backend, run_dir, "ddpg", cfg.logger.project_name
    )
    remaining = cfg.collector.total_frames - frames
    if remaining <= 0:
        print(f"Nothing to do: {frames} frames already done in {run_dir}.")
        return
    collector = make_collector(
        env,
        policy,
        cfg,
        total_frames=remaining,
        init_random_frames=max(0, cfg.collector.init_random_frames - frames),
    )
    updates_per_batch = int(cfg.collector.frames_per_batch * cfg.optim.utd_ratio)

    # ---- training loop ----------------------------------------------------------
    pbar = tqdm(
        total=cfg.collector.total_frames, initial=frames, unit="f", desc=cfg.bonus
    )
    start, start_frames, start_updates = time.perf_counter(), frames, updates
    logs: dict[str, list[torch.Tensor]] = {}

    def log_bonus(logs, next_td) -> None:
        # The raw bonus, and the normalised one that is mixed into the reward.
        logs.setdefault("train/intrinsic_reward", []).append(
            next_td[bonus_transform.intrinsic_reward_key].mean()
        )
        if bonus_transform.normalized_reward_key is not None:
            logs.setdefault("train/intrinsic_reward_normalized", []).append(
                next_td[bonus_transform.normalized_reward_key].mean()
            )

    fps = ups = 0.0
    for iteration, data in enumerate(collector):
        frames += data.numel()
        stats.update(data)
        obs_norm.update(data["next", OBS_KEY])
        if bonus_at_collection:
            with torch.no_grad():
                bonus_transform.set_frames(frames)
                data = bonus_transform(obs_norm(data))
            log_bonus(logs, data["next"])
        buffer.extend(data.select(*stored_keys).reshape(-1))

        if frames >= cfg.collector.init_random_frames:
            for _ in range(updates_per_batch):
                sample = buffer.sample(cfg.optim.batch_size)
                if bonus_at_sample:
                    with torch.no_grad():
                        bonus_transform.set_frames(frames)
                        sample = bonus_transform(obs_norm(sample))
                    log_bonus(logs, sample["next"])
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
                logs.setdefault("loss_value", []).append(loss_value.detach())
                logs.setdefault("loss_actor", []).append(loss_actor.detach())
                logs.setdefault("reward", []).append(sample["next", "reward"].mean())

                if vae_loss is not None and updates % cfg.intrinsic.update_every == 0:
                    vae_batch = obs_norm(buffer.sample(cfg.intrinsic.batch_size))
                    vae_td = vae_loss(vae_batch)
                    vae_total = vae_td["loss_reconstruction"] + vae_td["loss_kl"]
                    vae_optim.zero_grad()
                    vae_total.backward()
                    vae_optim.step()
                    for key, value in vae_td.items():
                        logs.setdefault(f"bonus/{key}", []).append(value.detach())

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
            if logs.get("loss_value"):
                metrics["train/loss_value"] = _mean(logs["loss_value"])
                metrics["train/loss_actor"] = _mean(logs["loss_actor"])
                metrics["train/reward"] = _mean(logs["reward"])
            if bonus_transform is not None:
                metrics["train/intrinsic_coef"] = bonus_transform.current_coef()
            for key, values in logs.items():
                if "/" in key:
                    metrics[key] = _mean(values)
            logs.clear()
            for name, value in metrics.items():
                logger.log_scalar(name, value, step=frames)
            if stats.returns:
                history["frames"].append(frames)
                history["return"].append(stats.mean_return)
            pbar.set_postfix(
                fps=f"{fps:.0f}", ups=f"{ups:.0f}", ret=f"{stats.mean_return:.1f}"
            )

        if frames >= next_eval:
            next_eval += cfg.eval.interval_frames
            actor.eval()
            ret = evaluate(eval_env, actor, cfg.eval.episodes)
            actor.train()
            logger.log_scalar("eval/episode_return", ret, step=frames)
            history["eval_frames"].append(frames)
            history["eval_return"].append(ret)
        if frames >= next_ckpt:
            next_ckpt += cfg.checkpoint.interval_frames
            checkpoint()
    pbar.close()
    collector.shutdown()
    checkpoint()

    curves = {"train (with noise)": (history["frames"], history["return"])}
    if history["eval_frames"]:
        curves["eval (deterministic)"] = (
            history["eval_frames"],
            history["eval_return"],
        )
    curve = plot_learning_curves(
        curves,
        run_dir / "learning_curve.png",
        title=f"{cfg.env.name}: DDPG + {cfg.bonus} (seed {cfg.seed})",
        ylabel="extrinsic episode return",
    )
    print(
        f"Done: {frames} frames, {updates} updates, {stats.episodes} episodes, last "
        f"{cfg.logger.episode_window}-episode mean return {stats.mean_return:.1f}, "
        f"{fps:.0f} frames/s, {ups:.0f} updates/s.\n"
        f"Learning curve: {curve}\nLogs: {run_dir / 'logs'}\nRun directory: {run_dir}"
    )


if __name__ == "__main__":
    main()
