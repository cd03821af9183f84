"""Rollout workers: local processes and Ray actors give transitions of the same shape and meaning (the
same transitions, in fact, for the same seeds), and selection-aware training envs see the scene as
deployment does."""

from __future__ import annotations

import queue
import time

import numpy as np
import pytest

from safemanip.env.observation import ROBOT_DIM, SLOT_DIM, observation_dim
from safemanip.rl.collector import CHUNK, TRANSITION_KEYS, LocalPool, RayPool, RolloutWorker
from safemanip.rl.config import ConfigError, TrainConfig
from safemanip.rl.envs import env_builder, make_env
from safemanip.selection.training_env import SelectedSlotsEnv

ENV = {"n_objects": 2, "constraints": "conservative", "max_episode_steps": 40, "slot_order": "nearest"}
CFG = dict(k=2, env={"max_episode_steps": 40}, envs_per_collector=2, n_collectors=1, random_steps=10**6,
           learning_starts=2 * CHUNK, batch_size=32, env_steps_per_update=4.0)


def training_env(cfg: TrainConfig):
    """The env ``cfg``'s rollouts run, built as ``safemanip train`` has ``rl.train.train`` build it: the
    selection-aware env's factory passed in when the config asks for it."""
    return make_env(cfg.rollout_env_kwargs, SelectedSlotsEnv if cfg.selection_aware else None)


def check_meaning(chunk: dict[str, np.ndarray], n_envs: int, episodes: list | None = None) -> None:
    """Shapes, dtypes, and that consecutive transitions of one env chain up (s' of one = s of the next)
    except where its episode ended: terminated (success/failure) or truncated (time limit; not terminal)."""
    n = len(chunk["obs"])
    assert set(chunk) == set(TRANSITION_KEYS)
    assert chunk["obs"].shape == chunk["next_obs"].shape == (n, observation_dim(2))
    assert chunk["act"].shape == (n, 3) and np.abs(chunk["act"]).max() <= 1.0
    assert chunk["terminated"].dtype == bool and chunk["obs"].dtype == np.float32
    for k in ("l", "g", "next_l", "next_g"):
        assert chunk[k].shape == (n,) and np.isfinite(chunk[k]).all()
    m = n - n_envs  # transition i and i + n_envs come from the same env, one step apart
    chained = np.array([np.array_equal(chunk["next_obs"][i], chunk["obs"][i + n_envs]) for i in range(m)])
    terminated = chunk["terminated"][:m]
    assert not (chained & terminated).any()  # after a terminal step the env was reset
    if episodes is not None:  # the other breaks are time-limit truncations, stored as not terminated
        timeouts = sum(e == "timeout" for e, _ in episodes)
        assert (~chained & ~terminated).sum() <= timeouts
    # a terminated transition's margins say why: success (l > 0) or failure (g < 0)
    term = chunk["terminated"]
    assert ((chunk["next_l"][term] > 0) | (chunk["next_g"][term] < 0)).all()


def test_rollout_worker_chunks_mean_what_the_buffer_expects():
    worker = RolloutWorker(ENV, seed=3, worker=0, n_envs=2, noise_std=0.3)
    chunk, episodes = worker.collect(CHUNK, random=True)
    assert len(chunk["obs"]) == CHUNK
    check_meaning(chunk, 2, episodes)
    assert episodes and all(isinstance(e, str) and t >= 1 for e, t in episodes)


def test_per_episode_noise_is_drawn_in_range_and_redrawn_at_each_reset():
    from safemanip.rl.networks import Actor, actor_arrays

    worker = RolloutWorker(ENV, seed=3, worker=0, n_envs=2, noise_std=0.3, noise_per_episode=True)
    worker.set_weights(actor_arrays(Actor(observation_dim(2), 3, (16, 16))))
    seen = {tuple(worker.env_noise)}
    for _ in range(60):
        worker.step_all(random=False)
        assert ((worker.env_noise >= 0.0) & (worker.env_noise <= 0.3)).all()
        seen.add(tuple(worker.env_noise))
    assert len(seen) > 1 and worker.episodes  # episodes ended and drew new stds
    fixed = RolloutWorker(ENV, seed=3, worker=0, n_envs=2, noise_std=0.3)
    assert (fixed.env_noise == 0.3).all()


