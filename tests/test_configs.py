"""The recipes' configs: every sweep job of the experiment files composes on its
recipe's schema and validates, with the setting it is labelled by; a bad value is
refused before a run starts, naming the setting by its full key and what it expects
(in-process through Hydra's compose API; one run from the command line)."""

from __future__ import annotations

import ast
import copy
import hashlib
import inspect
import itertools
import json
import subprocess
import sys
from pathlib import Path

import pytest
from hydra import compose, initialize_config_dir
from hydra._internal.config_loader_impl import (
    ConfigLoaderImpl,
    get_overrides_dirname,
)
from hydra.core.override_parser.overrides_parser import OverridesParser
from hydra.errors import ConfigCompositionException
from omegaconf import OmegaConf

import common.config
from common.bonuses import VAE_VARIANTS as VAE_TRANSFORMS
from common.config import (
    VAE_VARIANTS,
    DDPGConfig,
    MiniGridConfig,
    validate_ddpg,
    validate_minigrid,
)
from common.rundir import RESUMABLE_CHANGES, _flatten

RECIPES = Path(__file__).resolve().parents[1] / "recipes"
VALIDATE = {"minigrid": validate_minigrid, "ddpg_mujoco": validate_ddpg}
EXPERIMENTS = [
    (
        recipe,
        path.relative_to(RECIPES / recipe / "experiment").with_suffix("").as_posix(),
    )
    for recipe in ("minigrid", "ddpg_mujoco")
    for path in sorted((RECIPES / recipe / "experiment").glob("**/*.yaml"))
]
# The recipe, and the learner for MiniGrid.
RECIPE_RUNS = {
    "a2c": ("minigrid", ["algo=a2c"]),
    "ppo": ("minigrid", ["algo=ppo"]),
    "ddpg": ("ddpg_mujoco", []),
}


def sweep_values(value) -> list[str]:
    text = str(value)
    if text.startswith("range("):
        return [str(v) for v in range(*map(int, text[6:-1].split(",")))]
    return text.split(",")


def composed(recipe: str, overrides: list[str]):
    with initialize_config_dir(config_dir=str(RECIPES / recipe), version_base=None):
        return compose("config", overrides=overrides)


def refusal(recipe: str, overrides: list[str]) -> str:
    """What refuses a config, as Hydra composes it or as the recipe validates it:
    the message, with the cause of a composition error (where Hydra names the key)."""
    try:
        VALIDATE[recipe](composed(recipe, overrides))
    except ConfigCompositionException as err:
        return f"{err}\n{err.__cause__}"
    except ValueError as err:
        return str(err)
    pytest.fail(f"{recipe} accepted {overrides}")


def is_group(recipe: str, key: str) -> bool:
    """Whether a sweep key chooses a config group (``+setting``) or sets a value."""
    return (RECIPES / recipe / key.lstrip("+~")).is_dir()


def with_values(cfg, overrides: list[str]):
    """``cfg`` with value overrides applied as Hydra applies them after composing
    the defaults list (a copy: ``cfg`` is left as it was)."""
    cfg = copy.deepcopy(cfg)
    parsed = OverridesParser.create().parse_overrides(overrides)
    ConfigLoaderImpl._apply_overrides_to_config(parsed, cfg)
    return cfg


