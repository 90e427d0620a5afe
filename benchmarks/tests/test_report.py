"""benchmarks/report.py: RESULTS.md's tables agree with the result files, and say so when not.

Fast: reads JSON and text only (no JAX). Each test runs the report on a copy of
RESULTS.md and benchmarks/results/ laid out as in the repository.
"""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

BENCH = Path(__file__).resolve().parents[1]
REPORT = BENCH / "report.py"


def run_report(*args: str | Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, str(REPORT), *map(str, args)], capture_output=True, text=True
    )


@pytest.fixture
def tree(tmp_path: Path) -> Path:
    """A copy of RESULTS.md and results/, side by side as in benchmarks/."""
    shutil.copy(BENCH / "RESULTS.md", tmp_path / "RESULTS.md")
    shutil.copytree(BENCH / "results", tmp_path / "results")
    return tmp_path


def check(tree: Path) -> subprocess.CompletedProcess[str]:
    return run_report("--check", "--doc", tree / "RESULTS.md", "--results", tree / "results")


def test_check_passes_on_the_committed_tree() -> None:
    res = run_report("--check")
    assert res.returncode == 0, res.stderr


@pytest.mark.full
def test_an_edited_figure_fails_naming_its_table(tree: Path) -> None:
    doc = tree / "RESULTS.md"
    text = doc.read_text()
    start = text.index("<!-- report:scaling-ppo -->")
    figure = "**1.41x**"
    at = text.index(figure, start)
    doc.write_text(text[:at] + "**1.51x**" + text[at + len(figure) :])
    res = check(tree)
    assert res.returncode == 1
    assert "'scaling-ppo'" in res.stderr
    assert "'scaling-env'" not in res.stderr  # only the table that differs is named


@pytest.mark.full
def test_an_edited_result_file_fails_naming_its_table(tree: Path) -> None:
    path = tree / "results" / "soak_h100_all_tasks.json"
    rec = json.loads(path.read_text())
    rec["rows"][0]["wall_s"] = 99.9
    path.write_text(json.dumps(rec))
    res = check(tree)
    assert res.returncode == 1
    assert "'soak-h100'" in res.stderr


@pytest.mark.full
def test_rebuilding_restores_the_table(tree: Path) -> None:
    doc = tree / "RESULTS.md"
    committed = doc.read_text()
    doc.write_text(committed.replace("| 3.96 |", "| 4.96 |", 1))
    res = run_report("--doc", doc, "--results", tree / "results")
    assert res.returncode == 0, res.stderr
    assert doc.read_text() == committed


@pytest.mark.parametrize(
    ("content", "says"),
    [
        ("{not json", "not valid JSON"),
        ('{"schema": 1}', "missing field 'name'"),
        (None, "missing field 'commit'"),
    ],
)
def test_a_malformed_result_file_is_one_line_naming_it(
    tree: Path, content: str | None, says: str
) -> None:
    path = tree / "results" / "facade_cpu2_reacher_c.json"
    if content is None:  # a valid file that lost one field
        rec = json.loads(path.read_text())
        del rec["commit"]
        content = json.dumps(rec)
    path.write_text(content)
    res = check(tree)
    assert res.returncode == 2
    lines = res.stderr.strip().splitlines()
    errors = [line for line in lines if "note:" not in line]
    assert len(errors) == 1, res.stderr
    assert "facade_cpu2_reacher_c.json" in errors[0]
    assert says in errors[0]
    assert "Traceback" not in res.stderr


def test_every_result_file_follows_the_schema_and_backs_a_table() -> None:
    sys.path.insert(0, str(BENCH))
    try:
        import report
        import results_io
    finally:
        sys.path.remove(str(BENCH))
    recs = results_io.load_all()
    used = {f for t in report.TABLES.values() for f in t.files}
    assert set(recs) == used


@pytest.mark.full
def test_a_marker_no_table_module_defines_is_one_line_naming_it(tree: Path) -> None:
    doc = tree / "RESULTS.md"
    doc.write_text(
        doc.read_text() + "\n<!-- report:no-such-table -->\n<!-- /report:no-such-table -->\n"
    )
    res = check(tree)
    assert res.returncode == 2
    (line,) = res.stderr.strip().splitlines()
    assert "unknown table 'no-such-table'" in line and "benchmarks/tables/" in line