def _lag_one_correlation(noise_color: float) -> np.ndarray:
    """Per action axis, the correlation of consecutive exploration actions within an episode, with an actor
    that always outputs 0 (so the actions are the noise)."""
    from safemanip.rl.networks import Actor, actor_arrays

    worker = RolloutWorker(ENV, seed=3, worker=0, n_envs=1, noise_std=0.1, noise_color=noise_color)
    worker.set_weights([0 * a for a in actor_arrays(Actor(observation_dim(2), 3, (16, 16)))])
    chunk, episodes = worker.collect(300, random=False)
    act = chunk["act"]
    same_episode = np.array([np.array_equal(chunk["next_obs"][i], chunk["obs"][i + 1]) for i in range(len(act) - 1)])
    assert episodes and same_episode.sum() > 200  # several episodes, most pairs within one
    x, y = act[:-1][same_episode], act[1:][same_episode]
    return np.array([np.corrcoef(x[:, d], y[:, d])[0, 1] for d in range(3)])


def test_coloured_exploration_noise_is_correlated_within_an_episode_and_white_noise_is_not():
    assert (np.abs(_lag_one_correlation(0.0)) < 0.2).all()  # white: independent every step
    assert (_lag_one_correlation(1.0) > 0.5).all()  # pink
    assert (_lag_one_correlation(2.0) > 0.9).all()  # red: a slow drift
    from safemanip.rl.networks import Actor, actor_arrays

    worker = RolloutWorker(ENV, seed=3, worker=0, n_envs=1, noise_std=0.1, noise_color=1.0)
    worker.set_weights(actor_arrays(Actor(observation_dim(2), 3, (16, 16))))
    for _ in range(200):  # each episode starts a sequence of its own
        worker.step_all(random=False)
        if worker.episodes:
            assert worker.noise_seq[0] is None
            worker.step_all(random=False)
            assert worker.noise_t[0] == 1
            break
    else:
        pytest.fail("no episode ended in 200 steps")
    with pytest.raises(ConfigError, match="noise_color"):
        TrainConfig(**{**CFG, "noise_color": 2.5})


def test_local_process_pool_streams_the_same_transitions_as_the_worker_class():
    cfg = TrainConfig(**CFG)
    pool = LocalPool(cfg, env_builder(ENV), seed=5, env_steps=0, updates=0)
    try:
        chunk, _ = pool.get(timeout=60)
    finally:
        pool.close()
    reference, _ = RolloutWorker(ENV, seed=5, worker=0, n_envs=2, noise_std=cfg.exploration_noise,
                              noise_per_episode=cfg.noise_per_episode).collect(CHUNK, True)
    check_meaning(chunk, 2)
    for k in TRANSITION_KEYS:  # same seeds, same code: the very same transitions
        np.testing.assert_array_equal(chunk[k], reference[k])


@pytest.mark.slow
def test_ray_actors_give_the_same_transitions_as_local_workers():
    ray = pytest.importorskip("ray")
    from safemanip.rl.networks import Actor, actor_arrays

    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False)
    try:
        cfg = TrainConfig(**{**CFG, "random_steps": CHUNK, "backend": "ray"})
        pool = RayPool(cfg, env_builder(ENV), seed=7, env_steps=0, updates=0)
        arrays = actor_arrays(Actor(observation_dim(2), 3, (16, 16)))
        pool.broadcast(arrays)
        chunks = []
        deadline = time.time() + 120
        while len(chunks) < 2 and time.time() < deadline:  # one random chunk, then one with the actor
            try:
                chunks.append(pool.get(timeout=1.0)[0])
            except queue.Empty:
                pass
        pool.close()
    finally:
        ray.shutdown()
    assert len(chunks) == 2 and pool.env_steps == 2 * CHUNK
    local = RolloutWorker(ENV, seed=7, worker=0, n_envs=2, noise_std=cfg.exploration_noise,
                          noise_per_episode=cfg.noise_per_episode)
    local.set_weights(arrays)
    expected = [local.collect(CHUNK, random=True)[0], local.collect(CHUNK, random=False)[0]]
    for got, want in zip(chunks, expected):
        check_meaning(got, 2)
        for k in TRANSITION_KEYS:
            np.testing.assert_array_equal(got[k], want[k])


