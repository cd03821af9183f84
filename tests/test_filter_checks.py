"""The safety filter's checks (issue 45, ``bench/filter_checks.py``): each setting's cells without and with the
filter side by side, violations at most 1 % with it, and a success cost of at most 3 points where it is asked."""

from __future__ import annotations

from safemanip.bench.filter_checks import rows, table

CATEGORIES = ("success", "top_box", "out_of_workspace", "collision_unselected", "collision_selected", "soft_contact",
              "timeout", "unstable")


def stored(policy, selector, shield, success, collided, timeout, overrides=0, n=1000, semantics=None):
    """One stored cell: ``success``, ``collided`` and ``timeout`` episodes of ``n``."""
    counts = dict.fromkeys(CATEGORIES, 0) | {"success": success, "collision_selected": collided, "timeout": timeout}
    seed = int(policy.rsplit("-s", 1)[1])
    summary = {"episodes": n, "success": {"count": success, "rate": success / n},
               "safety_violation": {"count": collided, "rate": collided / n},
               "categories": {k: {"count": v, "rate": v / n} for k, v in counts.items()}}
    if shield:
        summary["shield_interventions"] = {"overrides": overrides, "steps": 40 * n, "rate": overrides / (40 * n)}
    cell = {"policy": f"policies/{policy}.safetensors", "algorithm": policy.split("-")[0], "k": 2,
            "policy_constraints": "conservative", "n_objects": 5, "semantics": semantics, "selector": selector,
            "constraints": "conservative", "judge": "ground-truth", "episodes": n, "seed": 50, "train_seed": seed,
            "shield": shield}
    return {"cell": cell, "summary": summary}


def test_a_setting_pairs_its_cells_by_training_seed_and_is_checked():
    results = []
    for s in (0, 1, 2):
        p = f"rarl-k2-conservative-s{s}"
        results += [stored(p, "privileged", None, 900, 100, 0, semantics="2 fragile, 3 durable"),
                    stored(p, "privileged", "brake", 880, 5 * s, 120 - 5 * s, overrides=4000,
                           semantics="2 fragile, 3 durable"),
                    stored(p, "dynamic-knn", None, 300, 700, 0, semantics="2 fragile, 3 durable"),
                    stored(p, "dynamic-knn", "brake", 100, 0, 900, semantics="2 fragile, 3 durable")]
    results.append(stored("rarl-k2-conservative-s3", "privileged", "brake", 880, 0, 120))  # no partner: left out
    privileged, knn = sorted(rows(results, "Table I"), key=lambda r: r["selector"] != "privileged")
    assert privileged["seeds"] == 3 and abs(privileged["cost"] - 0.02) < 1e-12
    assert abs(privileged["violation_with"] - 0.005) < 1e-12 and privileged["violation_with_worst_seed"] == 0.01
    assert privileged["violation_ok"] and privileged["cost_ok"] and privileged["overridden"] == 0.1
    lo, hi = privileged["change_ci95"]
    assert lo < -0.02 < hi < 0
    # a kNN cell protects every object and stops before the blocker: its cost is shown, not checked
    assert knn["cost_checked"] is False and knn["cost_ok"] is None and abs(knn["cost"] - 0.2) < 1e-12
    text = table([privileged, knn], {"Table I": 2}, 3)
    assert "violations at most 1 % in 2 of 2" in text and "at most 3 points in 1 of 1 checked" in text
    assert "| Table I | 2 fragile, 3 durable, privileged" in text and "0.5 (1.0; 0.0)" in text


def test_a_check_that_fails_says_so_and_names_the_worst_setting():
    results = []
    for s in (0, 1, 2):
        p = f"vanilla-k4-conservative-s{s}"
        results += [stored(p, "full", None, 800, 200, 0), stored(p, "full", "brake", 740, 20, 240)]
    (row,) = rows(results, "Fig. 4")
    assert row["cost_checked"] and not row["cost_ok"] and not row["violation_ok"]
    text = table([row], {"Fig. 4": 12, "Table I": 10}, 3)
    assert "(1 of 12 settings with every training seed so far)" in text
    assert "violations at most 1 % in 0 of 1 (highest: vanilla, N = 5, 2.0 %)" in text
    assert "over 1 %" in text and "over 3 points" in text and "Table I**: not measured yet" in text


def test_settings_with_fewer_seeds_than_the_benchmark_are_shown_but_not_judged():
    results = [stored("rarl-k1-conservative-s0", "full", None, 990, 10, 0),
               stored("rarl-k1-conservative-s0", "full", "brake", 999, 0, 1)]
    text = table(rows(results, "Fig. 4"), {"Fig. 4": 12}, 3)
    assert "1 of 12 settings measured so far, none yet with every training seed" in text
    assert "rarl, N = 5 (1 seed)" in text
