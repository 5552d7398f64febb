"""The documentation builds with Sphinx, warnings as errors (as ``make docs``)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

DOCS = Path(__file__).resolve().parent.parent / "docs"


def test_docs_build_without_warnings(tmp_path: Path) -> None:
    # A subprocess keeps Sphinx's global state (registries, logging, warnings
    # filters) out of the test process.
    out = tmp_path / "html"
    result = subprocess.run(
        [
            sys.executable,
            "-m",
            "sphinx",
            "-W",
            "--keep-going",
            "-q",
            "-b",
            "html",
            "-d",
            str(tmp_path / "doctrees"),
            str(DOCS),
            str(out),
        ],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert result.returncode == 0, (
        f"sphinx failed ({result.returncode}):\n{result.stdout}\n{result.stderr}"
    )
    api = (out / "api.html").read_text(encoding="utf-8")
    assert "VAESurpriseTransform" in api
    assert 'id="torchrl_surprise.transforms.VAESurpriseTransform"' in api
