"""The offline SemanticBackend with the real shipped embedding model (all-MiniLM-L6-v2, CPU).

Numbers asserted here were measured first (see the semantics module docstring): on the 35 catalog
names, which the classifier never saw, the default (v3: logistic regression on 165 example names,
margin 0.19 picked by cross-validation over the examples) gets 30 right; v2 (class means, margin
0.035) got 29 and v1 (argmax) 27. On the 60-name held-out list, v3 gets 55 and v2 54.
"""

from __future__ import annotations


import numpy as np
import pytest

from safemanip.scene.catalog import SEMANTIC_CLASSES, load_catalog
from safemanip.selection.base import SceneView
from safemanip.semantics.base import ConstraintQuery, ObjectQuery
from safemanip.semantics.commands import classify_constraints, constraint_matrix
from safemanip.semantics.selectors import DynamicVLMSelector, VLMConstraintSelector
from safemanip.semantics.semantic_backend import (SemanticBackend, load_class_examples, load_decision_rule,
                                                   select_margin)


@pytest.fixture(scope="module")
def backend() -> SemanticBackend:
    b = SemanticBackend()
    b.prepare(sorted(load_catalog()))  # one model load + one batched call for the whole catalog
    return b


def _catalog_errors(backend):
    catalog = load_catalog()
    names = sorted(catalog)
    predicted = backend.classify(names)
    wrong = {n: (catalog[n].semantic_class, p) for n, p in zip(names, predicted) if p != catalog[n].semantic_class}
    order = {c: i for i, c in enumerate(SEMANTIC_CLASSES)}  # fragile < soft < durable: larger = looser constraint
    looser = {n: v for n, v in wrong.items() if order[v[1]] > order[v[0]]}
    return len(names) - len(wrong), wrong, looser


def test_catalog_accuracy_held_out(backend):
    correct, wrong, looser = _catalog_errors(backend)
    # measured: 30/35 (fragile 11/11, soft 9/12, durable 10/12); one name of slack for a different BLAS
    assert correct >= 29, wrong
    # the safety lean: one error looser than the truth (glue stick -> durable)
    assert len(looser) <= 1, looser


def test_heldout_list_accuracy():
    from safemanip.semantics.commands import object_set
    truth = object_set("heldout")
    assert len(truth) == 60
    for version, measured in (("v3", 55), ("v2", 54)):
        b = SemanticBackend(examples_file=version)
        predicted = b.assign_constraints(ConstraintQuery(names=tuple(truth))).constraints
        correct = sum(p == t for p, t in zip(predicted, truth.values()))
        assert measured - 1 <= correct <= measured + 1, (version, correct)


def test_earlier_example_sets_still_reproduce():
    v1 = SemanticBackend(examples_file="v1")
    assert v1.margin == 0.0 and sum(len(v) for v in v1.examples.values()) == 24
    correct, wrong, looser = _catalog_errors(v1)
    assert 26 <= correct <= 28, wrong  # measured 27/35 with plant pot's ground truth now soft
    assert len(looser) >= 3, looser  # glass jar, glass vase -> soft; glue stick -> durable; ...
    v2 = SemanticBackend(examples_file="v2")
    assert v2.decision["rule"] == "strictest_within_margin" and v2.margin == 0.035
    correct, wrong, looser = _catalog_errors(v2)
    assert 28 <= correct <= 30 and "egg carton" in looser, wrong  # measured 29/35


def test_stored_margins_are_the_example_only_choices():
    result = select_margin(load_class_examples("v2"))
    assert result["n_examples"] == 75
    assert result["margin"] == pytest.approx(load_decision_rule("v2")["margin"])
    best = result["best"]
    assert best["accuracy"] >= 0.84 and best["recall"]["fragile"] >= 0.84  # measured 0.867 and 0.88
    plain = result["table"][0]
    assert plain["margin"] == 0.0 and plain["cost"] > best["cost"]
    v3 = load_decision_rule("v3")
    result = select_margin(load_class_examples("v3"), rule=v3["rule"])
    assert result["n_examples"] == 165 and result["margin"] == pytest.approx(v3["margin"])
    assert result["best"]["accuracy"] >= 0.87  # measured 0.898 (5-fold CV, 4 repeats)
    assert result["table"][0]["cost"] > result["best"]["cost"]
    # the logistic rule is the better of the two on the same examples (CV cost 32.2 vs 39.0)
    assert result["best"]["cost"] < select_margin(load_class_examples("v3"))["best"]["cost"]


