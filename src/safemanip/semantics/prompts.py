"""Prompts as versioned data files in ``semantics/prompts/``.

A prompt file is ``<name>_<version>.txt`` (versioned) or ``<name>.txt`` (unversioned, e.g. the
default task). ``$task`` in a file is replaced by the task description. Changing a prompt means
adding a new version file, so cached answers and logged results stay attributable to the exact
text that produced them (the cache key includes the full prompt text anyway).
"""

from __future__ import annotations

import string
from functools import lru_cache
from importlib import resources

PROMPT_NAMES = ("object_selection", "constraint_selection", "task_default")


@lru_cache(maxsize=None)
def _read(filename: str) -> str:
    root = resources.files("safemanip.semantics").joinpath("prompts")
    path = root.joinpath(filename)
    if not path.is_file():
        available = sorted(p.name for p in root.iterdir() if p.name.endswith(".txt"))
        raise FileNotFoundError(
            f"no prompt file {filename!r} in safemanip/semantics/prompts/; available: {available}")
    return path.read_text(encoding="utf-8")


def default_task() -> str:
    """The paper's task (own words): slide the white cereal box out from under the blue one, to the right."""
    return _read("task_default.txt").strip()


def load_prompt(name: str, version: str = "v1", task: str | None = None) -> str:
    """Prompt text ``name`` at ``version`` with ``$task`` filled in (default task when ``task`` is None).

    ``name`` is one of ``object_selection``, ``constraint_selection`` or ``task_default``
    (the last is unversioned and ignores ``version``).
    """
    if name == "task_default":
        return default_task()
    if name not in PROMPT_NAMES:
        raise ValueError(f"unknown prompt {name!r}; choose one of {PROMPT_NAMES}")
    text = _read(f"{name}_{version}.txt")
    task_text = default_task() if task is None else task.strip()
    if not task_text:
        raise ValueError("task description is empty; pass a sentence describing the task or None for the default")
    # safe_substitute: a stray '$' in a user-supplied task must not raise
    return string.Template(text).safe_substitute(task=task_text).strip()
