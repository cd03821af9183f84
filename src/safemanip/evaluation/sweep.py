"""Experiment sweeps: a named grid of policies x N x selectors x semantics, run cell by cell, resumable,
rendered as the paper's figure and a markdown table from the stored results alone.

A sweep config is a JSON file (shipped ones live in ``evaluation/sweeps/``; a path to your own works
too)::

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
   "table": {"rows": ["k"], "columns": ["n_objects", "selector"]}}

``seed`` is the episode seed block (block B = seeds B x 100,000 + i). The shipped sweeps report on blocks reserved
for reported results (the benchmark's reporting blocks, ``bench/benchmark.json``, which checks that they agree with
these specs): no checkpoint, hyper-parameter or classifier is ever chosen on them (a run's final or best policy is
chosen on the benchmark's selection block, ``safemanip bench promote``).

Policy files are named ``{algorithm}-k{k}-{constraints}[-selaware][-s{seed}].safetensors``, so a cell knows its
k, how its policy was trained and its training seed before the file exists; the table and the figures pool the
training seeds of one method (``pool_seeds``). Cells with k > N are not applicable and left out; a cell whose
policy file is missing is reported as skipped, with the commands that train and bring in a benchmark policy of that
name.

Layout of the output folder (default ``results/FOLDER``, the spec's ``folder``, else ``results/NAME``)::

  cells/<cell id>.json         the cell's parameters and summary (written last: its presence = done)
  cells/<cell id>/summary.json the full summary; cells/<cell id>/episodes.csv the per-episode records (not
                               committed: the same command regenerates them)
  NAME.png, NAME.md            the figure and the table, rebuilt from cells/*.json by --render-only
"""

from __future__ import annotations

import contextlib
import json
import re
import sys
import textwrap
from dataclasses import asdict, dataclass
from importlib import resources
from pathlib import Path

from safemanip.evaluation.registry import display_name
from safemanip.util.files import OutputLock, atomic_write_text, check_output_dir
from safemanip.util.procs import Interrupted, stop_on_signals

POLICY_NAME = re.compile(r"(?P<algorithm>[a-z0-9]+)-k(?P<k>\d+)-(?P<constraints>conservative|all)"
                         r"(?:-(?P<variant>selaware))?(?:-s(?P<train_seed>\d+))?$")
"""ALGORITHM-kK-CONSTRAINTS[-selaware][-sSEED]: a cell knows its policy's k, how it was trained (``selaware``: with the
object selector in the loop, ``TrainConfig.scene_objects``) and its training seed from the file name alone."""
PLANNER_AVOID = ("all", "fragile")
"""The planner references a sweep can add (``bounds``, the spec key's historical name: they are not upper bounds): the
privileged planner keeping clear of every object, or of the fragile ones only (``control.planner.GridPlanner``)."""
SCENE_KEYS = {"layout": str, "gate_share": float, "exit_share": float}
"""What a sweep's ``scenes`` may set: the layout and the shares of gate and exit scenes (``scene.config.SceneConfig``)."""
FIGURES = ("fig4", "fig5", "fig6", "table")
DEFAULT_ROOT = Path("results")


class SweepError(ValueError):
    pass


@dataclass(frozen=True)
class Cell:
    policy: str
    algorithm: str
    k: int
    policy_constraints: str
    n_objects: int
    semantics: str | None
    selector: str
    constraints: str
    judge: str
    episodes: int
    seed: int
    vlm: str | None = None
    """Identity of the semantic backend for cells that query it (its example set and rule version), so a
    new classifier version makes those cells stale; None for cells that do not use it."""
    variant: str = ""
    """'selaware' for a policy trained with the object selector in the loop, '' for one trained the paper's way."""
    train_seed: int | None = None
    """The policy's training seed (from its name); the table and figure pool the seeds of one method."""
    scenes: str | None = None
    """The sweep's scene settings (``scenes``) in short, e.g. 'layout=exit,exit_share=1.0'; None: the policy's own."""
    shield: str | None = None
    """The safety filter around the policy (``safety.SHIELDS``), None for none (the sweep's ``shields``)."""

    @property
    def id(self) -> str:
        sem = "any" if not self.semantics else re.sub(r"[^a-z0-9]+", "-", self.semantics.lower()).strip("-")
        scenes = "" if not self.scenes else "__" + re.sub(r"[^a-z0-9.]+", "-", self.scenes.lower()).strip("-")
        shield = "" if not self.shield else f"__shield-{self.shield}"
        return (f"{Path(self.policy).stem}__N{self.n_objects}__{sem}__{self.selector}__{self.constraints}"
                f"__{self.judge}{scenes}{shield}")

    @property
    def group(self) -> str:
        """The method this cell measures, whatever its training seed: the policy's name without ``-sSEED``."""
        return re.sub(r"-s\d+$", "", Path(self.policy).stem)

    def train_command(self) -> str:
        """The commands that train this cell's policy as the benchmark's were and bring it in. The recipe, the budget
        and every setting's flags live in one place, ``bench/benchmark.json``; a name the benchmark does not list is
        refused by ``bench train --only`` with the names it does."""
        return f"safemanip bench train --only {Path(self.policy).stem} && safemanip bench promote"


# ------------------------------------------------------------------------------------------ configs
def available() -> list[str]:
    folder = resources.files("safemanip.evaluation").joinpath("sweeps")
    return sorted(p.name[:-5] for p in folder.iterdir() if p.name.endswith(".json"))


SPEC_KEYS = ("name", "title", "description", "figure", "episodes", "seed", "judge", "policies", "n_objects", "semantics",
             "selectors", "constraints", "pairs", "k_equals_n_selector", "table", "scenes", "bounds", "folder", "shields")
"""Every key a sweep spec may hold; any other (a misspelt "seeds", a "layout" the grid does not take) is refused."""
REQUIRED_KEYS = ("name", "figure", "episodes", "policies", "n_objects", "judge")
POLICY_ENTRY_KEYS = ("path", "n_objects", "semantics")
CELL_FIELDS = ("policy", "algorithm", "k", "policy_constraints", "n_objects", "semantics", "selector", "constraints",
               "judge", "episodes", "seed", "vlm", "variant", "train_seed", "scenes", "shield")
"""What a table's rows and columns may name (the fields of ``Cell``)."""
PLAIN_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9._-]{0,99}")
MAX_SPEC_BYTES = 1_000_000
MAX_RESULT_BYTES = 10_000_000


