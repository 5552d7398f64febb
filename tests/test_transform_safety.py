"""Safety of the bonus transforms: no bonus is lost, no state is loaded or kept wrongly.

* Two bonus transforms that would write the same keys are refused (in a
  ``Compose``, on an env whose reward spec already has the keys, and on batches);
  with distinct keys they stack: ``r_ext + c1 * b1 + c2 * b2`` on both paths, with
  the task reward kept.
* A ``state_dict`` saved under one ``normalization`` does not load into a
  transform with another.
* A bonus transform inside the envs of batched-env workers warns that the
  workers' statistics and model are copies.
* Entries with one value per transition (reward, done, a precomputed bonus) of
  another shape are refused with the key and the expected shape; a batch with
  an empty time dimension gives empty bonuses.
"""

from __future__ import annotations

import warnings
from functools import partial

import pytest
import torch
from torch import nn
from torchrl.data import Composite, LazyTensorStorage, ReplayBuffer, Unbounded
from torchrl.envs import Compose, ParallelEnv, SerialEnv, TransformedEnv
from torchrl.envs.utils import check_env_specs
from torchrl.testing.mocking_classes import ContinuousActionVecMockEnv

from torchrl_surprise import (
    ICMModel,
    ICMTransform,
    StateVAE,
    VAESurpriseTransform,
)
from torchrl_surprise.transforms import base

OBS_DIM = 7
ACTION_DIM = 7


def make_vae_transform(**kwargs) -> VAESurpriseTransform:
    return VAESurpriseTransform(
        StateVAE.for_vector(OBS_DIM, latent_dim=4, hidden_dim=16), **kwargs
    )


def make_icm_transform(**kwargs) -> ICMTransform:
    return ICMTransform(
        ICMModel.for_vector(OBS_DIM, ACTION_DIM, hidden_dim=16), **kwargs
    )


def make_env_with_vae(**kwargs) -> TransformedEnv:
    # Module level: ParallelEnv pickles its env factory.
    return TransformedEnv(ContinuousActionVecMockEnv(), make_vae_transform(**kwargs))


def icm_keys(**kwargs) -> dict:
    """The keys of an ICM bonus stacked after a default-keyed one."""
    return {
        "intrinsic_reward_key": "icm_reward",
        "extrinsic_reward_key": "reward_before_icm",
        **kwargs,
    }


def perturb(model: nn.Module) -> None:
    with torch.no_grad():
        for p in model.parameters():
            p.add_(0.5 * torch.randn_like(p))


def vae_bonus(transform: VAESurpriseTransform, td) -> torch.Tensor:
    with torch.no_grad():
        return transform.vae.kl(td["next", "observation"]).unsqueeze(-1)


def icm_bonus(transform: ICMTransform, td) -> torch.Tensor:
    with torch.no_grad():
        error = transform.icm.forward_error(
            [td["observation"]], td["action"], [td["next", "observation"]]
        )
    return error.unsqueeze(-1)


# ============================================= 1. two bonuses on one env


def test_clashing_bonus_keys_are_refused_in_an_env():
    # Both with default keys: the second would overwrite the first's bonus.
    with pytest.raises(ValueError) as info:
        env = TransformedEnv(
            ContinuousActionVecMockEnv(),
            Compose(make_vae_transform(coef=0.5), make_icm_transform(coef=0.25)),
        )
        check_env_specs(env)
    message = str(info.value)
    for text in ("'intrinsic_reward'", "'extrinsic_reward'", "intrinsic_reward_key="):
        assert text in message, message

    # A distinct bonus key is not enough: both would keep "their" extrinsic
    # reward under one key, and the second would drop the first's bonus.
    with pytest.raises(ValueError, match="'extrinsic_reward'"):
        env = TransformedEnv(
            ContinuousActionVecMockEnv(),
            Compose(
                make_vae_transform(),
                make_icm_transform(intrinsic_reward_key="icm_reward"),
            ),
        )
        check_env_specs(env)

    # Appended to an env that already has a bonus.
    env = TransformedEnv(ContinuousActionVecMockEnv(), make_vae_transform())
    with pytest.raises(ValueError, match="'intrinsic_reward'"):
        env.append_transform(make_icm_transform())
        check_env_specs(env)


