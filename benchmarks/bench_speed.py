"""The speed targets, measured side by side: one table of ratios, written as JSON.

Every number is a ratio of two setups run interleaved in this one command
(A, B, A, B, ... with the order alternating each round, so that both see the
same machine load), the median over rounds of the per-round ratio. The load
average is recorded with each measurement.

1. Bonus overhead in the A2C recipe: frames/s with ``bonus=vae|icm|rnd`` over
   ``bonus=none`` (recipe defaults, ``recipes/minigrid``, ``algo=a2c``), and beside them the
   VAE bonus trained on every rollout (the committed studies' setting), on every
   8th, and never (an untrained VAE: the bonus's own cost).
2. DDPG (``recipes/ddpg_mujoco``, Hopper-v5): the recipe's ``time/updates_per_s``
   (its whole loop, collection included) over a bare eager-PyTorch DDPG update of
   the same sizes (OurDDPG's loop: 256-256 MLPs, batch 256, Adam, soft target
   update, 1 thread); and ``bonus=vae`` over ``bonus=none``.
3. The A2C recipe (``bonus=none``, on minigrid's envs and on envpool's) over
   torch-ac 1.4.0 running the same A2C (rl-starter-files' model and defaults),
   on MultiRoom-N3S4 and DoorKey-8x8 (goal 2x).
   Skipped, with a message, when torch-ac is not installed (``pip install -e
   ".[bench]"``).
4. The env pipeline: ``make_minigrid_env`` / ``make_mujoco_env`` (with the
   recipes' numbers of envs, ``env.rollout`` with random actions) over a raw
   gymnasium loop of one env of the same id, in steps per CPU second of this
   single-threaded process (the wall-clock ratio is in the details); for
   MiniGrid also ``make_minigrid_env(16, backend="envpool")`` (one envpool
   thread, goal 5x).
5. Memory: each recipe's peak resident memory (a subprocess with a short budget,
   ``ru_maxrss`` from ``wait4``), the DDPG replay buffer's bytes per transition
   (measured in the recipe's buffer) extrapolated to 1M transitions, and two runs
   side by side against 24 GiB.
6. Collector workers: frames/s of the A2C recipe (defaults) with
   ``collector.workers=2`` over ``collector.workers=1``, for ``bonus=none`` and
   ``bonus=vae`` (the goal, >= 1, is that one run gets more than one core's
   frames/s; how much more depends on the free cores); and the same for the
   recipe's collector alone (its envs, policy and ``make_collector``, no
   training), with the A2C recipe's batch (16 envs x 8 steps) and the PPO
   recipe's (16 x 128), which separates what the workers cost per batch from
   what the training process leaves unparallelised. Printed under the table:
   the collector's frames per CPU second in one process with 16, 8, 4 and 2 envs
   (what a worker's share of the envs costs per frame).
7. The learners against the simulator: the MiniGrid recipe with ``algo=a2c`` and
   ``algo=ppo`` (defaults: the elliptical VAE bonus), on the envpool and the
   gymnasium backend, in frames per CPU second of its process (its logged
   ``time/fps_cpu``) over a raw gymnasium loop of one MultiRoom-N3S4 env in
   steps per CPU second; goals A2C 1.0, PPO 0.75 (3x the ratios at commit
   6453210, 0.32 and 0.24).
8. More envs a step: item 7's ratio on envpool for the shapes of a batch that
   the ``*_envpool_64envs*`` and ``*_64x2`` experiments measure for learning:
   A2C 64 x 8 and 64 x 2 beside its defaults (16 x 8); PPO's defaults (64 x 32,
   minibatches of 256) and 64 x 32 with minibatches of 512 beside its former
   defaults (16 x 128); and the env pipeline with 16 and 64 envs on envpool over
   the raw loop (DoorKey-8x8, MultiRoom-N3S4).
   Whether a shape pays is read with its learning results (``docs/speed.rst``,
   "More envs a step"): a shape that takes more frames to learn buys no time.
9. The suite's bonuses: the MiniGrid recipe with PPO on the hard-exploration
   suite's DoorKey-16x16 batch (``+experiment=ppo/suite_doorkey16x16_16x512``:
   envpool, 16 envs x 512 frames), each of the settings ``e3b`` (its 1024-wide
   embedding), ``e3b_128``, ``noveld`` and ``vae_noveld``, in frames per CPU
   second of its process (``time/fps_cpu``) over the plain learner
   (``+setting=none``); goal 0.5 (a bonus at most doubles what a frame costs).
   Under the table, ``e3b_128`` over ``e3b``.
10. The PPO recipe against a hand-written PPO: ``algo=ppo`` (envpool, 64 envs x
    32 steps) with ``+setting=none`` and ``+setting=vae_noveld``, in frames per
    CPU second of its process (``time/fps_cpu``), over ``benchmarks/ppo_baseline.py``
    with the same settings and bonus (plain tensors on envpool, CleanRL's
    ``ppo_atari_envpool.py`` in shape; its own frames per CPU second of its
    training loop, in a subprocess); goal 1.0 (the recipe no slower than by hand).
11. The suite's VAE bonus end to end on KeyCorridorS3R3 (PPO, envpool, the
    suite's experiment): frames per CPU second of ``+setting=vae_noveld`` with
    its VAE trained on the whole batch (the committed runs') and on 512 of its
    transitions a step (``intrinsic.batch_size=512``) over ``+setting=none``
    (goal 0.8); and each one's CPU seconds to 0.9 of the oracle: the median
    frames to 0.9 of its committed runs (5 seeds, ``summary.csv`` of
    ``docs/results/suite_keycorridor_s3r3`` and ``vae_noveld_batch512_s3r3``)
    over its frames per CPU second here (goal: the cheaper one at most half).

Recipes, the peer and the hand-written PPO run as subprocesses (their start-up is
not timed: the recipes time their own training loop, the peer and the hand-written
PPO are timed the same way). Usage::

    python benchmarks/bench_speed.py            # ~40 min on 2 busy cores
    python benchmarks/bench_speed.py --quick    # smoke run, ~4 min
    python benchmarks/bench_speed.py --items 2 4 --rounds 5
    python benchmarks/bench_speed.py --items 6 --out docs/results/bench_workers
    python benchmarks/bench_speed.py --items 10 --rounds 3 --out /tmp/bench_ppo

Writes ``<out>.json`` and ``<out>.txt`` (default ``docs/results/bench_speed``;
with ``--quick`` a temporary directory unless ``--out`` is given).
"""

from __future__ import annotations

