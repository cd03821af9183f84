"""The verdict rules of ``safemanip bench`` (``bench/verdict.py``): a method is better only if the seed-level (cluster
bootstrap) interval of the difference lies above 0 and its worst training seed clears the other's best; a finding holds
only if its method wins somewhere and loses nowhere. And ``safemanip bench findings`` (``bench/findings.py``), which
writes them into docs/results.md."""

from __future__ import annotations

from types import SimpleNamespace

from safemanip.bench import findings
from safemanip.bench.verdict import compare, difference, per_seed, verdict
from safemanip.evaluation.stats import wilson_interval
from safemanip.evaluation.sweep.pooling import pooled_entry
from conftest import ROOT, run_cli

DOC = ROOT / "docs" / "results.md"


def method(*rates, n=1000):
    """A method's result pooled over training seeds of these success rates (n episodes each), as pool_seeds makes."""
    counts = [round(r * n) for r in rates]
    e = pooled_entry([{"rate": c / n} for c in counts], counts, [n] * len(counts))
    return {"summary": {"success": e, "categories": {"top_box": e}, "episodes": n * len(rates),
                        "seeds": list(range(len(rates)))}, "cell": {}}


def test_a_method_is_better_when_the_seed_level_difference_and_its_seeds_both_clear():
    high, low = method(0.80, 0.81, 0.82), method(0.50, 0.51, 0.52)
    assert compare(high, low) == "win" and compare(low, high) == "loss"
    assert compare(low, high, "top_box", lower_is_better=True) == "win"  # fewer violations is better
    assert compare(high, low, "top_box", lower_is_better=True) == "loss"
    assert compare(method(0.51, 0.52, 0.53), low) == "tie"


def test_seeds_that_agree_separate_where_the_two_pooled_intervals_overlap():
    a, b = method(0.825, 0.825, 0.825), method(0.80, 0.80, 0.80)
    assert a["summary"]["success"]["ci95"][0] < b["summary"]["success"]["ci95"][1]  # the old rule: a tie
    assert difference(a, b)[0] > 0
    assert compare(a, b) == "win" and compare(b, a) == "loss"


def test_one_good_seed_does_not_win_a_cell_the_pooled_interval_would_give():
    a, b = method(0.80, 0.80, 0.86), method(0.79, 0.79, 0.79)
    assert a["summary"]["success"]["ci95"][0] > b["summary"]["success"]["ci95"][1]  # pooled intervals disjoint
    assert difference(a, b)[0] < 0
    assert compare(a, b) == "tie"


def test_the_worst_seed_must_still_clear_the_others_best():
    # RARL against Vanilla at N = 1 (Fig. 4): the bootstrapped difference is above 0, but one RARL seed is below
    # one Vanilla seed
    a, b = method(0.979, 0.990, 0.996), method(0.971, 0.976, 0.981)
    assert difference(a, b)[0] > 0
    assert compare(a, b) == "tie"


def test_a_single_policy_compares_as_one_seed():
    count = 700
    single = {"summary": {"success": {"count": count, "rate": count / 1000, "ci95": list(wilson_interval(count, 1000))},
                          "categories": {}, "episodes": 1000}, "cell": {}}
    assert per_seed(single) == ([700], [1000])
    assert compare(method(0.80, 0.81, 0.82), single) == "win"
    assert compare(single, method(0.69, 0.70, 0.71)) == "tie"


def test_compare_is_deterministic():
    a, b = method(0.70, 0.78, 0.74), method(0.69, 0.71, 0.73)
    assert difference(a, b) == difference(a, b)


def test_verdicts():
    assert verdict(["win", "tie"], True, 3).startswith("holds")
    assert verdict(["tie", "tie"], True, 3).startswith("within the interval")
    assert verdict(["loss", "tie"], True, 3).startswith("does not hold")
    assert verdict(["win", "loss"], True, 3).startswith("mixed")
    assert verdict([], True, 3) == "not measured yet"
    assert "fewer than 3 training seeds" in verdict(["win"], False, 3)


