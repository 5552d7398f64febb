"""The base of every intrinsic-reward transform of the library.

:class:`IntrinsicRewardTransform` owns everything a bonus shares: reading and
validating the observation keys, the reward specs, normalisation of the bonus,
the coefficient and its schedule, mixing with the extrinsic reward, and the two
paths (inside an env through ``_step``, on a collected batch or a replay-buffer
sample through ``forward``). A bonus is a subclass that implements
:meth:`IntrinsicRewardTransform._compute_bonus`.
"""

from __future__ import annotations

import copy
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import torch
from tensordict import TensorDictBase
from tensordict.utils import NestedKey, unravel_key
from torchrl.data.tensor_specs import Composite, Unbounded
from torchrl.envs.transforms import Transform
from torchrl.envs.transforms.rnd import RunningMeanStd

__all__ = [
    "IntrinsicRewardTransform",
    "LinearSchedule",
    "NORMALIZATIONS",
    "make_coef_schedule",
]

#: Accepted values of ``normalization``.
NORMALIZATIONS = ("none", "reward_std", "return_std", "zscore")


@dataclass(frozen=True)
class LinearSchedule:
    """A coefficient schedule in frames: 0 before ``delay``, then ``start`` -> ``end``.

    The delay lets the bonus model warm up on visited states before its reward is
    used; the ramp anneals the bonus (``end < start``) or brings it in gradually.

    Args:
        start (float): coefficient right after the delay.
        end (float): coefficient once ``delay + frames`` frames have been seen.
        frames (int): length of the linear ramp (``0`` jumps straight to ``end``).
        delay (int): frames during which the coefficient is ``0``.

    Examples:
        >>> schedule = LinearSchedule(start=0.1, end=0.0, frames=100, delay=50)
        >>> schedule(0), schedule(50), schedule(100), schedule(1000)
        (0.0, 0.1, 0.05, 0.0)
    """

    start: float
    end: float
    frames: int
    delay: int = 0

    def __call__(self, frame: int) -> float:
        if frame < self.delay:
            return 0.0
        if self.frames <= 0:
            return float(self.end)
        progress = min(1.0, (frame - self.delay) / self.frames)
        return float(self.start + (self.end - self.start) * progress)


def make_coef_schedule(
    coef: float,
    coef_end: float | None = None,
    anneal_frames: int = 0,
    warmup_frames: int = 0,
) -> LinearSchedule | None:
    """The schedule a recipe's ``intrinsic.*`` settings describe, ``None`` if constant.

    Args:
        coef (float): the coefficient after the warm-up.
        coef_end (float, optional): anneal linearly to this value.
        anneal_frames (int): length of the anneal in frames.
        warmup_frames (int): frames during which the coefficient is 0.

    Examples:
        >>> make_coef_schedule(0.5) is None
        True
        >>> make_coef_schedule(0.5, warmup_frames=100)(50)
        0.0
    """
    if not warmup_frames and coef_end is None:
        return None
    return LinearSchedule(
        start=coef,
        end=coef if coef_end is None else coef_end,
        frames=int(anneal_frames),
        delay=int(warmup_frames),
    )


