"""TorchRL's transform contract and the behaviour of the bonus transforms.

The first part runs the eleven checks of TorchRL's ``TransformBase``
(test/transforms/_transforms_common.py) for both bonus transforms; the rest
checks what the shared base promises: the KL, the two paths (env and batch),
mixing, normalisation, statistics, freezing, the schedule, ``state_dict``,
batch shapes, several keys, and clear errors on bad input.
"""

from __future__ import annotations

import math
from functools import partial

import pytest
import torch
from tensordict import TensorDict, TensorDictBase
from tensordict import assert_close as assert_td_close
from torch import nn
from torchrl.data import (
    Composite,
    LazyTensorStorage,
    ReplayBuffer,
    SamplerWithoutReplacement,
    TensorDictReplayBuffer,
    Unbounded,
)
from torchrl.envs import (
    Compose,
    GymEnv,
    ParallelEnv,
    SerialEnv,
    TransformedEnv,
)
from torchrl.envs.transforms.rnd import RunningMeanStd
from torchrl.envs.utils import check_env_specs
from torchrl.testing.mocking_classes import (
    ContinuousActionVecMockEnv,
    DiscreteActionVecMockEnv,
)

from torchrl_surprise import (
    ICMModel,
    ICMTransform,
    LinearSchedule,
    StateVAE,
    VAESurpriseTransform,
)
from torchrl_surprise.modules import E3BModel, RNDModel, kl_to_standard_normal
from torchrl_surprise.transforms import (
    E3BTransform,
    NovelDTransform,
    VAENovelDTransform,
)

OBS_DIM = 7  # the vector mock envs
ACTION_DIM = 7
KINDS = ["vae", "icm"]
#: Episodic bonuses: their batch path walks a time dimension.
EPISODIC = ["e3b", "noveld", "vae_noveld", "vae_noveld_kl"]
#: The transforms that pass TorchRL's eleven checks.
CONTRACT_KINDS = KINDS + EPISODIC
NORMALIZATIONS = ["none", "reward_std", "zscore", "return_std", "e3b_std"]


# --------------------------------------------------------------- helpers
# Module level: ParallelEnv pickles its env factories into spawned workers.


def make_model(kind: str, obs_dim: int = OBS_DIM, action_dim: int = ACTION_DIM):
    if kind in ("vae", "vae_noveld", "vae_noveld_kl"):
        return StateVAE.for_vector(obs_dim, latent_dim=4, hidden_dim=16)
    if kind == "e3b":
        return E3BModel.for_vector(obs_dim, action_dim, embedding_dim=8, hidden_dim=16)
    if kind == "noveld":
        return RNDModel.for_vector(obs_dim, embedding_dim=8, hidden_dim=16)
    return ICMModel.for_vector(obs_dim, action_dim, hidden_dim=16)


TRANSFORMS = {
    "vae": VAESurpriseTransform,
    "icm": ICMTransform,
    "e3b": E3BTransform,
    "noveld": NovelDTransform,
    "vae_noveld": VAENovelDTransform,
}


def make_transform(kind: str, model=None, **kwargs):
    if model is None:
        model = make_model(kind)
    if kind == "vae_noveld_kl":  # NovelD on the VAE's KL
        return VAENovelDTransform(model, novelty="kl", **kwargs)
    return TRANSFORMS[kind](model, **kwargs)


def time_ordered(kind: str, td: TensorDict) -> TensorDict:
    """An episodic bonus reads its last dimension as time (collectors name it)."""
    if kind in EPISODIC:
        td.refine_names(*[None] * (td.ndim - 1), "time")
    return td


def reset_episodes(transform) -> None:
    if hasattr(transform, "reset_episodes"):
        transform.reset_episodes()


def make_env(kind: str, **kwargs) -> TransformedEnv:
    return TransformedEnv(
        ContinuousActionVecMockEnv(), make_transform(kind, coef=0.5, **kwargs)
    )


def make_stacked_bonus_env() -> TransformedEnv:
    """All four bonuses, each stacked on the reward the one before it mixed."""
    return TransformedEnv(
        ContinuousActionVecMockEnv(),
        Compose(
            make_transform("vae", coef=0.5),
            *[
                make_transform(
                    kind,
                    coef=coef,
                    intrinsic_reward_key=f"{kind}_reward",
                    extrinsic_reward_key=f"reward_before_{kind}",
                )
                for kind, coef in [("icm", 0.25), ("e3b", 0.125), ("noveld", 0.0625)]
            ],
        ),
    )


def bonus_model(transform):
    for name in ("vae", "icm", "model", "rnd"):
        if hasattr(transform, name):
            return getattr(transform, name)
    raise AssertionError(type(transform))


