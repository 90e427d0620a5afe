"""Atomic file writes: a reader sees the old file or the whole new one, never a part.

Every file the package writes (checkpoints, progress tables, summaries, plots, videos,
stored programs, benchmark JSON) goes through :func:`atomic_path`: the content is written
to a fresh temporary file in the target's directory (same file system, so the final
rename is atomic), then renamed over the target. If writing fails or is interrupted the
temporary file is removed and the target is left as it was.

    with atomic_path("out/plot.png") as tmp:     # tmp keeps the suffix: .png
        fig.savefig(tmp)
    write_bytes("out/state.bin", data, fsync=True)

A process that writes a directory's files for a while (a training run) first claims the
directory with :func:`claim_directory`: an exclusive lock held until it is done, so a
second process is refused at once instead of mixing its files in. The lock is the
operating system's (``flock``), released when the holder exits however it exits, so a
killed run never leaves a claim that blocks the next one. Under the claim,
:func:`remove_temporaries` deletes what an interrupted writer left behind.
"""

from __future__ import annotations

import os
import tempfile
from collections.abc import Iterable, Iterator
from contextlib import contextmanager
from pathlib import Path

#: the file a claimed directory holds its lock on (its text names the holder)
CLAIM_FILE = ".claim"

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


class DirectoryBusy(OSError):
    """Another process holds the claim on a directory."""


def _lock(fd: int) -> bool:
    """Take an exclusive lock on the open file ``fd`` without waiting; False if held."""
    try:
        import fcntl
    except ImportError:  # no flock on this platform: lock the file's first byte
        import msvcrt

        try:
            msvcrt.locking(fd, msvcrt.LK_NBLCK, 1)  # type: ignore[attr-defined]
        except OSError:
            return False
        return True
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        return False
    return True


@contextmanager
def claim_directory(path: str | os.PathLike[str], owner: str) -> Iterator[Path]:
    """Hold an exclusive claim on directory ``path`` (created) for the ``with`` block.

    ``owner`` (one line: who claims it, e.g. a pid and a command) is recorded in the
    claim file while the claim is held. Raises :class:`DirectoryBusy` at once, naming the
    directory and the holder, when another process (or another claim in this one) holds
    it. The claim ends with the block or with the process.
    """
    path = Path(path)
    path.mkdir(parents=True, exist_ok=True)
    fd = os.open(path / CLAIM_FILE, os.O_RDWR | os.O_CREAT, FILE_MODE)
    try:
        if not _lock(fd):
            holder = os.read(fd, 1000).decode(errors="replace").strip()
            raise DirectoryBusy(f"{path} is in use by {holder or 'another process'}")
        os.ftruncate(fd, 0)
        os.write(fd, owner.encode())
        try:
            yield path
        finally:
            os.ftruncate(fd, 0)
    finally:
        os.close(fd)


def remove_temporaries(directory: str | os.PathLike[str], names: Iterable[str]) -> list[Path]:
    """Delete the temporary files :func:`atomic_path` left in ``directory`` for the files
    ``names`` (a writer killed mid-write leaves one); returns those removed. Only safe
    while no other process writes them (under :func:`claim_directory`)."""
    removed = []
    for name in names:
        suffix = Path(name).suffix
        for tmp in Path(directory).glob(f".{name}.*{suffix}"):
            if tmp.is_file():
                tmp.unlink(missing_ok=True)
                removed.append(tmp)
    return removed
