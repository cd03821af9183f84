"""The evaluation harness: full-scene judging, records, argument validation, local and Ray backends."""

import csv
import json

import mujoco
import numpy as np
import pytest

from safemanip.env.observation import observation_dim
from safemanip.env.slide_out import SlideOutEnv
from safemanip.evaluation.episode import format_selections, parse_selections, run_episode
from safemanip.evaluation.harness import EvalConfigError, EvalRequest, evaluate, prepare, read_records
from safemanip.evaluation.parallel import chunk_seeds, run_episodes
from safemanip.rl.numpy_actor import NumpyActor
from safemanip.scene.catalog import load_catalog
from safemanip.scene.placement import LAYOUTS
from safemanip.selection.reducer import Reducer
from safemanip.selection.selectors import ConservativeConstraints, DynamicKNN, GroundTruthConstraints
from safemanip.selection.view import EnvViewBuilder
from conftest import make_policy


class Fixed:
    """An object selector that always picks the same ids."""

    name = "fixed"

    def __init__(self, ids):
        self.ids = list(ids)

    def reset(self, view, k):
        pass

    def select(self, view, k):
        return list(self.ids)


def touch_object_1(env):
    """Put object 1 right in front of the held box, 3 mm from it: inside the 1 cm collision threshold."""
    r = load_catalog()[env.names[1]].footprint_radius
    bx, by, _ = env.data.xpos[env.index.bottom_box_body]
    adr = env.index.object_qpos[1]
    env.data.qpos[adr:adr + 3] = (bx + 0.08, by - env.geometry.box_half_extents[1] - r - 0.003, 0.0005)
    env.data.qpos[adr + 3:adr + 7] = (1, 0, 0, 0)
    mujoco.mj_forward(env.model, env.data)


ZERO = NumpyActor([np.zeros((3, observation_dim(1)), np.float32), np.zeros(3, np.float32)])


@pytest.mark.parametrize("picked, expected", [([0], "collision_unselected"), ([1], "collision_selected")])
def test_the_judge_is_the_full_scene(picked, expected):
    env = SlideOutEnv(n_objects=2, names=["red mug", "toy sheep"], constraints="conservative")
    rec = run_episode(env, ZERO, Reducer(1, "conservative"), Fixed(picked), ConservativeConstraints(), seed=0,
                      after_reset=touch_object_1)
    assert rec["category"] == expected and rec["event"] == "failure:hard"
    assert rec["object"] == "toy sheep" and rec["object_id"] == 1 and rec["length"] == 1
    assert rec["selected"] == ("yes" if expected == "collision_selected" else "no")
    assert rec["selections"] == f"0:{picked[0]}" and rec["outcome"] == "failure"


def test_a_durable_object_is_not_a_failure_under_the_ground_truth_judge():
    env = SlideOutEnv(n_objects=2, names=["red mug", "toy sheep"], constraints="ground_truth")  # toy: any_contact
    env.max_episode_steps = 3
    rec = run_episode(env, ZERO, Reducer(1, "conservative"), Fixed([0]), GroundTruthConstraints(), seed=0,
                      after_reset=touch_object_1)
    assert rec["category"] == "timeout" and rec["object"] == ""
    assert rec["judge_constraints"] == "no_contact;any_contact"
    assert rec["assigned_constraints"] == "no_contact;any_contact"


def test_selection_history_string_round_trips():
    changes = [(0, (1, 4)), (8, (1, 2)), (12, ())]
    assert format_selections(changes) == "0:1,4;8:1,2;12:"
    assert parse_selections(format_selections(changes)) == changes


def test_dynamic_selection_is_recorded_over_time():
    env = SlideOutEnv(n_objects=4, constraints="conservative", max_episode_steps=30)
    actor = NumpyActor([np.zeros((3, observation_dim(2)), np.float32), np.array([0.5, -0.3, 0.0], np.float32)])
    sel = DynamicKNN()
    rec = run_episode(env, actor, Reducer(2, "conservative"), sel, ConservativeConstraints(), seed=3)
    changes = parse_selections(rec["selections"])
    assert changes[0][0] == 0 and all(t % 4 == 0 for t, _ in changes)  # changes only at re-pick times
    assert sel.picks == rec["length"] // 4 + (1 if rec["length"] % 4 else 0)
    assert rec["selection_changes"] == len(changes) - 1


class RecordingBackend:
    """A semantic backend that wants images: checks the render seam end to end (no network)."""

    name = "fake-vlm"
    needs_images = True

    def __init__(self):
        self.images = []

    def prepare(self, names):
        pass

    def select_objects(self, query):
        from safemanip.semantics.base import ObjectAnswer

        self.images.append(query.images)
        return ObjectAnswer(ids=list(query.order[:query.k]))


