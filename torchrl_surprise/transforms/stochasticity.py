"""Injected stochasticity for MiniGrid: random action replacement and a noisy TV.

The paper's Figure 2 sweeps four levels of "stochasticity" on MultiRoom-N3S4 without
saying how the randomness was injected. :class:`StochasticityTransform` is our
definition; :data:`STOCHASTICITY_LEVELS` are our four levels.
"""

from __future__ import annotations

import numbers
from collections.abc import Sequence

import torch
from tensordict import NestedKey, TensorDictBase
from torchrl.data import Categorical, MultiCategorical, MultiOneHot, OneHot
from torchrl.envs import Transform

from torchrl_surprise.modules.vae import (
    MINIGRID_NUM_COLORS,
    MINIGRID_NUM_OBJECTS,
    MINIGRID_NUM_STATES,
)

__all__ = [
    "AGENT_CELL",
    "DEFAULT_NOISE_PATCH",
    "STOCHASTICITY_LEVELS",
    "STOCHASTICITY_LEVEL_NAMES",
    "StochasticityTransform",
]

AGENT_CELL: tuple[int, int] = (3, 6)
"""``(x, y)`` of the agent's own cell in MiniGrid's default 7x7 egocentric image.

MiniGrid's ``image[x, y]`` is column ``x`` (left to right in the agent's view) and
row ``y`` (``0`` farthest, ``6`` the agent's row): the agent sits at the bottom
centre, looking towards ``y = 0``.
"""

DEFAULT_NOISE_PATCH: tuple[tuple[int, int], ...] = tuple(
    (x, y) for x in range(3) for y in range(3)
)
"""The default noisy-TV patch: the 3x3 block in the far-left corner of the view.

Cells ``(x, y)`` with ``x, y in {0, 1, 2}``: far from the agent's cell
:data:`AGENT_CELL` and from the cell it faces, ``(3, 5)``, so the noise never hides
what the agent is about to interact with.
"""

STOCHASTICITY_LEVELS: dict[int, tuple[float, float]] = {
    0: (0.0, 0.0),
    1: (0.05, 0.1),
    2: (0.1, 0.3),
    3: (0.2, 0.5),
}
"""Level -> ``(action_noise, obs_noise)`` for the Figure 2 sweep (our choice).

The paper names no values. Level 1 ("mild") barely perturbs the task; level 2
("more") and level 3 ("most") make the noisy TV frequent enough to dominate a forward
model's error, while action noise of 10-20% still leaves the 60-step N3S4 task
solvable (a sticky agent loses a few steps per episode).
"""

STOCHASTICITY_LEVEL_NAMES: dict[str, int] = {"none": 0, "mild": 1, "more": 2, "most": 3}
"""Names accepted by :meth:`StochasticityTransform.from_level`."""

# Random patch values: every object a MiniGrid view can contain ("agent" never
# appears in the egocentric image), every colour and every door state.
_NOISE_HIGH = (
    MINIGRID_NUM_OBJECTS - 1,
    MINIGRID_NUM_COLORS,
    MINIGRID_NUM_STATES,
)


def _check_probability(name: str, value: float) -> float:
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise TypeError(f"{name} must be a real number in [0, 1], got {value!r}.")
    value = float(value)
    if not 0.0 <= value <= 1.0:
        raise ValueError(f"{name} must be in [0, 1], got {value}.")
    return value


def _check_patch(
    patch: Sequence[Sequence[int]], view_size: int
) -> tuple[tuple[int, int], ...]:
    try:
        cells = tuple((int(c[0]), int(c[1])) for c in patch if len(c) == 2)
        malformed = len(cells) != len(patch)
    except (TypeError, IndexError, ValueError):
        malformed = True
    if malformed:
        raise ValueError(
            f"patch must be a sequence of (x, y) integer pairs, got {patch!r}."
        )
    if not cells:
        raise ValueError("patch must contain at least one (x, y) cell.")
    outside = [
        c for c in cells if not (0 <= c[0] < view_size and 0 <= c[1] < view_size)
    ]
    if outside:
        raise ValueError(
            f"patch cells {outside} are outside the {view_size}x{view_size} image "
            f"(valid x and y are 0..{view_size - 1})."
        )
    if len(set(cells)) != len(cells):
        raise ValueError(f"patch contains repeated cells: {cells}.")
    return cells


