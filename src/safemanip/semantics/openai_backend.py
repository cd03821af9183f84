"""VLM backend speaking the OpenAI chat-completions API (OpenAI itself, or any compatible server:
vLLM, llama.cpp server, Ollama's /v1 endpoint, ...).

Structured outputs (``response_format`` of type ``json_schema`` with ``strict: true``) restrict the
answer to the scene's labels; every answer is still validated here, since compatible servers differ
in how faithfully they honour the schema. Retries are our own loop (the client's are switched off)
so that back-off, the number of attempts and which errors are retried are explicit and testable.

Time limits hold against any server: ``timeout_s`` bounds the *whole* of one request (connect, headers, body),
not each socket read, so a server that drips one byte a second is cut off at the deadline (a watchdog shuts the
request's socket down); a query deadline set by ``GuardedBackend`` (the episode and run budgets) bounds the
attempts and back-off together. The server's reply is read through the package's bounded JSON reader (size and
nesting checked before parsing), and the API key and URL credentials never reach a message, a log or the cache.
"""

from __future__ import annotations

import base64
import contextlib
import json
import logging
import math
import os
import random
import re
import socket
import threading
import time
from typing import Any, Callable, Sequence

import openai

from safemanip.semantics.base import (BackendError, ConstraintAnswer, ConstraintQuery, ObjectAnswer, ObjectQuery,
                                      SchemaError)
from safemanip.semantics.cache import ResponseCache, cache_key
from safemanip.semantics.prompts import load_prompt
from safemanip.semantics.schemas import (CONSTRAINT_SCHEMA_NAME, OBJECT_SCHEMA_NAME, SCHEMA_VERSION, constraint_schema,
                                         object_selection_schema, parse_constraint_answer, parse_object_answer)
from safemanip.util.files import JSONInputError, parse_json
from safemanip.util.secrets import mask_url, redact, redact_value

log = logging.getLogger(__name__)

# HTTP statuses worth another attempt: timeouts, conflicts, rate limits and server-side failures
_RETRY_STATUS = {408, 409, 429}
MAX_REPLY_BYTES = 4_000_000
"""Largest reply body read from the server (an answer is a few kB; the images go the other way)."""


