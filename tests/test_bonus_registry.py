"""One bonus registry (recipes/common/bonuses.py): every list of bonuses reads it,
and a bonus declared in this file alone runs end to end under A2C and PPO."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import pytest
import torch

from common.bonuses import BONUSES, Bonus, bonus_choices, register_bonus
from common.checkpoint import load_checkpoint
from common.config import MiniGridConfig
from common.rundir import unused_bonus_sections
from torchrl_surprise import RNDDistillationLoss, RNDModel
from torchrl_surprise.transforms import IntrinsicRewardTransform

ROOT = Path(__file__).resolve().parents[1]
MAIN = ROOT / "recipes" / "minigrid" / "main.py"
NAME = "next_state_novelty"


class NextStateNovelty(IntrinsicRewardTransform):
    """RND's error on the next state alone: a bonus the library does not have."""

    def __init__(self, rnd: RNDModel, **kwargs):
        super().__init__(rnd.in_keys, **kwargs)
        self.rnd = rnd

    def _compute_bonus(self, tensordict, next_tensordict):
        observations = self._observations(next_tensordict, "the 'next' tensordict")
        return self.rnd.novelty(*observations)


def build_next_state_novelty(cfg, action_spec, common):
    rnd = RNDModel.for_minigrid(embedding_dim=16, hidden_dim=32)
    return NextStateNovelty(rnd, **common), RNDDistillationLoss(rnd), None


def register() -> None:
    """Declares the bonus: one entry (what a user's module does once)."""
    register_bonus(Bonus(NAME, build_next_state_novelty, model_attr="rnd"))


def test_the_config_choices_and_the_resume_rule_read_the_registry():
    assert bonus_choices() == ("none", *BONUSES)
    field = MiniGridConfig.__dataclass_fields__["bonus"].metadata["rule"]
    assert all(field.holds(name) for name in bonus_choices())
    assert not field.holds("nosuchbonus")
    # every other bonus's section may change on resume, whichever bonus runs
    config = {"bonus": "e3b", "intrinsic": {"coef": 0.1}}
    config["intrinsic"].update({b.section: {} for b in BONUSES.values() if b.section})
    others = {f"intrinsic.{b.section}" for b in BONUSES.values() if b.name != "e3b"}
    assert set(unused_bonus_sections(config)) == others - {"intrinsic.None"}


def test_the_docs_list_every_bonus():
    # config.yaml's comment on bonus, and the recipes page's ``bonus=`` entry
    yaml = (ROOT / "recipes" / "minigrid" / "config.yaml").read_text()
    line = next(x for x in yaml.splitlines() if x.startswith("bonus:"))
    listed = re.findall(r"\w+", line.split("#", 1)[1])[: len(bonus_choices())]
    assert listed == list(bonus_choices())
    page = (ROOT / "docs" / "recipes.rst").read_text()
    entry = page.split("\n``bonus=``\n", 1)[1].split("\n\n", 1)[0]
    assert [name for name in bonus_choices() if f"``{name}``" not in entry] == []


def test_a_name_is_registered_once():
    with pytest.raises(ValueError, match="already registered"):
        register_bonus(Bonus("vae", build_next_state_novelty))
    with pytest.raises(ValueError, match="already registered"):
        register_bonus(Bonus("none", build_next_state_novelty))


LEARNERS = {
    "a2c": ["algo=a2c", "env.num_envs=4", "collector.frames_per_env=8"],
    "ppo": [
        "algo=ppo",
        "env.num_envs=4",
        "collector.frames_per_env=32",
        "loss.epochs=2",
        "loss.minibatch_size=64",
    ],
}


@pytest.mark.parametrize("algo", sorted(LEARNERS))
def test_a_bonus_registered_in_a_test_file_runs_end_to_end(tmp_path, algo):
    # The recipe's own script, run after this file's register(): the config
    # accepts the name, make_bonus builds it, the run trains and checkpoints it.
    argv = [
        str(MAIN),
        f"bonus={NAME}",
        f"hydra.run.dir={tmp_path}",
        "env.name=MiniGrid-MultiRoom-N3-S4-v0",
        "collector.total_frames=256",
        "eval.interval_frames=256",
        "eval.episodes=2",
        "eval.num_envs=2",
        "checkpoint.interval_frames=128",
        *LEARNERS[algo],
    ]
    code = (
        "import runpy, sys\n"
        f"sys.path[:0] = [{str(ROOT / 'tests')!r}, {str(ROOT / 'recipes')!r}, "
        f"{str(MAIN.parent)!r}]\n"
        "import test_bonus_registry\n"
        "test_bonus_registry.register()\n"
        f"sys.argv = {argv!r}\n"
        f"runpy.run_path({str(MAIN)!r}, run_name='__main__')\n"
    )
    proc = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=300
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert "Done: 256 frames" in proc.stdout
    state = load_checkpoint(tmp_path / "checkpoint.torchrl")
    assert state["config"]["bonus"] == NAME
    weights = [k for k in state["bonus_transform"] if k.startswith("rnd.predictor")]
    assert weights and all(
        torch.isfinite(state["bonus_transform"][k]).all() for k in weights
    )
    logged = tmp_path.glob("logs/*/scalars/train/intrinsic_reward.csv")
    assert any(path.read_text().strip() for path in logged)
