"""The example scripts of the docs run, and do what the docs say."""

from __future__ import annotations

import importlib.util
import math
from pathlib import Path

EXAMPLES = Path(__file__).resolve().parents[1] / "docs" / "examples"


def load(name: str):
    spec = importlib.util.spec_from_file_location(name, EXAMPLES / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_two_stream_a2c_example_trains_a_users_pipeline():
    result = load("two_stream_a2c").main(frames=1024)
    assert result["episodes"] > 0
    assert 0.0 <= result["mean_return_last_100"] <= 1.0
    # The VAE trained between rollouts: the bonus it gives has moved.
    assert math.isfinite(result["mean_bonus_last"])
    assert result["mean_bonus_last"] != result["mean_bonus_first"]
