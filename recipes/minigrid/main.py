"""A2C or PPO with an exploration bonus on MiniGrid, in TorchRL.

``algo=a2c`` is the paper's Algorithm 1; ``algo=ppo`` the same bonus under PPO.
Every update, in this order:

1. the collector gathers ``frames_per_env`` steps from each of ``num_envs`` envs
   (A2C: 16 x 8 = 128 transitions, the set D of Algorithm 1; PPO: 64 x 32 =
   2,048), in this process or split over ``collector.workers`` processes;
2. the bonus of every transition is computed in one batched pass with the bonus
   model as it was during the rollout, and mixed, ``r = r_ext + coef *
   normalize(r_int)``, or kept for the intrinsic critic (the env's reward is kept
   as ``extrinsic_reward`` and is what is logged);
3. the advantages, once for the whole batch (as torch-ac and CleanRL do): GAE on
   the (mixed) reward, or with ``intrinsic.intrinsic_critic=true`` the two streams
   ``A_ext + coef * A_int`` (:class:`torchrl_surprise.TwoStreamAdvantage`), with the
   critics as they were during the rollout;
4. the learner's update: A2C takes one RMSprop step of TorchRL's ``A2CLoss`` on the
   whole batch; PPO takes ``loss.epochs`` passes over it in shuffled minibatches of
   ``loss.minibatch_size``, one Adam step of ``ClipPPOLoss`` per minibatch (plus
   :class:`IntrinsicValueLoss` with two critics, in both);
5. the bonus model (VAE, ICM or RND predictor) takes ``update_steps`` gradient
   steps on the states of the batch, which is then discarded (no replay), on every
   ``intrinsic.update_every``-th batch; with ``intrinsic.vae.variant=info_gain``
   this comes before step 2 (the bonus is the posterior shift of this update).

Run: ``python recipes/minigrid/main.py algo=ppo bonus=vae env.name=MiniGrid-DoorKey-8x8-v0``
Sweep: ``python recipes/minigrid/main.py -m +experiment=a2c/n3s4`` (rerun it to resume).
Resume a killed run: ``... hydra.run.dir=<its run dir>`` (``resume=auto``, the
default, continues from the checkpoint; the resumed run logs exactly what the
uninterrupted run would have). Ctrl-C or SIGTERM saves a checkpoint and exits.
"""

from __future__ import annotations

import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

# recipes/ holds what the recipes share (common) and the results tools (results).
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import hydra
import torch
import utils  # the learners beside this script

import common
from common.checkpoint import RunCounters
from common.config import validate_minigrid
from common.errors import ConfigError, report_mistakes
from common.evaluation import EVAL_SEED_OFFSET, EpisodeStats, evaluate
from common.minigrid import (
    bonus_update_steps,
    inverse_head,
    load_bonus_model,
    make_actor_critic,
    make_bonus,
    make_collector,
    make_env,
    measured_comparison,
    oracle_optimum,
    rollout_metrics,
    shared_trunk,
    train_bonus_model,
)
from common.run import TrainingRun
from common.stopping import register_sweep_pickling, sweep_requested
from common.video import record_minigrid_video, video_path


@dataclass
class Training:
    """What a run is built of (:func:`build`) and what its loop (:func:`train`) uses."""

    env: Any
    eval_env: Any
    eval_seed: int
    bonus_transform: Any
    bonus_loss: Any
    env_side: Any
    model: Any
    int_value: Any
    policy: Any
    trunk: Any
    loss_module: Any
    advantage: Any
    int_value_loss: Any
    params: list
    optim: Any
    bonus_optim: Any
    batches: Any
    reward_clip: Any
    stats: EpisodeStats
    progress: RunCounters
    collector: Any


@hydra.main(config_path=".", config_name="config", version_base=None)
@report_mistakes
def main(cfg) -> None:
    """The run, in the steps the module's docstring numbers: checks, build, the
    loop of updates, the end (curve, video, the committed results beside it)."""
    device = check(cfg)
    # Seeds, resume checks, the checkpoint to resume from (common/rundir.py)
    run = TrainingRun(cfg, cfg.algo.name)
    # a finished run writes the video (or curve) its end left missing
    video = [video_path(run.run_dir, run.done_frames)] if cfg.eval.video else []
    if run.nothing_to_do(outputs=video):
        return
    with run.starting():  # a mistake before the run starts leaves nothing behind
        training = build(cfg, run, device)
    frames, fps = train(cfg, run, training)
    finish(cfg, run, training, frames, fps)


