"""On-disk cache of structured VLM answers, so evaluations can be re-run without calling out again.

One JSON file per answer (never pickle: cache directories get shared and JSON cannot execute code).
The key hashes everything that determines the answer's distribution: model, full prompt text,
image bytes and the schema. Writes go to a temporary file that is then renamed with ``os.replace``,
so a crash or a concurrent writer never leaves a half-written entry behind.

A command checks its cache folder before it asks anything (``cache_dir_problems``); a store that still fails
later (a full disk, a folder replaced or remounted read-only during the run) is a warning, and the run goes on
without caching rather than losing the answer it just paid for.
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
import tempfile
import time
from pathlib import Path
from typing import Sequence

from safemanip.semantics.base import BackendError
from safemanip.util.files import JSONInputError, check_output_dir, read_json_file
from safemanip.util.secrets import redact_value

log = logging.getLogger(__name__)

CACHE_FORMAT = "safemanip-vlm-cache/1"
CACHE_MODES = ("readwrite", "readonly", "cache_only")
MAX_ENTRY_BYTES = 4_000_000


def cache_key(model: str, prompt: str, images: Sequence[bytes], schema: dict) -> str:
    """sha256 hex digest over (model, prompt text, image bytes, canonical schema JSON).

    Every field is length-prefixed so that moving bytes from one field to the next changes the key.
    """
    h = hashlib.sha256()

    def feed(tag: bytes, data: bytes) -> None:
        h.update(tag + len(data).to_bytes(8, "big") + data)

    feed(b"model", model.encode("utf-8"))
    feed(b"prompt", prompt.encode("utf-8"))
    for img in images:
        feed(b"image", bytes(img))
    feed(b"schema", json.dumps(schema, sort_keys=True, separators=(",", ":")).encode("utf-8"))
    return h.hexdigest()


def cache_dir_problems(root: str | os.PathLike, flag: str = "--vlm-cache") -> list[str]:
    """Problems with storing answers under folder ``root`` (created if missing), found before any query: every
    existing component a folder, the deepest one writable; an existing folder also by a real probe write
    (``os.access`` can say yes where a write fails, e.g. on a read-only mount or with ACLs)."""
    problems = check_output_dir(root, flag)
    if problems:
        return [f"{problems[0]}; or replay stored answers with --vlm-cache-only"]
    path = Path(root)
    if path.is_dir():
        try:
            fd, probe = tempfile.mkstemp(prefix=".write-probe.", suffix=".tmp", dir=path)
            os.close(fd)
            os.unlink(probe)
        except OSError as exc:
            return [f"{flag} {path}: cannot store answers in it ({exc.strerror or exc}); choose a folder you can "
                    f"write to, or replay stored answers with --vlm-cache-only"]
    return []


class ResponseCache:
    """Answers stored as ``<root>/<key[:2]>/<key>.json``.

    Modes:
      - ``readwrite``: read hits, store new answers (default).
      - ``readonly``: read hits, never write (e.g. a shared, frozen cache).
      - ``cache_only``: read hits; a miss raises ``BackendError("cache miss ...")`` *before* any call
        goes out, which makes an evaluation reproducible offline from a recorded cache.
    """

    def __init__(self, root: str | os.PathLike, mode: str = "readwrite") -> None:
        if mode not in CACHE_MODES:
            raise ValueError(f"cache mode must be one of {CACHE_MODES}, got {mode!r}")
        self.root = Path(root)
        self.mode = mode
        self.hits = 0
        self.misses = 0
        self.write_error: str | None = None
        """Why storing an answer failed (then nothing more is stored in this run), or None."""

    @property
    def cache_only(self) -> bool:
        return self.mode == "cache_only"

    def _path(self, key: str) -> Path:
        return self.root / key[:2] / f"{key}.json"

    def get(self, key: str, expect: dict | None = None) -> dict | None:
        """The stored answer for ``key``, or None. In cache_only mode a miss raises BackendError.

        ``expect``: meta values the entry must have been recorded with (model, prompt and schema versions);
        an entry recorded under other versions is a miss."""
        path = self._path(key)
        entry: dict | None = None
        corrupt: str | None = None
        try:
            entry = read_json_file(path, str(path), max_bytes=MAX_ENTRY_BYTES)
        except FileNotFoundError:
            pass
        except (OSError, ValueError) as exc:
            # a corrupt entry (unreadable, too large or deep, not JSON) is treated as a miss (and overwritten on the
            # next store), not as fatal
            corrupt = str(exc) if isinstance(exc, JSONInputError) else f"{path}: {exc}"
        if entry is not None and not isinstance(entry, dict):
            corrupt, entry = f"{path}: not a JSON object", None
        if entry is not None and (entry.get("format") != CACHE_FORMAT or entry.get("key") != key
                                  or not isinstance(entry.get("answer"), dict)):
            corrupt, entry = f"{path}: not a {CACHE_FORMAT} entry for this key", None
        if entry is not None and expect:
            meta = entry.get("meta") if isinstance(entry.get("meta"), dict) else {}
            stale = {k: meta.get(k) for k, v in expect.items() if meta.get(k) != v}
            if stale:
                corrupt, entry = f"{path}: recorded with {stale}, not the current {expect}", None
        if entry is None:
            self.misses += 1
            if self.cache_only:
                why = f" (unreadable entry {corrupt})" if corrupt else ""
                raise BackendError(
                    f"cache miss for key {key[:12]}... in {self.root}{why}; the cache is in cache_only mode, so no "
                    "request was sent. Record answers first with a readwrite cache, or point at the cache "
                    "directory that holds them (the key covers model, prompt text, images and schema).")
            return None
        self.hits += 1
        return redact_value(entry["answer"])

    def put(self, key: str, answer: dict, meta: dict | None = None) -> None:
        """Store ``answer`` atomically (no-op unless mode is readwrite). A store that fails (OSError) is a warning,
        once; the answer is still used and the cache is not written to again in this run."""
        if self.mode != "readwrite" or self.write_error is not None:
            return
        try:
            self._store(key, answer, meta)
        except OSError as exc:
            self.write_error = f"{exc.strerror or exc}"
            log.warning("cannot store VLM answers in the cache folder %s (%s: %s); going on without caching",
                        self.root, exc.__class__.__name__, self.write_error)

    def _store(self, key: str, answer: dict, meta: dict | None) -> None:
        path = self._path(key)
        path.parent.mkdir(parents=True, exist_ok=True)
        entry = {"format": CACHE_FORMAT, "key": key, "created_unix": time.time(), "meta": redact_value(meta or {}),
                 "answer": redact_value(answer)}  # never a credential in a file that gets shared
        fd, tmp = tempfile.mkstemp(prefix=f".{key[:12]}.", suffix=".tmp", dir=path.parent)
        try:
            with os.fdopen(fd, "w", encoding="utf-8") as f:
                json.dump(entry, f, indent=1, sort_keys=True)
                f.flush()
                os.fsync(f.fileno())
            os.replace(tmp, path)
        except BaseException:
            try:
                os.unlink(tmp)
            except FileNotFoundError:
                pass
            raise

    def count(self) -> int:
        """Number of stored entries (a method, not __len__, so an empty cache is still truthy)."""
        return sum(1 for _ in self.root.glob("??/*.json")) if self.root.exists() else 0