import argparse
import copy
import importlib.util
import json
import os
import platform
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
import torch
from torch import nn

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "recipes"))  # the recipes' shared `common` package
# the MiniGrid recipe (algo=a2c, its default, or algo=ppo)
A2C_MAIN = ROOT / "recipes" / "minigrid" / "main.py"
DDPG_MAIN = ROOT / "recipes" / "ddpg_mujoco" / "main.py"
GIB = 1024**3
MEMORY_LIMIT = 24 * GIB
BONUSES = ("vae", "icm", "rnd")
# item 1, beside the defaults: the VAE bonus trained on every rollout (the committed
# studies' setting), less often, and never (an untrained VAE: what the bonus itself
# costs); label -> overrides
VAE_SCHEDULES = {
    "vae, update_every=1": ["intrinsic.update_every=1"],
    "vae, update_every=8": ["intrinsic.update_every=8"],
    "vae, untrained": ["intrinsic.update_steps=0"],
}
PEER_ENVS = ("MiniGrid-MultiRoom-N3-S4-v0", "MiniGrid-DoorKey-8x8-v0")
MINIGRID_PIPELINE_ENVS = ("MiniGrid-DoorKey-8x8-v0", "MiniGrid-MultiRoom-N3-S4-v0")
MUJOCO_PIPELINE_ENVS = ("Hopper-v5", "HalfCheetah-v5")
A2C_NUM_ENVS = 16  # recipes/minigrid/config.yaml
# item 6: the bonuses (without and with the bonus's work in the training process),
# and the frames per env of the collector-alone batches (the A2C and PPO recipes')
WORKER_BONUSES = ("none", "vae")
COLLECTOR_STEPS = (8, 128)
DDPG_NUM_ENVS = 4  # recipes/ddpg_mujoco/config.yaml
# item 4: the envpool backend's goal over the raw loop (per CPU second)
ENVPOOL_PIPELINE_GOAL = 5.0
# item 7: each learner's frames per CPU second (its defaults: the elliptical VAE
# bonus) over a raw gymnasium loop of one env of this task, per backend; the goals
# are 3x the ratios at commit 6453210 (A2C 0.32, PPO 0.24, gymnasium backend)
RECIPE_TASK = "MiniGrid-MultiRoom-N3-S4-v0"
RECIPE_GOALS = {"a2c": 1.0, "ppo": 0.75}
RECIPE_AT_6453210 = {"a2c": 0.32, "ppo": 0.24}
RECIPE_BACKENDS = ("envpool", "gymnasium")
# item 3's goal: the A2C recipe with bonus=none over torch-ac
PEER_GOAL = 2.0
# item 8: shapes of a batch (envs x frames per env), by learner: overrides of the
# envpool run; the first is each learner's reference (A2C's defaults; PPO's former
# defaults, 16 x 128, since 64 x 32 became its defaults)
SHAPES = {
    "a2c": {
        "16 x 8 (defaults)": [],
        "64 x 8": ["env.num_envs=64"],
        "64 x 2": ["env.num_envs=64", "collector.frames_per_env=2"],
    },
    "ppo": {
        "16 x 128": ["env.num_envs=16", "collector.frames_per_env=128"],
        "64 x 32, minibatch 512": ["loss.minibatch_size=512"],
        "64 x 32, minibatch 256 (defaults)": [],
    },
}
SHAPE_PIPELINE_ENVS = 64
# item 9: the suite's experiment whose batch is measured, its settings (the first
# is the reference), and the goal of each bonus over it
SUITE_EXPERIMENT = "ppo/suite_doorkey16x16_16x512"
SUITE_SETTINGS = ("none", "e3b", "e3b_128", "noveld", "vae_noveld")
SUITE_BONUS_GOAL = 0.5
# item 10: the PPO recipe (defaults, envpool) over a hand-written PPO of the same
# settings, with each bonus (``+setting=...``); goal: no slower than by hand
PPO_BASELINE = ROOT / "benchmarks" / "ppo_baseline.py"
BASELINE_BONUSES = ("none", "vae_noveld")
#: Item 11: the suite task, its experiment, and each setting's committed study.
E2E_EXPERIMENT = "ppo/suite_keycorridor_s3r3"
E2E_SETUPS = {
    "none": (["+setting=none"], None, None),
    "vae_noveld": (["+setting=vae_noveld"], "suite_keycorridor_s3r3", "vae_noveld"),
    "vae_noveld, batch 512": (
        ["+setting=vae_noveld", "intrinsic.batch_size=512"],
        "vae_noveld_batch512_s3r3",
        "vae_noveld,intrinsic.batch_size=512",
    ),
}
E2E_BONUS_GOAL = 0.8
E2E_TIME_GOAL = 0.5
BASELINE_GOAL = 1.0

__all__ = ["main"]


# ---- measurement helpers ---------------------------------------------------------
def load() -> list[float]:
    return [round(x, 2) for x in os.getloadavg()]


@dataclass
class Child:
    returncode: int
    stdout: str
    stderr: str
    maxrss_bytes: int
    wall_s: float


def run_child(cmd: list[str]) -> Child:
    """Runs ``cmd`` to the end; its own peak resident memory from ``wait4``."""
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    with tempfile.TemporaryFile() as out, tempfile.TemporaryFile() as err:
        start = time.perf_counter()
        proc = subprocess.Popen(cmd, stdout=out, stderr=err, cwd=ROOT, env=env)
        _, status, usage = os.wait4(proc.pid, 0)
        proc.returncode = os.waitstatus_to_exitcode(status)
        wall = time.perf_counter() - start
        out.seek(0)
        err.seek(0)
        child = Child(
            proc.returncode,
            out.read().decode(errors="replace"),
            err.read().decode(errors="replace"),
            usage.ru_maxrss * 1024,  # kB on Linux
            wall,
        )
    if child.returncode != 0:
        raise RuntimeError(
            f"{' '.join(cmd)} failed ({child.returncode}):\n{child.stderr[-3000:]}"
        )
    return child


def last_scalar(run_dir: Path, logger: str, name: str) -> float:
    from common.scalar_logs import read_scalar_csv

    _, values = read_scalar_csv(run_dir / "logs" / logger / "scalars" / f"{name}.csv")
    return float(values[-1])


@dataclass
class Sample:
    value: float
    load1: float
    extra: dict = field(default_factory=dict)


def interleave(
    setups: dict[str, Callable[[], Sample]], rounds: int
) -> dict[str, list[Sample]]:
    """Runs every setup once per round, the order reversed every other round."""
    names = list(setups)
    samples: dict[str, list[Sample]] = {n: [] for n in names}
    for r in range(rounds):
        for name in names if r % 2 == 0 else names[::-1]:
            sample = setups[name]()
            print(
                f"    round {r + 1}/{rounds} {name}: {sample.value:,.1f} "
                f"(load {sample.load1:.2f})",
                flush=True,
            )
            samples[name].append(sample)
    return samples


def paired_ratio(samples: dict[str, list[Sample]], num: str, den: str) -> float:
    """Median over rounds of ``num / den`` measured in the same round."""
    return statistics.median(
        a.value / b.value for a, b in zip(samples[num], samples[den], strict=True)
    )


def med(samples: list[Sample]) -> float:
    return statistics.median(s.value for s in samples)


@dataclass
class Target:
    item: int
    name: str
    measured: float | None
    goal: float
    higher_is_better: bool = True
    note: str = ""

    @property
    def met(self) -> bool | None:
        if self.measured is None:
            return None
        if self.higher_is_better:
            return self.measured >= self.goal
        return self.measured <= self.goal


# ---- items 1, 3 and 6: the A2C recipe ---------------------------------------------
def a2c_recipe(
    bonus: str | None,
    env_name: str | None,
    frames: int,
    tmp: Path,
    workers: int = 1,
    extra: Sequence[str] = (),
    algo: str = "a2c",
    metric: str = "time/fps",
) -> Sample:
    """The MiniGrid recipe's own ``metric`` (``time/fps``: frames per second of its
    loop; ``time/fps_cpu``: per CPU second of its process) at the end of a run.
    ``bonus=None`` leaves the bonus to ``extra`` (a ``+setting=...``)."""
    run_dir = tmp / f"{algo}_{bonus}_{len(list(tmp.iterdir()))}"
    overrides = [
        f"algo={algo}",
        *extra,
        *([] if bonus is None else [f"bonus={bonus}"]),
        f"collector.total_frames={frames}",
        f"eval.interval_frames={10 * frames}",
        f"checkpoint.interval_frames={10 * frames}",
        f"hydra.run.dir={run_dir}",
    ]
    if env_name is not None:
        overrides.append(f"env.name={env_name}")
    if workers != 1:
        # the workers' start-up is not timed: the recipe times its training loop
        overrides.append(f"collector.workers={workers}")
    load1 = os.getloadavg()[0]
    child = run_child([sys.executable, str(A2C_MAIN), *overrides])
    fps = last_scalar(run_dir, algo, metric)
    return Sample(fps, load1, {"maxrss_bytes": child.maxrss_bytes})


