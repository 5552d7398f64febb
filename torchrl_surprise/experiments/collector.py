"""A TorchRL ``Collector`` whose ``state_dict`` determines the rest of the run.

TorchRL's ``Collector.state_dict`` holds the env transforms' and the policy's
state and the frame counters, but not the episodes in progress: a collector
restored from it starts new episodes ("runtime environment state is not generally
serializable"), so a resumed run diverges from the uninterrupted one at its first
update. :class:`ResumableCollector` adds the two missing pieces:

* the carrier, the tensordict the next step starts from (the current
  observations, and the per-episode sums of ``RewardSum`` and ``StepCounter``);
* the runtime state of the gymnasium envs (layouts, agent, simulator state,
  random generators, time limits), through the envs' ``runtime_state()`` API
  (:class:`torchrl_surprise.envs.vector.RuntimeStateMixin`, which
  :func:`~torchrl_surprise.envs.make_minigrid_env` and
  :func:`~torchrl_surprise.envs.make_mujoco_env` build).

Restore it after building the collector with the same config, and restore the
global RNGs after it (the policy samples from torch's generator).
"""

from __future__ import annotations

from collections import OrderedDict

from torchrl.collectors import Collector
from torchrl.envs import EnvBase, TransformedEnv

__all__ = ["ResumableCollector"]


def _runtime_env(env: EnvBase):
    base = env
    while isinstance(base, TransformedEnv):
        base = base.base_env
    if not hasattr(base, "runtime_state"):
        raise TypeError(
            f"{type(base).__name__} cannot save the episodes in progress: exact "
            "resume needs an env with runtime_state()/load_runtime_state(), as "
            "built by torchrl_surprise.envs.make_minigrid_env or make_mujoco_env."
        )
    return base


class ResumableCollector(Collector):
    """``Collector`` that also saves and restores the episodes in progress.

    Same arguments as :class:`torchrl.collectors.Collector` (single process).

    Examples:
        >>> import torch
        >>> from torchrl.envs.utils import RandomPolicy
        >>> from torchrl_surprise.envs import make_minigrid_env
        >>> def run(state=None):
        ...     env = make_minigrid_env("MiniGrid-Empty-5x5-v0", num_envs=2, seed=0)
        ...     c = ResumableCollector(env, RandomPolicy(env.action_spec),
        ...                            frames_per_batch=8, total_frames=32)
        ...     if state is not None:
        ...         c.load_state_dict(state)
        ...     return c
        >>> _ = torch.manual_seed(0); c = run(); it = iter(c); _ = next(it)
        >>> saved, rng = c.state_dict(), torch.get_rng_state()
        >>> expected = next(it)["next", "image"]
        >>> resumed = run(saved); torch.set_rng_state(rng)
        >>> bool((next(iter(resumed))["next", "image"] == expected).all())
        True
    """

    def state_dict(self) -> OrderedDict:
        state = super().state_dict()
        state["carrier"] = self._carrier.clone()
        state["env_runtime"] = _runtime_env(self.env).runtime_state()
        return state

    def load_state_dict(self, state_dict: OrderedDict, **kwargs) -> None:
        state = OrderedDict(state_dict)
        missing = [k for k in ("carrier", "env_runtime") if k not in state]
        if missing:
            raise KeyError(
                f"the collector state has no {missing}: it was not saved by a "
                "ResumableCollector, so the episodes in progress are lost."
            )
        carrier, runtime = state.pop("carrier"), state.pop("env_runtime")
        # A policy without parameters saves no state: not an error.
        kwargs.setdefault("strict", "policy_state_dict" in state)
        super().load_state_dict(state, **kwargs)
        _runtime_env(self.env).load_runtime_state(runtime)
        self._carrier.update(carrier, inplace=True)
