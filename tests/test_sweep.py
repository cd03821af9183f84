"""Sweeps: shipped configs, cell grid, resume (a stored cell is not rerun), missing policies, rendering."""

import json
from pathlib import Path

import pytest

from safemanip.evaluation.sweep.grid import Cell, PlannerCell, cells_of
from safemanip.evaluation.sweep.render import render
from safemanip.evaluation.sweep.runner import run_sweep
from safemanip.evaluation.sweep.spec import SweepError, available, load_config
from conftest import ROOT, fake_summary, make_policy


def test_shipped_sweeps_load_and_form_the_paper_grids():
    assert {"fig4", "fig5", "fig6", "table1", "table2"} <= set(available())
    fig5 = cells_of(load_config("fig5"))
    policies = [c for c in fig5 if isinstance(c, Cell)]
    assert all(c.k <= c.n_objects for c in policies)
    assert {c.selector for c in policies if c.k < c.n_objects} == {"static-knn", "dynamic-knn"}
    assert {c.selector for c in policies if c.k == c.n_objects} == {"full"}
    assert {c.train_seed for c in policies} == {0, 1, 2} and {c.variant for c in policies} == {"", "selaware"}
    per_seed = 2 * (4 + 3 + 2 + 1) + 4 + 2 * (4 + 3 + 2 + 1) + 3  # paper's way: k<N x 2 selectors + full per N; selaware
    assert len(policies) == 3 * per_seed
    assert sorted(c.n_objects for c in fig5 if isinstance(c, PlannerCell)) == [3, 4, 5, 6]  # the bound on each N
    fig6 = cells_of(load_config("fig6"))
    assert {c.n_objects for c in fig6} == {6}
    assert {c.id for c in fig6} <= {c.id for c in fig5}  # the same cells: fig6 draws fig5's results folder
    assert all(c.episodes == 1000 for c in fig5 + fig6)
    assert cells_of(load_config("fig5"), episodes=10)[0].episodes == 10
    table1 = cells_of(load_config("table1"))
    assert {c.avoid for c in table1 if isinstance(c, PlannerCell)} == {"all", "fragile"}
    assert all(c.scenes == "gate_share=1.0,layout=gate" for c in table1)


def test_bad_sweep_configs_are_rejected(tmp_path):
    with pytest.raises(SweepError, match="no sweep named 'fig9'"):
        load_config("fig9")
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps({"name": "bad", "figure": "fig5", "episodes": 1, "judge": "conservative",
                               "policies": ["policies/k2.safetensors"], "n_objects": [3], "selectors": ["nearest"]}))
    with pytest.raises(SweepError) as err:
        load_config(str(bad))
    assert "ALGORITHM-kK-CONSTRAINTS" in str(err.value) and "unknown selector 'nearest'" in str(err.value)


def _config(tmp_path, policies):
    cfg = {"name": "mini", "title": "mini", "figure": "fig5", "episodes": 2, "seed": 0, "judge": "conservative",
           "policies": policies, "n_objects": [3], "semantics": [None], "selectors": ["static-knn", "dynamic-knn"],
           "constraints": ["conservative"], "table": {"rows": ["k"], "columns": ["n_objects", "selector"]}}
    path = tmp_path / "mini.json"
    path.write_text(json.dumps(cfg))
    return str(path)


def test_resume_skips_stored_cells_and_reports_missing_policies(tmp_path):
    pol = make_policy(tmp_path / "rarl-k2-conservative.safetensors", 2)
    missing = str(tmp_path / "rarl-k3-all.safetensors")
    name = _config(tmp_path, [pol, missing])
    out = tmp_path / "out"
    cells = cells_of(load_config(name))
    static = next(c for c in cells if c.selector == "static-knn" and c.k == 2)
    (out / "cells").mkdir(parents=True)
    stored = {"cell": static.record(), "summary": fake_summary(0.5)}
    (out / "cells" / f"{static.id}.json").write_text(json.dumps(stored))

    logs = []
    status = run_sweep(name, out=str(out), workers=1, progress=False, log=logs.append)
    assert status["done"] == [static.id]
    assert len(status["ran"]) == 1 and "dynamic-knn" in status["ran"][0]
    assert len(status["skipped"]) == 2  # both selectors for the k=3 policy
    assert status["skipped"][0]["train"] == "safemanip bench train --only rarl-k3-all && safemanip bench promote"
    assert any("skipped, no policy file" in line for line in logs)
    # the stored cell was not touched; the new one has its records next to it
    assert json.loads((out / "cells" / f"{static.id}.json").read_text()) == stored
    ran = status["ran"][0]
    assert (out / "cells" / ran / "episodes.csv").exists()
    assert Path(status["table"]).exists() and Path(status["figure"]).exists()
    # a second run reruns nothing; asking for more episodes redoes the cells
    again = run_sweep(name, out=str(out), workers=1, progress=False, log=lambda s: None)
    assert again["ran"] == [] and sorted(again["done"]) == sorted([static.id, ran])