def reference_episodic_bonus(transform, td: TensorDict) -> torch.Tensor:
    """E3B's or NovelD's (on RND or the VAE) bonus by its definition, episode by
    episode.

    ``td`` is ``[*envs, time]``; the bonus is ``[*envs, time, 1]``.
    """
    shape = td.batch_size
    flat = td.reshape(-1, shape[-1]) if td.ndim > 1 else td.unsqueeze(0)
    done = flat.get(("next", "done"), None)
    done = torch.zeros(flat.shape, dtype=torch.bool) if done is None else done
    done = done.reshape(flat.shape)
    bonus = torch.zeros(flat.shape, dtype=torch.float64)
    nxt = [flat["next", key] for key in transform.in_keys]
    if isinstance(transform, E3BTransform):
        phi = transform.model.embed(*nxt).double()
        # An episode's first state s_0 joins C before s_1's bonus (E3B's code).
        start = transform.model.embed(*[flat[key] for key in transform.in_keys])
        start = start.double() * transform.start_in_memory
        eye = torch.eye(phi.shape[-1], dtype=torch.float64)
        for env in range(flat.shape[0]):
            cov = transform.ridge * eye + torch.outer(start[env, 0], start[env, 0])
            for t in range(flat.shape[1]):
                u = phi[env, t]
                bonus[env, t] = u @ torch.linalg.solve(cov, u)
                cov = cov + torch.outer(u, u)
                if done[env, t] and t + 1 < flat.shape[1]:
                    s0 = start[env, t + 1]
                    cov = transform.ridge * eye + torch.outer(s0, s0)
    else:

        def novelty(obs):
            if isinstance(transform, VAENovelDTransform):
                vae = transform.vae
                if transform.novelty_kind == "kl":
                    return vae.kl(*obs).double()
                # the negative ELBO
                loc, scale = vae.posterior(*obs)
                nll = -vae.decoder.log_prob(loc, *obs)
                return (nll + kl_to_standard_normal(loc, scale)).double()
            rnd = transform.rnd
            return (rnd.predictor(*obs) - rnd.target(*obs)).norm(dim=-1).double()

        now = [flat[key] for key in transform.in_keys]
        gain = (novelty(nxt) - transform.alpha * novelty(now)).clamp_min(0)

        def state(source, env, t):
            return tuple(
                tuple(source[key][env, t].reshape(-1).tolist())
                for key in transform.visit_keys
            )

        for env in range(flat.shape[0]):
            seen = set()
            for t in range(flat.shape[1]):
                seen.add(state(flat, env, t))
                first = state(flat["next"], env, t) not in seen
                seen.add(state(flat["next"], env, t))
                bonus[env, t] = gain[env, t] * first
                if done[env, t]:
                    seen = set()
    return bonus.float().reshape(*shape, 1)


def expected_bonus(transform, td: TensorDict) -> torch.Tensor:
    """The bonus recomputed straight from the model, shaped like the reward."""
    with torch.no_grad():
        if isinstance(transform, (E3BTransform, NovelDTransform)):
            return reference_episodic_bonus(transform, td)
        if isinstance(transform, VAESurpriseTransform):
            obs = [td["next", key] for key in transform.in_keys]
            bonus = transform.vae.kl(*obs)
        else:
            obs = [td[key] for key in transform.in_keys]
            next_obs = [td["next", key] for key in transform.in_keys]
            bonus = transform.icm.forward_error(obs, td["action"], next_obs)
    return bonus.unsqueeze(-1)


def assert_close(actual, expected) -> None:
    if isinstance(actual, TensorDictBase):
        assert_td_close(actual, expected)
    else:
        torch.testing.assert_close(actual, expected)


def perturb(model: nn.Module) -> None:
    with torch.no_grad():
        for p in model.parameters():
            p.add_(0.3 * torch.randn_like(p))


# ============================================ TorchRL's eleven contract checks


@pytest.mark.parametrize("kind", CONTRACT_KINDS)
@pytest.mark.parametrize("normalization", ["none", "zscore"])
def test_single_trans_env_check(kind, normalization):
    env = make_env(kind, normalization=normalization)
    check_env_specs(env)
    reward_spec = env.full_reward_spec
    writer = type(env.transform).__name__
    expected = {
        "reward",
        "extrinsic_reward",
        "intrinsic_reward",
        ("reward_contributions", writer, "intrinsic_reward"),
    }
    if normalization != "none":
        expected.add("intrinsic_reward_normalized")
    assert set(reward_spec.keys(True, True)) == expected
    for key in expected:
        assert reward_spec[key].shape == torch.Size([1])
    # The action spec is the parent's: the transform writes rewards only.
    assert env.full_action_spec == env.base_env.full_action_spec


@pytest.mark.parametrize("kind", CONTRACT_KINDS)
def test_serial_trans_env_check(kind):
    env = SerialEnv(2, partial(make_env, kind))
    try:
        check_env_specs(env)
    finally:
        env.close()


