"""The fast bonus models compute what a straightforward version computes.

For speed on CPU, ``MiniGridEncoder`` sums embedding rows with a hand-written
weight gradient, ``MiniGridDecoder`` takes its log-softmax over a transposed
view, the large linear layers run on oneDNN, ICM encodes ``s`` and ``s'`` in one
pass and the input checks are single reductions. Here each model (MiniGrid and
vector VAE and ICM) is compared, forward values and parameter gradients, with a
reference written the obvious way on the same module's parameters: a one-hot
grid times the embedding matrix, ``F.linear`` layers, one ``cross_entropy`` per
channel. The recipe's sizes at batch 128 take the oneDNN and custom backward
paths; small sizes take the fallbacks.
"""

from __future__ import annotations

import pytest
import torch
import torch.nn.functional as F
from tensordict import TensorDict
from torch import nn

from torchrl_surprise import ICMLoss, StateVAE, VAELoss
from torchrl_surprise.modules import E3BModel, ICMModel
from torchrl_surprise.modules.vae import (
    MINIGRID_NUM_COLORS,
    MINIGRID_NUM_OBJECTS,
    MINIGRID_NUM_STATES,
    MiniGridDecoder,
    MiniGridEncoder,
    OneDNNLinear,
)

SIZES = (MINIGRID_NUM_OBJECTS, MINIGRID_NUM_COLORS, MINIGRID_NUM_STATES)
CELLS = 49
NUM_ACTIONS = 7

#: state_dict keys and shapes of the default models, as saved by checkpoints
#: written before the speed-up (torchrl_surprise at 7c3d541).
VAE_STATE = [
    ("encoder.bias", (256,)),
    ("encoder.embedding.weight", (984, 256)),
    ("encoder.hidden.1.weight", (256, 256)),
    ("encoder.hidden.1.bias", (256,)),
    ("decoder.net.0.weight", (256, 32)),
    ("decoder.net.0.bias", (256,)),
    ("decoder.net.2.weight", (256, 256)),
    ("decoder.net.2.bias", (256,)),
    ("decoder.net.4.weight", (984, 256)),
    ("decoder.net.4.bias", (984,)),
    ("head.weight", (64, 256)),
    ("head.bias", (64,)),
]
ICM_STATE = [
    ("encoder.bias", (256,)),
    ("encoder.embedding.weight", (984, 256)),
    ("encoder.hidden.1.weight", (256, 256)),
    ("encoder.hidden.1.bias", (256,)),
    ("inverse_model.0.weight", (256, 512)),
    ("inverse_model.0.bias", (256,)),
    ("inverse_model.2.weight", (7, 256)),
    ("inverse_model.2.bias", (7,)),
    ("forward_model.0.weight", (256, 263)),
    ("forward_model.0.bias", (256,)),
    ("forward_model.2.weight", (256, 256)),
    ("forward_model.2.bias", (256,)),
]

# (hidden_dim, latent_dim, batch_shape): the recipe's sizes on its rollout,
# flat and as collected (16 envs x 8 steps), which take the oneDNN and custom
# backward paths; small sizes (the F.linear path).
CONFIGS = [(256, 32, (128,)), (256, 32, (16, 8)), (16, 4, (3, 5))]
CONFIG_IDS = ["default-128", "default-16x8", "small-3x5"]


def assert_close(actual, expected, msg=None):
    torch.testing.assert_close(actual, expected, rtol=1e-5, atol=1e-5, msg=msg)


def minigrid_inputs(batch_shape, dtype=torch.uint8):
    """Valid image ids ``[*batch, 7, 7, 3]``, directions and actions."""
    ids = [torch.randint(0, n, (*batch_shape, 7, 7)) for n in SIZES]
    image = torch.stack(ids, -1).to(dtype)
    direction = torch.randint(0, 4, batch_shape)
    action = torch.randint(0, NUM_ACTIONS, batch_shape)
    return image, direction, action


# ------------------------------------------------------------ the references


def ref_mlp(layers: nn.Sequential, x: torch.Tensor) -> torch.Tensor:
    for layer in layers:
        if isinstance(layer, nn.Linear):
            x = F.linear(x, layer.weight, layer.bias)
        else:
            assert isinstance(layer, nn.ReLU)
            x = F.relu(x)
    return x