@pytest.mark.parametrize("name", ["fig4", "fig5", "fig6", "table1"])
def test_render_only_uses_stored_results(tmp_path, name):
    cfg = load_config(name)
    results = []
    for i, cell in enumerate(cells_of(cfg)):
        static = isinstance(cell, Cell) and cell.selector == "static-knn"
        fails = {"collision_unselected": 10 if static else 3, "top_box": 5,
                 "collision_selected": 7}
        results.append({"cell": cell.record(), "summary": fake_summary(0.3 + 0.05 * (i % 5), **fails)})
    root = tmp_path / name
    (root / "cells").mkdir(parents=True)
    for r in results:
        (root / "cells" / f"{r['cell']['policy'].split('/')[-1]}-{r['cell']['n_objects']}-"
                          f"{r['cell']['selector']}-{r['cell']['semantics']}.json").write_text(json.dumps(r))
    status = run_sweep(name, out=str(root), render_only=True, log=lambda s: None)
    assert status["ran"] == [] and status["skipped"] == []
    table = Path(status["table"]).read_text()
    assert "| k |" in table or "| semantics |" in table or "| algorithm |" in table
    policies = [r for r in results if r["cell"]["algorithm"] != "planner"]
    assert table.count("\n| rarl-") + table.count("\n| vanilla-") == len(policies)  # one row per cell and seed
    assert "(reference)" in table and "(bound)" not in table  # the planner's row in the pivot: not an upper bound
    assert "{" in table and "with training seeds as the unit" in table  # the seed-level interval beside Wilson's
    if cfg.figure in ("fig4", "fig5", "fig6"):
        png = Path(status["figure"])
        assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and png.stat().st_size > 10_000
    else:
        assert status["figure"] is None


def test_render_with_no_results_says_how_to_get_them(tmp_path):
    fig, table = render(load_config("fig6"), [], tmp_path)
    assert fig is None and "safemanip sweep fig6" in Path(table).read_text()


def test_cells_that_query_the_semantic_backend_go_stale_with_its_version(tmp_path):
    from safemanip.evaluation.sweep.store import is_done
    from safemanip.semantics.semantic_backend import DEFAULT_EXAMPLES

    cells = {(c.selector, c.constraints): c for c in cells_of(load_config("table2"), episodes=10)
             if isinstance(c, Cell) and c.k == 2}
    vlm_cell, plain_cell = cells[("dynamic-vlm", "vlm")], cells[("dynamic-knn", "conservative")]
    assert vlm_cell.vlm == f"semantic:{DEFAULT_EXAMPLES}" and plain_cell.vlm is None
    path = tmp_path / "cell.json"
    old = {**vlm_cell.record(), "vlm": "semantic:class_examples_v2.json"}
    path.write_text(json.dumps({"cell": old, "summary": fake_summary(0.5)}))
    assert not is_done(path, vlm_cell)  # a result of an older classifier is redone
    legacy = {k: v for k, v in plain_cell.record().items() if k != "vlm"}  # stored before the field existed
    path.write_text(json.dumps({"cell": legacy, "summary": fake_summary(0.5)}))
    assert is_done(path, plain_cell)
    path.write_text(json.dumps({"cell": {k: v for k, v in vlm_cell.record().items() if k != "vlm"}, "summary": fake_summary(0.5)}))
    assert not is_done(path, vlm_cell)


def test_printed_train_commands_parse_and_name_the_benchmark_run():
    """A skipped cell's commands, parsed by ``safemanip``, train exactly that cell's run of the benchmark and bring it
    in; the recipe they train with is benchmark.json's (``test_bench``: it gives every shipped policy's config)."""
    import shlex

    from safemanip.bench.benchmark import load_benchmark
    from safemanip.cli import build_parser

    cell = next(c for c in cells_of(load_config("fig5")) if c.k == 3 and c.variant == "selaware" and c.train_seed == 1)
    train, promote = (shlex.split(part)[1:] for part in cell.train_command().split(" && "))
    args = build_parser().parse_args(train)
    assert args.command == "bench train" and [r.name for r in load_benchmark().select(args.only)] == \
        ["rarl-k3-conservative-selaware-s1"]
    assert build_parser().parse_args(promote).command == "bench promote"


