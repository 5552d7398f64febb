"""benchmarks/ppo_baseline.py computes the PPO recipe's PPO (the speed anchor of
benchmarks/bench_speed.py, item 10): its settings are the recipe's resolved
config, its network the recipe's weight for weight, its GAE TorchRL's, its bonus
the library's transform's, and a short run gives finite losses."""

from __future__ import annotations

import importlib.util
import math
import sys
from pathlib import Path

import pytest
import torch
from hydra import compose, initialize_config_dir
from tensordict import TensorDict
from torchrl.data import Categorical
from torchrl.objectives.value.functional import vec_generalized_advantage_estimate

from common.minigrid import make_actor_critic
from torchrl_surprise import StateVAE
from torchrl_surprise.transforms import EpisodicVisits, VAENovelDTransform

ROOT = Path(__file__).resolve().parents[1]
_spec = importlib.util.spec_from_file_location(
    "ppo_baseline", ROOT / "benchmarks" / "ppo_baseline.py"
)
baseline = importlib.util.module_from_spec(_spec)
sys.modules["ppo_baseline"] = baseline  # dataclasses look their module up
_spec.loader.exec_module(baseline)


def recipe_config(setting: str):
    with initialize_config_dir(
        config_dir=str(ROOT / "recipes" / "minigrid"), version_base=None
    ):
        return compose("config", overrides=["algo=ppo", f"+setting={setting}"])


@pytest.mark.parametrize("setting", baseline.BONUSES)
def test_settings_are_the_recipes(setting):
    cfg = recipe_config(setting)
    args = baseline.Args(bonus=setting)
    recipe = {
        "env_id": cfg.env.name,
        "seed": cfg.seed,
        "torch_threads": cfg.torch_threads,
        "num_envs": cfg.env.num_envs,
        "env_threads": cfg.env.num_threads,
        "num_steps": cfg.collector.frames_per_env,
        "learning_rate": cfg.optim.lr,
        "adam_eps": cfg.optim.eps,
        "max_grad_norm": cfg.optim.max_grad_norm,
        "gamma": cfg.loss.gamma,
        "gae_lambda": cfg.loss.gae_lambda,
        "ent_coef": cfg.loss.entropy_coef,
        "vf_coef": cfg.loss.critic_coef,
        "norm_adv": cfg.loss.normalize_advantage,
        "clip_coef": cfg.loss.clip_epsilon,
        "update_epochs": cfg.loss.epochs,
        "minibatch_size": cfg.loss.minibatch_size,
        "intrinsic_coef": cfg.intrinsic.coef,
        "intrinsic_lr": cfg.intrinsic.lr,
        "vae_update_steps": cfg.intrinsic.update_steps,
        "vae_latent_dim": cfg.intrinsic.vae.latent_dim,
        "vae_hidden_dim": cfg.intrinsic.vae.hidden_dim,
        "vae_kl_weight": cfg.intrinsic.vae.kl_weight,
        "noveld_alpha": cfg.intrinsic.vae.alpha,
    }
    assert {k: getattr(args, k) for k in recipe} == recipe
    # the choices the baseline implements, and no other
    assert (cfg.algo.name, cfg.optim.name, cfg.env.backend) == (
        "ppo",
        "adam",
        "envpool",
    )
    assert (cfg.env.stochasticity, cfg.collector.workers, cfg.device) == (0, 1, "cpu")
    assert cfg.loss.reward_clip is None
    if setting == "none":
        assert cfg.bonus == "none"
        return
    icfg, vcfg = cfg.intrinsic, cfg.intrinsic.vae
    assert (cfg.bonus, vcfg.variant, vcfg.novelty) == ("vae", "noveld", "neg_elbo")
    assert (icfg.normalization, icfg.intrinsic_critic, icfg.episodic) == (
        "return_std",
        True,
        False,
    )
    assert (icfg.clip, icfg.coef_end, icfg.warmup_frames) == (None, None, 0)
    assert (icfg.update_every, icfg.finetune, icfg.init_from) == (1, True, None)
    assert (vcfg.use_direction, vcfg.inverse_weight) == (True, 0.0)