def load_config(name_or_path: str) -> dict:
    """A shipped sweep by name (``fig5``) or a JSON file by path; validated against the schema (``_validate``)
    before anything is created."""
    from safemanip.util.files import JSONInputError, parse_json, read_json_file

    path = Path(name_or_path)
    try:
        if path.suffix == ".json" and path.exists():
            cfg = read_json_file(path, f"sweep {name_or_path!r}", max_bytes=MAX_SPEC_BYTES)
        else:
            res = resources.files("safemanip.evaluation").joinpath("sweeps", f"{name_or_path}.json")
            if not PLAIN_NAME.fullmatch(str(name_or_path)) or not res.is_file():
                raise SweepError(f"no sweep named {str(name_or_path)[:100]!r}; shipped sweeps: {', '.join(available())} "
                                 f"(or pass the path of a sweep .json file)")
            cfg = parse_json(res.read_text(), f"sweep {name_or_path!r}", max_bytes=MAX_SPEC_BYTES)
    except JSONInputError as err:
        raise SweepError(str(err)) from err
    except OSError as err:
        raise SweepError(f"cannot read sweep {name_or_path!r}: {err.strerror or err}") from err
    _validate(cfg, name_or_path)
    return cfg


def _is_int(value) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


def _short(value) -> str:
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


def _validate(cfg, where: str) -> None:
    """The sweep-spec schema: known keys only, each of its type and range, every name one the registries know.
    All problems in one message."""
    from safemanip.evaluation.harness import JUDGES, SEED_STRIDE, parse_semantics_checked
    from safemanip.evaluation.registry import CONSTRAINT_SELECTORS, OBJECT_SELECTORS
    from safemanip.scene.config import MAX_OBJECTS

    if not isinstance(cfg, dict):
        raise SweepError(f"sweep {where}: a sweep spec is a JSON object of {', '.join(REQUIRED_KEYS)}, ...; got "
                         f"{_short(cfg)}")
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
                              f"{' or null' if nullable else ''}, got {_short(value)}"):
            return False
        for v in value:
            if allowed is not None and v not in allowed and not (nullable and v is None):
                problems.append(f"unknown {key[:-1] if key.endswith('s') else key} {_short(v)}; choose from "
                                f"{', '.join(sorted(allowed))}")
        return True

    def counts(key: str, value) -> bool:
        return need(isinstance(value, list) and bool(value) and all(_is_int(n) and 0 <= n <= MAX_OBJECTS for n in value),
                    f"{key} must be a non-empty list of object counts 0..{MAX_OBJECTS}, got {_short(value)}")

    name = cfg["name"]
    need(isinstance(name, str) and PLAIN_NAME.fullmatch(name) is not None and ".." not in name,
         f"name must be a plain file name (letters, digits, '.', '_', '-'; no folders), got {_short(name)}: it names "
         f"the table and figure written inside the output folder")
    if "folder" in cfg:
        folder = cfg["folder"]
        need(isinstance(folder, str) and all(PLAIN_NAME.fullmatch(part) and part != ".." for part in folder.split("/")),
             f"folder must be a relative path of plain names under results/ (e.g. 'exit/fig4'), got {_short(folder)}")
    for key in ("title", "description"):
        if key in cfg:
            need(isinstance(cfg[key], str) and len(cfg[key]) <= 2000, f"{key} must be a string, got {_short(cfg[key])}")
    need(cfg["figure"] in FIGURES, f"figure must be one of {FIGURES}, got {_short(cfg['figure'])}")
    need(isinstance(cfg["judge"], str) and cfg["judge"] in JUDGES,
         f"judge must be one of {list(JUDGES)}, got {_short(cfg['judge'])}")
    need(_is_int(cfg["episodes"]) and 1 <= cfg["episodes"] <= SEED_STRIDE,
         f"episodes must be an integer 1..{SEED_STRIDE}, got {_short(cfg['episodes'])}")
    if "seed" in cfg:
        most = 2**31 // SEED_STRIDE - 1
        need(_is_int(cfg["seed"]) and 0 <= cfg["seed"] <= most,
             f"seed (the episode seed block) must be an integer 0..{most}, got {_short(cfg['seed'])}")
    counts("n_objects", cfg["n_objects"])
    semantics = [None]
    if "semantics" in cfg and str_list("semantics", cfg["semantics"], nullable=True):
        semantics = list(cfg["semantics"])
    policies = cfg["policies"]
    if need(isinstance(policies, list) and bool(policies),
            f"policies must be a non-empty list of policy files, got {_short(policies)}"):
        for entry in policies:
            if isinstance(entry, dict):
                if not need(set(entry) <= set(POLICY_ENTRY_KEYS) and isinstance(entry.get("path"), str),
                            f"policy entry {_short(entry)} must be a path or {{'path', 'n_objects', 'semantics'}}"):
                    continue
                if "n_objects" in entry:
                    counts(f"n_objects of {entry['path']}", entry["n_objects"])
                if "semantics" in entry and str_list("semantics", entry["semantics"], nullable=True):
                    semantics += entry["semantics"]
                p = entry["path"]
            elif isinstance(entry, str):
                p = entry
            else:
                problems.append(f"policy entry {_short(entry)} must be a path or {{'path', 'n_objects', 'semantics'}}")
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
                f"pairs must be a non-empty list of [selector, constraints] pairs, got {_short(pairs)}"):
            for s, c in pairs:
                need(s in OBJECT_SELECTORS, f"unknown selector {_short(s)}")
                need(c in CONSTRAINT_SELECTORS, f"unknown constraint selector {_short(c)}")
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
                f"scenes must be an object of {', '.join(SCENE_KEYS)}, got {_short(scenes)}"):
            problems += _scene_problems(scenes)
    if "bounds" in cfg:
        str_list("bounds", cfg["bounds"], PLANNER_AVOID)
    if "shields" in cfg:
        from safemanip.safety import SHIELDS
        str_list("shields", cfg["shields"], SHIELDS, nullable=True)
    extra = cfg.get("k_equals_n_selector")
    if extra is not None:
        need(isinstance(extra, str) and extra in OBJECT_SELECTORS, f"unknown k_equals_n_selector {_short(extra)}")
    if "table" in cfg:
        table = cfg["table"]
        if need(isinstance(table, dict) and set(table) == {"rows", "columns"},
                f"table must be {{'rows': [...], 'columns': [...]}}, got {_short(table)}"):
            for part in ("rows", "columns"):
                names = table[part]
                if need(isinstance(names, list) and bool(names) and all(isinstance(n, str) for n in names)
                        and len(set(names)) == len(names), f"table {part} must be a non-empty list of distinct cell "
                                                           f"fields, got {_short(names)}"):
                    bad = [n for n in names if n not in CELL_FIELDS]
                    need(not bad, f"table {part}: unknown cell field(s) {', '.join(_short(n) for n in bad)}; choose "
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
        problems.append(f"scenes layout must be a layout's name, got {_short(scenes['layout'])}")
    for key in ("gate_share", "exit_share"):
        value = scenes.get(key)
        if value is not None and (isinstance(value, bool) or not isinstance(value, (int, float))):
            problems.append(f"scenes {key} must be a number from 0 to 1, got {_short(value)}")
    if not problems:
        try:
            SceneConfig(**scenes)
        except ValueError as err:
            problems.append(f"scenes: {err}")
    return problems


def scenes_label(scenes: dict | None) -> str | None:
    """A sweep's ``scenes`` in short, for cell ids and tables (None: each policy's own scenes)."""
    if not scenes:
        return None
    return ",".join(f"{k}={float(v) if k != 'layout' else v}" for k, v in sorted(scenes.items()))


def vlm_identity(vlm: dict | None) -> str:
    """What a cell that queries the semantic backend records as ``Cell.vlm``: the offline classifier's example
    set, or the openai backend's model, so results of one backend never count as done for another."""
    from safemanip.semantics.semantic_backend import DEFAULT_EXAMPLES

    vlm = vlm or {}
    if (vlm.get("vlm_backend") or "semantic") == "openai":
        return f"openai:{vlm.get('vlm_model') or 'gpt-4o'}"
    return f"semantic:{DEFAULT_EXAMPLES}"


def cells_of(cfg: dict, episodes: int | None = None, vlm: dict | None = None) -> list[Cell]:
    """The grid's applicable cells, in a stable order.

    Left out: k > N (the policy has more slots than objects) and semantics that do not describe N
    objects (so one config can pair each N with its own semantics). Duplicates (k == N cells that all
    map to ``k_equals_n_selector``) are merged.
    """
    from safemanip.evaluation.registry import USES_VLM
    from safemanip.scene.config import parse_semantics

    episodes = int(episodes or cfg["episodes"])
    scenes = scenes_label(cfg.get("scenes"))
    pairs = cfg.get("pairs") or [(s, c) for s in cfg["selectors"] for c in cfg.get("constraints", ["conservative"])]
    out: dict[str, Cell] = {}
    for entry in cfg["policies"]:
        own = entry if isinstance(entry, dict) else {}
        policy = own.get("path", entry)
        m = POLICY_NAME.fullmatch(Path(policy).stem)
        k = int(m["k"])
        for n in own.get("n_objects", cfg["n_objects"]):
            for sem in own.get("semantics", cfg.get("semantics", [None])):
                if sem is not None and len(parse_semantics(sem)) != n:
                    continue
                for selector, constraints in pairs:
                    if k > n:
                        continue
                    if k == n and cfg.get("k_equals_n_selector"):
                        selector = cfg["k_equals_n_selector"]
                    uses_vlm = selector in USES_VLM or constraints in USES_VLM
                    for shield in cfg.get("shields") or [None]:
                        cell = Cell(policy, m["algorithm"], k, m["constraints"], int(n), sem, selector, constraints,
                                    cfg["judge"], episodes, int(cfg.get("seed", 0)),
                                    vlm_identity(vlm) if uses_vlm else None, m["variant"] or "",
                                    None if m["train_seed"] is None else int(m["train_seed"]), scenes, shield)
                        out.setdefault(cell.id, cell)
    sizes = sorted({int(n) for e in cfg["policies"] for n in (e.get("n_objects", cfg["n_objects"]) if isinstance(e, dict)
                                                               else cfg["n_objects"])})
    own = [s for e in cfg["policies"] if isinstance(e, dict) for s in e.get("semantics", [])]
    all_semantics = list(dict.fromkeys(cfg.get("semantics", [] if own else [None]) + own))
    for avoid in cfg.get("bounds", []):  # the planner on the very same scenes (same seeds), once per scene setting
        for n in sizes:
            for sem in all_semantics:
                if sem is not None and len(parse_semantics(sem)) != n:
                    continue
                cell = Cell(f"planner-{avoid}", "planner", n, avoid, n, sem, "full", "ground-truth", cfg["judge"],
                            episodes, int(cfg.get("seed", 0)), scenes=scenes)
                out.setdefault(cell.id, cell)
    return list(out.values())


# ------------------------------------------------------------------------------------------ running
def _read_result(path: Path) -> dict | None:
    """A stored cell result (``{"cell": ..., "summary": ...}``) read with the bounded reader and its structure
    checked (the fields rendering reads are there, of their types); None if it cannot be used."""
    from safemanip.util.files import read_json_file

    try:
        result = read_json_file(path, max_bytes=MAX_RESULT_BYTES)
    except (OSError, ValueError):
        return None
    return result if _result_ok(result) else None


def _rate_ok(entry) -> bool:
    import math

    def num(v):
        return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)

    return (isinstance(entry, dict) and num(entry.get("rate")) and isinstance(entry.get("ci95"), list)
            and len(entry["ci95"]) == 2 and all(num(v) for v in entry["ci95"]))


