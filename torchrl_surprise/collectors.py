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

:class:`ResumableMultiSyncCollector` is the same for TorchRL's
``MultiSyncCollector``: each worker process runs a :class:`ResumableCollector`,
and the collector's ``state_dict`` gathers each worker's carrier, env runtime
state and the worker's own torch generator (its policy samples from it).
"""

from __future__ import annotations

import atexit
import functools
import io
import signal
import weakref
from collections import OrderedDict
from collections.abc import Callable, Sequence

import numpy as np
import torch
from torchrl.collectors import Collector, MultiSyncCollector
from torchrl.envs import EnvBase, TransformedEnv
from torchrl.weight_update import SharedMemWeightSyncScheme

__all__ = [
    "STOP_SIGNALS",
    "CollectorWorkerDied",
    "ResumableCollector",
    "ResumableMultiSyncCollector",
    "worker_seed",
]

STOP_SIGNALS: tuple[signal.Signals, ...] = (
    signal.SIGINT,
    signal.SIGTERM,
    signal.SIGUSR2,
    signal.SIGHUP,
)
"""The signals on which a run saves its state and stops: Ctrl-C, a scheduler's
SIGTERM, SIGUSR2 (what submitit asks SLURM to send before the time limit) and
SIGHUP (the terminal closed). They often reach every process of the job (Ctrl-C
and a closed terminal the foreground process group, SLURM every process of the
job step): the worker processes of :class:`ResumableMultiSyncCollector` ignore
them, so that the main process can still gather their state and save it.

Examples:
    >>> import signal
    >>> signal.SIGUSR2 in STOP_SIGNALS
    True
