"""Runs against a full disk and damaged files (common/run.py), without a recipe.

A write that fails (no space left, permission denied) names the file and the
cause and leaves no temporary file; the run resumes once the disk has room. A
damaged checkpoint (empty, cut short, garbage, overwritten in part; both formats)
or scalar log is named with what to do, on resume and in the tools that read it.
A resume refuses a run whose scalar logs are gone. ``status.json`` records how
far a run got.

The disk fills up by monkeypatching the writes: ``torch.save`` fails as it did on
a full disk (``RuntimeError: [enforce fail at inline_container.cc:672] .
unexpected pos``, no errno, the free space then tells), Python's writes with
``OSError(ENOSPC)`` or ``OSError(EACCES)`` after part of the data.
"""

from __future__ import annotations

import errno
import json
import os
import shutil
from pathlib import Path

import pytest
import torch
from omegaconf import OmegaConf

import common.files as files_module
from common.checkpoint import (
    CHECKPOINT_NAME,
    LEGACY_CHECKPOINT_NAME,
    RunCheckpoint,
    RunCounters,
    load_checkpoint,
)
from common.run import TrainingRun
from common.rundir import prepare_run
from common.scalar_logs import read_scalar_csv, truncate_scalar_logs

SCALARS = "logs/demo/scalars"
DRAW = f"{SCALARS}/train/draw.csv"
TORCH_FULL_DISK = (
    "[enforce fail at inline_container.cc:672] . unexpected pos 704 vs 598"
)


def _cfg(total_frames=512, keep=False, **extra):
    return OmegaConf.create(
        {
            "seed": 0,
            "resume": "auto",
            "torch_threads": 1,
            "env": {"name": "MiniGrid-Empty-5x5-v0"},
            "bonus": "none",
            "collector": {"total_frames": total_frames},
            "logger": {"backend": "csv", "project_name": "p"},
            "checkpoint": {"interval_frames": 128, "keep": keep},
            **extra,
        }
    )


def _train(run_dir, total_frames=512, *, stop_at=None, keep=False, **extra):
    """A run of 64-frame updates, checkpointing every 128 frames; ``stop_at``:
    the frames after which it dies (no final checkpoint)."""
    run = TrainingRun(_cfg(total_frames, keep, **extra), "demo", run_dir=run_dir)
    if run.nothing_to_do():
        return None
    counters = RunCounters(frames=0, next_ckpt=128)
    net = torch.nn.Linear(2, 1)
    run.restore({"progress": counters, "net": net}, show_progress=False)
    try:
        while counters.frames < total_frames:
            counters.frames += 64
            run.log({"train/draw": float(counters.frames)}, step=counters.frames)
            run.after_update()
            if counters.frames == stop_at:
                return run
        run.finish(f"{counters.frames} frames.", curves={"train/draw": "draw"})
    finally:
        _release(run)
    return run


def _release(run):
    # what the end of the process does: the signal handlers and the lock go
    if run._stop is not None:
        run._stop.restore()
    if run.progress_bar is not None:
        run.progress_bar.close()
    run.dir.release()


def _listing(folder: Path) -> list[str]:
    return sorted(p.relative_to(folder).as_posix() for p in folder.rglob("*"))


def _temporaries(folder: Path) -> list[str]:
    return [
        name
        for name in _listing(folder)
        if Path(name).name.startswith(".") or name.endswith(".tmp")
    ]


def _full_disk_torch_save(monkeypatch):
    """torch.save writes part of its file, then fails as on a full disk; the
    device has no space left."""
    save = torch.save

    def failing(obj, f, *args, **kwargs):
        save(obj, f, *args, **kwargs)
        with open(f, "r+b") as file:
            file.truncate(16)
        raise RuntimeError(TORCH_FULL_DISK)

    monkeypatch.setattr(torch, "save", failing)
    usage = shutil.disk_usage("/")
    monkeypatch.setattr(shutil, "disk_usage", lambda path: usage._replace(free=4096))


class _FailingFile:
    """A file whose writes stop after a few bytes with ``OSError(code)``."""

    def __init__(self, file, code):
        self.file, self.code = file, code

    def write(self, data):
        self.file.write(data[:5])
        self.file.flush()
        raise OSError(self.code, os.strerror(self.code))

    def __getattr__(self, name):
        return getattr(self.file, name)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.file.close()


