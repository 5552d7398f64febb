"""Replays the defects a new user found, each by the tests that pin its fix.

The last probe of the recipes as a new user runs them (a refused launch, a
misspelt key, a run going non-finite, a deleted lock, emptied logs, the video,
paths that need quoting, a dead worker, the thread count on resume, and the
smaller ones) found ten defects; each is fixed, and the tests below fail on the
code before the fix. A new probe starts here: run this, then try what the list
does not hold yet, and add each new defect with its tests.

    .venv/bin/python tests/probe_new_user.py          # every item
    .venv/bin/python tests/probe_new_user.py 4 6      # some items

Prints one line per item with the pytest outcome of its tests; exits non-zero
if any fails.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

#: item: (what broke, the tests that pin the fix)
PROBE: dict[int, tuple[str, list[str]]] = {
    1: (
        "a refused launch rewrote the running run's recorded config",
        [
            "tests/test_mistakes.py::test_a_run_dir_in_use_is_one_message_and_changes_nothing",
            "tests/test_mistakes.py::test_a_changed_experiment_is_one_message_and_changes_nothing",
        ],
    ),
    2: (
        "a misspelt key added with + was ignored",
        [
            "tests/test_mistakes.py::test_a_bad_setting_is_a_config_error_naming_it",
            "tests/test_mistakes.py::test_a_bad_setting_is_one_message_and_leaves_no_file",
        ],
    ),
    3: (
        "a run going non-finite saved over the last good checkpoint",
        [
            "tests/test_mistakes.py::test_a_run_that_diverges_is_one_message_and_keeps_a_finite_checkpoint",
            "tests/test_mistakes.py::test_a_non_finite_state_never_replaces_a_finite_checkpoint",
        ],
    ),
    4: (
        "deleting run.lock let a second process take the run",
        [
            "tests/test_mistakes.py::test_a_run_dir_in_use_is_one_message_and_changes_nothing"
        ],
    ),
    5: (
        "a resume whose logs did not reach its checkpoint went on without a word",
        [
            "tests/test_mistakes.py::test_a_resume_whose_logs_do_not_reach_its_checkpoint_is_refused"
        ],
    ),
    6: (
        "the video's errors were raw, left partial files, and a rerun skipped it",
        [
            "tests/test_video.py::test_a_gif_write_that_fails_names_the_file_and_leaves_nothing",
            "tests/test_video.py::test_a_run_whose_video_cannot_be_written_says_it_is_saved_and_how_to_finish",
            "tests/test_video.py::test_a_finished_run_missing_its_curve_and_video_writes_them_on_rerun",
        ],
    ),
    7: (
        "printed commands could not be pasted (spaces, non-ASCII)",
        [
            "tests/test_mistakes.py::test_the_printed_commands_can_be_pasted_whatever_the_run_dir"
        ],
    ),
    8: (
        "a dead collector worker was not named",
        [
            "tests/test_recipe_workers.py::test_a_worker_that_dies_is_named_with_how_it_ended_and_what_to_do",
            "tests/test_recipe_workers.py::test_a_recipe_whose_worker_died_ends_with_one_line_and_the_resume_command",
        ],
    ),
    9: (
        "exact resume holds only at the thread count the run started with",
        [
            "tests/test_docs.py::test_the_docs_say_exact_resume_needs_the_same_thread_count"
        ],
    ),
    10: (
        "smaller: heatmap on DDPG, a lowered budget, envpool's -v1 hint, empty "
        "batches, the space a save needs, DDPG's video",
        [
            "tests/test_heatmap.py::test_a_ddpg_run_is_refused_in_one_line_naming_the_minigrid_recipe",
            "tests/test_mistakes.py::test_nothing_to_do_changes_nothing",
            "tests/test_envpool.py::test_errors",
            "tests/test_transform_safety.py::test_a_batch_of_no_envs_gives_empty_bonuses",
            "tests/test_run_damage.py::test_a_checkpoint_that_fills_the_disk_is_named_and_leaves_no_temporary",
            "tests/test_recipe_ddpg.py::test_eval_video_records_the_actor_or_is_refused_before_training",
        ],
    ),
}


def main(argv: list[str]) -> int:
    items = [int(a) for a in argv] or sorted(PROBE)
    failed = 0
    for item in items:
        what, tests = PROBE[item]
        result = subprocess.run(
            [sys.executable, "-m", "pytest", "-q", *tests],
            cwd=ROOT,
            capture_output=True,
            text=True,
        )
        outcome = result.stdout.strip().splitlines()[-1] if result.stdout else "?"
        status = "held" if result.returncode == 0 else "BROKEN"
        failed += result.returncode != 0
        print(f"{item:>2}. {status:<6} {what} ({outcome})", flush=True)
    return 1 if failed else 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
