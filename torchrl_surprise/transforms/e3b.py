"""E3B's elliptical episodic bonus (Henaff et al. 2022) on the shared base."""

from __future__ import annotations

from collections.abc import Sequence

import torch
from tensordict import TensorDictBase
from tensordict.utils import NestedKey, unravel_key

from torchrl_surprise.modules.e3b import E3BModel
from torchrl_surprise.transforms.base import IntrinsicRewardTransform
from torchrl_surprise.transforms.episodic import (
    EllipticalEpisodicMemory,
    checked_flag,
    embed_where,
)

__all__ = ["E3BTransform"]


class E3BTransform(IntrinsicRewardTransform):
    """Exploration via Elliptical Episodic Bonuses: ``phi(s')^T C^{-1} phi(s')``.

    With ``phi`` the inverse-dynamics embedding of an
    :class:`~torchrl_surprise.modules.E3BModel` (trained by
    :class:`~torchrl_surprise.objectives.InverseDynamicsLoss`) and
    ``C = ridge * I + sum phi phi^T`` over the states seen so far in the
    episode,

    ``r_int(s_{t+1}) = phi(s_{t+1})^T C^{-1} phi(s_{t+1})``

    then ``s_{t+1}`` joins ``C`` (Henaff et al. 2022, "Exploration via
    Elliptical Episodic Bonuses"). A state unlike every state of the episode so
    far, in what the agent controls, earns a high bonus; a state close to many
    of them a small one. ``ridge=0.1`` is the paper's.

    As in E3B's code, an episode's first state ``s_0`` joins ``C`` before
    ``s_1``'s bonus and earns none (``start_in_memory=True``): ``s_1`` then
    pays ``phi(s_1)^T (ridge I + phi(s_0) phi(s_0)^T)^{-1} phi(s_1)``, not
    ``|phi(s_1)|^2 / ridge``, which grows with the embedding's scale and would
    put the bonus at every episode's start.

    The memory is an
    :class:`~torchrl_surprise.transforms.EllipticalEpisodicMemory` per env,
    the one :class:`~torchrl_surprise.transforms.VAEEllipticalTransform` uses,
    saved by ``state_dict`` (a resumed run continues its episodes). In an env
    (``_step``) it advances one step of every env and restarts an env's memory
    when it is done or reset; on a batch (``forward``) it walks the dimension
    named ``"time"`` (or ``time_dim``) and restarts after each ``done``. A batch
    that is not time-ordered (a replay-buffer sample) is refused. Call
    :meth:`reset_episodes` before recomputing the bonus of a batch already seen.

    Args:
        model (E3BModel): the embedding (shared with ``InverseDynamicsLoss``).
        in_keys (sequence of NestedKey, optional): observation keys, in the order
            the model takes them. Defaults to ``model.in_keys``.

    Keyword Args:
        ridge (float): ``lambda`` of ``C``'s ``lambda * I`` (E3B: 0.1).
        start_in_memory (bool): an episode's first state joins ``C`` before
            the first bonus (E3B's code); ``False``: ``C`` starts from
            ``ridge * I``.
        done_key (NestedKey): the ``"next"`` entry that ends an episode.
        **kwargs: see :class:`~torchrl_surprise.transforms.IntrinsicRewardTransform`.

    Examples:
        >>> import torch
        >>> from torchrl.envs import TransformedEnv
        >>> from torchrl.testing.mocking_classes import ContinuousActionVecMockEnv
        >>> from torchrl_surprise.modules import E3BModel
        >>> base = ContinuousActionVecMockEnv()
        >>> model = E3BModel.for_vector(7, 7, embedding_dim=16, hidden_dim=16)
        >>> env = TransformedEnv(base, E3BTransform(model, coef=0.1))
        >>> rollout = env.rollout(4)
        >>> rollout["next", "intrinsic_reward"].shape
        torch.Size([4, 1])
        >>> env.transform.reset_episodes()  # the batch path gives the same bonus
        >>> again = env.transform(rollout.clone())
        >>> torch.allclose(again["next", "intrinsic_reward"],
        ...                rollout["next", "intrinsic_reward"])
        True
    """

    def __init__(
        self,
        model: E3BModel,
        in_keys: Sequence[NestedKey] | None = None,
        *,
        ridge: float = 0.1,
        start_in_memory: bool = True,
        done_key: NestedKey = "done",
        **kwargs,
    ):
        if in_keys is None:
            in_keys = model.in_keys
        memory = EllipticalEpisodicMemory(model.embedding_dim, ridge)
        super().__init__(in_keys, **kwargs)
        self.model = model
        self.memory = memory
        self.start_in_memory = checked_flag("start_in_memory", start_in_memory)
        self.done_key = unravel_key(done_key)

    @property
    def ridge(self) -> float:
        """``lambda`` of ``C``'s ``lambda * I``."""
        return self.memory.ridge

    def reset_episodes(self) -> None:
        """Forgets every episode in progress (their next states start afresh)."""
        self.memory.reset()

    def _reset(self, tensordict, tensordict_reset):
        self.memory.reset_from(tensordict)
        return tensordict_reset

    def _embedding(self, next_tensordict: TensorDictBase) -> torch.Tensor:
        observations = self._observations(next_tensordict, "the 'next' tensordict")
        return self.model.embed(*observations)

    def _starts(self, tensordict: TensorDictBase, mask: torch.Tensor):
        """The embeddings of the states that begin an episode (``mask``), or
        ``None`` when they do not join the memory."""
        if not self.start_in_memory:
            return None
        observations = self._observations(tensordict, "the root tensordict")
        return embed_where(
            self.model.embed, observations, mask, self.model.embedding_dim
        )

    def _compute_bonus(
        self, tensordict: TensorDictBase, next_tensordict: TensorDictBase
    ) -> torch.Tensor:
        # The env path: one step of every env.
        done = self._episode_ends(next_tensordict, self.done_key)
        phi = self._embedding(next_tensordict)
        start = self._starts(tensordict, self.memory.pending(phi.shape[:-1]))
        return self.memory.step(phi, done, start).to(phi.dtype)

    def _compute_batch_bonus(
        self,
        tensordict: TensorDictBase,
        next_tensordict: TensorDictBase,
        time_dim: int | None,
    ) -> torch.Tensor:
        time_dim = self._require_time_dim(time_dim)
        done = self._episode_ends(next_tensordict, self.done_key)
        phi = self._embedding(next_tensordict)
        if done is None:
            done = torch.zeros(phi.shape[:-1], dtype=torch.bool, device=phi.device)
        start = self._starts(tensordict, self.memory.pending_starts(done, time_dim))
        return self.memory.walk(phi, done, time_dim, start).to(phi.dtype)
