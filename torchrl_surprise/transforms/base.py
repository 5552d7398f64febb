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
import warnings
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass

import torch
from tensordict import TensorDictBase
from tensordict.utils import NestedKey, unravel_key
from torch import nn
from torchrl.data.tensor_specs import Composite, Unbounded
from torchrl.envs.transforms import Compose, Transform
from torchrl.envs.transforms.rnd import RunningMeanStd

from torchrl_surprise.transforms.episodic import EpisodicMemory

__all__ = [
    "CONTRIBUTIONS_KEY",
    "E3BRewardMoments",
    "IntrinsicRewardTransform",
    "LinearSchedule",
    "NORMALIZATIONS",
    "WorkerCopyWarning",
    "make_coef_schedule",
]

#: Accepted values of ``normalization``.
NORMALIZATIONS = ("none", "reward_std", "return_std", "zscore", "e3b_std")

#: The ``"next"`` entry under which each bonus keeps what it added to the reward,
#: ``coef * normalised bonus``, as ``(CONTRIBUTIONS_KEY, <transform class>,
#: *intrinsic_reward_key)``.
CONTRIBUTIONS_KEY = "reward_contributions"


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


class E3BRewardMoments(nn.Module):
    """The running statistic E3B's code divides its bonus by (``normalization="e3b_std"``).

    Transcribed from facebookresearch/e3b, ``minihack/torchbeast/src/models.py``
    l.413-434 (``update_running_moments``, ``get_running_std``), as
    ``algos/e3b.py`` l.82-86 calls it on each learner batch of ``batch_size``
    trajectories of T steps (``--batch_size 8``, ``arguments.py`` l.46). That code
    counts T bonuses per batch where there are T x ``batch_size``, and centres
    them on the batch's sum over T: ``sqrt(m2 / count)`` is about
    ``sqrt(B (sigma^2 + (B - 1)^2 mu^2))`` for bonuses of mean ``mu`` and std
    ``sigma``, many times their std. It is kept as written, so that E3B's
    bonus has the scale its authors' runs gave it. A batch of N envs is taken
    ``batch_size`` envs at a time.

    Examples:
        >>> moments = E3BRewardMoments(batch_size=2)
        >>> moments.update(torch.tensor([[1.0, 1.0], [1.0, 1.0]]))  # T=2, 2 envs
        >>> moments.std()  # sum 4 over a count of 2: mean 2, not 1
        tensor(1.4142, dtype=torch.float64)
    """

    def __init__(self, batch_size: int = 8):
        super().__init__()
        self.batch_size = int(batch_size)
        self.register_buffer("reward_sum", torch.zeros((), dtype=torch.float64))
        self.register_buffer("reward_m2", torch.zeros((), dtype=torch.float64))
        self.register_buffer("reward_count", torch.full((), 1e-8, dtype=torch.float64))

    def update(self, bonus: torch.Tensor) -> None:
        """Adds ``bonus``, ``[T, N]`` (time first), ``batch_size`` envs at a time."""
        for group in bonus.to(torch.float64).split(self.batch_size, dim=1):
            new_count = group.shape[0]
            new_sum = group.sum()
            new_mean = new_sum / new_count
            curr_mean = self.reward_sum / self.reward_count
            new_m2 = ((group - new_mean) ** 2).sum() + (
                self.reward_count * new_count / (self.reward_count + new_count)
            ) * (new_mean - curr_mean) ** 2
            self.reward_count += new_count
            self.reward_sum += new_sum
            self.reward_m2 += new_m2

    def std(self) -> torch.Tensor:
        """``sqrt(m2 / count)``."""
        return (self.reward_m2 / self.reward_count).sqrt()