class OpenAIBackend:
    """Object selection and constraint assignment by a vision-language model behind an OpenAI-style API.

    The API key is read from ``OPENAI_API_KEY`` (``"none"`` when unset, which local servers accept);
    it is handed to the client only and never logged, cached or included in ``describe()``.
    """

    needs_images = True

    def __init__(self, model: str = "gpt-4o", base_url: str | None = None, *, timeout_s: float = 30.0,
                 attempts: int = 3, backoff_s: float = 1.0, backoff_max_s: float = 16.0,
                 temperature: float | None = 0.0, max_tokens: int | None = 1000, prompt_version: str = "v1",
                 cache: ResponseCache | None = None, client: Any | None = None,
                 sleep: Callable[[float], None] = time.sleep, seed: int | None = None) -> None:
        if attempts < 1:
            raise ValueError(f"attempts must be >= 1, got {attempts}")
        if timeout_s <= 0:
            raise ValueError(f"timeout_s must be > 0, got {timeout_s}")
        self.name = f"openai:{model}"
        self.model = model
        self.base_url = base_url
        self.timeout_s = float(timeout_s)
        self.attempts = int(attempts)
        self.backoff_s = float(backoff_s)
        self.backoff_max_s = float(backoff_max_s)
        self.temperature = temperature
        self.max_tokens = max_tokens
        self.prompt_version = prompt_version
        self.cache = cache
        self._sleep = sleep
        self._rng = random.Random(seed)
        self.calls = 0
        """Requests actually sent (cache hits do not count)."""
        self.shown_url = mask_url(base_url)
        """``base_url`` as messages show it: without ``user:password@``."""
        self._query_deadline: float | None = None
        self._streams: list = []
        self._aborted = threading.Event()
        if client is None:
            http = openai.DefaultHttpxClient(event_hooks={"request": [self._on_request], "response": [self._on_response]})
            client = openai.OpenAI(base_url=base_url, api_key=os.environ.get("OPENAI_API_KEY") or "none",
                                   timeout=self.timeout_s, max_retries=0, http_client=http)
        self._client = client

    def __repr__(self) -> str:
        return f"OpenAIBackend(model={self.model!r}, base_url={self.shown_url!r})"

    def set_deadline(self, seconds: float | None) -> None:
        """Bound the next queries (all their attempts and back-off) to ``seconds`` from now; None: no bound beyond
        ``timeout_s`` per request. Set by ``GuardedBackend`` from the episode and run budgets."""
        self._query_deadline = None if seconds is None else time.monotonic() + max(0.0, seconds)

    def describe(self) -> dict:
        return {"backend": "openai", "model": self.model, "base_url": self.shown_url,
                "prompt_version": self.prompt_version, "temperature": self.temperature,
                "cache": None if self.cache is None else {"root": str(self.cache.root), "mode": self.cache.mode}}

    def prepare(self, names: Sequence[str]) -> None:
        """Nothing to precompute: the model sees names and images at query time."""

    # ----------------------------------------------------------------- queries

    def select_objects(self, query: ObjectQuery) -> ObjectAnswer:
        labels = query.labels
        k = query.n_select
        schema = object_selection_schema(labels, k)
        system = load_prompt("object_selection", self.prompt_version, task=query.task)
        listing = "\n".join(f"position {pos}: {label}" for pos, label in enumerate(labels))
        user = (f"Objects on the table, sorted by distance to the end-effector (position 0 is the nearest):\n"
                f"{listing}\n\nChoose exactly k = {k} objects.")
        if not query.images:
            user += " No camera frame is available for this query; rely on the sorted list."
        with _redacted_errors():
            answer, cached = self._structured(system, user, query.images or [], OBJECT_SCHEMA_NAME, schema,
                                              lambda a: parse_object_answer(a, labels, k))
        ids, explanation, description = parse_object_answer(answer, labels, k)
        return ObjectAnswer(ids=ids, explanation=explanation, image_description=description, raw=answer,
                            cached=cached)

    def assign_constraints(self, query: ConstraintQuery) -> ConstraintAnswer:
        labels = query.labels
        schema = constraint_schema(labels)
        system = load_prompt("constraint_selection", self.prompt_version, task=query.task)
        listing = "\n".join(f"- {label}" for label in labels)
        user = f"Objects on the table:\n{listing}\n\nGive one constraint type for every object."
        with _redacted_errors():
            answer, cached = self._structured(system, user, query.images or [], CONSTRAINT_SCHEMA_NAME, schema,
                                              lambda a: parse_constraint_answer(a, labels))
        constraints, explanations = parse_constraint_answer(answer, labels)
        return ConstraintAnswer(constraints=constraints, explanations=explanations, raw=answer, cached=cached)

    # ----------------------------------------------------------------- transport

    def _structured(self, system: str, user: str, images: Sequence[bytes], schema_name: str, schema: dict,
                    check: Callable[[dict], Any]) -> tuple[dict, bool]:
        """A validated structured answer (from the cache when possible) and whether it was cached."""
        key = cache_key(self.model, json.dumps([system, user]), images, schema) if self.cache is not None else ""
        if self.cache is not None:
            hit = self.cache.get(key, expect=self._cache_meta(schema_name))  # BackendError on a miss if cache_only
            if hit is not None:
                try:
                    check(hit)
                    return hit, True
                except SchemaError as exc:
                    if self.cache.cache_only:
                        raise BackendError(f"cached answer {key[:12]}... does not fit the scene ({exc}) and the "
                                           "cache is in cache_only mode; delete the entry or re-record it") from exc
                    log.warning("ignoring cached answer %s...: %s", key[:12], exc)
        content: list[dict] = [{"type": "text", "text": user}]
        for png in images:
            url = "data:image/png;base64," + base64.b64encode(png).decode("ascii")
            content.append({"type": "image_url", "image_url": {"url": url}})
        messages = [{"role": "system", "content": system}, {"role": "user", "content": content}]
        response_format = {"type": "json_schema",
                           "json_schema": {"name": schema_name, "strict": True, "schema": schema}}

        last: BackendError | None = None
        query_deadline = self._query_deadline if self._query_deadline is not None else math.inf
        for attempt in range(self.attempts):
            if attempt:
                delay = min(self.backoff_max_s, self.backoff_s * 2 ** (attempt - 1))
                delay *= 0.5 + 0.5 * self._rng.random()  # jitter so parallel workers do not retry in lock-step
                if time.monotonic() + delay >= query_deadline:
                    break
                log.warning("%s: attempt %d/%d failed (%s); retrying in %.2fs", self.name, attempt, self.attempts,
                            last, delay)
                self._sleep(delay)
            now = time.monotonic()
            if now >= query_deadline:
                last = last or BackendError("the query's time budget was used up before a request could be sent")
                break
            try:
                answer = self._request(messages, response_format, min(now + self.timeout_s, query_deadline))
                answer = redact_value(answer)  # a model that repeats a credential never gets it stored or shown
                check(answer)
            except _Retryable as exc:
                last = BackendError(str(exc))
                continue
            except SchemaError as exc:
                # a model (esp. behind a server that ignores strict schemas) can miss once and succeed next time
                last = exc
                continue
            if self.cache is not None:
                self.cache.put(key, answer, meta=self._cache_meta(schema_name))
            return answer, False
        tried = f"{attempt + 1} of {self.attempts}" if attempt + 1 < self.attempts else f"{self.attempts}"
        raise BackendError(f"{self.name}: no valid answer after {tried} attempt(s); last error: {last}")

    def _cache_meta(self, schema_name: str) -> dict:
        """What a cache entry must have been recorded with to be used: model, prompt version, schema."""
        return {"model": self.model, "schema": schema_name, "prompt_version": self.prompt_version,
                "schema_version": SCHEMA_VERSION}

    def _request(self, messages: list[dict], response_format: dict, deadline: float) -> dict:
        """One request, over by ``deadline`` (time.monotonic) whatever the server does: the client's own timeout
        bounds each connect and read, and a watchdog shuts the request's socket down at the deadline (a server
        that drips its reply a byte at a time never lets a read time out)."""
        remaining = deadline - time.monotonic()
        if remaining <= 0:
            raise _Retryable("no time left for another request")
        kwargs: dict[str, Any] = {"model": self.model, "messages": messages, "response_format": response_format,
                                  "timeout": remaining}
        if self.temperature is not None:
            kwargs["temperature"] = self.temperature
        if self.max_tokens is not None:
            kwargs["max_tokens"] = self.max_tokens
        self.calls += 1
        self._aborted.clear()
        watchdog = threading.Timer(remaining, self._abort)
        watchdog.daemon = True
        watchdog.start()
        try:
            raw = self._client.chat.completions.with_raw_response.create(**kwargs)
            body = raw.content
        except openai.APITimeoutError as exc:
            raise _Retryable(f"request timed out after {self.timeout_s:g}s ({exc.__class__.__name__})") from exc
        except openai.AuthenticationError as exc:
            raise BackendError(f"{self.name}: authentication failed (HTTP 401); set OPENAI_API_KEY to a valid key "
                               "for this server") from exc
        except openai.NotFoundError as exc:
            raise BackendError(f"{self.name}: HTTP 404 from {self.shown_url or 'the OpenAI API'}; check the model "
                               "name and that base_url ends in /v1") from exc
        except openai.APIStatusError as exc:
            if exc.status_code in _RETRY_STATUS or exc.status_code >= 500:
                raise _Retryable(f"HTTP {exc.status_code} from server") from exc
            raise BackendError(f"{self.name}: HTTP {exc.status_code}: {_brief(exc)}; the server may not support "
                               "json_schema response_format or image inputs for this model") from exc
        except Exception as exc:  # a connection error, an aborted or oversized reply, a reply the client cannot read
            if self._aborted.is_set():
                raise _Retryable(f"no complete answer within {remaining:.1f} s (the request's time limit: "
                                 f"--vlm-timeout or what is left of a time budget); the server is too slow") from exc
            cause = exc.__cause__ if isinstance(exc.__cause__, _ReplyTooLarge) else exc
            if isinstance(cause, _ReplyTooLarge):
                raise _Retryable(str(cause)) from exc
            if isinstance(exc, openai.APIConnectionError):
                raise _Retryable(f"cannot reach {self.shown_url or 'the OpenAI API'}: {_brief(exc)}") from exc
            raise _Retryable(f"unreadable response: {exc.__class__.__name__}: {_brief(exc)}") from exc
        finally:
            watchdog.cancel()
        if self._aborted.is_set():
            raise _Retryable(f"no complete answer within {remaining:.1f} s (the request's time limit)")
        try:
            reply = parse_json(body, "the server's reply", max_bytes=MAX_REPLY_BYTES)
        except JSONInputError as exc:
            raise _Retryable(f"unreadable response: {exc.reason}") from None
        return _content_json(reply)

    # ----------------------------------------------------------------- the request's deadline

    def _on_request(self, request) -> None:
        """httpx request hook: trace the request's connection so that the watchdog can find its socket."""
        request.extensions["trace"] = self._trace

    def _trace(self, event: str, info: dict) -> None:
        if event in ("connection.connect_tcp.complete", "connection.start_tls.complete") and info.get("return_value"):
            self._streams = [s for s in self._streams if _socket_of(s) is not None] + [info["return_value"]]

    def _on_response(self, response) -> None:
        """httpx response hook: refuse an oversized reply before its body is read, and cap a body of unknown size."""
        length = response.headers.get("content-length", "")
        if length.isdigit() and int(length) > MAX_REPLY_BYTES:
            raise _ReplyTooLarge(f"the server's reply is {int(length):,} bytes, more than the {MAX_REPLY_BYTES:,} "
                                 "accepted")
        response.stream = _capped_stream(response, MAX_REPLY_BYTES)

    def _abort(self) -> None:
        """The watchdog: the deadline passed, shut the sockets down (the blocked read returns at once)."""
        self._aborted.set()
        for stream in list(self._streams):
            sock = _socket_of(stream)
            if sock is not None:
                with contextlib.suppress(OSError):
                    sock.shutdown(socket.SHUT_RDWR)


