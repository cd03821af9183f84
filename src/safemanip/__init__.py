"""safemanip: safe, dynamic manipulation in clutter with task-relevant reach-avoid RL."""

import gymnasium as gym

__version__ = "0.1.0"

if "safemanip/SlideOut-v0" not in gym.registry:
    gym.register(
        id="safemanip/SlideOut-v0",
        entry_point="safemanip.env.slide_out:SlideOutEnv",
        max_episode_steps=None,  # the env truncates itself at max_episode_steps (default 300)
    )
