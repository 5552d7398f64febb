"""Resume checks of ``prepare_run`` on a run directory, and the checkpoint format
(``RunCheckpoint``), without running a recipe."""

from __future__ import annotations

import random

import numpy as np
import pytest
import torch
from omegaconf import OmegaConf

from common.checkpoint import (
    CHECKPOINT_NAME,
    LEGACY_CHECKPOINT_NAME,
    RunCheckpoint,
    RunCounters,
    load_checkpoint,
)
from common.run import TrainingRun
from common.rundir import prepare_run, seed_everything


def config(bonus: str, variant: str = "kl"):
    return OmegaConf.create(
        {
            "seed": 0,
            "resume": "auto",
            "torch_threads": 1,
            "bonus": bonus,
            "env": {"name": "MiniGrid-MultiRoom-N3-S4-v0"},
            "intrinsic": {"coef": 0.5, "vae": {"variant": variant}, "icm": {}},
        }
    )


def checkpointed_run(tmp_path, cfg):
    saved = OmegaConf.to_container(cfg, resolve=True)
    tmp_path.mkdir(parents=True, exist_ok=True)
    counters = RunCounters(frames=64)
    RunCheckpoint(tmp_path / CHECKPOINT_NAME, {"progress": counters}, saved).save()
    return tmp_path


@pytest.mark.parametrize("bonus", ["icm", "none"])
def test_a_new_default_for_an_unused_bonus_leaves_the_run_resumable(tmp_path, bonus):
    run_dir = checkpointed_run(tmp_path, config(bonus, variant="kl"))
    _, ckpt = prepare_run(config(bonus, variant="elliptical"), run_dir)
    assert ckpt["frames"] == 64


def test_a_changed_setting_of_the_bonus_in_use_is_refused(tmp_path):
    run_dir = checkpointed_run(tmp_path, config("vae", variant="kl"))
    with pytest.raises(ValueError, match=r"intrinsic\.vae\.variant: 'kl' -> 'ell"):
        prepare_run(config("vae", variant="elliptical"), run_dir)


def test_a_changed_bonus_is_refused(tmp_path):
    run_dir = checkpointed_run(tmp_path, config("icm"))
    with pytest.raises(ValueError, match=r"bonus: 'icm' -> 'vae'"):
        prepare_run(config("vae"), run_dir)


def test_none_run_refuses_a_changed_coefficient_only_when_it_reads_it(tmp_path):
    # a bonus=none run never reads intrinsic.*: its coef may change
    run_dir = checkpointed_run(tmp_path, config("none"))
    cfg = config("none")
    cfg.intrinsic.coef = 0.1
    prepare_run(cfg, run_dir)
    # a vae run does
    vae_dir = checkpointed_run(tmp_path / "vae", config("vae"))
    cfg = config("vae")
    cfg.intrinsic.coef = 0.1
    with pytest.raises(ValueError, match=r"intrinsic\.coef"):
        prepare_run(cfg, vae_dir)


def run_config():
    cfg = config("none")
    cfg.collector = {"total_frames": 1024}
    cfg.logger = {"backend": "", "project_name": "p"}
    cfg.checkpoint = {"interval_frames": 128}
    return cfg


def test_the_checkpoint_restores_state_and_the_random_generators_last(tmp_path):
    cfg = run_config()
    net, counters = torch.nn.Linear(3, 2), RunCounters(frames=256, next_ckpt=384)
    seed_everything(1)
    RunCheckpoint(
        tmp_path / CHECKPOINT_NAME,
        {"net": net, "progress": counters},
        OmegaConf.to_container(cfg),
    ).save()
    draws = (random.random(), np.random.rand(), torch.rand(3))

    run = TrainingRun(cfg, "demo", run_dir=tmp_path)  # seeds with cfg.seed
    other, restored = torch.nn.Linear(3, 2), RunCounters(frames=0, next_ckpt=128)
    torch.rand(5)  # building a run draws random numbers: restored over
    run.restore({"net": other, "progress": restored}, show_progress=False)
    assert restored.state_dict() == {"frames": 256, "next_ckpt": 384}
    assert all(torch.equal(a, b) for a, b in zip(net.parameters(), other.parameters()))
    again = (random.random(), np.random.rand(), torch.rand(3))
    assert draws[:2] == again[:2] and torch.equal(draws[2], again[2])


def test_a_checkpoint_of_the_previous_release_still_resumes(tmp_path):
    # 0.2 wrote checkpoint.pt, a torch.save of a dict, RNG under python/numpy/torch
    cfg = run_config()
    net = torch.nn.Linear(3, 2)
    seed_everything(1)
    legacy = {
        "progress": {"frames": 256, "next_ckpt": 384},
        "net": net.state_dict(),
        "rng": {
            "python": random.getstate(),
            "numpy": np.random.get_state(),
            "torch": torch.get_rng_state(),
        },
        "config": OmegaConf.to_container(cfg),
        "frames": 256,
    }
    torch.save(legacy, tmp_path / LEGACY_CHECKPOINT_NAME)
    draws = (random.random(), torch.rand(3))
    assert load_checkpoint(tmp_path / LEGACY_CHECKPOINT_NAME)["frames"] == 256

    run = TrainingRun(cfg, "demo", run_dir=tmp_path)
    other, restored = torch.nn.Linear(3, 2), RunCounters(frames=0, next_ckpt=128)
    run.restore({"net": other, "progress": restored}, show_progress=False)
    assert restored.frames == 256
    assert torch.equal(net.weight, other.weight)
    again = (random.random(), torch.rand(3))
    assert draws[0] == again[0] and torch.equal(draws[1], again[1])
    # its successor, once written, replaces it
    restored.frames = 384
    run.after_update()
    assert not (tmp_path / LEGACY_CHECKPOINT_NAME).exists()
    assert load_checkpoint(tmp_path / CHECKPOINT_NAME)["frames"] == 384
    run.finish("384 frames.", curves={})


def test_a_failed_write_keeps_the_previous_checkpoint_and_leaves_no_temporary(
    tmp_path, monkeypatch
):
    from torchrl.checkpoint import Checkpoint

    counters = RunCounters(frames=128)
    ckpt = RunCheckpoint(tmp_path / CHECKPOINT_NAME, {"progress": counters}, {})
    ckpt.save()
    counters.frames = 256
    save = Checkpoint.save

    def half_written(self, path, **kwargs):
        save(self, path, **kwargs)  # written, then the disk fills up
        with open(path, "r+b") as f:
            f.truncate(10)
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(Checkpoint, "save", half_written)
    with pytest.raises(OSError, match="checkpoint.torchrl: no space left on device"):
        ckpt.save()
    assert load_checkpoint(tmp_path / CHECKPOINT_NAME)["frames"] == 128
    assert sorted(p.name for p in tmp_path.iterdir()) == [CHECKPOINT_NAME]


def test_a_setting_added_with_a_new_behaviour_is_compared_with_the_old_one():
    # E3B's episode start: a checkpoint written before the setting existed ran
    # with start_in_memory=False, which is what a resume must keep.
    from common.rundir import config_differences

    saved = {"bonus": "e3b", "intrinsic": {"e3b": {"ridge": 0.1}}}
    now = {"bonus": "e3b", "intrinsic": {"e3b": {"ridge": 0.1}}}
    now["intrinsic"]["e3b"]["start_in_memory"] = True
    assert config_differences(saved, now) == [
        "intrinsic.e3b.start_in_memory: False -> True"
    ]
    now["intrinsic"]["e3b"]["start_in_memory"] = False
    assert config_differences(saved, now) == []