def test_a_verdict_with_cells_missing_from_its_sweep_says_so():
    assert "provisional, 7 of its 10 cells measured" in verdict(["win"], True, 3, (3, 10))
    assert "provisional" not in verdict(["win"], True, 3, (0, 10))


def test_missing_cells_counts_the_sweep_spec_cells_without_a_stored_result(tmp_path):
    def fig5_dynamic_n6(cell):
        return cell.n_objects == 6 and cell.selector == "dynamic-knn" and cell.k == 2 and not cell.variant

    stored = findings.Stored(tmp_path, 3)
    assert stored.missing("fig5", fig5_dynamic_n6) == (3, 3)  # pi_2 seeds 0..2, nothing stored under tmp_path
    cells = ROOT / "results" / "exit" / "fig5" / "cells"
    name = "rarl-k2-conservative-s1__N6__any__dynamic-knn__conservative__conservative__layout-exit.json"
    (tmp_path / "exit" / "fig5" / "cells").mkdir(parents=True)
    (tmp_path / "exit" / "fig5" / "cells" / name).write_bytes((cells / name).read_bytes())
    assert stored.missing("fig5", fig5_dynamic_n6) == (2, 3)


def test_docs_results_is_in_step_with_the_stored_cells_and_shipped_policies(capsys):
    # a cell or policy committed without re-running safemanip bench findings would leave the published verdicts stale
    code, _, err = run_cli(capsys, ["bench", "findings", "--check", "--doc", DOC, "--results", ROOT / "results"])
    assert code == 0, "run safemanip bench findings and commit docs/results.md\n" + err


def test_check_flags_a_stale_results_page_and_writes_nothing(tmp_path, capsys):
    stale = tmp_path / "results.md"
    text = DOC.read_text().replace("<!-- /findings -->", "| 6 | a row no cell gave |\n<!-- /findings -->")
    stale.write_text(text)
    argv = ["bench", "findings", "--doc", stale, "--results", ROOT / "results"]
    code, _, err = run_cli(capsys, [*argv, "--check"])
    assert code == 1 and "out of date" in err
    assert stale.read_text() == text
    assert run_cli(capsys, argv)[0] == 0 and "a row no cell gave" not in stale.read_text()


def test_a_page_without_its_markers_is_refused_in_one_line(tmp_path, capsys):
    page = tmp_path / "results.md"
    page.write_text("# results\n")
    code, out, err = run_cli(capsys, ["bench", "findings", "--doc", page, "--results", ROOT / "results"])
    assert code == 2 and "has no <!-- status --> ... <!-- /status --> block" in err and "Traceback" not in err
    assert page.read_text() == "# results\n"


def test_full_state_finding_judges_each_way_of_training_pi_k_apart():
    def cell(k, n, rate, variant="", selector="dynamic-knn"):
        r = method(rate - 0.03, rate, rate + 0.03)
        r["cell"] = {"k": k, "n_objects": n, "variant": variant, "selector": "full" if k == n else selector}
        return r

    policies = [cell(5, 5, 0.90), cell(6, 6, 0.86)]
    for n in (5, 6):
        policies += [cell(2, n, 0.70), cell(4, n, 0.88), cell(2, n, 0.86, "selaware"), cell(4, n, 0.97, "selaware")]
    stored = SimpleNamespace(pooled=lambda folder: (policies, []), missing=lambda sweep, wanted: (0, 10), needed=3)
    _, _, text = findings.finding_fig5_full_state(stored)
    assert text.startswith("the paper's way: does not hold (0 better, 2 tied, 2 worse)")
    assert "selection-aware: holds (2 better, 2 tied, 0 worse)" in text


def test_a_way_of_training_with_cells_in_the_spec_but_none_measured_says_so():
    text = findings.verdicts_by_way({"": ["win"], "selaware": []}, {"": True, "selaware": True},
                                    {"": (0, 4), "selaware": (4, 4)}, 3)
    assert text == "the paper's way: holds (1 better, 0 tied, 0 worse); selection-aware: not measured yet"
