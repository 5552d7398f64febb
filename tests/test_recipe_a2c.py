"""The A2C MiniGrid recipe, run end to end as a user runs it (tiny budgets)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pandas as pd
import pytest
import torch
from _recipe_run import (
    SharedRun,
    assert_resume_refused,
    differing_logs,
    kill_after_checkpoint,
    load_recipe_utils,
    run_sweep,
    shared_run,
    wait_for_checkpoint,
)
from tensordict import TensorDict

from common.checkpoint import load_checkpoint
from common.scalar_logs import read_scalar_csv
from results.heatmap import load_bonus_transform

RECIPES = Path(__file__).resolve().parents[1] / "recipes"
MAIN = RECIPES / "minigrid" / "main.py"
AGGREGATE = RECIPES / "results" / "aggregate.py"
TINY = [
    # minigrid's envs (the PPO recipe's tests run on envpool, the default)
    "env.backend=gymnasium",
    "env.name=MiniGrid-MultiRoom-N3-S4-v0",
    "env.num_envs=4",
    "collector.frames_per_env=8",
    "eval.interval_frames=256",
    "eval.episodes=4",
    "eval.num_envs=2",
    "checkpoint.interval_frames=128",
    "logger.log_interval=1",
]


def run_recipe(run_dir: Path, *overrides: str, check: bool = True):
    cmd = [sys.executable, str(MAIN), f"hydra.run.dir={run_dir}", *TINY, *overrides]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
    if check and proc.returncode != 0:
        raise AssertionError(
            f"recipe failed:\n{proc.stdout[-3000:]}\n{proc.stderr[-3000:]}"
        )
    return proc


# Runs that several tests read, each made once (tests/_recipe_run.py: shared_run).
# A VAE run checkpointed only at its end: the reference of the seed test and of the
# restart without a checkpoint.
VAE_RUN = [
    "bonus=vae",
    "collector.total_frames=384",
    "seed=3",
    "checkpoint.interval_frames=10000",
]
# An RND run: the end-to-end run of bonus=rnd and the reference of its resume test.
RND_RUN = ["bonus=rnd", "collector.total_frames=1024"]


@pytest.fixture(scope="module")
def vae_run(tmp_path_factory):
    return shared_run(tmp_path_factory, "a2c_vae", lambda d: run_recipe(d, *VAE_RUN))


@pytest.fixture(scope="module")
def rnd_run(tmp_path_factory):
    return shared_run(tmp_path_factory, "a2c_rnd", lambda d: run_recipe(d, *RND_RUN))


@pytest.fixture(scope="module")
def every_bonus(tmp_path_factory) -> SharedRun:
    """A sweep over the bonuses but RND (its run is ``rnd_run``), its runs in
    ``<sweep>/<bonus>``, one after the other in one process (start-up is most of a
    tiny run's time). They keep their periodic checkpoints (points of training);
    the RND run keeps only its last."""

    def make(sweep_dir: Path) -> subprocess.CompletedProcess:
        keep, total = "checkpoint.keep=true", "collector.total_frames=512"
        return run_sweep(
            MAIN, sweep_dir, "${bonus}", *TINY, "bonus=none,vae,icm", keep, total
        )

    return shared_run(tmp_path_factory, "a2c_every_bonus", make)


@pytest.mark.parametrize("bonus", ["none", "vae", "icm", "rnd"])
def test_every_bonus_runs_end_to_end(request, bonus):
    keep = bonus != "rnd"
    frames = 512 if keep else 1024
    shared = request.getfixturevalue("every_bonus" if keep else "rnd_run")
    run_dir = shared.path / bonus if keep else shared.path
    stdout = shared.stdout
    assert f"Learning curve: {run_dir / 'learning_curve.png'}" in stdout
    assert (run_dir / "learning_curve.png").stat().st_size > 0
    assert (run_dir / "config_resolved.yaml").exists()
    scalars = run_dir / "logs" / "a2c" / "scalars"
    steps, fps = read_scalar_csv(scalars / "time" / "fps.csv")
    assert steps[-1] == frames and (fps > 0).all()
    assert (scalars / "eval" / "episode_return.csv").exists()
    if bonus != "none":
        _, raw = read_scalar_csv(scalars / "train" / "intrinsic_reward.csv")
        assert torch.isfinite(torch.as_tensor(raw)).all()
        assert list((scalars / "bonus").iterdir()), "bonus-model losses are logged"
    ckpt = load_checkpoint(run_dir / "checkpoint.torchrl")
    assert ckpt["frames"] == frames
    if keep:
        # one per checkpoint.interval_frames (128), each at its own frame count
        kept = sorted((run_dir / "checkpoints").glob("*.torchrl"))
        assert [p.name for p in kept] == [
            f"checkpoint-{n:012d}.torchrl" for n in (128, 256, 384, 512)
        ]
        assert load_checkpoint(kept[1])["frames"] == 256
    if bonus == "vae":
        _, _, frames = load_bonus_transform(kept[1])
        assert frames == 256
        early = load_checkpoint(kept[0])["bonus_transform"]
        late = ckpt["bonus_transform"]
        assert any(not torch.equal(early[k], late[k]) for k in early if "vae." in k)
    if not keep:
        assert not (run_dir / "checkpoints").exists()


VARIANTS = ["neg_elbo", "info_gain", "lagged_kl", "noveld"]


@pytest.fixture(scope="module")
def vae_variants(tmp_path_factory) -> Path:
    """A sweep over the VAE's variants, its runs in ``<sweep>/<variant>``, one after
    the other in one process (start-up is most of a tiny run's time). Every variant
    trains the VAE on every batch: info_gain and lagged_kl refuse a longer period."""

    def make(sweep_dir: Path) -> subprocess.CompletedProcess:
        return run_sweep(
            MAIN,
            sweep_dir,
            "${intrinsic.vae.variant}",
            *TINY,
            "bonus=vae",
            f"intrinsic.vae.variant={','.join(VARIANTS)}",
            "intrinsic.vae.lag_updates=2",
            "intrinsic.update_every=1",
            "collector.total_frames=256",
        )

    return shared_run(tmp_path_factory, "a2c_vae_variants", make).path


@pytest.mark.parametrize("variant", VARIANTS)
def test_vae_variants_run_end_to_end(vae_variants, variant):
    run_dir = vae_variants / variant
    _, raw = read_scalar_csv(run_dir / "logs/a2c/scalars/train/intrinsic_reward.csv")
    assert torch.isfinite(torch.as_tensor(raw)).all() and (raw > 0).any()
    # the variant's own state is in the checkpoint: NovelD's first-visit sets,
    # the posterior shift's reference copy
    state = load_checkpoint(run_dir / "checkpoint.torchrl")["bonus_transform"]
    own = {"noveld": "visits.", "info_gain": "reference.", "lagged_kl": "reference."}
    if variant in own:
        assert any(key.startswith(own[variant]) for key in state), sorted(state)


def test_transfer_starts_the_bonus_model_from_another_run(tmp_path):
    source = tmp_path / "source"
    # with the inverse model on the VAE's latent, which starts from the source's too
    inverse = "intrinsic.vae.inverse_weight=1.0"
    run_recipe(source, "bonus=vae", inverse, "collector.total_frames=128")
    frozen = tmp_path / "frozen"
    out = run_recipe(
        frozen,
        "bonus=vae",
        inverse,
        "env.name=MiniGrid-DoorKey-5x5-v0",
        f"intrinsic.init_from={source}",
        "intrinsic.finetune=false",
        "collector.total_frames=128",
    ).stdout
    assert "Bonus model from" in out
    heads = [
        load_checkpoint(run / "checkpoint.torchrl")["bonus_inverse_head"]
        for run in (source, frozen)
    ]
    assert all(torch.equal(heads[0][k], heads[1][k]) for k in heads[0])

    def vae_weights(run):
        state = load_checkpoint(run / "checkpoint.torchrl")["bonus_transform"]
        return {k: v for k, v in state.items() if k.startswith("vae.")}

    src, dst = vae_weights(source), vae_weights(frozen)
    assert src.keys() == dst.keys() and all(torch.equal(src[k], dst[k]) for k in src)
    proc = run_recipe(
        tmp_path / "bad",
        "bonus=icm",
        f"intrinsic.init_from={source}",
        "collector.total_frames=128",
        check=False,
    )
    assert proc.returncode != 0 and "bonus='vae'" in proc.stderr


def test_same_seed_same_curve(tmp_path, vae_run):
    # Again as the second job of a sweep: the first job (another seed) leaves
    # nothing to it that would change what it logs.
    other_seeds = [*(a for a in VAE_RUN if not a.startswith("seed=")), "seed=4,3"]
    run_sweep(MAIN, tmp_path, "${seed}", *TINY, *other_seeds)
    assert differing_logs(vae_run.path, tmp_path / "3") == []
    assert "logs/a2c/scalars/train/loss_critic.csv" in differing_logs(
        vae_run.path, tmp_path / "4"
    )


def test_standardize_advantage_centres_and_scales_the_batch_without_nans():
    utils = load_recipe_utils(MAIN.parent)
    adv = torch.randn(4, 8, 1) * 3.0 + 2.0
    data = TensorDict({"adv": adv.clone(), "other": adv.clone()}, batch_size=[4, 8])
    out = utils.standardize_advantage(data, "adv")
    assert out["adv"].mean().abs() < 1e-5
    assert (out["adv"].std() - 1.0).abs() < 1e-5
    assert torch.equal(out["other"], adv), "only the advantage changes"
    flat = TensorDict({"advantage": torch.full((5, 1), 0.3)}, batch_size=[5])
    assert torch.equal(
        utils.standardize_advantage(flat)["advantage"], torch.zeros(5, 1)
    )


def test_normalized_advantages_change_the_policy_term_only(tmp_path):
    # Same seed, same first batch: the critic's target is the unnormalised return,
    # so the first update's critic loss is the same and the policy term is not.
    args = ["bonus=none", "collector.total_frames=32", "seed=3"]
    subdir = "${loss.normalize_advantage}"
    run_sweep(
        MAIN, tmp_path, subdir, *TINY, *args, "loss.normalize_advantage=false,true"
    )

    def first(run: str, name: str) -> float:
        path = tmp_path / run / "logs" / "a2c" / "scalars" / "train" / f"{name}.csv"
        return read_scalar_csv(path)[1][0]

    assert first("False", "loss_critic") == first("True", "loss_critic")
    assert first("False", "loss_objective") != first("True", "loss_objective")


@pytest.mark.parametrize(
    "overrides",
    [
        # with the inverse head on the VAE's latent, which the checkpoint holds
        [
            "bonus=vae",
            "env.stochasticity=2",
            "intrinsic.update_every=3",
            "intrinsic.vae.inverse_weight=1.0",
        ],
        ["bonus=rnd"],
    ],
    ids=["vae-inverse-noise-every3", "rnd"],
)
def test_killed_and_resumed_run_logs_what_the_uninterrupted_run_logs(
    tmp_path, request, overrides
):
    total = "collector.total_frames=1024"
    if [*overrides, total] == RND_RUN:
        whole = request.getfixturevalue("rnd_run").path
    else:
        whole = tmp_path / "whole"
        run_recipe(whole, *overrides, total)
    if "intrinsic.update_every=3" in overrides:
        # the VAE trains (and logs its losses) after rollouts 0, 3, 6, ... only
        steps, _ = read_scalar_csv(
            whole / "logs/a2c/scalars/bonus/loss_reconstruction.csv"
        )
        rollouts = [int(s) // 32 - 1 for s in steps]  # TINY: 4 envs x 8 frames
        assert rollouts == list(range(0, 1024 // 32, 3))
    killed_dir = tmp_path / "killed"
    cmd = [sys.executable, str(MAIN), f"hydra.run.dir={killed_dir}", *TINY]
    killed = kill_after_checkpoint(
        [*cmd, *overrides, total], killed_dir / "checkpoint.torchrl", min_frames=256
    )
    assert 256 <= killed["frames"] < 1024, "the kill must land mid-run"
    run_recipe(killed_dir, *overrides, total)
    assert differing_logs(whole, killed_dir) == []


def test_a_run_killed_before_its_first_checkpoint_restarts_without_its_old_rows(
    tmp_path, vae_run
):
    # killed before any checkpoint: logs on disk, no checkpoint
    killed_dir = tmp_path / "killed"
    run_recipe(killed_dir, *VAE_RUN)
    (killed_dir / "checkpoint.torchrl").unlink()
    run_recipe(killed_dir, *VAE_RUN)
    assert differing_logs(vae_run.path, killed_dir) == []


def test_sigint_and_sigterm_save_a_checkpoint_and_exit_cleanly(tmp_path):
    for sig in (signal.SIGINT, signal.SIGTERM):
        run_dir = tmp_path / sig.name
        cmd = [sys.executable, str(MAIN), f"hydra.run.dir={run_dir}", *TINY]
        proc = subprocess.Popen(
            [*cmd, "bonus=vae", "collector.total_frames=1000000"],
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        wait_for_checkpoint(run_dir / "checkpoint.torchrl", min_frames=128)
        proc.send_signal(sig)
        out, err = proc.communicate(timeout=60)
        assert proc.returncode == 128 + sig, err[-2000:]
        assert "Traceback" not in err
        assert f"{sig.name}: stopped at" in out and "Resume with:" in out
        frames = load_checkpoint(run_dir / "checkpoint.torchrl")["frames"]
        steps, _ = read_scalar_csv(run_dir / "logs/a2c/scalars/train/reward.csv")
        assert steps[-1] == frames, "the checkpoint holds every logged step"
    target = f"collector.total_frames={frames + 64}"
    out = run_recipe(run_dir, "bonus=vae", target).stdout
    assert f"Done: {frames + 64} frames" in out


def test_resume_refuses_a_changed_experiment_and_never_overwrites_a_run(tmp_path):
    run_dir = tmp_path / "run"
    run_recipe(run_dir, "bonus=vae", "collector.total_frames=128")
    config = (run_dir / "config_resolved.yaml").read_text()
    # Three changes at once: the refusal names each (one process; what counts as a
    # change: config_differences' doctests in recipes/common/rundir.py).
    changes = {
        "env.name=MiniGrid-DoorKey-5x5-v0": (
            "env.name: 'MiniGrid-MultiRoom-N3-S4-v0' -> 'MiniGrid-DoorKey-5x5-v0'"
        ),
        "bonus=none": "bonus: 'vae' -> 'none'",
        "intrinsic.vae.latent_dim=8": "intrinsic.vae.latent_dim: 32 -> 8",
    }
    proc = run_recipe(run_dir, *changes, "collector.total_frames=256", check=False)
    assert_resume_refused(proc, *changes.values())
    assert (run_dir / "config_resolved.yaml").read_text() == config
    proc = run_recipe(
        run_dir, "bonus=vae", "resume=false", "collector.total_frames=256", check=False
    )
    assert proc.returncode != 0 and "already holds a checkpoint" in proc.stderr
    assert load_checkpoint(run_dir / "checkpoint.torchrl")["frames"] == 128
    # What does not change the experiment may change: longer, other logging, the
    # name of the experiment the run is filed under.
    run_recipe(
        run_dir,
        "bonus=vae",
        "collector.total_frames=256",
        "eval.episodes=2",
        "experiment_name=renamed",
    )
    assert load_checkpoint(run_dir / "checkpoint.torchrl")["frames"] == 256


# submitit_local starts a process per job at once: 2 jobs (one seed) keep it short.
@pytest.mark.parametrize("launcher, seeds", [("local", 2), ("submitit_local", 1)])
def test_sweep_runs_each_job_once_and_a_rerun_starts_no_new_work(
    tmp_path, launcher, seeds
):
    sweep = [
        sys.executable,
        str(MAIN),
        "-m",
        "+experiment=a2c/tiny",
        f"hydra/launcher={launcher}",
        f"hydra.sweep.dir={tmp_path}",
        "collector.total_frames=256",
        "env.num_envs=4",
        "logger.log_interval=1",
        *(["seed=0"] if seeds == 1 else []),
    ]
    first = subprocess.run(sweep, capture_output=True, text=True, timeout=600)
    assert first.returncode == 0, first.stderr[-3000:]
    ckpts = sorted(tmp_path.glob("*/checkpoint.torchrl"))
    names = sorted(p.parent.name for p in ckpts)
    assert len(names) == 2 * seeds and any("+setting=vae" in n for n in names)
    assert all(load_checkpoint(p)["frames"] == 256 for p in ckpts)
    mtimes = [p.stat().st_mtime_ns for p in ckpts]
    # Rerun with what may change on resume (other evaluation and logging): the
    # jobs find their directories, and there is nothing to do.
    rerun = [*sweep, "eval.episodes=2", "logger.log_interval=2"]
    again = subprocess.run(rerun, capture_output=True, text=True, timeout=600)
    assert again.returncode == 0, again.stderr[-3000:]
    assert sorted(p.parent.name for p in tmp_path.glob("*/.hydra")) == names
    assert [p.stat().st_mtime_ns for p in ckpts] == mtimes
    if launcher != "local":
        return
    # The aggregation command turns the sweep into a table with IQM and CIs.
    out = tmp_path / "results"
    cmd = [sys.executable, str(AGGREGATE)]
    subprocess.run([*cmd, str(tmp_path), "--out", str(out), "--reps", "50"], check=True)
    summary = pd.read_csv(out / "summary.csv")
    assert sorted(summary["setting"]) == ["none", "vae"]
    assert (summary["seeds"] == 2).all()
    assert summary[["train_return_iqm", "train_return_ci_low"]].notna().all().all()


def test_sigterm_to_a_local_sweep_stops_every_job_and_starts_no_new_one(tmp_path):
    # 4 jobs, 2 at a time: SIGTERM to the sweep's process group (what a scheduler or
    # `kill -- -PGID` sends) must save the 2 running jobs and leave no joblib worker
    # behind to start the 2 queued ones with no parent.
    sweep_dir = tmp_path / "sweep"
    sweep = [
        sys.executable,
        str(MAIN),
        "-m",
        "+experiment=a2c/tiny",
        f"hydra.sweep.dir={sweep_dir}",
        "hydra.launcher.n_jobs=2",
        "collector.total_frames=1000000",
        "checkpoint.interval_frames=128",
        "eval.interval_frames=1000000",
        "logger.log_interval=1",
    ]
    err = tmp_path / "stderr.txt"
    with open(err, "w") as stderr:
        proc = subprocess.Popen(
            sweep, stdout=subprocess.DEVNULL, stderr=stderr, start_new_session=True
        )
    try:
        deadline = time.time() + 300
        while len(list(sweep_dir.glob("*/checkpoint.torchrl"))) < 2:
            assert time.time() < deadline, "the sweep wrote no 2 checkpoints"
            assert proc.poll() is None, err.read_text()[-3000:]
            time.sleep(0.2)
        started = sorted(p.parent.name for p in sweep_dir.glob("*/.hydra"))
        os.killpg(proc.pid, signal.SIGTERM)
        proc.wait(timeout=120)
        deadline = time.time() + 60
        while group_alive(proc.pid):
            assert time.time() < deadline, "a process of the sweep outlived SIGTERM"
            time.sleep(0.2)
    finally:
        if group_alive(proc.pid):
            os.killpg(proc.pid, signal.SIGKILL)
    assert sorted(p.parent.name for p in sweep_dir.glob("*/.hydra")) == started
    assert len(started) == 2, started
    for name in started:
        frames = load_checkpoint(sweep_dir / name / "checkpoint.torchrl")["frames"]
        steps, _ = read_scalar_csv(
            sweep_dir / name / "logs/a2c/scalars/train/reward.csv"
        )
        assert steps[-1] == frames, f"{name}: the stop saved no final checkpoint"


def group_alive(pgid: int) -> bool:
    try:
        os.killpg(pgid, 0)
    except ProcessLookupError:
        return False
    return True


@pytest.mark.parametrize(
    "override, message",
    [
        # refused by what the run builds or finds (the config's validation:
        # test_configs.py, every setting in-process, one on the command line)
        ("env.name=MiniGrid-NoSuchEnv-v0", "MiniGrid-NoSuchEnv-v0"),
        ("resume=true", "no checkpoint"),
    ],
)
def test_bad_config_fails_clearly(tmp_path, override, message):
    proc = run_recipe(tmp_path / "bad", override, check=False)
    assert proc.returncode != 0
    assert message in proc.stdout + proc.stderr