class StochasticityTransform(Transform):
    """Injects stochasticity into MiniGrid: random action replacement and a noisy TV.

    Two independent knobs, each drawn independently per env and per step:

    * ``action_noise`` ``p``: with probability ``p`` the action *executed* by the env
      is replaced by one drawn uniformly from all actions (possibly the same one).
      This is done in the inverse path (on the copy of the input that TorchRL hands
      to the base env), so the tensordict keeps the agent's chosen action: the
      action whose log-probability a policy-gradient loss must use. The number of
      actions is read from the parent env's action spec (categorical or one-hot).
    * ``obs_noise`` ``q``: with probability ``q`` a fixed patch of cells of the
      7x7 egocentric ``"image"`` shows random (object, colour, state) ids, drawn
      uniformly and independently per cell: a noisy TV in a corner of the view. It
      applies to step and reset observations alike.

    Why these two. Action noise makes the dynamics stochastic (a "slippery" agent),
    which costs every method some steps; for ICM it also corrupts the labels of its
    inverse-dynamics model, since the recorded action is not always the executed
    one. The noisy TV is the classic failure case of prediction-error curiosity: a
    forward model cannot predict the patch, so wherever its features still encode
    the patch the ICM bonus stays high regardless of novelty (ICM's inverse-dynamics
    features are meant to discard what the agent cannot control; the TV tests how
    well they do). A VAE that encodes the state structure can learn that the patch
    is structureless noise carrying no information about the layout, which is the
    paper's argument for the VAE bonus. The patch does not depend on the agent's
    behaviour, so no policy can "watch" it more: differences between bonuses
    reflect how they treat unpredictability, not a trap the agent can exploit.

    Randomness comes from the transform's own ``torch.Generator``: the same seed and
    the same actions give the same noise. Seed it with ``seed=`` or
    :meth:`set_seed`; note that TorchRL 0.14's ``TransformedEnv.set_seed`` only
    seeds the base env, it does not reach transforms. With ``seed=None`` the
    generator is seeded from torch's global RNG at construction, so
    ``torch.manual_seed`` also makes it reproducible. The specs are unchanged. With
    both probabilities at 0 the transform is the identity and draws nothing.

    Args:
        action_noise: probability ``p`` in ``[0, 1]`` of replacing the executed
            action by a uniformly random one.
        obs_noise: probability ``q`` in ``[0, 1]`` that the noisy-TV patch shows
            random ids.

    Keyword Args:
        patch: the ``(x, y)`` cells of the image replaced by the noisy TV, with
            MiniGrid's convention ``image[x, y]`` (see :data:`AGENT_CELL`).
            Defaults to :data:`DEFAULT_NOISE_PATCH`, the far-left 3x3 corner.
        image_key: the image entry. Defaults to ``"image"``.
        action_key: the action entry. Defaults to ``"action"``.
        num_actions: number of discrete actions; only needed without a parent env
            (e.g. when calling :meth:`inv` on a hand-built tensordict).
        one_hot: whether actions are one-hot; only used without a parent env (with
            one, the encoding is read from its action spec). Defaults to ``False``.
        view_size: side of the egocentric image, used to validate ``patch``.
            Defaults to 7 (MiniGrid's ``agent_view_size``).
        seed: seed of the transform's generator (see above).

    Raises:
        ValueError: if a probability is outside ``[0, 1]`` or the patch is empty,
            malformed or outside the image.
        TypeError: if a probability is not a real number.

    Examples:
        >>> import torch
        >>> from torchrl.envs import TransformedEnv
        >>> from torchrl_surprise.envs import make_minigrid_env
        >>> from torchrl_surprise.transforms.stochasticity import (
        ...     STOCHASTICITY_LEVELS,
        ...     StochasticityTransform,
        ... )
        >>> STOCHASTICITY_LEVELS[2]
        (0.1, 0.3)
        >>> base = make_minigrid_env("MiniGrid-MultiRoom-N3-S4-v0", num_envs=2, seed=0)
        >>> env = TransformedEnv(base, StochasticityTransform(action_noise=1.0, seed=0))
        >>> forward = lambda td: td.set("action", torch.full((2,), 2))  # always "forward"
        >>> td = env.rollout(5, policy=forward)
        >>> td["action"]  # the agent's action is kept; the env executed random ones
        tensor([[2, 2, 2, 2, 2],
                [2, 2, 2, 2, 2]])
        >>> noisy_tv = StochasticityTransform.from_level("most", seed=0)
        >>> noisy_tv.action_noise, noisy_tv.obs_noise
        (0.2, 0.5)
        >>> env.close()
    """

    def __init__(
        self,
        action_noise: float = 0.0,
        obs_noise: float = 0.0,
        *,
        patch: Sequence[Sequence[int]] = DEFAULT_NOISE_PATCH,
        image_key: NestedKey = "image",
        action_key: NestedKey = "action",
        num_actions: int | None = None,
        one_hot: bool = False,
        view_size: int = 7,
        seed: int | None = None,
    ) -> None:
        if num_actions is not None and (
            isinstance(num_actions, bool)
            or not isinstance(num_actions, int)
            or num_actions < 1
        ):
            raise ValueError(
                f"num_actions must be a positive int, got {num_actions!r}."
            )
        if (
            isinstance(view_size, bool)
            or not isinstance(view_size, int)
            or view_size < 1
        ):
            raise ValueError(f"view_size must be a positive int, got {view_size!r}.")
        super().__init__(
            in_keys=[image_key],
            out_keys=[image_key],
            in_keys_inv=[action_key],
            out_keys_inv=[action_key],
        )
        self.action_noise = action_noise
        self.obs_noise = obs_noise
        self.patch = _check_patch(patch, view_size)
        self.view_size = view_size
        self.image_key = image_key
        self.action_key = action_key
        self.num_actions = num_actions
        self.one_hot = bool(one_hot)
        self._action_info: tuple[int, bool] | None = None
        self._generator = torch.Generator()
        self._set_seed(seed)

    @classmethod
    def from_level(cls, level: int | str, **kwargs) -> StochasticityTransform:
        """Builds the transform for one of :data:`STOCHASTICITY_LEVELS`.

        Args:
            level: a level (0-3) or its name (``"none"``, ``"mild"``, ``"more"``,
                ``"most"``).
            **kwargs: other keyword arguments of the constructor (``seed``,
                ``patch``, ...).

        Returns:
            The transform with that level's ``(action_noise, obs_noise)``.

        Raises:
            ValueError: for an unknown level.

        Examples:
            >>> from torchrl_surprise.transforms.stochasticity import (
            ...     StochasticityTransform,
            ... )
            >>> t = StochasticityTransform.from_level(1, seed=0)
            >>> t.action_noise, t.obs_noise
            (0.05, 0.1)
        """
        key = (
            STOCHASTICITY_LEVEL_NAMES.get(level, level)
            if isinstance(level, str)
            else level
        )
        if isinstance(key, bool) or key not in STOCHASTICITY_LEVELS:
            raise ValueError(
                f"Unknown stochasticity level {level!r}: expected one of "
                f"{sorted(STOCHASTICITY_LEVELS)} or {sorted(STOCHASTICITY_LEVEL_NAMES)}."
            )
        action_noise, obs_noise = STOCHASTICITY_LEVELS[key]
        return cls(action_noise=action_noise, obs_noise=obs_noise, **kwargs)

    @property
    def action_noise(self) -> float:
        """Probability of replacing the executed action (settable, validated)."""
        return self._action_noise

    @action_noise.setter
    def action_noise(self, value: float) -> None:
        self._action_noise = _check_probability("action_noise", value)

    @property
    def obs_noise(self) -> float:
        """Probability that the noisy-TV patch shows random ids (settable, validated)."""
        return self._obs_noise

    @obs_noise.setter
    def obs_noise(self, value: float) -> None:
        self._obs_noise = _check_probability("obs_noise", value)

    # Seeding ---------------------------------------------------------------------
    def _set_seed(self, seed: int | None) -> None:
        if seed is None:
            # Draw from torch's global RNG, so torch.manual_seed controls it.
            seed = int(torch.randint(0, 2**62, (), dtype=torch.int64))
        self.seed = int(seed)
        self._generator.manual_seed(self.seed)

    def set_seed(self, seed: int | None) -> int | None:
        """Re-seeds the transform's generator.

        Args:
            seed: the seed; ``None`` draws one from torch's global RNG.

        Returns:
            The ``seed`` argument, unchanged.
        """
        self._set_seed(seed)
        return seed

    def get_extra_state(self) -> dict:
        # In the state_dict, so that a checkpoint continues the same noise sequence.
        return {"seed": self.seed, "generator": self._generator.get_state()}

    def set_extra_state(self, state: dict) -> None:
        self.seed = state["seed"]
        self._generator.set_state(state["generator"])

    def clone(self) -> StochasticityTransform:
        """A copy without parent, with its own generator in the same state."""
        other = super().clone()
        other._generator = torch.Generator()
        other._generator.set_state(self._generator.get_state())
        other._action_info = None
        return other

    def set_container(self, container) -> None:
        super().set_container(container)
        self._action_info = None

    def reset_parent(self) -> None:
        super().reset_parent()
        self._action_info = None

    # Action noise (inverse path) ------------------------------------------------
    def _resolve_action_info(self) -> tuple[int, bool]:
        if self._action_info is not None:
            return self._action_info
        parent = self.parent
        if parent is None:
            if self.num_actions is None:
                raise RuntimeError(
                    "StochasticityTransform needs the number of actions: attach it to "
                    "an env with a discrete action spec or pass num_actions=."
                )
            return self.num_actions, self.one_hot
        try:
            spec = parent.full_action_spec[self.action_key]
        except KeyError as err:
            raise KeyError(
                f"StochasticityTransform: action key {self.action_key!r} not in the "
                f"parent's action spec {list(parent.full_action_spec.keys(True, True))}."
            ) from err
        if isinstance(spec, (MultiOneHot, MultiCategorical)) or not isinstance(
            spec, (OneHot, Categorical)
        ):
            raise TypeError(
                "StochasticityTransform's action noise needs a single discrete action "
                f"(Categorical or OneHot spec), got {type(spec).__name__}."
            )
        n = int(spec.space.n)
        if self.num_actions is not None and self.num_actions != n:
            raise ValueError(
                f"num_actions={self.num_actions} does not match the action spec (n={n})."
            )
        self._action_info = (n, isinstance(spec, OneHot))
        return self._action_info

    def _inv_apply_transform(self, action: torch.Tensor) -> torch.Tensor:
        if self.action_noise == 0.0:
            return action
        n, one_hot = self._resolve_action_info()
        shape = action.shape[:-1] if one_hot else action.shape
        replace = torch.rand(shape, generator=self._generator) < self.action_noise
        random_action = torch.randint(n, shape, generator=self._generator)
        replace = replace.to(action.device)
        random_action = random_action.to(action.device)
        if one_hot:
            random_action = torch.nn.functional.one_hot(random_action, n).to(
                action.dtype
            )
            replace = replace.unsqueeze(-1)
        else:
            random_action = random_action.to(action.dtype)
        return torch.where(replace, random_action, action)

    def _inv_call(self, tensordict: TensorDictBase) -> TensorDictBase:
        if self.action_noise == 0.0:
            return tensordict
        return super()._inv_call(tensordict)

    # Observation noise (forward path) -------------------------------------------
    def _apply_transform(self, image: torch.Tensor) -> torch.Tensor:
        if self.obs_noise == 0.0:
            return image
        if image.ndim < 3 or image.shape[-1] != len(_NOISE_HIGH):
            raise ValueError(
                f"Expected a MiniGrid image [..., W, H, 3] under {self.image_key!r}, "
                f"got shape {tuple(image.shape)}."
            )
        width, height = image.shape[-3], image.shape[-2]
        if any(x >= width or y >= height for x, y in self.patch):
            raise ValueError(
                f"patch {self.patch} does not fit in the {width}x{height} image."
            )
        batch = image.shape[:-3]
        num_cells = len(self.patch)
        show = torch.rand(batch, generator=self._generator) < self.obs_noise
        noise = torch.stack(
            [
                torch.randint(high, (*batch, num_cells), generator=self._generator)
                for high in _NOISE_HIGH
            ],
            dim=-1,
        ).to(device=image.device, dtype=image.dtype)
        xs = torch.tensor([c[0] for c in self.patch], device=image.device)
        ys = torch.tensor([c[1] for c in self.patch], device=image.device)
        current = image[..., xs, ys, :]
        show = show.to(image.device)[..., None, None]
        out = image.clone()
        out[..., xs, ys, :] = torch.where(show, noise, current)
        return out

    def _call(self, next_tensordict: TensorDictBase) -> TensorDictBase:
        if self.obs_noise == 0.0:
            return next_tensordict
        return super()._call(next_tensordict)

    def _reset(
        self, tensordict: TensorDictBase, tensordict_reset: TensorDictBase
    ) -> TensorDictBase:
        # The TV is part of the world: first observations are noised too. Only the
        # entries of envs that actually reset are kept by TorchRL.
        return self._call(tensordict_reset)

    def __repr__(self) -> str:
        return (
            f"{self.__class__.__name__}(action_noise={self.action_noise}, "
            f"obs_noise={self.obs_noise}, patch={len(self.patch)} cells, "
            f"image_key={self.image_key!r}, action_key={self.action_key!r})"
        )
