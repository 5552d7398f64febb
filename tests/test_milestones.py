"""How far into a task a policy gets: milestones read from MiniGrid's own views."""

from __future__ import annotations

import math

import gymnasium as gym
import pandas as pd
import pytest
import torch
from _recipe_run import run_results_script
from tensordict import TensorDict
from torchrl.data import Categorical

from common.checkpoint import RunCheckpoint, RunCounters
from common.minigrid import make_actor_critic
from results.milestones import (
    MILESTONES,
    TOGGLE_COLUMNS,
    TOGGLE_CONTEXTS,
    Episodes,
    episode_milestones,
    load_policy,
    main,
    max_steps,
    policy_episodes,
    toggle_contexts,
    toggle_probability_at_door,
)
from torchrl_surprise.envs.oracle import solve_minigrid


def _played(env_id: str, seed: int, actions=None) -> Episodes:
    """One episode of ``env_id`` (``[1, steps, ...]``), playing the oracle's
    shortest solution (or ``actions``)."""
    env = gym.make(env_id)
    obs, _ = env.reset(seed=seed)
    if actions is None:
        actions = solve_minigrid(env.unwrapped).actions
    before, after, rewards, dones = [], [], [], []
    for action in actions:
        before.append(torch.as_tensor(obs["image"]))
        obs, reward, terminated, truncated, _ = env.step(action)
        after.append(torch.as_tensor(obs["image"]))
        rewards.append(float(reward))
        dones.append(terminated or truncated)
    env.close()
    return Episodes(
        torch.stack(before)[None],
        torch.stack(after)[None],
        torch.tensor(rewards)[None],
        torch.tensor(dones)[None],
        torch.tensor(actions)[None],
    )


_KEY_AT_DOOR = ("saw_locked_door_with_key", "faced_locked_door_with_key")


@pytest.mark.parametrize(
    "env_id, reached",
    [
        # move the blocking ball, open the box, take its key, unlock, fetch the
        # target ball (the success, not counted as carrying)
        (
            "MiniGrid-ObstructedMaze-1Dlhb-v0",
            {"carried_ball", "carried_key", *_KEY_AT_DOOR, "unlocked_door"},
        ),
        ("MiniGrid-DoorKey-5x5-v0", {"carried_key", *_KEY_AT_DOOR, "unlocked_door"}),
        # unlocked doors only: opened, none unlocked, nothing carried
        ("MiniGrid-MultiRoom-N2-S4-v0", set()),
    ],
)
def test_the_oracles_solution_reaches_every_milestone_on_its_way(env_id, reached):
    table = episode_milestones(_played(env_id, seed=1))
    assert len(table) == 1
    row = table.iloc[0]
    expected = reached | {"opened_door", "success"}
    assert {name for name in MILESTONES if row[name]} == expected


def test_a_key_brought_to_the_locked_door_and_not_used_is_told_from_one_kept_away():
    # DoorKey-5x5, seed 1: the oracle takes the key (the locked door in view),
    # turns to face the door, unlocks it. Cut after each step.
    env = gym.make("MiniGrid-DoorKey-5x5-v0")
    env.reset(seed=1)
    actions = solve_minigrid(env.unwrapped).actions
    env.close()
    reached = []
    for n in (1, 2, 3):
        episode = _played("MiniGrid-DoorKey-5x5-v0", seed=1, actions=actions[:n])
        episode.done[0, -1] = True
        row = episode_milestones(episode).iloc[0]
        reached.append({name for name in MILESTONES if row[name]})
    assert reached[0] == {"carried_key", "saw_locked_door_with_key"}
    assert reached[1] == {"carried_key", *_KEY_AT_DOOR}
    assert reached[2] == {"carried_key", *_KEY_AT_DOOR, "opened_door", "unlocked_door"}