@pytest.mark.parametrize("name,constraint", [
    ("red mug", "no_contact"), ("blue mug", "no_contact"), ("porcelain mug", "no_contact"),
    # plant pot is soft in the ground truth; like the paper's GPT-4o (73 % no_contact) we call it fragile
    ("plant pot", "no_contact"), ("supplement bottle", "soft_contact"), ("soda can", "soft_contact"),
    ("toy sheep", "any_contact"), ("toy squirrel", "any_contact"), ("toy android", "any_contact"),
])
def test_paper_objects(backend, name, constraint):
    answer = backend.assign_constraints(ConstraintQuery(names=(name,)))
    assert answer.constraints == [constraint]
    assert answer.probabilities.shape == (1, 3) and abs(answer.probabilities.sum() - 1) < 1e-6


def test_unseen_names_cost_one_batched_call(backend):
    before = backend.embed_calls
    backend.prepare(["coffee mug with a chipped rim", "plush giraffe", "bottle of hand sanitizer", "red mug"])
    assert backend.embed_calls == before + 1
    assert backend.classify(["coffee mug with a chipped rim", "plush giraffe"]) == ["fragile", "durable"]
    backend.prepare(["plush giraffe"])
    assert backend.embed_calls == before + 1


def _scene(t: int, box_x: float, vel_x: float) -> SceneView:
    names = ("toy sheep", "red mug", "wine glass", "stuffed bear", "soda can", "sponge")
    pos = np.array([[0.12, 0.00, 0.85], [0.20, 0.14, 0.85], [0.45, 0.30, 0.85],
                    [0.30, -0.05, 0.85], [-0.25, 0.00, 0.85], [0.05, -0.30, 0.85]])
    box = np.array([[box_x - 0.02, 0.0, 0.85], [box_x, 0.0, 0.85]])
    return SceneView(t=t, names=names, positions=pos, velocities=np.zeros((6, 3)), ee_path=box + [-0.1, 0, 0],
                     box_path=box, box_velocity=np.array([vel_x, 0.0, 0.0]))


def test_selector_prefers_fragile_near_the_path_and_is_fast(backend):
    sel = DynamicVLMSelector(backend, query_interval=1)
    view = _scene(0, 0.0, 0.4)
    sel.reset(view, 2)
    ids = sel.select(view, 2)
    # the toy sheep and stuffed bear are on the path but harmless; the red mug is near it and fragile, so it
    # ranks first; the second slot goes to the sheep (right in front of the box) with v3's softer
    # probabilities, to the far wine glass with v2's sharper ones, never to the bear behind the sheep
    assert ids[0] == 1 and 3 not in ids
    score, _, harm = backend.risk_scores(ObjectQuery(view=view, k=2, order=list(range(6))))
    assert harm[1] > 5 * harm[0] and harm[2] > 5 * harm[3]
    for t in range(1, 401):
        sel.select(_scene(t, 0.0005 * t, 0.4), 2)
    assert sel.stats.fallbacks == 0
    assert np.median(sel.stats.latencies_s) < 0.005  # target: < 5 ms per query after warm-up


def test_constraint_selector_end_to_end(backend):
    sel = VLMConstraintSelector(backend)
    assert sel.assign(_scene(0, 0.0, 0.0)) == ["any_contact", "no_contact", "no_contact", "any_contact",
                                                "soft_contact", "any_contact"]
    assert sel.stats.fallbacks == 0


def test_commands_with_the_real_model(backend):
    assert classify_constraints(backend, ["red mug", "toy sheep"]) == "red mug\tno_contact\ntoy sheep\tany_contact"
    text, result = constraint_matrix(backend, trials=50, seed=0)  # its speed: benchmarks/selector_latency.py
    assert "deterministic" in text
    assert result["object_accuracy"] >= 80.0  # measured 85.7 (30/35)
    assert result["table3"]["no_contact"]["no_contact"] >= 95.0  # measured 100.0 at 200 trials
    # the paper's Tables III/IV are over its eight objects: there the goal (GPT-4o: 99.0 / 41.5 / 100) is met
    _, paper = constraint_matrix(backend, trials=200, seed=0, objects="paper")
    t3 = paper["table3"]
    assert t3["no_contact"]["no_contact"] >= 99.0 and t3["soft_contact"]["soft_contact"] > 41.5
    assert t3["any_contact"]["any_contact"] == 100.0