def ref_one_hot_grid(image, direction, use_direction):
    """``[N, 980 (+ 4)]``: per cell the one-hot object, colour and state ids."""
    ids = image.reshape(-1, CELLS, 3).long()
    grid = torch.cat([F.one_hot(ids[..., c], n) for c, n in enumerate(SIZES)], -1)
    grid = grid.reshape(ids.shape[0], -1)
    if use_direction:
        grid = torch.cat([grid, F.one_hot(direction.reshape(-1).long(), 4)], -1)
    return grid.float()


def ref_encoder(enc: MiniGridEncoder, image, direction=None):
    """A linear layer on the one-hot grid, then ReLU, Linear, ReLU."""
    one_hot = ref_one_hot_grid(image, direction, enc.use_direction)
    features = one_hot @ enc.embedding.weight + enc.bias
    return ref_mlp(enc.hidden, features).reshape(*image.shape[:-3], -1)


def ref_log_prob(dec: MiniGridDecoder, z, image, direction=None):
    """Minus one cross-entropy per channel (and one for the direction)."""
    logits = ref_mlp(dec.net, z).reshape(-1, dec.net[-1].out_features)
    n = logits.shape[0]
    grid = logits[:, : CELLS * sum(SIZES)].reshape(n, CELLS, sum(SIZES))
    ids = image.reshape(n, CELLS, 3).long()
    total = torch.zeros(n)
    start = 0
    for channel, size in enumerate(SIZES):
        nll = F.cross_entropy(
            grid[..., start : start + size].reshape(-1, size),
            ids[..., channel].reshape(-1),
            reduction="none",
        )
        total = total - nll.reshape(n, CELLS).sum(-1)
        start += size
    if dec.use_direction:
        direction_logits = logits[:, CELLS * sum(SIZES) :]
        total = total - F.cross_entropy(
            direction_logits, direction.reshape(-1).long(), reduction="none"
        )
    return total.reshape(z.shape[:-1])


def ref_posterior(vae: StateVAE, *observations):
    features = ref_encoder(vae.encoder, *observations)
    loc, raw = F.linear(features, vae.head.weight, vae.head.bias).chunk(2, -1)
    scale = F.softplus(raw + vae._scale_bias) + vae.min_scale
    return loc, scale


def ref_kl(loc, scale):
    posterior = torch.distributions.Normal(loc, scale)
    prior = torch.distributions.Normal(torch.zeros_like(loc), torch.ones_like(scale))
    return torch.distributions.kl_divergence(posterior, prior).sum(-1)


def param_grads(module: nn.Module, loss: torch.Tensor) -> dict[str, torch.Tensor]:
    names, params = zip(*module.named_parameters(), strict=True)
    grads = torch.autograd.grad(loss, params, allow_unused=True)
    return {
        name: torch.zeros_like(p) if g is None else g
        for name, p, g in zip(names, params, grads, strict=True)
    }


def assert_same_grads(actual: dict, expected: dict):
    assert actual.keys() == expected.keys()
    for name in expected:
        assert_close(actual[name], expected[name], msg=name)


# ------------------------------------------------------------------ the VAE


@pytest.mark.parametrize("hidden, latent, batch_shape", CONFIGS, ids=CONFIG_IDS)
@pytest.mark.parametrize("use_direction", [True, False])
def test_encoder_equals_one_hot_linear(hidden, latent, batch_shape, use_direction):
    enc = MiniGridEncoder(hidden_dim=hidden, use_direction=use_direction)
    image, direction, _ = minigrid_inputs(batch_shape)
    args = (image, direction) if use_direction else (image,)
    out = enc(*args)
    ref = ref_encoder(enc, *args)
    assert out.shape == (*batch_shape, hidden)
    assert_close(out, ref)
    weights = torch.randn_like(ref)
    assert_same_grads(
        param_grads(enc, (out * weights).sum()),
        param_grads(enc, (ref * weights).sum()),
    )
    with torch.no_grad():
        assert_close(enc(*args), ref)


