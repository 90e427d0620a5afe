"""Atomic writes: the target holds the old or the whole new content, and no temp file stays."""

from __future__ import annotations

import stat
from pathlib import Path

import pytest

from jaxenvs import files


def _leftovers(directory: Path, keep: str) -> list[str]:
    return sorted(p.name for p in directory.iterdir() if p.name != keep)


def test_write_replaces_whole_file_readable_by_others(tmp_path: Path) -> None:
    target = tmp_path / "summary.json"
    target.write_text("old")
    files.write_text(target, '{"new": 1}\n', fsync=True)
    assert target.read_text() == '{"new": 1}\n'
    assert stat.S_IMODE(target.stat().st_mode) == files.FILE_MODE
    assert _leftovers(tmp_path, "summary.json") == []


def test_failed_write_keeps_old_file_and_removes_temp(tmp_path: Path) -> None:
    target = tmp_path / "curve.png"
    target.write_bytes(b"old picture")
    with pytest.raises(RuntimeError, match="disk full"), files.atomic_path(target) as tmp:
        assert tmp.parent == tmp_path and tmp.suffix == ".png" and tmp.name.startswith(".")
        tmp.write_bytes(b"half a pict")
        raise RuntimeError("disk full")
    assert target.read_bytes() == b"old picture"
    assert _leftovers(tmp_path, "curve.png") == []


def test_interrupt_keeps_old_file(tmp_path: Path) -> None:
    target = tmp_path / "progress.csv"
    target.write_text("a,b\n1,2\n")
    with pytest.raises(KeyboardInterrupt), files.atomic_path(target) as tmp:
        tmp.write_text("a,b\n")
        raise KeyboardInterrupt
    assert target.read_text() == "a,b\n1,2\n"
    assert _leftovers(tmp_path, "progress.csv") == []


def test_missing_directory_is_an_error_not_a_silent_skip(tmp_path: Path) -> None:
    with pytest.raises(FileNotFoundError):
        files.write_bytes(tmp_path / "nope" / "x.bin", b"1")
