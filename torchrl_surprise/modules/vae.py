"""A state VAE whose posterior-to-prior KL is the surprise bonus.

The VAE maps one or several observation tensors to a diagonal Gaussian posterior
``q(z|s) = N(loc, diag(scale^2))``; a decoder turns a latent sample into the
parameters of a likelihood over the same observations. Two families ship:

* MiniGrid's 7x7x3 symbolic grid (object, colour and state ids, plus the agent's
  direction): ids are categories, so the encoder embeds them and the decoder
  predicts a categorical distribution per cell and channel.
* Flat float vectors (MuJoCo): an MLP encoder and a Gaussian decoder with a
  learned per-dimension scale.
"""

from __future__ import annotations

import functools
import math
import platform
from collections.abc import Sequence

import torch
import torch.nn.functional as F
from tensordict.utils import NestedKey, unravel_key
from torch import nn
from torch.autograd.function import once_differentiable

__all__ = [
    "GaussianVectorDecoder",
    "MiniGridDecoder",
    "MiniGridEncoder",
    "OneDNNLinear",
    "StateVAE",
    "linear_layer",
    "VectorEncoder",
    "kl_to_standard_normal",
    "MINIGRID_NUM_OBJECTS",
    "MINIGRID_NUM_COLORS",
    "MINIGRID_NUM_STATES",
]

# minigrid.core.constants: 11 object types, 6 colours, 3 door states, 4 directions.
MINIGRID_NUM_OBJECTS = 11
MINIGRID_NUM_COLORS = 6
MINIGRID_NUM_STATES = 3
MINIGRID_NUM_DIRECTIONS = 4


def kl_to_standard_normal(loc: torch.Tensor, scale: torch.Tensor) -> torch.Tensor:
    """Closed-form ``KL(N(loc, diag(scale^2)) || N(0, I))``, summed over the last dim.

    Args:
        loc (torch.Tensor): posterior mean, shape ``[..., latent_dim]``.
        scale (torch.Tensor): posterior standard deviation (positive), same shape.

    Returns:
        The KL in nats, shape ``[...]``.

    Examples:
        >>> import torch
        >>> kl_to_standard_normal(torch.zeros(2, 3), torch.ones(2, 3))
        tensor([0., 0.])
        >>> kl_to_standard_normal(torch.ones(1, 2), torch.ones(1, 2))
        tensor([1.])
    """
    var = scale.pow(2)
    return 0.5 * (loc.pow(2) + var - 1.0 - var.log()).sum(-1)


def _check_floating(name: str, tensor: torch.Tensor, last_shape: tuple[int, ...]):
    if not torch.is_floating_point(tensor):
        raise TypeError(
            f"{name}: expected a floating-point tensor, got dtype {tensor.dtype}."
        )
    if tuple(tensor.shape[len(tensor.shape) - len(last_shape) :]) != last_shape:
        raise ValueError(
            f"{name}: expected trailing shape {last_shape}, got {tuple(tensor.shape)}."
        )


@functools.cache
def _onednn_linear():
    """oneDNN's dense linear (``x @ w.T + b``) on strided CPU tensors, or ``None``.

    Probed on first use (a :class:`OneDNNLinear` forward), never at import.

    ``nn.Linear`` runs float32 products on MKL. On the AMD EPYC (Zen 5, AVX-512)
    this was measured on, MKL's sgemm reached ~90 GFLOP/s on one core at every
    size tried (up to 2048^3, AVX2 speed) and oneDNN's AVX-512 kernels 160-200:
    the large layers of these models take half the time on oneDNN. The op is
    the one torch.compile's CPU backend emits for linear layers; it is used only
    on x86-64 and after it agrees with ``F.linear`` here.
    """
    if platform.machine().lower() not in ("x86_64", "amd64"):
        return None
    try:
        op = torch.ops.mkldnn._linear_pointwise
        if not torch.backends.mkldnn.is_available():
            return None
        generator = torch.Generator().manual_seed(0)
        x, w, b = (
            torch.randn(*shape, generator=generator)
            for shape in ((5, 8), (16, 8), (16,))
        )
        if not torch.allclose(op(x, w, b, "none", [], ""), F.linear(x, w, b)):
            return None
        # Transposed (non-contiguous) operands, as in the backward.
        xt, wt = x.t().contiguous().t(), w.t().contiguous().t()
        if not torch.allclose(op(xt, wt, None, "none", [], ""), xt @ wt.t()):
            return None
    except (AttributeError, RuntimeError):
        return None
    return op


