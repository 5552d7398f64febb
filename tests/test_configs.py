"""Every sweep job of the recipes' experiment files composes into a config that the
recipe accepts, with the setting it is labelled by (no run: Hydra's compose API)."""

from __future__ import annotations

import itertools
from pathlib import Path

import pytest
from _recipe_run import load_recipe_utils
from hydra import compose, initialize_config_dir
from omegaconf import OmegaConf

RECIPES = Path(__file__).resolve().parents[1] / "recipes"
EXPERIMENTS = [
    (
        recipe,
        path.relative_to(RECIPES / recipe / "experiment").with_suffix("").as_posix(),
    )
    for recipe in ("minigrid", "ddpg_mujoco")
    for path in sorted((RECIPES / recipe / "experiment").glob("**/*.yaml"))
]


def recipe_check(recipe: str):
    return load_recipe_utils(RECIPES / recipe).check_config


def sweep_values(value) -> list[str]:
    text = str(value)
    if text.startswith("range("):
        return [str(v) for v in range(*map(int, text[6:-1].split(",")))]
    return text.split(",")


@pytest.mark.parametrize(("recipe", "experiment"), EXPERIMENTS)
def test_every_sweep_job_composes_and_passes_the_recipe_checks(recipe, experiment):
    check_config = recipe_check(recipe)
    with initialize_config_dir(config_dir=str(RECIPES / recipe), version_base=None):
        base = [f"+experiment={experiment}"]
        sweep = compose("config", overrides=base, return_hydra_config=True)
        params = {k: sweep_values(v) for k, v in sweep.hydra.sweeper.params.items()}
        assert params, f"{experiment}: no sweep"
        jobs = [dict(zip(params, job)) for job in itertools.product(*params.values())]
        for job in jobs:
            cfg = compose(
                "config", overrides=[*base, *(f"{k}={v}" for k, v in job.items())]
            )
            OmegaConf.to_container(cfg, resolve=True)  # every interpolation resolves
            check_config(cfg)
            assert cfg.experiment_name == experiment.split("/")[-1]
            if "+setting" in job:
                assert cfg.setting == job["+setting"], "a setting file's label"
            variants = OmegaConf.select(cfg, "intrinsic.vae.variant") is not None
            if cfg.bonus == "vae" and "+setting" in job and variants:
                # settings name the VAE variant they measure, never the default
                path = RECIPES / recipe / "setting" / f"{job['+setting']}.yaml"
                text = path.read_text()
                assert "variant:" in text, f"{path.name} must name its VAE variant"


@pytest.mark.parametrize("algo", ["a2c", "ppo"])
@pytest.mark.parametrize(
    ("overrides", "message"),
    [
        (["intrinsic.update_every=0"], "intrinsic.update_every must be a positive"),
        (["intrinsic.update_every=1.5"], "intrinsic.update_every must be a positive"),
        (
            [
                "bonus=vae",
                "intrinsic.vae.variant=info_gain",
                "intrinsic.update_every=2",
            ],
            "set intrinsic.update_every=1",
        ),
    ],
)
def test_a_bonus_model_update_schedule_that_cannot_run_is_refused(
    algo, overrides, message
):
    check_config = recipe_check("minigrid")
    with initialize_config_dir(config_dir=str(RECIPES / "minigrid"), version_base=None):
        cfg = compose("config", overrides=[f"algo={algo}", *overrides])
    with pytest.raises(ValueError, match=message):
        check_config(cfg)
