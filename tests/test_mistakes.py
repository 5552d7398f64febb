"""A user's mistake is one message: what is wrong, where, what to do; no
traceback, exit status 2, and a launch refused before its run starts leaves
nothing behind (nor changes a run directory that holds a run)."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
import torch
from _recipe_run import shared_run

from common.checkpoint import RunCheckpoint, RunCounters, load_checkpoint
from common.errors import NonFiniteRun

ROOT = Path(__file__).resolve().parents[1]
MAIN = ROOT / "recipes" / "minigrid" / "main.py"
DDPG_MAIN = ROOT / "recipes" / "ddpg_mujoco" / "main.py"
TINY = [
    "collector.total_frames=128",
    "env.num_envs=4",
    "collector.frames_per_env=8",
    "eval.interval_frames=128",
    "eval.episodes=2",
    "eval.num_envs=2",
    "checkpoint.interval_frames=128",
]


def launch(main: Path, run_dir: Path, *overrides: str, env=None):
    cmd = [sys.executable, str(main), f"hydra.run.dir={run_dir}", *overrides]
    return subprocess.run(cmd, capture_output=True, text=True, timeout=300, env=env)


def assert_one_message(proc, *words: str) -> str:
    """``proc`` exited 2 with one ``Error:`` line naming ``words``, no traceback."""
    assert proc.returncode == 2, proc.stderr[-3000:]
    assert "Traceback" not in proc.stderr, proc.stderr[-3000:]
    errors = [line for line in proc.stderr.splitlines() if line.startswith("Error:")]
    assert len(errors) == 1, proc.stderr[-3000:]
    missing = [word for word in words if word not in errors[0]]
    assert not missing, f"{errors[0]!r} does not name {missing}"
    return errors[0]


@pytest.fixture(scope="module")
def finished_run(tmp_path_factory):
    """A finished tiny run, copied by each test that changes it."""

    def make(run_dir: Path):
        proc = launch(MAIN, run_dir, *TINY)
        assert proc.returncode == 0, proc.stderr[-3000:]
        return proc

    return shared_run(tmp_path_factory, "mistakes_run", make).path


def snapshot(run_dir: Path) -> dict[str, bytes]:
    # run.lock names the last process that took the lock (for the message that
    # refuses another); everything else must stay as it was
    return {
        p.relative_to(run_dir).as_posix(): p.read_bytes()
        for p in sorted(run_dir.rglob("*"))
        if p.is_file() and p.name != "run.lock"
    }


# Refused by the config's checks: in one process (each message as a user reads it)
CONFIG_MISTAKES = [
    ("intrinsic.coef_end=nan", ["intrinsic.coef_end", "nan"]),
    ("optim.lr=inf", ["optim.lr", "inf"]),
    # RMSprop and Adam divide by sqrt(v) + eps: 0 goes non-finite
    ("optim.eps=0", ["optim.eps", "> 0"]),
    ("env.backend=foo", ["env.backend", "'foo'"]),
    ("bonus=nosuchbonus", ["bonus", "'e3b'", "nosuchbonus"]),
    # a misspelt key added with "+" (Hydra's hint for a key it does not know)
    ("+intrinsic.coeff=0.1", ["intrinsic.coeff", "intrinsic.coef?"]),
]


@pytest.mark.parametrize("override, words", CONFIG_MISTAKES)
def test_a_bad_setting_is_a_config_error_naming_it(override, words):
    from hydra import compose, initialize_config_dir

    from common.config import validate_minigrid
    from common.errors import ConfigError

    with initialize_config_dir(str(MAIN.parent), version_base=None):
        cfg = compose("config", overrides=[override])
    with pytest.raises(ConfigError) as refused:
        validate_minigrid(cfg)
    missing = [word for word in words if word not in str(refused.value)]
    assert not missing, f"{refused.value} does not name {missing}"


# ... and end to end, as a user launches them: the recipes' scripts
@pytest.mark.parametrize(
    "main, override, words",
    [
        (MAIN, "intrinsic.coef_end=nan", ["intrinsic.coef_end", "nan"]),
        (MAIN, "env.name=NoSuchEnv-v0", ["env.name=NoSuchEnv-v0", "no MiniGrid task"]),
        # a misspelt key added with "+" (eval.video is a DDPG setting since)
        (DDPG_MAIN, "+eval.vidoe=true", ["eval.vidoe", "eval.video?"]),
    ],
)
def test_a_bad_setting_is_one_message_and_leaves_no_file(
    tmp_path, main, override, words
):
    run_dir = tmp_path / "run"
    overrides = TINY if main == MAIN else []
    assert_one_message(launch(main, run_dir, *overrides, override), *words)
    assert not run_dir.exists(), sorted(os.listdir(run_dir))


def test_full_hydra_error_keeps_the_traceback(tmp_path):
    env = {**os.environ, "HYDRA_FULL_ERROR": "1"}
    proc = launch(MAIN, tmp_path / "run", "optim.lr=inf", env=env)
    assert proc.returncode != 0
    assert "Traceback" in proc.stderr and "ConfigError" in proc.stderr


def test_a_changed_experiment_is_one_message_and_changes_nothing(
    tmp_path, finished_run
):
    run_dir = tmp_path / "run"
    shutil.copytree(finished_run, run_dir)
    before = snapshot(run_dir)
    proc = launch(MAIN, run_dir, *TINY, "bonus=icm", "intrinsic.coef=0.9")
    assert_one_message(proc, "experiment changed", "bonus: 'vae' -> 'icm'")
    assert snapshot(run_dir) == before  # .hydra/overrides.yaml included


def test_a_damaged_checkpoint_is_one_message_and_changes_nothing(
    tmp_path, finished_run
):
    run_dir = tmp_path / "run"
    shutil.copytree(finished_run, run_dir)
    checkpoint = run_dir / "checkpoint.torchrl"
    checkpoint.write_bytes(checkpoint.read_bytes()[:1000])
    before = snapshot(run_dir)
    proc = launch(MAIN, run_dir, *TINY, "collector.total_frames=256")
    assert_one_message(proc, str(checkpoint), "is damaged")
    assert snapshot(run_dir) == before


@pytest.mark.parametrize("lock_file", ["kept", "deleted"])
def test_a_run_dir_in_use_is_one_message_and_changes_nothing(
    tmp_path, finished_run, lock_file
):
    # Deleting run.lock (the reflex for a "stale lock") releases nothing.
    run_dir = tmp_path / "run"
    shutil.copytree(finished_run, run_dir)
    holder = subprocess.Popen(
        [
            sys.executable,
            "-c",
            f"import sys, time; sys.path.insert(0, {str(ROOT / 'recipes')!r}); "
            "from common.rundir import RunLock; "
            f"lock = RunLock({str(run_dir)!r}); print('held', flush=True); "
            "time.sleep(300)",
        ],
        stdout=subprocess.PIPE,
        text=True,
    )
    try:
        assert holder.stdout.readline().strip() == "held"
        if lock_file == "deleted":
            (run_dir / "run.lock").unlink()
        before = snapshot(run_dir)
        proc = launch(MAIN, run_dir, *TINY, "bonus=icm")
        named = f"process {holder.pid}" if lock_file == "kept" else "another process"
        assert_one_message(proc, str(run_dir), "is in use by", named)
        assert snapshot(run_dir) == before  # Hydra's record of the run included
    finally:
        holder.kill()
        holder.wait()


def test_a_run_that_diverges_is_one_message_and_keeps_a_finite_checkpoint(tmp_path):
    # A learning rate that overflows the policy within an update or two.
    run_dir = tmp_path / "run"
    overrides = [
        "optim.lr=1e30",
        "collector.total_frames=2048",
        "checkpoint.interval_frames=32",
    ]
    proc = launch(MAIN, run_dir, *TINY, *overrides)
    assert_one_message(proc, "not finite", "Start a new run")
    state = load_checkpoint(run_dir / "checkpoint.torchrl")
    weights = {k: v for k, v in state["model"].items() if v.is_floating_point()}
    assert weights and all(torch.isfinite(v).all() for v in weights.values())


def test_a_non_finite_state_never_replaces_a_finite_checkpoint(tmp_path):
    net, counters = torch.nn.Linear(2, 1), RunCounters(frames=64)
    path = tmp_path / "checkpoint.torchrl"
    checkpoint = RunCheckpoint(path, {"net": net, "progress": counters}, config={})
    checkpoint.save()
    saved = path.read_bytes()
    with torch.no_grad():
        net.weight[0, 1] = float("nan")
    counters.frames = 128
    with pytest.raises(NonFiniteRun, match="net: weight is not finite at 128 frames"):
        checkpoint.save()
    assert path.read_bytes() == saved
    assert sorted(p.name for p in tmp_path.iterdir()) == ["checkpoint.torchrl"]


@pytest.mark.parametrize("name", ["sp ace", "été", "it's", "a\\b", "c\\'d\\"])
def test_the_printed_commands_can_be_pasted_whatever_the_run_dir(tmp_path, name):
    import shlex

    from hydra.core.override_parser.overrides_parser import OverridesParser

    from common.checkpoint import DamagedCheckpoint
    from common.stopping import hydra_path_override

    run_dir = tmp_path / name
    (word,) = shlex.split(hydra_path_override("hydra.run.dir", run_dir))
    assert OverridesParser.create().parse_override(word).value() == str(run_dir)
    # the damaged checkpoint's mv && cp, run by a shell as printed
    kept = run_dir / "checkpoints"
    kept.mkdir(parents=True)
    net, counters = torch.nn.Linear(2, 1), RunCounters(frames=64)
    RunCheckpoint(
        kept / "checkpoint-000000000064.torchrl",
        {"net": net, "progress": counters},
        config={},
    ).save()
    (run_dir / "checkpoint.torchrl").write_bytes(b"garbage")
    message = str(
        DamagedCheckpoint(run_dir / "checkpoint.torchrl", ValueError("x"), run_dir)
    )
    command = message.split("damaged file: ", 1)[1].split("; then", 1)[0]
    subprocess.run(["bash", "-c", command], check=True)
    assert load_checkpoint(run_dir / "checkpoint.torchrl")["frames"] == 64


def test_a_resume_whose_logs_do_not_reach_its_checkpoint_is_refused(
    tmp_path, finished_run
):
    # An emptied scalar log: resumed, the curve would start at the checkpoint.
    run_dir = tmp_path / "emptied"
    shutil.copytree(finished_run, run_dir)
    log = next(run_dir.glob("logs/*/scalars/train/episode_return.csv"))
    log.write_text("")
    proc = launch(MAIN, run_dir, *TINY, "collector.total_frames=256")
    assert_one_message(proc, "episode_return.csv (emptied)", "resume_without_logs")
    # A run that logged nowhere, resumed with the CSV logger.
    run_dir = tmp_path / "unlogged"
    proc = launch(MAIN, run_dir, *TINY, "logger.backend=")
    assert proc.returncode == 0, proc.stderr[-3000:]
    proc = launch(MAIN, run_dir, *TINY, "collector.total_frames=256")
    assert_one_message(proc, "logger.backend=''", "resume_without_logs")


def test_nothing_to_do_changes_nothing(tmp_path, finished_run):
    # A budget below the frames done: nothing runs, and the run's record (Hydra's
    # overrides included) keeps the budget it ran with.
    run_dir = tmp_path / "run"
    shutil.copytree(finished_run, run_dir)
    before = snapshot(run_dir)
    proc = launch(MAIN, run_dir, *TINY, "collector.total_frames=64")
    assert proc.returncode == 0 and "Nothing to do" in proc.stdout, proc.stderr
    assert snapshot(run_dir) == before
