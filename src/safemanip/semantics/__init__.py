"""Semantic backends for relevant-object and constraint selection (paper Sec. IV-C, V, VI-C, App. B/C).

Pieces
------
``prompts/`` + ``prompts.py``
    The object-selection and constraint-selection instructions as versioned text files
    (``object_selection_v1.txt``, ``constraint_selection_v1.txt``) and the default task
    (``task_default.txt``). ``load_prompt(name, version="v1", task=None)`` fills in ``$task``.
``schemas.py``
    Strict JSON schemas for structured answers, built per scene: the object field is an enum of the
    scene's labels (``"3: red mug"``) with exactly k items; the constraint answer has one entry per
    label with a constraint from (no_contact, soft_contact, any_contact). ``parse_*_answer`` validate
    an answer against the scene and raise ``SchemaError``.
``openai_backend.OpenAIBackend``
    A VLM behind any OpenAI-compatible chat-completions server (OpenAI, vLLM, llama.cpp, Ollama).
    Images go as base64 PNG data URLs; own retry loop with exponential back-off; per-call timeout;
    every answer validated; failures raise ``BackendError``. The API key comes from OPENAI_API_KEY and
    is never logged.
``cache.ResponseCache``
    JSON-file cache of answers keyed by sha256(model, prompt text, images, schema); atomic writes;
    ``cache_only`` mode raises ``BackendError("cache miss ...")`` instead of calling out.
``semantic_backend.SemanticBackend``
    The offline default: zero-shot fragile/soft/durable classification of object names with the
    shipped all-MiniLM-L6-v2 embedding model against prototypes built from example names that are not
    in the catalog (``data/class_examples_v1.json``), and a metric-risk object ranking along the box's
    extrapolated path weighted by fragility. Numpy-only per query after one embedding call per scene.
``selectors``
    ``DynamicVLMSelector`` (ObjectSelector; queries every ``query_interval`` steps, falls back to
    dynamic-kNN per failed query) and ``VLMConstraintSelector`` (ConstraintSelector; queried at t = 0,
    falls back to all no_contact). Fallbacks are logged and counted in ``stats.fallbacks``.
``commands``
    Plain functions for the CLI: ``classify_constraints``, ``constraint_matrix`` (Tables III and IV
    over the catalog), ``object_selection_latency``, and ``make_backend``.

Measured (SemanticBackend, CPU, seed 0)
---------------------------------------
- Held-out catalog (35 names, none used as examples): 28/35 correct (80.0 %); by class fragile 9/12,
  soft 9/11, durable 10/12. Wrong: glass vase, glass jar, egg carton -> soft_contact; yogurt cup ->
  no_contact; glue stick -> any_contact; tennis ball, wooden spoon -> no_contact. No fragile object
  is ever given any_contact.
- Table III (200 trials x 6 objects, % of appearances; rows GT, columns predicted
  no/soft/any_contact): no_contact 77.6/22.4/0.0, soft_contact 10.2/82.4/7.4, any_contact
  19.5/0.0/80.5. The backend is deterministic, so trials only reweight objects; with mild name
  variants (``name_variants=True``) 78.7/21.3/0.0, 6.6/85.5/7.9, 20.2/0.0/79.8.
- Object selection with 6 objects, k=2, through DynamicVLMSelector after warm-up: median 0.06 ms,
  p95 0.09 ms per query. Model load about 6 s once per process; one batched embedding call per new
  scene about 17 ms.

Heavy dependencies (openai, torch via sentence-transformers) are imported only when a backend that
needs them is used.
"""

from __future__ import annotations

from typing import Any

from safemanip.semantics.base import (Backend, BackendError, ConstraintAnswer, ConstraintQuery, ObjectAnswer,
                                      ObjectQuery, SchemaError, object_label)
from safemanip.semantics.cache import ResponseCache, cache_key
from safemanip.semantics.prompts import default_task, load_prompt
from safemanip.semantics.schemas import (constraint_schema, object_selection_schema, parse_constraint_answer,
                                         parse_object_answer)

_LAZY = {
    "OpenAIBackend": "safemanip.semantics.openai_backend",
    "SemanticBackend": "safemanip.semantics.semantic_backend",
    "DynamicVLMSelector": "safemanip.semantics.selectors",
    "VLMConstraintSelector": "safemanip.semantics.selectors",
}

__all__ = ["Backend", "BackendError", "ConstraintAnswer", "ConstraintQuery", "ObjectAnswer", "ObjectQuery",
           "SchemaError", "object_label", "ResponseCache", "cache_key", "default_task", "load_prompt",
           "constraint_schema", "object_selection_schema", "parse_constraint_answer", "parse_object_answer",
           *_LAZY]


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        import importlib
        return getattr(importlib.import_module(_LAZY[name]), name)
    raise AttributeError(f"module 'safemanip.semantics' has no attribute {name!r}")