class WorkerCopyWarning(UserWarning):
    """A bonus transform sits in the env of a ``SerialEnv``/``ParallelEnv`` worker.

    Each worker then holds its own copy of the transform's normalisation
    statistics and frame counter and, in a ``ParallelEnv``, of the bonus model:
    training the model in the main process never changes the workers' bonus.
    The transform belongs on the outer env, ``TransformedEnv(ParallelEnv(...),
    transform)``, or on collected batches, ``transform(batch)``. Silence it with
    ``warnings.filterwarnings("ignore", category=WorkerCopyWarning)`` where the
    copies are intended (a frozen model, per-worker statistics).

    Examples:
        >>> import warnings
        >>> from torchrl.envs import SerialEnv, TransformedEnv
        >>> from torchrl.testing.mocking_classes import ContinuousActionVecMockEnv
        >>> from torchrl_surprise import StateVAE, VAESurpriseTransform
        >>> def make_env():  # the bonus inside each worker's env
        ...     vae = StateVAE.for_vector(7, latent_dim=4, hidden_dim=16)
        ...     bonus = VAESurpriseTransform(vae)
        ...     return TransformedEnv(ContinuousActionVecMockEnv(), bonus)
        >>> with warnings.catch_warnings(record=True) as caught:
        ...     warnings.simplefilter("always")
        ...     env = SerialEnv(2, make_env)
        >>> any(issubclass(w.category, WorkerCopyWarning) for w in caught)
        True
        >>> env.close(raise_if_closed=False)
    """


def _bonus_transforms(compose: Compose) -> Iterator[IntrinsicRewardTransform]:
    for transform in compose.transforms:
        if isinstance(transform, Compose):
            yield from _bonus_transforms(transform)
        elif isinstance(transform, IntrinsicRewardTransform):
            yield transform


