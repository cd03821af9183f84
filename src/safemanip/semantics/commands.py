"""Plain functions behind the semantics sub-commands (the CLI wiring is ``semantics/cli.py``).

Each takes ordinary arguments and returns text (and, where useful, a dict for JSON output).
"""

from __future__ import annotations

import io
import json
import logging
import statistics
import time
from importlib import resources
from typing import Sequence

import numpy as np
from PIL import Image

from safemanip.scene.catalog import CONSTRAINT_OF_CLASS, CONSTRAINT_TYPES, SEMANTIC_CLASSES, load_catalog
from safemanip.selection.base import SceneView, nearest_ids
from safemanip.selection.selectors import DEFAULT_SOFT_REACH
from safemanip.semantics.base import VLM_BACKENDS, Backend, BackendError, ConstraintQuery, ObjectQuery, object_label
from safemanip.semantics.cache import ResponseCache
from safemanip.util.secrets import redact, redact_value

log = logging.getLogger(__name__)

# Mild rewordings a person or a detector might produce for the same object; used to give a
# deterministic backend something to disagree with itself about across trials.
NAME_VARIANTS = ("{name}", "the {name}", "a {name}", "{Name}", "{name} on the table", "small {name}")


def make_backend(backend_name: str, *, model: str | None = None, base_url: str | None = None,
                 cache_dir: str | None = None, cache_mode: str = "readwrite", timeout_s: float = 30.0,
                 attempts: int = 3, semantic_examples: str | None = None, ranking: str = "criticality",
                 soft_reach: float = DEFAULT_SOFT_REACH) -> Backend:
    """Build a backend by name: ``semantic`` (offline, default) or ``openai`` (any compatible server).

    ``semantic_examples`` picks the semantic backend's example set and decision rule ("v1", "v2", "v3" or a
    file name in ``semantics/data``; default: the newest). ``ranking``: how the offline backend ranks objects
    (``SemanticBackend``) and ``soft_reach`` its criticality tiers; a VLM ranks them itself.
    """
    if backend_name == "semantic":
        from safemanip.semantics.semantic_backend import DEFAULT_EXAMPLES, SemanticBackend
        return SemanticBackend(examples_file=semantic_examples or DEFAULT_EXAMPLES, ranking=ranking,
                               soft_reach=soft_reach)
    if backend_name == "openai":
        from safemanip.semantics.openai_backend import OpenAIBackend
        cache = ResponseCache(cache_dir, mode=cache_mode) if cache_dir else None
        return OpenAIBackend(model=model or "gpt-4o", base_url=base_url, cache=cache, timeout_s=timeout_s,
                             attempts=attempts)
    raise ValueError(f"unknown backend {backend_name!r}; choose one of {VLM_BACKENDS}")


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


PAPER_OBJECTS = ("toy squirrel", "toy sheep", "toy android", "red mug", "blue mug", "porcelain mug", "supplement bottle",
                 "plant pot")
"""The eight objects of the paper's experiments (its Tables III and IV are over these)."""
HELDOUT_FILES = {"heldout": "heldout_names_v1.json", "heldout-v2": "heldout_names_v2.json",
                 "heldout-v3": "heldout_names_v3.json", "heldout-v4": "heldout_names_v4.json"}
"""The shipped held-out name lists (``semantics/data/``), by object-set name."""
OBJECT_SETS = ("catalog", "paper", *HELDOUT_FILES)


def object_set(which: str) -> dict[str, str]:
    """Name -> ground-truth constraint for a named set of test objects.

    ``catalog``: all catalog objects; ``paper``: the paper's eight; ``heldout``: the held-out name list
    shipped in ``semantics/data/heldout_names_v1.json`` (not catalog objects; labels from that file).
    """
    if which == "catalog":
        return {n: o.constraint for n, o in sorted(load_catalog().items())}
    if which == "paper":
        catalog = load_catalog()
        return {n: catalog[n].constraint for n in PAPER_OBJECTS}
    if which in HELDOUT_FILES:
        from safemanip.util.files import parse_json

        raw = parse_json(resources.files("safemanip.semantics").joinpath("data", HELDOUT_FILES[which])
                         .read_bytes(), HELDOUT_FILES[which])
        return {n: CONSTRAINT_OF_CLASS[c] for c in SEMANTIC_CLASSES for n in sorted(raw["classes"][c])}
    raise ValueError(f"unknown object set {which!r}; choose one of {OBJECT_SETS}")


