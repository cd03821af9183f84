"""Running a sweep: every cell not stored yet, one after another, each through the evaluation harness, then the table
and figure redrawn from every stored cell of the spec. Resumable: a stored cell is not rerun, and a signal stops the
sweep with the cells finished before it kept."""

from __future__ import annotations

import contextlib
from pathlib import Path

from safemanip.evaluation.sweep.grid import Cell, PlannerCell, cells_of, check_policies, record_id, select_cells
from safemanip.evaluation.sweep.render import render
from safemanip.evaluation.sweep.spec import SweepError, SweepSpec, load_config
from safemanip.evaluation.sweep.store import is_done, load_results, result_path, write_result
from safemanip.util.files import OutputLock, check_output_dir
from safemanip.util.procs import Interrupted, stop_on_signals

DEFAULT_ROOT = Path("results")


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

    spec = load_config(name)
    root = Path(out) if out else DEFAULT_ROOT / spec.folder
    vlm = {k: v for k, v in (vlm or {}).items() if v}
    unknown = sorted(set(vlm) - set(VLM_FIELDS))
    if unknown:
        raise SweepError(f"unknown semantic-backend option(s) {unknown}; known: {', '.join(VLM_FIELDS)}")
    cells = cells_of(spec, episodes, vlm)
    if only and render_only:
        raise SweepError("--only picks cells to run and --render-only runs none: drop one of them")
    to_run = select_cells(cells, only, spec.name) if only else cells
    if vlm and not render_only:
        if not any(isinstance(c, Cell) and c.vlm for c in to_run):
            raise SweepError(f"sweep {spec.name} has no cell that queries the semantic backend (selector "
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
        check_policies(to_run, spec.name)
    status = {"ran": [], "done": [], "skipped": [], "failed": [], "interrupted": None}
    with OutputLock(root):
        if not render_only:
            try:
                with stop_on_signals(), _ray_session(backend, address, workers):
                    _run_cells(spec, to_run, root, status, workers, backend, address, progress, log, vlm)
            except Interrupted as stop:
                status["interrupted"] = stop.signum
            if status["interrupted"]:
                log(f"interrupted: {len(status['ran'])} cell(s) finished in this run are kept; run the same command "
                    f"to continue")
        # only this spec's cells: sweeps may share a folder (fig6 draws N = 6 from fig5's cells at N = 3..6)
        wanted = {c.id for c in cells}
        results = [r for r in load_results(root) if record_id(r["cell"]) in wanted]
        status["figure"], status["table"] = render(spec, results, root)
    log(f"wrote {status['table']}" + (f" and {status['figure']}" if status["figure"] else ""))
    if status["skipped"]:
        log(f"{len(status['skipped'])} cell(s) skipped for missing policies (train commands above)")
    return status


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


def _run_cells(spec: SweepSpec, cells: list[Cell | PlannerCell], root: Path, status: dict, workers: int,
               backend: str, address: str | None, progress: bool, log, vlm: dict) -> None:
    from safemanip.evaluation.harness import EvalRequest
    from safemanip.rl.checkpoint import resolve_policy

    cells_dir = root / "cells"
    scenes = spec.scenes.settings()
    log(f"sweep {spec.name}: {len(cells)} cells, {cells[0].episodes if cells else 0} episodes each -> {root}")
    for i, cell in enumerate(cells, 1):
        tag = f"[{i}/{len(cells)}] {cell.id}"
        if is_done(result_path(root, cell), cell):
            status["done"].append(cell.id)
            log(f"{tag}: done already")
            continue
        if isinstance(cell, PlannerCell):
            req = EvalRequest(policy=None, planner=cell.avoid, n_objects=cell.n_objects, semantics=cell.semantics,
                              judge=cell.judge, episodes=cell.episodes, seed_block=cell.seed, workers=workers,
                              backend=backend, address=address, out=str(cells_dir / cell.id), progress=progress,
                              env=scenes)
            if not _evaluate_cell(req, cell, root, status, tag, log):
                return
            continue
        # a relative path such as policies/rarl-k2-conservative-s0.safetensors falls back to the benchmark's policy
        # of that name, so a shipped sweep runs from any working folder
        policy = Path(cell.policy) if Path(cell.policy).is_absolute() else resolve_policy(cell.policy)
        if not policy.exists():
            status["skipped"].append({"cell": cell.id, "policy": cell.policy, "train": cell.train_command()})
            log(f"{tag}: skipped, no policy file {cell.policy}; make it with:\n    {cell.train_command()}")
            continue
        req = EvalRequest(policy=str(policy), n_objects=cell.n_objects, semantics=cell.semantics,
                          selector=cell.selector, constraint_selector=cell.constraints, judge=cell.judge,
                          episodes=cell.episodes, seed_block=cell.seed, workers=workers, backend=backend,
                          address=address, out=str(cells_dir / cell.id), progress=progress, shield=cell.shield,
                          env=scenes, **(vlm if cell.vlm else {}))
        # the file's identity (k, constraints, ...) was checked against its name before any cell ran (check_policies)
        if not _evaluate_cell(req, cell, root, status, tag, log):
            return


def _evaluate_cell(req, cell: Cell | PlannerCell, root: Path, status: dict, tag: str, log) -> bool:
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
    write_result(root, cell, summary)
    status["ran"].append(cell.id)
    s = summary["success"]
    log(f"{tag}: success {100 * s['rate']:.1f}% [{100 * s['ci95'][0]:.1f}, {100 * s['ci95'][1]:.1f}]")
    return True
