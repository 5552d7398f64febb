"""VAELoss and ICMLoss, tested as TorchRL tests its losses (test/objectives).

Keys and ``set_keys``, keyword calls, reduction, which parameters each
``loss_*`` reaches, the input left untouched, ``state_dict``; then what the
bonus needs from training: the loss and the transform share one model, and what
training on a set of states does to their bonus.
"""

from __future__ import annotations

import pytest
import torch
from tensordict import TensorDict, TensorDictBase
from tensordict import assert_close as assert_td_close
from torch import nn

from torchrl_surprise import (
    ICMLoss,
    ICMModel,
    ICMTransform,
    StateVAE,
    VAELoss,
    VAESurpriseTransform,
)

OBS_DIM = 7


def assert_close(actual, expected) -> None:
    if isinstance(actual, TensorDictBase):
        assert_td_close(actual, expected)
    else:
        torch.testing.assert_close(actual, expected)


def grads(module: nn.Module) -> list[torch.Tensor | None]:
    return [p.grad for p in module.parameters()]


def reached(module: nn.Module) -> bool:
    """Every parameter got a gradient and at least one is non-zero."""
    gs = grads(module)
    return all(g is not None for g in gs) and any(g.abs().sum() > 0 for g in gs)


def untouched(module: nn.Module) -> bool:
    return all(g is None or not g.any() for g in grads(module))


@pytest.fixture(params=["vector", "minigrid"])
def vae_and_batch(
    request, vector_vae, minigrid_vae, make_vector_batch, make_minigrid_batch
):
    """A VAE and a [2, 3] batch of transitions it can read."""
    if request.param == "vector":
        return vector_vae, make_vector_batch((2, 3))
    return minigrid_vae, make_minigrid_batch((2, 3))


@pytest.fixture(params=["continuous", "discrete", "minigrid"])
def icm_and_batch(
    request,
    continuous_icm,
    discrete_icm,
    minigrid_icm,
    make_vector_batch,
    make_minigrid_batch,
):
    """An ICM and a [2, 3] batch of transitions it can read."""
    if request.param == "continuous":
        return continuous_icm, make_vector_batch((2, 3))
    if request.param == "discrete":
        return discrete_icm, make_vector_batch((2, 3), action="discrete")
    return minigrid_icm, make_minigrid_batch((2, 3))


# =================================================================== keys


def test_vae_loss_keys(vector_vae, minigrid_vae):
    loss = VAELoss(vector_vae)
    assert loss.in_keys == [("next", "observation")]
    assert loss.tensor_keys.observations == (("next", "observation"),)
    assert set(loss.out_keys) == {
        "loss_reconstruction",
        "loss_kl",
        "kl",
        "reconstruction_nll",
    }
    assert VAELoss(minigrid_vae).in_keys == [("next", "image"), ("next", "direction")]

    loss.set_keys(observations="state")
    assert loss.in_keys == ["state"]
    loss.set_keys(observations=[("next", "obs", "vec")])
    assert loss.in_keys == [("next", "obs", "vec")]
    td = TensorDict({"next": {"obs": {"vec": torch.randn(4, OBS_DIM)}}}, [4])
    assert set(loss(td).keys()) == set(loss.out_keys)
    with pytest.raises(ValueError):
        loss.set_keys(not_a_key="x")


def test_icm_loss_keys(continuous_icm, make_vector_batch):
    loss = ICMLoss(continuous_icm)
    assert loss.in_keys == ["observation", ("next", "observation"), "action"]
    assert set(loss.out_keys) == {
        "loss_forward",
        "loss_inverse",
        "forward_error",
        "inverse_error",
    }
    td = make_vector_batch((4,))
    reference = loss(td.clone())

    loss.set_keys(action="act", observations=["state"])
    assert loss.in_keys == ["state", ("next", "state"), "act"]
    renamed = td.clone().rename_key_("action", "act")
    renamed.rename_key_("observation", "state")
    renamed.rename_key_(("next", "observation"), ("next", "state"))
    assert_close(loss(renamed), reference)
    with pytest.raises(ValueError):
        loss.set_keys(not_a_key="x")


def test_loss_argument_validation(vector_vae, continuous_icm):
    with pytest.raises(ValueError, match="reduction"):
        VAELoss(vector_vae, reduction="max")
    with pytest.raises(ValueError, match="reduction"):
        ICMLoss(continuous_icm, reduction="max")
    with pytest.raises(ValueError, match="beta"):
        ICMLoss(continuous_icm, beta=1.5)