def test_a_missing_policy_in_another_folder_is_skipped_not_replaced_by_the_shipped_one(tmp_path, monkeypatch):
    """Only a bare name or ``policies/FILE`` falls back to a known policy: ``runs/x/rarl-k2-conservative``
    must not silently evaluate the benchmark's π_2 (it once did, and stored the cells as done)."""
    from safemanip.rl.checkpoint import resolve_policy

    benchmark = (ROOT / "results" / "policies" / "rarl-k3-conservative-s1.safetensors").resolve()
    assert resolve_policy("rarl-k3-conservative-s1").resolve() == benchmark
    monkeypatch.chdir(tmp_path)  # from any working folder: the source checkout's results/policies
    assert resolve_policy("policies/rarl-k3-conservative-s1.safetensors").resolve() == benchmark
    elsewhere = tmp_path / "runs" / "rarl-k2-conservative.safetensors"
    assert resolve_policy(elsewhere) == elsewhere and not elsewhere.exists()
    relative = "runs/selaware/rarl-k2-conservative.safetensors"
    assert resolve_policy(relative) == Path(relative)
    monkeypatch.chdir(tmp_path)  # the sweep resolves relative policy paths from the working folder
    name = _config(tmp_path, [relative])
    status = run_sweep(name, out=str(tmp_path / "out"), workers=1, progress=False, log=lambda s: None)
    assert status["ran"] == [] and len(status["skipped"]) == 2


def test_a_sweep_renders_only_its_own_cells_from_a_shared_folder(tmp_path):
    # fig6 is fig5's cells at N = 6: the N = 3..5 cells in the same folder must not enter its table or its bound
    root = tmp_path / "fig5"
    (root / "cells").mkdir(parents=True)
    for cell in cells_of(load_config("fig5")):
        if isinstance(cell, PlannerCell) or cell.k in (2, 6) and "selaware" not in cell.policy:
            summary = fake_summary(0.5 if cell.n_objects == 6 else 0.9, n=100)
            (root / "cells" / f"{cell.id}.json").write_text(json.dumps({"cell": cell.record(), "summary": summary}))
    status = run_sweep("fig6", out=str(root), render_only=True, log=lambda s: None)
    table = Path(status["table"]).read_text()
    rows = [line for line in table.splitlines() if line.startswith("| rarl-")]
    assert rows and all(line.split(" | ")[2] == "6" for line in rows)  # the N column
    assert "90.0" not in table  # no N < 6 rate anywhere, the planner's bound included


def test_only_runs_the_matching_cells_and_a_pattern_matching_nothing_is_an_error(tmp_path):
    pol = make_policy(tmp_path / "rarl-k2-conservative.safetensors", 2)
    name = _config(tmp_path, [pol])
    out = tmp_path / "out"
    status = run_sweep(name, out=str(out), workers=1, progress=False, log=lambda s: None, only=["*__dynamic-knn__*"])
    assert len(status["ran"]) == 1 and "__dynamic-knn__" in status["ran"][0]
    assert [p.name for p in (out / "cells").glob("*.json")] == [f"{status['ran'][0]}.json"]
    with pytest.raises(SweepError, match=r"--only \*-s7__\* matches no cell of sweep mini; cell ids look like rarl-k2"):
        run_sweep(name, out=str(out), workers=1, progress=False, log=lambda s: None, only=["*-s7__*"])
    with pytest.raises(SweepError, match="drop one of them"):
        run_sweep(name, out=str(out), render_only=True, log=lambda s: None, only=["*"])


def test_pooled_cells_carry_a_seed_level_interval_shown_in_braces():
    from safemanip.evaluation.sweep.pooling import pool_seeds
    from safemanip.evaluation.sweep.render import markdown_table

    cfg = load_config("fig4")
    results = [{"cell": c.record(), "summary": fake_summary(rate, n=1000)}
               for c, rate in zip([c for c in cells_of(cfg) if isinstance(c, Cell) and c.algorithm == "rarl"
                                   and c.n_objects == 2],
                                  (0.70, 0.85, 0.78))]
    (pooled,) = pool_seeds(results)
    entry = pooled["summary"]["success"]
    assert entry["seed_counts"] == [700, 850, 780] and entry["seed_totals"] == [1000] * 3
    lo, hi = entry["ci95_seeds"]
    assert lo < entry["ci95"][0] and hi > entry["ci95"][1]  # seeds that disagree: wider than the pooled interval
    assert f"{{{100 * lo:.1f}, {100 * hi:.1f}}} (70-85)" in markdown_table(cfg, results)