@pytest.mark.parametrize(("recipe", "experiment"), EXPERIMENTS)
def test_every_sweep_job_composes_and_validates(recipe, experiment):
    with initialize_config_dir(config_dir=str(RECIPES / recipe), version_base=None):
        base = [f"+experiment={experiment}"]
        sweep = compose("config", overrides=base, return_hydra_config=True)
        params = {k: sweep_values(v) for k, v in sweep.hydra.sweeper.params.items()}
        assert params, f"{experiment}: no sweep"
        jobs = [dict(zip(params, job)) for job in itertools.product(*params.values())]
        # Each choice of config groups is composed once; the values a job sets
        # (seed, env.name, ...) go on top of it as Hydra puts them on top of the
        # composed defaults list.
        by_groups = {}
        for job in jobs:
            groups = tuple(f"{k}={v}" for k, v in job.items() if is_group(recipe, k))
            if groups not in by_groups:
                by_groups[groups] = compose("config", overrides=[*base, *groups])
            values = [f"{k}={v}" for k, v in job.items() if not is_group(recipe, k)]
            cfg = with_values(by_groups[groups], values)
            for key, value in job.items():
                if not is_group(recipe, key):
                    assert str(OmegaConf.select(cfg, key)) == value, (job, key)
            OmegaConf.to_container(cfg, resolve=True)  # every interpolation resolves
            VALIDATE[recipe](cfg)
            assert cfg.experiment_name == experiment.split("/")[-1]
            if "+setting" in job:
                assert cfg.setting == job["+setting"], "a setting file's label"
            variants = OmegaConf.select(cfg, "intrinsic.vae.variant") is not None
            if cfg.bonus == "vae" and "+setting" in job and variants:
                # settings name the VAE variant they measure, never the default
                name = f"{job['+setting']}.yaml"
                folders = (RECIPES / recipe, RECIPES / recipe / "studies")
                path = next(
                    f / "setting" / name
                    for f in folders
                    if (f / "setting" / name).is_file()
                )
                text = path.read_text()
                assert "variant:" in text, f"{path.name} must name its VAE variant"
    # and it runs what it ran when its results were committed (SNAPSHOT)
    recorded = json.loads(SNAPSHOT.read_text()).get(f"{recipe}/{experiment}")
    assert recorded is not None, f"{experiment}: not in {SNAPSHOT.name}"
    found = _experiment_digests(recipe, experiment, by_groups)
    changed = sorted(
        k for k in set(found) | set(recorded) if found.get(k) != recorded.get(k)
    )
    assert changed == [], f"{experiment}: composed config changed for {changed}"


def test_a_jobs_values_go_on_its_composed_groups_as_hydra_puts_them():
    # what the sweep test relies on: the same config as composing the whole job
    overrides = ["+experiment=a2c/noise", "+setting=icm"]
    values = ["seed=3", "env.stochasticity=2"]
    with initialize_config_dir(config_dir=str(RECIPES / "minigrid"), version_base=None):
        whole = compose("config", overrides=[*overrides, *values])
        groups = compose("config", overrides=overrides)
    assert with_values(groups, values) == whole
    assert groups.seed != 3, "the values are applied to a copy"
    with pytest.raises(
        ConfigCompositionException, match="Error merging override seed=abc"
    ):
        with_values(groups, ["seed=abc"])


@pytest.mark.parametrize("recipe", ["minigrid", "ddpg_mujoco"])
def test_what_may_change_on_resume_does_not_name_a_sweep_runs_directory(recipe):
    # A sweep rerun with a longer budget, other logging or checkpoints must find its
    # runs: the keys Hydra leaves out of a job's directory name are exactly
    # RESUMABLE_CHANGES' entries and sections, and each key under those sections
    # (Hydra matches whole keys), and the experiment file that is the sweep's
    # folder.
    with initialize_config_dir(config_dir=str(RECIPES / recipe), version_base=None):
        cfg = compose("config", return_hydra_config=True)
    excluded = list(cfg.hydra.job.config.override_dirname.exclude_keys)
    config = OmegaConf.to_container(cfg, resolve=False)
    del config["hydra"]
    resumable = [
        name
        for name in _flatten(config)
        if any(name == a or name.startswith(a + ".") for a in RESUMABLE_CHANGES)
    ]
    assert len(resumable) > len(RESUMABLE_CHANGES)  # sections key by key
    expected = {"experiment", *RESUMABLE_CHANGES, *resumable}
    assert sorted(excluded) == sorted(expected)
    overrides = OverridesParser.create().parse_overrides(
        [
            "+experiment=x",
            "seed=3",
            "+setting=s",
            "eval.episodes=2",
            "logger.log_interval=9",
            "experiment_name=y",
            "collector.total_frames=7",
            "checkpoint={interval_frames:5}",
        ]
    )
    dirname = get_overrides_dirname(overrides, excluded, item_sep=",", kv_sep="=")
    assert dirname == "+setting=s,seed=3"


