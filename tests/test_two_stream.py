"""The two-stream advantage (extrinsic + intrinsic critics) and its critic loss."""

from __future__ import annotations

import pytest
import torch
from tensordict import TensorDict
from tensordict.nn import NormalParamExtractor, TensorDictModule, TensorDictSequential
from torch import nn
from torchrl.modules import ProbabilisticActor, TanhNormal
from torchrl.objectives import A2CLoss, ClipPPOLoss
from torchrl.objectives.value import GAE

from torchrl_surprise import IntrinsicValueLoss, LinearSchedule, TwoStreamAdvantage

B, T, D = 3, 6, 4


def critics(seed: int = 0):
    torch.manual_seed(seed)
    value = TensorDictModule(nn.Linear(D, 1), ["obs"], ["state_value"])
    value_int = TensorDictModule(nn.Linear(D, 1), ["obs"], ["state_value_int"])
    return value, value_int


def batch(done_at: int | None = 2) -> TensorDict:
    torch.manual_seed(1)
    done = torch.zeros(B, T, 1, dtype=torch.bool)
    if done_at is not None:
        done[:, done_at] = True
    return TensorDict(
        {
            "obs": torch.randn(B, T, D),
            "action": torch.randn(B, T, 2).clamp(-0.9, 0.9),
            "next": {
                "obs": torch.randn(B, T, D),
                "reward": torch.randn(B, T, 1),
                "intrinsic_reward": torch.rand(B, T, 1),
                "done": done,
                "terminated": done.clone(),
            },
        },
        [B, T],
    )


def reference_gae(value_net, td, reward_key, done, gamma=0.99, lmbda=0.95):
    """TorchRL's GAE on ``reward_key`` with the given done flags."""
    td = td.clone()
    td["next", "reward"] = td["next", reward_key]
    td["next", "done"] = done
    td["next", "terminated"] = done
    gae = GAE(gamma=gamma, lmbda=lmbda, value_network=value_net, average_gae=False)
    gae.set_keys(value=value_net.out_keys[0])
    return gae(td)


def test_the_advantage_is_the_extrinsic_one_plus_coef_times_the_intrinsic_one():
    value, value_int = critics()
    td = TwoStreamAdvantage(value, value_int, coef=0.3)(batch())
    expected = td["advantage_ext"] + 0.3 * td["advantage_int"]
    torch.testing.assert_close(td["advantage"], expected)
    ref = reference_gae(value, batch(), "reward", batch()["next", "done"])
    torch.testing.assert_close(td["advantage_ext"], ref["advantage"])
    torch.testing.assert_close(td["value_target"], ref["value_target"])


@pytest.mark.parametrize("episodic", [False, True])
def test_intrinsic_returns_cross_episode_ends_unless_episodic(episodic):
    value, value_int = critics()
    td = TwoStreamAdvantage(value, value_int, episodic=episodic)(batch(done_at=2))
    done = batch()["next", "done"] if episodic else torch.zeros(B, T, 1, dtype=bool)
    ref = reference_gae(value_int, batch(), "intrinsic_reward", done)
    torch.testing.assert_close(td["advantage_int"], ref["advantage"])
    torch.testing.assert_close(td["value_target_int"], ref["value_target"])
    # And the two choices differ exactly where an episode ends.
    other = TwoStreamAdvantage(value, value_int, episodic=not episodic)(batch())
    assert not torch.allclose(other["advantage_int"][:, :3], td["advantage_int"][:, :3])
    torch.testing.assert_close(
        other["advantage_int"][:, 3:], td["advantage_int"][:, 3:]
    )


def test_a_callable_coef_follows_the_transform_schedule():
    value, value_int = critics()
    schedule = LinearSchedule(1.0, 0.0, 100)
    mix = TwoStreamAdvantage(value, value_int, coef=lambda: schedule(frames[0]))
    frames = [0]
    first = mix(batch())
    frames[0] = 100
    last = mix(batch())
    torch.testing.assert_close(
        first["advantage"], first["advantage_ext"] + first["advantage_int"]
    )
    torch.testing.assert_close(last["advantage"], last["advantage_ext"])


def test_a_missing_bonus_is_a_clear_error():
    value, value_int = critics()
    td = batch()
    del td["next", "intrinsic_reward"]
    with pytest.raises(KeyError, match="intrinsic_reward"):
        TwoStreamAdvantage(value, value_int)(td)
    with pytest.raises(KeyError, match="value_target_int"):
        IntrinsicValueLoss(value_int)(batch())


def actor():
    net = nn.Sequential(nn.Linear(D, 4), NormalParamExtractor())
    module = TensorDictModule(net, ["obs"], ["loc", "scale"])
    return ProbabilisticActor(
        module,
        in_keys=["loc", "scale"],
        distribution_class=TanhNormal,
        return_log_prob=True,
    )


@pytest.mark.parametrize("loss_cls", [A2CLoss, ClipPPOLoss])
def test_torchrl_policy_losses_use_the_mixed_advantage(loss_cls):
    value, value_int = critics()
    policy = actor()
    td = batch()
    with torch.no_grad():
        policy(td)
    td = TwoStreamAdvantage(value, value_int, coef=2.0)(td)
    loss = loss_cls(policy, value)
    before = loss(td.clone())["loss_objective"]
    td_shifted = td.clone()
    td_shifted["advantage_int"] = td["advantage_int"] + 1.0
    td_shifted["advantage"] = td["advantage"] + 2.0  # as the mix would give
    after = loss(td_shifted)["loss_objective"]
    assert not torch.allclose(before, after), "the loss reads the mixed advantage"


def test_the_intrinsic_critic_loss_trains_only_the_intrinsic_critic():
    value, value_int = critics()
    td = TwoStreamAdvantage(value, value_int)(batch())
    loss = IntrinsicValueLoss(value_int, critic_coef=0.5)
    out = loss(td)["loss_critic_int"]
    expected = (
        0.5
        * (value_int(td.clone())["state_value_int"] - td["value_target_int"])
        .pow(2)
        .mean()
    )
    torch.testing.assert_close(out, expected)
    out.backward()
    assert all(p.grad is not None for p in value_int.parameters())
    assert all(p.grad is None for p in value.parameters())
    assert IntrinsicValueLoss(value_int, reduction="none")(td)[
        "loss_critic_int"
    ].shape == (B, T, 1)


@pytest.mark.parametrize("episodic", [False, True])
def test_one_two_headed_critic_gives_what_two_critics_give(episodic):
    value, value_int = critics()
    td = batch()
    two = TwoStreamAdvantage(value, value_int, coef=0.3, episodic=episodic)(td.clone())
    both = TensorDictSequential(value, value_int)
    one = TwoStreamAdvantage(both, None, coef=0.3, episodic=episodic)(td.clone())
    for key in ["advantage", "advantage_ext", "advantage_int", "value_target"]:
        torch.testing.assert_close(one[key], two[key])
    torch.testing.assert_close(one["value_target_int"], two["value_target_int"])
    torch.testing.assert_close(one["state_value_int"], two["state_value_int"])
    # a network that writes one value only is refused by name
    with pytest.raises(KeyError, match="state_value_int"):
        TwoStreamAdvantage(value, None)(td.clone())