def check(cfg):
    """Refuses a config the recipe cannot run, before anything is built; returns
    the device of the policy, critics and bonus model (the envs step on the CPU)."""
    validate_minigrid(cfg)
    device = utils.resolve_device(cfg.device)
    if cfg.bonus == "rnd" and device.type != "cpu":
        raise ConfigError(
            "bonus=rnd runs its networks inside the envs (TorchRL's RNDTransform), "
            f"on the CPU: run it with device=cpu (device={cfg.device} gave {device})."
        )
    return device


def build(cfg, run: TrainingRun, device) -> Training:
    """Envs, the bonus, the actor-critic, losses, optimisers and the collector,
    in the order they draw random numbers; then the checkpoint restored."""
    # Create envs and the bonus
    env = make_env(cfg.env, cfg.env.num_envs, seed=cfg.seed)
    bonus_transform, bonus_loss, env_side = build_bonus(cfg, run, env, device)
    eval_seed = cfg.seed + EVAL_SEED_OFFSET
    eval_env = make_env(cfg.env, cfg.eval.num_envs, seed=eval_seed)

    # Create the actor-critic; PPO's policy records the log-probability of each
    # action it takes: its ratio.
    use_int_critic = cfg.intrinsic.intrinsic_critic and bonus_transform is not None
    model, int_value = make_actor_critic(
        env.action_spec, use_int_critic, return_log_prob=cfg.algo.name == "ppo"
    )
    model.to(device)
    if int_value is not None:
        int_value.to(device)
    # The policy in one call per env step (same layers, same draws: utils); it
    # takes the envs' CPU observations in evaluation and videos.
    policy = utils.SampledCategoricalPolicy(model.get_policy_operator(), device)

    # Create losses and optimisers
    loss_module, advantage, int_value_loss = utils.make_loss(
        cfg, model, int_value, bonus_transform
    )
    params = list(model.parameters())
    if int_value is not None:
        shared = {id(p) for p in params}
        params += [p for p in int_value.parameters() if id(p) not in shared]
    optim = utils.make_optimizer(cfg, params)
    bonus_optim = None
    if bonus_loss is not None:
        bonus_params = [p for p in bonus_loss.parameters() if p.requires_grad]
        # fused: the same Adam update in one kernel (faster VAE steps on CPU)
        bonus_optim = torch.optim.Adam(bonus_params, lr=cfg.intrinsic.lr, fused=True)
    batches = utils.make_minibatches(cfg)

    # Create the collector: it holds the episodes in progress and runs to
    # total_frames from its own saved frame count. With collector.workers > 1,
    # worker processes step the envs synchronously, each rollout with the
    # policy's weights after the last update; the bonus and the updates stay here.
    collector = make_collector(
        env, policy, cfg, total_frames=cfg.collector.total_frames, device=device
    )
    training = Training(
        env=env,
        eval_env=eval_env,
        eval_seed=eval_seed,
        bonus_transform=bonus_transform,
        bonus_loss=bonus_loss,
        env_side=env_side,
        model=model,
        int_value=int_value,
        policy=policy,
        trunk=shared_trunk(model),
        loss_module=loss_module,
        advantage=advantage,
        int_value_loss=int_value_loss,
        params=params,
        optim=optim,
        bonus_optim=bonus_optim,
        batches=batches,
        reward_clip=utils.make_reward_clip(cfg),
        stats=EpisodeStats(window=cfg.logger.episode_window),
        progress=RunCounters(
            frames=0,
            next_eval=cfg.eval.interval_frames,
            next_ckpt=cfg.checkpoint.interval_frames,
        ),
        collector=collector,
    )
    restore(run, training)
    return training


def restore(run: TrainingRun, t: Training) -> None:
    """What a checkpoint holds, saved and loaded from this one mapping (with the
    random generators, restored last); restored when resuming."""
    run.restore(
        {
            "progress": t.progress,
            "model": t.model,
            "int_value": t.int_value,
            "optim": t.optim,
            "bonus_transform": t.bonus_transform,
            "bonus_optim": t.bonus_optim,
            "collector": t.collector,
            "stats": t.stats,
            # PPO: the minibatch order of the next update's first epoch, drawn already
            "minibatch_sampler": None if t.batches is None else t.batches.sampler,
            # intrinsic.vae.inverse_weight > 0: the inverse head on the VAE's latent
            # (the VAE itself is the bonus transform's)
            "bonus_inverse_head": inverse_head(t.bonus_loss),
        },
        on_exit=[t.collector.shutdown],
    )