@pytest.mark.parametrize("schema", [MiniGridConfig, DDPGConfig])
def test_the_schemas_hold_no_values_only_types(schema):
    # The values and their reasons live in config.yaml: a default here would compete.
    def leaves(node, prefix=""):
        for key in node:
            if OmegaConf.is_missing(node, key):
                continue
            value = node[key]
            if OmegaConf.is_dict(value):
                yield from leaves(value, f"{prefix}{key}.")
            else:
                yield f"{prefix}{key}"

    assert list(leaves(OmegaConf.structured(schema))) == []


def test_the_vae_variants_are_those_the_recipe_builds():
    assert VAE_VARIANTS == tuple(VAE_TRANSFORMS)


def test_every_setting_is_documented():
    # As CleanRL's Args: a docstring under each field says what it is and its range.
    tree = ast.parse(inspect.getsource(common.config))
    undocumented = []
    for cls in (n for n in tree.body if isinstance(n, ast.ClassDef)):
        if not any(getattr(d, "id", None) == "dataclass" for d in cls.decorator_list):
            continue
        for stmt, after in zip(cls.body, [*cls.body[1:], None]):
            if not isinstance(stmt, ast.AnnAssign):
                continue
            if isinstance(stmt.value, ast.Call) and stmt.value.func.id == "section":
                continue  # a section: its class has the docstring
            documented = isinstance(after, ast.Expr) and isinstance(
                after.value, ast.Constant
            )
            if not documented:
                undocumented.append(f"{cls.name}.{stmt.target.id}")
    assert undocumented == []


# (override, the message that refuses it): the values each recipe must refuse by
# type, by range or as not finite, before anything is built.
BAD_VALUES = {
    "seed=abc": "Value 'abc' of type 'str' could not be converted to Integer\n"
    "    full_key: seed",
    "intrinsic.vae.latent_dim=0": "intrinsic.vae.latent_dim must be an integer > 0, "
    "got 0.",
    "env.num_envs=2.5": "Value '2.5' of type 'float' could not be converted to "
    "Integer\n    full_key: env.num_envs",
    "collector.frames_per_env=8.5": "Value '8.5' of type 'float' could not be "
    "converted to Integer\n    full_key: collector.frames_per_env",
    "intrinsic.update_steps=1.5": "Value '1.5' of type 'float' could not be "
    "converted to Integer\n    full_key: intrinsic.update_steps",
    "intrinsic.coef_end=nan": "intrinsic.coef_end must be a finite number or null, "
    "got nan.",
    "optim.lr=inf": "optim.lr must be a finite number > 0, got inf.",
    "optim.max_grad_norm=nan": "optim.max_grad_norm must be a finite number > 0, "
    "got nan.",
    "loss.entropy_coef=nan": "loss.entropy_coef must be a finite number >= 0, got nan.",
    "intrinsic.vae.novelty=foo": "intrinsic.vae.novelty must be one of 'neg_elbo', "
    "'kl', got 'foo'.",
    # both recipes' bonus-model batch (MiniGrid's may be null: the whole batch)
    "intrinsic.batch_size=0": "intrinsic.batch_size must be an integer > 0",
    "logger.backend=foo": "logger.backend must be one of 'csv', 'tensorboard', "
    "'wandb', 'mlflow', '', got 'foo'.",
    # DDPG's counterparts of MiniGrid's settings
    "collector.frames_per_batch=8.5": "Value '8.5' of type 'float' could not be "
    "converted to Integer\n    full_key: collector.frames_per_batch",
    "optim.actor_lr=inf": "optim.actor_lr must be a finite number > 0, got inf.",
    "optim.critic_lr=nan": "optim.critic_lr must be a finite number > 0, got nan.",
}
MINIGRID_ONLY = {
    "collector.frames_per_env=8.5",
    "intrinsic.vae.novelty=foo",
    "intrinsic.update_steps=1.5",
    "optim.lr=inf",
    "optim.max_grad_norm=nan",
    "loss.entropy_coef=nan",
}
DDPG_ONLY = {
    "collector.frames_per_batch=8.5",
    "optim.actor_lr=inf",
    "optim.critic_lr=nan",
}