def _result_ok(result) -> bool:
    from safemanip.evaluation.episode import CATEGORIES

    if not isinstance(result, dict) or not isinstance(result.get("cell"), dict) or not isinstance(result.get("summary"), dict):
        return False
    cell, summary = result["cell"], result["summary"]
    try:
        Cell(**{"vlm": None, **cell})
    except TypeError:
        return False
    types_ok = (all(isinstance(cell[k], str) for k in ("policy", "algorithm", "policy_constraints", "selector",
                                                         "constraints", "judge"))
                and all(_is_int(cell[k]) for k in ("k", "n_objects", "episodes", "seed"))
                and (cell["semantics"] is None or isinstance(cell["semantics"], str))
                and (cell.get("vlm") is None or isinstance(cell["vlm"], str)))
    categories = summary.get("categories")
    return bool(types_ok and _rate_ok(summary.get("success")) and _rate_ok(summary.get("safety_violation"))
                and isinstance(categories, dict) and all(_rate_ok(categories.get(c)) for c in CATEGORIES)
                and _is_int(summary.get("episodes")) and isinstance(summary.get("mean_length"), (int, float)))


def _done(path: Path, cell: Cell) -> bool:
    if not path.exists():
        return False
    stored = _read_result(path)
    if stored is None:
        return False  # a damaged result file is simply redone
    return _with_defaults(stored["cell"]) == asdict(cell)


def _with_defaults(cell: dict) -> dict:
    """A stored cell's fields, with the defaults of fields added since it was stored ('vlm', 'shield')."""
    return {"vlm": None, "shield": None, **cell}


