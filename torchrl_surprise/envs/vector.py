"""TorchRL wrappers for gymnasium envs whose runtime state can be saved and restored.

A checkpoint that determines the rest of a run must hold what the env is in the
middle of: the layouts and agent positions of unfinished MiniGrid episodes, the
MuJoCo simulator state, the envs' random generators and the step counters of
gymnasium's wrappers. TorchRL's collectors say this state "is not generally
serializable"; for gymnasium envs it is, and :class:`RuntimeStateMixin` does it:

* :meth:`~RuntimeStateMixin.runtime_state` returns one entry per sub-env;
* :meth:`~RuntimeStateMixin.load_runtime_state` puts it back, after which the
  env steps exactly as the saved one would have.

A MuJoCo env is saved through ``mujoco.mj_getState`` (its integration state, solver
warm start included, so the continuation is bit-exact); any other env is pickled
whole with ``cloudpickle`` (MiniGrid's grid, agent and mission).
"""

from __future__ import annotations

import copy
from typing import Any

import cloudpickle
import gymnasium as gym
import torch
from tensordict import TensorDict, TensorDictBase
from torchrl.envs import GymEnv, GymWrapper

__all__ = [
    "RuntimeStateMixin",
    "VectorGymWrapper",
    "SingleGymEnv",
    "gym_env_state",
    "load_gym_env_state",
]

_WRAPPER_FIELDS = (int, float, bool, type(None))


def _is_mujoco(env: gym.Env) -> bool:
    return hasattr(env, "model") and hasattr(env, "data") and hasattr(env, "init_qpos")


def gym_env_state(env: gym.Env) -> dict[str, Any]:
    """The runtime state of one gymnasium env, its wrappers included.

    Examples:
        >>> import gymnasium as gym
        >>> env = gym.make("CartPole-v1"); _ = env.reset(seed=0)
        >>> state = gym_env_state(env)
        >>> a = env.step(0)[0]
        >>> load_gym_env_state(env, state)
        >>> bool((env.step(0)[0] == a).all())
        True
    """
    wrappers = []
    inner = env
    while isinstance(inner, gym.Wrapper):
        # Step counters and flags (TimeLimit._elapsed_steps, OrderEnforcing, ...).
        wrappers.append(
            {k: v for k, v in vars(inner).items() if isinstance(v, _WRAPPER_FIELDS)}
        )
        inner = inner.env
    state: dict[str, Any] = {"wrappers": wrappers}
    if _is_mujoco(inner):
        import mujoco
        import numpy as np

        spec = mujoco.mjtState.mjSTATE_INTEGRATION
        physics = np.empty(mujoco.mj_stateSize(inner.model, spec))
        mujoco.mj_getState(inner.model, inner.data, physics, spec)
        state["mujoco"] = physics
        state["np_random"] = copy.deepcopy(inner.np_random.bit_generator.state)
    else:
        state["env"] = cloudpickle.dumps(inner)
    return state


def load_gym_env_state(env: gym.Env, state: dict[str, Any]) -> None:
    """Restores, in place, what :func:`gym_env_state` returned for a same-id env."""
    inner = env
    for fields in state["wrappers"]:
        if not isinstance(inner, gym.Wrapper):
            raise ValueError("the saved env has more wrappers than this one")
        for name, value in fields.items():
            setattr(inner, name, value)
        if not isinstance(inner.env, gym.Wrapper) and "env" in state:
            inner.env = cloudpickle.loads(state["env"])
            return
        inner = inner.env
    if "mujoco" in state:
        import mujoco

        if not _is_mujoco(inner):
            raise ValueError(
                "the saved state is a MuJoCo state, this env is not MuJoCo"
            )
        spec = mujoco.mjtState.mjSTATE_INTEGRATION
        mujoco.mj_setState(inner.model, inner.data, state["mujoco"], spec)
        mujoco.mj_forward(inner.model, inner.data)
        inner.np_random.bit_generator.state = copy.deepcopy(state["np_random"])
    elif "env" in state:
        raise ValueError("an unwrapped env cannot be restored in place; wrap it")


class RuntimeStateMixin:
    """Adds ``runtime_state`` / ``load_runtime_state`` to a TorchRL gymnasium wrapper.

    Works for a single gymnasium env and for a gymnasium ``SyncVectorEnv`` (one
    entry per sub-env).
    """

    def _gym_envs(self) -> list[gym.Env]:
        env = self._env
        return list(env.envs) if isinstance(env, gym.vector.SyncVectorEnv) else [env]

    def runtime_state(self) -> list[dict[str, Any]]:
        """One :func:`gym_env_state` per sub-env."""
        return [gym_env_state(env) for env in self._gym_envs()]

    def load_runtime_state(self, state: list[dict[str, Any]]) -> None:
        """Restores what :meth:`runtime_state` returned (same id, same number of envs)."""
        envs = self._gym_envs()
        if len(state) != len(envs):
            raise ValueError(
                f"the saved runtime state has {len(state)} envs, this env has "
                f"{len(envs)}: build it with the same num_envs."
            )
        for env, env_state in zip(envs, state):
            load_gym_env_state(env, env_state)