# ------------------------------------------------------------------------------------------ selection-aware
def test_selection_aware_env_shows_k_selected_slots_and_judges_all_objects():
    from safemanip.selection.reducer import Reducer
    from safemanip.selection.selectors import DynamicKNN
    from safemanip.selection.view import EnvViewBuilder

    cfg = TrainConfig(k=2, scene_objects=5, env={"max_episode_steps": 30})
    env = training_env(cfg)
    obs, info = env.reset(seed=11)
    assert obs.shape == (observation_dim(2),) and len(info["names"]) == 5
    # the same pipeline by hand, as evaluation/episode.py runs it at deployment
    builder, knn, reducer = EnvViewBuilder(), DynamicKNN(4), Reducer(2, "conservative")
    builder.reset(env.env)
    view = builder.view(env.env, env.env.scene_state(), 0)
    knn.reset(view, 2)
    np.testing.assert_array_equal(obs, reducer(env.env.scene_state(), knn.select(view, 2), env.env.constraints))
    picks = [tuple(env.selected)]
    for t in range(1, 13):
        obs, _, terminated, truncated, info = env.step(np.array([0.3, 0.0, 0.0]))
        if terminated or truncated:
            break
        view = builder.view(env.env, env.env.scene_state(), t)
        np.testing.assert_array_equal(obs, reducer(env.env.scene_state(), knn.select(view, 2), env.env.constraints))
        picks.append(tuple(env.selected))
    if info["event"].startswith("failure:") and info["object_id"] is not None:
        assert 0 <= info["object_id"] < 5  # the judge names objects of the full scene


def test_dynamic_radius_training_env_leaves_absent_slots_empty():
    cfg = TrainConfig(k=4, scene_objects=6, network="set", selector="dynamic-radius", selection_radius=0.3)
    env = training_env(cfg)
    obs, _ = env.reset(seed=2)
    slots = obs[ROBOT_DIM:].reshape(4, SLOT_DIM)
    present = slots[:, 6:9].sum(1) > 0.5
    assert present.sum() == len(env.selected) <= 4
    assert np.all(slots[~present] == 0)  # absent slots are all zero: the set network masks them
    box = env.env.scene_state().bottom_pos
    for i in env.selected:
        assert np.linalg.norm(env.env.scene_state().obj_pos[i, :2] - box[:2]) <= 0.3


def test_mixed_clutter_draws_each_scene_size_pads_flat_slots_with_dummies_and_is_reproducible():
    from safemanip.selection.reducer import DUMMY_POSITIONS

    cfg = TrainConfig(k=4, scene_objects_min=2, env={"max_episode_steps": 30})
    env, again = training_env(cfg), training_env(cfg)
    sizes = []
    for episode in range(24):
        seed = 5 if episode == 0 else None  # seeded once, as a rollout worker does
        obs, info = env.reset(seed=seed)
        obs_again, _ = again.reset(seed=seed)
        np.testing.assert_array_equal(obs, obs_again)  # the same stream of scene sizes and scenes
        n = len(info["names"])
        sizes.append(n)
        assert obs.shape == (observation_dim(4),) and len(env.env.names) == n
        slots = obs[ROBOT_DIM:].reshape(4, SLOT_DIM)
        if n < 4:  # the flat MLP's empty slots hold far-away dummies, standing still, typed no_contact
            dummies = slots[n:]
            np.testing.assert_allclose(np.sort(dummies[:, 0]), np.sort(DUMMY_POSITIONS[:4 - n, 0]), atol=1e-6)
            assert np.all(dummies[:, 3:6] == 0) and np.all(dummies[:, 6:9] == [1, 0, 0])
    assert set(sizes) == {2, 3, 4}  # every size from scene_objects_min to k comes up
    # a set network gets absent (all-zero) slots instead
    sparse = training_env(TrainConfig(k=4, scene_objects_min=1, network="set"))
    for seed in range(20):
        obs, info = sparse.reset(seed=seed)
        n = len(info["names"])
        if n < 4:
            assert np.all(obs[ROBOT_DIM + n * SLOT_DIM:] == 0)
            break
    else:
        raise AssertionError("no sparse scene in 20 draws")


