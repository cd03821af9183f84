"""A sweep spec: the JSON file that names a sweep's grid, read and checked once into a ``SweepSpec``.

Shipped specs live in ``evaluation/sweeps/`` (``safemanip sweep NAME``); a path to your own works too::

  {"name": "fig5", "folder": "exit/fig5", "title": "...", "figure": "fig4" | "fig5" | "fig6" | "table",
   "episodes": 1000, "seed": 32, "judge": "conservative" | "ground-truth",
   "scenes": {"layout": "exit", "exit_share": 1.0},   optional: the scenes of every cell (default: each
                                               policy's own layout)
   "policies": ["policies/rarl-k2-conservative-s0.safetensors", ...],   each entry may also be
                                               {"path": ..., "n_objects": [...], "semantics": [...]}
                                               to give that policy its own N and semantics
   "n_objects": [3, 4, 5, 6], "semantics": [null | "2 fragile, 3 durable", ...],
   "selectors": ["static-knn", "dynamic-knn"], "constraints": ["conservative"],
   "pairs": [["dynamic-vlm", "vlm"], ...],      optional: (selector, constraints) pairs instead of
                                               the product of selectors x constraints
   "k_equals_n_selector": "full",              optional: selector used when k == N (the full-state
                                               policy sees every object in its training layout)
   "bounds": ["all", "fragile"],               optional: the privileged planner on the same scenes, keeping
                                               clear of every object or of the fragile ones only (a
                                               reference, not an upper bound: a learned policy can beat it)
   "shields": [null, "brake"],                 optional: every policy cell once per safety filter (null: none)
   "table": {"rows": ["k"], "columns": ["n_objects", "selector"]}}

``seed`` is the episode seed block (block B = seeds B x 100,000 + i). The shipped sweeps report on blocks reserved
for reported results (the benchmark's reporting blocks, ``bench/benchmark.json``, which checks that they agree with
these specs): no checkpoint, hyper-parameter or classifier is ever chosen on them (a run's final or best policy is
chosen on the benchmark's selection block, ``safemanip bench promote``).

Policy files are named ``{algorithm}-k{k}-{constraints}[-selaware][-s{seed}].safetensors`` (``POLICY_NAME``): the name
makes the cell ids, and stands for the policy's identity until the file exists (``grid.cells_of``).
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from importlib import resources
from pathlib import Path

from safemanip.util.values import brief, is_int

POLICY_NAME = re.compile(r"(?P<algorithm>[a-z0-9]+)-k(?P<k>\d+)-(?P<constraints>conservative|all)"
                         r"(?:-(?P<variant>selaware))?(?:-s(?P<train_seed>\d+))?$")
"""ALGORITHM-kK-CONSTRAINTS[-selaware][-sSEED]: what a policy file's name says it holds (``selaware``: trained with the
object selector in the loop, ``TrainConfig.scene_objects``; ``-sSEED``: one training seed of a method the table and
figures pool)."""
PLANNER_AVOID = ("all", "fragile")
"""The planner references a sweep can add (``bounds``, the spec key's historical name: they are not upper bounds): the
privileged planner keeping clear of every object, or of the fragile ones only (``control.planner.GridPlanner``)."""
SCENE_KEYS = {"layout": str, "gate_share": float, "exit_share": float}
"""What a sweep's ``scenes`` may set: the layout and the shares of gate and exit scenes (``scene.config.SceneConfig``)."""
FIGURES = ("fig4", "fig5", "fig6", "table")
SPEC_KEYS = ("name", "title", "description", "figure", "episodes", "seed", "judge", "policies", "n_objects", "semantics",
             "selectors", "constraints", "pairs", "k_equals_n_selector", "table", "scenes", "bounds", "folder", "shields")
"""Every key a sweep spec may hold; any other (a misspelt "seeds", a "layout" the grid does not take) is refused."""
REQUIRED_KEYS = ("name", "figure", "episodes", "policies", "n_objects", "judge")
POLICY_ENTRY_KEYS = ("path", "n_objects", "semantics")
CELL_FIELDS = ("policy", "algorithm", "k", "policy_constraints", "n_objects", "semantics", "selector", "constraints",
               "judge", "episodes", "seed", "vlm", "variant", "train_seed", "scenes", "shield")
"""What a table's rows and columns may name: the fields of every stored cell (``grid.RECORD_FIELDS``)."""
PLAIN_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9._-]{0,99}")
MAX_SPEC_BYTES = 1_000_000


