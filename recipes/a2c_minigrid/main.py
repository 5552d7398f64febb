"""A2C with a surprise bonus on MiniGrid (the paper's Algorithm 1), in TorchRL.

Every update, in this order:

1. the collector gathers ``frames_per_env`` steps from each of ``num_envs`` envs
   (the set D of Algorithm 1, N = frames_per_env * num_envs transitions), in this
   process or split over ``collector.workers`` processes;
2. the bonus of every transition in D is computed in one batched pass with the
   current bonus model and mixed: ``r = r_ext + coef * normalize(r_int)``
   (the env's reward is kept as ``extrinsic_reward`` and is what is logged);
3. GAE on the mixed reward (centred and scaled over the batch with
   ``loss.normalize_advantage``), then one A2C step (TorchRL's A2CLoss);
   with ``intrinsic.intrinsic_critic=true`` a second value head learns the
   intrinsic return instead and the advantage is ``A_ext + coef * A_int``
   (:class:`torchrl_surprise.TwoStreamAdvantage`, :class:`IntrinsicValueLoss`);
4. the bonus model (VAE, ICM or RND predictor) takes ``update_steps`` gradient
   steps on the states of D, which is then discarded (no replay); with
   ``intrinsic.update_every`` k > 1 (the default is 4) only on every k-th D.

Run: ``python recipes/a2c_minigrid/main.py bonus=vae env.name=MiniGrid-MultiRoom-N3-S4-v0``
Sweep: ``python recipes/a2c_minigrid/main.py -m +experiment=n3s4`` (rerun it to resume).
Resume a killed run: ``... hydra.run.dir=<its run dir>`` (``resume=auto``, the
default, continues from the checkpoint; the resumed run logs exactly what the
uninterrupted run would have). Ctrl-C or SIGTERM saves a checkpoint and exits.
"""

from __future__ import annotations

import time
from pathlib import Path

import cloudpickle
import hydra
import torch
import utils  # the builders beside this script
from hydra.core.hydra_config import HydraConfig
from hydra.types import RunMode
from omegaconf import OmegaConf
from tqdm import tqdm
from utils import (
    check_config,
    make_a2c,
    make_actor_critic,
    make_bonus,
    make_collector,
    make_env,
    shared_trunk,
)

from torchrl_surprise.experiments import (
    Checkpointer,
    EpisodeStats,
    Progress,
    RNGState,
    StopSignal,
    get_run_logger,
    plot_scalar_logs,
    prepare_run,
)
from torchrl_surprise.experiments.minigrid import (
    EVAL_SEED_OFFSET,
    bonus_update_steps,
    documented_results_message,
    evaluate,
    load_bonus_model,
    rollout_metrics,
    train_bonus_model,
)

# Sweep launchers pickle this script's task function for their worker processes,
# where the module beside the script is not importable (submitit, Ray): it travels
# by value instead.
cloudpickle.register_pickle_by_value(utils)


