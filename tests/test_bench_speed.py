"""The benchmarks keep up with the recipes: bench_speed.py's baselines run in a
fresh process, where nothing has registered the paper's MultiRoom ids with
gymnasium yet (``import torchrl_surprise`` registers nothing), and
profile_stages.py finds every stage it names in the recipes' loops."""

from __future__ import annotations

import importlib.util
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def test_the_raw_gymnasium_loop_runs_the_papers_task_in_a_fresh_process():
    # item 7's baseline: a raw gymnasium loop of the recipes' task
    code = (
        "import sys; sys.argv = ['bench_speed.py']\n"
        f"sys.path.insert(0, {str(ROOT / 'benchmarks')!r})\n"
        "import bench_speed\n"
        "sample = bench_speed.raw_env(bench_speed.RECIPE_TASK, 50)\n"
        "assert sample.value > 0, sample\n"
        "print(bench_speed.RECIPE_TASK)\n"
    )
    done = subprocess.run(
        [sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True
    )
    assert done.returncode == 0, done.stderr[-2000:]
    assert done.stdout.strip() == "MiniGrid-MultiRoom-N3-S4-v0"


def _profile_stages():
    spec = importlib.util.spec_from_file_location(
        "profile_stages", ROOT / "benchmarks" / "profile_stages.py"
    )
    module = importlib.util.module_from_spec(spec)
    sys.modules["profile_stages"] = module  # dataclasses look their module up
    spec.loader.exec_module(module)
    return module


@pytest.mark.parametrize("name", ["ppo-envpool", "ddpg-none"])
def test_the_profiles_stages_are_found_in_the_recipes_loops(name, tmp_path):
    stages = _profile_stages()
    main, markers, _ = stages.PROFILES[name]
    stage_map = stages.StageMap.from_source(main, markers)
    assert set(stage_map.lines.values()) == {stage for _, _, stage in markers}
    # a sample is the stage of its innermost frame of main.py that has one
    in_update = next(n for (f, n) in stage_map.lines if f == "train")
    frames = [
        f"main ({main}:1)",
        f"train ({main}:{in_update})",
        "forward (/x/torch/nn/modules/linear.py:10)",
    ]
    raw = tmp_path / "raw.txt"
    raw.write_text(";".join(frames) + " 7\n" + f"main ({main}:1) 3\n")
    counts, total = stages.attribute(raw, main, stage_map)
    assert total == 7  # the sample outside the loop is left out
    assert counts[stage_map.lines["train", in_update]]["torch ops"] == 7
    gone = [*markers, ("train", "a line no recipe has", "x")]
    with pytest.raises(stages.MissingMarker, match="a line no recipe has"):
        stages.StageMap.from_source(main, gone)
