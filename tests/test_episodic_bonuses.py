"""E3B and NovelD: their definitions, episodes, state, losses and MiniGrid builders.

TorchRL's eleven transform checks run for both in tests/test_transform_contract.py;
here: the bonus against its definition across episodes (env path and batch path),
restarts on done and on reset, state_dict resume, copies with their own episodes,
the losses (TorchRL's LossModule conventions) and what training does to the bonus.
"""

from __future__ import annotations

import pytest
import torch
from tensordict import TensorDict
from test_transform_contract import reference_episodic_bonus
from torchrl.envs import Compose, SerialEnv, StepCounter, TransformedEnv
from torchrl.envs.utils import check_env_specs
from torchrl.testing.mocking_classes import (
    ContinuousActionVecMockEnv,
    DiscreteActionVecMockEnv,
)

from torchrl_surprise.modules import E3BModel, RNDModel
from torchrl_surprise.objectives import InverseDynamicsLoss, RNDDistillationLoss
from torchrl_surprise.transforms import (
    E3BTransform,
    EllipticalEpisodicMemory,
    NovelDTransform,
)

OBS_DIM = 7
ACTION_DIM = 7
KINDS = ["e3b", "noveld"]


def make_transform(kind: str, **kwargs):
    if kind == "e3b":
        model = E3BModel.for_vector(OBS_DIM, ACTION_DIM, embedding_dim=8, hidden_dim=16)
        return E3BTransform(model, **kwargs)
    rnd = RNDModel.for_vector(OBS_DIM, embedding_dim=8, hidden_dim=16)
    return NovelDTransform(rnd, **kwargs)


def episodic_env(transform, max_steps: int = 3, num_envs: int = 0) -> TransformedEnv:
    # Short episodes: the memories must restart inside a rollout.
    base = (
        SerialEnv(num_envs, ContinuousActionVecMockEnv)
        if num_envs
        else ContinuousActionVecMockEnv()
    )
    return TransformedEnv(base, Compose(StepCounter(max_steps=max_steps), transform))


def timed(td: TensorDict) -> TensorDict:
    return td.refine_names(*[None] * (td.ndim - 1), "time")


def revisiting_batch(obs_dim: int = 3) -> TensorDict:
    """Two envs, 6 steps: env 0 goes a -> b -> a -> b, ends, then a -> b."""
    a, b = torch.zeros(obs_dim), torch.ones(obs_dim)
    path = torch.stack([a, b, a, b, a, b, a])
    obs = torch.stack([path[:-1], torch.randn(6, obs_dim)])
    nxt = torch.stack([path[1:], torch.randn(6, obs_dim)])
    done = torch.zeros(2, 6, 1, dtype=torch.bool)
    done[0, 3] = True
    return timed(
        TensorDict(
            {
                "observation": obs,
                "action": torch.randn(2, 6, 2),
                "next": {
                    "observation": nxt,
                    "reward": torch.zeros(2, 6, 1),
                    "done": done,
                },
            },
            [2, 6],
        )
    )


# ================================================ the bonus, env and batch


@pytest.mark.parametrize("kind", KINDS)
@pytest.mark.parametrize("num_envs", [0, 2])
def test_env_path_and_batch_path_follow_the_definition_across_episodes(kind, num_envs):
    transform = make_transform(kind, coef=0.5)
    env = episodic_env(transform, num_envs=num_envs)
    check_env_specs(env)
    transform.reset_episodes()
    rollout = env.rollout(10, break_when_any_done=False)
    nxt = rollout["next"]
    assert nxt["done"].sum() == 3 * max(num_envs, 1)
    expected = reference_episodic_bonus(transform, rollout)
    torch.testing.assert_close(nxt["intrinsic_reward"], expected)
    torch.testing.assert_close(nxt["reward"], nxt["extrinsic_reward"] + 0.5 * expected)
    transform.reset_episodes()
    recomputed = transform(rollout.clone())
    torch.testing.assert_close(recomputed["next", "intrinsic_reward"], expected)