# Below ~2M multiply-adds oneDNN's fixed cost per call (~15 us) outweighs its
# faster kernel: small products stay on MKL.
_ONEDNN_MIN_MACS = 1 << 21


def _matmul_t(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """``a @ b.T`` for 2-D float32 CPU tensors (any strides), on the faster library."""
    op = _onednn_linear()
    if op is not None and a.shape[0] * a.shape[1] * b.shape[0] >= _ONEDNN_MIN_MACS:
        return op(a, b, None, "none", [], "")
    return a.mm(b.t())


class _OneDNNLinearFunction(torch.autograd.Function):
    """``F.linear`` on 2-D inputs whose three products go through ``_matmul_t``."""

    @staticmethod
    def forward(x: torch.Tensor, weight: torch.Tensor, bias: torch.Tensor | None):
        return _onednn_linear()(x, weight, bias, "none", [], "")

    @staticmethod
    def setup_context(ctx, inputs, output) -> None:
        x, weight, bias = inputs
        ctx.save_for_backward(x, weight)
        ctx.has_bias = bias is not None

    @staticmethod
    @once_differentiable
    def backward(ctx, grad: torch.Tensor):
        x, weight = ctx.saved_tensors
        grad_x = grad_w = grad_b = None
        if ctx.needs_input_grad[0]:
            grad_x = _matmul_t(grad, weight.t())
        if ctx.needs_input_grad[1]:
            grad_w = _matmul_t(grad.t(), x.t())
        if ctx.has_bias and ctx.needs_input_grad[2]:
            grad_b = grad.sum(0)
        return grad_x, grad_w, grad_b


class OneDNNLinear(nn.Linear):
    """``nn.Linear`` whose large float32 CPU products run on oneDNN.

    Same parameters, initialisation and state_dict as ``nn.Linear``; results
    equal up to float32 rounding (another summation order). Small products,
    other dtypes or devices and code traced by torch.compile go to
    ``F.linear``. Not twice differentiable on the oneDNN path. It calls a
    private PyTorch op (``torch.ops.mkldnn._linear_pointwise``), so the
    networks use it only when asked (``onednn_linear=True``, see
    :func:`linear_layer`).
    """

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        weight, bias = self.weight, self.bias
        # torch.compile's CPU backend lowers this op for frozen weights only.
        op = None if torch.compiler.is_compiling() else _onednn_linear()
        if (
            op is None
            or x.device.type != "cpu"
            or x.dtype != torch.float32
            or weight.dtype != torch.float32
            or x.numel() // self.in_features * self.out_features * self.in_features
            < _ONEDNN_MIN_MACS
        ):
            return F.linear(x, weight, bias)
        x2d = x.reshape(-1, self.in_features)
        if torch.is_grad_enabled() and (
            x.requires_grad
            or weight.requires_grad
            or (bias is not None and bias.requires_grad)
        ):
            out = _OneDNNLinearFunction.apply(x2d, weight, bias)
        else:
            out = op(x2d, weight, bias, "none", [], "")
        return out.reshape(*x.shape[:-1], self.out_features)


def linear_layer(
    in_features: int, out_features: int, onednn_linear: bool = False
) -> nn.Linear:
    """``nn.Linear``, or :class:`OneDNNLinear` where ``onednn_linear`` asks for it.

    The networks of this package take ``onednn_linear`` (default ``False``):
    the two layers have the same parameters and state_dict, so a checkpoint
    loads either way.

    Examples:
        >>> type(linear_layer(4, 2)).__name__, type(linear_layer(4, 2, True)).__name__
        ('Linear', 'OneDNNLinear')
    """
    layer = OneDNNLinear if onednn_linear else nn.Linear
    return layer(in_features, out_features)


def _check_ids(ids: torch.Tensor, limits: Sequence[int]) -> bool:
    """Whether ``0 <= ids[..., c] < limits[c]`` for every channel ``c``.

    One min/max reduction over all channels, compared in Python: the check runs
    on every call, so it costs one pass over the ids.
    """
    if ids.numel() == 0:
        return True
    low, high = torch.aminmax(ids.reshape(-1, len(limits)), dim=0)
    return min(low.tolist()) >= 0 and all(
        h < n for h, n in zip(high.tolist(), limits, strict=True)
    )


class _SummedEmbedding(torch.autograd.Function):
    """``embedding_bag(idx, weight, mode="sum")`` with a cheaper weight gradient.

    ``idx`` is ``[N, P]`` and column ``p`` indexes only rows of its own block,
    the blocks in column order (``MiniGridEncoder``'s layout). The weight
    gradient ``one_hot(idx)^T @ grad`` is then itself an embedding bag over the
    rows of ``grad``, one bag per weight row, whose members come from sorting
    each column's ``N`` ids. PyTorch's generic backward sorts all ``N * P``
    indices at once and zero-fills the gradient before accumulating into it:
    about three times slower at ``N = 128`` on one CPU thread.
    """

    @staticmethod
    def forward(idx: torch.Tensor, weight: torch.Tensor) -> torch.Tensor:
        return F.embedding_bag(idx, weight, mode="sum")

    @staticmethod
    def setup_context(ctx, inputs, output) -> None:
        idx, weight = inputs
        ctx.save_for_backward(idx)
        ctx.num_rows = weight.shape[0]

    @staticmethod
    @once_differentiable
    def backward(ctx, grad: torch.Tensor):
        (idx,) = ctx.saved_tensors
        # Each column's states sorted by row, the columns one after the other:
        # the members of every row's bag, in row order.
        members = idx.t().argsort(dim=1).reshape(-1)
        counts = torch.bincount(idx.reshape(-1), minlength=ctx.num_rows)
        offsets = counts.cumsum(0) - counts
        return None, F.embedding_bag(members, grad, offsets, mode="sum")


class MiniGridEncoder(nn.Module):
    """Embeds MiniGrid's symbolic ``7x7x3`` grid (and optionally the direction).

    Each (cell, channel, id) triple has its own embedding row and the rows of a
    state are summed: exactly a linear layer on the one-hot grid, at the cost of
    147 look-ups instead of a ``980``-wide matrix product. Ids are categories,
    never magnitudes.

    Args:
        hidden_dim (int): width of the embedding and of the hidden layer.
        use_direction (bool): also embed the agent's direction (an integer in
            ``[0, 4)``); then ``forward`` takes ``(image, direction)``.
        grid_size (int): side of the egocentric view (7 in MiniGrid).
        onednn_linear (bool): run the hidden layer on :class:`OneDNNLinear`.

    Examples:
        >>> import torch
        >>> enc = MiniGridEncoder(hidden_dim=32)
        >>> image = torch.zeros(5, 7, 7, 3, dtype=torch.uint8)
        >>> enc(image, torch.zeros(5, dtype=torch.long)).shape
        torch.Size([5, 32])
    """

    def __init__(
        self,
        hidden_dim: int = 256,
        use_direction: bool = True,
        grid_size: int = 7,
        onednn_linear: bool = False,
    ):
        super().__init__()
        self.grid_size = grid_size
        self.use_direction = use_direction
        self.out_features = hidden_dim
        self._sizes = (MINIGRID_NUM_OBJECTS, MINIGRID_NUM_COLORS, MINIGRID_NUM_STATES)
        per_cell = sum(self._sizes)
        channel_offset = torch.tensor([0, self._sizes[0], sum(self._sizes[:2])])
        cell_offset = torch.arange(grid_size * grid_size) * per_cell
        offsets = (cell_offset[:, None] + channel_offset[None, :]).reshape(-1)
        # int32 indices: half the memory traffic of int64 and a faster sort in
        # the backward; embedding_bag takes either.
        self.register_buffer("_offsets", offsets.int(), persistent=False)
        num_rows = grid_size * grid_size * per_cell
        self._direction_row = num_rows
        num_rows += MINIGRID_NUM_DIRECTIONS if use_direction else 0
        # The module only holds the weight (state_dict key "embedding.weight"):
        # forward calls _SummedEmbedding on it.
        self.embedding = nn.EmbeddingBag(num_rows, hidden_dim, mode="sum")
        nn.init.normal_(self.embedding.weight, std=1.0 / math.sqrt(3 * grid_size**2))
        self.bias = nn.Parameter(torch.zeros(hidden_dim))
        self.hidden = nn.Sequential(
            nn.ReLU(), linear_layer(hidden_dim, hidden_dim, onednn_linear), nn.ReLU()
        )

    def _indices(
        self, image: torch.Tensor, direction: torch.Tensor | None
    ) -> torch.Tensor:
        """Embedding rows ``[N, 147 (+ 1)]`` (int32) of the flattened batch."""
        g = self.grid_size
        if image.dtype.is_floating_point or image.dtype == torch.bool:
            raise TypeError(
                "MiniGrid image: expected an integer tensor of object/colour/state "
                f"ids, got dtype {image.dtype}."
            )
        if tuple(image.shape[-3:]) != (g, g, 3):
            raise ValueError(
                f"MiniGrid image: expected trailing shape ({g}, {g}, 3), got "
                f"{tuple(image.shape)}."
            )
        if not _check_ids(image, self._sizes):
            raise ValueError(
                "MiniGrid image: ids out of range; expected objects < "
                f"{MINIGRID_NUM_OBJECTS}, colours < {MINIGRID_NUM_COLORS}, states < "
                f"{MINIGRID_NUM_STATES}."
            )
        # In range, so int32 holds them whatever the input's integer dtype.
        idx = image.reshape(-1, g * g * 3).int() + self._offsets
        if not self.use_direction:
            return idx
        if direction is None:
            raise ValueError("MiniGridEncoder(use_direction=True) needs a direction.")
        if direction.dtype.is_floating_point:
            raise TypeError(
                f"MiniGrid direction: expected integers, got {direction.dtype}."
            )
        if direction.numel() != idx.shape[0]:
            raise ValueError(
                "MiniGrid direction: expected one integer per state, got shape "
                f"{tuple(direction.shape)} for images of shape {tuple(image.shape)}."
            )
        if not _check_ids(direction, (MINIGRID_NUM_DIRECTIONS,)):
            raise ValueError("MiniGrid direction: expected values in [0, 4).")
        direction = direction.reshape(-1, 1).int() + self._direction_row
        return torch.cat([idx, direction], -1)

    def forward(
        self, image: torch.Tensor, direction: torch.Tensor | None = None
    ) -> torch.Tensor:
        """Features ``[..., hidden_dim]`` of ``image`` ``[..., 7, 7, 3]`` (ids)."""
        idx = self._indices(image, direction)
        weight = self.embedding.weight
        if torch.is_grad_enabled() and weight.requires_grad:
            out = _SummedEmbedding.apply(idx, weight)
        else:
            out = F.embedding_bag(idx, weight, mode="sum")
        out = out + self.bias
        return self.hidden(out).reshape(*image.shape[:-3], self.out_features)


class MiniGridDecoder(nn.Module):
    """Categorical likelihood over each cell's object, colour and state (and direction).

    Args:
        latent_dim (int): size of ``z``.
        hidden_dim (int): hidden width.
        use_direction (bool): also reconstruct the direction.
        grid_size (int): side of the egocentric view.
        onednn_linear (bool): run the layers on :class:`OneDNNLinear`.

    Examples:
        >>> import torch
        >>> dec = MiniGridDecoder(latent_dim=4, hidden_dim=16)
        >>> image = torch.ones(2, 7, 7, 3, dtype=torch.uint8)
        >>> dec.log_prob(torch.zeros(2, 4), image, torch.zeros(2, dtype=torch.long)).shape
        torch.Size([2])
    """

    def __init__(
        self,
        latent_dim: int,
        hidden_dim: int = 256,
        use_direction: bool = True,
        grid_size: int = 7,
        onednn_linear: bool = False,
    ):
        super().__init__()
        self.grid_size = grid_size
        self.use_direction = use_direction
        self._sizes = (MINIGRID_NUM_OBJECTS, MINIGRID_NUM_COLORS, MINIGRID_NUM_STATES)
        out = grid_size * grid_size * sum(self._sizes)
        out += MINIGRID_NUM_DIRECTIONS if use_direction else 0
        self.net = nn.Sequential(
            linear_layer(latent_dim, hidden_dim, onednn_linear),
            nn.ReLU(),
            linear_layer(hidden_dim, hidden_dim, onednn_linear),
            nn.ReLU(),
            linear_layer(hidden_dim, out, onednn_linear),
        )

    def forward(self, z: torch.Tensor) -> torch.Tensor:
        """Returns the logits, ``[..., 49 * 20 (+ 4)]``."""
        return self.net(z)

    def log_prob(
        self,
        z: torch.Tensor,
        image: torch.Tensor,
        direction: torch.Tensor | None = None,
    ) -> torch.Tensor:
        """Log-likelihood of the observation under the decoder, summed over cells."""
        logits = self(z)
        batch = logits.shape[:-1]
        logits = logits.reshape(-1, logits.shape[-1])
        cells = self.grid_size * self.grid_size
        per_cell = sum(self._sizes)
        # [N, 20, cells] (a view): each channel's classes along dim 1 and the
        # cells innermost, where log_softmax vectorises over the cells. Along
        # the last dim (11, 6 or 3 classes, one short row each) it is ~3x slower
        # on CPU.
        grid_logits = logits[:, : cells * per_cell].unflatten(1, (cells, per_cell))
        grid_logits = grid_logits.transpose(1, 2)
        ids = image.reshape(-1, cells, 3).transpose(1, 2).long()
        total = 0.0
        start = 0
        for channel, size in enumerate(self._sizes):
            log_p = grid_logits[:, start : start + size].log_softmax(1)
            target = ids[:, channel : channel + 1]
            total = total + log_p.gather(1, target).sum((1, 2))
            start += size
        if self.use_direction:
            log_p = logits[:, cells * per_cell :].log_softmax(-1)
            target = direction.reshape(-1, 1).long()
            total = total + log_p.gather(-1, target).squeeze(-1)
        return total.reshape(batch)


class VectorEncoder(nn.Module):
    """MLP encoder for flat float observations (MuJoCo).

    Args:
        obs_dim (int): observation size.
        hidden_dim (int): hidden width.
        num_layers (int): hidden layers.
        onednn_linear (bool): run the layers on :class:`OneDNNLinear`.

    Examples:
        >>> import torch
        >>> VectorEncoder(obs_dim=17, hidden_dim=64)(torch.randn(3, 17)).shape
        torch.Size([3, 64])
    """

    def __init__(
        self,
        obs_dim: int,
        hidden_dim: int = 256,
        num_layers: int = 2,
        onednn_linear: bool = False,
    ):
        super().__init__()
        self.obs_dim = obs_dim
        self.out_features = hidden_dim
        layers, width = [], obs_dim
        for _ in range(num_layers):
            layers += [linear_layer(width, hidden_dim, onednn_linear), nn.ReLU()]
            width = hidden_dim
        self.net = nn.Sequential(*layers)

    def forward(self, observation: torch.Tensor) -> torch.Tensor:
        """Features ``[..., hidden_dim]`` of ``observation`` ``[..., obs_dim]``."""
        _check_floating("observation", observation, (self.obs_dim,))
        # float64 observations (MuJoCo's native dtype) are accepted.
        return self.net(observation.to(self.net[0].weight.dtype))


class GaussianVectorDecoder(nn.Module):
    """Gaussian likelihood with a learned per-dimension scale for flat observations.

    Args:
        latent_dim (int): size of ``z``.
        obs_dim (int): observation size.
        hidden_dim (int): hidden width.
        min_log_scale (float): lower bound of the learned log standard deviation,
            which keeps the likelihood finite when a dimension is constant.
        onednn_linear (bool): run the layers on :class:`OneDNNLinear`.

    Examples:
        >>> import torch
        >>> dec = GaussianVectorDecoder(latent_dim=4, obs_dim=6, hidden_dim=16)
        >>> dec.log_prob(torch.zeros(3, 4), torch.zeros(3, 6)).shape
        torch.Size([3])
    """

    def __init__(
        self,
        latent_dim: int,
        obs_dim: int,
        hidden_dim: int = 256,
        min_log_scale: float = -5.0,
        onednn_linear: bool = False,
    ):
        super().__init__()
        self.net = nn.Sequential(
            linear_layer(latent_dim, hidden_dim, onednn_linear),
            nn.ReLU(),
            linear_layer(hidden_dim, hidden_dim, onednn_linear),
            nn.ReLU(),
            linear_layer(hidden_dim, obs_dim, onednn_linear),
        )
        self.log_scale = nn.Parameter(torch.zeros(obs_dim))
        self.min_log_scale = min_log_scale

    def forward(self, z: torch.Tensor) -> torch.Tensor:
        """Returns the reconstruction mean."""
        return self.net(z)

    def log_prob(self, z: torch.Tensor, observation: torch.Tensor) -> torch.Tensor:
        """Gaussian log-likelihood of the observation, summed over dimensions."""
        log_scale = self.log_scale.clamp_min(self.min_log_scale)
        dist = torch.distributions.Normal(self(z), log_scale.exp())
        return dist.log_prob(observation).sum(-1)


class StateVAE(nn.Module):
    """A VAE over states: encoder, diagonal Gaussian posterior, decoder.

    The posterior scale is ``softplus(x + b) + min_scale`` with ``b`` chosen so
    that a zero pre-activation gives ``scale == 1`` (the prior's): the scale is
    positive, bounded away from 0 (so ``log scale`` and the KL stay finite) and
    an untrained head starts near the prior.

    Args:
        encoder (nn.Module): maps the observation tensors (in the order of
            ``in_keys``) to features; must expose ``out_features``.
        decoder (nn.Module): has ``log_prob(z, *observations) -> [...]``.
        latent_dim (int): size of ``z``.
        in_keys (sequence of NestedKey): the observation keys the VAE reads, in
            the order the encoder takes them. Transforms and losses default to them.
        min_scale (float): floor of the posterior standard deviation.
        onednn_linear (bool): run the posterior head on :class:`OneDNNLinear`
            (the builders pass it to the encoder and decoder too). Off by
            default: it calls a private PyTorch op, for large float32 layers
            on x86-64 CPUs only.

    Examples:
        >>> import torch
        >>> vae = StateVAE.for_vector(obs_dim=5, latent_dim=3, hidden_dim=16)
        >>> loc, scale = vae.posterior(torch.randn(4, 5))
        >>> vae.kl(torch.randn(4, 5)).shape
        torch.Size([4])
        >>> bool((scale > 0).all())
        True
    """

    def __init__(
        self,
        encoder: nn.Module,
        decoder: nn.Module,
        latent_dim: int,
        in_keys: Sequence[NestedKey] = ("observation",),
        min_scale: float = 1e-4,
        onednn_linear: bool = False,
    ):
        super().__init__()
        if isinstance(in_keys, str):
            in_keys = [in_keys]
        self.in_keys = [unravel_key(key) for key in in_keys]
        self.encoder = encoder
        self.decoder = decoder
        self.latent_dim = latent_dim
        self.min_scale = min_scale
        self.head = linear_layer(encoder.out_features, 2 * latent_dim, onednn_linear)
        # softplus(bias) + min_scale == 1 at a zero pre-activation.
        self._scale_bias = math.log(math.expm1(1.0 - min_scale))

    @classmethod
    def for_minigrid(
        cls,
        latent_dim: int = 32,
        hidden_dim: int = 256,
        use_direction: bool = True,
        in_keys: Sequence[NestedKey] | None = None,
        onednn_linear: bool = False,
    ) -> StateVAE:
        """A VAE for MiniGrid's symbolic grid (``"image"``) and ``"direction"``.

        Args:
            latent_dim (int): size of ``z``.
            hidden_dim (int): width of the encoder and decoder.
            use_direction (bool): also encode and reconstruct the direction.
            in_keys (sequence of NestedKey, optional): observation keys; defaults
                to ``["image", "direction"]`` (``["image"]`` without direction).
            onednn_linear (bool): run the linear layers on :class:`OneDNNLinear`.

        Examples:
            >>> import torch
            >>> vae = StateVAE.for_minigrid(latent_dim=8, hidden_dim=32)
            >>> vae.in_keys
            ['image', 'direction']
            >>> image = torch.randint(0, 3, (2, 7, 7, 3), dtype=torch.uint8)
            >>> vae.kl(image, torch.tensor([0, 1])).shape
            torch.Size([2])
        """
        if in_keys is None:
            in_keys = ["image", "direction"] if use_direction else ["image"]
        return cls(
            MiniGridEncoder(
                hidden_dim=hidden_dim,
                use_direction=use_direction,
                onednn_linear=onednn_linear,
            ),
            MiniGridDecoder(
                latent_dim,
                hidden_dim=hidden_dim,
                use_direction=use_direction,
                onednn_linear=onednn_linear,
            ),
            latent_dim,
            in_keys=in_keys,
            onednn_linear=onednn_linear,
        )

    @classmethod
    def for_vector(
        cls,
        obs_dim: int,
        latent_dim: int = 16,
        hidden_dim: int = 256,
        in_keys: Sequence[NestedKey] = ("observation",),
        onednn_linear: bool = False,
    ) -> StateVAE:
        """A VAE for flat float observations with a Gaussian decoder.

        Args:
            obs_dim (int): observation size.
            latent_dim (int): size of ``z``.
            hidden_dim (int): width of the encoder and decoder.
            in_keys (sequence of NestedKey): observation key(s).
            onednn_linear (bool): run the linear layers on :class:`OneDNNLinear`.
        """
        return cls(
            VectorEncoder(obs_dim, hidden_dim=hidden_dim, onednn_linear=onednn_linear),
            GaussianVectorDecoder(
                latent_dim, obs_dim, hidden_dim=hidden_dim, onednn_linear=onednn_linear
            ),
            latent_dim,
            in_keys=list(in_keys),
            onednn_linear=onednn_linear,
        )

    def posterior(
        self, *observations: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """The posterior's ``(loc, scale)``, each ``[..., latent_dim]``."""
        features = self.encoder(*observations)
        loc, raw = self.head(features).chunk(2, -1)
        scale = F.softplus(raw + self._scale_bias) + self.min_scale
        return loc, scale

    def kl(self, *observations: torch.Tensor) -> torch.Tensor:
        """``KL(q(z|s) || N(0, I))`` per state, in nats, shape ``[...]``."""
        return kl_to_standard_normal(*self.posterior(*observations))

    def novelty(self, *observations: torch.Tensor) -> torch.Tensor:
        """The negative ELBO per state, in nats, shape ``[...]``.

        ``-log p(s | z = loc) + KL(q(z|s) || N(0, I))``: how badly the VAE
        explains a state. It falls as the VAE trains on a state, as RND's error
        does; the reconstruction reads the posterior mean, so it is deterministic.

        Examples:
            >>> import torch
            >>> vae = StateVAE.for_vector(obs_dim=5, latent_dim=3, hidden_dim=16)
            >>> vae.novelty(torch.randn(4, 5)).shape
            torch.Size([4])
        """
        loc, scale = self.posterior(*observations)
        nll = -self.decoder.log_prob(loc, *observations)
        return nll + kl_to_standard_normal(loc, scale)

    def forward(self, *observations: torch.Tensor):
        """Posterior, a reparameterised sample and the reconstruction log-likelihood.

        Returns:
            ``(loc, scale, z, log_likelihood)``; ``log_likelihood`` is ``[...]``.
        """
        loc, scale = self.posterior(*observations)
        z = loc + scale * torch.randn_like(loc)
        return loc, scale, z, self.decoder.log_prob(z, *observations)