def name_confusion(backend: Backend, objects: str) -> dict:
    """Each name of an object set classified once, alone: counts[truth][predicted] over the constraint types,
    the unsafe-error rate (a no_contact object given any other type), per-class recall, balanced accuracy
    and the names that were wrong."""
    truth = object_set(objects)
    names = list(truth)
    predicted = [backend.assign_constraints(ConstraintQuery(names=(n,))).constraints[0] for n in names]
    counts = {t: {p: 0 for p in CONSTRAINT_TYPES} for t in CONSTRAINT_TYPES}
    for n, p in zip(names, predicted):
        counts[truth[n]][p] += 1
    recall = {t: counts[t][t] / max(1, sum(counts[t].values())) for t in CONSTRAINT_TYPES}
    fragile = sum(counts["no_contact"].values())
    return {"objects": objects, "names": len(names), "counts": counts, "recall": recall,
            "balanced_accuracy": sum(recall.values()) / len(recall),
            "unsafe_rate": (fragile - counts["no_contact"]["no_contact"]) / max(1, fragile),
            "wrong": {n: [truth[n], p] for n, p in zip(names, predicted) if p != truth[n]}}


def constraint_matrix(backend_name: str | Backend, trials: int = 200, seed: int = 0, *, objects_per_scene: int = 6,
                      name_variants: bool = False, task: str | None = None, objects: str = "catalog",
                      **backend_kwargs) -> tuple[str, dict]:
    """The paper's Table III (ground truth vs predicted constraint) and Table IV (per object).

    ``objects`` picks the test names (``object_set``): the catalog (default), the paper's eight objects
    (the set the paper's own tables are over) or the shipped held-out list.

    Each trial samples a scene of ``objects_per_scene`` distinct catalog objects and asks the backend
    for all of their constraints at once (as ConstraintVLM is asked at t = 0). Percentages are over
    object appearances: Table III rows over all appearances of objects of that ground-truth class,
    Table IV rows over the appearances of that object. With ``name_variants`` each appearance uses
    a random mild rewording of the name (e.g. "the red mug", "Red Mug"); the ground truth stays that of
    the catalog object. Trials whose query fails are counted and skipped.
    """
    if trials < 1:
        raise ValueError(f"trials must be >= 1, got {trials}")
    truth = object_set(objects)
    all_names = list(truth)
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
        gt_rows[truth[name]] += counts

    def pct(counts: np.ndarray) -> dict[str, float] | None:
        total = int(counts.sum())
        return None if total == 0 else {c: round(100.0 * counts[i] / total, 1) for i, c in enumerate(CONSTRAINT_TYPES)}

    table3 = {gt: pct(counts) for gt, counts in gt_rows.items()}
    table4 = {n: {"ground_truth": truth[n], "n": int(c.sum()), "percent": pct(c)}
              for n, c in per_object.items()}
    appearances = sum(int(c.sum()) for c in per_object.values())
    correct = sum(int(c[ci[truth[n]]]) for n, c in per_object.items())
    majority_ok = [n for n, c in per_object.items() if c.sum() and CONSTRAINT_TYPES[int(c.argmax())] == truth[n]]
    sampled = [n for n, c in per_object.items() if c.sum()]

    notes = []
    deterministic = getattr(backend, "name", "") == "semantic"
    if deterministic and not name_variants:
        notes.append("The semantic backend is deterministic and classifies each name on its own: every appearance "
                     "of an object gets the same answer, so trials only change how often each object is counted "
                     "(Table IV rows are 0/100). Use name_variants=True (CLI: --name-variants) for a mild robustness check.")
    if failed:
        notes.append(f"{failed} of {trials} trials failed and were skipped.")
    result = {
        "backend": backend.describe(), "trials": trials, "failed_trials": failed, "seed": seed,
        "objects_per_scene": objects_per_scene, "name_variants": name_variants, "objects": objects,
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
    lines += ["", f"Table IV: predicted constraint per object ({result['objects']} set), % of its appearances", head + f"{'GT':>14s}{'n':>6s}"]
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


class _RecordingBackend:
    """Wraps a backend (or none) for ``render_query``: records every object query, answers with ``inner``
    when given, else with the k objects nearest the end-effector."""

    needs_images = True

    def __init__(self, inner: Backend | None) -> None:
        self.inner = inner
        self.name = f"recording:{getattr(inner, 'name', 'nearest')}"
        self.queries: list[ObjectQuery] = []
        self.answers: list = []

    def prepare(self, names) -> None:
        if self.inner is not None:
            self.inner.prepare(names)

    def select_objects(self, query: ObjectQuery):
        from safemanip.semantics.base import ObjectAnswer

        self.queries.append(query)
        try:
            if self.inner is not None:
                answer = self.inner.select_objects(query)
            else:
                answer = ObjectAnswer(ids=list(query.order[:query.n_select]), explanation="nearest to the end-effector")
        except BackendError as exc:
            self.answers.append(exc)
            raise
        self.answers.append(answer)
        return answer

    def assign_constraints(self, query: ConstraintQuery):
        raise BackendError("render_query records object queries only")

    def describe(self) -> dict:
        return {"backend": "recording", "inner": None if self.inner is None else self.inner.describe()}


def render_query(seed: int, out_dir: str, *, n_objects: int = 4, steps: int = 8, k: int = 2, interval: int = 4,
                 history: int = 2, camera: str = "front", backend: Backend | None = None,
                 task: str | None = None) -> tuple[str, dict]:
    """Roll the scripted controller out for ``steps`` control steps in a SlideOutEnv and save the image
    Dynamic-VLM sends at its last query: the annotated frames of the last ``history`` queries side by side
    (boxes labelled ``<id>: <name>``, the end-effector's past path as a black arrow), plus the object list
    sorted by horizontal distance to the end-effector, as ``query_t<T>.png`` / ``.json`` / ``.txt``.

    Queries happen at t = 0, interval, 2 * interval, ... (the selector's own schedule), so the image is
    the one of the last query at or before ``steps``. ``backend`` (optional) answers the queries so the
    JSON also says what it picked; without one the k nearest objects are "picked".
    The episode may end early (collision, success); then the last query before the end is written.
    """
    import os
    from pathlib import Path

    from safemanip.semantics.prompts import load_prompt
    from safemanip.semantics.selectors import DynamicVLMSelector

    if steps < 0:
        raise ValueError(f"--steps must be >= 0, got {steps}")
    if n_objects < 1:
        raise ValueError(f"--n-objects must be >= 1, got {n_objects}")
    os.environ.setdefault("MUJOCO_GL", "egl")
    from safemanip.control.scripted import ScriptedController
    from safemanip.env.slide_out import SlideOutEnv
    from safemanip.selection.view import EnvViewBuilder

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    env = SlideOutEnv(n_objects=n_objects, visual=True)  # the annotated images show the arm as it looks
    try:
        _, info = env.reset(seed=seed)
        controller = ScriptedController()
        controller.reset()
        builder = EnvViewBuilder(camera=camera)
        builder.reset(env)
        recorder = _RecordingBackend(backend)
        selector = DynamicVLMSelector(recorder, query_interval=interval, history=history, task=task)
        view = builder.view(env, env.scene_state(), 0)
        selector.reset(view, k)
        query_steps: list[int] = []
        event, t = "running", 0
        for t in range(steps + 1):
            if t > 0:
                _, _, terminated, truncated, info = env.step(controller.act(info, env))
                view = builder.view(env, env.scene_state(), t)
                if terminated or truncated:
                    event = info["event"]
            before = len(recorder.queries)
            selected = selector.select(view, k)
            if len(recorder.queries) > before:
                query_steps.append(t)
            if event != "running":
                break
        if not recorder.queries or not recorder.queries[-1].images:
            raise RuntimeError("no annotated frame was rendered (is an OpenGL backend available? try MUJOCO_GL=egl "
                               "or MUJOCO_GL=osmesa)")
        query = recorder.queries[-1]
        t_query = query_steps[-1]
        answer = recorder.answers[-1]
        v = query.view
        dist = np.linalg.norm(np.asarray(v.positions)[:, :2] - v.ee_position[:2], axis=1)
        objects = [{"position": pos, "id": int(i), "name": v.names[i], "label": lbl,
                    "distance_to_ee_m": round(float(dist[i]), 4), "ground_truth": env.constraints[i]}
                   for pos, (i, lbl) in enumerate(zip(query.order, query.labels))]
        from safemanip.env.render import project_points

        h, w = env.render_size  # the frame size EnvViewBuilder renders at; the camera is fixed in the world
        path_px = project_points(env.model, env.data, camera, np.asarray(v.ee_path), h, w)
        stem = out / f"query_t{t_query:03d}"
        png = stem.with_suffix(".png")
        png.write_bytes(query.images[0])
        listing = "\n".join(f"position {o['position']}: {o['label']}" for o in objects)
        user_text = (f"Objects on the table, sorted by distance to the end-effector (position 0 is the nearest):\n"
                     f"{listing}\n\nChoose exactly k = {query.n_select} objects.")
        frames_at = query_steps[-history:]
        picked = (None if isinstance(answer, Exception) else
                  {"ids": answer.ids, "labels": [object_label(i, v.names[i]) for i in answer.ids],
                   "explanation": answer.explanation})
        result = {
            "seed": seed, "n_objects": n_objects, "k": k, "query_interval": interval, "camera": camera,
            "steps_run": t, "episode_event": event, "query_t": t_query, "frames_from_queries_at_t": frames_at,
            "image": str(png), "image_size": list(Image.open(io.BytesIO(query.images[0])).size),
            "ee_position": [round(float(x), 4) for x in v.ee_position],
            "box_position": [round(float(x), 4) for x in v.box_position],
            "objects_by_distance_to_ee": objects,
            "ee_path_px_in_last_frame": [[round(float(x), 1), round(float(y), 1)] for x, y in path_px],
            "selected": picked if picked is not None else {"error": str(answer)},
            "selected_by": recorder.describe()["inner"] or "k nearest to the end-effector (no backend)",
            "selector_currently_holds": [int(i) for i in selected],
            "prompt": {"system": load_prompt("object_selection", task=task), "user": user_text},
            "note": ("ground_truth is for the reader only; the model is sent the image and the prompt. The image "
                     "tiles the annotated frames of the queries in frames_from_queries_at_t, oldest left."),
        }
        result = redact_value(result)  # the backend's description and answer: never a key or URL credentials
        stem.with_suffix(".json").write_text(json.dumps(result, indent=1))
        stem.with_suffix(".txt").write_text(redact(user_text) + "\n")
    finally:
        env.close()
    lines = [f"render-query: seed {seed}, {n_objects} objects, scripted controller, {t} step(s) run"
             + (f" (episode ended: {event})" if event != "running" else ""),
             f"  query at t = {t_query}; frames from the queries at t = {', '.join(map(str, frames_at))} (oldest left)",
             "  objects by horizontal distance to the end-effector:"]
    lines += [f"    {o['position']}: {o['label']:28s} {o['distance_to_ee_m']:.3f} m  (ground truth {o['ground_truth']})"
              for o in objects]
    if picked is not None:
        lines.append(f"  picked (k = {k}, {'nearest' if backend is None else backend.name}): "
                     + ", ".join(picked["labels"]))
    else:
        lines.append(f"  the backend failed on this query: {answer}")
    lines += [f"  image: {png}", f"  list + prompt: {stem.with_suffix('.json')}, {stem.with_suffix('.txt')}"]
    return redact("\n".join(lines)), result