def test_e3b_bonus_falls_on_repeats_and_restarts_with_the_episode():
    model = E3BModel.for_vector(3, 2, embedding_dim=16, hidden_dim=8)
    transform = E3BTransform(model, ridge=0.1)
    td = revisiting_batch()
    b = transform(td)["next", "intrinsic_reward"][..., 0]
    torch.testing.assert_close(b, reference_episodic_bonus(transform, td)[..., 0])
    phi_a = model.embed(torch.zeros(3)).double()
    phi_b = model.embed(torch.ones(3)).double()
    # The episode's first state, a, is in C when b is paid (E3B's code).
    cov = 0.1 * torch.eye(16, dtype=torch.float64) + torch.outer(phi_a, phi_a)
    first = float(phi_b @ torch.linalg.solve(cov, phi_b))
    assert b[0, 0].item() == pytest.approx(first, rel=1e-5)
    assert b[0, 2] < b[0, 0]  # b again in the same episode
    torch.testing.assert_close(b[0, 4], b[0, 0])  # a new episode: novel again
    # Without it, C starts from ridge * I.
    empty = E3BTransform(model, ridge=0.1, start_in_memory=False)
    b = empty(revisiting_batch())["next", "intrinsic_reward"][..., 0]
    assert b[0, 0].item() == pytest.approx(float(phi_b @ phi_b / 0.1), rel=1e-5)


def official_e3b_bonuses(embed, observations, starts, ridge):
    """E3B's own act loop (facebookresearch/e3b, minihack/torchbeast/src/utils.py
    l.373-379, 392, 425-442, 495-500), written independently of the library:
    at an episode's start the inverse restarts at ``I / ridge``; every state
    ``s_t`` the agent acts from is embedded, its bonus read from the inverse,
    then joins it; the bonus of an episode's first step is set to 0. Returns
    the bonus of each ``s_t`` (``[envs, T]``), which that loop writes beside
    the transition leaving ``s_t``."""
    envs, steps = starts.shape
    out = torch.zeros(envs, steps, dtype=torch.float64)
    for env in range(envs):
        for t in range(steps):
            if starts[env, t]:  # env_output['done']: cov_inverse reset, step = 0
                dim = embed(observations[env, t]).shape[-1]
                cov_inverse = torch.eye(dim, dtype=torch.float64) / ridge
                step = 0
            h = embed(observations[env, t]).double()
            u = torch.mv(cov_inverse, h)
            b = torch.dot(h, u).item()
            cov_inverse = cov_inverse - torch.outer(u, u) / (1.0 + b)
            out[env, t] = 0.0 if step == 0 else b
            step += 1
    return out


@pytest.mark.parametrize("kind", ["e3b", "vae_elliptical"])
def test_the_episode_start_is_e3b_official_recursion_on_both_paths(kind):
    # Our transition s_t -> s_{t+1} pays s_{t+1}'s bonus: E3B's loop pays the
    # same number beside the next transition, the one leaving s_{t+1}.
    from torchrl_surprise import StateVAE
    from torchrl_surprise.transforms import VAEEllipticalTransform

    torch.manual_seed(0)
    if kind == "e3b":
        model = E3BModel.for_vector(OBS_DIM, ACTION_DIM, embedding_dim=8, hidden_dim=16)
        transform = E3BTransform(model, ridge=0.1)
        embed = model.embed
    else:
        vae = StateVAE.for_vector(OBS_DIM, latent_dim=8, hidden_dim=16)
        transform = VAEEllipticalTransform(vae, ridge=0.1, start_in_memory=True)

        def embed(obs):
            return vae.posterior(obs)[0]

    env = episodic_env(transform, max_steps=4, num_envs=2)
    rollout = env.rollout(13, break_when_any_done=False)
    done = rollout["next", "done"][..., 0]
    starts = torch.zeros_like(done)
    starts[:, 0] = True
    starts[:, 1:] = done[:, :-1]
    with torch.no_grad():
        official = official_e3b_bonuses(embed, rollout["observation"], starts, 0.1)
    ours = rollout["next", "intrinsic_reward"][..., 0].double()
    inside = ~done[:, :-1]  # s_{t+1} is the next state acted from
    assert inside.sum() > 10 and (~inside).sum() >= 4
    torch.testing.assert_close(
        ours[:, :-1][inside], official[:, 1:][inside], rtol=1e-5, atol=1e-6
    )
    assert (official[starts] == 0).all()
    transform.reset_episodes()
    batch = transform(timed(rollout.clone()))["next", "intrinsic_reward"][..., 0]
    torch.testing.assert_close(batch.double(), ours)