def _socket_of(stream):
    """The open socket under an httpcore network stream, or None once it is closed."""
    try:
        sock = stream.get_extra_info("socket")
        return sock if sock is not None and sock.fileno() != -1 else None
    except Exception:
        return None


class _ReplyTooLarge(Exception):
    pass


def _capped_stream(response, limit: int):
    """``response.stream`` wrapped so that reading past ``limit`` bytes raises _ReplyTooLarge. The wrapper derives
    from the HTTP library's own SyncByteStream (the client checks the type), found from the response's module."""
    import importlib

    http = importlib.import_module(type(response).__module__.split(".")[0])
    inner = response.stream

    class Capped(http.SyncByteStream):
        def __iter__(self):
            seen = 0
            for chunk in inner:
                seen += len(chunk)
                if seen > limit:
                    raise _ReplyTooLarge(f"the server's reply is larger than the {limit:,} bytes accepted")
                yield chunk

        def close(self) -> None:
            inner.close()

    return Capped()


@contextlib.contextmanager
def _redacted_errors():
    """Re-raise a BackendError with credentials removed from its message (and no chained server error)."""
    try:
        yield
    except BackendError as exc:
        raise type(exc)(redact(str(exc))) from None


class _Retryable(Exception):
    """Transient failure: worth another attempt after back-off."""