# ---- item 3: the peer, torch-ac 1.4.0 ---------------------------------------------
class RLStarterACModel(nn.Module):
    """rl-starter-files' ``ACModel`` without memory or text (its defaults).

    torch-ac does not ship it: 3 conv layers (16/32/64) on the 7x7x3 image and
    64-unit actor and critic heads, its ``init_params``.
    """

    recurrent = False

    def __init__(self, num_actions: int):
        super().__init__()
        self.image_conv = nn.Sequential(
            nn.Conv2d(3, 16, (2, 2)),
            nn.ReLU(),
            nn.MaxPool2d((2, 2)),
            nn.Conv2d(16, 32, (2, 2)),
            nn.ReLU(),
            nn.Conv2d(32, 64, (2, 2)),
            nn.ReLU(),
        )
        self.actor = nn.Sequential(
            nn.Linear(64, 64), nn.Tanh(), nn.Linear(64, num_actions)
        )
        self.critic = nn.Sequential(nn.Linear(64, 64), nn.Tanh(), nn.Linear(64, 1))
        self.apply(self._init_params)

    @staticmethod
    def _init_params(m: nn.Module) -> None:
        if isinstance(m, nn.Linear):
            m.weight.data.normal_(0, 1)
            m.weight.data *= 1 / torch.sqrt(m.weight.data.pow(2).sum(1, keepdim=True))
            m.bias.data.fill_(0)

    def forward(self, obs):
        x = obs.image.transpose(1, 3).transpose(2, 3)
        x = self.image_conv(x)
        x = x.reshape(x.shape[0], -1)
        dist = torch.distributions.Categorical(
            logits=nn.functional.log_softmax(self.actor(x), dim=1)
        )
        return dist, self.critic(x).squeeze(1)