def run_sweep(name: str, *, episodes: int | None = None, out: str | None = None, workers: int = 2,
              backend: str = "local", address: str | None = None, render_only: bool = False,
              progress: bool = True, log=print, vlm: dict | None = None, only: list[str] | None = None) -> dict:
    """Run the cells not done yet, then render. Returns {"ran", "done", "skipped", "failed", "interrupted",
    "figure", "table"}; "interrupted" is the signal number when SIGINT/SIGTERM stopped the run (the cells
    finished before it are kept, the one in progress is redone next time).

    ``vlm``: the semantic-backend options (``VLM_FIELDS`` of the harness: backend, model, cache, timeout,
    budgets, breaker), applied to the cells that query the backend. The output folder and these options are
    checked, and the folder locked, before any cell runs.

    ``only``: shell-style patterns (``fnmatch``) over cell ids; only the cells that match one are run, e.g.
    ``["*-s0__*"]`` for training seed 0's cells while the other seeds' policies are still training. The figure
    and table are still drawn from every stored cell of the spec."""
    from types import SimpleNamespace

    from safemanip.evaluation.harness import VLM_FIELDS, vlm_option_problems

    cfg = load_config(name)
    root = Path(out) if out else DEFAULT_ROOT / cfg.get("folder", cfg["name"])
    vlm = {k: v for k, v in (vlm or {}).items() if v}
    unknown = sorted(set(vlm) - set(VLM_FIELDS))
    if unknown:
        raise SweepError(f"unknown semantic-backend option(s) {unknown}; known: {', '.join(VLM_FIELDS)}")
    cells = cells_of(cfg, episodes, vlm)
    if only and render_only:
        raise SweepError("--only picks cells to run and --render-only runs none: drop one of them")
    to_run = select_cells(cells, only, cfg["name"]) if only else cells
    if vlm and not render_only:
        if not any(c.vlm for c in to_run):
            raise SweepError(f"sweep {cfg['name']} has no cell that queries the semantic backend (selector "
                             f"dynamic-vlm or constraints vlm): drop the --vlm-* options")
        problems = vlm_option_problems(SimpleNamespace(**{f: vlm.get(f) for f in VLM_FIELDS}), uses_vlm=True)
        if problems:
            raise SweepError("; ".join(problems))
    problems = check_output_dir(root)
    if backend == "ray" and not render_only:
        from safemanip.evaluation.harness import ray_address_problems

        problems += ray_address_problems(address)
    if problems:
        raise SweepError("; ".join(problems))
    if not render_only:
        check_policies(to_run, cfg["name"])
    status = {"ran": [], "done": [], "skipped": [], "failed": [], "interrupted": None}
    with OutputLock(root):
        if not render_only:
            try:
                with stop_on_signals(), _ray_session(backend, address, workers):
                    _run_cells(cfg, to_run, root, status, workers, backend, address, progress, log, vlm)
            except Interrupted as stop:
                status["interrupted"] = stop.signum
            if status["interrupted"]:
                log(f"interrupted: {len(status['ran'])} cell(s) finished in this run are kept; run the same command "
                    f"to continue")
        # only this spec's cells: sweeps may share a folder (fig6 draws N = 6 from fig5's cells at N = 3..6)
        wanted = {c.id for c in cells}
        results = [r for r in load_results(root) if Cell(**r["cell"]).id in wanted]
        status["figure"], status["table"] = render(cfg, results, root)
    log(f"wrote {status['table']}" + (f" and {status['figure']}" if status["figure"] else ""))
    if status["skipped"]:
        log(f"{len(status['skipped'])} cell(s) skipped for missing policies (train commands above)")
    return status


def select_cells(cells: list[Cell], patterns: list[str], name: str) -> list[Cell]:
    """The cells whose id matches one of ``patterns`` (shell-style, ``fnmatch``), in the sweep's order. A pattern
    that matches no cell is an error that shows what ids look like: a typo must not run nothing silently."""
    from fnmatch import fnmatchcase

    unmatched = [p for p in patterns if not any(fnmatchcase(c.id, p) for c in cells)]
    if unmatched:
        example = cells[0].id if cells else "(the sweep has no cells)"
        raise SweepError(f"--only {' '.join(unmatched)} matches no cell of sweep {name}; cell ids look like "
                         f"{example} (use * and ?, e.g. --only '*-s0__*' for training seed 0)")
    return [c for c in cells if any(fnmatchcase(c.id, p) for p in patterns)]


@contextlib.contextmanager
def _ray_session(backend: str, address: str | None, workers: int):
    """One Ray connection for the whole sweep (starting Ray per cell would cost seconds each time)."""
    if backend != "ray":
        yield
        return
    import ray

    if ray.is_initialized():
        yield
        return
    from safemanip.util.procs import init_ray

    init_ray(address, workers)
    try:
        yield
    finally:
        ray.shutdown()


def _run_cells(cfg, cells, root, status, workers, backend, address, progress, log, vlm: dict) -> None:
    from safemanip.evaluation.harness import EvalRequest
    from safemanip.rl.checkpoint import resolve_policy

    cells_dir = root / "cells"
    log(f"sweep {cfg['name']}: {len(cells)} cells, {cells[0].episodes if cells else 0} episodes each -> {root}")
    for i, cell in enumerate(cells, 1):
        result_path = cells_dir / f"{cell.id}.json"
        tag = f"[{i}/{len(cells)}] {cell.id}"
        if _done(result_path, cell):
            status["done"].append(cell.id)
            log(f"{tag}: done already")
            continue
        # a relative path such as policies/rarl-k2-conservative-s0.safetensors falls back to the shipped policy
        # of that name, so a shipped sweep runs from any working folder
        scenes = dict(cfg.get("scenes") or {})
        if cell.algorithm == "planner":
            req = EvalRequest(policy=None, planner=cell.policy_constraints, n_objects=cell.n_objects,
                              semantics=cell.semantics, judge=cell.judge, episodes=cell.episodes, seed_block=cell.seed,
                              workers=workers, backend=backend, address=address, out=str(cells_dir / cell.id),
                              progress=progress, **scenes)
            if not _evaluate_cell(req, cell, result_path, status, tag, log):
                return
            continue
        policy = Path(cell.policy) if Path(cell.policy).is_absolute() else resolve_policy(cell.policy)
        if not policy.exists():
            status["skipped"].append({"cell": cell.id, "policy": cell.policy, "train": cell.train_command()})
            log(f"{tag}: skipped, no policy file {cell.policy}; make it with:\n    {cell.train_command()}")
            continue
        req = EvalRequest(policy=str(policy), n_objects=cell.n_objects, semantics=cell.semantics,
                          selector=cell.selector, constraint_selector=cell.constraints, judge=cell.judge,
                          episodes=cell.episodes, seed_block=cell.seed, workers=workers, backend=backend,
                          address=address, out=str(cells_dir / cell.id), progress=progress, shield=cell.shield,
                          **scenes, **(vlm if cell.vlm else {}))
        # the file's identity (k, constraints, ...) was checked against its name before any cell ran (check_policies)
        if not _evaluate_cell(req, cell, result_path, status, tag, log):
            return


