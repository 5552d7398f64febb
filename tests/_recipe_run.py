"""Running a recipe as a user does, for the recipe tests."""

from __future__ import annotations

import os
import signal
import subprocess
import time
from pathlib import Path

from torchrl_surprise.experiments import load_checkpoint


def kill_after_checkpoint(cmd: list[str], ckpt_path: Path, min_frames: int) -> dict:
    """Starts ``cmd``, SIGKILLs it once its checkpoint holds ``min_frames``.

    Returns the checkpoint the killed run left behind.
    """
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.time() + 120
    try:
        while time.time() < deadline:
            if (
                ckpt_path.exists()
                and load_checkpoint(ckpt_path)["frames"] >= min_frames
            ):
                break
            time.sleep(0.5)
    finally:
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait()
    return load_checkpoint(ckpt_path)
