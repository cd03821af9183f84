"""Plain functions behind the semantics sub-commands (the CLI wiring lives elsewhere).

Each takes ordinary arguments and returns text (and, where useful, a dict for JSON output).
"""

from __future__ import annotations

import logging
import statistics
import time
from typing import Sequence

import numpy as np

from safemanip.scene.catalog import CONSTRAINT_OF_CLASS, CONSTRAINT_TYPES, SEMANTIC_CLASSES, load_catalog
from safemanip.selection.base import SceneView, nearest_ids
from safemanip.semantics.base import Backend, BackendError, ConstraintQuery, ObjectQuery
from safemanip.semantics.cache import ResponseCache

log = logging.getLogger(__name__)

BACKEND_NAMES = ("semantic", "openai")

# Mild rewordings a person or a detector might produce for the same object; used to give a
# deterministic backend something to disagree with itself about across trials.
NAME_VARIANTS = ("{name}", "the {name}", "a {name}", "{Name}", "{name} on the table", "small {name}")


def make_backend(backend_name: str, *, model: str | None = None, base_url: str | None = None,
                 cache_dir: str | None = None, cache_mode: str = "readwrite", timeout_s: float = 30.0,
                 attempts: int = 3) -> Backend:
    """Build a backend by name: ``semantic`` (offline, default) or ``openai`` (any compatible server)."""
    if backend_name == "semantic":
        from safemanip.semantics.semantic_backend import SemanticBackend
        return SemanticBackend()
    if backend_name == "openai":
        from safemanip.semantics.openai_backend import OpenAIBackend
        cache = ResponseCache(cache_dir, mode=cache_mode) if cache_dir else None
        return OpenAIBackend(model=model or "gpt-4o", base_url=base_url, cache=cache, timeout_s=timeout_s,
                             attempts=attempts)
    raise ValueError(f"unknown backend {backend_name!r}; choose one of {BACKEND_NAMES}")


def _backend(backend: str | Backend, **kwargs) -> Backend:
    return make_backend(backend, **kwargs) if isinstance(backend, str) else backend


def classify_constraints(backend_name: str | Backend, names: Sequence[str], *, task: str | None = None,
                         **backend_kwargs) -> str:
    """One line ``name<TAB>constraint`` per name (the names are treated as one scene)."""
    names = [n.strip() for n in names if n.strip()]
    if not names:
        raise ValueError("give at least one object name, e.g. 'red mug' 'toy sheep'")
    backend = _backend(backend_name, **backend_kwargs)
    answer = backend.assign_constraints(ConstraintQuery(names=tuple(names), task=task))
    return "\n".join(f"{n}\t{c}" for n, c in zip(names, answer.constraints))


def constraint_matrix(backend_name: str | Backend, trials: int = 200, seed: int = 0, *, objects_per_scene: int = 6,
                      name_variants: bool = False, task: str | None = None, **backend_kwargs) -> tuple[str, dict]:
    """The paper's Table III (ground truth vs predicted constraint) and Table IV (per object) on the catalog.

    Each trial samples a scene of ``objects_per_scene`` distinct catalog objects and asks the backend
    for all of their constraints at once (as ConstraintVLM is asked at t = 0). Percentages are over
    object appearances: Table III rows over all appearances of objects of that ground-truth class,
    Table IV rows over the appearances of that object. With ``name_variants`` each appearance uses
    a random mild rewording of the name (e.g. "the red mug", "Red Mug"); the ground truth stays that of
    the catalog object. Trials whose query fails are counted and skipped.
    """
    if trials < 1:
        raise ValueError(f"trials must be >= 1, got {trials}")
    catalog = load_catalog()
    all_names = sorted(catalog)
    if not 1 <= objects_per_scene <= len(all_names):
        raise ValueError(f"objects_per_scene must be between 1 and {len(all_names)}, got {objects_per_scene}")
    backend = _backend(backend_name, **backend_kwargs)
    rng = np.random.default_rng(seed)
    ci = {c: i for i, c in enumerate(CONSTRAINT_TYPES)}
    per_object = {n: np.zeros(len(CONSTRAINT_TYPES), dtype=int) for n in all_names}
    failed = 0
    for _ in range(trials):
        picked = [all_names[i] for i in rng.choice(len(all_names), size=objects_per_scene, replace=False)]
        shown = [_variant(n, rng) if name_variants else n for n in picked]
        try:
            answer = backend.assign_constraints(ConstraintQuery(names=tuple(shown), task=task))
        except BackendError as exc:
            failed += 1
            log.warning("constraint_matrix: trial failed: %s", exc)
            continue
        for name, pred in zip(picked, answer.constraints):
            per_object[name][ci[pred]] += 1

    gt_rows = {CONSTRAINT_OF_CLASS[c]: np.zeros(len(CONSTRAINT_TYPES), dtype=int) for c in SEMANTIC_CLASSES}
    for name, counts in per_object.items():
        gt_rows[catalog[name].constraint] += counts

    def pct(counts: np.ndarray) -> dict[str, float] | None:
        total = int(counts.sum())
        return None if total == 0 else {c: round(100.0 * counts[i] / total, 1) for i, c in enumerate(CONSTRAINT_TYPES)}

    table3 = {gt: pct(counts) for gt, counts in gt_rows.items()}
    table4 = {n: {"ground_truth": catalog[n].constraint, "n": int(c.sum()), "percent": pct(c)}
              for n, c in per_object.items()}
    appearances = sum(int(c.sum()) for c in per_object.values())
    correct = sum(int(c[ci[catalog[n].constraint]]) for n, c in per_object.items())
    majority_ok = [n for n, c in per_object.items() if c.sum() and CONSTRAINT_TYPES[int(c.argmax())] == catalog[n].constraint]
    sampled = [n for n, c in per_object.items() if c.sum()]

    notes = []
    deterministic = getattr(backend, "name", "") == "semantic"
    if deterministic and not name_variants:
        notes.append("The semantic backend is deterministic and classifies each name on its own: every appearance "
                     "of an object gets the same answer, so trials only change how often each object is counted "
                     "(Table IV rows are 0/100). Use name_variants=True for a mild robustness check.")
    if failed:
        notes.append(f"{failed} of {trials} trials failed and were skipped.")
    result = {
        "backend": backend.describe(), "trials": trials, "failed_trials": failed, "seed": seed,
        "objects_per_scene": objects_per_scene, "name_variants": name_variants,
        "table3": table3, "table4": table4,
        "appearance_accuracy": round(100.0 * correct / appearances, 1) if appearances else None,
        "object_accuracy": round(100.0 * len(majority_ok) / len(sampled), 1) if sampled else None,
        "notes": notes,
    }
    return _format_tables(result), result


