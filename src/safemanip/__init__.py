"""safemanip: safe, dynamic manipulation in clutter with task-relevant reach-avoid RL."""

import os

# Offscreen rendering on a headless CPU machine: EGL through Mesa. Must be chosen before mujoco is
# imported; a user's own MUJOCO_GL (osmesa, glfw) wins.
os.environ.setdefault("MUJOCO_GL", "egl")

import gymnasium as gym  # noqa: E402

__version__ = "0.1.0"

if "safemanip/SlideOut-v0" not in gym.registry:
    gym.register(
        id="safemanip/SlideOut-v0",
        entry_point="safemanip.env.slide_out:SlideOutEnv",
        max_episode_steps=None,  # the env truncates itself at its max_episode_steps kwarg (default 300)
        additional_wrappers=(gym.envs.registration.WrapperSpec("TimeoutEvent", "safemanip.env.slide_out:TimeoutEvent", {}),),
    )