def test_clashing_bonus_keys_are_refused_by_the_reward_spec():
    # Whatever wrote them (a bonus inside ParallelEnv workers, a nested env, the
    # env itself), keys the parent env already has are not overwritten.
    parent = Composite(
        reward=Unbounded(shape=(1,)),
        intrinsic_reward=Unbounded(shape=(1,)),
        extrinsic_reward=Unbounded(shape=(1,)),
    )
    transform = make_icm_transform(normalization="zscore")
    with pytest.raises(ValueError) as info:
        transform.transform_reward_spec(parent.clone())
    message = str(info.value)
    for text in ("'intrinsic_reward'", "'extrinsic_reward'", "intrinsic_reward_key="):
        assert text in message, message
    # Distinct keys pass, and the parent's entries are kept.
    spec = make_icm_transform(**icm_keys()).transform_reward_spec(parent.clone())
    assert {"intrinsic_reward", "extrinsic_reward", "icm_reward"} <= set(spec.keys())


def test_clashing_bonus_keys_are_refused_on_batches(make_vector_batch):
    batch = make_vector_batch((4,))
    with pytest.raises(ValueError, match="'intrinsic_reward'"):
        Compose(make_vae_transform(), make_icm_transform())(batch.clone())

    rb = ReplayBuffer(storage=LazyTensorStorage(8), batch_size=4)
    rb.extend(make_vector_batch((8,)))
    with pytest.raises(ValueError, match="'extrinsic_reward'"):
        rb.append_transform(make_vae_transform())
        rb.append_transform(make_icm_transform(intrinsic_reward_key="icm_reward"))
        rb.sample()

    # One after the other on the same batch, outside any Compose.
    vae_out = make_vae_transform()(batch.clone())
    with pytest.raises(ValueError, match="'intrinsic_reward'"):
        make_icm_transform()(vae_out)


def test_stacked_bonuses_keep_every_bonus_and_the_task_reward():
    vae_t = make_vae_transform(coef=0.5)
    icm_t = make_icm_transform(coef=0.25, **icm_keys())
    env = TransformedEnv(ContinuousActionVecMockEnv(), Compose(vae_t, icm_t))
    check_env_specs(env)

    # Env path.
    rollout = env.rollout(6)
    nxt = rollout["next"]
    task_reward = nxt["done"].to(nxt["reward"].dtype)  # the mock env's reward
    torch.testing.assert_close(nxt["extrinsic_reward"], task_reward)
    b1, b2 = vae_bonus(vae_t, rollout), icm_bonus(icm_t, rollout)
    torch.testing.assert_close(nxt["intrinsic_reward"], b1)
    torch.testing.assert_close(nxt["icm_reward"], b2)
    torch.testing.assert_close(nxt["reward_before_icm"], task_reward + 0.5 * b1)
    torch.testing.assert_close(nxt["reward"], task_reward + 0.5 * b1 + 0.25 * b2)

    # Batch path, after both models were trained: both bonuses are fresh in the
    # mixed reward, not the ICM bonus on top of the stale VAE one.
    perturb(vae_t.vae)
    perturb(icm_t.icm)
    b1, b2 = vae_bonus(vae_t, rollout), icm_bonus(icm_t, rollout)
    assert not torch.allclose(b1, nxt["intrinsic_reward"])
    expected = task_reward + 0.5 * b1 + 0.25 * b2
    out = env.transform(rollout.clone())
    torch.testing.assert_close(out["next", "extrinsic_reward"], task_reward)
    torch.testing.assert_close(out["next", "intrinsic_reward"], b1)
    # The reward the ICM bonus received is kept as it was first received.
    torch.testing.assert_close(
        out["next", "reward_before_icm"], nxt["reward_before_icm"]
    )
    torch.testing.assert_close(out["next", "reward"], expected)

    # The same, called one after the other, or in a replay buffer.
    torch.testing.assert_close(
        icm_t(vae_t(rollout.clone()))["next", "reward"], expected
    )
    rb = ReplayBuffer(storage=LazyTensorStorage(6), batch_size=6)
    rb.append_transform(env.transform.clone())
    rb.extend(rollout.clone())
    sample = rb.sample()
    torch.testing.assert_close(
        sample["next", "reward"],
        sample["next", "extrinsic_reward"]
        + 0.5 * vae_bonus(vae_t, sample)
        + 0.25 * icm_bonus(icm_t, sample),
    )

    # Recomputing again (the stack, or one of its bonuses) counts nothing twice.
    again = env.transform(out)
    torch.testing.assert_close(again["next", "reward"], expected)
    torch.testing.assert_close(icm_t(again)["next", "reward"], expected)
    torch.testing.assert_close(vae_t(out.clone())["next", "reward"], expected)
    torch.testing.assert_close(icm_t(out.clone())["next", "reward"], expected)


