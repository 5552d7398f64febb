"""NovelD's bonus (Zhang et al. 2021) on the shared base."""

from __future__ import annotations

from collections.abc import Sequence

import torch
from tensordict import TensorDictBase
from tensordict.utils import NestedKey, unravel_key

from torchrl_surprise.modules.rnd import RNDModel
from torchrl_surprise.transforms.base import IntrinsicRewardTransform
from torchrl_surprise.transforms.episodic import EpisodicVisits

__all__ = ["NovelDTransform"]


class NovelDTransform(IntrinsicRewardTransform):
    """NovelD: the novelty gained by a transition, paid on first visits only.

    ``r_int(s, s') = max(novelty(s') - alpha * novelty(s), 0) * 1[s' is visited
    for the first time in this episode]``

    (Zhang et al. 2021, "NovelD: A Simple yet Effective Exploration Criterion";
    ``alpha = 0.5`` is the paper's). ``novelty`` is RND's error,
    ``||predictor(s) - target(s)||_2``, of an
    :class:`~torchrl_surprise.modules.RNDModel` whose predictor
    :class:`~torchrl_surprise.objectives.RNDDistillationLoss` trains. The
    difference pays crossing from explored to unexplored states (the boundary),
    not lingering in the unexplored; the indicator pays each state once per
    episode.

    The indicator compares exact observations: the bytes of ``visit_keys``
    (default: ``in_keys``). NovelD's MiniGrid runs count the agent's full state;
    the library's MiniGrid envs give the agent its egocentric 7x7 view and
    direction, and by default that is what is counted: the same observation the
    policy and RND see, available from every env without privileged state. Two
    places that look alike from the agent's view count as one (the second earns
    no bonus in that episode); pass ``visit_keys`` to count another key (the
    agent's position, where an env exposes it).

    The seen observations are kept per env in ``visits``, an
    :class:`~torchrl_surprise.transforms.EpisodicVisits` saved by ``state_dict``
    (a resumed run continues its episodes). In an env (``_step``) it advances
    one step of every env and restarts an env's set when it is done or reset;
    on a batch (``forward``) it walks the dimension named ``"time"`` (or
    ``time_dim``) and restarts after each ``done``. A batch that is not
    time-ordered (a replay-buffer sample) is refused. Call
    :meth:`reset_episodes` before recomputing the bonus of a batch already seen.

    A subclass may take another novelty model: it sets :attr:`model_attr`, the
    attribute that holds the model (its ``state_dict`` prefix), and the model
    gives ``novelty(*observations)`` and ``in_keys``
    (:class:`~torchrl_surprise.transforms.VAENovelDTransform`: the VAE's
    negative ELBO or its KL).

    Args:
        rnd (RNDModel): the target and predictor (shared with the loss).
        in_keys (sequence of NestedKey, optional): observation keys, in the order
            the networks take them. Defaults to ``rnd.in_keys``.

    Keyword Args:
        alpha (float): the weight of ``novelty(s)`` (NovelD: 0.5).
        visit_keys (sequence of NestedKey, optional): the keys whose exact values
            make a state for the first-visit indicator. Defaults to ``in_keys``.
        done_key (NestedKey): the ``"next"`` entry that ends an episode.
        **kwargs: see :class:`~torchrl_surprise.transforms.IntrinsicRewardTransform`.

    Examples:
        >>> import torch
        >>> from torchrl.envs import TransformedEnv
        >>> from torchrl.testing.mocking_classes import ContinuousActionVecMockEnv
        >>> from torchrl_surprise.modules import RNDModel
        >>> rnd = RNDModel.for_vector(7, embedding_dim=8, hidden_dim=16)
        >>> env = TransformedEnv(ContinuousActionVecMockEnv(),
        ...                      NovelDTransform(rnd, coef=0.1))
        >>> rollout = env.rollout(4)
        >>> bool((rollout["next", "intrinsic_reward"] >= 0).all())
        True
        >>> env.transform.reset_episodes()  # the batch path gives the same bonus
        >>> again = env.transform(rollout.clone())
        >>> torch.allclose(again["next", "intrinsic_reward"],
        ...                rollout["next", "intrinsic_reward"])
        True
    """

    #: The attribute that holds the novelty model (its ``state_dict`` prefix).
    model_attr = "rnd"

    def __init__(
        self,
        rnd: RNDModel,
        in_keys: Sequence[NestedKey] | None = None,
        *,
        alpha: float = 0.5,
        visit_keys: Sequence[NestedKey] | None = None,
        done_key: NestedKey = "done",
        **kwargs,
    ):
        if in_keys is None:
            in_keys = rnd.in_keys
        if not 0.0 <= alpha:
            raise ValueError(f"alpha must be non-negative, got {alpha}.")
        super().__init__(in_keys, **kwargs)
        if visit_keys is None:
            visit_keys = self.in_keys
        elif isinstance(visit_keys, str):
            visit_keys = [visit_keys]
        if not visit_keys:
            raise ValueError(f"{type(self).__name__}: visit_keys must not be empty.")
        setattr(self, self.model_attr, rnd)
        self.alpha = float(alpha)
        self.visit_keys = [unravel_key(key) for key in visit_keys]
        self.done_key = unravel_key(done_key)
        self.visits = EpisodicVisits()

    def reset_episodes(self) -> None:
        """Forgets every episode in progress (their states count as unseen)."""
        self.visits.reset()

    def _reset(self, tensordict, tensordict_reset):
        self.visits.reset_from(tensordict)
        return tensordict_reset

    def _inputs(self, tensordict: TensorDictBase, next_tensordict: TensorDictBase):
        """The done flags and the visit keys of ``s`` and ``s'``."""
        done = self._episode_ends(next_tensordict, self.done_key)
        if done is None:
            done = torch.zeros(next_tensordict.batch_size, dtype=torch.bool)
        where, where_next = "the root tensordict (s_t)", "the 'next' tensordict"
        visits = self._observations(tensordict, where, self.visit_keys)
        next_visits = self._observations(next_tensordict, where_next, self.visit_keys)
        return done, visits, next_visits

    def novelty(self, *observations: torch.Tensor) -> torch.Tensor:
        """``novelty(s)`` per state, ``[...]``: the model's ``novelty``."""
        return getattr(self, self.model_attr).novelty(*observations)

    def _novelty_gain(
        self, tensordict: TensorDictBase, next_tensordict: TensorDictBase
    ) -> torch.Tensor:
        """``max(novelty(s') - alpha * novelty(s), 0)``, one model pass for both."""
        obs = self._observations(tensordict, "the root tensordict (s_t)")
        next_obs = self._observations(next_tensordict, "the 'next' tensordict")
        if all(o.shape == n.shape for o, n in zip(obs, next_obs, strict=True)):
            stacked = [torch.stack([o, n]) for o, n in zip(obs, next_obs, strict=True)]
            novelty, next_novelty = self.novelty(*stacked).unbind(0)
        else:
            novelty, next_novelty = self.novelty(*obs), self.novelty(*next_obs)
        return (next_novelty - self.alpha * novelty).clamp_min(0.0)

    def _compute_bonus(
        self, tensordict: TensorDictBase, next_tensordict: TensorDictBase
    ) -> torch.Tensor:
        # The env path: one step of every env.
        done, visits, next_visits = self._inputs(tensordict, next_tensordict)
        gain = self._novelty_gain(tensordict, next_tensordict)
        first = self.visits.step(visits, next_visits, done)
        return gain * first.to(gain.device, gain.dtype)

    def _compute_batch_bonus(
        self,
        tensordict: TensorDictBase,
        next_tensordict: TensorDictBase,
        time_dim: int | None,
    ) -> torch.Tensor:
        time_dim = self._require_time_dim(time_dim)
        done, visits, next_visits = self._inputs(tensordict, next_tensordict)
        gain = self._novelty_gain_along(tensordict, next_tensordict, done, time_dim)
        first = self.visits.walk(visits, next_visits, done, time_dim)
        return gain * first.to(gain.device, gain.dtype)

    def _novelty_gain_along(
        self,
        tensordict: TensorDictBase,
        next_tensordict: TensorDictBase,
        done: torch.Tensor,
        time_dim: int,
    ) -> torch.Tensor:
        """:meth:`_novelty_gain` of a trajectory batch, each state scored once.

        ``s_t`` is ``s'_{t-1}`` but where ``t = 0`` or an episode ended at
        ``t - 1``: its novelty is read from the previous step's ``s'`` (the
        model scores each state on its own, so the value is the same), and only
        the other states go through the model with the ``s'``. Where the
        observations say otherwise (a transform that rewrites them between
        steps), every state is scored, as on the env path.
        """
        obs = self._observations(tensordict, "the root tensordict (s_t)")
        next_obs = self._observations(next_tensordict, "the 'next' tensordict")
        dims = len(next_tensordict.batch_size)
        time_dim = time_dim % dims
        if any(o.shape != n.shape for o, n in zip(obs, next_obs, strict=True)):
            return self._novelty_gain(tensordict, next_tensordict)
        # carried[..., t]: s_t is s'_{t-1}
        carried = torch.zeros_like(done).movedim(time_dim, -1)
        carried[..., 1:] = ~done.movedim(time_dim, -1)[..., :-1]
        carried = carried.movedim(-1, time_dim)

        def previous(x: torch.Tensor) -> torch.Tensor:
            # x at t - 1, along the time dim (row 0 is never read)
            return x.roll(1, dims=time_dim)

        if not all(
            torch.equal(o[carried], previous(n)[carried])
            for o, n in zip(obs, next_obs, strict=True)
        ):
            return self._novelty_gain(tensordict, next_tensordict)
        fresh = [o[~carried] for o in obs]
        scored = self.novelty(
            *(
                torch.cat([n.reshape(-1, *n.shape[dims:]), f])
                for n, f in zip(next_obs, fresh, strict=True)
            )
        )
        next_novelty = scored[: done.numel()].reshape(done.shape)
        novelty = previous(next_novelty).clone()
        novelty[~carried] = scored[done.numel() :]
        return (next_novelty - self.alpha * novelty).clamp_min(0.0)
