"""The main job: one rollout in the default cluttered scene, a video, a JSON summary and a report."""

from __future__ import annotations

import json
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

DEFAULT_SCENE = {"n_objects": 4, "seed": 7}
DEFAULT_POLICY = "rarl-k2-conservative-s0"  # the one policy the package ships (src/safemanip/policies/)
_WATCH_FPS = 100  # frames per simulated second when filming every 5 substeps of 2 ms
VIDEO_FPS = (20, 25, 50, 100)
"""Frames per simulated second a demo video can have (divisors of 100)."""


@dataclass
class DemoResult:
    event: str
    steps: int
    object: str | None
    video: Path | None
    summary: Path


def write_video(frames: list[np.ndarray], path_stem: Path, fps: int) -> Path:
    """MP4 through imageio-ffmpeg (shipped in its wheel); GIF if that is unavailable."""
    import imageio.v2 as imageio

    try:
        path = path_stem.with_suffix(".mp4")
        imageio.mimwrite(path, frames, fps=fps, codec="libx264", quality=7, macro_block_size=8)
        return path
    except Exception:  # no ffmpeg backend: fall back to a GIF, which pillow always writes
        path = path_stem.with_suffix(".gif")
        imageio.mimwrite(path, frames, duration=1000 / fps, loop=0)
        return path