@pytest.mark.parametrize("intrinsic_critic", [False, True])
def test_network_is_the_recipes(intrinsic_critic):
    model, int_value = make_actor_critic(
        Categorical(7), intrinsic_critic, return_log_prob=True
    )
    recipe = list(model.parameters())
    if int_value is not None:  # as the recipe's optimiser gets them
        shared = {id(p) for p in recipe}
        recipe += [p for p in int_value.parameters() if id(p) not in shared]
    agent = baseline.ActorCritic(7, intrinsic_critic)
    ours = list(agent.parameters())
    assert [p.shape for p in ours] == [p.shape for p in recipe]
    assert sum(p.numel() for p in ours) == sum(p.numel() for p in recipe)
    for layer in (agent.actor[0], agent.critic[2]):  # rl-starter-files' init
        torch.testing.assert_close(
            layer.weight.norm(dim=1), torch.ones(len(layer.weight))
        )
        assert not layer.bias.any()
    with torch.no_grad():
        for mine, theirs in zip(ours, recipe, strict=True):
            mine.copy_(theirs)
    image = torch.randint(0, 6, (5, 7, 7, 3), dtype=torch.uint8)
    td = model.get_value_operator()(TensorDict(image=image, batch_size=[5]))
    hidden = agent.hidden(image)
    value, value_int = agent.values(hidden)
    torch.testing.assert_close(
        agent.actor(hidden), model.get_policy_head().module[0](td["hidden"])
    )
    torch.testing.assert_close(value, td["state_value"].squeeze(-1))
    if int_value is not None:
        out = int_value(TensorDict(image=image, batch_size=[5]))
        torch.testing.assert_close(value_int, out["state_value_int"].squeeze(-1))


def test_gae_is_torchrls():
    T, N = 9, 4
    reward, value, next_value = torch.randn(3, T, N).unbind(0)
    done = torch.rand(T, N) < 0.3
    terminated = done & (torch.rand(T, N) < 0.5)
    advantage, target = baseline.gae(
        reward, value, next_value, terminated, done, 0.99, 0.95
    )
    theirs = vec_generalized_advantage_estimate(
        0.99,
        0.95,
        *(x.T[..., None] for x in (value, next_value, reward, done, terminated)),
        time_dim=1,
    )
    torch.testing.assert_close(advantage, theirs[0][..., 0].T)
    torch.testing.assert_close(target, theirs[1][..., 0].T)


def test_bonus_is_the_transforms():
    """Two batches in a row: the raw and the normalised bonus, its return carried."""
    torch.manual_seed(0)
    T, N = 6, 3
    vae = StateVAE.for_minigrid(latent_dim=4, hidden_dim=16)
    transform = VAENovelDTransform(
        vae, alpha=0.5, normalization="return_std", gamma=0.99, reward_key=None
    )
    visits, normalize = EpisodicVisits(), baseline.ReturnStd(N, 0.99)
    states = torch.randint(0, 3, (4, 7, 7, 3), dtype=torch.uint8)
    for _ in range(2):
        which = torch.randint(0, 4, (T + 1, N))
        image, direction = states[which], which % 4
        done = torch.rand(T, N) < 0.2
        raw = baseline.noveld_bonus(
            vae, visits, image[:-1], direction[:-1], image[1:], direction[1:], done, 0.5
        )
        normalized = normalize(raw)
        td = TensorDict(
            {
                "image": image[:-1].transpose(0, 1),
                "direction": direction[:-1].T,
                "next": {
                    "image": image[1:].transpose(0, 1),
                    "direction": direction[1:].T,
                    "reward": torch.zeros(N, T, 1),
                    "done": done.T[..., None],
                },
            },
            [N, T],
            names=[None, "time"],
        )
        td = transform(td)["next"]
        assert raw.gt(0).any() and raw.eq(0).any()
        torch.testing.assert_close(raw, td["intrinsic_reward"][..., 0].T)
        torch.testing.assert_close(
            normalized, td["intrinsic_reward_normalized"][..., 0].T
        )


@pytest.mark.parametrize("bonus", baseline.BONUSES)
def test_a_short_run_gives_finite_losses(bonus):
    args = baseline.Args(
        num_envs=8, num_steps=16, minibatch_size=64, total_frames=256, bonus=bonus
    )
    out = baseline.train(args)
    assert out["frames"] == 256 and out["fps_cpu"] > 0
    losses = {k: v for k, v in out.items() if k.startswith("loss") or k == "entropy"}
    assert len(losses) == 4 + (bonus != "none")
    assert all(math.isfinite(v) for v in losses.values()), losses