def _evaluate_cell(req, cell: Cell, result_path: Path, status: dict, tag: str, log) -> bool:
    """Run one cell and store its result; False when a signal stopped it (the sweep stops too)."""
    from safemanip.evaluation.harness import evaluate

    try:
        report = evaluate(req)
    except ValueError as err:  # an evaluation that cannot run: report, go on with the rest
        status["failed"].append({"cell": cell.id, "error": str(err)})
        log(f"{tag}: failed: {err}")
        return True
    if report["summary"].get("interrupted"):  # a partial cell is not a result: redo it next time
        status["interrupted"] = report["summary"]["interrupted"]["signum"]
        return False
    if report["summary"].get("failed"):  # a worker died: the cell is incomplete, redone next time
        from safemanip.evaluation.harness import failure_line

        error = failure_line(report["summary"], req.out)
        status["failed"].append({"cell": cell.id, "error": error})
        log(f"{tag}: failed: {error}")
        return True
    summary = {k: v for k, v in report["summary"].items() if k not in ("request", "policy_meta")}
    atomic_write_text(result_path, json.dumps({"cell": asdict(cell), "summary": summary}, indent=1))
    status["ran"].append(cell.id)
    s = summary["success"]
    log(f"{tag}: success {100 * s['rate']:.1f}% [{100 * s['ci95'][0]:.1f}, {100 * s['ci95'][1]:.1f}]")
    return True


def _check_policy_name(cell: Cell) -> str | None:
    """What the policy file's metadata says that its name (and so the cell id) contradicts: k, constraints,
    algorithm, how it was trained (selection-aware: ``train_config.scene_objects`` set) and the training seed; None if
    they agree. Fields the metadata does not hold are not checked; a file that cannot be read is left to its cell,
    which reports it as failed."""
    from safemanip.rl.checkpoint import load_policy

    try:
        _, meta = load_policy(cell.policy)  # resolves shipped policies by file name
    except (OSError, ValueError):
        return None
    train = meta.get("train_config") if isinstance(meta.get("train_config"), dict) else {}
    variant = None if "scene_objects" not in train else "selaware" if train["scene_objects"] else "the paper's way"
    found = {"k": meta.get("k"), "constraints": meta.get("constraints"), "algorithm": meta.get("algorithm"),
             "variant": variant, "seed": train.get("seed") if cell.train_seed is not None else None}
    named = {"k": cell.k, "constraints": cell.policy_constraints, "algorithm": cell.algorithm,
             "variant": "selaware" if cell.variant == "selaware" else "the paper's way", "seed": cell.train_seed}
    differ = [f for f in named if found[f] is not None and found[f] != named[f]]
    if not differ:
        return None
    return (f"{cell.policy}: its metadata says {', '.join(f'{f}={found[f]}' for f in differ)}, its name "
            f"{', '.join(f'{f}={named[f]}' for f in differ)}")


def check_policies(cells: list[Cell], name: str) -> None:
    """Refuse the sweep (SweepError, one line) if any existing policy file of ``cells`` holds a policy other than
    its name says: the cell id is made from the name, so such a file would store its results under another policy's
    cells. Checked for every policy before any cell runs, rather than failing cell by cell and drawing a table."""
    from safemanip.rl.checkpoint import resolve_policy

    problems, seen = [], set()
    for cell in cells:
        if cell.algorithm == "planner" or cell.policy in seen:
            continue
        seen.add(cell.policy)
        path = Path(cell.policy) if Path(cell.policy).is_absolute() else resolve_policy(cell.policy)
        if path.exists():  # a missing file is reported as skipped, with the command that trains it
            problem = _check_policy_name(cell)
            if problem:
                problems.append(problem)
    if problems:
        raise SweepError(f"sweep {name}: no cell run: " + "; ".join(problems) + ": rename the file(s) or fix the sweep")


def load_results(root: Path) -> list[dict]:
    """The stored cell results; a file that is not one (unreadable, too large or deep, wrong structure) is left out
    with a warning, and its cell is redone by the next run."""
    out = []
    for path in sorted((Path(root) / "cells").glob("*.json")):
        result = _read_result(path)
        if result is None:
            print(f"warning: ignoring unreadable result {path} (its cell is redone by the next run)", file=sys.stderr)
            continue
        out.append({**result, "cell": _with_defaults(result["cell"])})
    return out


# ------------------------------------------------------------------------------------------ rendering
def _pooled_entry(entries: list[dict], counts: list[int], totals: list[int]) -> dict:
    """Rate entries of one method's training seeds as one: the mean rate, the Wilson interval of all their episodes
    together (``ci95``), the 95 % interval with training seeds as the unit (``ci95_seeds``: a two-stage cluster
    bootstrap, ``stats.seed_bootstrap_interval``), the lowest and highest seed (``spread``) and each seed's count
    and episodes (``seed_counts``, ``seed_totals``: what ``bench/verdict.py`` bootstraps a difference from). The
    pooled interval treats 3 x 1000 episodes as independent and understates the uncertainty when seeds disagree."""
    from safemanip.evaluation.stats import seed_bootstrap_interval, wilson_interval

    rates = [e["rate"] for e in entries]
    counts, totals = [int(c) for c in counts], [int(n) for n in totals]
    measured = [(c, n) for c, n in zip(counts, totals) if n > 0]  # a scene kind a seed never met has no rate
    return {"count": int(sum(counts)), "rate": float(sum(rates) / len(rates)),
            "ci95": list(wilson_interval(int(sum(counts)), int(sum(totals)))),
            "ci95_seeds": list(seed_bootstrap_interval(*zip(*measured))) if measured else [0.0, 1.0],
            "spread": [min(rates), max(rates)],
            "seeds": len(entries), "seed_counts": counts, "seed_totals": totals}