@pytest.mark.parametrize("run", list(RECIPE_RUNS))
@pytest.mark.parametrize("override", list(BAD_VALUES))
def test_a_bad_value_is_refused_naming_its_setting(run, override):
    recipe, base = RECIPE_RUNS[run]
    message = refusal(recipe, [*base, override])
    if override in (MINIGRID_ONLY if recipe == "ddpg_mujoco" else DDPG_ONLY):
        # not a setting of this recipe: refused as such
        key = override.split("=")[0]
        assert f"Could not override '{key}'" in message
        assert f"full_key: {key}" in message
        return
    assert BAD_VALUES[override] in message


@pytest.mark.parametrize(
    ("run", "override", "message"),
    [
        *(
            (run, override, message)
            for run in ("a2c", "ppo")
            for override, message in [
                (
                    "bonus=banana",
                    "bonus must be one of 'none', 'vae', 'icm', 'rnd', 'e3b', 'noveld', got 'banana'.",
                ),
                (
                    "algo.name=sac",
                    "algo.name must be one of 'a2c', 'ppo', got 'sac'.",
                ),
                (
                    "optim.name=sgd",
                    "optim.name must be one of 'rmsprop', 'adam', got 'sgd'.",
                ),
                (
                    "intrinsic.normalization=median",
                    "intrinsic.normalization must be one of 'none', 'reward_std', "
                    "'return_std', 'zscore', 'e3b_std', got 'median'.",
                ),
                (
                    "intrinsic.vae.variant=novelty",
                    "intrinsic.vae.variant must be one of 'kl', 'neg_elbo', "
                    "'info_gain', 'lagged_kl', 'elliptical', 'noveld', got 'novelty'.",
                ),
                (
                    "intrinsic.vae.global_bonus=rnd",
                    "intrinsic.vae.global_bonus must be one of 'none', 'kl', got "
                    "'rnd'.",
                ),
                (
                    "env.backend=atari",
                    "env.backend must be one of 'gymnasium', 'envpool', got 'atari'.",
                ),
                (
                    "resume=maybe",
                    "resume must be one of auto, true, false (any case), got 'maybe'.",
                ),
                ("env.stochasticity=4", "env.stochasticity must be one of 0, 1, 2, 3"),
                (
                    "collector.total_frames=-5",
                    "collector.total_frames must be an integer > 0, got -5.",
                ),
                ("loss.gamma=1.5", "loss.gamma must be a finite number in [0, 1]"),
                (
                    "loss.normalize_advantage=maybe",
                    "Value 'maybe' is not a valid bool (type str)\n"
                    "    full_key: loss.normalize_advantage",
                ),
                ("loss.epochs=0", "loss.epochs must be an integer > 0, got 0."),
                (
                    "loss.clip_epsilon=0",
                    "loss.clip_epsilon must be a finite number > 0, got 0.0.",
                ),
                (
                    "intrinsic.coef=inf",
                    "intrinsic.coef must be a finite number, got inf.",
                ),
                (
                    "intrinsic.warmup_frames=-1",
                    "intrinsic.warmup_frames must be an integer >= 0, got -1.",
                ),
                (
                    "intrinsic.update_every=0",
                    "intrinsic.update_every must be an integer > 0, got 0.",
                ),
                (
                    "intrinsic.update_every=1.5",
                    "full_key: intrinsic.update_every",
                ),
                (
                    "intrinsic.clip=0",
                    "intrinsic.clip must be a finite number > 0 or null, got 0.0.",
                ),
                (
                    "env.typo=1",
                    "Key 'typo' not in 'MiniGridEnvConfig'\n    full_key: env.typo",
                ),
                # rules between settings
                (
                    "env.num_envs=16 collector.workers=3",
                    "env.num_envs (16) must be a multiple of collector.workers (3)",
                ),
                (
                    "collector.workers=0",
                    "collector.workers must be an integer > 0, got 0.",
                ),
                (
                    "bonus=rnd collector.workers=2",
                    "Run bonus=rnd with collector.workers=1",
                ),
                *(
                    (
                        f"device={device} collector.workers=2",
                        f"device={device} with collector.workers=2: ",
                    )
                    for device in ("cuda", "auto")
                ),
                (
                    "bonus=vae intrinsic.vae.variant=info_gain "
                    "intrinsic.update_every=2",
                    "set intrinsic.update_every=1 (got 2)",
                ),
                (
                    "bonus=vae intrinsic.vae.variant=lagged_kl "
                    "intrinsic.update_every=4",
                    "set intrinsic.update_every=1 (got 4)",
                ),
                (
                    "bonus=rnd intrinsic.init_from=runs/x",
                    "bonus must be vae, icm, e3b or noveld with it, got bonus=rnd.",
                ),
            ]
        ),
        (
            "ppo",
            "loss.minibatch_size=4096",
            "loss.minibatch_size must be an integer in [1, 2048] (env.num_envs * "
            "collector.frames_per_env, the collected batch), got 4096.",
        ),
        *(
            ("ddpg", override, message)
            for override, message in [
                (
                    "bonus=banana",
                    "bonus must be one of 'none', 'vae', got 'banana'.",
                ),
                ("resume=maybe", "resume must be one of auto, true, false"),
                (
                    "intrinsic.bonus_at=never",
                    "intrinsic.bonus_at must be one of 'sample', 'collection', got "
                    "'never'.",
                ),
                (
                    "intrinsic.normalization=median",
                    "intrinsic.normalization must be one of 'none', 'reward_std', "
                    "'return_std', 'zscore', 'e3b_std', got 'median'.",
                ),
                (
                    "exploration.noise=pink",
                    "exploration.noise must be one of 'gaussian', 'ou', got 'pink'.",
                ),
                (
                    "loss.delay_actor=maybe",
                    "Value 'maybe' is not a valid bool (type str)\n"
                    "    full_key: loss.delay_actor",
                ),
                (
                    "collector.total_frames=-5",
                    "collector.total_frames must be an integer > 0, got -5.",
                ),
                (
                    "collector.init_random_frames=-1",
                    "collector.init_random_frames must be an integer >= 0, got -1.",
                ),
                ("optim.batch_size=0", "optim.batch_size must be an integer > 0"),
                ("optim.tau=0", "optim.tau must be a finite number in (0, 1]"),
                ("optim.gamma=-0.1", "optim.gamma must be a finite number in [0, 1]"),
                ("intrinsic.coef=nan", "intrinsic.coef must be a finite number"),
                ("obs_norm.clip=-1", "obs_norm.clip must be a finite number > 0"),
                (
                    "network.hidden_sizes=[256,0]",
                    "network.hidden_sizes[1] must be an integer > 0, got 0.",
                ),
                # rules between settings
                (
                    "intrinsic.normalization=return_std",
                    "return_std needs whole trajectories",
                ),
                (
                    "collector.total_frames=1500",
                    "collector.total_frames (1500) must be a multiple of "
                    "collector.frames_per_batch (1000).",
                ),
                (
                    "collector.init_random_frames=500",
                    "collector.init_random_frames (500) must be a multiple of "
                    "collector.frames_per_batch (1000).",
                ),
                (
                    "env.num_envs=3",
                    "collector.frames_per_batch (1000) must be a multiple of "
                    "env.num_envs (3).",
                ),
            ]
        ),
    ],
)
def test_a_config_the_recipe_cannot_run_is_refused(run, override, message):
    recipe, base = RECIPE_RUNS[run]
    assert message in refusal(recipe, [*base, *override.split()])