def build_bonus(cfg, run: TrainingRun, env, device):
    """The bonus (``make_bonus``), its env-side transform appended to ``env``,
    its model started from another run's with ``intrinsic.init_from``."""
    bonus_transform, bonus_loss, env_side = make_bonus(cfg, env.action_spec, cfg.bonus)
    if env_side is not None:
        env.append_transform(env_side)
    if cfg.intrinsic.init_from and not run.resumed_from:
        # Transfer: the bonus model starts from another run's (a resumed run
        # restores its own from the checkpoint).
        source_frames = load_bonus_model(
            bonus_transform,
            cfg.bonus,
            cfg.intrinsic.init_from,
            inverse_head=inverse_head(bonus_loss),
        )
        print(f"Bonus model from {cfg.intrinsic.init_from} ({source_frames} frames).")
    if bonus_transform is not None:
        # the bonus model (and its normalisation statistics) with the learner
        bonus_transform.to(device)
        bonus_loss.to(device)
    return bonus_transform, bonus_loss, env_side


def train(cfg, run: TrainingRun, t: Training) -> tuple[int, float]:
    """The loop of updates (steps 1-5); returns the frames done and frames/s."""
    frames = t.progress.frames
    # CPU seconds of this process (all its threads) in the loop: frames per CPU
    # second are what a shared machine's load moves least (time/fps_cpu). Not
    # the collector's worker processes' (collector.workers > 1): there the envs
    # step elsewhere and time/fps_cpu overstates the run's frames per CPU second.
    cpu_start = time.process_time()
    variant = cfg.intrinsic.vae.variant if cfg.bonus == "vae" else None
    fps = 0.0
    # Step 1: the collector's batch
    for data in t.collector:
        frames += data.numel()
        iteration = frames // data.numel() - 1
        t.stats.update(data)
        # intrinsic.update_steps on every intrinsic.update_every-th batch, else 0
        # (always 0 for a frozen transferred model, finetune=false).
        bonus_steps = bonus_update_steps(cfg, iteration)
        if variant == "info_gain":
            # The bonus is the posterior shift of this batch's VAE update: the VAE
            # trains first (step 5 comes before step 2).
            t.bonus_transform.snapshot()
            bonus_td = train_bonus(cfg, t, data, bonus_steps)
        data = bonus_and_advantage(cfg, t, data)  # steps 2 and 3
        logs = learner_update(cfg, run, t, data, frames)  # step 4
        # Step 5: train the bonus model on the states of this rollout.
        if variant != "info_gain":
            bonus_td = train_bonus(cfg, t, data, bonus_steps)
        if variant == "lagged_kl" and iteration % cfg.intrinsic.vae.lag_updates == 0:
            t.bonus_transform.snapshot()

        # Logging
        fps = run.per_second(frames - run.start_frames)
        if iteration % cfg.logger.log_interval == 0:
            metrics = rollout_metrics(t.stats, data, t.bonus_transform, bonus_td)
            metrics.update({f"train/{k}": v.item() for k, v in logs.items()})
            metrics["time/fps"] = fps
            metrics["time/fps_cpu"] = (frames - run.start_frames) / max(
                time.process_time() - cpu_start, 1e-9
            )
            run.log(metrics, step=frames)
            run.progress_bar.set_postfix(
                fps=f"{fps:.0f}", ret=f"{t.stats.mean_return:.3f}"
            )
        t.progress.frames = frames
        maybe_evaluate(cfg, run, t, frames)
        # Progress, periodic checkpoint, stop on a signal (common/run.py)
        run.after_update()
    return frames, fps


def train_bonus(cfg, t: Training, data, steps: int):
    """Step 5: ``steps`` gradient steps of the bonus model on the batch's states
    (``intrinsic.batch_size`` of its transitions a step, or all of them)."""
    return train_bonus_model(
        t.bonus_loss, t.bonus_optim, data, steps, t.env_side, cfg.intrinsic.batch_size
    )