def test_a_turn_from_a_locked_door_to_an_open_one_is_not_an_unlock():
    # A cell between two doors (ObstructedMaze-2Dlhb has them): the agent faces
    # a locked door, an open one to its right. Turning right puts the open door
    # in front of it; only a toggle that opens the door in front is an unlock.
    from minigrid.core.actions import Actions
    from minigrid.core.constants import DIR_TO_VEC
    from minigrid.core.world_object import Door, Key

    def turn_then_toggle(with_key: bool) -> list[bool]:
        env = gym.make("MiniGrid-Empty-5x5-v0")
        env.reset(seed=0)
        grid = env.unwrapped
        grid.grid.set(*grid.front_pos, Door("blue", is_locked=True))
        right = grid.agent_pos + DIR_TO_VEC[(grid.agent_dir + 1) % 4]
        grid.grid.set(*right, Door("red", is_open=True))
        grid.carrying = Key("blue") if with_key else None
        rows = []
        for action in (Actions.right, Actions.left, Actions.toggle):
            before = torch.as_tensor(grid.gen_obs()["image"])
            obs, *_ = env.step(action)
            rows.append((before, torch.as_tensor(obs["image"]), int(action)))
        env.close()
        reached = []
        for n in (1, 3):  # the turn alone; turned back and toggled
            steps = Episodes(
                torch.stack([r[0] for r in rows[:n]])[None],
                torch.stack([r[1] for r in rows[:n]])[None],
                torch.zeros(1, n),
                torch.tensor([[False] * (n - 1) + [True]]),
                torch.tensor([[r[2] for r in rows[:n]]]),
            )
            row = episode_milestones(steps).iloc[0]
            reached.append(row["unlocked_door"])
        return reached

    assert turn_then_toggle(with_key=False) == [False, False]
    assert turn_then_toggle(with_key=True) == [False, True]


def test_a_key_counts_only_at_a_locked_door_of_its_colour():
    # one step: the agent holds a yellow key (colour 4) facing a locked door
    # (state 2) of colour 4, then of colour 1 (ObstructedMaze-2Dlhb has a door
    # of each of two colours); the view is otherwise walls
    rows = []
    for door_colour in (4, 1):
        view = torch.full((1, 1, 7, 7, 3), 0, dtype=torch.uint8)
        view[..., 0] = 2  # walls
        view[0, 0, 3, 6] = torch.tensor([5, 4, 0], dtype=torch.uint8)  # the key
        view[0, 0, 3, 5] = torch.tensor([4, door_colour, 2], dtype=torch.uint8)
        steps = Episodes(
            view,
            view,
            torch.zeros(1, 1),
            torch.ones(1, 1, dtype=torch.bool),
            torch.zeros(1, 1),
        )
        row = episode_milestones(steps).iloc[0]
        rows.append({name for name in MILESTONES if row[name]})
    assert rows == [{"carried_key", *_KEY_AT_DOOR}, {"carried_key"}]


def _joined(*parts: Episodes) -> Episodes:
    return Episodes(
        *(
            None if fields[0] is None else torch.cat(fields, 1)
            for fields in zip(*parts, strict=True)
        )
    )


def test_each_episode_is_scored_on_its_own_steps_and_an_unfinished_one_left_out():
    solved = _played("MiniGrid-DoorKey-5x5-v0", seed=1)
    # an episode that only turns left, then one cut off before it ends
    idle = _played("MiniGrid-DoorKey-5x5-v0", seed=1, actions=[0, 0, 0])
    idle.done[0, -1] = True
    cut = _played("MiniGrid-DoorKey-5x5-v0", seed=1, actions=[0, 0])
    table = episode_milestones(_joined(solved, idle, cut))
    assert len(table) == 2
    reached = {name for name in MILESTONES if table.iloc[0][name]}
    assert reached == {
        "carried_key",
        *_KEY_AT_DOOR,
        "opened_door",
        "unlocked_door",
        "success",
    }
    assert not table.iloc[1].any()
    # each env's first episodes only, and an env short of them is refused
    assert len(episode_milestones(_joined(solved, idle), per_env=1)) == 1
    with pytest.raises(ValueError, match="env 0 ended 2 episodes.*at least 3"):
        episode_milestones(_joined(solved, idle, cut), per_env=3)


def test_the_toggle_probability_is_read_where_the_key_faces_its_door_only():
    # DoorKey-5x5, seed 1: the oracle takes the key, turns to its door (step 1),
    # toggles it (step 2, the one step that starts facing the locked door with
    # the key), then walks to the goal. Three such episodes, the last cut off
    # before it ends, then an idle one.
    solved = _played("MiniGrid-DoorKey-5x5-v0", seed=1)
    cut = _played("MiniGrid-DoorKey-5x5-v0", seed=1)
    cut.done[0, -1] = False
    idle = _played("MiniGrid-DoorKey-5x5-v0", seed=1, actions=[0, 0, 0])
    idle.done[0, -1] = True
    n = solved.image.shape[1]
    logits = torch.randn(1, 3 * n, 7, generator=torch.manual_seed(0))
    steps = _joined(solved, solved, cut)._replace(logits=logits)
    toggle = logits[0].softmax(-1)[:, 5]  # MiniGrid's toggle
    # each env's first episode: its own door step only; all ended ones: both,
    # never the unfinished one's
    assert toggle_probability_at_door(steps, per_env=1) == pytest.approx(
        float(toggle[2])
    )
    both = float((toggle[2] + toggle[n + 2]) / 2)
    assert toggle_probability_at_door(steps) == pytest.approx(both)
    assert toggle_probability_at_door(steps, per_env=2) == pytest.approx(both)
    with pytest.raises(ValueError, match="env 0 ended 2 episodes.*at least 3"):
        toggle_probability_at_door(steps, per_env=3)
    # never at the door: NaN; no logits: refused
    assert math.isnan(toggle_probability_at_door(idle._replace(logits=logits[:, :3])))
    with pytest.raises(ValueError, match="expected the policy's logits"):
        toggle_probability_at_door(solved)