def test_mixed_selectors_draw_knn_or_radius_per_episode_reproducibly_for_set_networks_only():
    """``selector='mixed'``: each episode's selector is drawn from the env's seeded generator; a dynamic-radius
    episode leaves the slots of objects beyond the radius absent (zero), a dynamic-kNN one fills all k."""
    cfg = TrainConfig(k=4, scene_objects=6, selector="mixed", network="set", env={"max_episode_steps": 30})
    env, again = training_env(cfg), training_env(cfg)
    drawn, filled = [], {"dynamic-knn": set(), "dynamic-radius": set()}
    for episode in range(16):
        seed = 3 if episode == 0 else None  # seeded once, as a rollout worker does
        obs, info = env.reset(seed=seed)
        obs_again, _ = again.reset(seed=seed)
        np.testing.assert_array_equal(obs, obs_again)
        assert env.selector_name == again.selector_name and len(info["names"]) == 6
        drawn.append(env.selector_name)
        slots = obs[ROBOT_DIM:].reshape(4, -1)
        filled[env.selector_name].add(int(np.count_nonzero(np.abs(slots).sum(axis=1))))
    assert set(drawn) == {"dynamic-knn", "dynamic-radius"}
    assert filled["dynamic-knn"] == {4}  # six objects: the four nearest, always
    assert min(filled["dynamic-radius"]) < 4  # some objects stand beyond 0.35 m at the start
    with pytest.raises(ConfigError, match="selector 'mixed' hands the policy a varying number"):
        TrainConfig(k=4, scene_objects=6, selector="mixed")


def test_config_rejects_mixed_clutter_outside_one_to_the_largest_scene():
    from safemanip.rl.config import ConfigError

    with pytest.raises(ConfigError, match="scene_objects_min must be in 1..4"):
        TrainConfig(k=4, scene_objects_min=5)
    with pytest.raises(ConfigError, match="scene_objects_min must be in 1..6"):
        TrainConfig(k=2, scene_objects=6, scene_objects_min=0)


def test_object_size_reaches_the_env_and_the_selection_aware_reducer():
    plain, sized = TrainConfig(k=2), TrainConfig(k=2, env={"object_size": True})
    assert plain.env_kwargs["object_size"] is False and sized.env_kwargs["object_size"] is True
    for cfg in (sized, TrainConfig(k=2, scene_objects=4, env={"object_size": True})):
        env = training_env(cfg)
        obs, _ = env.reset(seed=1)
        assert obs.shape == (observation_dim(2, object_size=True),) == env.observation_space.shape
        env.close()


def test_config_rejects_dynamic_radius_for_the_flat_mlp():
    from safemanip.rl.config import ConfigError

    with pytest.raises(ConfigError, match="use network 'set'"):
        TrainConfig(selector="dynamic-radius")
    with pytest.raises(ConfigError, match="scene_objects must be"):
        TrainConfig(k=3, scene_objects=2)


@pytest.mark.slow
def test_train_runs_a_set_network_with_selection_aware_dynamic_k_and_records_it(tmp_path):
    import json

    from safemanip.rl.checkpoint import load_policy
    from safemanip.rl.numpy_actor import NumpySetActor
    from safemanip.rl.train import train

    cfg = TrainConfig(k=3, scene_objects=5, network="set", selector="dynamic-radius", set_embed=16, env={"object_size": True, "max_episode_steps": 40},
                      hidden=(32, 32), batch_size=32, buffer_size=5000, learning_starts=256, random_steps=256,
                      eval_episodes=2, eval_every_s=60, checkpoint_every_s=60, log_every_s=60, envs_per_collector=2,
                      env_steps_per_update=4.0, minutes=0.12, out_dir=str(tmp_path / "run"))
    run = train(cfg, progress=False, env_factory=SelectedSlotsEnv)
    summary = json.loads((run / "summary.json").read_text())
    assert summary["updates"] > 0 and summary["learner"]["dtype"] in ("fp32", "bf16") and summary["learner"]["reason"]
    assert summary["learner"]["cpu"]  # the speeds in the record belong to this CPU
    actor, meta = load_policy(run / "policy.safetensors")
    assert isinstance(actor, NumpySetActor) and meta["network"] == "set" and meta["k"] == 3
    assert meta["train_config"]["scene_objects"] == 5 and meta["env_kwargs"]["n_objects"] == 3  # eval sees a k=3 policy
    assert meta["env_kwargs"]["object_size"] and actor.slot_width == 10  # slots carry the footprint radius