def test_parallel_trans_env_check_and_trans_parallel_env_check():
    # Spawning a worker costs 3-10 s on this shared machine, so one ParallelEnv
    # (spawn, as the recipes use it: the factory is pickled) serves both checks
    # for all transforms: the workers hold the four bonuses (parallel env
    # check) and four more wrap the parallel env (transform over a parallel
    # env). Each keeps the reward it receives under its own extrinsic key, which
    # is how bonuses stack.
    penv = ParallelEnv(2, make_stacked_bonus_env)
    try:
        check_env_specs(penv)
        coefs = {"vae": 0.1, "icm": 0.2, "e3b": 0.3, "noveld": 0.4}
        outer = {
            kind: make_transform(
                kind,
                coef=coef,
                intrinsic_reward_key=f"outer_{kind}_reward",
                extrinsic_reward_key=f"reward_before_outer_{kind}",
            )
            for kind, coef in coefs.items()
        }
        env = TransformedEnv(penv, Compose(*outer.values()))
        check_env_specs(env)
        for transform in outer.values():
            reset_episodes(transform)
        rollout = env.rollout(3)
        nxt = rollout["next"]
        assert nxt["outer_noveld_reward"].shape == (2, 3, 1)
        mixed = nxt["extrinsic_reward"] + 0.5 * nxt["intrinsic_reward"]
        inner = [("icm", 0.25), ("e3b", 0.125), ("noveld", 0.0625)]
        for kind, coef in inner:
            assert_close(nxt[f"reward_before_{kind}"], mixed)
            mixed = mixed + coef * nxt[f"{kind}_reward"]
        for kind, coef in coefs.items():
            assert_close(nxt[f"reward_before_outer_{kind}"], mixed)
            mixed = mixed + coef * nxt[f"outer_{kind}_reward"]
        assert_close(nxt["reward"], mixed)
        # The outer models live in this process: the batch path agrees with them.
        for kind, transform in outer.items():
            assert_close(
                nxt[f"outer_{kind}_reward"], expected_bonus(transform, rollout)
            )
    finally:
        if not penv.is_closed:
            penv.close()


@pytest.mark.parametrize("kind", CONTRACT_KINDS)
def test_trans_serial_env_check(kind):
    transform = make_transform(kind, coef=0.5)
    env = TransformedEnv(SerialEnv(2, ContinuousActionVecMockEnv), transform)
    try:
        check_env_specs(env)
        reset_episodes(transform)
        rollout = env.rollout(4)
        assert rollout["next", "intrinsic_reward"].shape == (2, 4, 1)
        assert_close(
            rollout["next", "intrinsic_reward"], expected_bonus(transform, rollout)
        )
        # The batch path on the [env, time] rollout gives the env path's values.
        reset_episodes(transform)
        recomputed = transform(rollout.clone())
        assert_close(recomputed["next", "reward"], rollout["next", "reward"])
    finally:
        env.close()


@pytest.mark.parametrize("kind", CONTRACT_KINDS)
@pytest.mark.parametrize("batch_shape", [(), (4,), (2, 3)])
def test_transform_no_env(kind, batch_shape, make_vector_batch):
    if kind in EPISODIC and not batch_shape:
        pytest.skip("an episodic bonus needs a time dimension")
    transform = make_transform(kind, coef=0.5)
    td = time_ordered(kind, make_vector_batch(batch_shape))
    out = transform(td.clone())
    bonus = expected_bonus(transform, td)
    assert out.batch_size == td.batch_size
    assert out["next", "intrinsic_reward"].shape == (*batch_shape, 1)
    assert_close(out["next", "intrinsic_reward"], bonus)
    assert_close(out["next", "extrinsic_reward"], td["next", "reward"])
    assert_close(out["next", "reward"], td["next", "reward"] + 0.5 * bonus)
    # Nothing else is touched.
    assert_close(out.exclude("next"), td.exclude("next"))
    assert_close(out["next", "observation"], td["next", "observation"])


@pytest.mark.parametrize("kind", CONTRACT_KINDS)
def test_transform_compose(kind, make_vector_batch):
    transform = make_transform(kind, coef=0.5)
    env = TransformedEnv(ContinuousActionVecMockEnv(), Compose(transform))
    check_env_specs(env)
    reset_episodes(transform)
    td = time_ordered(kind, make_vector_batch((3,)))
    out = Compose(transform.clone())(td.clone())
    assert_close(out, transform(td.clone()))


@pytest.mark.parametrize("kind", CONTRACT_KINDS)
def test_transform_env(kind):
    # A real env: gymnasium's Pendulum-v1 (3-d observation, 1-d action).
    base = GymEnv("Pendulum-v1")
    obs_dim = base.observation_spec["observation"].shape[-1]
    action_dim = base.action_spec.shape[-1]
    transform = make_transform(kind, make_model(kind, obs_dim, action_dim), coef=0.5)
    env = TransformedEnv(base, transform)
    try:
        env.set_seed(0)
        check_env_specs(env)
        td = env.reset()
        assert "intrinsic_reward" not in td.keys(True, True)
        td = env.rand_step(td)
        assert torch.isfinite(td["next", "intrinsic_reward"]).all()
        reset_episodes(transform)
        rollout = env.rollout(5)
        nxt = rollout["next"]
        assert_close(nxt["intrinsic_reward"], expected_bonus(transform, rollout))
        assert_close(
            nxt["reward"], nxt["extrinsic_reward"] + 0.5 * nxt["intrinsic_reward"]
        )
    finally:
        env.close()


@pytest.mark.parametrize("kind", CONTRACT_KINDS)
def test_transform_model(kind, make_vector_batch):
    transform = make_transform(kind, coef=0.5)
    model = nn.Sequential(transform, nn.Identity())
    td = time_ordered(kind, make_vector_batch((5,)))
    out = model(td.clone())
    reset_episodes(transform)
    assert_close(out, transform(td.clone()))