def run_demo(out_dir: str | Path = "demo_output", controller: str = "policy", policy: str = DEFAULT_POLICY,
             seed: int = DEFAULT_SCENE["seed"], n_objects: int = DEFAULT_SCENE["n_objects"], video: bool = True,
             camera: str = "front", selector: str = "dynamic-knn", fps: int = 50, slowmo: float = 1.0,
             embodiment: str | None = None) -> DemoResult:
    """One rollout in the default cluttered scene (ground-truth semantics judge every object).

    ``controller="policy"``: a shipped or trained policy sees the ``selector``'s k relevant objects
    through the reducer; ``"scripted"``: the fast-pull-then-slide baseline that ignores the clutter;
    ``"planner"``: the privileged planner that sees the whole scene and drives around it (``control/planner.py``).
    The video has ``fps`` frames per simulated second (rendered between control steps, from inside the
    physics substeps) and plays ``slowmo`` times slower than real time. ``embodiment``: the robot (default:
    the policy's own, the Panda for the scripted controller and the planner); a policy from another one is
    refused.
    """
    from safemanip.control.planner import GridPlanner
    from safemanip.control.scripted import ScriptedController
    from safemanip.env.slide_out import SlideOutEnv

    if controller not in ("policy", "scripted", "planner"):
        raise ValueError(f"unknown controller {controller!r}: use 'policy', 'scripted' or 'planner'")
    if fps not in VIDEO_FPS:
        raise ValueError(f"--fps must be one of {VIDEO_FPS} frames per simulated second, got {fps!r}")
    if not (isinstance(slowmo, (int, float)) and 1.0 <= slowmo <= 100.0):
        raise ValueError(f"--slowmo must be a number from 1 (real time) to 100, got {slowmo!r}")
    action_curve = 1.0  # the scripted controller and the planner command speeds linearly
    if controller == "policy":  # the policy file is checked before anything is built or written
        from safemanip.rl.checkpoint import embodiment_problem, load_policy, policy_action_curve, policy_embodiment

        actor, meta = load_policy(policy)
        problem = embodiment_problem(meta, embodiment, f"--policy {policy}")
        if problem:
            raise ValueError(problem)
        embodiment = policy_embodiment(meta)
        action_curve = policy_action_curve(meta)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    env = SlideOutEnv(n_objects=n_objects, render_mode="rgb_array" if video else None, slot_order="nearest",
                      embodiment=embodiment or "panda", action_curve=action_curve)
    frames: list[np.ndarray] = []
    trace: list[dict] = []
    selections: list[list[str]] = []

    def record(env, info, ids=()) -> None:
        trace.append({"t": info["t"], "l": info["l"], "g": info["g"], **info["margins"]})
        selections.append([env.names[i] for i in ids])
        if video and info["t"] == 0:
            frames.append(env.render_camera(camera))

    if video:  # frames between control steps: every 5 physics substeps is 100 per simulated second
        calls = {"n": 0}

        def film(env) -> None:
            calls["n"] += 1
            if calls["n"] % (_WATCH_FPS // fps) == 0:
                frames.append(env.render_camera(camera))

        env.watch_substeps(env.n_substeps // 5, film)

    t0 = time.perf_counter()
    if controller in ("scripted", "planner"):
        agent = ScriptedController() if controller == "scripted" else GridPlanner()
        _, info = env.reset(seed=seed)
        agent.reset(env)
        record(env, info)
        while True:
            _, _, terminated, truncated, info = env.step(agent.act(info, env))
            record(env, info)
            if terminated or truncated:
                break
        event, culprit, steps = info["event"], info["object"], info["t"]
        agent_desc = ("scripted (fast pull, then a slide to the goal; ignores the clutter)" if controller == "scripted"
                      else "planner (sees the whole scene: fast pull, then a path through the clutter's free space)")
    else:
        from safemanip.evaluation.episode import run_episode
        from safemanip.rl.checkpoint import resolve_policy
        from safemanip.selection.reducer import Reducer
        from safemanip.evaluation.registry import make_constraint_selector, make_object_selector

        k = int(meta["k"])
        set_network = actor.network == "set"  # takes fewer than k objects: its empty slots are masked out
        if n_objects < k and not set_network:
            raise ValueError(f"the policy needs at least k={k} objects in the scene; use --n-objects {k} or more")
        from safemanip.rl.checkpoint import policy_object_size

        reducer = Reducer(k, meta["constraints"], empty_slots=set_network, object_size=policy_object_size(meta))
        constraint_selector = make_constraint_selector("conservative" if meta["constraints"] == "conservative"
                                                       else "ground-truth")
        record_reset = {"done": False}

        def after_reset(env) -> None:
            if not record_reset["done"]:
                state = env.scene_state()
                record(env, env._info(env._margins(state), "running", None))
                record_reset["done"] = True

        result = run_episode(env, actor, reducer, make_object_selector(selector), constraint_selector, seed,
                             after_reset=after_reset, on_step=record)
        event, culprit, steps = result["event"], result["object"] or None, result["length"]
        agent_desc = (f"policy {resolve_policy(policy).name} ({meta['algorithm']}, k={k}, {meta['constraints']}) "
                      f"seeing the {k} objects picked by {selector}")
    wall = time.perf_counter() - t0
    video_path = write_video(frames, out / "rollout", fps / slowmo) if video else None
    summary = {
        "outcome": event, "steps": steps, "object": culprit, "controller": agent_desc,
        "scene": {"seed": seed, "objects": list(env.names), "constraints": list(env.constraints)},
        "embodiment": env.embodiment_name,
        "video": str(video_path) if video_path else None, "video_frames": len(frames),
        "video_fps_simulated": fps if video else None, "slowmo": slowmo if video else None,
        "wall_time_s": round(wall, 3),
        "margins_over_time": trace, "selected_over_time": selections,
    }
    summary_path = out / "summary.json"
    summary_path.write_text(json.dumps(summary, indent=1))
    env.close()
    return DemoResult(event, steps, culprit, video_path, summary_path)


def print_report(result: DemoResult, summary_path: Path) -> None:
    summary = json.loads(summary_path.read_text())
    scene = summary["scene"]
    print(f"safemanip demo: {summary['controller']}")
    print(f"  scene  : seed {scene['seed']}, " + ", ".join(f"{n} ({c})" for n, c in zip(scene["objects"], scene["constraints"])))
    culprit = f" (object: {result.object})" if result.object else ""
    print(f"  outcome: {result.event}{culprit} after {result.steps} steps ({result.steps * 0.05:.2f} s simulated)")
    last = summary["margins_over_time"][-1]
    print(f"  final margins: l = {last['l']:+.3f}, g = {last['g']:+.3f}")
    if result.video:
        print(f"  video  : {result.video}")
    print(f"  summary: {summary_path}")