def test_the_selection_aware_env_comes_from_the_closed_registry_only():
    """``slide-out-selected`` is a fixed registry name whose factory the caller hands in (the selection layer's
    ``SelectedSlotsEnv``; importing it registers nothing); a config cannot name it (nor a module), and a factory
    does not make an unknown name known."""
    from safemanip.rl import envs

    built = envs.env_builder(TrainConfig(k=2, scene_objects=3).rollout_env_kwargs, SelectedSlotsEnv)
    assert built.factory is SelectedSlotsEnv and built.kwargs["k"] == 2 and built.kwargs["n_objects"] == 3
    assert "env" not in built.kwargs
    with pytest.raises(ValueError, match="import SelectedSlotsEnv"):  # this module has imported it: still refused
        envs.env_builder(TrainConfig(k=2, scene_objects=3).rollout_env_kwargs)
    for name in (envs.SELECTED_ENV, "safemanip.selection.training_env:SelectedSlotsEnv"):
        with pytest.raises(ConfigError, match="registered envs"):
            TrainConfig.from_dict({"env_name": name})
    for factory in (None, SelectedSlotsEnv):
        with pytest.raises(ValueError, match="unknown env"):
            envs.make_env({"env": "selection:SelectedSlotsEnv"}, factory)


def test_evaluation_workers_build_the_selection_aware_env_resolved_in_the_parent():
    """Spawned evaluation workers get the factory resolved in the parent (by reference) and give the in-process
    result."""
    from safemanip.rl.networks import Actor, actor_arrays
    from safemanip.rl.rollout import evaluate_actor

    cfg = TrainConfig(k=2, scene_objects=4, env={"max_episode_steps": 10})
    arrays = actor_arrays(Actor(observation_dim(2), 3, (16, 16)))
    seeds = [5, 6]
    build = env_builder(cfg.rollout_env_kwargs, SelectedSlotsEnv)
    assert evaluate_actor(arrays, build, seeds, workers=2) == evaluate_actor(arrays, build, seeds, workers=1)


@pytest.mark.slow
def test_train_from_python_takes_the_selection_aware_env_as_its_factory(tmp_path):
    """``rl.train.train`` called from Python trains selection-aware when handed ``SelectedSlotsEnv``: the factory
    reaches the spawned rollout worker and the evaluations, and the run is recorded as ``safemanip train`` records
    it."""
    import json

    from safemanip.rl.checkpoint import load_policy
    from safemanip.rl.train import train

    cfg = TrainConfig(k=2, scene_objects=3, hidden=(32, 32), batch_size=32, buffer_size=5000, learning_starts=256,
                      random_steps=256, eval_episodes=2, eval_every_s=60, checkpoint_every_s=60, log_every_s=60,
                      envs_per_collector=2, env_steps_per_update=4.0, env={"max_episode_steps": 40}, total_env_steps=768,
                      out_dir=str(tmp_path / "run"))
    run = train(cfg, progress=False, env_factory=SelectedSlotsEnv)
    summary = json.loads((run / "summary.json").read_text())
    assert summary["env_steps"] >= 768 and summary["updates"] > 0 and summary["final_eval"]["episodes"] == 2
    meta = load_policy(run / "policy.safetensors")[1]
    assert meta["train_config"]["scene_objects"] == 3 and meta["env_kwargs"]["n_objects"] == 2


def test_train_without_the_selection_aware_factory_says_which_to_pass(tmp_path):
    """A selection-aware config and no factory, or a factory the worker processes cannot receive: refused with
    what to pass, before the run folder is made."""
    from safemanip.rl.train import train

    cfg = TrainConfig(k=2, scene_objects=3, out_dir=str(tmp_path / "run"))
    with pytest.raises(ValueError, match=r"from safemanip\.selection\.training_env import SelectedSlotsEnv, then "
                                         r"train\(cfg, env_factory=SelectedSlotsEnv\)"):
        train(cfg, progress=False)
    with pytest.raises(ConfigError, match="module-level class or function"):
        train(cfg, progress=False, env_factory=lambda **kwargs: SelectedSlotsEnv(**kwargs))
    assert not (tmp_path / "run").exists()
