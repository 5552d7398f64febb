"""Resume checks of ``prepare_run`` on a run directory, without running a recipe."""

from __future__ import annotations

import pytest
from omegaconf import OmegaConf

from common.run import prepare_run, save_checkpoint


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
    save_checkpoint(tmp_path / "checkpoint.pt", {"frames": 64, "config": saved})
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