def test_noveld_pays_first_visits_only_and_restarts_with_the_episode():
    rnd = RNDModel.for_vector(3, embedding_dim=4, hidden_dim=8)
    transform = NovelDTransform(rnd, alpha=0.5)
    td = revisiting_batch()
    out = transform(td.clone())["next", "intrinsic_reward"][..., 0]
    with torch.no_grad():
        gain = (
            rnd.novelty(td["next", "observation"])
            - 0.5 * rnd.novelty(td["observation"])
        ).clamp_min(0)
    # env 0: a->b (new), b->a (a is the episode's first state), a->b, b->a (done),
    # then a new episode: a->b new, b->a not (a was its first state).
    first = torch.tensor([[1, 0, 0, 0, 1, 0], [1, 1, 1, 1, 1, 1]], dtype=torch.bool)
    torch.testing.assert_close(out, gain * first)
    assert (gain[0, 0] > 0) and (gain[1] > 0).all()  # the indicator did the zeros


def test_noveld_visit_keys_choose_what_makes_a_state():
    rnd = RNDModel.for_vector(3, embedding_dim=4, hidden_dim=8)
    td = revisiting_batch()
    # A key constant over the episode: only the first transition is a first visit.
    td["room"] = torch.zeros(2, 6, 1)
    td["next", "room"] = torch.zeros(2, 6, 1)
    transform = NovelDTransform(rnd, visit_keys=["room"])
    out = transform(td.clone())["next", "intrinsic_reward"][..., 0]
    assert (out[:, 1:4] == 0).all() and (out[0, 4:] == 0).all()
    with pytest.raises(KeyError, match="room"):
        NovelDTransform(rnd, visit_keys=["room"])(revisiting_batch())
    with pytest.raises(ValueError, match="alpha"):
        NovelDTransform(rnd, alpha=-1.0)


@pytest.mark.parametrize("kind", KINDS)
def test_a_reset_restarts_only_the_envs_it_resets(kind):
    transform = make_transform(kind)
    env = TransformedEnv(SerialEnv(2, ContinuousActionVecMockEnv), transform)
    env.rollout(2)
    memory = transform.memory if kind == "e3b" else transform.visits
    assert memory.env_shape == (2,)
    before = {
        k: v.clone() for k, v in memory.state_dict().items() if k != "_extra_state"
    }
    extra = memory.get_extra_state() if kind == "noveld" else None
    reset = TensorDict({"_reset": torch.tensor([[True], [False]])}, [2])
    env.reset(reset)
    if kind == "e3b":
        fresh = torch.eye(8, dtype=torch.float64) / transform.ridge
        torch.testing.assert_close(memory.inv_cov[0], fresh)
        torch.testing.assert_close(memory.inv_cov[1], before["inv_cov"][1])
    else:
        seen = memory.get_extra_state()["seen"]
        assert seen[0] == [] and seen[1] == extra["seen"][1] != []
    env.reset()
    assert memory.env_shape is None


@pytest.mark.parametrize("kind", KINDS)
def test_episodic_state_is_saved_so_a_resumed_run_continues_its_episodes(kind):
    td = revisiting_batch(OBS_DIM)
    td["action"] = torch.randn(2, 6, ACTION_DIM)
    first = make_transform(kind)
    whole = first.clone()
    expected = whole(td.clone())["next", "intrinsic_reward"][:, 3:]
    first(td[:, :3].clone())
    resumed = make_transform(kind)
    resumed.load_state_dict(first.state_dict())
    second = resumed(td[:, 3:].clone())
    torch.testing.assert_close(second["next", "intrinsic_reward"], expected)


