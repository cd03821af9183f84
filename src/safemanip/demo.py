"""The main job: one rollout in the default cluttered scene, a video, a JSON summary and a report."""

from __future__ import annotations

import json
import os
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

DEFAULT_SCENE = {"n_objects": 4, "seed": 7}


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


def run_demo(out_dir: str | Path = "demo_output", controller: str = "scripted", policy: str | None = None,
             seed: int = DEFAULT_SCENE["seed"], n_objects: int = DEFAULT_SCENE["n_objects"], video: bool = True,
             camera: str = "front") -> DemoResult:
    from safemanip.control.scripted import ScriptedController
    from safemanip.env.slide_out import SlideOutEnv

    os.environ.setdefault("MUJOCO_GL", "egl")
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    env = SlideOutEnv(n_objects=n_objects, render_mode="rgb_array" if video else None)
    obs, info = env.reset(seed=seed)
    if controller == "scripted":
        agent = ScriptedController()
        agent.reset()
        act = lambda obs, info: agent.act(info, env)  # noqa: E731
        agent_desc = "scripted (fast pull, then a slide to the goal; ignores clutter)"
    else:
        raise ValueError(f"unknown controller {controller!r}: use 'scripted'")
    frames = [env.render_camera(camera)] if video else []
    trace = [{"t": 0, "l": info["l"], "g": info["g"], **info["margins"]}]
    t0 = time.perf_counter()
    while True:
        obs, _, terminated, truncated, info = env.step(act(obs, info))
        trace.append({"t": info["t"], "l": info["l"], "g": info["g"], **info["margins"]})
        if video:
            frames.append(env.render_camera(camera))
        if terminated or truncated:
            break
    wall = time.perf_counter() - t0
    video_path = write_video(frames, out / "rollout", env.metadata["render_fps"]) if video else None
    summary = {
        "outcome": info["event"], "steps": info["t"], "object": info["object"], "controller": agent_desc,
        "scene": {"seed": seed, "objects": list(env.names), "constraints": list(env.constraints)},
        "video": str(video_path) if video_path else None, "wall_time_s": round(wall, 3),
        "margins_over_time": trace,
    }
    summary_path = out / "summary.json"
    summary_path.write_text(json.dumps(summary, indent=1))
    env.close()
    return DemoResult(info["event"], info["t"], info["object"], video_path, summary_path)


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