class SweepError(ValueError):
    pass


@dataclass(frozen=True)
class SweepPolicy:
    """One entry of ``policies``: a policy file, with the object counts and semantics it is measured on when they are
    not the sweep's."""

    path: str
    """The policy file, named as ``POLICY_NAME`` says; a bare name or ``policies/FILE`` also finds the benchmark's
    policy of that name (``rl.checkpoint.resolve_policy``)."""
    n_objects: tuple[int, ...] | None = None
    """This policy's object counts N; None: the sweep's ``n_objects``."""
    semantics: tuple[str | None, ...] | None = None
    """This policy's scene semantics; None: the sweep's ``semantics``."""


@dataclass(frozen=True)
class SweepScenes:
    """The scene settings every cell of a sweep is measured in (``scenes``); a setting left None is the layout's own,
    and without any, each policy's own layout."""

    layout: str | None = None
    """The layout (``scene.placement.LAYOUTS``)."""
    gate_share: float | None = None
    """The share of gate (semantic-only) scenes, 0..1."""
    exit_share: float | None = None
    """The share of exit-probe scenes, 0..1."""

    def settings(self) -> dict:
        """The settings given, as ``EvalRequest``'s fields of the same names take them."""
        return {key: value for key in SCENE_KEYS if (value := getattr(self, key)) is not None}

    def label(self) -> str | None:
        """The settings in short, for cell ids and tables ('layout=exit,exit_share=1.0'; None: each policy's own)."""
        settings = self.settings()
        if not settings:
            return None
        return ",".join(f"{k}={float(v) if k != 'layout' else v}" for k, v in sorted(settings.items()))


@dataclass(frozen=True)
class TableLayout:
    """The pivot of a sweep's table (``table``): cell fields (``CELL_FIELDS``) as its rows and its columns."""

    rows: tuple[str, ...]
    """The fields whose values make a row, e.g. ('k',)."""
    columns: tuple[str, ...]
    """The fields whose values make a column, e.g. ('n_objects', 'selector')."""


@dataclass(frozen=True)
class SweepSpec:
    """A sweep spec, checked: every field of its type and range, every name one the registries know."""

    name: str
    """A plain file name: it names the table and the figure written into the output folder."""
    folder: str
    """The output folder under results/ (``folder``; default: the name)."""
    title: str
    """The table's heading and the figure's title (default: the name)."""
    description: str
    """A paragraph under the table's heading ('' for none)."""
    figure: str
    """What is drawn besides the table: 'fig4', 'fig5' or 'fig6' (the paper's figures), or 'table' (nothing)."""
    episodes: int
    """Episodes per cell and training seed."""
    seed: int
    """The episode seed block every cell runs (block B = seeds B x 100,000 + i)."""
    judge: str
    """Which constraints judge an episode: 'conservative' or 'ground-truth' (``harness.JUDGES``)."""
    policies: tuple[SweepPolicy, ...]
    """The policies measured, in the order their cells run."""
    n_objects: tuple[int, ...]
    """The object counts N of every policy without its own."""
    semantics: tuple[str | None, ...] | None
    """The scene semantics of every policy without its own (None in it: any classes); None: the spec gives none, so
    those policies meet any classes and the planner references only the policies' own semantics."""
    pairs: tuple[tuple[str, str], ...]
    """(object selector, constraint selector) of every cell: the spec's ``pairs``, else each of ``selectors`` with
    each of ``constraints`` (default ['conservative'])."""
    k_equals_n_selector: str | None
    """The object selector of a cell whose policy has as many slots as the scene has objects (k == N); None: that
    cell takes the pairs' selectors like any other."""
    planners: tuple[str, ...]
    """The planner references (the spec's ``bounds``): one row per entry of ``PLANNER_AVOID``, on the same scenes."""
    shields: tuple[str | None, ...]
    """The safety filters every policy cell is measured with (``safety.SHIELDS``; None: no filter); default (None,)."""
    scenes: SweepScenes
    """The scene settings of every cell."""
    table: TableLayout | None
    """The table's pivot; None: only the list of all cells."""

    @classmethod
    def from_json(cls, raw, where: str) -> SweepSpec:
        """The spec of a parsed JSON document; SweepError naming every problem at once if it is not one."""
        _validate(raw, where)
        selectors, constraints = raw.get("selectors", ()), raw.get("constraints", ["conservative"])
        table = raw.get("table")
        return cls(
            name=raw["name"], folder=raw.get("folder", raw["name"]), title=raw.get("title", raw["name"]),
            description=raw.get("description", ""), figure=raw["figure"], episodes=raw["episodes"],
            seed=raw.get("seed", 0), judge=raw["judge"], policies=tuple(_policy(e) for e in raw["policies"]),
            n_objects=tuple(raw["n_objects"]),
            semantics=tuple(raw["semantics"]) if "semantics" in raw else None,
            pairs=tuple(map(tuple, raw.get("pairs") or [(s, c) for s in selectors for c in constraints])),
            k_equals_n_selector=raw.get("k_equals_n_selector"), planners=tuple(raw.get("bounds", ())),
            shields=tuple(raw.get("shields") or (None,)), scenes=SweepScenes(**raw.get("scenes", {})),
            table=TableLayout(tuple(table["rows"]), tuple(table["columns"])) if table else None)

    def n_objects_of(self, policy: SweepPolicy) -> tuple[int, ...]:
        return policy.n_objects or self.n_objects

    def semantics_of(self, policy: SweepPolicy) -> tuple[str | None, ...]:
        return policy.semantics or self.semantics or (None,)