@pytest.mark.parametrize("kind", CONTRACT_KINDS)
@pytest.mark.parametrize("rbclass", [ReplayBuffer, TensorDictReplayBuffer])
def test_transform_rb(kind, rbclass, make_vector_batch):
    if kind in EPISODIC:
        # Samples taken in storage order are one env's time steps (time_dim=0);
        # a shuffled sample is refused (tests/test_episodic_bonuses.py).
        transform = make_transform(kind, coef=0.5, time_dim=0)
        sampler = SamplerWithoutReplacement(shuffle=False)
    else:
        transform = make_transform(kind, coef=0.5)
        sampler = None
    rb = rbclass(storage=LazyTensorStorage(16), batch_size=8, sampler=sampler)
    rb.append_transform(transform)
    data = make_vector_batch((16,))
    # Stored with a stale bonus already mixed in, as a collector would leave it.
    data["next", "extrinsic_reward"] = data["next", "reward"].clone()
    data["next", "intrinsic_reward"] = torch.full((16, 1), 123.0)
    data["next", "reward"] = data["next", "reward"] + 0.5 * 123.0
    rb.extend(data)

    sample = rb.sample()
    bonus = expected_bonus(transform, sample)
    assert_close(sample["next", "intrinsic_reward"], bonus)
    assert_close(
        sample["next", "reward"], sample["next", "extrinsic_reward"] + 0.5 * bonus
    )

    # A model update is seen by the next sample: the bonus is fresh, not stored.
    perturb(bonus_model(transform))
    reset_episodes(transform)
    sample = rb.sample()
    fresh = expected_bonus(transform, sample)
    assert_close(sample["next", "intrinsic_reward"], fresh)
    stored = rb.storage[:]
    assert (stored["next", "intrinsic_reward"] == 123.0).all()


@pytest.mark.parametrize("kind", CONTRACT_KINDS)
def test_transform_inverse(kind, make_vector_batch):
    # The bonus is not invertible: ``inv`` (applied to actions on the way into
    # the env, and by replay buffers on extend) must leave data unchanged.
    transform = make_transform(kind)
    assert list(transform.in_keys_inv) == []
    td = make_vector_batch((3,))
    assert_close(transform.inv(td.clone()), td)
    env = TransformedEnv(ContinuousActionVecMockEnv(), transform)
    action_td = env.full_action_spec.rand().update(env.reset())
    assert_close(env.transform.inv(action_td.clone()), action_td)


def test_discrete_icm_env_check(discrete_icm):
    for categorical in (False, True):
        base = DiscreteActionVecMockEnv(categorical_action_encoding=categorical)
        transform = ICMTransform(discrete_icm, coef=0.5)
        env = TransformedEnv(base, transform)
        check_env_specs(env)
        rollout = env.rollout(4)
        assert_close(
            rollout["next", "intrinsic_reward"], expected_bonus(transform, rollout)
        )


# ============================================================= the VAE's KL


def test_kl_matches_torch_distributions(vector_vae, minigrid_vae, make_minigrid_batch):
    td = make_minigrid_batch((6,))
    for vae, obs in [
        (vector_vae, (torch.randn(6, OBS_DIM) * 3,)),
        (minigrid_vae, (td["image"], td["direction"])),
    ]:
        loc, scale = vae.posterior(*obs)
        reference = torch.distributions.kl_divergence(
            torch.distributions.Normal(loc, scale),
            torch.distributions.Normal(torch.zeros_like(loc), torch.ones_like(scale)),
        ).sum(-1)
        assert_close(vae.kl(*obs), reference)
        assert_close(kl_to_standard_normal(loc, scale), reference)
    # A transform reports that same KL for the next state.
    transform = VAESurpriseTransform(minigrid_vae)
    out = transform(td.clone())
    loc, scale = minigrid_vae.posterior(td["next", "image"], td["next", "direction"])
    reference = torch.distributions.kl_divergence(
        torch.distributions.Normal(loc, scale), torch.distributions.Normal(0.0, 1.0)
    ).sum(-1)
    assert_close(out["next", "intrinsic_reward"], reference.detach().unsqueeze(-1))


# ======================================================= env path == batch path


@pytest.mark.parametrize("kind", KINDS)
@pytest.mark.parametrize("normalization", NORMALIZATIONS)
def test_env_path_equals_batch_path(kind, normalization):
    transform = make_transform(kind, coef=0.3, normalization=normalization)
    env = TransformedEnv(ContinuousActionVecMockEnv(), transform)
    if normalization != "none":
        # Warm the statistics up in the env, then freeze: the env path updates
        # them at every step, so only a frozen transform gives equal outputs.
        # (``env.train()``: TransformedEnv put the transform in eval mode.)
        env.train()
        env.rollout(20)
        if normalization == "e3b_std":
            assert transform.e3b_moments.reward_count >= 20  # one a step
        else:
            assert transform.reward_rms.count > 20
        transform.freeze()
    rollout = env.rollout(10)
    assert rollout.names[-1] == "time"
    recomputed = transform(rollout.clone())
    keys = ["intrinsic_reward", "extrinsic_reward", "reward"]
    if normalization != "none":
        keys.append("intrinsic_reward_normalized")
    for key in keys:
        assert_close(recomputed["next", key], rollout["next", key])


# ================================================================== mixing