def test_a_view_of_the_wrong_shape_is_refused_naming_the_expected_one():
    flat = torch.zeros(2, 7, 7, 3)
    steps = Episodes(flat, flat, torch.zeros(2), torch.zeros(2), torch.zeros(2))
    with pytest.raises(ValueError, match=r"\[envs, steps, 7, 7, 3\].*\(2, 7, 7, 3\)"):
        episode_milestones(steps)


def _contexts_from_the_env(env_id: str, seed: int) -> tuple[list[str | None], list]:
    # the oracle's solution played in the real env; before each step, the context
    # read from the env's own state (the object in front of the agent, what it
    # carries), not from its view
    from minigrid.core.world_object import Box, Door, Key

    env = gym.make(env_id)
    env.reset(seed=seed)
    game = env.unwrapped
    actions = solve_minigrid(game).actions
    contexts = []
    for action in actions:
        front, held = game.grid.get(*game.front_pos), game.carrying
        if isinstance(front, Door) and front.is_locked:
            its_key = isinstance(held, Key) and held.color == front.color
            contexts.append(
                "key_at_its_door" if its_key else "locked_door_without_its_key"
            )
        elif isinstance(front, Door) and not front.is_open:
            contexts.append("closed_door")
        elif isinstance(front, Box):
            contexts.append("box")
        else:
            contexts.append(None)
        env.step(action)
    env.close()
    return contexts, actions


@pytest.mark.parametrize(
    "env_id, seed, passed",
    [
        # the locked door before its key is held, the box, the door with its key
        (
            "MiniGrid-ObstructedMaze-1Dlhb-v0",
            3,
            {"locked_door_without_its_key", "box", "key_at_its_door"},
        ),
        ("MiniGrid-MultiRoom-N2-S4-v0", 1, {"closed_door"}),
        (
            "MiniGrid-DoorKey-5x5-v0",
            2,
            {"locked_door_without_its_key", "key_at_its_door"},
        ),
    ],
)
def test_each_toggle_context_is_the_one_the_envs_own_state_gives(env_id, seed, passed):
    contexts, actions = _contexts_from_the_env(env_id, seed)
    assert passed <= set(contexts)  # the solution passes through them
    steps = _played(env_id, seed, actions=actions)
    n = len(actions)
    logits = torch.randn(1, n, 7, generator=torch.manual_seed(1))
    read = toggle_contexts(steps._replace(logits=logits))
    toggle = logits[0].softmax(-1)[:, 5]
    for context in TOGGLE_CONTEXTS:
        at = [t for t, c in enumerate(contexts) if context in ("anywhere", c)]
        expected = float(toggle[at].mean()) if at else math.nan
        count, probability = read[context]
        assert count == len(at), context
        assert probability == pytest.approx(expected, nan_ok=True), context
    # the door's toggle is the one toggle_probability_at_door reads
    door = read["key_at_its_door"][1]
    assert toggle_probability_at_door(steps._replace(logits=logits)) == pytest.approx(
        door, nan_ok=True
    )