@pytest.mark.parametrize("run", list(RECIPE_RUNS))
@pytest.mark.parametrize(
    "overrides",
    [
        ["resume=true"],  # YAML reads a bool: any case of auto, true, false
        ["resume=False"],
        ["logger.backend="],  # no logger
        ["intrinsic.coef_end=0.0", "intrinsic.anneal_frames=1000"],
        ["intrinsic.clip=null"],
        ["intrinsic.coef=-0.5"],
    ],
)
def test_the_values_a_recipe_takes_are_accepted(run, overrides):
    recipe, base = RECIPE_RUNS[run]
    VALIDATE[recipe](composed(recipe, [*base, *overrides]))


def test_a_bad_value_exits_the_script_before_the_run_starts(tmp_path):
    run_dir = tmp_path / "run"
    cmd = [
        sys.executable,
        str(RECIPES / "minigrid" / "main.py"),
        f"hydra.run.dir={run_dir}",
        "optim.lr=inf",
    ]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
    assert proc.returncode != 0
    assert "optim.lr must be a finite number > 0, got inf." in proc.stderr
    assert not run_dir.exists() or not any(run_dir.glob("checkpoint*"))


# ------------------------------------- committed experiments keep their configs

# Every committed experiment's sweep grid and each of its jobs' resolved configs,
# as digests: a move of config files, or a new default, must not change what a
# committed experiment runs (its results would no longer reproduce). After a
# deliberate change (a new experiment, or one meant to run otherwise), rewrite
# the record with `PYTHONPATH=recipes python tests/test_configs.py` and say why
# in the commit.
SNAPSHOT = Path(__file__).resolve().parent / "data" / "experiment_configs.json"