"""


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
        workers = sum(1 for k in state if str(k).startswith("worker"))
        if workers:
            raise ValueError(
                f"the collector state was saved by {workers} worker processes "
                "(ResumableMultiSyncCollector): resume with the number of workers "
                "the run started with."
            )
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


class CollectorWorkerDied(RuntimeError):
    """A worker process of :class:`ResumableMultiSyncCollector` died while
    collecting: the message names it (index, process id), how it ended (the
    signal that killed it, or its exit code) and what to do.

    Attributes:
        worker (int): the worker's index.
        pid (int): its process id.
        exitcode (int): its exit code (``-N``: killed by signal ``N``).

    Examples:
        >>> print(CollectorWorkerDied(1, 4242, -9))  # doctest: +ELLIPSIS
        collector worker 1 (process 4242) died while collecting: killed by SIGKILL...
    """

    def __init__(self, worker: int, pid: int, exitcode: int):
        self.worker, self.pid, self.exitcode = worker, pid, exitcode
        if exitcode is not None and exitcode < 0:
            try:
                how = f"killed by {signal.Signals(-exitcode).name}"
            except ValueError:
                how = f"killed by signal {-exitcode}"
            if exitcode == -signal.SIGKILL:
                how += " (often the out-of-memory killer: check the memory left)"
        else:
            how = f"exited with code {exitcode} (its error is printed above it)"
        super().__init__(
            f"collector worker {worker} (process {pid}) died while collecting: "
            f"{how}. The batch it was collecting is lost and the collector stops; "
            "the other workers are shut down. A run resumes from its last "
            "checkpoint with the same number of workers."
        )


def worker_seed(seed: int, worker: int) -> int:
    """The seed of worker ``worker``'s torch generator in a run seeded ``seed``.

    Drawn from ``numpy.random.SeedSequence([seed, worker])``: a stream of its own,
    unrelated to the main process's (seeded ``seed``) and to the other workers'.

    Examples:
        >>> worker_seed(0, 0) == worker_seed(0, 0) != worker_seed(0, 1)
        True
    """
    return int(np.random.SeedSequence([seed, worker]).generate_state(1)[0])


class _ResumableWorker(ResumableCollector):
    """The collector each worker process of :class:`ResumableMultiSyncCollector` runs.

    Its state adds the worker's torch generator, which its policy samples from,
    and leaves out the policy's weights: they are the main process's (shared
    memory), restored there.
    """

    def __init__(self, *args, seed: int, worker_idx: int | None = None, **kwargs):
        # The main process handles the stop signals (a checkpoint, then shutting
        # the workers down); one sent to the whole process group or job step must
        # not kill a worker before the main process has saved its state.
        for sig in STOP_SIGNALS:
            signal.signal(sig, signal.SIG_IGN)
        torch.manual_seed(worker_seed(seed, worker_idx or 0))
        super().__init__(*args, worker_idx=worker_idx, **kwargs)

    def state_dict(self) -> OrderedDict:
        state = super().state_dict()
        state.pop("policy_state_dict", None)
        state["torch_rng"] = torch.get_rng_state()
        # TorchRL's worker loop sends a worker's state through a TensorDict, which
        # turns Python numbers into tensors: it travels as bytes, unchanged.
        buffer = io.BytesIO()
        torch.save(state, buffer)
        packed = torch.frombuffer(bytearray(buffer.getvalue()), dtype=torch.uint8)
        return OrderedDict(packed_state=packed)

    def load_state_dict(self, state_dict, **kwargs) -> None:
        packed = state_dict["packed_state"]
        state = torch.load(io.BytesIO(packed.numpy().tobytes()), weights_only=False)
        rng = state.pop("torch_rng")
        super().load_state_dict(state, **kwargs)
        torch.set_rng_state(rng)


class ResumableMultiSyncCollector(MultiSyncCollector):
    """TorchRL's ``MultiSyncCollector`` whose ``state_dict`` determines the rest of
    the run, as :class:`ResumableCollector` does for one process.

    Each worker process builds its env with its factory and runs a
    :class:`ResumableCollector`; every batch is the workers' rollouts concatenated
    along the env dimension (``cat_results=0``: with batched envs, the layout of a
    single collector over all the envs, ``[envs, time]``). The collection is
    synchronous: the workers collect only when a batch is asked for, and every
    worker collects with the policy as it is then. TorchRL's default weight sync
    for an ``nn.Module`` policy (``SharedMemWeightSyncScheme``) moves its
    parameters to shared memory, where the workers' copies read them: an update
    made in the main process between two batches is what the next batch is
    collected with, without a message per batch.

    Its ``state_dict`` holds, per worker, the carrier, the gymnasium envs'
    runtime state, the env transforms' state and the worker's torch generator, so
    a collector rebuilt with the same arguments and loaded from it continues
    exactly. Worker ``w`` seeds its torch generator with
    :func:`worker_seed(seed, w) <worker_seed>`; the env factories seed the envs.

    Args:
        create_env_fn: one env factory per worker: picklable (module-level
            functions or ``functools.partial`` of them), as the workers are
            started with ``spawn``.
        policy: the policy; its parameters are moved to shared memory.
        frames_per_batch (int): frames per batch from each worker (the batch holds
            ``len(create_env_fn) * frames_per_batch``).
        total_frames (int): frames to collect over the whole run.
        seed (int): the run's seed, from which each worker's torch seed is drawn.
        **kwargs: other arguments of ``MultiSyncCollector``.

    Examples:
        >>> import functools
        >>> from torchrl.envs.utils import RandomPolicy
        >>> from torchrl_surprise.envs import make_minigrid_env
        >>> factories = [functools.partial(make_minigrid_env, "MiniGrid-Empty-5x5-v0",
        ...                                num_envs=2, seed=2 * w) for w in range(2)]
        >>> spec = make_minigrid_env("MiniGrid-Empty-5x5-v0", num_envs=2).action_spec
        >>> collector = ResumableMultiSyncCollector(
        ...     factories, RandomPolicy(spec), frames_per_batch=8, total_frames=32, seed=0)
        >>> batch = next(iter(collector))
        >>> batch.shape  # 2 workers x 2 envs, 4 steps each
        torch.Size([4, 4])
        >>> sorted(collector.state_dict())
        ['frames', 'iter', 'worker0', 'worker1']
        >>> collector.shutdown()
    """

    def __init__(
        self,
        create_env_fn: Sequence[Callable[[], EnvBase]],
        policy=None,
        *,
        frames_per_batch: int,
        total_frames: int,
        seed: int,
        **kwargs,
    ):
        workers = len(create_env_fn)
        kwargs.setdefault("num_threads", torch.get_num_threads())
        if isinstance(policy, torch.nn.Module):
            # TorchRL's default for a module policy, made here to be shut down
            # with the collector (see shutdown).
            kwargs.setdefault(
                "weight_sync_schemes", {"policy": SharedMemWeightSyncScheme()}
            )
        schemes = list(kwargs.get("weight_sync_schemes", {}).values())
        super().__init__(
            list(create_env_fn),
            policy,
            frames_per_batch=[frames_per_batch] * workers,
            total_frames=total_frames,
            collector_class=functools.partial(_ResumableWorker, seed=seed),
            cat_results=0,
            use_buffers=True,
            **kwargs,
        )
        self._schemes_to_shut_down = schemes
        # The worker processes are not daemons (TorchRL): a run that fails before
        # calling shutdown() would wait for them forever at exit.
        collector = weakref.ref(self)

        def shutdown_at_exit() -> None:
            if (alive := collector()) is not None:
                alive.shutdown(raise_on_error=False)

        atexit.register(shutdown_at_exit)

    def shutdown(
        self,
        timeout: float | None = None,
        close_env: bool = True,
        raise_on_error: bool = True,
    ) -> None:
        # TorchRL 0.14 leaves the weight-sync scheme to its __del__, which, when it
        # runs at interpreter exit, starts a queue thread and waits for it forever.
        schemes = getattr(self, "_schemes_to_shut_down", [])
        while schemes:
            schemes.pop().shutdown()
        super().shutdown(
            timeout=timeout, close_env=close_env, raise_on_error=raise_on_error
        )

    def iterator(self):
        """TorchRL's batches; a worker that dies raises :class:`CollectorWorkerDied`
        naming it, where TorchRL raises a broken pipe or "At least one process
        failed"."""
        batches = super().iterator()
        while True:
            try:
                batch = next(batches)
            except StopIteration:
                return
            # TorchRL: "At least one process failed", a broken pipe, or a
            # ValueError where it closes a live worker it has just terminated
            except (RuntimeError, OSError, EOFError, ValueError) as err:
                dead = self._dead_worker()
                if dead is None:
                    raise
                raise CollectorWorkerDied(*dead) from err
            yield batch

    def _dead_worker(self) -> tuple[int, int, int] | None:
        """``(index, pid, exit code)`` of the first worker that has ended."""
        for index, process in enumerate(getattr(self, "procs", [])):
            # TorchRL closes the processes it stops after finding a dead one
            if not process._closed and not process.is_alive():
                return index, process.pid, process.exitcode
        return None

    def load_state_dict(self, state_dict: OrderedDict) -> None:
        saved = sum(1 for k in state_dict if str(k).startswith("worker"))
        if saved != self.num_workers:
            source = f"{saved} workers" if saved else "a single-process collector"
            raise ValueError(
                f"the collector state was saved by {source}, this collector has "
                f"{self.num_workers} workers: resume with the number of workers the "
                "run started with (the recipes' collector.workers)."
            )
        super().load_state_dict(state_dict)