class VectorGymWrapper(RuntimeStateMixin, GymWrapper):
    """``GymWrapper`` over a gymnasium vector env, usable inside batched envs.

    Its step writes the same entries as ``GymWrapper._step``, with the done flags
    already of the spec's shape ``[B, 1]`` (``GymWrapper._step`` returns ``[B]``;
    the public ``step`` reshapes them, but ``SerialEnv`` and ``ParallelEnv`` call
    the private ``_step`` of their sub-envs and then fail on the mismatch, TorchRL
    0.14.1).

    For a vector env with one action, no info reader and no frame skip (what
    :func:`~torchrl_surprise.envs.make_minigrid_env` and
    :func:`~torchrl_surprise.envs.make_mujoco_env` build), the step is a direct
    path: the action goes to gymnasium as a numpy view, the outputs come back as
    tensors over gymnasium's arrays (fresh ones each step: the vector env copies
    its outputs) cast to the specs' dtypes. ``GymWrapper._step`` converts each
    entry through its spec, reads the done flags through generic helpers and
    copies the result to the device, a per-step cost comparable to a MiniGrid step
    itself (docs/speed.rst). Anything else takes ``GymWrapper._step``.
    """

    def _step(self, tensordict: TensorDictBase) -> TensorDictBase:
        direct = self.__dict__.get("_direct_step")
        if direct is None:
            direct = self.__dict__["_direct_step"] = self._make_direct_step()
        if direct is not None:
            return direct(tensordict)
        next_tensordict = super()._step(tensordict)
        self._complete_done(self.full_done_spec, next_tensordict)
        return next_tensordict

    def _make_direct_step(self):
        """The direct step, or ``None`` where ``GymWrapper._step`` is needed."""
        env = self._env
        if not (
            isinstance(env, gym.vector.VectorEnv)
            and getattr(env, "copy", False)
            and len(self.action_keys) == 1
            and not self.info_dict_reader
            and self.wrapper_frame_skip == 1
            and len(self.batch_size) == 1
        ):
            return None
        obs_dtypes = {
            key: spec.dtype
            for key, spec in self.observation_spec.items(True, True)
            if isinstance(key, str)
        }
        if isinstance(env.single_observation_space, gym.spaces.Dict):
            space_keys = list(env.single_observation_space.spaces)
            if set(space_keys) != set(obs_dtypes) or "state" in space_keys:
                return None  # renamed or non-tensor entries: GymWrapper's reading
            single_key = None
        elif len(obs_dtypes) == 1:
            single_key = next(iter(obs_dtypes))
        else:
            return None
        action_key, reward_key = self.action_key, self.reward_key
        reward_dtype = self.reward_spec.dtype
        done_dtype = self.full_done_spec["done"].dtype
        batch_size, device = self.batch_size, self.device
        shape = (batch_size[0], 1)
        to_device = device is not None and device != torch.device("cpu")

        def step(tensordict: TensorDictBase) -> TensorDictBase:
            action = tensordict.get(action_key).numpy(force=True)
            obs, reward, terminated, truncated, _ = env.step(action)
            if single_key is None:
                out = {
                    key: torch.as_tensor(value, dtype=obs_dtypes[key])
                    for key, value in obs.items()
                }
            else:
                out = {single_key: torch.as_tensor(obs, dtype=obs_dtypes[single_key])}
            terminated = torch.as_tensor(terminated, dtype=done_dtype).view(shape)
            truncated = torch.as_tensor(truncated, dtype=done_dtype).view(shape)
            out[reward_key] = torch.as_tensor(reward, dtype=reward_dtype).view(shape)
            out["truncated"] = truncated
            out["done"] = terminated | truncated
            out["terminated"] = terminated
            next_tensordict = TensorDict(out, batch_size=batch_size)
            return next_tensordict.to(device) if to_device else next_tensordict

        return step

    @property
    def gym_env(self) -> gym.Env:
        """The wrapped gymnasium env."""
        return self._env


class SingleGymEnv(RuntimeStateMixin, GymEnv):
    """TorchRL's ``GymEnv`` with the runtime-state API of :class:`RuntimeStateMixin`."""

    @property
    def gym_env(self) -> gym.Env:
        """The wrapped gymnasium env."""
        return self._env
