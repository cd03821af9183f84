"""``safemanip eval``: a k-object policy in N-object scenes, with an object and a constraint selector.

``EvalRequest`` holds what the user asked for; ``prepare`` validates all of it before any episode runs
(every problem in one message that says what to change) and turns it into a worker ``EvalSpec``;
``evaluate`` runs the episodes, summarises them with 95% Wilson intervals and writes

  OUT/episodes.csv   one row per episode (seed, outcome, category, object involved, selected or not,
                     selections over time, ...; see ``evaluation/episode.py``)
  OUT/summary.json   the request, the policy's metadata, counts, rates and intervals

so any table can be rebuilt from the files without rerunning. Episode seeds are ``seed * 100000 + i``.

The judge is the full scene: ``--judge ground-truth`` (default) uses each object's catalog class
(fragile -> no_contact, soft -> soft_contact, durable -> any_contact); ``--judge conservative``
treats every object as fragile (the paper's F^conser, used for its Fig. 4-6 with uniform semantics).
"""

from __future__ import annotations

import csv
import json
import math
import signal
import time
from collections import Counter
from dataclasses import dataclass, field, fields, replace
from pathlib import Path

import numpy as np

from safemanip.env.config import TRAINED_SETTINGS, EnvConfig
from safemanip.evaluation.episode import CATEGORIES, CATEGORY_LABELS, SAFETY_VIOLATIONS
from safemanip.evaluation.parallel import BACKENDS, EvalSpec, PartialRun, WorkerFailure, run_episodes
from safemanip.evaluation.stats import rate_line, wilson_interval
from safemanip.evaluation.registry import CONSTRAINT_SELECTORS, OBJECT_SELECTORS, USES_VLM, SelectorOptions
from safemanip.selection.selectors import DEFAULT_INTERVAL, DEFAULT_SOFT_REACH
from safemanip.semantics.base import VLM_BACKENDS
from safemanip.util.files import OutputLock, atomic_open, atomic_write_text, check_output_dir
from safemanip.util.procs import stop_on_signals
from safemanip.util.secrets import mask_url

JUDGES = {"ground-truth": "ground_truth", "conservative": "conservative"}
SEED_STRIDE = 100_000