def _variant(name: str, rng: np.random.Generator) -> str:
    template = NAME_VARIANTS[int(rng.integers(len(NAME_VARIANTS)))]
    return template.format(name=name, Name=name.title())


def _format_tables(result: dict) -> str:
    head = f"{'':22s}" + "".join(f"{c:>14s}" for c in CONSTRAINT_TYPES)
    lines = [f"Table III: ground truth (rows) vs predicted constraint, % of object appearances "
             f"({result['trials']} trials x {result['objects_per_scene']} objects, backend {result['backend']['backend']})",
             head]
    for gt, row in result["table3"].items():
        cells = "".join(f"{row[c]:>14.1f}" if row else f"{'n/a':>14s}" for c in CONSTRAINT_TYPES)
        lines.append(f"{gt + ' (GT)':22s}{cells}")
    lines += ["", "Table IV: predicted constraint per catalog object, % of its appearances", head + f"{'GT':>14s}{'n':>6s}"]
    for name, row in result["table4"].items():
        pcts = row["percent"]
        cells = "".join(f"{pcts[c]:>14.1f}" if pcts else f"{'n/a':>14s}" for c in CONSTRAINT_TYPES)
        lines.append(f"{name:22s}{cells}{row['ground_truth']:>14s}{row['n']:>6d}")
    lines += ["", f"accuracy over appearances: {result['appearance_accuracy']}%   "
                  f"objects whose majority answer is correct: {result['object_accuracy']}%"]
    lines += [f"note: {n}" for n in result["notes"]]
    return "\n".join(lines)


def object_selection_latency(backend_name: str | Backend = "semantic", *, n_objects: int = 6, k: int = 2,
                             queries: int = 200, seed: int = 0, **backend_kwargs) -> tuple[str, dict]:
    """Median / p95 latency of one object-selection query on random scenes (after a warm-up per scene)."""
    backend = _backend(backend_name, **backend_kwargs)
    rng = np.random.default_rng(seed)
    names = sorted(load_catalog())
    lat: list[float] = []
    for q in range(queries):
        if q % 20 == 0:  # a new scene every 20 queries, prepared as a selector's reset would
            scene = tuple(names[i] for i in rng.choice(len(names), size=n_objects, replace=False))
            positions = np.c_[rng.uniform(-0.4, 0.4, (n_objects, 2)), np.full(n_objects, 0.85)]
            backend.prepare(scene)
        box = np.array([rng.uniform(-0.3, 0.0), rng.uniform(-0.2, 0.2), 0.85])
        view = SceneView(t=q, names=scene, positions=positions, velocities=np.zeros((n_objects, 3)),
                         ee_path=np.stack([box - [0.05, 0, 0], box]), box_path=np.stack([box - [0.02, 0, 0], box]),
                         box_velocity=np.array([rng.uniform(0.0, 0.5), rng.uniform(-0.1, 0.1), 0.0]))
        query = ObjectQuery(view=view, k=k, order=nearest_ids(view.ee_position, positions, n_objects))
        start = time.perf_counter()
        backend.select_objects(query)
        lat.append(time.perf_counter() - start)
    med, p95 = statistics.median(lat), float(np.percentile(lat, 95))
    info = {"backend": backend.describe(), "n_objects": n_objects, "k": k, "queries": queries,
            "median_ms": round(1e3 * med, 3), "p95_ms": round(1e3 * p95, 3)}
    text = (f"object selection, {n_objects} objects, k={k}, {queries} queries: median {1e3 * med:.3f} ms, "
            f"p95 {1e3 * p95:.3f} ms")
    return text, info