@pytest.mark.parametrize("hidden, latent, batch_shape", CONFIGS, ids=CONFIG_IDS)
@pytest.mark.parametrize("use_direction", [True, False])
def test_decoder_log_prob_equals_per_channel_cross_entropy(
    hidden, latent, batch_shape, use_direction
):
    dec = MiniGridDecoder(latent, hidden_dim=hidden, use_direction=use_direction)
    image, direction, _ = minigrid_inputs(batch_shape)
    z = torch.randn(*batch_shape, latent, requires_grad=True)
    args = (image, direction) if use_direction else (image,)
    out = dec.log_prob(z, *args)
    ref = ref_log_prob(dec, z, *args)
    assert out.shape == batch_shape
    assert_close(out, ref)
    weights = torch.randn_like(ref)
    (grad_z,) = torch.autograd.grad((out * weights).sum(), z, retain_graph=True)
    (ref_grad_z,) = torch.autograd.grad((ref * weights).sum(), z, retain_graph=True)
    assert_close(grad_z, ref_grad_z)
    assert_same_grads(
        param_grads(dec, (out * weights).sum()),
        param_grads(dec, (ref * weights).sum()),
    )


@pytest.mark.parametrize("hidden, latent, batch_shape", CONFIGS, ids=CONFIG_IDS)
def test_vae_kl_equals_reference(hidden, latent, batch_shape):
    vae = StateVAE.for_minigrid(latent_dim=latent, hidden_dim=hidden)
    image, direction, _ = minigrid_inputs(batch_shape)
    with torch.no_grad():
        kl = vae.kl(image, direction)
        ref = ref_kl(*ref_posterior(vae, image, direction))
    assert kl.shape == batch_shape
    assert_close(kl, ref)


@pytest.mark.parametrize("hidden, latent, batch_shape", CONFIGS, ids=CONFIG_IDS)
def test_vae_loss_equals_reference(hidden, latent, batch_shape):
    vae = StateVAE.for_minigrid(latent_dim=latent, hidden_dim=hidden)
    image, direction, _ = minigrid_inputs(batch_shape)
    batch = TensorDict(
        {"next": {"image": image, "direction": direction}}, list(batch_shape)
    )
    torch.manual_seed(1)
    out = VAELoss(vae)(batch)
    torch.manual_seed(1)  # the same reparameterisation noise
    loc, scale = ref_posterior(vae, image, direction)
    z = loc + scale * torch.randn_like(loc)
    ref_nll = -ref_log_prob(vae.decoder, z, image, direction).mean()
    ref_kl_loss = ref_kl(loc, scale).mean()
    assert_close(out["loss_reconstruction"], ref_nll)
    assert_close(out["loss_kl"], ref_kl_loss)
    assert_same_grads(
        param_grads(vae, out["loss_reconstruction"] + out["loss_kl"]),
        param_grads(vae, ref_nll + ref_kl_loss),
    )


def test_vae_forward_on_int64_images_and_trailing_direction_dim():
    vae = StateVAE.for_minigrid(latent_dim=4, hidden_dim=16)
    image, direction, _ = minigrid_inputs((6,), dtype=torch.int64)
    direction = direction.unsqueeze(-1)
    torch.manual_seed(2)
    loc, scale, z, log_likelihood = vae(image, direction)
    assert_close(loc, ref_posterior(vae, image, direction)[0])
    assert_close(log_likelihood, ref_log_prob(vae.decoder, z, image, direction))


# ------------------------------------------------------------------ ICM


@pytest.mark.parametrize("hidden, latent, batch_shape", CONFIGS, ids=CONFIG_IDS)
def test_icm_forward_error_equals_reference(hidden, latent, batch_shape):
    icm = ICMModel.for_minigrid(num_actions=NUM_ACTIONS, hidden_dim=hidden)
    image, direction, action = minigrid_inputs(batch_shape)
    next_image, next_direction, _ = minigrid_inputs(batch_shape)
    obs, next_obs = (image, direction), (next_image, next_direction)
    out = icm.forward_error(obs, action, next_obs)
    phi = ref_encoder(icm.encoder, *obs)
    phi_next = ref_encoder(icm.encoder, *next_obs)
    action_one_hot = F.one_hot(action, NUM_ACTIONS).float()
    pred = ref_mlp(icm.forward_model, torch.cat([phi, action_one_hot], -1))
    ref = 0.5 * (pred - phi_next).pow(2).sum(-1)
    assert out.shape == batch_shape
    assert_close(out, ref)
    assert_same_grads(param_grads(icm, out.sum()), param_grads(icm, ref.sum()))


