"""Env steps per second next to raw ``mj_step`` throughput of the same compiled model, in one run.

    python benchmarks/env_throughput.py [--steps 3000] [--repeats 5]

Raw physics = mj_step calls per second divided by the substeps per env step (25), i.e. the env's
ceiling if it did nothing but integrate. Both run on one core (one process, one thread) with the same
actions (a noisy scripted controller) and the same episode length. Numbers are medians over repeats, interleaved so that machine
noise hits both columns alike.
"""

from __future__ import annotations

import argparse
import statistics
import time

import mujoco
import numpy as np

from safemanip.control.scripted import ScriptedController
from safemanip.env.slide_out import SlideOutEnv


def _physics_state(env: SlideOutEnv) -> np.ndarray:
    spec = mujoco.mjtState.mjSTATE_INTEGRATION
    state = np.empty(mujoco.mj_stateSize(env.model, spec))
    mujoco.mj_getState(env.model, env.data, state, spec)
    return state


def env_rate(env: SlideOutEnv, steps: int, rng):
    """(env steps/s, mean steps per episode, actions, episode starts).

    Actions come from the scripted controller plus Gaussian noise, so episodes look like a training
    rollout's (a pull, then a slide) rather than random flailing that fails in five steps. Resets
    (placement sampling; no compilation, since the object names are fixed) are part of the cost.
    Each episode's initial physics state is recorded (outside the timed region) for the raw replay.
    """
    controller = ScriptedController()
    noise = rng.normal(0, 0.3, (steps, 3))
    actions = np.zeros((steps, 3))
    _, info = env.reset(seed=0)
    controller.reset()
    starts = {0: _physics_state(env)}
    elapsed = 0.0
    for i in range(steps):
        actions[i] = np.clip(controller.act(info, env) + noise[i], -1, 1)  # the controller is not timed
        t0 = time.perf_counter()
        _, _, term, trunc, info = env.step(actions[i])
        if term or trunc:
            _, info = env.reset()
        elapsed += time.perf_counter() - t0
        if term or trunc:
            controller.reset()
            starts[i + 1] = _physics_state(env)
    return steps / elapsed, steps / len(starts), actions, starts


def raw_rate(env: SlideOutEnv, actions: np.ndarray, starts: dict) -> float:
    """Replays exactly the env's physics: the same initial states, the same hand commands, only mj_step
    (25 substeps per env step in one call)."""
    m, d, b = env.model, env.data, env.binding
    spec = mujoco.mjtState.mjSTATE_INTEGRATION
    velocities = actions * (env.max_step / 0.05)
    t0 = time.perf_counter()
    for i in range(len(actions)):
        if i in starts:
            mujoco.mj_setState(m, d, starts[i], spec)
        d.act[b.act_adr] = d.qpos[b.qpos_adr]
        d.ctrl[b.actuator_ids] = d.ctrl[b.velocity_actuator_ids] = velocities[i]
        mujoco.mj_step(m, d, nstep=env.n_substeps)
    return len(actions) / (time.perf_counter() - t0)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--steps", type=int, default=3000)
    p.add_argument("--repeats", type=int, default=5)
    args = p.parse_args()
    rows = []
    names = ("red mug", "toy sheep", "plant pot", "soda can", "wine glass", "tennis ball")
    for n in (0, 2, 6):
        for sleep in (True, False):
            env = SlideOutEnv(n_objects=n, names=names[:n], sleep=sleep)
            rng = np.random.default_rng(0)
            envs, raws, lengths = [], [], []
            for _ in range(args.repeats):
                rate, length, actions, starts = env_rate(env, args.steps, rng)
                envs.append(rate)
                lengths.append(length)
                raws.append(raw_rate(env, actions, starts))
            e, r = statistics.median(envs), statistics.median(raws)
            rows.append((n, "on" if sleep else "off", e, r, e / r, statistics.median(lengths)))
    print(f"{'N':>3} {'sleep':>5} {'env steps/s':>12} {'raw physics':>12} {'ratio':>6} {'ep. length':>10}")
    for n, s, e, r, ratio, length in rows:
        print(f"{n:>3} {s:>5} {e:>12.0f} {r:>12.0f} {ratio:>6.2f} {length:>10.1f}")


if __name__ == "__main__":
    main()
