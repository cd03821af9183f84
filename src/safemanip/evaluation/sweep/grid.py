"""A sweep's cells: what each one measures, its id, and the grid a spec makes of them (``cells_of``).

Two kinds of cell: a policy's (``Cell``: a policy file under one object selector, constraint selector and filter) and
a planner reference row (``PlannerCell``: the privileged planner on the same scenes, no policy). Both are stored in
one record format (``record``: the fields of ``Cell``), which the table, the figures and the findings read.

A policy cell's identity (algorithm, k, constraints, how it was trained, its training seed) is read from the policy
file's metadata; the file's name gives the cell id and stands in for the identity only while the file does not exist
(its cell is listed as skipped, with the commands that train it). Cells with k > N are not applicable and left out.
"""

from __future__ import annotations

import re
from dataclasses import asdict, dataclass, fields
from pathlib import Path

from safemanip.evaluation.sweep.spec import POLICY_NAME, SweepError, SweepSpec

PLANNER = "planner"
"""The ``algorithm`` of a planner row's record: what tells it from a policy's cell on disk."""


def record_id(record: dict) -> str:
    """A stored cell's id (its result file's name): policy, N, semantics, selectors, judge, scenes and filter."""
    semantics = record["semantics"]
    sem = "any" if not semantics else re.sub(r"[^a-z0-9]+", "-", semantics.lower()).strip("-")
    scenes = "" if not record.get("scenes") else "__" + re.sub(r"[^a-z0-9.]+", "-", record["scenes"].lower()).strip("-")
    shield = "" if not record.get("shield") else f"__shield-{record['shield']}"
    return (f"{Path(record['policy']).stem}__N{record['n_objects']}__{sem}__{record['selector']}__"
            f"{record['constraints']}__{record['judge']}{scenes}{shield}")


def is_planner(record: dict) -> bool:
    return record["algorithm"] == PLANNER


@dataclass(frozen=True)
class Cell:
    """One policy measured under one object selector, constraint selector and safety filter on one kind of scene."""

    policy: str
    """The policy file as the spec names it."""
    algorithm: str
    """How the policy was trained: 'rarl', 'vanilla', ... (its metadata's ``algorithm``)."""
    k: int
    """The objects the policy observes (its metadata's ``k``)."""
    policy_constraints: str
    """The constraint types the policy was trained with: 'conservative' or 'all'."""
    n_objects: int
    """The objects in the scene, N."""
    semantics: str | None
    """The scene's classes ('2 fragile, 3 durable'); None: any."""
    selector: str
    """The object selector (``registry.OBJECT_SELECTORS``)."""
    constraints: str
    """The constraint selector (``registry.CONSTRAINT_SELECTORS``)."""
    judge: str
    """Which constraints judge an episode (``harness.JUDGES``)."""
    episodes: int
    seed: int
    """The episode seed block."""
    vlm: str | None = None
    """Identity of the semantic backend for cells that query it (its example set and rule version), so a
    new classifier version makes those cells stale; None for cells that do not use it."""
    variant: str = ""
    """'selaware' for a policy trained with the object selector in the loop, '' for one trained the paper's way."""
    train_seed: int | None = None
    """The policy's training seed when its name makes it one seed of a method (``-sSEED``): the table and figure pool
    the seeds of one method; None for a policy named without one, which stands alone."""
    scenes: str | None = None
    """The sweep's scene settings (``scenes``) in short, e.g. 'layout=exit,exit_share=1.0'; None: the policy's own."""
    shield: str | None = None
    """The safety filter around the policy (``safety.SHIELDS``), None for none (the sweep's ``shields``)."""

    @property
    def id(self) -> str:
        return record_id(self.record())

    def record(self) -> dict:
        """The cell as its result file stores it."""
        return asdict(self)

    def train_command(self) -> str:
        """The commands that train this cell's policy as the benchmark's were and bring it in. The recipe, the budget
        and every setting's flags live in one place, ``bench/benchmark.json``; a name the benchmark does not list is
        refused by ``bench train --only`` with the names it does."""
        return f"safemanip bench train --only {Path(self.policy).stem} && safemanip bench promote"


RECORD_FIELDS = tuple(f.name for f in fields(Cell))
"""The fields of every stored cell, a planner row's included."""