@pytest.mark.parametrize("hidden, latent, batch_shape", CONFIGS, ids=CONFIG_IDS)
@pytest.mark.parametrize("action_format", ["integer", "one-hot"])
def test_icm_loss_equals_reference(hidden, latent, batch_shape, action_format):
    icm = ICMModel.for_minigrid(num_actions=NUM_ACTIONS, hidden_dim=hidden)
    image, direction, action = minigrid_inputs(batch_shape)
    next_image, next_direction, _ = minigrid_inputs(batch_shape)
    action_one_hot = F.one_hot(action, NUM_ACTIONS).float()
    batch = TensorDict(
        {
            "image": image,
            "direction": direction,
            "action": action if action_format == "integer" else action_one_hot,
            "next": {"image": next_image, "direction": next_direction},
        },
        list(batch_shape),
    )
    beta = 0.2
    out = ICMLoss(icm, beta=beta)(batch)
    phi = ref_encoder(icm.encoder, image, direction)
    phi_next = ref_encoder(icm.encoder, next_image, next_direction)
    logits = ref_mlp(icm.inverse_model, torch.cat([phi, phi_next], -1))
    inverse = F.cross_entropy(
        logits.reshape(-1, NUM_ACTIONS), action.reshape(-1), reduction="none"
    )
    pred = ref_mlp(icm.forward_model, torch.cat([phi.detach(), action_one_hot], -1))
    forward = 0.5 * (pred - phi_next.detach()).pow(2).sum(-1)
    ref_forward = beta * forward.mean()
    ref_inverse = (1 - beta) * inverse.mean()
    assert_close(out["loss_forward"], ref_forward)
    assert_close(out["loss_inverse"], ref_inverse)
    # Each loss on its own: the detached features keep the forward loss off
    # the encoder, as in the reference.
    for key, ref in (("loss_forward", ref_forward), ("loss_inverse", ref_inverse)):
        out = ICMLoss(icm, beta=beta)(batch)
        assert_same_grads(param_grads(icm, out[key]), param_grads(icm, ref))


def test_paired_features_equal_two_encoder_calls():
    icm = ICMModel.for_minigrid(num_actions=NUM_ACTIONS, hidden_dim=32)
    image, direction, _ = minigrid_inputs((4, 2))
    next_image, next_direction, _ = minigrid_inputs((4, 2))
    phi, phi_next = icm.paired_features(
        (image, direction), (next_image, next_direction)
    )
    assert_close(phi, icm.features((image, direction)))
    assert_close(phi_next, icm.features((next_image, next_direction)))
    # Batches of different shapes: two calls.
    phi, phi_next = icm.paired_features(
        (image, direction), (next_image[:3], next_direction[:3])
    )
    assert phi.shape == (4, 2, 32) and phi_next.shape == (3, 2, 32)
    assert_close(phi_next, icm.features((next_image[:3], next_direction[:3])))


# ------------------------------------------------- layers, checks, state_dict


@pytest.mark.parametrize(
    "batch, in_features, out_features",
    [((128,), 256, 984), ((16, 8), 256, 256), ((4,), 8, 3), ((), 256, 256)],
)
def test_onednn_linear_equals_nn_linear(batch, in_features, out_features):
    torch.manual_seed(3)
    fast = OneDNNLinear(in_features, out_features)
    torch.manual_seed(3)
    plain = nn.Linear(in_features, out_features)
    # Same class family and initialisation: runs at a given seed start alike.
    assert isinstance(fast, nn.Linear)
    assert_close(fast.weight, plain.weight)
    assert_close(fast.bias, plain.bias)
    x = torch.randn(*batch, in_features, requires_grad=True)
    out, ref = fast(x), plain(x)
    assert out.shape == (*batch, out_features)
    assert_close(out, ref)
    weights = torch.randn_like(ref)
    grads = torch.autograd.grad((out * weights).sum(), [x, *fast.parameters()])
    ref_grads = torch.autograd.grad((ref * weights).sum(), [x, *plain.parameters()])
    for grad, ref_grad in zip(grads, ref_grads, strict=True):
        assert_close(grad, ref_grad)
    with torch.no_grad():
        assert_close(fast(x), ref)
    # Only the weight trained (the input needs no gradient).
    (grad_w,) = torch.autograd.grad((fast(x.detach()) * weights).sum(), fast.weight)
    assert_close(grad_w, ref_grads[1])


