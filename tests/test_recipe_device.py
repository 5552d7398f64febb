"""The MiniGrid recipe's ``device`` setting and its one-call policy.

``device`` (cpu | cuda | auto) places the policy, critics and bonus model; the envs
stay on the CPU. Without a GPU here, these check the CPU and auto paths end to end,
the refusal of ``cuda`` and what ``auto`` picks when torch sees a GPU.
:class:`SampledCategoricalPolicy` (the policy the collector, the evaluation and
the videos run) must write what the policy operator writes, draw for draw.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest
import torch
from _recipe_run import load_recipe_utils
from hydra import compose, initialize_config_dir
from tensordict import TensorDict
from torchrl.data import Categorical as CategoricalSpec
from torchrl.envs.utils import ExplorationType, set_exploration_type

from common.minigrid import make_actor_critic, make_collector, make_env

RECIPE = Path(__file__).resolve().parents[1] / "recipes" / "minigrid"
MAIN = RECIPE / "main.py"
utils = load_recipe_utils(RECIPE)


def _config(*overrides: str):
    with initialize_config_dir(config_dir=str(RECIPE), version_base=None):
        return compose("config", overrides=list(overrides))


def _observations(n: int = 5) -> TensorDict:
    g = torch.Generator().manual_seed(1)
    image = torch.randint(0, 11, (n, 7, 7, 3), generator=g, dtype=torch.uint8)
    return TensorDict(image=image, batch_size=[n])


@pytest.mark.parametrize("return_log_prob", [False, True])
def test_one_call_policy_writes_what_the_policy_operator_writes(return_log_prob):
    torch.manual_seed(0)
    model, _ = make_actor_critic(
        CategoricalSpec(7), intrinsic_critic=False, return_log_prob=return_log_prob
    )
    operator = model.get_policy_operator()
    fast = utils.SampledCategoricalPolicy(operator)
    assert fast._fast  # the one-call path, not the fallback
    obs = _observations()
    with torch.no_grad(), set_exploration_type(ExplorationType.RANDOM):
        torch.manual_seed(7)
        expected = [operator(obs.clone()) for _ in range(3)]
        torch.manual_seed(7)
        got = [fast(obs.clone()) for _ in range(3)]
    for want, have in zip(expected, got, strict=True):
        assert set(have.keys()) == set(want.keys())
        for key in want.keys():
            assert torch.equal(have[key], want[key]), key
    # greedy evaluation goes through the operator: the mode of the policy
    with torch.no_grad(), set_exploration_type(ExplorationType.DETERMINISTIC):
        greedy = fast(obs.clone())["action"]
        assert torch.equal(greedy, operator(obs.clone())["action"])
    # a collector's checkpoint holds the operator's keys, and loads back
    assert list(fast.state_dict()) == list(operator.state_dict())
    fast.load_state_dict(operator.state_dict())


def test_one_call_policy_on_a_device_takes_observations_from_the_envs():
    torch.manual_seed(0)
    model, _ = make_actor_critic(CategoricalSpec(7), intrinsic_critic=False)
    operator = model.get_policy_operator()
    fast = utils.SampledCategoricalPolicy(operator, device="cpu")
    obs = _observations()
    with torch.no_grad(), set_exploration_type(ExplorationType.RANDOM):
        torch.manual_seed(3)
        want = operator(obs.clone())
        torch.manual_seed(3)
        have = fast(obs.clone())
    assert torch.equal(have["action"], want["action"])
    assert have["action"].device == obs["image"].device


def test_resolve_device(monkeypatch):
    assert utils.resolve_device("cpu") == torch.device("cpu")
    if not torch.cuda.is_available():
        assert utils.resolve_device("auto") == torch.device("cpu")
        with pytest.raises(
            RuntimeError, match="device=cuda.*no CUDA device.*device=cpu"
        ):
            utils.resolve_device("cuda")
    monkeypatch.setattr(torch.cuda, "is_available", lambda: True)
    assert utils.resolve_device("auto") == torch.device("cuda")
    assert utils.resolve_device("cuda") == torch.device("cuda")
    with pytest.raises(ValueError, match="'cpu', 'cuda', 'auto'.*'gpu'"):
        utils.resolve_device("gpu")


def test_device_is_cpu_by_default_and_a_bad_one_is_refused():
    assert _config().device == "cpu"
    from common.config import validate_minigrid

    with pytest.raises(ValueError, match="device must be one of 'cpu', 'cuda', 'auto'"):
        validate_minigrid(_config("device=gpu"))


def test_collector_on_a_device_collects_the_same_batch():
    # An explicit device puts the policy and the stored batch there (the envs on
    # the CPU); on the CPU the batch is the one collected without devices.
    cfg = _config("env.backend=envpool", "env.num_envs=4", "collector.frames_per_env=8")

    def batch(device):
        torch.manual_seed(0)
        env = make_env(cfg.env, cfg.env.num_envs, seed=0)
        model, _ = make_actor_critic(env.action_spec, intrinsic_critic=False)
        policy = utils.SampledCategoricalPolicy(model.get_policy_operator(), device)
        collector = make_collector(env, policy, cfg, total_frames=-1, device=device)
        data = next(iter(collector))
        collector.shutdown()
        return collector, data

    collector, on_cpu = batch(torch.device("cpu"))
    assert collector.policy_device == collector.storing_device == torch.device("cpu")
    assert collector.env_device == torch.device("cpu")
    assert on_cpu.device == torch.device("cpu")
    _, plain = batch(None)
    assert set(on_cpu.keys(True)) == set(plain.keys(True))
    for key in plain.keys(True, True):
        assert torch.equal(on_cpu[key], plain[key]), key


def _run(tmp_path: Path, *overrides: str):
    cmd = [
        sys.executable,
        str(MAIN),
        f"hydra.run.dir={tmp_path / 'run'}",
        "env.num_envs=4",
        "collector.total_frames=64",
        "eval.interval_frames=64",
        "eval.episodes=2",
        "eval.num_envs=2",
        *overrides,
    ]
    return subprocess.run(cmd, capture_output=True, text=True, timeout=300)


def test_recipe_runs_with_device_auto(tmp_path):
    proc = _run(tmp_path, "device=auto")
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert "Done: 64 frames" in proc.stdout


@pytest.mark.skipif(torch.cuda.is_available(), reason="a GPU is there")
def test_recipe_refuses_cuda_without_a_gpu(tmp_path):
    proc = _run(tmp_path, "device=cuda")
    assert proc.returncode != 0
    assert "device=cuda, but torch sees no CUDA device" in proc.stderr
    assert "device=cpu" in proc.stderr
    # refused before anything is built or written
    assert not (tmp_path / "run" / "checkpoint.torchrl").exists()
