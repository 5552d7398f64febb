"""The VAE with an inverse-dynamics term on its latent (VAELoss(inverse_dynamics=))."""

from __future__ import annotations

import pytest
import torch
from tensordict import TensorDict

from torchrl_surprise import StateVAE, VAELoss
from torchrl_surprise.modules import InverseDynamicsModel, PosteriorMean


def _batch(n: int = 16) -> TensorDict:
    def image():
        return torch.randint(0, 3, (n, 7, 7, 3), dtype=torch.uint8)

    return TensorDict(
        {
            "image": image(),
            "direction": torch.randint(0, 4, (n,)),
            "action": torch.randint(0, 7, (n,)),
            "next": {"image": image(), "direction": torch.randint(0, 4, (n,))},
        },
        [n],
    )


def test_posterior_mean_is_the_vaes_own_and_shares_its_weights():
    torch.manual_seed(0)
    vae = StateVAE.for_minigrid(latent_dim=4, hidden_dim=16)
    model = InverseDynamicsModel.on_vae(vae, action_dim=7, hidden_dim=8)
    batch = _batch(3)
    obs = (batch["image"], batch["direction"])
    assert isinstance(model.encoder, PosteriorMean)
    assert torch.equal(model.embed(*obs), vae.posterior(*obs)[0])
    vae_params = {id(p) for p in vae.parameters()}
    assert vae_params <= {id(p) for p in model.parameters()}


def test_the_inverse_term_trains_the_vaes_encoder_and_adds_to_the_elbo():
    torch.manual_seed(0)
    vae = StateVAE.for_minigrid(latent_dim=4, hidden_dim=16)
    inverse = InverseDynamicsModel.on_vae(vae, action_dim=7, hidden_dim=8)
    batch = _batch()
    plain = VAELoss(vae)
    weighted = VAELoss(vae, inverse_dynamics=inverse, inverse_weight=0.5)
    assert "action" in weighted.in_keys and "image" in weighted.in_keys
    assert "action" not in plain.in_keys
    out = weighted(batch)
    assert {"loss_inverse", "inverse_error"} <= set(out.keys())
    # the weight scales the loss, not the logged error
    assert torch.allclose(out["loss_inverse"], 0.5 * out["inverse_error"])
    # the ELBO terms are the plain loss's (same weights, fresh sample: compare KL)
    assert torch.allclose(out["kl"], plain(batch)["kl"])
    vae.zero_grad()
    out["loss_inverse"].backward()
    encoder_grads = [p.grad for p in vae.encoder.parameters()]
    assert all(g is not None and g.abs().sum() > 0 for g in encoder_grads)
    # the decoder is not in the inverse term's graph
    assert all(p.grad is None for p in vae.decoder.parameters())


def test_an_inverse_model_on_another_encoder_is_refused():
    vae = StateVAE.for_minigrid(latent_dim=4, hidden_dim=16)
    other = InverseDynamicsModel.for_minigrid(num_actions=7, embedding_dim=8)
    with pytest.raises(ValueError, match="on_vae"):
        VAELoss(vae, inverse_dynamics=other)
    another_vae = StateVAE.for_minigrid(latent_dim=4, hidden_dim=16)
    with pytest.raises(ValueError, match="posterior"):
        VAELoss(vae, inverse_dynamics=InverseDynamicsModel.on_vae(another_vae, 7))


def test_a_weight_that_is_not_positive_is_refused():
    vae = StateVAE.for_minigrid(latent_dim=4, hidden_dim=16)
    inverse = InverseDynamicsModel.on_vae(vae, 7)
    for weight in (0.0, -1.0, float("nan")):
        with pytest.raises(ValueError, match="inverse_weight must be > 0"):
            VAELoss(vae, inverse_dynamics=inverse, inverse_weight=weight)


def test_a_missing_action_is_named():
    vae = StateVAE.for_minigrid(latent_dim=4, hidden_dim=16)
    loss = VAELoss(vae, inverse_dynamics=InverseDynamicsModel.on_vae(vae, 7))
    with pytest.raises(KeyError, match="action"):
        loss(_batch().exclude("action"))