def test_onednn_linear_is_not_traced_by_torch_compile():
    """torch.compile's CPU backend only lowers the oneDNN op for frozen weights."""
    layer = OneDNNLinear(256, 256)
    seen = []

    def record_backend(graph_module, example_inputs):
        seen.extend(str(node.target) for node in graph_module.graph.nodes)
        return graph_module.forward

    compiled = torch.compile(layer, backend=record_backend, fullgraph=True)
    x = torch.randn(128, 256)
    assert_close(compiled(x), F.linear(x, layer.weight, layer.bias))
    assert seen and not any("mkldnn" in target for target in seen)


@pytest.mark.parametrize(
    "build",
    [
        lambda **kw: StateVAE.for_minigrid(latent_dim=4, hidden_dim=64, **kw),
        lambda **kw: StateVAE.for_vector(7, latent_dim=4, hidden_dim=64, **kw),
        lambda **kw: ICMModel.for_minigrid(hidden_dim=64, **kw),
        lambda **kw: ICMModel.for_vector(7, 7, hidden_dim=64, **kw),
        lambda **kw: E3BModel.for_minigrid(embedding_dim=64, hidden_dim=64, **kw),
    ],
    ids=["vae_minigrid", "vae_vector", "icm_minigrid", "icm_vector", "e3b"],
)
def test_onednn_linear_is_opt_in_and_changes_no_parameter(build):
    # The private oneDNN op runs only where asked; either way a model has the
    # same parameters at a seed, and its state_dict loads into the other.
    torch.manual_seed(5)
    plain = build()
    torch.manual_seed(5)
    fast = build(onednn_linear=True)
    linears = [m for m in plain.modules() if isinstance(m, nn.Linear)]
    assert linears and not any(isinstance(m, OneDNNLinear) for m in linears)
    fast_linears = [m for m in fast.modules() if isinstance(m, nn.Linear)]
    assert len(fast_linears) == len(linears)
    assert all(isinstance(m, OneDNNLinear) for m in fast_linears)
    for (key, value), (fast_key, fast_value) in zip(
        plain.state_dict().items(), fast.state_dict().items(), strict=True
    ):
        assert key == fast_key
        assert_close(value, fast_value)
    fast.load_state_dict(plain.state_dict())


@pytest.mark.parametrize("channel, value", [(0, 11), (1, 6), (2, 3), (1, -1)])
def test_out_of_range_ids_still_raise(channel, value):
    enc = MiniGridEncoder(hidden_dim=8)
    image, direction, _ = minigrid_inputs((3,), dtype=torch.int64)
    image[1, 2, 4, channel] = value
    with pytest.raises(ValueError, match="out of range"):
        enc(image, direction)
    image, direction, _ = minigrid_inputs((3,))
    direction[2] = 4
    with pytest.raises(ValueError, match=r"\[0, 4\)"):
        enc(image, direction)
    icm = ICMModel.for_minigrid(num_actions=NUM_ACTIONS, hidden_dim=8)
    for bad in (NUM_ACTIONS, -1):
        with pytest.raises(ValueError, match=r"\[0, 7\)"):
            icm.encode_action(torch.tensor([0, bad]))


