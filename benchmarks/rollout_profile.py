"""Where a rollout worker's time goes (issue 42): one ``RolloutWorker`` of a run's config, alone in this process.

    python benchmarks/rollout_profile.py [--config results/training/rarl-k2-conservative-s0/config.json]
        [--steps 5000] [--policy trained|untrained|random|POLICY] [--cprofile FILE]

The worker steps its ``envs_per_collector`` envs round-robin as in training (``step_all``, a chunk taken every
``CHUNK`` transitions and pickled as the local pool's queue would) and every part is timed in CPU seconds of this
process: physics (``mj_step`` inside ``env.step``), the rest of ``env.step`` (the controller, the judge's margins,
the observation), ``env.reset`` (the scene's compiled model and data, the gate/exit check on the planner's
free-space map, the rest of the sampling), the actor's forward pass, the exploration noise, the collector's
bookkeeping, taking the chunk, pickling it. Shares of the worker's time, and microseconds per env step.

``--policy``: ``trained`` (default) acts with the shipped policy of the recipe (``rarl-k2-conservative-s0``: short,
successful episodes, so frequent resets, as in most of a run), ``untrained`` with a freshly initialised actor (the
start of a run: long episodes), ``random`` with uniform actions (the first ``random_steps``), or a policy file.
The policy's exploration noise is the config's. Rates are CPU-time rates: a worker with a whole core reaches them;
set them beside ``training_loop.py``'s ``perf/rollout_cpu_ms_per_step`` to see what a run's worker pays on top.
"""

from __future__ import annotations

import argparse
import time
from collections import Counter
from multiprocessing.reduction import ForkingPickler
from pathlib import Path

import mujoco
import numpy as np

from safemanip.rl.collector import CHUNK, RolloutWorker
from safemanip.rl.config import load_run_config
from safemanip.rl.envs import env_builder

RECIPE = Path(__file__).resolve().parents[1] / "results" / "training" / "rarl-k2-conservative-s0" / "config.json"
SHIPPED = "rarl-k2-conservative-s0"


class Clock:
    """CPU seconds by section; ``wrap`` times a callable under a name (nested sections count in both)."""

    def __init__(self):
        self.total: Counter = Counter()

    def wrap(self, name: str, fn, when=None):
        total = self.total

        def timed(*args, **kwargs):
            if when is not None and not when():
                return fn(*args, **kwargs)
            t0 = time.process_time()
            try:
                return fn(*args, **kwargs)
            finally:
                total[name] += time.process_time() - t0

        return timed


def patch(clock: Clock, owner, attr: str, name: str, when=None) -> None:
    """Time ``owner.attr`` (a module function or a class's method) if it exists (the env's internals may move)."""
    fn = getattr(owner, attr, None)
    if fn is not None:
        setattr(owner, attr, clock.wrap(name, fn, when))


