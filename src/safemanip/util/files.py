"""Files written so that a crash, a kill or a concurrent writer never leaves a half-written result,
output folders checked before any work starts, and one live writer per output folder."""

from __future__ import annotations

import contextlib
import errno
import fcntl
import os
import tempfile
from pathlib import Path
from typing import Iterator


class OutputError(ValueError):
    """An output path that cannot be written; the message says what to change."""


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike) -> Iterator[str]:
    """A unique temporary file name beside ``path`` for a writer to fill; renamed over ``path`` when the block
    ends without an exception, removed otherwise."""
    path = Path(path)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    os.close(fd)
    try:
        yield tmp
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        raise


@contextlib.contextmanager
def atomic_open(path: str | os.PathLike, mode: str = "w", **kwargs) -> Iterator:
    """``open`` for writing a whole file at once: the file appears under ``path`` (fsynced) only when the
    block ends without an exception."""
    with atomic_path(path) as tmp, open(tmp, mode, **kwargs) as f:
        yield f
        f.flush()
        os.fsync(f.fileno())


def atomic_write_text(path: str | os.PathLike, text: str) -> Path:
    """Write ``text`` to a unique temporary file beside ``path``, fsync it, then rename it over ``path``."""
    with atomic_open(path, "w", encoding="utf-8", newline="") as f:
        f.write(text)
    return Path(path)


def check_output_dir(path: str | os.PathLike, flag: str = "--out") -> list[str]:
    """Problems with writing into folder ``path`` (created if missing), found without creating anything.

    Every existing component must be a folder, and the deepest existing one writable."""
    path = Path(path)
    if str(path).strip() == "":
        return [f"{flag} is empty; give a folder path"]
    if path.exists() and not path.is_dir():
        return [f"{flag} {path} is a file, not a folder; choose another path"]
    probe = path.absolute()
    while not probe.exists():
        if probe.is_symlink():
            return [f"{flag} {path}: {probe} is a dangling symbolic link"]
        probe = probe.parent
    if not probe.is_dir():
        return [f"{flag} {path}: {probe} is a file, so no folder can be made under it; choose another path"]
    if not os.access(probe, os.W_OK | os.X_OK):
        return [f"{flag} {path}: the folder {probe} is not writable; choose a folder you can write to"]
    return []


def check_output_file(path: str | os.PathLike, flag: str) -> list[str]:
    """Problems with writing file ``path`` (its folder is created if missing)."""
    path = Path(path)
    if path.is_dir():
        return [f"{flag} {path} is a folder; give a file path"]
    return check_output_dir(path.parent if str(path.parent) else ".", flag=f"{flag} {path}: its folder")


class OutputLock:
    """An exclusive lock on an output folder (``<folder>/.lock``, ``fcntl.flock``).

    The operating system drops the lock when the holder exits, however it exits, so a stale lock file
    from a killed run never blocks the next one; a folder held by a live process is refused."""

    def __init__(self, folder: str | os.PathLike, flag: str = "--out"):
        self.folder, self.flag = Path(folder), flag
        self._fd: int | None = None

    def acquire(self) -> "OutputLock":
        self.folder.mkdir(parents=True, exist_ok=True)
        path = self.folder / ".lock"
        fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError as err:
            holder = os.pread(fd, 64, 0).decode(errors="replace").strip() or "another process"
            os.close(fd)
            if err.errno in (errno.EAGAIN, errno.EACCES):
                raise OutputError(f"{self.flag} {self.folder} is in use by a running process (pid {holder}); wait for "
                                  f"it to finish or choose another {self.flag}") from None
            raise
        os.ftruncate(fd, 0)
        os.pwrite(fd, str(os.getpid()).encode(), 0)
        self._fd = fd
        return self

    def release(self) -> None:
        if self._fd is not None:
            fcntl.flock(self._fd, fcntl.LOCK_UN)
            os.close(self._fd)
            self._fd = None

    def __enter__(self) -> "OutputLock":
        return self.acquire()

    def __exit__(self, *exc) -> None:
        self.release()