def collector_worker(workers: int, frames_per_env: int, frames: int) -> None:
    """The A2C recipe's collector alone, frames/s after its first batch; prints JSON."""
    from hydra import compose, initialize_config_dir

    from common.minigrid import (
        make_actor_critic,
        make_collector,
        make_env,
    )

    torch.set_num_threads(1)  # the recipe's torch_threads
    overrides = [
        f"collector.workers={workers}",
        f"collector.frames_per_env={frames_per_env}",
    ]
    with initialize_config_dir(config_dir=str(A2C_MAIN.parent), version_base=None):
        cfg = compose(config_name="config", overrides=overrides)
    torch.manual_seed(0)
    env = make_env(cfg.env, cfg.env.num_envs, seed=0)
    model, _ = make_actor_critic(env.action_spec, intrinsic_critic=False)
    batch = cfg.env.num_envs * frames_per_env
    batches = max(frames // batch, 2)
    collector = make_collector(
        env, model.get_policy_operator(), cfg, total_frames=(batches + 1) * batch
    )
    it = iter(collector)
    next(it)  # the first batch: the workers' first steps, not timed
    start, done = time.perf_counter(), 0
    for data in it:
        done += data.numel()
    fps = done / (time.perf_counter() - start)
    collector.shutdown()
    print(json.dumps({"fps": fps}))


def collector_frames_per_cpu_s(num_envs: int, frames: int) -> float:
    """One process's collector (the A2C recipe's envs and policy, 128 steps per
    env and batch): frames per CPU second of this single-threaded process."""
    from hydra import compose, initialize_config_dir

    from common.minigrid import (
        make_actor_critic,
        make_collector,
        make_env,
    )

    overrides = [f"env.num_envs={num_envs}", "collector.frames_per_env=128"]
    with initialize_config_dir(config_dir=str(A2C_MAIN.parent), version_base=None):
        cfg = compose(config_name="config", overrides=overrides)
    env = make_env(cfg.env, num_envs, seed=0)
    model, _ = make_actor_critic(env.action_spec, intrinsic_critic=False)
    batch = num_envs * 128
    batches = max(frames // batch, 2)
    collector = make_collector(
        env, model.get_policy_operator(), cfg, total_frames=(batches + 1) * batch
    )
    it = iter(collector)
    next(it)  # warm-up
    cpu, done = time.process_time(), 0
    for data in it:
        done += data.numel()
    cpu = time.process_time() - cpu
    collector.shutdown()
    return done / cpu


def collector_alone(workers: int, frames_per_env: int, frames: int) -> Sample:
    load1 = os.getloadavg()[0]
    args = ["--collector-worker", str(workers), str(frames_per_env), str(frames)]
    child = run_child([sys.executable, __file__, *args])
    fps = json.loads(child.stdout.strip().splitlines()[-1])["fps"]
    return Sample(fps, load1)


def peer_worker(env_name: str, frames: int, seed: int, threads: int) -> None:
    """torch-ac's A2C as rl-starter-files' train.py runs it; prints JSON."""
    import gymnasium as gym
    import torch_ac  # sets multiprocessing's start method: only in this process

    from torchrl_surprise.envs import register_minigrid_envs

    register_minigrid_envs()
    torch.set_num_threads(threads)
    torch.manual_seed(seed)

    def preprocess_obss(obss, device=None):
        # rl-starter-files' image preprocessing (its text tokenising is left out:
        # the model does not read the mission, and leaving it out favours the peer)
        images = torch.tensor(np.array([o["image"] for o in obss]), dtype=torch.float)
        return torch_ac.DictList({"image": images})

    envs = []
    for i in range(A2C_NUM_ENVS):
        env = gym.make(env_name)
        env.reset(seed=seed + 10000 * i)
        envs.append(env)
    model = RLStarterACModel(envs[0].action_space.n)
    algo = torch_ac.A2CAlgo(
        envs,
        model,
        torch.device("cpu"),
        num_frames_per_proc=8,
        discount=0.99,
        lr=1e-3,
        gae_lambda=0.95,
        entropy_coef=0.01,
        value_loss_coef=0.5,
        max_grad_norm=0.5,
        recurrence=1,
        rmsprop_alpha=0.99,
        rmsprop_eps=1e-8,
        preprocess_obss=preprocess_obss,
    )
    done, start = 0, time.perf_counter()
    while done < frames:
        exps, _ = algo.collect_experiences()
        algo.update_parameters(exps)
        done += algo.num_frames
    fps = done / (time.perf_counter() - start)
    print(json.dumps({"fps": fps}))


def peer(env_name: str, frames: int, threads: int) -> Sample:
    load1 = os.getloadavg()[0]
    child = run_child(
        [
            sys.executable,
            __file__,
            "--peer-worker",
            env_name,
            str(frames),
            "0",
            str(threads),
        ]
    )
    fps = json.loads(child.stdout.strip().splitlines()[-1])["fps"]
    return Sample(fps, load1)


# ---- item 2: DDPG ---------------------------------------------------------------
def ddpg_recipe(bonus: str, frames: int, tmp: Path) -> Sample:
    run_dir = tmp / f"ddpg_{bonus}_{len(list(tmp.iterdir()))}"
    overrides = [
        f"bonus={bonus}",
        "env.name=Hopper-v5",
        f"collector.total_frames={frames}",
        # Updates from the first batch on (the default warm-up is 25k random frames).
        "collector.init_random_frames=1000",
        f"eval.interval_frames={10 * frames}",
        f"checkpoint.interval_frames={10 * frames}",
        "logger.log_interval=1",
        f"hydra.run.dir={run_dir}",
    ]
    load1 = os.getloadavg()[0]
    child = run_child([sys.executable, str(DDPG_MAIN), *overrides])
    ups = last_scalar(run_dir, "ddpg", "time/updates_per_s")
    return Sample(ups, load1, {"maxrss_bytes": child.maxrss_bytes})


class _Actor(nn.Module):
    def __init__(self, obs_dim: int, act_dim: int, max_action: float = 1.0):
        super().__init__()
        self.l1 = nn.Linear(obs_dim, 256)
        self.l2 = nn.Linear(256, 256)
        self.l3 = nn.Linear(256, act_dim)
        self.max_action = max_action

    def forward(self, state):
        a = torch.relu(self.l1(state))
        a = torch.relu(self.l2(a))
        return self.max_action * torch.tanh(self.l3(a))


class _Critic(nn.Module):
    def __init__(self, obs_dim: int, act_dim: int):
        super().__init__()
        self.l1 = nn.Linear(obs_dim + act_dim, 256)
        self.l2 = nn.Linear(256, 256)
        self.l3 = nn.Linear(256, 1)

    def forward(self, state, action):
        q = torch.relu(self.l1(torch.cat([state, action], 1)))
        q = torch.relu(self.l2(q))
        return self.l3(q)


class BareDDPG:
    """OurDDPG's ``train`` (github.com/sfujim/TD3) in plain eager PyTorch.

    As the recipe: no target actor (TorchRL's ``DDPGLoss(delay_actor=False)``),
    a target critic with a soft update. The minibatch is drawn from numpy arrays
    as in OurDDPG's ``ReplayBuffer.sample``.
    """

    def __init__(self, obs_dim=11, act_dim=3, size=100_000, batch=256, seed=0):
        torch.manual_seed(seed)
        rng = np.random.default_rng(seed)
        self.actor = _Actor(obs_dim, act_dim)
        self.critic = _Critic(obs_dim, act_dim)
        self.critic_target = copy.deepcopy(self.critic)
        self.actor_optimizer = torch.optim.Adam(self.actor.parameters(), lr=3e-4)
        self.critic_optimizer = torch.optim.Adam(self.critic.parameters(), lr=3e-4)
        self.state = rng.standard_normal((size, obs_dim), dtype=np.float32)
        self.action = rng.uniform(-1, 1, (size, act_dim)).astype(np.float32)
        self.next_state = rng.standard_normal((size, obs_dim), dtype=np.float32)
        self.reward = rng.standard_normal((size, 1), dtype=np.float32)
        self.not_done = (rng.random((size, 1)) > 0.01).astype(np.float32)
        self.size, self.batch = size, batch
        self.discount, self.tau = 0.99, 0.005

    def train(self) -> None:
        ind = np.random.randint(0, self.size, size=self.batch)
        state = torch.FloatTensor(self.state[ind])
        action = torch.FloatTensor(self.action[ind])
        next_state = torch.FloatTensor(self.next_state[ind])
        reward = torch.FloatTensor(self.reward[ind])
        not_done = torch.FloatTensor(self.not_done[ind])
        target_q = self.critic_target(next_state, self.actor(next_state))
        target_q = reward + (not_done * self.discount * target_q).detach()
        current_q = self.critic(state, action)
        critic_loss = nn.functional.mse_loss(current_q, target_q)
        self.critic_optimizer.zero_grad()
        critic_loss.backward()
        self.critic_optimizer.step()
        actor_loss = -self.critic(state, self.actor(state)).mean()
        self.actor_optimizer.zero_grad()
        actor_loss.backward()
        self.actor_optimizer.step()
        for param, target_param in zip(
            self.critic.parameters(), self.critic_target.parameters()
        ):
            target_param.data.copy_(
                self.tau * param.data + (1 - self.tau) * target_param.data
            )


def product_gflops(size: int = 256, reps: int = 400) -> dict[str, float]:
    """GFLOP/s of a ``size``-cubed float32 product on one thread, MKL and oneDNN.

    The recipe's DDPG layers run their products on oneDNN (``OneDNNLinear``), the
    bare update's on MKL (``nn.Linear``): how the two libraries compare on the
    host decides much of item 2's ratio, so the table prints it.
    """
    from torchrl_surprise.modules.vae import _onednn_linear

    previous = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        x, w, b = torch.randn(size, size), torch.randn(size, size), torch.randn(size)
        calls = {"mkl": lambda: nn.functional.linear(x, w, b)}
        if _onednn_linear() is not None:
            calls["onednn"] = lambda: _onednn_linear()(x, w, b, "none", [], "")
        rates = {}
        for name, call in calls.items():
            for _ in range(20):
                call()
            start = time.perf_counter()
            for _ in range(reps):
                call()
            rates[name] = 2 * size**3 * reps / (time.perf_counter() - start) / 1e9
        return rates
    finally:
        torch.set_num_threads(previous)


def bare_ddpg(updates: int) -> Sample:
    previous = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        ddpg = BareDDPG()
        for _ in range(20):  # warm-up
            ddpg.train()
        load1 = os.getloadavg()[0]
        start = time.perf_counter()
        for _ in range(updates):
            ddpg.train()
        return Sample(updates / (time.perf_counter() - start), load1)
    finally:
        torch.set_num_threads(previous)


# ---- item 4: env pipeline -------------------------------------------------------
def ours_env(make: Callable, steps: int) -> Sample:
    env = make()
    try:
        n = max(env.batch_size.numel(), 1)
        env.rollout(10, break_when_any_done=False)  # warm-up
        horizon = max(steps // n, 1)
        load1 = os.getloadavg()[0]
        wall, cpu = time.perf_counter(), time.process_time()
        env.rollout(horizon, break_when_any_done=False)
        wall, cpu = time.perf_counter() - wall, time.process_time() - cpu
        steps = horizon * n
        return Sample(steps / cpu, load1, {"wall_steps_per_s": steps / wall})
    finally:
        env.close()


def raw_env(env_name: str, steps: int) -> Sample:
    import gymnasium as gym

    from torchrl_surprise.envs import register_minigrid_envs

    register_minigrid_envs()  # the paper's MultiRoom ids are not minigrid's own
    env = gym.make(env_name)
    env.reset(seed=0)
    env.action_space.seed(0)
    load1 = os.getloadavg()[0]
    wall, cpu = time.perf_counter(), time.process_time()
    for _ in range(steps):
        _, _, terminated, truncated, _ = env.step(env.action_space.sample())
        if terminated or truncated:
            env.reset()
    wall, cpu = time.perf_counter() - wall, time.process_time() - cpu
    env.close()
    return Sample(steps / cpu, load1, {"wall_steps_per_s": steps / wall})


# ---- item 5: replay buffer bytes -------------------------------------------------
def ddpg_buffer_bytes_per_transition(env_name: str) -> float:
    """Bytes per transition in the recipe's buffer, measured on a filled one."""
    spec = importlib.util.spec_from_file_location(
        "ddpg_mujoco_utils", DDPG_MAIN.parent / "utils.py"
    )
    utils = importlib.util.module_from_spec(spec)
    sys.path.insert(0, str(DDPG_MAIN.parent))
    try:
        spec.loader.exec_module(utils)
    finally:
        sys.path.remove(str(DDPG_MAIN.parent))
    from hydra import compose, initialize_config_dir

    with initialize_config_dir(config_dir=str(DDPG_MAIN.parent), version_base=None):
        cfg = compose(config_name="config", overrides=[f"env.name={env_name}"])
    env = utils.make_env(cfg.env, 2, seed=0)
    data = env.rollout(500, break_when_any_done=False).reshape(-1)
    env.close()
    size = data.numel()
    buffer = utils.make_replay_buffer(size)
    buffer.extend(data.select(*utils.replay_keys(None, "sample")))
    storage = buffer.storage.get(slice(None))  # public: the stored transitions
    nbytes = sum(
        t.numel() * t.element_size()
        for t in storage.values(include_nested=True, leaves_only=True)
    )
    return nbytes / size


# ---- the run ---------------------------------------------------------------------
@dataclass
class Plan:
    rounds: int
    a2c_frames: int
    peer_frames: int
    ddpg_frames: int
    bare_updates: int
    env_steps: int
    recipe_frames: int = 40_960


FULL = Plan(
    rounds=3,
    a2c_frames=20_000,
    peer_frames=20_000,
    ddpg_frames=4_000,
    bare_updates=1_500,
    env_steps=8_000,
)
QUICK = Plan(
    rounds=1,
    a2c_frames=4_000,
    peer_frames=4_000,
    ddpg_frames=2_000,
    bare_updates=300,
    env_steps=2_000,
    recipe_frames=8_192,
)


def machine() -> dict:
    model = platform.processor()
    try:
        for line in subprocess.run(
            ["lscpu"], capture_output=True, text=True, check=True
        ).stdout.splitlines():
            if line.startswith("Model name:"):
                model = line.split(":", 1)[1].strip()
    except (OSError, subprocess.CalledProcessError):
        pass
    mem = None
    with open("/proc/meminfo") as f:
        for line in f:
            if line.startswith("MemTotal:"):
                mem = round(int(line.split()[1]) / 1024**2, 1)
    return {
        "cpu": model,
        "cores": os.cpu_count(),
        "memory_gib": mem,
        "python": platform.python_version(),
        "torch": torch.__version__,
    }


# ---- item 10: the PPO recipe against a hand-written PPO -------------------------
def ppo_baseline(bonus: str, frames: int) -> Sample:
    """``benchmarks/ppo_baseline.py`` in a subprocess: its frames per CPU second of
    its training loop (start-up not timed, as the recipe's ``time/fps_cpu``)."""
    load1 = os.getloadavg()[0]
    child = run_child(
        [sys.executable, str(PPO_BASELINE), "--frames", str(frames), "--bonus", bonus]
    )
    result = json.loads(child.stdout.strip().splitlines()[-1])
    extra = {"maxrss_bytes": child.maxrss_bytes, "frames_per_s": result["fps"]}
    return Sample(result["fps_cpu"], load1, extra)


# ---- the items --------------------------------------------------------------------
@dataclass
class Bench:
    """What the items share: the command line, the plan, a scratch directory for
    the recipes' runs, and what they report (targets, details, peak memory)."""

    args: argparse.Namespace
    plan: Plan
    tmp: Path
    targets: list[Target] = field(default_factory=list)
    details: dict = field(default_factory=dict)
    rss: dict[str, int] = field(default_factory=dict)

    def note(self, line: str) -> None:
        self.details.setdefault("notes", []).append(line)


def by_setup(samples: dict[str, list[Sample]], unit: str, *extra: str) -> dict:
    """Each setup's samples, their load averages and the ``extra`` entries' values."""
    return {
        k: {
            unit: [s.value for s in v],
            **{e: [s.extra[e] for s in v] for e in extra},
            "load1": [s.load1 for s in v],
        }
        for k, v in samples.items()
    }


def item_bonus_overhead(b: Bench) -> None:
    print("[1] A2C recipe (defaults): bonus vs none, frames/s", flush=True)
    plan, tmp = b.plan, b.tmp
    setups = {
        n: lambda n=n: a2c_recipe(n, None, plan.a2c_frames, tmp)
        for n in ["none", *BONUSES]
    }
    for label, extra in VAE_SCHEDULES.items():
        setups[label] = lambda extra=extra: a2c_recipe(
            "vae", None, plan.a2c_frames, tmp, extra=extra
        )
    samples = interleave(setups, plan.rounds)
    b.details["a2c_bonus"] = by_setup(samples, "frames_per_s")
    for n in [*BONUSES, *VAE_SCHEDULES]:
        b.targets.append(
            Target(
                1,
                f"A2C {n} / none (frames/s)",
                paired_ratio(samples, n, "none"),
                0.90,
                note=f"{med(samples[n]):,.0f} / {med(samples['none']):,.0f}",
            )
        )
    b.rss["a2c"] = max(s.extra["maxrss_bytes"] for v in samples.values() for s in v)


def item_ddpg(b: Bench) -> None:
    print("[2] DDPG recipe (Hopper-v5) vs bare eager update, updates/s")
    plan, tmp = b.plan, b.tmp
    b.details["products_gflops"] = product_gflops()
    samples = interleave(
        {
            "bare eager": lambda: bare_ddpg(plan.bare_updates),
            "none": lambda: ddpg_recipe("none", plan.ddpg_frames, tmp),
            "vae": lambda: ddpg_recipe("vae", plan.ddpg_frames, tmp),
        },
        plan.rounds,
    )
    b.details["ddpg"] = by_setup(samples, "updates_per_s")
    bare, none = med(samples["bare eager"]), med(samples["none"])
    b.targets.append(
        Target(
            2,
            "DDPG recipe none / bare eager (updates/s)",
            paired_ratio(samples, "none", "bare eager"),
            1.0,
            note=f"{none:,.0f} / {bare:,.0f}; stretch 1.5x",
        )
    )
    b.targets.append(
        Target(
            2,
            "DDPG recipe vae / none (updates/s)",
            paired_ratio(samples, "vae", "none"),
            0.85,
            note=f"{med(samples['vae']):,.0f} / {none:,.0f}",
        )
    )
    b.rss["ddpg"] = max(
        s.extra["maxrss_bytes"]
        for k, v in samples.items()
        if k != "bare eager"
        for s in v
    )


def item_peer(b: Bench) -> None:
    print("[3] A2C recipe (bonus=none) vs torch-ac 1.4.0, frames/s")
    if importlib.util.find_spec("torch_ac") is None:
        msg = (
            "skipped: torch-ac is not installed "
            '(pip install -e ".[bench]" installs torch-ac==1.4.0)'
        )
        print(f"    {msg}")
        for env_name in PEER_ENVS:
            b.targets.append(
                Target(3, f"A2C ours / torch-ac, {env_name}", None, PEER_GOAL, note=msg)
            )
        return
    plan, tmp, threads = b.plan, b.tmp, b.args.peer_threads
    b.details["peer"] = {"threads": threads}
    for env_name in PEER_ENVS:
        samples = interleave(
            {
                "ours": lambda e=env_name: a2c_recipe("none", e, plan.peer_frames, tmp),
                "ours, envpool": lambda e=env_name: a2c_recipe(
                    "none", e, plan.peer_frames, tmp, extra=["env.backend=envpool"]
                ),
                "torch-ac": lambda e=env_name: peer(e, plan.peer_frames, threads),
            },
            plan.rounds,
        )
        b.details["peer"][env_name] = by_setup(samples, "frames_per_s")
        for ours, label in (("ours", ""), ("ours, envpool", ", envpool")):
            b.targets.append(
                Target(
                    3,
                    f"A2C ours{label} / torch-ac, {env_name.removeprefix('MiniGrid-')}",
                    paired_ratio(samples, ours, "torch-ac"),
                    PEER_GOAL,
                    note=f"{med(samples[ours]):,.0f} / {med(samples['torch-ac']):,.0f}",
                )
            )


def item_env_pipeline(b: Bench) -> None:
    from torchrl_surprise.envs import make_minigrid_env, make_mujoco_env

    # One process, one thread: its CPU time is what the steps cost, less
    # sensitive than wall time to the other jobs on a shared machine.
    print("[4] env pipeline vs a raw gymnasium loop, steps per CPU second")
    b.details["envs"] = {}
    pipelines = [
        (e, A2C_NUM_ENVS, make_minigrid_env) for e in MINIGRID_PIPELINE_ENVS
    ] + [(e, DDPG_NUM_ENVS, make_mujoco_env) for e in MUJOCO_PIPELINE_ENVS]
    torch.set_num_threads(1)
    for env_name, n, factory in pipelines:
        env_pipeline(b, env_name, n, factory)


def env_pipeline(b: Bench, env_name: str, n: int, factory: Callable) -> None:
    """Item 4 for one env: ``factory`` (and envpool's, for MiniGrid) over the raw loop."""
    from torchrl_surprise.envs import make_minigrid_env

    steps = b.plan.env_steps
    ours = f"{factory.__name__}(num_envs={n})"
    setups = {
        ours: lambda: ours_env(lambda: factory(env_name, num_envs=n, seed=0), steps),
        "raw gymnasium": lambda: raw_env(env_name, steps),
    }
    envpool = f"{factory.__name__}(num_envs={n}, backend=envpool)"
    if factory is make_minigrid_env:
        # the C++ port: several times the steps, so several times as many
        setups[envpool] = lambda: ours_env(
            lambda: make_minigrid_env(
                env_name, num_envs=n, seed=0, backend="envpool", num_threads=1
            ),
            4 * steps,
        )
    samples = interleave(setups, b.plan.rounds + 2)  # short measurements: 2 more
    b.details["envs"][env_name] = {
        k: {
            "steps_per_cpu_s": [s.value for s in v],
            "steps_per_s": [s.extra["wall_steps_per_s"] for s in v],
            "load1": [s.load1 for s in v],
        }
        for k, v in samples.items()
    }
    wall_ratio = statistics.median(
        a.extra["wall_steps_per_s"] / r.extra["wall_steps_per_s"]
        for a, r in zip(samples[ours], samples["raw gymnasium"])
    )
    raw = med(samples["raw gymnasium"])
    short = env_name.removeprefix("MiniGrid-")
    b.targets.append(
        Target(
            4,
            f"{ours} / raw, {short}",
            paired_ratio(samples, ours, "raw gymnasium"),
            0.9,
            note=f"{med(samples[ours]):,.0f} / {raw:,.0f} steps/CPU-s; "
            f"wall clock {wall_ratio:.2f}x",
        )
    )
    if envpool in samples:
        b.targets.append(
            Target(
                4,
                f"{factory.__name__}({n}, envpool) / raw, {short}",
                paired_ratio(samples, envpool, "raw gymnasium"),
                ENVPOOL_PIPELINE_GOAL,
                note=f"{med(samples[envpool]):,.0f} / {raw:,.0f} steps/CPU-s; "
                "1 envpool thread",
            )
        )


def item_memory(b: Bench) -> None:
    print("[5] memory")
    rss = b.rss
    mem: dict = {"peak_rss_bytes": rss}
    for env_name in ("HalfCheetah-v5", "Hopper-v5"):
        per = ddpg_buffer_bytes_per_transition(env_name)
        mem[f"ddpg_buffer_bytes_per_transition_{env_name}"] = per
    per = max(v for k, v in mem.items() if k.startswith("ddpg_buffer"))
    buffer_1m = per * 1_000_000
    mem["ddpg_buffer_1M_bytes"] = buffer_1m
    b.details["memory"] = mem
    ddpg_run = rss["ddpg"] + buffer_1m
    b.targets.append(
        Target(
            5,
            "2 DDPG runs (1M buffer) / 24 GiB",
            2 * ddpg_run / MEMORY_LIMIT,
            1.0,
            higher_is_better=False,
            note=f"2 x ({rss['ddpg'] / GIB:.2f} GiB peak + "
            f"{buffer_1m / GIB:.2f} GiB buffer, {per:.0f} B/transition)",
        )
    )
    b.targets.append(
        Target(
            5,
            "2 A2C runs / 24 GiB",
            2 * rss["a2c"] / MEMORY_LIMIT,
            1.0,
            higher_is_better=False,
            note=f"2 x {rss['a2c'] / GIB:.2f} GiB peak",
        )
    )


def workers_ratio(b: Bench, key: str, name: str, measure: Callable, note: str) -> None:
    """Item 6: ``measure(workers)`` with 2 workers over 1, interleaved."""
    samples = interleave(
        {f"{w} worker{'s' * (w > 1)}": lambda w=w: measure(w) for w in (1, 2)},
        b.plan.rounds,
    )
    b.details["a2c_workers"][key] = by_setup(samples, "frames_per_s")
    one, two = med(samples["1 worker"]), med(samples["2 workers"])
    b.targets.append(
        Target(
            6,
            name,
            paired_ratio(samples, "2 workers", "1 worker"),
            1.0,
            note=f"{two:,.0f} / {one:,.0f}{note}",
        )
    )


def item_workers(b: Bench) -> None:
    print("[6] A2C recipe (defaults): 2 collector workers vs 1, frames/s")
    plan, tmp = b.plan, b.tmp
    b.details["a2c_workers"] = {"cores": os.cpu_count()}
    for bonus in WORKER_BONUSES:
        workers_ratio(
            b,
            bonus,
            f"A2C {bonus}: 2 collector workers / 1 (frames/s)",
            lambda w, bonus=bonus: a2c_recipe(
                bonus, None, plan.a2c_frames, tmp, workers=w
            ),
            f"; {os.cpu_count()} cores",
        )
    for steps in COLLECTOR_STEPS:
        workers_ratio(
            b,
            f"collector_16x{steps}",
            f"collector alone, 16 envs x {steps}: 2 workers / 1",
            lambda w, s=steps: collector_alone(w, s, plan.a2c_frames),
            " frames/s",
        )
    torch.set_num_threads(1)
    per_cpu_s = {
        n: statistics.median(
            collector_frames_per_cpu_s(n, plan.a2c_frames) for _ in range(plan.rounds)
        )
        for n in (16, 8, 4, 2)
    }
    b.details["a2c_workers"]["collector_frames_per_cpu_s"] = per_cpu_s
    b.note(
        "6  one process's collector, frames per CPU second by envs per "
        "process: "
        + ", ".join(
            f"{n}: {v:,.0f} ({v / per_cpu_s[16]:.2f}x)" for n, v in per_cpu_s.items()
        )
    )


def recipe_per_cpu_s(b: Bench, algo: str, extra: Sequence[str]) -> Sample:
    """The MiniGrid recipe's ``time/fps_cpu`` (items 7 to 10): its defaults' bonus
    unless ``extra`` sets one."""
    bonus = None if any(e.startswith("+setting=") for e in extra) else "vae"
    return a2c_recipe(
        bonus,
        None,
        b.plan.recipe_frames,
        b.tmp,
        extra=list(extra),
        algo=algo,
        metric="time/fps_cpu",
    )


def item_learners(b: Bench) -> None:
    # The recipe's frames per CPU second of its process (time/fps_cpu: its loop,
    # all its threads) over this process's raw loop, steps per CPU second: both
    # what one core does, which the machine's load moves less than wall clock.
    print(
        "[7] the learners (defaults) vs a raw gymnasium loop of one "
        f"{RECIPE_TASK} env, per CPU second",
        flush=True,
    )
    torch.set_num_threads(1)
    setups = {"raw gymnasium": lambda: raw_env(RECIPE_TASK, b.plan.env_steps)}
    for algo in RECIPE_GOALS:
        for backend in RECIPE_BACKENDS:
            setups[f"{algo}, {backend}"] = lambda a=algo, e=backend: recipe_per_cpu_s(
                b, a, [f"env.backend={e}"]
            )
    samples = interleave(setups, b.plan.rounds)
    b.details["recipes_vs_raw"] = by_setup(samples, "per_cpu_s")
    raw = med(samples["raw gymnasium"])
    for algo, goal in RECIPE_GOALS.items():
        for backend in RECIPE_BACKENDS:
            name = f"{algo}, {backend}"
            b.targets.append(
                Target(
                    7,
                    f"{algo.upper()} recipe ({backend}) / raw loop, frames per CPU-s",
                    paired_ratio(samples, name, "raw gymnasium"),
                    goal,
                    note=f"{med(samples[name]):,.0f} / {raw:,.0f}; "
                    f"6453210: {RECIPE_AT_6453210[algo]:.2f}x",
                )
            )


def item_shapes(b: Bench) -> None:
    print(
        "[8] more envs a step: the learners (envpool) and the env pipeline "
        "vs a raw gymnasium loop of one env, per CPU second",
        flush=True,
    )
    torch.set_num_threads(1)
    setups = {"raw gymnasium": lambda: raw_env(RECIPE_TASK, b.plan.env_steps)}
    for algo, shapes in SHAPES.items():
        for shape, overrides in shapes.items():
            setups[f"{algo}, {shape}"] = lambda a=algo, o=overrides: recipe_per_cpu_s(
                b, a, ["env.backend=envpool", *o]
            )
    samples = interleave(setups, b.plan.rounds)
    b.details["shapes"] = {
        k: {"per_cpu_s": [s.value for s in v], "load1": [s.load1 for s in v]}
        for k, v in samples.items()
    }
    raw = med(samples["raw gymnasium"])
    for algo, shapes in SHAPES.items():
        reference, *others = shapes
        for shape in shapes:
            name = f"{algo}, {shape}"
            note = f"{med(samples[name]):,.0f} / {raw:,.0f}"
            if shape in others:
                ratio = paired_ratio(samples, name, f"{algo}, {reference}")
                note += f"; {ratio:.2f}x {reference}"
            b.targets.append(
                Target(
                    8,
                    f"{algo.upper()} {shape} (envpool) / raw loop",
                    paired_ratio(samples, name, "raw gymnasium"),
                    RECIPE_GOALS[algo],
                    note=note,
                )
            )
    shape_pipelines(b)


def shape_pipelines(b: Bench) -> None:
    """Item 8's env pipelines: 16 and 64 envpool envs over the raw loop."""
    from torchrl_surprise.envs import make_minigrid_env

    steps = b.plan.env_steps
    b.details["shape_pipelines"] = {}
    for env_name in MINIGRID_PIPELINE_ENVS:
        setups = {
            "raw gymnasium": lambda e=env_name: raw_env(e, steps),
            **{
                f"envpool, {n} envs": lambda e=env_name, n=n: ours_env(
                    lambda: make_minigrid_env(
                        e, num_envs=n, seed=0, backend="envpool", num_threads=1
                    ),
                    4 * steps,
                )
                for n in (A2C_NUM_ENVS, SHAPE_PIPELINE_ENVS)
            },
        }
        samples = interleave(setups, b.plan.rounds + 2)
        b.details["shape_pipelines"][env_name] = {
            k: [s.value for s in v] for k, v in samples.items()
        }
        for n in (A2C_NUM_ENVS, SHAPE_PIPELINE_ENVS):
            name = f"envpool, {n} envs"
            b.targets.append(
                Target(
                    8,
                    f"make_minigrid_env({n}, envpool) / raw, "
                    f"{env_name.removeprefix('MiniGrid-')}",
                    paired_ratio(samples, name, "raw gymnasium"),
                    ENVPOOL_PIPELINE_GOAL,
                    note=f"{med(samples[name]):,.0f} / "
                    f"{med(samples['raw gymnasium']):,.0f} steps/CPU-s",
                )
            )


def with_peak_memory(samples: dict[str, list[Sample]]) -> dict:
    """Items 9 and 10's details: frames per CPU second, load, peak memory."""
    return {
        k: {
            "per_cpu_s": [s.value for s in v],
            "load1": [s.load1 for s in v],
            "maxrss_bytes": max(s.extra["maxrss_bytes"] for s in v),
        }
        for k, v in samples.items()
    }


def item_suite(b: Bench) -> None:
    print(
        "[9] the suite's bonuses: PPO on DoorKey-16x16's batch (16 x 512, "
        "envpool), each setting over the plain learner, per CPU second",
        flush=True,
    )
    setups = {
        setting: lambda s=setting: recipe_per_cpu_s(
            b, "ppo", [f"+experiment={SUITE_EXPERIMENT}", f"+setting={s}"]
        )
        for setting in SUITE_SETTINGS
    }
    samples = interleave(setups, b.plan.rounds)
    b.details["suite_settings"] = with_peak_memory(samples)
    reference, *bonuses = SUITE_SETTINGS
    for setting in bonuses:
        b.targets.append(
            Target(
                9,
                f"PPO 16 x 512, +setting={setting} / {reference}",
                paired_ratio(samples, setting, reference),
                SUITE_BONUS_GOAL,
                note=f"{med(samples[setting]):,.0f} / "
                f"{med(samples[reference]):,.0f} frames/CPU-s",
            )
        )
    b.note(
        "9: e3b_128 over e3b (the embedding 128 instead of 1024 wide): "
        f"{paired_ratio(samples, 'e3b_128', 'e3b'):.2f}x"
    )
    b.note(
        "9: peak resident memory of one recipe process: "
        + ", ".join(
            f"{k} {v['maxrss_bytes'] / GIB:.2f} GiB"
            for k, v in b.details["suite_settings"].items()
        )
    )


def item_ppo_baseline(b: Bench) -> None:
    # Both sides time their training loop in CPU seconds of their own process
    # (start-up excluded), on the same envpool env, batch and settings.
    print(
        "[10] the PPO recipe (defaults, envpool) vs a hand-written PPO "
        "(benchmarks/ppo_baseline.py), per CPU second",
        flush=True,
    )
    frames = b.plan.recipe_frames
    setups = {}
    for bonus in BASELINE_BONUSES:
        setups[f"recipe, {bonus}"] = lambda s=bonus: recipe_per_cpu_s(
            b, "ppo", [f"+setting={s}"]
        )
        setups[f"hand-written, {bonus}"] = lambda s=bonus: ppo_baseline(s, frames)
    samples = interleave(setups, b.plan.rounds)
    b.details["ppo_baseline"] = with_peak_memory(samples)
    for bonus in BASELINE_BONUSES:
        recipe, hand = f"recipe, {bonus}", f"hand-written, {bonus}"
        b.targets.append(
            Target(
                10,
                f"PPO recipe / hand-written PPO, {bonus}",
                paired_ratio(samples, recipe, hand),
                BASELINE_GOAL,
                note=f"{med(samples[recipe]):,.0f} / {med(samples[hand]):,.0f} "
                "frames/CPU-s",
            )
        )


def committed_frames_to(
    study: str, setting: str, fraction: float = 0.9
) -> tuple[float, str]:
    """The median frames to ``fraction`` of the oracle of a setting's runs in a
    committed study, and how many seeds got there."""
    import csv

    path = ROOT / "docs" / "results" / study / "summary.csv"
    with open(path) as f:
        row = next(r for r in csv.DictReader(f) if r["setting"] == setting)
    frames = row[f"median_frames_to_{fraction}"]
    return float(frames), f"{row[f'seeds_reaching_{fraction}']}/{row['seeds']} seeds"


def item_end_to_end(b: Bench) -> None:
    print(
        "[11] vae_noveld end to end on KeyCorridorS3R3: per CPU second over "
        "none, and CPU seconds to 0.9 of the oracle (committed frames / rate here)",
        flush=True,
    )
    setups = {
        name: lambda extra=extra: recipe_per_cpu_s(
            b, "ppo", [f"+experiment={E2E_EXPERIMENT}", *extra]
        )
        for name, (extra, _, _) in E2E_SETUPS.items()
    }
    samples = interleave(setups, b.plan.rounds)
    b.details["end_to_end"] = with_peak_memory(samples)
    seconds = {}
    for name, (_, study, setting) in E2E_SETUPS.items():
        if study is None:
            continue
        b.targets.append(
            Target(
                11,
                f"KeyCorridorS3R3, {name} / none",
                paired_ratio(samples, name, "none"),
                E2E_BONUS_GOAL,
                note=f"{med(samples[name]):,.0f} / {med(samples['none']):,.0f} "
                "frames/CPU-s",
            )
        )
        frames, reached = committed_frames_to(study, setting)
        seconds[name] = frames / med(samples[name])
        b.note(
            f"11: {name}: {frames:,.0f} frames to 0.9 of the oracle (median, "
            f"{reached}) / {med(samples[name]):,.0f} frames/CPU-s = "
            f"{seconds[name]:,.0f} CPU s"
        )
    cheap, full = seconds["vae_noveld, batch 512"], seconds["vae_noveld"]
    b.targets.append(
        Target(
            11,
            "KeyCorridorS3R3, CPU s to 0.9: batch 512 / whole batch",
            cheap / full,
            E2E_TIME_GOAL,
            note=f"{cheap:,.0f} / {full:,.0f} CPU s",
            higher_is_better=False,
        )
    )


# item -> (its function, the items that need it run)
ITEMS: dict[int, tuple[Callable[[Bench], None], tuple[int, ...]]] = {
    1: (item_bonus_overhead, (1, 5)),  # item 5 reads its peak memory
    2: (item_ddpg, (2, 5)),
    3: (item_peer, (3,)),
    4: (item_env_pipeline, (4,)),
    5: (item_memory, (5,)),
    6: (item_workers, (6,)),
    7: (item_learners, (7,)),
    8: (item_shapes, (8,)),
    9: (item_suite, (9,)),
    10: (item_ppo_baseline, (10,)),
    11: (item_end_to_end, (11,)),
}


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="a fast smoke run")
    parser.add_argument("--items", type=int, nargs="+", default=list(ITEMS))
    parser.add_argument("--rounds", type=int, help="interleaved rounds per ratio")
    parser.add_argument("--peer-threads", type=int, default=1)
    parser.add_argument("--out", help="output path prefix (.json and .txt added)")
    parser.add_argument("--peer-worker", nargs=4, help=argparse.SUPPRESS)
    parser.add_argument("--collector-worker", nargs=3, help=argparse.SUPPRESS)
    return parser.parse_args(argv)


def main(argv: list[str] | None = None) -> dict:
    args = parse_args(argv)
    if args.collector_worker:
        collector_worker(*(int(a) for a in args.collector_worker))
        return {}
    if args.peer_worker:
        env_name, frames, seed, threads = args.peer_worker
        peer_worker(env_name, int(frames), int(seed), int(threads))
        return {}
    plan = QUICK if args.quick else FULL
    if args.rounds:
        plan.rounds = args.rounds
    if args.out:
        out = Path(args.out)
    elif args.quick:
        out = Path(tempfile.mkdtemp(prefix="bench_speed_")) / "bench_speed_quick"
    else:
        out = ROOT / "docs" / "results" / "bench_speed"
    sys.path.insert(0, str(ROOT))
    started = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp_dir:
        bench = Bench(args, plan, Path(tmp_dir))
        bench.details.update({"plan": asdict(plan), "load_start": load()})
        for run, needed_by in ITEMS.values():
            if any(i in args.items for i in needed_by):
                run(bench)
    details = bench.details
    details["load_end"] = load()
    details["minutes"] = round((time.perf_counter() - started) / 60, 1)
    return write_result(bench, out)


def write_result(b: Bench, out: Path) -> dict:
    """Prints the table and writes ``<out>.txt`` and ``<out>.json``."""
    text = render(b.targets, b.details, b.plan)
    if b.args.quick:
        text += (
            "\n--quick: a smoke run; its budgets are too short for the ratios to "
            "mean much (the recipes' first iterations dominate)"
        )
    print(text)
    result = {
        "machine": machine(),
        "quick": b.args.quick,
        "targets": [
            {
                **asdict(t),
                "met": t.met,
                "goal_kind": ">=" if t.higher_is_better else "<=",
            }
            for t in b.targets
        ],
        "details": b.details,
    }
    out.parent.mkdir(parents=True, exist_ok=True)
    out.with_suffix(".json").write_text(json.dumps(result, indent=2) + "\n")
    out.with_suffix(".txt").write_text(text + "\n")
    print(f"wrote {out.with_suffix('.json')} and {out.with_suffix('.txt')}")
    return result


def render(targets: list[Target], details: dict, plan: Plan) -> str:
    m = machine()
    lines = [
        f"{m['cpu']}, {m['cores']} cores, {m['memory_gib']} GiB; torch {m['torch']}; "
        f"{plan.rounds} interleaved rounds, median of per-round ratios",
        f"load average {details['load_start']} at start, {details['load_end']} at end "
        f"({details['minutes']} min)",
        "",
        f"{'#':<2} {'target':<52} {'measured':>9} {'goal':>7}  {'met?':<5} details",
        "-" * 110,
    ]
    for t in targets:
        measured = "-" if t.measured is None else f"{t.measured:.2f}x"
        goal = f"{'>=' if t.higher_is_better else '<='}{t.goal:.2f}"
        met = {True: "yes", False: "NO", None: "skip"}[t.met]
        lines.append(
            f"{t.item:<2} {t.name:<52} {measured:>9} {goal:>7}  {met:<5} {t.note}"
        )
    if "products_gflops" in details:
        rates = details["products_gflops"]
        lines.append(
            "2: 256x256x256 float32 product on one thread: "
            + ", ".join(f"{k} {v:.0f} GFLOP/s" for k, v in rates.items())
            + " (the recipe's DDPG layers use oneDNN, the bare update MKL)"
        )
    lines += details.get("notes", [])
    return "\n".join(lines)


if __name__ == "__main__":
    main()
