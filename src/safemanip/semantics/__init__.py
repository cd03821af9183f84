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
    in the catalog, and a metric-risk object ranking along the box's extrapolated path weighted by
    fragility. Numpy-only per query after one embedding call per scene. The example names and the
    decision rule are versioned data: ``data/class_examples_v3.json`` (default; 55 names per class, a
    logistic regression on the embeddings, the strictest class within 0.19 of the most probable one,
    margin and rule picked by cross-validation over the examples), ``_v2`` (25 per class, class-mean
    cosine with a 0.035 margin) and ``_v1`` (8 per class, argmax), selectable with
    ``examples_file="v1"`` / ``--semantic-examples v1``. ``data/heldout_names_v1.json`` holds 60 labelled
    names no version was developed on (``constraint-matrix --objects heldout``).
``selectors``
    ``DynamicVLMSelector`` (ObjectSelector; queries every ``query_interval`` steps, falls back to
    dynamic-kNN per failed query) and ``VLMConstraintSelector`` (ConstraintSelector; queried at t = 0,
    falls back to all no_contact). Fallbacks are logged and counted in ``stats.fallbacks``.
``images``
    ``annotate`` (boxes labelled ``<id>: <name>`` on a patch of the box colour, placed so labels do not
    cover each other, the past end-effector path as a black arrow; sizes scale with the image),
    ``tile`` (oldest left) and ``to_png``.
``commands``
    Plain functions for the CLI: ``classify_constraints``, ``constraint_matrix`` (Tables III and IV
    over the catalog), ``render_query`` (the image + distance-sorted object list Dynamic-VLM sends,
    for a scripted rollout), ``object_selection_latency``, and ``make_backend``.
``cli``
    ``register(subparsers)``: ``safemanip classify-constraints``, ``constraint-matrix``, ``render-query``;
    input and backend failures exit with code 2 and one line on stderr.

Measured (SemanticBackend, CPU; catalog = 35 names, ground truth from scene/objects.json, plant pot soft)
--------------------------------------------------------------------------------------------------------
- v2 (the default before v3): leave-one-out over its 75 examples 86.7 % (recall fragile 0.88, soft 0.96, durable
  0.76). Held-out catalog 29/35 (fragile 10/11, soft 9/12, durable 10/12). Wrong: egg carton ->
  durable (the one looser-than-truth error); plant pot, plastic cup, yogurt cup -> fragile; pencil
  case, wooden spoon -> fragile. Table III (200 trials x 6 objects, % of appearances, rows GT,
  columns predicted no/soft/any_contact): no_contact 94.2/0.0/5.8, soft_contact 25.4/74.6/0.0,
  any_contact 20.1/0.0/79.9; with ``name_variants=True`` 94.0/1.6/4.4, 26.6/70.1/3.3, 23.0/2.5/74.5.
- v1 (8 examples per class, argmax): catalog 27/35; Table III 75.4/24.6/0.0, 18.2/75.1/6.8,
  19.5/0.0/80.5; four looser-than-truth errors (glass jar, glass vase -> soft; egg carton -> soft;
  glue stick -> durable).
- Paper (GPT-4o, Table III): no_contact 99.0/1.0/0.0, soft_contact 25.2/41.5/0.0, any_contact 0/0/100.
- Object selection through DynamicVLMSelector after warm-up: about 0.1 ms per query (6 objects, k=2);
  model load about 6-9 s once per process; one batched embedding call per new scene about 15-20 ms.
  See ``benchmarks/selector_latency.py``.

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
