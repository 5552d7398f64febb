"""Per-env episodic memories shared by the episodic bonuses.

An episodic bonus depends on what the agent has seen since its episode began,
so it keeps one memory per env. Both memories here are modules: their state is
part of the owning transform's ``state_dict`` (a resumed run continues its
episodes), they restart the envs whose episode ends, and they advance either by
one step of every env (:meth:`step`, an env's ``_step``) or along the time
dimension of a collected batch (:meth:`walk`, ``forward``).

* :class:`EllipticalEpisodicMemory`: ``C^{-1}`` with ``C = ridge * I + sum phi
  phi^T`` over the episode, for E3B's elliptical bonus
  (:class:`~torchrl_surprise.transforms.E3BTransform`,
  :class:`~torchrl_surprise.transforms.VAEEllipticalTransform`).
* :class:`EpisodicVisits`: the exact observations seen in the episode, for
  NovelD's first-visit indicator
  (:class:`~torchrl_surprise.transforms.NovelDTransform`).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np
import torch
from tensordict import TensorDictBase
from torch import nn

__all__ = [
    "EllipticalEpisodicMemory",
    "EpisodicMemory",
    "EpisodicVisits",
]


def checked_flag(name: str, value) -> bool:
    """``value`` if it is a bool, else a ``TypeError`` naming ``name``."""
    if not isinstance(value, bool):
        raise TypeError(
            f"{name} must be a bool, got {value!r} ({type(value).__name__})."
        )
    return value


def embed_where(
    embed: Callable[..., torch.Tensor],
    observations: Sequence[torch.Tensor],
    mask: torch.Tensor,
    dim: int,
) -> torch.Tensor:
    """``embed`` of the observations where ``mask`` is set, zeros elsewhere.

    For the states that begin an episode (a few in a batch): only those are
    embedded.

    Args:
        embed (callable): ``[n, ...]`` observations (one tensor per key) to
            ``[n, dim]`` embeddings.
        observations (sequence of torch.Tensor): ``[*batch, ...]`` each.
        mask (torch.Tensor): bool ``[*batch]``.
        dim (int): the embeddings' size.

    Returns:
        ``[*batch, dim]``, in the embeddings' dtype.

    Examples:
        >>> import torch
        >>> obs = torch.arange(6.0).reshape(3, 2)
        >>> embed_where(lambda o: o * 10, [obs], torch.tensor([False, True, False]), 2)
        tensor([[ 0.,  0.],
                [20., 30.],
                [ 0.,  0.]])
    """
    with torch.no_grad():
        chosen = embed(*(obs[mask] for obs in observations))
    out = chosen.new_zeros(*mask.shape, dim)
    out[mask] = chosen
    return out


class EpisodicMemory(nn.Module):
    """What an episodic bonus remembers of each env's current episode.

    Subclasses define :attr:`env_shape`, :meth:`reset` and :meth:`restart`;
    :meth:`reset_from` serves a transform's ``_reset``. Each copy of a bonus
    transform (``clone()``, ``frozen_copy()``) gets its own copy of its
    memories, so evaluating a frozen copy on other envs leaves the training
    episodes alone.
    """

    @property
    def env_shape(self) -> torch.Size | None:
        """The shape of the envs followed, ``None`` before the first call."""
        raise NotImplementedError

    def reset(self) -> None:
        """Forgets every episode in progress."""
        raise NotImplementedError

    def restart(self, mask: torch.Tensor) -> None:
        """The envs where ``mask`` (shape :attr:`env_shape`) is set start afresh."""
        raise NotImplementedError

    def reset_from(self, tensordict: TensorDictBase | None) -> None:
        """Restarts the envs an env ``_reset`` call resets (all without a mask)."""
        if self.env_shape is None:
            return
        mask = None if tensordict is None else tensordict.get("_reset", None)
        if mask is None:
            self.reset()
        else:
            self.restart(mask.reshape(self.env_shape).bool())


class EllipticalEpisodicMemory(EpisodicMemory):
    """``C^{-1}`` per env, ``C = ridge * I + sum over the episode of phi phi^T``.

    The elliptical bonus of an embedding ``phi`` is ``phi^T C^{-1} phi`` with
    ``C`` built from the embeddings seen *before* it in the episode; ``phi``
    then joins ``C`` (a Sherman-Morrison rank-one update of the inverse). The
    inverse is kept in float64 so that long episodes of rank-one updates stay
    accurate. Its shape is that of the envs it follows, set by the first call.

    Args:
        dim (int): size of the embeddings.
        ridge (float): ``lambda`` of ``C``'s ``lambda * I`` (E3B: 0.1).

    Examples:
        >>> import torch
        >>> memory = EllipticalEpisodicMemory(dim=2, ridge=0.1)
        >>> phi = torch.tensor([[1.0, 0.0], [0.0, 1.0]])  # two envs
        >>> memory.step(phi)  # 1 / ridge: nothing seen yet
        tensor([10., 10.], dtype=torch.float64)
        >>> memory.step(phi)  # seen once: 1 / (ridge + 1) ... less novel
        tensor([0.9091, 0.9091], dtype=torch.float64)
        >>> memory.restart(torch.tensor([True, False]))
        >>> memory.step(phi)
        tensor([10.0000,  0.4762], dtype=torch.float64)
    """

    def __init__(self, dim: int, ridge: float = 0.1):
        super().__init__()
        if not ridge > 0:
            raise ValueError(f"ridge must be positive, got {ridge}.")
        self.dim = int(dim)
        self.ridge = float(ridge)
        self.register_buffer("inv_cov", torch.zeros(0, dtype=torch.float64))
        # The envs whose episode has no state in ``C`` yet (restarted, or never
        # followed): there an episode's first state may join ``C`` before the
        # bonus of its next one (``start`` of :meth:`step` and :meth:`walk`).
        self.register_buffer("awaiting", torch.zeros(0, dtype=torch.bool))

    @property
    def env_shape(self) -> torch.Size | None:
        """The shape of the envs followed, ``None`` before the first call."""
        return self.inv_cov.shape[:-2] if self.inv_cov.numel() else None

    def reset(self) -> None:
        """Forgets every episode in progress."""
        self.inv_cov = torch.zeros(0, dtype=torch.float64, device=self.inv_cov.device)
        self.awaiting = torch.zeros(0, dtype=torch.bool, device=self.inv_cov.device)

    def _fresh(self, env_shape, device) -> torch.Tensor:
        eye = torch.eye(self.dim, dtype=torch.float64, device=device)
        return (eye / self.ridge).expand(*env_shape, -1, -1).clone()

    def _memory(self, env_shape, device) -> torch.Tensor:
        if self.env_shape is None:
            self.inv_cov = self._fresh(env_shape, device)
            self.awaiting = torch.ones(env_shape, dtype=torch.bool, device=device)
        elif self.env_shape != env_shape:
            raise ValueError(
                f"{type(self).__name__}: it follows episodes of "
                f"{tuple(self.env_shape)} envs, this batch has {tuple(env_shape)}; "
                "call reset_episodes() to start afresh."
            )
        return self.inv_cov

    def restart(self, mask: torch.Tensor) -> None:
        """The envs where ``mask`` (shape :attr:`env_shape`) is set start afresh."""
        if self.env_shape is None or not mask.any():
            return
        mask = mask.reshape(self.env_shape)
        self.inv_cov = torch.where(
            mask[..., None, None],
            self._fresh(self.env_shape, self.inv_cov.device),
            self.inv_cov,
        )
        self.awaiting = self.awaiting | mask

    def _check(self, phi: torch.Tensor) -> None:
        if phi.shape[-1:] != (self.dim,):
            raise ValueError(
                f"{type(self).__name__}: expected embeddings of size {self.dim}, "
                f"got shape {tuple(phi.shape)}."
            )

    def pending(self, env_shape: torch.Size) -> torch.Tensor:
        """The envs (``[*env_shape]``) whose episode has no state in ``C`` yet.

        Every env before the first call and after :meth:`reset`; an env after
        its episode ends (:meth:`restart`, or ``done`` in :meth:`step` and
        :meth:`walk`).
        """
        if self.env_shape is None or self.env_shape != env_shape:
            return torch.ones(env_shape, dtype=torch.bool, device=self.inv_cov.device)
        return self.awaiting.clone()

    def pending_starts(self, done: torch.Tensor, time_dim: int) -> torch.Tensor:
        """Where the states ``s_t`` of a time-ordered batch begin an episode.

        ``done`` is ``[*batch]``; ``s_t`` begins one where the env's memory
        awaits its first state (``t = 0``, :meth:`pending`) or where the
        transition before ended one. Those are the places :meth:`walk`'s
        ``start`` is read.
        """
        moved = done.movedim(time_dim, -1)
        starts = torch.zeros_like(moved)
        if not moved.shape[-1]:  # no time step
            return starts.movedim(-1, time_dim)
        starts[..., 0] = self.pending(moved.shape[:-1])
        starts[..., 1:] = moved[..., :-1]
        return starts.movedim(-1, time_dim)

    def _take_in(
        self, inv: torch.Tensor, start: torch.Tensor, mask: torch.Tensor
    ) -> torch.Tensor:
        """``inv`` (``[envs, dim, dim]``) with ``start`` (``[envs, dim]``) joined
        where ``mask`` (``[envs]``) is set."""
        if not mask.any():
            return inv
        u = start[mask].to(torch.float64)
        rows = inv[mask]
        inv_u = (rows @ u.unsqueeze(-1)).squeeze(-1)
        denominator = (1.0 + (u * inv_u).sum(-1))[..., None, None]
        inv = inv.clone()
        inv[mask] = rows - inv_u.unsqueeze(-1) * inv_u.unsqueeze(-2) / denominator
        return inv

    def step(
        self,
        phi: torch.Tensor,
        done: torch.Tensor | None = None,
        start: torch.Tensor | None = None,
    ) -> torch.Tensor:
        """The bonus of one step of every env, then ``C += phi phi^T``.

        Args:
            phi (torch.Tensor): ``[*envs, dim]``.
            done (torch.Tensor, optional): ``[*envs]``; where set, the env
                starts a new episode after this step.
            start (torch.Tensor, optional): ``[*envs, dim]``, the embedding of
                the state each env steps from; where the env's episode has no
                state in ``C`` yet (:meth:`pending`) it joins ``C`` first, and
                earns no bonus (E3B's episode start). Read nowhere else.

        Returns:
            The bonus, ``[*envs]``, in float64.
        """
        self._check(phi)
        inv = self._memory(phi.shape[:-1], phi.device)
        if start is not None:
            self._check(start)
            flat = inv.reshape(-1, self.dim, self.dim)
            flat = self._take_in(
                flat, start.reshape(-1, self.dim), self.awaiting.reshape(-1)
            )
            inv = flat.reshape(inv.shape)
        u = phi.to(torch.float64)
        inv_u = (inv @ u.unsqueeze(-1)).squeeze(-1)
        bonus = (u * inv_u).sum(-1)
        # Sherman-Morrison: (C + u u^T)^-1 = C^-1 - C^-1 u u^T C^-1 / (1 + u^T C^-1 u)
        self.inv_cov = (
            inv
            - inv_u.unsqueeze(-1) * inv_u.unsqueeze(-2) / (1.0 + bonus)[..., None, None]
        )
        self.awaiting = torch.zeros_like(self.awaiting)
        if done is not None:
            self.restart(done)
        return bonus

    def walk(
        self,
        phi: torch.Tensor,
        done: torch.Tensor | None,
        time_dim: int,
        start: torch.Tensor | None = None,
    ) -> torch.Tensor:
        """The bonus of every step of a time-ordered batch, walking ``time_dim``.

        Equal (up to float64 rounding) to :meth:`step` called on each time step
        in turn, but computed :attr:`chunk` steps at a time without a Python
        loop over them: with ``M = I + G``, ``G[i, j] = phi_i^T A phi_j`` for
        steps ``i, j`` of one episode (``A`` the inverse that episode starts
        from: the memory, or ``(ridge * I + p p^T)^{-1}`` for an episode that
        starts in the chunk from a state ``p``) and 0 across episodes, the
        bonus of step ``t`` is ``L[t, t]^2 - 1`` for the Cholesky factor ``L``
        of ``M`` (the Schur complement of ``M``'s leading block is
        ``1 + phi_t^T C_t^{-1} phi_t``, by Woodbury's identity), and the memory
        after the chunk is a Woodbury update of ``A`` with the last episode's
        steps.

        Args:
            phi (torch.Tensor): ``[*batch, dim]``, ``batch`` holding ``time_dim``.
            done (torch.Tensor, optional): ``[*batch]``.
            time_dim (int): the time dimension of ``batch`` (non-negative).
            start (torch.Tensor, optional): ``[*batch, dim]``, the embedding of
                the state each step leaves; read where it begins an episode
                (:meth:`pending_starts`), which joins ``C`` first and earns no
                bonus, as in :meth:`step`.

        Returns:
            The bonus, ``[*batch]``, in float64.
        """
        self._check(phi)
        phi = phi.movedim(time_dim, -2)
        env_shape, steps = phi.shape[:-2], phi.shape[-2]
        if done is None:
            done = torch.zeros(phi.shape[:-1], dtype=torch.bool, device=phi.device)
        else:
            done = done.movedim(time_dim, -1)
        if steps == 0:
            return phi.new_zeros(phi.shape[:-1], dtype=torch.float64).movedim(
                -1, time_dim
            )
        inv = self._memory(env_shape, phi.device).reshape(-1, self.dim, self.dim)
        phi = phi.reshape(-1, steps, self.dim).to(torch.float64)
        done = done.reshape(-1, steps)
        if start is not None:
            self._check(start)
            start = start.movedim(time_dim, -2).reshape(-1, steps, self.dim)
            start = start.to(torch.float64)
        awaiting = self.awaiting.reshape(-1)
        bonuses = []
        for first in range(0, steps, self.chunk):
            stop = first + self.chunk
            if start is not None:
                inv = self._take_in(inv, start[:, first], awaiting)
            chunk_start = None if start is None else start[:, first:stop]
            bonus, inv = self._walk_chunk(
                inv, phi[:, first:stop], done[:, first:stop], chunk_start
            )
            bonuses.append(bonus)
            awaiting = done[:, min(stop, steps) - 1]
        self.inv_cov = inv.reshape(*env_shape, self.dim, self.dim)
        self.awaiting = awaiting.reshape(env_shape).clone()
        bonus = torch.cat(bonuses, -1).reshape(*env_shape, steps)
        return bonus.movedim(-1, time_dim)

    #: Time steps per Cholesky factorisation in :meth:`walk`: its cost grows as
    #: ``chunk^3``, the Python loop's as ``steps / chunk``.
    chunk = 128

    def _episode_starts(
        self, start: torch.Tensor | None, done: torch.Tensor, episode: torch.Tensor
    ) -> torch.Tensor | None:
        """``q`` ``[envs, K, dim]`` with ``q q^T = p p^T / (ridge (ridge + |p|^2))``
        for ``p`` the first state of each step's episode (0 in episode 0, whose
        first state is already in the memory): ``(ridge I + p p^T)^{-1} = I /
        ridge - q q^T``, the inverse an episode that starts in the chunk begins
        from."""
        if start is None:
            return None
        steps = done.shape[1]
        begins = torch.zeros_like(done)
        begins[:, 1:] = done[:, :-1]
        time = torch.arange(steps, device=done.device).expand_as(done)
        first = torch.where(begins, time, 0).cummax(1).values
        p = start.gather(1, first.unsqueeze(-1).expand_as(start))
        p = p * (episode > 0).unsqueeze(-1)
        return p / (self.ridge * (self.ridge + p.pow(2).sum(-1, keepdim=True))).sqrt()

    def _walk_chunk(
        self,
        inv: torch.Tensor,
        phi: torch.Tensor,
        done: torch.Tensor,
        start: torch.Tensor | None = None,
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """Bonuses ``[envs, K]`` of ``phi`` ``[envs, K, dim]`` and the memory after."""
        steps = phi.shape[1]
        # The episode of each step, counted from the chunk's first: 0 continues
        # the memory ``inv``, later ones start from ``I / ridge`` (less ``q q^T``
        # where their first state joins the memory).
        episode = done.long().cumsum(1) - done.long()
        inv_phi = phi @ inv  # rows A phi_i (A symmetric)
        fresh_phi = phi / self.ridge
        q = self._episode_starts(start, done, episode)
        if q is not None:
            fresh_phi = fresh_phi - q * (q * phi).sum(-1, keepdim=True)
        continues = episode == 0
        gram = torch.where(
            continues[:, :, None] & continues[:, None, :],
            inv_phi @ phi.transpose(1, 2),
            fresh_phi @ phi.transpose(1, 2),
        )
        gram = gram * (episode[:, :, None] == episode[:, None, :])
        eye = torch.eye(steps, dtype=phi.dtype, device=phi.device)
        factor = torch.linalg.cholesky(gram + eye)
        bonus = factor.diagonal(dim1=-2, dim2=-1).pow(2) - 1.0
        # The memory after the chunk: the last episode's steps (none if it ended
        # on the chunk's last step) added to the inverse that episode started from.
        last = episode[:, -1] + done[:, -1].long()
        in_last = (episode == last[:, None]).unsqueeze(-1)
        last_continues = (last == 0)[:, None, None]
        u = torch.where(last_continues, inv_phi, fresh_phi) * in_last
        # inv - u^T M^-1 u where the last episode continues the memory, I / ridge
        # (- q q^T) - u^T M^-1 u where it starts afresh: in place, through a
        # product buffer kept between calls (the memory is envs x dim^2 float64,
        # 128 MiB for E3B's 16 x 1024^2; a new one a call would cost more than the
        # products).
        prod = self._product_buffer(inv)
        torch.matmul(u.transpose(1, 2), torch.cholesky_solve(u, factor), out=prod)
        fresh = ~last_continues.view(-1)
        inv = inv.sub_(prod)
        if fresh.any():
            begun = self._fresh((), phi.device) - prod[fresh]
            if q is not None:
                # The last step's q is its episode's, the last one's unless that
                # episode ended there (then it has no state yet).
                q_last = (q[:, -1] * ~done[:, -1, None])[fresh]
                begun = begun - q_last.unsqueeze(-1) * q_last.unsqueeze(-2)
            inv[fresh] = begun
        return bonus, inv

    def _product_buffer(self, inv: torch.Tensor) -> torch.Tensor:
        """A buffer of ``inv``'s shape for the memory's update (not saved, not
        copied with the module)."""
        buffer = self.__dict__.get("_product")
        if buffer is None or buffer.shape != inv.shape or buffer.device != inv.device:
            buffer = torch.empty_like(inv)
            self.__dict__["_product"] = buffer
        return buffer

    def __getstate__(self):
        state = super().__getstate__()
        state = dict(state)
        state.pop("_product", None)
        return state

    def _load_from_state_dict(self, state_dict, prefix, *args, **kwargs):
        # The memory takes the shape of the envs it follows.
        inv = state_dict.get(prefix + "inv_cov")
        if inv is not None:
            self.inv_cov = torch.zeros_like(inv)
            # A state_dict from before ``awaiting`` was kept: its episodes are
            # under way (an empty memory awaits every env, as a new one).
            awaiting = torch.zeros(inv.shape[:-2], dtype=torch.bool, device=inv.device)
            if not inv.numel():
                awaiting = torch.zeros(0, dtype=torch.bool, device=inv.device)
            state_dict.setdefault(prefix + "awaiting", awaiting)
            self.awaiting = torch.zeros_like(state_dict[prefix + "awaiting"])
        super()._load_from_state_dict(state_dict, prefix, *args, **kwargs)


class EpisodicVisits(EpisodicMemory):
    """The exact observations each env has seen in its current episode.

    An observation is the bytes of its tensors (one per key, in order), so two
    observations are the same state only if every byte is equal; no hash
    collision can merge two states. A transition ``s -> s'`` marks both as seen
    (``s`` is the first state of an episode the first time), so a state counts
    as visited from its first occurrence on, the episode's first state
    included. The sets are saved with ``state_dict``.

    Examples:
        >>> import torch
        >>> visits = EpisodicVisits()
        >>> s0, s1 = torch.tensor([[0, 0], [5, 5]]), torch.tensor([[0, 1], [5, 5]])
        >>> going = torch.tensor([False, False])
        >>> visits.step([s0], [s1], going)  # env 0 moves to a new state, env 1 stays
        tensor([ True, False])
        >>> visits.step([s1], [s0], torch.tensor([True, False]))  # env 0 is back
        tensor([False, False])
        >>> visits.step([s0], [s1], going)  # env 0 is in a new episode
        tensor([ True, False])
    """

    def __init__(self):
        super().__init__()
        self._seen: list[set[bytes]] = []
        self._env_shape: torch.Size | None = None

    @property
    def env_shape(self) -> torch.Size | None:
        """The shape of the envs followed, ``None`` before the first call."""
        return self._env_shape

    def reset(self) -> None:
        """Forgets every episode in progress."""
        self._seen = []
        self._env_shape = None

    def restart(self, mask: torch.Tensor) -> None:
        """The envs where ``mask`` (shape :attr:`env_shape`) is set start afresh."""
        if self._env_shape is None:
            return
        for env in mask.reshape(-1).nonzero().flatten().tolist():
            self._seen[env] = set()

    def _rows(self, observations: Sequence[torch.Tensor], env_shape) -> list[bytes]:
        """The bytes of each env's observation, in env order."""
        if self._env_shape is None:
            self._env_shape = torch.Size(env_shape)
            self._seen = [set() for _ in range(self._env_shape.numel())]
        elif self._env_shape != env_shape:
            raise ValueError(
                f"{type(self).__name__}: it follows episodes of "
                f"{tuple(self._env_shape)} envs, this batch has {tuple(env_shape)}; "
                "call reset_episodes() to start afresh."
            )
        n = self._env_shape.numel()
        if not n:  # a batch of no envs
            return []
        parts = [
            np.ascontiguousarray(obs.detach().cpu().numpy())
            .reshape(n, -1)
            .view(np.uint8)
            for obs in observations
        ]
        return [row.tobytes() for row in np.concatenate(parts, axis=1)]

    def step(
        self,
        observations: Sequence[torch.Tensor],
        next_observations: Sequence[torch.Tensor],
        done: torch.Tensor,
    ) -> torch.Tensor:
        """Whether each env's ``s'`` is seen for the first time in its episode.

        Args:
            observations (sequence of torch.Tensor): ``s`` of every env,
                ``[*envs, ...]`` each.
            next_observations (sequence of torch.Tensor): ``s'``, same shapes.
            done (torch.Tensor): ``[*envs]`` (its shape gives the envs); where
                set, the env starts a new episode after this step.

        Returns:
            A bool tensor ``[*envs]``.
        """
        rows = self._rows(observations, done.shape)
        next_rows = self._rows(next_observations, done.shape)
        first = []
        for seen, row, next_row in zip(self._seen, rows, next_rows, strict=True):
            seen.add(row)
            first.append(next_row not in seen)
            seen.add(next_row)
        self.restart(done)
        return torch.tensor(first, dtype=torch.bool).reshape(done.shape)

    def walk(
        self,
        observations: Sequence[torch.Tensor],
        next_observations: Sequence[torch.Tensor],
        done: torch.Tensor,
        time_dim: int,
    ) -> torch.Tensor:
        """:meth:`step` along ``time_dim`` of a time-ordered batch ``[*batch]``.

        ``done`` has the batch's shape (zeros where the batch has no done).
        """
        moved = [o.movedim(time_dim, 0) for o in observations]
        moved_next = [o.movedim(time_dim, 0) for o in next_observations]
        done = done.movedim(time_dim, 0)
        first = torch.zeros(done.shape, dtype=torch.bool)
        for t in range(done.shape[0]):
            first[t] = self.step(
                [o[t] for o in moved], [o[t] for o in moved_next], done[t]
            )
        return first.movedim(0, time_dim)

    def get_extra_state(self) -> dict:
        """The seen observations of every env (bytes), for ``state_dict``."""
        shape = None if self._env_shape is None else tuple(self._env_shape)
        return {"env_shape": shape, "seen": [sorted(seen) for seen in self._seen]}

    def set_extra_state(self, state: dict) -> None:
        shape = state["env_shape"]
        self._env_shape = None if shape is None else torch.Size(shape)
        self._seen = [set(seen) for seen in state["seen"]]