@pytest.mark.parametrize(
    "order", [("vae",), ("icm",), ("vae", "icm"), ("icm", "vae"), ("vae", "vae")]
)
@pytest.mark.parametrize("composed", [False, True], ids=["alone", "compose"])
def test_recomputing_one_stacked_bonus_keeps_the_others(
    order, composed, make_vector_batch
):
    # A batch that holds both bonuses (VAE, then ICM on its mixed reward);
    # recompute some of them, in any order, after both models changed.
    vae_t = make_vae_transform(coef=0.5, normalization="zscore")
    icm_t = make_icm_transform(coef=0.25, **icm_keys())
    batch = make_vector_batch((6,))
    task_reward = batch["next", "reward"].clone()
    mixed = icm_t(vae_t(batch.clone()))
    perturb(vae_t.vae)
    perturb(icm_t.icm)
    vae_t.freeze()
    icm_t.freeze()
    transforms = {"vae": vae_t, "icm": icm_t}
    out = mixed.clone()
    for name in order:
        transform = transforms[name]
        out = (Compose(transform.clone()) if composed else transform)(out)

    nxt, before = out["next"], mixed["next"]
    b1 = nxt["intrinsic_reward_normalized"]
    b2 = before["icm_reward"] if "icm" not in order else icm_bonus(icm_t, out)
    if "vae" in order:
        std = vae_t.reward_rms.var.sqrt()
        expected = (vae_bonus(vae_t, out) - vae_t.reward_rms.mean) / std
        torch.testing.assert_close(b1, expected)
        assert not torch.allclose(b1, before["intrinsic_reward_normalized"])
    if "icm" in order:
        assert not torch.allclose(nxt["icm_reward"], before["icm_reward"])
    torch.testing.assert_close(nxt["extrinsic_reward"], task_reward)
    torch.testing.assert_close(nxt["reward"], task_reward + 0.5 * b1 + 0.25 * b2)
    contributions = nxt["reward_contributions"]
    torch.testing.assert_close(
        contributions["VAESurpriseTransform", "intrinsic_reward"], 0.5 * b1
    )
    torch.testing.assert_close(contributions["ICMTransform", "icm_reward"], 0.25 * b2)


# =================================================== 2. state_dict settings


@pytest.mark.parametrize(
    "saved, loaded",
    [("zscore", "reward_std"), ("none", "zscore"), ("return_std", "none")],
)
def test_state_dict_refuses_another_normalization(saved, loaded, make_vector_batch):
    source = make_vae_transform(normalization=saved, time_dim=0)
    source(make_vector_batch((4, 3)))
    target = make_vae_transform(normalization=loaded, time_dim=0)
    before = {
        k: v.clone() for k, v in target.state_dict().items() if torch.is_tensor(v)
    }
    with pytest.raises(ValueError) as info:
        target.load_state_dict(source.state_dict())
    message = str(info.value)
    assert repr(saved) in message and repr(loaded) in message, message
    # Nothing was loaded before the refusal.
    after = target.state_dict()
    assert all(torch.equal(before[k], after[k]) for k in before)


def test_state_dict_of_an_env_checks_the_normalization(make_vector_batch):
    env = TransformedEnv(
        ContinuousActionVecMockEnv(), make_vae_transform(normalization="zscore")
    )
    env.rollout(3)
    same = TransformedEnv(
        ContinuousActionVecMockEnv(), make_vae_transform(normalization="zscore")
    )
    same.load_state_dict(env.state_dict())
    torch.testing.assert_close(
        same.transform.reward_rms.mean, env.transform.reward_rms.mean
    )
    other = TransformedEnv(
        ContinuousActionVecMockEnv(), make_vae_transform(normalization="reward_std")
    )
    with pytest.raises(ValueError, match="'zscore'.*'reward_std'"):
        other.load_state_dict(env.state_dict())


def test_state_dict_without_the_normalization_record_still_loads(make_vector_batch):
    # Checkpoints written before the record existed load as before.
    source = make_vae_transform(normalization="zscore")
    source(make_vector_batch((16,)))
    state = source.state_dict()
    assert state["_extra_state"] == {"normalization": "zscore"}
    del state["_extra_state"]
    target = make_vae_transform(normalization="zscore")
    target.load_state_dict(state)
    torch.testing.assert_close(target.reward_rms.var, source.reward_rms.var)


# =============================================== 3. bonus inside env workers


