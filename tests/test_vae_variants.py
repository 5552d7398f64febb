"""The novelty-aware VAE bonuses: what training does to them, and their contract."""

from __future__ import annotations

import pytest
import torch
from torchrl.envs import TransformedEnv, check_env_specs
from torchrl.testing.mocking_classes import ContinuousActionVecMockEnv

from torchrl_surprise import StateVAE, VAELoss
from torchrl_surprise.transforms import (
    VAENegativeELBOTransform,
    VAEPosteriorShiftTransform,
)


def _train(vae, td, steps):
    loss = VAELoss(vae)
    optim = torch.optim.Adam(vae.parameters(), lr=1e-3)
    for _ in range(steps):
        out = loss(td)
        optim.zero_grad()
        (out["loss_reconstruction"] + out["loss_kl"]).backward()
        optim.step()


def mean_bonus(transform, td):
    return transform(td.clone())["next", "intrinsic_reward"].mean().item()


def test_negative_elbo_falls_on_the_states_the_vae_trains_on(
    minigrid_vae, make_minigrid_batch
):
    # The opposite of the paper's KL (tests/test_losses.py): a novelty signal.
    torch.manual_seed(0)
    transform = VAENegativeELBOTransform(minigrid_vae)
    seen, unseen = make_minigrid_batch((16,)), make_minigrid_batch((256,))
    before = mean_bonus(transform, seen) / mean_bonus(transform, unseen)
    _train(minigrid_vae, seen.select("next"), steps=300)
    after = mean_bonus(transform, seen) / mean_bonus(transform, unseen)
    assert 0.8 < before < 1.2
    assert after < 0.5 * before


def test_posterior_shift_is_zero_at_the_snapshot_and_measures_the_update(
    minigrid_vae, make_minigrid_batch
):
    torch.manual_seed(0)
    transform = VAEPosteriorShiftTransform(minigrid_vae)
    seen, unseen = make_minigrid_batch((16,)), make_minigrid_batch((256,))
    assert mean_bonus(transform, seen) == pytest.approx(0.0, abs=1e-6)
    _train(minigrid_vae, seen.select("next"), steps=20)
    gain_seen, gain_unseen = mean_bonus(transform, seen), mean_bonus(transform, unseen)
    # The update moved the posterior of the states it trained on the most.
    assert gain_seen > gain_unseen > 0.0
    transform.snapshot()
    assert mean_bonus(transform, seen) == pytest.approx(0.0, abs=1e-6)


def test_the_reference_is_saved_and_not_trained(minigrid_vae):
    transform = VAEPosteriorShiftTransform(minigrid_vae)
    assert not any(p.requires_grad for p in transform.reference.parameters())
    assert {id(p) for p in VAELoss(minigrid_vae).parameters()}.isdisjoint(
        id(p) for p in transform.reference.parameters()
    )
    keys = transform.state_dict().keys()
    assert any(k.startswith("reference.") for k in keys)


@pytest.mark.parametrize(
    "transform_cls", [VAENegativeELBOTransform, VAEPosteriorShiftTransform]
)
def test_variants_pass_the_env_check_and_equal_the_batch_path(transform_cls):
    torch.manual_seed(0)
    base = ContinuousActionVecMockEnv()
    obs_dim = base.observation_spec["observation"].shape[-1]
    vae = StateVAE.for_vector(obs_dim, latent_dim=4, hidden_dim=16)
    with torch.no_grad():
        vae.head.bias.add_(0.1)  # a posterior shift away from any reference
    env = TransformedEnv(base, transform_cls(vae, coef=0.1))
    check_env_specs(env)
    rollout = env.rollout(6)
    recomputed = env.transform(rollout.clone())
    torch.testing.assert_close(
        recomputed["next", "intrinsic_reward"], rollout["next", "intrinsic_reward"]
    )