@pytest.mark.parametrize("kind", KINDS)
def test_copies_keep_their_own_episodes(kind):
    # A frozen copy evaluating on other envs must not advance training episodes.
    transform = make_transform(kind)
    td = revisiting_batch(OBS_DIM)
    td["action"] = torch.randn(2, 6, ACTION_DIM)
    transform(td[:, :2].clone())
    state = {k: v for k, v in transform.state_dict().items()}
    evaluation = transform.frozen_copy()
    evaluation.reset_episodes()
    evaluation(td[:1].clone())
    after = transform.state_dict()
    for key, value in state.items():
        if torch.is_tensor(value):
            assert torch.equal(after[key], value), key
        else:
            assert after[key] == value, key
    assert bonus_model_of(evaluation) is bonus_model_of(transform)


def bonus_model_of(transform):
    return transform.model if isinstance(transform, E3BTransform) else transform.rnd


@pytest.mark.parametrize("kind", KINDS)
def test_batches_that_are_not_time_ordered_are_refused(kind):
    transform = make_transform(kind)
    sample = revisiting_batch(OBS_DIM)
    sample.names = [None, None]
    sample["action"] = torch.randn(2, 6, ACTION_DIM)
    with pytest.raises(ValueError, match="time-ordered"):
        transform(sample.reshape(-1))
    transform(timed(sample.clone()))
    with pytest.raises(ValueError, match=r"\(2,\) envs, this batch has \(1,\)"):
        transform(timed(sample[:1].clone()))


def test_the_elliptical_memory_is_one_component_shared_with_the_vae_bonus():
    from torchrl_surprise import StateVAE
    from torchrl_surprise.transforms import VAEEllipticalTransform

    model = E3BModel.for_vector(OBS_DIM, ACTION_DIM, embedding_dim=8, hidden_dim=16)
    vae = StateVAE.for_vector(OBS_DIM, latent_dim=8, hidden_dim=16)
    for transform in (E3BTransform(model), VAEEllipticalTransform(vae)):
        assert type(transform.memory) is EllipticalEpisodicMemory
        assert transform.memory.ridge == 0.1


# ======================================================= MiniGrid builders


def test_minigrid_builders_give_bonuses_on_image_and_direction(make_minigrid_batch):
    td = timed(make_minigrid_batch((2, 4)))
    td["next", "done"] = torch.zeros(2, 4, 1, dtype=torch.bool)
    model = E3BModel.for_minigrid(num_actions=7, embedding_dim=16, hidden_dim=16)
    rnd = RNDModel.for_minigrid(embedding_dim=8, hidden_dim=16)
    assert model.in_keys == rnd.in_keys == ["image", "direction"]
    assert E3BModel.for_minigrid().embedding_dim == 1024  # E3B's
    for transform in (E3BTransform(model), NovelDTransform(rnd)):
        out = transform(td.clone())["next", "intrinsic_reward"]
        torch.testing.assert_close(out, reference_episodic_bonus(transform, td))
    loss = InverseDynamicsLoss(model)(td)
    assert loss["loss_inverse"].requires_grad
    assert RNDDistillationLoss(rnd)(td)["loss_predictor"].requires_grad


# ================================================================= losses


def e3b_and_batch(discrete: bool):
    action_dim = ACTION_DIM
    model = E3BModel.for_vector(
        OBS_DIM, action_dim, embedding_dim=8, hidden_dim=16, discrete=discrete
    )
    base = DiscreteActionVecMockEnv() if discrete else ContinuousActionVecMockEnv()
    return model, base.rollout(6)