def _policy(entry) -> SweepPolicy:
    if isinstance(entry, str):
        return SweepPolicy(entry)
    semantics = entry.get("semantics")
    return SweepPolicy(entry["path"], tuple(entry["n_objects"]) if "n_objects" in entry else None,
                       tuple(semantics) if semantics is not None else None)


def available() -> list[str]:
    """The shipped sweeps' names."""
    folder = resources.files("safemanip.evaluation").joinpath("sweeps")
    return sorted(p.name[:-5] for p in folder.iterdir() if p.name.endswith(".json"))


def load_config(name_or_path: str) -> SweepSpec:
    """A shipped sweep by name (``fig5``) or a JSON file by path, checked (``_validate``) before anything is created."""
    from safemanip.util.files import JSONInputError, parse_json, read_json_file

    path = Path(name_or_path)
    try:
        if path.suffix == ".json" and path.exists():
            raw = read_json_file(path, f"sweep {name_or_path!r}", max_bytes=MAX_SPEC_BYTES)
        else:
            res = resources.files("safemanip.evaluation").joinpath("sweeps", f"{name_or_path}.json")
            if not PLAIN_NAME.fullmatch(str(name_or_path)) or not res.is_file():
                raise SweepError(f"no sweep named {str(name_or_path)[:100]!r}; shipped sweeps: {', '.join(available())} "
                                 f"(or pass the path of a sweep .json file)")
            raw = parse_json(res.read_text(), f"sweep {name_or_path!r}", max_bytes=MAX_SPEC_BYTES)
    except JSONInputError as err:
        raise SweepError(str(err)) from err
    except OSError as err:
        raise SweepError(f"cannot read sweep {name_or_path!r}: {err.strerror or err}") from err
    return SweepSpec.from_json(raw, name_or_path)


