"""A run's own record of how far it got: ``<run dir>/status.json``."""

from __future__ import annotations

import json
import os
import time
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from .files import write_atomically
from .labels import run_labels
from .scalar_logs import scalar_log_files

STATUS_NAME = "status.json"
"""A run's own record of how far it got, ``<run dir>/status.json``
(:func:`write_run_status`), rewritten atomically with each checkpoint."""


def write_run_status(
    run_dir: str | os.PathLike,
    config: Mapping[str, Any],
    frames: int,
    labels: Mapping[str, Any] | None = None,
) -> Path:
    """Writes ``<run_dir>/status.json`` atomically: how far the run got.

    Keys: ``task`` (``env.name``, the env id), ``backend`` (``env.backend``:
    where the run stepped its env), ``seed``, ``setting`` (the labels the
    aggregation gives the run: ``labels``, else
    :func:`common.labels.run_labels` of ``config`` and the run's overrides), ``frames``
    (done, as in the checkpoint), ``total_frames`` (the budget,
    ``collector.total_frames``), ``finished`` (``frames >= total_frames``),
    ``logs`` (the scalar logs written so far, relative to the run directory:
    a resume refuses to go on without them) and ``updated`` (UTC time).

    Examples:
        >>> import tempfile
        >>> run_dir = tempfile.mkdtemp()
        >>> config = {"env": {"name": "MiniGrid-Empty-5x5-v0"}, "seed": 0,
        ...           "bonus": "vae", "collector": {"total_frames": 1024}}
        >>> _ = write_run_status(run_dir, config, frames=1024)
        >>> status = read_run_status(run_dir)
        >>> status["finished"], status["frames"], status["setting"]
        (True, 1024, 'vae')
        >>> status["task"], status["backend"]
        ('MiniGrid-Empty-5x5-v0', 'gymnasium')
    """
    run_dir = Path(run_dir)
    if labels is None:
        labels = run_labels(config, run_dir)
    total = (config.get("collector") or {}).get("total_frames")
    status = {
        "task": labels["task"],
        "backend": labels["backend"],
        "seed": labels["seed"],
        "setting": labels["setting"],
        "frames": int(frames),
        "total_frames": None if total is None else int(total),
        "finished": total is not None and int(frames) >= int(total),
        "logs": scalar_log_files(run_dir),
        "updated": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
    }
    path = run_dir / STATUS_NAME
    write_atomically(
        path,
        json.dumps(status, indent=1) + "\n",
        kept="The previous status.json is left as it was.",
    )
    return path


def read_run_status(run_dir: str | os.PathLike) -> dict[str, Any] | None:
    """The run's ``status.json`` (:func:`write_run_status`), or ``None`` for a run
    directory without one (written before it existed).

    Raises:
        ValueError: the file is not the JSON object it should be (named).
    """
    path = Path(run_dir) / STATUS_NAME
    try:
        status = json.loads(path.read_bytes())
    except FileNotFoundError:
        return None
    except ValueError as err:
        raise ValueError(f"{path} is damaged ({err}); delete it") from None
    if not isinstance(status, dict) or not {"frames", "finished"} <= set(status):
        raise ValueError(f"{path} is damaged (no frames or finished); delete it")
    return status