def test_empty_batch():
    vae = StateVAE.for_minigrid(latent_dim=4, hidden_dim=16)
    image, direction, _ = minigrid_inputs((0,))
    assert vae.kl(image, direction).shape == (0,)
    loc, scale, z, log_likelihood = vae(image, direction)
    (loc.sum() + log_likelihood.sum()).backward()
    assert not vae.encoder.embedding.weight.grad.any()
    icm = ICMModel.for_minigrid(num_actions=NUM_ACTIONS, hidden_dim=16)
    assert icm.encode_action(torch.zeros(0, dtype=torch.long)).shape == (0, 7)


def test_state_dict_keys_and_shapes_unchanged():
    vae_state = StateVAE.for_minigrid().state_dict()
    icm_state = ICMModel.for_minigrid(num_actions=NUM_ACTIONS).state_dict()
    assert [(k, tuple(v.shape)) for k, v in vae_state.items()] == VAE_STATE
    assert [(k, tuple(v.shape)) for k, v in icm_state.items()] == ICM_STATE
    # A checkpoint of that layout loads strictly.
    checkpoint = {key: torch.randn(shape) for key, shape in VAE_STATE}
    StateVAE.for_minigrid().load_state_dict(checkpoint, strict=True)


# ------------------------------------------- the vector models (MuJoCo)


@pytest.mark.parametrize("hidden, batch_shape", [(256, (256,)), (16, (3, 5))])
def test_vector_vae_loss_equals_reference(hidden, batch_shape):
    obs_dim = 17
    vae = StateVAE.for_vector(obs_dim, latent_dim=16, hidden_dim=hidden)
    obs = torch.randn(*batch_shape, obs_dim, dtype=torch.float64)
    batch = TensorDict({"next": {"observation": obs}}, list(batch_shape))
    torch.manual_seed(1)
    out = VAELoss(vae)(batch)
    torch.manual_seed(1)
    features = ref_mlp(vae.encoder.net, obs.float())
    loc, raw = F.linear(features, vae.head.weight, vae.head.bias).chunk(2, -1)
    scale = F.softplus(raw + vae._scale_bias) + vae.min_scale
    z = loc + scale * torch.randn_like(loc)
    dec = vae.decoder
    log_scale = dec.log_scale.clamp_min(dec.min_log_scale)
    mean = ref_mlp(dec.net, z)
    log_likelihood = torch.distributions.Normal(mean, log_scale.exp()).log_prob(obs)
    ref_nll = -log_likelihood.sum(-1).mean()
    ref_kl_loss = ref_kl(loc, scale).mean()
    assert_close(out["loss_reconstruction"], ref_nll)
    assert_close(out["loss_kl"], ref_kl_loss)
    assert_same_grads(
        param_grads(vae, out["loss_reconstruction"] + out["loss_kl"]),
        param_grads(vae, ref_nll + ref_kl_loss),
    )


@pytest.mark.parametrize("hidden, batch_shape", [(256, (256,)), (16, (3, 5))])
def test_vector_icm_loss_equals_reference(hidden, batch_shape):
    obs_dim, action_dim, beta = 17, 6, 0.2
    icm = ICMModel.for_vector(obs_dim, action_dim, hidden_dim=hidden)
    obs, next_obs = torch.randn(2, *batch_shape, obs_dim).unbind(0)
    action = torch.rand(*batch_shape, action_dim) * 2 - 1
    batch = TensorDict(
        {"observation": obs, "action": action, "next": {"observation": next_obs}},
        list(batch_shape),
    )
    out = ICMLoss(icm, beta=beta)(batch)
    phi = ref_mlp(icm.encoder.net, obs)
    phi_next = ref_mlp(icm.encoder.net, next_obs)
    inverse_out = ref_mlp(icm.inverse_model, torch.cat([phi, phi_next], -1))
    inverse = 0.5 * (inverse_out - action).pow(2).sum(-1)
    pred = ref_mlp(icm.forward_model, torch.cat([phi.detach(), action], -1))
    forward = 0.5 * (pred - phi_next.detach()).pow(2).sum(-1)
    ref = beta * forward.mean() + (1 - beta) * inverse.mean()
    assert_close(out["loss_forward"] + out["loss_inverse"], ref)
    assert_same_grads(
        param_grads(icm, out["loss_forward"] + out["loss_inverse"]),
        param_grads(icm, ref),
    )


