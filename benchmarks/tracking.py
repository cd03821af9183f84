"""Commanded vs achieved end-effector velocity of the Panda embodiment, for step commands.

    python benchmarks/tracking.py

From the home configuration (empty table), the end-effector is commanded a constant velocity of
0.25, 0.5, 1.0 and 1.7 m/s along +x (the pull, across the robot's front) and -y (towards the robot's
base) for 8 control steps (40 cm at 1 m/s: the arm stays mid-workspace). The env's limiter ramps each command at 13 m/s^2. Achieved velocity = the
end-effector's displacement over a control step / 50 ms. Reported: the steady achieved speed (median of
the last 4 steps), its shortfall against the command, the direction error, the rise time (the first
step end at which the speed reaches 95 % of the steady one), the worst 2 ms
acceleration, and on how many steps the joint limits scaled the IK's joint speeds down.
"""

from __future__ import annotations

import argparse

import mujoco
import numpy as np

from safemanip.env.slide_out import SlideOutEnv


def track(env: SlideOutEnv, direction: np.ndarray, speed: float, steps: int = 8) -> dict:
    env.reset(seed=0)
    fine: list[np.ndarray] = []

    def watch(e):
        velocity = np.zeros(6)
        mujoco.mj_objectVelocity(e.model, e.data, mujoco.mjtObj.mjOBJ_SITE, e.binding.ee_site, velocity, 0)
        fine.append(velocity[3:].copy())

    env.watch_substeps(1, watch)
    site = env.binding.ee_site
    positions = [env.data.site_xpos[site].copy()]
    limited = 0
    for _ in range(steps):
        env.step((direction * speed / env.max_speed).astype(np.float32))
        positions.append(env.data.site_xpos[site].copy())
        limited += getattr(env.binding, "speed_scale", 1.0) < 0.999
    env.watch_substeps(None)
    velocity = np.diff(np.array(positions), axis=0) / 0.05
    steady = np.median(velocity[-4:], axis=0)  # after the ramp (at most 3 steps to 1.7 m/s)
    achieved = float(np.linalg.norm(steady))
    cos = float(steady @ direction) / max(achieved, 1e-9)
    speeds = np.linalg.norm(velocity, axis=1)
    settle = next(i for i in range(len(speeds)) if speeds[i] >= 0.95 * achieved)
    accel = np.linalg.norm(np.diff(np.array(fine), axis=0), axis=1) / 0.002
    return {"achieved": achieved, "shortfall": 1 - achieved / speed, "direction_deg": float(np.degrees(np.arccos(min(1.0, cos)))),
            "settle_s": 0.05 * (settle + 1), "peak_accel": float(accel.max()), "limited_steps": int(limited)}


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--speeds", nargs="+", type=float, default=[0.25, 0.5, 1.0, 1.7])
    args = p.parse_args()
    env = SlideOutEnv(n_objects=0)
    print(f"{'direction':>9} {'command m/s':>11} {'achieved':>8} {'shortfall':>9} {'dir. error':>10} "
          f"{'rise time s':>11} {'peak accel (2 ms)':>17} {'joint-limited steps':>19}")
    for name, direction in (("+x", np.array([1.0, 0.0, 0.0])), ("-y", np.array([0.0, -1.0, 0.0]))):
        for speed in args.speeds:
            r = track(env, direction, speed)
            print(f"{name:>9} {speed:>11.2f} {r['achieved']:>8.2f} {100 * r['shortfall']:>8.1f}% "
                  f"{r['direction_deg']:>9.1f}° {r['settle_s']:>11.2f} {r['peak_accel']:>14.1f} m/s² "
                  f"{r['limited_steps']:>10d} of 8")


if __name__ == "__main__":
    main()