@pytest.mark.parametrize("discrete", [False, True])
def test_inverse_dynamics_loss_contract(discrete):
    model, batch = e3b_and_batch(discrete)
    loss = InverseDynamicsLoss(model)
    assert loss.in_keys == ["observation", ("next", "observation"), "action"]
    original = batch.clone()
    out = loss(batch)
    assert set(out.keys()) == set(loss.out_keys)
    torch.testing.assert_close(batch, original)  # input untouched
    # keyword call == TensorDict call
    torch.testing.assert_close(
        loss(
            observation=batch["observation"],
            action=batch["action"],
            next=batch["next"].select("observation"),
        )["loss_inverse"],
        out["loss_inverse"],
    )
    # reduction
    per_sample = InverseDynamicsLoss(model, reduction="none")(batch)["loss_inverse"]
    assert per_sample.shape == batch.batch_size
    torch.testing.assert_close(per_sample.mean(), out["loss_inverse"])
    # gradients reach the embedding and the inverse model
    out["loss_inverse"].backward()
    assert all(p.grad is not None for p in model.parameters())
    # keys
    renamed = batch.rename_key_("observation", "obs")
    renamed.rename_key_(("next", "observation"), ("next", "obs"))
    loss.set_keys(observations="obs")
    loss(renamed)
    with pytest.raises(ValueError):
        loss.set_keys(unknown="x")
    with pytest.raises(KeyError, match="expected the key"):
        loss(original)


def test_rnd_distillation_loss_contract(make_vector_batch):
    rnd = RNDModel.for_vector(OBS_DIM, embedding_dim=8, hidden_dim=16)
    loss = RNDDistillationLoss(rnd)
    batch = make_vector_batch((5,))
    assert loss.in_keys == [("next", "observation")]
    original = batch.clone()
    out = loss(batch)
    torch.testing.assert_close(batch, original)
    torch.testing.assert_close(
        loss(next=batch["next"].select("observation"))["loss_predictor"],
        out["loss_predictor"],
    )
    per_sample = RNDDistillationLoss(rnd, reduction="none")(batch)["loss_predictor"]
    assert per_sample.shape == (5,)
    out["loss_predictor"].backward()
    # Only the predictor trains: the target is the fixed random network.
    assert all(p.grad is not None for p in rnd.predictor.parameters())
    assert all(p.grad is None for p in rnd.target.parameters())
    assert not any(
        p.requires_grad for p in loss.parameters() if p in set(rnd.target.parameters())
    )
    state = loss.state_dict()
    other = RNDDistillationLoss(RNDModel.for_vector(OBS_DIM, 8, 16))
    other.load_state_dict(state)
    torch.testing.assert_close(other(batch)["loss_predictor"], out["loss_predictor"])


def _train(loss, params, batch, key, steps, lr=1e-2):
    optim = torch.optim.Adam(params, lr=lr)
    for _ in range(steps):
        value = loss(batch)[key]
        optim.zero_grad()
        value.backward()
        optim.step()
    return value.item()


def test_training_the_rnd_predictor_lowers_the_novelty_of_trained_states(
    make_vector_batch,
):
    rnd = RNDModel.for_vector(OBS_DIM, embedding_dim=8, hidden_dim=32)
    seen, unseen = make_vector_batch((32,)), make_vector_batch((256,))
    with torch.no_grad():
        before = rnd.novelty(seen["next", "observation"]).mean()
    _train(
        RNDDistillationLoss(rnd),
        rnd.predictor.parameters(),
        seen,
        "loss_predictor",
        200,
    )
    with torch.no_grad():
        after = rnd.novelty(seen["next", "observation"]).mean()
        other = rnd.novelty(unseen["next", "observation"] * 3).mean()
    assert after < 0.3 * before
    assert other > 2 * after


def test_training_the_inverse_model_lowers_its_error():
    # Transitions where the action shows in the next state: s' = s + one_hot(a).
    model, _ = e3b_and_batch(discrete=True)
    action = torch.randint(0, ACTION_DIM, (64,))
    obs = torch.randn(64, OBS_DIM)
    batch = TensorDict(
        {
            "observation": obs,
            "action": action,
            "next": {"observation": obs + torch.eye(OBS_DIM)[action]},
        },
        [64],
    )
    loss = InverseDynamicsLoss(model)
    start = loss(batch)["loss_inverse"].item()
    end = _train(loss, model.parameters(), batch, "loss_inverse", 100)
    assert end < 0.2 * start


# ============================================ the batched walk == the loop