def test_a_key_of_another_colour_at_a_locked_door_is_a_door_without_its_key():
    # a yellow key (colour 4) held facing a locked blue door (colour 2), then the
    # yellow one: a toggle does nothing at the first, unlocks the second
    view = torch.zeros(1, 2, 7, 7, 3, dtype=torch.uint8)
    view[0, :, 3, 6] = torch.tensor([5, 4, 0], dtype=torch.uint8)
    view[0, 0, 3, 5] = torch.tensor([4, 2, 2], dtype=torch.uint8)
    view[0, 1, 3, 5] = torch.tensor([4, 4, 2], dtype=torch.uint8)
    logits = torch.zeros(1, 2, 7)
    logits[0, 0, 5], logits[0, 1, 5] = -1.0, 1.0
    done = torch.tensor([[False, True]])
    steps = Episodes(view, view, torch.zeros(1, 2), done, torch.zeros(1, 2), logits)
    read = toggle_contexts(steps)
    toggle = logits[0].softmax(-1)[:, 5]
    assert read["locked_door_without_its_key"] == (1, pytest.approx(float(toggle[0])))
    assert read["key_at_its_door"] == (1, pytest.approx(float(toggle[1])))
    # a view of another shape is refused, as for the milestones
    flat = Episodes(view[..., 0], view[..., 0], *steps[2:])
    with pytest.raises(ValueError, match=r"\[envs, steps, 7, 7, 3\]"):
        toggle_contexts(flat)


def test_toggle_contexts_score_each_envs_first_episodes_and_need_logits():
    solved = _played("MiniGrid-DoorKey-5x5-v0", seed=1)
    cut = _played("MiniGrid-DoorKey-5x5-v0", seed=1)
    cut.done[0, -1] = False
    n = solved.image.shape[1]
    steps = _joined(solved, cut)._replace(logits=torch.zeros(1, 2 * n, 7))
    read = toggle_contexts(steps)
    assert read["anywhere"] == (n, pytest.approx(1 / 7))  # the cut one left out
    assert read["key_at_its_door"][0] == 1
    with pytest.raises(ValueError, match="env 0 ended 1 episodes.*at least 2"):
        toggle_contexts(steps, per_env=2)
    with pytest.raises(ValueError, match="expected the policy's logits"):
        toggle_contexts(solved)


def _checkpoint(
    run_dir,
    env_name: str,
    backend: str = "gymnasium",
    *,
    frames: int = 512,
    extra: dict | None = None,
    **env,
):
    torch.manual_seed(0)
    model, _ = make_actor_critic(Categorical(7), intrinsic_critic=False)
    config = {
        "setting": "demo",
        "bonus": "none",
        "seed": 4,
        "env": {"name": env_name, "backend": backend, **env},
        **(extra or {}),
    }
    run_dir.mkdir()
    progress = RunCounters(frames=frames)
    RunCheckpoint(
        run_dir / "checkpoint.torchrl", {"progress": progress, "model": model}, config
    ).save()


@pytest.mark.parametrize("backend", ["gymnasium", "envpool"])
def test_a_runs_policy_is_played_for_each_envs_first_episodes(tmp_path, backend):
    _checkpoint(tmp_path / "run", "MiniGrid-DoorKey-5x5-v0", backend)
    out = tmp_path / "milestones.csv"
    argv = [str(tmp_path / "run"), "--envs", "3", "--episodes", "2", "--out"]
    assert main([*argv, str(out)]) == 0
    table = pd.read_csv(out)
    row = table.iloc[0]
    assert (row["setting"], row["seed"], row["frames"]) == ("demo", 4, 512)
    assert row["episodes"] == 3 * 2
    assert all(0.0 <= row[name] <= 1.0 for name in MILESTONES)
    door = row["toggle_prob_at_door"]  # an untrained policy may never face it
    assert math.isnan(door) or 0.0 < door < 1.0
    # seeded: the same rollout again
    assert main([*argv, str(tmp_path / "again.csv")]) == 0
    pd.testing.assert_frame_equal(table, pd.read_csv(tmp_path / "again.csv"))
    # a checkpoint file (a kept point of training) reads as its run
    ckpt = tmp_path / "run" / "checkpoint.torchrl"
    argv[0] = str(ckpt)
    assert main([*argv, str(tmp_path / "file.csv")]) == 0
    from_file = pd.read_csv(tmp_path / "file.csv")
    assert from_file.pop("run").tolist() == [str(ckpt)]
    pd.testing.assert_frame_equal(from_file, table.drop(columns="run"))