def test_bonus_inside_batched_env_workers_warns():
    # Constructing the batched env is enough (its workers are not started): the
    # warning comes from the main process, where it is seen.
    with pytest.warns(UserWarning, match=r"TransformedEnv\(ParallelEnv") as record:
        penv = ParallelEnv(2, partial(make_env_with_vae, coef=0.1))
    try:
        warning = next(w for w in record if "ParallelEnv" in str(w.message))
        assert issubclass(warning.category, base.WorkerCopyWarning)
        message = str(warning.message)
        for text in ("VAESurpriseTransform", "copies", "transform(batch)"):
            assert text in message, message
    finally:
        if not penv.is_closed:
            penv.close()
    with pytest.warns(base.WorkerCopyWarning):
        senv = SerialEnv(2, make_env_with_vae)
    senv.close(raise_if_closed=False)


def test_bonus_on_the_outer_env_does_not_warn():
    with warnings.catch_warnings(record=True) as record:
        warnings.simplefilter("always")
        penv = ParallelEnv(2, ContinuousActionVecMockEnv)
        env = TransformedEnv(penv, make_vae_transform(coef=0.1))
        assert "intrinsic_reward" in env.full_reward_spec.keys()
    try:
        assert not [w for w in record if issubclass(w.category, base.WorkerCopyWarning)]
    finally:
        if not penv.is_closed:
            penv.close()


# ============================================ 4. shapes and empty batches


def _all_transforms(**kwargs):
    from torchrl_surprise.modules import E3BModel, RNDModel
    from torchrl_surprise.transforms import (
        E3BTransform,
        NovelDTransform,
        PrecomputedBonusTransform,
        VAEEllipticalTransform,
    )

    vae = StateVAE.for_vector(OBS_DIM, latent_dim=4, hidden_dim=16)
    return {
        "vae": make_vae_transform(**kwargs),
        "icm": make_icm_transform(**kwargs),
        "elliptical": VAEEllipticalTransform(vae, **kwargs),
        "e3b": E3BTransform(E3BModel.for_vector(OBS_DIM, ACTION_DIM, 8, 16), **kwargs),
        "noveld": NovelDTransform(RNDModel.for_vector(OBS_DIM, 8, 16), **kwargs),
        "precomputed": PrecomputedBonusTransform("rnd_reward", **kwargs),
    }


def _timed_batch(make_vector_batch, batch_shape=(4, 3)):
    td = make_vector_batch(batch_shape)
    td["next", "done"] = torch.zeros(*batch_shape, 1, dtype=torch.bool)
    td["next", "rnd_reward"] = torch.rand(*batch_shape, 1)
    return td.refine_names(None, "time")


@pytest.mark.parametrize(
    "name", ["vae", "icm", "elliptical", "e3b", "noveld", "precomputed"]
)
@pytest.mark.parametrize("normalization", ["none", "zscore", "return_std"])
def test_an_empty_time_dimension_gives_empty_bonuses(
    name, normalization, make_vector_batch
):
    transform = _all_transforms(normalization=normalization)[name]
    td = _timed_batch(make_vector_batch, (4, 0))
    out = transform(td)
    assert out["next", "intrinsic_reward"].shape == (4, 0, 1)
    assert out["next", "reward"].shape == (4, 0, 1)
    if normalization != "none":
        assert transform.reward_rms.count < 1  # nothing counted


_PER_TRANSITION_KEYS = [
    *[(name, "reward") for name in ("vae", "icm", "elliptical", "e3b", "noveld")],
    *[(name, "done") for name in ("elliptical", "e3b", "noveld")],
    ("precomputed", "reward"),
    ("precomputed", "rnd_reward"),
]


@pytest.mark.parametrize("name, key", _PER_TRANSITION_KEYS)
def test_per_transition_entries_of_another_shape_are_refused(
    name, key, make_vector_batch
):
    transform = _all_transforms()[name]
    td = _timed_batch(make_vector_batch)
    td["next", key] = torch.cat([td["next", key]] * 2, -1)  # [4, 3, 2]
    original = td.clone()
    with pytest.raises(ValueError) as info:
        transform(td)
    message = str(info.value)
    for text in (repr(key), "(4, 3)", "(4, 3, 1)", "(4, 3, 2)"):
        assert text in message, message
    # Nothing was half-written, no episode advanced.
    assert set(td.keys(True, True)) == set(original.keys(True, True))
    memory = getattr(transform, "memory", getattr(transform, "visits", None))
    assert memory is None or memory.env_shape is None


@pytest.mark.parametrize("name", ["elliptical", "e3b", "noveld"])
def test_a_batch_of_no_envs_gives_empty_bonuses(name, make_vector_batch):
    # No env, some time steps (a numpy reshape of 0 rows failed in NovelD's visits).
    transform = _all_transforms(normalization="none")[name]
    out = transform(_timed_batch(make_vector_batch, (0, 5)))
    assert out["next", "intrinsic_reward"].shape == (0, 5, 1)
