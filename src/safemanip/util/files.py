"""Files written so that a crash, a kill or a concurrent writer never leaves a half-written result,
output folders checked before any work starts, one live writer per output folder, and the one bounded
JSON reader (``parse_json``/``read_json_file``) every file and server reply goes through."""

from __future__ import annotations

import contextlib
import errno
import fcntl
import json
import os
import re
import tempfile
from itertools import accumulate
from pathlib import Path
from typing import Any, Iterator


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


# ------------------------------------------------------------------------------------------ reading JSON
MAX_JSON_BYTES = 10_000_000
"""Largest JSON document read from a file or a server (10 MB: a policy's metadata, a checkpoint's meta.json, a
sweep cell, a cache entry or a model's answer is a few kB)."""
MAX_JSON_DEPTH = 64
"""Deepest nesting of arrays and objects accepted (the package's own files nest fewer than 10 levels). Checked
before parsing: Python's parser recurses once per level, so 100,000 levels would end in a RecursionError."""

_JSON_STRING = re.compile(r'"[^"\\]*(?:\\.[^"\\]*)*"', re.S)
_NOT_BRACKET = re.compile(r"[^\[\]{}]+")
_BRACKET_STEP = {"[": 1, "{": 1, "]": -1, "}": -1}


class JSONInputError(ValueError):
    """A JSON document (from a file or a server) that is refused: too large, nested too deep, not JSON, holding
    NaN/Infinity or a key twice. ``reason`` says which, without the document's content."""

    def __init__(self, message: str, reason: str):
        super().__init__(message)
        self.reason = reason


def json_depth(text: str) -> int:
    """The deepest nesting of arrays and objects in JSON ``text``, counted without parsing it (brackets inside
    strings do not count)."""
    brackets = _NOT_BRACKET.sub("", _JSON_STRING.sub('""', text))
    return max(accumulate(map(_BRACKET_STEP.__getitem__, brackets)), default=0)


def _refuse_constant(name: str):
    raise ValueError(f"it holds {name}, which is not a JSON number")


def _unique_keys(pairs: list) -> dict:
    out: dict = {}
    for key, value in pairs:
        if key in out:
            raise ValueError(f"it holds the key {key[:40]!r} twice")
        out[key] = value
    return out


def parse_json(text: str | bytes, what: str, *, max_bytes: int = MAX_JSON_BYTES,
               max_depth: int = MAX_JSON_DEPTH) -> Any:
    """The one way the package parses JSON it did not just build itself (config files, policy metadata,
    safetensors headers, checkpoints, sweep specs and results, logs, cache entries, a server's replies).

    Size and nesting depth are checked before the parser sees the text; NaN/Infinity (not JSON) and a key given
    twice in one object are refused. Raises ``JSONInputError``: "<what> is not valid JSON: <reason>"."""
    def refuse(reason: str):
        raise JSONInputError(f"{what} is not valid JSON: {reason}", reason) from None

    if isinstance(text, (bytes, bytearray, memoryview)):
        if len(text) > max_bytes:
            refuse(f"{len(text):,} bytes, more than the {max_bytes:,} accepted")
        try:
            text = bytes(text).decode("utf-8")
        except UnicodeDecodeError:
            refuse("it is not UTF-8 text")
    if len(text) > max_bytes:
        refuse(f"{len(text):,} characters, more than the {max_bytes:,} accepted")
    depth = json_depth(text)
    if depth > max_depth:
        refuse(f"it nests {depth:,} levels deep, more than the {max_depth} accepted")
    try:
        return json.loads(text, parse_constant=_refuse_constant, object_pairs_hook=_unique_keys)
    except RecursionError:  # not reachable after the depth check; kept so that no input can end in a traceback
        refuse("it nests too deep")
    except ValueError as err:
        refuse(str(err))


def read_json_file(path: str | os.PathLike, what: str | None = None, *, max_bytes: int = MAX_JSON_BYTES,
                   max_depth: int = MAX_JSON_DEPTH) -> Any:
    """``parse_json`` of a file's content; a file larger than ``max_bytes`` is refused without being read.
    OSError (a missing or unreadable file) is left to the caller."""
    path = Path(path)
    what = what or str(path)
    with open(path, "rb") as f:
        size = os.fstat(f.fileno()).st_size
        if size > max_bytes:
            raise JSONInputError(f"{what} is not valid JSON: {size:,} bytes, more than the {max_bytes:,} accepted",
                                 f"{size:,} bytes, more than the {max_bytes:,} accepted")
        data = f.read(max_bytes + 1)
    return parse_json(data, what, max_bytes=max_bytes, max_depth=max_depth)