@pytest.mark.parametrize("kind", KINDS)
@pytest.mark.parametrize("normalization", ["none", "reward_std", "zscore"])
def test_mixing(kind, normalization, make_vector_batch):
    transform = make_transform(kind, coef=0.7, normalization=normalization)
    td = make_vector_batch((64,))
    out = transform(td.clone())
    nxt = out["next"]
    normalized = (
        nxt["intrinsic_reward"]
        if normalization == "none"
        else nxt["intrinsic_reward_normalized"]
    )
    assert_close(nxt["extrinsic_reward"], td["next", "reward"])
    assert_close(nxt["reward"], nxt["extrinsic_reward"] + 0.7 * normalized)


@pytest.mark.parametrize("kind", KINDS)
@pytest.mark.parametrize("normalization", ["none", "zscore"])
def test_recompute_is_idempotent(kind, normalization, make_vector_batch):
    transform = make_transform(kind, coef=0.5, normalization=normalization)
    td = make_vector_batch((32,))
    transform(td.clone())  # statistics away from their initial values
    transform.freeze()
    once = transform(td.clone())
    twice = transform(transform(once.clone()))
    assert_close(twice["next", "extrinsic_reward"], td["next", "reward"])
    assert_close(twice["next", "reward"], once["next", "reward"])
    # Also in training mode, where the statistics move between calls, the bonus
    # is mixed into the extrinsic reward, never into the previous mix.
    transform.unfreeze()
    again = transform(once.clone())
    key = (
        "intrinsic_reward" if normalization == "none" else "intrinsic_reward_normalized"
    )
    assert_close(
        again["next", "reward"], td["next", "reward"] + 0.5 * again["next", key]
    )


@pytest.mark.parametrize("kind", KINDS)
def test_reward_key_none_writes_the_bonus_only(kind, make_vector_batch):
    transform = make_transform(kind, reward_key=None)
    td = make_vector_batch((2, 3))
    out = transform(td.clone())
    assert_close(out["next", "reward"], td["next", "reward"])
    assert "extrinsic_reward" not in out["next"].keys()
    assert_close(out["next", "intrinsic_reward"], expected_bonus(transform, td))
    env = TransformedEnv(
        ContinuousActionVecMockEnv(), make_transform(kind, reward_key=None)
    )
    check_env_specs(env)
    assert "extrinsic_reward" not in env.full_reward_spec.keys()


@pytest.mark.parametrize("kind", KINDS)
def test_missing_parent_reward_key_raises(kind):
    env = TransformedEnv(
        ContinuousActionVecMockEnv(), make_transform(kind, reward_key="missing")
    )
    with pytest.raises(KeyError, match="missing"):
        _ = env.full_reward_spec


def test_constructor_validation(vector_vae):
    with pytest.raises(ValueError, match="normalization"):
        VAESurpriseTransform(vector_vae, normalization="std")
    with pytest.raises(ValueError, match="in_keys"):
        VAESurpriseTransform(vector_vae, in_keys=[])
    with pytest.raises(ValueError, match="coef"):
        VAESurpriseTransform(vector_vae, coef=math.nan)
    with pytest.raises(ValueError, match="gamma"):
        VAESurpriseTransform(vector_vae, gamma=1.5)
    with pytest.raises(ValueError, match="clip"):
        VAESurpriseTransform(vector_vae, clip=0.0)


# ============================================================ normalisation


@pytest.mark.parametrize("kind", KINDS)
def test_zscore_gives_zero_mean_unit_std(kind, make_vector_batch):
    transform = make_transform(kind, normalization="zscore")
    for _ in range(20):
        transform(make_vector_batch((256,)))
    transform.freeze()
    out = transform(make_vector_batch((4096,)))
    normalized = out["next", "intrinsic_reward_normalized"]
    assert abs(normalized.mean().item()) < 0.1
    assert abs(normalized.std().item() - 1.0) < 0.1


@pytest.mark.parametrize("kind", KINDS)
def test_reward_std_divides_by_the_running_std(kind, make_vector_batch):
    transform = make_transform(kind, normalization="reward_std")
    for _ in range(3):
        out = transform(make_vector_batch((128,)))
    std = transform.reward_rms.var.sqrt()
    raw = out["next", "intrinsic_reward"]
    assert_close(out["next", "intrinsic_reward_normalized"], raw / std)
    # Not centred: a positive bonus stays positive.
    assert (out["next", "intrinsic_reward_normalized"] >= 0).all()


def _discounted(bonus: torch.Tensor, gamma: float, time_dim: int) -> torch.Tensor:
    moved = bonus.movedim(time_dim, 0)
    acc, out = torch.zeros_like(moved[0]), []
    for step in moved:
        acc = acc * gamma + step
        out.append(acc)
    return torch.stack(out).movedim(0, time_dim)


