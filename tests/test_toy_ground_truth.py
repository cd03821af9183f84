"""Ground truth for the reach-avoid learner on a problem solved exactly (safemanip.rl.toy).

The grid solution is checked on its own (Bellman fixed point against the env's dynamics, hand-placed
states, its policy in the continuous env), then the shipped model (actor + critic trained by the same
Learner/backup code through train()) is scored against it. Retrain the shipped model with the command in
tests/data/toy_reach_avoid/README.md.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from safemanip.toy import oracle as toy
from safemanip.toy.system import SPEC, ToyReachAvoidEnv

MODEL = Path(__file__).parent / "data" / "toy_reach_avoid" / "model.safetensors"


@pytest.fixture(scope="module")
def grid():
    return toy.solve_grid(SPEC, n=1)


@pytest.fixture(scope="module")
def states():
    return toy.sample_states(np.random.default_rng(2024), 4000)


# ------------------------------------------------------------------ the env
def test_env_info_contract_and_events():
    env = ToyReachAvoidEnv(max_episode_steps=5)
    obs, info = env.reset(seed=3)
    assert obs.shape == (4,) and env.action_space.shape == (2,)
    assert {"l", "g", "event", "t"} <= set(info) and info["event"] == "running" and info["t"] == 0
    assert info["g"] >= 0 and info["l"] <= 0
    # at rest just left of the target, accelerate right: enters the target -> success, terminated
    env.reset(options={"state": [0.35, 0.0, 0.0, 0.0]})
    events = []
    for _ in range(5):
        _, r, term, trunc, info = env.step(np.array([1.0, 0.0]))
        events.append(info["event"])
        if term or trunc:
            break
    assert events[-1] == "success" and term and not trunc and info["l"] > 0 and r == min(info["l"], info["g"])
    # full speed into the right wall from 0.1 away -> failure:oob on the first step
    env.reset(options={"state": [0.92, -0.8, 2.0, 0.0]})
    _, _, term, trunc, info = env.step(np.array([-1.0, 0.0]))
    assert (info["event"], term, trunc) == ("failure:oob", True, False) and info["g"] < 0
    # into the obstacle -> failure:hard
    env.reset(options={"state": [-0.4, 0.0, 2.0, 0.0]})
    _, _, term, _, info = env.step(np.zeros(2))
    assert info["event"] == "failure:hard" and term
    # standing still -> timeout, truncated not terminated
    env.reset(options={"state": [-0.6, 0.6, 0.0, 0.0]})
    for _ in range(5):
        _, _, term, trunc, info = env.step(np.zeros(2))
    assert (info["event"], term, trunc, info["t"]) == ("timeout", False, True, 5)


def test_reset_is_seeded_and_uniform_over_running_states():
    env = ToyReachAvoidEnv()
    a = [env.reset(seed=11)[0] for _ in range(2)]
    assert np.array_equal(a[0], a[1])
    starts = np.array([env.reset()[0] for _ in range(3000)])
    l, g, _, _ = toy.margins(starts)
    assert (g >= 0).all() and (l <= 0).all()
    assert np.abs(starts[:, :2]).max() <= 1 and np.abs(starts[:, 2:]).max() <= SPEC.v_max
    # uniform: each quadrant of the velocity box gets about a quarter
    quad = (starts[:, 2] > 0) * 2 + (starts[:, 3] > 0)
    assert np.bincount(quad, minlength=4).min() > 0.2 * len(starts)


# ------------------------------------------------------------------ the grid solution on its own
def test_grid_is_a_fixed_point_of_the_reach_avoid_bellman_equation_under_the_env_dynamics(grid):
    """Recompute V(s) = min(g, max(l, max_a V(f(s, a)))) at random lattice states with the env's own
    step function (not the solver's index shifts): the successors must land on the lattice, and the
    equation must hold exactly."""
    rng = np.random.default_rng(0)
    V, pad = grid.values, grid.pad
    n_inner = V.shape[0] - 2 * pad
    idx = np.stack([rng.integers(pad, pad + n_inner, 3000), rng.integers(pad, pad + n_inner, 3000),
                    rng.integers(0, V.shape[2], 3000), rng.integers(0, V.shape[3], 3000)], 1)
    s = np.stack([-1 + (idx[:, 0] - pad) * grid.h_p, -1 + (idx[:, 1] - pad) * grid.h_p,
                  -SPEC.v_max + idx[:, 2] * grid.h_v, -SPEC.v_max + idx[:, 3] * grid.h_v], 1)
    best = np.full(len(s), -np.inf)
    for ax in (-1.0, 0.0, 1.0):
        for ay in (-1.0, 0.0, 1.0):
            nxt = toy.step_states(s, np.tile([ax, ay], (len(s), 1)))
            c = np.stack([(nxt[:, 0] + 1) / grid.h_p + pad, (nxt[:, 1] + 1) / grid.h_p + pad,
                          (nxt[:, 2] + SPEC.v_max) / grid.h_v, (nxt[:, 3] + SPEC.v_max) / grid.h_v], 1)
            assert np.abs(c - np.round(c)).max() < 1e-6, "a successor left the lattice"
            ci = np.round(c).astype(int)
            best = np.maximum(best, V[ci[:, 0], ci[:, 1], ci[:, 2], ci[:, 3]])
    l, g, _, _ = toy.margins(s)
    rhs = np.minimum(g, np.maximum(l, best))
    np.testing.assert_allclose(V[idx[:, 0], idx[:, 1], idx[:, 2], idx[:, 3]], rhs, atol=1e-6)
    assert 10 < grid.sweeps < 100


def test_grid_on_hand_placed_states(grid):
    at = lambda *s: float(grid(np.array(s, dtype=float)))  # noqa: E731
    assert at(0.6, 0.0, 0.0, 0.0) == pytest.approx(SPEC.target_radius, abs=1e-6)  # target centre: V = l
    assert at(0.0, 0.0, 0.0, 0.0) < 0  # inside the obstacle
    assert at(-0.7, 0.7, 0.0, 0.0) > 0  # at rest in free space, far side of the obstacle
    assert at(0.9, 0.5, 2.0, 0.0) < 0  # braking needs v^2 / 2a = 1 m, the wall is 0.1 m away
    assert at(0.9, 0.5, -2.0, 0.0) > 0  # same place, moving away from the wall
    assert at(-0.55, 0.0, 2.0, 0.0) < 0  # full speed at the obstacle from 0.25 m
    assert at(-0.55, 0.0, 0.0, 0.0) > 0  # same place at rest


def test_grid_labels_hold_in_the_continuous_env(grid, states):
    """The grid's own policy reaches the target from the grid-safe states, and the grid-unsafe states
    (off the resolution band) are not reached: the labels mean what they say off the lattice too."""
    check = toy.grid_self_check(grid, states)
    assert 0.6 < check["grid_safe"] < 0.8
    assert check["grid_policy_success_on_grid_safe"] >= 0.97
    assert check["grid_policy_success_on_grid_unsafe_off_band"] <= 0.01


# ------------------------------------------------------------------ the shipped learned model
def test_shipped_model_is_small_and_complete():
    assert MODEL.stat().st_size < 1_000_000
    actor, critic, meta = toy.load_model(MODEL)
    assert critic.q.heads == 2 and meta["train_config"]["algorithm"] == "rarl"
    assert meta["train_config"]["env_factory"] == "safemanip.rl.toy:ToyReachAvoidEnv" and meta["command"]


def test_shipped_model_against_the_grid(grid, states):
    actor, critic, meta = toy.load_model(MODEL)
    m = toy.ground_truth_metrics(actor, critic, grid, states, meta["train_config"]["gamma"], ceiling=False)
    print(toy.metrics_table(m))
    assert m["precision"] >= 0.97  # the brief's targets
    assert m["false_safe_of_predicted"] <= 0.03 and m["false_safe_of_unsafe"] <= 0.03
    assert m["success_grid_safe"] >= 0.93  # mu reaches nearly all of the true reach-avoid set
    # the sign: chance-corrected, and near the discount ceiling (about 0.73 at gamma 0.998, see the README)
    assert m["sign_agreement"] >= 0.65 and m["balanced_accuracy"] >= 0.75 and m["kappa"] >= 0.35
    assert m["critic_vs_own_return"] >= 0.65
    assert m["predicted_safe"] >= 0.3  # not the trivial "nothing is safe"


# ------------------------------------------------------------------ training from scratch
@pytest.mark.slow
def test_brief_training_learns_better_than_chance(tmp_path, grid):
    """A short training on the toy through the real loop (``rl.train.train``; 24k env steps, over 10k updates), with
    the rollout workers inline (``backend="inline"``) and fp32, so that the run is deterministic for its seed: the
    sign of the learned V already agrees with the grid's well beyond chance (Cohen's kappa corrects the agreement
    for the two sign rates; an untrained critic scores about 0). Faster target tracking and a higher learning rate
    than the shipped model, to learn something quickly."""
    from safemanip.rl.checkpoint import read_checkpoint
    from safemanip.rl.learner import Learner
    from safemanip.rl.train import train

    cfg = toy.toy_config(str(tmp_path / "run"), minutes=None, total_env_steps=24_000, gamma=0.995, gamma_start=0.95,
                         polyak=0.98, batch_size=128, learning_rate=2e-3, env_steps_per_update=2.0,
                         learning_starts=1000, random_steps=2000, backend="inline", precision="fp32",
                         eval_episodes=5)
    run = train(cfg, progress=False)
    tensors, _, meta = read_checkpoint(run / "checkpoint")
    assert meta["updates"] > 10_000, f"only {meta['updates']} learner updates for 24k env steps"
    learner = Learner(4, 2, cfg)
    learner.load_state_tensors(tensors)
    states = toy.sample_states(np.random.default_rng(7), 3000)
    m = toy.ground_truth_metrics(learner.actor, learner.critic, grid, states, cfg.gamma, ceiling=False)
    print(toy.metrics_table(m))
    assert m["kappa"] > 0.08 and m["balanced_accuracy"] > 0.55  # untrained: about 0 and 0.5
    assert m["false_safe_of_unsafe"] <= 0.03
