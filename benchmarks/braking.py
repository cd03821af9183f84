"""How far the held box goes once the arm is told to stop, against the safety filter's braking model; and what the
filter costs per control step next to the env's own step.

    python benchmarks/braking.py [--cost]

Empty table; the box is pulled out to the right, brought to rest, then pushed at full action in each of eight
directions for 2, 4 or 6 control steps, then given zero actions (the filter's brake). Per run: the box's speed and
the controller's command when the brake starts, the distance the box then travels, and what
``safety.braking.BrakingShield.slowing_distance`` predicts. The model must not predict less than the arm does
(the 'model - measured' column must be >= 0); its deceleration parameters were set from this table.
"""

from __future__ import annotations

import numpy as np

from safemanip.env.slide_out import SlideOutEnv
from safemanip.safety.braking import BrakingShield


def main() -> None:
    env = SlideOutEnv(n_objects=0)
    shield = BrakingShield()
    rows = []
    for angle in range(0, 360, 45):
        direction = np.array([np.cos(np.radians(angle)), np.sin(np.radians(angle)), 0.0])
        for pushes in (2, 4, 6):
            env.reset(seed=0)
            for _ in range(8):
                env.step(np.array([0.7, 0.0, 0.0], dtype=np.float32))
            for _ in range(15):
                env.step(np.zeros(3, dtype=np.float32))
            for _ in range(pushes):
                env.step(direction.astype(np.float32))
            state = env.scene_state()
            velocity, start = state.bottom_vel[:2].copy(), state.bottom_pos[:2].copy()
            speed, command = float(np.linalg.norm(velocity)), float(np.linalg.norm(env.setpoint.command[:2]))
            for _ in range(30):
                env.step(np.zeros(3, dtype=np.float32))
            travelled = float(np.linalg.norm(env.scene_state().bottom_pos[:2] - start))
            u = velocity / speed if speed > 1e-6 else direction[:2]
            predicted = shield.slowing_distance(speed, max(command, speed), u)
            rows.append((angle, pushes, speed, command, travelled, predicted))
    print(f"decel (x, y) = {shield.decel} m/s^2, lag {shield.lag} s\n")
    print("| direction | pushes | box speed m/s | command m/s | travelled cm | model cm | model - measured cm |")
    print("|---|---|---|---|---|---|---|")
    for angle, pushes, speed, command, travelled, predicted in rows:
        print(f"| {angle} deg | {pushes} | {speed:.2f} | {command:.2f} | {100 * travelled:.1f} | {100 * predicted:.1f} | "
              f"{100 * (predicted - travelled):+.1f} |")
    worst = min(p - t for *_, t, p in rows)
    print(f"\nleast margin of the model: {100 * worst:+.1f} cm (negative: the arm went further than predicted)")
    cost()


def cost(steps: int = 400) -> None:
    """Median microseconds of ``filter`` per control step against the env's step, random actions, N = 2 and 6."""
    import statistics
    import time

    print("\n| N | env step us | filter us (median) | filter us (p95) | overridden steps |")
    print("|---|---|---|---|---|")
    for n in (2, 6):
        env = SlideOutEnv(n_objects=n, layout="exit", exit_share=1.0)
        shield, rng = BrakingShield(), np.random.default_rng(0)
        env.reset(seed=0)
        filtering, stepping = [], []
        for _ in range(steps):
            action = rng.uniform(-1.0, 1.0, 3).astype(np.float32)
            t0 = time.perf_counter()
            action = shield.filter(env, action, env.constraints)
            t1 = time.perf_counter()
            _, _, terminated, truncated, _ = env.step(action)
            stepping.append(time.perf_counter() - t1)
            filtering.append(t1 - t0)
            if terminated or truncated:
                env.reset()
        print(f"| {n} | {1e6 * statistics.median(stepping):.0f} | {1e6 * statistics.median(filtering):.0f} | "
              f"{1e6 * float(np.percentile(filtering, 95)):.0f} | {shield.stats.overrides} of {shield.stats.steps} |")
    in_gate_cells()


def in_gate_cells(episodes: int = 6) -> None:
    """What the filter costs where it works hardest: a Table I cell (pi_2, dynamic kNN, conservative constraints, 5
    objects in gate scenes, development block 45), whose kNN selection stops the box before durable blockers, so
    most steps are stops at which every candidate (slower, sliding, turned, the brake) is checked."""
    import statistics
    import time

    from safemanip.env.slide_out import SlideOutEnv as Env
    from safemanip.evaluation.harness import EvalRequest, prepare
    from safemanip.evaluation.parallel import run_chunk

    filtering, stepping = [], []
    original_filter, original_step = BrakingShield.filter, Env.step

    def timed_filter(self, env, action, constraints):
        t0 = time.perf_counter()
        out = original_filter(self, env, action, constraints)
        filtering.append(time.perf_counter() - t0)
        return out

    def timed_step(self, action):
        t0 = time.perf_counter()
        out = original_step(self, action)
        stepping.append(time.perf_counter() - t0)
        return out

    request = EvalRequest(policy="rarl-k2-conservative-s0", n_objects=5, semantics="2 fragile, 3 durable",
                          selector="dynamic-knn", env={"layout": "gate", "gate_share": 1.0}, episodes=episodes,
                          seed_block=45, shield="brake", workers=1)
    prepared = prepare(request)
    BrakingShield.filter, Env.step = timed_filter, timed_step  # timing only; restored below
    try:
        records = run_chunk(prepared.spec, prepared.seeds)
    finally:
        BrakingShield.filter, Env.step = original_filter, original_step
    overridden = sum(r["shield_overrides"] for r in records)
    print("\n| Table I cell, gate scenes (dynamic kNN, N = 5) | env step us | filter us (median) | filter us (p95) | "
          "overridden steps |")
    print("|---|---|---|---|---|")
    print(f"| {episodes} episodes | {1e6 * statistics.median(stepping):.0f} | {1e6 * statistics.median(filtering):.0f} "
          f"| {1e6 * float(np.percentile(filtering, 95)):.0f} | {overridden} of {len(filtering)} |")


if __name__ == "__main__":
    import sys

    if sys.argv[1:] == ["--cost"]:  # only the filter's cost per step (two tables)
        cost()
    else:
        main()