@pytest.mark.parametrize("time_position", [0, 1])
def test_return_std_uses_the_time_dimension(
    time_position, vector_vae, make_vector_batch
):
    td = make_vector_batch((5, 3) if time_position == 0 else (3, 5))
    names = [None, None]
    names[time_position] = "time"

    transform = VAESurpriseTransform(vector_vae, normalization="return_std", gamma=0.9)
    out = transform(td.clone().refine_names(*names))
    bonus = out["next", "intrinsic_reward"]
    returns = _discounted(bonus, 0.9, time_position)
    reference = RunningMeanStd(shape=())
    reference.update(returns)
    assert_close(transform.reward_rms.var, reference.var)
    assert_close(transform.reward_rms.mean, reference.mean)
    assert_close(
        out["next", "intrinsic_reward_normalized"], bonus / reference.var.sqrt()
    )

    # Without a named time dim the batch path refuses; ``time_dim`` names it.
    with pytest.raises(ValueError, match="time"):
        VAESurpriseTransform(vector_vae, normalization="return_std")(td.clone())
    explicit = VAESurpriseTransform(
        vector_vae, normalization="return_std", gamma=0.9, time_dim=time_position
    )
    out = explicit(td.clone())
    assert_close(explicit.reward_rms.var, reference.var)


def test_clip_bounds_the_normalized_bonus(vector_vae, make_vector_batch):
    transform = VAESurpriseTransform(vector_vae, normalization="zscore", clip=0.5)
    out = transform(make_vector_batch((256,)))
    normalized = out["next", "intrinsic_reward_normalized"]
    assert normalized.abs().max() <= 0.5
    assert (normalized.abs() == 0.5).any()


# ================================================= statistics and freezing


@pytest.mark.parametrize("kind", KINDS)
def test_env_path_updates_stats_and_frames_by_default(kind):
    """A new transform put in an env counts frames and normalises with live stats.

    ``TransformedEnv`` (like ``Compose.append``, hence
    ``ReplayBuffer.append_transform``) calls ``transform.eval()``: statistics and
    the frame counter must not depend on the training flag, only on ``freeze()``.
    """
    transform = make_transform(kind, normalization="zscore")
    assert transform.training
    env = TransformedEnv(ContinuousActionVecMockEnv(), transform)
    env.rollout(5)
    assert int(transform.frames) == 5
    assert transform.reward_rms.count > 5


def _stats(transform):
    rms = transform.reward_rms
    return (
        rms.mean.clone(),
        rms.var.clone(),
        rms.count.clone(),
        transform.frames.clone(),
        transform._return_acc.clone(),
    )


def _same(a, b) -> bool:
    return all(x.shape == y.shape and torch.equal(x, y) for x, y in zip(a, b))


@pytest.mark.parametrize("kind", KINDS)
@pytest.mark.parametrize("normalization", ["reward_std", "zscore", "return_std"])
def test_stats_update_unless_frozen(kind, normalization, make_vector_batch):
    transform = make_transform(kind, normalization=normalization, time_dim=0)
    td = make_vector_batch((8, 2))
    transform(td.clone())
    before = _stats(transform)

    # eval() (which TorchRL sets when attaching a transform) does not freeze.
    transform.eval()
    transform(td.clone())
    assert not _same(before, _stats(transform))
    before = _stats(transform)

    transform.train().freeze()
    assert transform.frozen
    transform(td.clone())
    assert _same(before, _stats(transform))

    transform.unfreeze()
    assert not transform.frozen
    transform(td.clone())
    after = _stats(transform)
    assert not _same(before, after)
    assert int(after[3]) == int(before[3]) + 16


@pytest.mark.parametrize("kind", KINDS)
def test_frozen_copy_shares_the_model_not_the_stats(kind, make_vector_batch):
    transform = make_transform(kind, normalization="zscore")
    transform(make_vector_batch((64,)))
    frozen = transform.frozen_copy()
    assert frozen.frozen and not transform.frozen
    assert bonus_model(frozen) is bonus_model(transform)
    frozen_stats = _stats(frozen)
    assert _same(frozen_stats, _stats(transform))

    # Stats: the original moves, the copy does not (nor with its own calls).
    transform(make_vector_batch((64,)))
    assert not _same(frozen_stats, _stats(transform))
    frozen(make_vector_batch((64,)))
    assert _same(frozen_stats, _stats(frozen))

    # Model: a weight change made through the original is seen by the copy.
    td = make_vector_batch((16,))
    before = frozen(td.clone())["next", "intrinsic_reward"]
    perturb(bonus_model(transform))
    after = frozen(td.clone())["next", "intrinsic_reward"]
    assert not torch.allclose(before, after)
    assert_close(after, transform(td.clone())["next", "intrinsic_reward"])


# ================================================================ schedule


def test_linear_schedule_drives_coef_via_frames(vector_vae, make_vector_batch):
    schedule = LinearSchedule(start=1.0, end=0.0, frames=100, delay=10)
    transform = VAESurpriseTransform(vector_vae, coef=5.0, coef_schedule=schedule)
    td = make_vector_batch((4,))
    bonus = expected_bonus(transform, td)
    reward = td["next", "reward"]

    transform.eval()
    for frames, coef in [(0, 0.0), (9, 0.0), (10, 1.0), (60, 0.5), (1000, 0.0)]:
        transform.set_frames(frames)
        assert transform.current_coef() == pytest.approx(coef)
        out = transform(td.clone())
        assert_close(out["next", "reward"], reward + coef * bonus)

    # Unfrozen, every processed transition counts, in env and batch paths.
    transform.train()
    transform.set_frames(0)
    transform(make_vector_batch((2, 5)))
    assert int(transform.frames) == 10
    env = TransformedEnv(ContinuousActionVecMockEnv(), transform)
    env.rollout(7)
    assert int(transform.frames) == 17
    assert transform.current_coef() == pytest.approx(schedule(17))