def test_a_committed_table_plus_new_runs_is_the_table_of_all_at_once(tmp_path, capsys):
    # runs no longer on disk live on in their committed table (--from-data): new
    # runs added to it give the table all of them would give at once, a run's
    # points of training in the order of their frames (not of their names); a
    # run given again replaces its row, the same run by another spelling too
    for name, frames in [("a_late", 1024), ("b_early", 512)]:
        _checkpoint(tmp_path / name, "MiniGrid-DoorKey-5x5-v0", frames=frames)
    late, early = str(tmp_path / "a_late"), str(tmp_path / "b_early")
    common = ["--envs", "2", "--episodes", "1", "--out"]
    whole, part = tmp_path / "whole.csv", tmp_path / "part.csv"
    assert main([late, early, *common, str(whole)]) == 0
    assert pd.read_csv(whole)["frames"].tolist() == [512, 1024]
    assert main([late, *common, str(part)]) == 0
    for again in (early, str(tmp_path / "." / "b_early")):  # in place, and again
        assert main([again, "--from-data", str(part), *common, str(part)]) == 0
        assert part.read_bytes() == whole.read_bytes().replace(
            early.encode(), again.encode()
        )
    # the fresh row wins over a stale one of the same run
    stale = pd.read_csv(part)
    stale.loc[stale["frames"] == 512, "episodes"] = 999
    stale.to_csv(part, index=False)
    assert main([early, "--from-data", str(part), *common, str(part)]) == 0
    assert part.read_bytes() == whole.read_bytes()
    # an earlier table that is not this tool's, empty, or not there is named
    other, empty = tmp_path / "other.csv", tmp_path / "empty.csv"
    pd.DataFrame({"run": [late], "score": [0.5]}).to_csv(other, index=False)
    empty.write_text("")
    for earlier, expected in [
        (other, "has the columns ['run', 'score']"),
        (empty, "empty.csv is empty"),
        (tmp_path / "nowhere.csv", "nowhere.csv does not exist"),
    ]:
        with pytest.raises(SystemExit) as exit_:
            main([early, "--from-data", str(earlier), *common, str(part)])
        assert exit_.value.code == 2
        assert expected in capsys.readouterr().err
    assert part.read_bytes() == whole.read_bytes()  # nothing written


def test_an_earlier_tables_labels_are_read_as_written(tmp_path):
    # a setting named like a missing value or a number stays the string it was
    _checkpoint(tmp_path / "run", "MiniGrid-DoorKey-5x5-v0")
    common = ["--envs", "2", "--episodes", "1", "--out"]
    part = tmp_path / "part.csv"
    assert main([str(tmp_path / "run"), *common, str(part)]) == 0
    earlier = pd.concat([pd.read_csv(part)] * 2, ignore_index=True)
    earlier["run"], earlier["setting"] = ["runs/x", "runs/y"], ["NA", "2"]
    earlier.to_csv(part, index=False)
    out = tmp_path / "out.csv"
    assert (
        main([str(tmp_path / "run"), "--from-data", str(part), *common, str(out)]) == 0
    )
    assert pd.read_csv(out, dtype={"setting": str}, keep_default_na=False)[
        "setting"
    ].tolist() == ["2", "NA", "demo"]


def test_toggles_writes_where_the_policy_would_toggle(tmp_path, capsys):
    _checkpoint(tmp_path / "run", "MiniGrid-DoorKey-5x5-v0")
    argv = [str(tmp_path / "run"), "--envs", "3", "--episodes", "2", "--toggles"]
    out = tmp_path / "toggles.csv"
    assert main([*argv, "--out", str(out)]) == 0
    table = pd.read_csv(out)
    assert list(table.columns) == list(TOGGLE_COLUMNS)
    row = table.iloc[0]
    assert (row["setting"], row["seed"], row["frames"], row["episodes"]) == (
        "demo",
        4,
        512,
        6,
    )
    # 2 episodes of DoorKey-5x5 (at most 250 steps each) in each of 3 envs
    assert 6 <= row["steps_anywhere"] <= 3 * 2 * 250
    assert 0.0 < row["toggle_anywhere"] < 1.0
    # the row is toggle_contexts' on the episodes the milestones play
    policy, config, _ = load_policy(tmp_path / "run")
    steps = 2 * max_steps("MiniGrid-DoorKey-5x5-v0")
    played = policy_episodes(policy, config, envs=3, steps=steps, seed=0)
    for context, (count, probability) in toggle_contexts(played, 2).items():
        assert row[f"steps_{context}"] == count, context
        assert row[f"toggle_{context}"] == pytest.approx(
            round(probability, 4), nan_ok=True
        ), context
    # the same episodes as the milestones': where the key faces its door
    milestones = tmp_path / "milestones.csv"
    assert main([*argv[:-1], "--out", str(milestones)]) == 0
    door = pd.read_csv(milestones)["toggle_prob_at_door"].iloc[0]
    assert row["toggle_key_at_its_door"] == pytest.approx(door, nan_ok=True)
    # a milestones table is not a toggles one
    with pytest.raises(SystemExit):
        main([*argv, "--from-data", str(milestones), "--out", str(out)])
    assert "has the columns ['run', 'setting'" in capsys.readouterr().err