def test_a_policy_whose_metadata_contradicts_its_name_is_refused_before_any_cell_runs(tmp_path, capsys):
    """A shipped k = 2 policy copied under a k = 3 name: the sweep refuses up front with exit 2 and one line, and
    writes nothing (it used to fail the cell, exit 1 and draw the table)."""
    from safemanip.cli import main
    from safemanip.rl.policy_index import PACKAGE_POLICIES

    good = make_policy(tmp_path / "rarl-k2-conservative.safetensors", 2)
    wrong = tmp_path / "rarl-k3-conservative-s0.safetensors"
    wrong.write_bytes((PACKAGE_POLICIES / "rarl-k2-conservative-s0.safetensors").read_bytes())
    name = _config(tmp_path, [good, str(wrong)])
    out = tmp_path / "out"
    assert main(["sweep", name, "--out", str(out), "--workers", "1", "--no-progress"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "no cell run" in err
    assert f"{wrong}: its metadata says k=2, its name k=3" in err
    assert not out.exists()
    # rendering stored cells needs no policy file, and is not refused
    assert run_sweep(name, out=str(out), render_only=True, log=lambda s: None)["ran"] == []


def test_every_identity_field_of_the_cell_id_is_checked(tmp_path):
    from safemanip.evaluation.sweep.grid import check_policies
    from safemanip.rl.policy_index import PACKAGE_POLICIES

    renamed = tmp_path / "vanilla-k2-conservative-selaware-s1.safetensors"
    renamed.write_bytes((PACKAGE_POLICIES / "rarl-k2-conservative-s0.safetensors").read_bytes())
    with pytest.raises(SweepError, match="says algorithm=rarl, variant=the paper's way, seed=0, its name "
                                         "algorithm=vanilla, variant=selaware, seed=1"):
        check_policies(cells_of(load_config(_config(tmp_path, [str(renamed)]))), "mini")
    for shipped in ("fig4", "fig5", "table1", "table2"):  # every shipped policy is what its name says
        check_policies(cells_of(load_config(shipped)), shipped)


def test_a_sweep_measures_each_cell_with_and_without_a_safety_filter(tmp_path):
    """``shields``: every policy cell once per filter (null: none), side by side in the table; a cell stored before the
    field existed still counts as done without a filter."""
    pol = make_policy(tmp_path / "rarl-k2-conservative.safetensors", 2, goal_seeker=True)
    cfg = json.loads(Path(_config(tmp_path, [pol])).read_text())
    cfg.update(selectors=["dynamic-knn"], shields=[None, "brake"],
               table={"rows": ["selector"], "columns": ["shield"]})
    spec = tmp_path / "shielded.json"
    spec.write_text(json.dumps(cfg))
    cells = cells_of(load_config(str(spec)))
    assert sorted(c.shield or "" for c in cells) == ["", "brake"]
    plain = next(c for c in cells if c.shield is None)
    assert "shield" not in plain.id and next(c for c in cells if c.shield).id == plain.id + "__shield-brake"
    out = tmp_path / "out"
    (out / "cells").mkdir(parents=True)
    old = {k: v for k, v in plain.record().items() if k != "shield"}  # as stored before the field existed
    (out / "cells" / f"{plain.id}.json").write_text(json.dumps({"cell": old, "summary": fake_summary(0.5)}))
    status = run_sweep(str(spec), out=str(out), workers=1, progress=False, log=lambda s: None)
    assert status["done"] == [plain.id] and status["ran"] == [plain.id + "__shield-brake"]
    shielded = json.loads((out / "cells" / f"{plain.id}__shield-brake.json").read_text())
    assert shielded["cell"]["shield"] == "brake" and shielded["summary"]["eval"]["shield"] == "brake"
    table = Path(status["table"]).read_text()
    assert "| no filter | filter: brake |" in table
    bad = dict(cfg, shields=["airbag"])
    spec.write_text(json.dumps(bad))
    with pytest.raises(SweepError, match="unknown shield 'airbag'"):
        load_config(str(spec))


def test_a_spec_is_checked_once_into_a_typed_frozen_sweep_spec(tmp_path):
    from dataclasses import FrozenInstanceError

    from safemanip.evaluation.sweep.spec import SweepSpec

    table2 = load_config("table2")
    assert isinstance(table2, SweepSpec) and table2.folder == "gate/table2" and table2.seed == 46
    assert table2.semantics is None and all(p.semantics for p in table2.policies)  # each policy gives its own
    assert ("dynamic-vlm", "vlm") in table2.pairs and table2.planners == ("all", "fragile")
    assert table2.scenes.label() == "gate_share=1.0,layout=gate" and table2.table.rows == ("k", "semantics")
    with pytest.raises(FrozenInstanceError):
        table2.episodes = 10  # read once, never changed afterwards
    raw = json.loads(Path(_config(tmp_path, ["policies/rarl-k2-conservative-s0.safetensors"])).read_text())
    mini = SweepSpec.from_json(raw, "mini")
    assert mini.pairs == (("static-knn", "conservative"), ("dynamic-knn", "conservative"))
    assert mini.folder == mini.title == "mini" and mini.shields == (None,) and mini.scenes.label() is None
    with pytest.raises(SweepError, match=r"sweep mini: episodes must be an integer 1\.\.100000, got 0; unknown "
                                         r"selector 'nearest'"):
        SweepSpec.from_json({**raw, "episodes": 0, "selectors": ["nearest"]}, "mini")


def test_a_planner_row_is_not_a_policy_cell_but_is_stored_like_one():
    from safemanip.evaluation.sweep.grid import RECORD_FIELDS, check_policies
    from safemanip.evaluation.sweep.spec import CELL_FIELDS

    cells = cells_of(load_config("table1"))
    planners = [c for c in cells if isinstance(c, PlannerCell)]
    assert len(planners) == 4 and not any(isinstance(c, Cell) for c in planners)
    row = next(c for c in planners if c.avoid == "all" and c.semantics == "2 fragile, 3 durable")
    assert not hasattr(row, "k") and not hasattr(row, "train_command")  # no policy, no training
    record = row.record()
    assert tuple(record) == RECORD_FIELDS == CELL_FIELDS  # the format every stored cell has (and a table may name)
    assert record["algorithm"] == "planner" and record["policy"] == "planner-all" and record["k"] == 5
    assert row.id == ("planner-all__N5__2-fragile-3-durable__full__ground-truth__ground-truth__"
                      "gate-share-1.0-layout-gate")
    assert (ROOT / "results" / "gate" / "table1" / "cells" / f"{row.id}.json").is_file()  # the stored result's name
    check_policies(planners, "table1")  # no policy file to check


def test_a_cell_identity_is_read_from_the_policy_metadata_and_from_the_name_only_for_a_missing_file(tmp_path):
    from safemanip.evaluation.sweep.grid import check_policies

    # a k = 2 policy under a k = 3 name: its cells are those of k = 2 (so N = 2 is measured), its ids keep the name
    misnamed = make_policy(tmp_path / "rarl-k3-conservative.safetensors", 2)
    missing = str(tmp_path / "vanilla-k3-all-s4.safetensors")
    raw = json.loads(Path(_config(tmp_path, [misnamed, missing])).read_text())
    spec = tmp_path / "identity.json"
    spec.write_text(json.dumps({**raw, "n_objects": [2, 3], "selectors": ["static-knn"]}))
    cells = cells_of(load_config(str(spec)))
    mine = [c for c in cells if c.policy == misnamed]
    assert [(c.k, c.n_objects) for c in mine] == [(2, 2), (2, 3)]
    assert mine[0].id.startswith("rarl-k3-conservative__N2__")
    (named,) = [c for c in cells if c.policy == missing]  # k = 3 from the name: N = 3 only
    assert (named.algorithm, named.k, named.policy_constraints, named.train_seed) == ("vanilla", 3, "all", 4)
    with pytest.raises(SweepError, match="its metadata says k=2, its name k=3"):
        check_policies(cells, "identity")


def test_pooled_filter_cells_keep_the_share_of_steps_the_filter_overrode():
    """Pooled over seeds, the filter's overrides are every seed's overridden steps over every seed's steps (they
    used to be dropped, and the table showed 0.0 for every pooled filter row)."""
    from safemanip.evaluation.sweep.pooling import pool_seeds

    cells = [c for c in cells_of(load_config("fig4-filter")) if isinstance(c, Cell) and c.shield
             and c.algorithm == "rarl" and c.n_objects == 3]
    steps = (30_000, 40_000, 50_000)
    results = [{"cell": c.record(), "summary": {**fake_summary(0.9, n=1000),
                                                "shield_interventions": {"overrides": s // 10, "steps": s,
                                                                         "rate": 0.1}}}
               for c, s in zip(cells, steps)]
    (pooled,) = pool_seeds(results)
    assert pooled["summary"]["shield_interventions"] == {"overrides": 12_000, "steps": 120_000, "rate": 0.1}
