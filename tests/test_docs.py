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


ROOT = DOCS.parent


def _shell_lines() -> list[tuple[str, str]]:
    # (where, line) of each documented shell command: the docs' "$ " lines and
    # the README's fenced blocks other than Python's
    lines = []
    for page in sorted(DOCS.glob("*.rst")):
        for number, line in enumerate(page.read_text().splitlines(), 1):
            if line.strip().startswith("$ "):
                lines.append((f"{page.name}:{number}", line.strip()[2:]))
    fence = None
    for number, line in enumerate((ROOT / "README.md").read_text().splitlines(), 1):
        if line.startswith("```"):
            fence = None if fence is not None else line[3:].strip()
        elif fence is not None and fence not in ("python", "py"):
            lines.append((f"README.md:{number}", line))
    return lines


def _quoted_globs(line: str) -> list[str]:
    # the quoted words of a shell line holding * or ?: the shell would pass them
    # on unexpanded (a run directory named "+setting=*" exists nowhere)
    found, quote, word = [], None, ""
    for char in line.split(" #", 1)[0]:
        if quote is None and char in "\"'":
            quote, word = char, ""
        elif char == quote:
            if any(c in word for c in "*?"):
                found.append(word)
            quote = None
        elif quote is not None:
            word += char
    return found


def test_documented_commands_leave_their_globs_to_the_shell() -> None:
    assert _quoted_globs('ls "runs/+setting=*,seed=0" "a"/b*.pt') == [
        "runs/+setting=*,seed=0"
    ]
    lines = _shell_lines()
    assert len(lines) > 50  # the docs' commands were found
    quoted = {where: _quoted_globs(line) for where, line in lines}
    assert {where: words for where, words in quoted.items() if words} == {}