def test_missing_and_non_finite_inputs(vector_vae, continuous_icm, make_vector_batch):
    td = make_vector_batch((3,))
    with pytest.raises(KeyError) as info:
        VAELoss(vector_vae)(td.exclude(("next", "observation")))
    assert "observation" in info.value.args[0]
    with pytest.raises(KeyError) as info:
        ICMLoss(continuous_icm)(td.exclude("action"))
    assert "'action'" in info.value.args[0]
    bad = td.clone()
    bad["next", "observation"][0, 0] = float("nan")
    with pytest.raises(ValueError, match="NaN"):
        VAELoss(vector_vae)(bad)
    with pytest.raises(ValueError, match="NaN"):
        ICMLoss(continuous_icm)(bad)


# ========================================================= keyword call


def test_vae_loss_keyword_call_equals_tensordict_call(vector_vae, make_vector_batch):
    loss = VAELoss(vector_vae)
    td = make_vector_batch((5,))
    torch.manual_seed(3)
    from_td = loss(td)
    torch.manual_seed(3)
    # The default keys are nested under "next": the keyword is "next".
    from_kwargs = loss(next={"observation": td["next", "observation"]})
    assert_close(from_kwargs, from_td)


def test_icm_loss_keyword_call_equals_tensordict_call(discrete_icm, make_vector_batch):
    loss = ICMLoss(discrete_icm)
    td = make_vector_batch((5,), action="discrete")
    from_kwargs = loss(
        observation=td["observation"],
        action=td["action"],
        next={"observation": td["next", "observation"]},
    )
    assert_close(from_kwargs, loss(td))


# ============================================================= reduction


def test_vae_loss_reduction(vae_and_batch):
    vae, td = vae_and_batch
    out = {}
    for reduction in ("none", "mean", "sum"):
        torch.manual_seed(1)
        out[reduction] = VAELoss(vae, kl_weight=0.5, reduction=reduction)(td)
    for key in ("loss_kl", "loss_reconstruction"):
        assert out["none"][key].shape == td.batch_size
        assert_close(out["mean"][key], out["none"][key].mean())
        assert_close(out["sum"][key], out["none"][key].sum())

    # The values: 0.5 * KL(q || N(0, I)) and the one-sample reconstruction NLL.
    obs = [td["next", key] for key in vae.in_keys]
    kl = vae.kl(*obs)
    assert_close(out["none"]["loss_kl"], 0.5 * kl)
    assert_close(out["none"]["kl"], kl.detach().mean())
    torch.manual_seed(1)
    loc, scale = vae.posterior(*obs)
    z = loc + scale * torch.randn_like(loc)
    assert_close(out["none"]["loss_reconstruction"], -vae.decoder.log_prob(z, *obs))


def test_icm_loss_reduction(icm_and_batch):
    icm, td = icm_and_batch
    out = {r: ICMLoss(icm, beta=0.2, reduction=r)(td) for r in ("none", "mean", "sum")}
    for key in ("loss_forward", "loss_inverse"):
        assert out["none"][key].shape == td.batch_size
        assert_close(out["mean"][key], out["none"][key].mean())
        assert_close(out["sum"][key], out["none"][key].sum())
    # The forward loss is the bonus the transform hands out, weighted by beta.
    bonus = ICMTransform(icm)(td.clone())["next", "intrinsic_reward"].squeeze(-1)
    assert_close(out["none"]["loss_forward"], 0.2 * bonus)


# ============================================== gradients reach their owners


def test_vae_loss_gradients(vae_and_batch):
    vae, td = vae_and_batch
    loss = VAELoss(vae)
    loss(td)["loss_kl"].backward()
    assert reached(vae.encoder) and reached(vae.head)
    assert untouched(vae.decoder)

    vae.zero_grad(set_to_none=True)
    loss(td)["loss_reconstruction"].backward()
    assert reached(vae.decoder)


def test_icm_loss_gradients(icm_and_batch):
    icm, td = icm_and_batch
    loss = ICMLoss(icm)
    loss(td)["loss_forward"].backward()
    assert reached(icm.forward_model)
    assert untouched(icm.encoder) and untouched(icm.inverse_model)

    icm.zero_grad(set_to_none=True)
    loss(td)["loss_inverse"].backward()
    assert reached(icm.encoder) and reached(icm.inverse_model)
    assert untouched(icm.forward_model)


# ======================================================= input, state_dict


def test_losses_do_not_modify_their_input(vae_and_batch, icm_and_batch):
    for loss, td in [
        (VAELoss(vae_and_batch[0]), vae_and_batch[1]),
        (ICMLoss(icm_and_batch[0]), icm_and_batch[1]),
    ]:
        before = td.clone()
        loss(td)
        assert set(td.keys(True, True)) == set(before.keys(True, True))
        assert_close(td, before)


