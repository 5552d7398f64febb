"""ICM and E3B on the shared inverse-dynamics model and loss load what was saved
before, and compute what they computed.

``tests/data/icm_e3b_state_819782e.pt`` was written by the code at 819782e
(before ``InverseDynamicsModel`` and ``InverseDynamicsLoss`` were shared): on a
fixed MiniGrid batch of 5 transitions,

* ``icm_model``: ``torch.manual_seed(1); ICMModel.for_minigrid(7, hidden_dim=8)``,
  its ``ICMLoss(beta=0.3)`` (``icm_loss``, keys ``icm.*``) and
  ``ICMTransform(coef=0.1)`` (``icm_transform``: a recipe checkpoint's
  ``bonus_transform``), with ``forward_error`` and the loss's outputs;
* ``e3b_model``: ``torch.manual_seed(2); E3BModel.for_minigrid(7,
  embedding_dim=8, hidden_dim=8)``, its ``InverseDynamicsLoss`` (``e3b_loss``),
  with ``embed`` and the loss's outputs.
"""

from __future__ import annotations

from pathlib import Path

import pytest
import torch
from tensordict import TensorDict

from torchrl_surprise import (
    E3BModel,
    E3BTransform,
    ICMLoss,
    ICMModel,
    ICMTransform,
    InverseDynamicsLoss,
)
from torchrl_surprise.modules import InverseDynamicsModel

FIXTURE = Path(__file__).parent / "data" / "icm_e3b_state_819782e.pt"


@pytest.fixture(scope="module")
def saved():
    return torch.load(FIXTURE, weights_only=True)


def batch_of(saved) -> TensorDict:
    return TensorDict(saved["batch"], [5])


def observations(batch: TensorDict, *prefix: str) -> tuple[torch.Tensor, ...]:
    return batch[(*prefix, "image")], batch[(*prefix, "direction")]


def assert_state_equal(actual: dict, expected: dict) -> None:
    assert list(actual) == list(expected)
    for key in expected:
        torch.testing.assert_close(actual[key], expected[key], rtol=0, atol=0)


def icm() -> ICMModel:
    return ICMModel.for_minigrid(num_actions=7, hidden_dim=8)


def e3b() -> E3BModel:
    return E3BModel.for_minigrid(num_actions=7, embedding_dim=8, hidden_dim=8)


def test_builders_give_the_same_parameters_at_a_seed(saved):
    torch.manual_seed(1)
    assert_state_equal(icm().state_dict(), saved["icm_model"])
    torch.manual_seed(2)
    assert_state_equal(e3b().state_dict(), saved["e3b_model"])


def test_an_icm_loss_state_dict_of_the_old_layout_loads(saved):
    assert all(key.startswith("icm.") for key in saved["icm_loss"])
    torch.manual_seed(0)  # other weights than the saved ones
    loss = ICMLoss(icm(), beta=0.3)
    loss.load_state_dict(saved["icm_loss"], strict=True)
    assert_state_equal(loss.icm.state_dict(), saved["icm_model"])
    out = loss(batch_of(saved))
    for key, value in saved["icm_loss_out"].items():
        torch.testing.assert_close(out[key], value, rtol=0, atol=0)
    # The caller's dict is left as it was.
    assert all(key.startswith("icm.") for key in saved["icm_loss"])


def test_the_icm_loss_holds_one_model_under_both_names(saved):
    model = icm()
    loss = ICMLoss(model)
    assert loss.icm is model and loss.model is model
    # One copy of the weights, in the model's order (a bonus optimiser's state
    # in a checkpoint follows it).
    assert [id(p) for p in loss.parameters()] == [id(p) for p in model.parameters()]
    assert list(loss.state_dict()) == [f"model.{k}" for k in model.state_dict()]
    # The current layout loads too, strictly.
    other = ICMLoss(icm())
    other.load_state_dict(loss.state_dict(), strict=True)
    assert_state_equal(other.model.state_dict(), model.state_dict())


def test_a_recipe_checkpoints_icm_transform_state_loads(saved):
    # A checkpoint's bonus_transform of an ICM run: the transform's state_dict.
    torch.manual_seed(0)
    transform = ICMTransform(icm(), coef=0.1)
    transform.load_state_dict(saved["icm_transform"], strict=True)
    batch = batch_of(saved)
    error = transform.icm.forward_error(
        observations(batch), batch["action"], observations(batch, "next")
    )
    torch.testing.assert_close(error, saved["icm_forward_error"], rtol=0, atol=0)


def test_e3b_model_and_loss_state_dicts_of_the_old_layout_load(saved):
    torch.manual_seed(0)
    model = e3b()
    loss = InverseDynamicsLoss(model)
    loss.load_state_dict(saved["e3b_loss"], strict=True)
    assert_state_equal(model.state_dict(), saved["e3b_model"])
    batch = batch_of(saved)
    torch.testing.assert_close(
        model.embed(*observations(batch)), saved["e3b_embedding"], rtol=0, atol=0
    )
    out = loss(batch)
    for key, value in saved["e3b_loss_out"].items():
        torch.testing.assert_close(out[key], value, rtol=0, atol=0)
    E3BTransform(e3b()).model.load_state_dict(saved["e3b_model"], strict=True)


def test_icm_loss_and_the_inverse_dynamics_loss_share_the_inverse_term(saved):
    # ICM's inverse loss is the inverse-dynamics loss weighted by 1 - beta.
    torch.manual_seed(3)
    model = icm()
    batch = batch_of(saved)
    icm_out = ICMLoss(model, beta=0.3, reduction="none")(batch)
    inverse = InverseDynamicsLoss(model, reduction="none")(batch)
    torch.testing.assert_close(icm_out["loss_inverse"], 0.7 * inverse["loss_inverse"])
    torch.testing.assert_close(icm_out["inverse_error"], inverse["inverse_error"])


@pytest.mark.parametrize("model", [e3b, lambda: InverseDynamicsModel.for_vector(3, 2)])
def test_icm_loss_refuses_a_model_without_a_forward_model(model):
    with pytest.raises(TypeError, match="ICMLoss: expected an ICMModel"):
        ICMLoss(model())