# ============================================================== state_dict


@pytest.mark.parametrize("kind", KINDS)
def test_state_dict_round_trip(kind, make_vector_batch):
    transform = make_transform(kind, normalization="return_std", time_dim=1)
    for _ in range(3):
        transform(make_vector_batch((3, 5)))
    state = transform.state_dict()

    torch.manual_seed(1)
    fresh = make_transform(kind, normalization="return_std", time_dim=1)
    td = make_vector_batch((3, 5))
    fresh.freeze()
    transform.freeze()
    assert not torch.allclose(
        fresh(td.clone())["next", "intrinsic_reward"],
        transform(td.clone())["next", "intrinsic_reward"],
    )
    fresh.load_state_dict(state)
    assert _same(_stats(fresh), _stats(transform))
    assert int(fresh.frames) == 45
    assert fresh._return_acc.shape == (3, 1)
    assert_close(fresh(td.clone()), transform(td.clone()))


# ========================================================== several in_keys


@pytest.mark.parametrize("batch_shape", [(), (4,), (2, 3)])
def test_minigrid_vae_on_image_and_direction(
    batch_shape, minigrid_vae, make_minigrid_batch
):
    transform = VAESurpriseTransform(minigrid_vae, coef=0.1)
    assert transform.in_keys == ["image", "direction"]
    td = make_minigrid_batch(batch_shape)
    out = transform(td.clone())
    bonus = minigrid_vae.kl(td["next", "image"], td["next", "direction"])
    assert out["next", "intrinsic_reward"].shape == (*batch_shape, 1)
    assert_close(out["next", "intrinsic_reward"], bonus.detach().unsqueeze(-1))
    # The direction matters: it is read, not ignored.
    turned = td.clone()
    turned["next", "direction"] = (td["next", "direction"] + 1) % 4
    assert not torch.allclose(
        transform(turned)["next", "intrinsic_reward"], out["next", "intrinsic_reward"]
    )


def test_minigrid_icm_on_image_and_direction(minigrid_icm, make_minigrid_batch):
    transform = ICMTransform(minigrid_icm, coef=0.1)
    td = make_minigrid_batch((2, 3))
    out = transform(td.clone())
    bonus = minigrid_icm.forward_error(
        (td["image"], td["direction"]),
        td["action"],
        (td["next", "image"], td["next", "direction"]),
    )
    assert_close(out["next", "intrinsic_reward"], bonus.detach().unsqueeze(-1))


def test_nested_in_keys(minigrid_vae, make_minigrid_batch):
    td = make_minigrid_batch((3,))
    nested = TensorDict(
        {
            "next": {
                "obs": {"image": td["next", "image"], "dir": td["next", "direction"]},
                "reward": td["next", "reward"],
            }
        },
        [3],
    )
    transform = VAESurpriseTransform(
        minigrid_vae, in_keys=[("obs", "image"), ("obs", "dir")]
    )
    out = transform(nested)
    reference = VAESurpriseTransform(minigrid_vae)(td.clone())
    assert_close(out["next", "intrinsic_reward"], reference["next", "intrinsic_reward"])


# ================================================================ bad input


def assert_key_error_names(key: str, fn, *args) -> None:
    with pytest.raises(KeyError) as info:
        fn(*args)
    assert repr(key) in info.value.args[0], info.value.args[0]


@pytest.mark.parametrize("kind", KINDS)
def test_missing_keys_raise_key_error_naming_the_key(kind, make_vector_batch):
    transform = make_transform(kind)
    td = make_vector_batch((3,))
    without = td.clone().exclude
    assert_key_error_names("observation", transform, without(("next", "observation")))
    assert_key_error_names("next", transform, without("next"))
    assert_key_error_names("reward", transform, without(("next", "reward")))
    assert_key_error_names("extrinsic_reward", transform, without(("next", "reward")))
    if kind == "icm":
        assert_key_error_names("observation", transform, without("observation"))
        assert_key_error_names("action", transform, without("action"))


@pytest.mark.parametrize("kind", KINDS)
def test_wrong_vector_shape_and_dtype(kind, make_vector_batch):
    transform = make_transform(kind)
    td = make_vector_batch((3,), obs_dim=5)
    with pytest.raises(ValueError, match=r"\(7,\)"):
        transform(td)
    td = make_vector_batch((3,))
    td["next", "observation"] = td["next", "observation"].long()
    td["observation"] = td["observation"].long()
    with pytest.raises(TypeError, match="float"):
        transform(td)
    if kind == "icm":
        td = make_vector_batch((3,))
        td["action"] = td["action"][..., :3]
        with pytest.raises(ValueError, match="7"):
            transform(td)


