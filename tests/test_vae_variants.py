"""The novelty-aware VAE bonuses: what training does to them, and their contract."""

from __future__ import annotations

import pytest
import torch
from tensordict import TensorDict
from torchrl.envs import TransformedEnv, check_env_specs
from torchrl.testing.mocking_classes import ContinuousActionVecMockEnv

from torchrl_surprise import StateVAE, VAELoss
from torchrl_surprise.transforms import (
    VAENegativeELBOTransform,
    VAENovelDTransform,
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


def _elliptical_env(**kwargs):
    from torchrl.envs import Compose, StepCounter

    from torchrl_surprise.transforms import VAEEllipticalTransform

    base = ContinuousActionVecMockEnv()
    obs_dim = base.observation_spec["observation"].shape[-1]
    vae = StateVAE.for_vector(obs_dim, latent_dim=4, hidden_dim=16)
    bonus = VAEEllipticalTransform(vae, coef=0.1, **kwargs)
    # Episodes of 3 steps: the memory must restart inside a rollout.
    return TransformedEnv(base, Compose(StepCounter(max_steps=3), bonus)), bonus


@pytest.mark.parametrize(
    "global_bonus, unit_latent", [("none", False), ("kl", False), ("none", True)]
)
def test_elliptical_bonus_env_path_equals_batch_path_across_episodes(
    global_bonus, unit_latent
):
    kwargs = {"global_bonus": global_bonus, "unit_latent": unit_latent}
    env, bonus = _elliptical_env(**kwargs)
    check_env_specs(env)
    env, bonus = _elliptical_env(**kwargs)
    rollout = env.rollout(10, break_when_any_done=False)
    assert rollout["next", "done"].sum() == 3
    bonus.reset_episodes()
    recomputed = bonus(rollout.clone())
    torch.testing.assert_close(
        recomputed["next", "intrinsic_reward"], rollout["next", "intrinsic_reward"]
    )


def test_a_unit_latent_bonus_reads_directions_not_the_latents_scale():
    from tensordict import TensorDict

    from torchrl_surprise.transforms import VAEEllipticalTransform

    torch.manual_seed(0)
    vae = StateVAE.for_vector(3, latent_dim=4, hidden_dim=8)
    obs = torch.randn(2, 6, 3)
    done = torch.zeros(2, 6, 1, dtype=torch.bool)
    done[0, 3] = True

    def bonus(unit_latent: bool) -> torch.Tensor:
        transform = VAEEllipticalTransform(
            vae, in_keys=["observation"], ridge=0.1, unit_latent=unit_latent
        )
        td = TensorDict(
            {
                "next": {
                    "observation": obs,
                    "reward": torch.zeros(2, 6, 1),
                    "done": done,
                }
            },
            [2, 6],
            names=[None, "time"],
        )
        return transform(td)["next", "intrinsic_reward"][..., 0]

    unit, raw = bonus(True), bonus(False)
    # an episode's first state: 1 / ridge at unit length, |mu|^2 / ridge otherwise
    assert unit[:, 0].tolist() == pytest.approx([10.0, 10.0])
    assert unit[0, 4].item() == pytest.approx(10.0)  # after env 0's episode ended
    assert not torch.allclose(raw[:, 0], unit[:, 0])
    # posterior means 5 times longer (the encoder's mean head scaled): the same
    # unit-length bonus; the raw one 25 times larger at an episode's first state
    # and changed everywhere (against the same ridge)
    with torch.no_grad():
        loc_rows = vae.head.weight.shape[0] // 2
        vae.head.weight[:loc_rows] *= 5.0
        vae.head.bias[:loc_rows] *= 5.0
    torch.testing.assert_close(bonus(True), unit)
    longer = bonus(False)
    torch.testing.assert_close(longer[:, 0], raw[:, 0] * 25.0, rtol=1e-4, atol=0.0)
    assert ((longer - raw).abs() > 1e-3).all()
    # a config's string is not taken for a bool ("false" would be true)
    with pytest.raises(TypeError, match="unit_latent must be a bool, got 'false'"):
        VAEEllipticalTransform(vae, unit_latent="false")


def test_elliptical_bonus_falls_on_repeats_and_restarts_with_the_episode():
    from tensordict import TensorDict

    from torchrl_surprise.transforms import VAEEllipticalTransform

    vae = StateVAE.for_vector(3, latent_dim=4, hidden_dim=8)
    transform = VAEEllipticalTransform(vae, in_keys=["observation"], ridge=0.1)
    state, other = torch.randn(3), torch.randn(3)
    # env 0 sees one state 3 times, its episode ends, then sees it twice more;
    # env 1 sees the same state, then another one.
    obs = torch.stack(
        [state.expand(5, 3), torch.stack([state, other, state, other, state])]
    )
    done = torch.zeros(2, 5, 1, dtype=torch.bool)
    done[0, 2] = True
    td = TensorDict(
        {"next": {"observation": obs, "reward": torch.zeros(2, 5, 1), "done": done}},
        [2, 5],
        names=[None, "time"],
    )
    b = transform(td)["next", "intrinsic_reward"][..., 0]
    phi = vae.posterior(state)[0].double()
    first = float(phi @ phi / 0.1)
    assert b[0, 0].item() == pytest.approx(first, rel=1e-5)
    assert b[0, 1] < b[0, 0] and b[0, 2] < b[0, 1]
    torch.testing.assert_close(b[0, 3:], b[0, :2])  # a new episode: novel again
    assert b[1, 0] == b[0, 0]  # envs keep separate memories
    assert b[1, 1] > b[1, 2]  # a state seen in the episode is less novel


def test_elliptical_bonus_refuses_batches_without_time_and_other_env_counts():
    from tensordict import TensorDict

    from torchrl_surprise.transforms import VAEEllipticalTransform

    vae = StateVAE.for_vector(3, latent_dim=2, hidden_dim=8)
    transform = VAEEllipticalTransform(vae, in_keys=["observation"])
    sample = TensorDict(
        {"next": {"observation": torch.randn(4, 3), "reward": torch.zeros(4, 1)}}, [4]
    )
    with pytest.raises(ValueError, match="time-ordered"):
        transform(sample)
    timed = TensorDict(
        {"next": {"observation": torch.randn(4, 2, 3), "reward": torch.zeros(4, 2, 1)}},
        [4, 2],
        names=[None, "time"],
    )
    transform(timed)
    with pytest.raises(ValueError, match=r"\(4,\) envs, this batch has \(3,\)"):
        transform(timed[:3])
    with pytest.raises(ValueError, match="ridge"):
        VAEEllipticalTransform(vae, in_keys=["observation"], ridge=0.0)


def test_elliptical_memory_is_saved_so_a_resumed_run_continues_its_episodes():
    from tensordict import TensorDict

    from torchrl_surprise.transforms import VAEEllipticalTransform

    vae = StateVAE.for_vector(3, latent_dim=4, hidden_dim=8)
    td = TensorDict(
        {"next": {"observation": torch.randn(2, 6, 3), "reward": torch.zeros(2, 6, 1)}},
        [2, 6],
        names=[None, "time"],
    )
    whole = VAEEllipticalTransform(vae, in_keys=["observation"])(td.clone())
    first = VAEEllipticalTransform(vae, in_keys=["observation"])
    first(td[:, :3].clone())
    resumed = VAEEllipticalTransform(vae, in_keys=["observation"])
    resumed.load_state_dict(first.state_dict())
    second = resumed(td[:, 3:].clone())
    torch.testing.assert_close(
        second["next", "intrinsic_reward"], whole["next", "intrinsic_reward"][:, 3:]
    )


def test_elliptical_memory_of_an_older_state_dict_loads():
    # The memory used to be the transform's own ``_inv_cov`` buffer.
    from tensordict import TensorDict

    from torchrl_surprise.transforms import VAEEllipticalTransform

    vae = StateVAE.for_vector(3, latent_dim=4, hidden_dim=8)
    td = TensorDict(
        {"next": {"observation": torch.randn(2, 3, 3), "reward": torch.zeros(2, 3, 1)}},
        [2, 3],
        names=[None, "time"],
    )
    source = VAEEllipticalTransform(vae, in_keys=["observation"])
    source(td.clone())
    state = source.state_dict()
    state["_inv_cov"] = state.pop("memory.inv_cov")
    resumed = VAEEllipticalTransform(vae, in_keys=["observation"])
    resumed.load_state_dict(state)
    torch.testing.assert_close(resumed.memory.inv_cov, source.memory.inv_cov)


def test_vae_noveld_pays_the_crossing_into_what_the_vae_has_not_learned(
    minigrid_vae, make_minigrid_batch
):
    torch.manual_seed(0)
    transform = VAENovelDTransform(minigrid_vae)
    batch = make_minigrid_batch((16,))
    seen = batch.select("image", "direction")
    unseen = batch["next"].select("image", "direction")

    def bonus(next_states):
        # One step per env from a seen state; each s' is a first visit.
        td = batch.clone()
        td["next"].update(next_states)
        transform.reset_episodes()
        td = td.unsqueeze(-1).refine_names(None, "time")
        return mean_bonus(transform, td)

    # Untrained, the VAE's novelty is about the same for every state.
    with torch.no_grad():
        novelty = minigrid_vae.novelty(seen["image"], seen["direction"])
    assert novelty.std() / novelty.mean() < 0.01
    within = seen.roll(1, 0)  # another seen state, never the state itself
    before = bonus(unseen) / bonus(within)
    _train(minigrid_vae, TensorDict({"next": seen}, [16]), steps=300)
    after = bonus(unseen) / bonus(within)
    # Untrained, every state is about as novel: the bonus is an episodic count.
    assert 0.8 < before < 1.25
    # Trained on the seen states: moving among them pays little, leaving them pays.
    assert after > 2.0


def test_vae_noveld_env_path_equals_batch_path_across_episodes():
    from torchrl.envs import Compose, StepCounter

    def make():
        torch.manual_seed(0)
        base = ContinuousActionVecMockEnv()
        obs_dim = base.observation_spec["observation"].shape[-1]
        vae = StateVAE.for_vector(obs_dim, latent_dim=4, hidden_dim=16)
        bonus = VAENovelDTransform(vae, coef=0.1)
        return TransformedEnv(base, Compose(StepCounter(max_steps=3), bonus)), bonus

    env, bonus = make()
    check_env_specs(env)
    env, bonus = make()
    rollout = env.rollout(10, break_when_any_done=False)
    assert rollout["next", "done"].sum() == 3
    assert (rollout["next", "intrinsic_reward"] > 0).any()
    bonus.reset_episodes()
    recomputed = bonus(rollout.clone())
    torch.testing.assert_close(
        recomputed["next", "intrinsic_reward"], rollout["next", "intrinsic_reward"]
    )
    # The VAE is held as ``vae`` (its state_dict prefix) beside the episodes' sets.
    keys = bonus.state_dict().keys()
    assert any(k.startswith("vae.") for k in keys)
    assert not any(k.startswith("rnd.") for k in keys)


def test_vae_noveld_novelty_is_the_elbo_or_the_kl_and_nothing_else():
    vae = StateVAE.for_vector(3, latent_dim=2, hidden_dim=8)
    obs = torch.randn(5, 3)
    with torch.no_grad():
        kl = VAENovelDTransform(vae, in_keys=["observation"], novelty="kl")
        elbo = VAENovelDTransform(vae, in_keys=["observation"])
        torch.testing.assert_close(kl.novelty(obs), vae.kl(obs))
        torch.testing.assert_close(elbo.novelty(obs), vae.novelty(obs))
    with pytest.raises(
        ValueError, match=r"novelty must be one of \('neg_elbo', 'kl'\)"
    ):
        VAENovelDTransform(vae, in_keys=["observation"], novelty="elbo")


def test_a_trajectory_batch_scores_each_state_once_and_gives_the_same_bonus():
    # On a batch with a time dim, s_t is s'_{t-1} within an episode: its novelty
    # is read from the step before; only the first states and the reset states
    # go through the model beside the s'. The bonus is the one of scoring every
    # (s, s') pair, which the transform falls back to when the states differ.
    from torchrl.envs import Compose, StepCounter

    torch.manual_seed(0)
    base = ContinuousActionVecMockEnv()
    obs_dim = base.observation_spec["observation"].shape[-1]
    vae = StateVAE.for_vector(obs_dim, latent_dim=4, hidden_dim=16)
    bonus = VAENovelDTransform(vae, coef=0.1)
    env = TransformedEnv(base, Compose(StepCounter(max_steps=4), bonus))
    runs = [env.rollout(10, break_when_any_done=False) for _ in range(3)]
    batch = torch.stack(runs).refine_names(None, "time")  # [3 envs, 10 steps]
    assert batch["next", "done"].sum() == 6  # two resets in each env
    rows = []
    score = vae.novelty

    def counting(*observations):
        rows.append(observations[0][..., 0].numel())  # states scored
        return score(*observations)

    def every_pair(td, next_td, done, time_dim):
        return bonus._novelty_gain(td, next_td)

    bonus.reset_episodes()
    vae.novelty = counting
    once = bonus(batch.clone())["next", "intrinsic_reward"]
    # the 30 s', then each env's first state and its two reset states
    assert rows == [30 + 3 + 6]
    bonus.reset_episodes()
    bonus._novelty_gain_along = every_pair
    assert torch.equal(once, bonus(batch.clone())["next", "intrinsic_reward"])
    del bonus._novelty_gain_along
    # a batch whose s_t is not its s'_{t-1} (rewritten between steps): every
    # pair is scored
    rows.clear()
    changed = batch.clone()
    changed["observation"] = changed["observation"] + 1.0
    bonus.reset_episodes()
    bonus(changed)
    assert sum(rows) == 2 * 30
