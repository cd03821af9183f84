"""Env steps per second next to raw ``mj_step`` throughput of the same physics, in one run, per embodiment.

    python benchmarks/env_throughput.py [--steps 2000] [--repeats 5] [--embodiments panda hand]

Raw physics = the same compiled model stepped with bare ``mj_step`` (25 substeps per env step in one
call) from the same initial states with the same actuator commands the env produced: the env's ceiling
if it did nothing but integrate. "raw, no judge" is the same replay on the scene compiled without the
per-substep judge sensors and contact gap, so its difference to "raw" is what judging costs inside
MuJoCo. The controller (the Panda's differential IK, the hand's set-point write) and the judge's Python
side (one history gather and the substep margins) are timed separately, in microseconds per env step.
Actions: the scripted controller plus noise, so episodes look like a rollout's. Resets are inside the env
rate (a rollout pays them too) and also shown alone ("reset ms", per reset); these use one fixed object
set, so a reset never compiles. A second table prices what training and evaluation pay: a reset into an
object set that another env of the process compiled (a fresh MjData only), and one into a set new to the
process (it compiles a model). One process, one thread;
medians over interleaved repeats.
"""

from __future__ import annotations

import argparse
import statistics
import time

import mujoco
import numpy as np

from safemanip.control.scripted import ScriptedController
from safemanip.env.slide_out import SlideOutEnv
from safemanip.scene.builder import build_model, build_spec, scene_index
from safemanip.scene.embodiment import make_embodiment

STATE = mujoco.mjtState.mjSTATE_INTEGRATION


def _physics_state(model, data) -> np.ndarray:
    state = np.empty(mujoco.mj_stateSize(model, STATE))
    mujoco.mj_getState(model, data, state, STATE)
    return state


def env_rate(env: SlideOutEnv, steps: int, rng):
    """(env steps/s, mean episode length, ms per reset, ctrl per step, act per step, episode start states)."""
    controller = ScriptedController()
    noise = rng.normal(0, 0.3, (steps, 3))
    ctrls: list = []  # per step, the embodiment's phases ((substeps, ctrl), ...)
    acts = np.zeros((steps, env.model.na))
    _, info = env.reset(seed=int(rng.integers(1 << 30)))
    controller.reset()
    starts = {0: _physics_state(env.model, env.data)}
    elapsed = resetting = 0.0
    for i in range(steps):
        action = np.clip(controller.act(info, env) + noise[i], -1, 1)  # the controller is not timed
        acts[i] = env.data.act  # the set-points the step starts from (the embodiment's controller only reads them)
        t0 = time.perf_counter()
        _, _, term, trunc, info = env.step(action)
        if term or trunc:
            t1 = time.perf_counter()
            _, info = env.reset()
            resetting += time.perf_counter() - t1
        elapsed += time.perf_counter() - t0
        # what the embodiment commanded for this step (its phases), copied here: the bookkeeping is not timed
        ctrls.append(tuple((n, np.array(ctrl, copy=True)) for n, ctrl in env._bench_phases))
        if term or trunc:
            controller.reset()
            starts[i + 1] = _physics_state(env.model, env.data)
    resets = len(starts) - 1
    return steps / elapsed, steps / len(starts), 1e3 * resetting / max(resets, 1), ctrls, acts, starts


def raw_rate(model, data, ctrls, acts, starts, actuators) -> float:
    """Replays the env's physics: the same initial states and actuator commands (each step's phases), only mj_step."""
    t0 = time.perf_counter()
    for i in range(len(ctrls)):
        if i in starts:
            mujoco.mj_setState(model, data, starts[i], STATE)
        data.act[:] = acts[i]
        for substeps, ctrl in ctrls[i]:
            data.ctrl[actuators] = ctrl
            mujoco.mj_step(model, data, nstep=substeps)
    return len(ctrls) / (time.perf_counter() - t0)


def _record_commands(env: SlideOutEnv) -> None:
    """Wrap the embodiment's controller so each step's phases are kept (only a reference inside the timed step: the
    phases' arrays are new each step and never written to, ``env_rate`` copies them after the step)."""
    controller = env.controller
    original = controller.command_velocity

    def command_velocity(model, data, binding, velocity, dt):
        env._bench_phases = phases = original(model, data, binding, velocity, dt)
        return phases

    controller.command_velocity = command_velocity


def component_costs(env: SlideOutEnv, repeats: int = 2000) -> tuple[float, float]:
    """(controller us per call, judge us per step) on the env's current state."""
    m, d, b = env.model, env.data, env.binding
    velocity = np.array([0.5, 0.1, 0.0])
    saved = _physics_state(env.model, env.data)
    t0 = time.perf_counter()
    for _ in range(repeats):
        env.controller.command_velocity(m, d, b, velocity, 0.05)
    controller = (time.perf_counter() - t0) / repeats * 1e6
    mujoco.mj_setState(m, d, saved, STATE)
    t0 = time.perf_counter()
    for _ in range(repeats):
        env._margins(substeps=True)
    with_substeps = (time.perf_counter() - t0) / repeats
    t0 = time.perf_counter()
    for _ in range(repeats):
        env._margins()
    end_only = (time.perf_counter() - t0) / repeats
    return controller, (with_substeps - end_only) * 1e6