def _validate(cfg, where: str) -> None:
    """The sweep-spec schema: known keys only, each of its type and range, every name one the registries know.
    All problems in one message."""
    from safemanip.evaluation.harness import JUDGES, SEED_STRIDE, parse_semantics_checked
    from safemanip.evaluation.registry import CONSTRAINT_SELECTORS, OBJECT_SELECTORS
    from safemanip.scene.config import MAX_OBJECTS

    if not isinstance(cfg, dict):
        raise SweepError(f"sweep {where}: a sweep spec is a JSON object of {', '.join(REQUIRED_KEYS)}, ...; got "
                         f"{brief(cfg, 60)}")
    problems = [f"missing key {key!r}" for key in REQUIRED_KEYS if key not in cfg]
    unknown = [key for key in cfg if key not in SPEC_KEYS]
    if unknown:
        problems.append(f"unknown key(s) {', '.join(repr(k[:40]) for k in unknown[:5])}; a sweep spec takes "
                        f"{', '.join(SPEC_KEYS)}")
    if problems:
        raise SweepError(f"sweep {where}: " + "; ".join(problems))

    def need(ok: bool, message: str) -> bool:
        if not ok:
            problems.append(message)
        return ok

    def str_list(key: str, value, allowed=None, nullable: bool = False) -> bool:
        ok = isinstance(value, list) and value and all(isinstance(v, str) or (nullable and v is None) for v in value)
        if not need(bool(ok), f"{key} must be a non-empty list of {'names' if allowed else 'strings'}"
                              f"{' or null' if nullable else ''}, got {brief(value, 60)}"):
            return False
        for v in value:
            if allowed is not None and v not in allowed and not (nullable and v is None):
                problems.append(f"unknown {key[:-1] if key.endswith('s') else key} {brief(v, 60)}; choose from "
                                f"{', '.join(sorted(allowed))}")
        return True

    def counts(key: str, value) -> bool:
        return need(isinstance(value, list) and bool(value) and all(is_int(n) and 0 <= n <= MAX_OBJECTS for n in value),
                    f"{key} must be a non-empty list of object counts 0..{MAX_OBJECTS}, got {brief(value, 60)}")

    name = cfg["name"]
    need(isinstance(name, str) and PLAIN_NAME.fullmatch(name) is not None and ".." not in name,
         f"name must be a plain file name (letters, digits, '.', '_', '-'; no folders), got {brief(name, 60)}: it names "
         f"the table and figure written inside the output folder")
    if "folder" in cfg:
        folder = cfg["folder"]
        need(isinstance(folder, str) and all(PLAIN_NAME.fullmatch(part) and part != ".." for part in folder.split("/")),
             f"folder must be a relative path of plain names under results/ (e.g. 'exit/fig4'), got {brief(folder, 60)}")
    for key in ("title", "description"):
        if key in cfg:
            need(isinstance(cfg[key], str) and len(cfg[key]) <= 2000, f"{key} must be a string, got {brief(cfg[key], 60)}")
    need(cfg["figure"] in FIGURES, f"figure must be one of {FIGURES}, got {brief(cfg['figure'], 60)}")
    need(isinstance(cfg["judge"], str) and cfg["judge"] in JUDGES,
         f"judge must be one of {list(JUDGES)}, got {brief(cfg['judge'], 60)}")
    need(is_int(cfg["episodes"]) and 1 <= cfg["episodes"] <= SEED_STRIDE,
         f"episodes must be an integer 1..{SEED_STRIDE}, got {brief(cfg['episodes'], 60)}")
    if "seed" in cfg:
        most = 2**31 // SEED_STRIDE - 1
        need(is_int(cfg["seed"]) and 0 <= cfg["seed"] <= most,
             f"seed (the episode seed block) must be an integer 0..{most}, got {brief(cfg['seed'], 60)}")
    counts("n_objects", cfg["n_objects"])
    semantics = [None]
    if "semantics" in cfg and str_list("semantics", cfg["semantics"], nullable=True):
        semantics = list(cfg["semantics"])
    policies = cfg["policies"]
    if need(isinstance(policies, list) and bool(policies),
            f"policies must be a non-empty list of policy files, got {brief(policies, 60)}"):
        for entry in policies:
            if isinstance(entry, dict):
                if not need(set(entry) <= set(POLICY_ENTRY_KEYS) and isinstance(entry.get("path"), str),
                            f"policy entry {brief(entry, 60)} must be a path or {{'path', 'n_objects', 'semantics'}}"):
                    continue
                if "n_objects" in entry:
                    counts(f"n_objects of {entry['path']}", entry["n_objects"])
                if "semantics" in entry and str_list("semantics", entry["semantics"], nullable=True):
                    semantics += entry["semantics"]
                p = entry["path"]
            elif isinstance(entry, str):
                p = entry
            else:
                problems.append(f"policy entry {brief(entry, 60)} must be a path or {{'path', 'n_objects', 'semantics'}}")
                continue
            if not POLICY_NAME.fullmatch(Path(p).stem):
                problems.append(f"policy {p[:200]!r} is not named ALGORITHM-kK-CONSTRAINTS.safetensors "
                                f"(e.g. policies/rarl-k2-conservative-s0.safetensors)")
    if "selectors" in cfg:
        str_list("selectors", cfg["selectors"], OBJECT_SELECTORS)
    if "constraints" in cfg:
        str_list("constraints", cfg["constraints"], CONSTRAINT_SELECTORS)
    if "pairs" in cfg:
        pairs = cfg["pairs"]
        if need(isinstance(pairs, list) and bool(pairs) and all(isinstance(p, list) and len(p) == 2
                                                                 and all(isinstance(x, str) for x in p) for p in pairs),
                f"pairs must be a non-empty list of [selector, constraints] pairs, got {brief(pairs, 60)}"):
            for s, c in pairs:
                need(s in OBJECT_SELECTORS, f"unknown selector {brief(s, 60)}")
                need(c in CONSTRAINT_SELECTORS, f"unknown constraint selector {brief(c, 60)}")
    elif "selectors" not in cfg:
        problems.append("give 'selectors' (and optionally 'constraints') or 'pairs'")
    for sem in semantics:
        if isinstance(sem, str):
            try:
                parse_semantics_checked(sem)
            except ValueError as err:
                problems.append(str(err))
    if "scenes" in cfg:
        scenes = cfg["scenes"]
        if need(isinstance(scenes, dict) and set(scenes) <= set(SCENE_KEYS),
                f"scenes must be an object of {', '.join(SCENE_KEYS)}, got {brief(scenes, 60)}"):
            problems += _scene_problems(scenes)
    if "bounds" in cfg:
        str_list("bounds", cfg["bounds"], PLANNER_AVOID)
    if "shields" in cfg:
        from safemanip.safety import SHIELDS
        str_list("shields", cfg["shields"], SHIELDS, nullable=True)
    extra = cfg.get("k_equals_n_selector")
    if extra is not None:
        need(isinstance(extra, str) and extra in OBJECT_SELECTORS, f"unknown k_equals_n_selector {brief(extra, 60)}")
    if "table" in cfg:
        table = cfg["table"]
        if need(isinstance(table, dict) and set(table) == {"rows", "columns"},
                f"table must be {{'rows': [...], 'columns': [...]}}, got {brief(table, 60)}"):
            for part in ("rows", "columns"):
                names = table[part]
                if need(isinstance(names, list) and bool(names) and all(isinstance(n, str) for n in names)
                        and len(set(names)) == len(names), f"table {part} must be a non-empty list of distinct cell "
                                                           f"fields, got {brief(names, 60)}"):
                    bad = [n for n in names if n not in CELL_FIELDS]
                    need(not bad, f"table {part}: unknown cell field(s) {', '.join(brief(n, 60) for n in bad)}; choose "
                                  f"from {', '.join(CELL_FIELDS)}")
            if isinstance(table.get("rows"), list) and isinstance(table.get("columns"), list):
                both = sorted(set(map(str, table["rows"])) & set(map(str, table["columns"])))
                need(not both, f"table rows and columns both name {', '.join(both)}")
    if problems:
        raise SweepError(f"sweep {where}: " + "; ".join(problems))


def _scene_problems(scenes: dict) -> list[str]:
    from safemanip.scene.config import SceneConfig

    problems = []
    if "layout" in scenes and not isinstance(scenes["layout"], str):
        problems.append(f"scenes layout must be a layout's name, got {brief(scenes['layout'], 60)}")
    for key in ("gate_share", "exit_share"):
        value = scenes.get(key)
        if value is not None and (isinstance(value, bool) or not isinstance(value, (int, float))):
            problems.append(f"scenes {key} must be a number from 0 to 1, got {brief(value, 60)}")
    if not problems:
        try:
            SceneConfig(**scenes)
        except ValueError as err:
            problems.append(f"scenes: {err}")
    return problems