def test_label_keys_tell_apart_runs_of_one_setting(tmp_path, capsys):
    # a sweep over a hyperparameter beside a named setting: the setting alone
    # labels both runs "demo"; --label-keys adds the key's value
    for coef in (0.01, 0.1):
        _checkpoint(
            tmp_path / f"coef_{coef}",
            "MiniGrid-DoorKey-5x5-v0",
            extra={"loss": {"entropy_coef": coef}},
        )
    runs = [str(tmp_path / "coef_0.01"), str(tmp_path / "coef_0.1")]
    common = ["--envs", "2", "--episodes", "1", "--toggles", "--out"]
    plain, labelled = tmp_path / "plain.csv", tmp_path / "labelled.csv"
    assert main([*runs, *common, str(plain)]) == 0
    assert pd.read_csv(plain)["setting"].tolist() == ["demo", "demo"]
    keys = ["--label-keys", "loss.entropy_coef"]
    assert main([*runs, *keys, *common, str(labelled)]) == 0
    table = pd.read_csv(labelled)
    assert table["setting"].tolist() == [
        "demo,loss.entropy_coef=0.01",
        "demo,loss.entropy_coef=0.1",
    ]
    # only the labels differ
    pd.testing.assert_frame_equal(
        table.drop(columns="setting"), pd.read_csv(plain).drop(columns="setting")
    )
    # a key the runs' configs lack, or a section, is refused before any playing
    for key, expected in [
        ("loss.gamma", "has no 'loss.gamma'"),
        ("loss", "'loss' is a dict, not a value"),
    ]:
        with pytest.raises(SystemExit) as exit_:
            main([*runs, "--label-keys", key, *common, str(tmp_path / "x.csv")])
        assert exit_.value.code == 2
        assert expected in capsys.readouterr().err
    assert not (tmp_path / "x.csv").exists()


def test_the_policy_acts_by_sampling_as_in_training(tmp_path):
    # an untrained policy's most likely action is one action everywhere; sampled,
    # it takes them all
    _checkpoint(tmp_path / "run", "MiniGrid-DoorKey-5x5-v0")
    policy, config, _ = load_policy(tmp_path / "run")
    steps = policy_episodes(policy, config, envs=2, steps=200, seed=0)
    assert len(steps.action.unique()) == 7
    # the logits kept are the ones each step's action was drawn from
    with torch.no_grad():
        again = policy(TensorDict({"image": steps.image}, batch_size=[2, 200]))
    torch.testing.assert_close(steps.logits, again["logits"])
    # main plays episodes x max_steps steps: an episode lasts at most max_steps
    assert max_steps("MiniGrid-DoorKey-5x5-v0") == 250


def test_a_run_that_is_not_a_clean_minigrid_policy_is_refused(tmp_path, capsys):
    _checkpoint(tmp_path / "cheetah", "HalfCheetah-v5")
    _checkpoint(tmp_path / "noisy", "MiniGrid-DoorKey-5x5-v0", stochasticity=3)
    # what <sweep>/* matches beside the runs: not called a damaged checkpoint
    (tmp_path / "multirun.yaml").write_text("hydra:\n  mode: MULTIRUN\n")
    for run, expected in [
        ("cheetah", "expected a MiniGrid recipe's checkpoint"),
        ("noisy", "env.stochasticity=3"),
        ("nowhere", "nowhere"),
        ("multirun.yaml", "multirun.yaml is not a checkpoint: expected a run"),
    ]:
        with pytest.raises(SystemExit) as exit_:
            main([str(tmp_path / run)])
        assert exit_.value.code == 2
        assert expected in capsys.readouterr().err


def test_the_documented_command_runs_as_a_script(tmp_path):
    # as docs/results.rst runs it: a script, with nothing of recipes/ importable
    # but what it puts on sys.path itself
    _checkpoint(tmp_path / "run", "MiniGrid-DoorKey-5x5-v0")
    run_results_script(
        "milestones.py",
        str(tmp_path / "run"),
        *("--envs", "2", "--episodes", "1", "--out", str(tmp_path / "m.csv")),
        cwd=tmp_path,
    )
    assert pd.read_csv(tmp_path / "m.csv")["episodes"].tolist() == [2]