def reset_costs(n: int, embodiment: str, resets: int = 40) -> tuple[float, float, float]:
    """(median ms of a reset whose object set this env saw before, of one whose set another env in the process
    compiled, of one that draws a set new to the process).

    The throughput rows above use one fixed object set, so their resets always find the compiled scene in
    the env's cache. Training and evaluation draw the objects' names per episode, and most draws are new
    to an env (N = 4 fragile: 330 sets, N = 6 from the whole catalog: 1.6 million). Compiled models are
    shared by the envs of a process (``MODEL_CACHE_SIZE`` of them), so a set met before anywhere in the
    process costs only a fresh MjData; a set new to the process compiles a model."""
    build_model.cache_clear()
    scene_index.cache_clear()
    first, second = SlideOutEnv(n_objects=n, embodiment=embodiment), SlideOutEnv(n_objects=n, embodiment=embodiment)
    cached, shared, fresh = [], [], []
    for i in range(resets):
        t0 = time.perf_counter()
        first.reset(seed=10_000 + i)  # a new draw of names (a repeat of an earlier set is possible but rare)
        fresh.append(time.perf_counter() - t0)
        t0 = time.perf_counter()
        first.reset(seed=10_000 + i)  # the same scene again: this env's own cache
        cached.append(time.perf_counter() - t0)
        t0 = time.perf_counter()
        second.reset(seed=10_000 + i)  # new to this env, compiled by the other
        shared.append(time.perf_counter() - t0)
    first.close()
    second.close()
    return tuple(1e3 * statistics.median(x) for x in (cached, shared, fresh))


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--steps", type=int, default=2000)
    p.add_argument("--repeats", type=int, default=5)
    p.add_argument("--embodiments", nargs="+", default=["panda", "hand"], choices=["panda", "hand"])
    p.add_argument("--objects", nargs="+", type=int, default=[0, 2, 6])
    args = p.parse_args()
    rows = []
    names = ("red mug", "toy sheep", "plant pot", "soda can", "wine glass", "tennis ball")
    for embodiment in args.embodiments:
        for n in args.objects:
            for sleep in (True, False):
                env = SlideOutEnv(n_objects=n, names=names[:n], sleep=sleep, embodiment=embodiment)
                _record_commands(env)
                env.reset(seed=0)
                bare = build_spec(names[:n], make_embodiment(embodiment, visual=False, gap=0.0), sleep=sleep,
                                  judge=False).compile()
                bare_data = mujoco.MjData(bare)
                rng = np.random.default_rng(0)
                envs, raws, bares, lengths, reset_ms = [], [], [], [], []
                for _ in range(args.repeats):
                    rate, length, reset, ctrls, acts, starts = env_rate(env, args.steps, rng)
                    envs.append(rate)
                    lengths.append(length)
                    reset_ms.append(reset)
                    raws.append(raw_rate(env.model, env.data, ctrls, acts, starts, env.binding.actuator_ids))
                    bare_starts = {}
                    for i, s in starts.items():  # same qpos/qvel/act, the bare model has no sensor history
                        mujoco.mj_setState(env.model, env.data, s, STATE)
                        bare_data.qpos[:], bare_data.qvel[:], bare_data.act[:] = env.data.qpos, env.data.qvel, env.data.act
                        bare_data.time = env.data.time
                        bare_starts[i] = _physics_state(bare, bare_data)
                    bares.append(raw_rate(bare, bare_data, ctrls, acts, bare_starts, env.binding.actuator_ids))
                env.reset(seed=1)
                env.step(np.array([0.5, 0.0, 0.0]))
                controller_us, judge_us = component_costs(env)
                e, r, b = statistics.median(envs), statistics.median(raws), statistics.median(bares)
                rows.append((embodiment, n, "on" if sleep else "off", e, r, e / r, b, controller_us, judge_us,
                             statistics.median(lengths), statistics.median(reset_ms)))
    print(f"{'robot':>6} {'N':>2} {'sleep':>5} {'env steps/s':>11} {'raw physics':>11} {'ratio':>5} "
          f"{'raw, no judge':>13} {'controller us':>13} {'judge us':>8} {'ep. len':>7} {'reset ms':>8}")
    for robot, n, s, e, r, ratio, b, c, j, length, reset in rows:
        print(f"{robot:>6} {n:>2} {s:>5} {e:>11.0f} {r:>11.0f} {ratio:>5.2f} {b:>13.0f} {c:>13.1f} {j:>8.1f} "
              f"{length:>7.1f} {reset:>8.2f}")
    print(f"\n{'robot':>6} {'N':>2} {'reset ms: same env':>18} {'model from the process':>22} {'new object set':>14}")
    for embodiment in args.embodiments:
        for n in args.objects:
            if n:
                cached, shared, fresh = reset_costs(n, embodiment)
                print(f"{embodiment:>6} {n:>2} {cached:>18.2f} {shared:>22.2f} {fresh:>14.2f}")


if __name__ == "__main__":
    main()
