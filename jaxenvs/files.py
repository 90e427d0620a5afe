"""Atomic file writes: a reader sees the old file or the whole new one, never a part.

Every file the package writes (checkpoints, progress tables, summaries, plots, videos,
stored programs, benchmark JSON) goes through :func:`atomic_path`: the content is written
to a fresh temporary file in the target's directory (same file system, so the final
rename is atomic), then renamed over the target. If writing fails or is interrupted the
temporary file is removed and the target is left as it was.

    with atomic_path("out/plot.png") as tmp:     # tmp keeps the suffix: .png
        fig.savefig(tmp)
    write_bytes("out/state.bin", data, fsync=True)
"""

from __future__ import annotations

import os
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

#: permissions of a finished file (``mkstemp`` creates 0600, which would make it private).
FILE_MODE = 0o644


@contextmanager
def atomic_path(path: str | os.PathLike[str], *, fsync: bool = False) -> Iterator[Path]:
    """Yield a temporary path next to ``path``; on a clean exit rename it over ``path``.

    The temporary name starts with ``.`` and keeps ``path``'s suffix, so tools that pick a
    format from the extension (matplotlib, imageio) see the right one. ``fsync`` flushes
    the finished file to disk before the rename (for files a crash must not lose). The
    parent directory must exist.
    """
    path = Path(path)
    fd, name = tempfile.mkstemp(prefix=f".{path.name}.", suffix=path.suffix, dir=path.parent)
    os.close(fd)
    tmp = Path(name)
    try:
        os.chmod(tmp, FILE_MODE)
        yield tmp
        if fsync:
            with tmp.open("rb+") as f:
                os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def write_bytes(path: str | os.PathLike[str], data: bytes, *, fsync: bool = False) -> None:
    """Write ``data`` to ``path`` atomically."""
    with atomic_path(path, fsync=fsync) as tmp:
        tmp.write_bytes(data)


def write_text(path: str | os.PathLike[str], text: str, *, fsync: bool = False) -> None:
    """Write ``text`` (UTF-8) to ``path`` atomically."""
    write_bytes(path, text.encode(), fsync=fsync)
