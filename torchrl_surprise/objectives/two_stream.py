"""Two value streams, one advantage: the extrinsic and intrinsic critics of RND.

A bonus mixed into the reward of one critic (the paper's literal form,
``r_ext + beta * r_int``) makes that critic learn a moving target, and in an
episodic task a positive per-step bonus pays the agent for not finishing. RND
(Burda et al. 2019) separates the two: an extrinsic critic learns the episodic
task return, an intrinsic critic learns the return of the bonus, which is
non-episodic by default (an episode's end does not end the novelty to be found
after it), and the policy follows ``A = A_ext + coef * A_int``.

:class:`TwoStreamAdvantage` computes both advantages and their mix, and the
critics' targets, in the keys TorchRL's :class:`~torchrl.objectives.A2CLoss` and
:class:`~torchrl.objectives.ClipPPOLoss` read (``"advantage"``,
``"value_target"``); :class:`IntrinsicValueLoss` trains the intrinsic critic.
The coefficient is the bonus transform's own (``coef=transform.current_coef``),
so it means one thing, schedule included.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import torch
from tensordict import TensorDict, TensorDictBase
from tensordict.nn import TensorDictModuleBase
from tensordict.utils import NestedKey
from torch import nn
from torchrl.objectives.common import LossModule
from torchrl.objectives.value import GAE
from torchrl.objectives.value.functional import vec_generalized_advantage_estimate

__all__ = ["IntrinsicValueLoss", "TwoStreamAdvantage"]


class TwoStreamAdvantage(nn.Module):
    """Extrinsic and intrinsic GAE with two critics, mixed into one advantage.

    Writes, on a batch with a time dimension last (``[*B, T]``, as collectors
    give):

    * ``"advantage_ext"`` and ``"value_target"``: TorchRL's :class:`GAE` on the
      env reward with episode ends, from ``value_network``;
    * ``"advantage_int"`` and ``"value_target_int"``: GAE on the bonus from
      ``intrinsic_value_network``; with ``episodic=False`` (the default, RND's
      choice) returns run across episode ends, with ``True`` they stop there;
    * ``"advantage"`` = ``advantage_ext + coef * advantage_int``, what the policy
      losses read.

    With ``intrinsic_value_network=None``, ``value_network`` is one critic with
    two heads on a shared trunk that writes both values: one forward pass over the
    batch's states and next states (stacked) then gives the four values, where two
    critics take four passes of the trunk.

    Args:
        value_network: the extrinsic critic, writing ``"state_value"`` (and
            ``intrinsic_value_key`` if ``intrinsic_value_network`` is ``None``).
        intrinsic_value_network: the intrinsic critic, writing
            ``intrinsic_value_key``; ``None``: ``value_network`` writes it.
        intrinsic_reward_key (NestedKey): the bonus under ``"next"``: the raw
            ``"intrinsic_reward"`` or a transform's normalised key.
        coef (float or callable): the mixing coefficient, or a callable returning
            it (``transform.current_coef`` follows the transform's schedule).
        gamma, lmbda (float): the extrinsic stream's discount and GAE lambda.
        intrinsic_gamma, intrinsic_lmbda (float, optional): the intrinsic
            stream's; default to the extrinsic ones (RND uses 0.99 for it).
        episodic (bool): whether intrinsic returns stop at episode ends.
        intrinsic_value_key (NestedKey): the intrinsic critic's output key.

    Examples:
        >>> from tensordict.nn import TensorDictModule
        >>> value = TensorDictModule(nn.Linear(3, 1), ["obs"], ["state_value"])
        >>> value_int = TensorDictModule(nn.Linear(3, 1), ["obs"], ["state_value_int"])
        >>> mix = TwoStreamAdvantage(value, value_int, coef=0.5)
        >>> td = TensorDict({
        ...     "obs": torch.randn(2, 5, 3),
        ...     "next": {"obs": torch.randn(2, 5, 3),
        ...              "reward": torch.zeros(2, 5, 1),
        ...              "intrinsic_reward": torch.ones(2, 5, 1),
        ...              "done": torch.zeros(2, 5, 1, dtype=torch.bool),
        ...              "terminated": torch.zeros(2, 5, 1, dtype=torch.bool)}},
        ...     [2, 5])
        >>> td = mix(td)
        >>> torch.allclose(td["advantage"],
        ...                td["advantage_ext"] + 0.5 * td["advantage_int"])
        True

        One critic, two heads, one pass (the same advantages):

        >>> from tensordict.nn import TensorDictSequential
        >>> both = TensorDictSequential(value, value_int)
        >>> td_one = TwoStreamAdvantage(both, None, coef=0.5)(td.clone())
        >>> torch.allclose(td_one["advantage"], td["advantage"])
        True
    """

    def __init__(
        self,
        value_network: TensorDictModuleBase,
        intrinsic_value_network: TensorDictModuleBase | None,
        *,
        intrinsic_reward_key: NestedKey = "intrinsic_reward",
        coef: float | Callable[[], float] = 1.0,
        gamma: float = 0.99,
        lmbda: float = 0.95,
        intrinsic_gamma: float | None = None,
        intrinsic_lmbda: float | None = None,
        episodic: bool = False,
        intrinsic_value_key: NestedKey = "state_value_int",
    ):
        super().__init__()
        # One critic for both values: it runs here, once, and TorchRL's GAE reads
        # the extrinsic values it wrote.
        self.joint_value_network = (
            value_network if intrinsic_value_network is None else None
        )
        self.extrinsic = GAE(
            gamma=gamma,
            lmbda=lmbda,
            value_network=None if intrinsic_value_network is None else value_network,
            average_gae=False,
        )
        self.extrinsic.set_keys(advantage="advantage_ext")
        self.intrinsic_value_network = intrinsic_value_network
        self.intrinsic_reward_key = intrinsic_reward_key
        self.intrinsic_value_key = intrinsic_value_key
        self.coef = coef
        self.intrinsic_gamma = gamma if intrinsic_gamma is None else intrinsic_gamma
        self.intrinsic_lmbda = lmbda if intrinsic_lmbda is None else intrinsic_lmbda
        self.episodic = episodic

    def current_coef(self) -> float:
        """The coefficient now (a callable ``coef`` is called)."""
        return float(self.coef() if callable(self.coef) else self.coef)

    @torch.no_grad()
    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        if tensordict.ndim < 1:
            raise ValueError("TwoStreamAdvantage needs a batch with a time dimension.")
        reward_int = tensordict.get(("next", self.intrinsic_reward_key), None)
        if reward_int is None:
            raise KeyError(
                f"TwoStreamAdvantage: expected the bonus at "
                f"('next', {self.intrinsic_reward_key!r}); run the bonus transform "
                "on the batch first."
            )
        if self.joint_value_network is not None:
            value, next_value = self._joint_values(tensordict)
            tensordict = self.extrinsic(tensordict)
        else:
            tensordict = self.extrinsic(tensordict)
            value = self.intrinsic_value_network(tensordict.copy()).get(
                self.intrinsic_value_key
            )
            next_value = self.intrinsic_value_network(
                tensordict.get("next").copy()
            ).get(self.intrinsic_value_key)
        if self.episodic:
            done = tensordict.get(("next", "done"))
            terminated = tensordict.get(("next", "terminated"), done)
        else:
            done = terminated = torch.zeros_like(reward_int, dtype=torch.bool)
        advantage_int, target_int = vec_generalized_advantage_estimate(
            self.intrinsic_gamma,
            self.intrinsic_lmbda,
            value,
            next_value,
            reward_int.to(value.dtype),
            done,
            terminated,
            time_dim=tensordict.ndim - 1,
        )
        tensordict.set(self.intrinsic_value_key, value)
        tensordict.set("advantage_int", advantage_int)
        tensordict.set("value_target_int", target_int)
        tensordict.set(
            "advantage",
            tensordict.get("advantage_ext") + self.current_coef() * advantage_int,
        )
        return tensordict

    def _joint_values(
        self, tensordict: TensorDictBase
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """One pass of the two-headed critic over the states and next states.

        Writes the extrinsic values where TorchRL's GAE reads them
        (``"state_value"`` and ``("next", "state_value")``) and returns the
        intrinsic ones.
        """
        network = self.joint_value_network
        in_keys = network.in_keys
        both = torch.stack(
            [tensordict.select(*in_keys), tensordict.get("next").select(*in_keys)], 0
        )
        out = network(both)
        value_key = self.extrinsic.tensor_keys.value
        for key in (value_key, self.intrinsic_value_key):
            if key not in out.keys(include_nested=True):
                raise KeyError(
                    f"TwoStreamAdvantage without an intrinsic_value_network: the "
                    f"value network must write {value_key!r} and "
                    f"{self.intrinsic_value_key!r}; it wrote {list(out.keys(True))}."
                )
        value, next_value = out.get(value_key).unbind(0)
        tensordict.set(value_key, value)
        tensordict.set(("next", value_key), next_value)
        return out.get(self.intrinsic_value_key).unbind(0)


class IntrinsicValueLoss(LossModule):
    """Squared error of the intrinsic critic against ``"value_target_int"``.

    Args:
        intrinsic_value_network: the intrinsic critic (shares the trunk with the
            actor-critic if it was built so; its gradient then reaches the trunk).
        critic_coef (float): the loss weight (TorchRL's ``critic_coeff``).
        reduction (str): ``"mean"``, ``"sum"`` or ``"none"``.

    Examples:
        >>> from tensordict.nn import TensorDictModule
        >>> value_int = TensorDictModule(nn.Linear(3, 1), ["obs"], ["state_value_int"])
        >>> loss = IntrinsicValueLoss(value_int, critic_coef=0.5)
        >>> td = TensorDict({"obs": torch.randn(4, 3),
        ...                  "value_target_int": torch.zeros(4, 1)}, [4])
        >>> loss(td)["loss_critic_int"].shape
        torch.Size([])
    """

    @dataclass
    class _AcceptedKeys:
        """Keys read by the loss.

        Attributes:
            value (NestedKey): the intrinsic critic's output.
            value_target (NestedKey): its target, from :class:`TwoStreamAdvantage`.
        """

        value: NestedKey = "state_value_int"
        value_target: NestedKey = "value_target_int"

    default_keys = _AcceptedKeys
    tensor_keys: _AcceptedKeys

    def __init__(
        self,
        intrinsic_value_network: TensorDictModuleBase,
        *,
        critic_coef: float = 0.5,
        reduction: str = "mean",
    ):
        if reduction not in ("mean", "sum", "none"):
            raise ValueError(f"reduction must be mean, sum or none, got {reduction!r}.")
        super().__init__()
        self.intrinsic_value_network = intrinsic_value_network
        self.critic_coef = critic_coef
        self.reduction = reduction

    def _forward_value_estimator_keys(self, **kwargs) -> None:
        pass

    @property
    def out_keys(self) -> list[str]:
        return ["loss_critic_int"]

    def forward(self, tensordict: TensorDictBase) -> TensorDict:
        target = tensordict.get(self.tensor_keys.value_target, None)
        if target is None:
            raise KeyError(
                f"IntrinsicValueLoss: expected {self.tensor_keys.value_target!r}; "
                "compute it with TwoStreamAdvantage first."
            )
        value = self.intrinsic_value_network(
            tensordict.select(*self.intrinsic_value_network.in_keys)
        ).get(self.tensor_keys.value)
        loss = self.critic_coef * (value - target).pow(2)
        if self.reduction == "mean":
            loss = loss.mean()
        elif self.reduction == "sum":
            loss = loss.sum()
        return TensorDict({"loss_critic_int": loss}, batch_size=[])
