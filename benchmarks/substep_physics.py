"""The arm and the grasp at physics resolution: every 2 ms substep of shipped-policy rollouts.

A real Franka checks the commanded joint motion at 1 kHz, so 50 ms figures are not enough. Per rollout this
watches every substep and prints, as shares of Franka's published limits:

* joint accelerations and jerks, by finite differences of the joint velocities (achieved) and of the servo
  set-points (commanded);
* the fingertip pads' contact force on the box against what their springs can push (a pad at the end of its
  travel would pass the arm's stiffness through);
* at the success step, the held box's speed read after the last substep, and whether a placed box stays in the
  goal for 1.5 s of zero actions afterwards;
* the drift of the hand over 10 s of zero actions from reset.

    python benchmarks/substep_physics.py --episodes 40 [--policy rarl-k2-conservative-s0]
"""

from __future__ import annotations

import argparse
import time

import mujoco
import numpy as np

from safemanip.env.slide_out import SlideOutEnv
from safemanip.rl.checkpoint import load_policy
from safemanip.scene.grasp import PAD_PRELOAD, PAD_STIFFNESS, PAD_TRAVEL
from safemanip.scene.panda import FRANKA_JOINT_ACCELS, FRANKA_JOINT_JERKS, PANDA_PADS

DT = 0.002


def pad_force(env, pad_geoms: set[int]) -> float:
    """Total normal force [N] of the pads' contacts with the held box, now."""
    m, d = env.model, env.data
    total, force = 0.0, np.zeros(6)
    for i in range(d.ncon):
        c = d.contact[i]
        if c.efc_address < 0 or not ({int(c.geom1), int(c.geom2)} & pad_geoms):
            continue
        mujoco.mj_contactForce(m, d, i, force)
        total += abs(force[0])
    return total


def rollout(env, actor, seed: int, settle_steps: int):
    """One episode watched at every substep; returns its per-substep arrays and its end."""
    samples = []

    def watch(e):
        b = e.binding
        samples.append((e.data.qvel[b.dof_adr].copy(), e.data.act[b.act_adr].copy(), pad_force(e, pads)))

    obs, _ = env.reset(seed=seed)
    pads = {env.model.geom(p).id for p in PANDA_PADS}
    env.watch_substeps(1, watch)
    watch(env)
    info = {}
    while True:
        obs, _, terminated, truncated, info = env.step(actor(obs[None])[0])
        if terminated or truncated:
            break
    end = {"event": info["event"], "success_speed": None, "left_goal": None}
    if info["event"] == "success":
        end["success_speed"] = float(np.linalg.norm(env.scene_state().bottom_vel))
        goal = np.asarray(env.geometry.goal_xy)
        left = False
        for _ in range(settle_steps):
            env.step(np.zeros(3, dtype=np.float32))
            if np.linalg.norm(env.scene_state().bottom_pos[:2] - goal) > env.thresholds.goal_radius:
                left = True
        end["left_goal"] = left
    env.watch_substeps(None)
    qvel = np.array([s[0] for s in samples])
    setpoint = np.array([s[1] for s in samples])
    return qvel, setpoint, np.array([s[2] for s in samples]), end


def zero_action_drift(seconds: float = 10.0) -> float:
    env = SlideOutEnv(n_objects=0)
    env.reset(seed=3)
    start = env.scene_state().bottom_pos[:2].copy()
    for _ in range(int(round(seconds / 0.05))):
        env.step(np.zeros(3, dtype=np.float32))
    return float(np.linalg.norm(env.scene_state().bottom_pos[:2] - start))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--policy", default="rarl-k2-conservative-s0")
    parser.add_argument("--episodes", type=int, default=40)
    parser.add_argument("--seed", type=int, default=900_000)
    args = parser.parse_args()
    actor, meta = load_policy(args.policy)
    env = SlideOutEnv(**meta["env_kwargs"])
    started = time.perf_counter()
    worst_acc, worst_jerk, worst_cmd_acc, worst_cmd_jerk, worst_pad = [], [], [], [], []
    speeds, left, events = [], [], {}
    for episode in range(args.episodes):
        qvel, setpoint, force, end = rollout(env, actor, args.seed + episode, settle_steps=30)
        events[end["event"]] = events.get(end["event"], 0) + 1
        acc = np.diff(qvel, axis=0) / DT
        cmd_acc = np.diff(setpoint, axis=0) / DT
        worst_acc.append((np.abs(acc) / FRANKA_JOINT_ACCELS).max(axis=0))
        worst_jerk.append((np.abs(np.diff(acc, axis=0) / DT) / FRANKA_JOINT_JERKS).max(axis=0))
        worst_cmd_acc.append((np.abs(cmd_acc) / FRANKA_JOINT_ACCELS).max(axis=0))
        worst_cmd_jerk.append((np.abs(np.diff(cmd_acc, axis=0) / DT) / FRANKA_JOINT_JERKS).max(axis=0))
        worst_pad.append(force.max())
        if end["success_speed"] is not None:
            speeds.append(end["success_speed"])
            left.append(end["left_goal"])
    spring_max = 2 * PAD_STIFFNESS * (PAD_PRELOAD + PAD_TRAVEL)
    rows = [("joint acceleration, achieved", np.array(worst_acc)), ("joint jerk, achieved", np.array(worst_jerk)),
            ("joint acceleration, commanded", np.array(worst_cmd_acc)),
            ("joint jerk, commanded", np.array(worst_cmd_jerk))]
    print(f"{args.episodes} rollouts of {args.policy} (seeds {args.seed}..), events {events}, "
          f"{time.perf_counter() - started:.0f} s\n")
    print("| per 2 ms substep, share of Franka's limit | worst joint, worst rollout | median rollout | rollouts over 1.1 |")
    print("|---|---|---|---|")
    for name, worst in rows:
        per_rollout = worst.max(axis=1)
        print(f"| {name} | {per_rollout.max():.2f} (joint {int(worst.max(axis=0).argmax()) + 1}) | "
              f"{np.median(per_rollout):.2f} | {int((per_rollout > 1.1).sum())} of {len(per_rollout)} |")
    pad = np.array(worst_pad)
    print(f"\npads on the box: worst {pad.max():.1f} N, median rollout's worst {np.median(pad):.1f} N; the springs "
          f"push at most {spring_max:.0f} N (both pads at the end of their travel)")
    if speeds:
        print(f"success step: box speed median {np.median(speeds):.3f} m/s, worst {max(speeds):.3f} m/s, "
              f"{sum(s > 0.05 for s in speeds)} of {len(speeds)} above 0.05 m/s; {sum(left)} of {len(left)} "
              f"placed boxes left the goal within 1.5 s of zero actions")
    print(f"zero actions from reset: the box moved {1000 * zero_action_drift():.2f} mm in 10 s")


if __name__ == "__main__":
    main()