@pytest.mark.parametrize("which", ["vae", "icm"])
def test_loss_state_dict_round_trip(which, make_vector_batch):
    def build():
        if which == "vae":
            return VAELoss(StateVAE.for_vector(OBS_DIM, latent_dim=4, hidden_dim=16))
        return ICMLoss(ICMModel.for_vector(OBS_DIM, 7, hidden_dim=16))

    loss = build()
    td = make_vector_batch((8,))
    optim = torch.optim.Adam(loss.parameters(), lr=1e-2)
    for _ in range(3):
        out = loss(td)
        optim.zero_grad()
        sum(v for k, v in out.items() if k.startswith("loss_")).backward()
        optim.step()

    torch.manual_seed(1)
    fresh = build()
    fresh.load_state_dict(loss.state_dict())
    for a, b in zip(loss.parameters(), fresh.parameters(), strict=True):
        assert torch.equal(a, b)
    torch.manual_seed(2)
    expected = loss(td)
    torch.manual_seed(2)
    assert_close(fresh(td), expected)


# ======================================== training and the bonus it drives


def _train(loss: nn.Module, td: TensorDict, steps: int, lr: float = 1e-3) -> None:
    optim = torch.optim.Adam(loss.parameters(), lr=lr)
    for _ in range(steps):
        out = loss(td)
        optim.zero_grad()
        sum(v for k, v in out.items() if k.startswith("loss_")).backward()
        optim.step()


def test_training_the_loss_changes_the_transform_output(
    vector_vae, continuous_icm, make_vector_batch
):
    td = make_vector_batch((16,))
    for transform_cls, loss_cls, model in [
        (VAESurpriseTransform, VAELoss, vector_vae),
        (ICMTransform, ICMLoss, continuous_icm),
    ]:
        transform, loss = transform_cls(model), loss_cls(model)
        before = transform(td.clone())["next", "intrinsic_reward"]
        _train(loss, td, steps=20, lr=1e-2)
        after = transform(td.clone())["next", "intrinsic_reward"]
        assert not torch.allclose(before, after)
        # What the transform outputs is the trained model's bonus.
        fresh = transform_cls(model)
        assert_close(after, fresh(td.clone())["next", "intrinsic_reward"])


def test_vae_training_on_fixed_states_raises_their_kl_above_unseen_states(
    minigrid_vae, make_minigrid_batch
):
    """What training does to the VAE bonus of the states it was trained on.

    A novelty signal would do this: a few hundred Adam steps on a small fixed set
    of states *lower* their bonus relative to unseen random states (count-like).
    Measured: the opposite. The ELBO makes the posterior of
    the trained states informative (narrow, away from the prior) so that they
    can be reconstructed, which raises ``KL(q(z|s) || N(0, I))`` on exactly
    those states, while states the VAE never fitted stay near the prior. Before
    training both sets have about the same KL; after 300 steps the 16 seen
    MiniGrid states have 5-7x the KL of unseen ones (~17 vs ~3 nats; seeds 0-4,
    hidden 16 and 32). This test pins that behaviour; if the bonus is changed to
    act as a novelty signal it will fail and should be inverted.

    (The vector VAE on random Gaussian states is no better: its posterior
    collapses to ~0.01-0.3 nats and the seen/unseen ratio after training is
    0.5-1.9 depending on the seed, i.e. no signal either way.)
    """
    transform = VAESurpriseTransform(minigrid_vae)
    seen, unseen = make_minigrid_batch((16,)), make_minigrid_batch((256,))

    def mean_bonus(td):
        return transform(td.clone())["next", "intrinsic_reward"].mean().item()

    ratio_before = mean_bonus(seen) / mean_bonus(unseen)
    _train(VAELoss(minigrid_vae), seen.select("next"), steps=300)
    ratio_after = mean_bonus(seen) / mean_bonus(unseen)
    assert 0.5 < ratio_before < 1.5
    assert ratio_after > 3.0


def test_icm_training_on_fixed_transitions_lowers_their_bonus(
    continuous_icm, make_vector_batch
):
    # ICM's forward error, unlike the VAE's KL, is a novelty signal: fitting a
    # set of transitions lowers their bonus relative to unseen transitions.
    transform = ICMTransform(continuous_icm)
    seen, unseen = make_vector_batch((16,)), make_vector_batch((256,))

    def mean_bonus(td):
        return transform(td.clone())["next", "intrinsic_reward"].mean().item()

    _train(ICMLoss(continuous_icm), seen, steps=300)
    assert mean_bonus(seen) < 0.5 * mean_bonus(unseen)