def bonus_and_advantage(cfg, t: Training, data):
    """Steps 2 and 3: the bonus of the whole rollout, with the bonus model as it
    was during it, then the advantages and value targets, once: GAE on the
    (mixed) reward, or the two streams (TwoStreamAdvantage)."""
    with torch.no_grad():
        if t.bonus_transform is not None:
            data = t.bonus_transform(data)
        if t.reward_clip is not None:
            data = t.reward_clip(data)
        data = t.advantage(data)
        if cfg.algo.name == "a2c" and cfg.loss.normalize_advantage:
            data = utils.standardize_advantage(
                data, t.loss_module.tensor_keys.advantage
            )
    return data


def learner_update(cfg, run: TrainingRun, t: Training, data, frames: int):
    """Step 4: the learner's update, on the whole batch (A2C) or on epochs of
    shuffled minibatches (PPO); returns the means of its logged losses. A loss
    or a parameter that goes non-finite stops the run, naming it."""
    logged = utils.LOGGED_LOSSES[cfg.algo.name]
    max_grad_norm = cfg.optim.max_grad_norm
    minibatch_logs = {}
    for batch in utils.minibatches(data, t.batches, cfg.loss.epochs):
        # The shared trunk once, with gradients: the losses' heads read its
        # features.
        batch = t.trunk(batch)
        loss_td = t.loss_module(batch)
        loss = (
            loss_td["loss_objective"] + loss_td["loss_critic"] + loss_td["loss_entropy"]
        )
        logs = {key: loss_td[key].detach() for key in logged}
        if t.int_value_loss is not None:
            loss_int = t.int_value_loss(batch)["loss_critic_int"]
            loss = loss + loss_int
            logs["loss_critic_int"] = loss_int.detach()
        run.check_finite(frames, **{k: v for k, v in logs.items() if "loss" in k})
        t.optim.zero_grad()
        loss.backward()
        logs["grad_norm"] = torch.nn.utils.clip_grad_norm_(t.params, max_grad_norm)
        t.optim.step()
        for key, value in logs.items():
            minibatch_logs.setdefault(key, []).append(value)
    run.check_finite(frames, model=t.model, int_value=t.int_value)
    return {key: torch.stack(values).mean() for key, values in minibatch_logs.items()}


def maybe_evaluate(cfg, run: TrainingRun, t: Training, frames: int) -> None:
    """Every ``eval.interval_frames``: the policy on the evaluation envs, on
    extrinsic reward only."""
    if frames < t.progress.next_eval:
        return
    t.progress.next_eval += cfg.eval.interval_frames
    t.model.eval()
    result = evaluate(
        t.eval_env,
        t.policy,
        cfg.eval.episodes,
        seed=t.eval_seed,
        deterministic=cfg.eval.deterministic,
    )
    t.model.train()
    run.log(
        {
            "eval/episode_return": result.mean_return,
            "eval/success_rate": result.success_rate,
        },
        step=frames,
    )


def finish(cfg, run: TrainingRun, t: Training, frames: int, fps: float) -> None:
    """The final checkpoint and learning curve, the video, and what the committed
    results measured on this task at this budget."""
    algo = cfg.algo.name
    stats = t.stats
    run.finish(
        f"{frames} frames, {stats.episodes} episodes, last "
        f"{cfg.logger.episode_window}-episode mean return {stats.mean_return:.3f}, "
        f"success rate {stats.success_rate:.2f}, {fps:.0f} frames/s.",
        curves={"train/episode_return": cfg.bonus},
        title=f"{cfg.env.name}: {algo.upper()} + {cfg.bonus} (seed {cfg.seed})",
        ylabel=f"extrinsic return ({cfg.logger.episode_window}-episode mean)",
        optimum=oracle_optimum(cfg.env.name, t.eval_seed, cfg.env.stochasticity),
    )
    if cfg.eval.video:
        # The final policy on the evaluation's first episodes, as a GIF (and to a
        # logger that shows videos); torch's generators are left as they were.
        video = record_minigrid_video(
            cfg, t.policy, run.run_dir, frames, seed=t.eval_seed, logger=run.logger
        )
        print(f"Video: {video}")
    measured = measured_comparison(
        cfg.env.name,
        cfg.env.backend,
        cfg.collector.total_frames,
        Path(__file__).resolve().parents[2] / "docs" / "results",
        f"{algo}_minigrid",
        stochasticity=cfg.env.stochasticity,
        run_return=stats.mean_return,
    )
    if measured:
        print(measured)


if __name__ == "__main__":
    if sweep_requested(sys.argv):
        # Sweep launchers pickle the task function for their worker processes,
        # where the modules beside the script are not importable (submitit, Ray).
        register_sweep_pickling(utils, common)
    main()