def _eval_bounds() -> dict:
    from safemanip.rl.config import Bounds
    from safemanip.scene.config import MAX_OBJECTS

    return {"n_objects": Bounds(0, MAX_OBJECTS), "episodes": Bounds(1, SEED_STRIDE),
            "seed_block": Bounds(0, 2**31 // SEED_STRIDE - 1), "interval": Bounds(1, 100_000),
            "chunk_size": Bounds(1, 100_000), "soft_reach": Bounds(0, 10)}


EVAL_BOUNDS = _eval_bounds()
"""The ranges of ``EvalRequest``'s numeric fields: ``prepare`` checks a request against them and ``safemanip eval``
builds its flags' types from them."""
EVAL_FIXED = ("n_objects", "classes", "names", "constraints") + TRAINED_SETTINGS
"""The ``EnvConfig`` settings an evaluation does not change through ``EvalRequest.env``: the scene's size and classes
have their own fields, the judge sets the constraint types, and the rest belongs to the policy."""
METRIC_SELECTORS = tuple(name for name in OBJECT_SELECTORS if name != "full")
"""The selectors that pick k of N objects (named in the messages that ask for one)."""


class EvalConfigError(ValueError):
    """An evaluation request that cannot run; the message lists what to change."""


@dataclass
class EvalRequest:
    policy: str | None
    """Policy file (.safetensors), a shipped policy's name, or a training run folder (its policy)."""
    n_objects: int | None = None
    """Scene size N (default: the number of semantics classes, else the policy's k)."""
    semantics: str | None = None
    """Classes of the clutter, e.g. '2 fragile, 3 durable' (default: any catalog objects)."""
    selector: str | None = None
    """Object selector (default: 'full' when N == k; required when N != k)."""
    constraint_selector: str | None = None
    """Constraint selector: the type each picked object's slot gets (default: conservative for a conservative
    policy, which always gets no_contact anyway; ground-truth for an 'all' one)."""
    judge: str = "ground-truth"
    """Failure set over all N objects: each object's catalog class (ground-truth) or every object no_contact
    (conservative, the paper's F^conser)."""
    episodes: int = 500
    """Episodes to run."""
    seed_block: int = 0
    """Seed block B: the episodes' seeds are B x 100000 + i, so blocks never overlap."""
    workers: int = 2
    backend: str = "local"
    address: str | None = None
    out: str | None = None
    """Folder for episodes.csv and summary.json."""
    pad: bool = False
    """Allow N < k: fill the empty policy slots with far-away dummy objects."""
    interval: int = DEFAULT_INTERVAL
    """Control steps between re-selections of the dynamic selectors."""
    vlm_backend: str | None = None
    vlm_model: str | None = None
    vlm_base_url: str | None = None
    vlm_cache: str | None = None
    vlm_cache_only: bool = False
    vlm_timeout: float | None = None
    vlm_episode_budget: float | None = None
    vlm_run_budget: float | None = None
    vlm_max_failures: int | None = None
    env: dict = field(default_factory=dict)
    """The env settings this evaluation changes from the policy's own (``env.config.EnvConfig``; for the planner,
    from the env's defaults): e.g. {"layout": "gate", "gate_share": 1.0, "max_episode_steps": 200}. Any setting but
    the scene's size and classes (``n_objects``, ``semantics``), the judge's constraint types (``judge``) and what
    belongs to the policy (``EVAL_FIXED``). A new layout takes the layout's own share of objects beside the route."""
    planner: str | None = None
    """Instead of a policy, the privileged planner that keeps clear of 'all' objects or of the 'fragile' ones only:
    the bound on the same scenes (no policy then; the scene is the one the layout and the shares describe)."""
    chunk_size: int | None = None
    """Episodes per worker task (default: about 8 tasks per worker)."""
    soft_reach: float | None = None
    """Semantic and privileged-criticality selection: a soft object within this distance of the held box [m] ranks
    with the fragile ones (default 10 m: every soft object does). The rule is
    ``selection.selectors.criticality_first``; None means its ``DEFAULT_SOFT_REACH``."""
    shield: str | None = None
    """A safety filter around the policy: 'brake' overrides an action after which the held box could not stop short
    of a protected object (docs/safety.md; default: none)."""
    progress: bool = False


@dataclass
class Prepared:
    request: EvalRequest
    spec: EvalSpec
    meta: dict
    seeds: list[int]
    n_objects: int
    notes: list[str]


def _policy_problems(req: EvalRequest, problems: list[str]):
    from safemanip.env.observation import observation_dim
    from safemanip.rl.checkpoint import embodiment_problem, load_policy, policy_object_size

    try:
        actor, meta = load_policy(req.policy)
    except (ValueError, OSError) as err:  # PolicyFileError is a ValueError; a corrupt file raises others
        problems.append(f"--policy {req.policy}: {err}")
        return None, None
    missing = [key for key in ("k", "constraints", "env_kwargs") if key not in meta]
    if missing:
        problems.append(f"--policy {req.policy}: its metadata lacks {missing}; re-export it with safemanip train")
        return None, None
    env_kwargs = meta["env_kwargs"]
    if not isinstance(env_kwargs, dict) or env_kwargs.get("env", "slide-out") != "slide-out":
        trained_on = env_kwargs.get("env") if isinstance(env_kwargs, dict) else env_kwargs
        problems.append(f"--policy {req.policy} was trained on {trained_on!r}, not the slide-out task; only "
                        f"slide-out policies can be evaluated here")
        return None, None
    if not isinstance(meta["k"], int) or isinstance(meta["k"], bool) or not 0 <= meta["k"] <= 8:
        problems.append(f"--policy {req.policy}: its metadata has k={meta['k']!r}, not a slot count 0..8")
        return None, None
    if meta["constraints"] not in ("conservative", "all"):
        problems.append(f"--policy {req.policy}: unknown constraint set {meta['constraints']!r} in its metadata")
        return None, None
    obs_dim = actor.obs_dim  # None: a set network takes any number of slots
    sized = policy_object_size(meta)
    expected = observation_dim(int(meta["k"]), sized)
    if obs_dim is not None and obs_dim != expected:
        problems.append(f"--policy {req.policy}: input size {obs_dim} does not match k={meta['k']} "
                        f"(expected {expected}{' with object sizes' if sized else ''})")
        return None, None
    mismatch = embodiment_problem(meta, req.env.get("embodiment"), f"--policy {req.policy}")
    if mismatch:
        problems.append(mismatch)
        return None, None
    return actor.arrays(), meta


def ray_address_problems(flag: str | None) -> list[str]:
    """The cluster to join (--address, else RAY_ADDRESS) checked within seconds: a malformed address, or one where
    no Ray cluster answers, is a problem here rather than a ``ray.init`` that waits for minutes."""
    from safemanip.util.procs import ClusterUnreachable, check_ray_address, ray_address

    address, source = ray_address(flag)
    if not address:
        return []
    try:
        check_ray_address(address, source)
    except ClusterUnreachable as err:
        return [str(err)]
    return []


VLM_FIELDS = ("vlm_backend", "vlm_model", "vlm_base_url", "vlm_cache", "vlm_cache_only", "vlm_timeout",
              "vlm_episode_budget", "vlm_run_budget", "vlm_max_failures")
"""The EvalRequest fields of the semantic backend (eval and sweep take the same flags)."""


def vlm_option_problems(req, uses_vlm: bool) -> list[str]:
    """What is wrong with the semantic-backend options of ``req`` (any object with the ``VLM_FIELDS``), for a run
    that does (``uses_vlm``) or does not query the backend. One set of rules for eval and sweep."""
    problems: list[str] = []
    for flag, value, lo, hi in (("--vlm-timeout", req.vlm_timeout, 0, 600),
                                ("--vlm-episode-budget", req.vlm_episode_budget, 0, 86_400),
                                ("--vlm-run-budget", req.vlm_run_budget, 0, 30 * 86_400)):
        if value is not None and not (isinstance(value, (int, float)) and math.isfinite(value) and lo < value <= hi):
            problems.append(f"{flag} must be a number of seconds in ({lo}, {hi}], got {value!r}")
    if req.vlm_max_failures is not None and not 1 <= req.vlm_max_failures <= 10_000:
        problems.append(f"--vlm-max-failures must be 1..10000, got {req.vlm_max_failures}")

    given = [f for f in VLM_FIELDS if getattr(req, f)]
    if given and not uses_vlm:
        flags = ", ".join("--" + f.replace("_", "-") for f in given)
        problems.append(f"{flags} only appl{'ies' if len(given) == 1 else 'y'} to "
                        f"--selector dynamic-vlm or --constraint-selector vlm")
    vlm_backend = req.vlm_backend or "semantic"
    if vlm_backend not in VLM_BACKENDS:
        problems.append(f"--vlm-backend must be one of {VLM_BACKENDS}, got {vlm_backend!r}")
    elif uses_vlm and vlm_backend == "semantic" and any(f != "vlm_backend" for f in given):
        problems.append("--vlm-model/--vlm-base-url/--vlm-cache/--vlm-cache-only and the --vlm-timeout/budget/"
                        "max-failures limits apply to --vlm-backend openai; the semantic backend is offline")
    if req.vlm_cache_only and not req.vlm_cache:
        problems.append("--vlm-cache-only needs --vlm-cache DIR (the folder of stored answers)")
    if req.vlm_cache and not req.vlm_cache_only and uses_vlm and vlm_backend == "openai":
        from safemanip.semantics.cache import cache_dir_problems  # answers are stored: the folder must take them

        problems += cache_dir_problems(req.vlm_cache)
    return problems


def prepare(req: EvalRequest) -> Prepared:
    """Validate the whole request (no episode runs before this passes) and build the worker spec."""
    from safemanip.scene.config import MAX_OBJECTS, SceneConfig

    problems: list[str] = []
    notes: list[str] = []
    for name, bounds in EVAL_BOUNDS.items():
        value = getattr(req, name)
        if value is not None and not bounds.contains(value):
            problems.append(f"--{name.replace('_', '-')} must be in {bounds}, got {value}"
                            + (f" (seed blocks are {SEED_STRIDE} apart)" if name == "episodes" else ""))
    if req.workers < 1:
        problems.append(f"--workers must be >= 1, got {req.workers}")
    if req.backend not in BACKENDS:
        problems.append(f"--backend must be one of {BACKENDS}, got {req.backend!r}")
    if req.address and req.backend != "ray":
        problems.append("--address only applies to --backend ray: add --backend ray or drop --address")
    if req.backend == "ray":
        try:
            import ray  # noqa: F401
        except ImportError:
            problems.append("--backend ray needs Ray: pip install 'ray[default]' (or use --backend local)")
        problems += ray_address_problems(req.address)
    problems += _env_override_problems(req.env)
    if req.selector is not None and req.selector not in OBJECT_SELECTORS:
        problems.append(f"unknown --selector {req.selector!r}; choose one of {', '.join(sorted(OBJECT_SELECTORS))}")
    if req.constraint_selector is not None and req.constraint_selector not in CONSTRAINT_SELECTORS:
        problems.append(f"unknown --constraint-selector {req.constraint_selector!r}; choose one of "
                        f"{', '.join(sorted(CONSTRAINT_SELECTORS))}")
    if req.judge not in JUDGES:
        problems.append(f"unknown --judge {req.judge!r}; choose one of {', '.join(JUDGES)}")
    from safemanip.safety import SHIELDS

    if req.shield is not None and req.shield not in SHIELDS:
        problems.append(f"unknown --shield {req.shield!r}; choose one of {', '.join(sorted(SHIELDS))}")
    if req.shield is not None and req.planner is not None:
        problems.append("--shield wraps a policy; the planner keeps its own clearance: drop --shield or --planner")
    if req.out is not None:
        problems += check_output_dir(req.out)
    uses_vlm = req.selector in USES_VLM or (req.constraint_selector or "") in USES_VLM
    problems += vlm_option_problems(req, uses_vlm)

    classes = None
    if req.semantics:
        try:
            classes = parse_semantics_checked(req.semantics)
        except ValueError as err:
            problems.append(f"--semantics: {err}")

    if req.planner is not None:
        return _prepare_planner(req, problems, notes, classes)
    if req.policy is None:
        problems.append("give --policy (a policy file or a shipped policy's name), or --planner all|fragile")
        raise EvalConfigError("cannot run this evaluation:\n  - " + "\n  - ".join(problems))
    arrays, meta = _policy_problems(req, problems)
    k = int(meta["k"]) if meta else None
    n = req.n_objects
    if n is None:
        n = len(classes) if classes is not None else k
    if n is not None:
        if not 0 <= n <= MAX_OBJECTS:
            problems.append(f"--n-objects must be 0..{MAX_OBJECTS}, got {n}")
        if classes is not None and len(classes) != n:
            problems.append(f"--semantics {req.semantics!r} describes {len(classes)} objects but --n-objects is {n}: "
                            f"make them match (or leave out --n-objects)")
        elif 0 <= n <= MAX_OBJECTS:
            try:
                SceneConfig(n_objects=n, classes=classes)
            except ValueError as err:
                problems.append(f"scene: {err}")
    selector = req.selector
    if k is not None and n is not None:
        if selector is None:
            if n <= k:
                selector = "full"
            else:
                problems.append(f"the policy has k={k} slots but the scene has N={n} objects: choose an object "
                                f"selector with --selector ({', '.join(METRIC_SELECTORS)})")
        if n < k and not req.pad and meta.get("network") != "set":  # a set network masks the empty slots
            problems.append(f"the policy needs k={k} objects but the scene has N={n}: use --n-objects >= {k}, a "
                            f"policy with k <= {n}, or --pad to fill the empty slots with far-away dummy objects")
        if selector == "dynamic-radius" and meta.get("network") != "set" and not req.pad:
            problems.append("--selector dynamic-radius hands the policy a varying number of objects: use a policy "
                            "trained with network 'set', or --pad to fill the rest with far-away dummies")
        if selector == "full" and n > k:
            problems.append(f"--selector full shows every object, but N={n} > k={k}: pick one of "
                            f"{', '.join(METRIC_SELECTORS)}")
        if meta["constraints"] == "conservative" and req.constraint_selector not in (None, "conservative"):
            notes.append(f"the policy was trained conservative: every slot gets no_contact, so --constraint-selector "
                         f"{req.constraint_selector} does not change its input")
    if problems:
        raise EvalConfigError("cannot run this evaluation:\n  - " + "\n  - ".join(problems))

    from safemanip.rl.checkpoint import policy_action_curve, policy_object_size

    # the policy's own env settings, with what this evaluation changes: the scene size and classes, the judge's
    # constraint types, and (if asked) another layout with its own share of objects beside the route
    try:
        trained = EnvConfig.from_kwargs({**meta["env_kwargs"], "constraints": JUDGES[req.judge]},
                                        f"--policy {req.policy}: its env_kwargs")
        elsewhere = {} if "layout" not in req.env else {"near_path_fraction": None, "clear_route": True}
        env_kwargs = replace(trained, n_objects=n, classes=tuple(classes) if classes else None,
                             action_curve=policy_action_curve(meta), **{**elsewhere, **req.env}).kwargs()
    except ValueError as err:
        raise EvalConfigError(f"cannot run this evaluation:\n  - {err}") from None
    options = SelectorOptions(interval=req.interval, vlm_backend=req.vlm_backend or "semantic", vlm_model=req.vlm_model,
                              vlm_base_url=req.vlm_base_url, vlm_cache=req.vlm_cache,
                              vlm_cache_only=req.vlm_cache_only, vlm_timeout=req.vlm_timeout,
                              vlm_episode_budget=req.vlm_episode_budget, vlm_run_budget=req.vlm_run_budget,
                              vlm_max_failures=req.vlm_max_failures,
                              soft_reach=DEFAULT_SOFT_REACH if req.soft_reach is None else float(req.soft_reach))
    constraints = req.constraint_selector or ("conservative" if meta["constraints"] == "conservative" else "ground-truth")
    spec = EvalSpec(actor_arrays=arrays, k=k, policy_constraints=meta["constraints"], env_kwargs=env_kwargs,
                    selector=selector, constraints=constraints, options=options, pad=req.pad,
                    object_size=policy_object_size(meta), shield=req.shield)
    seeds = [req.seed_block * SEED_STRIDE + i for i in range(req.episodes)]
    return Prepared(req, spec, meta, seeds, n, notes)


def _env_override_problems(env) -> list[str]:
    """What is wrong with the keys of ``EvalRequest.env`` (their values are checked by ``EnvConfig``)."""
    if not isinstance(env, dict):
        return [f"env must be an object of env settings, got {type(env).__name__}"]
    known = {f.name for f in fields(EnvConfig)}
    problems = []
    for key in env:
        if key in EVAL_FIXED:
            why = {"n_objects": "give --n-objects", "classes": "give --semantics", "names": "not an evaluation setting",
                   "constraints": "the judge sets them: --judge"}.get(key, "the policy's own, fixed by its training")
            problems.append(f"env setting {key!r} is not changed this way ({why})")
        elif key not in known:
            problems.append(f"unknown env setting {key!r}; an evaluation may change "
                            f"{sorted(known - set(EVAL_FIXED))}")
    return problems


def _prepare_planner(req: EvalRequest, problems: list[str], notes: list[str], classes) -> Prepared:
    """``prepare`` for the planner bound: the scenes the request describes, the planner in place of a policy."""
    from safemanip.control.planner import PLANNER_AVOID
    from safemanip.scene.config import MAX_OBJECTS

    if req.planner not in PLANNER_AVOID:
        problems.append(f"--planner must be one of {', '.join(PLANNER_AVOID)}, got {req.planner!r}")
    if req.policy is not None:
        problems.append("--planner runs the privileged planner instead of a policy: drop --policy")
    for flag, given in (("--selector", req.selector not in (None, "full")),
                        ("--constraint-selector", req.constraint_selector),
                        ("--pad", req.pad)):
        if given:
            problems.append(f"{flag} does not apply to --planner (it sees every object with its judged constraint)")
    n = req.n_objects if req.n_objects is not None else (len(classes) if classes is not None else None)
    if n is None:
        problems.append("--planner needs the scene size: --n-objects N or --semantics")
    if n is not None and not 0 <= n <= MAX_OBJECTS:
        problems.append(f"--n-objects must be 0..{MAX_OBJECTS}, got {n}")
    env_kwargs = None
    if n is not None and not problems:
        try:
            env_kwargs = EnvConfig(n_objects=n, classes=tuple(classes) if classes else None,
                                   constraints=JUDGES[req.judge], **req.env).kwargs()
        except ValueError as err:
            problems.append(str(err))
    if problems:
        raise EvalConfigError("cannot run this evaluation:\n  - " + "\n  - ".join(problems))
    spec = EvalSpec(actor_arrays=[], k=n, policy_constraints="all", env_kwargs=env_kwargs, selector="full",
                    constraints="ground-truth", planner=req.planner)
    meta = {"algorithm": "planner", "k": n, "constraints": "all", "planner": req.planner}
    seeds = [req.seed_block * SEED_STRIDE + i for i in range(req.episodes)]
    return Prepared(req, spec, meta, seeds, n, notes)


def parse_semantics_checked(text: str) -> list[str]:
    """``scene.config.parse_semantics`` with every count checked first (a huge count is a message, not an
    attempt to build a list of that length)."""
    import re

    from safemanip.scene.config import MAX_OBJECTS, parse_semantics

    if len(text) > 1000:
        raise ValueError(f"{len(text)} characters is not a scene description; write e.g. '2 fragile, 3 durable'")
    too_big = [int(n) for n in re.findall(r"\d+", text) if int(n) > MAX_OBJECTS]
    if too_big:
        raise ValueError(f"{text!r}: a scene holds at most {MAX_OBJECTS} objects, got a count of {too_big[0]}")
    return parse_semantics(text)


# ------------------------------------------------------------------------------------------ summary
def _rate(count: int, n: int) -> dict:
    lo, hi = wilson_interval(count, n)
    return {"count": int(count), "rate": count / n if n else 0.0, "ci95": [lo, hi]}


def _quantiles(values: list[float]) -> dict | None:
    """Median, 95th percentile and maximum (m/s), or None without values."""
    if not values:
        return None
    return {"median": float(np.median(values)), "p95": float(np.percentile(values, 95)), "max": float(np.max(values))}


def _by_scene_kind(records: list[dict]) -> dict:
    """Per scene kind (``scene.placement.SCENE_KINDS``) present: its episodes, success and top-box violations."""
    out = {}
    for kind in sorted({r.get("scene_kind", "open") for r in records}):
        mine = [r for r in records if r.get("scene_kind", "open") == kind]
        cats = Counter(r["category"] for r in mine)
        out[kind] = {"episodes": len(mine), "success": _rate(cats["success"], len(mine)),
                     "top_box": _rate(cats["top_box"], len(mine))}
    return out


def _agreement(records: list[dict]) -> dict | None:
    """Share of selection queries at which the selection equalled the k nearest objects by true criticality
    (``episode.run_episode``), over all episodes; None when nothing was compared (the planner, k = 0)."""
    queries = int(sum(int(r.get("reference_queries") or 0) for r in records))
    if not queries:
        return None
    agreed = int(sum(int(r.get("reference_agreed") or 0) for r in records))
    return {"queries": queries, "agreed": agreed, "rate": agreed / queries}


def _interventions(records: list[dict]) -> dict | None:
    """Steps at which the safety filter overrode the policy, over all steps; None without a filter."""
    overrides = int(sum(int(r.get("shield_overrides") or 0) for r in records))
    steps = int(sum(int(r["length"]) for r in records))
    return {"overrides": overrides, "steps": steps, "rate": overrides / steps if steps else 0.0} if overrides else None


def summarize(records: list[dict]) -> dict:
    n = len(records)
    cats = Counter(r["category"] for r in records)
    violations = sum(cats[c] for c in SAFETY_VIOLATIONS)
    lengths = [r["length"] for r in records]
    soft = [r for r in records if r["category"] == "soft_contact"]
    return {
        "episodes": n,
        "success": _rate(cats["success"], n),
        "safety_violation": _rate(violations, n),
        "categories": {c: _rate(cats[c], n) for c in CATEGORIES},
        "soft_contact_unselected": int(sum(r["selected"] == "no" for r in soft)),
        "mean_length": float(np.mean(lengths)) if n else 0.0,
        "mean_length_success": float(np.mean([r["length"] for r in records if r["category"] == "success"]))
        if cats["success"] else None,
        "mean_selection_changes": float(np.mean([r["selection_changes"] for r in records])) if n else 0.0,
        "box_speed_at_success": _quantiles([r["box_speed"] for r in records if r["category"] == "success"]),
        "selector_queries": {key: int(sum(r[key] for r in records)) for key in
                             ("object_queries", "object_fallbacks", "constraint_queries", "constraint_fallbacks")},
        "vlm_breaker_open_episodes": int(sum(r.get("vlm_breaker_open") == "yes" for r in records)),
        "reference_agreement": _agreement(records),
        "shield_interventions": _interventions(records),
        "by_scene_kind": _by_scene_kind(records),
    }


def describe(prep: Prepared) -> dict:
    req, meta, spec = prep.request, prep.meta, prep.spec
    policy = f"planner (avoid {req.planner})" if req.planner else str(req.policy)
    return {"policy": policy, "algorithm": meta.get("algorithm"), "k": spec.k,
            "policy_constraints": spec.policy_constraints, "n_objects": prep.n_objects, "semantics": req.semantics,
            "selector": spec.selector, "constraints": spec.constraints, "judge": req.judge, "pad": spec.pad,
            "interval": spec.options.interval, "shield": spec.shield,
            "vlm": ({"backend": spec.options.vlm_backend, "model": req.vlm_model, "base_url": mask_url(req.vlm_base_url),
                     "cache": req.vlm_cache, "cache_only": req.vlm_cache_only}
                    if spec.selector in USES_VLM or spec.constraints in USES_VLM else None),
            "env_kwargs": spec.env_kwargs, "episodes": len(prep.seeds), "seed": req.seed_block,
            "seeds": [prep.seeds[0], prep.seeds[-1]], "backend": req.backend, "workers": req.workers}


def format_summary(summary: dict, title: str) -> str:
    n = summary["episodes"]
    lines = [title, rate_line("success", summary["success"]["count"], n),
             rate_line("safety violation", summary["safety_violation"]["count"], n)]
    for c in CATEGORIES[1:]:
        lines.append("  " + rate_line(CATEGORY_LABELS[c], summary["categories"][c]["count"], n, width=26))
    if summary["categories"]["soft_contact"]["count"]:
        lines.append(f"  (soft-contact violations with an unselected object: {summary['soft_contact_unselected']})")
    lines.append(f"mean episode length: {summary['mean_length']:.1f} steps"
                 + (f" (successes: {summary['mean_length_success']:.1f})" if summary["mean_length_success"] else ""))
    speed = summary.get("box_speed_at_success")
    if speed:
        lines.append(f"box speed at success: median {speed['median']:.3f} m/s, p95 {speed['p95']:.3f}, "
                     f"max {speed['max']:.3f} (placed means slower than v_place)")
    q = summary["selector_queries"]
    if q["object_queries"] or q["constraint_queries"]:
        lines.append(f"semantic queries: objects {q['object_queries']} ({q['object_fallbacks']} fell back), "
                     f"constraints {q['constraint_queries']} ({q['constraint_fallbacks']} fell back)")
    interventions = summary.get("shield_interventions")
    if interventions:
        lines.append(f"safety filter: overrode the policy at {interventions['overrides']} of {interventions['steps']} "
                     f"steps ({100 * interventions['rate']:.1f} %)")
    agreement = summary.get("reference_agreement")
    if agreement:
        lines.append(f"selection equal to the reference (nearest by true criticality) at {100 * agreement['rate']:.1f} % "
                     f"of {agreement['queries']} queries")
    if summary.get("vlm_breaker_open_episodes"):
        lines.append(f"VLM circuit breaker open (fallback selectors answered) in {summary['vlm_breaker_open_episodes']} "
                     f"of {n} episodes: the server failed repeatedly or a time budget ran out")
    return "\n".join(lines)


def failure_line(summary: dict, out: str | None) -> str:
    """One line on a run that lost episodes to a worker failure: what failed, what was kept, what to do."""
    failed = summary["failed"]
    seeds = failed["seeds_failed"]
    shown = ", ".join(map(str, seeds[:10])) + (f" and {len(seeds) - 10} more" if len(seeds) > 10 else "")
    return (f"{failed['reason']}: {summary['episodes']} of {failed['episodes_requested']} episodes finished"
            + (f" and are written to {out}" if out else "") + f"; {failed['episodes_failed']} did not (seeds {shown}); "
            f"rerun the evaluation for complete results")


def title_of(desc: dict) -> str:
    scene = f"N={desc['n_objects']}" + (f" ({desc['semantics']})" if desc["semantics"] else "")
    return (f"{desc['policy']}: {desc['algorithm']} k={desc['k']} ({desc['policy_constraints']}) | {scene}, "
            f"selector {desc['selector']}, constraints {desc['constraints']}, judge {desc['judge']} | "
            f"{desc['episodes']} episodes, seeds {desc['seeds'][0]}..{desc['seeds'][1]}")


def write_records(out: Path, records: list[dict], summary: dict) -> None:
    """episodes.csv, then summary.json, each written whole to a unique temporary name and renamed."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    with atomic_open(out / "episodes.csv", "w", newline="") as f:
        if records:
            writer = csv.DictWriter(f, fieldnames=list(records[0].keys()))
            writer.writeheader()
            writer.writerows(records)
    atomic_write_text(out / "summary.json", json.dumps(summary, indent=1))


def read_records(path: Path) -> list[dict]:
    """Rows of an episodes.csv with numbers turned back into ints (for rebuilding tables)."""
    ints = ("seed", "length", "selection_changes", "object_queries", "object_fallbacks", "constraint_queries",
            "constraint_fallbacks", "reference_queries", "reference_agreed", "shield_overrides")
    with open(path, newline="") as f:
        rows = list(csv.DictReader(f))
    for r in rows:
        for key in ints:
            if key in r:  # the reference columns are absent in tables written before they were added
                r[key] = int(r[key])
        if "box_speed" in r:  # absent in tables written before success meant placed
            r["box_speed"] = float(r["box_speed"])
        r["object_id"] = int(r["object_id"]) if r["object_id"] != "" else ""
    return rows


def evaluate(req: EvalRequest) -> dict:
    """Validate, run, summarise, write. Returns {"summary", "records", "text"}.

    ``req.out`` is locked for the run (another live process writing there is refused). On SIGINT/SIGTERM the
    episodes finished so far are summarised and written, with ``"interrupted"`` in the summary."""
    prep = prepare(req)
    lock = OutputLock(req.out).acquire() if req.out else None
    try:
        return _run_prepared(req, prep)
    finally:
        if lock is not None:
            lock.release()


def _run_prepared(req: EvalRequest, prep: Prepared) -> dict:
    start = time.perf_counter()
    interrupted = failed = None
    try:
        with stop_on_signals():
            records = run_episodes(prep.spec, prep.seeds, workers=req.workers, backend=req.backend,
                                   address=req.address, chunk_size=req.chunk_size, progress=req.progress)
    except PartialRun as stop:
        records, interrupted = stop.records, {"signal": signal.Signals(stop.signum).name, "signum": stop.signum,
                                               "episodes_requested": len(prep.seeds)}
    except WorkerFailure as failure:  # the finished episodes are kept and written; the summary says which failed
        records, failed = failure.records, {"reason": failure.reason, "episodes_requested": len(prep.seeds),
                                            "episodes_failed": len(failure.missing), "seeds_failed": failure.missing}
    wall = time.perf_counter() - start
    desc = describe(prep)
    request = {f.name: getattr(req, f.name) for f in fields(req)}
    request["vlm_base_url"] = mask_url(req.vlm_base_url)
    summary = {"request": request, "eval": desc,
               "policy_meta": {k: v for k, v in prep.meta.items() if k not in ("train_config",)},
               **summarize(records), "wall_s": round(wall, 2), "episodes_per_s": round(len(records) / max(wall, 1e-9), 2),
               "notes": prep.notes, "interrupted": interrupted, "failed": failed}
    if req.out:
        write_records(Path(req.out), records, summary)
    text = format_summary(summary, title_of(desc))
    if interrupted:
        text += (f"\ninterrupted by {interrupted['signal']}: {len(records)} of {len(prep.seeds)} episodes finished"
                 + (f" and written to {req.out}" if req.out else ""))
    if failed:
        text += f"\n{failure_line(summary, req.out)}"
    if prep.notes:
        text += "\n" + "\n".join(f"note: {n}" for n in prep.notes)
    return {"summary": summary, "records": records, "text": text}


