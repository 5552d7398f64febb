"""benchmarks/bench_speed.py's baselines run in a fresh process, where nothing has
registered the paper's MultiRoom ids with gymnasium yet (``import
torchrl_surprise`` registers nothing)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

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