@pytest.mark.parametrize("time_dim", [0, 1, 2])
@pytest.mark.parametrize("chunk", [4, 128])
def test_the_elliptical_walk_equals_one_step_at_a_time(time_dim, chunk):
    # Episodes ending mid-chunk, on a chunk's last step and on the batch's last
    # step, over several chunks, from a memory already holding an episode.
    torch.manual_seed(0)
    dim, envs, steps = 6, (2, 3), 11
    phi = torch.randn(*envs, steps, dim) * 2
    done = torch.rand(*envs, steps) < 0.2
    done[0, 0, [3, 7]] = True
    done[1, 2, -1] = True
    walked = EllipticalEpisodicMemory(dim, ridge=0.1)
    walked.chunk = chunk
    stepped = EllipticalEpisodicMemory(dim, ridge=0.1)
    start = torch.randn(*envs, dim)
    walked.step(start)
    stepped.step(start)
    # each step's first state, taken in where an episode begins (chunk edges too)
    firsts = torch.randn(*envs, steps, dim)
    loop = torch.stack(
        [
            stepped.step(phi[..., t, :], done[..., t], firsts[..., t, :])
            for t in range(steps)
        ],
        -1,
    )
    bonus = walked.walk(
        phi.movedim(2, time_dim),
        done.movedim(2, time_dim),
        time_dim,
        firsts.movedim(2, time_dim),
    ).movedim(time_dim, 2)
    torch.testing.assert_close(bonus, loop, rtol=1e-9, atol=1e-12)
    torch.testing.assert_close(walked.inv_cov, stepped.inv_cov, rtol=1e-9, atol=1e-12)
    # And they go on equally.
    more = torch.randn(*envs, dim)
    torch.testing.assert_close(walked.step(more), stepped.step(more))


def official_running_std(batches, batch_size):
    """models.py l.413-434 of facebookresearch/e3b as written, on learner batches
    ``[T, batch_size]`` (a NetHackPolicyNet's buffers: count starts at 1e-8)."""
    reward_sum = torch.zeros((), dtype=torch.float64)
    reward_m2 = torch.zeros((), dtype=torch.float64)
    reward_count = torch.zeros((), dtype=torch.float64).fill_(1e-8)
    for batch in batches:
        for reward_batch in batch.double().split(batch_size, dim=1):
            new_count = len(reward_batch)
            new_sum = torch.sum(reward_batch)
            new_mean = new_sum / new_count
            curr_mean = reward_sum / reward_count
            new_m2 = torch.sum((reward_batch - new_mean) ** 2) + (
                (reward_count * new_count)
                / (reward_count + new_count)
                * (new_mean - curr_mean) ** 2
            )
            reward_count += new_count
            reward_sum += new_sum
            reward_m2 += new_m2
    return torch.sqrt(reward_m2 / reward_count)


@pytest.mark.parametrize("envs", [2, 12])  # one learner batch of E3B's, or 8 + 4
def test_e3b_std_divides_by_the_statistic_of_e3b_code(envs):
    # A bonus of mean ~1: E3B's statistic is several times the bonus's std.
    model = E3BModel.for_vector(3, 2, embedding_dim=8, hidden_dim=8)
    transform = E3BTransform(model, normalization="e3b_std", reward_key=None)
    batches = []
    for _ in range(3):
        td = timed(
            TensorDict(
                {
                    "observation": torch.randn(envs, 6, 3),
                    "action": torch.randn(envs, 6, 2),
                    "next": {
                        "observation": torch.randn(envs, 6, 3),
                        "reward": torch.zeros(envs, 6, 1),
                        "done": torch.rand(envs, 6, 1) < 0.2,
                    },
                },
                [envs, 6],
            )
        )
        out = transform(td)
        raw = out["next", "intrinsic_reward"][..., 0]
        batches.append(raw.T)  # [T, envs], time first as E3B's learner batch
        expected = official_running_std(batches, 8)
        torch.testing.assert_close(
            out["next", "intrinsic_reward_normalized"][..., 0].double(),
            raw.double() / expected,
        )
    assert expected > 1.5 * torch.cat([b.reshape(-1) for b in batches]).double().std()
