"""Keeping credentials out of everything the package prints, logs or writes.

``redact`` removes the OpenAI API key (its value in any letter case, read from ``OPENAI_API_KEY`` under any
spelling of that name; a placeholder shorter than 8 characters, such as "none" for a local server, only where
it stands as a word), anything shaped like a credential (``Bearer ...``, ``sk-...``, ``api_key=...`` /
``"Api-Key": ...`` / ``apiKey: ...`` in any case, ``password=...``, ``token=...``) and the ``user:password@``
part of URLs. ``mask_url`` shows a URL without its credentials; ``redact_value`` applies ``redact`` to every
string in a JSON-like value (what goes into a cache file or a results file).
"""

from __future__ import annotations

import os
import re
from typing import Any
from urllib.parse import quote

REDACTED = "[redacted]"
KEY_VARIABLE = "OPENAI_API_KEY"

_URL_CREDENTIALS = re.compile(r"(?i)\b([a-z][a-z0-9+.\-]*://)[^\s/@'\"<>]+@")
_SECRET = r"(?:\[redacted\]|[^\s'\",}\]]+)"
_PATTERNS = (
    re.compile(r"(?i)((?<![a-z0-9])(?:api[\s_\-]?key|(?:proxy-)?authorization|access[_\-]?token|auth[_\-]?token|password"
               r"|passwd|secret|token)[\"']?\s*[:=]\s*[\"']?)(?:bearer\s+|basic\s+)?" + _SECRET),
    re.compile(r"(?i)\b(bearer\s+)(?!\[redacted\])[^\s'\",}\]]+"),
    re.compile(r"(?i)\bsk-[a-z0-9_\-]{8,}"),
)


def api_keys() -> list[str]:
    """The values of ``OPENAI_API_KEY`` under any case variant of the name (longest first), 4+ characters."""
    values = {v for k, v in os.environ.items() if k.upper() == KEY_VARIABLE and v and len(v) >= 4}
    return sorted(values, key=len, reverse=True)


def redact(text: str) -> str:
    """``text`` with the API key, credential-shaped strings and URL credentials replaced by ``[redacted]``."""
    text = str(text)
    for key in api_keys():
        for form in {key, quote(key, safe="")}:
            if len(form) >= 8:  # a real key, in any letter case
                text = re.sub(re.escape(form), REDACTED, text, flags=re.IGNORECASE)
            else:  # a placeholder such as "none" or "EMPTY" for a local server: only where it stands as a word
                text = re.sub(rf"(?<![\w-]){re.escape(form)}(?![\w-])", REDACTED, text)
    text = _URL_CREDENTIALS.sub(lambda m: m.group(1) + REDACTED + "@", text)
    for pattern in _PATTERNS:
        text = pattern.sub(lambda m: (m.group(1) if m.groups() else "") + REDACTED, text)
    return text


def mask_url(url: str | None) -> str | None:
    """``url`` as it may be shown: without ``user:password@`` (and any key in it)."""
    return None if url is None else redact(url)


def redact_value(value: Any) -> Any:
    """A JSON-like value with ``redact`` applied to every string in it (keys included)."""
    if isinstance(value, str):
        return redact(value)
    if isinstance(value, dict):
        return {redact(k) if isinstance(k, str) else k: redact_value(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [redact_value(v) for v in value]
    return value