@pytest.mark.parametrize("kind", KINDS)
def test_float64_observations_give_a_bonus_or_a_clear_type_error(
    kind, make_vector_batch
):
    # MuJoCo observations are float64; a float32 model must either cast them or
    # name the dtype it expects, never fail deep inside a Linear layer.
    transform = make_transform(kind)
    td = make_vector_batch((3,))
    td64 = td.clone()
    td64["observation"] = td["observation"].double()
    td64["next", "observation"] = td["next", "observation"].double()
    try:
        out = transform(td64)
    except TypeError as error:
        assert "float64" in str(error)
    else:
        reference = transform(td.clone())
        assert_close(
            out["next", "intrinsic_reward"], reference["next", "intrinsic_reward"]
        )


@pytest.mark.parametrize("kind", KINDS)
def test_written_dtypes_match_the_reward_spec(kind, make_vector_batch):
    # A float64 task reward (DMControl, some gymnasium envs): the spec announced
    # for the bonus keys must have the dtype of the tensors actually written.
    transform = make_transform(kind, normalization="zscore")
    spec = transform.transform_reward_spec(
        Composite(reward=Unbounded(shape=(1,), dtype=torch.float64))
    )
    td = make_vector_batch((3,))
    td["next", "reward"] = td["next", "reward"].double()
    out = transform(td)
    for key in spec.keys(True, True):
        assert out["next", key].dtype == spec[key].dtype, key


def test_wrong_minigrid_shape_and_dtype(minigrid_vae, make_minigrid_batch):
    transform = VAESurpriseTransform(minigrid_vae)
    td = make_minigrid_batch((2,))
    bad = td.clone()
    bad["next", "image"] = bad["next", "image"].float()
    with pytest.raises(TypeError, match="integer"):
        transform(bad)
    bad = td.clone()
    bad["next", "direction"] = bad["next", "direction"].float()
    with pytest.raises(TypeError, match="direction"):
        transform(bad)
    bad = td.clone()
    bad["next", "image"] = bad["next", "image"][..., :6, :6, :]
    with pytest.raises(ValueError, match=r"\(7, 7, 3\)"):
        transform(bad)


@pytest.mark.parametrize("channel, value", [(0, 11), (1, 6), (2, 3), (0, -1)], ids=str)
def test_out_of_range_minigrid_ids(
    channel, value, minigrid_vae, minigrid_icm, make_minigrid_batch
):
    td = make_minigrid_batch((2,))
    image = td["next", "image"].long()
    image[0, 3, 3, channel] = value
    td["next", "image"] = image
    for transform in (VAESurpriseTransform(minigrid_vae), ICMTransform(minigrid_icm)):
        with pytest.raises(ValueError, match="out of range"):
            transform(td.clone())


def test_out_of_range_direction_and_action(
    minigrid_vae, minigrid_icm, make_minigrid_batch
):
    td = make_minigrid_batch((2,))
    bad = td.clone()
    bad["next", "direction"][0] = 4
    with pytest.raises(ValueError, match=r"\[0, 4\)"):
        VAESurpriseTransform(minigrid_vae)(bad)
    bad = td.clone()
    bad["action"][1] = 7
    with pytest.raises(ValueError, match=r"\[0, 7\)"):
        ICMTransform(minigrid_icm)(bad)


@pytest.mark.parametrize("kind", KINDS)
@pytest.mark.parametrize("value", [math.nan, math.inf, -math.inf])
@pytest.mark.parametrize("where", ["root", "next"])
def test_non_finite_observation_raises(kind, value, where, make_vector_batch):
    transform = make_transform(kind)
    td = make_vector_batch((3,))
    key = "observation" if where == "root" else ("next", "observation")
    td[key][1, 2] = value
    original = td.clone()
    if kind == "vae" and where == "root":
        # The VAE reads s_{t+1} only; s_t is not its input.
        transform(td)
        return
    with pytest.raises(ValueError, match="NaN or inf"):
        transform(td)
    # Nothing was half-written before the error.
    assert set(td.keys(True, True)) == set(original.keys(True, True))
    assert_close(td["next", "reward"], original["next", "reward"])


@pytest.mark.parametrize("kind", KINDS)
def test_non_finite_observation_in_env_raises(kind):
    env = make_env(kind)
    td = env.full_action_spec.rand().update(env.reset())
    # The mock env's next observation is its input "observation_orig" + action.
    td["observation_orig"][0] = math.nan
    with pytest.raises(ValueError, match="NaN or inf"):
        env.step(td)


# ================================================================ gradients


@pytest.mark.parametrize("kind", KINDS)
def test_no_gradients_flow_from_outputs(kind, make_vector_batch):
    transform = make_transform(kind, normalization="zscore")
    td = make_vector_batch((4,))
    td["next", "observation"].requires_grad_(True)
    td["observation"].requires_grad_(True)
    with torch.enable_grad():
        out = transform(td)
    for key in ("intrinsic_reward", "intrinsic_reward_normalized", "reward"):
        assert not out["next", key].requires_grad
    assert all(p.grad is None for p in bonus_model(transform).parameters())


def test_a_frozen_copy_keeps_its_own_e3b_statistic(make_vector_batch):
    transform = make_transform("vae", normalization="e3b_std")
    transform(make_vector_batch((64,)))
    frozen = transform.frozen_copy()
    assert frozen.e3b_moments is not transform.e3b_moments
    count = frozen.e3b_moments.reward_count.clone()
    transform(make_vector_batch((64,)))
    assert frozen.e3b_moments.reward_count == count
    assert transform.e3b_moments.reward_count > count
