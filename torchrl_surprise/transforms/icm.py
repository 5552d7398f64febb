"""The ICM curiosity bonus (Pathak et al., 2017) on the shared transform base."""

from __future__ import annotations

from collections.abc import Sequence

import torch
from tensordict import TensorDictBase
from tensordict.utils import NestedKey, unravel_key

from torchrl_surprise.modules.icm import ICMModel
from torchrl_surprise.transforms.base import IntrinsicRewardTransform

__all__ = ["ICMTransform"]


class ICMTransform(IntrinsicRewardTransform):
    """Curiosity bonus: the forward model's error in ICM's feature space.

    ``r_int(s, a, s') = 0.5 * ||f(phi(s), a) - phi(s')||^2``. Needs ``s`` and
    ``a`` at the root of the tensordict and ``s'`` under ``"next"``, which both an
    env step and a collected batch provide. :class:`~torchrl_surprise.ICMLoss`
    trains the same :class:`~torchrl_surprise.modules.ICMModel` instance.

    Args:
        icm (ICMModel): the ICM networks.
        in_keys (sequence of NestedKey, optional): observation keys. Defaults to
            ``icm.in_keys``.
        action_key (NestedKey): the action key.
        **kwargs: see :class:`~torchrl_surprise.transforms.IntrinsicRewardTransform`.

    Examples:
        >>> import torch
        >>> from torchrl.envs import TransformedEnv
        >>> from torchrl.testing.mocking_classes import ContinuousActionVecMockEnv
        >>> from torchrl_surprise import ICMTransform
        >>> from torchrl_surprise.modules import ICMModel
        >>> base = ContinuousActionVecMockEnv()
        >>> obs_dim = base.observation_spec["observation"].shape[-1]
        >>> act_dim = base.action_spec.shape[-1]
        >>> icm = ICMModel.for_vector(obs_dim, act_dim, hidden_dim=32)
        >>> env = TransformedEnv(base, ICMTransform(icm, coef=0.01))
        >>> env.rollout(4)["next", "intrinsic_reward"].shape
        torch.Size([4, 1])
    """

    def __init__(
        self,
        icm: ICMModel,
        in_keys: Sequence[NestedKey] | None = None,
        action_key: NestedKey = "action",
        **kwargs,
    ):
        if in_keys is None:
            in_keys = icm.in_keys
        super().__init__(in_keys, **kwargs)
        self.icm = icm
        self.action_key = unravel_key(action_key)

    def _compute_bonus(
        self, tensordict: TensorDictBase, next_tensordict: TensorDictBase
    ) -> torch.Tensor:
        observations = self._observations(tensordict, "the root tensordict (s_t)")
        next_observations = self._observations(next_tensordict, "the 'next' tensordict")
        action = tensordict.get(self.action_key, None)
        if action is None:
            raise KeyError(
                f"ICMTransform: expected the action key {self.action_key!r} in the "
                "root tensordict."
            )
        return self.icm.forward_error(observations, action, next_observations)