def pool_seeds(results: list[dict]) -> list[dict]:
    """The results with the cells of one method (all fields equal but the policy's training seed) pooled into one,
    whose rates are the mean over the seeds, with the Wilson interval of all their episodes and each rate's
    ``spread`` (lowest, highest seed). Cells of a policy without a seed in its name stay as they are."""
    groups: dict[tuple, list[dict]] = {}
    for r in results:
        c = r["cell"]
        if c.get("train_seed") is None:
            groups[("single", c["policy"], tuple(sorted(map(str, c.items()))))] = [r]
            continue
        rest = tuple((k, str(v)) for k, v in sorted(c.items()) if k not in ("policy", "train_seed"))
        groups.setdefault((re.sub(r"-s\d+$", "", Path(c["policy"]).stem),) + rest, []).append(r)
    out = []
    for members in groups.values():
        first = members[0]
        if first["cell"].get("train_seed") is None:
            out.append(first)
            continue
        cell = {**first["cell"], "policy": re.sub(r"-s\d+$", "", Path(first["cell"]["policy"]).stem),
                "train_seed": None}
        sums = [m["summary"] for m in members]
        totals = [s["episodes"] for s in sums]

        def pooled(get) -> dict:
            entries = [get(s) for s in sums]
            return _pooled_entry(entries, [e["count"] for e in entries], totals)

        summary = {"episodes": int(sum(totals)), "success": pooled(lambda s: s["success"]),
                   "safety_violation": pooled(lambda s: s["safety_violation"]),
                   "categories": {c: pooled(lambda s, c=c: s["categories"][c]) for c in sums[0]["categories"]},
                   "mean_length": float(sum(s["mean_length"] for s in sums) / len(sums)),
                   "seeds": sorted(m["cell"]["train_seed"] for m in members)}
        kinds = sorted({k for s in sums for k in s.get("by_scene_kind", {})})
        if kinds and all(set(s.get("by_scene_kind", {})) == set(kinds) for s in sums):
            summary["by_scene_kind"] = {
                k: {"episodes": int(sum(s["by_scene_kind"][k]["episodes"] for s in sums)),
                    **{m: _pooled_entry([s["by_scene_kind"][k][m] for s in sums],
                                        [s["by_scene_kind"][k][m]["count"] for s in sums],
                                        [s["by_scene_kind"][k]["episodes"] for s in sums]) for m in ("success", "top_box")}}
                for k in kinds}
        agreements = [s.get("reference_agreement") for s in sums]
        if all(agreements):  # the selections' agreement with the reference oracle, over every seed's queries
            queries, agreed = sum(a["queries"] for a in agreements), sum(a["agreed"] for a in agreements)
            summary["reference_agreement"] = {"queries": queries, "agreed": agreed, "rate": agreed / queries}
        out.append({"cell": cell, "summary": summary})
    return out


def _pct(summary: dict, key: str) -> float:
    if key in ("success", "safety_violation"):
        return 100 * summary[key]["rate"]
    return 100 * summary["categories"][key]["rate"]


def _fmt_entry(entry: dict) -> str:
    """'69.2 [67.5, 70.8]' for one policy; pooled over training seeds, '69.2 [67.5, 70.8] {66.4, 71.9} (67-72)': the
    mean, the Wilson interval of all episodes pooled, the seed-level (cluster bootstrap) interval in braces, and the
    lowest and highest seed."""
    lo, hi = entry["ci95"]
    text = f"{100 * entry['rate']:.1f} [{100 * lo:.1f}, {100 * hi:.1f}]"
    if entry.get("seeds", 1) > 1:  # pooled over training seeds: seeds as the unit, and their spread
        if "ci95_seeds" in entry:
            text += f" {{{100 * entry['ci95_seeds'][0]:.1f}, {100 * entry['ci95_seeds'][1]:.1f}}}"
        text += f" ({100 * entry['spread'][0]:.0f}-{100 * entry['spread'][1]:.0f})"
    return text


def _fmt(summary: dict, key: str = "success") -> str:
    return _fmt_entry(summary[key] if key in ("success", "safety_violation") else summary["categories"][key])


def _agreement(summary: dict) -> str:
    """How often the cell's selection equalled the reference oracle's (nearest by true criticality), in %; empty for
    cells measured before it was recorded and for the planner."""
    agreement = summary.get("reference_agreement")
    return f"{100 * agreement['rate']:.1f}" if agreement else ""


def _interventions(cell: dict, summary: dict) -> str:
    """The safety filter's name and the share of steps it overrode the policy, in %; empty without a filter."""
    if not cell.get("shield"):
        return ""
    rate = (summary.get("shield_interventions") or {}).get("rate", 0.0)
    return f"{cell['shield']} {100 * rate:.1f}"


def _kinds(summary: dict) -> str:
    """Success per scene kind, where a cell mixes kinds ('open 99.0 / exit 71.5')."""
    kinds = summary.get("by_scene_kind") or {}
    if len(kinds) < 2:
        return ""
    return " / ".join(f"{k} {100 * v['success']['rate']:.1f}" for k, v in kinds.items())


def _pairs(cfg: dict) -> list:
    return [tuple(p) for p in cfg.get("pairs") or
            [(s, c) for s in cfg["selectors"] for c in cfg.get("constraints", ["conservative"])]]


def _orderer(cfg: dict):
    """Sort key for tuples of cell values named ``keys``: the order the config lists them in, numbers by value."""
    listed = {"selector": [s for s, _ in _pairs(cfg)] + [cfg.get("k_equals_n_selector")],
              "constraints": [c for _, c in _pairs(cfg)],
              "semantics": ["any" if s is None else s for s in cfg.get("semantics", [None])]
              + [s for e in cfg["policies"] if isinstance(e, dict) for s in e.get("semantics", [])],
              "shield": [f"filter: {s}" if s else "no filter" for s in cfg.get("shields") or [None]]}

    def one(name, value):
        if isinstance(value, (int, float)):
            return (0, value, "")
        seq = listed.get(name, [])
        return (1, seq.index(value) if value in seq else len(seq), str(value))

    return lambda keys, values: tuple(one(k, v) for k, v in zip(keys, values))