class IntrinsicRewardTransform(Transform):
    """Base class of the bonus transforms: keys, specs, normalisation, mixing.

    For each transition the transform writes, in the ``"next"`` tensordict:

    * ``intrinsic_reward_key``: the raw bonus (never normalised, for logging);
    * ``intrinsic_reward_key + "_normalized"`` (only when ``normalization`` is
      not ``"none"``): the normalised bonus that is mixed in;
    * ``extrinsic_reward_key``: the reward it received, so the task reward is
      never lost;
    * :attr:`contribution_key`, ``("reward_contributions", <class name>,
      *intrinsic_reward_key)``: what it added to the reward, ``coef *
      normalised bonus``;
    * ``reward_key``: the received reward plus that contribution,
      ``r_ext + coef * r_int`` for a single bonus (the key losses and value
      estimators read; ``reward_key=None`` writes the bonus only and mixes
      nothing).

    Recomputing (``forward`` on a batch that already holds this transform's
    contribution, e.g. a replay-buffer sample with the current model) replaces
    the contribution: ``reward - old contribution + new contribution``. The
    other bonuses mixed into the reward stay in it, whichever order they are
    recomputed in; the kept ``extrinsic_reward_key`` is the reward as first
    received and is not rewritten.

    Normalisation (``normalization``):

    * ``"none"``: the raw bonus.
    * ``"reward_std"``: divided by the running standard deviation of the bonus.
    * ``"zscore"``: centred by the running mean and divided by the running std.
      Centring removes the constant part of a bonus that is positive everywhere,
      which in an episodic task otherwise acts as a living bonus.
    * ``"e3b_std"``: divided by the running statistic of E3B's code
      (:class:`E3BRewardMoments`), as its authors' runs divided it.
    * ``"return_std"``: divided by the running std of the discounted intrinsic
      return (non-episodic), as in RND. Needs a time dimension: one ``_step`` call
      in an env is one time step; a batch must have a dimension named ``"time"``
      (TorchRL's collectors name it) or ``time_dim`` set.

    Statistics (and the schedule's frame counter) are updated on every call until
    the transform is frozen (:meth:`freeze`; :meth:`frozen_copy` for evaluation),
    as for TorchRL's ``VecNormV2``: not by ``train()``/``eval()``, which TorchRL
    sets on its own when it attaches a transform to an env or a buffer. They are
    buffers, so they are part of ``state_dict``, which also records
    ``normalization``: a ``state_dict`` does not load into a transform that
    normalises differently (its statistics would be meaningless there).

    Stacking bonuses: each transform needs its own ``intrinsic_reward_key`` and
    ``extrinsic_reward_key``. The second then adds its bonus to the reward it
    receives and keeps that reward under its ``extrinsic_reward_key``, while the
    first one's stays the task reward; the reward is the task reward plus every
    contribution under ``"reward_contributions"``. Transforms that would write
    the same keys are refused: in one ``Compose``, on an env whose reward spec
    already has them, and on a batch where another bonus wrote them (its
    contribution names it).

    Inside the env of a ``SerialEnv``/``ParallelEnv`` worker the transform emits
    a :class:`WorkerCopyWarning`: its statistics, and in a ``ParallelEnv`` its
    model, are per-worker copies that the main process never sees.

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

    Examples:
        Two bonuses on one env, the second with its own keys:

        >>> import torch
        >>> from torchrl.envs import Compose, TransformedEnv
        >>> from torchrl.testing.mocking_classes import ContinuousActionVecMockEnv
        >>> from torchrl_surprise import (
        ...     ICMModel, ICMTransform, StateVAE, VAESurpriseTransform)
        >>> vae = StateVAE.for_vector(7, latent_dim=4, hidden_dim=16)
        >>> icm = ICMModel.for_vector(7, 7, hidden_dim=16)
        >>> env = TransformedEnv(ContinuousActionVecMockEnv(), Compose(
        ...     VAESurpriseTransform(vae, coef=0.5),
        ...     ICMTransform(icm, coef=0.1, intrinsic_reward_key="icm_reward",
        ...                  extrinsic_reward_key="reward_before_icm")))
        >>> rollout = env.rollout(3)
        >>> nxt = rollout["next"]
        >>> task, vae_bonus, icm_bonus = (
        ...     nxt["extrinsic_reward"], nxt["intrinsic_reward"], nxt["icm_reward"])
        >>> torch.allclose(nxt["reward"], task + 0.5 * vae_bonus + 0.1 * icm_bonus)
        True

        Each keeps its contribution; recomputing one bonus (here after a VAE
        update) replaces its own and keeps the other's:

        >>> sorted(nxt["reward_contributions"].keys(True, True))
        [('ICMTransform', 'icm_reward'), ('VAESurpriseTransform', 'intrinsic_reward')]
        >>> with torch.no_grad():
        ...     _ = vae.head.bias.add_(0.3)
        >>> nxt = env.transform[0](rollout.clone())["next"]
        >>> bool((nxt["intrinsic_reward"] != vae_bonus).all())
        True
        >>> torch.allclose(nxt["reward"], task + 0.5 * nxt["intrinsic_reward"]
        ...                + 0.1 * icm_bonus)
        True

        With the same keys, the second would overwrite the first's bonus:

        >>> Compose(VAESurpriseTransform(vae), ICMTransform(icm))
        Traceback (most recent call last):
            ...
        ValueError: ICMTransform would write ('next', 'intrinsic_reward'), ...
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
        keys = [unravel_key(intrinsic_reward_key), unravel_key(extrinsic_reward_key)]
        if reward_key is not None:
            keys.append(unravel_key(reward_key))
        if len(set(keys)) != len(keys):
            raise ValueError(
                f"{type(self).__name__}: intrinsic_reward_key, extrinsic_reward_key "
                f"and reward_key must be distinct, got {keys}."
            )
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
        if normalization == "e3b_std":
            self.e3b_moments = E3BRewardMoments()
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

    @property
    def contribution_key(self) -> NestedKey | None:
        """Where this bonus keeps ``coef * normalised bonus``, ``None`` if it mixes none.

        ``(CONTRIBUTIONS_KEY, <transform class>, *intrinsic_reward_key)``: the
        class names the writer, so that a bonus finds its own earlier
        contribution on a batch and tells another bonus's apart.
        """
        if self.reward_key is None:
            return None
        key = self.intrinsic_reward_key
        key = key if isinstance(key, tuple) else (key,)
        return (CONTRIBUTIONS_KEY, type(self).__name__, *key)

    def _written_reward_keys(self) -> list[NestedKey]:
        keys = [self.intrinsic_reward_key]
        if self.normalized_reward_key is not None:
            keys.append(self.normalized_reward_key)
        if self.reward_key is not None:
            keys.append(self.extrinsic_reward_key)
            keys.append(self.contribution_key)
        return keys

    def _clash_error(self, clashing: Sequence[NestedKey], writer: str) -> ValueError:
        """The error for keys this transform would write over ``writer``'s."""
        stem = type(self).__name__.removesuffix("Transform").lower()
        keys = ", ".join(
            repr(("next", *(key if isinstance(key, tuple) else (key,))))
            for key in clashing
        )
        return ValueError(
            f"{type(self).__name__} would write {keys}, which {writer} already "
            "writes: it would overwrite that bonus (or the reward kept there) and "
            "lose it silently. To stack bonuses, give this transform its own keys, "
            f"e.g. {type(self).__name__}(..., intrinsic_reward_key='{stem}_reward', "
            f"extrinsic_reward_key='reward_before_{stem}'): it then adds its bonus "
            "to the reward it receives and keeps that reward under its "
            "extrinsic_reward_key."
        )

    def set_container(self, container) -> None:
        """Attaches the transform; refuses a ``Compose`` whose bonuses share keys."""
        super().set_container(container)
        if not isinstance(container, Compose):
            return
        bonuses = list(_bonus_transforms(container))
        if self not in bonuses:  # nested: the outer Compose checks it
            return
        for other in bonuses:
            if other is self:
                continue
            # Reported against the later one: it is the one to give other keys.
            earlier, later = sorted((self, other), key=bonuses.index)
            theirs = set(earlier._written_reward_keys())
            clashing = [k for k in later._written_reward_keys() if k in theirs]
            if clashing:
                raise later._clash_error(
                    clashing, f"{type(earlier).__name__}, earlier in the same Compose,"
                )

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

    def clone(self) -> IntrinsicRewardTransform:
        """A copy sharing the bonus model, with its own episodic memories.

        TorchRL's ``clone`` shares submodules; an
        :class:`~torchrl_surprise.transforms.EpisodicMemory` is copied instead,
        so the copy's episodes (on another env, or in evaluation) are its own.
        """
        other = super().clone()
        for name, module in self.named_children():
            if isinstance(module, EpisodicMemory):
                setattr(other, name, copy.deepcopy(module))
        return other

    def frozen_copy(self) -> IntrinsicRewardTransform:
        """A frozen copy with its own statistics that shares the bonus model."""
        other = self.clone()
        other.reward_rms = copy.deepcopy(self.reward_rms)
        if self.normalization == "e3b_std":
            other.e3b_moments = copy.deepcopy(self.e3b_moments)
        other.frames = self.frames.clone()
        other._return_acc = self._return_acc.clone()
        return other.freeze()

    def get_extra_state(self) -> dict:
        """What a ``state_dict`` is tied to: the ``normalization`` of its statistics."""
        return {"normalization": self.normalization}

    def set_extra_state(self, state) -> None:
        # Checked in _load_from_state_dict, before anything is loaded.
        pass

    def _load_from_state_dict(
        self,
        state_dict,
        prefix,
        local_metadata,
        strict,
        missing_keys,
        unexpected_keys,
        error_msgs,
    ):
        # torch's key for get_extra_state().
        extra_key = prefix + "_extra_state"
        saved = state_dict.get(extra_key)
        if isinstance(saved, Mapping):
            normalization = saved.get("normalization", self.normalization)
            if normalization != self.normalization:
                raise ValueError(
                    f"{type(self).__name__}: this state_dict was saved with "
                    f"normalization={normalization!r}, but this transform uses "
                    f"normalization={self.normalization!r}; its running statistics "
                    f"do not apply here. Build the transform with "
                    f"normalization={normalization!r} to load it."
                )
        # The return accumulator takes the shape of the batches it has seen.
        acc = state_dict.get(prefix + "_return_acc")
        if acc is not None:
            self._return_acc = torch.zeros_like(acc)
        super()._load_from_state_dict(
            state_dict,
            prefix,
            local_metadata,
            strict,
            missing_keys,
            unexpected_keys,
            error_msgs,
        )
        # State dicts saved before the record existed load as before, unchecked.
        if saved is None and extra_key in missing_keys:
            missing_keys.remove(extra_key)

    @property
    def _updating(self) -> bool:
        # Not gated on ``self.training``: TorchRL calls ``eval()`` on every
        # transform it attaches (TransformedEnv, Compose.append, replay buffers),
        # which would silently freeze the statistics inside an env. As VecNormV2,
        # only ``freeze()`` stops the updates.
        return not self._frozen

    # -------------------------------------------------------------- reading
    def _observations(
        self,
        tensordict: TensorDictBase,
        where: str,
        keys: Sequence[NestedKey] | None = None,
    ) -> list[torch.Tensor]:
        """The tensors of ``keys`` (default ``in_keys``), checked to be finite."""
        observations = []
        for key in self.in_keys if keys is None else keys:
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

    def _per_transition(
        self,
        key: NestedKey,
        value: torch.Tensor,
        batch_size: torch.Size,
        where: str = "the 'next' tensordict",
    ) -> torch.Tensor:
        """Checks that ``value`` holds one entry per transition and returns it.

        Accepts ``[*batch]`` and ``[*batch, 1]`` (TorchRL's reward and done
        shape); anything else is refused with the key and both shapes.
        """
        if value.shape not in (batch_size, (*batch_size, 1)):
            raise ValueError(
                f"{type(self).__name__}: expected {key!r} in {where} to hold one "
                f"value per transition, shape {tuple(batch_size)} or "
                f"{(*batch_size, 1)}; got {tuple(value.shape)}."
            )
        return value

    def _episode_ends(
        self, next_tensordict: TensorDictBase, done_key: NestedKey
    ) -> torch.Tensor | None:
        """``done_key`` as a bool ``[*batch]`` (``None`` if absent), for episodic bonuses."""
        done = next_tensordict.get(done_key, None)
        if done is None:
            return None
        batch_size = next_tensordict.batch_size
        done = self._per_transition(done_key, done, batch_size)
        return done.reshape(batch_size).bool()

    def _require_time_dim(self, time_dim: int | None) -> int:
        """``time_dim``, or an error for a bonus that needs time-ordered batches."""
        if time_dim is None:
            raise ValueError(
                f"{type(self).__name__}: the episodic bonus needs time-ordered "
                "transitions: a batch with a dimension named 'time' (collectors "
                "name it) or time_dim set; a replay-buffer sample has neither."
            )
        return time_dim

    def _compute_bonus(
        self, tensordict: TensorDictBase, next_tensordict: TensorDictBase
    ) -> torch.Tensor:
        """The raw bonus of each transition, shape ``next_tensordict.batch_size``.

        ``tensordict`` holds ``s_t`` (and the action), ``next_tensordict``
        ``s_{t+1}``. Called under ``torch.no_grad()`` by the env path (one step
        of every env) and, unless :meth:`_compute_batch_bonus` is overridden, by
        the batch path.
        """
        raise NotImplementedError

    def _compute_batch_bonus(
        self,
        tensordict: TensorDictBase,
        next_tensordict: TensorDictBase,
        time_dim: int | None,
    ) -> torch.Tensor:
        """The raw bonus of a batch of transitions (the batch path).

        ``time_dim`` is the batch's time dimension (non-negative), or ``None``
        when it has none. A bonus that does not depend on the order of
        transitions computes it as one step; an episodic bonus walks
        ``time_dim``.
        """
        return self._compute_bonus(tensordict, next_tensordict)

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
        if not len(moved):
            return bonus
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
        if self.normalization == "e3b_std":
            return self._normalize_e3b(bonus, time_dim)
        if self.normalization == "return_std":
            stats_input = self._discounted_returns(bonus, time_dim)
        else:
            stats_input = bonus
        if self._updating and stats_input.numel():
            self.reward_rms.update(stats_input)
        std = self.reward_rms.var.clamp_min(1e-8).sqrt()
        if self.normalization == "zscore":
            out = (bonus - self.reward_rms.mean) / std
        else:
            out = bonus / std
        if self.clip is not None:
            out = out.clamp(-self.clip, self.clip)
        return out

    def _normalize_e3b(self, bonus: torch.Tensor, time_dim: int | None):
        # One env step (time_dim None) is T = 1; a batch is [T, N] time first.
        moved = bonus.unsqueeze(0) if time_dim is None else bonus.movedim(time_dim, 0)
        if self._updating and moved.numel():
            self.e3b_moments.update(moved.reshape(moved.shape[0], -1))
        std = self.e3b_moments.std()
        out = bonus / std.to(bonus.dtype) if std > 0 else bonus
        if self.clip is not None:
            out = out.clamp(-self.clip, self.clip)
        return out

    # --------------------------------------------------------------- paths
    def _received_reward(
        self, next_tensordict: TensorDictBase
    ) -> tuple[torch.Tensor | None, torch.Tensor | None]:
        """The reward to mix the bonus into, and this bonus's contribution in it.

        Returns ``(reward, previous)``: ``previous`` is what this transform added
        to ``reward`` when it last mixed these transitions (its
        :attr:`contribution_key`), ``None`` the first time. Refuses a batch where
        another bonus wrote this transform's keys.
        """
        if self.reward_key is None:
            return None, None
        batch_size = next_tensordict.batch_size
        reward = next_tensordict.get(self.reward_key, None)
        previous = next_tensordict.get(self.contribution_key, None)
        if previous is not None and reward is not None:
            self._per_transition(self.reward_key, reward, batch_size)
            self._per_transition(self.contribution_key, previous, batch_size)
            return reward, previous.reshape(reward.shape)
        kept = next_tensordict.get(self.extrinsic_reward_key, None)
        self._refuse_other_writers(next_tensordict, kept is not None)
        if kept is not None:
            # Mixed without a recorded contribution (by hand, or by a version of
            # the library that did not record them): start from the kept reward.
            return self._per_transition(
                self.extrinsic_reward_key, kept, batch_size
            ), None
        if reward is None:
            raise KeyError(
                f"{type(self).__name__}: expected the reward key "
                f"{self.reward_key!r} (or {self.extrinsic_reward_key!r}) in "
                "the 'next' tensordict."
            )
        return self._per_transition(self.reward_key, reward, batch_size), None

    def _refuse_other_writers(
        self, next_tensordict: TensorDictBase, has_kept_reward: bool
    ) -> None:
        """Raises if another bonus already wrote this transform's keys on the batch.

        The contributions under :data:`CONTRIBUTIONS_KEY` name their writers:
        another class with this ``intrinsic_reward_key`` wrote the bonus keys;
        any other bonus, where this ``extrinsic_reward_key`` is already filled
        and this transform has no contribution, wrote the kept reward.
        """
        group = next_tensordict.get(CONTRIBUTIONS_KEY, None)
        if not isinstance(group, TensorDictBase):
            return
        own = self.contribution_key[1:]
        writers = []
        for writer, *bonus_key in group.keys(True, True):
            if (writer, *bonus_key) == own:
                continue
            writers.append(writer)
            if tuple(bonus_key) == own[1:]:
                clashing = [self.intrinsic_reward_key]
                if has_kept_reward:
                    clashing.append(self.extrinsic_reward_key)
                raise self._clash_error(
                    clashing, f"{writer}, applied to this batch before,"
                )
        if writers and has_kept_reward:
            raise self._clash_error(
                [self.extrinsic_reward_key],
                f"{', '.join(writers)}, applied to this batch before,",
            )

    def _mix(
        self,
        next_tensordict: TensorDictBase,
        bonus: torch.Tensor,
        reward: torch.Tensor | None,
        previous: torch.Tensor | None,
        time_dim: int | None,
    ) -> TensorDictBase:
        """Writes the bonus, its normalised and weighted forms, and the mixed reward."""
        if bonus.shape != next_tensordict.batch_size:
            raise ValueError(
                f"{type(self).__name__}: the bonus model returned shape "
                f"{tuple(bonus.shape)}, expected one bonus per transition, "
                f"{tuple(next_tensordict.batch_size)}."
            )
        if not torch.isfinite(bonus).all():
            raise ValueError(
                f"{type(self).__name__}: the bonus model produced NaN or inf; its "
                "parameters may have diverged."
            )
        shape = reward.shape if reward is not None else (*bonus.shape, 1)
        dtype = reward.dtype if reward is not None else torch.float32
        bonus = bonus.reshape(shape).to(dtype)
        normalized = self._normalize(bonus, time_dim)
        coef = self.current_coef()
        if self._updating and self.count_frames:
            self.frames += next_tensordict.numel()
        next_tensordict.set(self.intrinsic_reward_key, bonus)
        if self.normalized_reward_key is not None:
            next_tensordict.set(self.normalized_reward_key, normalized)
        if reward is not None:
            weighted = coef * normalized
            if previous is None:
                next_tensordict.set(self.extrinsic_reward_key, reward)
                mixed = reward + weighted
            else:
                # Only this bonus changes: the others' contributions stay in.
                mixed = reward - previous + weighted
            next_tensordict.set(self.contribution_key, weighted)
            next_tensordict.set(self.reward_key, mixed)
        return next_tensordict

    def _step(
        self, tensordict: TensorDictBase, next_tensordict: TensorDictBase
    ) -> TensorDictBase:
        """The env path: the bonus of one step of every env."""
        reward, previous = self._received_reward(next_tensordict)
        with torch.no_grad():
            bonus = self._compute_bonus(tensordict, next_tensordict)
        return self._mix(next_tensordict, bonus, reward, previous, None)

    def _time_dim(self, tensordict: TensorDictBase) -> int | None:
        """The batch's time dimension (non-negative), or ``None`` without one."""
        time_dim = self.time_dim
        if time_dim is None:
            names = tensordict.names if tensordict._has_names() else None
            if names is not None and "time" in names:
                time_dim = names.index("time")
        if time_dim is None:
            if self.normalization == "return_std":
                raise ValueError(
                    f"{type(self).__name__}: normalization='return_std' on a batch "
                    "needs a time dimension: name it 'time' (collectors do) or pass "
                    "time_dim."
                )
            return None
        if not -tensordict.ndim <= time_dim < tensordict.ndim:
            raise ValueError(
                f"{type(self).__name__}: time_dim={time_dim} is not a dimension of "
                f"a batch of shape {tuple(tensordict.batch_size)}."
            )
        return time_dim % tensordict.ndim

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
        reward, previous = self._received_reward(next_tensordict)
        with torch.no_grad():
            bonus = self._compute_batch_bonus(tensordict, next_tensordict, time_dim)
        next_tensordict = self._mix(next_tensordict, bonus, reward, previous, time_dim)
        tensordict.set("next", next_tensordict)
        return tensordict

    # ---------------------------------------------------------------- specs
    def transform_reward_spec(self, reward_spec: Composite) -> Composite:
        """Declares the bonus entries (and the kept extrinsic reward) as rewards.

        Raises if the parent env already has one of them (another bonus
        transform, in a nested env or in batched-env workers, or the env itself
        writes it): this transform would overwrite it.
        """
        existing = set(reward_spec.keys(True, True))
        in_keys = {unravel_key(key) for key in self.in_keys}
        clashing = [
            key
            for key in self._written_reward_keys()
            # A precomputed bonus may be read from, and rewritten to, its own key.
            if key in existing and key not in in_keys
        ]
        if clashing:
            raise self._clash_error(clashing, "the parent env")
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
            if key == self.extrinsic_reward_key:
                continue
            if isinstance(key, tuple):
                # Intermediate entries (the contributions group) take the
                # parent's batch shape, as every entry of a reward spec.
                for depth in range(1, len(key)):
                    if key[:depth] not in reward_spec.keys(True):
                        reward_spec[key[:depth]] = Composite(
                            shape=reward_spec.shape, device=device
                        )
            reward_spec[key] = Unbounded(shape=shape, device=device, dtype=dtype)
        return reward_spec

    def _check_batched_worker_compat(self) -> None:
        # TorchRL's hook: SerialEnv and ParallelEnv call it, in the main process
        # where a warning is seen, on the transforms of their worker envs when
        # they are built.
        warnings.warn(
            WorkerCopyWarning(
                f"{type(self).__name__} is inside the env of a SerialEnv/ParallelEnv "
                "worker: each worker keeps its own copies of its normalisation "
                "statistics and frame counter and, in a ParallelEnv, of its bonus "
                "model, which training in the main process never updates. Put it on "
                "the outer env, TransformedEnv(ParallelEnv(...), transform), or apply "
                "it to collected batches with transform(batch)."
            ),
            stacklevel=2,
        )

    def __repr__(self) -> str:
        return (
            f"{type(self).__name__}(in_keys={self.in_keys}, "
            f"intrinsic_reward_key={self.intrinsic_reward_key!r}, "
            f"reward_key={self.reward_key!r}, coef={self.coef}, "
            f"normalization={self.normalization!r})"
        )