class IntrinsicRewardTransform(Transform):
    """Base class of the bonus transforms: keys, specs, normalisation, mixing.

    For each transition the transform writes, in the ``"next"`` tensordict:

    * ``intrinsic_reward_key``: the raw bonus (never normalised, for logging);
    * ``intrinsic_reward_key + "_normalized"`` (only when ``normalization`` is
      not ``"none"``): the normalised bonus that is mixed in;
    * ``extrinsic_reward_key``: a copy of the task reward, so it is never lost;
    * ``reward_key``: ``r_ext + coef * r_int`` (the key losses and value
      estimators read; ``None`` writes the bonus only and mixes nothing).

    The batch path (``forward``) always starts from ``extrinsic_reward_key`` when
    it is present: recomputing the bonus of a replay-buffer sample with the
    current model replaces the old bonus instead of stacking a new one on it.

    Normalisation (``normalization``):

    * ``"none"``: the raw bonus.
    * ``"reward_std"``: divided by the running standard deviation of the bonus.
    * ``"zscore"``: centred by the running mean and divided by the running std.
      Centring removes the constant part of a bonus that is positive everywhere,
      which in an episodic task otherwise acts as a living bonus.
    * ``"return_std"``: divided by the running std of the discounted intrinsic
      return (non-episodic), as in RND. Needs a time dimension: one ``_step`` call
      in an env is one time step; a batch must have a dimension named ``"time"``
      (TorchRL's collectors name it) or ``time_dim`` set.

    Statistics (and the schedule's frame counter) are updated on every call until
    the transform is frozen (:meth:`freeze`; :meth:`frozen_copy` for evaluation),
    as for TorchRL's ``VecNormV2``: not by ``train()``/``eval()``, which TorchRL
    sets on its own when it attaches a transform to an env or a buffer. They are
    buffers, so they are part of ``state_dict``.

    Args:
        in_keys (sequence of NestedKey): observation keys the bonus reads.

    Keyword Args:
        intrinsic_reward_key (NestedKey): where the raw bonus is written.
        reward_key (NestedKey or None): where the mixed reward is written (and the
            extrinsic reward is read the first time).
        extrinsic_reward_key (NestedKey): where the extrinsic reward is kept.
        coef (float): the mixing coefficient ``beta`` when no schedule is given.
        coef_schedule (callable, optional): ``frames -> coef``, evaluated at the
            number of transitions this transform has processed while not frozen
            (see :meth:`set_frames`), e.g. :class:`LinearSchedule`.
        normalization (str): one of :data:`NORMALIZATIONS`.
        gamma (float): discount of the intrinsic return for ``"return_std"``.
        clip (float, optional): clip the normalised bonus to ``[-clip, clip]``.
        time_dim (int, optional): the time dimension of batches for
            ``"return_std"`` when it is not named ``"time"``.
        count_frames (bool): advance the schedule's frame counter by the number
            of transitions of every call while not frozen. Set it to ``False``
            when the transform recomputes bonuses of replay-buffer samples (which
            are not new frames) and drive the counter with :meth:`set_frames`.
    """

    def __init__(
        self,
        in_keys: Sequence[NestedKey],
        *,
        intrinsic_reward_key: NestedKey = "intrinsic_reward",
        reward_key: NestedKey | None = "reward",
        extrinsic_reward_key: NestedKey = "extrinsic_reward",
        coef: float = 1.0,
        coef_schedule: Callable[[int], float] | None = None,
        normalization: str = "none",
        gamma: float = 0.99,
        clip: float | None = None,
        time_dim: int | None = None,
        count_frames: bool = True,
    ):
        if isinstance(in_keys, str):
            in_keys = [in_keys]
        if not in_keys:
            raise ValueError(f"{type(self).__name__}: in_keys must not be empty.")
        if normalization not in NORMALIZATIONS:
            raise ValueError(
                f"{type(self).__name__}: normalization must be one of {NORMALIZATIONS}, "
                f"got {normalization!r}."
            )
        if not math.isfinite(coef):
            raise ValueError(f"coef must be finite, got {coef}.")
        if not 0.0 <= gamma <= 1.0:
            raise ValueError(f"gamma must be in [0, 1], got {gamma}.")
        if clip is not None and clip <= 0:
            raise ValueError(f"clip must be positive, got {clip}.")
        super().__init__(in_keys=list(in_keys), out_keys=[intrinsic_reward_key])
        self.intrinsic_reward_key = unravel_key(intrinsic_reward_key)
        self.reward_key = None if reward_key is None else unravel_key(reward_key)
        self.extrinsic_reward_key = unravel_key(extrinsic_reward_key)
        self.coef = float(coef)
        self.coef_schedule = coef_schedule
        self.normalization = normalization
        self.gamma = gamma
        self.clip = clip
        self.time_dim = time_dim
        self.count_frames = count_frames
        self._frozen = False
        self.reward_rms = RunningMeanStd(shape=())
        self.register_buffer("frames", torch.zeros((), dtype=torch.long))
        self.register_buffer("_return_acc", torch.zeros(0))

    # ------------------------------------------------------------------ keys
    @property
    def normalized_reward_key(self) -> NestedKey | None:
        """Key of the normalised bonus, or ``None`` without normalisation."""
        if self.normalization == "none":
            return None
        key = self.intrinsic_reward_key
        if isinstance(key, str):
            return key + "_normalized"
        return (*key[:-1], key[-1] + "_normalized")

    def _written_reward_keys(self) -> list[NestedKey]:
        keys = [self.intrinsic_reward_key]
        if self.normalized_reward_key is not None:
            keys.append(self.normalized_reward_key)
        if self.reward_key is not None:
            keys.append(self.extrinsic_reward_key)
        return keys

    # ----------------------------------------------------- coef and schedule
    def current_coef(self) -> float:
        """The coefficient in force now (from the schedule when there is one)."""
        if self.coef_schedule is None:
            return self.coef
        return float(self.coef_schedule(int(self.frames)))

    def set_frames(self, frames: int) -> None:
        """Sets the frame counter that drives ``coef_schedule``."""
        self.frames.fill_(int(frames))

    # ------------------------------------------------------ freeze / unfreeze
    def freeze(self) -> IntrinsicRewardTransform:
        """Stops updating the normalisation statistics (and the frame counter)."""
        self._frozen = True
        return self

    def unfreeze(self) -> IntrinsicRewardTransform:
        """Resumes updating the statistics."""
        self._frozen = False
        return self

    @property
    def frozen(self) -> bool:
        """Whether the statistics are frozen."""
        return self._frozen

    def frozen_copy(self) -> IntrinsicRewardTransform:
        """A frozen copy with its own statistics that shares the bonus model."""
        other = self.clone()
        other.reward_rms = copy.deepcopy(self.reward_rms)
        other.frames = self.frames.clone()
        other._return_acc = self._return_acc.clone()
        return other.freeze()

    def _load_from_state_dict(self, state_dict, prefix, *args, **kwargs):
        # The return accumulator takes the shape of the batches it has seen.
        acc = state_dict.get(prefix + "_return_acc")
        if acc is not None:
            self._return_acc = torch.zeros_like(acc)
        super()._load_from_state_dict(state_dict, prefix, *args, **kwargs)

    @property
    def _updating(self) -> bool:
        # Not gated on ``self.training``: TorchRL calls ``eval()`` on every
        # transform it attaches (TransformedEnv, Compose.append, replay buffers),
        # which would silently freeze the statistics inside an env. As VecNormV2,
        # only ``freeze()`` stops the updates.
        return not self._frozen

    # -------------------------------------------------------------- reading
    def _observations(
        self, tensordict: TensorDictBase, where: str
    ) -> list[torch.Tensor]:
        observations = []
        for key in self.in_keys:
            value = tensordict.get(key, None)
            if value is None:
                available = sorted(
                    str(k) for k in tensordict.keys(True, True) if k != "next"
                )
                raise KeyError(
                    f"{type(self).__name__}: expected the observation key {key!r} in "
                    f"{where}; found {available}."
                )
            if not isinstance(value, torch.Tensor):
                raise TypeError(
                    f"{type(self).__name__}: {key!r} in {where} must be a tensor, "
                    f"got {type(value).__name__}."
                )
            if value.dtype.is_floating_point and not torch.isfinite(value).all():
                raise ValueError(
                    f"{type(self).__name__}: the observation {key!r} in {where} "
                    "contains NaN or inf; refusing to compute a bonus from it."
                )
            observations.append(value)
        return observations

    def _compute_bonus(
        self, tensordict: TensorDictBase, next_tensordict: TensorDictBase
    ) -> torch.Tensor:
        """The raw bonus of each transition, shape ``next_tensordict.batch_size``.

        ``tensordict`` holds ``s_t`` (and the action), ``next_tensordict``
        ``s_{t+1}``. Called under ``torch.no_grad()``.
        """
        raise NotImplementedError

    # --------------------------------------------------------- normalising
    def _discounted_returns(self, bonus: torch.Tensor, time_dim: int | None):
        if time_dim is None:
            if self._return_acc.shape != bonus.shape:
                self._return_acc = torch.zeros_like(bonus)
            returns = self._return_acc * self.gamma + bonus
            if self._updating:
                self._return_acc = returns
            return returns
        moved = bonus.movedim(time_dim, 0)
        acc = self._return_acc
        if acc.shape != moved.shape[1:]:
            acc = torch.zeros_like(moved[0])
        returns = []
        for step in moved:
            acc = acc * self.gamma + step
            returns.append(acc)
        if self._updating:
            self._return_acc = acc
        return torch.stack(returns, 0).movedim(0, time_dim)

    def _normalize(self, bonus: torch.Tensor, time_dim: int | None) -> torch.Tensor:
        if self.normalization == "none":
            return bonus
        if self.normalization == "return_std":
            stats_input = self._discounted_returns(bonus, time_dim)
        else:
            stats_input = bonus
        if self._updating:
            self.reward_rms.update(stats_input)
        std = self.reward_rms.var.clamp_min(1e-8).sqrt()
        if self.normalization == "zscore":
            out = (bonus - self.reward_rms.mean) / std
        else:
            out = bonus / std
        if self.clip is not None:
            out = out.clamp(-self.clip, self.clip)
        return out

    # --------------------------------------------------------------- paths
    def _write_bonus(
        self,
        tensordict: TensorDictBase,
        next_tensordict: TensorDictBase,
        time_dim: int | None,
    ) -> TensorDictBase:
        with torch.no_grad():
            bonus = self._compute_bonus(tensordict, next_tensordict)
        if not torch.isfinite(bonus).all():
            raise ValueError(
                f"{type(self).__name__}: the bonus model produced NaN or inf; its "
                "parameters may have diverged."
            )
        reward = None
        if self.reward_key is not None:
            reward = next_tensordict.get(self.extrinsic_reward_key, None)
            if reward is None:
                reward = next_tensordict.get(self.reward_key, None)
                if reward is None:
                    raise KeyError(
                        f"{type(self).__name__}: expected the reward key "
                        f"{self.reward_key!r} (or {self.extrinsic_reward_key!r}) in "
                        "the 'next' tensordict."
                    )
        shape = reward.shape if reward is not None else (*bonus.shape, 1)
        dtype = reward.dtype if reward is not None else torch.float32
        bonus = bonus.reshape(shape).to(dtype)
        if time_dim is not None and time_dim < 0:
            time_dim = next_tensordict.ndim + time_dim
        normalized = self._normalize(bonus, time_dim)
        coef = self.current_coef()
        if self._updating and self.count_frames:
            self.frames += next_tensordict.numel()
        next_tensordict.set(self.intrinsic_reward_key, bonus)
        if self.normalized_reward_key is not None:
            next_tensordict.set(self.normalized_reward_key, normalized)
        if reward is not None:
            next_tensordict.set(self.extrinsic_reward_key, reward)
            next_tensordict.set(self.reward_key, reward + coef * normalized)
        return next_tensordict

    def _step(
        self, tensordict: TensorDictBase, next_tensordict: TensorDictBase
    ) -> TensorDictBase:
        return self._write_bonus(tensordict, next_tensordict, time_dim=None)

    def _time_dim(self, tensordict: TensorDictBase) -> int | None:
        if self.time_dim is not None:
            return self.time_dim
        names = tensordict.names if tensordict._has_names() else None
        if names is not None and "time" in names:
            return names.index("time")
        if self.normalization == "return_std":
            raise ValueError(
                f"{type(self).__name__}: normalization='return_std' on a batch needs "
                "a time dimension: name it 'time' (collectors do) or pass time_dim."
            )
        return None

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        """Recomputes the bonus of a batch of transitions with the current model.

        ``tensordict`` holds ``s_t`` (and the action) at its root and ``s_{t+1}``
        and the reward under ``"next"``, as collectors and replay buffers give.
        """
        next_tensordict = tensordict.get("next", None)
        if next_tensordict is None:
            raise KeyError(
                f"{type(self).__name__}.forward expects transitions with a 'next' "
                "entry holding the next observation and the reward."
            )
        time_dim = self._time_dim(tensordict)
        next_tensordict = self._write_bonus(tensordict, next_tensordict, time_dim)
        tensordict.set("next", next_tensordict)
        return tensordict

    # ---------------------------------------------------------------- specs
    def transform_reward_spec(self, reward_spec: Composite) -> Composite:
        """Declares the bonus entries (and the kept extrinsic reward) as rewards."""
        shape, device = reward_spec.shape, reward_spec.device
        dtype = torch.float32
        if self.reward_key is not None:
            if self.reward_key not in reward_spec.keys(True, True):
                raise KeyError(
                    f"{type(self).__name__}: the parent env has no reward "
                    f"{self.reward_key!r}; its rewards are "
                    f"{list(reward_spec.keys(True, True))}."
                )
            reference = reward_spec[self.reward_key]
            # The bonus is written in the reward's dtype.
            shape, device, dtype = reference.shape, reference.device, reference.dtype
            reward_spec[self.extrinsic_reward_key] = reference.clone()
        else:
            shape = (*shape, 1)
        for key in self._written_reward_keys():
            if key != self.extrinsic_reward_key:
                reward_spec[key] = Unbounded(shape=shape, device=device, dtype=dtype)
        return reward_spec

    def __repr__(self) -> str:
        return (
            f"{type(self).__name__}(in_keys={self.in_keys}, "
            f"intrinsic_reward_key={self.intrinsic_reward_key!r}, "
            f"reward_key={self.reward_key!r}, coef={self.coef}, "
            f"normalization={self.normalization!r})"
        )