def markdown_table(cfg: dict, results: list[dict]) -> str:
    lines = [f"# {cfg.get('title', cfg['name'])}", ""]
    if cfg.get("description"):
        lines += [cfg["description"], ""]
    if not results:
        return "\n".join(lines + ["No results yet: run `safemanip sweep " + cfg["name"] + "`."]) + "\n"
    every = results
    bounds = [r for r in results if r["cell"]["algorithm"] == "planner"]
    results = pool_seeds([r for r in results if r["cell"]["algorithm"] != "planner"])
    pivot = cfg.get("table")
    if pivot and results:
        rows, cols = list(pivot["rows"]), list(pivot["columns"])
        order = _orderer(cfg)

        def value(cell: dict, k: str):
            if k == "policy":
                return Path(cell["policy"]).stem
            if k == "shield":
                return f"filter: {cell[k]}" if cell.get(k) else "no filter"
            return cell[k] if cell[k] is not None else "any"

        key = lambda r, ks: tuple(value(r["cell"], k) for k in ks)  # noqa: E731
        full = cfg.get("k_equals_n_selector")
        # a k == N cell stands for every selector column of its N (the paper plots it on both curves)
        expanded = []
        for r in results:
            if full and r["cell"]["selector"] == full and "selector" in cols:
                for sel in dict.fromkeys(s for s, _ in _pairs(cfg)):
                    expanded.append(({**r["cell"], "selector": sel}, r["summary"], " (k = N)"))
            else:
                expanded.append((r["cell"], r["summary"], ""))
        if "policy" not in rows and "policy" not in cols:
            # two policies that share the rows' and columns' values (two k = 2 policies of different algorithms in a
            # table by k) are both shown, one row each, not one over the other
            seen: dict = {}
            for c, _, _ in expanded:
                if seen.setdefault((key({"cell": c}, rows), key({"cell": c}, cols)), c["policy"]) != c["policy"]:
                    rows.append("policy")
                    break
        cells = {(key({"cell": c}, rows), key({"cell": c}, cols)): (s, mark) for c, s, mark in expanded}
        row_keys = sorted({rk for rk, _ in cells}, key=lambda t: order(rows, t))
        col_keys = sorted({ck for _, ck in cells}, key=lambda t: order(cols, t))
        lines.append("Success rate (%), 95% Wilson interval [in brackets]" +
                     ("; over several training seeds: their mean, the Wilson interval of all their episodes pooled, "
                      "the 95% interval with training seeds as the unit {in braces: a two-stage cluster bootstrap, "
                      "seeds then their episodes}, and the lowest and highest seed (in parentheses)"
                      if any("seeds" in s for _, s, _ in expanded) else "") +
                     ("; (k = N): the full-state policy, the same cell in every selector column" if full else "") +
                     ("; the planner rows: a reference, not an upper bound: the privileged, hand-made planner, which "
                      "knows the whole scene, on the same scenes (a learned policy can beat it)" if bounds else "")
                     + ":")
        lines.append("")
        backend = next((r["cell"].get("vlm") for r in every if r["cell"].get("vlm")), None)

        def show(names: list[str], values: tuple) -> str:
            parts = [display_name(str(v), backend) if n in ("selector", "constraints") else str(v)
                     for n, v in zip(names, values)]
            if "selector" in names and "constraints" in names:  # "object selector + constraint selector"
                i = names.index("selector")
                parts[i:i + 2] = [f"{parts[i]} + {parts[i + 1]}"]
            return " ".join(parts)

        lines.append("| " + " / ".join(rows) + " | " + " | ".join(show(cols, c) for c in col_keys) + " |")
        lines.append("|" + "---|" * (len(col_keys) + 1))
        for rk in row_keys:
            vals = [(_fmt(cells[(rk, ck)][0]) + cells[(rk, ck)][1]) if (rk, ck) in cells else "n/a" for ck in col_keys]
            lines.append("| " + " / ".join(show([n], (v,)) for n, v in zip(rows, rk)) + " | " + " | ".join(vals) + " |")
        shared = [i for i, name in enumerate(cols) if name in ("n_objects", "semantics", "scenes", "judge")]
        for avoid in PLANNER_AVOID:  # a reference matches a column by the scenes alone (N, semantics, settings)
            mine = [r for r in bounds if r["cell"]["policy_constraints"] == avoid]
            if not mine:
                continue
            vals = []
            for ck in col_keys:
                match = [r for r in mine if all(str(value(r["cell"], cols[i])) == str(ck[i]) for i in shared)]
                vals.append(_fmt(match[0]["summary"]) if match else "n/a")
            what = "every object" if avoid == "all" else "the fragile objects"
            lines.append(f"| planner, avoiding {what} (reference) | " + " | ".join(vals) + " |")
        lines.append("")
    lines.append("All cells, each training seed on its own (rates in %, 95% Wilson interval for success; coll. = collision "
                 "with a fragile object the policy saw (selected) or did not see (unselected); selection = reference: "
                 "share of selection queries at which the selected objects were the k nearest by true criticality; "
                 "filter overrides: the safety filter and the share of steps it overrode the policy):")
    lines.append("")
    head = ["policy", "k", "N", "semantics", "selector", "constraints", "episodes", "success", "violation",
            "top box / OOB", "coll. unselected", "coll. selected", "soft", "timeout", "unstable", "mean length",
            "selection = reference", "filter overrides", "success by scene kind"]
    lines.append("| " + " | ".join(head) + " |")
    lines.append("|" + "---|" * len(head))
    order = lambda r: (r["cell"]["k"], r["cell"]["n_objects"], str(r["cell"]["semantics"]), r["cell"]["selector"],  # noqa: E731
                       r["cell"]["constraints"], r["cell"]["policy"])
    for r in sorted(every, key=order):
        c, s = r["cell"], r["summary"]
        lines.append("| " + " | ".join([
            Path(c["policy"]).stem, str(c["k"]), str(c["n_objects"]), c["semantics"] or "any",
            display_name(c["selector"], c.get("vlm")), display_name(c["constraints"], c.get("vlm")), str(s["episodes"]), _fmt(s), f"{_pct(s, 'safety_violation'):.1f}",
            f"{_pct(s, 'top_box') + _pct(s, 'out_of_workspace'):.1f}", f"{_pct(s, 'collision_unselected'):.1f}",
            f"{_pct(s, 'collision_selected'):.1f}", f"{_pct(s, 'soft_contact'):.1f}", f"{_pct(s, 'timeout'):.1f}",
            f"{_pct(s, 'unstable'):.1f}", f"{s['mean_length']:.1f}", _agreement(s), _interventions(c, s),
            _kinds(s)]) + " |")
    return "\n".join(lines) + "\n"


def _error_bars(entries: list[dict]) -> list[list[float]]:
    """matplotlib's (below, above) error bars in %: an entry pooled over training seeds spans its lowest and highest
    seed, a single one its 95 % interval; clamped at 0, as an interval's end may round to the other side of 0 or 1."""
    span = [e["spread"] if e.get("seeds", 1) > 1 else e["ci95"] for e in entries]
    return [[max(0.0, 100 * (e["rate"] - lo)) for e, (lo, _) in zip(entries, span)],
            [max(0.0, 100 * (hi - e["rate"])) for e, (_, hi) in zip(entries, span)]]


def _plot_bound(ax, bounds: list[dict], avoid: str = "all") -> None:
    """The planner's success on the same scenes, against N: the reference a figure's policies are read against (not
    an upper bound: a privileged, hand-made planner that knows the whole scene, which a learned policy can beat)."""
    pts = sorted((r["cell"]["n_objects"], 100 * r["summary"]["success"]["rate"]) for r in bounds
                 if r["cell"]["policy_constraints"] == avoid)
    if pts:
        ax.plot(*zip(*pts), color="black", linestyle="--", marker="x", linewidth=1,
                label=f"planner reference (avoiding {'everything' if avoid == 'all' else 'fragile objects'})")