def _failing_writes(monkeypatch, code):
    # Every file the run writes (common.files) fails after 5 bytes.
    def failing_open(path, mode="r", *args, **kwargs):
        file = open(path, mode, *args, **kwargs)
        return _FailingFile(file, code) if "w" in mode else file

    monkeypatch.setattr(files_module, "open", failing_open, raising=False)


# -- writes that fail ----------------------------------------------------------


def test_a_checkpoint_that_fills_the_disk_is_named_and_leaves_no_temporary(
    tmp_path, monkeypatch
):
    counters = RunCounters(frames=128)
    net = torch.nn.Linear(2, 1)
    ckpt = RunCheckpoint(
        tmp_path / CHECKPOINT_NAME, {"net": net, "progress": counters}, {}
    )
    ckpt.save()
    before = _listing(tmp_path)
    counters.frames = 256
    _full_disk_torch_save(monkeypatch)
    with pytest.raises(OSError) as failed:
        ckpt.save()
    message = str(failed.value)
    assert f"could not write {tmp_path / CHECKPOINT_NAME}" in message
    assert "no space left on device" in message
    # the space a save needs: a new file beside the previous one
    size = (tmp_path / CHECKPOINT_NAME).stat().st_size
    assert f"the write needs about {size / 2**20:.1f} MiB more" in message
    assert failed.value.errno == errno.ENOSPC
    assert f"The previous checkpoint, {tmp_path / CHECKPOINT_NAME}" in message
    assert _listing(tmp_path) == before
    monkeypatch.undo()
    assert load_checkpoint(tmp_path / CHECKPOINT_NAME)["frames"] == 128


def test_a_checkpoint_without_permission_says_permission_denied(tmp_path, monkeypatch):
    from torchrl.checkpoint import Checkpoint

    def denied(self, path, **kwargs):
        Path(path).write_bytes(b"PK")  # a part, then the file system says no
        raise PermissionError(errno.EACCES, "Permission denied", str(path))

    monkeypatch.setattr(Checkpoint, "save", denied)
    ckpt = RunCheckpoint(
        tmp_path / CHECKPOINT_NAME, {"progress": RunCounters(frames=64)}, {}
    )
    with pytest.raises(OSError, match="permission denied") as failed:
        ckpt.save()
    assert f"could not write {tmp_path / CHECKPOINT_NAME}" in str(failed.value)
    assert "no earlier checkpoint" in str(failed.value)
    assert _listing(tmp_path) == []


@pytest.mark.parametrize(
    "code, cause",
    [(errno.ENOSPC, "no space left on device"), (errno.EACCES, "permission denied")],
)
def test_cutting_the_logs_on_a_full_disk_leaves_them_and_no_temporary(
    tmp_path, monkeypatch, code, cause
):
    # the resume of a killed run cuts its logs at the checkpoint: fps.csv is
    # rewritten, and the disk is full
    fps = tmp_path / "logs/a2c/scalars/train/fps.csv"
    fps.parent.mkdir(parents=True)
    fps.write_text("64,10.0\n128,11.0\n192,12.0\n")
    _failing_writes(monkeypatch, code)
    with pytest.raises(OSError) as failed:
        truncate_scalar_logs(tmp_path / "logs", 128)
    assert f"could not write {fps}: {cause}" in str(failed.value)
    assert f"{fps} is left as it was" in str(failed.value)
    assert _listing(fps.parent) == ["fps.csv"]
    assert fps.read_text() == "64,10.0\n128,11.0\n192,12.0\n"
    monkeypatch.undo()
    assert truncate_scalar_logs(tmp_path / "logs", 128) == 1
    assert fps.read_text() == "64,10.0\n128,11.0\n"


def test_a_status_file_that_cannot_be_written_is_named(tmp_path, monkeypatch):
    _train(tmp_path, 256, stop_at=128)
    status = tmp_path / "status.json"
    before = status.read_text()
    _failing_writes(monkeypatch, errno.ENOSPC)
    ckpt = RunCheckpoint(
        tmp_path / CHECKPOINT_NAME,
        {"progress": RunCounters(frames=192)},
        OmegaConf.to_container(_cfg(256)),
        status=True,
    )
    with pytest.raises(OSError, match="status.json: no space left on device"):
        ckpt.save()
    assert status.read_text() == before
    assert _temporaries(tmp_path) == []