def _digest(value) -> str:
    text = json.dumps(value, sort_keys=True, default=str)
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def _experiment_digests(recipe: str, experiment: str, by_groups=None) -> dict:
    """{"sweep": the grid's digest, "<group choices>": the resolved config's}."""
    with initialize_config_dir(config_dir=str(RECIPES / recipe), version_base=None):
        base = [f"+experiment={experiment}"]
        sweep = compose("config", overrides=base, return_hydra_config=True)
        params = {k: sweep_values(v) for k, v in sweep.hydra.sweeper.params.items()}
        digests = {"sweep": _digest(params)}
        groups = [k for k in params if is_group(recipe, k)]
        for choice in itertools.product(*(params[k] for k in groups)):
            key = tuple(f"{k}={v}" for k, v in zip(groups, choice))
            cfg = (by_groups or {}).get(key)
            if cfg is None:
                cfg = compose("config", overrides=[*base, *key])
            digests[",".join(key)] = _digest(OmegaConf.to_container(cfg, resolve=True))
    return digests


if __name__ == "__main__":  # rewrite the record (run from the repository root)
    record = {
        f"{recipe}/{experiment}": _experiment_digests(recipe, experiment)
        for recipe, experiment in EXPERIMENTS
    }
    SNAPSHOT.write_text(json.dumps(record, indent=1, sort_keys=True) + "\n")
    print(f"Wrote {SNAPSHOT} ({len(record)} experiments)")


def test_a_user_chooses_among_bonuses_and_studies_keep_their_variants():
    # setting/ holds what a user picks (the bonuses, the recommended variants);
    # a study's variants are in studies/setting/, found by +setting= as well
    minigrid = RECIPES / "minigrid"
    chosen = {p.stem for p in (minigrid / "setting").glob("*.yaml")}
    assert chosen == {
        "none",
        "vae",
        "vae_literal",
        "vae_elliptical",
        "vae_elliptical_kl",
        "vae_noveld",
        "icm",
        "rnd",
        "e3b",
        "e3b_128",
        "noveld",
    }
    study = minigrid / "studies" / "setting" / "vae_elliptical_every4.yaml"
    assert study.is_file()
    cfg = composed("minigrid", ["+setting=vae_elliptical_every4"])
    assert cfg.setting == "vae_elliptical_every4" and cfg.intrinsic.update_every == 4
    assert not set(chosen) & {p.stem for p in study.parent.glob("*.yaml")}


def test_ppos_default_bonus_is_the_recommended_vae_noveld_and_a2cs_the_elliptical():
    # a user who names no bonus gets, under each learner, the VAE bonus the data
    # recommends for it (README, "Which bonus to use"): under PPO the setting's
    # whole bonus config, under A2C its VAE (A2C trains it every 4th batch)
    for algo, setting in (("ppo", "vae_noveld"), ("a2c", "vae_elliptical")):
        plain = composed("minigrid", [f"algo={algo}"])
        chosen = composed("minigrid", [f"algo={algo}", f"+setting={setting}"])
        assert plain.bonus == chosen.bonus == "vae"
        assert plain.intrinsic.vae == chosen.intrinsic.vae, (algo, setting)
    assert plain.intrinsic.update_every == 4
    ppo = [
        composed("minigrid", ["algo=ppo", *s]) for s in ([], ["+setting=vae_noveld"])
    ]
    assert ppo[0].intrinsic == ppo[1].intrinsic