@hydra.main(config_path=".", config_name="config", version_base=None)
def main(cfg) -> None:  # noqa: C901 (one readable loop, as TorchRL's recipes)
    check_config(cfg)
    run_dir = Path(HydraConfig.get().runtime.output_dir)
    ckpt_path, ckpt = prepare_run(cfg, run_dir)

    # ---- envs, models, losses -------------------------------------------------
    env = make_env(cfg, cfg.env.num_envs, seed=cfg.seed)
    bonus_transform, bonus_loss, env_side = make_bonus(cfg, env.action_spec, cfg.bonus)
    if env_side is not None:
        env.append_transform(env_side)
    if cfg.intrinsic.init_from and not ckpt:
        # Transfer: the bonus model starts from another run's (a resumed run
        # restores its own from the checkpoint below).
        source_frames = load_bonus_model(
            bonus_transform, cfg.bonus, cfg.intrinsic.init_from
        )
        print(f"Bonus model from {cfg.intrinsic.init_from} ({source_frames} frames).")
    eval_seed = cfg.seed + EVAL_SEED_OFFSET
    eval_env = make_env(cfg, cfg.eval.num_envs, seed=eval_seed)
    use_int_critic = cfg.intrinsic.intrinsic_critic and bonus_transform is not None
    model, int_value = make_actor_critic(env.action_spec, use_int_critic)
    policy = model.get_policy_operator()
    trunk = shared_trunk(model)
    loss_module, advantage, int_value_loss = make_a2c(
        cfg, model, int_value, bonus_transform
    )
    params = list(model.parameters())
    if int_value is not None:
        shared = {id(p) for p in params}
        params += [p for p in int_value.parameters() if id(p) not in shared]
    optim = torch.optim.RMSprop(
        params, lr=cfg.optim.lr, alpha=cfg.optim.alpha, eps=cfg.optim.eps
    )
    bonus_optim = None
    if bonus_loss is not None:
        bonus_params = [p for p in bonus_loss.parameters() if p.requires_grad]
        # fused: the same Adam update in one kernel (~20% faster VAE steps on CPU)
        bonus_optim = torch.optim.Adam(bonus_params, lr=cfg.intrinsic.lr, fused=True)

    stats = EpisodeStats(window=cfg.logger.episode_window)
    progress = Progress(
        frames=0,
        next_eval=cfg.eval.interval_frames,
        next_ckpt=cfg.checkpoint.interval_frames,
    )
    # The collector holds the episodes in progress; it runs to total_frames from
    # its own saved frame count, so it is built for the whole run. With
    # collector.workers > 1, worker processes step the envs synchronously, each
    # rollout with the policy's weights after the last update (synced before each
    # batch); the bonus and the updates stay in this process.
    collector = make_collector(
        env, policy, cfg, total_frames=cfg.collector.total_frames
    )
    # What a checkpoint holds, saved and loaded from this one mapping (RNG last:
    # building the run above drew random numbers).
    checkpointer = Checkpointer(
        ckpt_path,
        {
            "progress": progress,
            "model": model,
            "int_value": int_value,
            "optim": optim,
            "bonus_transform": bonus_transform,
            "bonus_optim": bonus_optim,
            "collector": collector,
            "stats": stats,
            "rng": RNGState(),
        },
        config=OmegaConf.to_container(cfg, resolve=True),
        keep_dir=run_dir / "checkpoints" if cfg.checkpoint.keep else None,
    )
    if ckpt:
        checkpointer.load(ckpt)
    frames = progress.frames
    logger = get_run_logger(cfg.logger.backend, run_dir, "a2c", cfg.logger.project_name)
    if frames >= cfg.collector.total_frames:
        print(f"Nothing to do: {frames} frames already done in {run_dir}.")
        collector.shutdown()
        return
    variant = cfg.intrinsic.vae.variant if cfg.bonus == "vae" else None
    bonus_after_update = variant == "info_gain"

    stop = StopSignal()

    # ---- training loop ----------------------------------------------------------
    pbar = tqdm(
        total=cfg.collector.total_frames,
        initial=frames,
        unit="f",
        desc=cfg.bonus,
        # In a sweep, parallel bars garble each other: the logs hold the progress.
        disable=HydraConfig.get().mode == RunMode.MULTIRUN,
    )
    start, start_frames = time.perf_counter(), frames
    for data in collector:
        frames += data.numel()
        iteration = frames // data.numel() - 1
        stats.update(data)
        # intrinsic.update_steps on every intrinsic.update_every-th rollout, else 0
        # (always 0 for a frozen transferred model, finetune=false).
        bonus_steps = bonus_update_steps(cfg, iteration)

        if bonus_after_update:
            # The information gain of this rollout's VAE update on each state.
            bonus_transform.snapshot()
            bonus_td = train_bonus_model(
                bonus_loss, bonus_optim, data, bonus_steps, env_side
            )
        # Step 2: the bonus of the whole rollout, with the VAE as it was during it.
        with torch.no_grad():
            if bonus_transform is not None:
                data = bonus_transform(data)
            # Step 3: advantages: GAE on the (mixed) reward, or the two streams
            # (A_ext + coef * A_int, TwoStreamAdvantage).
            data = advantage(data)
            if cfg.loss.normalize_advantage:
                data = utils.standardize_advantage(
                    data, loss_module.tensor_keys.advantage
                )
        # The shared trunk once, with gradients: the losses' heads read its features.
        data = trunk(data)
        loss_td = loss_module(data)
        loss = (
            loss_td["loss_objective"] + loss_td["loss_critic"] + loss_td["loss_entropy"]
        )
        if int_value_loss is not None:
            loss_int = int_value_loss(data)["loss_critic_int"]
            loss = loss + loss_int
        optim.zero_grad()
        loss.backward()
        grad_norm = torch.nn.utils.clip_grad_norm_(params, cfg.optim.max_grad_norm)
        optim.step()

        # Step 4: train the bonus model on the states of this rollout.
        if not bonus_after_update:
            bonus_td = train_bonus_model(
                bonus_loss, bonus_optim, data, bonus_steps, env_side
            )
        if variant == "lagged_kl" and iteration % cfg.intrinsic.vae.lag_updates == 0:
            bonus_transform.snapshot()

        pbar.update(data.numel())
        fps = (frames - start_frames) / (time.perf_counter() - start)
        if iteration % cfg.logger.log_interval == 0:
            metrics = {
                **rollout_metrics(stats, data, bonus_transform, bonus_td),
                "train/loss_objective": loss_td["loss_objective"].item(),
                "train/loss_critic": loss_td["loss_critic"].item(),
                "train/loss_entropy": loss_td["loss_entropy"].item(),
                "train/entropy": loss_td["entropy"].item(),
                "train/grad_norm": grad_norm.item(),
                "time/fps": fps,
            }
            if int_value is not None:
                metrics["train/loss_critic_int"] = loss_int.item()
            if logger is not None:
                for name, value in metrics.items():
                    logger.log_scalar(name, value, step=frames)
            pbar.set_postfix(fps=f"{fps:.0f}", ret=f"{stats.mean_return:.3f}")

        progress.frames = frames
        if frames >= progress.next_eval:
            progress.next_eval += cfg.eval.interval_frames
            model.eval()
            ret, success = evaluate(
                eval_env,
                policy,
                cfg.eval.episodes,
                seed=eval_seed,
                deterministic=cfg.eval.deterministic,
            )
            model.train()
            if logger is not None:
                logger.log_scalar("eval/episode_return", ret, step=frames)
                logger.log_scalar("eval/success_rate", success, step=frames)
        checkpointer.save_every(cfg.checkpoint.interval_frames)
        stop.save_and_exit(
            checkpointer, frames, run_dir, pbar.close, collector.shutdown
        )
    stop.restore()
    pbar.close()
    checkpointer.save()
    collector.shutdown()

    curve = plot_scalar_logs(
        run_dir / "logs",
        "train/episode_return",
        run_dir / "learning_curve.png",
        label=cfg.bonus,
        title=f"{cfg.env.name}: A2C + {cfg.bonus} (seed {cfg.seed})",
        ylabel=f"extrinsic return ({cfg.logger.episode_window}-episode mean)",
    )
    print(
        f"Done: {frames} frames, {stats.episodes} episodes, last "
        f"{cfg.logger.episode_window}-episode mean return {stats.mean_return:.3f}, "
        f"success rate {stats.success_rate:.2f}, {fps:.0f} frames/s.\n"
        f"Learning curve: {curve}\nLogs: {run_dir / 'logs'}\nRun directory: {run_dir}"
    )
    measured = documented_results_message(
        cfg.env.name,
        cfg.collector.total_frames,
        Path(__file__).resolve().parents[2] / "docs" / "results",
        "a2c_minigrid",
        stochasticity=cfg.env.stochasticity,
    )
    if measured:
        print(measured)


if __name__ == "__main__":
    main()