@pytest.mark.parametrize("algo", ["a2c", "ppo"])
def test_the_recipes_losses_on_the_shared_trunk_equal_one_trunk_per_head(algo):
    """The recipes run the actor-critic's trunk once per update (``shared_trunk``)
    and give the losses its heads; the two-stream advantage takes one pass of a
    two-headed critic. Same advantages and the same gradients as the losses and
    critics built on whole operators (one trunk pass per head)."""
    from pathlib import Path

    from _recipe_run import load_recipe_utils
    from hydra import compose, initialize_config_dir
    from torchrl.objectives import A2CLoss, ClipPPOLoss

    from common.minigrid import (
        make_actor_critic,
        make_bonus,
        make_collector,
        make_env,
        shared_trunk,
    )
    from torchrl_surprise import IntrinsicValueLoss, TwoStreamAdvantage

    root = Path(__file__).resolve().parents[1] / "recipes" / "minigrid"
    utils = load_recipe_utils(root)
    with initialize_config_dir(config_dir=str(root), version_base=None):
        overrides = [f"algo={algo}", "bonus=vae", "env.num_envs=4"]
        cfg = compose("config", overrides=overrides)
    torch.manual_seed(0)
    env = make_env(cfg.env, 4, seed=0)
    bonus, _, _ = make_bonus(cfg, env.action_spec, "vae")
    ppo = algo == "ppo"
    model, int_value = make_actor_critic(env.action_spec, True, ppo)
    loss, advantage, int_loss = utils.make_loss(cfg, model, int_value, bonus)
    policy = model.get_policy_operator()
    collector = make_collector(env, policy, cfg, total_frames=10 * 4 * 8)
    data = next(iter(collector))
    collector.shutdown()
    with torch.no_grad():
        data = bonus(data)
    # the reference: whole operators, one trunk pass per head and critic
    kwargs = dict(
        entropy_coeff=cfg.loss.entropy_coef,
        critic_coeff=cfg.loss.critic_coef,
        loss_critic_type="l2",
    )
    if ppo:  # make_ppo's settings
        kwargs.update(
            clip_epsilon=cfg.loss.clip_epsilon,
            clip_value=True,
            normalize_advantage=bool(cfg.loss.get("normalize_advantage", False)),
        )
    ref_loss = (ClipPPOLoss if ppo else A2CLoss)(
        policy, model.get_value_operator(), **kwargs
    )
    ref_advantage = TwoStreamAdvantage(
        model.get_value_operator(),
        int_value,
        intrinsic_reward_key=advantage.intrinsic_reward_key,
        coef=advantage.coef,
        gamma=cfg.loss.gamma,
        lmbda=cfg.loss.gae_lambda,
    )
    ref_int_loss = IntrinsicValueLoss(int_value, critic_coef=cfg.loss.critic_coef)

    def step(fn):
        model.zero_grad()
        int_value.zero_grad()
        total, adv = fn()
        total.backward()
        params = {
            **dict(model.named_parameters()),
            **dict(int_value.named_parameters()),
        }
        return adv, {k: p.grad.clone() for k, p in params.items() if p.grad is not None}

    def ours():
        with torch.no_grad():
            td = advantage(data.clone())
        td = shared_trunk(model)(td)
        out = loss(td)
        total = sum(v for k, v in out.items() if k.startswith("loss_"))
        return total + int_loss(td)["loss_critic_int"], td["advantage"]

    def reference():
        with torch.no_grad():
            td = ref_advantage(data.clone())
        out = ref_loss(td)
        total = sum(v for k, v in out.items() if k.startswith("loss_"))
        return total + ref_int_loss(td)["loss_critic_int"], td["advantage"]

    adv, grads = step(ours)
    ref_adv, ref_grads = step(reference)
    torch.testing.assert_close(adv, ref_adv)
    assert grads.keys() == ref_grads.keys() and len(grads) > 0
    trunk_keys = [k for k in grads if "net.0" in k]
    assert trunk_keys and all(grads[k].abs().sum() > 0 for k in trunk_keys)
    for k in grads:
        torch.testing.assert_close(grads[k], ref_grads[k], rtol=1e-4, atol=1e-6)