def test_vlm_selector_gets_annotated_frames_only_when_it_queries(gl):
    from safemanip.semantics.selectors import DynamicVLMSelector

    env = SlideOutEnv(n_objects=3, constraints="conservative", max_episode_steps=9)
    backend = RecordingBackend()
    builder = EnvViewBuilder(render_size=(96, 128))
    still = NumpyActor([np.zeros((3, observation_dim(2)), np.float32), np.zeros(3, np.float32)])
    rec = run_episode(env, still, Reducer(2, "conservative"), DynamicVLMSelector(backend, query_interval=4),
                      ConservativeConstraints(), seed=1, builder=builder)
    assert rec["category"] == "timeout"
    assert rec["object_queries"] == 3 and rec["object_fallbacks"] == 0  # t = 0, 4, 8
    assert builder.renders == 3 and len(backend.images) == 3
    assert all(imgs and imgs[0][:8] == b"\x89PNG\r\n\x1a\n" for imgs in backend.images)


# ------------------------------------------------------------------------------------------ requests
def test_a_policy_runs_on_its_own_layout_unless_another_is_asked_for(tmp_path):
    pol = make_policy(tmp_path / "rarl-k2-conservative.safetensors", 2)
    own = prepare(EvalRequest(policy=pol, episodes=1)).spec.env_kwargs
    assert (own["layout"], own["clear_route"]) == ("route", True)
    narrow = prepare(EvalRequest(policy=pol, episodes=1, env={"layout": "narrow"})).spec.env_kwargs
    # the narrow layout with its own share of objects beside the route, not the policy's recorded one
    assert (narrow["layout"], narrow["clear_route"], narrow["near_path_fraction"]) == ("narrow", True, None)
    env = SlideOutEnv(**{**narrow, "constraints": "conservative"})
    env.reset(seed=3)
    assert env.placement.near_path.all() and env.placement.route.layout is LAYOUTS["narrow"]
    with pytest.raises(EvalConfigError, match="layout must be one of route, narrow, gate, exit, got 'tight'"):
        prepare(EvalRequest(policy=pol, episodes=1, env={"layout": "tight"}))
    # what belongs to the policy, the judge or the scene's own fields is not changed through env
    for key, why in (("object_size", "the policy's own"), ("constraints", "--judge"), ("n_objects", "--n-objects"),
                     ("speed", "unknown env setting 'speed'")):
        with pytest.raises(EvalConfigError, match=why):
            prepare(EvalRequest(policy=pol, episodes=1, env={key: 1}))


def test_validation_lists_every_problem_before_any_work(tmp_path):
    pol = make_policy(tmp_path / "rarl-k2-conservative.safetensors", 2)
    with pytest.raises(EvalConfigError) as err:
        prepare(EvalRequest(policy=pol, n_objects=6, semantics="2 fragile, 3 durable", selector="nearest",
                            address="ray://x:1", vlm_model="gpt", workers=0))
    msg = str(err.value)
    for part in ("unknown --selector 'nearest'", "describes 5 objects but --n-objects is 6",
                 "--address only applies to --backend ray", "--vlm-model only applies to --selector dynamic-vlm",
                 "--workers must be >= 1"):
        assert part in msg
    with pytest.raises(EvalConfigError, match=r"needs k=2 objects but the scene has N=1.*--pad"):
        prepare(EvalRequest(policy=pol, n_objects=1))
    with pytest.raises(EvalConfigError, match="choose an object selector with --selector"):
        prepare(EvalRequest(policy=pol, n_objects=4))
    with pytest.raises(EvalConfigError, match="--selector full shows every object"):
        prepare(EvalRequest(policy=pol, n_objects=4, selector="full"))
    with pytest.raises(EvalConfigError, match="no policy file"):
        prepare(EvalRequest(policy=str(tmp_path / "missing.safetensors")))
    with pytest.raises(EvalConfigError, match="cannot read 'two fragile'"):
        prepare(EvalRequest(policy=pol, semantics="two fragile"))
    with pytest.raises(EvalConfigError, match="--vlm-cache-only needs --vlm-cache"):
        prepare(EvalRequest(policy=pol, n_objects=3, selector="dynamic-vlm", vlm_backend="openai",
                            vlm_cache_only=True))
    with pytest.raises(EvalConfigError, match=r"a scene holds at most 8 objects, got a count of 9"):
        prepare(EvalRequest(policy=pol, semantics="9 fragile", selector="dynamic-knn"))
    ok = prepare(EvalRequest(policy=pol))  # k == N: the full-state layout by default
    assert ok.spec.selector == "full" and ok.n_objects == 2 and ok.spec.constraints == "conservative"
    ok = prepare(EvalRequest(policy=pol, semantics="2 fragile, 3 durable", selector="privileged", judge="conservative"))
    assert ok.n_objects == 5 and ok.spec.env_kwargs["constraints"] == "conservative"