def actor_weights(cfg, policy: str, obs_dim: int, act_dim: int):
    if policy == "random":
        return None
    if policy == "untrained":
        import torch

        from safemanip.rl.learner import Learner
        from safemanip.rl.networks import actor_arrays

        torch.manual_seed(0)
        return actor_arrays(Learner(obs_dim, act_dim, cfg).actor)
    from safemanip.rl.checkpoint import load_policy

    return load_policy(SHIPPED if policy == "trained" else policy)[0].arrays()


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--config", type=Path, default=RECIPE, help="a run's config.json (default: the benchmark recipe's)")
    p.add_argument("--steps", type=int, default=5000, help="env steps, all envs together")
    p.add_argument("--policy", default="trained", help="trained (default), untrained, random, or a policy file")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--cprofile", type=Path, help="also write a cProfile of the stepping to this file")
    args = p.parse_args()
    cfg, _ = load_run_config(args.config)
    factory = None
    if cfg.selection_aware:  # as safemanip train passes it
        from safemanip.selection.training_env import SelectedSlotsEnv

        factory = SelectedSlotsEnv
    build = env_builder(cfg.rollout_env_kwargs, factory)
    probe = build()
    obs_dim, act_dim = probe.observation_space.shape[0], probe.action_space.shape[0]
    probe.close()
    weights = actor_weights(cfg, args.policy, obs_dim, act_dim)

    clock = Clock()
    stepping = [False]  # physics inside env.step only (a reset's mj_forward is the reset's)
    patch(clock, mujoco, "mj_step", "physics (mj_step)", when=lambda: stepping[0])
    from safemanip.env import sampling, slide_out

    for attr, name in (("is_its_kind", "scene check (planner free-space map)"), ("sample_placement", "placement"),
                       ("sample_route", "placement"), ("set_poses", "set poses (mj_resetData, mj_forward)")):
        patch(clock, sampling, attr, f"reset: {name}")
    patch(clock, slide_out.SlideOutEnv, "_sim", "reset: scene model and data (compile on a cache miss)",
          when=lambda: not stepping[0])
    for attr in ("_margins", "_observe", "_read_state"):
        patch(clock, slide_out.SlideOutEnv, attr, f"step: {attr}", when=lambda: stepping[0])

    worker = RolloutWorker(build, args.seed, 0, cfg.envs_per_collector, cfg.exploration_noise, cfg.noise_per_episode,
                           cfg.noise_color)
    if weights is not None:
        worker.set_weights(weights)
        worker.actor = clock.wrap("actor forward", worker.actor)
    worker._unit_noise = clock.wrap("exploration noise", worker._unit_noise)
    controllers: set[int] = set()  # an embodiment's controller may be shared by the envs: timed once
    for env in worker.envs:
        step, reset = env.step, env.reset

        def timed_step(action, _step=step):
            stepping[0] = True
            try:
                return _step(action)
            finally:
                stepping[0] = False

        env.step = clock.wrap("env.step", timed_step)
        env.reset = clock.wrap("env.reset", reset)
        controller = getattr(env, "controller", None)
        if controller is not None and hasattr(controller, "command_velocity") and id(controller) not in controllers:
            controllers.add(id(controller))
            controller.command_velocity = clock.wrap("step: controller (command_velocity)",
                                                     controller.command_velocity)
    random = weights is None
    for _ in range(4):  # first calls allocate
        worker.step_all(random)
    worker.take()
    clock.total.clear()

    profiler = None
    if args.cprofile:
        import cProfile

        profiler = cProfile.Profile()
        profiler.enable()
    steps, episodes, t0, c0 = 0, [], time.perf_counter(), time.process_time()
    while steps < args.steps:
        s0 = time.process_time()
        steps += worker.step_all(random)
        clock.total["step_all"] += time.process_time() - s0
        if worker.pending() >= CHUNK:
            s0 = time.process_time()
            chunk = worker.take()
            s1 = time.process_time()
            ForkingPickler.dumps(chunk)  # what the local pool's queue sends (timed, then dropped)
            clock.total["take (chunk arrays)"] += s1 - s0
            clock.total["pickle (queue put)"] += time.process_time() - s1
            episodes += chunk[1]
    cpu, wall = time.process_time() - c0, time.perf_counter() - t0
    if profiler is not None:
        profiler.disable()
        profiler.dump_stats(args.cprofile)
    episodes += worker.episodes

    t = clock.total
    physics = t["physics (mj_step)"]
    collector = t["step_all"] - t["env.step"] - t["env.reset"] - t["actor forward"] - t["exploration noise"]
    rows = [("env.step", t["env.step"]), ("  physics (mj_step)", physics),
            ("  env Python (controller, judge, observation, rest)", t["env.step"] - physics)]
    rows += [(f"    {k[6:]}", v) for k, v in sorted(t.items()) if k.startswith("step: ")]
    reset_parts = sorted((k, v) for k, v in t.items() if k.startswith("reset: "))
    rows += [("env.reset", t["env.reset"])] + [(f"  {k[7:]}", v) for k, v in reset_parts]
    rows += [("  rest of the reset", t["env.reset"] - sum(v for _, v in reset_parts)),
             ("actor forward (NumPy, all envs at once)", t["actor forward"]),
             ("exploration noise", t["exploration noise"]),
             ("collector bookkeeping (step_all's own code)", collector),
             ("take (chunk arrays)", t["take (chunk arrays)"]),
             ("pickle (queue put)", t["pickle (queue put)"])]
    lengths = [n for _, n in episodes]
    print(f"config {args.config}: {cfg.envs_per_collector} envs, policy {args.policy}; {steps} env steps, "
          f"{len(episodes)} episodes (mean length {np.mean(lengths) if lengths else float('nan'):.1f}: "
          f"{dict(Counter(e for e, _ in episodes))})")
    print(f"{steps / cpu:.0f} env steps per CPU-second ({steps / wall:.0f}/s wall; CPU share of this process "
          f"{cpu / wall:.2f}), timing included\n")
    print("| part | share | us per env step |")
    print("|---|---|---|")
    for name, seconds in rows:
        print(f"| {name} | {100 * seconds / cpu:.1f}% | {1e6 * seconds / steps:.0f} |")


if __name__ == "__main__":
    main()