def test_a_run_that_filled_the_disk_resumes_once_there_is_room(tmp_path, monkeypatch):
    whole, parts = tmp_path / "whole", tmp_path / "parts"
    _train(whole, 512)
    # the checkpoint at 256 frames finds the disk full: the run stops there
    save = torch.save

    def full_from_256(obj, f, *args, **kwargs):
        if isinstance(obj, dict) and obj.get("frames") == 256:
            raise RuntimeError(TORCH_FULL_DISK)
        return save(obj, f, *args, **kwargs)

    monkeypatch.setattr(torch, "save", full_from_256)
    usage = shutil.disk_usage("/")
    monkeypatch.setattr(shutil, "disk_usage", lambda p: usage._replace(free=0))
    with pytest.raises(OSError, match="no space left on device"):
        _train(parts, 512)
    assert _temporaries(parts) == []
    assert json.loads((parts / "status.json").read_text())["frames"] == 128
    # space is back: the run resumes from 128 frames and logs what it would have
    monkeypatch.undo()
    _train(parts, 512)
    assert load_checkpoint(parts / CHECKPOINT_NAME)["frames"] == 512
    assert (parts / DRAW).read_bytes() == (whole / DRAW).read_bytes()


def _space_warnings(record):
    return [str(w.message) for w in record if "checkpoint.keep=true" in str(w.message)]


def test_kept_checkpoints_that_would_not_fit_are_warned_of_once(tmp_path, monkeypatch):
    # 8 checkpoints of a 1024-frame run are kept; the disk has room for about 2
    kept = tmp_path / "probe" / "checkpoints"
    _train(tmp_path / "probe", 128, keep=True)
    size = next(kept.iterdir()).stat().st_size
    usage = shutil.disk_usage("/")
    monkeypatch.setattr(
        shutil, "disk_usage", lambda p: usage._replace(free=int(2.5 * size))
    )
    with pytest.warns(UserWarning) as record:
        _train(tmp_path / "run", 1024, keep=True)
    (message,) = _space_warnings(record)  # at the first kept checkpoint only
    assert "the 7 still to come" in message
    assert str(tmp_path / "run" / "checkpoints") in message
    assert "checkpoint.keep=false" in message
    # a warning, not an error: the run went on to its end, every checkpoint kept
    assert len(list((tmp_path / "run" / "checkpoints").iterdir())) == 8


def test_kept_checkpoints_that_fit_and_a_run_that_keeps_none_are_not_warned_of(
    tmp_path, monkeypatch, recwarn
):
    usage = shutil.disk_usage("/")
    monkeypatch.setattr(shutil, "disk_usage", lambda p: usage._replace(free=2**40))
    _train(tmp_path / "kept", 1024, keep=True)
    monkeypatch.setattr(shutil, "disk_usage", lambda p: usage._replace(free=0))
    _train(tmp_path / "not_kept", 1024, keep=False)
    assert _space_warnings(recwarn) == []


def test_temporaries_of_a_killed_write_go_when_the_run_resumes(tmp_path):
    _train(tmp_path, 512, stop_at=128)
    leftovers = [
        tmp_path / ".checkpoint.torchrl.123-abcdef12.tmp",
        tmp_path / "..checkpoint.torchrl.123-abcdef12.tmp.stage-0a1b",
        tmp_path / ".status.json.123-abcdef12.tmp",
        tmp_path / f"{SCALARS}/train/.draw.csv.123-abcdef12.tmp",
    ]
    for path in leftovers:
        path.write_bytes(b"PK\x03")
    _train(tmp_path, 512)
    assert _temporaries(tmp_path) == []


# -- damaged checkpoints -------------------------------------------------------


