"""The documentation builds with Sphinx, warnings as errors (as ``make docs``)."""

from __future__ import annotations

import csv
import re
import subprocess
import sys
from pathlib import Path

import pandas as pd

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


# ---------------------------------------------- the "which bonus" table's numbers

_SCORE = re.compile(r"(-?\d+\.\d+) \[(-?\d+\.\d+), (-?\d+\.\d+)\]")
_BUDGET = {"k": 1_000, "M": 1_000_000}


def _which_bonus_rows() -> list[tuple[str, list[str]]]:
    # (where, cells) of the README's table and of docs/results.rst's "What to use"
    rows = []
    readme = (ROOT / "README.md").read_text().split("## Which bonus to use", 1)[1]
    for line in readme.split("\n## ", 1)[0].splitlines():
        cells = [cell.strip() for cell in line.strip().strip("|").split("|")]
        if line.startswith("| ") and not cells[0].startswith(("situation", "---")):
            rows.append(("README.md", cells))
    page = (DOCS / "results.rst").read_text()
    table = page.split(".. csv-table:: Which bonus to use", 1)[1].split("\n\n", 2)[1]
    lines = (line.strip() for line in table.splitlines())
    for cells in csv.reader(lines, skipinitialspace=True):
        rows.append(("docs/results.rst", [cell.strip() for cell in cells]))
    return rows


def _setting(cell: str) -> str:
    found = re.search(r"(?:\+setting|bonus)=(\w+)", cell)
    assert found, f"no +setting= or bonus= in {cell!r}"
    # bonus=vae runs the recipes' default variant, the elliptical VAE bonus
    return "vae_elliptical" if found.group() == "bonus=vae" else found.group(1)


def test_the_which_bonus_tables_read_their_numbers_from_committed_summaries():
    rows = _which_bonus_rows()
    assert sum(where == "README.md" for where, _ in rows) >= 5
    readme = [cells for where, cells in rows if where == "README.md"]
    page = [cells for where, cells in rows if where != "README.md"]

    # the results page's table is the README's, row for row (markup aside)
    def plain(rows):
        return [[cell.replace("`", "") for cell in cells[:5]] for cells in rows]

    assert plain(page) == plain(readme)
    for where, (situation, setting, _, score, budget, data) in rows:
        study = re.search(r"docs/results/(\w+)", data) or re.search(r"(\w+)", data)
        summary = pd.read_csv(
            ROOT / "docs" / "results" / study.group(1) / "summary.csv",
            keep_default_na=False,
        )
        name = _setting(setting)
        found = summary[
            (summary["setting"] == name) | summary["setting"].str.startswith(name + ",")
        ]
        assert len(found) == 1, f"{where}, {situation!r}: {name} in {study.group(1)}"
        row = found.iloc[0]
        iqm, low, high = _SCORE.search(score).groups()
        shown = [float(iqm), float(low), float(high)]
        stored = [row[f"train_return_{k}"] for k in ("iqm", "ci_low", "ci_high")]
        # rounded as the reports print them (a stored 0.995 is 0.99499...: 0.99)
        assert shown == [float(f"{v:.2f}") for v in stored], f"{where}, {situation!r}"
        frames, seeds = (part.strip() for part in budget.split(","))
        assert int(float(frames[:-1]) * _BUDGET[frames[-1]]) == row["budget"]
        assert int(seeds) == row["seeds"], f"{where}, {situation!r}: seeds"


def test_the_docs_say_exact_resume_needs_the_same_thread_count():
    # torch_threads may change on resume (the same run), but a resume is exact
    # only at the thread count the run started with: the recipes' page says so
    recipes = " ".join((DOCS / "recipes.rst").read_text().split())
    assert "``torch_threads``" in recipes
    assert "a resume is exact at the thread count it started with" in recipes


def test_the_new_user_probe_names_tests_that_exist():
    # tests/probe_new_user.py replays the defects a new user found by the tests
    # that pin their fixes: each must be a test pytest collects
    sys.path.insert(0, str(ROOT / "tests"))
    try:
        from probe_new_user import PROBE
    finally:
        sys.path.remove(str(ROOT / "tests"))
    ids = sorted({test for _, tests in PROBE.values() for test in tests})
    assert sorted(PROBE) == list(range(1, 11))
    result = subprocess.run(
        [sys.executable, "-m", "pytest", "--collect-only", "-q", *ids],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert result.returncode == 0, result.stdout[-2000:] + result.stderr[-2000:]
    collected = {
        line.split("[")[0] for line in result.stdout.splitlines() if "::" in line
    }
    assert set(ids) <= collected, set(ids) - collected