@dataclass(frozen=True)
class PlannerCell:
    """The privileged planner (``control.planner.GridPlanner``) on a sweep's scenes, keeping clear of every object or
    of the fragile ones only: a reference the policies are read against, not an upper bound (a learned policy can beat
    it). It has no policy file, selector or training."""

    avoid: str
    """'all' or 'fragile' (``spec.PLANNER_AVOID``)."""
    n_objects: int
    semantics: str | None
    judge: str
    episodes: int
    seed: int
    """The episode seed block: the policies' own, so the planner meets the very same scenes."""
    scenes: str | None = None
    """The sweep's scene settings in short, as ``Cell.scenes``."""

    @property
    def id(self) -> str:
        return record_id(self.record())

    def record(self) -> dict:
        """The row as its result file stores it, in the policy cells' format: policy 'planner-AVOID', algorithm
        'planner', k = N (it sees every object), selector 'full' and the true classes as its constraints."""
        return {"policy": f"planner-{self.avoid}", "algorithm": PLANNER, "k": self.n_objects,
                "policy_constraints": self.avoid, "n_objects": self.n_objects, "semantics": self.semantics,
                "selector": "full", "constraints": "ground-truth", "judge": self.judge, "episodes": self.episodes,
                "seed": self.seed, "vlm": None, "variant": "", "train_seed": None, "scenes": self.scenes,
                "shield": None}


def vlm_identity(vlm: dict | None) -> str:
    """What a cell that queries the semantic backend records as ``Cell.vlm``: the offline classifier's example
    set, or the openai backend's model, so results of one backend never count as done for another."""
    from safemanip.semantics.semantic_backend import DEFAULT_EXAMPLES

    vlm = vlm or {}
    if (vlm.get("vlm_backend") or "semantic") == "openai":
        return f"openai:{vlm.get('vlm_model') or 'gpt-4o'}"
    return f"semantic:{DEFAULT_EXAMPLES}"


def cells_of(spec: SweepSpec, episodes: int | None = None, vlm: dict | None = None) -> list[Cell | PlannerCell]:
    """The grid's applicable cells, in a stable order: every policy's, then the planner rows.

    Left out: k > N (the policy has more slots than objects) and semantics that do not describe N
    objects (so one config can pair each N with its own semantics). Duplicates (k == N cells that all
    map to ``k_equals_n_selector``) are merged.
    """
    from safemanip.evaluation.registry import USES_VLM
    from safemanip.scene.config import parse_semantics

    episodes = int(episodes or spec.episodes)
    scenes = spec.scenes.label()
    out: dict[str, Cell | PlannerCell] = {}
    for entry in spec.policies:
        identity = policy_identity(entry.path)
        for n in spec.n_objects_of(entry):
            if identity["k"] > n:
                continue
            for sem in spec.semantics_of(entry):
                if sem is not None and len(parse_semantics(sem)) != n:
                    continue
                for selector, constraints in spec.pairs:
                    if identity["k"] == n and spec.k_equals_n_selector:
                        selector = spec.k_equals_n_selector
                    uses_vlm = selector in USES_VLM or constraints in USES_VLM
                    for shield in spec.shields:
                        cell = Cell(entry.path, n_objects=int(n), semantics=sem, selector=selector,
                                    constraints=constraints, judge=spec.judge, episodes=episodes, seed=spec.seed,
                                    vlm=vlm_identity(vlm) if uses_vlm else None, scenes=scenes, shield=shield,
                                    **identity)
                        out.setdefault(cell.id, cell)
    sizes = sorted({int(n) for entry in spec.policies for n in spec.n_objects_of(entry)})
    own = tuple(s for entry in spec.policies for s in entry.semantics or ())
    # a spec that gives semantics only per policy has the planner on those alone, not also on any classes
    listed = spec.semantics if spec.semantics is not None else (() if own else (None,))
    for avoid in spec.planners:  # the planner on the very same scenes (same seeds), once per scene setting
        for n in sizes:
            for sem in dict.fromkeys(listed + own):
                if sem is not None and len(parse_semantics(sem)) != n:
                    continue
                planner = PlannerCell(avoid, n, sem, spec.judge, episodes, spec.seed, scenes)
                out.setdefault(planner.id, planner)
    return list(out.values())