def _damage(path: Path, how: str) -> None:
    data = path.read_bytes()
    if how == "empty":
        path.write_bytes(b"")
    elif how == "truncated":
        path.write_bytes(data[: len(data) // 2])
    elif how == "garbage":
        path.write_bytes(b"line\x00\x17 not a checkpoint" * 40)
    elif how == "overwritten":  # the same size, zeros in the middle of a payload
        middle = len(data) // 2
        path.write_bytes(data[:middle] + bytes(200) + data[middle + 200 :])


def _legacy(run_dir: Path) -> None:
    # the run's checkpoint as the 0.2 release wrote it: checkpoint.pt
    state = load_checkpoint(run_dir / CHECKPOINT_NAME)
    (run_dir / CHECKPOINT_NAME).unlink()
    torch.save(state, run_dir / LEGACY_CHECKPOINT_NAME)


FORMATS = [CHECKPOINT_NAME, LEGACY_CHECKPOINT_NAME]
DAMAGES = ["empty", "truncated", "garbage", "overwritten"]


@pytest.mark.parametrize("name", FORMATS)
@pytest.mark.parametrize("how", DAMAGES)
def test_a_damaged_checkpoint_is_named_with_the_kept_one_to_resume_from(
    tmp_path, name, how
):
    if name == LEGACY_CHECKPOINT_NAME and how == "overwritten":
        pytest.skip("a torch.save file has no checksums to tell")
    _train(tmp_path, 512, stop_at=384, keep=True)
    if name == LEGACY_CHECKPOINT_NAME:
        _legacy(tmp_path)
    damaged = tmp_path / name
    _damage(damaged, how)
    # the newest kept one (384) is damaged as well: the one before it is named
    kept = tmp_path / "checkpoints"
    _damage(kept / "checkpoint-000000000384.torchrl", "truncated")
    earlier = kept / "checkpoint-000000000256.torchrl"

    with pytest.raises(ValueError) as failed:
        load_checkpoint(damaged)
    message = str(failed.value)
    assert f"{damaged} is damaged" in message
    assert f"kept: {earlier} (256 frames); pass that file instead" in message

    with pytest.raises(ValueError) as failed:
        _train(tmp_path, 512)
    message = str(failed.value)
    assert f"Cannot resume {tmp_path}: {damaged} is damaged" in message
    assert f"mv {damaged} {damaged}.damaged" in message
    assert f"cp {earlier} {tmp_path / CHECKPOINT_NAME}" in message
    assert "resume=false" in message
    assert read_scalar_csv(tmp_path / DRAW)[0].tolist()[-1] == 384  # logs untouched

    # doing what it says resumes the run from 256 frames
    damaged.rename(f"{damaged}.damaged")
    shutil.copy(earlier, tmp_path / CHECKPOINT_NAME)
    _train(tmp_path, 512)
    steps, values = read_scalar_csv(tmp_path / DRAW)
    assert steps.tolist() == list(range(64, 513, 64))


@pytest.mark.parametrize("how", ["empty", "garbage"])
def test_a_damaged_checkpoint_without_a_kept_one_says_start_afresh(tmp_path, how):
    _train(tmp_path, 512, stop_at=128)
    _damage(tmp_path / CHECKPOINT_NAME, how)
    with pytest.raises(ValueError) as failed:
        prepare_run(_cfg(), tmp_path)
    message = str(failed.value)
    assert f"{tmp_path / CHECKPOINT_NAME} is damaged" in message
    assert "No earlier checkpoint is kept" in message
    assert f"mv {tmp_path} {tmp_path}.damaged" in message
    assert "resume=false" in message


def test_the_heatmap_names_a_damaged_checkpoint(tmp_path):
    from results.heatmap import main

    run_dir = tmp_path / "vae_run"
    _train(run_dir, 512, stop_at=256, keep=True)
    _damage(run_dir / CHECKPOINT_NAME, "truncated")
    earlier = run_dir / "checkpoints" / "checkpoint-000000000256.torchrl"
    with pytest.raises(ValueError) as failed:
        main([str(run_dir), "--out", str(tmp_path / "map.png")])
    message = str(failed.value)
    assert f"{run_dir / CHECKPOINT_NAME} is damaged" in message
    assert f"{earlier} (256 frames); pass that file instead" in message


@pytest.mark.parametrize("name", FORMATS)
def test_init_from_names_a_damaged_checkpoint(tmp_path, name):
    from common.minigrid import load_bonus_model

    _train(tmp_path, 512, stop_at=128)
    if name == LEGACY_CHECKPOINT_NAME:
        _legacy(tmp_path)
    _damage(tmp_path / name, "empty")
    with pytest.raises(ValueError) as failed:
        load_bonus_model(None, "vae", tmp_path)
    message = str(failed.value)
    assert message.startswith(f"intrinsic.init_from: {tmp_path / name} is damaged")
    assert "it is empty" in message


# -- damaged and missing logs --------------------------------------------------


def test_a_damaged_log_line_is_named_on_resume(tmp_path):
    _train(tmp_path, 512, stop_at=256)
    draw = tmp_path / DRAW
    rows = draw.read_text().splitlines(keepends=True)
    draw.write_text(rows[0] + "line\n" + "".join(rows[1:]))
    with pytest.raises(ValueError) as failed:
        _train(tmp_path, 512)
    assert f"{draw}, line 2: 'line' is not a 'step,value' row" in str(failed.value)
    with pytest.raises(ValueError, match=rf"{draw}, line 2: 'line'"):
        read_scalar_csv(draw)


def test_a_last_line_cut_short_is_dropped_on_resume(tmp_path):
    # the run died (a full disk) in the middle of a row after its checkpoint
    _train(tmp_path, 512, stop_at=320)
    draw = tmp_path / DRAW
    with open(draw, "a") as f:
        f.write("384,")
    steps, _ = read_scalar_csv(draw)  # read while being written: skipped
    assert steps.tolist()[-1] == 320
    _train(tmp_path, 512)
    steps, _ = read_scalar_csv(draw)
    assert steps.tolist() == list(range(64, 513, 64))


def test_a_resume_refuses_scalar_logs_that_are_gone(tmp_path):
    _train(tmp_path, 512, stop_at=256)
    (tmp_path / DRAW).unlink()
    with pytest.raises(FileNotFoundError) as failed:
        _train(tmp_path, 512)
    message = str(failed.value)
    assert f"Cannot resume {tmp_path}" in message
    assert "at 256 frames" in message
    assert DRAW in message
    assert "resume_without_logs=true" in message
    # allowed explicitly: the run goes on, its curve starts at the checkpoint
    _train(tmp_path, 512, resume_without_logs=True)
    assert read_scalar_csv(tmp_path / DRAW)[0].tolist() == [320, 384, 448, 512]


def test_a_run_without_status_refuses_a_resume_without_any_log(tmp_path):
    # a run directory of an earlier release: no status.json lists its logs
    _train(tmp_path, 512, stop_at=256)
    (tmp_path / "status.json").unlink()
    shutil.rmtree(tmp_path / "logs")
    with pytest.raises(FileNotFoundError, match="logs/\\*/scalars/\\*.csv"):
        prepare_run(_cfg(), tmp_path)
    prepare_run(_cfg(resume_without_logs=True), tmp_path)


# -- status.json ---------------------------------------------------------------


def test_status_records_how_far_the_run_got(tmp_path):
    _train(tmp_path, 512, stop_at=320)  # killed after the checkpoint at 256
    status = json.loads((tmp_path / "status.json").read_text())
    assert status["frames"] == 256
    assert status["total_frames"] == 512
    assert status["finished"] is False
    assert status["task"] == "MiniGrid-Empty-5x5-v0"
    assert status["backend"] == "gymnasium"
    assert status["seed"] == 0
    assert status["setting"] == "none"
    assert status["logs"] == [DRAW]
    _train(tmp_path, 512)
    status = json.loads((tmp_path / "status.json").read_text())
    assert (status["frames"], status["finished"]) == (512, True)


def test_status_names_an_envpool_run_as_the_aggregation_does(tmp_path):
    # the task is the env id, the backend where it ran: two fields, as the
    # aggregation's task and backend columns
    env = {"name": "MiniGrid-Empty-5x5-v0", "backend": "envpool"}
    _train(tmp_path, 128, env=env)
    status = json.loads((tmp_path / "status.json").read_text())
    assert (status["task"], status["backend"]) == ("MiniGrid-Empty-5x5-v0", "envpool")