def _content_json(reply: Any) -> dict:
    """The JSON object in the first choice's message of a chat-completion reply, or _Retryable/BackendError saying
    why not. The message content is parsed with the bounded reader (a deep or huge answer is a bad answer)."""
    try:
        choice = reply["choices"][0]
        message = choice["message"]
        if not isinstance(message, dict):
            raise TypeError("message is not an object")
    except (KeyError, IndexError, TypeError) as exc:
        raise _Retryable(f"response has no choices: {_brief(str(reply)[:400])}") from exc
    refusal = message.get("refusal")
    if refusal:
        raise BackendError(f"model refused: {_brief(refusal)}")
    if choice.get("finish_reason") == "length":
        raise _Retryable("answer truncated (finish_reason=length); raise max_tokens")
    content = message.get("content")
    if not isinstance(content, str) or not content.strip():
        raise _Retryable("empty message content")
    try:
        answer = parse_json(_json_part(content), "the model's answer", max_bytes=MAX_REPLY_BYTES)
    except JSONInputError as exc:
        raise _Retryable(f"message content is not JSON ({exc.reason}): {_brief(content)}") from None
    if not isinstance(answer, dict):
        raise _Retryable(f"message content is JSON but not an object: {_brief(content)}")
    return answer


def _json_part(content: str) -> str:
    """The JSON object in a model's message: the whole content, or, from a server that does not enforce the schema
    and lets the model talk ("Here is my answer: ```json {...} ```"), the one fenced or braced object in it."""
    text = content.strip()
    if text.startswith("{"):
        return text
    fenced = re.findall(r"```(?:json)?\s*(\{.*?\})\s*```", text, flags=re.DOTALL)
    if len(fenced) == 1:
        return fenced[0]
    first, last = text.find("{"), text.rfind("}")
    return text[first:last + 1] if 0 <= first < last else text


__all__ = ["OpenAIBackend", "redact"]  # ``redact`` lives in util/secrets.py; re-exported for older imports


def _brief(value: Any, limit: int = 200) -> str:
    text = redact(str(value))
    return text if len(text) <= limit else text[: limit - 3] + "..."