def _named(policy: str) -> dict:
    """What a policy's file name says it is: ``POLICY_NAME``'s fields, as ``Cell`` names them."""
    m = POLICY_NAME.fullmatch(Path(policy).stem)
    return {"algorithm": m["algorithm"], "k": int(m["k"]), "policy_constraints": m["constraints"],
            "variant": m["variant"] or "", "train_seed": None if m["train_seed"] is None else int(m["train_seed"])}


def policy_identity(policy: str) -> dict:
    """A policy cell's identity (``Cell``'s algorithm, k, policy_constraints, variant and train_seed), from the policy
    file's metadata: how it was trained is ``train_config.scene_objects`` (set: selection-aware), its seed
    ``train_config.seed``, kept only when the name makes the policy one seed of a method. What the metadata does not
    hold, or all of it for a file not trained yet or not readable, is what the name says; a file that cannot be read
    fails in its cell."""
    from safemanip.rl.checkpoint import load_policy, resolve_policy

    named = _named(policy)
    try:
        path = resolve_policy(policy)
        if not path.exists():
            return named
        _, meta = load_policy(path)
    except (OSError, ValueError):
        return named
    train = meta.get("train_config") if isinstance(meta.get("train_config"), dict) else {}
    found = {"algorithm": meta.get("algorithm"), "k": meta.get("k"), "policy_constraints": meta.get("constraints"),
             "variant": None if "scene_objects" not in train else "selaware" if train["scene_objects"] else "",
             "train_seed": train.get("seed") if named["train_seed"] is not None else None}
    return {field: named[field] if found[field] is None else found[field] for field in named}


def check_policies(cells: list[Cell | PlannerCell], name: str) -> None:
    """Refuse the sweep (SweepError, one line) if any existing policy file of ``cells`` holds a policy other than
    its name says: the cell id is made from the name, so such a file would store its results under another policy's
    cells. Checked for every policy before any cell runs, rather than failing cell by cell and drawing a table."""
    from safemanip.rl.checkpoint import resolve_policy

    problems, seen = [], set()
    for cell in cells:
        if isinstance(cell, PlannerCell) or cell.policy in seen:
            continue
        seen.add(cell.policy)
        path = Path(cell.policy) if Path(cell.policy).is_absolute() else resolve_policy(cell.policy)
        if path.exists():  # a missing file is reported as skipped, with the command that trains it
            problem = _name_problem(cell)
            if problem:
                problems.append(problem)
    if problems:
        raise SweepError(f"sweep {name}: no cell run: " + "; ".join(problems) + ": rename the file(s) or fix the sweep")


CHECKED = {"k": "k", "policy_constraints": "constraints", "algorithm": "algorithm", "variant": "variant",
           "train_seed": "seed"}
"""The identity fields a policy's name must agree with, and what the refusal calls them."""


def _name_problem(cell: Cell) -> str | None:
    """What the cell's identity (the file's metadata: ``policy_identity``) says that its name (and so its id)
    contradicts; None if they agree."""
    named, found = _named(cell.policy), cell.record()
    differ = [f for f in CHECKED if found[f] != named[f]]
    if not differ:
        return None

    def say(values: dict) -> str:
        shown = {**values, "variant": values["variant"] or "the paper's way"}
        return ", ".join(f"{CHECKED[f]}={shown[f]}" for f in differ)

    return f"{cell.policy}: its metadata says {say(found)}, its name {say(named)}"


def select_cells(cells: list[Cell | PlannerCell], patterns: list[str], name: str) -> list[Cell | PlannerCell]:
    """The cells whose id matches one of ``patterns`` (shell-style, ``fnmatch``), in the sweep's order. A pattern
    that matches no cell is an error that shows what ids look like: a typo must not run nothing silently."""
    from fnmatch import fnmatchcase

    unmatched = [p for p in patterns if not any(fnmatchcase(c.id, p) for c in cells)]
    if unmatched:
        example = cells[0].id if cells else "(the sweep has no cells)"
        raise SweepError(f"--only {' '.join(unmatched)} matches no cell of sweep {name}; cell ids look like "
                         f"{example} (use * and ?, e.g. --only '*-s0__*' for training seed 0)")
    return [c for c in cells if any(fnmatchcase(c.id, p) for p in patterns)]