def _plot_fig5(cfg: dict, results: list[dict], path: Path, bounds: list[dict] = ()) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    panels = [s for s in ("static-knn", "dynamic-knn") if any(r["cell"]["selector"] == s for r in results)]
    panels = panels or sorted({r["cell"]["selector"] for r in results if r["cell"]["k"] != r["cell"]["n_objects"]})
    full = [r for r in results if r["cell"]["k"] == r["cell"]["n_objects"]]
    ks = sorted({r["cell"]["k"] for r in results})
    colours = {k: plt.cm.viridis(i / max(1, len(ks) - 1)) for i, k in enumerate(ks)}
    lines = []
    for k in ks:
        policies = sorted({r["cell"]["policy"] for r in results if r["cell"]["k"] == k})
        for j, policy in enumerate(policies):
            lines.append((k, policy, ("-", "--", ":", "-.")[j % 4],
                          f"k = {k}" + (f" ({Path(policy).stem})" if len(policies) > 1 else "")))
    fig, axes = plt.subplots(1, max(1, len(panels)), figsize=(5 * max(1, len(panels)), 4), sharey=True, squeeze=False)
    for ax, sel in zip(axes[0], panels or ["full"]):
        for k, policy, style, label in lines:  # one line per policy: two policies of one k are both drawn
            pts = sorted(((r["cell"]["n_objects"], r["summary"]) for r in results
                          if r["cell"]["k"] == k and r["cell"]["policy"] == policy
                          and (r["cell"]["selector"] == sel or r in full)), key=lambda p: p[0])
            if not pts:
                continue
            xs = [n for n, _ in pts]
            ys = [100 * s["success"]["rate"] for _, s in pts]
            err = _error_bars([s["success"] for _, s in pts])
            ax.errorbar(xs, ys, yerr=err, marker="o", capsize=3, color=colours[k], linestyle=style, label=label)
        fx = [(r["cell"]["n_objects"], 100 * r["summary"]["success"]["rate"]) for r in full]
        if fx:
            ax.scatter(*zip(*fx), marker="*", s=160, color="black", zorder=5, label="k = N (full state)")
        _plot_bound(ax, list(bounds))
        ax.set_title(sel)
        ax.set_xlabel("objects in the scene N")
        ax.set_xticks(sorted({r["cell"]["n_objects"] for r in results}))
        ax.grid(alpha=0.3)
    axes[0][0].set_ylabel("success rate (%)")
    # beside the panels, not on them: with nine lines the legend covered the dynamic-kNN curves at N = 3..4
    axes[0][-1].legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.02, 1.0))
    fig.suptitle(cfg.get("title", cfg["name"]), fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=120, bbox_inches="tight")
    plt.close(fig)


def _plot_fig4(cfg: dict, results: list[dict], path: Path, bounds: list[dict] = ()) -> None:
    """Paper Fig. 4: per algorithm, success (solid) and top-box violations (dotted) against N, with 95 % intervals."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    algorithms = sorted({r["cell"]["algorithm"] for r in results})
    colours = {a: c for a, c in zip(algorithms, ("tab:blue", "tab:red", "tab:green", "tab:purple"))}
    labels = {"rarl": "RARL", "vanilla": "Vanilla-RL"}
    fig, ax = plt.subplots(figsize=(6, 4))
    for algorithm in algorithms:
        pts = sorted(((r["cell"]["n_objects"], r["summary"]) for r in results if r["cell"]["algorithm"] == algorithm),
                     key=lambda p: p[0])
        xs = [n for n, _ in pts]
        for key, style, what in (("success", "-", "success"), ("top_box", ":", "top-box violation")):
            entries = [s[key] if key == "success" else s["categories"][key] for _, s in pts]
            ys = [100 * e["rate"] for e in entries]
            ax.errorbar(xs, ys, yerr=_error_bars(entries), linestyle=style, marker="o", capsize=3, color=colours[algorithm],
                        label=f"{labels.get(algorithm, algorithm)}: {what}")
    _plot_bound(ax, list(bounds))
    ax.set_xlabel("objects in the scene N (policy k = N)")
    ax.set_ylabel("episodes (%)")
    ax.set_ylim(-2, 102)
    ax.set_xticks(sorted({r["cell"]["n_objects"] for r in results}))
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    ax.set_title(textwrap.fill(cfg.get("title", cfg["name"]), 70), fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


FIG6_STACK = (("success", ("success",), "tab:green"), ("top box / OOB", ("top_box", "out_of_workspace"), "tab:orange"),
              ("collision with unselected", ("collision_unselected",), "tab:red"),
              ("collision with selected", ("collision_selected",), "tab:purple"),
              ("other (soft, timeout, unstable)", ("soft_contact", "timeout", "unstable"), "tab:gray"))


def _plot_fig6(cfg: dict, results: list[dict], path: Path, bounds: list[dict] = ()) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    order = _orderer(cfg)
    results = sorted(results, key=lambda r: order(("k", "n_objects", "selector", "constraints"),
                                                  [r["cell"][x] for x in ("k", "n_objects", "selector", "constraints")]))
    labels = [f"k={r['cell']['k']}{' sel.-aware' if r['cell'].get('variant') else ''}, N={r['cell']['n_objects']}"
              f"\n{r['cell']['selector']}" for r in results]
    fig, ax = plt.subplots(figsize=(max(5, 1.2 * len(results) + 2), 4.5))
    bottom = np.zeros(len(results))
    for name, keys, colour in FIG6_STACK:
        vals = np.array([sum(100 * r["summary"]["categories"][k]["rate"] for k in keys) for r in results])
        ax.bar(range(len(results)), vals, bottom=bottom, color=colour, label=name)
        bottom += vals
    ax.set_xticks(range(len(results)))
    ax.set_xticklabels(labels, fontsize=8)
    ax.set_ylabel("episodes (%)")
    ax.set_ylim(0, 100)
    ax.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.0, 1.0))
    ax.set_title(cfg.get("title", cfg["name"]), fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def render(cfg: dict, results: list[dict], root: Path) -> tuple[str | None, str]:
    """Write NAME.md (always) and NAME.png (fig4/fig5/fig6, when there are results) from stored results only. The
    figures show each method pooled over its training seeds (``pool_seeds``) and the planner's reference."""
    root = Path(root)
    root.mkdir(parents=True, exist_ok=True)
    table = root / f"{cfg['name']}.md"
    atomic_write_text(table, markdown_table(cfg, results))
    figure = None
    policies = pool_seeds([r for r in results if r["cell"]["algorithm"] != "planner"])
    bounds = [r for r in results if r["cell"]["algorithm"] == "planner"]
    if policies and cfg["figure"] in ("fig4", "fig5", "fig6"):
        figure = root / f"{cfg['name']}.png"
        {"fig4": _plot_fig4, "fig5": _plot_fig5, "fig6": _plot_fig6}[cfg["figure"]](cfg, policies, figure, bounds)
    return (str(figure) if figure else None), str(table)


__all__ = ["Cell", "SweepError", "available", "load_config", "cells_of", "check_policies", "run_sweep", "load_results",
           "render", "markdown_table"]