def test_cli_reports_bad_arguments_with_exit_code_2(tmp_path, capsys):
    from safemanip.cli import main

    pol = make_policy(tmp_path / "p.safetensors", 2)
    assert main(["eval", "--policy", pol, "--n-objects", "5"]) == 2
    err = capsys.readouterr().err
    assert "safemanip eval: error" in err and "--selector" in err


def test_evaluate_writes_records_and_summary(tmp_path):
    pol = make_policy(tmp_path / "p.safetensors", 2, goal_seeker=True)
    out = tmp_path / "out"
    report = evaluate(EvalRequest(policy=pol, n_objects=4, selector="static-knn", judge="conservative", episodes=4,
                                  seed_block=2, workers=1, out=str(out)))
    recs = read_records(out / "episodes.csv")
    assert [r["seed"] for r in recs] == [200000, 200001, 200002, 200003]
    assert recs == report["records"]  # the CSV alone rebuilds the records
    summary = json.loads((out / "summary.json").read_text())
    assert summary["episodes"] == 4 and summary["eval"]["selector"] == "static-knn"
    cats = summary["categories"]
    assert sum(c["count"] for c in cats.values()) == 4
    assert summary["safety_violation"]["count"] == sum(cats[c]["count"] for c in (
        "top_box", "out_of_workspace", "collision_unselected", "collision_selected", "soft_contact"))
    assert "collision with unselected" in report["text"] and "mean episode length" in report["text"]
    with open(out / "episodes.csv") as f:
        header = next(csv.reader(f))
    for col in ("seed", "outcome", "category", "object", "selected", "selections"):
        assert col in header


def test_padding_runs_a_policy_in_a_smaller_scene(tmp_path):
    pol = make_policy(tmp_path / "p.safetensors", 3, constraints="all")
    report = evaluate(EvalRequest(policy=pol, n_objects=1, pad=True, episodes=2, workers=1,
                                  env={"max_episode_steps": 15}))
    assert report["summary"]["eval"]["selector"] == "full" and len(report["records"]) == 2
    assert all(r["selections"] == "0:0" for r in report["records"])


def test_chunks_cover_all_seeds_in_order():
    seeds = list(range(23))
    for workers, size in ((1, None), (2, None), (2, 5), (4, 1)):
        chunks = chunk_seeds(seeds, workers, size)
        assert [s for c in chunks for s in c] == seeds


# ------------------------------------------------------------------------------------------ backends
def _spec(tmp_path):
    pol = make_policy(tmp_path / "p.safetensors", 2, goal_seeker=True)
    return prepare(EvalRequest(policy=pol, n_objects=5, selector="dynamic-knn", judge="conservative", episodes=6,
                               env={"max_episode_steps": 40}))


def test_local_results_do_not_depend_on_workers_or_chunking(tmp_path):
    prep = _spec(tmp_path)
    one = run_episodes(prep.spec, prep.seeds, workers=1)
    two = run_episodes(prep.spec, prep.seeds, workers=2, chunk_size=2)
    assert one == two
    assert {r["category"] for r in one} & {"collision_selected", "collision_unselected"}


@pytest.mark.slow
def test_ray_backend_gives_the_same_records_as_local(tmp_path):
    ray = pytest.importorskip("ray")
    prep = _spec(tmp_path)
    local = run_episodes(prep.spec, prep.seeds, workers=1)
    ray.init(num_cpus=1, include_dashboard=False, log_to_driver=False)
    try:
        remote = run_episodes(prep.spec, prep.seeds, workers=1, backend="ray", chunk_size=4)
    finally:
        ray.shutdown()
    assert remote == local


def test_a_policy_trained_with_object_sizes_gets_them_at_evaluation(tmp_path):
    """The harness reads ``object_size`` from the policy and its reducer hands each slot the object's radius;
    a policy whose input size disagrees with its metadata is refused before any episode."""
    sized = make_policy(tmp_path / "sized.safetensors", 2, object_size=True)
    prepared = prepare(EvalRequest(policy=sized, n_objects=3, selector="dynamic-knn", episodes=2, workers=1))
    assert prepared.spec.object_size and observation_dim(2, object_size=True) == observation_dim(2) + 2
    result = evaluate(EvalRequest(policy=sized, n_objects=3, selector="dynamic-knn", episodes=2, workers=1,
                                   out=str(tmp_path / "ev")))
    assert result["summary"]["episodes"] == 2
    assert not prepare(EvalRequest(policy=make_policy(tmp_path / "plain.safetensors", 2), n_objects=3,
                                   selector="dynamic-knn", episodes=1)).spec.object_size  # older policies: no sizes
    wrong = make_policy(tmp_path / "wrong.safetensors", 2, object_size=True, obs_dim=observation_dim(2))
    with pytest.raises(EvalConfigError, match="with object sizes"):
        prepare(EvalRequest(policy=wrong, n_objects=3, selector="dynamic-knn", episodes=1))
